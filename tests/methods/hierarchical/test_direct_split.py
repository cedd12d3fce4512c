"""The emitters' light at points, the links carrying only the light after its first bounce
(radiosity.direct.mode, SPEC §10): the furnace stays exact, the split and the old way agree as
epsilon falls, the oracle's weights and the auto rule."""

from __future__ import annotations

import os

import numpy as np
import pytest

from radiosity.core.exact import differential_to_rectangle
from radiosity.errors import RadiosityError
from radiosity.methods.hierarchical.links.master import compute_links
from radiosity.methods.hierarchical.params import (choose_direct, direct_estimate,
                                                   oracle_weights)
from radiosity.runtime.store import RunStore
from radiosity.scene.load import load_scene
from radiosity.settings import options as settings_of
from helpers import prepared, radiance, scene_path, write_scene

OPPOSED = """
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 0 1 1
v 1 1 1
v 1 0 1
usemtl emitter
f 1 2 3 4
usemtl receiver
f 5 6 7 8
"""
MATERIALS = """
[material.emitter]
emission = [1.0, 1.0, 1.0]
reflectance = [0.0, 0.0, 0.0]
[material.receiver]
reflectance = [0.5, 0.5, 0.5]
"""
CAMERA = """
[camera]
position = [0.5, 0.5, 0.25]
look_at = [0.5, 0.5, 1.0]
up = [0.0, 1.0, 0.0]
fov_y = 90.0
resolution = [16, 16]
"""


def _furnace(tmp_path, rho=0.99) -> str:
    cube = scene_path("furnace-cube")
    src = open(cube).read().replace("reflectance = [0.5, 0.5, 0.5]", f"reflectance = [{rho}, {rho}, {rho}]")
    src = src.replace('path = "furnace-cube.obj"',
                      f'path = "{os.path.join(os.path.dirname(cube), "furnace-cube.obj")}"')
    path = tmp_path / "furnace.toml"
    path.write_text(src)
    return str(path)


def _solve(client, out, links=False, leaf_points=4, **kw):
    """The run's links and solve (cg to 1e-12); the link stage's figures with `links`."""
    from radiosity.stages.solve import run_solve

    s = settings_of(**kw).replace({"direct.leaf-points": leaf_points})
    lf = compute_links(out, client, s, progress=False)
    fig = run_solve(out, client, s.replace({"solve.solver": "cg", "solve.tol": 1e-12}),
                    method="hierarchical", progress=False)
    return lf if links else fig


def _means(out) -> np.ndarray:
    """(n, 3): each original's area-weighted mean radiance of its front side."""
    rs = RunStore(out)
    part, L = rs.load_partition(), radiance(out)[:, 0, :]
    n = len(part.offsets) - 1
    w = np.zeros((n, 3))
    np.add.at(w, part.orig, part.area[:, None] * L)
    return w / np.bincount(part.orig, part.area, n)[:, None]


def test_the_furnace_with_direct_at_points_is_exact(client, tmp_path):
    """Closed cube, Le = 1, rho = 0.99: with the emitters' light at points the solve's fixed
    point is R = L1 + rho K R, L1 = rho Le exactly (the contour integral, nothing shadows), and
    Le + R = Le / (1 - rho) = 100 to 1e-6 after the final gather; the store holds R as
    leaf_radiance and says direct: points; the rounds see R (previous_solution)."""
    from radiosity.methods.hierarchical.views.rounds import previous_solution

    out = prepared(client, tmp_path, _furnace(tmp_path), 8, visibility=False)
    fig = _solve(client, out, direct="points", epsilon=0.3)  # (the answer holds at any epsilon)
    assert fig["converged"] and fig["direct"] == "points" and fig["row_sums"]["mode"] == "closed"
    np.testing.assert_allclose(radiance(out)[:, 0, :], 100.0, rtol=1e-6)
    rs = RunStore(out)
    assert rs.group_attrs("solution")["direct"] == "points"
    np.testing.assert_allclose(rs.read_arrays("solution")["leaf_radiance"][:, 0, :], 99.0, rtol=1e-6)
    np.testing.assert_allclose(previous_solution(rs)["radiance"][:, 0, :], 99.0, rtol=1e-6)


