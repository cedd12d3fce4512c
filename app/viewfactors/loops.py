"""Numba kernels of the view-factor task (task.py) up to the unobstructed factor: per-facet
quadrature and moments, cluster culling over the facet tree, facing pairs, the cheap kernel
with its proven bound (*), and the CSR assembly loops. Small, no I/O, no configuration.

Facet arrays are in the leaf order of the facets' tree (scene/originals.build_tree, the one
bounding-volume tree of the package); tree arguments are `Nodes` tuples.
The form factor, the cheap kernel and the derivation of its bound (*):
docs/src/design/viewfactors-method.md ("The cheap kernel and its proven bound").
"""

from __future__ import annotations

import math
from collections import namedtuple

import numba
import numpy as np

#: The node arrays of the facets' tree (scene/originals.OriginalsTree) as one argument of the
#: numba kernels (here and occlusion.py): ranges start:end of the leaf order, children left,
#: right (-1 at a leaf), vertex boxes lo, hi (K, 3), normal cones axis (K, 3), spread (K,)
#: (>= |n - axis| for every facet below), facet area (K,), and the root node.
Nodes = namedtuple("Nodes", "start end left right lo hi axis spread area root")

C6 = 231.0 / math.pi             # the constant of bound (*): 166320 / (720 pi)
MAXQ = 14                        # quadrature nodes per facet, at most

# Radon's degree-5 rule on a triangle: the centroid and barycentric points (1 - 2a, a, a) with
# permutations, a = (6 -+ sqrt 15) / 21 (weights sum to 1)
_R15 = math.sqrt(15.0)
_TRI5 = ((1 / 3, 1 / 3, 9 / 40),) + tuple(
    (a, a, (155.0 + sg * _R15) / 1200.0) for sg, a in ((-1, (6 - _R15) / 21), (1, (6 + _R15) / 21)))


# ----------------------------------------------------------------------------- per facet

def facet_quadrature(verts: np.ndarray, nverts: np.ndarray, area: np.ndarray, tol: float = 1e-9):
    """Degree-5 quadrature of every facet: nodes (n, MAXQ, 3), weights (n, MAXQ) summing to 1
    (unused slots weight 0) and node counts (n,) int64. Parallelograms (v0 + v2 = v1 + v3
    within tol relative) get 3 x 3 Gauss points, triangles Radon's 7 points, other quads 14."""
    n = len(verts)
    nodes = np.zeros((n, MAXQ, 3))
    w = np.zeros((n, MAXQ))
    count = np.zeros(n, np.int64)
    v0, v1, v2, v3 = (verts[:, k] for k in range(4))
    diam = np.linalg.norm(v2 - v0, axis=1) + np.linalg.norm(v3 - v1, axis=1)
    para = (nverts == 4) & (np.linalg.norm(v0 + v2 - v1 - v3, axis=1) <= tol * diam)
    g = math.sqrt(0.6)
    gx = (0.5 * (1 - g), 0.5, 0.5 * (1 + g))
    gw = (5 / 18, 8 / 18, 5 / 18)
    k = 0
    for a, wa in zip(gx, gw):
        for b, wb in zip(gx, gw):
            nodes[para, k] = v0[para] + a * (v1 - v0)[para] + b * (v3 - v0)[para]
            w[para, k] = wa * wb
            k += 1
    count[para] = 9
    bary = [((1 / 3, 1 / 3, 1 / 3), _TRI5[0][2])]
    for a, _, W in _TRI5[1:]:
        bary += [((1 - 2 * a, a, a), W), ((a, 1 - 2 * a, a), W), ((a, a, 1 - 2 * a), W)]

    def tri(sel, p0, p1, p2, frac, first):
        for m, ((x, y, z), W) in enumerate(bary):
            nodes[sel, first + m] = x * p0 + y * p1 + z * p2
            w[sel, first + m] = W * frac

    t = nverts == 3
    tri(t, v0[t], v1[t], v2[t], 1.0, 0)
    count[t] = 7
    q = (nverts == 4) & ~para
    if q.any():
        a1 = 0.5 * np.linalg.norm(np.cross(v1[q] - v0[q], v2[q] - v0[q]), axis=1)
        a2 = 0.5 * np.linalg.norm(np.cross(v2[q] - v0[q], v3[q] - v0[q]), axis=1)
        tri(q, v0[q], v1[q], v2[q], a1 / (a1 + a2), 0)
        tri(q, v0[q], v2[q], v3[q], a2 / (a1 + a2), 7)
        count[q] = 14
    return nodes, w, count


