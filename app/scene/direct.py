"""Direct light at points (SPEC §10): H1(x), the irradiance arriving at a point straight from the
scene's emitters, with shadow rays through the emitter seam (scene/emitters.py).

The unoccluded part is exact: per emitting element the point-to-polygon contour integral
(core/exact.point_ff, clipped to the receiver's horizon). Shadow rays only estimate the visible
share of it, as a ratio: H1 = sum_slots H0_slot * sum_k w_k V_k / sum_k w_k, so wherever nothing
blocks (V = 1) the answer is exact whatever the ray count: the furnace and every unshadowed point.

Rays are spent by importance. Emitting elements are grouped into lights (connected elements of
one Le); a light gets samples * sqrt(its share of the point's exact unoccluded H1) first-pass
rays (the square root: a penumbra's error falls slower than 1 / rays, so weak lights get
relatively more), and the lights due less than one ray share one pooled slot. Within a slot ray
j is Sobol point j, rotated by offsets hashed from (point index, slot, seed): its first
coordinate picks the element by its share (elements in Morton order) and the point on it; an
element that subtends much is sampled uniformly in solid angle (Arvo 1995), a small one by area.
The same points give the same bits in every process and batch. A second pass continues the
sequence to `refine` times the first pass's rays in every slot whose rays disagree (a
penumbra). Weights are per channel (a pooled slot mixes colours). A light whose box and the
point lie apart from every occluder box (shafts.clear_of) needs no ray.
Design note and figures: docs/src/design/scene-direct.md.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from radiosity.core.colour import LUMA  # the importance's weights (Rec. 709)
from radiosity.core.exact import point_ff
from radiosity.scene.emitters import AreaEmitters, PointEmitters
from radiosity.tracing.rays import caster_of
from radiosity.core.geometry import on_hull_planes
from radiosity.core.spherical import arvo, dot, spherical_triangle, unit3
from radiosity.tracing.shafts import box_apart, clear_of

#: Entries of the per-batch (points x emitting elements) arrays (about 40 bytes each in flight).
BATCH_ENTRIES = 1 << 21
#: Points per batch at most (the shadow rays of one batch: about points x samples x refine).
BATCH_POINTS = 4096
#: Occluder boxes of the shaft test (as tracing.rays.OCCLUDER_BOXES) and the share of the
#: elements past which the test is not tried (a terrain: every box holds receivers).
OCCLUDER_BOXES = 8
INNER_SHARE = 0.9
#: Solid angle (sr, about area / distance^2) past which an emitting element is sampled
#: uniformly in solid angle rather than by area (_sample).
CLOSE = 0.05
#: First-pass rays of a light that is not pooled, at least: fewer cannot tell a penumbra.
MIN_RAYS = 4

_K1 = np.uint64(0x9E3779B97F4A7C15)
_K2 = np.uint64(0xBF58476D1CE4E5B9)
_K3 = np.uint64(0x94D049BB133111EB)


@numba.njit(cache=True, nogil=True)
def _unoccluded(P, N, V, nv, Lf, Lb, out):
    """out[i, e, :] = pi Le F(P[i] -> emitter e), Le of the emitter's side that faces P[i] (Lf
    front, Lb back, (E, 3)); P, N (p, 3) points and unit normals, V (E, 4, 3) / nv (E,) the
    emitting polygons. A point in an emitter's plane (on it) or facing away gets 0 from it."""
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
            L = Lf if s > 0.0 else Lb
            if L[e, 0] <= 0.0 and L[e, 1] <= 0.0 and L[e, 2] <= 0.0:
                continue
            up = False                  # some vertex above the point's horizon?
            for j in range(nv[e]):
                up = up or ((V[e, j, 0] - P[i, 0]) * N[i, 0] + (V[e, j, 1] - P[i, 1]) * N[i, 1]
                            + (V[e, j, 2] - P[i, 2]) * N[i, 2]) > 0.0
            if not up:
                continue
            f = point_ff(P[i, 0], P[i, 1], P[i, 2], N[i, 0], N[i, 1], N[i, 2], V[e], nv[e], Qc)
            if f <= 0.0:
                continue
            for c3 in range(3):
                out[i, e, c3] = math.pi * f * L[e, c3]


