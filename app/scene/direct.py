"""Direct light at points (SPEC §10): H1(x), the irradiance arriving at a point straight from the
scene's emitters, with shadow rays through the emitter seam (scene/emitters.py).

For an area emitter the unoccluded part is exact (the point-to-polygon contour integral,
core/exact.point_ff, clipped to the receiver's horizon) and the shadow rays only estimate the
visible share of it: H1 = sum_e pi Le_e F(x -> e) * sum_k w_k V_k / sum_k w_k, w_k the
integrand cos_x cos_y / r^2 at stratified samples of e. Where nothing blocks (V = 1) this is
exact whatever the sample count, so the furnace and every unshadowed point stay exact; a
penumbra gets the weighted visible fraction. Samples are the emitter's equal-area strata
rotated by a per-point offset (Cranley-Patterson) from a hash of the point's index and a seed:
the same points give the same answer in every process.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from radiosity.core.exact import point_ff
from radiosity.scene.emitters import AreaEmitters
from radiosity.tracing.rays import caster_of

#: Points per batch of shadow rays (memory: about (points x samples) x 80 bytes in flight).
BATCH_POINTS = 4096


@numba.njit(cache=True, nogil=True)
def _unoccluded(P, N, V, nv, Lf, Lb, out):
    """out[i, e, :] = pi Le F(P[i] -> emitter e), Le of the emitter's side that faces P[i] (Lf
    front, Lb back, (E, 3)); P, N (p, 3) points and unit normals, V (E, 4, 3) / nv (E,) the
    emitting polygons."""
    Qc = np.empty((10, 3))
    for e in range(V.shape[0]):
        a = V[e, 0]
        b = V[e, 1]
        c = V[e, 2]
        ux, uy, uz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
        wx, wy, wz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        for i in range(P.shape[0]):
            s = (P[i, 0] - a[0]) * nx + (P[i, 1] - a[1]) * ny + (P[i, 2] - a[2]) * nz
            if s == 0.0:
                continue
            f = point_ff(P[i, 0], P[i, 1], P[i, 2], N[i, 0], N[i, 1], N[i, 2], V[e], nv[e], Qc)
            if f <= 0.0:
                continue
            for c3 in range(3):
                out[i, e, c3] = math.pi * f * (Lf[e, c3] if s > 0.0 else Lb[e, c3])


class DirectLight:
    """H1 at points of a scene, from its area emitters (the only type today).

    elements: the scene's Elements; ray_offset: the shadow rays' offset (settings.rays.offset);
    samples: shadow rays per point and emitting element (a square: s x s strata per triangle,
    rounded down to one triangle's strata for a quad's two); seed: the offsets' seed.
    """

    def __init__(self, elements, ray_offset: float, samples: int = 16, seed: int = 0):
        self.elements = elements
        self.emitters = AreaEmitters(elements)
        self.ids = np.flatnonzero(self.emitters.emitting())
        self.ray_offset = float(ray_offset)
        self.samples = max(1, int(samples))
        self.seed = int(seed)
        self._caster = None

    @property
    def caster(self):
        if self._caster is None:
            self._caster = caster_of(self.elements.verts, self.elements.nverts, self.ray_offset)
        return self._caster

    def __bool__(self) -> bool:
        return bool(len(self.ids))

    def irradiance(self, points: np.ndarray, normals: np.ndarray, elem: np.ndarray,
                   index: np.ndarray | None = None) -> np.ndarray:
        """(p, 3) W m^-2: H1 at `points` (p, 3) on elements `elem` (p,) (-1: on none), facing
        unit `normals` (p, 3) (the receiving side's). index (p,) int: the points' stable numbers
        for their sample offsets (None: 0..p-1)."""
        P = np.ascontiguousarray(points, np.float64)
        N = np.ascontiguousarray(normals, np.float64)
        E = np.asarray(elem, np.int64)
        idx = np.arange(len(P)) if index is None else np.asarray(index, np.int64)
        out = np.zeros((len(P), 3))
        if not len(self.ids) or not len(P):
            return out
        for s in range(0, len(P), BATCH_POINTS):
            sl = slice(s, min(len(P), s + BATCH_POINTS))
            out[sl] = self._batch(P[sl], N[sl], E[sl], idx[sl])
        return out

    def _batch(self, P, N, E, idx):
        el = self.elements
        ids = self.ids
        V = np.ascontiguousarray(el.verts[ids], np.float64)
        nv = np.ascontiguousarray(el.nverts[ids], np.int64)
        Le = np.asarray(el.emission, np.float64)[ids]
        H0 = np.zeros((len(P), len(ids), 3))
        _unoccluded(P, N, V, nv, np.ascontiguousarray(Le[:, 0]), np.ascontiguousarray(Le[:, 1]), H0)
        seen = H0.max(axis=2) > 0                                     # (p, E)
        pi, ei = np.nonzero(seen)
        if not len(pi):
            return H0.sum(axis=1)
        k = int(math.isqrt(self.samples)) ** 2 or 1
        y, w = self._samples(P[pi], N[pi], ei, idx[pi], k)            # (q, k, 3), (q, k)
        x = np.repeat(P[pi], k, axis=0)
        vis = ~self.caster.occluded(x, y.reshape(-1, 3), np.repeat(E[pi], k),
                                    np.repeat(ids[ei], k))
        vis = vis.reshape(-1, k)
        ws = w.sum(axis=1)
        frac = np.where(ws > 0, (w * vis).sum(axis=1) / np.where(ws > 0, ws, 1.0), vis.mean(axis=1))
        H0[pi, ei] *= frac[:, None]
        return H0.sum(axis=1)

    def _samples(self, x, nx, ei, key, k):
        """Shadow-ray ends y (q, k, 3) on emitter ei[j] seen from x[j] (normal nx[j]): k equal-area
        strata of its triangle (a quad: k / 2 on each of v0 v1 v2 and v0 v2 v3), rotated by an
        offset hashed from (key[j], ei[j]); and their weights cos_x cos_y / r^2 * area (q, k)."""
        el = self.elements
        s = int(math.isqrt(k))
        gu, gv = (np.arange(k) // s + 0.5) / s, (np.arange(k) % s + 0.5) / s
        off = _hash2(key * 1_000_003 + ei, self.seed)                  # (q, 2) in [0, 1)
        u = (gu[None] + off[:, :1]) % 1.0
        v = (gv[None] + off[:, 1:]) % 1.0
        e = self.ids[ei]
        Vt = np.asarray(el.verts, np.float64)[e]
        quad = (np.asarray(el.nverts)[e] == 4)[:, None]
        second = quad & (u >= 0.5)          # a quad: u's second half on triangle v0 v2 v3
        u = np.where(quad, np.where(second, 2 * u - 1, 2 * u), u)
        su = np.sqrt(u)
        b1, b2 = (su * (1 - v))[..., None], (su * v)[..., None]
        a = Vt[:, None, 0]
        b = np.where(second[..., None], Vt[:, None, 2], Vt[:, None, 1])
        c = np.where(second[..., None], Vt[:, None, 3], Vt[:, None, 2])
        y = a + b1 * (b - a) + b2 * (c - a)
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=2)    # (q, k)
        d = y - x[:, None]
        r2 = (d ** 2).sum(axis=2)
        cos_x = np.maximum(np.einsum("qkc,qc->qk", d, nx), 0.0)
        cos_y = np.abs(np.einsum("qkc,qc->qk", d, np.asarray(el.normal, np.float64)[e]))
        w = cos_x * cos_y / np.where(r2 > 0, r2 * r2, np.inf) * area
        return y, w


def _hash2(key: np.ndarray, seed: int) -> np.ndarray:
    """(n, 2) in [0, 1): two uniform numbers per integer key (splitmix64)."""
    out = np.empty((len(key), 2))
    z = np.asarray(key, np.uint64) + np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15)
    with np.errstate(over="ignore"):
        for j in range(2):
            z = z + np.uint64(0x9E3779B97F4A7C15)
            x = z.copy()
            x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
            x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
            x = x ^ (x >> np.uint64(31))
            out[:, j] = (x >> np.uint64(11)).astype(np.float64) / float(1 << 53)
    return out

