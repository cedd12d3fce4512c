"""Clustering above the originals (SPEC §9): the cluster refinement's limits (epsilon = 0 lists
exactly the facing pairs of originals), its bound, the cluster form factor against the exact
sum over triangle pairs, and that links grow like n log n, not n^2."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.core.bundles import Elements
from radiosity.core.geometry import polygon_properties
from radiosity.methods.hierarchical.clusters.refine import cluster_tree
from radiosity.methods.hierarchical.clusters.weights import link_form_factors
from radiosity.methods.hierarchical.clusters.tasks import refine_all
from radiosity.scene.originals import facing_pairs, tree_of
from radiosity.settings import options as settings_of


def _elements(verts, nverts, rho=0.5, emit=None) -> Elements:
    verts = np.asarray(verts, np.float64)
    nverts = np.asarray(nverts, np.int64)
    area, normal, center = polygon_properties(verts, nverts)
    n = len(verts)
    refl = np.full((n, 2, 3), rho)
    em = np.zeros((n, 2, 3)) if emit is None else np.asarray(emit, np.float64)
    return Elements(verts=verts, nverts=nverts.astype(np.int8), normal=normal, center=center,
                    area=area, reflectance=refl, emission=em, two_sided=np.zeros(n, bool),
                    material=np.zeros(n, np.int32), source=np.zeros(n, np.int32),
                    face=np.arange(n, dtype=np.int64), material_names=("m",), sources=("x",))


def _grid(n: int, z: float, up: bool, x0=0.0, size=1.0):
    """An n x n grid of squares cut into 2 n^2 triangles in the plane z, facing +z if `up`."""
    tris = []
    h = size / n
    for i in range(n):
        for j in range(n):
            a = (x0 + i * h, j * h, z)
            b = (x0 + (i + 1) * h, j * h, z)
            c = (x0 + (i + 1) * h, (j + 1) * h, z)
            d = (x0 + i * h, (j + 1) * h, z)
            for t in ((a, b, c), (a, c, d)):
                tris.append(t if up else (t[0], t[2], t[1]))
    v = np.zeros((len(tris), 4, 3))
    v[:, :3] = np.array(tris)
    v[:, 3] = v[:, 2]
    return v, np.full(len(tris), 3)


def _tree(el):
    from radiosity.methods.hierarchical.params import oracle_weights

    return cluster_tree(el, *oracle_weights(el, "none"))


def _sphere(n_theta: int, n_phi: int, inward: bool = True):
    """A closed triangulated sphere of radius 1 (normals inward if `inward`)."""
    th = np.linspace(0, np.pi, n_theta + 1)
    ph = np.linspace(0, 2 * np.pi, n_phi + 1)
    P = np.stack([np.sin(th)[:, None] * np.cos(ph)[None, :], np.sin(th)[:, None] * np.sin(ph)[None, :],
                  np.cos(th)[:, None] * np.ones_like(ph)[None, :]], -1)
    tris = []
    for i in range(n_theta):
        for j in range(n_phi):
            a, b, c, d = P[i, j], P[i + 1, j], P[i + 1, j + 1], P[i, j + 1]
            if i > 0:
                tris.append((a, b, d))
            if i < n_theta - 1:
                tris.append((b, c, d))
    v = np.zeros((len(tris), 4, 3))
    v[:, :3] = np.array(tris)
    if inward:
        v[:, :3] = v[:, [0, 2, 1]]
    v[:, 3] = v[:, 2]
    return v, np.full(len(tris), 3)


def test_epsilon_zero_lists_exactly_the_facing_pairs_of_originals():
    v1, n1 = _grid(6, 0.0, True)
    v2, n2 = _grid(5, 1.0, False)
    v3, n3 = _grid(4, 0.5, True, x0=0.3, size=0.4)   # a small shelf in between, both ways
    v = np.concatenate([v1, v2, v3])
    n = np.concatenate([n1, n2, n3])
    el = _elements(v, n)
    ct = _tree(el)
    links, pairs, counts = refine_all(ct, 0.0, 64)
    assert len(links) == 0
    bi, bj, _ = facing_pairs(tree_of(el))
    got = {tuple(p) for p in pairs.tolist()}
    assert got == set(zip(bi.tolist(), bj.tolist())) and len(got) == len(pairs)


def _tilted(v, axis=(0.3, -0.5, 0.8), angle=0.7, at=(0.0, 0.0, 0.0)):
    """v (n, 4, 3) turned by `angle` about `axis`, moved to `at`, rounded to float32 (as a mesh
    file stores it)."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_rotvec(np.asarray(axis) / np.linalg.norm(axis) * angle)
    out = r.apply(v.reshape(-1, 3)).reshape(v.shape) + np.asarray(at)
    return out.astype(np.float32).astype(np.float64)


def test_a_tilted_flat_face_in_float32_has_no_links_within_itself():
    """A flat face cut into 1 250 triangles, turned off the axes and rounded to float32, facing
    a plate: no cluster link and no pair of originals joins two of its triangles (they lie on
    one plane within the facing tolerance), at epsilon 0 as at a working epsilon."""
    v1, n1 = _grid(25, 0.0, True, size=1.0)
    v2, n2 = _grid(4, 0.6, False, x0=0.2, size=0.6)
    v = _tilted(np.concatenate([v1, v2]))
    el = _elements(v, np.concatenate([n1, n2]))
    face = np.arange(len(v)) < len(v1)
    normals = el.normal[face]
    assert np.ptp(normals, axis=0).max() > 0   # float32: not one normal to the bit
    ct = _tree(el)
    for eps in (0.0, 1e-3):
        links, pairs, _ = refine_all(ct, eps, 64)
        assert len(links) + len(pairs) > 0
        assert not (face[pairs[:, 0]] & face[pairs[:, 1]]).any()
        start, end, order = ct.tree.start, ct.tree.end, ct.tree.order
        within = [face[order[start[p]:end[p]]].all() and face[order[start[q]:end[q]]].all()
                  for p, q in links]
        assert not any(within), eps


