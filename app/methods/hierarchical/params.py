"""The link stage's settings, resolved once on the driver (SPEC §8, §9, §10): the refinement's
parameters (LinkParams, resolve_params), the epsilon for a raster size (choose_epsilon), where
the emitters' light is taken (choose_direct: at points or through the links) and the oracle's
weights, the cluster layer's with the receivers no camera sees weighed less (oracle_weights,
cluster_weights).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from radiosity.core.geometry import COS_TOL
from radiosity.errors import RadiosityError
from radiosity.methods.hierarchical.links.refine import RefineParams
from radiosity.scene.emitters import AreaEmitters

WEIGHTS = ("none", "bf", "arriving")
ORACLES = ("ff", "gradient", "spread")
FAR_KERNELS = ("centroid", "polygon", "gauss")


def _far_kernel(name: str) -> int:
    if name not in FAR_KERNELS:
        raise RadiosityError(f"radiosity.hierarchy.far-kernel must be one of "
                             f"{', '.join(FAR_KERNELS)}, got {name!r}")
    return FAR_KERNELS.index(name)


def _oracle_id(name: str) -> int:
    if name not in ORACLES:
        raise RadiosityError(f"radiosity.hierarchy.oracle must be one of {', '.join(ORACLES)}, "
                             f"got {name!r}")
    return ORACLES.index(name)


# ----------------------------------------------------------------------------- inputs

@dataclass(frozen=True)
class LinkParams:
    """The refinement settings (resolved on the driver). direct: the emitters' light is taken
    at points (choose_direct), the oracle weighs sources by their first bounce, not by Le.

    epsilon: oracle threshold; shadow: threshold for splitting partly visible links; near:
    near-field factor (node sizes); min_size: size limit (sqrt of area, scene units) for
    splitting unseen originals; rays: sample rays per link (1: centroids); kid: 0 point, 1 disc
    (kept far links); exact: kept near links get the exact polygon form factor; plane_tol:
    distance (scene units) within which a vertex counts as on a plane; occlusion: False when
    nothing can block (scene/effects.py); hull_shafts: before rays, links test their candidate
    occluders against their polygons' planes (1) or tight shaft (2), and with N > 2 those
    without a list walk N occluder-tree nodes for one in it (refine.RefineParams.hull); 0 (the
    default: none pays for its cost, docs/src/design/methods-hierarchical-links.md): the
    boxes' shafts alone. smooth (direct.oracle smooth, with direct): the oracle weighs links by
    how far the light after the first bounce is from its mean, relative to the receiver's own
    radiance (smooth_weights, smooth_floor)."""

    epsilon: float
    shadow: float
    near: float
    min_size: float
    rays: int
    kid: int
    exact: bool
    plane_tol: float
    occlusion: bool = True
    oracle: int = 2
    gauss_gap: float = 2.0
    far_polygon: int = 1
    weighted_rays: bool = True
    direct: bool = False
    solids: bool = True
    hull_shafts: int = 0
    smooth: bool = False
    smooth_floor: float = 0.25

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    def smooth_args(self) -> float | None:
        """smooth_weights' floor, None where the oracle is not smooth."""
        return self.smooth_floor if self.smooth and self.direct else None

    def kernel_params(self) -> RefineParams:
        """The scalars the refinement kernels read (refine.RefineParams)."""
        return RefineParams(self.epsilon, self.shadow, self.near, self.min_size, self.kid,
                            self.exact, self.plane_tol, self.oracle, self.gauss_gap,
                            self.far_polygon, self.occlusion, int(self.hull_shafts))


