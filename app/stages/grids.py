"""Illuminance on calculation grids (issue 52; the grids: scene/grids.py): at points anywhere,
seen by a camera or not, from a solved run, and the grids' files.

At a point x with unit normal n (SPEC §10):
- direct: H1(x) from every emitter, scene/direct.DirectLight.irradiance (exact unoccluded part,
  shadow rays for the visible share), whatever the run's direct.mode;
- indirect: the light reflected by every surface x sees, gathered from the solution: per
  sub-element j, pi F(x -> j) V(x, j) (L_j - Le_j), F the exact point-to-polygon form factor
  (scene/grids.point_form_factors), V the share of up to 4 rays from x to points of j (one to
  its centroid beyond RAY_FAR sizes), L_j - Le_j the radiance j reflects on the side facing x.
  solution/radiance holds Le + reflected light in both direct modes (with links the leaves
  carry the first bounce through the links; with points it is added at the leaf points), so
  subtracting Le never counts the emitters' light twice, and the point's own surface does not
  enter (a point on a black floor or in mid-air alike).
illuminance = maintenance_factor x EFFICACY x Y(direct + indirect) (tables.py's conversion).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from radiosity.core.colour import EFFICACY, LUMA
from radiosity.formats.csvtext import write_csv
from radiosity.runtime.store import StageFigures
from radiosity.scene.direct import DirectLight
from radiosity.scene.grids import point_form_factors

#: The point-to-disc kernel beyond this many times a sub-element's size (as views/points.FAR).
FAR = 6.0
#: One visibility ray to a sub-element's centroid beyond this many times its size, else 4.
RAY_FAR = 6.0
#: (point, sub-element) entries per batch at most (the dense form-factor block, 12 bytes each).
BATCH_ENTRIES = 1 << 22
#: First-pass shadow rays a grid point takes (over all the lights it sees; scene/direct.py:
#: a penumbra's points take 4 times more). A grid has few points and each is a number a
#: lighting engineer reads: in the obstruction case (scenes/cie171/obstruction) deep in the
#: penumbra (visible share 0.1) 16 rays were off by up to 30 %, 64 by 6 %, 256 by 1.4 %,
#: 1024 by 0.3 % (docs/src/measurements/cie171.md).
GRID_SHADOW_RAYS = 1024
#: ... and the centre of a black sub-element for the tables (an area's mean, not a point).
TABLE_SHADOW_RAYS = 256
#: Black (sub-element, sub-element) pairs above which the tables gather the light that
#: reaches black sub-elements from the originals (their area-weighted mean radiance) instead
#: of the sub-elements: the indirect light is smooth, and the cost stays black x originals.
BLACK_PAIRS = 1 << 26
#: The column a sky will fill (issue 52's daylight): not written until a run has a sky.
DAYLIGHT_COLUMN = "daylight_factor_percent"


@dataclass(frozen=True)
class GridResult:
    """One grid's answer: its Grid, and per point the direct and indirect irradiance (k, 3)
    W m^-2 (before the maintenance factor) and the illuminance columns (lx, after it)."""

    grid: object
    direct: np.ndarray
    indirect: np.ndarray
    efficacy: float = EFFICACY

    def lux(self, part: str = "total") -> np.ndarray:
        """(k,) lx, maintenance factor applied: part total, direct or indirect."""
        H = {"total": self.direct + self.indirect, "direct": self.direct,
             "indirect": self.indirect}[part]
        return self.grid.maintenance_factor * self.efficacy * (H @ LUMA)

    def table(self) -> dict:
        """The grid's CSV columns: x, y, z, nx, ny, nz, illuminance_lux, direct_lux,
        indirect_lux (a sky adds DAYLIGHT_COLUMN here)."""
        g = self.grid
        t = {c: g.points[:, i] for i, c in enumerate("xyz")}
        t.update({f"n{c}": g.normals[:, i] for i, c in enumerate("xyz")})
        t["illuminance_lux"] = self.lux()
        t["direct_lux"] = self.lux("direct")
        t["indirect_lux"] = self.lux("indirect")
        return t

    def stats(self) -> dict:
        """min / average / max lx and U0 = Emin / Eavg (the lighting engineer's uniformity)."""
        e = self.lux()
        avg = float(e.mean())
        return {"name": self.grid.name, "points": int(len(e)), "min_lux": float(e.min()),
                "average_lux": avg, "max_lux": float(e.max()),
                "uniformity_u0": float(e.min() / avg) if avg > 0 else None,
                "maintenance_factor": float(self.grid.maintenance_factor)}


def indirect_at(P, N, part, elements, radiance, caster, ray_far: float = RAY_FAR) -> np.ndarray:
    """(p, 3) W m^-2: the irradiance at points P (p, 3), unit normals N (p, 3), from the light
    the sub-elements of `part` reflect (radiance (m, 2, 3), solution/radiance, less the
    emission), with occlusion by rays from the point (module docstring)."""
    from radiosity.scene.emitters import AreaEmitters

    orig = np.asarray(part.orig, np.int64)
    Le = np.asarray(AreaEmitters(elements).radiance(), np.float64)[orig]
    Lr = np.maximum(np.asarray(radiance, np.float64) - Le, 0.0)
    Lr[~np.asarray(elements.two_sided, bool)[orig], 1] = 0.0  # a one-sided back sends nothing
    Lr = np.ascontiguousarray(Lr)
    V = np.ascontiguousarray(part.verts, np.float64)
    nv = np.ascontiguousarray(part.nverts, np.int64)
    C = np.ascontiguousarray(part.center, np.float64)
    Nm = np.ascontiguousarray(part.normal, np.float64)
    A = np.ascontiguousarray(part.area, np.float64)
    m = len(A)
    out = np.zeros((len(P), 3))
    if not m or not len(P) or not Lr.any():
        return out
    step = max(1, BATCH_ENTRIES // m)
    for s in range(0, len(P), step):
        Pb = np.ascontiguousarray(P[s:s + step], np.float64)
        Nb = np.ascontiguousarray(N[s:s + step], np.float64)
        F = np.zeros((len(Pb), m))
        S = np.zeros((len(Pb), m), np.int8)
        point_form_factors(Pb, Nb, V, nv, C, Nm, A, Lr, FAR, F, S)
        I, J = np.nonzero(F)
        f = F[I, J]
        # visibility: rays from the point to up to 4 points of the sub-element (halfway from
        # its centroid to its corners), one to the centroid where it is far
        d2 = np.sum((C[J] - Pb[I]) ** 2, axis=1)
        one = d2 > ray_far * ray_far * A[J]
        k = np.where(one, 1, nv[J].clip(max=4))
        own = np.repeat(np.arange(len(I)), k)
        corner = np.arange(len(own)) - np.repeat(np.cumsum(k) - k, k)
        Q = np.where(one[own, None], C[J[own]],
                     C[J[own]] + 0.5 * (V[J[own], corner] - C[J[own]]))
        blocked = caster.occluded(Pb[I[own]], Q)
        vis = np.bincount(own, ~blocked, minlength=len(I)) / k
        w = math.pi * f * vis
        L = Lr[J, S[I, J]]
        for c in range(3):
            out[s:s + len(Pb), c] = np.bincount(I, w * L[:, c], minlength=len(Pb))
    return out


def illuminate(rs, settings, grids) -> list:
    """GridResult of each Grid of `grids` in the solved run `rs` (runtime.store.RunStore)."""
    from radiosity.tracing.rays import caster_of

    el = rs.load_elements()
    part = rs.load_partition()
    radiance = rs.read_arrays("solution")["radiance"]
    offset = float(settings.rays.offset)
    light = DirectLight(el, offset, samples=max(GRID_SHADOW_RAYS, int(settings.direct.samples)))
    caster = caster_of(el.verts, el.nverts, offset)
    out = []
    for g in grids:
        P, N = g.points, g.normals
        H1 = light.irradiance(P, N, np.full(len(P), -1, np.int64))
        Hr = indirect_at(P, N, part, el, radiance, caster)
        out.append(GridResult(g, H1, Hr))
    return out


@dataclass(frozen=True)
class GridFigures(StageFigures):
    """The grids' figures (report.json, section "grids"): per grid its files and min / average
    / max lx and U0."""

    SECTION = "grids"
    grids: list

    def rows(self):
        return grid_rows(self.to_dict())


def grid_rows(section: dict | None) -> list[tuple[str, str]]:
    """The CLI's rows for report.json's "grids" section: one per grid."""
    def u0(g):
        return "n/a" if g["uniformity_u0"] is None else f"{g['uniformity_u0']:.3f}"

    return [(f"grid {g['name']}",
             f"{g['average_lux']:.4g} lx average, {g['min_lux']:.4g} .. {g['max_lux']:.4g} lx, "
             f"U0 {u0(g)}" + (f", MF {g['maintenance_factor']:g}"
                              if g["maintenance_factor"] != 1 else "") + f" ({g['files'][0]})")
            for g in (section or {}).get("grids", [])]


def write_grids(run_dir: str, results: list) -> GridFigures:
    """RUN/grids/NAME.csv and NAME.png per grid, section "grids" of report.json."""
    d = os.path.join(run_dir, "grids")
    os.makedirs(d, exist_ok=True)
    rows = []
    prev = {}
    try:
        import json

        with open(os.path.join(run_dir, "report.json")) as f:
            prev = {g["name"]: g for g in json.load(f).get("grids", {}).get("grids", [])}
    except (OSError, ValueError):
        pass
    for r in results:
        name = r.grid.name
        write_csv(os.path.join(d, f"{name}.csv"), r.table())
        files = [f"grids/{name}.csv"]
        if r.grid.shape:
            write_map(os.path.join(d, f"{name}.png"), r)
            files.append(f"grids/{name}.png")
        prev[name] = {**r.stats(), "files": files}
    fig = GridFigures(grids=list(prev.values()))
    fig.write(run_dir)
    return fig


def write_map(path: str, r: GridResult) -> None:
    """A false-colour map of a regular grid's illuminance with isolux lines and a scale (lx)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    g = r.grid
    nu, nv = g.shape
    E = r.lux().reshape(nu, nv)
    lu, lv = float(np.linalg.norm(g.u)), float(np.linalg.norm(g.v))
    fig = Figure(figsize=(6.0, 6.0 * min(2.0, max(0.5, lv / lu))), dpi=100)
    ax = fig.add_subplot()
    ext = (0.0, lu, 0.0, lv)
    im = ax.imshow(E.T, origin="lower", extent=ext, cmap="viridis", interpolation="nearest",
                   aspect="equal")
    if nu > 1 and nv > 1 and np.ptp(E) > 0:
        x = (np.arange(nu) + 0.5) / nu * lu
        y = (np.arange(nv) + 0.5) / nv * lv
        cs = ax.contour(x, y, E.T, levels=8, colors="white", linewidths=0.7)
        ax.clabel(cs, fmt="%.0f", fontsize=7)
    fig.colorbar(im, ax=ax, label="illuminance (lx)")
    st = r.stats()
    ax.set_title(f"{g.name}: min {st['min_lux']:.0f}, avg {st['average_lux']:.0f}, "
                 f"max {st['max_lux']:.0f} lx, U0 {st['uniformity_u0'] or 0:.2f}", fontsize=9)
    ax.set_xlabel("along u")
    ax.set_ylabel("along v")
    fig.savefig(path)


def black_irradiance(part, elements, radiance, settings) -> np.ndarray:
    """(m, 2, 3) W m^-2: the irradiance at the centres of the sub-elements (front, and back of
    two-sided ones) that have a channel of reflectance 0, where the solution holds no trace of
    the light that arrives (L = Le there): direct by shadow rays (DirectLight) plus the light
    the other sub-elements reflect (indirect_at); NaN elsewhere (tables.light_tables takes
    pi (L - Le) / rho there). Costs (such sub-elements) x m form factors."""
    from radiosity.tracing.rays import caster_of

    m = len(part)
    out = np.full((m, 2, 3), np.nan)
    orig = np.asarray(part.orig, np.int64)
    rho = np.asarray(elements.reflectance, np.float64)[orig]             # (m, 2, 3)
    two = np.asarray(elements.two_sided, bool)[orig]
    black = (rho <= 0).any(axis=2)
    black[:, 1] &= two
    sub, side = np.nonzero(black)
    if not len(sub):
        return out
    offset = float(settings.rays.offset)
    sign = np.where(side == 0, 1.0, -1.0)[:, None]
    N = sign * np.asarray(part.normal, np.float64)[sub]
    C = np.asarray(part.center, np.float64)[sub]
    light = DirectLight(elements, offset,
                        samples=max(TABLE_SHADOW_RAYS, int(settings.direct.samples)))
    H1 = light.irradiance(C, N, orig[sub], index=sub * 2 + side)
    caster = caster_of(elements.verts, elements.nverts, offset)
    # the gather's points a hair off their own plane (their own original is coplanar: F = 0)
    eps = 1e-7 * float(np.ptp(elements.verts.reshape(-1, 3), axis=0).max() or 1.0)
    src, rad = part, radiance
    if len(sub) * m > BLACK_PAIRS:
        src, rad = _originals(part, elements, radiance)
    Hr = indirect_at(C + eps * N, N, src, elements, rad, caster)
    out[sub, side] = H1 + Hr
    return out


def _originals(part, elements, radiance):
    """The originals as a partition (one sub-element each) and their area-weighted mean
    radiance (n, 2, 3): the coarse sources of black_irradiance's gather."""
    from types import SimpleNamespace

    n = len(elements)
    orig = np.asarray(part.orig, np.int64)
    a = np.asarray(part.area, np.float64)
    A = np.bincount(orig, a, minlength=n)
    rad = np.stack([np.stack([np.bincount(orig, a * radiance[:, s, c], minlength=n)
                              for c in range(3)], -1) for s in range(2)], 1)
    rad /= np.where(A > 0, A, 1.0)[:, None, None]
    return SimpleNamespace(orig=np.arange(n), verts=elements.verts, nverts=elements.nverts,
                           center=elements.center, normal=elements.normal,
                           area=elements.area), rad
