"""Enclosures: is a set of facets closed, and balancing a view-factor matrix so that its rows sum
to 1 while reciprocity is kept (pure numpy / scipy; no Dask).

Closed: every edge is shared by exactly two facets that run it in opposite directions, and the
normals point into the enclosed volume. Balancing: symmetric Sinkhorn-Knopp scaling
F_ij <- d_i F_ij d_j (Knight 2008), which keeps reciprocity, the sparsity pattern and every
factor in [0, 1]. Why, and how: docs/src/design/viewfactors-method.md ("Enclosures and balancing").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MeshClosure:
    """closed: every edge shared by two facets with opposite windings; inward: the normals
    point into the enclosed volume; volume: signed volume (outward convention) in the mesh's
    unit cubed; reason: why it is not an enclosure ('' when it is one)."""

    closed: bool
    inward: bool
    volume: float
    reason: str

    @property
    def enclosure(self) -> bool:
        return self.closed and self.inward


def mesh_closure(verts: np.ndarray, nverts: np.ndarray) -> MeshClosure:
    """Is the mesh of facets verts (n, 4, 3) float64 with nverts (n,) in {3, 4} watertight, and
    which way do its normals point? (The radiosity path asks another question, with rays:
    scene/closure.detect_closure.)"""
    n = len(verts)
    nv = np.asarray(nverts, np.int64)
    pts = verts.reshape(-1, 3)
    uniq, vid = np.unique(pts, axis=0, return_inverse=True)
    vid = vid.reshape(n, 4)
    src, dst, face = [], [], []
    for k in range(4):
        has = nv > k
        nxt = np.where(k + 1 < nv, k + 1, 0)
        f = np.nonzero(has)[0]
        src.append(vid[f, k])
        dst.append(vid[f, nxt[f]])
        face.append(f)
    src, dst, face = np.concatenate(src), np.concatenate(dst), np.concatenate(face)
    V = int(vid.max()) + 1
    key = src.astype(np.int64) * V + dst
    rev = dst.astype(np.int64) * V + src
    order = np.argsort(key, kind="stable")
    ks = key[order]
    dup = np.nonzero(ks[1:] == ks[:-1])[0]
    c = _centre(verts)
    vol = _signed_volume(verts - c, nv)
    if len(dup):
        a, b = order[dup[0]], order[dup[0] + 1]
        return MeshClosure(False, False, vol, f"facets {face[a]} and {face[b]} run the edge "
                       f"{_pt(uniq, src[a])} - {_pt(uniq, dst[a])} the same way "
                       "(inconsistent winding, or more than two facets on an edge)")
    pos = np.searchsorted(ks, rev)
    found = (pos < len(ks)) & (ks[np.minimum(pos, len(ks) - 1)] == rev)
    if not found.all():
        e = int(np.nonzero(~found)[0][0])
        return MeshClosure(False, False, vol, f"the edge {_pt(uniq, src[e])} - "
                       f"{_pt(uniq, dst[e])} of facet {face[e]} has no neighbour running "
                       "it the other way (an open boundary, a crack or a T-junction)")
    if not vol < 0:
        return MeshClosure(True, False, vol, "the mesh is closed but its normals point out of the "
                       "enclosed volume (a solid seen from outside, not an enclosure)")
    return MeshClosure(True, True, vol, "")


def _centre(verts):
    p = verts.reshape(-1, 3)
    return 0.5 * (p.min(0) + p.max(0))


def _signed_volume(v, nv) -> float:
    """Sum over facets of the fan tetrahedra with the origin (outward convention: > 0)."""
    t1 = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2]))
    t2 = np.where(nv == 4, np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 2], v[:, 3])), 0.0)
    return float((t1.sum() + t2.sum()) / 6.0)


def _pt(uniq, vid) -> str:
    """Coordinates of vertex `vid` (for messages)."""
    return "(" + ", ".join(f"{x:.6g}" for x in uniq[vid]) + ")"


@dataclass(frozen=True)
class Balance:
    """scale d (n,), iterations, converged, the largest |row sum - 1| before and after."""

    scale: np.ndarray
    iterations: int
    converged: bool
    residual_before: float
    residual_after: float


def balance(F, tol: float = 1e-13, max_iterations: int = 10000, exact: np.ndarray | None = None):
    """Scale the CSR matrix F (n x n, rows summing to about 1, A F symmetric) to
    F'_ij = d_i F_ij d_j with every row summing to 1 (docs/src/design/viewfactors-method.md). Rows that
    are all zero are left alone (d_i = 1). exact (n,) bool: the rows whose target is 1 (None:
    all); the others (facets partly covered by a touching surface: they see less than their
    hemisphere) are only capped at 1 in the same iteration (d_i <= 1). Returns (F' as a new
    CSR matrix, Balance)."""
    import scipy.sparse as sp

    F = sp.csr_matrix(F)
    n = F.shape[0]
    rows0 = np.asarray(F.sum(axis=1)).ravel()
    live = rows0 > 0
    bal = live if exact is None else live & exact
    cap = live & ~bal
    d = np.ones(n)
    before = float(np.abs(rows0[bal] - 1.0).max(initial=0.0))

    def residual(d):
        r = d * (F @ d)
        return max(float(np.abs(r[bal] - 1.0).max(initial=0.0)),
                   float(np.maximum(r[cap] - 1.0, 0.0).max(initial=0.0)))

    it = 0
    res = residual(d)
    while res > tol and it < max_iterations:
        Fd = F @ d
        safe = np.where(Fd > 0, Fd, 1.0)
        d = np.where(bal, np.sqrt(d / safe), np.where(cap, np.minimum(1.0, np.sqrt(d / safe)), d))
        it += 1
        res = residual(d)
    rows = np.repeat(np.arange(n), np.diff(F.indptr))
    out = sp.csr_matrix((F.data * (d[rows] * d[F.indices]), F.indices.copy(), F.indptr.copy()),
                        shape=F.shape)
    after = float(np.abs(np.asarray(out.sum(axis=1)).ravel()[bal] - 1.0).max(initial=0.0))
    return out, Balance(d, it, res <= tol, before, after)