@numba.njit(cache=True, nogil=True)
def _lights(H0, light_of, nL, HL):
    """HL[i, L] (pb, nL, 3) += H0[i, e] (pb, E, 3) over the elements e of light L = light_of[e]."""
    for i in range(H0.shape[0]):
        for e in range(H0.shape[1]):
            L = light_of[e]
            for c in range(3):
                HL[i, L, c] += H0[i, e, c]


@numba.njit(cache=True, nogil=True)
def _clear(P, elem, lo, hi, flat, LO, HI, out):
    """out[i, L] (pb, nL) bool: no segment from P[i] (on an element: elem[i] >= 0) to light L's
    box [lo[L], hi[L]] meets an occluder box [LO, HI] (shafts.clear_of) nor another light's box
    (nor its own unless it is flat: a segment ends on a flat light from its emitting side)."""
    A = np.empty((2, 3))
    B = np.empty((2, 3))
    for i in range(P.shape[0]):
        if elem[i] < 0:
            continue
        for k in range(3):
            A[0, k] = P[i, k]
            A[1, k] = P[i, k]
        for L in range(lo.shape[0]):
            for k in range(3):
                B[0, k] = lo[L, k]
                B[1, k] = hi[L, k]
            ok = clear_of(A, B, LO, HI)
            for M in range(lo.shape[0]):
                if ok and (M != L or not flat[L]):
                    ok = box_apart(A, B, lo, hi, M)
            out[i, L] = ok


@numba.njit(cache=True, nogil=True)
def _plan(lum, clear, budget, n, pooled):
    """Rays per slot: n (pb, nL + 1) int64, slot nL the pooled one; pooled (pb, nL) bool. A
    point's light with luminance lum (pb, nL) > 0 that is not clear is due budget * sqrt(its
    share) rays (at least MIN_RAYS); one due less than one ray joins the pooled slot, which gets
    at least one."""
    nL = lum.shape[1]
    for i in range(lum.shape[0]):
        T = 0.0
        for L in range(nL):
            if not clear[i, L]:
                T += lum[i, L]
        if T <= 0.0:
            continue
        tail = 0.0
        for L in range(nL):
            if clear[i, L] or lum[i, L] <= 0.0:
                continue
            m = budget * math.sqrt(lum[i, L] / T)
            if m >= 1.0:
                n[i, L] = max(MIN_RAYS, int(m + 0.5))
            else:
                pooled[i, L] = True
                tail += m
        if tail > 0.0:
            n[i, nL] = max(1, int(tail + 0.5))


@numba.njit(cache=True, nogil=True, inline="always")
def _unit(key, salt):
    """A uniform number in [0, 1) from the integers key and salt (splitmix64)."""
    z = np.uint64(key) * _K1 + np.uint64(salt) * _K2 + _K1
    z = (z ^ (z >> np.uint64(30))) * _K2
    z = (z ^ (z >> np.uint64(27))) * _K3
    z = z ^ (z >> np.uint64(31))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _sobol(j):
    """Point j of the 2D Sobol (0, 2)-sequence: (van der Corput base 2, Sobol's second
    dimension). Its first 2^k points are a (0, k, 2)-net: stratified in every dyadic box."""
    r0 = np.uint32(0)
    r1 = np.uint32(0)
    v = np.uint32(0x80000000)
    bit = np.uint32(0x80000000)
    while j:
        if j & 1:
            r0 ^= bit
            r1 ^= v
        j >>= 1
        bit >>= np.uint32(1)
        v ^= v >> np.uint32(1)
    return float(r0) * (1.0 / 4294967296.0), float(r1) * (1.0 / 4294967296.0)


