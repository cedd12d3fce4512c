"""The leaves' first bounce L1 (methods/hierarchical/solve/direct.py, SPEC §10): exact in a
furnace, against brute force, the same bits on the workers as in process, stored and resumed."""

from __future__ import annotations

import dataclasses
import json
import os
from types import SimpleNamespace

import numpy as np
import pytest

from radiosity.methods.hierarchical.solve.direct import (_Prepared, first_bounce, leaf_points,
                                                         leaf_strata, polygon_distance)
from radiosity.scene.load import load_scene
from radiosity.settings import options as settings_of
from radiosity.tracing.rays import RayCaster
from helpers import scene_path, write_scene

# an occluded floor: a unit floor (rho 0.5, the one receiver), a 0.3 x 0.3 emitter 0.5 above it
# facing down, and a blocker (rho 0) half across between them
FLOOR = """
v 0 0 0
v 1 0 0
v 1 0 1
v 0 0 1
v 0.35 0.5 0.35
v 0.65 0.5 0.35
v 0.65 0.5 0.65
v 0.35 0.5 0.65
v 0.2 0.25 0.2
v 0.5 0.25 0.2
v 0.5 0.25 0.8
v 0.2 0.25 0.8
usemtl receiver
f 1 4 3 2
usemtl emitter
f 5 6 7 8
usemtl blocker
f 9 10 11 12
"""
FLOOR_MATERIALS = """
[material.receiver]
reflectance = [0.5, 0.5, 0.5]
[material.emitter]
emission = [1.0, 1.0, 1.0]
reflectance = [0.0, 0.0, 0.0]
[material.blocker]
reflectance = [0.0, 0.0, 0.0]
two_sided = true
"""


def with_direct(s, samples=16, leaf_points=4):
    """Settings with a direct section (settings.direct comes with the split's part of issue 50)."""
    return SimpleNamespace(rays=s.rays, visibility=s.visibility,
                           direct=SimpleNamespace(samples=samples, leaf_points=leaf_points))


def grid_table(el, orig: int, n: int) -> dict:
    """A link table whose leaves are an n x n grid of original `orig` (a quad)."""
    V = el.verts[orig]
    u, v = np.meshgrid(np.arange(n) / n, np.arange(n) / n, indexing="ij")
    corners = [(0, 0), (1, 0), (1, 1), (0, 1)]
    quads = np.stack([V[0] + (u.ravel()[:, None] + a / n) * (V[1] - V[0])
                      + (v.ravel()[:, None] + b / n) * (V[3] - V[0]) for a, b in corners], 1)
    return {"verts": quads, "nverts": np.full(n * n, 4, np.int8),
            "orig": np.full(n * n, orig, np.int64), "leaf_node": np.arange(n * n)}


def jittered(rng, n):
    """(n^2, 2) points of the unit square, one uniform in each of its n x n cells."""
    cells = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    return (cells + rng.random((n * n, 2))) / n


def brute_l1(el, table, side_points=24, emitter_points=24, seed=1):
    """L1 (M,) of the front side, red: rho / pi times the mean over side_points^2 jittered points
    of each leaf of H1 = integral of Le cos cos / r^2 V over the emitter (emitter_points^2
    jittered samples, each ray cast): no contour integral, no strata of the code's."""
    rng = np.random.default_rng(seed)
    caster = RayCaster(el.verts, el.nverts, 1e-6)
    em = int(np.flatnonzero(el.emission.max(axis=(1, 2)) > 0)[0])
    E, Le, ne = el.verts[em], el.emission[em, 0, 0], el.normal[em]
    area_e = np.linalg.norm(np.cross(E[1] - E[0], E[3] - E[0]))
    out = []
    for q, o in zip(table["verts"], table["orig"]):
        a, b = jittered(rng, side_points), jittered(rng, emitter_points)
        x = q[0] + a[:, :1] * (q[1] - q[0]) + a[:, 1:] * (q[3] - q[0])
        y = E[0] + b[:, :1] * (E[1] - E[0]) + b[:, 1:] * (E[3] - E[0])
        X, Y = np.repeat(x, len(y), 0), np.tile(y, (len(x), 1))
        d = Y - X
        r2 = (d * d).sum(1)
        cx = np.maximum(d @ el.normal[o], 0) / np.sqrt(r2)
        cy = np.maximum(-(d @ ne), 0) / np.sqrt(r2)
        vis = ~caster.occluded(X, Y, np.full(len(X), o), np.full(len(X), em))
        H = (Le * cx * cy / r2 * vis).reshape(len(x), len(y)).mean(1) * area_e
        out.append(el.reflectance[o, 0, 0] / np.pi * H.mean())
    return np.array(out)


