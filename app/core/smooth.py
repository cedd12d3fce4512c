"""Radiance at the vertices of the sub-elements, for smooth exports (mesh.glb, mesh.ply,
viewer.html): the solution is one value per sub-element (a cell average), the exports draw a
continuous piecewise-linear surface through it.

The reconstruction, in four steps:

1. Smoothing surfaces: original elements that share a corner are joined when they have the
   same material and sidedness and their normals differ by less than `CREASE_DEG`; nothing
   is blended across a crease, a change of material or between the two sides of an element.
   Corners of sub-elements are welded by position (to `TOL.weld` of the scene's diagonal)
   within one surface and side.
2. A linear model per cell (sub-element side): its gradient is the weighted least-squares fit
   (weights 1 / distance^2, in the cell's plane) to the values of the cells that share a
   vertex with it, T-junctions included; the model is clipped to the range of those values
   (no new extremes, so no overshoot at shadow edges), a range widened by its own width at
   the border of a surface, where a vertex lies beyond every centroid (never below 0). One
   cell without neighbours is flat.
3. A vertex's radiance is the area-weighted mean of the models of the cells that have it as
   a corner, evaluated at the vertex: exact for a radiance linear in position, at the border
   of a surface too (plain vertex averaging is half a cell off there).
4. T-junctions: a vertex lying inside an edge of a coarser cell takes the linear
   interpolation of that edge's end values, so the coarse cell's triangles and the fine ones
   meet without a step (no triangle is added). Those of the adaptive subdivision are found by
   looking for each edge's midpoint among the vertices, recursively (the split rule only ever
   cuts at midpoints); those of the input mesh (an original's corner inside another's edge,
   anywhere along it) by a k-d tree over the edges no other cell shares. Chains and
   "zippers" (two originals' vertices each inside the other's edges) are solved together as
   one sparse least-squares system.

The values are radiance (W sr^-1 m^-2, linear RGB), as in solution/radiance. numpy and scipy,
and one numba kernel for the cells' fits (_cell_fits); no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from radiosity.core.arrays import unique, unique_rows
from radiosity.core.geometry import tangent_basis
from radiosity.core.tolerances import TOL
#: Originals whose normals differ by more than this (degrees) are never blended: 30 degrees is
#: the usual auto-smooth angle; walls meeting at a corner (90) stay apart, the facets of a
#: finely tessellated curved surface (a few degrees) are blended.
CREASE_DEG = 30.0


@dataclass(frozen=True)
class SmoothMesh:
    """Vertices with radiance and the triangles of the sub-elements through them.

    verts : (V, 3) float64, vertex positions
    radiance : (V, 3) float64, reconstructed linear RGB radiance, W sr^-1 m^-2
    faces : (T, 3) int64, counter-clockwise seen from the side drawn: the front triangles of
        every sub-element (quads: (0, 1, 2), (0, 2, 3)) in sub-element order, then the
        reversed back triangles of the two-sided ones
    face_sub : (T,) int64, sub-element of each triangle; face_side : (T,) int8, 0 front, 1 back
    corner : (m, 2, 4) int64, vertex of each sub-element's corner on each side (-1: no such
        corner, or a one-sided back)
    surface : (n,) int64, smoothing surface of each original element
    hanging : int, T-junction vertices made continuous (step 4)
    """

    verts: np.ndarray
    radiance: np.ndarray
    faces: np.ndarray
    face_sub: np.ndarray
    face_side: np.ndarray
    corner: np.ndarray
    surface: np.ndarray
    hanging: int

    @property
    def front_triangles(self) -> int:
        return int(np.sum(self.face_side == 0))


# ----------------------------------------------------------------------------- helpers

def _diagonal(pts: np.ndarray) -> float:
    """Length of the bounding-box diagonal of pts (k, 3) (1 for an empty or point set)."""
    d = float(np.linalg.norm(np.ptp(pts, axis=0))) if len(pts) else 0.0
    return d if d > 0 else 1.0


def _quantise(p: np.ndarray, lo: np.ndarray, tol: float) -> np.ndarray:
    return np.round((p - lo) / tol).astype(np.int64)


def _pairs_within(keys: np.ndarray, members: np.ndarray, cap: int = 64):
    """All ordered pairs (a, b), a != b, of `members` with equal `keys` (groups larger than
    `cap` pair each member with its neighbours in key order only)."""
    if len(keys) == 0:
        e = np.zeros(0, np.int64)
        return e, e
    order = np.argsort(keys, kind="stable")
    k, mem = keys[order], members[order]
    start = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    size = np.diff(np.r_[start, len(k)])
    size_of = np.repeat(size, size)
    start_of = np.repeat(start, size)
    small = size_of <= cap
    pos = np.flatnonzero(small)
    rep = size_of[pos]
    a_pos = np.repeat(pos, rep)
    offs = np.arange(len(a_pos)) - np.repeat(np.cumsum(rep) - rep, rep)
    b_pos = np.repeat(start_of[pos], rep) + offs
    big = np.flatnonzero(~small[:-1] & ~small[1:] & (k[1:] == k[:-1])) if len(k) > 1 else []
    a = np.r_[mem[a_pos], mem[big], mem[np.add(big, 1)]]
    b = np.r_[mem[b_pos], mem[np.add(big, 1)], mem[big]]
    keep = a != b
    return a[keep], b[keep]


def smoothing_surfaces(elements, crease_deg: float = CREASE_DEG,
                       tol: float | None = None) -> np.ndarray:
    """Label (n,) int64 of the smoothing surface of each original element: connected
    components of originals sharing a corner, with the same material and sidedness and
    normals within `crease_deg` (step 1 of the module docstring)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(elements)
    if n == 0:
        return np.zeros(0, np.int64)
    V = np.asarray(elements.verts, np.float64)
    nv = np.asarray(elements.nverts, np.int64)
    lo = V.reshape(-1, 3).min(0)
    tol = TOL.weld * _diagonal(V.reshape(-1, 3)) if tol is None else tol
    has = np.arange(4)[None, :] < nv[:, None]
    orig = np.broadcast_to(np.arange(n)[:, None], (n, 4))[has]
    q = _quantise(V[has], lo, tol)
    _, _, vid = unique_rows(q)
    a, b = _pairs_within(vid.ravel(), orig)
    N = np.asarray(elements.normal, np.float64)
    mat, two = np.asarray(elements.material), np.asarray(elements.two_sided, bool)
    ok = ((mat[a] == mat[b]) & (two[a] == two[b])
          & (np.einsum("ij,ij->i", N[a], N[b]) >= np.cos(np.radians(crease_deg))))
    g = coo_matrix((np.ones(int(ok.sum())), (a[ok], b[ok])), shape=(n, n))
    return connected_components(g, directed=False)[1].astype(np.int64)


