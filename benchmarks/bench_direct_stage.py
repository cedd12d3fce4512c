"""The leaves' first bounce L1 (methods/hierarchical/solve/direct.py) in process and as the
direct stage on a local cluster, on a real scene's partition (its sub-elements as the leaves, as
a link table without refinement below them has): leaves, points, shadow rays, seconds each
way (the stage on cold workers, on warm ones, and again on its own store: every task reused by
the token), the stage's tasks, and that both give the same bits.

    python benchmarks/bench_direct_stage.py [--scene modern-hall] [--res 64] [--workers 2]

docs/src/measurements/direct-stage.md's table comes from this script.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings

import numpy as np

from common import HERE, table, write

from radiosity.methods.hierarchical.solve.direct import first_bounce
from radiosity.runtime.cluster import open_client
from radiosity.runtime.store import RunStore
from radiosity.scene.load import load_scene
from radiosity.scene.subdivide import subdivide_scene
from radiosity.settings import options as settings_of


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="modern-hall")
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    s = settings_of()
    path = os.path.join(HERE, "real", args.scene, "scene.toml")
    sc = load_scene(path, resolution=args.res, settings=s)
    el = sc.elements
    part = subdivide_scene(el, sc.camera)[0]
    leaves = {"verts": part.verts, "nverts": part.nverts, "orig": part.orig,
              "leaf_node": np.arange(len(part))}
    rows, figs = [], []
    t = time.perf_counter()
    here = first_bounce(leaves, el, s, figures=figs)
    rows.append({"where": "driver", "seconds": round(time.perf_counter() - t, 2)})
    with open_client(args.workers, quiet=True, settings=s.cluster) as client, \
            tempfile.TemporaryDirectory() as d:
        # cold: the workers' first stage (imports, Embree scene); warm: a second store, as in a
        # run whose link stage built the scene already; reused: the same store again (the token)
        for label, where in (("cold", "a"), ("warm", "b"), ("reused", "b")):
            rs = RunStore(os.path.join(d, where), "w" if label != "reused" else "r+")
            t = time.perf_counter()
            there = first_bounce(leaves, el, s, rs=rs, client=client, where="workers",
                                 figures=figs)
            rows.append({"where": f"workers, {label}", "seconds": round(time.perf_counter() - t, 2),
                         "same_bits": bool(np.array_equal(here, there))})
    for r, f in zip(rows, figs):
        r.update({"leaves": f.leaves, "points": f.points, "max_a_leaf": f.points_per_leaf_max,
                  "more_points": f.leaves_more_points, "emitters": f.emitters,
                  "shadow_rays": f.shadow_rays, "tasks": f.tasks, "reused": f.tasks_reused,
                  "rays_per_s": "" if f.tasks_reused else
                  round(f.shadow_rays / max(r["seconds"], 1e-9))})
    print(table(rows, ["where", "leaves", "points", "max_a_leaf", "more_points", "emitters",
                       "shadow_rays", "tasks", "reused", "seconds", "rays_per_s", "same_bits"]))
    print("wrote", write(f"direct-stage-{args.scene}", rows, {"scene": args.scene, "resolution": args.res,
                                          "workers": args.workers, "triangles": len(el)}))


if __name__ == "__main__":
    main()
