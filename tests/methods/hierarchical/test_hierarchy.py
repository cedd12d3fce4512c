"""Hierarchical radiosity (--method hierarchical, SPEC §8): canonical nodes, link refinement,
link visibility, the push-pull operator, and exact answers it must reach."""

from __future__ import annotations

import dataclasses
import os
import shutil

import dask.config
import numpy as np
import pytest

from radiosity.core.exact import differential_to_rectangle, pair_form_factors_exact
from radiosity.scene.splittrees import decode, node_table, seen_originals, tree_nodes
from radiosity.methods.hierarchical.links.master import COUNTERS, LinkInputs, compute_links, refine_pairs
from radiosity.methods.hierarchical.params import resolve_params
from radiosity.methods.hierarchical.solve.transport import (LinkOperator, LocalLinkOperator,
                                                      open_link_operator)
from radiosity.tracing.rays import RayCaster
from radiosity.scene.load import load_scene
from radiosity.runtime.store import RunStore
from radiosity.scene.subdivide import split_polygons, subdivide_scene
from radiosity.settings import resolve
from helpers import link_power_balance, prepared, radiance, scene_path, write_scene
from radiosity.settings import options as settings_of

ALL_PAIRS = {"radiosity.hierarchy.min-node-size": 1e9, "radiosity.hierarchy.weight": "none",
             "radiosity.hierarchy.near-gauss-gap": float("inf"),
             "radiosity.hierarchy.far-kernel": "centroid",
             "radiosity.hierarchy.inside-solids": False,
             "radiosity.direct.mode": "links"}  # the emitters' light through the links, as pairs


def _count(counts, name):
    return int(counts[COUNTERS.index(name)])


def run_solve_links(out, client, **kw):
    """The solve of a run's links: the solve stage through the hierarchical method's seam."""
    from radiosity.stages.solve import run_solve

    run = {k: kw.pop(k) for k in ("progress", "where", "callback") if k in kw}
    if "max_iter" in kw:
        kw["max_iterations"] = kw.pop("max_iter")
    return run_solve(out, client, settings_of(**kw), method="hierarchical", **run)


def in_process(path, res=None, kernel="point-nf", epsilon=None, rays=None, seen=None, cfg=None):
    """A scene's LinkInputs without a cluster: (scene, partition, tree, inputs)."""
    sc = load_scene(path, resolution=res, settings=settings_of())
    el = sc.elements
    part, raster, _, _ = subdivide_scene(el, sc.camera)
    tree = tree_nodes(part, el)
    seen = seen_originals(raster, len(el)) if seen is None else seen
    s = resolve({"hierarchy.kernel": kernel, "hierarchy.epsilon": epsilon, "hierarchy.link-rays": rays,
                 **{f"hierarchy.{k}": v for k, v in (cfg or {}).items()}})
    prm, weight = resolve_params(el, s)
    return sc, part, tree, LinkInputs(tree, part, el, seen, prm, weight, "test", 1e-6)


# ----------------------------------------------------------------------------- the all-pairs limit

@pytest.mark.parametrize("scene, res, kernel", [("three-rectangles", 16, "point"),
                                                ("three-rectangles", 16, "point-nf"),
                                                ("cornell-box", 16, "point"),
                                                ("cornell-box", 16, "point-nf")])
def test_epsilon_zero_with_one_ray_per_leaf_pair_equals_the_pairs_method(client, tmp_path, scene,
                                                                         res, kernel,
                                                                         monkeypatch):
    """epsilon = 0 refines every link to a pair of leaves; one ray between centroids
    (--link-rays 1) is the pairs method's visibility; unseen originals are not split; near
    links use the contour integral (no Gauss shortcut); nothing is taken for inside a solid.
    Then F L and the solver's solution equal --method pairs with the same kernel (near field
    and row caps included: with the pairs' min(cap_a, cap_b), which at leaf links is what the
    hierarchical operator's CAP_MIN does; its default caps leaf by leaf, transport.leaf_caps)."""
    from radiosity.methods.hierarchical.solve import transport as transport
    from radiosity.methods.pairs.transport import open_operator
    from radiosity.stages.solve import run_solve

    monkeypatch.setattr(transport._Base, "leaf_caps", False)

    out = prepared(client, tmp_path, scene_path(scene), res)
    rs = RunStore(out)
    opP, part, el = open_operator(rs, client, kernel, settings_of())
    run_solve(out, client, settings_of(solver="cg", kernel=kernel, tol=1e-12), progress=False)
    LP = radiance(out)
    with dask.config.set(ALL_PAIRS):
        fig = compute_links(out, client,
                            settings_of(epsilon=0.0, link_rays=1)
                                .replace({"hierarchy.kernel": kernel}),
                            progress=False)
    opH, table, _, _ = open_link_operator(RunStore(out), None, "auto", settings_of())
    assert np.array_equal(table["leaf_sub"], np.arange(len(part)))
    x = np.random.default_rng(3).random((2, 3, len(part)))
    yP, yH = opP.apply(x, use_need=False), opH.apply(x, use_need=False)
    assert np.abs(yH - yP).max() <= 1e-9 * np.abs(yP).max()
    with dask.config.set(ALL_PAIRS):
        run_solve_links(out, None, solver="cg", tol=1e-12, progress=False)
    # the solver's fixed point on the leaves (leaf k is sub-element k, asserted above); the
    # final gather after it re-evaluates form factors exactly, without the pairs' row caps
    LH = RunStore(out).read_arrays("solution")["leaf_radiance"]
    assert np.abs(LH - LP).max() <= 1e-9 * np.abs(LP).max()
    assert fig["rays"] < fig["links"] + fig["dropped_orientation"]  # shafts spared some rays


