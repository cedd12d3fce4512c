"""Cluster links between clusters holding two-sided elements (design:
docs/src/design/methods-hierarchical-clusters.md, "Two-sided clusters"): a two-sided element
shows A |n . u| toward u and sends and receives on the side that faces the link's other end.
Checked against the one-sided answer of the same geometry, the exact sum, a closed furnace, the
energy balance and the method without clusters."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from radiosity.methods.hierarchical.clusters.tasks import refine_all
from radiosity.methods.hierarchical.clusters.refine import refine_clusters
from radiosity.methods.hierarchical.clusters.weights import link_form_factors

from test_clusters import _elements, _grid, _obj, _sphere, _tree, _links_and_solve


def _flip(v, every: int = 2):
    """v (n, 4, 3) triangles with every `every`-th one's orientation reversed."""
    v = v.copy()
    v[::every, :3] = v[::every][:, [0, 2, 1]]
    v[::every, 3] = v[::every, 2]
    return v


def _two(el):
    """el with every element two-sided."""
    return dataclasses.replace(el, two_sided=np.ones(len(el.area), bool))


def _far_groups(flip: bool, two: bool):
    d = 20.0
    v1, n1 = _grid(16, 0.0, True)
    v2, n2 = _grid(16, d, False)
    if flip:
        v1, v2 = _flip(v1), _flip(v2, 3)
    el = _elements(np.concatenate([v1, v2]), np.concatenate([n1, n2]))
    return _two(el) if two else el


def test_two_sided_groups_with_mixed_orientations_are_one_link_with_the_one_sided_factor():
    """Two far groups of 512 small triangles each, two-sided, every second (every third) one
    turned over: the refinement keeps cluster links and hands no pair of originals on, and
    the power carried, sum A_p F_pq, is the brute-force sum over every pair of triangles of
    A_i A_j |cos_i| |cos_j| / (pi r^2) (far apart: the centroids' kernel is exact to 1e-6)
    within 0.2 %, as the one-sided groups' is. Without two-sided links
    (two=False) the same scene went down to every pair of originals."""
    one = _far_groups(flip=False, two=False)
    mixed = _far_groups(flip=True, two=True)
    ct1, ct2 = _tree(one), _tree(mixed)
    links1, pairs1, _ = refine_all(ct1, 1e-2, 64)
    links2, pairs2, _ = refine_all(ct2, 1e-2, 64)
    assert len(pairs1) == 0 and len(pairs2) == 0 and len(links2) >= 1
    A1, A2 = ct1.tree.area, ct2.tree.area
    F1, F2 = link_form_factors(ct1, links1), link_form_factors(ct2, links2)
    got1 = float(sum(A1[p] * F1[k, 0] for k, (p, q) in enumerate(links1)))
    got2 = float(sum(A2[p] * F2[k, 0] for k, (p, q) in enumerate(links2)))
    c, nrm, a = mixed.center, mixed.normal, mixed.area
    lo, hi = slice(0, 512), slice(512, 1024)
    d = c[None, hi] - c[lo, None]
    r2 = (d * d).sum(-1)
    ci = np.abs((nrm[lo, None] * d).sum(-1))
    cj = np.abs((nrm[None, hi] * d).sum(-1))
    exact = float((a[lo, None] * a[None, hi] * ci * cj / (np.pi * r2 * r2)).sum())
    assert got1 == pytest.approx(exact, rel=2e-3) and got2 == pytest.approx(exact, rel=2e-3)
    _, pairs, _, _, _ = refine_clusters(ct2.tree, ct2.elems, 1e-2, ct2.lref, 64,
                                        np.zeros((1, 2), np.int64), 0, 0.0, False)
    assert len(pairs) == 512 * 512


def test_a_two_sided_group_seen_from_its_back_carries_what_its_front_would():
    """The upper group turned over as a whole (its fronts face away, two-sided): the same
    form factor as facing (the same tree, mirrored normals), to 1e-9; one-sided it is culled
    (no link, no pair)."""
    d = 20.0
    v1, n1 = _grid(16, 0.0, True)
    v2, n2 = _grid(16, d, True)  # facing up, away from the lower group
    back = _elements(np.concatenate([v1, v2]), np.concatenate([n1, n2]))
    face = _far_groups(flip=False, two=False)
    ctb, ctf = _tree(_two(back)), _tree(face)
    lb, pb, _ = refine_all(ctb, 1e-2, 64)
    lf, _, _ = refine_all(ctf, 1e-2, 64)
    assert len(pb) == 0 and len(lb) >= 1
    Fb, Ff = link_form_factors(ctb, lb), link_form_factors(ctf, lf)
    gb = float(sum(ctb.tree.area[p] * Fb[k, 0] for k, (p, q) in enumerate(lb)))
    gf = float(sum(ctf.tree.area[p] * Ff[k, 0] for k, (p, q) in enumerate(lf)))
    assert gb == pytest.approx(gf, rel=1e-9)
    l1, p1, _ = refine_all(_tree(back), 1e-2, 64)
    assert len(l1) == 0 and len(p1) == 0


