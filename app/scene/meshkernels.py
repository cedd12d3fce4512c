"""numba loops of the mesh loader (scene.meshes): the polygons of the faces, and the greedy merge
of triangle pairs into parallelograms (the OBJ byte scanner is formats.objscan's).

Each is an exact stand-in for the per-face or per-triangle Python loop it replaced: the merge
tries the same candidates in the same order with the same floating-point expressions as numpy
(sums of three products left to right, as np.dot and np.linalg.norm of a 3-vector give them
here; no fused multiply-adds: fastmath off). Issue #25: a mesh of 10^6 triangles loads in
seconds.
"""

from __future__ import annotations

import numba
import numpy as np


# ----------------------------------------------------------------------------- polygons

@numba.njit(cache=True, nogil=True)
def vertex_flags(V, max_coord):
    """Per vertex of V (n, 3): 1 if a coordinate is NaN or infinite, else 2 if one is beyond
    max_coord in size, else 0."""
    out = np.zeros(V.shape[0], np.uint8)
    for i in range(V.shape[0]):
        for c in range(3):
            x = V[i, c]
            if not np.isfinite(x):
                out[i] = 1
                break
            if abs(x) > max_coord:
                out[i] = 2
    return out


@numba.njit(cache=True, nogil=True)
def fill_polygons(V, flat, starts, first, how, verts):
    """Writes the polygons of each face f (vertex indices flat[starts[f]:starts[f + 1]]) into
    verts (n, 4, 3) from row first[f]: how[f] 0: a triangle (0, 1, 2, 2); 1: a quad; 2: two
    triangles (0, 1, 2, 2), (0, 2, 3, 3); 3: two triangles (1, 2, 3, 3), (1, 3, 0, 0); 4: a fan
    (0, k, k + 1, k + 1) for k = 1 .. n - 2."""
    rows = np.array([[0, 1, 2, 2], [0, 1, 2, 3], [0, 1, 2, 2], [1, 2, 3, 3], [0, 2, 3, 3],
                     [1, 3, 0, 0]])
    for f in range(len(how)):
        s = starts[f]
        o = first[f]
        h = how[f]
        if h == 4:
            for k in range(1, starts[f + 1] - s - 1):
                for slot in range(4):
                    t = 0 if slot == 0 else (k if slot == 1 else k + 1)
                    for c in range(3):
                        verts[o + k - 1, slot, c] = V[flat[s + t], c]
            continue
        r = 0 if h == 0 else (1 if h == 1 else (2 if h == 2 else 3))
        for slot in range(4):
            for c in range(3):
                verts[o, slot, c] = V[flat[s + rows[r, slot]], c]
        if h >= 2:
            r2 = 4 if h == 2 else 5
            for slot in range(4):
                for c in range(3):
                    verts[o + 1, slot, c] = V[flat[s + rows[r2, slot]], c]


# ----------------------------------------------------------------------------- merge

@numba.njit(cache=True, nogil=True)
def _mix(a, b, c):
    """A 64-bit hash of three 64-bit words."""
    h = a * np.uint64(0x9E3779B97F4A7C15)
    h ^= (h >> np.uint64(29)) ^ b * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= (h >> np.uint64(31)) ^ c * np.uint64(0x165667B19E3779F9)
    h ^= h >> np.uint64(32)
    return h


@numba.njit(cache=True, nogil=True)
def _ids(w):
    """An id per row of w (n, 2 or 3) uint64, the same for equal rows (0, 1, ...: in the order
    of their first rows), by an open-addressing hash table."""
    n, m = w.shape
    size = 16
    while size < 2 * n:
        size *= 2
    mask = np.uint64(size - 1)
    table = -np.ones(size, np.int64)
    ids = np.empty(n, np.int64)
    nid = 0
    for p in range(n):
        h = _mix(w[p, 0], w[p, 1], w[p, m - 1]) & mask
        while True:
            q = table[h]
            if q < 0:
                table[h] = p
                ids[p] = nid
                nid += 1
                break
            same = True
            for c in range(m):
                if w[q, c] != w[p, c]:
                    same = False
            if same:
                ids[p] = ids[q]
                break
            h = (h + np.uint64(1)) & mask
    return ids


def point_ids(pts: np.ndarray) -> np.ndarray:
    """An id per point of pts (n, 3) float64, finite: equal for points with equal coordinates
    (-0.0 is 0.0)."""
    w = np.ascontiguousarray(pts + 0.0).view(np.uint64)  # + 0.0: -0.0 -> 0.0; then the bits
    return _ids(w)