# ----------------------------------------------------------------------------- canonical nodes

EMITTER_AND_TWO_RECEIVERS = """
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 0 0.5 1
v 1 0.5 1
v 1 0 1
v 0 0.5 1
v 0 1 1
v 1 1 1
v 1 0.5 1
usemtl emitter
f 1 2 3 4
usemtl receiver
f 5 6 7 8
f 9 10 11 12
"""
MATERIALS = """
[material.emitter]
emission = [1.0, 1.0, 1.0]
reflectance = [0.0, 0.0, 0.0]
[material.receiver]
reflectance = [0.5, 0.5, 0.5]
"""
CAMERA_ON_RECEIVERS = """
[camera]
position = [0.5, 0.5, 0.25]
look_at = [0.5, 0.5, 1.0]
up = [0.0, 1.0, 0.0]
fov_y = 90.0
resolution = [24, 24]
"""


def _naive_polygon(root_verts, nv, path, depth):
    """A node's polygon by walking its path with subdivide.split_polygons (the seed's rule)."""
    poly = root_verts[None].copy()
    for d in range(int(depth)):
        c0, c1, _, _ = split_polygons(poly, np.array([nv], np.int8))
        bit = (int(path) >> (63 - d)) & 1
        poly = c1 if bit else c0
    return poly[0]


def test_two_tasks_split_an_unseen_original_into_the_same_named_nodes(tmp_path):
    """The emitter is unseen: the tasks (emitter, receiver 1) and (emitter, receiver 2) split it
    independently. Nodes with the same name have bit-identical polygons, equal to walking the
    path with subdivide.split_polygons; the union tree tiles the emitter; the leaves of the seen
    receivers are exactly their camera sub-elements."""
    path = write_scene(tmp_path, EMITTER_AND_TWO_RECEIVERS, MATERIALS, camera=CAMERA_ON_RECEIVERS)
    sc, part, tree, inp = in_process(path, epsilon=1e-4, rays=4)
    el = sc.elements
    # the emitter alone is unseen: its one sub-element may split
    assert inp.ext[tree.orig == 0].all() and not inp.ext[tree.orig > 0].any()
    rc = RayCaster(el.verts, el.nverts)
    got = [refine_pairs(inp, np.array([[0, j]]), rc, polygons=True) for j in (1, 2)]
    (_, n1, _, v1), (_, n2, _, v2) = got
    assert len(n1) > 10 and len(n2) > 10
    c1 = {int(c): v for c, v in zip(n1["c"], v1)}
    c2 = {int(c): v for c, v in zip(n2["c"], v2)}
    common = set(c1) & set(c2)
    assert len(common) > 0 and len(set(c1) ^ set(c2)) > 0  # shared nodes, and nodes of one only
    for c in common:
        assert np.array_equal(c1[c], c2[c])
    for c, v in list(c1.items()) + list(c2.items()):
        p, d = decode(np.array([c], np.uint64))
        assert np.array_equal(v, _naive_polygon(el.verts[0], el.nverts[0], p[0], d[0]))
    xs = np.concatenate([n1, n2])
    table = node_table(tree, part, xs["o"], xs["c"])
    lo, orig = table.leaf_node, table.orig
    area = np.bincount(orig[lo], table.leaf_area, minlength=len(el))
    np.testing.assert_allclose(area, el.area, rtol=1e-12)
    seen = table.pnode[lo] >= 0
    assert np.array_equal(table.verts[lo[seen & (orig[lo] > 0)]],
                          part.verts[table.leaf_sub[seen & (orig[lo] > 0)]])
    leaves = tree.leaf >= 0
    assert np.array_equal(tree.verts[leaves], part.verts[tree.leaf[leaves]])


