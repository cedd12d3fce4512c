"""The emitters' light at points against through the links (radiosity.direct.mode, SPEC §10;
issue 50): whole `radiosity render` processes of each scene with --direct links (the old way)
and --direct points, in turns; links, links a leaf, rays, stage and whole times, peak memory of
the process tree, and each surface's mean radiance (surfaces.csv, RGB sum) of the points run
against the links run.

    python benchmarks/bench_split.py [--scenes cornell-box,real/modern-hall] [--resolution 64]
        [--runs 1] [--workers N] [--name direct]

A scene is a folder of scenes/ or, with real/, of benchmarks/real/. Writes
benchmarks/results/<name>.json and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import HERE, ROOT, table, write  # noqa: E402

MODES = ("links", "points")


def scene_toml(name: str) -> str:
    if name.startswith("real/"):
        return os.path.join(HERE, "real", name[5:], "scene.toml")
    return os.path.join(ROOT, "scenes", name, "scene.toml")


def surfaces(run: str) -> dict:
    """(surface, side) -> (area, RGB sum of the mean radiance) from surfaces.csv."""
    with open(os.path.join(run, "surfaces.csv")) as f:
        return {(r["surface"], r["side"]): (float(r["area"]), sum(float(r[f"radiance_{c}"])
                                                                  for c in "rgb"))
                for r in csv.DictReader(f)}


def render(toml: str, out: str, mode: str, res: int, workers: int | None) -> dict:
    """One whole render; its figures (report.json) and the process tree's wall time."""
    cmd = [sys.executable, "-m", "radiosity.cli", "render", toml, "--out", out, "--force",
           "--resolution", str(res), "--direct", mode]
    if workers:
        cmd += ["--workers", str(workers)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode not in (0, 3):
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    rep = json.load(open(os.path.join(out, "report.json")))
    lk, st = rep.get("links", {}), rep["render"]["stages"]
    return {"mode": mode, "direct": rep["plan"].get("direct"), "links": lk.get("links"),
            "links_per_leaf": lk.get("links_per_leaf"), "rays": lk.get("rays"),
            "link_s": round(st["visibility_s"], 1), "solve_s": round(st["solve_s"], 1),
            "total_s": round(st["total_s"], 1), "wall_s": round(wall, 1),
            "peak_mib": _peak(st.get("peak_rss_mb"))}


def _peak(p) -> float:
    """The process tree's peak (MiB): the driver's and every worker process's (threads in the
    driver's process count once)."""
    if not isinstance(p, dict):
        return float("nan") if p is None else float(p)
    w = {k: v for k, v in (p.get("workers") or {}).items() if not k.startswith("inproc")}
    return float(p.get("master") or 0.0) + float(sum(w.values()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="cornell-box")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--name", default="split")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.scenes.split(","):
            toml = scene_toml(name)
            best, runs = {}, {}
            for k in range(a.runs):
                for mode in MODES:
                    out = os.path.join(tmp, f"{name.replace('/', '-')}-{mode}")
                    r = render(toml, out, mode, a.resolution, a.workers)
                    if mode not in best or r["total_s"] < best[mode]["total_s"]:
                        best[mode] = r
                    runs[mode] = out
            old, new = surfaces(runs["links"]), surfaces(runs["points"])
            lit = [s for s in old if old[s][1] > 0 and s in new]
            rel = np.array([new[s][1] / old[s][1] - 1 for s in lit])
            area = np.array([old[s][0] for s in lit])
            for mode in MODES:
                rows.append({"scene": name, "resolution": a.resolution, **best[mode],
                             **({"surface_vs_links_max": float(np.abs(rel).max()),
                                 "surface_vs_links_mean": float((area * np.abs(rel)).sum()
                                                                / area.sum())}
                                if mode == "points" else {})})
    cols = ["scene", "mode", "direct", "links", "links_per_leaf", "rays", "link_s", "solve_s",
            "total_s", "wall_s", "peak_mib", "surface_vs_links_max", "surface_vs_links_mean"]
    print(table(rows, cols))
    print("wrote", write(a.name, rows, {"runs": a.runs}))


if __name__ == "__main__":
    main()
