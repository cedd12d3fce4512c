"""Deliberately naive references: every optimised path must agree with these on small scenes."""

from __future__ import annotations

import numpy as np

from radiosity.rays import RayCaster

COS_TOL = 1e-9


def facing(part, two_sided_sub) -> np.ndarray:
    """(m, m) bool: a faces b (cos beyond tolerance on a side that exists), plain numpy."""
    d = part.center[None, :, :] - part.center[:, None, :]
    length = np.linalg.norm(d, axis=2)
    c = np.einsum("ac,abc->ab", part.normal, d)
    t = COS_TOL * length
    return (c > t) | (two_sided_sub[:, None] & (c < -t))


def visibility(part, elements) -> np.ndarray:
    """One ray for every ordered pair (a, b), a != b: no culling, no symmetry; then orientation."""
    rc = RayCaster(elements.verts, elements.nverts)
    m = len(part)
    a, b = np.nonzero(~np.eye(m, dtype=bool))
    occ = np.zeros((m, m), bool)
    occ[a, b] = rc.occluded(part.center[a], part.center[b], part.orig[a], part.orig[b])  # no pair indexing
    f = facing(part, elements.two_sided[part.orig])
    V = ~occ & f & f.T
    np.fill_diagonal(V, False)
    return V


def form_factor_matrix(part, elements, V, kernel: str = "point") -> np.ndarray:
    """Dense F over (side, sub-element) unknowns, (2m, 2m): row s*m + a, column t*m + b.

    F[(sa, a), (sb, b)] = F_ab where sa / sb are the sides of a / b that face each other."""
    m = len(part)
    c, n, A = part.center, part.normal, part.area
    F = np.zeros((2 * m, 2 * m))
    a, b = np.nonzero(V)
    d = c[b] - c[a]
    r2 = np.einsum("ij,ij->i", d, d)
    ca = np.einsum("ij,ij->i", n[a], d)
    cb = -np.einsum("ij,ij->i", n[b], d)
    g = np.abs(ca * cb)
    if kernel == "point":
        f = A[b] * g / (np.pi * r2 * r2)
    else:
        f = A[b] * g / r2 / (np.pi * r2 + A[b])
    sa = (ca <= 0).astype(int)
    sb = (cb <= 0).astype(int)
    F[sa * m + a, sb * m + b] = f
    return F


def normalised(F: np.ndarray, m: int) -> np.ndarray:
    """Rows summing past 1 scaled pairwise by min(cap_a, cap_b), cap = 1 / row sum (max over sides)."""
    rs = F.sum(axis=1).reshape(2, m).max(axis=0)
    cap = 1.0 / np.maximum(rs, 1.0)
    cap[rs <= 1 + 1e-12] = 1.0
    c2 = np.concatenate([cap, cap])
    return F * np.minimum(c2[:, None], c2[None, :])


def dense_solution(part, elements, V, kernel: str = "point", normalise: bool = True) -> np.ndarray:
    """Direct solve of (I - rho F) L = Le per channel with numpy.linalg.solve: (m, 2, 3)."""
    F = form_factor_matrix(part, elements, V, kernel)
    return dense_solution_of(normalised(F, len(part)) if normalise else F, elements, part)


def dense_solution_of(F: np.ndarray, elements, part) -> np.ndarray:
    """Direct solve of (I - rho F) L = Le for a dense F (2m, 2m): (m, 2, 3)."""
    m = len(part)
    Le = elements.emission[part.orig]       # (m, 2, 3)
    rho = elements.reflectance[part.orig]
    out = np.zeros((m, 2, 3))
    for ch in range(3):
        r = np.concatenate([rho[:, 0, ch], rho[:, 1, ch]])
        e = np.concatenate([Le[:, 0, ch], Le[:, 1, ch]])
        x = np.linalg.solve(np.eye(2 * m) - r[:, None] * F, e)
        out[:, 0, ch], out[:, 1, ch] = x[:m], x[m:]
    return out


def sampled_form_factor_matrix(part, elements, kernel: str, pts, w) -> np.ndarray:
    """Dense F (2m, 2m) of a sampled kernel by brute force: for every ordered pair facing by
    centres, one ray per sample pair, F_ab = A_b / pi * sum w c_a c_b V / r^4 (nxm: every
    (k, l); mc: (s, s), weights 1/S); no culling, no symmetry, no fractions."""
    rc = RayCaster(elements.verts, elements.nverts)
    m, S = pts.shape[:2]
    two = elements.two_sided[part.orig]
    f = facing(part, two)
    F = np.zeros((2 * m, 2 * m))
    if kernel == "nxm":
        kk, ll = np.meshgrid(np.arange(S), np.arange(S), indexing="ij")
        kk, ll = kk.ravel(), ll.ravel()
    else:
        kk = ll = np.arange(S)
    for a, b in zip(*np.nonzero(f & f.T)):
        if a == b:
            continue
        d0 = part.center[b] - part.center[a]
        sga = 1.0 if part.normal[a] @ d0 > 0 else -1.0
        sgb = 1.0 if -part.normal[b] @ d0 > 0 else -1.0
        p, q = pts[a, kk], pts[b, ll]
        d = q - p
        r2 = np.einsum("ij,ij->i", d, d)
        ca = np.maximum(sga * d @ part.normal[a], 0)
        cb = np.maximum(-sgb * d @ part.normal[b], 0)
        wt = w[a, kk] * w[b, ll] if kernel == "nxm" else np.full(len(kk), 1.0 / S)
        vis = ~rc.occluded(p, q, np.full(len(p), part.orig[a]), np.full(len(q), part.orig[b]))
        F[(sga < 0) * m + a, (sgb < 0) * m + b] = part.area[b] * np.sum(wt * ca * cb * vis / r2 ** 2) / np.pi
    return F