def test_a_hidden_sub_element_of_a_seen_original_is_split_on_demand(tmp_path):
    """hierarchy.split-hidden: a sub-element no pixel hits (here: receiver 1's largest, marked
    so) may split below the camera's partition like an unseen original. The union tree keeps
    the partition's own nodes above it (the closure repeats them), its new leaves tile it and
    map back to it (leaf_sub), and every other leaf of the seen originals is exactly its camera
    sub-element. (epsilon 1e-5: there the oracle asks for leaves finer than the camera's.)"""
    path = write_scene(tmp_path, EMITTER_AND_TWO_RECEIVERS, MATERIALS, camera=CAMERA_ON_RECEIVERS)
    sc, part, tree, inp = in_process(path, epsilon=1e-5, rays=4)
    el = sc.elements
    r1 = np.arange(part.offsets[1], part.offsets[2])
    big = int(r1[np.argmax(part.area[r1])])
    hit = np.ones(len(part), bool)
    hit[part.offsets[0]:part.offsets[1]] = False  # the unseen emitter's one sub-element
    hit[big] = False
    seen = seen_originals(subdivide_scene(el, sc.camera)[1], len(el))
    inp2 = LinkInputs(tree, part, el, seen, inp.params, "bf", "test", 1e-6, hit)
    assert inp2.ext[tree.leaf == big].all() and inp2.ext.sum() == 2
    rc = RayCaster(el.verts, el.nverts)
    _, nodes, _ = refine_pairs(inp2, np.array([[0, 1]]), rc)
    assert np.any(nodes["o"] == 1)  # the hidden sub-element was split
    _, nodes0, _ = refine_pairs(inp, np.array([[0, 1]]), rc)
    assert not np.any(nodes0["o"] == 1)  # and is not without split-hidden
    table = node_table(tree, part, nodes["o"], nodes["c"])
    lo = table.leaf_node
    under = table.leaf_sub == big
    assert under.sum() > 1
    np.testing.assert_allclose(table.leaf_area[under].sum(), part.area[big], rtol=1e-12)
    rest = ~under & (table.orig[lo] > 0)
    assert np.array_equal(table.verts[lo[rest]], part.verts[table.leaf_sub[rest]])
    assert sorted(set(table.leaf_sub[table.orig[lo] > 0])) == list(range(part.offsets[1], len(part)))


# ----------------------------------------------------------------------------- exact answers

def _solve(client, tmp_path, path, res=None, **kw):
    out = prepared(client, tmp_path, path, res, visibility=False)
    fig = compute_links(out, client, settings_of(), progress=False, **kw)
    run_solve_links(out, client, solver="cg", tol=1e-11, progress=False)
    rs = RunStore(out)
    return rs.load_partition(), rs.load_elements(), radiance(out), fig


