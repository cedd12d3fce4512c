"""Points, links and sub-elements inside solids (scene/contact.inside_solid): a floor under a
block standing on it, with no bottom face, sees only the block's insides. Its points are left
out of the links' visible fractions (element links: sampling.SolidPoints; cluster links:
clusterweights.SolidEnds) and its sub-elements out of the transport
(leaves.live_leaves, stages/solve.py)."""

from __future__ import annotations

import numpy as np

from radiosity.methods.hierarchical.links.sampling import SolidPoints, link_fractions
from radiosity.scene.contact import inside_solid
from radiosity.tracing.rays import RayCaster
from radiosity.settings import options as settings_of


def _quad(a, b, c, d):
    return np.array([a, b, c, d], float)


def _block_scene(two_sided_block: bool = False):
    """A floor 0..10 (facing +y), an open-bottom block x, z in 3..6, 2 high (faces out), and a
    ceiling over x 0..2.5 at y = 10 (facing down). Returns verts (n, 4, 3), nverts, two_sided."""
    lo, hi, h = 3.0, 6.0, 2.0
    V = [_quad([0, 0, 0], [0, 0, 10], [10, 0, 10], [10, 0, 0]),
         _quad([lo, 0, lo], [hi, 0, lo], [hi, h, lo], [lo, h, lo])[::-1],
         _quad([lo, 0, hi], [hi, 0, hi], [hi, h, hi], [lo, h, hi]),
         _quad([lo, 0, lo], [lo, 0, hi], [lo, h, hi], [lo, h, lo]),
         _quad([hi, 0, lo], [hi, 0, hi], [hi, h, hi], [hi, h, lo])[::-1],
         _quad([lo, h, lo], [lo, h, hi], [hi, h, hi], [hi, h, lo]),
         _quad([0, 10, 0], [2.5, 10, 0], [2.5, 10, 10], [0, 10, 10])]
    two = np.zeros(len(V), bool)
    two[1:6] = two_sided_block
    return np.array(V), np.full(len(V), 4), two


def test_points_inside_a_solid_are_those_whose_hemisphere_rays_all_meet_backs():
    V, nv, two = _block_scene()
    rc = RayCaster(V, nv, 1e-6)
    up = np.tile([0.0, 1.0, 0.0], (6, 1))
    pts = np.array([[4.5, 0, 4.5],    # under the block
                    [3.05, 0, 3.05],  # under it, by a corner
                    [5.99, 0, 4.0],   # under it, by a side
                    [1.0, 0, 1.0],    # the open floor
                    [4.5, 0, 2.95],   # just in front of the block
                    [2.99, 0, 4.5]])  # just beside it
    assert inside_solid(rc, pts, up, two).tolist() == [True, True, True, False, False, False]
    # the block's inner faces seen from under it are two-sided: not a solid
    V2, nv2, two2 = _block_scene(two_sided_block=True)
    assert not inside_solid(RayCaster(V2, nv2, 1e-6), pts, up, two2).any()
    # a box open at the top: one hemisphere ray from its floor leaves, so it is no solid
    V3 = V[[0, 1, 2, 3, 4, 6]]
    assert not inside_solid(RayCaster(V3, nv[:6], 1e-6), pts[:3], up[:3], two[:6]).any()


def test_a_floor_node_half_under_a_block_sees_the_ceiling_by_its_live_half():
    """A floor node x 1..5 (the block covers x 3..6) linked to the ceiling above x 0..2.5:
    every ray from its live half reaches the ceiling, every ray from under the block is
    blocked. Its visible fraction: one half with every ray counted, 1 with the points inside
    the block left out (the live half's light then comes through the solve's weights,
    leaves.live_leaves)."""
    V, nv, two = _block_scene()
    rc = RayCaster(V, nv, 1e-6)
    floor = _quad([1, 0, 4], [1, 0, 5], [5, 0, 5], [5, 0, 4])
    ceil = _quad([0, 10, 4], [2.5, 10, 4], [2.5, 10, 5], [0, 10, 5])
    nverts = np.array([4, 4])
    verts = np.array([floor, ceil])
    center = verts.mean(axis=1)
    orig = np.array([0, 6])  # the originals they lie on
    normal = rc.normal
    p, q = np.array([0]), np.array([1])
    plain = link_fractions(rc, 16, verts, nverts, center, orig, p, q, None, normal)
    solid = SolidPoints(rc, normal, two)
    live = link_fractions(rc, 16, verts, nverts, center, orig, p, q, None, normal, solid)
    assert 0.3 < plain[0] < 0.7
    assert live[0] == 1.0
    # the node's four points per row of x: the two rows under the block are marked
    assert solid.mask[0] > 0 and solid.mask[1] == 0
    # a link with no blocked ray tests no point
    s2 = SolidPoints(rc, normal, two)
    free = link_fractions(rc, 16, np.array([ceil, _quad([0, 0, 4], [0, 0, 5], [1, 0, 5],
                                                        [1, 0, 4])]),
                          nverts, center, np.array([6, 0]), p, q, None, normal, s2)
    assert free[0] == 1.0 and (s2.mask < 0).all()
    # nor does a link whose every ray is blocked (wholly under the block: v = 0 either way)
    s3 = SolidPoints(rc, normal, two)
    under = _quad([3.5, 0, 4], [3.5, 0, 5], [5.5, 0, 5], [5.5, 0, 4])
    shut = link_fractions(rc, 16, np.array([under, ceil]), nverts, center, orig, p, q, None,
                          normal, s3)
    assert shut[0] == 0.0 and (s3.mask < 0).all()
    assert link_fractions(rc, 16, np.array([under, ceil]), nverts, center, orig, p, q, None,
                          normal)[0] == 0.0