def second_moments(verts: np.ndarray, nverts: np.ndarray, center: np.ndarray, area: np.ndarray):
    """J = E|x - c|^2 over each facet (uniform by area), (n,), and R = max |v - c| over its
    vertices, (n,). Exact: a triangle (p, q, r) about its own centroid g has
    E|x - g|^2 = (|p-g|^2 + |q-g|^2 + |r-g|^2) / 12; quads are their two triangles."""
    def tri(p, q, r):
        g = (p + q + r) / 3.0
        a = 0.5 * np.linalg.norm(np.cross(q - p, r - p), axis=1)
        j = (np.sum((p - g) ** 2, 1) + np.sum((q - g) ** 2, 1) + np.sum((r - g) ** 2, 1)) / 12.0
        return a, g, j

    v0, v1, v2, v3 = (verts[:, k] for k in range(4))
    a1, g1, j1 = tri(v0, v1, v2)
    a2, g2, j2 = tri(v0, v2, v3)
    a2 = np.where(nverts == 4, a2, 0.0)
    tot = np.maximum(a1 + a2, 1e-300)
    J = (a1 * (j1 + np.sum((g1 - center) ** 2, 1)) + a2 * (j2 + np.sum((g2 - center) ** 2, 1))) / tot
    R = np.linalg.norm(verts - center[:, None, :], axis=2).max(axis=1)
    return J, R


# ----------------------------------------------------------------------------- cluster tests

@numba.njit(cache=True, nogil=True, inline="always")
def behind(alo, ahi, axis, spread, blo, bhi, tol):
    """Is box B wholly in the closed back half-space (within tol) of the plane of every facet
    of node A (normal cone axis, spread; facets inside box A)? Then F = 0 from every facet of A
    to every facet of B, and back (F_ji = F_ij A_i / A_j)."""
    m = 0.0
    cn = 0.0
    hn = 0.0
    for k in range(3):
        c = 0.5 * (blo[k] + bhi[k]) - 0.5 * (alo[k] + ahi[k])
        h = 0.5 * (bhi[k] - blo[k]) + 0.5 * (ahi[k] - alo[k])
        m += axis[k] * c + abs(axis[k]) * h
        cn += c * c
        hn += h * h
    return m + spread * (math.sqrt(cn) + math.sqrt(hn)) <= tol


@numba.njit(cache=True, nogil=True, inline="always")
def _box_gap2(alo, ahi, blo, bhi):
    g = 0.0
    for k in range(3):
        d = max(0.0, blo[k] - ahi[k], alo[k] - bhi[k])
        g += d * d
    return g