@pytest.mark.parametrize("unseen", ["keep", "refine"])
def test_opposed_squares_with_the_emitter_out_of_view_pointwise(client, tmp_path, unseen):
    """Receiver (seen, rho 0.5) over an unseen unit emitter (Le = 1) at distance 1: the
    receiver's radiance is 0.5 F(x -> emitter), F from Howell's B-3 by superposition at each
    sub-element's centre; within 1 % everywhere (one element for the emitter would be off by
    up to 50 %). With subdivide.unseen: keep the emitter stays one sub-element and the links
    must split it on demand; with the default (refine) preprocessing split it already."""
    obj = """
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
    path = write_scene(tmp_path, obj, MATERIALS, camera=CAMERA_ON_RECEIVERS)
    with dask.config.set({"radiosity.subdivide.unseen": unseen}):
        part, el, L, fig = _solve(client, tmp_path, path)
    if unseen == "keep":
        assert fig["originals_split"] == 1 and fig["split_off_nodes"] > 0
    r = part.orig == 1
    x, y = part.center[r, 0], part.center[r, 1]
    F = sum(differential_to_rectangle(np.abs(a), np.abs(b), 1.0)
            for a in (x, 1 - x) for b in (y, 1 - y))
    rel = L[r, 0, 0] / (0.5 * F) - 1
    print(f"opposed squares: {fig['links']} links, max |rel err| {np.abs(rel).max():.2e}")
    assert np.abs(rel).max() < 0.01


def test_perpendicular_squares_in_the_corner_strip(client, tmp_path):
    """A seen floor (rho 0.5) and an unseen emitting wall sharing an edge at 90 degrees: the
    floor's sub-elements within 0.1 of the edge get 0.5 F(sub-element -> wall) (exact polygon
    form factor) within 2 %."""
    obj = """
    v 0 0 0
    v 0 0 1
    v 1 0 1
    v 1 0 0
    v 0 0 0
    v 1 0 0
    v 1 1 0
    v 0 1 0
    usemtl receiver
    f 1 2 3 4
    usemtl emitter
    f 5 6 7 8
    """
    cam = """
    [camera]
    position = [0.5, 2.0, 0.6]
    look_at = [0.5, 0.0, 0.6]
    up = [0.0, 0.0, 1.0]
    fov_y = 32.0
    resolution = [32, 32]
    """
    path = write_scene(tmp_path, obj, MATERIALS, camera=cam)
    part, el, L, fig = _solve(client, tmp_path, path)
    r = (part.orig == 0) & (part.center[:, 2] < 0.1)
    assert r.sum() > 20
    F = pair_form_factors_exact(part.verts[r], part.nverts[r], np.repeat(el.verts[1:2], r.sum(), 0),
                                np.repeat(el.nverts[1:2], r.sum(), 0))
    rel = L[r, 0, 0] / (0.5 * F) - 1
    print(f"perpendicular squares: {fig['links']} links, max |rel err| {np.abs(rel).max():.2e}")
    assert np.abs(rel).max() < 0.02


def test_closed_cube_rho_099_with_balanced_rows(client, tmp_path):
    """Furnace cube, rho = 0.99, Le = 1: detected closed (closure: auto), rows balanced to 1,
    the answer is Le / (1 - rho) = 100 within 0.1 %, after the final gather too (its fresh
    form factors are balanced in turn: without that, 95-105)."""
    cube = scene_path("furnace-cube")
    src = open(cube).read().replace("reflectance = [0.5, 0.5, 0.5]", "reflectance = [0.99, 0.99, 0.99]")
    src = src.replace('path = "furnace-cube.obj"',
                      f'path = "{os.path.join(os.path.dirname(cube), "furnace-cube.obj")}"')
    path = tmp_path / "furnace.toml"
    path.write_text(src)
    out = prepared(client, tmp_path, str(path), 12, visibility=False)
    compute_links(out, client, settings_of(), progress=False)
    fig = run_solve_links(out, client, solver="cg", tol=1e-12, progress=False)  # closure: auto
    assert fig["converged"] and fig["closure"]["closed"] and fig["row_sums"]["mode"] == "closed"
    L = radiance(out)[:, 0, :]
    np.testing.assert_allclose(L, 100.0, rtol=1e-3)


# ----------------------------------------------------------------------------- the operator

def test_push_pull_conserves_energy_in_an_open_scene(client, tmp_path):
    """three-rectangles is open. Emitted power = absorbed + escaped, where escaped uses each
    leaf's total outgoing form factor summed directly from the stored links over its ancestors
    (not through the operator): this holds only if pull and push weigh by area consistently.
    (The emitters' light at points, the default here: what the leaves emit is their first
    bounce, SPEC §10; the split loses and doubles no light.)"""
    out = prepared(client, tmp_path, scene_path("three-rectangles"), 16, visibility=False)
    fig = compute_links(out, client, settings_of(), progress=False)
    run_solve_links(out, client, solver="gauss-seidel", tol=1e-13, max_iter=500, progress=False)
    emitted, absorbed, escaped = link_power_balance(out)
    assert fig["links"] < fig["leaves"] ** 2 / 4 and escaped > 0.01 * emitted
    assert absorbed + escaped == pytest.approx(emitted, rel=1e-9)


def test_symmetric_form_and_every_solver_agree(client, tmp_path):
    """With both directions on every link, x . A K z = z . A K x (to 1e-12); Jacobi,
    Gauss-Seidel, progressive refinement and CG reach the same answer on the links, and the
    passes on the workers give the driver's answer."""
    out = prepared(client, tmp_path, scene_path("cornell-box"), 12, visibility=False)
    compute_links(out, client, settings_of(), progress=False)
    op, table, el, part = open_link_operator(RunStore(out), client, "cluster", settings_of())
    assert isinstance(op, LinkOperator)
    A = table["leaf_area"]
    rng = np.random.default_rng(5)
    x, z = rng.random((2, 2, 3, len(A)))
    a, b = np.sum(x * A * op.apply(z)), np.sum(z * A * op.apply(x))
    assert abs(a - b) <= 1e-12 * abs(a)
    sols = {}
    for solver in ("jacobi", "gauss-seidel", "progressive", "cg"):
        fig = run_solve_links(out, client, solver=solver, tol=1e-10, progress=False)
        assert fig["converged"], solver
        sols[solver] = radiance(out)
    ref = sols["cg"]
    for s, L in sols.items():
        assert np.abs(L - ref).max() <= 1e-7 * np.abs(ref).max(), s
    for solver in ("gauss-seidel", "cg"):  # the same passes on the workers
        run_solve_links(out, client, solver=solver, tol=1e-10, progress=False, where="cluster")
        assert np.abs(radiance(out) - sols[solver]).max() <= 1e-12 * np.abs(ref).max(), solver
    assert isinstance(open_link_operator(RunStore(out), client, "auto", settings_of())[0], LocalLinkOperator)


