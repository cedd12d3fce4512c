"""Many original elements (issue 15): a floor of N small jittered triangles (they do not merge
into quads) under one light quad, seen from above. `radiosity plan` and `radiosity render` run as
the user runs them (their own processes); their wall time and peak memory (the largest process:
driver or worker) are measured, and the figures of the hierarchy over the originals
(originals.py) on the driver. Before issue 15 each of plan, render and visibility allocated an
(n, n, 4) float64 array: 1.16 TiB at N = 200 000.

    python benchmarks/bench_many_originals.py [--triangles 200000] [--resolution 16] [--no-render]

Writes benchmarks/results/many_originals.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

from common import ROOT, table, write
from radiosity.settings import options as settings_of


def write_scene(d: str, triangles: int, resolution: int, seed: int = 5) -> str:
    """An OBJ of about `triangles` floor triangles (jittered grid, normals up) and a light."""
    side = max(1, int(round(np.sqrt(triangles / 2))))
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(np.arange(side + 1.0), np.arange(side + 1.0), indexing="ij"), -1)
    g += rng.uniform(-0.2, 0.2, g.shape)
    idx = np.arange((side + 1) ** 2).reshape(side + 1, side + 1) + 1
    a, b, c, e = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                            np.stack([a, e, c], -1).reshape(-1, 3)])
    s = float(side)
    with open(os.path.join(d, "floor.obj"), "w") as f:
        f.write("usemtl floor\n")
        f.write("".join(f"v {x:.6f} 0 {z:.6f}\n" for x, z in g.reshape(-1, 2)))
        f.write("".join(f"f {i} {j} {k}\n" for i, j, k in faces))
        m = len(g.reshape(-1, 2))
        f.write(f"usemtl light\nv {0.4 * s} {0.3 * s} {0.4 * s}\nv {0.6 * s} {0.3 * s} {0.4 * s}\n"
                f"v {0.6 * s} {0.3 * s} {0.6 * s}\nv {0.4 * s} {0.3 * s} {0.6 * s}\n"
                f"f {m + 1} {m + 2} {m + 3} {m + 4}\n")  # facing down
    toml = f"""name = "many-originals-{len(faces)}"
[[mesh]]
path = "floor.obj"
[material.floor]
reflectance = [0.6, 0.6, 0.6]
[material.light]
reflectance = [0.0, 0.0, 0.0]
emission = [10.0, 10.0, 10.0]
[camera]
position = [{0.2 * s}, {0.8 * s}, {0.2 * s - 0.01}]
look_at = [{0.2 * s}, 0.0, {0.2 * s}]
up = [0.0, 0.0, 1.0]
fov_y = 20.0
resolution = [{resolution}, {resolution}]
"""
    fn = os.path.join(d, "scene.toml")
    with open(fn, "w") as f:
        f.write(toml)
    return fn


def run(args: list[str]) -> dict:
    """`radiosity ARGS` in a process of its own: exit status, wall time, peak RSS of the
    largest process it and its workers had (RUSAGE_CHILDREN is the maximum over waited ones)."""
    env = dict(os.environ)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "radiosity.cli", *args], cwd=ROOT, env=env,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return {"rc": p.returncode, "wall_s": round(wall, 1), "peak_rss_mib_max_so_far": round(peak, 1),
            "stdout": p.stdout, "stderr": p.stderr}


def tree_figures(scene: str) -> dict:
    """The hierarchy on the driver, in this process: times and memory (tracemalloc)."""
    import tracemalloc

    from radiosity.scene.originals import behind_any, estimate_facing_pairs, facing_pairs, tree_of
    from radiosity.scene.load import load_scene

    t0 = time.perf_counter()
    el = load_scene(scene, settings=settings_of()).elements
    t_load = time.perf_counter() - t0
    tracemalloc.start()
    t0 = time.perf_counter()
    t = tree_of(el)
    t_tree = time.perf_counter() - t0
    t0 = time.perf_counter()
    est = estimate_facing_pairs(t)
    t_est = time.perf_counter() - t0
    t0 = time.perf_counter()
    bi, bj, st = facing_pairs(t)
    t_pairs = time.perf_counter() - t0
    t0 = time.perf_counter()
    behind_any(t)
    t_behind = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    n = len(el)
    return {"originals": n, "facing_pairs": int(len(bi)), "estimate": est["estimate"],
            "estimate_exact": est["exact"], "node_pairs": st["node_pairs"],
            "leaf_pairs": st["leaf_pairs"], "load_s": round(t_load, 2), "tree_s": round(t_tree, 2),
            "estimate_s": round(t_est, 2), "pairs_s": round(t_pairs, 2),
            "behind_s": round(t_behind, 2), "hierarchy_peak_mib": round(peak / 2 ** 20, 1),
            "tree_mib": round(t.nbytes() / 2 ** 20, 1),
            "dense_nn4_gib_avoided": round(n * n * 4 * 8 / 2 ** 30, 1)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--triangles", type=int, default=200_000)
    ap.add_argument("--resolution", type=int, default=16)
    ap.add_argument("--no-render", action="store_true")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        scene = write_scene(d, a.triangles, a.resolution)
        fig = tree_figures(scene)
        plan = run(["plan", scene])
        rows.append({"command": "plan", **fig, "rc": plan["rc"], "wall_s": plan["wall_s"],
                     "peak_rss_mib": plan["peak_rss_mib_max_so_far"]})
        if plan["rc"] != 0:
            print(plan["stderr"][-2000:])
        if not a.no_render:
            out = os.path.join(d, "run")
            r = run(["render", scene, "--out", out, "--workers", "2", "--no-preview"])
            rep = json.load(open(os.path.join(out, "report.json"))) if r["rc"] == 0 else {}
            st = rep.get("render", {}).get("stages", {})
            rows.append({"command": f"render {a.resolution}x{a.resolution}", **fig, "rc": r["rc"],
                         "wall_s": r["wall_s"], "peak_rss_mib": r["peak_rss_mib_max_so_far"],
                         "sub_elements": rep.get("preprocess", {}).get("sub_elements"),
                         "visibility_tasks": rep.get("visibility", {}).get("tasks"),
                         "rays": rep.get("visibility", {}).get("rays"),
                         "stages": {k: v for k, v in st.items() if k.endswith("_s")},
                         "driver_peak_mib": st.get("peak_rss_mb", {}).get("master")})
            if r["rc"] != 0:
                print(r["stderr"][-3000:])
    fn = write("many_originals", rows, {"triangles": a.triangles, "resolution": a.resolution})
    print(table(rows, ["command", "originals", "facing_pairs", "tree_s", "pairs_s",
                       "hierarchy_peak_mib", "dense_nn4_gib_avoided", "rc", "wall_s",
                       "peak_rss_mib"]))
    print(f"wrote {fn}")


if __name__ == "__main__":
    main()