@numba.njit(cache=True, nogil=True)
def near_leaves(nodes, a, tol, cutoff, leaves_out, drop_node, drop_ab, drop_ba):
    """The leaves B (tree order, start[B] >= start[a]) of the tree `nodes` (Nodes) whose
    facets leaf `a` may exchange radiation with: every pair (i in a, j in B, i < j) is visited
    once over all leaves a.

    Node pairs that face away (`behind`, either way) are culled; with cutoff > 0, a node B
    apart from a whose form-factor bounds area(B) / (pi rho^2) (from any facet of a to B) and
    area(a) / (pi rho^2) (from any facet of B to a), rho the distance between the boxes, are
    both <= cutoff is dropped and recorded in drop_node / drop_ab / drop_ba.
    Returns (leaves found, pairs culled by orientation, pairs dropped, records)."""
    start, end, left, right = nodes.start, nodes.end, nodes.left, nodes.right
    lo, hi, axis, spread, area = nodes.lo, nodes.hi, nodes.axis, nodes.spread, nodes.area
    a0 = start[a]
    na = end[a] - a0
    stack = np.empty(512, np.int64)
    stack[0] = nodes.root
    sp = 1
    nl = 0
    nd = 0
    culled = 0
    dropped = 0
    while sp > 0:
        sp -= 1
        v = stack[sp]
        if end[v] <= a0:
            continue
        if start[v] < a0:          # also holds earlier facets: look inside
            stack[sp] = right[v]
            stack[sp + 1] = left[v]
            sp += 2
            continue
        nb = end[v] - start[v]
        pairs = na * (na - 1) // 2 + na * (nb - na) if start[v] == a0 else na * nb
        if (behind(lo[a], hi[a], axis[a], spread[a], lo[v], hi[v], tol)
                or behind(lo[v], hi[v], axis[v], spread[v], lo[a], hi[a], tol)):
            culled += pairs
            continue
        if cutoff > 0.0 and start[v] >= end[a]:
            g2 = _box_gap2(lo[a], hi[a], lo[v], hi[v])
            if g2 > 0.0:
                bab = area[v] / (math.pi * g2)
                bba = area[a] / (math.pi * g2)
                if bab <= cutoff and bba <= cutoff:
                    drop_node[nd] = v
                    drop_ab[nd] = bab
                    drop_ba[nd] = bba
                    nd += 1
                    dropped += pairs
                    continue
        if left[v] < 0:
            leaves_out[nl] = v
            nl += 1
        else:
            stack[sp] = right[v]
            stack[sp + 1] = left[v]
            sp += 2
    return nl, culled, dropped, nd


# ----------------------------------------------------------------------------- pairs

@numba.njit(cache=True, nogil=True)
def facing_pairs(verts, nv, normal, doff, a0, a1, bstart, bend, tol, ia, ib, blk, full):
    """Pairs (i in a0:a1, j in each range bstart[k]:bend[k], i < j) that can exchange
    radiation: some vertex of j lies beyond tol in front of i's plane and some vertex of i in
    front of j's. full: each lies wholly in the other's closed front half-space (within tol).
    Fills ia, ib, blk (the range k), full; returns the count and the pairs facing away."""
    m = 0
    away = 0
    for k in range(bstart.shape[0]):
        for i in range(a0, a1):
            j0 = max(bstart[k], i + 1)
            for j in range(j0, bend[k]):
                fi = -1e300
                mi = 1e300
                for q in range(nv[j]):
                    s = (normal[i, 0] * verts[j, q, 0] + normal[i, 1] * verts[j, q, 1]
                         + normal[i, 2] * verts[j, q, 2]) - doff[i]
                    fi = max(fi, s)
                    mi = min(mi, s)
                if fi <= tol:
                    away += 1
                    continue
                fj = -1e300
                mj = 1e300
                for q in range(nv[i]):
                    s = (normal[j, 0] * verts[i, q, 0] + normal[j, 1] * verts[i, q, 1]
                         + normal[j, 2] * verts[i, q, 2]) - doff[j]
                    fj = max(fj, s)
                    mj = min(mj, s)
                if fj <= tol:
                    away += 1
                    continue
                ia[m] = i
                ib[m] = j
                blk[m] = k
                full[m] = mi >= -tol and mj >= -tol
                m += 1
    return m, away


@numba.njit(cache=True, nogil=True, inline="always")
def _g(nix, niy, niz, njx, njy, njz, dx, dy, dz):
    """(n_i . d)(-n_j . d) / |d|^4 (no 1/pi)."""
    r2 = dx * dx + dy * dy + dz * dz
    return (nix * dx + niy * dy + niz * dz) * -(njx * dx + njy * dy + njz * dz) / (r2 * r2)


@numba.njit(cache=True, nogil=True, inline="always")
def _m(k, J, R):
    """An upper bound of E|u|^k over a facet (m_1 <= J^(1/2), m_k <= R^(k-2) J)."""
    if k == 0:
        return 1.0
    if k == 1:
        return math.sqrt(J)
    return R ** (k - 2) * J


