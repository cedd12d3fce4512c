"""Form-factor kernels (SPEC §2), evaluated on the fly inside the solver's pair loop.

Only the visibility bit is stored (seed §2.2, remark); every pass recomputes F from the
sub-elements' centres, normals and areas. For a visible pair (a, b) with d = c_b - c_a,
r2 = |d|^2, ca = n_a . d and cb = -n_b . d (so cos_a = ca / r, cos_b = cb / r):

    point (seed eq. 6, corrected):  F_ab = A_b |ca cb| / (pi r2^2)
    disc  (Wallace et al. 1989):    F_ab = A_b |ca cb| / r2 / (pi r2 + A_b)
    nxm   (seed §2.2, method 2):    the point kernel averaged over N x N sample pairs
    mc    (Monte Carlo):            the point kernel averaged over k random sample pairs

The two sampled kernels (nxm, mc) put S points with weights w on every sub-element
(`sample_points`) and evaluate, for a visible pair,

    F_ab = A_b / pi * sum_(k, l) w_k w_l c_a c_b / r_kl^4     (nxm: every k, l; N*N rays)
    F_ab = A_b / pi * 1/S sum_s c_a c_b / r_ss^4               (mc: p_s with q_s; S rays)

with c_a = max(0, +-n_a . d_kl) on the side the centres face (a sample pair whose segment
leaves either element's plane on the wrong side adds 0). The weights are the area fractions of the sample cells, 1/N for the
equal cells of triangles and parallelograms: the 1/(N M) the seed's printed formula lacks.
Both are reciprocal (A_a F_ab = A_b F_ba). Their visibility is one ray per sample pair; the bit
says "some sample pair sees", and pairs that are only partly visible keep, sparsely, the
fraction phi = sum w c c V / r^4 / sum w c c / r^4 (visibility.py), so that phi times the
unoccluded sum is exactly the kernel with a visibility term per sample pair.

Radiance lives per side: the side of a that b sees is 0 (front) if ca > 0 else 1 (back).
Arrays are structure-of-arrays so the inner loop vectorises: L and y are (2, 3, m) float64
[side, channel, sub-element].
"""

from __future__ import annotations

from dataclasses import dataclass

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
    "nxm": (2, "point kernel averaged over N x N sample points, N*N rays per pair (seed §2.2)", True, False),
    "mc": (3, "point kernel averaged over k random (seeded) sample pairs, k rays per pair", True, False),
}
NXM, MC = 2, 3


@dataclass(frozen=True)
class Sampling:
    """Where a sampled kernel's points lie: kind "nxm" (n points per element, a square; n*n
    rays per pair) or "mc" (n random points per element, paired: n rays per pair)."""
    kind: str
    n: int
    seed: int = 0

    @property
    def rays_per_pair(self) -> int:
        return self.n * self.n if self.kind == "nxm" else self.n

    def to_dict(self) -> dict:
        return {"kind": self.kind, "n": self.n, "seed": self.seed}

    def describe(self) -> str:
        if self.kind == "nxm":
            return f"{self.n} points per element ({self.rays_per_pair} rays per pair)"
        return f"{self.n} random sample pairs (seed {self.seed})"


def sampling_of(kernel: str, points: int | None = None, samples: int | None = None,
                seed: int | None = None) -> Sampling | None:
    """The sample points kernel `kernel` needs (None: one ray between centres), from
    radiosity.solve.nxm-points / mc-samples / mc-seed unless given."""
    from . import config

    kid = kernel_id(kernel)
    if kid == NXM:
        n = int(config.get("solve.nxm-points", points))
        if n < 1 or int(round(np.sqrt(n))) ** 2 != n:
            raise RadiosityError(f"radiosity.solve.nxm-points must be a square (1, 4, 9, 16, ...), got {n}")
        return Sampling("nxm", n)
    if kid == MC:
        n = int(config.get("solve.mc-samples", samples))
        if n < 1:
            raise RadiosityError(f"radiosity.solve.mc-samples must be at least 1, got {n}")
        return Sampling("mc", n, int(config.get("solve.mc-seed", seed)))
    return None


def _tri_area(a, b, c):
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=-1)