@numba.njit(cache=True, nogil=True)
def edge_runs(vid):
    """The edges of triangles vid (t, 3) (vertex ids): slot 3 k + e is edge (vid[k, e],
    vid[k, (e + 1) % 3]), either way round. Returns order (3 t,): the slots by edge, each edge's
    in slot order; start (edges + 1,): where each edge's run begins in order; group (3 t,): the
    edge of each slot."""
    t = vid.shape[0]
    w = np.empty((3 * t, 2), np.uint64)
    for k in range(t):
        for e in range(3):
            a = vid[k, e]
            b = vid[k, (e + 1) % 3]
            w[3 * k + e, 0] = min(a, b)
            w[3 * k + e, 1] = max(a, b)
    group = _ids(w)
    nedge = 0
    for s in range(3 * t):
        nedge = max(nedge, group[s] + 1)
    start = np.zeros(nedge + 1, np.int64)
    for s in range(3 * t):
        start[group[s] + 1] += 1
    for g in range(nedge):
        start[g + 1] += start[g]
    fill = start[:-1].copy()
    order = np.empty(3 * t, np.int64)
    for s in range(3 * t):
        order[fill[group[s]]] = s
        fill[group[s]] += 1
    return order, start, group


@numba.njit(cache=True, nogil=True)
def _norm3(x, y, z):
    return np.sqrt(x * x + y * y + z * z)


@numba.njit(cache=True, nogil=True)
def merge_pairs(P, vid, mat, order, gstart, group, tol):
    """The greedy pairing of merge_parallelograms. P (t, 3, 3): the triangles' vertices; vid
    (t, 3): vertex identities; mat (t,): material codes; order: the edge slots 3 k + e sorted by
    edge (stable: in the order the Python loop appended them), gstart: where each edge's run
    starts in order (and its end), group (3 t,): the run of each slot; tol: merge tolerance.
    Returns partner (t,) (-1: none), edge (t,): the shared edge e of the triangle that became
    the quad (-1 for the others), and pedge (t,): the slot ej of that edge in its partner."""
    t = P.shape[0]
    partner = -np.ones(t, np.int64)
    edge = -np.ones(t, np.int64)
    pedge = -np.ones(t, np.int64)
    for k in range(t):
        if partner[k] >= 0:
            continue
        for e in range(3):
            e1 = (e + 1) % 3
            e2 = (e + 2) % 3
            b = vid[k, e1]
            g = group[3 * k + e]
            for r in range(gstart[g], gstart[g + 1]):
                s = order[r]
                j = s // 3
                ej = s - 3 * j
                if j == k or partner[j] >= 0 or mat[j] != mat[k]:
                    continue
                if vid[j, ej] != b:
                    continue
                y = (ej + 2) % 3
                pax, pay, paz = P[k, e, 0], P[k, e, 1], P[k, e, 2]
                pbx, pby, pbz = P[k, e1, 0], P[k, e1, 1], P[k, e1, 2]
                pxx, pxy, pxz = P[k, e2, 0], P[k, e2, 1], P[k, e2, 2]
                qyx, qyy, qyz = P[j, y, 0], P[j, y, 1], P[j, y, 2]
                d1 = _norm3(pax - pbx, pay - pby, paz - pbz)
                d2 = _norm3(pxx - qyx, pxy - qyy, pxz - qyz)
                d = d2 if d2 > d1 else d1
                m = _norm3((pax + pbx) - (pxx + qyx), (pay + pby) - (pxy + qyy),
                           (paz + pbz) - (pxz + qyz))
                if m > tol * d:
                    continue
                ux, uy, uz = pbx - pax, pby - pay, pbz - paz
                vx, vy, vz = pxx - pax, pxy - pay, pxz - paz
                n1x, n1y, n1z = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
                ux, uy, uz = pax - pbx, pay - pby, paz - pbz
                vx, vy, vz = qyx - pbx, qyy - pby, qyz - pbz
                n2x, n2y, n2z = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
                dot = n1x * n2x + n1y * n2y + n1z * n2z
                cx = n1y * n2z - n1z * n2y
                cy = n1z * n2x - n1x * n2z
                cz = n1x * n2y - n1y * n2x
                if dot <= 0 or _norm3(cx, cy, cz) > tol * _norm3(n1x, n1y, n1z) * _norm3(n2x, n2y, n2z):
                    continue
                partner[k] = j
                partner[j] = k
                edge[k] = e
                pedge[k] = ej
                break
            if partner[k] >= 0:
                break
    return partner, edge, pedge
