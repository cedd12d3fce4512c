"""radiosity heat (issue 53) at scale: the synthetic urban scene of bench_viewfactors.py
(ground, walls and roofs in 2.5 m tiles, the sky the environment), its materials by facet
orientation (ground e 0.95 300 K, walls e 0.9 295 K, roofs e 0.9 reradiating), the sky at
260 K.

    python benchmarks/bench_heat.py [--blocks 5] [--blocks-gr 3] [--cutoffs 0,1e-6,1e-4]
        [--workers 2]

solve: `--blocks`^2 blocks (8 960 facets at 5), the view factors (2 worker processes) and
the net radiation solve: wall times, the solve's steps, the heat stage's peak memory
(tracemalloc: numpy's and scipy's arrays) and the process's peak RSS.
conductances: `--blocks-gr`^2 blocks (2 976 facets at 3), GR at each cutoff: time, nonzeros
against the view-factor matrix's (the fill), what the rows dropped, the heat GR gives against
the solve's.

Writes benchmarks/results/heat.json and prints a table; the load average before and after.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
import tracemalloc

import numpy as np

from common import table, write

from bench_viewfactors import urban
from radiosity.runtime.cluster import open_client
from radiosity.settings import options as settings_of


def scene(d: str, nb: int) -> str:
    """The urban scene of nb x nb blocks as an OBJ (usemtl ground / wall / roof) and a scene
    TOML with its materials and the sky; returns the TOML's path."""
    V, F = urban(nb)
    P = V[np.array(F)]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    up = n[:, 2] > 0.5 * np.linalg.norm(n, axis=1)
    kind = np.where(up & (P[:, 0, 2] < 1e-9), "ground", np.where(up, "roof", "wall"))
    with open(os.path.join(d, "urban.obj"), "w") as f:
        for v in V:
            f.write(f"v {float(v[0])!r} {float(v[1])!r} {float(v[2])!r}\n")
        for name in ("ground", "wall", "roof"):
            f.write(f"usemtl {name}\n")
            for face, k in zip(F, kind):
                if k == name:
                    f.write("f " + " ".join(str(i + 1) for i in face) + "\n")
    fn = os.path.join(d, "scene.toml")
    with open(fn, "w") as f:
        f.write('[[mesh]]\npath = "urban.obj"\n\n'
                "[material.ground]\nemissivity = 0.95\ntemperature_K = 300\n\n"
                "[material.wall]\nemissivity = 0.9\ntemperature_K = 295\n\n"
                "[material.roof]\nemissivity = 0.9\nheat_flux_W_m2 = 0\n\n"
                "[environment]\ntemperature_K = 260\n")
    return fn


def loadavg() -> str:
    return " ".join(open("/proc/loadavg").read().split()[:3])


def part_solve(nb: int, workers: int) -> dict:
    from radiosity.viewfactors.heat import compute_heat, solve_facets
    from radiosity.viewfactors.thermal import ThermalDefaults

    with tempfile.TemporaryDirectory() as d, \
            open_client(workers, quiet=True, settings=settings_of().cluster) as client:
        fn = scene(d, nb)
        st = settings_of(conductances="off")
        load0 = loadavg()
        t = time.perf_counter()
        res = compute_heat(fn, os.path.join(d, "run"), client, st, ThermalDefaults(),
                           progress=False)
        wall = time.perf_counter() - t
        # the heat stage alone again, its memory traced
        tracemalloc.start()
        t = time.perf_counter()
        again = solve_facets(res.facets, res.inputs, res.viewfactors, res.live, st.heat,
        covered=res.covered)
        t_heat = time.perf_counter() - t
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        fig = again.figures
        vf = res.viewfactors
        return {"part": "solve", "facets": len(res.area_m2), "vf_nonzeros": int(vf.nnz),
                "vf_MiB": round((vf.data.nbytes + vf.indices.nbytes + vf.indptr.nbytes) / 2**20, 1),
                "wall_s": round(wall, 1), "heat_s": round(t_heat, 2),
                "heat_peak_MiB": round(peak / 2**20, 1), "steps": fig.solve_steps,
                "residual": fig.solve_residual,
                "energy_balance_rel": abs(fig.energy_balance_W) / max(abs(fig.net_heat_W), 1e-300),
                "net_heat_W": round(fig.net_heat_W, 1),
                "process_peak_rss_MiB": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
                "load": f"{load0} -> {loadavg()}"}


def part_conductances(nb: int, cutoffs: list, workers: int, dense: int | None = None) -> list:
    from radiosity.viewfactors.heat import compute_heat, solve_facets
    from radiosity.viewfactors.thermal import ThermalDefaults

    rows = []
    with tempfile.TemporaryDirectory() as d, \
            open_client(workers, quiet=True, settings=settings_of().cluster) as client:
        fn = scene(d, nb)
        res = compute_heat(fn, os.path.join(d, "run"), client, settings_of(conductances="off"),
                           ThermalDefaults(), progress=False)
        for cut in cutoffs:
            st = settings_of(conductances="on", conductance_cutoff=cut)
            if dense is not None:
                st = st.replace({"heat.conductance-dense-facets": dense})
            load0 = loadavg()
            tracemalloc.start()
            t = time.perf_counter()
            r = solve_facets(res.facets, res.inputs, res.viewfactors, res.live, st.heat,
            covered=res.covered)
            dt = time.perf_counter() - t
            _, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            c = r.figures.conductances
            rows.append({"part": "conductances", "facets": len(res.area_m2), "cutoff": cut,
                         "dense": len(res.area_m2) <= st.heat.conductance_dense_facets,
                         "vf_nonzeros": int(res.viewfactors.nnz), "gr_nonzeros": c["nonzeros"],
                         "fill": round(c["nonzeros"] / max(1, res.viewfactors.nnz), 2),
                         "blocks": c["blocks"], "time_s": round(dt, 1),
                         "peak_MiB": round(peak / 2**20, 1),
                         "dropped_rel_max": c["dropped_relative_max"],
                         "row_err_max": c["row_sum_relative_error_max"],
                         "heat_err_max": c["heat_relative_error_max"],
                         "load": f"{load0} -> {loadavg()}"})
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blocks", type=int, default=5)
    ap.add_argument("--blocks-gr", type=int, default=3)
    ap.add_argument("--cutoffs", default="0,1e-6,1e-4")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--part", choices=["solve", "conductances", "both"], default="both")
    ap.add_argument("--dense-facets", type=int, default=None,
                    help="radiosity.heat.conductance-dense-facets (0: conjugate gradients)")
    ap.add_argument("--name", default="heat", help="results/NAME.json")
    a = ap.parse_args()
    rows = []
    if a.part in ("solve", "both"):
        rows.append(part_solve(a.blocks, a.workers))
        print(table(rows, list(rows[0])))
    if a.part in ("conductances", "both"):
        gr = part_conductances(a.blocks_gr, [float(x) for x in a.cutoffs.split(",")], a.workers,
                               a.dense_facets)
        print(table(gr, list(gr[0])))
        rows += gr
    fn = write(a.name, rows, {"args": vars(a)})
    print(f"wrote {fn}")


if __name__ == "__main__":
    main()