@numba.njit(cache=True, nogil=True)
def _fill(P, N, lum_e, em, lstart, n, j0, pooled, off, key, seed, Y, Ye, W, Rs):
    """The shadow rays of every slot: rays j0[i, s] .. j0[i, s] + n[i, s] - 1 of a slot's sequence
    from point i (P, N (pb, 3)), written from off[i, s] into Y (ends, (R, 3)), Ye (their
    elements, local), W (ratio weights) and Rs (slot i (nL + 1) + s). Ray j is Sobol point j,
    rotated by offsets hashed from (key[i], slot, seed); its first coordinate picks the element
    by the slot's luminances lum_e (pb, E) (light L: elements lstart[L]:lstart[L+1]; the pooled
    slot: those of pooled[i] lights) and, rescaled, is the point's first coordinate in it. So a
    second pass continues the first's sequence. em: the emitters' (V, f1, normal, area,
    Le (E, 2, 3)) bundle; W (R, 3)."""
    V, f1, nrm, area, Le = em
    nL = lstart.shape[0] - 1
    ce = np.empty(lum_e.shape[1], np.int64)
    cc = np.empty(lum_e.shape[1] + 1)
    sph = np.zeros((lum_e.shape[1], 7))        # close?, then (omega, angle, cos side) x 2
    dirs = np.zeros((lum_e.shape[1], 4, 3))
    for i in range(P.shape[0]):
        for s in range(nL + 1):
            m = n[i, s]
            if m <= 0:
                continue
            L0, L1 = (s, s + 1) if s < nL else (0, nL)
            q = 0
            cc[0] = 0.0
            for L in range(L0, L1):
                if s == nL and not pooled[i, L]:
                    continue
                for e in range(lstart[L], lstart[L + 1]):
                    if lum_e[i, e] > 0.0:
                        ce[q] = e
                        cc[q + 1] = cc[q] + lum_e[i, e]
                        q += 1
            if q == 0:
                continue
            for k in range(q):
                _spherical_of(P, i, ce[k], V, f1, area, sph[k], dirs[k])
            S = cc[q]
            o0 = _unit(key[i] * (nL + 1) + s, seed)
            o1 = _unit(key[i] * (nL + 1) + s, seed + 7919)
            for j in range(m):
                u, v = _sobol(j0[i, s] + j)
                t = ((u + o0) % 1.0) * S
                lo, hi = 0, q - 1               # the element whose [cc[k], cc[k + 1]) holds t
                while lo < hi:
                    mid = (lo + hi + 1) // 2
                    if cc[mid] <= t:
                        lo = mid
                    else:
                        hi = mid - 1
                e = ce[lo]
                h = cc[lo + 1] - cc[lo]
                r = min(max((t - cc[lo]) / h, 0.0), 1.0 - 1e-12)
                k = off[i, s] + j
                _sample(P, N, i, e, r, (v + o1) % 1.0, V, f1, nrm, area, Le, h, k, Y, W,
                        sph[lo], dirs[lo])
                Ye[k] = e
                Rs[k] = i * (nL + 1) + s


@numba.njit(cache=True, nogil=True, inline="always")
def _vertex(V, e, j, x):
    """The unit direction from x to vertex j of emitter e."""
    return unit3(V[e, j, 0] - x[0], V[e, j, 1] - x[1], V[e, j, 2] - x[2])