def test_a_closed_two_sided_sphere_with_mixed_orientations_is_the_furnace(client, tmp_path):
    """A closed sphere of 4 992 two-sided triangles, every second one turned over (rho 0.9,
    emitting 1 on both sides): cluster links are kept and every pixel seen from inside is
    Le / (1 - rho) within 0.5 % (the furnace stays exact with two-sided clusters), in the
    render and in a new view of the run."""
    from helpers import write_scene

    from radiosity.pipeline import render_scene
    from radiosity.scene.load import load_scene
    from radiosity.settings import options as settings_of
    from radiosity.stages.image import read_exr

    v, _ = _sphere(40, 64)
    v = _flip(v)
    scene = write_scene(tmp_path, _obj([(t[:3], "wall") for t in v]),
                        "[material.wall]\nreflectance = [0.9, 0.9, 0.9]\n"
                        "emission = [1.0, 1.0, 1.0]\ntwo_sided = true\n",
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
    img = read_exr(f"{out}/image.exr")
    np.testing.assert_allclose(img, 10.0, rtol=5e-3)
    # a new view of the solved run gathers the two-sided cluster links the same way
    from radiosity.runtime.store import RunStore
    from radiosity.stages.views import render_view

    v = render_view(out, RunStore(out).load_camera(), name="again", settings=settings_of())
    np.testing.assert_allclose(v.image, 10.0, rtol=5e-3)


def _two_sided_plates(tmp_path, n: int = 8) -> str:
    """test_clusters' plates (a floor and a ceiling of n x n squares cut in two, a small lamp
    under the ceiling), the plates two-sided with every second triangle turned over."""
    from helpers import write_scene

    polys = []
    for up, z in ((True, 0.0), (False, 1.0)):
        polys += [(t[:3], "wall") for t in _flip(_grid(n, z, up)[0])]
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
    return write_scene(tmp_path, _obj(polys),
                       "[material.wall]\nreflectance = [0.6, 0.6, 0.6]\ntwo_sided = true\n"
                       "[material.lamp]\nreflectance = [0.0, 0.0, 0.0]\n"
                       "emission = [10.0, 10.0, 10.0]\n", camera=camera)


def test_energy_is_conserved_with_two_sided_cluster_links(client, tmp_path):
    """The two-sided plates with cluster links: emitted = absorbed + escaped to 1e-9 with the
    operator's own row sums (the sides' transfer is symmetric: diag(A) K symmetric)."""
    from radiosity.methods.hierarchical.solve.leaves import leaf_vectors
    from radiosity.methods.hierarchical.solve.transport import open_link_operator
    from radiosity.runtime.store import RunStore
    from radiosity.settings import resolve

    scene = _two_sided_plates(tmp_path)
    out, fig, _, _ = _links_and_solve(client, tmp_path, scene, 8, "run",
                                      **{"hierarchy.clusters": "on", "hierarchy.epsilon": 2e-2,
                                         "solve.normalise-rows": "off",
                                         "hierarchy.final-gather": "none",
                                         "direct.mode": "links"})
    assert fig["cluster_links"] > 0
    rs = RunStore(out)
    op, table, el, _ = open_link_operator(rs, None, "driver", resolve())
    assert op.inp.clusters.two_sided
    Le, rho, area = leaf_vectors(table, el)
    L = np.transpose(rs.read_arrays("solution")["leaf_radiance"], (1, 2, 0))
    y = op.apply(L)
    r = op.apply(np.ones((2, 1, len(area))))
    emitted = float((area * Le).sum())
    escaped = float((area * L * (1.0 - r)).sum())
    absorbed = float((area * (1.0 - rho) * y).sum())
    assert emitted > 0 and escaped > 0.01 * emitted
    assert escaped + absorbed == pytest.approx(emitted, rel=1e-9)
    # reciprocity of the whole operator, both sides: x' A K y = y' A K x
    rng = np.random.default_rng(1)
    a, b = rng.random((2, 1, len(area))), rng.random((2, 1, len(area)))
    lhs = float((area * a * op.apply(b)).sum())
    rhs = float((area * b * op.apply(a)).sum())
    assert lhs == pytest.approx(rhs, rel=1e-9)


def test_two_sided_cluster_links_agree_with_the_method_without_clusters(client, tmp_path):
    """The two-sided plates at the default epsilon: with clusters (keeping cluster links) the
    radiance of every lit sub-element, both sides, within 2 % of the method without them and
    1e-3 on average (the one-sided test's tolerance)."""
    scene = _two_sided_plates(tmp_path)
    kw = {"direct.mode": "links"}
    _, f_off, _, L_off = _links_and_solve(client, tmp_path, scene, 8, "off",
                                          **kw, **{"hierarchy.clusters": "off"})
    _, f_on, _, L_on = _links_and_solve(client, tmp_path, scene, 8, "on",
                                        **kw, **{"hierarchy.clusters": "on"})
    assert f_on["cluster_links"] > 0 and f_off["cluster_links"] == 0
    on, off = L_on.sum(axis=-1).ravel(), L_off.sum(axis=-1).ravel()
    lit = off > 0.05 * off.mean()
    err = np.abs(on[lit] / off[lit] - 1.0)
    assert err.max() < 0.02 and err.mean() < 2e-3
