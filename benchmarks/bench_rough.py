"""Rough against smooth terrains of the same size (issue 50: a rough terrain should cost at most
1.5x a smooth one, in time and in memory): scenes_generated.terrain with rough = 0 and 1.5
(per-vertex noise of 1.5 grid spacings), rendered one after the other as whole `radiosity
render` processes. Per terrain: the render's wall time, the peak resident memory of the process
tree (GNU time's maximum RSS; the workers run in the render's process), cluster links, pairs
handed to the element level, element links and links a leaf, rays, the cluster layer's time and
the blocked links its probes dropped; and per size the rough / smooth ratios. Writes
benchmarks/results/rough.json.

    python benchmarks/bench_rough.py                          # 2e4 and 5e4 triangles, 64^2
    python benchmarks/bench_rough.py --triangles 200000 --resolution 128
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from common import ROOT, table, write

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import scenes_generated as gen  # noqa: E402


def render(scene: str, out: str) -> dict:
    """One whole `radiosity render` of `scene` into `out` in a fresh process: its figures."""
    t = time.perf_counter()
    # GNU time's %M: the largest maximum RSS among the process and its waited-for children
    r = subprocess.run(["/usr/bin/time", "-f", "peak_kib %M", sys.executable, "-m", "radiosity.cli",
                        "render", scene, "--out", out, "--no-preview", "--force"], cwd=ROOT,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t
    if r.returncode not in (0, 3):
        raise RuntimeError(f"radiosity render {scene} failed:\n{r.stdout}\n{r.stderr}")
    peak = int(r.stderr.rsplit("peak_kib", 1)[1].split()[0])
    rep = json.load(open(os.path.join(out, "report.json")))
    lk = rep.get("links", {})
    cl = lk.get("clusters") or {}
    return {"render_s": round(wall, 1), "peak_gib": round(peak / 2**20, 2),
            "cluster_s": cl.get("time_s", 0.0), "cluster_links": lk.get("cluster_links", 0),
            "probed": cl.get("probed", 0), "dropped_blocked": cl.get("dropped_blocked", 0),
            "element_pairs": lk.get("pairs", 0), "links": lk.get("links", 0),
            "links_per_leaf": round(lk.get("links_per_leaf", 0.0), 1),
            "rays": lk.get("rays", 0) + cl.get("rays", 0),
            "links_stage_s": round(rep["render"]["stages"]["visibility_s"], 1)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--triangles", default="20000,50000", help="terrain triangle counts")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--rough", type=float, default=1.5, help="noise in grid spacings")
    ap.add_argument("--name", default="rough", help="results/NAME.json")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in [int(x) for x in a.triangles.split(",") if x]:
            got = {}
            for kind, rough in (("smooth", 0.0), ("rough", a.rough)):
                sc = gen.terrain(os.path.join(tmp, f"{kind}{n}"), n, a.resolution, rough=rough)
                got[kind] = {"scene": f"terrain {n}, {kind}", **render(sc, os.path.join(tmp, f"o{kind}{n}"))}
                print(f"  {got[kind]['scene']}: {got[kind]['render_s']} s", flush=True)
                rows.append(got[kind])
            s, r = got["smooth"], got["rough"]
            r["time_vs_smooth"] = round(r["render_s"] / s["render_s"], 2)
            r["memory_vs_smooth"] = round(r["peak_gib"] / s["peak_gib"], 2)
    cols = ["scene", "render_s", "peak_gib", "cluster_s", "links_stage_s", "cluster_links",
            "probed", "dropped_blocked", "element_pairs", "links", "links_per_leaf", "rays",
            "time_vs_smooth", "memory_vs_smooth"]
    print(table(rows, cols))
    print("wrote", write(a.name, rows, {"resolution": a.resolution, "rough": a.rough}))


if __name__ == "__main__":
    main()
