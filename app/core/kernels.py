"""Form-factor kernels (SPEC §2): the registry, the formulas and the sample points, evaluated
on the fly inside the solver's pass loops (passes.py).

Design notes and measurements: docs/src/design/core-kernels.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from radiosity.errors import RadiosityError

@dataclass(frozen=True)
class Kernel:
    """A form-factor kernel of the registry: its id in the numba loops, one line for --help,
    whether it is reciprocal (A_a F_ab == A_b F_ba: CG applies) and whether pairs closer than a
    few element sizes get the exact form factor (near field, nearfield.py)."""

    name: str
    id: int
    help: str
    reciprocal: bool
    near_field: bool

    @property
    def base(self) -> str:
        """The centre-to-centre kernel under a near-field variant ("point-nf" -> "point")."""
        return self.name[:-3] if self.near_field else self.name


KERNELS = {k.name: k for k in (
    Kernel("point", 0, "one ray between centres, F = A cos cos / (pi r^2) (seed eq. 6)", True, False),
    Kernel("disc", 1, "the receiver as a disc of its area, F = A cos cos / (pi r^2 + A) (2nd seed)", False, False),
    Kernel("point-nf", 0, "point, with exact polygon form factors in the near field (nearfield.py)", True, True),
    Kernel("disc-nf", 1, "disc, with exact polygon form factors in the near field", False, True),
    Kernel("nxm", 2, "point kernel averaged over N x N sample points, N*N rays per pair (seed §2.2)", True, False),
    Kernel("mc", 3, "point kernel averaged over k random (seeded) sample pairs, k rays per pair", True, False),
)}
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


def make_sampling(kernel: str, points: int, samples: int, seed: int) -> Sampling | None:
    """The sample points kernel `kernel` needs (None: one ray between centres): nxm with
    `points` per element (a square), mc with `samples` random pairs from generator `seed`."""
    kid = kernel_id(kernel)
    if kid == NXM:
        n = int(points)
        if n < 1 or int(round(np.sqrt(n))) ** 2 != n:
            raise RadiosityError(f"radiosity.solve.nxm-points must be a square (1, 4, 9, 16, ...), got {n}")
        return Sampling("nxm", n)
    if kid == MC:
        n = int(samples)
        if n < 1:
            raise RadiosityError(f"radiosity.solve.mc-samples must be at least 1, got {n}")
        return Sampling("mc", n, int(seed))
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


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy", fastmath=True)
def _term(p, q, nax, nay, naz, nbx, nby, nbz):
    """c_a c_b / r^4 of the sample pair p -> q (points (3,)), 0 where either cosine is not > 0."""
    dx = q[0] - p[0]
    dy = q[1] - p[1]
    dz = q[2] - p[2]
    r2 = dx * dx + dy * dy + dz * dz + 1e-300
    ca = max(nax * dx + nay * dy + naz * dz, 0.0)
    cb = max(-(nbx * dx + nby * dy + nbz * dz), 0.0)
    return ca * cb / (r2 * r2)


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy", fastmath=True)
def sampled_sum(kid, pa, wa, pb, wb, nax, nay, naz, nbx, nby, nbz):
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


@numba.njit(cache=True, nogil=True, inline="always")
def facing_signs(cx, cy, cz, nx, ny, nz, a, b):
    """+1 / -1: the side of a that b's centre lies on, and of b that a's lies on."""
    dx = cx[b] - cx[a]
    dy = cy[b] - cy[a]
    dz = cz[b] - cz[a]
    sa = 1.0 if nx[a] * dx + ny[a] * dy + nz[a] * dz > 0 else -1.0
    sb = 1.0 if -(nx[b] * dx + ny[b] * dy + nz[b] * dz) > 0 else -1.0
    return sa, sb

def get_kernel(name: str) -> Kernel:
    """The registry entry of kernel `name`; an unknown name lists the valid ones."""
    try:
        return KERNELS[name]
    except KeyError:
        raise RadiosityError(f"unknown kernel {name!r}: use one of {', '.join(KERNELS)}") from None


def kernel_id(name: str) -> int:
    """The id of kernel `name` in the numba loops."""
    return get_kernel(name).id


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def kernel_ff(kid, g, r2, area):
    """Form factor towards an element of `area`, from g = |ca cb| (unnormalised cosines)."""
    if kid == 0:
        return area * g / (np.pi * r2 * r2)
    return area * g / r2 / (np.pi * r2 + area)


@numba.njit(cache=True, nogil=True, inline="always")
def pair_sampled(kid, a, b, cx, cy, cz, nx, ny, nz, pts, w):
    """The unoccluded sampled kernel of pair (a, b) without the area (F_ab = A_b acc, F_ba =
    A_a acc) and the sides (0 front, 1 back) the centres face."""
    sa, sb = facing_signs(cx, cy, cz, nx, ny, nz, a, b)
    acc = sampled_sum(kid, pts[a], w[a], pts[b], w[b], sa * nx[a], sa * ny[a], sa * nz[a],
                   sb * nx[b], sb * ny[b], sb * nz[b])
    return acc, 0 if sa > 0 else 1, 0 if sb > 0 else 1


@numba.njit(cache=True, nogil=True)
def sampled_pairs(kid, pts, w, cx, cy, cz, nx, ny, nz, ia, ib):
    """The unoccluded sampled kernel of pairs (ia, ib) without the area: F_ab = A_b acc[k]
    (and F_ba = A_a acc[k]), and the sides sa, sb (k,) int8 the centres face."""
    acc = np.empty(ia.shape[0])
    sa = np.empty(ia.shape[0], np.int8)
    sb = np.empty(ia.shape[0], np.int8)
    for k in range(ia.shape[0]):
        acc[k], sa[k], sb[k] = pair_sampled(kid, ia[k], ib[k], cx, cy, cz, nx, ny, nz, pts, w)
    return acc, sa, sb


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
        sa, sb = facing_signs(cx, cy, cz, nx, ny, nz, a, b)
        for p in range(P):
            ka = p // S if kid == NXM else p
            kb = p % S if kid == NXM else p
            ra[q * P + p] = a * S + ka
            rb[q * P + p] = b * S + kb
            wt = w[a, ka] * w[b, kb] if kid == NXM else 1.0
            term[q, p] = wt * _term(pts[a, ka], pts[b, kb], sa * nx[a], sa * ny[a], sa * nz[a],
                                    sb * nx[b], sb * ny[b], sb * nz[b])
    return ra, rb, term


def base_kernel(name: str) -> str:
    """The centre-to-centre kernel under a near-field variant ("point-nf" -> "point")."""
    return get_kernel(name).base


def pair_form_factors(kernel: str, ca_pts, na, aa, cb_pts, nb, ab):
    """F_ab and F_ba for arrays of pairs (numpy, for tests and studies): returns two (k,) arrays."""
    kid = kernel_id(kernel)
    d = cb_pts - ca_pts
    r2 = np.einsum("ij,ij->i", d, d)
    g = np.abs(np.einsum("ij,ij->i", na, d) * np.einsum("ij,ij->i", nb, d))
    if kid == 0:
        return ab * g / (np.pi * r2 * r2), aa * g / (np.pi * r2 * r2)
    return ab * g / r2 / (np.pi * r2 + ab), aa * g / r2 / (np.pi * r2 + aa)