@numba.njit(cache=True, nogil=True)
def _spherical_of(P, i, e, V, f1, area, sph, dirs):
    """sph (7,): whether emitter e subtends more than CLOSE sr from P[i] and, if so, its
    triangles' (solid angle, angle at the first vertex, cosine of the first side); dirs (4, 3):
    the unit directions to its vertices."""
    x = (P[i, 0], P[i, 1], P[i, 2])
    cx = (V[e, 0, 0] + V[e, 1, 0] + V[e, 2, 0] + V[e, 3, 0]) * 0.25 - x[0]
    cy = (V[e, 0, 1] + V[e, 1, 1] + V[e, 2, 1] + V[e, 3, 1]) * 0.25 - x[1]
    cz = (V[e, 0, 2] + V[e, 1, 2] + V[e, 2, 2] + V[e, 3, 2]) * 0.25 - x[2]
    sph[0] = 0.0
    if area[e] <= CLOSE * (cx * cx + cy * cy + cz * cz):
        return
    for j in range(4):
        d = _vertex(V, e, j, x)
        for q in range(3):
            dirs[j, q] = d[q]
    A = (dirs[0, 0], dirs[0, 1], dirs[0, 2])
    B = (dirs[1, 0], dirs[1, 1], dirs[1, 2])
    C = (dirs[2, 0], dirs[2, 1], dirs[2, 2])
    D = (dirs[3, 0], dirs[3, 1], dirs[3, 2])
    sph[1], sph[2], sph[3] = spherical_triangle(A, B, C)
    sph[4] = sph[5] = sph[6] = 0.0
    if f1[e] != 1.0:
        sph[4], sph[5], sph[6] = spherical_triangle(A, C, D)
    sph[0] = 1.0 if sph[1] + sph[4] > 0.0 else 0.0


@numba.njit(cache=True, nogil=True, inline="always")
def _sample(P, N, i, e, u, v, V, f1, nrm, area, Le, h, k, Y, W, sph, dirs):
    """Y[k]: the point (u, v) of the unit square on emitter e; W[k] (3,): its ratio weights per
    channel, Le cos_x / pdf / h, pdf the density of Y in solid angle (h the element's exact
    unoccluded luminance at the point: it was picked with a probability in proportion to h).
    An emitter that subtends more than CLOSE sr (sph[0], from _spherical_of) is sampled
    uniformly in solid angle, its triangles by their solid angles (Arvo 1995: the weights stay
    bounded near a large emitter); a smaller one by area: a parallelogram (f1[e] < 0) along its
    sides, else its triangles by area (f1: the first's share), the square folded onto each."""
    if sph[0] > 0.0:
        x = (P[i, 0], P[i, 1], P[i, 2])
        A = (dirs[0, 0], dirs[0, 1], dirs[0, 2])
        C = (dirs[2, 0], dirs[2, 1], dirs[2, 2])
        om = sph[1] + sph[4]
        if u * om < sph[1] or f1[e] == 1.0:
            B = (dirs[1, 0], dirs[1, 1], dirs[1, 2])
            w = arvo(A, B, C, sph[1], sph[2], sph[3], min(u * om / sph[1], 1.0), v)
        else:
            D = (dirs[3, 0], dirs[3, 1], dirs[3, 2])
            w = arvo(A, C, D, sph[4], sph[5], sph[6], min((u * om - sph[1]) / sph[4], 1.0), v)
        pn = (nrm[e, 0], nrm[e, 1], nrm[e, 2])
        den = dot(w, pn)
        t = ((V[e, 0, 0] - x[0]) * pn[0] + (V[e, 0, 1] - x[1]) * pn[1]
             + (V[e, 0, 2] - x[2]) * pn[2]) / den if den != 0.0 else 0.0
        if t > 0.0:
            for q in range(3):
                Y[k, q] = x[q] + t * w[q]
            cosx = dot(w, (N[i, 0], N[i, 1], N[i, 2]))
            side = 0 if den < 0.0 else 1
            g = max(cosx, 0.0) * om / h
            for c3 in range(3):
                W[k, c3] = Le[e, side, c3] * g
            return
    if f1[e] < 0.0:                     # a parallelogram: (u, v) along its two sides
        b, c, b1, b2 = 1, 3, u, v
    else:
        if u < f1[e]:
            u = u / f1[e]
            b, c = 1, 2
        else:
            u = (u - f1[e]) / (1.0 - f1[e])
            b, c = 2, 3
        b1, b2 = (u, v) if u + v <= 1.0 else (1.0 - u, 1.0 - v)   # the square folded
    dx = dy = dz = 0.0
    for q in range(3):
        y = V[e, 0, q] + b1 * (V[e, b, q] - V[e, 0, q]) + b2 * (V[e, c, q] - V[e, 0, q])
        Y[k, q] = y
        if q == 0:
            dx = y - P[i, 0]
        elif q == 1:
            dy = y - P[i, 1]
        else:
            dz = y - P[i, 2]
    r2 = dx * dx + dy * dy + dz * dz
    cy = dx * nrm[e, 0] + dy * nrm[e, 1] + dz * nrm[e, 2]   # < 0: x on the front side
    cxn = dx * N[i, 0] + dy * N[i, 1] + dz * N[i, 2]
    if r2 <= 0.0 or cxn <= 0.0:
        for c3 in range(3):
            W[k, c3] = 0.0
        return
    side = 0 if cy < 0.0 else 1
    g = cxn * abs(cy) / (r2 * r2) * area[e] / h
    for c3 in range(3):
        W[k, c3] = Le[e, side, c3] * g


