"""Deliberately naive references: every optimised path must agree with these on small scenes."""

from __future__ import annotations

import numpy as np

from radiosity.tracing.rays import RayCaster

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


def _strata(m: int, n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """(m, n) pairs (u, v) in [0, 1)^2, jittered on a k x k grid (n = k^2), in random order per
    row: stratified samples (less noise than independent ones, still unbiased)."""
    k = int(round(np.sqrt(n)))
    assert k * k == n, "a square number of samples"
    i, j = np.divmod(np.arange(n), k)
    u = (i[None] + rng.random((m, n))) / k
    v = (j[None] + rng.random((m, n))) / k
    order = np.argsort(rng.random((m, n)), axis=1)
    return np.take_along_axis(u, order, 1), np.take_along_axis(v, order, 1)


def uniform_points(verts: np.ndarray, nverts: np.ndarray, n: int, rng) -> np.ndarray:
    """n points uniform by area (stratified) on each convex polygon verts (m, 4, 3) (a triangle
    repeats vertex 2 in slot 3; a quad is split along 0-2): (m, n, 3). Written here, not taken
    from kernels.sample_points, so that the power balance below shares no code with the engine."""
    v0, v1, v2, v3 = (verts[:, k] for k in range(4))
    a1 = 0.5 * np.linalg.norm(np.cross(v1 - v0, v2 - v0), axis=1)
    a2 = np.where(nverts == 4, 0.5 * np.linalg.norm(np.cross(v2 - v0, v3 - v0), axis=1), 0.0)
    m = len(verts)
    u, w = _strata(m, n, rng)
    # u picks the triangle of a quad (by area) and, rescaled, the first barycentric coordinate
    f1 = (a1 / (a1 + a2))[:, None]
    second = u >= f1
    u = np.where(second, (u - f1) / np.maximum(1 - f1, 1e-300), u / f1)
    b = np.where(second[..., None], v2[:, None], v1[:, None])
    c = np.where(second[..., None], v3[:, None], v2[:, None])
    su = np.sqrt(u)[..., None]
    w = w[..., None]
    return v0[:, None] + su * (1 - w) * (b - v0[:, None]) + su * w * (c - v0[:, None])


def cosine_directions(normal: np.ndarray, n: int, rng) -> np.ndarray:
    """n cosine-weighted unit directions (stratified) about each normal (m, 3): (m, n, 3)."""
    m = len(normal)
    u1, u2 = _strata(m, n, rng)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], axis=-1)
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t = np.cross(normal, helper)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    s = np.cross(normal, t)
    return local[..., :1] * t[:, None] + local[..., 1:2] * s[:, None] + local[..., 2:] * normal[:, None]


def power_balance(part, elements, L: np.ndarray, rays: int, rng):
    """Where the light leaving every sub-element goes, by brute-force Monte Carlo over the
    geometry (Embree first hits, no form factor, no visibility bit): each side of each
    sub-element with L > 0 sends `rays` cosine-weighted rays from uniform points, each carrying
    pi A L / rays. A ray that hits a side with reflectance rho deposits (1 - rho) of its power
    there (the back of a one-sided element is black: rho 0); one that hits nothing escapes.

    L: (m, 2, 3) radiance per sub-element and side. Returns (emitted, absorbed, escaped), each
    (3,) W per channel, where emitted = pi sum A Le. For the exact radiance
    emitted = absorbed + escaped (what leaves a surface is what was emitted there plus the
    reflected part of what arrived); a discrete L meets it up to its discretisation error."""
    rc = RayCaster(elements.verts, elements.nverts)
    m = len(part)
    Le = elements.emission[part.orig]
    rho_el = elements.reflectance                      # (n, 2, 3): [front, back]
    eps = 1e-7 * rc.scale
    absorbed, escaped = np.zeros(3), np.zeros(3)
    for side, sign in ((0, 1.0), (1, -1.0)):
        src = np.nonzero(L[:, side].max(axis=1) > 0)[0]
        if side == 1:
            src = src[elements.two_sided[part.orig[src]]]
        for chunk in np.array_split(src, max(1, len(src) * rays // 500_000 + 1)):
            if len(chunk) == 0:
                continue
            nrm = sign * part.normal[chunk]
            p = uniform_points(part.verts[chunk], part.nverts[chunk], rays, rng)
            d = cosine_directions(nrm, rays, rng)
            o = (p + eps * nrm[:, None]).reshape(-1, 3)
            hit = rc.first_hit(o, d.reshape(-1, 3), unit=False)
            power = (np.pi * part.area[chunk, None] * L[chunk, side]) / rays       # (k, 3) per ray
            power = np.repeat(power, rays, axis=0)
            miss = hit < 0
            escaped += power[miss].sum(axis=0)
            h = hit[~miss]
            front = np.einsum("ij,ij->i", d.reshape(-1, 3)[~miss], elements.normal[h]) < 0
            rho = np.where(front[:, None], rho_el[h, 0], np.where(elements.two_sided[h][:, None],
                                                                  rho_el[h, 1], 0.0))
            absorbed += ((1 - rho) * power[~miss]).sum(axis=0)
    emitted = np.pi * np.einsum("m,mc->c", part.area, Le[:, 0] + np.where(
        elements.two_sided[part.orig][:, None], Le[:, 1], 0.0))
    return emitted, absorbed, escaped


def near_field_matrix(part, elements, V, kernel: str, factor: float) -> np.ndarray:
    """Dense F (2m, 2m) of a near-field kernel (point-nf, disc-nf) by brute force: the base
    kernel everywhere, and for each visible pair of different originals closer than `factor`
    element sizes (|c_a - c_b| < factor max(sqrt A_a, sqrt A_b)) the exact form factor of the two
    polygons (exact.polygon_form_factor, one pair at a time, the sides facing each other)."""
    from radiosity.core.exact import polygon_form_factor

    m = len(part)
    F = form_factor_matrix(part, elements, V, kernel.removesuffix("-nf"))
    size = np.sqrt(part.area)
    d = np.linalg.norm(part.center[:, None] - part.center[None], axis=2)
    near = (d < factor * np.maximum(size[:, None], size[None])) & V
    near &= part.orig[:, None] != part.orig[None, :]
    for a, b in zip(*np.nonzero(near)):
        dv = part.center[b] - part.center[a]
        sa, sb = int(part.normal[a] @ dv <= 0), int(-part.normal[b] @ dv <= 0)
        P = part.verts[a][:part.nverts[a]]
        Q = part.verts[b][:part.nverts[b]]
        F[sa * m + a, sb * m + b] = polygon_form_factor(P, Q, two_sided=True)
    return F