def choose_direct(elements, settings) -> tuple[str, str]:
    """(mode, why): where the hierarchical method takes the emitters' light (SPEC §10),
    direct.mode: points or links as stated; auto: points when something emits and the emitting
    originals' area is at most direct.auto-share of the scene's (a lamp, windows: their light
    is sharp, the light after its first bounce smooth), links where emitters cover more (a
    furnace, where every surface emits: the split would only add shadow rays)."""
    d = settings.direct
    if d.mode not in ("auto", "points", "links"):
        raise RadiosityError(f"radiosity.direct.mode must be auto, points or links, got {d.mode!r}")
    from radiosity.scene.emitters import point_emitters

    lums = point_emitters(elements)
    if lums.any():        # links cannot carry a point source: its light is taken at points
        if d.mode == "links":
            raise RadiosityError(f"radiosity.direct.mode = links cannot carry the scene's "
                                 f"{lums.describe()} (point sources): use points or auto")
        return "points", f"points: {lums.describe()} (point sources: their light at points)"
    if d.mode != "auto":
        return d.mode, f"{d.mode}: stated (--direct {d.mode})"
    em = AreaEmitters(elements).emitting()
    if not em.any():
        return "links", "links: auto, nothing emits"
    A = np.asarray(elements.area, np.float64)
    share = float(A[em].sum() / A.sum())
    lim = float(d.auto_share)
    if share <= lim:
        return "points", (f"points: auto, emitters {share:.1%} of the area (<= auto-share "
                          f"{lim:g}): their light at points, links after its first bounce")
    return "links", (f"links: auto, emitters {share:.0%} of the area (> auto-share {lim:g}): "
                     f"all light through the links")


#: Shadow rays per emitting element for direct_estimate (an estimate for the oracle only).
ESTIMATE_SAMPLES = 4
_ESTIMATES: dict = {}


def direct_estimate(elements, ray_offset: float) -> np.ndarray:
    """(n, 2): the largest channel of rho H1 / pi at each original's centroid, per side (front
    normal, back -normal): the first bounce the original sends on as a link source when the
    emitters' light is taken at points (SPEC §10), from ESTIMATE_SAMPLES shadow rays per
    emitting element (scene/direct.DirectLight; n points, nothing n x n). Kept per scene."""
    from dask.base import tokenize

    from radiosity.scene.direct import DirectLight

    key = tokenize(elements.verts, elements.nverts, elements.emission, elements.reflectance,
                   float(ray_offset), getattr(elements, "luminaires", None))
    if key in _ESTIMATES:
        return _ESTIMATES[key]
    n = len(elements)
    out = np.zeros((n, 2))
    light = DirectLight(elements, ray_offset, samples=ESTIMATE_SAMPLES)
    rho = np.asarray(elements.reflectance, np.float64)
    for side, sign in ((0, 1.0), (1, -1.0)):
        on = np.flatnonzero(rho[:, side].max(axis=1) > 0)
        if light and len(on):
            H = light.irradiance(elements.center[on], sign * elements.normal[on], on,
                                 index=on * 2 + side)
            out[on, side] = (rho[on, side] * H).max(axis=1) / np.pi
    _ESTIMATES.clear()
    _ESTIMATES[key] = out
    return out


def oracle_weights(elements, weight: str, direct: np.ndarray | None = None,
                   smooth: float | None = None):
    """The oracle's weights: link p <- q counts F_pq * wrho[p, side] * lhat[q, side] / lref.

    none: all 1 (form factors alone). bf: wrho = the largest channel of the reflectance of that
    side (arriving: 1, the light that arrives counts whatever the receiver reflects:
    hierarchy.receiver); lhat = the largest channel of the emission plus an ambient estimate
    La = E rho / (1 - rho) (E, rho: area-weighted means over the scene); lref = E + La, the
    mean radiance one expects. direct (n, 2) (the emitters' light taken at points:
    direct_estimate): lhat = direct + La rho, the original's own first bounce and the light
    after the second (La less its first bounce E rho), never the emission (emitters are no
    link sources then, SPEC §10). smooth (LinkParams.smooth_args; with direct): as
    smooth_weights changes them. Returns wrho (n, 2), lhat (n, 2), lref."""
    n = len(elements)
    if weight == "arriving":  # bf for the light that arrives, whatever the receiver reflects
        wrho, lhat, lref = oracle_weights(elements, "bf", direct, smooth)
        return np.ones_like(wrho), lhat, lref
    if weight == "none":
        return np.ones((n, 2)), np.ones((n, 2)), 1.0
    if weight != "bf":
        raise RadiosityError(f"radiosity.hierarchy.weight must be one of {', '.join(WEIGHTS)}, "
                             f"got {weight!r}")
    rho = elements.reflectance.max(axis=2)   # (n, 2)
    em = AreaEmitters(elements).peak()
    E, r, La = ambient(elements, direct is not None)
    lref = E + La
    if lref <= 0:
        return np.ones((n, 2)), np.ones((n, 2)), 1.0
    if direct is None:
        return rho, em + La, lref
    lhat = np.asarray(direct, np.float64) + La * r
    if smooth is None:
        return rho, lhat, lref
    return smooth_weights(elements, rho, lhat, lref, direct, smooth)


