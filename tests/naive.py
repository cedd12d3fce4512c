"""Deliberately naive references: every optimised path must agree with these on small scenes."""

from __future__ import annotations

import numpy as np

from app.rays import RayCaster

COS_TOL = 1e-9


def facing(part, two_sided_sub) -> np.ndarray:
    """(m, m) bool: a faces b (cos beyond tolerance on a side that exists), plain numpy."""
    d = part.center[None, :, :] - part.center[:, None, :]
    length = np.linalg.norm(d, axis=2)
    c = np.einsum("ac,abc->ab", part.normal, d)
    t = COS_TOL * length
    return (c > t) | (two_sided_sub[:, None] & (c < -t))


def visibility(part, elements) -> np.ndarray:
    """One ray for every ordered pair (a, b), a != b: no culling, no symmetry; then orientation."""
    rc = RayCaster(elements.verts, elements.nverts)
    m = len(part)
    a, b = np.nonzero(~np.eye(m, dtype=bool))
    occ = np.zeros((m, m), bool)
    occ[a, b] = rc.occluded(part.center[a], part.center[b], part.orig[a], part.orig[b])  # no pair indexing
    f = facing(part, elements.two_sided[part.orig])
    V = ~occ & f & f.T
    np.fill_diagonal(V, False)
    return V
