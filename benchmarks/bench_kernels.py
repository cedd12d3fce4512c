"""What each rung of the accuracy ladder costs: visibility (rays, partly visible pairs, bytes)
and solve (passes, pair terms/s) per kernel on the Cornell box, times as ratios to the point
kernel in the same run; and the form-factor error each kernel reaches on the two validation
scenes with exact answers (parallel and perpendicular unit squares), with its time.

    python benchmarks/bench_kernels.py [--res 32,64] [--kernels point,disc,point-nf,nxm:4,mc:16]
        [--validation-res 8,16,32] [--skip-cost]

The accuracy table of docs/src/measurements/kernels.md (errors at 8 / 16 / 32 and the order
column, every row) and the cost
ratios of the sampled kernels come from this script; tests/test_accuracy.py asserts the point,
disc, point-nf, nxm N = 4 and mc k = 16 rows.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings

import dask.config
import numpy as np

from common import ROOT, table, write

from radiosity.runtime.cluster import open_client
from radiosity.core.kernels import KERNELS
from radiosity.settings import sampling_of
from radiosity.stages.preprocess import preprocess
from radiosity.scene.load import load_scene
from radiosity.stages.solve import run_solve
from radiosity.runtime.store import RunStore
from radiosity.validation.study import form_factor_of_run, kernel_setting
from radiosity.methods.pairs.visibility import compute_visibility
from radiosity.settings import options as settings_of

CORNELL = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")
VALIDATION = ("parallel-squares", "perpendicular-squares")


def _settings(specs):
    """(label, kernel, dask.config overrides) of each kernel spec ("nxm:16": 16 points)."""
    return [(spec, *kernel_setting(spec, settings_of())) for spec in specs]


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
            preprocess(load_scene(CORNELL, resolution=res, settings=settings_of()), d, client,
                       settings_of(), progress=False)
        for label, kernel, cfg in settings:
            with dask.config.set(cfg):
                smp = sampling_of(kernel)
                if smp is not None and smp.rays_per_pair > max_rays_per_pair:
                    continue
                t_vis = float("inf")
                for _ in range(2):
                    t = time.perf_counter()
                    vis = compute_visibility(d, client, settings_of(kernel=kernel), progress=False)
                    t_vis = min(t_vis, time.perf_counter() - t)
                solver = "cg" if KERNELS[kernel].reciprocal else "gauss-seidel"
                t = time.perf_counter()
                sol = run_solve(d, client, settings_of(solver=solver, kernel=kernel),
                                progress=False)
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
            exact = load_scene(path, settings=settings_of()).validation["form_factor"]
            for res in resolutions:
                run = os.path.join(d, f"{name}-{res}")
                with dask.config.set({"radiosity.subdivide.hidden": "keep"}):  # the camera's
                    preprocess(load_scene(path, resolution=res, settings=settings_of()), run,
                               client, settings_of(), progress=False)
                part = RunStore(run).load_partition()
                m, size = len(part), float(np.sqrt(part.area.mean()))
                for label, kernel, cfg in settings:
                    with dask.config.set(cfg):
                        t = time.perf_counter()
                        compute_visibility(run, client, settings_of(kernel=kernel), progress=False)
                        f = form_factor_of_run(run, client, kernel, "emitter", "receiver",
                                               settings=settings_of())
                        t = time.perf_counter() - t
                    rows.append({"scene": name, "res": res, "sub_elements": m, "size": size,
                                 "kernel": label, "error": abs(f / exact - 1), "time_s": round(t, 3)})
    return rows


def orders(err_rows):
    """The order of each kernel on each scene: the log-log slope of the error against the
    element size (sqrt of the mean sub-element area) over the resolutions (the table's order column)."""
    out = []
    for name in dict.fromkeys(r["scene"] for r in err_rows):
        for label in dict.fromkeys(r["kernel"] for r in err_rows):
            rr = [r for r in err_rows if r["scene"] == name and r["kernel"] == label]
            if len(rr) < 2:
                continue
            slope = np.polyfit(np.log([r["size"] for r in rr]),
                               np.log([max(r["error"], 1e-16) for r in rr]), 1)[0]
            out.append({"scene": name, "kernel": label, "order": round(float(slope), 2),
                        "errors": " / ".join(f"{r['error']:.2g}" for r in rr)})
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", default="32,64", help="Cornell box resolutions for the cost table.")
    ap.add_argument("--kernels", default="point,disc,point-nf,nxm:4,nxm:16,mc:16,mc:64")
    ap.add_argument("--max-rays-per-pair", type=int, default=64,
                    help="Skip sampled settings above this on the Cornell box.")
    ap.add_argument("--validation-res", default="8,16,32")
    ap.add_argument("--skip-cost", action="store_true", help="Only the validation scenes' errors.")
    args = ap.parse_args()
    settings = _settings(args.kernels.split(","))
    with open_client(2, None, "local", echo=lambda *a: None, settings=settings_of().cluster) as client:
        rows = []
        if not args.skip_cost:
            # warm-up: numba caches, Embree, workers
            cost(client, 8, settings, args.max_rays_per_pair)
            for res in (int(r) for r in args.res.split(",")):
                rows += cost(client, res, settings, args.max_rays_per_pair)
        err = errors(client, [int(r) for r in args.validation_res.split(",")], settings)
    if rows:
        print("Cornell box: what each kernel costs (ratios to point in the same run)")
        print(table(rows, ["res", "kernel", "sub_elements", "rays", "partial_pairs", "disk_MiB",
                           "visibility_s", "visibility_x", "solver", "iterations", "products",
                           "solve_s", "solve_x", "pair_terms_per_s"]))
    print("\nValidation scenes: form-factor error against the exact value")
    print(table(err, ["scene", "res", "sub_elements", "kernel", "error", "time_s"]))
    order = orders(err)
    print("\nOrder (log-log slope of the error against the element size): docs/src/measurements/kernels.md")
    print(table(order, ["scene", "kernel", "errors", "order"]))
    # --skip-cost keeps the cost results of a full run (results/kernels.json) as they are
    print("wrote", write("kernels-validation" if args.skip_cost else "kernels", rows,
                         {"validation": err, "orders": order}))


if __name__ == "__main__":
    main()