def sample_points(verts: np.ndarray, nverts: np.ndarray, sampling: Sampling | None):
    """Sample points (m, S, 3) and weights (m, S) of polygons verts (m, 4, 3), nverts (m,).

    nxm: n = s^2 cell centres: triangles in s^2 equal sub-triangles (the regular subdivision),
    quads in an s x s grid of the bilinear map (weights: cell areas / area, exact for planar
    quads). mc: n points uniform by area from numpy's seeded generator (weights 1/n).
    None: no samples, (m, 0, 3)."""
    m = len(verts)
    if sampling is None:
        return np.zeros((m, 0, 3)), np.zeros((m, 0))
    v0, v1, v2, v3 = (verts[:, k][:, None, :] for k in range(4))
    tri = (nverts == 3)[:, None, None]
    if sampling.kind == "mc":
        rng = np.random.default_rng([sampling.seed, m])
        u = rng.random((m, sampling.n, 3))
        a1 = _tri_area(verts[:, 0], verts[:, 1], verts[:, 2])
        a2 = np.where(nverts == 4, _tri_area(verts[:, 0], verts[:, 2], verts[:, 3]), 0.0)
        second = u[:, :, 2] * (a1 + a2)[:, None] >= a1[:, None]  # which triangle of a quad
        b, c = np.where(second[..., None], v2, v1), np.where(second[..., None], v3, v2)
        su = np.sqrt(u[:, :, 0])[..., None]
        pts = v0 + su * (1 - u[:, :, 1:2]) * (b - v0) + su * u[:, :, 1:2] * (c - v0)
        return np.ascontiguousarray(pts), np.full((m, sampling.n), 1.0 / sampling.n)
    s = int(round(np.sqrt(sampling.n)))
    # triangle: barycentric (u, v) of the centroids of the s^2 sub-triangles
    tu, tv = [], []
    for i in range(s):
        for j in range(s - i):
            tu.append((i + 1 / 3) / s)
            tv.append((j + 1 / 3) / s)
            if i + j <= s - 2:
                tu.append((i + 2 / 3) / s)
                tv.append((j + 2 / 3) / s)
    tu, tv = np.array(tu)[None, :, None], np.array(tv)[None, :, None]
    tpts = v0 + tu * (v1 - v0) + tv * (v2 - v0)
    # quad: the bilinear map of an s x s grid, weights from the cells' areas
    g = np.arange(s + 1) / s

    def bil(u, v):
        u, v = u[None, :, None], v[None, :, None]
        return (1 - u) * (1 - v) * v0 + u * (1 - v) * v1 + u * v * v2 + (1 - u) * v * v3

    cu, cv = np.meshgrid((np.arange(s) + 0.5) / s, (np.arange(s) + 0.5) / s, indexing="ij")
    qpts = bil(cu.ravel(), cv.ravel())
    iu, iv = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    iu, iv = iu.ravel(), iv.ravel()
    c00, c10 = bil(g[iu], g[iv]), bil(g[iu + 1], g[iv])
    c11, c01 = bil(g[iu + 1], g[iv + 1]), bil(g[iu], g[iv + 1])
    qa = _tri_area(c00, c10, c11) + _tri_area(c00, c11, c01)
    qw = qa / np.maximum(qa.sum(axis=1, keepdims=True), 1e-300)
    pts = np.where(tri, tpts, qpts)
    w = np.where(tri[:, :, 0], 1.0 / sampling.n, qw)
    return np.ascontiguousarray(pts), np.ascontiguousarray(w)


@numba.njit(cache=True, inline="always", error_model="numpy", fastmath=True)
def _term(p, q, nax, nay, naz, nbx, nby, nbz):
    """c_a c_b / r^4 of the sample pair p -> q (points (3,)), 0 where either cosine is not > 0."""
    dx = q[0] - p[0]
    dy = q[1] - p[1]
    dz = q[2] - p[2]
    r2 = dx * dx + dy * dy + dz * dz + 1e-300
    ca = max(nax * dx + nay * dy + naz * dz, 0.0)
    cb = max(-(nbx * dx + nby * dy + nbz * dz), 0.0)
    return ca * cb / (r2 * r2)


@numba.njit(cache=True, inline="always", error_model="numpy", fastmath=True)
def _sampled(kid, pa, wa, pb, wb, nax, nay, naz, nbx, nby, nbz):
    """sum over the sample pairs of w c_a c_b / r^4 / pi (unoccluded), the normals already
    turned to the sides that face (see the module docstring)."""
    acc = 0.0
    S = pa.shape[0]
    if kid == NXM:
        for k in range(S):
            for l in range(S):
                acc += wa[k] * wb[l] * _term(pa[k], pb[l], nax, nay, naz, nbx, nby, nbz)
    else:
        for s in range(S):
            acc += _term(pa[s], pb[s], nax, nay, naz, nbx, nby, nbz)
        acc /= S
    return acc / np.pi