class _Lookup:
    """Row lookup of (k, 4) int64 keys: index of each query row among `keys`, -1 if absent."""

    _P = np.array([0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0x27D4EB2F165667C5],
                  np.uint64)

    def __init__(self, keys: np.ndarray):
        self.keys = keys
        h = self._hash(keys)
        self.order = np.argsort(h, kind="stable")
        self.h = h[self.order]

    @classmethod
    def _hash(cls, k: np.ndarray) -> np.ndarray:
        with np.errstate(over="ignore"):
            return (k.astype(np.uint64) * cls._P).sum(axis=1, dtype=np.uint64)

    def find(self, q: np.ndarray) -> np.ndarray:
        h = self._hash(q)
        i = np.minimum(np.searchsorted(self.h, h), max(len(self.h) - 1, 0))
        out = np.full(len(q), -1, np.int64)
        if len(self.h) == 0:
            return out
        cand = self.order[i]
        hit = (self.h[i] == h) & np.all(self.keys[cand] == q, axis=1)
        out[hit] = cand[hit]
        return out


def _hanging(P, key, lookup, gv, nv, lo, tol):
    """T-junctions of the sub-elements' edges (step 4) and the border of the surfaces.

    Returns (v, a, b, t, cell): vertex v = (1 - t) a + t b lies inside an edge of sub-element
    `cell` that does not have v as a corner ((k,) int64, t (k,) float64); and border (G,)
    bool: vertices on an edge that no other cell shares (not even in part, across a
    T-junction). Midpoints first (the split rule's T-junctions, found by hashing, level by
    level), then any vertex inside a remaining unshared segment of the same surface
    (T-junctions of the input mesh between originals, by a k-d tree)."""
    m = len(gv)
    k = np.arange(4)
    a = gv[:, k]
    b = gv[np.arange(m)[:, None], (k[None, :] + 1) % nv[:, None]]
    has = k[None, :] < nv[:, None]
    a, b = a[has], b[has]
    cell = np.broadcast_to(np.arange(m)[:, None], (m, 4))[has]
    found, leaves = [], []   # leaves: segments without a vertex at their midpoint
    for _ in range(64):  # a level per halving; 48 splits is the depth guard
        if len(a) == 0:
            break
        mid = _quantise(0.5 * (P[a] + P[b]), lo, tol)
        v = lookup.find(np.column_stack([key[a, 0], mid]))
        hit = (v >= 0) & (v != a) & (v != b)
        leaves.append((a[~hit], b[~hit], cell[~hit]))
        a, b, v, cell = a[hit], b[hit], v[hit], cell[hit]
        found.append((v, a, b, np.full(len(v), 0.5), cell))
        a, b, cell = np.r_[a, v], np.r_[v, b], np.r_[cell, cell]
    la, lb, lc = (np.concatenate([x[i] for x in leaves]) for i in range(3))
    # a segment is shared when another cell's edge or half-edge equals it
    G = len(P)
    e = np.sort(np.column_stack([la, lb]), axis=1)
    code = e[:, 0] * G + e[:, 1]
    u, cnt = np.unique(code, return_counts=True)
    single = cnt[np.searchsorted(u, code)] == 1
    la, lb, lc = la[single], lb[single], lc[single]
    ends = np.zeros(G, bool)
    ends[la] = True
    ends[lb] = True
    extra = _inside_border_edges(P, key, la, lb, lc, ends, tol)
    found.append(extra)
    # the border: unshared segments without a vertex of the same surface inside
    hosts = np.zeros(len(la), bool)
    hosts[extra[5]] = True
    border = np.zeros(G, bool)
    border[la[~hosts]] = True
    border[lb[~hosts]] = True
    border[extra[0]] = False
    return (*(np.concatenate([f[i] for f in found]) for i in range(5)), border)


