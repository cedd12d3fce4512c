"""The link oracle with the emitters' light at points: smooth against plain (radiosity.direct.oracle,
methods/hierarchical/params.smooth_weights; issue 50). On one scene at one raster: the link stage
and solve of each configuration ORACLE:FLOOR:EPSILON (the first is the reference, a fine epsilon),
in one process on a LocalCluster of 2 single-threaded workers; links, leaves, rays, link stage
plus solve time, and each original's mean radiance (front side, largest channel) against the
reference: worst and mean relative difference over the originals above the 20th percentile of
area.

    python benchmarks/bench_smooth_oracle.py [--scene cornell-box] [--resolution 24]
        [--configs plain:0:5e-5,plain:0:2e-4,plain:0:4e-4,smooth:0.25:2e-4,...] [--name smooth-oracle]

Writes benchmarks/results/<name>.json and prints the table.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import ROOT, table, write  # noqa: E402

CONFIGS = ("plain:0:5e-5,plain:0:2e-4,plain:0:4e-4,plain:0:8e-4,smooth:0.25:1e-4,"
           "smooth:0.25:2e-4,smooth:0.1:2e-4,smooth:0:2e-4")


def _means(out: str) -> tuple[np.ndarray, np.ndarray]:
    """Each original's area-weighted mean radiance (front side, largest channel), and area."""
    from radiosity.runtime.store import RunStore

    rs = RunStore(out)
    part, L = rs.load_partition(), rs.read_arrays("solution")["radiance"][:, 0, :]
    n = len(part.offsets) - 1
    w = np.zeros((n, 3))
    np.add.at(w, part.orig, part.area[:, None] * L)
    a = np.bincount(part.orig, part.area, n)
    return (w / np.maximum(a, 1e-300)[:, None]).max(axis=1), a


def main() -> None:
    from distributed import Client, LocalCluster

    from radiosity.methods.hierarchical.links.master import compute_links
    from radiosity.scene.load import load_scene
    from radiosity.settings import options
    from radiosity.stages.preprocess import preprocess
    from radiosity.stages.solve import run_solve

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cornell-box")
    ap.add_argument("--resolution", type=int, default=24)
    ap.add_argument("--configs", default=CONFIGS)
    ap.add_argument("--name", default="smooth-oracle")
    a = ap.parse_args()
    toml = os.path.join(ROOT, "scenes", a.scene, "scene.toml")
    rows, ref = [], None
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp, \
            LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                         dashboard_address=None, silence_logs=40) as cl, Client(cl) as c:
        for k, cfg in enumerate(a.configs.split(",")):
            oracle, floor, eps = cfg.split(":")
            out = os.path.join(tmp, f"run{k}")
            preprocess(load_scene(toml, resolution=a.resolution, settings=options()), out, c,
                       options(), progress=False)
            s = options(direct="points", epsilon=float(eps)).replace(
                {"direct.oracle": oracle, "direct.smooth-floor": float(floor)})
            t = time.perf_counter()
            lf = compute_links(out, c, s, progress=False)
            run_solve(out, c, s, method="hierarchical", progress=False)
            dt = time.perf_counter() - t
            m, area = _means(out)
            row = {"oracle": oracle, "floor": float(floor), "epsilon": float(eps),
                   "links": int(lf.links), "leaves": int(lf.leaves), "rays": int(lf.rays),
                   "time_s": round(dt, 1)}
            if ref is None:
                ref = m
                big = (area > np.percentile(area, 20)) & (ref > 0)
            rel = np.abs(m[big] / ref[big] - 1)
            row.update(worst=float(rel.max()), mean=float(rel.mean()))
            rows.append(row)
            print(row, flush=True)
    cols = ["oracle", "floor", "epsilon", "links", "leaves", "rays", "time_s", "worst", "mean"]
    print(table(rows, cols))
    print("wrote", write(a.name, rows, {"scene": a.scene, "resolution": a.resolution,
                                        "reference": a.configs.split(",")[0],
                                        "loadavg_start": load0, "loadavg_end": os.getloadavg()}))


if __name__ == "__main__":
    main()