@numba.njit(cache=True, inline="always")
def _facing_signs(cx, cy, cz, nx, ny, nz, a, b):
    """+1 / -1: the side of a that b's centre lies on, and of b that a's lies on."""
    dx = cx[b] - cx[a]
    dy = cy[b] - cy[a]
    dz = cz[b] - cz[a]
    sa = 1.0 if nx[a] * dx + ny[a] * dy + nz[a] * dz > 0 else -1.0
    sb = 1.0 if -(nx[b] * dx + ny[b] * dy + nz[b] * dz) > 0 else -1.0
    return sa, sb

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


@numba.njit(cache=True, inline="always")
def _pair_sampled(kid, a, b, cx, cy, cz, nx, ny, nz, pts, w):
    """The unoccluded sampled kernel of pair (a, b) without the area (F_ab = A_b acc, F_ba =
    A_a acc) and the sides (0 front, 1 back) the centres face."""
    sa, sb = _facing_signs(cx, cy, cz, nx, ny, nz, a, b)
    acc = _sampled(kid, pts[a], w[a], pts[b], w[b], sa * nx[a], sa * ny[a], sa * nz[a],
                   sb * nx[b], sb * ny[b], sb * nz[b])
    return acc, 0 if sa > 0 else 1, 0 if sb > 0 else 1


@numba.njit(cache=True, inline="always")
def _add_pair_sampled(kid, a, b, f, to_a, to_b, cx, cy, cz, nx, ny, nz, area, cap, pts, w, L, y):
    """y += f F L for pair (a, b) of a sampled kernel: into a (if to_a) and into b (if to_b)."""
    acc, ia, ib = _pair_sampled(kid, a, b, cx, cy, cz, nx, ny, nz, pts, w)
    acc *= f * (min(cap[a], cap[b]) if cap[a] > 0 else cap[a] * cap[b])
    if to_a:
        for k in range(L.shape[1]):
            y[ia, k, a] += acc * area[b] * L[ib, k, b]
    if to_b:
        for k in range(L.shape[1]):
            y[ib, k, b] += acc * area[a] * L[ia, k, a]


@numba.njit(cache=True, error_model="numpy")
def _row_sampled(kid, mask, a, b0, C, cx, cy, cz, nx, ny, nz, area, cap, pts, w, L, y, mode):
    """One row of a tile for the sampled kernels (nxm, mc): S or S^2 point kernels per pair.
    Written out rather than through _add_pair_sampled: this is the hot loop, and the shared
    helper measured 19 % slower here (14.0 against 17.2 M pair terms/s, nxm, one core)."""
    for c in range(C):
        if mask[c] == 0.0:
            continue
        b = b0 + c
        sa, sb = _facing_signs(cx, cy, cz, nx, ny, nz, a, b)
        acc = _sampled(kid, pts[a], w[a], pts[b], w[b], sa * nx[a], sa * ny[a], sa * nz[a],
                       sb * nx[b], sb * ny[b], sb * nz[b])
        acc *= min(cap[a], cap[b]) if cap[a] > 0 else cap[a] * cap[b]
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


@numba.njit(cache=True)
def sampled_pairs(kid, pts, w, cx, cy, cz, nx, ny, nz, ia, ib):
    """The unoccluded sampled kernel of pairs (ia, ib) without the area: F_ab = A_b acc[k]
    (and F_ba = A_a acc[k]), and the sides sa, sb (k,) int8 the centres face."""
    acc = np.empty(ia.shape[0])
    sa = np.empty(ia.shape[0], np.int8)
    sb = np.empty(ia.shape[0], np.int8)
    for k in range(ia.shape[0]):
        acc[k], sa[k], sb[k] = _pair_sampled(kid, ia[k], ib[k], cx, cy, cz, nx, ny, nz, pts, w)
    return acc, sa, sb


@numba.njit(cache=True)
def partial_apply(kid, pairs, phi, pts, w, cx, cy, cz, nx, ny, nz, area, cap, L, y, orig, need):
    """y += (phi - 1) F L over the partly visible pairs of one visibility task (pairs (k, 3)
    [a, b, visible rays], phi (k,)): the pass counted them whole, the kernel with a visibility
    term per sample pair is phi times that. Rows whose original does not gather (need False;
    empty = all) are left alone. Returns the number of pair terms."""
    use_need = need.shape[0] > 0
    for q in range(pairs.shape[0]):
        a, b = pairs[q, 0], pairs[q, 1]
        _add_pair_sampled(kid, a, b, phi[q] - 1.0, not use_need or need[orig[a]],
                          not use_need or need[orig[b]], cx, cy, cz, nx, ny, nz, area, cap, pts, w,
                          L, y)
    return 2 * pairs.shape[0]