def test_the_split_and_the_old_way_agree_on_the_cornell_box(client, tmp_path):
    """The Cornell box (24^2), its emitters' light at points (16 points a leaf) and through the
    links, at epsilon 2e-3 and 5e-4: the floor (lit directly, shadows of both boxes) converges
    to the split's answer (within 1 % at 5e-4, closer than at 2e-3), every surface is within
    4 %, and the split needs fewer links. The 4 %: the tall box's front face, lit at grazing
    angles, where the links' own first bounce is 5 % low (their far-field form factors; the
    split's is the exact contour integral: Monte Carlo over both polygons, below, agrees to
    0.2 %) and stays so as epsilon falls."""
    from radiosity.methods.hierarchical.solve.direct import first_bounce

    means, links = {}, {}
    for eps in (2e-3, 5e-4):
        for mode in ("points", "links"):
            out = prepared(client, tmp_path, scene_path("cornell-box"), 24,
                           name=f"{mode}{eps}", visibility=False)
            links[mode, eps] = _solve(client, out, direct=mode, epsilon=eps, links=True,
                                      leaf_points=16).links
            s = settings_of(direct=mode, epsilon=eps)
            means[mode, eps] = _means(out)
    gap = {eps: means["points", eps] / means["links", eps] - 1 for eps in (2e-3, 5e-4)}
    floor = 0
    print(f"cornell points vs links: floor {gap[2e-3][floor].max():.4f} -> "
          f"{gap[5e-4][floor].max():.4f}, worst {np.abs(gap[5e-4]).max():.4f}, links "
          f"{links['points', 5e-4]} vs {links['links', 5e-4]}")
    assert np.abs(gap[5e-4][floor]).max() < 0.01
    assert np.abs(gap[5e-4][floor]).max() < np.abs(gap[2e-3][floor]).max()
    assert np.abs(gap[5e-4]).max() < 0.04
    assert links["points", 5e-4] < links["links", 5e-4]
    # the grazing face's first bounce against Monte Carlo over both polygons (nothing shadows it)
    rs = RunStore(out)
    el, t = rs.load_elements(), rs.read_arrays("hierarchy")
    face = 19
    L1 = first_bounce(t, el, s, k=16)[0, 0]
    o, A = t["orig"][t["leaf_node"]], t["leaf_area"]
    got = (A * L1)[o == face].sum() / A[o == face].sum()
    rng = np.random.default_rng(1)
    x, y = (_uniform(el, i, 2_000_000, rng) for i in (face, 1))
    d = y - x
    r2 = (d * d).sum(axis=1)
    f = (np.maximum(d @ el.normal[face], 0) * np.maximum(-(d @ el.normal[1]), 0)
         / (np.pi * r2 * r2) * el.area[1])
    want = el.reflectance[face, 0, 0] * el.emission[1, 0, 0] * f.mean()
    assert got == pytest.approx(want, rel=0.005)


def _uniform(el, i, n, rng) -> np.ndarray:
    """n points uniform over original i (a triangle or a quad)."""
    v = el.verts[i]
    tris = [(v[0], v[1], v[2])] + ([(v[0], v[2], v[3])] if el.nverts[i] == 4 else [])
    ar = np.array([0.5 * np.linalg.norm(np.cross(b - a, c - a)) for a, b, c in tris])
    k = rng.choice(len(tris), n, p=ar / ar.sum())
    u, w = np.sqrt(rng.random(n)), rng.random(n)
    a, b, c = (np.array([t[j] for t in tris])[k] for j in range(3))
    return a + (u * (1 - w))[:, None] * (b - a) + (u * w)[:, None] * (c - a)


