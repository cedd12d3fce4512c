"""Form-factor kernels (SPEC §2), evaluated on the fly inside the solver's pair loop.

Only the visibility bit is stored (seed §2.2, remark); every pass recomputes F from the
sub-elements' centres, normals and areas. For a visible pair (a, b) with d = c_b - c_a,
r2 = |d|^2, ca = n_a . d and cb = -n_b . d (so cos_a = ca / r, cos_b = cb / r):

    point (seed eq. 6, corrected):  F_ab = A_b |ca cb| / (pi r2^2)
    disc  (Wallace et al. 1989):    F_ab = A_b |ca cb| / r2 / (pi r2 + A_b)

Radiance lives per side: the side of a that b sees is 0 (front) if ca > 0 else 1 (back).
Arrays are structure-of-arrays so the inner loop vectorises: L and y are (2, 3, m) float64
[side, channel, sub-element].
"""

from __future__ import annotations

import numba
import numpy as np

from .errors import RadiosityError

# name -> (id used by the numba loop, one line for --help, reciprocal: A_a F_ab == A_b F_ba,
#          near field: pairs closer than a few element sizes get the exact form factor)
KERNELS = {
    "point": (0, "one ray between centres, F = A cos cos / (pi r^2) (seed eq. 6)", True, False),
    "disc": (1, "the receiver as a disc of its area, F = A cos cos / (pi r^2 + A) (2nd seed)", False, False),
    "point-nf": (0, "point, with exact polygon form factors in the near field (nearfield.py)", True, True),
    "disc-nf": (1, "disc, with exact polygon form factors in the near field", False, True),
}

BOTH, ROWS, COLS = 0, 1, 2  # which directions of a tile a pass applies


def kernel_id(name: str) -> int:
    """The registry id of kernel `name`; an unknown name lists the valid ones."""
    try:
        return KERNELS[name][0]
    except KeyError:
        raise RadiosityError(f"unknown kernel {name!r}: use one of {', '.join(KERNELS)}") from None


@numba.njit(cache=True, inline="always", error_model="numpy")
def _f(kid, g, r2, area):
    """Form factor towards an element of `area`, from g = |ca cb| (unnormalised cosines)."""
    if kid == 0:
        return area * g / (np.pi * r2 * r2)
    return area * g / r2 / (np.pi * r2 + area)