@pytest.fixture
def floor(tmp_path):
    path = write_scene(tmp_path, FLOOR, FLOOR_MATERIALS)
    return load_scene(path, settings=settings_of()).elements


def test_l1_under_a_half_blocked_emitter_matches_brute_force(floor):
    """8 x 8 leaves of the floor, lit, penumbra and umbra. Unoccluded leaves (x > 0.75) within
    0.5 % (the contour integral; 4 points a leaf), the floor's mean within 1.5 %; the penumbra's
    leaves carry the shadow rays' noise (design/methods-hierarchical-direct.md) and converge:
    with 1024 rays and 16 points every leaf within 4 % of the mean."""
    el, table = floor, grid_table(floor, 0, 8)
    ref = brute_l1(el, table)
    assert ref.min() < 0.05 * ref.max()  # the blocker's shadow is there
    L1 = first_bounce(table, el, with_direct(settings_of()))
    assert L1.shape == (2, 3, 64) and not L1[1].any()  # the floor is one-sided
    free = table["verts"][:, :, 0].min(axis=1) >= 0.75
    assert free.sum() == 16
    np.testing.assert_allclose(L1[0, 0, free], ref[free], rtol=5e-3)
    assert abs(L1[0, 0].mean() / ref.mean() - 1) < 0.015
    fine = first_bounce(table, el, with_direct(settings_of(), samples=1024, leaf_points=16))
    err = np.abs(fine[0, 0] - ref) / ref.mean()
    print(f"default: max |L1 - brute| / mean {np.abs(L1[0, 0] - ref).max() / ref.mean():.3f}, "
          f"1024 rays and 16 points: {err.max():.3f}")
    assert err.max() < 0.04


def test_a_large_leaf_near_the_emitter_takes_more_points_and_gets_closer(tmp_path):
    """The floor without the blocker as 2 x 2 leaves of 0.5 m, 0.5 m below the emitter:
    leaf_strata gives them more than 2 x 2 points, and their L1 is closer to brute force than
    with 4 points a leaf."""
    obj = FLOOR[:FLOOR.index("v 0.2 0.25")] + FLOOR[FLOOR.index("usemtl receiver"):
                                                   FLOOR.index("usemtl blocker")]
    mtl = FLOOR_MATERIALS[:FLOOR_MATERIALS.index("[material.blocker]")]
    el = load_scene(write_scene(tmp_path, obj, mtl), settings=settings_of()).elements
    table = grid_table(el, 0, 2)
    s = with_direct(settings_of())
    assert (leaf_strata(table, el, 4) > 2).all()
    ref = brute_l1(el, table, side_points=48, emitter_points=16)
    fixed = first_bounce(table, el, s, adaptive=False)[0, 0]
    more = first_bounce(table, el, s)[0, 0]
    e_fixed, e_more = np.abs(fixed / ref - 1).max(), np.abs(more / ref - 1).max()
    print(f"4 points a leaf: {e_fixed:.3f}, adaptive: {e_more:.3f}")
    assert e_more < 0.5 * e_fixed and e_more < 0.02


