"""What each rung of the accuracy ladder costs: visibility (rays, partly visible pairs, bytes)
and solve (passes, pair terms/s) per kernel on the Cornell box, times as ratios to the point
kernel in the same run; and the form-factor error each kernel reaches on the two validation
scenes with exact answers (parallel and perpendicular unit squares), with its time.

    python benchmarks/bench_kernels.py [--res 32,64] [--kernels point,disc,point-nf,nxm:4,mc:16]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings

import dask.config

from common import ROOT, table, write

from radiosity.cluster import open_client
from radiosity.kernels import KERNELS
from radiosity.settings import sampling_of
from radiosity.preprocess import preprocess
from radiosity.scene import load_scene
from radiosity.solve import run_solve
from radiosity.store import RunStore
from radiosity.study import form_factor_of_run, kernel_setting
from radiosity.visibility import compute_visibility

CORNELL = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")
VALIDATION = ("parallel-squares", "perpendicular-squares")


def _settings(specs):
    """(label, kernel, dask.config overrides) of each kernel spec ("nxm:16": 16 points)."""
    return [(spec, *kernel_setting(spec)) for spec in specs]


def _disk_mib(run: str) -> float:
    """What the visibility matrix (bits and partly visible pairs) and the near-field corrections
    take on disk (compressed Zarr chunks), MiB."""
    total = 0
    for group in ("visibility", "nearfield"):
        for root, _, files in os.walk(os.path.join(run, "store.zarr", group)):
            total += sum(os.path.getsize(os.path.join(root, f)) for f in files)
    return total / 2**20


def cost(client, res, settings, max_rays_per_pair):
    """Per kernel: visibility (the best of two runs: the first also warms caches), then the
    solve (CG for reciprocal kernels, Gauss-Seidel for the others, as `study accuracy` does)."""
    rows = []
    with tempfile.TemporaryDirectory() as d:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            preprocess(load_scene(CORNELL, resolution=res), d, client, progress=False)
        for label, kernel, cfg in settings:
            with dask.config.set(cfg):
                smp = sampling_of(kernel)
                if smp is not None and smp.rays_per_pair > max_rays_per_pair:
                    continue
                t_vis = float("inf")
                for _ in range(2):
                    t = time.perf_counter()
                    vis = compute_visibility(d, client, progress=False, kernel=kernel)
                    t_vis = min(t_vis, time.perf_counter() - t)
                solver = "cg" if KERNELS[kernel].reciprocal else "gauss-seidel"
                t = time.perf_counter()
                sol = run_solve(d, client, solver=solver, kernel=kernel, progress=False)
                t_sol = time.perf_counter() - t
            rows.append({"res": res, "kernel": label, "sub_elements": vis["sub_elements"],
                         "rays": vis["rays"], "partial_pairs": vis.get("pairs_partial") or 0,
                         "disk_MiB": round(_disk_mib(d), 2), "visibility_s": round(t_vis, 3),
                         "solver": solver, "iterations": sol["iterations"],
                         "products": sol["passes"], "solve_s": round(t_sol, 3),
                         "pair_terms_per_s": sol["pair_terms_per_s"]})
    base = next(r for r in rows if r["kernel"] == "point")
    for r in rows:
        r["visibility_x"] = round(r["visibility_s"] / base["visibility_s"], 2)
        r["solve_x"] = round(r["solve_s"] / base["solve_s"], 2)
    return rows


def errors(client, resolutions, settings):
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for name in VALIDATION:
            path = os.path.join(ROOT, "scenes", name, "scene.toml")
            exact = load_scene(path).validation["form_factor"]
            for res in resolutions:
                run = os.path.join(d, f"{name}-{res}")
                preprocess(load_scene(path, resolution=res), run, client, progress=False)
                m = len(RunStore(run).load_partition())
                for label, kernel, cfg in settings:
                    with dask.config.set(cfg):
                        t = time.perf_counter()
                        compute_visibility(run, client, progress=False, kernel=kernel)
                        f = form_factor_of_run(run, client, kernel, "emitter", "receiver")
                        t = time.perf_counter() - t
                    rows.append({"scene": name, "res": res, "sub_elements": m, "kernel": label,
                                 "error": abs(f / exact - 1), "time_s": round(t, 3)})
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", default="32,64", help="Cornell box resolutions for the cost table.")
    ap.add_argument("--kernels", default="point,disc,point-nf,nxm:4,nxm:16,mc:16,mc:64")
    ap.add_argument("--max-rays-per-pair", type=int, default=64,
                    help="Skip sampled settings above this on the Cornell box.")
    ap.add_argument("--validation-res", default="8,16,32")
    args = ap.parse_args()
    settings = _settings(args.kernels.split(","))
    with open_client(2, None, "local", echo=lambda *a: None) as client:
        # warm-up: numba caches, Embree, workers
        cost(client, 8, settings, args.max_rays_per_pair)
        rows = []
        for res in (int(r) for r in args.res.split(",")):
            rows += cost(client, res, settings, args.max_rays_per_pair)
        err = errors(client, [int(r) for r in args.validation_res.split(",")], settings)
    print("Cornell box: what each kernel costs (ratios to point in the same run)")
    print(table(rows, ["res", "kernel", "sub_elements", "rays", "partial_pairs", "disk_MiB",
                       "visibility_s", "visibility_x", "solver", "iterations", "products", "solve_s",
                       "solve_x", "pair_terms_per_s"]))
    print("\nValidation scenes: form-factor error against the exact value")
    print(table(err, ["scene", "res", "sub_elements", "kernel", "error", "time_s"]))
    print("wrote", write("kernels", rows, {"validation": err}))


if __name__ == "__main__":
    main()