def test_a_cluster_link_leaves_out_the_rays_of_elements_under_a_block():
    """Cluster links' rays (clusterweights._visible) between floor triangles beside and under
    the block and a ceiling triangle: with SolidEnds the rays that start under the block are
    left out; links with no blocked ray, and links whose every ray starts inside, are as
    before."""
    from types import SimpleNamespace

    from radiosity.methods.hierarchical.clusters.weights import SolidEnds, _visible, solid_ends

    V, nv, two = _block_scene()

    def tri(a, b, c):
        return np.array([a, b, c, c], float)

    tris = np.array([tri([1, 0, 4], [1, 0, 5], [2, 0, 4]),      # 0: beside the block
                     tri([4, 0, 4], [4, 0, 5], [5, 0, 4]),      # 1: under it
                     tri([0, 10, 4], [2, 10, 4], [0, 10, 5])])  # 2: the ceiling
    tris[2] = tris[2][[0, 2, 1, 1]]                             # facing down
    verts = np.concatenate([V, tris])
    nverts = np.concatenate([nv, [3, 3, 3]])
    two_sided = np.concatenate([two, [False] * 3])
    rc = RayCaster(verts, nverts, 1e-6)
    padded = np.where(nverts[:, None, None] == 3, verts[:, [0, 1, 2, 2]], verts)
    e = SimpleNamespace(verts=padded, normal=rc.normal, two_sided=two_sided,
                        area=np.ones(len(verts)))
    live, under, ceil = 7, 8, 9
    ep = np.array([[live, under, live, under], [live] * 4, [under] * 4])
    eq = np.full((3, 4), ceil)
    few, col = np.zeros(3, bool), np.zeros(3, np.int64)  # every link with its four rays
    clear = np.zeros(3, bool)
    plain, n = _visible(rc, e, ep, eq, few, clear, col)
    assert n == 12
    solid = SolidEnds(rc, e)
    with_solid, _ = _visible(rc, e, ep, eq, few, clear, col, solid)
    assert plain.tolist() == [0.5, 1.0, 0.0]
    assert with_solid.tolist() == [1.0, 1.0, 0.0]
    # a faint link takes the one ray of its column, and solids are not asked for it
    one, n = _visible(rc, e, ep, eq, np.ones(3, bool), clear, np.array([1, 0, 2]), solid)
    assert one.tolist() == [0.0, 1.0, 0.0] and n == 3
    assert (solid.flags[under] == 1).all()  # tested where a link had a blocked ray
    assert solid.flags[live].tolist() == [0, -1, 0, -1]
    # one per caster and process: the cluster tasks share what each found
    shared = solid_ends(rc, e)
    assert shared is solid_ends(rc, e) and shared is not solid_ends(RayCaster(verts, nverts), e)
    _visible(rc, e, ep, eq, few, clear, col, shared)
    assert np.array_equal(solid_ends(rc, e).flags, solid.flags)


def test_the_floor_under_the_cornell_boxs_blocks_takes_no_part(client, tmp_path):
    """The Cornell box (its blocks have no bottom faces) at 16^2: the floor leaves whose four
    points lie under a block are 0 in leaves.live_leaves, those across a block's edge
    between 0 and 1, every other leaf 1; the solve leaves the first out (no radiance), and a
    render without the rule (hierarchy.inside-solids false) gives them light."""
    import dask
    from scipy.spatial import Delaunay

    from helpers import prepared, scene_path
    from radiosity.core.geometry import polygon_properties
    from radiosity.methods.hierarchical.links.master import compute_links
    from radiosity.methods.hierarchical.solve.leaves import live_leaves
    from radiosity.methods.hierarchical.solve.transport import open_link_operator
    from radiosity.runtime.store import RunStore
    from radiosity.stages.solve import run_solve

    leaves = {}
    for solids in (True, False):
        with dask.config.set({"radiosity.hierarchy.inside-solids": solids}):
            out = prepared(client, tmp_path, scene_path("cornell-box"), 16, name=f"s{solids}",
                           visibility=False)
            compute_links(out, client, settings_of(), progress=False)
            run_solve(out, client, settings_of(), method="hierarchical", progress=False)
        rs = RunStore(out)
        _, table, el, _ = open_link_operator(rs, None, "auto", settings_of())
        L = rs.read_arrays("solution")["leaf_radiance"][:, 0].sum(axis=1)  # front, RGB summed
        leaves[solids] = (table, el, L)
    table, el, L = leaves[True]
    live = live_leaves(table, el, 1e-6)
    ln = table["leaf_node"]
    _, _, c = polygon_properties(table["verts"][ln], table["nverts"][ln])
    v = el.verts.reshape(-1, 3)
    feet = v[(v[:, 1] == 0.0) & (v[:, 0] > 50) & (v[:, 0] < 500) & (v[:, 2] > 50) & (v[:, 2] < 500)]
    feet = np.unique(feet[:, [0, 2]], axis=0)
    short, tall = feet[feet.sum(axis=1) < 540], feet[feet.sum(axis=1) >= 540]
    assert len(short) == len(tall) == 4
    under = ((Delaunay(short).find_simplex(c[:, [0, 2]]) >= 0)
             | (Delaunay(tall).find_simplex(c[:, [0, 2]]) >= 0)) & (np.abs(c[:, 1]) < 1e-6)
    dead = live == 0.0
    assert dead.sum() > 4 and not (dead & ~under).any()
    assert ((live > 0) & (live < 1)).any()          # across the blocks' edges
    assert (live[~under & (np.abs(c[:, 1]) > 1)] == 1.0).all()  # nothing off the floor
    assert (L[dead] == 0.0).all()
    table0, _, L0 = leaves[False]
    assert (L0[live_leaves(table0, el, 1e-6) == 0.0] > 0).any()