# ----------------------------------------------------------------------------- link visibility

TWO_SQUARES = """
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 2
v 0 1 2
v 1 1 2
v 1 0 2
usemtl emitter
f 1 2 3 4
usemtl receiver
f 5 6 7 8
"""
CAMERA_AWAY = """
[camera]
position = [0.5, 0.5, -5.0]
look_at = [0.5, 0.5, -10.0]
up = [0.0, 1.0, 0.0]
fov_y = 30.0
resolution = [8, 8]
"""


@pytest.mark.parametrize("occluder, rays", [("", False), ("side", False), ("between", True)])
def test_links_the_shafts_prove_visible_cast_no_ray(tmp_path, occluder, rays):
    """Two facing squares alone, or with an occluder beside the shaft: every link is proven
    visible by the shafts and no ray is cast; an occluder between them makes rays necessary."""
    quads = {"side": "v 3 0 0.5\nv 4 0 0.5\nv 4 1 1.5\nv 3 1 1.5\nf 9 10 11 12\n",
             "between": "v 0.2 0.2 1\nv 0.6 0.2 1\nv 0.6 0.6 1\nv 0.2 0.6 1\nf 9 10 11 12\n",
             "": ""}
    path = write_scene(tmp_path, TWO_SQUARES + quads[occluder], MATERIALS, camera=CAMERA_AWAY)
    sc, part, tree, inp = in_process(path, epsilon=1e-3, rays=16)
    links, _, counts = refine_pairs(inp, np.array([[0, 1]]), RayCaster(sc.elements.verts,
                                                                       sc.elements.nverts))
    assert len(links) > 1
    if rays:
        assert _count(counts, "rays") > 0 and np.any(links["v"] < 1)
    else:
        assert _count(counts, "rays") == 0
        assert _count(counts, "shaft_visible") == len(links) and np.all(links["v"] == 1)


@pytest.mark.parametrize("min_size", [10.0, 0.15])
def test_a_pair_of_originals_with_few_leaves_leaves_visibility_to_rays(tmp_path, min_size):
    """Two unseen facing unit squares whose refinement can reach few leaves (min-node-size at
    or above their size, as a mesh's small triangles, or a few times below it): no shaft
    search, every link takes its rays (with no occluder box proving them clear, which here,
    where nothing can block, leaves them none); the squares that may split finely are proven
    visible by the shafts (the test above)."""
    from radiosity.methods.hierarchical.links.master import SHAFT_MIN_LEAVES

    path = write_scene(tmp_path, TWO_SQUARES, MATERIALS, camera=CAMERA_AWAY)
    sc, part, tree, inp = in_process(path, epsilon=1e-3, rays=4, cfg={"min-node-size": min_size})
    leaves = max(1.0, 1.0 / inp.params.min_size ** 2)  # unit squares: area / min_size^2
    np.testing.assert_allclose(inp.reach, [leaves, leaves], rtol=1e-9)
    assert inp.reach[0] * inp.reach[1] < SHAFT_MIN_LEAVES
    hull = inp.params
    inp.params = dataclasses.replace(hull, hull_shafts=0)  # the boxes' shafts alone
    caster = RayCaster(sc.elements.verts, sc.elements.nverts)
    assert caster.occluder_boxes()[0].shape == (0, 3)  # nothing can block
    clear, _, counts_clear = refine_pairs(inp, np.array([[0, 1]]), caster)
    caster.occluder_boxes = lambda: None  # no box: every ray link casts its rays
    links, _, counts = refine_pairs(inp, np.array([[0, 1]]), caster)
    assert len(links) >= 1 and np.all(links["v"] == 1.0)
    assert _count(counts, "shaft_visible") == 0
    assert _count(counts, "rays") == 4 * _count(counts, "ray_links") > 0
    assert np.array_equal(clear, links) and _count(counts_clear, "rays") == 0
    # the tight shafts with the tree walk (off by default: on a real mesh it seldom proves
    # anything, docs/src/design/methods-hierarchical-links.md): the occluder tree holds nothing
    # between them, so no link waits for rays
    inp.params = dataclasses.replace(hull, hull_shafts=16)  # > 2: the walk
    tight, _, counts_tight = refine_pairs(inp, np.array([[0, 1]]), caster)
    assert np.array_equal(tight, links) and _count(counts_tight, "ray_links") == 0
    assert _count(counts_tight, "hull_visible") == len(links)