def test_epsilon_zero_lists_exactly_the_facing_pairs_on_tilted_and_folded_faces():
    """The slab bound of _may_face never drops a facing pair: two tilted faces folded at a
    shallow angle (they face each other a little), a tilted plate above, and a soup of random
    triangles; epsilon 0 lists exactly originals.facing_pairs."""
    a, na = _grid(12, 0.0, True, size=1.0)
    b, nb = _grid(12, 0.0, True, x0=1.0, size=1.0)
    fold = np.radians(3.0)   # b turned up about the line x = 1: it faces a, and a faces it
    x = b[..., 0] - 1.0
    b = np.stack([1.0 + x * np.cos(fold), b[..., 1], x * np.sin(fold)], -1)
    c, nc = _grid(5, 0.4, False, x0=0.3, size=0.5)
    rng = np.random.default_rng(7)
    s = rng.random((60, 1, 3)) * 2 + rng.normal(scale=0.1, size=(60, 4, 3))
    s[:, 3] = s[:, 2]
    v = _tilted(np.concatenate([a, b, c, s]))
    el = _elements(v, np.concatenate([na, nb, nc, np.full(60, 3)]))
    ct = _tree(el)
    links, pairs, _ = refine_all(ct, 0.0, 64)
    assert len(links) == 0
    bi, bj, _ = facing_pairs(tree_of(el))
    got = {tuple(p) for p in pairs.tolist()}
    want = set(zip(bi.tolist(), bj.tolist()))
    assert got == want and len(got) == len(pairs)
    n = len(a)
    assert any(i < n <= j < 2 * n for i, j in want)   # the fold's pairs are there


def test_far_groups_are_one_cluster_link_whose_form_factor_is_the_exact_sum():
    """Two groups of 2 000 small coplanar triangles facing each other far apart: one link
    between the groups at a moderate epsilon, and its transported power within 1 % of the sum
    of the exact point-to-polygon form factors over every triangle pair."""
    from radiosity.core.exact import polygon_form_factor

    d = 20.0
    v1, n1 = _grid(32, 0.0, True, size=1.0)      # 2 048 triangles
    v2, n2 = _grid(32, d, False, size=1.0)
    el = _elements(np.concatenate([v1, v2]), np.concatenate([n1, n2]))
    ct = _tree(el)
    links, pairs, _ = refine_all(ct, 1e-2, 64)
    assert len(pairs) == 0 and len(links) >= 1
    F = link_form_factors(ct, links)
    A = ct.tree.area
    # power from group 2 to group 1 through the kept links (every link joins the two groups)
    got = float(sum(A[p] * F[k, 0] for k, (p, q) in enumerate(links)))
    # exact: the area-weighted sum over every pair, by groups of receivers (far: polygon to
    # polygon equals centroid to polygon within 1e-6 here)
    n = len(v1)
    exact = 0.0
    rng = np.random.default_rng(3)
    sample = rng.choice(n, 64, replace=False)   # receivers sampled (the field is smooth)
    for i in sample:
        exact += sum(polygon_form_factor(v1[i, :3], v2[j, :3]) for j in range(0, n, 16)) * 16
    exact *= el.area[:n].sum() / len(sample)
    assert got == pytest.approx(exact, rel=0.01)


def test_cluster_links_grow_like_n_log_n_on_a_closed_sphere():
    counts = {}
    for k in (12, 24, 48):
        v, nv = _sphere(k, 2 * k)
        el = _elements(v, nv)
        ct = _tree(el)
        links, pairs, c = refine_all(ct, 5e-3, 1024)
        counts[len(v)] = len(links) + len(pairs)
    ns = sorted(counts)
    for a, b in zip(ns, ns[1:]):
        growth = counts[b] / counts[a]
        nlogn = (b * np.log(b)) / (a * np.log(a))
        assert growth < 1.5 * nlogn, counts   # n^2 would be (b / a)^2 = 16
    assert counts[ns[-1]] < 0.05 * ns[-1] ** 2 / 2


def _plates_and_sphere():
    """The cluster tree of two facing grids of triangles and a small sphere between them:
    flat nodes, mixed ones, and links both ways of _all_face."""
    v1, n1 = _grid(10, 0.0, True)
    v2, n2 = _grid(10, 3.0, False, x0=0.5)
    v3, n3 = _sphere(8, 16, inward=False)
    v = np.concatenate([v1, v2, v3 * 0.3 + [0.5, 0.5, 1.5]])
    return _tree(_elements(v, np.concatenate([n1, n2, n3])))


def test_the_carried_light_bound_holds_and_kept_links_meet_epsilon():
    """For every kept cluster link: its form factors (clamped cosines, centroids) stay below the
    bound on the light it carries (areas, cone-bounded cosines, box distance), and its error
    bound or, where the bound is too coarse, its error estimate is below epsilon."""
    from radiosity.methods.hierarchical.clusters.refine import (_box_distance2, _cos_bound, _error_bound,
                                                         _error_estimate)

    ct = _plates_and_sphere()
    eps = 2e-3
    links, _, _ = refine_all(ct, eps, 64)
    assert len(links) > 10
    F = link_form_factors(ct, links)
    t = ct.tree
    for k, (p, q) in enumerate(links):
        d2 = _box_distance2(t.rec, p, q)
        d = np.sqrt(d2)
        cc = _cos_bound(t.rec, p, q, d) * _cos_bound(t.rec, q, p, d)
        assert F[k, 0] <= t.area[q] * cc / (np.pi * d2) * (1 + 1e-12)
        assert F[k, 1] <= t.area[p] * cc / (np.pi * d2) * (1 + 1e-12)
        assert _error_bound(t.rec, p, q, d2, ct.lref) <= eps or \
            _error_estimate(t.rec, t.start, t.end, ct.elems.ona, p, q, d2,
                            ct.lref, np.inf) < eps


def test_the_estimate_stops_once_it_reaches_epsilon_and_decides_as_the_whole_sum():
    """The estimate's element sums only grow, so it may stop at epsilon: below epsilon it is
    the whole estimate to the bit, at or above it a lower bound of the whole one that is at
    least epsilon, on flat nodes, mixed ones (a sphere's), and both branches of _all_face."""
    from radiosity.methods.hierarchical.clusters.refine import (_all_face, _box_distance2,
                                                         _error_estimate)

    ct = _plates_and_sphere()
    t = ct.tree
    rng = np.random.default_rng(3)
    pairs = rng.integers(0, ct.nodes, (4000, 2))
    full = np.array([_error_estimate(t.rec, t.start, t.end, ct.elems.ona, p, q,
                                     _box_distance2(t.rec, p, q), ct.lref, np.inf)
                     for p, q in pairs])
    finite = np.isfinite(full) & (full > 0)
    eps = float(np.median(full[finite]))
    cut = np.array([_error_estimate(t.rec, t.start, t.end, ct.elems.ona, p, q,
                                    _box_distance2(t.rec, p, q), ct.lref, eps)
                    for p, q in pairs])
    below = full < eps
    assert below.sum() > 100 and (~below & finite).sum() > 100
    np.testing.assert_array_equal(cut[below], full[below])
    assert ((cut[~below] >= eps) & (cut[~below] <= full[~below])).all()
    assert (cut[~below & finite] < full[~below & finite]).any()  # some stopped early
    along = np.array([_all_face(t.rec, p, q) for p, q in pairs])
    assert (along & finite).any() and (~along & finite).any()