@numba.njit(cache=True, nogil=True)
def cheap_ff(ia, ib, full, normal, center, area, J, R, flo, fhi, qn, qw, qc, f, bound):
    """The cheap kernel and its bound (*) (docs/src/design/viewfactors-method.md) for pairs (ia, ib) that are `full`
    and apart (rho > 0): f = F_ij (from ia to ib), bound its proven error bound. Other pairs
    get bound = inf (they need the exact integral)."""
    binom = (1.0, 6.0, 15.0, 20.0, 15.0, 6.0, 1.0)
    for p in range(ia.shape[0]):
        i, j = ia[p], ib[p]
        dx = center[j, 0] - center[i, 0]
        dy = center[j, 1] - center[i, 1]
        dz = center[j, 2] - center[i, 2]
        rho = max(math.sqrt(dx * dx + dy * dy + dz * dz) - R[i] - R[j],
                  math.sqrt(_box_gap2(flo[i], fhi[i], flo[j], fhi[j])))
        if not full[p] or rho <= 0.0:
            f[p] = 0.0
            bound[p] = np.inf
            continue
        nix, niy, niz = normal[i, 0], normal[i, 1], normal[i, 2]
        njx, njy, njz = normal[j, 0], normal[j, 1], normal[j, 2]
        s = 0.0
        q6 = 0.0
        for k in range(qc[i]):
            ux = qn[i, k, 0] - center[i, 0]
            uy = qn[i, k, 1] - center[i, 1]
            uz = qn[i, k, 2] - center[i, 2]
            sk = 0.0
            q6k = 0.0
            for l in range(qc[j]):
                ex = qn[j, l, 0] - qn[i, k, 0]
                ey = qn[j, l, 1] - qn[i, k, 1]
                ez = qn[j, l, 2] - qn[i, k, 2]
                sk += qw[j, l] * _g(nix, niy, niz, njx, njy, njz, ex, ey, ez)
                vx = qn[j, l, 0] - center[j, 0] - ux
                vy = qn[j, l, 1] - center[j, 1] - uy
                vz = qn[j, l, 2] - center[j, 2] - uz
                e2 = vx * vx + vy * vy + vz * vz
                q6k += qw[j, l] * e2 * e2 * e2
            s += qw[i, k] * sk
            q6 += qw[i, k] * q6k
        e6 = 0.0
        for k in range(7):
            e6 += binom[k] * _m(k, J[i], R[i]) * _m(6 - k, J[j], R[j])
        f[p] = max(area[j] * s / math.pi, 0.0)
        r2 = rho * rho
        r8 = r2 * r2 * r2 * r2
        bound[p] = area[j] * C6 * (q6 + e6) / r8


# ----------------------------------------------------------------------------- assembly

@numba.njit(cache=True, nogil=True)
def scatter_rows(rows, cols, vals, fill, indices, data):
    """CSR fill: entry k goes to row rows[k] at position fill[row] (then advanced)."""
    for k in range(rows.shape[0]):
        r = rows[k]
        p = fill[r]
        indices[p] = cols[k]
        data[p] = vals[k]
        fill[r] = p + 1


@numba.njit(cache=True, nogil=True)
def reciprocity_residual(indptr, indices, data, area):
    """max |A_i F_ij - A_j F_ji| over the entries of a CSR matrix with sorted indices (an entry
    whose transpose is absent counts with F_ji = 0)."""
    worst = 0.0
    for i in range(indptr.shape[0] - 1):
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            lo, hi = indptr[j], indptr[j + 1]
            while lo < hi:   # binary search for i in row j
                mid = (lo + hi) // 2
                if indices[mid] < i:
                    lo = mid + 1
                else:
                    hi = mid
            back = data[lo] if lo < indptr[j + 1] and indices[lo] == i else 0.0
            worst = max(worst, abs(area[i] * data[p] - area[j] * back))
    return worst
