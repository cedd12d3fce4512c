"""Preprocessing time against camera resolution on the Cornell box (seed Fig. 3), and camera
rays/s of our ray module against raw embreex first-hit throughput on the same rays, same run.

    python benchmarks/bench_preprocess.py [--max-res 512] [--workers 2]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from common import best_of, table, write

from radiosity.core.camera import ray_directions32
from radiosity.core.geometry import element_triangles
from radiosity.tracing.rays import RayCaster
from radiosity.scene.load import load_scene
from radiosity.tracing.rays import raster_band
from radiosity.scene.subdivide import subdivide
from radiosity.settings import options as settings_of


def raw_embree(el):
    """A bare embreex scene of the same normalised triangles, and the frame it uses."""
    from embreex import mesh_construction, rtcore_scene

    tris, owner = element_triangles(el.verts, el.nverts)
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    origin, scale = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    sc = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(sc, ((tris - origin) / scale).astype(np.float32))
    return sc, origin, scale


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-res", type=int, default=512)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scene", default="scenes/cornell-box/scene.toml")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    sc = load_scene(args.scene, settings=settings_of())
    el = sc.elements
    rc = RayCaster(el.verts, el.nverts)
    raw, origin, scale = raw_embree(el)
    rows = []
    res = 32
    while res <= args.max_res:
        cam = sc.camera.with_resolution(res, res)
        d32 = ray_directions32(cam, 1, 0, res)
        n = len(d32)
        o32 = np.ascontiguousarray(np.broadcast_to((cam.center - origin) / scale, d32.shape), np.float32)
        t_raw = best_of(lambda: raw.run(o32, d32), 5)
        t_ours = best_of(lambda: rc.first_hit(cam.center, d32, unit=True), 5)
        t_band = best_of(lambda: raster_band(rc, el.normal, el.center, cam, 1, slice(0, res)), 5)
        elem, pts = raster_band(rc, el.normal, el.center, cam, 1, slice(0, res))
        hit = elem >= 0
        t_sub = best_of(lambda: subdivide(el.verts, el.nverts, el.normal, pts[hit], elem[hit]), 2)
        part, fig = subdivide(el.verts, el.nverts, el.normal, pts[hit], elem[hit])
        rows.append({"resolution": res, "rays": n, "sub_elements": len(part), "levels": fig["levels"],
                     "raster_s": t_band, "subdivide_s": t_sub, "preprocess_s": t_band + t_sub,
                     "raw_embree_Mrays_s": n / t_raw / 1e6, "ours_Mrays_s": n / t_ours / 1e6,
                     "ours_vs_raw": t_raw / t_ours, "raster_vs_raw": t_raw / t_band})
        res *= 2
    # the Dask pipeline at the largest resolution (includes cluster round trips)
    from radiosity.runtime.cluster import open_client
    from radiosity.stages.preprocess import preprocess
    import tempfile

    with open_client(args.workers, quiet=True, settings=settings_of().cluster) as client:
        for res in (128, args.max_res):
            s2 = load_scene(args.scene, resolution=res, settings=settings_of())
            with tempfile.TemporaryDirectory() as d:
                preprocess(s2, d, client, settings_of(), progress=False)  # warm the workers
                t = time.perf_counter()
                fig = preprocess(s2, d, client, settings_of(), progress=False)
                rows.append({"resolution": res, "rays": res * res, "sub_elements": fig["sub_elements"],
                             "levels": fig["levels"], "dask_pipeline_s": time.perf_counter() - t})
    cols = ["resolution", "rays", "sub_elements", "levels", "raster_s", "subdivide_s", "preprocess_s",
            "raw_embree_Mrays_s", "ours_Mrays_s", "ours_vs_raw", "raster_vs_raw", "dask_pipeline_s"]
    print(table(rows, cols))
    fn = write("preprocess", rows, {"scene": args.scene, "workers": args.workers})
    print(f"wrote {fn}")


if __name__ == "__main__":
    main()