def test_more_points_only_where_an_emitter_can_light_the_leaf(tmp_path):
    """A 0.2 m lamp (one-sided, facing down) in a ceiling: the 1 m floor 0.5 m below gets more
    than 2 x 2 points; the ceiling beside the lamp (in its plane), a board above it (behind it)
    and a black floor tile keep 2 x 2."""
    obj = """
    v 0.4 1 0.4
    v 0.6 1 0.4
    v 0.6 1 0.6
    v 0.4 1 0.6
    v 0.6 1 0.4
    v 1.6 1 0.4
    v 1.6 1 0.6
    v 0.6 1 0.6
    v 0 0.5 0
    v 1 0.5 0
    v 1 0.5 1
    v 0 0.5 1
    v 0.4 1.1 0.4
    v 0.6 1.1 0.4
    v 0.6 1.1 0.6
    v 0.4 1.1 0.6
    v 1.2 0.5 0
    v 1.3 0.5 0
    v 1.3 0.5 0.1
    v 1.2 0.5 0.1
    usemtl emitter
    f 1 2 3 4
    usemtl wall
    f 5 6 7 8
    f 9 12 11 10
    f 13 16 15 14
    usemtl black
    f 17 20 19 18
    """
    mtl = FLOOR_MATERIALS.replace("[material.receiver]", "[material.wall]").replace(
        "[material.blocker]", "[material.black]")
    el = load_scene(write_scene(tmp_path, obj, mtl), settings=settings_of()).elements
    assert el.normal[0, 1] == -1 and el.normal[1, 1] == -1 and el.normal[2, 1] == 1
    table = {"verts": el.verts, "nverts": el.nverts, "orig": np.arange(len(el)),
             "leaf_node": np.arange(len(el))}
    s = leaf_strata(table, el, 4)
    assert s[2] > 2 and s[1] == s[3] == s[4] == 2
    assert (leaf_strata(table, el, 4, adaptive=False) == 2).all()


def test_polygon_distance_against_a_dense_grid(rng):
    """Point to quad and to triangle distance within the grid's step of the nearest of 401^2
    points on the polygon."""
    V = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0.2], [0, 1, 0.2]],
                  [[0, 0, 1], [1, 0, 1], [0, 1, 1], [0, 1, 1]]], float)
    c = rng.uniform(-1, 2, (30, 3))
    d = polygon_distance(c, V, np.tile([0, 1], (30, 1)))
    u, v = (g.ravel() for g in np.meshgrid(np.linspace(0, 1, 401), np.linspace(0, 1, 401)))
    quad = V[0, 0] + u[:, None] * (V[0, 1] - V[0, 0]) + v[:, None] * (V[0, 3] - V[0, 0])
    t = u + v <= 1
    tri = V[1, 0] + u[t, None] * (V[1, 1] - V[1, 0]) + v[t, None] * (V[1, 2] - V[1, 0])
    for k, pts in enumerate((quad, tri)):
        ref = np.linalg.norm(pts[None] - c[:, None], axis=2).min(axis=1)
        assert (d[:, k] <= ref + 1e-12).all() and (ref - d[:, k]).max() < 5e-3


def test_leaf_points_lie_in_their_leaves_and_are_stratified():
    """Per-leaf strata: s^2 points a leaf, each inside its leaf, none repeated, means at the
    leaf's centroid (the strata are symmetric)."""
    table = {"verts": np.array([[[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0]],
                                [[0, 0, 1], [1, 0, 1], [0, 1, 1], [0, 1, 1]]], float),
             "nverts": np.array([4, 3], np.int8), "orig": np.array([5, 7]),
             "leaf_node": np.array([1, 0])}
    pts, e, first = leaf_points(table, np.array([3, 2]))
    assert first.tolist() == [0, 9, 13] and e.tolist() == [7] * 9 + [5] * 4
    tri, quad = pts[:9], pts[9:]
    assert np.allclose(tri[:, 2], 1) and (tri[:, :2].sum(1) < 1).all()
    assert np.allclose(tri.mean(0), [1 / 3, 1 / 3, 1]) and len(np.unique(tri, axis=0)) == 9
    assert np.allclose(quad.mean(0), [1, 1, 0]) and len(np.unique(quad, axis=0)) == 4


def test_furnace_cube_l1_is_rho_le_everywhere():
    """Closed cube, every face emitting Le = 1, rho 0.5: from every point the emitters fill the
    hemisphere, so H1 = pi Le and L1 = rho Le = 0.5 (no shadow ray may be lost at the edges)."""
    sc = load_scene(scene_path("furnace-cube"), settings=settings_of())
    el = sc.elements
    tables = [grid_table(el, o, 3) for o in range(len(el))]
    table = {k: np.concatenate([t[k] for t in tables]) for k in ("verts", "nverts", "orig")}
    table["leaf_node"] = np.arange(len(table["orig"]))
    L1 = first_bounce(table, el, with_direct(settings_of()))
    np.testing.assert_allclose(L1[0], 0.5, rtol=0, atol=1e-9)
    assert not L1[1].any()


