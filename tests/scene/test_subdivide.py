"""Camera-driven subdivision (seed §3): the criterion, the split rules, parallel == sequential."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radiosity.core.camera import pixel_directions, project
from radiosity.core.geometry import polygon_properties
from radiosity.runtime.packing import capped_starts, pack_groups, subscene_ranges
from radiosity.stages.preprocess import preprocess
from radiosity.scene.load import load_scene
from radiosity.runtime.store import RunStore
from radiosity.scene.subdivide import lookup, split_polygons, subdivide, subdivide_scene
from radiosity.core.bundles import Camera, Scene
from helpers import scene_path
from radiosity.settings import options as settings_of


def _check_partition(el, part, raster, pts):
    # areas of sub-elements sum to the original area
    sums = np.bincount(part.orig, part.area, minlength=len(el))
    np.testing.assert_allclose(sums, el.area, rtol=1e-9)
    # every sub-element covers at most one pixel (two-level lookup of every hit point)
    e = raster.ravel()
    sub = lookup(part, pts, e)
    assert np.all((sub >= 0) == (e >= 0))
    assert np.bincount(sub[sub >= 0], minlength=len(part)).max() <= 1
    # lookup lands in the sub-element of the original that was hit
    assert np.array_equal(part.orig[sub[e >= 0]], e[e >= 0])
    # unseen elements stay unsplit
    seen = np.zeros(len(el), bool)
    seen[e[e >= 0]] = True
    assert np.all(np.diff(part.offsets)[~seen] == 1)
    return sub


@pytest.mark.parametrize("name", ["cornell-box", "three-rectangles", "construction-in-wood",
                                  "room-2400", "furnace-cube", "furnace-sphere"])
def test_builtin_scenes_satisfy_the_criterion(name):
    sc = load_scene(scene_path(name), resolution=48, settings=settings_of())
    part, raster, pts, fig = subdivide_scene(sc.elements, sc.camera, 1)
    _check_partition(sc.elements, part, raster, pts)
    assert fig["guarded"] == 0


def test_subpixel_criterion_on_the_finer_raster():
    sc = load_scene(scene_path("three-rectangles"), resolution=16, settings=settings_of())
    p1, *_ = subdivide_scene(sc.elements, sc.camera, 1)
    p3, raster, pts, _ = subdivide_scene(sc.elements, sc.camera, 3)
    assert raster.shape == (48, 48)
    _check_partition(sc.elements, p3, raster, pts)
    assert len(p3) > 4 * len(p1)


def test_split_rules_make_the_papers_shapes():
    # triangle: median from the opposite vertex to the midpoint of the longest edge
    tri = np.array([[[0, 0, 0], [4, 0, 0], [1, 0, 1], [1, 0, 1]]], float)
    c0, c1, a, m = split_polygons(tri, np.array([3], np.int8))
    np.testing.assert_allclose(c0[0, :3], [[0, 0, 0], [2, 0, 0], [1, 0, 1]])
    np.testing.assert_allclose(c1[0, :3], [[2, 0, 0], [4, 0, 0], [1, 0, 1]])
    # rectangle 2 x 1: the segment joins the midpoints of the two longer sides -> two unit squares
    quad = np.array([[[0, 0, 0], [0, 0, 1], [2, 0, 1], [2, 0, 0]]], float)
    c0, c1, a, m = split_polygons(quad, np.array([4], np.int8))
    for c in (c0, c1):
        area, normal, _ = polygon_properties(c, np.array([4], np.int8))
        np.testing.assert_allclose(area, 1.0)
        np.testing.assert_allclose(normal[0], [0, 1, 0])  # winding kept
        e = np.linalg.norm(np.roll(c[0], -1, 0) - c[0], axis=1)
        np.testing.assert_allclose(e, 1.0)
    assert set(map(tuple, c0[0])) | set(map(tuple, c1[0])) >= {(1.0, 0.0, 0.0), (1.0, 0.0, 1.0)}
    # the in-plane normal points into the second child
    assert np.dot(np.mean(c1[0], 0) - a[0], m[0]) > 0 > np.dot(np.mean(c0[0], 0) - a[0], m[0])


polys = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(0.05, 1), st.floats(0.05, 1),
                  st.floats(0, 2 * np.pi), st.integers(3, 4), st.integers(1, 400), st.integers(0, 2**32 - 1))


@settings(max_examples=40, deadline=None)
@given(polys)
def test_any_point_set_ends_with_at_most_one_point_per_leaf(p):
    x0, y0, sx, sy, ang, nv, npts, seed = p
    c, s = np.cos(ang), np.sin(ang)
    R = np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])
    if nv == 4:
        loc = np.array([[0, 0, 0], [0, 0, sy], [sx, 0, sy], [sx, 0, 0]])
    else:
        loc = np.array([[0, 0, 0], [0, 0, sy], [sx, 0, 0.3 * sy], [sx, 0, 0.3 * sy]])
    verts = (loc @ R.T + [x0, 0, y0])[None]
    r = np.random.default_rng(seed)
    # random points inside: barycentric in triangle (0,1,2) or (0,2,3)
    u, v = r.random(npts), r.random(npts)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = r.integers(0, nv - 2, npts)
    q = verts[0]
    pts = q[0] + u[:, None] * (q[1 + t] - q[0]) + v[:, None] * (q[2 + t] - q[0])
    pts = np.unique(pts, axis=0)
    part, fig = subdivide(verts, np.array([nv], np.int8), np.array([[0, 1.0, 0]]), pts,
                          np.zeros(len(pts), int))
    sub = lookup(part, pts, np.zeros(len(pts), np.int32))
    assert np.bincount(sub).max() <= 1
    np.testing.assert_allclose(part.area.sum(), polygon_properties(verts, np.array([nv]))[0][0], rtol=1e-9)
    assert len(part) <= 2 * len(pts) * 64  # finite and modest


def test_depth_guard_warns(recwarn):
    from radiosity.scene.subdivide import DepthGuardWarning, warn_depth_guard

    verts = np.array([[[0, 0, 0], [0, 0, 1], [1, 0, 1], [1, 0, 0]]], float)
    pts = np.array([[0.3, 0, 0.3], [0.3 + 1e-13, 0, 0.3]])
    part, fig = subdivide(verts, np.array([4], np.int8), np.array([[0, 1.0, 0]]), pts, np.zeros(2, int),
                          max_depth=6)
    assert fig["guarded"] == 1 and part.depth.max() == 6
    with pytest.warns(DepthGuardWarning, match="still cover more than one pixel after 6 splits"):
        warn_depth_guard(fig["guarded"], fig["guarded_first"], 6)


def _scaled(sc: Scene, f: float) -> Scene:
    el = sc.elements
    verts = el.verts * f
    area, normal, center = polygon_properties(verts, el.nverts)
    el2 = dataclasses.replace(el, verts=verts, area=area, normal=normal, center=center)
    c = sc.camera
    cam = Camera(c.center * f, c.x, c.y, c.z, c.focal, c.width, c.height, c.half_w, c.half_h)
    return Scene(sc.name, sc.path, el2, cam)


@pytest.mark.parametrize("factor", [1e-3, 1e3])
def test_scale_invariance(factor):
    sc = load_scene(scene_path("cornell-box"), resolution=64, settings=settings_of())
    p1, r1, *_ = subdivide_scene(sc.elements, sc.camera, 1)
    p2, r2, *_ = subdivide_scene(_scaled(sc, factor).elements, _scaled(sc, factor).camera, 1)
    assert np.array_equal(r1, r2)
    assert np.array_equal(p1.orig, p2.orig) and np.array_equal(p1.depth, p2.depth)
    np.testing.assert_allclose(p2.verts / factor, p1.verts, rtol=1e-9, atol=1e-9 * 556)


def test_parallel_partition_equals_sequential(client, tmp_path):
    from radiosity.scene.hidden import subdivide_scene_hidden
    from radiosity.settings import resolve

    sc = load_scene(scene_path("cornell-box"), resolution=64, settings=settings_of())
    s = resolve().subdivide  # with the default rule for hidden sub-elements (scene/hidden.py)
    seq, raster, pts, fig = subdivide_scene_hidden(sc.elements, sc.camera, s.hidden_factor,
                                                   s.unseen_budget, s.hidden_rays, 2)
    assert s.hidden == "refine" and fig["hidden"]["split"] > 0
    fig = preprocess(sc, str(tmp_path / "run"), client, settings_of(subpixel=2, subscenes=5),
                     progress=False)
    assert fig["subscene_tasks"] == 5
    st_ = RunStore(str(tmp_path / "run"))
    par = st_.load_partition()
    for k, v in seq.arrays().items():
        assert np.array_equal(getattr(par, k), v), k
    ras = st_.read_arrays("raster")
    assert np.array_equal(ras["orig"], raster)
    assert np.array_equal(ras["sub"].ravel(), lookup(seq, pts, raster.ravel()))
    el = st_.load_elements()
    assert el.material_names == sc.elements.material_names
    np.testing.assert_array_equal(el.verts, sc.elements.verts)
    assert st_.load_camera().to_dict() == sc.camera.to_dict()


def test_seed_variant_over_refines_hidden_elements(client, tmp_path):
    sc = load_scene(scene_path("cornell-box"), resolution=32, settings=settings_of())
    fig = preprocess(sc, str(tmp_path / "run"), client, settings_of(variant="seed", subscenes=4),
                     progress=False)
    assert fig["sub_elements"] > fig["sub_elements_exact"]
    assert fig["over_refined_elements"] > 0
    assert fig["max_pixels_per_sub_element"] <= 1


def test_subscene_ranges_are_contiguous_and_balanced():
    w = np.array([1, 1, 1, 10, 1, 1, 1, 1, 1, 1.0])
    r = subscene_ranges(w, 3)
    assert r[0][0] == 0 and r[-1][1] == len(w)
    assert all(a[1] == b[0] for a, b in zip(r, r[1:]))
    assert subscene_ranges(np.ones(2), 8) == [(0, 1), (1, 2)]


def test_capped_starts_close_each_run_before_the_cap():
    """The link stage's stripes: consecutive runs covering every item once, each within the cap
    unless it is one item above it, and each closed only where the next item would go over."""
    rng = np.random.default_rng(1)
    cost = rng.integers(1, 60, 5000).astype(np.int64)
    cost[17] = 500
    for cap in (1, 50, 100, 1000, 10 ** 9):
        s = capped_starts(cost, np.int64(cap))
        assert s[0] == 0 and s[-1] == len(cost) and (np.diff(s) > 0).all()
        sums = np.add.reduceat(cost, s[:-1])
        assert ((sums <= cap) | (np.diff(s) == 1)).all()
        assert (sums[:-1] + cost[s[1:-1]] > cap).all()
    assert capped_starts(np.zeros(0, np.int64), np.int64(5)).tolist() == [0]


def test_pack_groups_puts_the_longest_tasks_first_onto_the_least_loaded_group():
    """The solver's and the final gather's groups: every task once, each group's ids sorted,
    and the same groups as the greedy rule written out (longest first, stable among equals,
    onto the first least loaded group), for integer and float costs."""
    rng = np.random.default_rng(4)

    def greedy(cost, k):
        load, members = [0.0] * k, [[] for _ in range(k)]
        for t in sorted(range(len(cost)), key=lambda t: -cost[t]):
            g = load.index(min(load))
            members[g].append(t)
            load[g] += float(cost[t])
        return [sorted(m) for m in members if m]

    for n, k in ((5000, 2), (37, 5), (3, 8), (1, 1), (0, 2)):
        for cost in (rng.integers(1, 9, n), rng.random(n)):
            groups = pack_groups(cost, k)
            assert [g.tolist() for g in groups] == greedy(cost, k)
            assert sorted(np.concatenate(groups + [np.zeros(0, np.int64)]).tolist()) == \
                list(range(n))
    cost = rng.integers(1, 9, 5000)
    loads = [cost[g].sum() for g in pack_groups(cost, 2)]
    assert abs(loads[0] - loads[1]) <= cost.max()


def test_pixel_directions_invert_projection():
    sc = load_scene(scene_path("cornell-box"), resolution=[20, 10], settings=settings_of())
    cam = sc.camera
    d = pixel_directions(cam, 2)
    col, row, z = project(cam, cam.center + 3 * d, 2)
    c, r = np.meshgrid(np.arange(40) + 0.5, np.arange(20) + 0.5)
    np.testing.assert_allclose(col, c.ravel(), atol=1e-9)
    np.testing.assert_allclose(row, r.ravel(), atol=1e-9)


def test_numba_camera_rays_match_the_numpy_reference():
    from radiosity.core.camera import ray_directions32

    sc = load_scene(scene_path("cornell-box"), resolution=[12, 7], settings=settings_of())
    d = ray_directions32(sc.camera, 2, 3, 9)
    np.testing.assert_allclose(d, pixel_directions(sc.camera, 2, slice(3, 9)), atol=1e-7)


def test_the_footprint_holds_the_originals_between_pixel_centres_that_face_the_camera():
    """splittrees.footprint_originals: on a floor of triangles finer than the pixels, the
    triangles no pixel centre hits still count (they lie within a pixel of a hit point and face
    the camera); the same triangles turned away from the camera do not, nor does a facing floor
    far from every hit point."""
    from radiosity.core.bundles import Elements
    from radiosity.scene.splittrees import footprint_originals

    def grid(n, z, up, x0=0.0):
        tris = []
        for i in range(n):
            for j in range(n):
                a, b = (x0 + i / n, j / n, z), (x0 + (i + 1) / n, j / n, z)
                c, d = (x0 + (i + 1) / n, (j + 1) / n, z), (x0 + i / n, (j + 1) / n, z)
                for t in ((a, b, c), (a, c, d)):
                    tris.append(t if up else (t[0], t[2], t[1]))
        v = np.zeros((len(tris), 4, 3))
        v[:, :3] = tris
        v[:, 3] = v[:, 2]
        return v

    v = np.concatenate([grid(32, 0.0, True), grid(32, -0.01, False), grid(32, 0.0, True, 5.0)])
    nv = np.full(len(v), 3)
    area, normal, center = polygon_properties(v, nv)
    n = len(v)
    el = Elements(verts=v, nverts=nv.astype(np.int8), normal=normal, center=center, area=area,
                  reflectance=np.full((n, 2, 3), 0.5), emission=np.zeros((n, 2, 3)),
                  two_sided=np.zeros(n, bool), material=np.zeros(n, np.int32),
                  source=np.zeros(n, np.int32), face=np.arange(n, dtype=np.int64),
                  material_names=("m",), sources=("x",))
    g = np.arange(0.5, 8) / 8   # pixel centres every 1/8: one triangle in 32 is hit
    hp = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    hp = np.concatenate([hp, np.zeros((len(hp), 1))], 1)
    he = np.array([np.argmin(np.linalg.norm(center[:2048] - p, axis=1)) for p in hp])
    foot = footprint_originals(el, he, hp, np.zeros(len(hp), np.int64),
                               np.array([[0.5, 0.5, 3.0]]), 1 / 8)
    first = np.arange(n) < 2048
    assert foot[he].all() and len(set(he.tolist())) < 100
    assert foot[first].all()
    assert not foot[2048:].any()