def test_direct_estimate_is_the_first_bounce_at_the_centroid(tmp_path):
    """A receiver (rho 0.5) over a unit emitter (Le = 1) at distance 1: the oracle's estimate of
    its first bounce is rho F(centroid -> emitter) (Howell's B-3) on the side that faces the
    emitter, 0 on the other and on the emitter (it reflects nothing); the oracle's lhat is
    that plus the ambient term after the second bounce, never the emission."""
    sc = load_scene(write_scene(tmp_path, OPPOSED, MATERIALS, camera=CAMERA), settings=settings_of())
    el = sc.elements
    est = direct_estimate(el, 1e-6)
    F = 4 * differential_to_rectangle(0.5, 0.5, 1.0)
    side = 0 if el.normal[1, 2] < 0 else 1  # the receiver's side facing down, to the emitter
    assert est[1, side] == pytest.approx(0.5 * F, rel=1e-9)
    assert est[1, 1 - side] == 0.0 and (est[0] == 0.0).all()
    _, lhat_links, _ = oracle_weights(el, "bf")
    _, lhat, _ = oracle_weights(el, "bf", est)
    assert lhat_links[0].max() > 1.0 and lhat[0].max() < 0.5  # the emitter: no source
    assert lhat[1, side] > est[1, side]


def test_auto_takes_points_for_small_emitters_and_links_for_furnaces():
    """auto: points where the emitters are a small share of the area (the Cornell box's lamp),
    links where everything emits (the furnace) or nothing does; a stated mode is kept; the
    pairs method keeps the seed's way; a bad mode is one line naming the flag."""
    from radiosity.pipeline import direct_choice

    s = settings_of()
    cb = load_scene(scene_path("cornell-box"), settings=s).elements
    fc = load_scene(scene_path("furnace-cube"), settings=s).elements
    mode, why = choose_direct(cb, s)
    assert mode == "points" and "auto" in why and "of the area" in why
    assert choose_direct(fc, s)[0] == "links" and "100%" in choose_direct(fc, s)[1]
    assert choose_direct(fc, settings_of(direct="points"))[0] == "points"
    assert choose_direct(cb, settings_of(direct="links")) == ("links", "links: stated (--direct links)")
    assert choose_direct(cb, s.replace({"direct.auto-share": 0.0}))[0] == "links"
    assert direct_choice("pairs", cb, s)[0] == "links"
    with pytest.raises(RadiosityError, match=r"direct \(--direct, radiosity.direct.mode\) must be"):
        settings_of(direct="sometimes")
    with pytest.raises(RadiosityError, match="radiosity.direct.leaf-points must be a square"):
        settings_of(base=s.replace({"direct.leaf-points": 3}))


def test_the_cli_flag_reaches_the_setting_and_refuses_bad_values(tmp_path):
    """--direct on the commands that take --method: a bad value exits 2 with one line."""
    from click.testing import CliRunner

    from radiosity.cli.commands import main

    r = CliRunner().invoke(main, ["render", scene_path("cornell-box"), "-o", str(tmp_path / "o"),
                                  "--direct", "sometimes"])
    assert r.exit_code == 2 and "--direct" in r.output and "Traceback" not in r.output
    r = CliRunner().invoke(main, ["render", "--help"])
    assert "--direct [auto|points|links]" in r.output


def test_the_study_shows_the_old_and_the_new_way_side_by_side(client, tmp_path):
    """`study accuracy --epsilons E --direct-modes links,points`: hier:E:RAYS:MODE rows, each
    with its direct light column, both exact on the furnace cube (its [validation] radiance,
    Le / (1 - rho)); results.md has the column; a bad mode is one line."""
    from radiosity.validation.study import accuracy, kernel_setting

    rows = accuracy(scene_path("furnace-cube"), str(tmp_path / "st"), client, [8], [1],
                    ["hier:1e-3:4:links", "hier:1e-3:4:points"], [1e-9], echo=lambda *a: None,
                    settings=settings_of())
    assert [(r["kernel"], r["direct"]) for r in rows] == [("hier:1e-3:4:links", "links"),
                                                           ("hier:1e-3:4:points", "points")]
    for r in rows:
        assert r["error"] < 1e-6 and r["passes"] > 0, r
    md = open(tmp_path / "st" / "results.md").read()
    assert "| direct light |" in md and "| points |" in md and "| links |" in md
    with pytest.raises(RadiosityError, match="direct light's mode must be one of"):
        kernel_setting("hier:1e-3:4:sometimes", settings_of())
