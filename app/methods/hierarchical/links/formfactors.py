"""Form factors of a link's two nodes: the oracle's disc estimate spread over a node's vertices
(disc_spread), the exact-to-quadrature near-field pair (near_ff) and the far link's centroid-to-polygon
form factor (centroid_to_polygon). Numba kernels called by the refinement (refine.py)."""

from __future__ import annotations

import numba
import numpy as np

from radiosity.core.exact import FAST_FLOOR, FAST_GW, FAST_GX, point_to_polygon_ff, point_ff, polygon_ff_rule

@numba.njit(cache=True, nogil=True)
def disc_spread(V, x, nv, nx, ny, nz, C, y, mx, my, mz, As, fc):
    """The disc estimate F(v -> c) between the point c = C[y] (normal m, area As) and the
    vertices v of polygon V[x, :nv] (normal n), against its value fc at the polygon's centroid:
    (largest change, change of the mean). The first is how much a receiver's irradiance varies
    over it (first order, and what the centroids miss at grazing angles near a shared edge); the
    second the error of the centroid rule over a source (second order: the linear part averages
    out)."""
    big = 0.0
    mean = 0.0
    for i in range(nv):
        dx, dy, dz = C[y, 0] - V[x, i, 0], C[y, 1] - V[x, i, 1], C[y, 2] - V[x, i, 2]
        r2 = dx * dx + dy * dy + dz * dz + 1e-300
        a = max(nx * dx + ny * dy + nz * dz, 0.0)
        b = max(-(mx * dx + my * dy + mz * dz), 0.0)
        f = As * a * b / (r2 * (np.pi * r2 + As))
        big = max(big, abs(f - fc))
        mean += f
    return big, abs(mean / nv - fc)


G2 = 0.5 / np.sqrt(3.0)  # 2 x 2 Gauss-Legendre on [0, 1]: 0.5 -+ G2


