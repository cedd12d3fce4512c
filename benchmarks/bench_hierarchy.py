"""Hierarchical radiosity (--method hierarchical) against the seed's all-pairs matrix (--method
pairs), both in the same run, on the Cornell box at growing resolutions.

Per (method, resolution): sub-elements, nodes, links, links per leaf, rays, the time of every
stage (the whole `render_scene` on a warm 2-worker LocalCluster, not the process start; up to
--repeat-below the best of --repeat rounds of both methods in turn, by visibility + solve, the
median beside it), peak memory per worker, and the error of the image against a Mitsuba 3 path-traced reference of the
same view (rendered at 64x64 with high spp; it and every image are box-filtered to --grid
(32x32) before comparing, exact because the pixels nest, so that the reference's own noise,
printed as its noise floor, stays well below the methods' errors): over all cells, and over the
cells wholly inside one element (the solution's error without the edges' sampling). Peak memory is each
worker's high-water mark within the run (VmHWM, reset before each run). The link stage's whole
throughput (its rays over its wall time on all workers) is set against raw embreex casting the
same rays (one thread, times the worker count) in the same run, and so is the stage's own ray
call (RayCaster.occluded_pairs, one thread) on the same batches.

    python benchmarks/bench_hierarchy.py [--sizes 64,128,256,512] [--pairs 64,128]
                                         [--spp 8192] [--grid 32] [--room 256]
                                         [--repeat 3] [--repeat-below 128]

Writes benchmarks/results/hierarchy.json and prints the tables.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

from common import ROOT, best_of, table, write
from radiosity.runtime.cluster import open_client
from radiosity.validation.compare import box_down, box_down_stderr, errors, noise_floor
from radiosity.pipeline import render_scene
from radiosity.stages.image import read_exr
from radiosity.scene.load import load_scene
from radiosity.settings import options as settings_of

CORNELL = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")
ROOM = os.path.join(ROOT, "scenes", "room-2400", "scene.toml")
GRID = 64


def reference(spp: int, out: str) -> dict:
    """The Mitsuba reference of the Cornell box at GRID x GRID: mean, stderr, figures."""
    from radiosity.validation.reference import make_reference

    fig = make_reference(load_scene(CORNELL, resolution=GRID, settings=settings_of()), out,
                         spp=spp, passes=8, echo=lambda *a: None, settings=settings_of())
    return {"mean": read_exr(os.path.join(out, "reference.exr")),
            "stderr": read_exr(os.path.join(out, "reference-stderr.exr")), "figures": fig}


def link_rays_vs_raw(run_dir: str, workers: int, stage_rays_per_s: float) -> dict:
    """The rays of a few link tasks, re-made in-process (refine_pairs keeps them), cast by raw
    embreex: its rays/s on one thread times `workers`, against the whole stage's."""
    from embreex import mesh_construction, rtcore_scene

    from radiosity.scene.splittrees import seen_originals, tree_nodes
    from radiosity.methods.hierarchical.links.master import LinkInputs, refine_pairs
    from radiosity.methods.hierarchical.params import resolve_params
    from radiosity.core.geometry import element_triangles
    from radiosity.tracing.rays import RayCaster
    from radiosity.methods.hierarchical.store import LinkStore
    from radiosity.runtime.store import RunStore

    rs = RunStore(run_dir)
    part, el = rs.load_partition(), rs.load_elements()
    prm, weight = resolve_params(el, settings_of())
    seen = seen_originals(rs.read_arrays("raster")["orig"], len(el))
    inp = LinkInputs(tree_nodes(part, el), part, el, seen, prm, weight, "bench",
                     float(settings_of().rays.offset))
    pairs, first = LinkStore(rs).plan()
    rc = RayCaster(el.verts, el.nverts)
    kept: list = []
    refine_pairs(inp, pairs[: min(len(pairs), 40)], rc, kept)
    pts = np.concatenate([k[0] for k in kept])
    segs = []
    for p, _ in kept:  # each batch: n ray starts, then n ray ends
        n = len(p) // 2
        segs.append((p[:n], p[n:]))
    a = np.concatenate([s[0] for s in segs])
    b = np.concatenate([s[1] for s in segs])
    tris, _ = element_triangles(el.verts, el.nverts)
    raw = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(raw, ((tris - rc.origin) / rc.scale).astype(np.float32))
    a1 = (a - rc.origin) / rc.scale
    dv = (b - rc.origin) / rc.scale - a1
    L = np.linalg.norm(dv, axis=1)
    ok = L > 2 * rc.ray_offset
    a1, dv, L = a1[ok], dv[ok], L[ok]
    dv /= L[:, None]
    o32 = (a1 + rc.ray_offset * dv).astype(np.float32)
    d32 = dv.astype(np.float32)
    f32 = (L - 2 * rc.ray_offset).astype(np.float32)
    t_raw = best_of(lambda: raw.run(o32, d32, dists=f32, query="OCCLUDED"), 3)
    raw_rate = len(o32) / t_raw

    def call():  # the stage's own ray call on the same batches (links.link_fractions)
        for p, e in kept:
            idx = np.arange(len(p) // 2)
            rc.occluded_pairs(p, idx, idx + len(idx), e)

    call_rate = sum(len(p) // 2 for p, _ in kept) / best_of(call, 3)
    return {"sample_rays": int(len(o32)), "raw_Mrays_s_1thread": raw_rate / 1e6,
            "call_Mrays_s_1thread": call_rate / 1e6, "call_vs_raw": call_rate / raw_rate,
            "stage_Mrays_s": stage_rays_per_s / 1e6,
            "stage_vs_raw": stage_rays_per_s / (raw_rate * workers), "points": int(len(pts))}


def _reset_peak() -> None:
    """Reset this process's VmHWM to its current RSS (Linux: clear_refs 5)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


def interior_cells(grid: int) -> np.ndarray:
    """(grid, grid) bool: the error grid's cells wholly inside one element of the Cornell box
    (compare.interior of the element raster at that size): there the error is the solution's,
    not the edges' (a pixel that straddles the light's edge is point-sampled by the engine and
    area-averaged by the path tracer: -85 % on the light's border cells, about half of the
    all-cell error at 128^2, the same for both methods)."""
    from radiosity.validation.compare import element_raster, interior

    return interior(element_raster(load_scene(CORNELL, resolution=grid, settings=settings_of())))


def run_one(client, scene_file: str, res: int, method: str, d: str, ref=None, grid: int = 32) -> dict:
    sc = load_scene(scene_file, resolution=res, settings=settings_of())
    client.run(_reset_peak)
    out = os.path.join(d, f"{os.path.basename(os.path.dirname(scene_file))}-{method}-{res}")
    t = time.perf_counter()
    rep = render_scene(sc, out, client, settings_of(method=method), preview=False, progress=False)
    wall = time.perf_counter() - t
    st = rep.stages
    row = {"scene": os.path.basename(os.path.dirname(scene_file)), "method": method, "res": res,
           "sub_elements": rep["preprocess"]["sub_elements"],
           "preprocess_s": st["preprocess_s"], "visibility_s": st["visibility_s"],
           "solve_s": st["solve_s"], "image_s": st["image_s"], "total_s": wall,
           "vis_plus_solve_s": st["visibility_s"] + st["solve_s"],
           "peak_worker_mib": max((st.get("peak_rss_mb") or {}).get("workers", {}).values(), default=None),
           "peak_driver_mib": (st.get("peak_rss_mb") or {}).get("master"),
           "passes": rep["solve"]["iterations"], "kernel": rep["solve"]["kernel"]}
    if method == "hierarchical":
        lk = rep["links"]
        row.update(nodes=lk["nodes"], leaves=lk["leaves"], links=lk["links"],
                   links_per_leaf=lk["links_per_leaf"], rays=lk["rays"],
                   split_off=lk["split_off_nodes"], link_stage_Mrays_s=lk["rays_per_s"] / 1e6,
                   link_bytes_mib=lk["link_bytes"] / 2**20)
        row["_run"] = out
    else:
        row.update(rays=rep["visibility"]["rays"], pairs=rep["visibility"]["pairs_total"])
    if ref is not None:
        img = box_down(read_exr(os.path.join(out, "image.exr")), grid, grid)
        r = box_down(ref["mean"], grid, grid)
        e = errors(img, r)
        row.update(mare=e["mare"], max_rel=e["max"],
                   mare_interior=errors(img, r, ref["interior"])["mare"])
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="64,128,256,512")
    ap.add_argument("--pairs", default="64,128,256", help="resolutions for --method pairs too")
    ap.add_argument("--spp", type=int, default=8192, help="reference samples per pixel (64x64)")
    ap.add_argument("--grid", type=int, default=32, help="errors on this grid (box filter)")
    ap.add_argument("--room", type=int, default=256, help="room-2400 hierarchical at this (0: skip)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3, help="runs per row up to --repeat-below")
    ap.add_argument("--repeat-below", type=int, default=128)
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",") if s]
    pairs_sizes = [int(s) for s in args.pairs.split(",") if s]
    rows = []
    with tempfile.TemporaryDirectory() as d, open_client(args.workers, quiet=True,
                                                         settings=settings_of().cluster) as client:
        t = time.perf_counter()
        ref = reference(args.spp, os.path.join(d, "reference"))
        ref["interior"] = interior_cells(args.grid)
        mean, se = (box_down(ref["mean"], args.grid, args.grid),
                    box_down_stderr(ref["stderr"], args.grid, args.grid))
        ref_fig = {**ref["figures"], "wall_s": time.perf_counter() - t, "grid": args.grid,
                   "noise_floor": noise_floor(mean, se),
                   "noise_floor_interior": noise_floor(mean, se, ref["interior"]),
                   "interior_cells": int(ref["interior"].sum())}
        print(f"reference: Mitsuba {ref_fig['variant']}, {ref_fig['spp']} spp at {GRID}x{GRID} in "
              f"{ref_fig['time_s']:.1f} s; errors on {args.grid}x{args.grid}, where its noise floor "
              f"(mean abs. rel. error of an exact image) is {ref_fig['noise_floor']:.2e}")
        # warm numba caches and the workers
        run_one(client, CORNELL, 16, "hierarchical", d)
        run_one(client, CORNELL, 16, "pairs", d)
        for res in sizes:
            methods = (["pairs"] if res in pairs_sizes else []) + ["hierarchical"]
            # the machine is shared: up to --repeat-below, --repeat rounds of both methods in
            # turn (a slow minute slows both), the best run of each by visibility + solve, the
            # median beside it
            n = args.repeat if res <= args.repeat_below else 1
            runs = {m: [] for m in methods}
            for _ in range(n):
                for method in methods:
                    runs[method].append(run_one(client, CORNELL, res, method, d, ref, args.grid))
            for method in methods:
                row = min(runs[method], key=lambda r: r["vis_plus_solve_s"])
                row["runs"] = n
                row["vis_plus_solve_median_s"] = float(np.median([r["vis_plus_solve_s"]
                                                                  for r in runs[method]]))
                rows.append(row)
                print(f"  {method:12s} {res:4d}^2: {row['sub_elements']} sub-elements, total "
                      f"{row['total_s']:.1f} s, error {row['mare']:.4f} (interior cells "
                      f"{row['mare_interior']:.4f})", flush=True)
        if args.room:
            rows.append(run_one(client, ROOM, args.room, "hierarchical", d))
        h = [r for r in rows if r["method"] == "hierarchical" and r["scene"] == "cornell-box"]
        ratio = link_rays_vs_raw(h[min(1, len(h) - 1)]["_run"], args.workers,
                                 h[min(1, len(h) - 1)]["link_stage_Mrays_s"] * 1e6) if h else None
    for r in rows:
        r.pop("_run", None)
    for a in pairs_sizes:
        p = [r for r in rows if r["res"] == a and r["method"] == "pairs" and r["scene"] == "cornell-box"]
        q = [r for r in rows if r["res"] == a and r["method"] == "hierarchical" and r["scene"] == "cornell-box"]
        if p and q:
            q[0]["speedup_vis_solve"] = p[0]["vis_plus_solve_s"] / q[0]["vis_plus_solve_s"]
            q[0]["speedup_total"] = p[0]["total_s"] / q[0]["total_s"]
    fn = write("hierarchy", rows, {"reference": {k: v for k, v in ref_fig.items() if k != "camera"},
                                   "link_rays_vs_raw": ratio})
    print(table(rows, ["scene", "method", "res", "sub_elements", "nodes", "links", "links_per_leaf",
                       "rays", "visibility_s", "solve_s", "total_s", "peak_worker_mib", "mare", "mare_interior",
                       "vis_plus_solve_median_s", "speedup_vis_solve", "speedup_total"]))
    if ratio:
        print("\nlink stage rays/s against raw embreex on the same rays (x workers):")
        print(table([ratio], ["sample_rays", "raw_Mrays_s_1thread", "call_Mrays_s_1thread",
                              "call_vs_raw", "stage_Mrays_s", "stage_vs_raw"]))
    print(f"wrote {fn}")


if __name__ == "__main__":
    main()
