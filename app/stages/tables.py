"""Numbers for engineers: radiance, exitance, irradiance and illuminance of the solution per
sub-element, per original surface and per material, as numpy arrays (which
`pandas.DataFrame(t.table(name))` takes as they are; radiosity does not need pandas), CSV files
(Parquet too when pyarrow is there; formats/ writes them) and a summary in report.json.

Units and the photometric conversion (docs/how-to/exports.md says the same):
- radiance L, emitted radiance Le: W sr^-1 m^-2 per RGB channel (SPEC §1); exitance
  (radiosity) B = pi L and irradiance E: W m^-2. They do not depend on the scene's length
  unit; areas are in the scene's unit squared.
- Irradiance is what arrives: L = Le + rho E / pi (a Lambertian element, SPEC §2), so
  E = pi (L - Le) / rho, channel by channel, where rho > 0; where rho = 0 nothing of the
  incident light is in the solution: a render gathers it at the sub-element's centre
  (stages/grids.black_irradiance: direct light by shadow rays plus the light the other
  sub-elements reflect); light_tables without it leaves E NaN there.
- Photometric: each RGB channel is read as a radiometric quantity in watts whose luminous
  efficiency is the Rec. 709 / sRGB luminance weight, Y = 0.2126 R + 0.7152 G + 0.0722 B
  (`LUMA`), and 1 W of Y is 683 lm (`EFFICACY`, the luminous efficacy at 555 nm that
  defines the candela): luminance = 683 Y(L) cd m^-2, illuminance = 683 Y(E) lx. This
  assumes the RGB numbers of the scene are "photometric watts" of that kind; tools that read
  RGB as equal-energy white over the visible band use 179 lm/W instead (Radiance): pass
  `efficacy=` to get their numbers.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from radiosity.core.arrays import unique_rows
from radiosity.core.colour import EFFICACY, LUMA
from radiosity.formats.csvtext import write_csv
from radiosity.formats.parquet import write_parquet
from radiosity.runtime.store import StageFigures

#: The statement written with every table (report.json "light", the docs page).
CONVERSION = ("luminance-weighted Y = 0.2126 R + 0.7152 G + 0.0722 B (Rec. 709), "
              "{efficacy:g} lm per W of Y: luminance = {efficacy:g} Y(L) cd/m^2, "
              "illuminance = {efficacy:g} Y(E) lx; E = pi (L - Le) / rho, where rho = 0 "
              "gathered at the sub-element's centre (direct light by shadow rays plus the light "
              "the others reflect)")
#: The summary rows the CLI prints after a render: at most this many materials, else one line.
SUMMARY_MAX_ROWS = 8
TABLES = ("elements", "surfaces", "materials")
_RGB = ("r", "g", "b")


@dataclass(frozen=True)
class LightTables:
    """Three tables, each a dict column name -> (rows,) numpy array (numbers float64 or int64,
    names as str arrays), in column order:

    elements: one row per sub-element and side (the back only for two-sided originals)
    surfaces: one row per original element and side, area-weighted over its sub-elements
    materials: one row per material and side, area-weighted over its sub-elements

    Per row: radiance_r/g/b, radiance_y (W sr^-1 m^-2), luminance (cd m^-2), exitance_r/g/b,
    exitance_y (W m^-2), irradiance_r/g/b, irradiance_y (W m^-2; where rho = 0 gathered, or NaN),
    illuminance (lx); surfaces and materials add illuminance_min / _max over their
    sub-elements and uniformity = min / mean (the lighting designer's U0).
    """

    elements: dict
    surfaces: dict
    materials: dict
    efficacy: float = EFFICACY
    conversion: str = field(default="")

    def table(self, name: str) -> dict:
        if name not in TABLES:
            raise KeyError(f"no table {name!r}: one of {', '.join(TABLES)}")
        return getattr(self, name)

    def records(self, name: str) -> np.ndarray:
        """The table as a numpy structured array (one record per row)."""
        t = self.table(name)
        dt = [(k, v.dtype if v.dtype.kind != "U" else f"U{max(1, v.dtype.itemsize // 4)}")
              for k, v in t.items()]
        out = np.zeros(len(next(iter(t.values()))), dt)
        for k, v in t.items():
            out[k] = v
        return out


# ----------------------------------------------------------------------------- computing

def _quantities(L, Le, rho, efficacy, gathered=None):
    """Columns of the light quantities from L, Le, rho (k, 3) float64; gathered (k, 3): the
    irradiance gathered where rho = 0 (stages/grids.black_irradiance), else NaN there."""
    out = {}
    y = L @ LUMA
    for i, c in enumerate(_RGB):
        out[f"radiance_{c}"] = L[:, i]
    out["radiance_y"] = y
    out["luminance"] = efficacy * y
    for i, c in enumerate(_RGB):
        out[f"exitance_{c}"] = math.pi * L[:, i]
    out["exitance_y"] = math.pi * y
    with np.errstate(divide="ignore", invalid="ignore"):
        # rounding of the solver may leave L a hair below Le: no negative irradiance
        E = np.where(rho > 0, math.pi * np.maximum(L - Le, 0.0) / np.where(rho > 0, rho, 1.0),
                     np.nan)
    if gathered is not None:  # black channels: the light that arrives, gathered
        E = np.where(rho > 0, E, gathered)
    for i, c in enumerate(_RGB):
        out[f"irradiance_{c}"] = E[:, i]
    out["irradiance_y"] = E @ LUMA
    out["illuminance"] = efficacy * out["irradiance_y"]
    return out


def _group(keys: np.ndarray, area: np.ndarray, cols: dict, efficacy: float):
    """Area-weighted means of `cols` over the rows with equal `keys` (k,) int64, in key order;
    min / max / uniformity of the illuminance. Returns (unique keys, first row of each, dict)."""
    u, first, inv = np.unique(keys, return_index=True, return_inverse=True)
    g = len(u)
    a = np.bincount(inv, weights=area, minlength=g)
    out = {"area": a, "sub_elements": np.bincount(inv, minlength=g).astype(np.int64)}
    for k, v in cols.items():
        if k in ("luminance", "illuminance"):
            continue
        out[k] = np.bincount(inv, weights=v * area, minlength=g) / np.where(a > 0, a, 1.0)
    out["luminance"] = efficacy * out["radiance_y"]
    out["illuminance"] = efficacy * out["irradiance_y"]
    ill = cols["illuminance"]
    lo = np.full(g, np.inf)
    hi = np.full(g, -np.inf)
    with np.errstate(invalid="ignore"):  # NaN propagates: a group with rho = 0 has no minimum
        np.minimum.at(lo, inv, ill)
        np.maximum.at(hi, inv, ill)
    out["illuminance_min"], out["illuminance_max"] = lo, hi
    with np.errstate(divide="ignore", invalid="ignore"):
        out["uniformity"] = np.where(out["illuminance"] > 0, lo / out["illuminance"], np.nan)
    return u, first, out


def light_tables(part, elements, radiance: np.ndarray, efficacy: float = EFFICACY,
                 irradiance: np.ndarray | None = None) -> LightTables:
    """The three tables of a solution (module docstring for the units and the conversion).

    part: core.bundles.Partition (m sub-elements); elements: core.bundles.Elements;
    radiance (m, 2, 3) float64, linear RGB radiance per sub-element and side (0 front, 1 back),
    as solution/radiance; irradiance (m, 2, 3): the irradiance gathered where rho = 0
    (stages/grids.black_irradiance; None: NaN there). Returns LightTables.
    """
    from radiosity.scene.emitters import AreaEmitters

    radiance = np.asarray(radiance, np.float64)
    m = len(part)
    if radiance.shape != (m, 2, 3):
        raise ValueError(f"radiance has shape {radiance.shape}, the partition needs {(m, 2, 3)}")
    orig = np.asarray(part.orig, np.int64)
    two = np.asarray(elements.two_sided, bool)[orig]
    sub = np.r_[np.arange(m), np.flatnonzero(two)]
    side = np.r_[np.zeros(m, np.int64), np.ones(int(two.sum()), np.int64)]
    o = orig[sub]
    sign = np.where(side == 0, 1.0, -1.0)[:, None]
    L = radiance[sub, side]
    Le = np.asarray(AreaEmitters(elements).radiance(), np.float64)[o, side]
    rho = np.asarray(elements.reflectance, np.float64)[o, side]
    area = np.asarray(part.area, np.float64)[sub]
    names = np.array(list(elements.material_names) or ["?"], dtype=str)
    mat = np.asarray(elements.material, np.int64)[o]
    sides = np.array(["front", "back"])
    q = _quantities(L, Le, rho, efficacy,
                    None if irradiance is None else np.asarray(irradiance, np.float64)[sub, side])

    el = {"element": sub.astype(np.int64), "original": o, "side": sides[side],
          "material": names[np.minimum(mat, len(names) - 1)], "area": area}
    for i, c in enumerate("xyz"):
        el[f"center_{c}"] = np.asarray(part.center, np.float64)[sub, i]
    for i, c in enumerate("xyz"):
        el[f"normal_{c}"] = sign[:, 0] * np.asarray(part.normal, np.float64)[sub, i]
    for i, c in enumerate(_RGB):
        el[f"reflectance_{c}"] = rho[:, i]
    for i, c in enumerate(_RGB):
        el[f"emission_{c}"] = Le[:, i]
    el.update(q)

    n = len(elements)
    u, first, s = _group(o * 2 + side, area, q, efficacy)
    so, sside = u // 2, u % 2
    srcs = np.array([os.path.basename(x) for x in elements.sources] or ["?"], dtype=str)
    src = np.asarray(elements.source, np.int64)[so] if n else np.zeros(0, np.int64)
    surf = {"surface": so, "side": sides[sside], "material": el["material"][first],
            "source": srcs[np.minimum(src, len(srcs) - 1)],
            "face": np.asarray(elements.face, np.int64)[so] + 1}
    for i, c in enumerate("xyz"):
        surf[f"normal_{c}"] = el[f"normal_{c}"][first]
    for k in [f"reflectance_{c}" for c in _RGB] + [f"emission_{c}" for c in _RGB]:
        surf[k] = el[k][first]
    surf.update(s)

    key = mat * 2 + side
    u, first, s = _group(key, area, q, efficacy)
    pairs = unique_rows(np.column_stack([key, o]))[0]       # (material-side, original)
    mats = {"material": el["material"][first], "side": sides[u % 2],
            "surfaces": np.unique(pairs[:, 0], return_counts=True)[1].astype(np.int64)}
    mats.update(s)
    return LightTables(el, surf, mats, float(efficacy), CONVERSION.format(efficacy=efficacy))


def read_light_tables(run_dir: str, efficacy: float = EFFICACY) -> LightTables:
    """light_tables of a solved run directory (its partition, elements and solution)."""
    from radiosity.runtime.store import RunStore

    rs = RunStore(run_dir, "r")
    return light_tables(rs.load_partition(), rs.load_elements(),
                        rs.read_arrays("solution")["radiance"], efficacy)


# ----------------------------------------------------------------------------- files

def _finite(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class LightFigures(StageFigures):
    """The light tables' figures (report.json, section "light"): the files, the photometric
    conversion and the per-material summary (rows of the materials table, NaN as null)."""

    SECTION = "light"
    files: list
    efficacy_lm_per_w: float
    luma: list
    conversion: str
    elements: int
    surfaces: int
    materials: list

    def rows(self):
        return summary_rows(self.to_dict())


def summary_rows(section: dict | None) -> list[tuple[str, str]]:
    """The CLI's rows for report.json's "light" section: one per material and side (up to
    SUMMARY_MAX_ROWS), else one line that says where the numbers are."""
    if not section or not section.get("materials"):
        return []
    mats = section["materials"]
    if len(mats) > SUMMARY_MAX_ROWS:
        return [("light", f"{len(mats)} materials: report.json \"light\", surfaces.csv, "
                          "elements.csv")]

    def num(x, unit):
        return "n/a" if x is None else f"{x:.4g} {unit}"

    rows = []
    for r in mats:
        label = f"light: {r['material']}" + (" (back)" if r["side"] == "back" else "")
        ill = "illuminance n/a (black)" if r["illuminance"] is None else (
            f"illuminance {num(r['illuminance'], 'lx')} mean, "
            f"{num(r['illuminance_min'], '')}.. {num(r['illuminance_max'], 'lx')}")
        rows.append((label, f"{ill}; luminance {num(r['luminance'], 'cd/m^2')}"))
    return rows


def write_light_tables(run_dir: str, tables: LightTables) -> LightFigures:
    """elements.csv, surfaces.csv, materials.csv (and .parquet with pyarrow) into run_dir,
    and section "light" of report.json. Returns the figures."""
    files = []
    for name in TABLES:
        fn = os.path.join(run_dir, f"{name}.csv")
        write_csv(fn, tables.table(name))
        files.append(os.path.basename(fn))
        pq = os.path.join(run_dir, f"{name}.parquet")
        if write_parquet(pq, tables.table(name)):
            files.append(os.path.basename(pq))
    mt = tables.materials
    keep = ("area", "sub_elements", "surfaces", "radiance_y", "luminance", "exitance_y",
            "irradiance_y", "illuminance", "illuminance_min", "illuminance_max", "uniformity")
    summary = []
    for i in range(len(mt["material"])):
        row = {"material": str(mt["material"][i]), "side": str(mt["side"][i])}
        for k in keep:
            v = mt[k][i]
            row[k] = int(v) if np.asarray(v).dtype.kind in "iu" else _finite(v)
        summary.append(row)
    fig = LightFigures(files=files, efficacy_lm_per_w=tables.efficacy, luma=LUMA.tolist(),
                       conversion=tables.conversion,
                       elements=len(tables.elements["element"]),
                       surfaces=len(tables.surfaces["surface"]), materials=summary)
    fig.write(run_dir)
    return fig
