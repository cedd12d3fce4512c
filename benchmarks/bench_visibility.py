"""Visibility stage: time against the number of sub-elements (seed Fig. 4), speedup and parallel
efficiency for 1 and 2 workers (seed §5.2), rays/s of our ray module against raw embreex
occlusion on the same segments in the same run, the fraction of pairs that still needed a ray,
and peak memory per worker.

    python benchmarks/bench_visibility.py [--resolutions 24,32,48,64,96,128] [--speedup-res 96]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings

import numpy as np

from common import best_of, table, write

from radiosity.runtime.cluster import open_client
from radiosity.stages.preprocess import preprocess
from radiosity.scene.load import load_scene
from radiosity.runtime.store import RunStore
from radiosity.tracing.shafts import block_candidates, classify
from radiosity.methods.pairs.visibility import compute_visibility, vis_inputs
from radiosity.settings import options as settings_of


def run(scene, res, workers, unit=None):
    sc = load_scene(scene, resolution=res, settings=settings_of())
    with open_client(workers, quiet=True, settings=settings_of().cluster) as client, tempfile.TemporaryDirectory() as d:
        preprocess(sc, d, client, settings_of(), progress=False)
        # warm-up: numba kernels load from cache, Embree scenes build on every worker
        compute_visibility(d, client, settings_of(), progress=False, unit=unit)
        t = time.perf_counter()
        fig = compute_visibility(d, client, settings_of(), progress=False, unit=unit).to_dict()
        fig["wall_s"] = time.perf_counter() - t
        return fig


def ray_throughput(scene, res):
    """Segments of the largest block that needed rays: our occluded() against raw embreex."""
    from radiosity.core.geometry import element_triangles
    from radiosity.tracing.rays import RayCaster
    from embreex import mesh_construction, rtcore_scene

    sc = load_scene(scene, resolution=res, settings=settings_of())
    with open_client(1, quiet=True, settings=settings_of().cluster) as client, tempfile.TemporaryDirectory() as d:
        preprocess(sc, d, client, settings_of(), progress=False)
        rs = RunStore(d)
        part, el = rs.load_partition(), rs.load_elements()
    inp = vis_inputs(part, el, "bench", 1e-6)
    sizes = np.diff(part.offsets)
    i, j = np.argsort(sizes)[-2:]
    i, j = min(i, j), max(i, j)
    a0, a1, b0, b1 = part.offsets[i], part.offsets[i + 1], part.offsets[j], part.offsets[j + 1]
    A = np.array([inp.lo[a0:a1].min(0), inp.hi[a0:a1].max(0)])
    B = np.array([inp.lo[b0:b1].min(0), inp.hi[b0:b1].max(0)])
    pad = inp.pad
    cand = block_candidates(A, B, inp.elo, inp.ehi, inp.enormal, inp.eoffset, pad, i, j)
    code, _ = classify((inp.center[a0:a1], inp.normal[a0:a1], inp.two_sided[a0:a1], inp.lo[a0:a1],
                        inp.hi[a0:a1]),
                       (inp.center[b0:b1], inp.normal[b0:b1], inp.two_sided[b0:b1], inp.lo[b0:b1],
                        inp.hi[b0:b1]),
                       (inp.elo, inp.ehi, inp.enormal, inp.eoffset, pad), cand, False)
    need = np.nonzero(code == 2)[0]
    if len(need) < 1000:  # an unoccluded pair of blocks: take all facing pairs instead
        need = np.nonzero(code > 0)[0]
    nb = b1 - b0
    ia, ib = a0 + need // nb, b0 + need % nb
    p, q = part.center[ia], part.center[ib]
    rc = RayCaster(el.verts, el.nverts)
    tris, _ = element_triangles(el.verts, el.nverts)
    raw = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(raw, ((tris - rc.origin) / rc.scale).astype(np.float32))
    a = (p - rc.origin) / rc.scale
    dv = (q - rc.origin) / rc.scale - a
    L = np.linalg.norm(dv, axis=1)
    dv /= L[:, None]
    o32 = (a + rc.ray_offset * dv).astype(np.float32)
    d32 = dv.astype(np.float32)
    f32 = (L - 2 * rc.ray_offset).astype(np.float32)
    t_raw = best_of(lambda: raw.run(o32, d32, dists=f32, query="OCCLUDED"), 5)
    t_ours = best_of(lambda: rc.occluded_pairs(part.center, ia, ib, part.orig), 5)
    return {"rays": len(need), "raw_Mrays_s": len(need) / t_raw / 1e6,
            "ours_Mrays_s": len(need) / t_ours / 1e6, "ours_vs_raw": t_raw / t_ours}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="scenes/cornell-box/scene.toml")
    ap.add_argument("--resolutions", default="24,32,48,64,96,128")
    ap.add_argument("--speedup-res", type=int, default=96)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    rows = []
    for res in [int(r) for r in args.resolutions.split(",")]:
        f = run(args.scene, res, 2)
        peak = f["peak_rss_mb"].get("workers", {})
        rows.append({"resolution": res, "workers": 2, "sub_elements": f["sub_elements"],
                     "pairs": f["pairs_total"], "facing": f["pairs_facing"] / f["pairs_total"],
                     "rays_frac": f["rays_fraction_of_pairs"], "rays": f["rays"], "time_s": f["wall_s"],
                     "Mpairs_s": f["pairs_total"] / f["wall_s"] / 1e6, "idle": f["idle_fraction"],
                     "peak_worker_MiB": max(peak.values()) if peak else None, "tasks": f["tasks"]})
    m = np.array([r["sub_elements"] for r in rows], float)
    t = np.array([r["time_s"] for r in rows])
    big = m >= np.median(m)
    order = float(np.polyfit(np.log(m[big]), np.log(t[big]), 1)[0]) if big.sum() >= 2 else None
    speed = []
    for w in (1, 2):
        f = run(args.scene, args.speedup_res, w)
        speed.append({"workers": w, "time_s": f["wall_s"], "idle": f["idle_fraction"]})
    for s in speed:
        s["speedup"] = speed[0]["time_s"] / s["time_s"]
        s["efficiency"] = s["speedup"] / s["workers"]
    rt = ray_throughput(args.scene, 128)
    print("visibility time against sub-elements (seed Fig. 4)")
    print(table(rows, ["resolution", "sub_elements", "pairs", "facing", "rays_frac", "rays", "time_s",
                       "Mpairs_s", "idle", "peak_worker_MiB", "tasks"]))
    if order is not None:
        print(f"growth order (log-log slope of time against sub-elements, upper half): {order:.2f}")
    print(f"\nspeedup at {args.speedup_res}x{args.speedup_res} (seed §5.2)")
    print(table(speed, ["workers", "time_s", "speedup", "efficiency", "idle"]))
    print("\nocclusion rays: ours against raw embreex on the same segments")
    print(table([rt], ["rays", "raw_Mrays_s", "ours_Mrays_s", "ours_vs_raw"]))
    fn = write("visibility", rows, {"scene": args.scene, "growth_order": order, "speedup": speed,
                                    "ray_throughput": rt})
    print(f"wrote {fn}")


if __name__ == "__main__":
    main()