def _inside_border_edges(P, key, a, b, cell, ends, tol):
    """Vertices among `ends` (G,) bool strictly inside segments (a, b) of the same surface:
    (v, a, b, t, cell, segment) as in _hanging, segment the index into (a, b)."""
    from scipy.spatial import cKDTree

    z = np.zeros(0, np.int64)
    none = (z, z, z, np.zeros(0), z, z)
    bv = np.flatnonzero(ends)
    if len(a) == 0 or len(bv) < 3:
        return none
    tree = cKDTree(P[bv])
    mid = 0.5 * (P[a] + P[b])
    half = 0.5 * np.linalg.norm(P[b] - P[a], axis=1)
    hits = tree.query_ball_point(mid, half + 4 * tol)
    cnt = np.fromiter((len(h) for h in hits), np.int64, len(hits))
    if cnt.sum() == 0:
        return none
    e = np.repeat(np.arange(len(a)), cnt)
    v = bv[np.fromiter((i for h in hits for i in h), np.int64, int(cnt.sum()))]
    d = P[b[e]] - P[a[e]]
    ll = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    t = np.einsum("ij,ij->i", P[v] - P[a[e]], d) / ll
    off = np.linalg.norm(P[v] - P[a[e]] - t[:, None] * d, axis=1)
    eps = 4 * tol / np.sqrt(ll)
    ok = ((key[v, 0] == key[a[e], 0]) & (v != a[e]) & (v != b[e]) & (t > eps) & (t < 1 - eps)
          & (off <= 4 * tol))
    e, v, t = e[ok], v[ok], t[ok]
    return v, a[e], b[e], t, cell[e], e