class DirectLight:
    """H1 at points of a scene, from its area emitters and its luminaires (Elements.luminaires:
    point and IES sources, exact: one shadow ray per luminaire and point, `_luminaires`).

    elements: the scene's Elements; ray_offset: the shadow rays' offset (settings.rays.offset);
    samples: shadow rays per point in the first pass, over all the lights it sees; seed: the
    offsets' seed; refine: a penumbra slot's rays after the second pass, in first-pass rays;
    shafts: prove lights clear with the occluder boxes before casting rays.
    """

    def __init__(self, elements, ray_offset: float, samples: int = 16, seed: int = 0,
                 refine: int = 4, shafts: bool = True):
        self.elements = elements
        self.emitters = AreaEmitters(elements)
        self.points = PointEmitters.of_scene(elements)
        self.ray_offset = float(ray_offset)
        self.samples = max(1, int(samples))
        self.seed = int(seed)
        self.refine = max(1, int(refine))
        self.shafts = bool(shafts)
        self._caster = None
        self._occ = None
        self.rays = 0                 # shadow rays cast so far (the benchmark's counts)
        self.pairs = self.cleared = 0  # (point, light) pairs with light; proven clear by shafts
        ids, self.light_of, self.lstart = _group(elements, np.flatnonzero(self.emitters.emitting()))
        self.ids = ids
        V = np.ascontiguousarray(elements.verts[ids], np.float64)
        nv = np.ascontiguousarray(elements.nverts[ids], np.int64)
        V[nv == 3, 3] = V[nv == 3, 2]
        a1 = 0.5 * np.linalg.norm(np.cross(V[:, 1] - V[:, 0], V[:, 2] - V[:, 0]), axis=1)
        a2 = 0.5 * np.linalg.norm(np.cross(V[:, 2] - V[:, 0], V[:, 3] - V[:, 0]), axis=1)
        a2[nv == 3] = 0.0
        Le = np.asarray(elements.emission, np.float64)[ids]
        self._V, self._nv = V, nv
        self._Lf, self._Lb = np.ascontiguousarray(Le[:, 0]), np.ascontiguousarray(Le[:, 1])
        para = (nv == 4) & np.all(np.abs(V[:, 0] + V[:, 2] - V[:, 1] - V[:, 3])
                                  <= 1e-9 * np.abs(V).max(axis=(1, 2))[:, None], axis=1)
        f1 = np.where(a1 + a2 > 0, a1 / np.maximum(a1 + a2, 1e-300), 1.0)
        self._em = (V, np.where(para, -1.0, f1),
                    np.ascontiguousarray(elements.normal[ids], np.float64), a1 + a2,
                    np.ascontiguousarray(Le.reshape(-1, 2, 3)))
        nL = len(self.lstart) - 1
        self._llo = np.array([V[self.light_of == L].reshape(-1, 3).min(0) for L in range(nL)])
        self._lhi = np.array([V[self.light_of == L].reshape(-1, 3).max(0) for L in range(nL)])
        pad = 1e-6 * float(np.ptp(elements.verts.reshape(-1, 3), axis=0).max() or 1.0)
        self._llo, self._lhi = self._llo.reshape(-1, 3) - pad, self._lhi.reshape(-1, 3) + pad
        nrm = self._em[2]
        self._flat = np.array([bool(np.all(np.abs(nrm[self.light_of == L] @ nrm[self.lstart[L]]
                                                  - 1.0) < 1e-9)) and np.ptp(
            V[self.light_of == L].reshape(-1, 3) @ nrm[self.lstart[L]]) < 2e-6 * np.abs(V).max()
            for L in range(nL)], bool)

    @property
    def caster(self):
        if self._caster is None:
            self._caster = caster_of(self.elements.verts, self.elements.nverts, self.ray_offset)
        return self._caster

    def _boxes(self):
        """(LO, HI) (b, 3): boxes over the elements that may block a segment from a point on an
        element to a light, the lights left out (_clear tests their own boxes): not those in a
        supporting plane of the scene's hull (tracing.rays._inner_scene), cut into OCCLUDER_BOXES
        groups at median centres; None where they are most of the scene (a terrain)."""
        if self._occ is None:
            el = self.elements
            keep = ~on_hull_planes(el.verts, el.nverts, el.normal)
            keep[self.ids] = False
            keep = np.flatnonzero(keep)
            if len(keep) > INNER_SHARE * len(el.verts):
                self._occ = (None,)
                return None
            groups = [keep] if len(keep) else []
            while 0 < len(groups) < OCCLUDER_BOXES and max(len(g) for g in groups) > 1:
                g = groups.pop(int(np.argmax([len(g) for g in groups])))
                c = el.center[g]
                o = np.argsort(c[:, int(np.argmax(np.ptp(c, axis=0)))], kind="stable")
                groups += [g[o[:len(g) // 2]], g[o[len(g) // 2:]]]
            pad = 1e-6 * self.caster.scale
            V = [el.verts[g].reshape(-1, 3) for g in groups]   # a triangle's slot 3: its slot 2
            self._occ = (np.array([v.min(0) - pad for v in V]).reshape(-1, 3),
                         np.array([v.max(0) + pad for v in V]).reshape(-1, 3))
        return None if self._occ[0] is None else self._occ

    def __getstate__(self):
        """Pickled without the Embree scene (not picklable): a worker builds its own on use."""
        return {**self.__dict__, "_caster": None}

    @property
    def lights(self) -> int:
        """How many lights (connected emitting elements of one Le) the scene has."""
        return len(self.lstart) - 1

    def __bool__(self) -> bool:
        return bool(len(self.ids)) or self.points.any()

    def irradiance(self, points: np.ndarray, normals: np.ndarray, elem: np.ndarray,
                   index: np.ndarray | None = None) -> np.ndarray:
        """(p, 3) W m^-2: H1 at `points` (p, 3) on elements `elem` (p,) (-1: on none), facing
        unit `normals` (p, 3) (the receiving side's). index (p,) int: the points' stable numbers
        for their sample offsets (None: 0..p-1)."""
        P = np.ascontiguousarray(points, np.float64)
        N = np.ascontiguousarray(normals, np.float64)
        E = np.ascontiguousarray(elem, np.int64)
        idx = np.arange(len(P), dtype=np.int64) if index is None else np.asarray(index, np.int64)
        out = np.zeros((len(P), 3))
        if not len(P):
            return out
        if self.points.any():
            out += self._luminaires(P, N, E, shadows=True)
        if not len(self.ids):
            return out
        step = max(64, min(BATCH_POINTS, BATCH_ENTRIES // len(self.ids)))
        for s in range(0, len(P), step):
            sl = slice(s, min(len(P), s + step))
            out[sl] += self._batch(P[sl], N[sl], E[sl], np.ascontiguousarray(idx[sl]))
        return out

    def unoccluded(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(p, 3) W m^-2: the exact H1 with every shadow ray taken as visible."""
        P = np.ascontiguousarray(points, np.float64)
        H0 = np.zeros((len(P), len(self.ids), 3))
        _unoccluded(P, np.ascontiguousarray(normals, np.float64), self._V, self._nv,
                    self._Lf, self._Lb, H0)
        out = H0.sum(axis=1)
        if self.points.any():
            out += self._luminaires(P, np.ascontiguousarray(normals, np.float64),
                                    np.full(len(P), -1, np.int64), shadows=False)
        return out

    def _luminaires(self, P, N, E, shadows: bool) -> np.ndarray:
        """(p, 3) W m^-2 from the luminaires, exact: I(direction) max(cos_x, 0) / r^2 V, I from
        the candela table toward the point, V one shadow ray per luminaire and lit point."""
        lums = self.points.luminaires
        out = np.zeros((len(P), 3))
        for k, y in enumerate(lums.positions):
            d = y[None] - P                                        # toward the luminaire
            r2 = np.einsum("pc,pc->p", d, d)
            r = np.sqrt(r2)
            cos_x = np.einsum("pc,pc->p", d, N) / np.where(r > 0, r, 1.0)
            lit = np.flatnonzero((cos_x > 0) & (r2 > 0))
            if not len(lit):
                continue
            E_k = lums.intensity_w(k, -d[lit] / r[lit, None]) * (cos_x[lit] / r2[lit])[:, None]
            go = np.flatnonzero(E_k.max(axis=1) > 0)
            if shadows and len(go):
                pts = np.concatenate([P[lit[go]], y[None]])
                vis = ~self.caster.occluded_pairs(pts, np.arange(len(go)),
                                                  np.full(len(go), len(go)),
                                                  np.concatenate([E[lit[go]], [-1]]))
                self.rays += len(go)
                E_k[go] *= vis[:, None]
            out[lit] += E_k
        return out

    def _batch(self, P, N, E, idx):
        nL = self.lights
        H0 = np.zeros((len(P), len(self.ids), 3))
        _unoccluded(P, N, self._V, self._nv, self._Lf, self._Lb, H0)
        HL = np.zeros((len(P), nL, 3))
        _lights(H0, self.light_of, nL, HL)
        clear = np.zeros((len(P), nL), bool)
        boxes = self._boxes() if self.shafts else None
        if boxes is not None:
            _clear(P, E, self._llo, self._lhi, self._flat, boxes[0], boxes[1], clear)
        seen = HL.max(axis=2) > 0
        self.pairs += int(seen.sum())
        self.cleared += int((clear & seen).sum())
        n = np.zeros((len(P), nL + 1), np.int64)
        pooled = np.zeros((len(P), nL), bool)
        _plan(np.ascontiguousarray(HL @ LUMA), clear, float(self.samples), n, pooled)
        lum_e = np.ascontiguousarray(H0 @ LUMA)
        sw, swv, cnt = self._pass(P, N, E, idx, lum_e, n, np.zeros_like(n), pooled)
        a, b = sw.sum(axis=1), swv.sum(axis=1)
        partial = (b > 0) & (b < a * (1 - 1e-12))
        if self.refine > 1 and partial.any():
            n2 = np.where(partial.reshape(n.shape), (self.refine - 1) * n, 0)
            a, b, c = self._pass(P, N, E, idx, lum_e, n2, n, pooled)
            sw, swv, cnt = sw + a, swv + b, cnt + c
        # per channel: a pooled slot's lights may differ in colour
        frac = np.where(sw > 0, swv / np.where(sw > 0, sw, 1.0),
                        (cnt[1] / np.maximum(cnt[0], 1.0))[:, None])
        frac[cnt[0] == 0] = 1.0
        frac = frac.reshape(len(P), nL + 1, 3)
        return (HL * np.where(pooled[..., None], frac[:, nL:], frac[:, :nL])).sum(axis=1)

    def _pass(self, P, N, E, idx, lum_e, n, j0, pooled):
        """Rays j0 .. j0 + n - 1 of each slot's sequence: per slot (flat, S = pb (nL + 1)) the
        sums of w and w V (S, 3) and the counts of rays and visible ones (2, S)."""
        S = n.size
        off = np.zeros(S + 1, np.int64)
        np.cumsum(n.ravel(), out=off[1:])
        R = int(off[-1])
        if not R:
            return np.zeros((S, 3)), np.zeros((S, 3)), np.zeros((2, S))
        Y = np.zeros((R, 3))
        Ye = np.zeros(R, np.int64)
        W = np.zeros((R, 3))
        Rs = np.zeros(R, np.int64)
        _fill(P, N, lum_e, self._em, self.lstart, n, j0, pooled, off[:-1].reshape(n.shape), idx,
              np.int64(self.seed), Y, Ye, W, Rs)
        self.rays += R
        pts = np.concatenate([P, Y])
        ia = Rs // n.shape[1]
        ib = len(P) + np.arange(R)
        vis = ~self.caster.occluded_pairs(pts, ia, ib, np.concatenate([E, self.ids[Ye]]))
        sw = np.stack([np.bincount(Rs, W[:, c], S) for c in range(3)], axis=1)
        swv = np.stack([np.bincount(Rs, W[:, c] * vis, S) for c in range(3)], axis=1)
        return (sw, swv,
                np.stack([np.bincount(Rs, None, S), np.bincount(Rs, vis, S)]).astype(float))


def _group(elements, ids):
    """The emitting elements `ids` ordered by light, the light of each (E,) and the lights'
    starts (nL + 1,): a light is a connected set (shared vertices) of elements of one Le. Within
    a light the elements follow a Morton curve, so that the first sample coordinate, which picks
    the element, sweeps the light region by region (stratification across its elements)."""
    if not len(ids):
        return ids, np.zeros(0, np.int64), np.zeros(1, np.int64)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V = np.asarray(elements.verts, np.float64)[ids]
    nv = np.asarray(elements.nverts)[ids]
    Le = np.asarray(elements.emission, np.float64)[ids].reshape(len(ids), -1)
    _, le_key = np.unique(Le, axis=0, return_inverse=True)
    span = float(np.ptp(V.reshape(-1, 3), axis=0).max()) or 1.0
    q = np.round(V / (1e-9 * span)).astype(np.int64)                      # (E, 4, 3)
    slot = np.arange(4)[None] < nv[:, None]                              # (E, 4)
    e_of = np.repeat(np.arange(len(ids)), 4).reshape(-1, 4)[slot]
    keys = np.concatenate([le_key.reshape(-1)[e_of][:, None], q[slot]], axis=1)
    _, vid = np.unique(keys, axis=0, return_inverse=True)
    vid = vid.reshape(-1)
    m = len(ids) + int(vid.max()) + 1
    g = coo_matrix((np.ones(len(e_of)), (e_of, len(ids) + vid)), shape=(m, m))
    _, comp = connected_components(g, directed=False)
    light = np.unique(comp[:len(ids)], return_inverse=True)[1].reshape(-1).astype(np.int64)
    order = np.lexsort((_morton(elements.center[ids]), light))
    light = light[order]
    return ids[order], np.ascontiguousarray(light), np.searchsorted(light, np.arange(light.max() + 2))


def _morton(c: np.ndarray) -> np.ndarray:
    """(n,) int64 Morton codes of the points c (n, 3), 10 bits an axis over their box."""
    lo, span = c.min(0), np.ptp(c, axis=0).max() or 1.0
    q = np.minimum(((c - lo) / span * 1024).astype(np.int64), 1023)
    code = np.zeros(len(c), np.int64)
    for b in range(10):
        for a in range(3):
            code |= ((q[:, a] >> b) & 1) << (3 * b + a)
    return code