def test_a_link_between_two_originals_sees_a_shadow_that_misses_their_centroids():
    """A floor triangle and the same triangle in the ceiling, a blocker between them over
    x < 0.3: the ray between their centroids passes it, so a link that cast its k rays between
    the centroids (as it did) saw the pair wholly visible. Its rays now run between four points
    of each triangle (the centroids of its midpoint sub-triangles, whose mean is the centroid):
    the link sees the shadow, within one of its four rays of the fraction that 40 000 rays
    between uniform points give."""
    from radiosity.methods.hierarchical.clusters.weights import _ends, link_weights
    from radiosity.tracing.rays import RayCaster

    floor = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 1, 0)]
    ceiling = [(0, 0, 1), (0, 1, 1), (1, 0, 1), (1, 0, 1)]
    blocker = [(-1, -1, 0.5), (-1, 2, 0.5), (0.3, 2, 0.5), (0.3, -1, 0.5)]
    el = _elements([floor, ceiling, blocker], [3, 3, 4])
    ct = _tree(el)
    leaf = {int(o): x for x, o in enumerate(ct.leaf_orig) if o >= 0}
    link = np.array([[leaf[0], leaf[1]]], np.int64)
    caster = RayCaster(el.verts, el.nverts)
    assert not caster.occluded(el.center[:1], el.center[1:2])[0]
    _, v, rays = link_weights(ct, link, caster, 4)
    assert rays == 4 and 0.0 < v[0] < 1.0
    rng = np.random.default_rng(3)

    def uniform(tri, n):
        a, b = rng.random((2, n))
        flip = a + b > 1
        a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
        t = np.asarray(tri, float)
        return t[0] + a[:, None] * (t[1] - t[0]) + b[:, None] * (t[2] - t[0])

    x, y = uniform(floor, 40_000), uniform(ceiling, 40_000)
    d = y - x
    w = d[:, 2] ** 2 / (d ** 2).sum(1) ** 2  # the kernel's cosines over r^4
    exact = 1.0 - (w * caster.occluded(x, y)).sum() / w.sum()
    assert 0.2 < exact < 0.8 and abs(v[0] - exact) <= 0.25
    pts = np.empty((4, 3))
    _ends(ct.elems.verts, np.zeros(4, np.int64), np.arange(4), pts)
    assert np.allclose(pts.mean(0), el.center[0]) and (pts[:, :2] > 0).all() \
        and (pts[:, :2].sum(1) < 1).all() and len(np.unique(pts, axis=0)) == 4


def test_faint_cluster_links_take_one_ray_and_the_others_all_of_theirs():
    """link_weights' `faint`: a link that carries at most that much light (the oracle's weights)
    casts one ray, one of its k, and every other link its k; the form factors do not change,
    and the one-ray links' fractions are what that ray alone gives."""
    from radiosity.methods.hierarchical.clusters.weights import clear_links, link_weights
    from radiosity.tracing.rays import RayCaster

    v1, n1 = _sphere(16, 32)
    v2, n2 = _sphere(6, 12, inward=False)
    el = _elements(np.concatenate([v1, v2 * 0.3]), np.concatenate([n1, n2]),
                   emit=np.full((len(v1) + len(v2), 2, 3), 1.0))
    from radiosity.methods.hierarchical.params import oracle_weights

    ct = cluster_tree(el, *oracle_weights(el, "bf"))
    links, _, _ = refine_all(ct, 1e-3, 64)
    caster = RayCaster(el.verts, el.nverts)
    F4, v4, r4 = link_weights(ct, links, caster, 4)
    clear = clear_links(ct.tree.rec, links, *caster.occluder_boxes())  # cast no ray
    assert r4 == 4 * (~clear).sum()
    t, p, q = ct.tree, links[:, 0], links[:, 1]  # the carried light, as the oracle weighs it
    c = np.maximum(t.rho[p] * F4[:, 0] * t.lhat[q], t.rho[q] * F4[:, 1] * t.lhat[p]) / ct.lref
    faint = float(np.median(c))
    F, v, r = link_weights(ct, links, caster, 4, faint=faint)
    few = c <= faint
    assert 0 < few.sum() < len(links) and r == 4 * (~few & ~clear).sum() + (few & ~clear).sum()
    assert np.array_equal(F, F4) and np.array_equal(v[~few], v4[~few])
    F1, v1_, _ = link_weights(ct, links, caster, 4, faint=np.inf)
    assert np.array_equal(v[few], v1_[few]) and set(np.unique(v1_)) <= {0.0, 1.0}
    assert (v1_ != v4).any()  # one ray is not four


def _plane(n, axis, at, sign, lo=(0.0, 0.0), size=(1.0, 1.0)):
    """n x n squares cut in two on the plane x[axis] = at, facing sign * e_axis, spanning lo to
    lo + size on the other two axes (in cyclic order)."""
    a1, a2 = (axis + 1) % 3, (axis + 2) % 3
    tris = []
    for i in range(n):
        for j in range(n):
            def at_(u, v):
                p = [0.0, 0.0, 0.0]
                p[axis], p[a1], p[a2] = at, lo[0] + size[0] * u / n, lo[1] + size[1] * v / n
                return p
            a, b, c, d = at_(i, j), at_(i + 1, j), at_(i + 1, j + 1), at_(i, j + 1)
            for t in ((a, b, c), (a, c, d)):
                tris.append(t if sign > 0 else (t[0], t[2], t[1]))
    v = np.zeros((len(tris), 4, 3))
    v[:, :3] = np.array(tris)
    v[:, 3] = v[:, 2]
    return v