@numba.njit(cache=True, fastmath=True, error_model="numpy")
def _row_fast(kid, mask, ax, ay, az, anx, any_, anz, aa, capa, la0, la1, la2, C, cx, cy, cz, nx,
              ny, nz, area, cap, L0, L1, L2, y0, y1, y2, mode):
    """One row of a tile where neither element is two-sided: every visible pair is front-front
    (ca > 0 and cb > 0), so the loop is branch-free over the columns and vectorises. Column
    arrays are slices starting at the tile's first column (no negative-index checks) and
    error_model="numpy" drops the division-by-zero check: both are needed for SIMD.
    Returns the row's sums (F_ab L_b over the columns)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for c in range(C):
        dx = cx[c] - ax
        dy = cy[c] - ay
        dz = cz[c] - az
        r2 = dx * dx + dy * dy + dz * dz + 1e-300
        g = -mask[c] * (anx * dx + any_ * dy + anz * dz) * (nx[c] * dx + ny[c] * dy + nz[c] * dz)
        g *= min(capa, cap[c]) if capa > 0 else capa * cap[c]
        if kid == 0:  # point: one division serves both directions
            w = g / (np.pi * r2 * r2)
            fab = w * area[c]
            fba = w * aa
        else:
            fab = _f(kid, g, r2, area[c])
            fba = _f(kid, g, r2, aa)
        if mode != COLS:
            s0 += fab * L0[c]
            s1 += fab * L1[c]
            s2 += fab * L2[c]
        if mode != ROWS:
            y0[c] += fba * la0
            y1[c] += fba * la1
            y2[c] += fba * la2
    return s0, s1, s2


@numba.njit(cache=True, fastmath=True, error_model="numpy")
def _row_fast1(kid, mask, ax, ay, az, anx, any_, anz, aa, capa, la0, C, cx, cy, cz, nx, ny, nz,
               area, cap, L0, y0, mode):
    """_row_fast for one channel (grey scenes, planner.py)."""
    s0 = 0.0
    for c in range(C):
        dx = cx[c] - ax
        dy = cy[c] - ay
        dz = cz[c] - az
        r2 = dx * dx + dy * dy + dz * dz + 1e-300
        g = -mask[c] * (anx * dx + any_ * dy + anz * dz) * (nx[c] * dx + ny[c] * dy + nz[c] * dz)
        g *= min(capa, cap[c]) if capa > 0 else capa * cap[c]
        if mode != COLS:
            s0 += _f(kid, g, r2, area[c]) * L0[c]
        if mode != ROWS:
            y0[c] += _f(kid, g, r2, aa) * la0
    return s0


@numba.njit(cache=True, error_model="numpy")
def _row_sided(kid, mask, a, b0, C, cx, cy, cz, nx, ny, nz, area, cap, L, y, mode):
    """One row of a tile with a two-sided element: each pair picks the sides that face."""
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
        g = abs(ca * cb) * (min(cap[a], cap[b]) if cap[a] > 0 else cap[a] * cap[b])
        if mode != COLS:
            fab = _f(kid, g, r2, area[b])
            for k in range(L.shape[1]):
                y[sa, k, a] += fab * L[sb, k, b]
        if mode != ROWS:
            fba = _f(kid, g, r2, area[a])
            for k in range(L.shape[1]):
                y[sb, k, b] += fba * L[sa, k, a]


@numba.njit(cache=True)
def tile_apply(kid, packed, R, C, a0, b0, cx, cy, cz, nx, ny, nz, area, cap, sided, L, y, mode,
               row_live, col_live):
    """y += F L over one tile: rows a0..a0+R against columns b0..b0+C, bits packed row-major,
    little-endian (see plan.py). mode BOTH applies F_ab (into rows) and F_ba (into columns);
    ROWS or COLS only one direction (Gauss-Seidel). row_live / col_live: skip the direction
    whose source is all zero (progressive shooting). cap (m,): a pair's form factors are scaled
    by min(cap_a, cap_b) (row normalisation that keeps reciprocity; 1 = none); negative caps
    (all of them: the "closed" normalisation) scale by the product cap_a cap_b instead. Returns
    the number of pair terms.
    """
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
        if sided[a] or any_sided_cols:
            _row_sided(kid, mask, a, b0, C, cx, cy, cz, nx, ny, nz, area, cap, L, y, m)
        elif L.shape[1] == 1:
            y[0, 0, a] += _row_fast1(kid, mask, cx[a], cy[a], cz[a], nx[a], ny[a], nz[a], area[a],
                                     cap[a], L[0, 0, a], C, cx[b0:b1], cy[b0:b1], cz[b0:b1],
                                     nx[b0:b1], ny[b0:b1], nz[b0:b1], area[b0:b1], cap[b0:b1],
                                     L[0, 0, b0:b1], y[0, 0, b0:b1], m)
        else:
            s0, s1, s2 = _row_fast(kid, mask, cx[a], cy[a], cz[a], nx[a], ny[a], nz[a], area[a],
                                   cap[a], L[0, 0, a], L[0, 1, a], L[0, 2, a], C, cx[b0:b1],
                                   cy[b0:b1], cz[b0:b1], nx[b0:b1], ny[b0:b1], nz[b0:b1],
                                   area[b0:b1], cap[b0:b1], L[0, 0, b0:b1], L[0, 1, b0:b1], L[0, 2, b0:b1], y[0, 0, b0:b1],
                                   y[0, 1, b0:b1], y[0, 2, b0:b1], m)
            y[0, 0, a] += s0
            y[0, 1, a] += s1
            y[0, 2, a] += s2
    return terms


def base_kernel(name: str) -> str:
    """The centre-to-centre kernel under a near-field variant ("point-nf" -> "point")."""
    kernel_id(name)
    return name[:-3] if name.endswith("-nf") else name


def pair_form_factors(kernel: str, ca_pts, na, aa, cb_pts, nb, ab):
    """F_ab and F_ba for arrays of pairs (numpy, for tests and studies): returns two (k,) arrays."""
    kid = kernel_id(kernel)
    d = cb_pts - ca_pts
    r2 = np.einsum("ij,ij->i", d, d)
    g = np.abs(np.einsum("ij,ij->i", na, d) * np.einsum("ij,ij->i", nb, d))
    if kid == 0:
        return ab * g / (np.pi * r2 * r2), aa * g / (np.pi * r2 * r2)
    return ab * g / r2 / (np.pi * r2 + ab), aa * g / r2 / (np.pi * r2 + aa)


@numba.njit(cache=True)
def tiles_apply(kid, data, base, tiles, offsets, cx, cy, cz, nx, ny, nz, area, cap, sided, L, y,
                mode, live, need):
    """tile_apply over many tiles whose bytes lie in `data` starting at byte `base`.

    tiles (t, 7) int64 as in plan.py; live (n,) bool: originals whose L may be non-zero; need
    (n,) bool: originals that gather (dead rows drop out, planner.py); empty = all. Returns
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
        terms += tile_apply(kid, packed, r1 - r0, ncols, offsets[i] + r0, offsets[j], cx, cy, cz,
                            nx, ny, nz, area, cap, sided, L, y, mode, row_live, col_live)
    return terms


@numba.njit(cache=True)
def gs_sweep(kid, data, tiles, row_ptr, row_idx, col_ptr, col_idx, offsets, cx, cy, cz, nx, ny,
             nz, area, cap, sided, L, Le, rho, y, need):
    """One block Gauss-Seidel sweep (in place on L): for each original e in order, gather
    y_e = sum_J F_eJ L_J from its row tiles (e, J) and the transposed column tiles (J, e) with
    the latest L, then L_e = Le_e + rho_e y_e. `data` holds every tile's bytes at tiles[:, 5];
    row_ptr/row_idx and col_ptr/col_idx list the tiles of each original (CSR)."""
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
            terms += tiles_apply(kid, data, 0, tiles[k:k + 1], offsets, cx, cy, cz, nx, ny, nz,
                                 area, cap, sided, L, y, ROWS, none, none)
        for q in range(col_ptr[e], col_ptr[e + 1]):
            k = col_idx[q]
            terms += tiles_apply(kid, data, 0, tiles[k:k + 1], offsets, cx, cy, cz, nx, ny, nz,
                                 area, cap, sided, L, y, COLS, none, none)
        for s in range(2):
            for c in range(L.shape[1]):
                for a in range(a0, a1):
                    L[s, c, a] = Le[s, c, a] + rho[s, c, a] * y[s, c, a]
    return terms