def _cell_models(cells_c, cells_n, L, ci, cj):
    """Least-squares gradients (k, 3 channels, 3) and clip ranges lo, hi (k, 3) of the cells'
    linear models from the neighbour pairs (ci, cj) (step 2)."""
    t1, t2 = tangent_basis(cells_n)
    return _cell_fits(np.ascontiguousarray(cells_c, np.float64), t1, t2,
                      np.ascontiguousarray(L, np.float64), np.asarray(ci, np.int64),
                      np.asarray(cj, np.int64), PINV_RCOND)


#: Eigenvalues of a cell's 2 x 2 normal matrix below this fraction of the largest are taken as
#: zero (numpy.linalg.pinv's rcond): neighbours along one line only (a strip one cell wide)
#: give the minimum-norm gradient.
PINV_RCOND = 1e-8


@numba.njit(cache=True, nogil=True)
def _cell_fits(cc, t1, t2, L, ci, cj, rcond):
    """_cell_models in one pass over the pairs (i receives from j): each cell's range of its
    neighbours' values, and the weighted (1 / distance^2) least-squares gradient in its plane
    (basis t1, t2) by the pseudo-inverse of its symmetric 2 x 2 normal matrix, from its two
    eigenvalues in closed form."""
    k = L.shape[0]
    lo = L.copy()
    hi = L.copy()
    M = np.zeros((k, 3))  # [xx, xy, yy]
    R = np.zeros((k, 2, 3))
    for e in range(ci.shape[0]):
        i, j = ci[e], cj[e]
        dx, dy, dz = cc[j, 0] - cc[i, 0], cc[j, 1] - cc[i, 1], cc[j, 2] - cc[i, 2]
        x = dx * t1[i, 0] + dy * t1[i, 1] + dz * t1[i, 2]
        y = dx * t2[i, 0] + dy * t2[i, 1] + dz * t2[i, 2]
        w = 1.0 / max(x * x + y * y, 1e-300)
        M[i, 0] += w * x * x
        M[i, 1] += w * x * y
        M[i, 2] += w * y * y
        for c in range(3):
            lo[i, c] = min(lo[i, c], L[j, c])
            hi[i, c] = max(hi[i, c], L[j, c])
            d = (L[j, c] - L[i, c]) * w
            R[i, 0, c] += d * x
            R[i, 1, c] += d * y
    grad = np.zeros((k, 3, 3))
    for i in range(k):
        a, b, c_ = M[i, 0], M[i, 1], M[i, 2]
        m = 0.5 * (a + c_)
        r = np.sqrt(0.25 * (a - c_) ** 2 + b * b)
        big, small = m + r, m - r  # the eigenvalues (>= 0 up to rounding)
        if big <= 0.0:
            continue
        if abs(small) > rcond * big:  # regular: the inverse
            det = a * c_ - b * b
            p00, p01, p11 = c_ / det, -b / det, a / det
        else:  # rank one: v v^T / big, v the unit eigenvector of the large eigenvalue
            if a >= c_:
                vx, vy = big - c_, b
            else:
                vx, vy = b, big - a
            n2 = vx * vx + vy * vy
            if n2 <= 0.0:  # b = 0 and a = c: M = a I, already handled as regular
                vx, vy, n2 = 1.0, 0.0, 1.0
            p00, p01, p11 = vx * vx / (n2 * big), vx * vy / (n2 * big), vy * vy / (n2 * big)
        for ch in range(3):
            g0 = p00 * R[i, 0, ch] + p01 * R[i, 1, ch]
            g1 = p01 * R[i, 0, ch] + p11 * R[i, 1, ch]
            for d in range(3):
                grad[i, ch, d] = g0 * t1[i, d] + g1 * t2[i, d]
    return grad, lo, hi