def test_one_ray_links_are_not_biased_toward_any_part_of_their_nodes():
    """A closed unit room of 3 072 triangles with a block standing on its floor: the cluster
    links' transfer sum g v with one ray each (faint: every link) is that with 16 rays each,
    within 0.4 % in all and 3 % over the partly visible links. One fixed column of the k for
    every link put all those rays' ends at the same place of each node (in the tree's order,
    low on the walls, near the block): 0.991 and 0.86."""
    from radiosity.methods.hierarchical.clusters.weights import clear_links, link_weights
    from radiosity.methods.hierarchical.params import oracle_weights
    from radiosity.tracing.rays import RayCaster

    el = _room_with_block(16)
    ct = cluster_tree(el, *oracle_weights(el, "bf"))
    links, _, _ = refine_all(ct, 2e-3, 64)
    caster = RayCaster(el.verts, el.nverts)
    F, v16, _ = link_weights(ct, links, caster, 16)
    _, v1, rays = link_weights(ct, links, caster, 4, faint=np.inf)
    clear = clear_links(ct.tree.rec, links, *caster.occluder_boxes())  # take no ray
    assert rays == (~clear).sum() > 20_000 and len(links) > 50_000
    g = ct.tree.area[links[:, 0]] * F[:, 0]
    part = (v16 > 0) & (v16 < 1)
    assert part.sum() > 1000
    assert (g * v1).sum() / (g * v16).sum() == pytest.approx(1.0, abs=0.004)
    assert (g * v1)[part].sum() / (g * v16)[part].sum() == pytest.approx(1.0, abs=0.03)