@pytest.mark.parametrize("height", [0.6, 1.3])
@pytest.mark.parametrize("angle", [0.0, 30.0, 75.0])
@pytest.mark.parametrize("k", [4, 16])
def test_half_occluded_pair_gets_the_visible_fraction_within_one_ray(tmp_path, height, angle, k):
    """Unit squares at z = 0 and z = 2 (one link: nothing may split) and a large occluder at
    z = height covering the half-plane through the shaft's axis at `angle`: half of all point
    pairs see each other. k stratified rays give the fraction within 1/k."""
    t = np.radians(angle)
    n, u = np.array([np.cos(t), np.sin(t)]), np.array([-np.sin(t), np.cos(t)])
    c = np.array([0.5, 0.5])
    corners = [c + 5 * u, c + 5 * u - 5 * n, c - 5 * u - 5 * n, c - 5 * u]  # behind the line
    occ = "".join(f"v {x:.12f} {y:.12f} {height}\n" for x, y in corners) + "f 9 10 11 12\n"
    path = write_scene(tmp_path, TWO_SQUARES + occ, MATERIALS, camera=CAMERA_AWAY)
    sc, part, tree, inp = in_process(path, epsilon=1e9, rays=k, seen=np.zeros(3, bool),
                                     cfg={"min-node-size": 1e9})
    links, _, counts = refine_pairs(inp, np.array([[0, 1]]),
                                    RayCaster(sc.elements.verts, sc.elements.nverts))
    assert len(links) == 1 and _count(counts, "rays") == k
    assert abs(float(links["v"][0]) - 0.5) <= 1.0 / k


# ----------------------------------------------------------------------------- store, CLI

