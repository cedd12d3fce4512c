"""Numba kernels of the view-factor stage (viewfactor.py): small, no I/O, no configuration.

Facet arrays are in the tree order of bvh.FacetTree. Facets are one-sided: facet i radiates
from its front, the side its normal n_i points to. The unoccluded form factor is

    F_ij = 1 / A_i  int_i int_j  max(0, n_i . d) max(0, -n_j . d) / (pi |d|^4)  dA_j dA_i,
    d = y - x  (x on i, y on j),

so A_i F_ij = A_j F_ji, and F_ij = 0 when j lies wholly in the closed back half-space of i.

The cheap kernel (`cheap_ff`) and its proven bound
-------------------------------------------------
When each facet lies wholly in front of the other (closed half-spaces), the integrand is the
smooth g(d) = (n_i . d)(-n_j . d) / (pi |d|^4) on the whole domain, and F_ij = A_j E[g(d)] over
independent uniform points x, y. The kernel applies to both facets a positive-weight quadrature
rule exact for polynomials of degree 5 (a parallelogram: 3 x 3 Gauss points of its affine map;
a triangle: Radon's 7-point rule; another convex quad: that rule on its two triangles). Their
product is exact for every polynomial of degree <= 5 in d, so with the Taylor expansion of g
about d0 = c_j - c_i (centroids) only the remainder R6 is missed:

    |Q(g) - E(g)| <= |Q(R6)| + |E(R6)|,   |R6(d)| <= sup|D^6_u g| |d - d0|^6 / 720.

The directional derivatives of |d|^-4 along a unit u are k! C_k^(2)(-cos) |d|^-(4+k)
(Gegenbauer), at most (k+3)!/6 |d|^-(4+k): 840, 6720, 60480 for k = 4, 5, 6. With Leibniz on
(a.d)(b.d) |d|^-4 (|a| = |b| = 1: |D_u p| <= 2|d|, |D^2_u p| <= 2, D^3 p = 0):
sup |D^6_u g| <= (60480 + 6*2*6720 + 15*2*840) / (pi rho^6 rho^2) = 166320 / (pi rho^8), where
rho is a lower bound of the distance between the facets (the larger of |c_j - c_i| - R_i - R_j,
R the largest distance from a centroid to its vertices, and the gap between the facets'
boxes); every segment between two points of the Minkowski difference (convex) keeps |d| >=
rho. With u = x - c_i, v = y - c_j, E|v - u|^6 <= E(|u| + |v|)^6 = sum_k C(6,k) m_k(u)
m_(6-k)(v), m_0 = 1, m_1 <= J^(1/2), m_k <= R^(k-2) J (J = E|u|^2, the polar second moment per
area), and Q|v - u|^6 is summed at the nodes. So

    |F_cheap - F_exact| <= A_j 231 / pi (Q|v - u|^6 + E|v - u|^6) / rho^8            (*)

`cheap_ff` returns the value and this bound; viewfactor.py uses the value only where the bound
is a small fraction of it, and the exact contour integral (exact.py) everywhere else.
"""

from __future__ import annotations

import math

import numba
import numpy as np

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

@numba.njit(cache=True, inline="always")
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


@numba.njit(cache=True, inline="always")
def _box_gap2(alo, ahi, blo, bhi):
    g = 0.0
    for k in range(3):
        d = max(0.0, blo[k] - ahi[k], alo[k] - bhi[k])
        g += d * d
    return g


@numba.njit(cache=True)
def near_leaves(start, end, left, right, lo, hi, axis, spread, area, root, a, tol, cutoff,
                leaves_out, drop_node, drop_ab, drop_ba):
    """The leaves B (tree order, start[B] >= start[a]) whose facets leaf `a` may exchange
    radiation with: every pair (i in a, j in B, i < j) is visited once over all leaves a.

    Node pairs that face away (`behind`, either way) are culled; with cutoff > 0, a node B
    apart from a whose form-factor bounds area(B) / (pi rho^2) (from any facet of a to B) and
    area(a) / (pi rho^2) (from any facet of B to a), rho the distance between the boxes, are
    both <= cutoff is dropped and recorded in drop_node / drop_ab / drop_ba.
    Returns (leaves found, pairs culled by orientation, pairs dropped, records)."""
    a0 = start[a]
    na = end[a] - a0
    stack = np.empty(512, np.int64)
    stack[0] = root
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

@numba.njit(cache=True)
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


@numba.njit(cache=True, inline="always")
def _g(nix, niy, niz, njx, njy, njz, dx, dy, dz):
    """(n_i . d)(-n_j . d) / |d|^4 (no 1/pi)."""
    r2 = dx * dx + dy * dy + dz * dz
    return (nix * dx + niy * dy + niz * dz) * -(njx * dx + njy * dy + njz * dz) / (r2 * r2)