def _resolve_hanging(val, v, a, b, t, weight: float = 1e-6):
    """Vertex values (k, 3) with every T-junction made continuous: val[v] = (1 - t) val[a] +
    t val[b] for each constraint (step 4). Chains (a vertex hanging on a segment whose ends
    hang themselves) and zippers (two originals' vertices each inside the other's edges) are
    one sparse least-squares system in the hanging vertices; a weak pull (`weight`) towards
    the averaged values decides what the constraints leave open. Vertices that hang nowhere
    keep their values."""
    from scipy.sparse import coo_matrix, identity
    from scipy.sparse.linalg import spsolve

    if len(v) == 0:
        return val
    h = unique(v)
    col = np.full(len(val), -1, np.int64)
    col[h] = np.arange(len(h))
    rows, cols, coef = [np.arange(len(v))], [col[v]], [np.ones(len(v))]
    rhs = np.zeros((len(v), val.shape[1]))
    for end, w in ((a, 1.0 - t), (b, t)):
        free = col[end] >= 0
        rows.append(np.flatnonzero(free))
        cols.append(col[end[free]])
        coef.append(-w[free])
        rhs[~free] += w[~free, None] * val[end[~free]]
    A = coo_matrix((np.concatenate(coef), (np.concatenate(rows), np.concatenate(cols))),
                   shape=(len(v), len(h))).tocsr()
    lhs = (A.T @ A + weight ** 2 * identity(len(h))).tocsc()
    x = spsolve(lhs, A.T @ rhs + weight ** 2 * val[h])
    out = val.copy()
    out[h] = np.asarray(x).reshape(len(h), -1)
    return out


# ----------------------------------------------------------------------------- the mesh