def ambient(elements, points: bool = False) -> tuple[float, float, float]:
    """(E, r, La) of oracle_weights: the area-weighted mean emission E (largest channel; with
    points, direct light taken at points, the luminaires' flux spread over the scene as an
    exitance too) and reflectance r (front sides, at most 0.99), and the ambient radiance
    La = E r / (1 - r), the mean light after the emitters' (all bounces) of a scene where every
    point sees the same."""
    A = elements.area
    rho = elements.reflectance.max(axis=2)
    em = AreaEmitters(elements).peak()
    E = float((A * em.sum(axis=1)).sum() / A.sum())
    if points:
        from radiosity.scene.emitters import point_emitters

        E += float(point_emitters(elements).power().max(initial=0.0)) / (math.pi * A.sum())
    r = float(min((A * rho[:, 0]).sum() / A.sum(), 0.99))
    return E, r, E * r / (1.0 - r)


def smooth_weights(elements, wrho, lhat, lref, direct, floor: float):
    """The oracle's weights where the emitters' light is taken at points and the links carry
    only R, the light after its first bounce (direct.oracle smooth, SPEC §10;
    docs/src/design/direct-light.md, "The oracle after the split"). Two changes to
    oracle_weights':

    - receiving: a link's error counts relative to the receiver's own radiance where that is
      above lref (wrho times lref / max(lref, Le + L1 + rho La), per side): under strong direct
      light what the links bring is a small share of what the image shows there;
    - sending: R is smooth, about its mean La everywhere but where the first bounce adds to
      it. A uniform R reaches a receiver through its links as the sum of their form factors,
      which the links to one receiver get right together (the sum of the mean over the
      receiver of every F is the mean of the fraction of its hemisphere that meets geometry;
      exactly where the rows are balanced to 1, in closed scenes) even where each one alone is
      off: a link's error is its form factor's error times how far its source's R is from
      uniform, lhat = |lhat - La| + floor La (never above lhat), the floor for the uniform part
      the sum does not get right (links to one receiver at different levels).

    Returns wrho, lhat, lref."""
    _, _, La = ambient(elements, True)
    rho = elements.reflectance.max(axis=2)
    em = AreaEmitters(elements).peak()
    own = em + np.asarray(direct, np.float64) + rho * La
    wrho = np.asarray(wrho, np.float64) * (lref / np.maximum(own, lref))
    if La > 0:
        lhat = smooth_source(lhat, La, floor)
    return wrho, lhat, lref


def smooth_source(lhat: np.ndarray, mean: float, floor: float) -> np.ndarray:
    """A source's smooth weight (smooth_weights): |lhat - mean| + floor mean, never above lhat
    (a source dimmer than the mean carries no more than its own light)."""
    lhat = np.asarray(lhat, np.float64)
    return np.minimum(lhat, np.abs(lhat - mean) + float(floor) * mean)


def cluster_weights(elements, weight: str, seen: np.ndarray, importance: float,
                    direct: np.ndarray | None = None, smooth: float | None = None):
    """The cluster layer's oracle weights: oracle_weights, with the receiving weight wrho of
    the originals no camera sees (`seen` False) times `importance` (Smits, Arvo & Salesin
    1992's importance, one value for all unseen receivers): their light reaches the image only
    after a bounce off a seen surface, which passes on at most its reflectance of their error,
    spread over what they light. direct, smooth: as oracle_weights takes them."""
    wrho, lhat, lref = oracle_weights(elements, weight, direct, smooth)
    if importance != 1.0:
        wrho = wrho * np.where(np.asarray(seen, bool), 1.0, float(importance))[:, None]
    return wrho, lhat, lref


