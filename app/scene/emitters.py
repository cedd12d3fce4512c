"""Emitters: every source of light in a scene behind one protocol, chosen by type from a registry.

Two types: area emitters, elements whose material emits (`Elements.emission`, Le per element
and side, W sr^-1 m^-2 per RGB channel), read through `AreaEmitters`; and point emitters, the
scene's [[luminaire]] tables (point sources and IES / EULUMDAT candela tables,
scene/luminaires.py, carried as `Elements.luminaires`), read through `PointEmitters`. A sky
(issue 52) plugs in beside them as one class and one `EMITTER_TYPES` line. Design note:
docs/src/design/scene-emitters.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from radiosity.core.colour import EFFICACY
from radiosity.core.sky import SKY_TYPES, luminance as sky_luminance, zenith_luminance
from radiosity.errors import RadiosityError, SceneError

#: What a scene without an emitter is told (a warning: it renders black, runtime/checks.py).
NO_EMITTER = "no element emits light (every emission is 0)"


@dataclass(frozen=True)
class EmitterSamples:
    """Shadow-ray samples of one emitter: where rays to a receiving point start and how much
    each stands for.

    position : (k, 3) float64, a point on the emitter (a point light: its position)
    normal : (k, 3) float64, unit front normal there (a point-like source: zeros, no cosine)
    weight : (k,) float64, 1 / (k pdf) in the emitter's measure: m^2 of surface for an area
        emitter (the stratum's area), sr for a sky, 1 for a point light
    source : (k,) int64, which part of the emitter a sample lies on (an element for area
        emitters; whatever the type indexes its radiance by otherwise)
    """

    position: np.ndarray
    normal: np.ndarray
    weight: np.ndarray
    source: np.ndarray

    def __len__(self) -> int:
        return len(self.weight)


@runtime_checkable
class Emitter(Protocol):
    """What every emitter type provides; units W, sr, m, per RGB channel.

    - `power()` (3,): the flux it emits, W per channel (the oracle's scale, energy checks).
    - `sample(n, rng)`: EmitterSamples, stratified (n per stratum count the type chooses;
      rng None: the strata's centres, deterministic), for shadow rays toward receiving points.
    - `intensity(samples, points)` (p, k, 3): what sample k sends toward point p, W sr^-1
      (area: L_e cos_y w_k; point and spot: I(direction) w_k; IES: the candela table; sky:
      L(direction) w_k as seen from p, with position at infinity). Direct irradiance at x with
      normal n is then sum_k intensity cos_x / r^2 V (`irradiance`), H1(x) of issue 50.
    - `irradiance_bound(lo, hi)` (3,): an upper bound on the irradiance any point of the box
      [lo, hi] can receive from it, whatever its normal and occlusion (the refinement oracle).

    A type is built by its registry entry's `of_scene(elements, entries)` (EMITTER_TYPES).
    """

    kind: str

    def power(self) -> np.ndarray: ...

    def sample(self, n: int, rng: np.random.Generator | None = None) -> EmitterSamples: ...

    def intensity(self, samples: EmitterSamples, points: np.ndarray) -> np.ndarray: ...

    def irradiance_bound(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray: ...


def area_emission(emis: np.ndarray, material: np.ndarray, two_sided: np.ndarray) -> np.ndarray:
    """Le (n, 2, 3) float64 of the elements from their materials' emission `emis` (m, 2, 3)
    ([front, back] RGB) and `material` (n,): a one-sided element's back emits nothing."""
    emission = emis[material].copy()
    emission[~two_sided, 1] = 0.0
    return emission


def _triangle_strata(k: int, rng: np.random.Generator | None) -> np.ndarray:
    """(k^2, 2) barycentric (b1, b2) of k x k equal-area strata of a triangle: the unit square's
    grid (centres, or jittered with rng) mapped by the area-preserving warp
    (b1, b2) = (sqrt(u) (1 - v), sqrt(u) v)."""
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    off = np.full((2, k, k), 0.5) if rng is None else rng.random((2, k, k))
    u = ((i + off[0]) / k).ravel()
    v = ((j + off[1]) / k).ravel()
    s = np.sqrt(u)
    return np.stack([s * (1.0 - v), s * v], axis=1)


class AreaEmitters:
    """The elements that emit, as Lambertian area emitters: radiance Le[i, side] leaves side
    `side` of element i in every direction of its half-space.

    Le : (n, 2, 3) float64, [front, back] RGB radiance (W sr^-1 m^-2), the elements' own array
    """

    kind = "area"

    def __init__(self, elements):
        self.elements = elements
        self.Le = elements.emission

    @classmethod
    def of_scene(cls, elements, entries=()) -> "AreaEmitters":
        """The registry's constructor: a type builds itself from the scene's elements and its
        entries of that type (area emitters need none: their materials say it)."""
        return cls(elements)

    # ---------------------------------------------------------------- per element, for the solve
    def radiance(self, index=None) -> np.ndarray:
        """Le (k, 2, 3) of the elements `index` (None: all, the array itself)."""
        return self.Le if index is None else self.Le[index]

    def side_vectors(self, index) -> np.ndarray:
        """Le (2, 3, k) float64, C-contiguous, of the elements `index`: the solvers' layout."""
        return np.ascontiguousarray(np.transpose(self.Le[index], (1, 2, 0)))

    def peak(self) -> np.ndarray:
        """(n, 2): the largest channel of Le per element and side."""
        return self.Le.max(axis=2)

    def emitting(self) -> np.ndarray:
        """(n,) bool: elements with some side emitting in some channel."""
        return self.Le.max(axis=(1, 2)) > 0

    def emitting_sides(self) -> np.ndarray:
        """(n, 2) bool: [front, back] emits in some channel."""
        return self.Le.max(axis=2) > 0.0

    def any(self) -> bool:
        return bool((self.Le > 0).any())

    def describe(self) -> str:
        """One line: how many elements emit and their power, or NO_EMITTER."""
        if not self.any():
            return NO_EMITTER
        p = ", ".join(f"{x:.4g}" for x in self.power())
        return f"{int(self.emitting().sum())} emitting elements, power ({p}) W"

    def grey(self) -> bool:
        """Every element's Le is the same in the three channels."""
        return bool(np.all(self.Le == self.Le[..., :1]))

    # ---------------------------------------------------------------- the Emitter protocol
    def power(self) -> np.ndarray:
        """(3,) W: the sum over elements and sides of Le pi A (a Lambertian side's exitance
        is pi Le)."""
        return math.pi * np.einsum("isc,i->c", np.asarray(self.Le, np.float64),
                                   np.asarray(self.elements.area, np.float64))

    def sample(self, n: int, rng: np.random.Generator | None = None) -> EmitterSamples:
        """n x n equal-area strata on each triangle of each emitting element (a quad is its two
        triangles v0 v1 v2, v0 v2 v3), one point per stratum; weight = the stratum's area."""
        el = self.elements
        idx = np.flatnonzero(self.emitting())
        bary = _triangle_strata(int(n), rng)                 # (s, 2)
        pos, nrm, w, src = [], [], [], []
        for t in (0, 1):
            ids = idx if t == 0 else idx[np.asarray(el.nverts, np.int64)[idx] == 4]
            v = np.asarray(el.verts, np.float64)[ids]
            a, b, c = v[:, 0], v[:, 1 + t], v[:, 2 + t]
            p = (a[:, None] + bary[None, :, :1] * (b - a)[:, None]
                 + bary[None, :, 1:] * (c - a)[:, None])   # (e, s, 3)
            area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
            pos.append(p.reshape(-1, 3))
            nrm.append(np.repeat(np.asarray(el.normal, np.float64)[ids], len(bary), axis=0))
            w.append(np.repeat(area / len(bary), len(bary)))
            src.append(np.repeat(ids.astype(np.int64), len(bary)))
        return EmitterSamples(np.concatenate(pos), np.concatenate(nrm), np.concatenate(w),
                              np.concatenate(src))

    def radiance_toward(self, samples: EmitterSamples, points: np.ndarray) -> np.ndarray:
        """(p, k, 3): Le of the side of sample k's element that faces point p (0 on its plane)."""
        d = np.asarray(points, np.float64)[:, None, :] - samples.position[None]
        cos = np.einsum("pkc,kc->pk", d, samples.normal)
        Le = np.asarray(self.Le, np.float64)[samples.source]           # (k, 2, 3)
        return np.where((cos > 0)[..., None], Le[None, :, 0], np.where((cos < 0)[..., None],
                                                                        Le[None, :, 1], 0.0))

    def intensity(self, samples: EmitterSamples, points: np.ndarray) -> np.ndarray:
        """(p, k, 3) W sr^-1: Le |cos_y| times the stratum's area."""
        d = np.asarray(points, np.float64)[:, None, :] - samples.position[None]
        r = np.linalg.norm(d, axis=2)
        cos = np.abs(np.einsum("pkc,kc->pk", d, samples.normal)) / np.where(r > 0, r, 1.0)
        return self.radiance_toward(samples, points) * (cos * samples.weight)[..., None]

    def irradiance_bound(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(3,) W m^-2: sum over emitting elements of Le_max min(pi, A / d^2), d the distance
        from the box [lo, hi] to the element's bounding box. A Lambertian patch of radiance L
        gives E = L int cos_x cos_y / r^2 dA <= L A / d^2, and never more than L pi."""
        el = self.elements
        idx = np.flatnonzero(self.emitting())
        v = np.asarray(el.verts, np.float64)[idx]
        gap = np.maximum(np.maximum(v.min(axis=1) - np.asarray(hi, float), 0.0),
                         np.maximum(np.asarray(lo, float) - v.max(axis=1), 0.0))
        d2 = (gap ** 2).sum(axis=1)
        A = np.asarray(el.area, np.float64)[idx]
        solid = np.where(d2 > 0, np.minimum(math.pi, A / np.where(d2 > 0, d2, 1.0)), math.pi)
        return (np.asarray(self.Le, np.float64)[idx].max(axis=1) * solid[:, None]).sum(axis=0)


class PointEmitters:
    """The scene's luminaires (scene/luminaires.Luminaires: point sources and IES / EULUMDAT
    candela tables) as point emitters: one sample each, at its position, weight 1, no normal;
    its intensity toward a point is the candela table in that direction, in W sr^-1 per channel
    (cd x colour / 683). Their direct light at points is exact: scene/direct.DirectLight casts
    one shadow ray per luminaire and point."""

    kind = "point"

    def __init__(self, luminaires):
        self.luminaires = luminaires

    @classmethod
    def of_scene(cls, elements, entries=()) -> "PointEmitters":
        """The luminaires that travel with the elements (Elements.luminaires)."""
        from radiosity.scene.luminaires import luminaires_of

        return cls(luminaires_of(elements))

    def __len__(self) -> int:
        return len(self.luminaires)

    def any(self) -> bool:
        return bool(len(self.luminaires))

    def describe(self) -> str:
        return self.luminaires.describe()

    def power(self) -> np.ndarray:
        """(3,) W: each luminaire's flux (the integral of its table) x colour / 683."""
        return self.luminaires.power()

    def sample(self, n: int = 1, rng: np.random.Generator | None = None) -> EmitterSamples:
        """One sample per luminaire whatever n: its position, weight 1, source its index."""
        k = len(self.luminaires)
        return EmitterSamples(self.luminaires.positions, np.zeros((k, 3)), np.ones(k),
                              np.arange(k, dtype=np.int64))

    def intensity(self, samples: EmitterSamples, points: np.ndarray) -> np.ndarray:
        """(p, k, 3) W sr^-1: luminaire source[k]'s intensity toward point p."""
        P = np.asarray(points, np.float64)
        out = np.zeros((len(P), len(samples), 3))
        for j, (y, src, w) in enumerate(zip(samples.position, samples.source, samples.weight)):
            d = P - y
            r = np.linalg.norm(d, axis=1)
            u = d / np.where(r > 0, r, 1.0)[:, None]
            out[:, j] = self.luminaires.intensity_w(int(src), u) * w
        return out

    def irradiance_bound(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(3,) W m^-2: sum over luminaires of I_max / d^2, d the distance from it to the box
        (inf for a luminaire inside the box)."""
        out = np.zeros(3)
        for lum in self.luminaires.items:
            gap = np.maximum(np.maximum(np.asarray(lo, float) - lum.position, 0.0),
                             np.maximum(lum.position - np.asarray(hi, float), 0.0))
            d2 = float(gap @ gap)
            peak = lum.peak_cd() * lum.colour / EFFICACY
            out = out + (peak / d2 if d2 > 0 else np.where(peak > 0, np.inf, 0.0))
        return out


def irradiance(emitter: Emitter, samples: EmitterSamples, points: np.ndarray,
               normals: np.ndarray, visible: np.ndarray | None = None) -> np.ndarray:
    """(p, 3) W m^-2: the direct irradiance at `points` (p, 3) with unit `normals` (p, 3) from
    `samples` of `emitter`, sum_k intensity cos_x / r^2 V; cos_x < 0 (the emitter behind the
    receiver's plane) counts 0. visible (p, k) bool: the shadow rays' verdict (None: unoccluded)."""
    P = np.asarray(points, np.float64)
    d = samples.position[None] - P[:, None, :]                          # (p, k, 3) toward y
    r2 = (d ** 2).sum(axis=2)
    cos_x = np.maximum(np.einsum("pkc,pc->pk", d, np.asarray(normals, np.float64)), 0.0)
    g = cos_x / np.where(r2 > 0, r2 * np.sqrt(r2), np.inf)
    if visible is not None:
        g = g * visible
    return np.einsum("pkc,pk->pc", emitter.intensity(samples, P), g)


#: Emitter types by the name a scene gives them: "area" (emitting materials), "point" (the
#: [[luminaire]] tables: point sources and IES / EULUMDAT candela tables, a spot being a table).
#: Planned (issue 52): "sky" (radiance by direction from infinity, sampled by solid angle,
#: bound pi L_max).
EMITTER_TYPES = {"area": AreaEmitters, "point": PointEmitters}


def emitter_type(name: str):
    """The emitter class registered as `name`; RadiosityError listing the known ones otherwise."""
    try:
        return EMITTER_TYPES[name]
    except KeyError:
        raise RadiosityError(f"unknown emitter type {name!r}: one of "
                             f"{', '.join(sorted(EMITTER_TYPES))}") from None


def area_emitters(elements) -> AreaEmitters:
    """The scene's area emitters (its emitting materials)."""
    return AreaEmitters(elements)


def point_emitters(elements) -> PointEmitters:
    """The scene's luminaires ([[luminaire]] tables) as point emitters."""
    return PointEmitters.of_scene(elements)


def emits(elements) -> bool:
    """Whether anything in the scene emits light: an emitting material or a luminaire."""
    return AreaEmitters(elements).any() or point_emitters(elements).any()


# ----------------------------------------------------------------------------- the sky
# Issue 52's daylight: a CIE standard overcast or uniform sky over a uniform ground
# (core/sky.py), at infinity, given by its unobstructed horizontal illuminance. A sample is a
# direction placed SKY_FAR scene diagonals from the scene's centre, and its intensity is scaled
# by the squared distance to each receiving point, so `irradiance`'s I cos / r^2 is L w cos,
# the sky's own integral. Not wired yet: scene files cannot say `[sky]` and the direct stage
# asks only the area emitters; this is the tested piece for that work.

#: Lux per W of Rec. 709 Y (stages/tables.py EFFICACY): the sky's lux become W per channel.
SKY_EFFICACY = EFFICACY
#: How far the samples stand, in scene diagonals: directions as seen from any point of the
#: scene then differ from the sample's own by at most about 1e-6 rad.
SKY_FAR = 1e6
SKY_KEYS = {"type", "horizontal_illuminance_lux", "ground_reflectance", "up"}


class SkyEmitter:
    """kind: "cie-overcast" | "uniform"; horizontal_lux: Eh; ground_reflectance: rho_g in
    [0, 1); up (3,): the zenith; centre (3,), diagonal: the scene's, for where samples stand.
    Grey: every channel carries Eh / 683 W m^-2."""

    kind = "sky"

    def __init__(self, sky: str, horizontal_lux: float, ground_reflectance: float = 0.0,
                 up=(0.0, 0.0, 1.0), centre=(0.0, 0.0, 0.0), diagonal: float = 1.0):
        if sky not in SKY_TYPES:
            raise SceneError(f"[sky] type {sky!r}: one of {', '.join(SKY_TYPES)}")
        if not (horizontal_lux > 0 and math.isfinite(horizontal_lux)):
            raise SceneError(f"[sky] horizontal_illuminance_lux must be a positive number, got "
                             f"{horizontal_lux!r}")
        if not 0.0 <= ground_reflectance < 1.0:
            raise SceneError(f"[sky] ground_reflectance must be in [0, 1), got {ground_reflectance!r}")
        up = np.asarray(up, np.float64)
        if up.shape != (3,) or not np.linalg.norm(up) > 0:
            raise SceneError(f"[sky] up must be a non-zero vector [x, y, z], got {up.tolist()!r}")
        self.sky, self.eh, self.rho_g = sky, float(horizontal_lux) / SKY_EFFICACY, float(ground_reflectance)
        self.up = up / np.linalg.norm(up)
        self.centre = np.asarray(centre, np.float64)
        self.radius = SKY_FAR * float(diagonal)
        self.diagonal = float(diagonal)

    @classmethod
    def of_scene(cls, elements, entries=()) -> "SkyEmitter":
        """The registry's constructor from the scene's one `[sky]` table (a dict; none: the
        defaults, a CIE overcast sky of 10 000 lx over a black ground)."""
        entries = list(entries)
        if len(entries) > 1:
            raise SceneError(f"a scene has one [sky], got {len(entries)}")
        entry = entries[0] if entries else {}
        extra = set(entry) - SKY_KEYS
        if extra:
            raise SceneError(f"[sky]: unknown key {sorted(extra)[0]!r} (known: {', '.join(sorted(SKY_KEYS))})")
        v = np.asarray(elements.verts, np.float64).reshape(-1, 3)
        lo, hi = v.min(axis=0), v.max(axis=0)
        return cls(str(entry.get("type", "cie-overcast")),
                   float(entry.get("horizontal_illuminance_lux", 10_000.0)),
                   float(entry.get("ground_reflectance", 0.0)), entry.get("up", (0.0, 0.0, 1.0)),
                   (lo + hi) / 2, float(np.linalg.norm(hi - lo)) or 1.0)

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """(k,) W sr^-1 m^-2 per channel toward unit `directions` (k, 3) (away from the scene)."""
        return sky_luminance(self.sky, self.eh, self.rho_g, np.asarray(directions) @ self.up)

    def _basis(self) -> np.ndarray:
        a = np.array([1.0, 0.0, 0.0]) if abs(self.up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(self.up, a)
        u /= np.linalg.norm(u)
        return np.stack([u, np.cross(self.up, u), self.up])

    # ---------------------------------------------------------------- the Emitter protocol
    def power(self) -> np.ndarray:
        """(3,) W: the flux the sky sends down through a horizontal disc of the scene's
        half-diagonal (a sky's own power is unbounded; this is the scale the scene sees)."""
        return np.full(3, self.eh * math.pi * (self.diagonal / 2) ** 2)

    def sample(self, n: int, rng: np.random.Generator | None = None) -> EmitterSamples:
        """2 n x n equal solid-angle strata of the sphere (cos of the zenith angle in [-1, 1],
        n x 2n cells of the azimuth; the horizon is a stratum edge), one direction each;
        weight = the stratum's solid angle (sr)."""
        n = int(n)
        i, j = np.meshgrid(np.arange(n), np.arange(2 * n), indexing="ij")
        off = np.full((2, n, 2 * n), 0.5) if rng is None else rng.random((2, n, 2 * n))
        c = (-1.0 + 2.0 * (i + off[0]) / n).ravel()
        phi = (2.0 * math.pi * (j + off[1]) / (2 * n)).ravel()
        s = np.sqrt(np.maximum(0.0, 1.0 - c * c))
        local = np.stack([s * np.cos(phi), s * np.sin(phi), c], axis=1)
        d = local @ self._basis()
        k = len(d)
        return EmitterSamples(self.centre + self.radius * d, np.zeros((k, 3)),
                              np.full(k, 4.0 * math.pi / k), np.zeros(k, np.int64))

    def intensity(self, samples: EmitterSamples, points: np.ndarray) -> np.ndarray:
        """(p, k, 3) W sr^-1: L(direction k) w_k |y_k - x_p|^2, so that the protocol's
        I cos / r^2 is L w cos (the sky at infinity)."""
        d = (samples.position - self.centre) / self.radius
        L = self.radiance(d) * samples.weight                                   # (k,)
        r2 = ((samples.position[None] - np.asarray(points, np.float64)[:, None]) ** 2).sum(axis=2)
        return np.repeat((L[None] * r2)[..., None], 3, axis=2)

    def irradiance_bound(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(3,) W m^-2: pi times the largest radiance of sky and ground, whatever the box."""
        top = zenith_luminance(self.sky, self.eh)  # the brightest sky direction: the zenith
        return np.full(3, math.pi * max(top, self.rho_g * self.eh / math.pi))


EMITTER_TYPES["sky"] = SkyEmitter
