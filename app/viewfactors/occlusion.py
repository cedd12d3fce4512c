"""Numba kernels of the view-factor task's visibility (task.py): the search of the facets' tree
for occluders in the shaft between two boxes (the shaft and plane tests are the render's,
tracing/shafts.py) that proves pairs unobstructed, and the jittered stratified sample points,
rays and visible fractions of the pairs that need rays. Small, no I/O, no configuration.

Facet arrays are in the leaf order of the facets' tree; tree arguments are loops.Nodes tuples.
The method: docs/src/design/viewfactors-method.md.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from radiosity.tracing.shafts import same_side_boxes, same_side_polys, shaft_excludes


# ----------------------------------------------------------------------------- shafts

@numba.njit(cache=True, nogil=True, inline="always")
def _box_of(lo, hi, x, out):
    """out (2, 3) = the box [lo[x], hi[x]] (the (lo, hi) pair tracing/shafts' tests take)."""
    for k in range(3):
        out[0, k] = lo[x, k]
        out[1, k] = hi[x, k]


@numba.njit(cache=True, nogil=True)
def block_occluders(nodes, flo, fhi, normal, doff, pad, A, B, out):
    """Facets that may cut a segment between boxes A and B ((2, 3): lo, hi): their box enters
    the shaft and their plane does not hold both boxes on one closed side (tracing/shafts:
    shaft_excludes, same_side_boxes). Traversal of the tree `nodes` (loops.Nodes) with the
    shaft test on node boxes. Writes facet ids (leaf order) into out; returns their count."""
    start, end, left, right = nodes.start, nodes.end, nodes.left, nodes.right
    stack = np.empty(512, np.int64)
    stack[0] = nodes.root
    sp = 1
    m = 0
    while sp > 0:
        sp -= 1
        v = stack[sp]
        if shaft_excludes(A, B, nodes.lo, nodes.hi, v):
            continue
        if left[v] >= 0:
            stack[sp] = right[v]
            stack[sp + 1] = left[v]
            sp += 2
            continue
        for o in range(start[v], end[v]):
            if same_side_boxes(A, B, normal, doff, o, pad):
                continue
            if shaft_excludes(A, B, flo, fhi, o):
                continue
            out[m] = o
            m += 1
    return m


@numba.njit(cache=True, nogil=True)
def prove_unobstructed(ia, ib, blk, need, bleaf, aleaf, nodes, verts, nv, flo, fhi, normal, doff,
                       pad, proven):
    """For pairs sorted by block (blk indexes bleaf; all rows in leaf aleaf): proven[p] = True
    when no facet can cut a segment between facets ia[p] and ib[p]. Blocks with a pair that
    needs it (need[p]: pairs that would otherwise take many rays) are tested: a block whose
    shaft holds no candidate at all is proven whole; otherwise each needing pair is proven when
    none of the block's candidates survives the pair's own tests (its plane holds both facets'
    vertices on one closed side, or its box is outside the shaft of the two facets' boxes).
    Returns the number of facet tests made."""
    cand = np.empty(flo.shape[0], np.int64)
    A = np.empty((2, 3))
    B = np.empty((2, 3))
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
        _box_of(nodes.lo, nodes.hi, aleaf, A)
        _box_of(nodes.lo, nodes.hi, bleaf[k], B)
        nc = block_occluders(nodes, flo, fhi, normal, doff, pad, A, B, cand)
        if nc == 0:
            for r in range(p, q):
                proven[r] = True
        else:
            for r in range(p, q):
                if not need[r]:
                    continue
                i, j = ia[r], ib[r]
                _box_of(flo, fhi, i, A)
                _box_of(flo, fhi, j, B)
                ok = True
                for c in range(nc):
                    o = cand[c]
                    if o == i or o == j:
                        continue
                    tests += 1
                    if same_side_polys(verts, i, nv[i], j, nv[j], normal, doff, o, pad):
                        continue
                    if shaft_excludes(A, B, flo, fhi, o):
                        continue
                    ok = False
                    break
                proven[r] = ok
        p = q
    return tests


# ----------------------------------------------------------------------------- sampling

@numba.njit(cache=True, nogil=True, inline="always")
def _mix(z):
    """splitmix64 finaliser (uint64 -> uint64)."""
    z = z + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True, nogil=True, inline="always")