@numba.njit(cache=True, inline="always")
def _m(k, J, R):
    """An upper bound of E|u|^k over a facet (m_1 <= J^(1/2), m_k <= R^(k-2) J)."""
    if k == 0:
        return 1.0
    if k == 1:
        return math.sqrt(J)
    return R ** (k - 2) * J


@numba.njit(cache=True)
def cheap_ff(ia, ib, full, normal, center, area, J, R, flo, fhi, qn, qw, qc, f, bound):
    """The cheap kernel and its bound (*) (module docstring) for pairs (ia, ib) that are `full`
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


# ----------------------------------------------------------------------------- shafts

@numba.njit(cache=True, inline="always")
def shaft_out(alo, ahi, blo, bhi, clo, chi):
    """Is box C outside the shaft between boxes A and B (their box hull, cut by the planes that
    join the two boxes' corners in each coordinate plane; Haines & Wallace 1991)? Then no
    segment from A to B meets C."""
    for k in range(3):
        if chi[k] < min(alo[k], blo[k]) or clo[k] > max(ahi[k], bhi[k]):
            return True
    for i in range(3):
        for j in range(i + 1, 3):
            for si in range(2):
                for sj in range(2):
                    gi = 1.0 if si == 1 else -1.0
                    gj = 1.0 if sj == 1 else -1.0
                    ai = ahi[i] if si == 1 else alo[i]
                    aj = ahi[j] if sj == 1 else alo[j]
                    bi = bhi[i] if si == 1 else blo[i]
                    bj = bhi[j] if sj == 1 else blo[j]
                    if (gi * (ai - bi) > 0) == (gj * (aj - bj) > 0):
                        continue   # one corner is outermost both ways: the box hull suffices
                    ni = -(bj - aj)
                    nj = bi - ai
                    if ni * gi + nj * gj < 0:
                        ni = -ni
                        nj = -nj
                    d = ni * ai + nj * aj
                    x = clo[i] if ni > 0 else chi[i]
                    y = clo[j] if nj > 0 else chi[j]
                    if ni * x + nj * y > d + 1e-12 * (abs(d) + (abs(ni) + abs(nj))
                                                      * (abs(x) + abs(y))):
                        return True
    return False


@numba.njit(cache=True, inline="always")
def _box_side(lo, hi, n, d, pad):
    """+1: box in the closed front half-space of plane (n, d) within pad; -1 closed back;
    2 both (within pad of the plane); 0 neither."""
    mn = 0.0
    mx = 0.0
    for k in range(3):
        if n[k] > 0:
            mn += n[k] * lo[k]
            mx += n[k] * hi[k]
        else:
            mn += n[k] * hi[k]
            mx += n[k] * lo[k]
    front = mn - d >= -pad
    back = mx - d <= pad
    if front and back:
        return 2
    if front:
        return 1
    if back:
        return -1
    return 0


@numba.njit(cache=True, inline="always")
def _closed_apart(sa, sb):
    """Both on one closed side: a segment between them meets the plane only where it lies in
    it, which has measure zero (or zero kernel) in the form-factor integral."""
    return (sa == 2 or sb == 2 or sa == sb) and sa != 0 and sb != 0


@numba.njit(cache=True)
def block_occluders(start, end, left, right, lo, hi, root, flo, fhi, normal, doff, pad,
                    alo, ahi, blo, bhi, out):
    """Facets that may cut a segment between boxes A and B: their box enters the shaft and
    their plane does not hold both boxes on one closed side. Tree traversal with the shaft
    test on node boxes. Writes facet ids (tree order) into out; returns their count."""
    stack = np.empty(512, np.int64)
    stack[0] = root
    sp = 1
    m = 0
    while sp > 0:
        sp -= 1
        v = stack[sp]
        if shaft_out(alo, ahi, blo, bhi, lo[v], hi[v]):
            continue
        if left[v] >= 0:
            stack[sp] = right[v]
            stack[sp + 1] = left[v]
            sp += 2
            continue
        for o in range(start[v], end[v]):
            if _closed_apart(_box_side(alo, ahi, normal[o], doff[o], pad),
                             _box_side(blo, bhi, normal[o], doff[o], pad)):
                continue
            if shaft_out(alo, ahi, blo, bhi, flo[o], fhi[o]):
                continue
            out[m] = o
            m += 1
    return m


@numba.njit(cache=True, inline="always")
def _verts_side(verts, nv, i, n, d, pad):
    """Side of facet i's vertices with respect to plane (n, d), as _box_side."""
    mn = 1e300
    mx = -1e300
    for q in range(nv[i]):
        s = n[0] * verts[i, q, 0] + n[1] * verts[i, q, 1] + n[2] * verts[i, q, 2] - d
        mn = min(mn, s)
        mx = max(mx, s)
    front = mn >= -pad
    back = mx <= pad
    if front and back:
        return 2
    if front:
        return 1
    if back:
        return -1
    return 0


@numba.njit(cache=True)
def prove_unobstructed(ia, ib, blk, need, bleaf, aleaf, start, end, left, right, lo, hi, root,
                       verts, nv, flo, fhi, normal, doff, pad, proven):
    """For pairs sorted by block (blk indexes bleaf; all rows in leaf aleaf): proven[p] = True
    when no facet can cut a segment between facets ia[p] and ib[p]. Blocks with a pair that
    needs it (need[p]: pairs that would otherwise take many rays) are tested: a block whose
    shaft holds no candidate at all is proven whole; otherwise each needing pair is proven when
    none of the block's candidates survives the pair's own tests (its plane holds both facets'
    vertices on one closed side, or its box is outside the shaft of the two facets' boxes).
    Returns the number of facet tests made."""
    cand = np.empty(flo.shape[0], np.int64)
    tests = 0
    p = 0
    n = ia.shape[0]
    while p < n:
        k = blk[p]
        q = p
        any_need = False
        while q < n and blk[q] == k:
            any_need = any_need or need[q]
            q += 1
        if not any_need:   # one ray each decides them as well as a proof would
            p = q
            continue
        b = bleaf[k]
        nc = block_occluders(start, end, left, right, lo, hi, root, flo, fhi, normal, doff, pad,
                             lo[aleaf], hi[aleaf], lo[b], hi[b], cand)
        if nc == 0:
            for r in range(p, q):
                proven[r] = True
        else:
            for r in range(p, q):
                if not need[r]:
                    continue
                i, j = ia[r], ib[r]
                ok = True
                for c in range(nc):
                    o = cand[c]
                    if o == i or o == j:
                        continue
                    tests += 1
                    if _closed_apart(_verts_side(verts, nv, i, normal[o], doff[o], pad),
                                     _verts_side(verts, nv, j, normal[o], doff[o], pad)):
                        continue
                    if shaft_out(flo[i], fhi[i], flo[j], fhi[j], flo[o], fhi[o]):
                        continue
                    ok = False
                    break
                proven[r] = ok
        p = q
    return tests


# ----------------------------------------------------------------------------- sampling

@numba.njit(cache=True, inline="always")
def _mix(z):
    """splitmix64 finaliser (uint64 -> uint64)."""
    z = z + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True, inline="always")