def test_the_token_follows_samples_leaf_points_offset_and_emitters(floor):
    """The same inputs give the same token (reused); samples, points, the rays' offset and the
    emitters each change it (recomputed)."""
    table = grid_table(floor, 0, 4)
    s = settings_of()

    def token(el=floor, adaptive=False, **kw):
        return _Prepared(table, el, with_direct(s, **kw), None, adaptive).token

    base = token()
    assert token() == base
    assert token(samples=4) != base and token(leaf_points=9) != base
    moved = SimpleNamespace(rays=SimpleNamespace(offset=1e-5), visibility=s.visibility,
                            direct=SimpleNamespace(samples=16, leaf_points=4))
    assert _Prepared(table, floor, moved, None, False).token != base
    assert token(dataclasses.replace(floor, emission=floor.emission * 2)) != base


# ----------------------------------------------------------------------------- the stage

def _run(client, tmp_path):
    """A Cornell box run at 16^2 with its links (the leaves of a real link table)."""
    from helpers import prepared
    from radiosity.methods.hierarchical.links.master import compute_links
    from radiosity.methods.hierarchical.store import LinkStore
    from radiosity.runtime.store import RunStore

    out = prepared(client, tmp_path, scene_path("cornell-box"), 16, visibility=False)
    compute_links(out, client, settings_of(), progress=False)
    rs = RunStore(out, "r+")
    return rs, LinkStore(rs).read_nodes(), rs.load_elements()


def test_the_stage_gives_the_in_process_bits_and_resumes(client, tmp_path):
    """On 2 workers, over many tasks: L1 equal to the in-process one to the bit; figures in
    report.json; a second call reuses every task; a run stopped after 3 tasks resumes with those
    3 and computes only the rest; other samples recompute every task."""
    rs, table, el = _run(client, tmp_path)
    s = with_direct(settings_of())
    here = first_bounce(table, el, s)
    figs = []
    there = first_bounce(table, el, s, rs=rs, client=client, where="workers", figures=figs)
    np.testing.assert_array_equal(there, here)
    f = figs[0]
    assert f.where == "workers" and f.tasks >= 8 and f.tasks_computed == f.tasks
    assert f.points >= 4 * f.leaves and f.shadow_rays > 0
    assert json.load(open(os.path.join(rs.run_dir, "report.json")))["direct"]["tasks"] == f.tasks
    figs = []
    again = first_bounce(table, el, s, rs=rs, client=client, where="workers", figures=figs)
    np.testing.assert_array_equal(again, here)
    assert figs[0].tasks_reused == f.tasks and figs[0].tasks_computed == 0

    class Stop(Exception):
        pass

    def stop(n):
        if n == 3:
            raise Stop

    s4 = with_direct(settings_of(), samples=4)
    with pytest.raises(Stop):
        first_bounce(table, el, s4, rs=rs, client=client, where="workers", on_done=stop)
    figs = []
    resumed = first_bounce(table, el, s4, rs=rs, client=client, where="workers", figures=figs)
    assert figs[0].tasks_reused == 3 and figs[0].tasks_computed == f.tasks - 3
    np.testing.assert_array_equal(resumed, first_bounce(table, el, s4))
    assert not np.array_equal(resumed, here)


def test_a_corrupted_direct_task_is_recomputed(client, tmp_path):
    rs, table, el = _run(client, tmp_path)
    s = with_direct(settings_of())
    first_bounce(table, el, s, rs=rs, client=client, where="workers")
    a = os.path.join(rs.path, "direct", "0")
    chunk = next(os.path.join(r, f) for r, _, fs in os.walk(a) for f in fs if "zarr.json" not in f)
    with open(chunk, "r+b") as fh:
        data = bytearray(fh.read())
        data[len(data) // 2] ^= 0xFF
        fh.seek(0)
        fh.write(data)
    figs = []
    L1 = first_bounce(table, el, s, rs=rs, client=client, where="workers", figures=figs)
    assert figs[0].tasks_corrupted_recomputed == 1 and figs[0].tasks_computed == 1
    np.testing.assert_array_equal(L1, first_bounce(table, el, s))
