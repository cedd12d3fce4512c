"""Per-leaf vectors of a run's link table for the solve: the leaves' emission (from the scene's
emitters, scene/emitters.py), reflectance and area, the part of each leaf outside solids, and the
leaves' radiance back on the partition's sub-elements (the link transport itself:
solve/transport.py)."""

from __future__ import annotations

import numpy as np

from radiosity.scene.emitters import AreaEmitters


def leaf_vectors(table: dict, elements):
    """Le, rho (2, 3, M) and area (M,) of the leaves, per side."""
    o = table["orig"][table["leaf_node"]]
    Le = AreaEmitters(elements).side_vectors(o)
    rho = np.ascontiguousarray(np.transpose(elements.reflectance[o], (1, 2, 0)))
    return Le, rho, table["leaf_area"]


def live_leaves(table: dict, elements, epsilon: float) -> np.ndarray:
    """(M,) the part of each leaf outside solids: 1 minus the share of its four stratified
    points (links/sampling.link_points) that lie inside a solid (scene/contact.inside_solid: a
    floor's leaves under a block standing on it are 0, those across the block's edge between).
    The solve leaves the leaves at 0 out of the transport, as contact sides
    (stages/solve.RowTargets), and weighs the others' light in their nodes by it
    (LinkSolveInputs.pull_area); two-sided leaves are 1."""
    from radiosity.methods.hierarchical.links.sampling import link_points, ray_pairing, triangle_strata
    from radiosity.scene.contact import inside_solid
    from radiosity.tracing.rays import caster_of

    ln = np.asarray(table["leaf_node"], np.int64)
    o = table["orig"][ln]
    out = np.ones(len(ln))
    two = np.asarray(elements.two_sided, bool)
    one = np.nonzero(~two[o])[0]
    if not len(one):
        return out
    k = 4
    verts, nverts = table["verts"], table["nverts"].astype(np.int64)
    nodes = ln[one]
    pts, e = link_points(verts, nverts, np.zeros((len(verts), 3)), table["orig"].astype(np.int64),
                         nodes, nodes, 2, triangle_strata(k), ray_pairing(k))
    pts, e = pts[:len(nodes) * k], e[:len(nodes) * k]
    # the link stage's caster where this process built it (in-process workers)
    caster = caster_of(elements.verts, elements.nverts, epsilon)
    ins = inside_solid(caster, pts, elements.normal[e], two)
    out[one] = 1.0 - ins.reshape(len(nodes), k).mean(axis=1)
    return out


def to_sub_elements(L: np.ndarray, table: dict, m: int) -> np.ndarray:
    """Leaf radiance (2, C, M) -> sub-element radiance (m, 2, C): identical for seen originals,
    the area-weighted mean of the split-off leaves for an unseen original's one sub-element."""
    sub = table["leaf_sub"]
    A = table["leaf_area"]
    out = np.zeros((m, L.shape[0], L.shape[1]))
    wsum = np.bincount(sub, A, minlength=m)
    for s in range(L.shape[0]):
        for c in range(L.shape[1]):
            out[:, s, c] = np.bincount(sub, A * L[s, c], minlength=m) / np.where(wsum > 0, wsum, 1)
    return out