@numba.njit(cache=True, nogil=True)
def near_ff(P, nP, Ap, gp, Q, nQ, Aq, gq, npx, npy, npz, nqx, nqy, nqz, gap_factor):
    """F_pq, F_qp of a near link, exact to quadrature accuracy: where the smaller polygon is
    farther from the larger one's box than gap_factor times its size, Lambert's exact
    point-to-polygon form factor (exact.py) integrated over the smaller one by Gauss rules
    (2 x 2 on a quad's bilinear map, 3 points on a triangle: smooth integrand there); otherwise
    (touching, or about to) the double contour integral (exact.py) with its coarser rule (about
    1e-7 relative, 0.6-0.7 of the reference's time). gp, gq: +-1, the sides that face."""
    small_is_p = Ap <= Aq
    S, nS = (P, nP) if small_is_p else (Q, nQ)
    L, nL = (Q, nQ) if small_is_p else (P, nP)
    As, Al = (Ap, Aq) if small_is_p else (Aq, Ap)
    gap2 = 0.0
    for k in range(3):
        slo = shi = S[0, k]
        llo = lhi = L[0, k]
        for i in range(1, 4):
            slo, shi = min(slo, S[i, k]), max(shi, S[i, k])
            llo, lhi = min(llo, L[i, k]), max(lhi, L[i, k])
        d = max(llo - shi, slo - lhi, 0.0)
        gap2 += d * d
    if gap_factor >= 0.0 and gap2 <= gap_factor * gap_factor * As:
        f = polygon_ff_rule(P, nP, Q, nQ, True, FAST_GX, FAST_GW, FAST_FLOOR)
        return f, f * Ap / Aq
    n = np.empty(3)
    m = np.empty(3)  # the larger one's facing side: points behind it see none of it
    if small_is_p:
        n[0], n[1], n[2] = gp * npx, gp * npy, gp * npz
        m[0], m[1], m[2] = gq * nqx, gq * nqy, gq * nqz
    else:
        n[0], n[1], n[2] = gq * nqx, gq * nqy, gq * nqz
        m[0], m[1], m[2] = gp * npx, gp * npy, gp * npz
    m0 = m[0] * L[0, 0] + m[1] * L[0, 1] + m[2] * L[0, 2]
    x = np.empty(3)
    acc = 0.0
    wsum = 0.0
    if nS == 3:
        for j in range(3):
            u = 2.0 / 3.0 if j == 1 else 1.0 / 6.0
            v = 2.0 / 3.0 if j == 2 else 1.0 / 6.0
            for c in range(3):
                x[c] = S[0, c] + u * (S[1, c] - S[0, c]) + v * (S[2, c] - S[0, c])
            if m[0] * x[0] + m[1] * x[1] + m[2] * x[2] > m0:
                acc += point_to_polygon_ff(x, n, L, nL)
            wsum += 1.0
    else:
        for j in range(4):
            u = 0.5 + (G2 if j // 2 else -G2)
            v = 0.5 + (G2 if j % 2 else -G2)
            # the Jacobian of the bilinear map at (u, v): |dx/du x dx/dv|
            du = (1 - v) * (S[1] - S[0]) + v * (S[2] - S[3])
            dv = (1 - u) * (S[3] - S[0]) + u * (S[2] - S[1])
            w = np.sqrt((du[1] * dv[2] - du[2] * dv[1]) ** 2 + (du[2] * dv[0] - du[0] * dv[2]) ** 2
                        + (du[0] * dv[1] - du[1] * dv[0]) ** 2)
            for c in range(3):
                x[c] = ((1 - u) * (1 - v) * S[0, c] + u * (1 - v) * S[1, c] + u * v * S[2, c]
                        + (1 - u) * v * S[3, c])
            if m[0] * x[0] + m[1] * x[1] + m[2] * x[2] > m0:
                acc += w * point_to_polygon_ff(x, n, L, nL)
            wsum += w
    fs = acc / wsum if wsum > 0 else 0.0  # F from the smaller to the larger
    if small_is_p:
        return fs, fs * Ap / Aq
    return fs * Aq / Ap, fs


@numba.njit(cache=True, nogil=True)
def centroid_to_polygon(Lv, Ln, Lc, p, q, Ap, gp, Aq, gq, normal, op, oq, S, Sc):
    """F_pq, F_qp of a far link (p, q) between nodes of originals op, oq (normals normal[op],
    normal[oq]): the exact form factor from a differential element at the smaller node's
    centroid Lc to the larger polygon Lv (Lambert's formula, exact.py), the other by
    reciprocity. Exact over the larger node: only the smaller one's extent is approximated (to
    second order), where the point kernel errs over both. S (4, 3), Sc (10, 3): scratch."""
    npx, npy, npz = normal[op, 0], normal[op, 1], normal[op, 2]
    nqx, nqy, nqz = normal[oq, 0], normal[oq, 1], normal[oq, 2]
    if Ap <= Aq:
        a, b, g, nx, ny, nz, mx, my, mz = p, q, gp, npx, npy, npz, gq * nqx, gq * nqy, gq * nqz
    else:
        a, b, g, nx, ny, nz, mx, my, mz = q, p, gq, nqx, nqy, nqz, gp * npx, gp * npy, gp * npz
    if mx * (Lc[a, 0] - Lv[b, 0, 0]) + my * (Lc[a, 1] - Lv[b, 0, 1]) \
            + mz * (Lc[a, 2] - Lv[b, 0, 2]) <= 0:
        return 0.0, 0.0
    for i in range(Ln[b]):
        for c in range(3):
            S[i, c] = Lv[b, i, c]
    f = point_ff(Lc[a, 0], Lc[a, 1], Lc[a, 2], g * nx, g * ny, g * nz, S, Ln[b], Sc)
    if Ap <= Aq:
        return f, f * Ap / Aq
    return f * Aq / Ap, f