def _u01(seed, facet, s, cell, comp):
    """A uniform double in [0, 1) that depends only on its arguments (counter-based)."""
    z = _mix(np.uint64(seed) ^ np.uint64(0x5851F42D4C957F2D))
    z = _mix(z ^ np.uint64(facet))
    z = _mix(z ^ (np.uint64(s) << np.uint64(40)) ^ (np.uint64(cell) << np.uint64(2))
             ^ np.uint64(comp))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, inline="always")
def _bilinear_jacobian(P, u, v):
    """|dB/du x dB/dv| at (u, v) of the bilinear map B of the quad P (4, 3)."""
    ax = (1 - v) * (P[1, 0] - P[0, 0]) + v * (P[2, 0] - P[3, 0])
    ay = (1 - v) * (P[1, 1] - P[0, 1]) + v * (P[2, 1] - P[3, 1])
    az = (1 - v) * (P[1, 2] - P[0, 2]) + v * (P[2, 2] - P[3, 2])
    bx = (1 - u) * (P[3, 0] - P[0, 0]) + u * (P[2, 0] - P[1, 0])
    by = (1 - u) * (P[3, 1] - P[0, 1]) + u * (P[2, 1] - P[1, 1])
    bz = (1 - u) * (P[3, 2] - P[0, 2]) + u * (P[2, 2] - P[1, 2])
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    return math.sqrt(cx * cx + cy * cy + cz * cz)