def smooth_mesh(part, elements, radiance: np.ndarray, crease_deg: float = CREASE_DEG) -> SmoothMesh:
    """The sub-elements as a mesh with radiance at its vertices (module docstring).

    part: core.bundles.Partition (m sub-elements); elements: core.bundles.Elements (n
    originals: material, two_sided, normal); radiance (m, 2, 3) float64, linear RGB per
    sub-element and side (0 front, 1 back, as solution/radiance). Backs are reconstructed for
    two-sided originals only. Returns a SmoothMesh.
    """
    radiance = np.asarray(radiance, np.float64)
    m = len(part)
    if radiance.shape != (m, 2, 3):
        raise ValueError(f"radiance has shape {radiance.shape}, the partition needs {(m, 2, 3)}")
    surface = smoothing_surfaces(elements, crease_deg)
    orig = np.asarray(part.orig, np.int64)
    nv = np.asarray(part.nverts, np.int64)
    Vs = np.asarray(part.verts, np.float64)
    pts = Vs.reshape(-1, 3)
    lo = pts.min(0) if m else np.zeros(3)
    tol = TOL.weld * _diagonal(pts)

    # geometry vertices: (surface, quantised position)
    has = np.arange(4)[None, :] < nv[:, None]
    keys = np.column_stack([np.repeat(surface[orig], nv), _quantise(Vs[has], lo, tol)])
    ukeys, first, inv = unique_rows(keys)
    P = Vs[has][first]
    gv = np.full((m, 4), -1, np.int64)
    gv[has] = inv.ravel()
    lookup = _Lookup(ukeys)
    hv, ha, hb, ht, hcell, border = _hanging(P, ukeys, lookup, gv, nv, lo, tol)

    two = np.asarray(elements.two_sided, bool)[orig]
    G = len(P)
    verts_out, rad_out, corner = [], [], np.full((m, 2, 4), -1, np.int64)
    faces, face_sub, face_side, face_j = [], [], [], []
    base = 0
    fan = np.array([[0, 1, 2], [0, 2, 3]])
    normals = np.asarray(elements.normal, np.float64)[orig]
    for side in (0, 1):
        cells = np.arange(m) if side == 0 else np.flatnonzero(two)
        if len(cells) == 0:
            continue
        L = radiance[cells, side]
        cidx = np.full(m, -1, np.int64)
        cidx[cells] = np.arange(len(cells))
        # incidences (cell, vertex): corners, plus coarse cells at their hanging vertices
        cn = nv[cells]
        inc_cell = np.repeat(np.arange(len(cells)), cn)
        inc_v = gv[cells][np.arange(4)[None, :] < cn[:, None]]
        hc = cidx[hcell]
        sel = hc >= 0
        ci, cj = _pairs_within(np.r_[inc_v, hv[sel]], np.r_[inc_cell, hc[sel]])
        if len(ci):
            u = unique(ci * len(cells) + cj)
            ci, cj = u // len(cells), u % len(cells)
        c = np.asarray(part.center, np.float64)[cells]
        grad, clo, chi = _cell_models(c, normals[cells], L, ci, cj)
        # vertex values: area-weighted clipped models of the cells with the vertex as a corner
        est = L[inc_cell] + np.einsum("kcd,kd->kc", grad[inc_cell], P[inc_v] - c[inc_cell])
        # the range of the neighbourhood bounds the model inside a surface; at its border
        # the vertex lies beyond every centroid, so the model may leave the range there by
        # the range's width (a linear field needs half of it on a regular grid), never below 0
        span = (chi - clo)[inc_cell] * border[inc_v][:, None]
        est = np.clip(est, np.maximum(clo[inc_cell] - span, 0.0), chi[inc_cell] + span)
        wa = np.asarray(part.area, np.float64)[cells][inc_cell]
        used = unique(inc_v)
        vmap = np.full(G, -1, np.int64)
        vmap[used] = np.arange(len(used))
        val = np.zeros((len(used), 3))
        wsum = np.zeros(len(used))
        for c in range(3):
            val[:, c] = np.bincount(vmap[inc_v], est[:, c] * wa, len(used))
        wsum = np.bincount(vmap[inc_v], wa, len(used))
        val /= np.where(wsum > 0, wsum, 1.0)[:, None]
        hsel = (vmap[hv] >= 0) & (vmap[ha] >= 0) & (vmap[hb] >= 0)
        val = _resolve_hanging(val, vmap[hv[hsel]], vmap[ha[hsel]], vmap[hb[hsel]], ht[hsel])
        verts_out.append(P[used])
        rad_out.append(val)
        cor = np.where(gv[cells] >= 0, vmap[np.maximum(gv[cells], 0)] + base, -1)
        corner[cells, side] = cor
        for j in (0, 1):
            fc = cells[nv[cells] >= 3 + j]
            tri = corner[fc, side][:, fan[j]]
            if side == 1:
                tri = tri[:, ::-1]
            faces.append(tri)
            face_sub.append(fc)
            face_side.append(np.full(len(fc), side, np.int8))
            face_j.append(np.full(len(fc), j, np.int8))
        base += len(used)
    if not verts_out:
        e = np.zeros(0, np.int64)
        return SmoothMesh(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3), np.int64), e,
                          np.zeros(0, np.int8), corner, surface, 0)
    faces, face_sub = np.concatenate(faces), np.concatenate(face_sub)
    face_side, face_j = np.concatenate(face_side), np.concatenate(face_j)
    # triangles in sub-element order within each side (fronts first), like the flat export
    o = np.lexsort((face_j, face_sub, face_side))
    return SmoothMesh(np.concatenate(verts_out), np.concatenate(rad_out), faces[o], face_sub[o],
                      face_side[o], corner, surface, int(len(unique(hv))))