def test_corrupted_link_task_is_detected_and_recomputed_on_resume(client, tmp_path):
    out = prepared(client, tmp_path, scene_path("three-rectangles"), 12, visibility=False)
    fig = compute_links(out, client, settings_of(), progress=False)
    from radiosity.methods.hierarchical.store import links_path

    store = os.path.join(out, "store.zarr")
    a = os.path.join(links_path(store), "0-links")
    assert os.path.isdir(a)
    chunk = next(os.path.join(r, f) for r, _, fs in os.walk(a) for f in fs if "zarr.json" not in f)
    with open(chunk, "r+b") as f:
        data = bytearray(f.read())
        data[len(data) // 2] ^= 0xFF
        f.seek(0)
        f.write(data)
    from radiosity.errors import StoreError

    with pytest.raises(StoreError, match="corrupted"):
        open_link_operator(RunStore(out), None, "auto", settings_of())[0].apply(np.ones((2, 3, fig["leaves"])))
    fig2 = compute_links(out, client, settings_of(), progress=False, resume=True)
    assert fig2["tasks_corrupted_recomputed"] == 1 and fig2["tasks_computed"] == 1
    assert fig2["links"] == fig["links"]


def test_render_with_the_hierarchical_method_from_the_cli(client, tmp_path):
    from click.testing import CliRunner

    from radiosity.cli.commands import main

    addr = client.scheduler.address
    out = str(tmp_path / "run")
    res = CliRunner().invoke(main, ["render", scene_path("three-rectangles"), "--out", out,
                                    "--resolution", "16", "--method", "hierarchical",
                                    "--epsilon", "1e-3", "--link-rays", "9", "--no-preview",
                                    "--scheduler", addr])
    assert res.exit_code == 0, res.output
    assert "links" in res.output and os.path.exists(os.path.join(out, "image.png"))
    import json

    rep = json.load(open(os.path.join(out, "report.json")))
    assert rep["links"]["link_rays"] == 9 and rep["solve"]["method"] == "hierarchical"
    bad = CliRunner().invoke(main, ["visibility", out, "--method", "hierarchical",
                                    "--link-rays", "5", "--scheduler", addr])
    assert bad.exit_code == 2 and "square" in bad.output
    shutil.rmtree(out)


def test_dashboard_heat_map_shows_link_progress_then_links_per_pair():
    """While link tasks run the heat map is the fraction done per bin of original pairs; once
    all are done it is the links per pair on a log scale (the busiest bin 1, an empty bin -1
    on the page), titled with the total."""
    from radiosity.runtime.monitor import PairBins, link_heat

    pairs = np.array([[0, 1], [0, 2], [1, 2]])
    first = np.array([0, 2, 3])  # task 0 holds pairs (0,1), (0,2); task 1 holds (1,2)
    hm, title = link_heat(pairs, first, {0: {"n": 10}}, 3)
    assert title is None and hm[0, 1] == hm[0, 2] == 1.0 and hm[1, 2] == 0.0
    hm, title = link_heat(pairs, first, {0: {"n": 10}, 1: {"n": 99}}, 3)
    assert "109 links" in title
    np.testing.assert_allclose(hm[1, 2], 1.0)
    np.testing.assert_allclose(hm[0, 1], np.log1p(5) / np.log1p(99))
    assert np.isnan(hm[2, 0]) and np.isnan(hm[0, 0])
    binned = PairBins(pairs, first, 3)  # binned once per plan, as the Monitor keeps it
    for done in ({0: {"n": 10}}, {0: {"n": 10}, 1: {"n": 99}}):
        a, b = link_heat(pairs, first, done, 3), link_heat(pairs, first, done, 3, binned=binned)
        np.testing.assert_array_equal(a[0], b[0])
        assert a[1] == b[1]


def test_method_auto_takes_hierarchical_above_the_threshold_and_says_why(tmp_path):
    """auto (the default): pairs up to radiosity.visibility.hierarchical-above sub-elements,
    hierarchical beyond; a sampled kernel keeps pairs (its rays are the pairs'); a stated method
    is kept. `radiosity plan` prints the choice and the links it would keep."""
    from click.testing import CliRunner

    from radiosity.cli.commands import main
    from radiosity.methods.base import choose_method

    with dask.config.set({"radiosity.visibility.method": "auto",
                          "radiosity.visibility.hierarchical-above": 1000}):
        s = resolve()
        assert choose_method(1000, s)[0] == "pairs" and choose_method(1001, s)[0] == "hierarchical"
        assert "1001 sub-elements > 1000" in choose_method(1001, s)[1]
        assert choose_method(10 ** 6, s.replace({"solve.kernel": "nxm"}))[0] == "pairs"
        assert choose_method(10, s.replace({"visibility.method": "hierarchical"}))[0] == "hierarchical"
        # many originals: clustered (SPEC §9); without clusters, about one sub-element each
        # leaves nothing for links to coarsen
        assert choose_method(20016, s, originals=20001)[0] == "hierarchical"
        assert "clustered" in choose_method(20016, s, originals=20001)[1]
        off = s.replace({"hierarchy.clusters": "off"})
        assert choose_method(20016, off, originals=20001)[0] == "pairs"
        assert "under 4 each" in choose_method(20016, off, originals=20001)[1]
        assert choose_method(21208, s, originals=20)[0] == "hierarchical"
        r = CliRunner().invoke(main, ["plan", scene_path("three-rectangles"), "--resolution", "64"])
    assert r.exit_code == 0, r.output
    line = [ln for ln in r.output.splitlines() if ln.startswith("method: ")]
    assert len(line) == 1 and "hierarchical: auto" in line[0] and "links" in line[0], r.output
    # clustered: the tree over the originals, the links and the link stage's time estimated
    # per original (clusters.LINKS_PER_ORIGINAL, LINKS_PER_THREAD_S)
    from radiosity.methods.hierarchical.clusters.tasks import LINKS_PER_ORIGINAL

    with dask.config.set({"radiosity.hierarchy.clusters": "on"}):
        r = CliRunner().invoke(main, ["plan", scene_path("three-rectangles"), "--resolution", "64"])
    assert r.exit_code == 0, r.output
    line = [ln for ln in r.output.splitlines() if ln.startswith("clusters: ")]
    assert len(line) == 1 and "a tree of 5 clusters over the 3 originals" in line[0], r.output
    assert f"about {LINKS_PER_ORIGINAL[0] * 3:.2g} to" in line[0] and " s on " in line[0]


def test_epsilon_auto_scales_with_the_raster_and_reaches_the_links(client, tmp_path):
    """epsilon auto (the default): epsilon-base up to epsilon-resolution^2 criterion pixels,
    base x resolution / sqrt(pixels) above, so a finer image gets finer links (more of them per
    leaf than the same epsilon would keep); a number is used as given; a bad value is one
    line. The run's report says which epsilon and why."""
    from radiosity.errors import RadiosityError
    from radiosity.methods.hierarchical.params import choose_epsilon

    s = resolve({"hierarchy.epsilon": "auto", "hierarchy.epsilon-base": 5e-4,
                 "hierarchy.epsilon-resolution": 128})
    assert choose_epsilon(s, 64 * 64)[0] == 5e-4
    assert choose_epsilon(s.hierarchy, 128 * 128)[0] == 5e-4  # the section does as well
    eps, why = choose_epsilon(s, 512 * 512)
    assert eps == pytest.approx(1.25e-4) and why.startswith("auto: 0.0005 x 128 / 512")
    assert choose_epsilon(s, None)[0] == 5e-4  # before the raster exists: the base
    assert choose_epsilon(s.replace({"hierarchy.epsilon": 2e-3}), 512 * 512) == (2e-3, "stated")
    with pytest.raises(RadiosityError, match="number >= 0 or auto, got 'fine'"):
        choose_epsilon(resolve({"hierarchy.epsilon": "fine"}), 100)
    out = prepared(client, tmp_path, scene_path("cornell-box"), 24)
    figs = {}
    for res0 in (24, 6):  # 24^2 pixels: the base; 6: a quarter of it
        with dask.config.set({"radiosity.hierarchy.epsilon": "auto",
                              "radiosity.hierarchy.epsilon-base": 2e-3,
                              "radiosity.hierarchy.epsilon-resolution": res0}):
            figs[res0] = compute_links(out, client, settings_of(), progress=False)
    assert figs[24]["epsilon"] == 2e-3 and figs[24]["epsilon_reason"] == "auto: 0.002 up to 24^2 pixels"
    assert figs[6]["epsilon"] == pytest.approx(5e-4) and "x 6 / 24" in figs[6]["epsilon_reason"]
    assert figs[6]["links_per_leaf"] > 1.5 * figs[24]["links_per_leaf"]


def test_the_final_gather_adds_no_negative_light(client, tmp_path):
    """The linear final gather spreads a link over a coarse receiver by the form factor's
    gradient; where the receiver's centroid barely sees the source and its vertices see much
    more, the unlimited plane dives below zero at the far leaves. The gradient is limited so
    that no leaf gets a negative share: room-2400 at 16^2 (2 400 originals, grazing links
    everywhere) had 19 sub-elements negative without the limit (down to -234)."""
    from radiosity.pipeline import render_scene

    out = str(tmp_path / "room")
    render_scene(load_scene(scene_path("room-2400"), resolution=16, settings=settings_of()), out,
                 client, settings_of(method="hierarchical"), preview=False, progress=False,
                 echo=lambda *a: None)
    sol = RunStore(out).read_arrays("solution")
    assert sol["leaf_radiance"].min() >= 0.0  # the solver's own fixed point
    assert sol["radiance"].min() >= 0.0, (sol["radiance"] < 0).sum()
    assert sol["radiance"].max() > 0.0


def test_far_links_gradient_in_the_final_gather_matches_exact_evaluation(client, tmp_path,
                                                                         monkeypatch):
    """The linear final gather takes the point kernel's analytic gradient over a receiver whose
    source is farther than FG_FAR times both nodes' sizes, instead of five exact point-to-
    polygon evaluations. Against the exact evaluations everywhere (FG_FAR = 0) on the Cornell
    box: far fewer evaluations, the same sub-element radiance to 0.05 % on average and 1.5 % at
    worst (the error of the method against Mitsuba is about 1 % on average)."""
    import radiosity.methods.hierarchical.solve.transport as ls
    from radiosity.pipeline import render_scene

    out = str(tmp_path / "cb")
    render_scene(load_scene(scene_path("cornell-box"), resolution=48, settings=settings_of()), out,
                 client, settings_of(method="hierarchical"), preview=False, progress=False,
                 echo=lambda *a: None)
    far0 = ls.FG_FAR
    assert far0 > 0
    runs = {}
    for far in (far0, 0.0):
        monkeypatch.setattr(ls, "FG_FAR", far)
        fig = run_solve_links(out, client, progress=False, where="driver")
        runs[far] = (fig.hierarchy["final_gather_evaluations"],
                     RunStore(out).read_arrays("solution")["radiance"])
    (e_far, fast), (e_exact, exact) = runs[far0], runs[0.0]
    assert e_far < 0.7 * e_exact, (e_far, e_exact)
    lit = exact > 1e-3 * exact.max()
    rel = np.abs(fast - exact)[lit] / exact[lit]
    assert rel.mean() < 5e-4 and rel.max() < 0.015, (rel.mean(), rel.max())
