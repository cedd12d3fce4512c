"""The cluster layer's probes (clusters/tasks._probe): links whose estimate is within
PROBE_RAYS times epsilon take PROBE_RAYS rays before they are split, and are dropped where all
are blocked. Where nothing blocks, the layer is the one without probes, link for link; where a
wall separates two plates, the links across it go, and what the dropped links carried (from
many rays) stays within epsilon each on average."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.methods.hierarchical.clusters import tasks
from radiosity.methods.hierarchical.params import oracle_weights

from test_clusters import _elements, _plane


def _plates(wall: bool):
    """Two 1 x 1 plates of 288 triangles, 1 apart, facing each other (the top one emits), and
    with `wall` a plate of 8 triangles halfway between them over half of them (x < 0.5)."""
    parts = [_plane(12, 2, 0.0, 1), _plane(12, 2, 1.0, -1)]
    if wall:
        parts.append(_plane(2, 2, 0.5, 1, lo=(-0.5, -0.5), size=(1.0, 2.0)))
    v = np.concatenate(parts)
    n = len(v)
    emit = np.zeros((n, 2, 3))
    emit[288:576, 0] = 1.0
    return _elements(v, np.full(n, 3), emit=emit)


def _layer(el, eps, probe_rays, monkeypatch):
    monkeypatch.setattr(tasks, "PROBE_RAYS", probe_rays)
    cl, pairs, fig = tasks.plan_clusters(el, eps, oracle_weights(el, "bf"), 4, True, 1e-6)
    return cl, pairs, fig


@pytest.mark.parametrize("eps", [2e-4, 1e-3])
def test_probes_change_nothing_where_nothing_blocks(eps, monkeypatch):
    """Two plates in the open: every probe sees through, is split as the refinement would have
    split it, and the layer (links, weights, pairs) is the one without probes, to the bit."""
    el = _plates(wall=False)
    cl0, p0, f0 = _layer(el, eps, 0, monkeypatch)
    cl1, p1, f1 = _layer(el, eps, 4, monkeypatch)
    assert f0.probed == 0 and f1.probed > 0 and f1.dropped_blocked == 0
    np.testing.assert_array_equal(cl0.p, cl1.p)
    np.testing.assert_array_equal(cl0.q, cl1.q)
    np.testing.assert_array_equal(cl0.g, cl1.g)
    np.testing.assert_array_equal(p0, p1)


def test_blocked_probes_are_dropped_and_carried_little(monkeypatch):
    """A wall between half of the plates: probes across it are dropped, the layer has fewer
    links and pairs than without probes, and the dropped links' transfer (form factors and 64 rays each, as the oracle weighs it) is within epsilon each
    on average and their sum within 1 % of what the links from the top plate carry."""
    from radiosity.methods.hierarchical.clusters.refine import cluster_tree
    from radiosity.methods.hierarchical.clusters.weights import link_weights
    from radiosity.tracing.rays import RayCaster

    el = _plates(wall=True)
    eps = 2e-4
    cl0, p0, f0 = _layer(el, eps, 0, monkeypatch)
    cl1, p1, f1 = _layer(el, eps, 4, monkeypatch)
    assert f1.dropped_blocked > 0
    assert cl1.links + len(p1) < cl0.links + len(p0)

    # the dropped links, found as _probe finds them, and what they carry seen with 64 rays
    ct = cluster_tree(el, *oracle_weights(el, "bf"))
    caster = RayCaster(el.verts, el.nverts)
    links, _, _, _, probes = tasks.refine_clusters(ct.tree, ct.elems, eps, ct.lref, 1024,
                                                   np.zeros((1, 2), np.int64), 0, 4 * eps)
    F, v, _ = link_weights(ct, probes, caster, 4)
    t = ct.tree
    drop = (v <= 0) & (tasks._carried(probes, F, t.rho, t.lhat, ct.lref) <= 4 * eps)
    assert drop.sum() > 0
    F64, v64, _ = link_weights(ct, probes[drop], caster, 16, samples=64)
    lost = tasks._carried(probes[drop], F64, t.rho, t.lhat, ct.lref) * v64
    assert lost.mean() <= eps
    Fk, vk, _ = link_weights(ct, links, caster, 4)
    assert lost.sum() <= 0.01 * float((tasks._carried(links, Fk, t.rho, t.lhat, ct.lref) * vk).sum())