def _u01(seed, facet, s, cell, comp):
    """A uniform double in [0, 1) that depends only on its arguments (counter-based)."""
    z = _mix(np.uint64(seed) ^ np.uint64(0x5851F42D4C957F2D))
    z = _mix(z ^ np.uint64(facet))
    z = _mix(z ^ (np.uint64(s) << np.uint64(40)) ^ (np.uint64(cell) << np.uint64(2))
             ^ np.uint64(comp))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, nogil=True, inline="always")
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


@numba.njit(cache=True, nogil=True)
def sample_facets(fids, key, s, seed, verts, nv, center, area, pts, w):
    """Jittered stratified points of facets fids (leaf order): s * s per facet, pts
    (len(fids) * s * s, 3), weights w (same count; each facet's sum to 1 in expectation).

    Triangles: one uniform point in each of the s^2 congruent sub-triangles of the regular
    subdivision, weight 1 / s^2. Quads: one point in each cell of an s x s grid of the bilinear
    map, weight = its Jacobian / (s^2 area) (unbiased for any planar convex quad). s = 1: the
    centroid (measured: one random point instead doubles the rows' errors on the urban scene of
    benchmarks/bench_viewfactors.py). The jitter depends on (seed, key[t], s, cell) only, so
    every task draws the same points: task.py keys them by the pair (both facets' original
    ids), so that a facet's points differ from pair to pair and their errors do not add up
    over its row (docs/src/design/viewfactors-method.md, "Sampled visibility")."""
    S = s * s
    for t in range(fids.shape[0]):
        f = fids[t]
        base = t * S
        if s == 1:
            for k in range(3):
                pts[base, k] = center[f, k]
            w[base] = 1.0
            continue
        g = key[t]
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


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
def visible_fraction(ptr, term, vis, expect, phi):
    """phi[p], the visible fraction of pair p from its rays ptr[p]:ptr[p + 1] (terms t,
    visibilities V), NaN when it has none. expect[p] = E[sum t] = pi F_ij / A_j, known exactly
    from the unobstructed factor, is a control variate: phi = (sum t V + b (expect - sum t))
    / expect, b the regression slope of t V on t over the pair's rays (clipped to [0, 1]),
    phi clipped to [0, 1]. Where the terms are spiky (facets that touch: the kernel grows as
    1 / r^2 toward their common edge) and the spike is visible, b ~ 1 and only the blocked rays
    add noise, where the ratio sum t V / sum t carries the spike's noise into every partly
    blocked pair. All rays visible or all blocked give exactly 1 or 0, as the ratio did.
    expect[p] <= 0: the ratio."""
    for p in range(ptr.shape[0] - 1):
        tot = 0.0
        seen = 0.0
        for r in range(ptr[p], ptr[p + 1]):
            tot += term[r]
            if vis[r]:
                seen += term[r]
        if tot <= 0.0:
            phi[p] = np.nan
            continue
        e = expect[p]
        if e <= 0.0 or seen == 0.0 or seen == tot:
            phi[p] = seen / tot
            continue
        k = ptr[p + 1] - ptr[p]
        mt = tot / k
        mv = seen / k
        sxy = 0.0
        sxx = 0.0
        for r in range(ptr[p], ptr[p + 1]):
            dx = term[r] - mt
            sxx += dx * dx
            sxy += dx * ((term[r] if vis[r] else 0.0) - mv)
        b = min(max(sxy / sxx, 0.0), 1.0) if sxx > 0.0 else 1.0
        phi[p] = min(max((seen + b * (e - tot)) / e, 0.0), 1.0)
