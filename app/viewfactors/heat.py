"""Radiative heat exchange between the user's facets (issue 53): `radiosity heat SCENE --out
DIR` and `radiosity.heat(scene)`. The view factors come from the view-factor stage (its run in
DIR/viewfactors), the thermal inputs from viewfactors/thermal.py, the solve from
core/netradiation.py; this module runs them in order and writes DIR/facets.csv, the
conductances (conductances.npz, conductances_esatan.txt) and report.json's "heat" section.
The method: docs/src/design/heat-method.md.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import time
from dataclasses import dataclass

import numpy as np

from radiosity.core.netradiation import (SIGMA, Conductances, HeatSolution, conductances,
                                         network_heat, solve_heat)
from radiosity.errors import RadiosityError
from radiosity.runtime.store import StageFigures
from radiosity.settings import HeatSettings, Settings
from radiosity.viewfactors.facets import Facets
from radiosity.viewfactors.thermal import HeatInputs, ThermalDefaults, heat_inputs

FACET_COLUMNS = ("facet", "mesh", "material", "area_m2", "emissivity", "temperature_K",
                 "radiosity_W_m2", "net_heat_flux_W_m2", "net_heat_W", "view_to_environment",
                 "boundary", "covered_fraction")
#: The ESATAN node number of the environment (the usual space node), unless the mesh has as
#: many facets: then it is the number after the last facet's.
ESATAN_SPACE_NODE = 99999


@dataclass(frozen=True)
class HeatFigures(StageFigures):
    """report.json's "heat" section: the environment, the energy balance (the facets' net heat
    and what the environment absorbs: equal by reciprocity, rounding apart), per material sums,
    the solve and the conductances (what was computed and how well it holds), the files."""

    SECTION = "heat"
    OPTIONAL = ("conductances",)
    facets: int
    live_facets: int
    partly_covered_facets: int
    environment_K: float
    length_unit_m: float
    net_heat_W: float
    environment_absorbed_W: float
    energy_balance_W: float
    materials: dict
    solve_steps: int
    solve_residual: float
    conductances: dict | None
    files: list
    time_solve_s: float
    time_conductances_s: float


@dataclass
class HeatResult:
    """What `radiosity.heat` returns. facets: the facets (load order); inputs: their
    emissivities and boundary conditions; area_m2 (n,) the facets' areas; solution: the net
    radiation solution (core.netradiation.HeatSolution, per m^2 of the uncovered part);
    conductances: GR ((n+1) x (n+1), the environment last) or None when not computed;
    viewfactors: the view-factor matrix (CSR n x n) it used; live (n,) bool: the facets that
    take part; covered (n,): the part of each facet's front a touching surface covers;
    figures: report.json's "heat" section."""

    facets: Facets
    inputs: HeatInputs
    area_m2: np.ndarray
    solution: HeatSolution
    conductances: Conductances | None
    viewfactors: object
    live: np.ndarray
    covered: np.ndarray
    figures: HeatFigures

    def table(self) -> dict:
        """The columns of facets.csv as arrays (name -> (n,) array), in FACET_COLUMNS order."""
        fac, inp, s = self.facets, self.inputs, self.solution
        n = len(fac)
        T = s.temperature
        return {
            "facet": np.arange(n),
            "mesh": np.array([os.path.basename(fac.sources[k]) if fac.sources else "mesh"
                              for k in fac.source], object),
            "material": np.array([inp.material_names[m] for m in inp.material], object),
            "area_m2": self.area_m2, "emissivity": inp.emissivity,
            "temperature_K": np.where(self.live, T, np.where(inp.fixed_t, inp.temperature_K,
                                                              np.nan)),
            "radiosity_W_m2": np.where(self.live, s.radiosity, np.nan),
            "net_heat_flux_W_m2": s.net_flux * (1 - self.covered),
            "net_heat_W": s.net_flux * (1 - self.covered) * self.area_m2,
            "view_to_environment": s.environment_view * (1 - self.covered),
            "boundary": np.where(~self.live, "contact",
                                 np.where(inp.fixed_t, "temperature", "heat_flux")),
            "covered_fraction": self.covered,
        }


