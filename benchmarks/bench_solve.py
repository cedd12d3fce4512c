"""Solve stage: pair-term throughput of the on-the-fly form-factor pass against a naive numba
loop on the same tiles (same run), passes to reach the tolerance per solver on the Cornell box
and on a furnace with rho = 0.99, and end-to-end time and memory of `render` on the Cornell box.

    python benchmarks/bench_solve.py [--e2e 64,128,256] [--tput-res 128]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings

import numba
import numpy as np

from common import ROOT, best_of, table, write

from radiosity.runtime.cluster import open_client
from radiosity.pipeline import render_scene
from radiosity.stages.preprocess import preprocess
from radiosity.scene.load import load_scene
from radiosity.methods.pairs.transport import all_task_bytes, open_operator, task_apply
from radiosity.methods.pairs.method import side_vectors
from radiosity.stages.solve import run_solve
from radiosity.runtime.store import RunStore
from radiosity.methods.pairs.visibility import compute_visibility
from radiosity.settings import options as settings_of

CORNELL = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")


@numba.njit(cache=True)
def naive_pass(data, base, tiles, offsets, c, n, area, L, y):
    """The straightforward loop: test each bit, compute F both ways, accumulate (one-sided)."""
    terms = 0
    for t in range(tiles.shape[0]):
        i, j, r0, r1, nj, s = tiles[t, 0], tiles[t, 1], tiles[t, 2], tiles[t, 3], tiles[t, 4], tiles[t, 5] - base
        for r in range(r1 - r0):
            a = offsets[i] + r0 + r
            for q in range(nj):
                k = r * nj + q
                if (data[s + (k >> 3)] >> (k & 7)) & 1:
                    b = offsets[j] + q
                    d = c[b] - c[a]
                    r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                    g = abs((n[a, 0] * d[0] + n[a, 1] * d[1] + n[a, 2] * d[2])
                            * (n[b, 0] * d[0] + n[b, 1] * d[1] + n[b, 2] * d[2])) / (np.pi * r2 * r2)
                    for ch in range(3):
                        y[0, ch, a] += area[b] * g * L[0, ch, b]
                        y[0, ch, b] += area[a] * g * L[0, ch, a]
                    terms += 2
    return terms


def throughput(client, res):
    sc = load_scene(CORNELL, resolution=res, settings=settings_of())
    with tempfile.TemporaryDirectory() as d:
        preprocess(sc, d, client, settings_of(), progress=False)
        compute_visibility(d, client, settings_of(), progress=False)
        op, part, el = open_operator(RunStore(d), client, "point", settings_of())
        inp = op.inp
        Le, rho, A = side_vectors(part, el)
        ids = np.arange(len(inp.tasks))
        L = Le + 0.1
        task_apply(inp, ids, L, 0, None)  # warm: tiles cached, kernels loaded
        terms = task_apply(inp, ids, L, 0, None)[1]
        t_ours = best_of(lambda: task_apply(inp, ids, L, 0, None), 3)
        data = all_task_bytes(inp)
        naive_terms = naive_pass(data, 0, inp.tiles, part.offsets, part.center, part.normal,
                                 part.area, L, np.zeros_like(L))  # also compiles it
        assert naive_terms == terms, (naive_terms, terms)  # the same work, done two ways
        t_naive = best_of(lambda: naive_pass(data, 0, inp.tiles, part.offsets, part.center,
                                             part.normal, part.area, L, np.zeros_like(L)), 2)
        # the distributed pass (all workers, tiles cached on them after the first pass)
        op.apply(L)
        t_dask = best_of(lambda: op.apply(L), 3)
        return {"resolution": res, "sub_elements": len(part), "pair_terms": terms,
                "ours_1core_M_s": terms / t_ours / 1e6, "naive_1core_M_s": terms / t_naive / 1e6,
                "ours_vs_naive": t_naive / t_ours, "dask_pass_M_s": terms / t_dask / 1e6}


def passes(client, scene, res, tol, rho=None):
    """Passes each solver needs to reach tol; each solver runs once untimed first (numba)."""
    rows = []
    with tempfile.TemporaryDirectory() as d:
        sc = load_scene(scene, resolution=res, settings=settings_of())
        if rho is not None:
            sc.elements.reflectance[sc.elements.reflectance > 0] = rho
        preprocess(sc, d, client, settings_of(), progress=False)
        compute_visibility(d, client, settings_of(), progress=False)
        for solver in ("jacobi", "gauss-seidel", "progressive", "cg"):
            run_solve(d, client, settings_of(solver=solver, tol=tol, max_iterations=3),
                      progress=False)  # warm
            f = run_solve(d, client, settings_of(solver=solver, tol=tol, max_iterations=5000),
                          progress=False)
            rows.append({"scene": os.path.basename(os.path.dirname(scene)) + (f" rho={rho}" if rho else ""),
                         "resolution": res, "solver": solver, "passes": f["iterations"],
                         "products": f["passes"], "converged": f["converged"],
                         "final_residual": f["final_residual"], "time_s": f["time_s"]})
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--e2e", default="64,128,256")
    ap.add_argument("--tput-res", type=int, default=128)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    with open_client(args.workers, quiet=True, settings=settings_of().cluster) as client:
        tp = throughput(client, args.tput_res)
        pr = passes(client, CORNELL, 64, 1e-6)
        pr += passes(client, os.path.join(ROOT, "scenes", "furnace-cube", "scene.toml"), 16, 1e-6, rho=0.99)
        e2e = []
        for res in [int(r) for r in args.e2e.split(",")]:
            with tempfile.TemporaryDirectory() as d:
                sc = load_scene(CORNELL, resolution=res, settings=settings_of())
                t = time.perf_counter()
                # the pairs method (this benchmark's subject; bench_hierarchy times the other)
                rep = render_scene(sc, d, client, settings_of(solver="cg", method="pairs"),
                                   progress=False, preview=False, echo=lambda *a: None)
                st = rep["render"]["stages"]
                e2e.append({"resolution": res, "sub_elements": rep["preprocess"]["sub_elements"],
                            "preprocess_s": st["preprocess_s"], "visibility_s": st["visibility_s"],
                            "solve_s": st["solve_s"], "image_s": st["image_s"],
                            "total_s": time.perf_counter() - t, "cg_passes": rep["solve"]["iterations"],
                            "store_MiB": rep["visibility"]["store_bytes"] / 2**20,
                            "peak_worker_MiB": max(st["peak_rss_mb"]["workers"].values()),
                            "peak_master_MiB": st["peak_rss_mb"]["master"]})
    print("pair-term throughput (Cornell box)")
    print(table([tp], ["resolution", "sub_elements", "pair_terms", "ours_1core_M_s", "naive_1core_M_s",
                       "ours_vs_naive", "dask_pass_M_s"]))
    print("\npasses to reach tol = 1e-6")
    print(table(pr, ["scene", "resolution", "solver", "passes", "products", "converged", "final_residual", "time_s"]))
    print("\nend to end: radiosity render, Cornell box, cg")
    print(table(e2e, ["resolution", "sub_elements", "preprocess_s", "visibility_s", "solve_s", "image_s",
                      "total_s", "cg_passes", "store_MiB", "peak_worker_MiB", "peak_master_MiB"]))
    fn = write("solve", e2e, {"throughput": tp, "passes": pr, "workers": args.workers})
    print(f"wrote {fn}")


if __name__ == "__main__":
    main()