@numba.njit(cache=True, error_model="numpy")
def sample_rays(kid, pts, w, center, normal, ia, ib):
    """The sample pairs of pairs (ia, ib), in the order the kernel sums them: the flat sample
    indices of both ends (into pts.reshape(-1, 3)), (k * P,) each, and each sample pair's term
    w c_a c_b / r^4, (k, P) (P = S^2 for nxm, S for mc)."""
    S = pts.shape[1]
    P = S * S if kid == NXM else S
    k = ia.shape[0]
    ra = np.empty(k * P, np.int64)
    rb = np.empty(k * P, np.int64)
    term = np.empty((k, P))
    cx, cy, cz = center[:, 0], center[:, 1], center[:, 2]
    nx, ny, nz = normal[:, 0], normal[:, 1], normal[:, 2]
    for q in range(k):
        a, b = ia[q], ib[q]
        sa, sb = _facing_signs(cx, cy, cz, nx, ny, nz, a, b)
        for p in range(P):
            ka = p // S if kid == NXM else p
            kb = p % S if kid == NXM else p
            ra[q * P + p] = a * S + ka
            rb[q * P + p] = b * S + kb
            wt = w[a, ka] * w[b, kb] if kid == NXM else 1.0
            term[q, p] = wt * _term(pts[a, ka], pts[b, kb], sa * nx[a], sa * ny[a], sa * nz[a],
                                    sb * nx[b], sb * ny[b], sb * nz[b])
    return ra, rb, term


@numba.njit(cache=True)
def tile_apply(kid, packed, R, C, a0, b0, cx, cy, cz, nx, ny, nz, area, cap, sided, pts, w, L, y,
               mode, row_live, col_live):
    """y += F L over one tile: rows a0..a0+R against columns b0..b0+C, bits packed row-major,
    little-endian (see plan.py). mode BOTH applies F_ab (into rows) and F_ba (into columns);
    ROWS or COLS only one direction (Gauss-Seidel). row_live / col_live: skip the direction
    whose source is all zero (progressive shooting). cap (m,): a pair's form factors are scaled
    by min(cap_a, cap_b) (row normalisation that keeps reciprocity; 1 = none); negative caps
    (all of them: the "closed" normalisation) scale by the product cap_a cap_b instead. pts, w:
    the sample points of the sampled kernels ((m, 0, 3) for the others). Returns the number of
    pair terms.
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
        if kid >= NXM:
            _row_sampled(kid, mask, a, b0, C, cx, cy, cz, nx, ny, nz, area, cap, pts, w, L, y, m)
        elif sided[a] or any_sided_cols:
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
def tiles_apply(kid, data, base, tiles, offsets, cx, cy, cz, nx, ny, nz, area, cap, sided, pts, w,
                L, y, mode, live, need):
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
                            nx, ny, nz, area, cap, sided, pts, w, L, y, mode, row_live, col_live)
    return terms


@numba.njit(cache=True)
def gs_sweep(kid, data, tiles, row_ptr, row_idx, col_ptr, col_idx, offsets, cx, cy, cz, nx, ny,
             nz, area, cap, sided, pts, w, L, Le, rho, y, need, sp_ptr, sp_t, sp_s, sp_d):
    """One block Gauss-Seidel sweep (in place on L): for each original e in order, gather
    y_e = sum_J F_eJ L_J from its row tiles (e, J) and the transposed column tiles (J, e) with
    the latest L, then L_e = Le_e + rho_e y_e. `data` holds every tile's bytes at tiles[:, 5];
    row_ptr/row_idx and col_ptr/col_idx list the tiles of each original (CSR). Sparse
    corrections (near field, partial visibility): entries sp_ptr[e]:sp_ptr[e + 1] add
    sp_d * L[source] to y[target]; sp_t, sp_s (k, 2) are [sub-element, side] (sparse_by_target)."""
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
                                 area, cap, sided, pts, w, L, y, ROWS, none, none)
        for q in range(col_ptr[e], col_ptr[e + 1]):
            k = col_idx[q]
            terms += tiles_apply(kid, data, 0, tiles[k:k + 1], offsets, cx, cy, cz, nx, ny, nz,
                                 area, cap, sided, pts, w, L, y, COLS, none, none)
        for q in range(sp_ptr[e], sp_ptr[e + 1]):
            t, s = sp_t[q, 0], sp_s[q, 0]
            f = sp_d[q] * (min(cap[t], cap[s]) if cap[t] > 0 else cap[t] * cap[s])
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