def facet_cover(vf_dir: str, F, closed_scene: bool) -> tuple:
    """(live (n,) bool, covered (n,) float64) of the view-factor run in vf_dir (its
    facets.csv) and its matrix F (CSR n x n). A facet covered by a touching surface (column
    contact) takes no part. In a closed scene (closed_scene: the closure test's verdict)
    nothing sees the environment: what a row lacks of 1 is the part of the facet that a
    touching surface covers (under a shelf's foot), which radiates nothing; a facet wholly so
    takes no part either. In an open scene covered is 0 and 1 - the row sum is the view to
    the environment (a facet's own closure target is not used: a few rays that all met
    geometry do not make a side closed)."""
    n = F.shape[0]
    live = np.ones(n, bool)
    fn = os.path.join(vf_dir, "facets.csv")
    if os.path.exists(fn):
        with open(fn, newline="") as f:
            for row in csv.DictReader(f):
                i = int(row["facet"])
                live[i] = not int(row.get("contact", 0) or 0)
    rows = np.asarray(F.sum(axis=1)).ravel()
    covered = np.where(live & bool(closed_scene), np.clip(1.0 - rows, 0.0, 1.0), 0.0)
    live &= covered < 1.0 - 1e-9
    return live, np.where(live, covered, 0.0)


def solve_facets(fac: Facets, inp: HeatInputs, F, live: np.ndarray, hs: HeatSettings,
                 echo=None, covered: np.ndarray | None = None) -> HeatResult:
    """The net radiation solve (and the conductances, as hs.conductances says) of facets `fac`
    with inputs `inp` on the view-factor matrix F (CSR n x n); live (n,) bool; covered (n,):
    the part of each facet that a touching surface covers (facet_cover; None: 0). A covered
    part radiates nothing: the facet radiates from A (1 - covered) with its row divided by
    (1 - covered), so that A F, reciprocity, is unchanged. No files."""
    import scipy.sparse as sp

    full = fac.area * inp.length_unit_m ** 2
    covered = np.zeros(len(full)) if covered is None else np.asarray(covered, float)
    keep = 1.0 - covered
    area = full * keep
    F0 = F
    if covered.any():
        F = sp.csr_matrix(sp.diags(1.0 / keep) @ F)
    Eenv = SIGMA * inp.environment_K ** 4
    E = np.where(inp.fixed_t, SIGMA * np.nan_to_num(inp.temperature_K) ** 4, 0.0)
    t0 = time.perf_counter()
    sol = solve_heat(F, area, inp.emissivity, inp.fixed_t, E, inp.heat_flux, Eenv, live,
                     tol=hs.tol, max_iterations=hs.max_iterations)
    t_solve = time.perf_counter() - t0
    if sol.residual > 1e3 * hs.tol:
        raise RadiosityError(
            f"the net radiation solve did not converge ({sol.steps} steps, residual "
            f"{sol.residual:.3g} > radiosity.heat.tol {hs.tol:g}): a closed part of the mesh "
            "whose every facet has a fixed heat flux has no temperature to hold on to; give "
            "one of its materials a temperature_K")
    nlive = int(live.sum())
    mode = hs.conductances
    want = mode in ("on", True) or (mode == "auto" and nlive <= hs.conductance_max_facets)
    cond, t_cond, cfig = None, 0.0, None
    if want:
        n = len(area)
        block = max(1, min(nlive, int(hs.conductance_block_mb * 2 ** 20 // (48 * max(1, n)))))
        if echo:
            echo(f"conductances: {nlive} facets, {-(-nlive // block)} blocks of {block} columns")
        t0 = time.perf_counter()
        cond = conductances(F, area, inp.emissivity, live, cutoff=hs.conductance_cutoff,
                            block=block, tol=hs.tol, max_iterations=hs.max_iterations,
                            dense_max=hs.conductance_dense_facets)
        t_cond = time.perf_counter() - t0
        cfig = _conductance_figures(cond, area, inp, sol, live)
    elif echo:
        echo(f"conductances: not computed ({nlive} facets > radiosity.heat.conductance-max-facets "
             f"{hs.conductance_max_facets}; --conductances on computes them)"
             if mode == "auto" else "conductances: not computed (--conductances off)")
    net = sol.net_flux * area
    mats = {}
    for mi, name in enumerate(inp.material_names):
        sel = (inp.material == mi) & live
        mats[name] = {"facets": int(sel.sum()), "area_m2": float(full[sel].sum()),
                      "net_heat_W": float(net[sel].sum()),
                      "emissivity_min": float(inp.emissivity[sel].min(initial=np.inf)) if sel.any() else None,
                      "temperature_K_min": float(sol.temperature[sel].min()) if sel.any() else None,
                      "temperature_K_max": float(sol.temperature[sel].max()) if sel.any() else None}
    fig = HeatFigures(
        facets=len(area), live_facets=nlive, partly_covered_facets=int((covered > 0).sum()),
        environment_K=inp.environment_K,
        length_unit_m=inp.length_unit_m, net_heat_W=float(net.sum()),
        environment_absorbed_W=sol.env_W, energy_balance_W=float(net.sum() - sol.env_W),
        materials=mats, solve_steps=sol.steps, solve_residual=sol.residual,
        conductances=cfig, files=[], time_solve_s=round(t_solve, 3),
        time_conductances_s=round(t_cond, 3))
    return HeatResult(fac, inp, full, sol, cond, F0, live, covered, fig)


def _conductance_figures(cond: Conductances, area, inp: HeatInputs, sol: HeatSolution,
                         live) -> dict:
    """How the conductances hold: symmetry (exact by construction), rows against e_i A_i,
    the heat they give for the solved temperatures against the solve's."""
    GR = cond.GR
    n = len(area)
    ea = inp.emissivity * area
    rows = np.asarray(GR.sum(axis=1)).ravel()[:n]
    rel = np.where(live, np.abs(rows + cond.dropped - ea) / ea, 0.0)
    Q = network_heat(GR, sol.emissive_power, SIGMA * inp.environment_K ** 4)
    net = sol.net_flux * area
    scale = max(float(np.abs(net).max(initial=0.0)), float((ea * sol.emissive_power).max(initial=0.0)))
    return {"nonzeros": int(GR.nnz), "blocks": cond.blocks, "solve_steps": cond.steps,
            "solve_residual": cond.residual,
            "row_sum_relative_error_max": float(rel.max(initial=0.0)),
            "dropped_relative_max": float((np.where(live, cond.dropped / ea, 0.0)).max(initial=0.0)),
            "heat_relative_error_max": float(np.abs(Q - net).max(initial=0.0) / max(scale, 1e-300))}


def write_outputs(res: HeatResult, out: str, hs: HeatSettings) -> list:
    """DIR/facets.csv, and with conductances conductances.npz ((n+1) x (n+1) CSR, the
    environment last) and conductances_esatan.txt (unless it would pass
    radiosity.heat.esatan-max-conductors). Returns the file names."""
    import scipy.sparse as sp

    os.makedirs(out, exist_ok=True)
    cols = res.table()
    with open(os.path.join(out, "facets.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(FACET_COLUMNS)
        for i in range(len(res.area_m2)):
            w.writerow([v[i] if isinstance(v[i], (str, np.str_)) or k in ("facet",)
                        else repr(float(v[i])) for k, v in cols.items()])
    files = ["facets.csv"]
    if res.conductances is not None:
        sp.save_npz(os.path.join(out, "conductances.npz"), res.conductances.GR, compressed=True)
        files.append("conductances.npz")
        upper = sp.triu(res.conductances.GR, k=1)
        if upper.nnz <= hs.esatan_max_conductors:
            write_esatan(os.path.join(out, "conductances_esatan.txt"), res.conductances.GR,
                         res.facets, res.inputs)
            files.append("conductances_esatan.txt")
    return files


def esatan_node(i: int, n: int) -> int:
    """The ESATAN node number of facet i (0-based) of n, i == n the environment."""
    if i < n:
        return i + 1
    return ESATAN_SPACE_NODE if n < ESATAN_SPACE_NODE else n + 1


def write_esatan(fn: str, GR, fac: Facets, inp: HeatInputs) -> None:
    """GR as an ESATAN-TMS $CONDUCTORS block: one `GR(a, b) = value;` per conductor (a < b,
    value m^2; the solver multiplies by sigma and the difference of the absolute temperatures
    to the fourth), facet i the node i + 1, the environment node esatan_node(n, n)."""
    import scipy.sparse as sp

    n = GR.shape[0] - 1
    U = sp.triu(GR, k=1).tocoo()
    env = esatan_node(n, n)
    with open(fn, "w") as f:
        f.write(f"# radiative conductances GR (m^2) of {n} facets, radiosity heat\n"
                f"# node a = facet a - 1 (facets.csv); node {env} = the environment "
                f"({inp.environment_K:g} K)\n"
                "# heat a -> b: GR(a, b) * sigma * (T_a^4 - T_b^4), T absolute\n$CONDUCTORS\n")
        order = np.lexsort((U.col, U.row))
        for r, c, v in zip(U.row[order].tolist(), U.col[order].tolist(), U.data[order].tolist()):
            f.write(f"GR({esatan_node(r, n)}, {esatan_node(c, n)}) = {v!r};\n")


def read_esatan(fn: str) -> list:
    """[(a, b, GR)] of an ESATAN conductor list as write_esatan writes it (tests, users)."""
    import re

    pat = re.compile(r"^\s*GR\(\s*(\d+)\s*,\s*(\d+)\s*\)\s*=\s*([^;]+);")
    out = []
    with open(fn) as f:
        for line in f:
            m = pat.match(line)
            if m:
                out.append((int(m.group(1)), int(m.group(2)), float(m.group(3))))
    return out


def compute_heat(mesh, out: str, client, settings: Settings, defaults: ThermalDefaults, *,
                 resume: bool = False, progress: bool = True, echo=None) -> HeatResult:
    """Heat exchange between the facets of `mesh` (a scene TOML whose materials carry
    emissivity and temperature_K or heat_flux_W_m2, or a mesh with `defaults` for every
    facet) into the run directory `out`: the view factors (their run in out/viewfactors,
    settings.viewfactors), the net radiation solve and the conductances (settings.heat),
    facets.csv, conductances.npz, conductances_esatan.txt, report.json (section "heat").
    echo(line): the stage lines (None: silent)."""
    from radiosity.viewfactors.facets import load_facets
    from radiosity.viewfactors.master import compute_viewfactors

    fac = load_facets(mesh, settings=settings)
    inp = heat_inputs(mesh, fac, defaults)   # bad values fail before the view factors
    vf_dir = os.path.join(out, "viewfactors")
    vf = compute_viewfactors(fac, vf_dir, client, settings, resume=resume, progress=progress)
    live, covered = facet_cover(vf_dir, vf.matrix, bool(vf.figures["closed"]))
    if echo:
        echo(f"heat: {int(live.sum())} facets, environment {inp.environment_K:g} K")
    res = solve_facets(fac, inp, vf.matrix, live, settings.heat, echo=echo, covered=covered)
    files = write_outputs(res, out, settings.heat)
    res.figures = fig = dataclasses.replace(res.figures, files=files)
    fig.write(out)
    return res

