"""Clustering above the originals (SPEC §9): the cluster refinement's limits (epsilon = 0 lists
exactly the facing pairs of originals), its bound, the cluster form factor against the exact
sum over triangle pairs, and that links grow like n log n, not n^2."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.core.bundles import Elements
from radiosity.core.geometry import polygon_properties
from radiosity.methods.hierarchical.clusters import cluster_tree, link_form_factors, refine_clusters
from radiosity.scene.originals import facing_pairs, tree_of


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
    from radiosity.methods.hierarchical.links import oracle_weights

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
    links, pairs, counts = refine_clusters(ct.tree, ct.elems, 0.0, ct.lref, 64)
    assert len(links) == 0
    bi, bj, _ = facing_pairs(tree_of(el))
    got = {tuple(p) for p in pairs.tolist()}
    assert got == set(zip(bi.tolist(), bj.tolist())) and len(got) == len(pairs)


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
    links, pairs, _ = refine_clusters(ct.tree, ct.elems, 1e-2, ct.lref, 64)
    assert len(pairs) == 0 and len(links) >= 1
    F = link_form_factors(ct.tree, ct.elems, links)
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
        links, pairs, c = refine_clusters(ct.tree, ct.elems, 5e-3, ct.lref, 1024)
        counts[len(v)] = len(links) + len(pairs)
    ns = sorted(counts)
    for a, b in zip(ns, ns[1:]):
        growth = counts[b] / counts[a]
        nlogn = (b * np.log(b)) / (a * np.log(a))
        assert growth < 1.5 * nlogn, counts   # n^2 would be (b / a)^2 = 16
    assert counts[ns[-1]] < 0.05 * ns[-1] ** 2 / 2


def test_the_bound_never_keeps_a_link_that_carries_more_than_epsilon():
    """Every kept cluster link's actual transfer (its form factors times the weights) is below
    the bound, hence below epsilon."""
    v1, n1 = _grid(10, 0.0, True)
    v2, n2 = _grid(10, 3.0, False, x0=0.5)
    el = _elements(np.concatenate([v1, v2]), np.concatenate([n1, n2]))
    ct = _tree(el)
    eps = 2e-3
    links, _, _ = refine_clusters(ct.tree, ct.elems, eps, ct.lref, 64)
    F = link_form_factors(ct.tree, ct.elems, links)
    t = ct.tree
    w = np.maximum(t.rho[links[:, 0]] * F[:, 0] * t.lhat[links[:, 1]],
                   t.rho[links[:, 1]] * F[:, 1] * t.lhat[links[:, 0]]) / ct.lref
    assert len(links) and (w <= eps).all()
