"""The solver's pass loops (numba): y += F L over the bit-packed visibility tiles, with the form
factors recomputed on the fly (kernels.py), and one block Gauss-Seidel sweep.

Arrays are structure-of-arrays so the inner loop vectorises: L and y are (2, 3, m) float64
[side, channel, sub-element]; the bit layout of a tile is in plan.py.

The sub-element arrays travel as the namedtuples below (numba unpacks them at compile time, no
cost): `Geometry`, `Caps` and `Samples`, built once per call on the driver (transport.py).
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from radiosity.core.kernels import NXM, kernel_ff, facing_signs, pair_sampled, sampled_sum

from radiosity.methods.base import CAP_MIN, CAP_PRODUCT  # noqa: F401  (CAP_PRODUCT: re-exported)

BOTH, ROWS, COLS = 0, 1, 2  # which directions of a tile a pass applies

# centres, normals (components) and areas of the sub-elements, (m,) float64 each
Geometry = namedtuple("Geometry", "cx cy cz nx ny nz area")
# the row normalisation: cap (m,) float64 and cmode (CAP_MIN or CAP_PRODUCT, int); a pair's form
# factors are scaled by _scale(cmode, cap_a, cap_b)
Caps = namedtuple("Caps", "cap cmode")
# the sample points and weights of the sampled kernels (kernels.sample_points; (m, 0, 3) and
# (m, 0) for the others)
Samples = namedtuple("Samples", "pts w")


@numba.njit(cache=True, nogil=True, inline="always")
def _scale(cmode, ca, cb):
    return min(ca, cb) if cmode == CAP_MIN else ca * cb


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _row_fast(kid, mask, row, la, C, cols, cap, cmode, L, y, mode):
    """One row of a tile where neither element is two-sided: every visible pair is front-front
    (ca > 0 and cb > 0), so the loop is branch-free over the columns and vectorises. row: the
    row element's (x, y, z, nx, ny, nz, area, cap); la: its L (3 channels, front side). Column
    arrays (cols: the Geometry's seven, cap; L, y: 3 channels of the front side) are slices
    starting at the tile's first column (no negative-index checks) and error_model="numpy"
    drops the division-by-zero check: both are needed for SIMD.
    Returns the row's sums (F_ab L_b over the columns)."""
    ax, ay, az, anx, any_, anz, aa, capa = row
    la0, la1, la2 = la
    cx, cy, cz, nx, ny, nz, area = cols
    L0, L1, L2 = L
    y0, y1, y2 = y
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for c in range(C):
        dx = cx[c] - ax
        dy = cy[c] - ay
        dz = cz[c] - az
        r2 = dx * dx + dy * dy + dz * dz + 1e-300
        g = -mask[c] * (anx * dx + any_ * dy + anz * dz) * (nx[c] * dx + ny[c] * dy + nz[c] * dz)
        g *= _scale(cmode, capa, cap[c])
        if kid == 0:  # point: one division serves both directions
            w = g / (np.pi * r2 * r2)
            fab = w * area[c]
            fba = w * aa
        else:
            fab = kernel_ff(kid, g, r2, area[c])
            fba = kernel_ff(kid, g, r2, aa)
        if mode != COLS:
            s0 += fab * L0[c]
            s1 += fab * L1[c]
            s2 += fab * L2[c]
        if mode != ROWS:
            y0[c] += fba * la0
            y1[c] += fba * la1
            y2[c] += fba * la2
    return s0, s1, s2


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _row_fast1(kid, mask, row, la0, C, cols, cap, cmode, L0, y0, mode):
    """_row_fast for one channel (grey scenes, effects.py): la0, L0, y0 that channel."""
    ax, ay, az, anx, any_, anz, aa, capa = row
    cx, cy, cz, nx, ny, nz, area = cols
    s0 = 0.0
    for c in range(C):
        dx = cx[c] - ax
        dy = cy[c] - ay
        dz = cz[c] - az
        r2 = dx * dx + dy * dy + dz * dz + 1e-300
        g = -mask[c] * (anx * dx + any_ * dy + anz * dz) * (nx[c] * dx + ny[c] * dy + nz[c] * dz)
        g *= _scale(cmode, capa, cap[c])
        if mode != COLS:
            s0 += kernel_ff(kid, g, r2, area[c]) * L0[c]
        if mode != ROWS:
            y0[c] += kernel_ff(kid, g, r2, aa) * la0
    return s0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _row_sided(kid, mask, a, b0, C, geo, caps, L, y, mode):
    """One row of a tile with a two-sided element: each pair picks the sides that face."""
    cx, cy, cz, nx, ny, nz, area = geo
    cap, cmode = caps
    for c in range(C):
        if mask[c] == 0.0:
            continue
        b = b0 + c
        dx = cx[b] - cx[a]
        dy = cy[b] - cy[a]
        dz = cz[b] - cz[a]
        r2 = max(dx * dx + dy * dy + dz * dz, 1e-300)
        ca = nx[a] * dx + ny[a] * dy + nz[a] * dz
        cb = -(nx[b] * dx + ny[b] * dy + nz[b] * dz)
        sa = 0 if ca > 0 else 1
        sb = 0 if cb > 0 else 1
        g = abs(ca * cb) * _scale(cmode, cap[a], cap[b])
        if mode != COLS:
            fab = kernel_ff(kid, g, r2, area[b])
            for k in range(L.shape[1]):
                y[sa, k, a] += fab * L[sb, k, b]
        if mode != ROWS:
            fba = kernel_ff(kid, g, r2, area[a])
            for k in range(L.shape[1]):
                y[sb, k, b] += fba * L[sa, k, a]


@numba.njit(cache=True, nogil=True, inline="always")
def _add_pair_sampled(kid, a, b, f, to_a, to_b, geo, caps, smp, L, y):
    """y += f F L for pair (a, b) of a sampled kernel: into a (if to_a) and into b (if to_b)."""
    cx, cy, cz, nx, ny, nz, area = geo
    cap, cmode = caps
    pts, w = smp
    acc, ia, ib = pair_sampled(kid, a, b, cx, cy, cz, nx, ny, nz, pts, w)
    acc *= f * _scale(cmode, cap[a], cap[b])
    if to_a:
        for k in range(L.shape[1]):
            y[ia, k, a] += acc * area[b] * L[ib, k, b]
    if to_b:
        for k in range(L.shape[1]):
            y[ib, k, b] += acc * area[a] * L[ia, k, a]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _row_sampled(kid, mask, a, b0, C, geo, caps, smp, L, y, mode):
    """One row of a tile for the sampled kernels (nxm, mc): S or S^2 point kernels per pair.
    Written out rather than through _add_pair_sampled: this is the hot loop, and the shared
    helper was slower (docs/src/measurements/choices.md)."""
    cx, cy, cz, nx, ny, nz, area = geo
    cap, cmode = caps
    pts, w = smp
    for c in range(C):
        if mask[c] == 0.0:
            continue
        b = b0 + c
        sa, sb = facing_signs(cx, cy, cz, nx, ny, nz, a, b)
        acc = sampled_sum(kid, pts[a], w[a], pts[b], w[b], sa * nx[a], sa * ny[a], sa * nz[a],
                       sb * nx[b], sb * ny[b], sb * nz[b])
        acc *= _scale(cmode, cap[a], cap[b])
        ia = 0 if sa > 0 else 1
        ib = 0 if sb > 0 else 1
        if mode != COLS:
            fab = acc * area[b]
            for k in range(L.shape[1]):
                y[ia, k, a] += fab * L[ib, k, b]
        if mode != ROWS:
            fba = acc * area[a]
            for k in range(L.shape[1]):
                y[ib, k, b] += fba * L[ia, k, a]


@numba.njit(cache=True, nogil=True)
def partial_apply(kid, pairs, phi, geo, caps, smp, L, y, orig, need):
    """y += (phi - 1) F L over the partly visible pairs of one visibility task (pairs (k, 3)
    [a, b, visible rays], phi (k,)): the pass counted them whole, the kernel with a visibility
    term per sample pair is phi times that. geo, caps, smp: Geometry, Caps, Samples. Rows whose
    original does not gather (need False; empty = all) are left alone. Returns the number of
    pair terms."""
    use_need = need.shape[0] > 0
    for q in range(pairs.shape[0]):
        a, b = pairs[q, 0], pairs[q, 1]
        _add_pair_sampled(kid, a, b, phi[q] - 1.0, not use_need or need[orig[a]],
                          not use_need or need[orig[b]], geo, caps, smp, L, y)
    return 2 * pairs.shape[0]


@numba.njit(cache=True, nogil=True)
def tile_apply(kid, packed, R, C, a0, b0, geo, caps, sided, smp, L, y, mode, row_live, col_live):
    """y += F L over one tile: rows a0..a0+R against columns b0..b0+C, bits packed row-major,
    little-endian (see plan.py). mode BOTH applies F_ab (into rows) and F_ba (into columns);
    ROWS or COLS only one direction (Gauss-Seidel). row_live / col_live: skip the direction
    whose source is all zero (progressive shooting). geo: the Geometry; caps: the Caps (cap (m,),
    cmode: a pair's form factors are scaled by _scale(cmode, cap_a, cap_b), row normalisation
    that keeps reciprocity); sided (m,) bool; smp: the Samples of the sampled kernels. Returns
    the number of pair terms.
    """
    cx, cy, cz, nx, ny, nz, area = geo
    cap, cmode = caps
    mask = np.zeros(C, np.float64)
    b1 = b0 + C
    any_sided_cols = False
    for c in range(C):
        if sided[b0 + c]:
            any_sided_cols = True
            break
    m = mode
    if not row_live and not col_live:
        return 0
    if not row_live:  # rows' sources (columns' L) are zero: only F_ba L_a matters
        m = COLS if mode != ROWS else -1
    elif not col_live:
        m = ROWS if mode != COLS else -1
    if m == -1:
        return 0
    terms = 0
    for r in range(R):
        base = r * C
        cnt = 0
        for c in range(C):
            k = base + c
            v = (packed[k >> 3] >> (k & 7)) & 1
            mask[c] = v
            cnt += v
        if cnt == 0:
            continue
        terms += cnt * (2 if m == BOTH else 1)
        a = a0 + r
        if kid >= NXM:
            _row_sampled(kid, mask, a, b0, C, geo, caps, smp, L, y, m)
        elif sided[a] or any_sided_cols:
            _row_sided(kid, mask, a, b0, C, geo, caps, L, y, m)
        elif L.shape[1] == 1:
            y[0, 0, a] += _row_fast1(kid, mask, (cx[a], cy[a], cz[a], nx[a], ny[a], nz[a], area[a],
                                                 cap[a]), L[0, 0, a], C,
                                     (cx[b0:b1], cy[b0:b1], cz[b0:b1], nx[b0:b1], ny[b0:b1],
                                      nz[b0:b1], area[b0:b1]), cap[b0:b1], cmode,
                                     L[0, 0, b0:b1], y[0, 0, b0:b1], m)
        else:
            s0, s1, s2 = _row_fast(kid, mask, (cx[a], cy[a], cz[a], nx[a], ny[a], nz[a], area[a],
                                               cap[a]), (L[0, 0, a], L[0, 1, a], L[0, 2, a]), C,
                                   (cx[b0:b1], cy[b0:b1], cz[b0:b1], nx[b0:b1], ny[b0:b1],
                                    nz[b0:b1], area[b0:b1]), cap[b0:b1], cmode,
                                   (L[0, 0, b0:b1], L[0, 1, b0:b1], L[0, 2, b0:b1]),
                                   (y[0, 0, b0:b1], y[0, 1, b0:b1], y[0, 2, b0:b1]), m)
            y[0, 0, a] += s0
            y[0, 1, a] += s1
            y[0, 2, a] += s2
    return terms


@numba.njit(cache=True, nogil=True)
def tiles_apply(kid, data, base, tiles, offsets, geo, caps, sided, smp, L, y, mode, live, need):
    """tile_apply over many tiles whose bytes lie in `data` starting at byte `base` (geo, caps,
    sided, smp as in tile_apply).

    tiles (t, 7) int64 as in plan.py; live (n,) bool: originals whose L may be non-zero; need
    (n,) bool: originals that gather (dead rows drop out, effects.py); empty = all. Returns
    the number of pair terms."""
    terms = 0
    use_live = live.shape[0] > 0
    use_need = need.shape[0] > 0
    for k in range(tiles.shape[0]):
        i, j = tiles[k, 0], tiles[k, 1]
        r0, r1, ncols = tiles[k, 2], tiles[k, 3], tiles[k, 4]
        s = tiles[k, 5] - base
        packed = data[s:s + tiles[k, 6]]
        # the rows gather from the columns' sources and the columns from the rows'
        row_live = (live[j] if use_live else True) and (need[i] if use_need else True)
        col_live = (live[i] if use_live else True) and (need[j] if use_need else True)
        terms += tile_apply(kid, packed, r1 - r0, ncols, offsets[i] + r0, offsets[j], geo, caps,
                            sided, smp, L, y, mode, row_live, col_live)
    return terms


@numba.njit(cache=True, nogil=True)
def gs_sweep(kid, data, tiles, index, offsets, geo, caps, sided, smp, L, Le, rho, y, need, sparse):
    """One block Gauss-Seidel sweep (in place on L): for each original e in order, gather
    y_e = sum_J F_eJ L_J from its row tiles (e, J) and the transposed column tiles (J, e) with
    the latest L, then L_e = Le_e + rho_e y_e. `data` holds every tile's bytes at tiles[:, 5];
    index = (row_ptr, row_idx, col_ptr, col_idx) lists the tiles of each original (CSR). geo,
    caps, sided, smp as in tile_apply. Sparse corrections (near field, partial visibility):
    sparse = (sp_ptr, sp_t, sp_s, sp_d) as sparse_by_target makes it; entries
    sp_ptr[e]:sp_ptr[e + 1] add sp_d * L[source] to y[target]; sp_t, sp_s (k, 2) are
    [sub-element, side]."""
    row_ptr, row_idx, col_ptr, col_idx = index
    sp_ptr, sp_t, sp_s, sp_d = sparse
    cap, cmode = caps
    n = offsets.shape[0] - 1
    none = np.zeros(0, np.bool_)
    terms = 0
    for e in range(n):
        if need.shape[0] > 0 and not need[e]:
            continue  # a dead row keeps L = Le
        a0, a1 = offsets[e], offsets[e + 1]
        y[:, :, a0:a1] = 0.0
        for q in range(row_ptr[e], row_ptr[e + 1]):
            k = row_idx[q]
            terms += tiles_apply(kid, data, 0, tiles[k:k + 1], offsets, geo, caps, sided, smp, L,
                                 y, ROWS, none, none)
        for q in range(col_ptr[e], col_ptr[e + 1]):
            k = col_idx[q]
            terms += tiles_apply(kid, data, 0, tiles[k:k + 1], offsets, geo, caps, sided, smp, L,
                                 y, COLS, none, none)
        for q in range(sp_ptr[e], sp_ptr[e + 1]):
            t, s = sp_t[q, 0], sp_s[q, 0]
            f = sp_d[q] * _scale(cmode, cap[t], cap[s])
            for c in range(L.shape[1]):
                y[sp_t[q, 1], c, t] += f * L[sp_s[q, 1], c, s]
        terms += sp_ptr[e + 1] - sp_ptr[e]
        for s in range(2):
            for c in range(L.shape[1]):
                for a in range(a0, a1):
                    L[s, c, a] = Le[s, c, a] + rho[s, c, a] * y[s, c, a]
    return terms


def sparse_by_target(sparse: dict | None, orig: np.ndarray, n: int):
    """Sparse pair corrections {ia, ib, sa, sb, dab, dba} as directed entries grouped by the
    original of their target (for gs_sweep): ptr (n + 1,), t, s (k, 2) [sub-element, side], d (k,)."""
    if sparse is None or len(sparse["ia"]) == 0:
        z = np.zeros((0, 2), np.int64)
        return np.zeros(n + 1, np.int64), z, z, np.zeros(0)
    ia, ib = sparse["ia"].astype(np.int64), sparse["ib"].astype(np.int64)
    sa, sb = sparse["sa"].astype(np.int64), sparse["sb"].astype(np.int64)
    t = np.concatenate([np.stack([ia, sa], 1), np.stack([ib, sb], 1)])
    src = np.concatenate([np.stack([ib, sb], 1), np.stack([ia, sa], 1)])
    d = np.concatenate([sparse["dab"], sparse["dba"]]).astype(np.float64)
    order = np.argsort(orig[t[:, 0]], kind="stable")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(orig[t[:, 0]], minlength=n))]).astype(np.int64)
    return ptr, np.ascontiguousarray(t[order]), np.ascontiguousarray(src[order]), d[order]