@numba.njit(cache=True)
def sample_facets(fids, gid, s, seed, verts, nv, center, area, pts, w):
    """Jittered stratified points of facets fids (tree order): s * s per facet, pts
    (len(fids) * s * s, 3), weights w (same count; each facet's sum to 1 in expectation).

    Triangles: one uniform point in each of the s^2 congruent sub-triangles of the regular
    subdivision, weight 1 / s^2. Quads: one point in each cell of an s x s grid of the bilinear
    map, weight = its Jacobian / (s^2 area) (unbiased for any planar convex quad). s = 1: the
    centroid (measured: one random point instead doubles the rows' errors on the urban scene of
    benchmarks/bench_viewfactors.py). The jitter depends on (seed, gid[facet], s, cell) only
    (gid: the facets' original ids), so every task draws the same points."""
    S = s * s
    for t in range(fids.shape[0]):
        f = fids[t]
        base = t * S
        if s == 1:
            for k in range(3):
                pts[base, k] = center[f, k]
            w[base] = 1.0
            continue
        g = gid[f]
        if nv[f] == 3:
            c = 0
            for a in range(s):
                for b in range(s - a):
                    for up in range(2):
                        if up == 1 and a + b > s - 2:
                            continue
                        r1 = _u01(seed, g, s, c, 0)
                        r2 = _u01(seed, g, s, c, 1)
                        if r1 + r2 > 1.0:
                            r1 = 1.0 - r1
                            r2 = 1.0 - r2
                        # sub-triangle corners in (e1, e2) units of 1/s
                        if up == 0:
                            u0, v0, u1, v1, u2, v2 = a, b, a + 1, b, a, b + 1
                        else:
                            u0, v0, u1, v1, u2, v2 = a + 1, b + 1, a, b + 1, a + 1, b
                        uu = (u0 + r1 * (u1 - u0) + r2 * (u2 - u0)) / s
                        vv = (v0 + r1 * (v1 - v0) + r2 * (v2 - v0)) / s
                        for k in range(3):
                            p0 = verts[f, 0, k]
                            pts[base + c, k] = (p0 + uu * (verts[f, 1, k] - p0)
                                                + vv * (verts[f, 2, k] - p0))
                        w[base + c] = 1.0 / S
                        c += 1
        else:
            c = 0
            for a in range(s):
                for b in range(s):
                    u = (a + _u01(seed, g, s, c, 0)) / s
                    v = (b + _u01(seed, g, s, c, 1)) / s
                    for k in range(3):
                        pts[base + c, k] = ((1 - u) * (1 - v) * verts[f, 0, k]
                                            + u * (1 - v) * verts[f, 1, k]
                                            + u * v * verts[f, 2, k] + (1 - u) * v * verts[f, 3, k])
                    w[base + c] = _bilinear_jacobian(verts[f], u, v) / (S * area[f])
                    c += 1


@numba.njit(cache=True)
def sample_rays(pi, pj, S, pts, w, normal, fi, fj, ptr, ra, rb, term):
    """Rays of the sample pairs of pairs p: facet fi[p] has points pi[p] * S ... + S - 1 of
    pts, fj[p] likewise. A ray (k, l) is kept when its term w_k w_l c_i c_j / r^4 > 0 (else
    it adds nothing). Fills ptr (pairs + 1,) (the rays of pair p are ptr[p]:ptr[p + 1]), ra,
    rb (point indices), term; returns the number of rays."""
    m = 0
    for p in range(pi.shape[0]):
        ptr[p] = m
        i, j = fi[p], fj[p]
        for k in range(S):
            x = pi[p] * S + k
            for l in range(S):
                y = pj[p] * S + l
                dx = pts[y, 0] - pts[x, 0]
                dy = pts[y, 1] - pts[x, 1]
                dz = pts[y, 2] - pts[x, 2]
                ci = normal[i, 0] * dx + normal[i, 1] * dy + normal[i, 2] * dz
                cj = -(normal[j, 0] * dx + normal[j, 1] * dy + normal[j, 2] * dz)
                if ci <= 0.0 or cj <= 0.0:
                    continue
                r2 = dx * dx + dy * dy + dz * dz
                ra[m] = x
                rb[m] = y
                term[m] = w[x] * w[y] * ci * cj / (r2 * r2)
                m += 1
    ptr[pi.shape[0]] = m
    return m


@numba.njit(cache=True)
def visible_fraction(ptr, term, vis, phi):
    """phi[p] = sum term V / sum term over the rays of pair p (NaN when it has none)."""
    for p in range(ptr.shape[0] - 1):
        tot = 0.0
        seen = 0.0
        for r in range(ptr[p], ptr[p + 1]):
            tot += term[r]
            if vis[r]:
                seen += term[r]
        phi[p] = seen / tot if tot > 0.0 else np.nan


# ----------------------------------------------------------------------------- assembly

@numba.njit(cache=True)
def scatter_rows(rows, cols, vals, fill, indices, data):
    """CSR fill: entry k goes to row rows[k] at position fill[row] (then advanced)."""
    for k in range(rows.shape[0]):
        r = rows[k]
        p = fill[r]
        indices[p] = cols[k]
        data[p] = vals[k]
        fill[r] = p + 1


@numba.njit(cache=True)
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