def _room_with_block(n: int = 16):
    parts = [_plane(n, 2, 0.0, 1), _plane(n, 2, 1.0, -1), _plane(n, 0, 0.0, 1),
             _plane(n, 0, 1.0, -1), _plane(n, 1, 0.0, 1), _plane(n, 1, 1.0, -1)]
    m = max(2, n // 4)
    parts += [_plane(m, 2, 0.4, 1, (0.3, 0.3), (0.3, 0.3)),
              _plane(m, 0, 0.3, -1, (0.3, 0.0), (0.3, 0.4)), _plane(m, 0, 0.6, 1, (0.3, 0.0), (0.3, 0.4)),
              _plane(m, 1, 0.3, -1, (0.0, 0.3), (0.4, 0.3)), _plane(m, 1, 0.6, 1, (0.0, 0.3), (0.4, 0.3))]
    v = np.concatenate(parts)
    return _elements(v, np.full(len(v), 3), emit=np.full((len(v), 2, 3), 1.0))


def test_links_clear_of_every_occluder_box_cast_no_ray_and_see_the_same():
    """RayCaster.occluder_boxes and shafts.clear_of: in a room of 3 072 triangles with a block on its
    floor, the boxes hold the block (the walls, in the hull's planes, block nothing). The
    cluster links and the element-level ray links whose ends' box is apart from them cast no
    ray; the visible fractions, links and form factors are the same as with every ray cast,
    and rays through the block still find it."""
    from radiosity.methods.hierarchical.clusters.weights import clear_links, link_weights
    from radiosity.methods.hierarchical.params import oracle_weights
    from radiosity.tracing.rays import RayCaster

    el = _room_with_block(16)
    caster = RayCaster(el.verts, el.nverts)
    lo, hi = caster.occluder_boxes()
    block = el.verts[3072:, :3].reshape(-1, 3)
    assert len(lo) == 8 and (lo.min(0) <= block.min(0)).all() and (hi.max(0) >= block.max(0)).all()
    assert (lo.min(0)[:2] > 0.29).all() and (hi.max(0) < [0.61, 0.61, 0.41]).all()
    ct = cluster_tree(el, *oracle_weights(el, "bf"))
    links, _, _ = refine_all(ct, 2e-3, 64)
    clear = clear_links(ct.tree.rec, links, lo, hi)
    F, v, r = link_weights(ct, links, caster, 4)
    every = RayCaster(el.verts, el.nverts)
    every.occluder_boxes = lambda: None  # no box: every link casts its rays
    F0, v0, r0 = link_weights(ct, links, every, 4)
    assert 0.1 < clear.mean() < 0.9 and (v0[~clear] < 1).any()
    assert np.array_equal(F, F0) and np.array_equal(v, v0) and (v0[clear] == 1).all()
    assert r0 == 4 * len(links) and r == 4 * (~clear).sum()
    # the element level's ray links (nodes here: the originals themselves)
    from radiosity.methods.hierarchical.links.sampling import clear_pairs, link_fractions

    rng = np.random.default_rng(3)
    p, q = rng.integers(0, len(el.verts), (2, 4000))
    args = (el.verts, el.nverts, el.center, np.arange(len(el.verts)), p, q, None)
    cp = clear_pairs(el.verts, el.nverts, p, q, lo, hi)
    w = link_fractions(caster, 4, *args)
    assert 0.1 < cp.mean() < 0.9 and (w[~cp] < 1).any() and (w[cp] == 1).all()
    assert np.array_equal(link_fractions(caster, 4, *args, None, None, cp), w)
    weighted = link_fractions(caster, 4, *args, el.normal)  # rays weighted by the kernel
    assert np.array_equal(link_fractions(caster, 4, *args, el.normal, None, cp), weighted)


def test_unseen_receivers_weigh_less_only_where_both_ends_are_unseen():
    """params.cluster_weights: the light to originals no camera sees weighs `importance` in the
    cluster oracle. On a room with a block whose walls no camera sees: with every original seen
    the weights are oracle_weights'; the links (and the pairs handed down) whose two ends both
    hold a seen original are the same at importance 0.25 as at 1 (every link above them holds a
    seen original at both ends too, and a node's weight is its largest); the links between
    wholly unseen nodes are fewer."""
    from radiosity.methods.hierarchical.params import cluster_weights, oracle_weights

    el = _room_with_block(16)
    zfloor = np.abs(el.normal[:, 2]) > 0.5  # the floors, the ceiling and the block's top
    base = oracle_weights(el, "bf")
    same = cluster_weights(el, "bf", np.ones(len(el), bool), 0.25)
    assert all(np.array_equal(a, b) for a, b in zip(same[:2], base[:2])) and same[2] == base[2]
    w = cluster_weights(el, "bf", zfloor, 0.25)
    np.testing.assert_array_equal(w[0][zfloor], base[0][zfloor])
    np.testing.assert_allclose(w[0][~zfloor], 0.25 * base[0][~zfloor])
    np.testing.assert_array_equal(w[1], base[1])

    def run(weights):
        ct = cluster_tree(el, *weights)
        links, pairs, _ = refine_all(ct, 0.02)
        t = ct.tree
        cs = np.concatenate([[0], np.cumsum(zfloor[t.order])])
        any_seen = (cs[t.end] - cs[t.start]) > 0
        both = any_seen[links[:, 0]] & any_seen[links[:, 1]]
        none = ~any_seen[links[:, 0]] & ~any_seen[links[:, 1]]
        key = {tuple(x) for x in links[both]}
        pk = {tuple(x) for x in pairs[zfloor[pairs[:, 0]] & zfloor[pairs[:, 1]]]}
        return key, pk, int(none.sum()), len(links) + len(pairs)

    k1, p1, none1, all1 = run(base)
    k4, p4, none4, all4 = run(w)
    assert len(k1) > 100 and k1 == k4 and p1 == p4
    assert none4 < none1 and all4 < all1


@pytest.mark.slow  # 20 s of CPU with the kernels cached: over half of the rest of the fast subset
def test_small_unseen_clusters_stay_whole_and_the_links_still_cover_every_facing_pair():
    """cluster_tree's `stop`: nodes wholly unseen and at most min_size across are not split
    where a link to them can be kept (the element level's min-node-size for unseen originals).
    On a room with a block whose walls no camera sees: the links and pairs still cover every
    facing pair of triangles once; every kept link meets epsilon unless neither of its ends
    can split; fewer links reach below the stopped nodes; epsilon 0 still lists exactly the
    facing pairs of originals."""
    from radiosity.methods.hierarchical.clusters.refine import (_box_distance2, _error_bound,
                                                         _error_estimate)
    from radiosity.methods.hierarchical.params import oracle_weights

    el = _room_with_block(16)
    seen = np.abs(el.normal[:, 2]) > 0.5  # the floors, the ceiling and the block's top
    w = oracle_weights(el, "bf")
    eps = 0.005
    plain = cluster_tree(el, *w)
    ct = cluster_tree(el, *w, unseen=~seen, min_size=0.15)
    t = ct.tree
    assert t.stop.any() and not plain.tree.stop.any()
    assert not t.stop[t.left < 0].any()
    cs = np.concatenate([[0], np.cumsum(seen[t.order])])
    assert ((cs[t.end] - cs[t.start])[t.stop] == 0).all()
    assert (np.sqrt(t.area[t.stop]) <= 0.15).all()

    d = el.center[None, :, :] - el.center[:, None, :]
    facing = (np.einsum("ic,ijc->ij", el.normal, d) > 0) & \
        (np.einsum("jc,ijc->ij", el.normal, d) < 0)

    def covered(tree, lk, pr):  # how often each pair of triangles is covered
        c = np.zeros((len(el), len(el)), np.int16)
        for p, q in lk:
            ep = tree.order[tree.start[p]:tree.end[p]]
            eq = tree.order[tree.start[q]:tree.end[q]]
            c[ep[:, None], eq] += 1
        c[pr[:, 0], pr[:, 1]] += 1
        return c + c.T

    L0, P0, _ = refine_all(plain, eps)
    L1, P1, _ = refine_all(ct, eps)
    both = facing & facing.T
    assert (covered(plain.tree, L0, P0)[both] == 1).all()
    assert (covered(t, L1, P1)[both] == 1).all()
    whole = (t.left < 0) | t.stop
    over = 0
    for p, q in L1:
        d2 = _box_distance2(t.rec, p, q)
        ok = _error_bound(t.rec, p, q, d2, ct.lref) <= eps or \
            _error_estimate(t.rec, t.start, t.end, ct.elems.ona, p, q, d2, ct.lref,
                            np.inf) < eps
        assert ok or (whole[p] and whole[q])
        over += not ok
    assert over > 0

    def below_stops(tree, lk):  # link ends strictly inside a stopped node of `t`
        inside = np.zeros(len(el), bool)
        for x in np.flatnonzero(t.stop):
            inside[t.order[t.start[x]:t.end[x]]] = True
        size = tree.end - tree.start
        return sum(1 for p, q in lk for x in (p, q)
                   if inside[tree.order[tree.start[x]]] and size[x] < 4)

    assert below_stops(t, L1) < 0.8 * below_stops(plain.tree, L0) and len(L1) < len(L0)
    links, pairs, _ = refine_all(ct, 0.0)
    bi, bj, _ = facing_pairs(tree_of(el))
    assert len(links) == 0 and {tuple(p) for p in pairs.tolist()} == set(zip(bi.tolist(),
                                                                               bj.tolist()))


@pytest.mark.parametrize("key,value,words", [
    ("hierarchy.clusters-epsilon", 0.0, "clusters-epsilon must be above 0, got 0.0"),
    ("hierarchy.unseen-importance", 0.0, "unseen-importance must be in (0, 1], got 0.0"),
    ("hierarchy.unseen-importance", 1.5, "unseen-importance must be in (0, 1], got 1.5")])
def test_the_cluster_layers_settings_are_checked_up_front(key, value, words):
    """resolve_params (the method's check before any cluster starts) names the bad setting."""
    import re

    from radiosity.errors import RadiosityError
    from radiosity.methods.hierarchical.params import resolve_params
    from radiosity.settings import resolve

    el = _elements(*_grid(2, 0.0, True))
    with pytest.raises(RadiosityError, match=re.escape(words)):
        resolve_params(el, resolve({key: value}))


def test_partly_visible_cluster_links_are_split_and_cover_the_same_pairs():
    """clustertasks._shadows on a closed room with a block on its floor: afterwards no kept
    link that carries more than the shadow threshold is partly visible, some were split, and
    the kept links and the pairs handed down cover every pair of facing triangles that the
    links before covered, each once."""
    from radiosity.methods.hierarchical.clusters.tasks import _shadows
    from radiosity.methods.hierarchical.params import oracle_weights
    from radiosity.tracing.rays import RayCaster

    el = _room_with_block(8)
    ct = cluster_tree(el, *oracle_weights(el, "bf"))
    eps = 2e-3
    links, pairs, counts = refine_all(ct, eps, 64)
    caster = RayCaster(el.verts, el.nverts)
    L2, P2, _, F, v, _ = _shadows(ct, links, pairs, counts, caster, 4, eps, eps)
    t = ct.tree
    carried = np.maximum(t.rho[L2[:, 0]] * F[:, 0] * t.lhat[L2[:, 1]],
                         t.rho[L2[:, 1]] * F[:, 1] * t.lhat[L2[:, 0]]) / ct.lref
    assert not ((v > 0) & (v < 1) & (carried > eps)).any()
    assert len(L2) > len(links)

    def covered(lk, pr):
        out = []
        for p, q in lk:
            ep = t.order[t.start[p]:t.end[p]]
            eq = t.order[t.start[q]:t.end[q]]
            out += [(min(i, j), max(i, j)) for i in ep for j in eq]
        out += [tuple(x) for x in pr.tolist()]
        return out

    def facing(i, j):
        d = el.center[j] - el.center[i]
        return el.normal[i] @ d > 0 and el.normal[j] @ d < 0

    before = [x for x in covered(links, pairs) if facing(*x)]
    after = [x for x in covered(L2, P2) if facing(*x)]
    assert len(after) == len(set(after)) and set(after) == set(before)


# ----------------------------------------------------------------------------- through the solve

def _obj(polys) -> str:
    out, k = [], 1
    for v, mat in polys:
        out.append(f"usemtl {mat}")
        for p in v:
            out.append(f"v {p[0]:.9f} {p[1]:.9f} {p[2]:.9f}")
        out.append("f " + " ".join(str(k + i) for i in range(len(v))))
        k += len(v)
    return "\n".join(out) + "\n"


def _plates_scene(tmp_path, n: int = 8) -> str:
    """An open scene of many small triangles: a floor and a ceiling plate (n x n squares cut in
    two) facing each other, and a small lamp under the ceiling facing down."""
    from helpers import write_scene

    polys = []
    for v, up in ((_grid(n, 0.0, True)[0], True), (_grid(n, 1.0, False)[0], False)):
        polys += [(t[:3], "wall") for t in v]
    lamp = [(0.4, 0.4, 0.95), (0.4, 0.6, 0.95), (0.6, 0.6, 0.95), (0.6, 0.4, 0.95)]
    polys.append((lamp, "lamp"))
    camera = """
    [camera]
    position = [0.5, 0.5, 0.5]
    look_at = [0.5, 0.5, 0.0]
    up = [0.0, 1.0, 0.0]
    fov_y = 90.0
    resolution = [8, 8]
    """
    return write_scene(tmp_path, _obj(polys), "[material.wall]\nreflectance = [0.6, 0.6, 0.6]\n"
                       "[material.lamp]\nreflectance = [0.0, 0.0, 0.0]\nemission = [10.0, 10.0, 10.0]\n",
                       camera=camera)


def _links_and_solve(client, tmp_path, scene, res, name, **overrides):
    from helpers import prepared, radiance

    from radiosity.methods.hierarchical.links.master import compute_links
    from radiosity.settings import resolve
    from radiosity.stages.solve import run_solve

    s = resolve({"solve.tol": 1e-12, **overrides})
    out = prepared(client, tmp_path, scene, res, name=name, visibility=False)
    fig = compute_links(out, client, s, progress=False)
    sol = run_solve(out, client, s, progress=False, method="hierarchical")
    return out, fig, sol, radiance(out)


@pytest.mark.parametrize("scene,res", [("three-rectangles", 16), ("cornell-box", 8)])
def test_epsilon_zero_with_clusters_equals_the_method_without(client, tmp_path, scene, res):
    """epsilon -> 0: every link refined to elements; the answer equals the hierarchical method
    without clusters (and so the all-pairs limit) to 1e-9."""
    from helpers import scene_path

    base = {"hierarchy.epsilon": 0.0, "hierarchy.min-node-size": 1e9}
    _, f_off, _, L_off = _links_and_solve(client, tmp_path, scene_path(scene), res, "off",
                                          **base, **{"hierarchy.clusters": "off"})
    _, f_on, _, L_on = _links_and_solve(client, tmp_path, scene_path(scene), res, "on",
                                        **base, **{"hierarchy.clusters": "on"})
    assert f_on["cluster_links"] == 0 and f_on["links"] == f_off["links"]
    np.testing.assert_allclose(L_on, L_off, rtol=1e-9, atol=1e-12)


def test_clusters_mixing_faces_do_not_darken_the_elements_that_face_the_light(client, tmp_path):
    """The Cornell box with each face cut into 16 triangles (no two forming a parallelogram), the
    default epsilon: with clusters every lit sub-element within 2 % of the method without them.
    A cluster holding elements of two faces of a block (or of a block and the floor) sees another
    cluster along the centroid direction at a grazing or back-facing angle even where its
    elements face parts of the other: an estimate from the centroid direction alone called such
    links faint, kept them and carried almost nothing (up to 39 % too dark here, -36 % on the
    tall block at 128^2); they are now judged by each element's cosine toward the other's box."""
    import sys

    from helpers import ROOT

    sys.path.insert(0, f"{ROOT}/benchmarks")
    import scenes_generated

    scene = scenes_generated.tessellated_cornell(str(tmp_path / "box"), 16, 16)
    _, f_off, _, L_off = _links_and_solve(client, tmp_path, scene, 16, "off",
                                          **{"hierarchy.clusters": "off"})
    _, f_on, _, L_on = _links_and_solve(client, tmp_path, scene, 16, "on",
                                        **{"hierarchy.clusters": "on"})
    assert f_on["cluster_links"] > 500 and f_off["cluster_links"] == 0
    on, off = L_on[:, 0].sum(axis=-1), L_off[:, 0].sum(axis=-1)
    lit = off > 0.05 * off.mean()
    err = np.abs(on[lit] / off[lit] - 1.0)
    assert err.max() < 0.02 and err.mean() < 2e-3


def test_energy_is_conserved_with_cluster_links(client, tmp_path):
    """An open scene with cluster links: emitted = absorbed + escaped to 1e-9, with the
    operator's own row sums (diag(A) K symmetric, the solution exact to the tolerance)."""
    from radiosity.methods.hierarchical.solve.leaves import leaf_vectors
    from radiosity.methods.hierarchical.solve.transport import open_link_operator
    from radiosity.runtime.store import RunStore
    from radiosity.settings import resolve

    scene = _plates_scene(tmp_path)
    out, fig, _, _ = _links_and_solve(client, tmp_path, scene, 8, "run",
                                      **{"hierarchy.clusters": "on", "hierarchy.epsilon": 2e-2,
                                         "solve.normalise-rows": "off",
                                         "hierarchy.final-gather": "none",
                                         "direct.mode": "links"})  # Le the source (as above)
    assert fig["cluster_links"] > 0 and fig["links"] > 0
    # the cluster layer at clusters-epsilon times epsilon, its unseen receivers weighed less
    c = fig["clusters"]
    assert c["epsilon"] == pytest.approx(0.5 * 2e-2) and c["unseen_importance"] == 0.25
    assert 0 <= c["unseen"] < len(RunStore(out).load_elements())
    rs = RunStore(out)
    op, table, el, _ = open_link_operator(rs, None, "driver", resolve())
    Le, rho, area = leaf_vectors(table, el)
    L = np.transpose(rs.read_arrays("solution")["leaf_radiance"], (1, 2, 0))
    y = op.apply(L)
    r = op.apply(np.ones((2, 1, len(area))))
    emitted = float((area * Le).sum())
    escaped = float((area * L * (1.0 - r)).sum())
    absorbed = float((area * (1.0 - rho) * y).sum())
    assert emitted > 0 and escaped > 0.01 * emitted
    assert escaped + absorbed == pytest.approx(emitted, rel=1e-9)


def test_the_solve_takes_the_cluster_links_the_link_stage_wrote_without_reading_them_back(
        client, tmp_path):
    """The link stage hands its cluster layer to the next read of the same store and links (the
    render's solve): the same arrays as the store holds, given once; other links get an error."""
    from helpers import prepared

    from radiosity.errors import StoreError
    from radiosity.methods.hierarchical import store
    from radiosity.methods.hierarchical.links.master import compute_links
    from radiosity.runtime.store import RunStore
    from radiosity.settings import resolve

    scene = _plates_scene(tmp_path)
    out = prepared(client, tmp_path, scene, 8, name="run", visibility=False)
    compute_links(out, client, resolve({"hierarchy.clusters": "on", "hierarchy.epsilon": 2e-2}),
                  progress=False)
    ls = store.LinkStore(RunStore(out))
    token = ls.token()
    assert len(store._HANDOFF) == 1
    with pytest.raises(StoreError, match="cluster links of other links"):
        ls.read_clusters("another")
    handed = ls.read_clusters(token)
    assert not store._HANDOFF
    read = ls.read_clusters(token)
    assert handed.keys() == read.keys() and len(read["p"]) > 0
    for k in read:
        np.testing.assert_array_equal(handed[k], read[k])


def test_cluster_links_are_the_same_on_the_driver_and_the_workers_and_across_task_cuts(client,
                                                                                         tmp_path):
    """Determinism: the same links and radiance for block and stripe tasks, and the passes in the
    driver or on the workers."""
    from radiosity.stages.solve import run_solve
    from radiosity.settings import resolve

    scene = _plates_scene(tmp_path)
    # the emitters' light through the links: with it at points the plates' light after the
    # first bounce is dim enough for the cluster links alone (no element-level tasks to cut)
    kw = {"hierarchy.clusters": "on", "hierarchy.epsilon": 2e-2, "direct.mode": "links"}
    out_b, fb, _, Lb = _links_and_solve(client, tmp_path, scene, 8, "block",
                                        **kw, **{"hierarchy.task-unit": "block"})
    out_s, fs, _, Ls = _links_and_solve(client, tmp_path, scene, 8, "stripe",
                                        **kw, **{"hierarchy.task-unit": "stripe"})
    assert fb["tasks"] != fs["tasks"]
    assert (fb["links"], fb["cluster_links"]) == (fs["links"], fs["cluster_links"])
    np.testing.assert_allclose(Ls, Lb, rtol=1e-12, atol=1e-14)
    s = resolve({"solve.tol": 1e-12, **kw})
    run_solve(out_b, client, s, progress=False, method="hierarchical", where="cluster")
    from helpers import radiance

    np.testing.assert_allclose(radiance(out_b), Lb, rtol=1e-12, atol=1e-14)


def test_a_closed_sphere_of_5000_triangles_is_the_furnace(client, tmp_path):
    """A closed sphere tessellated into 4 992 triangles (rho 0.9, emitting 1 uniformly), the
    defaults (hierarchical with clusters, chosen by the scene): Le / (1 - rho) on every pixel
    within 0.5 %; refinement rounds (auto) stay off, as on every clustered run."""
    from helpers import write_scene

    from radiosity.pipeline import render_scene
    from radiosity.scene.load import load_scene
    from radiosity.stages.image import read_exr

    v, _ = _sphere(40, 64)
    scene = write_scene(tmp_path, _obj([(t[:3], "wall") for t in v]),
                        "[material.wall]\nreflectance = [0.9, 0.9, 0.9]\nemission = [1.0, 1.0, 1.0]\n",
                        camera="""
                        [camera]
                        position = [0.0, 0.0, 0.0]
                        look_at = [0.0, 0.0, 1.0]
                        up = [0.0, 1.0, 0.0]
                        fov_y = 60.0
                        resolution = [16, 16]
                        """)
    out = str(tmp_path / "run")
    fig = render_scene(load_scene(scene, settings=settings_of()), out, client, settings_of(),
                       preview=False, progress=False, echo=lambda *a: None)
    assert fig["plan"]["method"] == "hierarchical" and fig["links"]["cluster_links"] > 0
    assert fig["rounds"]["why"].startswith("auto: none: the links start at clusters")
    img = read_exr(f"{out}/image.exr")
    np.testing.assert_allclose(img, 10.0, rtol=5e-3)


@pytest.mark.cluster
def test_the_cluster_layer_is_the_same_in_tasks_and_in_one_process(client):
    """The cluster refinement cut into tasks on the cluster (a frontier of waiting links, each
    one's subtree a task with its form factors and rays) gives the same links, pairs and
    weights as the whole refinement in one process: the result does not depend on the cut or
    the workers."""
    from radiosity.methods.hierarchical.clusters import tasks as clusters
    from radiosity.methods.hierarchical.params import oracle_weights

    v, n = _sphere(40, 64)
    el = _elements(v, n, rho=0.8, emit=np.where(np.arange(len(v))[:, None, None] < 40, 1.0, 0.0)
                   * np.ones((len(v), 2, 3)))
    w = oracle_weights(el, "bf")
    one = clusters.plan_clusters(el, 1e-3, w, 4, True, 1e-6)
    assert one[2]["tasks"] == 0 and one[0].links > 1000
    for cut in (4, 16):
        old = clusters.CUT_PER_TASK
        clusters.CUT_PER_TASK = cut
        try:
            many = clusters.plan_clusters(el, 1e-3, w, 4, True, 1e-6, client=client)
        finally:
            clusters.CUT_PER_TASK = old
        assert many[2]["tasks"] > 1
        for k, a in one[0].arrays().items():
            assert np.array_equal(a, many[0].arrays()[k]), k
        assert np.array_equal(one[1], many[1])
        assert many[2]["evaluated"] == one[2]["evaluated"]


def test_the_driver_merges_sorted_runs_bucket_by_bucket_into_one_order():
    """clustertasks._Runs: sorted runs of unique keys p K + q added in any order (as tasks
    finish) merge into the links sorted by (p, q), with their weights, whatever the buckets."""
    from radiosity.methods.hierarchical.clusters.tasks import _Runs

    rng = np.random.default_rng(3)
    K = np.int64(1000)
    key = rng.choice(K * K, 20000, replace=False).astype(np.int64)
    g = rng.random(len(key)).astype(np.float32)
    order = np.argsort(key)
    want = (key[order] // K, key[order] % K, g[order])
    for buckets in (1, 7, 16):
        runs = _Runs(K, buckets)
        parts = np.array_split(np.arange(len(key)), 9)
        for i in rng.permutation(len(parts)):
            part = parts[i]
            o = part[np.argsort(key[part])]
            runs.add(key[o], g[o])
        got = runs.merged(chunk=1000)
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)
        assert got[0].dtype == np.int32 and got[2].dtype == np.float32


def _final_gather_case():
    """A 1 x 1 floor of 2 048 triangles lit by a 0.25 x 0.25 ceiling patch of 128 triangles
    (radiance 1) 1.2 above it, off to one side: the floor's irradiance varies by about 3x."""
    v1, n1 = _grid(32, 0.0, True)
    v2, n2 = _grid(8, 1.2, False, x0=0.9, size=0.25)
    v = np.concatenate([v1, v2])
    el = _elements(v, np.concatenate([n1, n2]))
    ct = _tree(el)
    links, pairs, _ = refine_all(ct, 2e-2, 64)
    F = link_form_factors(ct, links)
    g = (ct.tree.area[links[:, 0]] * F[:, 0]).astype(np.float32)
    L = np.zeros((1, len(v)))
    L[0, len(v1):] = 1.0
    return el, ct, links, pairs, g, L, len(v1)


@pytest.mark.parametrize("flat,worst", [(None, 0.05), (2.0, 0.02)])
def test_the_cluster_final_gather_follows_the_light_over_each_receiver_and_conserves_it(
        monkeypatch, flat, worst):
    """cluster_final_gather on a floor lit by a far patch through cluster links: the power it
    hands out equals the uniform spread's (the solve's) to rounding, its parts add up to the
    whole, and each floor triangle's irradiance (at its centroid, and the gradient's value at
    its vertices) is within 1 % on average and `worst` at most of the exact sum of
    point-to-polygon form factors, where the uniform spread is off by 26 % at most. With the
    default FLAT the floor's clusters take one linear field each; with FLAT 2 every receiver
    is shared out per triangle."""
    from radiosity.core.exact import point_to_polygon_ff
    from radiosity.methods.hierarchical.clusters import transport as clusterlinks
    from radiosity.methods.hierarchical.clusters.transport import (GATHER_PARTS, ClusterGather,
                                                             cluster_final_gather, final_layout)

    if flat is not None:
        monkeypatch.setattr(clusterlinks, "FLAT", flat)
    el, ct, links, pairs, g, L, n1 = _final_gather_case()
    assert len(pairs) == 0 and len(links) >= 1
    args = (L, ct.parent, ct.leaf_orig, np.asarray(ct.tree.area), links[:, 0].astype(np.int32),
            links[:, 1].astype(np.int32), g)
    lay = final_layout(*args[1:4], el.center, el.normal, el.area, np.ascontiguousarray(el.verts),
                       el.nverts.astype(np.int64))

    def gathered(part=(0, 1)):  # per original: value (C, n), gradient (C, 3, n)
        f = cluster_final_gather(*args, lay, part)[lay.orig_node]
        return f[:, :1].T, f[:, 1:].reshape(-1, 1, 3).transpose(1, 2, 0)

    value, grad = gathered()
    uniform = np.zeros((1, len(el)))
    cg = ClusterGather(*args)
    for k in reversed(range(GATHER_PARTS)):  # any order
        cg.part(k)
    cg.push(uniform)
    assert (el.area * value[0]).sum() == pytest.approx((el.area * uniform[0]).sum(), rel=1e-12)
    halves = [gathered((i, 2)) for i in range(2)]
    assert np.allclose(halves[0][0] + halves[1][0], value, rtol=1e-12, atol=0)
    assert np.allclose(halves[0][1] + halves[1][1], grad, rtol=1e-12, atol=1e-12)

    def exact(x):
        return sum(point_to_polygon_ff(x, np.array([0.0, 0.0, 1.0]), el.verts[j], 3)
                   for j in range(n1, len(el)))

    rng = np.random.default_rng(5)
    E0 = np.array([exact(el.center[i]) for i in range(n1)])
    # the cluster links' form factors are estimates (within 1 %): compare shapes, scaled to the
    # same total
    scale = (el.area[:n1] * E0).sum() / (el.area[:n1] * value[0, :n1]).sum()
    assert abs(scale - 1) < 0.01
    err = np.abs(scale * value[0, :n1] / E0 - 1)
    err_uniform = np.abs(scale * uniform[0, :n1] / E0 - 1)
    assert err.max() < worst and err.mean() < 0.01, (err.max(), err.mean())
    assert err_uniform.max() > 0.2 and err_uniform.mean() > 0.03
    at_vertices = [abs(scale * (value[0, i] + grad[0, :, i] @ (x - el.center[i])) / exact(x) - 1)
                   for i in rng.choice(n1, 40, replace=False) for x in el.verts[i, :3]]
    assert max(at_vertices) < worst and np.mean(at_vertices) < 0.01


def test_the_end_table_holds_every_elements_four_ray_ends_once_per_caster():
    """clusterweights.end_table: row 4 i + s is point s of element i as _ends gives it (a
    triangle's four midpoint sub-triangles' centroids, a quad's four sub-quads' centres: their
    mean the centroid), the element of each row beside it, made once per caster."""
    from types import SimpleNamespace

    from radiosity.methods.hierarchical.clusters.weights import _ends, end_table
    from radiosity.tracing.rays import RayCaster

    verts = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0]],
                      [[0, 0, 1], [2, 0, 1], [2, 1, 1], [0, 1, 1]],
                      [[1, 1, 2], [2, 1, 2], [1, 3, 3], [1, 3, 3]]], float)
    nverts = np.array([3, 4, 3])
    rc = RayCaster(verts, nverts)
    area, _, center = polygon_properties(verts, nverts)
    e = SimpleNamespace(verts=verts, area=area)
    pts, owner = end_table(rc, e)
    assert pts.shape == (12, 3) and owner.tolist() == [0] * 4 + [1] * 4 + [2] * 4
    for i in range(3):
        for s in range(4):
            one = np.empty((1, 3))
            _ends(verts, np.array([i]), np.array([s + 4]), one)  # the column modulo 4
            assert np.array_equal(pts[4 * i + s], one[0])
        np.testing.assert_allclose(pts[4 * i:4 * i + 4].mean(axis=0), center[i], atol=1e-12)
    assert end_table(rc, e)[0] is pts  # once per caster
