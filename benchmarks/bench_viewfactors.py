"""View factors (issue 16): time and error against pyviewfactor in the same run, and a synthetic
urban scene of about 22 000 facets (time, memory, nonzeros, row sums).

    python benchmarks/bench_viewfactors.py [--part compare|urban|block|both] [--blocks-small 3]
        [--blocks 8] [--facets 100000] [--workers 2] [--repeat 2]

compare: an urban scene of `--blocks-small`^2 blocks (2 976 facets at 3: streets, walls and
roofs in 2.5 m tiles; buildings block most views). Both tools run on the same machine in the
same process tree: ours on a LocalCluster of `--workers` single-threaded processes,
pyviewfactor 1.1 (`compute_viewfactor_matrix(mesh, obstacles=[mesh])`: one ray between
centroids per pair, its numba `prange` on all cores). Both are warmed first (numba compiles),
then timed (best of --repeat). The machine is shared: the JSON records the load average. Reference: ours at accuracy 1e-4 with up to 32 x 32 points per facet; the
reference itself is checked against an independent brute force (the exact unobstructed factor
times a visible fraction from random point pairs, one Embree ray each) on 400 random pairs
that are partly blocked in the reference (4 096 rays each) and on 12 whole rows (1 024 rays
per partner). Errors per row of F: the L1 error
sum_j |F_ij - Fref_ij| (what an energy balance of facet i sees), the row-sum error and the
largest factor error.

urban: `--blocks`^2 blocks (22 352 facets at 8; View3D's documented run: 22 176 facets in
1 280 s on 8 threads, 0.83 GiB), ours at the default accuracy; time, peak resident memory per
worker, nonzeros, row sums.

block: the same urban scene with enough blocks for `--facets` facets (100 128 at 17 blocks for
the default 10^5; the sky is the environment: rows below 1), rows kept per size.

Writes benchmarks/results/viewfactors.json and prints a table.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

from common import table, write

from radiosity.runtime.cluster import open_client
from radiosity.settings import options as settings_of


# ----------------------------------------------------------------------------- the scene

def urban(nb=8, block=20.0, street=10.0, tile=2.5, hmin=7.5, hmax=22.5, seed=0):
    """Vertices (V, 3) and quad faces of nb x nb box buildings (block x block footprint, heights
    hmin..hmax in whole tiles, seeded) on a ground plane with streets of width `street` all
    round; ground, walls and roofs in tile x tile quads, normals out of the buildings and up."""
    rng = np.random.default_rng(seed)
    nh = rng.integers(int(round(hmin / tile)), int(round(hmax / tile)) + 1, (nb, nb))
    L = nb * (block + street) + street
    index, V, F = {}, [], []

    def quad(*corners):
        ids = []
        for p in corners:
            key = tuple(round(float(x), 9) for x in p)
            if key not in index:
                index[key] = len(V)
                V.append(key)
            ids.append(index[key])
        F.append(ids)

    nt, bt, st = (int(round(x / tile)) for x in (L, block, street))

    def under_building(a, b):
        return all(x >= st and (x - st) % (bt + st) < bt and (x - st) // (bt + st) < nb
                   for x in (a, b))

    for a in range(nt):
        for b in range(nt):
            if not under_building(a, b):
                x, y = a * tile, b * tile
                quad((x, y, 0), (x + tile, y, 0), (x + tile, y + tile, 0), (x, y + tile, 0))
    for i in range(nb):
        for j in range(nb):
            x0, y0 = street + i * (block + street), street + j * (block + street)
            h = nh[i, j] * tile
            for a in range(bt):
                for b in range(bt):
                    x, y = x0 + a * tile, y0 + b * tile
                    quad((x, y, h), (x + tile, y, h), (x + tile, y + tile, h), (x, y + tile, h))
            for k in range(nh[i, j]):
                z = k * tile
                for a in range(bt):
                    s = a * tile
                    x1, y1, x2, y2 = x0 + s, y0 + s, x0 + s + tile, y0 + s + tile
                    quad((x1, y0, z), (x2, y0, z), (x2, y0, z + tile), (x1, y0, z + tile))          # -y
                    quad((x2, y0 + block, z), (x1, y0 + block, z), (x1, y0 + block, z + tile),
                         (x2, y0 + block, z + tile))                                                # +y
                    quad((x0, y2, z), (x0, y1, z), (x0, y1, z + tile), (x0, y2, z + tile))          # -x
                    quad((x0 + block, y1, z), (x0 + block, y2, z), (x0 + block, y2, z + tile),
                         (x0 + block, y1, z + tile))                                                # +x
    return np.array(V, float), F


# ----------------------------------------------------------------------------- helpers

def ours(mesh, workers, accuracy=None, smax=None, warm=True, repeat=1):
    """Our result and best wall time of `repeat` runs on a fresh LocalCluster (warmed on a
    tiny mesh: numba loads its cache on every worker)."""
    import dask.config

    from radiosity.viewfactors.api import compute_viewfactors

    cfg = {} if smax is None else {"radiosity.viewfactors.max-points-per-side": smax}
    with dask.config.set(cfg), open_client(workers, quiet=True, settings=settings_of().cluster) as client, \
            tempfile.TemporaryDirectory() as d:
        if warm:
            compute_viewfactors(urban(1, block=5, street=5), os.path.join(d, "warm"), client,
                                settings_of(), progress=False)
        wall = np.inf
        for k in range(repeat):
            t, c = time.perf_counter(), time.process_time()
            res = compute_viewfactors(mesh, os.path.join(d, f"run{k}"), client,
                                      settings_of(accuracy=accuracy), progress=False)
            if time.perf_counter() - t < wall:
                wall = time.perf_counter() - t
                # CPU seconds: the tasks' on the workers plus the driver's (load-independent)
                res.figures = {**res.figures.to_dict(),  # a plain dict, to add the driver's
                               "cpu_s": round(res.figures.task_cpu_s + time.process_time() - c, 2)}
    return res, wall


def pyviewfactor_matrix(V, F, repeat=1):
    """pyviewfactor's matrix as ours (row i: from facet i), its best wall time of `repeat` runs
    (warmed) and the CPU seconds of that run."""
    import pyvista as pv
    import pyviewfactor as pvf
    import scipy.sparse as sp

    def run(V, F):
        faces = np.concatenate([[len(f), *f] for f in F])
        mesh = pv.PolyData(np.asarray(V, float), faces)
        return pvf.compute_viewfactor_matrix(mesh, obstacles=[mesh])

    Vw, Fw = urban(1, block=5, street=5)
    run(Vw, Fw)                                      # numba compiles
    wall, cpu = np.inf, None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        M = run(V, F)
        if time.perf_counter() - t < wall:
            wall, cpu = time.perf_counter() - t, time.process_time() - c   # all its threads
    return sp.csr_matrix(M.T), wall, round(cpu, 2)   # pyviewfactor: F[i, j] = F(j -> i)


def errors(M, ref, area) -> dict:
    """Row L1 errors, row-sum errors and the largest factor error of M against ref (CSR)."""
    D = (M - ref).tocsr()
    D.data = np.abs(D.data)
    l1 = np.asarray(D.sum(axis=1)).ravel()
    rs = np.abs(np.asarray(M.sum(axis=1)).ravel() - np.asarray(ref.sum(axis=1)).ravel())
    return {"row_l1_median": float(np.median(l1)), "row_l1_p99": float(np.quantile(l1, 0.99)),
            "row_l1_max": float(l1.max()), "row_sum_err_max": float(rs.max()),
            "factor_err_max": float(D.data.max(initial=0.0))}


def check_reference(fac, ref, acc_ref, k=400, rows=12, rays=4096, seed=5) -> dict:
    """The reference against brute force (the exact unobstructed factor times a kernel-weighted
    visible fraction from random point pairs, one Embree ray each): on k random pairs it says
    are partly blocked (the largest difference, and how many differ by more than acc_ref + 4
    standard errors), and on whole rows (every facing partner of `rows` random facets, 1 024
    rays each: the row L1 difference against the brute force's own noise, sum of 2 standard
    errors)."""
    from radiosity.core.exact import pair_form_factors_exact
    from radiosity.tracing.rays import RayCaster

    rng = np.random.default_rng(seed)
    rc = RayCaster(fac.verts, fac.nverts)
    R = ref.tocsr()

    def pts(face, m):       # quads of the urban scene: parallelograms
        v = fac.verts[face]
        a, b = rng.random((2, m, 1))
        return v[0] + a * (v[1] - v[0]) + b * (v[3] - v[0])

    def brute(a, b, fu, m):
        x, y = pts(a, m), pts(b, m)
        d = y - x
        w = np.maximum(d @ fac.normal[a], 0) * np.maximum(-(d @ fac.normal[b]), 0) / (d * d).sum(1) ** 2
        if w.sum() == 0:
            return 0.0, 0.0
        vis = ~rc.occluded(x, y, np.full(m, a), np.full(m, b))
        phi = (w * vis).sum() / w.sum()
        return fu * phi, fu * np.sqrt(((w * (vis - phi)) ** 2).sum()) / w.sum()

    C = R.tocoo()
    up = C.row < C.col
    i, j, f = C.row[up], C.col[up], C.data[up]
    fu = pair_form_factors_exact(fac.verts[i], fac.nverts[i], fac.verts[j], fac.nverts[j], False)
    part = np.nonzero((f < fu * (1 - 1e-9)) & (f > 0))[0]
    worst, beyond = 0.0, 0
    for p in rng.choice(part, size=min(k, len(part)), replace=False):
        b, se = brute(int(i[p]), int(j[p]), fu[p], rays)
        worst = max(worst, abs(b - f[p]))
        beyond += abs(b - f[p]) > acc_ref + 4 * se
    n = len(fac)
    l1, noise = [], []
    for a in rng.choice(n, size=rows, replace=False):
        others = np.delete(np.arange(n), a)
        fu_row = pair_form_factors_exact(np.repeat(fac.verts[a:a + 1], n - 1, 0),
                                         np.repeat(fac.nverts[a:a + 1], n - 1), fac.verts[others],
                                         fac.nverts[others], False)
        diff, err = 0.0, 0.0
        ref_row = R[a].toarray().ravel()
        for jj, fj in zip(others[fu_row > 0], fu_row[fu_row > 0]):
            b, se = brute(int(a), int(jj), fj, 1024)
            diff += abs(b - ref_row[jj])
            err += 2 * se
        l1.append(diff)
        noise.append(err)
    return {"pairs": int(min(k, len(part))), "pair_abs_diff_max": worst,
            "pairs_beyond_accuracy_plus_4se": int(beyond), "rows": rows,
            "row_l1_diff_median": float(np.median(l1)), "row_l1_diff_max": float(np.max(l1)),
            "row_l1_brute_noise_median": float(np.median(noise))}


# ----------------------------------------------------------------------------- parts

def compare(nb: int, workers: int, repeat: int) -> list:
    from radiosity.viewfactors.api import load_facets

    V, F = urban(nb)
    fac = load_facets((V, F), settings_of())
    print(f"compare: {len(F)} facets; reference (accuracy 1e-4, 32 points per side) ...", flush=True)
    ref, t_ref = ours((V, F), workers, accuracy=1e-4, smax=32)
    chk = check_reference(fac, ref.matrix, 1e-4)
    rows = []
    for acc in (1e-2, 1e-3):
        res, wall = ours((V, F), workers, accuracy=acc, repeat=repeat)
        f = res.figures
        rows.append({"part": "compare", "tool": f"radiosity (accuracy {acc:g})", "facets": len(F),
                     "time_s": round(wall, 2), "cpu_s": f["cpu_s"],
                     "nonzeros": f["nonzeros"], "rays": f["rays"],
                     "peak_worker_MiB": max(f["peak_rss_mb"].get("workers", {0: 0}).values()),
                     **errors(res.matrix, ref.matrix, fac.area)})
    M, wall, cpu = pyviewfactor_matrix(V, F, repeat)
    rows.append({"part": "compare", "tool": "pyviewfactor 1.1 (centroid ray)", "facets": len(F),
                 "time_s": round(wall, 2), "cpu_s": cpu, "nonzeros": int(M.nnz), "rays": None,
                 **errors(M, ref.matrix, fac.area)})
    rows.append({"part": "compare", "tool": "reference (accuracy 1e-4, s <= 32)", "facets": len(F),
                 "time_s": round(t_ref, 2), "nonzeros": ref.figures["nonzeros"],
                 "rays": ref.figures["rays"], "reference_vs_brute_force": chk})
    return rows


def big(nb: int, workers: int) -> list:
    V, F = urban(nb)
    print(f"urban: {len(F)} facets ...", flush=True)
    res, wall = ours((V, F), workers)
    f = res.figures
    workers_mib = f["peak_rss_mb"].get("workers", {})
    return [{"part": "urban", "tool": "radiosity (accuracy 1e-3)", "facets": len(F),
             "time_s": round(wall, 1), "cpu_s": f["cpu_s"], "nonzeros": f["nonzeros"],
             "rays": f["rays"],
             "peak_worker_MiB": max(workers_mib.values()) if workers_mib else None,
             "peak_master_MiB": f["peak_rss_mb"]["master"],
             "row_sum_min": f["row_sum_min"], "row_sum_max": f["row_sum_max"],
             "row_sum_histogram": f["row_sum_histogram"],
             "counts": {k: f[k] for k in f if k.startswith("pairs_") or k == "rays"},
             "task_time_by_stage_s": f["task_time_by_stage_s"],
             "busy_s_per_worker": f["busy_s_per_worker"],
             "view3d_s_on_8_threads": 1280.0,
             # its thread-seconds per our CPU-second (other hardware: an order of magnitude)
             "view3d_thread_s_per_our_cpu_s": round(1280.0 * 8 / f["cpu_s"], 1)}]


def blocks_for(facets: int) -> int:
    """The fewest blocks per side whose urban scene has at least `facets` facets (17: 100 128)."""
    nb = 1
    while len(urban(nb)[1]) < facets:
        nb += 1
    return nb


def block(facets: int, workers: int) -> list:
    """The urban block of about `facets` facets (issue 53: 10^5, view factors and heat in
    under 10 minutes on this machine): the urban scene's rows, tagged with the target size."""
    rows = big(blocks_for(facets), workers)
    for r in rows:
        r.update(part="block", target_facets=facets)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--part", choices=["compare", "urban", "block", "both"], default="both")
    ap.add_argument("--facets", type=int, default=100_000,
                    help="block: the urban block's size in facets (blocks chosen to reach it)")
    ap.add_argument("--blocks-small", type=int, default=3)
    ap.add_argument("--blocks", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=2, help="compare: best of this many timed runs")
    a = ap.parse_args()
    rows = []
    for part, fn in (("compare", lambda: compare(a.blocks_small, a.workers, a.repeat)),
                     ("urban", lambda: big(a.blocks, a.workers)),
                     ("block", lambda: block(a.facets, a.workers))):
        if a.part in (part, "both"):
            before = os.getloadavg()[0]
            got = fn()
            for r in got:   # the machine is shared: how busy it was
                r["load_average_1min_before_after"] = [before, os.getloadavg()[0]]
            rows += got
    # a run of one part keeps the other part's rows from the last JSON
    import json

    from common import RESULTS

    old = os.path.join(RESULTS, "viewfactors.json")
    if a.part != "both" and os.path.exists(old):
        with open(old) as f:
            rows = [r for r in json.load(f)["rows"] if r["part"] != a.part
                    or (a.part == "block" and r["facets"] != rows[-1]["facets"])] + rows
    fn = write("viewfactors", rows, {"workers": a.workers, "repeat": a.repeat})
    print(table(rows, ["part", "tool", "facets", "time_s", "cpu_s", "nonzeros", "rays", "peak_worker_MiB",
                       "row_l1_median", "row_l1_p99", "row_l1_max", "row_sum_err_max",
                       "factor_err_max"]))
    for r in rows:
        if "reference_vs_brute_force" in r:
            print("reference against brute force:", r["reference_vs_brute_force"])
        if r["part"] in ("urban", "block"):
            print("urban row sums:", r["row_sum_min"], "..", r["row_sum_max"], r["row_sum_histogram"])
            print("urban stages:", r["task_time_by_stage_s"], "busy:", r["busy_s_per_worker"])
    print(f"wrote {fn}")


if __name__ == "__main__":
    main()