def choose_epsilon(settings, pixels: int | None = None) -> tuple[float, str]:
    """The links' epsilon and why, from a settings.Settings or its hierarchy section: a number
    (hierarchy.epsilon) as given; `auto`: epsilon-base for a criterion raster of up to
    epsilon-resolution^2 pixels, times epsilon-resolution / sqrt(pixels) above. A link's error
    estimate is first order in its nodes' size and the leaves shrink like 1 / sqrt(pixels): at a
    fixed epsilon a finer image keeps the same links over smaller leaves, so its error stops
    falling (MEASURED in radiosity.yaml). pixels None (before the camera's raster exists): the
    base."""
    h = getattr(settings, "hierarchy", settings)
    v = h.epsilon
    if v != "auto":
        try:
            eps = float(v)
        except (TypeError, ValueError):
            raise RadiosityError(f"radiosity.hierarchy.epsilon must be a number >= 0 or auto, "
                                 f"got {v!r}") from None
        if not eps >= 0:
            raise RadiosityError(f"--epsilon must be >= 0, got {eps}")
        return eps, "stated"
    base = float(h.epsilon_base)
    res0 = float(h.epsilon_resolution)
    if not (base >= 0 and res0 > 0):
        raise RadiosityError(f"radiosity.hierarchy.epsilon-base must be >= 0 and epsilon-resolution "
                             f"> 0, got {base} and {res0}")
    r = float(np.sqrt(pixels)) if pixels else 0.0
    if r <= res0:
        return base, f"auto: {base:g} up to {res0:g}^2 pixels"
    return base * res0 / r, (f"auto: {base:g} x {res0:g} / {r:.0f} (finer leaves than at "
                             f"{res0:g}^2 pixels get finer links)")


def resolve_params(elements, settings, occlusion: bool = True,
                   pixels: int | None = None) -> tuple[LinkParams, str]:
    """The link settings from the run's settings.Settings, checked; returns (LinkParams,
    weight). epsilon `auto` (the default): choose_epsilon's for a criterion raster of `pixels`
    (None: its base)."""
    from radiosity.core.kernels import KERNELS, base_kernel, kernel_id
    s = settings
    h = s.hierarchy
    kernel = h.kernel
    kernel_id(kernel)
    if base_kernel(kernel) not in ("point", "disc"):
        raise RadiosityError(f"--method hierarchical supports the kernels point, disc, point-nf "
                             f"and disc-nf (links sample their own rays: --link-rays), not {kernel!r}")
    eps, _ = choose_epsilon(h, pixels)
    k = int(h.link_rays)
    if k < 1 or int(round(np.sqrt(k))) ** 2 != k:
        raise RadiosityError(f"--link-rays must be a square (1, 4, 9, 16, ...), got {k}")
    if not float(h.clusters_epsilon) > 0:
        raise RadiosityError("radiosity.hierarchy.clusters-epsilon must be above 0, got "
                             f"{h.clusters_epsilon}")
    if not 0 < float(h.unseen_importance) <= 1:
        raise RadiosityError("radiosity.hierarchy.unseen-importance must be in (0, 1], got "
                             f"{h.unseen_importance}")
    weight = h.weight
    if weight not in WEIGHTS:
        raise RadiosityError(f"radiosity.hierarchy.weight must be one of {', '.join(WEIGHTS)}, "
                             f"got {weight!r}")
    if weight == "bf" and getattr(h, "receiver", "reflected") == "arriving":
        weight = "arriving"  # illuminance asked for (grids): hierarchy.receiver
    v = elements.verts.reshape(-1, 3)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    prm = LinkParams(epsilon=eps, shadow=eps * float(h.shadow_factor),
                     near=float(s.solve.near_field_factor),
                     min_size=float(h.min_node_size) * diag, rays=k,
                     kid=0 if base_kernel(kernel) == "point" else 1,
                     exact=bool(KERNELS[kernel].near_field), plane_tol=COS_TOL * diag,
                     occlusion=bool(occlusion), oracle=_oracle_id(h.oracle),
                     gauss_gap=float(h.near_gauss_gap), far_polygon=_far_kernel(h.far_kernel),
                     weighted_rays=bool(h.kernel_weighted_rays),
                     solids=bool(h.inside_solids) and bool(occlusion),
                     direct=choose_direct(elements, s)[0] == "points",
                     **smooth_params(s))
    return prm, weight


def smooth_params(settings) -> dict:
    """LinkParams' smooth and smooth_floor from direct.oracle and direct.smooth-floor."""
    d = settings.direct
    mode = d.oracle
    if mode not in ("smooth", "plain"):
        raise RadiosityError(f"radiosity.direct.oracle must be smooth or plain, got {mode!r}")
    floor = float(d.smooth_floor)
    if not floor >= 0:
        raise RadiosityError(f"radiosity.direct.smooth-floor must be >= 0, got {floor}")
    return {"smooth": mode == "smooth", "smooth_floor": floor}
