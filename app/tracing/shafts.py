"""Shaft culling (Haines & Wallace 1991) and the pair loops of the visibility stage: numba
kernels on plain arrays, no I/O, no Dask.

A shaft is the convex hull of two boxes; an occluder whose box lies outside it, or whose plane
leaves both boxes on one side, cannot cut any segment between them. `classify` applies this
hierarchically to a block of sub-element pairs (ranges halved recursively; sub-elements are in
depth-first split order, so a range is a compact patch) and says, per pair, whether it faces
away (V = 0), is visible without a ray, or needs rays. The view factors' occluder search
(viewfactors/occlusion.py) uses the same tests (shaft_excludes, same_side_boxes,
same_side_polys) and boxes (occluders, node_boxes).
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from radiosity.core.geometry import COS_TOL
from radiosity.core.tolerances import TOL

LEAF = 64        # range pairs with at most this many pairs are tested pair by pair


def occluders(elements):
    """Padded occluder boxes and planes of the original elements: elo, ehi (n, 3), enormal
    (n, 3), eoffset (n,), and the plane-test tolerance pad (TOL.box_pad of the scene size plus the
    elements' own deviation from their planes; non-planar input was split, so that is rounding)."""
    ev = elements.verts
    lo, hi = ev.min(axis=1), ev.max(axis=1)
    pad = TOL.box_pad * float(np.linalg.norm(ev.reshape(-1, 3).max(0) - ev.reshape(-1, 3).min(0)))
    eoffset = np.einsum("ic,ic->i", elements.normal, elements.center)
    dev = np.abs(np.einsum("ic,ikc->ik", elements.normal, ev) - eoffset[:, None]).max(1)
    return lo - pad, hi + pad, elements.normal, eoffset, pad + float(dev.max(initial=0.0))


@numba.njit(cache=True, nogil=True, inline="always")
def faces_along(N, i, ts, dx, dy, dz, length):
    """Does element i with normal N[i] (two-sided if ts) face along d? cos beyond +-tol.
    (Hot-loop helpers here take an array and an index, not a row: a row is a view, and each
    view costs two atomic reference-count updates, a large share of the link stage's time:
    docs/src/measurements/choices.md.)"""
    c = N[i, 0] * dx + N[i, 1] * dy + N[i, 2] * dz
    t = COS_TOL * length
    return c > t or (ts and c < -t)


@numba.njit(cache=True, nogil=True, inline="always")
def _seg_box(px, py, pz, qx, qy, qz, lo, hi):
    """Does the segment p-q touch the closed box [lo, hi]? (slab test)"""
    t0, t1 = 0.0, 1.0
    p = (px, py, pz)
    d = (qx - px, qy - py, qz - pz)
    for k in range(3):
        if d[k] == 0.0:
            if p[k] < lo[k] or p[k] > hi[k]:
                return False
        else:
            inv = 1.0 / d[k]
            ta = (lo[k] - p[k]) * inv
            tb = (hi[k] - p[k]) * inv
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
            if t0 > t1:
                return False
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def side_code(mn, mx, pad):
    """The side of a set whose signed distances to a plane lie in [mn, mx]: +1 in the closed
    front half-space (within pad), -1 closed back, 2 both (within pad of the plane), 0
    neither."""
    front = mn >= -pad
    back = mx <= pad
    if front and back:
        return 2
    if front:
        return 1
    if back:
        return -1
    return 0


@numba.njit(cache=True, nogil=True, inline="always")
def closed_apart(sa, sb):
    """Two sets on one closed side of a plane (side_code's): a segment between them meets the
    plane only at an end or where it lies in it, which has measure zero (or zero kernel) in
    the form-factor integral, so a planar occluder in that plane cannot block it."""
    return (sa == 2 or sb == 2 or sa == sb) and sa != 0 and sb != 0


@numba.njit(cache=True, nogil=True, inline="always")
def _box_side(X, N, D, o, pad):
    """side_code of box X with respect to occluder o's plane (N[o], D[o])."""
    lo = 0.0
    hi = 0.0
    for k in range(3):
        n = N[o, k]
        if n > 0:
            lo += n * X[0, k]
            hi += n * X[1, k]
        else:
            lo += n * X[1, k]
            hi += n * X[0, k]
    return side_code(lo - D[o], hi - D[o], pad)


@numba.njit(cache=True, nogil=True, inline="always")
def same_side_boxes(A, B, N, D, o, pad):
    """Do boxes A and B lie on one closed side of occluder o's plane (N[o], D[o])? Then the
    (planar) occluder cannot block a segment between them (closed_apart); a coplanar
    neighbour of either end is no occluder."""
    return closed_apart(_box_side(A, N, D, o, pad), _box_side(B, N, D, o, pad))


@numba.njit(cache=True, nogil=True, inline="always")
def _poly_side(V, x, nv, N, D, o, pad):
    """side_code of polygon x of V (k, 4, 3) with nv vertices: its vertices, not its box (the
    box of a tilted polygon straddles the polygon's own plane and its coplanar neighbours')."""
    mn = np.inf
    mx = -np.inf
    for v in range(nv):
        d = N[o, 0] * V[x, v, 0] + N[o, 1] * V[x, v, 1] + N[o, 2] * V[x, v, 2] - D[o]
        mn = min(mn, d)
        mx = max(mx, d)
    return side_code(mn, mx, pad)


@numba.njit(cache=True, nogil=True, inline="always")
def same_side_polys(V, a, na, b, nb, N, D, o, pad):
    """same_side_boxes for polygons a, b of V (their vertices; a polygon is the convex hull of its
    vertices, so the closed half-space test on them holds for every point)."""
    return closed_apart(_poly_side(V, a, na, N, D, o, pad), _poly_side(V, b, nb, N, D, o, pad))


@numba.njit(cache=True, nogil=True)
def _range_box(lo, hi, a0, a1, out):
    for k in range(3):
        out[0, k] = np.inf
        out[1, k] = -np.inf
    for i in range(a0, a1):
        for k in range(3):
            if lo[i, k] < out[0, k]:
                out[0, k] = lo[i, k]
            if hi[i, k] > out[1, k]:
                out[1, k] = hi[i, k]


@numba.njit(cache=True, nogil=True, inline="always")
def box_apart(A, B, LO, HI, o):
    """Does some axis separate occluder o's box [LO[o], HI[o]] from the bounding box of boxes A
    and B ((2, 3): lo, hi)? Then no segment between A and B meets it (shaft_excludes' first
    test)."""
    for k in range(3):
        if HI[o, k] < min(A[0, k], B[0, k]) or LO[o, k] > max(A[1, k], B[1, k]):
            return True
    return False


@numba.njit(cache=True, nogil=True, inline="always")
def clear_of(A, B, LO, HI):
    """box_apart for every occluder box (LO, HI (b, 3)): no segment between boxes A and B can
    meet an occluder that lies in them (RayCaster.occluder_boxes). The shaft's planes
    (shaft_excludes) are left out: the rays they would save cost less than testing them
    (docs/src/design/methods-hierarchical-clusters.md, "Rays only where an occluder can be")."""
    for o in range(LO.shape[0]):
        if not box_apart(A, B, LO, HI, o):
            return False
    return True


@numba.njit(cache=True, nogil=True)
def shaft_excludes(A, B, LO, HI, o):
    """Is occluder o's box C = [LO[o], HI[o]] outside the shaft (convex hull) of boxes A and B? (A[0]=lo, A[1]=hi)

    Haines & Wallace: the union's bounding box, cut by the planes through box edges where one
    box sticks out on one axis and the other on a second axis. Conservative: False may be wrong,
    True never is.
    """
    if box_apart(A, B, LO, HI, o):
        return True
    for i in range(3):
        for j in range(i + 1, 3):
            for si in range(2):
                for sj in range(2):
                    # corner direction (+-1 on i, +-1 on j); box extremes on that corner
                    gi = 1.0 if si == 1 else -1.0
                    gj = 1.0 if sj == 1 else -1.0
                    ai, aj = A[si, i], A[sj, j]
                    bi, bj = B[si, i], B[sj, j]
                    a_out_i = gi * (ai - bi) > 0
                    a_out_j = gj * (aj - bj) > 0
                    if a_out_i == a_out_j:
                        continue  # one box is outermost on both axes: the bounding box suffices
                    # plane through (ai, aj) and (bi, bj) in the (i, j) plane, normal outward
                    ni = -(bj - aj)
                    nj = bi - ai
                    if ni * gi + nj * gj < 0:
                        ni, nj = -ni, -nj
                    d = ni * ai + nj * aj
                    # nearest corner of C to the inside: minimise ni*x + nj*y
                    x = LO[o, i] if ni > 0 else HI[o, i]
                    y = LO[o, j] if nj > 0 else HI[o, j]
                    if ni * x + nj * y > d + 1e-12 * (abs(d) + abs(ni) + abs(nj)):
                        return True
    return False


@numba.njit(cache=True, nogil=True)
def classify(rows, cols, occ, cand, sampled):
    """Classify every pair of a tile without rays.

    rows = (ca, na, tsa, la, ha): centres ca (ra, 3), normals na, two-sided flags tsa (ra,),
    boxes la/ha (ra, 3); cols = (cb, nb, tsb, lb, hb) likewise (rb); occ = (olo, ohi, on, od,
    pad) as `occluders` returns them: occluder boxes olo/ohi (k, 3), planes on (k, 3) / od (k,),
    the plane tolerance pad; and the ids `cand` of those that may block this block. sampled: the
    leaf test is the shaft between the pair's boxes (every point pair), not the centres'
    segment. Returns code (ra * rb,) uint8: 0 facing away (V = 0), 1 visible without a ray, 2
    needs rays; and the number of shaft tests made.
    """
    ca, na, tsa, la, ha = rows
    cb, nb, tsb, lb, hb = cols
    olo, ohi, on, od, pad = occ
    ra, rb = ca.shape[0], cb.shape[0]
    code = np.zeros(ra * rb, np.uint8)
    # explicit stack of range pairs; candidate lists live in a pool, LIFO
    pool = np.empty(len(cand) * 130 + 1, np.int64)
    pool[:len(cand)] = cand
    st_a0 = np.empty(256, np.int64)
    st_a1 = np.empty(256, np.int64)
    st_b0 = np.empty(256, np.int64)
    st_b1 = np.empty(256, np.int64)
    st_c0 = np.empty(256, np.int64)
    st_c1 = np.empty(256, np.int64)
    sp = 0
    st_a0[0], st_a1[0], st_b0[0], st_b1[0], st_c0[0], st_c1[0] = 0, ra, 0, rb, 0, len(cand)
    sp = 1
    A = np.empty((2, 3))
    B = np.empty((2, 3))
    tests = 0
    while sp > 0:
        sp -= 1
        a0, a1, b0, b1, c0, c1 = st_a0[sp], st_a1[sp], st_b0[sp], st_b1[sp], st_c0[sp], st_c1[sp]
        top = c1
        # keep the occluders that enter the shaft of this range pair
        _range_box(la, ha, a0, a1, A)
        _range_box(lb, hb, b0, b1, B)
        k = top
        for c in range(c0, c1):
            o = pool[c]
            tests += 1
            if not (same_side_boxes(A, B, on, od, o, pad) or shaft_excludes(A, B, olo, ohi, o)):
                pool[k] = o
                k += 1
        n0, n1 = top, k
        npairs = (a1 - a0) * (b1 - b0)
        if n1 == n0 or npairs <= LEAF:
            for a in range(a0, a1):
                for b in range(b0, b1):
                    dx = cb[b, 0] - ca[a, 0]
                    dy = cb[b, 1] - ca[a, 1]
                    dz = cb[b, 2] - ca[a, 2]
                    length = np.sqrt(dx * dx + dy * dy + dz * dz)
                    if not (faces_along(na, a, tsa[a], dx, dy, dz, length)
                            and faces_along(nb, b, tsb[b], -dx, -dy, -dz, length)):
                        continue
                    hit = False
                    if sampled:
                        _range_box(la, ha, a, a + 1, A)
                        _range_box(lb, hb, b, b + 1, B)
                    for c in range(n0, n1):
                        o = pool[c]
                        if sampled:
                            tests += 1
                            if not (same_side_boxes(A, B, on, od, o, pad)
                                    or shaft_excludes(A, B, olo, ohi, o)):
                                hit = True
                                break
                            continue
                        sp_ = (on[o, 0] * ca[a, 0] + on[o, 1] * ca[a, 1] + on[o, 2] * ca[a, 2]) - od[o]
                        sq_ = (on[o, 0] * cb[b, 0] + on[o, 1] * cb[b, 1] + on[o, 2] * cb[b, 2]) - od[o]
                        if (sp_ > pad and sq_ > pad) or (sp_ < -pad and sq_ < -pad):
                            continue  # both ends on one side of the occluder's plane
                        if _seg_box(ca[a, 0], ca[a, 1], ca[a, 2], cb[b, 0], cb[b, 1], cb[b, 2],
                                    olo[o], ohi[o]):
                            hit = True
                            break
                    code[a * rb + b] = 2 if hit else 1
            continue
        # split the longer range in two and push both halves with the filtered list
        if a1 - a0 >= b1 - b0:
            m = (a0 + a1) // 2
            halves = ((a0, m, b0, b1), (m, a1, b0, b1))
        else:
            m = (b0 + b1) // 2
            halves = ((a0, a1, b0, m), (a0, a1, m, b1))
        for h in halves:
            st_a0[sp], st_a1[sp], st_b0[sp], st_b1[sp] = h
            st_c0[sp], st_c1[sp] = n0, n1
            sp += 1
    return code, tests


@numba.njit(cache=True, nogil=True)
def block_candidates(A, B, olo, ohi, on, od, pad, skip_a, skip_b):
    """Occluders (ids) that may cut a segment between boxes A and B: their plane separates the
    boxes and their box enters the shaft. The block's own two elements never can."""
    out = np.empty(olo.shape[0], np.int64)
    k = 0
    for o in range(olo.shape[0]):
        if o == skip_a or o == skip_b:
            continue
        if not (same_side_boxes(A, B, on, od, o, pad) or shaft_excludes(A, B, olo, ohi, o)):
            out[k] = o
            k += 1
    return out[:k]


# A tree over the occluders (scene/originals.build_tree): per node its children left, right
# (-1 at a leaf), its range start:end into order (the occluders in leaf order) and the union of
# its occluders' padded boxes lo, hi.
OccluderTree = namedtuple("OccluderTree", "left right start end order lo hi")


@numba.njit(cache=True, nogil=True)
def node_boxes(left, right, start, end, order, elo, ehi):
    """Each tree node's box: the union of its occluders' boxes elo, ehi (n, 3), (K, 3) twice."""
    K = left.shape[0]
    lo = np.empty((K, 3))
    hi = np.empty((K, 3))
    for x in range(K - 1, -1, -1):
        if left[x] < 0:
            for k in range(3):
                lo[x, k] = np.inf
                hi[x, k] = -np.inf
            for m in range(start[x], end[x]):
                o = order[m]
                for k in range(3):
                    lo[x, k] = min(lo[x, k], elo[o, k])
                    hi[x, k] = max(hi[x, k], ehi[o, k])
        else:
            for k in range(3):
                lo[x, k] = min(lo[left[x], k], lo[right[x], k])
                hi[x, k] = max(hi[left[x], k], hi[right[x], k])
    return lo, hi


@numba.njit(cache=True, nogil=True)
def tree_candidates(A, B, V, a, na, b, nb, tree, olo, ohi, on, od, pad, skip_a, skip_b, limit):
    """block_candidates through the occluder tree for the shaft between polygons a and b of V
    (na, nb vertices; A, B their boxes): nodes whose box lies outside the shaft are skipped
    whole (a box inside an excluded box is excluded too), so the cost follows the occluders near
    the shaft, not all of them; an occluder whose plane holds both polygons on one closed side
    is none. The ids, ascending; with limit > 0 the search stops once more than `limit` are
    found (the caller leaves such a shaft to rays) and returns those, unsorted."""
    out = np.empty(64, np.int64)
    k = 0
    stack = np.empty(64, np.int64)
    ns = 1
    stack[0] = 0
    while ns > 0:
        ns -= 1
        x = stack[ns]
        if shaft_excludes(A, B, tree.lo, tree.hi, x):
            continue
        if tree.left[x] >= 0:
            if ns + 2 > stack.shape[0]:
                grown = np.empty(2 * stack.shape[0], np.int64)
                grown[:ns] = stack[:ns]
                stack = grown
            stack[ns] = tree.left[x]
            stack[ns + 1] = tree.right[x]
            ns += 2
            continue
        for m in range(tree.start[x], tree.end[x]):
            o = tree.order[m]
            if o == skip_a or o == skip_b:
                continue
            if not (same_side_polys(V, a, na, b, nb, on, od, o, pad)
                    or shaft_excludes(A, B, olo, ohi, o)):
                if k == out.shape[0]:
                    grown = np.empty(2 * k, np.int64)
                    grown[:k] = out
                    out = grown
                out[k] = o
                k += 1
                if 0 < limit < k:
                    return out[:k]
    return np.sort(out[:k])


@numba.njit(cache=True, nogil=True)
def small_tile_pairs(tiles, offsets, center, normal, two_sided, base):
    """Facing pairs of many small tiles at once (no shaft search: for a handful of pairs a ray is
    cheaper than looking for occluders among all elements). Returns ia, ib (sub-elements) and the
    bit index of each pair in the task's buffer (tiles' byte starts relative to `base`)."""
    total = 0
    for t in range(tiles.shape[0]):
        total += (tiles[t, 3] - tiles[t, 2]) * tiles[t, 4]
    ia = np.empty(total, np.int64)
    ib = np.empty(total, np.int64)
    bit = np.empty(total, np.int64)
    k = 0
    for t in range(tiles.shape[0]):
        i, j, r0, r1, nj = tiles[t, 0], tiles[t, 1], tiles[t, 2], tiles[t, 3], tiles[t, 4]
        first = (tiles[t, 5] - base) * 8
        for r in range(r1 - r0):
            a = offsets[i] + r0 + r
            for c in range(nj):
                b = offsets[j] + c
                dx = center[b, 0] - center[a, 0]
                dy = center[b, 1] - center[a, 1]
                dz = center[b, 2] - center[a, 2]
                length = np.sqrt(dx * dx + dy * dy + dz * dz)
                if faces_along(normal, a, two_sided[a], dx, dy, dz, length) and \
                        faces_along(normal, b, two_sided[b], -dx, -dy, -dz, length):
                    ia[k] = a
                    ib[k] = b
                    bit[k] = first + r * nj + c
                    k += 1
    return ia[:k], ib[:k], bit[:k]


@numba.njit(cache=True, nogil=True)
def set_bits(buf, bits):
    """Set bit positions `bits` in the uint8 buffer (little-endian within bytes)."""
    for k in range(bits.shape[0]):
        buf[bits[k] >> 3] |= np.uint8(1 << (bits[k] & 7))


# The tight shaft of two polygons P, Q: their convex hull, bounded by P's and Q's planes and the
# planes through an edge of one and a vertex of the other (Haines & Wallace's plane-bounded
# shaft). As a separating-axis test: along each plane's normal the hull spans [lo, hi] (both
# signs at once); an occluder polygon whose vertices all lie beyond one of them (by pad) meets
# no segment between P and Q. Tighter than the boxes' shaft for tilted polygons and for the
# slanted links between them.
HULL_AXES = 34   # 2 planes + 4 edges of P x 4 vertices of Q + 4 edges of Q x 4 vertices of P


@numba.njit(cache=True, nogil=True)
def hull_axes(V, a, na, b, nb, axes, lo, hi, full):
    """The axes (unit normals) of the hull planes of polygons a and b of V (na, nb vertices)
    into axes (HULL_AXES, 3) and the hull's extent along each into lo, hi (HULL_AXES,): the
    two polygons' own planes first, then with `full` the edge-vertex planes; returns how many
    (degenerate planes left out)."""
    m = 0
    for first in range(2):  # the polygon's own plane, from two of its edges
        x, nx = (a, na) if first == 0 else (b, nb)
        e1x, e1y, e1z = V[x, 1, 0] - V[x, 0, 0], V[x, 1, 1] - V[x, 0, 1], V[x, 1, 2] - V[x, 0, 2]
        e2x, e2y, e2z = (V[x, nx - 1, 0] - V[x, 0, 0], V[x, nx - 1, 1] - V[x, 0, 1],
                         V[x, nx - 1, 2] - V[x, 0, 2])
        m = _add_axis(e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x,
                      V, a, na, b, nb, axes, lo, hi, m)
    if not full:
        return m
    for first in range(2):
        x, nx, y, ny = (a, na, b, nb) if first == 0 else (b, nb, a, na)
        for i in range(nx):
            j = (i + 1) % nx
            ex, ey, ez = V[x, j, 0] - V[x, i, 0], V[x, j, 1] - V[x, i, 1], V[x, j, 2] - V[x, i, 2]
            for k in range(ny):
                wx, wy, wz = V[y, k, 0] - V[x, i, 0], V[y, k, 1] - V[x, i, 1], V[y, k, 2] - V[x, i, 2]
                m = _add_axis(ey * wz - ez * wy, ez * wx - ex * wz, ex * wy - ey * wx,
                              V, a, na, b, nb, axes, lo, hi, m)
    return m


@numba.njit(cache=True, nogil=True, inline="always")
def _add_axis(nx, ny, nz, V, a, na, b, nb, axes, lo, hi, m):
    """Append the axis (nx, ny, nz), normalised, with the extent of polygons a, b along it;
    a near-zero axis (an edge and a vertex in line) is left out."""
    ln = np.sqrt(nx * nx + ny * ny + nz * nz)
    if ln <= 1e-300 or m >= axes.shape[0]:
        return m
    nx, ny, nz = nx / ln, ny / ln, nz / ln
    mn, mx = np.inf, -np.inf
    for x, n in ((a, na), (b, nb)):
        for v in range(n):
            d = nx * V[x, v, 0] + ny * V[x, v, 1] + nz * V[x, v, 2]
            mn = min(mn, d)
            mx = max(mx, d)
    axes[m, 0], axes[m, 1], axes[m, 2] = nx, ny, nz
    lo[m], hi[m] = mn, mx
    return m + 1


@numba.njit(cache=True, nogil=True, inline="always")
def outside_hull(everts, envert, o, axes, lo, hi, m, pad):
    """Does some hull axis (hull_axes) separate occluder polygon o (everts, envert) from the
    hull by more than pad? Then it meets no segment between the two polygons."""
    for k in range(m):
        mn, mx = np.inf, -np.inf
        for v in range(envert[o]):
            d = axes[k, 0] * everts[o, v, 0] + axes[k, 1] * everts[o, v, 1] \
                + axes[k, 2] * everts[o, v, 2]
            mn = min(mn, d)
            mx = max(mx, d)
        if mn > hi[k] + pad or mx < lo[k] - pad:
            return True
    return False


@numba.njit(cache=True, nogil=True, inline="always")
def _box_outside_hull(lo_, hi_, x, axes, lo, hi, m, pad):
    """outside_hull for box x of (lo_, hi_) (a tree node's box)."""
    for k in range(m):
        c = 0.0
        r = 0.0
        for j in range(3):
            c += axes[k, j] * 0.5 * (lo_[x, j] + hi_[x, j])
            r += abs(axes[k, j]) * 0.5 * (hi_[x, j] - lo_[x, j])
        if c - r > hi[k] + pad or c + r < lo[k] - pad:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def first_in_hull(A, B, V, a, na, b, nb, tree, olo, ohi, everts, envert, on, od, pad, skip_a,
                  skip_b, axes, lo, hi, m, budget, stack):
    """The first occluder (an id) found in the tight shaft of polygons a and b of V (A, B their
    boxes; axes, lo, hi, m: hull_axes') by a walk of the occluder tree (shafts.OccluderTree);
    -1: none (no segment between the two can be blocked); -2: not known within `budget` tree
    nodes. An occluder whose plane holds both polygons on one closed side is none. stack:
    scratch (int64, at least the tree's depth x 2)."""
    ns = 1
    stack[0] = 0
    seen = 0
    while ns > 0:
        ns -= 1
        x = stack[ns]
        seen += 1
        if seen > budget:
            return -2
        if shaft_excludes(A, B, tree.lo, tree.hi, x) or \
                _box_outside_hull(tree.lo, tree.hi, x, axes, lo, hi, m, pad):
            continue
        if tree.left[x] >= 0:
            if ns + 2 > stack.shape[0]:
                return -2
            stack[ns] = tree.left[x]
            stack[ns + 1] = tree.right[x]
            ns += 2
            continue
        for j in range(tree.start[x], tree.end[x]):
            o = tree.order[j]
            if o == skip_a or o == skip_b:
                continue
            if not (same_side_polys(V, a, na, b, nb, on, od, o, pad)
                    or shaft_excludes(A, B, olo, ohi, o)
                    or outside_hull(everts, envert, o, axes, lo, hi, m, pad)):
                return o
    return -1
