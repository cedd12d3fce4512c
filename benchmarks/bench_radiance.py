"""Our lux against Radiance's on an office: time and error, whole processes, one run (issue 52).

    python benchmarks/bench_radiance.py [--res 32] [--points 60] [--levels draft,medium]
                                        [--truth high] [--out DIR]

1. The office, generated: a 6 x 4 x 3 m room (floor 0.2, walls 0.5, ceiling 0.7), a 3 x 1.2 m
   window opening in one long wall (nothing outside: light leaves through it; daylight comes
   later), four 0.6 x 0.6 m ceiling panels (Le 3 W sr^-1 m^-2 grey). The lead adds IES
   luminaires and a work-plane grid once those land; today the points are on the floor.
2. Ours: `radiosity render OFFICE --resolution RES` as a whole process (after a warm-up run of
   the same command, so numba's cache is warm), lux per floor sub-element (elements.csv).
3. The points: the centres of --points of those sub-elements (every k-th, all over the floor).
4. Radiance: `radiosity reference --engine radiance --points` at each of --levels and at
   --truth, whole processes; the truth's answer is the reference of every error.
5. Errors against the truth over the points: mean of |rel|, max |rel|, and the signed mean of
   the ratio; ours compares a sub-element's mean with the value at its centre (the difference
   is second order in its size and is part of our error here).

Writes benchmarks/results/radiance.json and prints a table with the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import table, write  # noqa: E402
from scenes_generated import _write  # noqa: E402

MATERIALS = """
[material.floor]
reflectance = [0.2, 0.2, 0.2]
[material.wall]
reflectance = [0.5, 0.5, 0.5]
[material.ceiling]
reflectance = [0.7, 0.7, 0.7]
[material.panel]
reflectance = [0.0, 0.0, 0.0]
emission = [3.0, 3.0, 3.0]
"""


def office(folder: str) -> str:
    """The office's OBJ and scene TOML in `folder` (z up, every normal into the room)."""
    W, D, H = 6.0, 4.0, 3.0

    def wall_y0(x0, x1, z0, z1):
        return [(x0, 0, z0), (x0, 0, z1), (x1, 0, z1), (x1, 0, z0)]

    walls = [wall_y0(0, W, 0, 1.0), wall_y0(0, W, 2.2, H), wall_y0(0, 1.5, 1.0, 2.2),
             wall_y0(4.5, W, 1.0, 2.2),                                   # window 1.5..4.5 x 1..2.2
             [(0, D, 0), (W, D, 0), (W, D, H), (0, D, H)],
             [(0, 0, 0), (0, D, 0), (0, D, H), (0, 0, H)],
             [(W, 0, 0), (W, 0, H), (W, D, H), (W, D, 0)]]
    panels = []
    for cx in (1.5, 4.5):
        for cy in (1.33, 2.67):
            x0, x1, y0, y1 = cx - 0.3, cx + 0.3, cy - 0.3, cy + 0.3
            panels.append([(x0, y0, 2.98), (x0, y1, 2.98), (x1, y1, 2.98), (x1, y0, 2.98)])
    quads = {"floor": [[(0, 0, 0), (W, 0, 0), (W, D, 0), (0, D, 0)]],
             "ceiling": [[(0, 0, H), (0, D, H), (W, D, H), (W, 0, H)]],
             "wall": walls, "panel": panels}
    camera = {"position": "[3.0, 0.4, 2.7]", "look_at": "[3.0, 2.6, 0.0]",
              "up": "[0.0, 0.0, 1.0]", "fov_y": "95.0", "resolution": "[32, 32]"}
    return _write(folder, "office", quads, camera, MATERIALS)


def run(cmd: list[str]) -> float:
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
    return time.perf_counter() - t


def errors(value: np.ndarray, truth: np.ndarray) -> dict:
    rel = value / truth - 1.0
    return {"mean_abs_rel": float(np.mean(np.abs(rel))), "max_abs_rel": float(np.max(np.abs(rel))),
            "mean_rel": float(value.mean() / truth.mean() - 1.0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=32)
    ap.add_argument("--points", type=int, default=60)
    ap.add_argument("--levels", default="draft,medium")
    ap.add_argument("--truth", default="high")
    ap.add_argument("--out", default=None)
    ap.add_argument("--reuse", action="store_true",
                    help="reuse OUT/ours and its time from an earlier run of this script")
    a = ap.parse_args()
    base = a.out or tempfile.mkdtemp(prefix="bench-radiance-")
    scene = office(os.path.join(base, "office"))
    cli = [sys.executable, "-m", "radiosity.cli"]
    load0 = open("/proc/loadavg").read().split()[:3]

    timed = os.path.join(base, "ours-time.json")
    if a.reuse and os.path.isfile(timed):
        with open(timed) as f:
            t_ours = json.load(f)["time_s"]
    else:
        run([*cli, "render", scene, "--out", os.path.join(base, "warm"), "--resolution", "8",
             "--force"])
        t_ours = run([*cli, "render", scene, "--out", os.path.join(base, "ours"), "--resolution",
                      str(a.res), "--force"])
        with open(timed, "w") as f:
            json.dump({"time_s": t_ours, "loadavg": open("/proc/loadavg").read().split()[:3]}, f)
    t = np.genfromtxt(os.path.join(base, "ours", "elements.csv"), delimiter=",", names=True,
                      dtype=None, encoding="utf-8")
    floor = np.flatnonzero((t["normal_z"] > 0.99) & (np.abs(t["center_z"]) < 1e-9)
                           & (t["side"] == "front"))
    pick = floor[np.linspace(0, len(floor) - 1, min(a.points, len(floor))).astype(int)]
    P = np.stack([t["center_x"], t["center_y"], t["center_z"]], axis=1)[pick]
    pts = os.path.join(base, "points.csv")
    with open(pts, "w") as f:
        f.write("x,y,z,nx,ny,nz\n")
        for p in P:
            f.write(f"{p[0]:.17g},{p[1]:.17g},{p[2]:.17g},0,0,1\n")
    ours = t["illuminance"][pick].astype(float)

    rad = {}
    for level in [*a.levels.split(","), a.truth]:
        out = os.path.join(base, f"radiance-{level}")
        secs = run([*cli, "reference", scene, "--engine", "radiance", "--points", pts, "--quality",
                    level, "--out", out, "--force"])
        r = np.genfromtxt(os.path.join(out, "points.csv"), delimiter=",", names=True)
        with open(os.path.join(out, "radiance.json")) as f:
            fig = json.load(f)
        rad[level] = (secs, r["illuminance_lux"], r["stderr_lux"], fig)
    truth = rad[a.truth][1]
    rows = [{"method": "ours", "setting": f"render --resolution {a.res}", "time_s": t_ours,
             "sub_elements_on_floor": int(len(floor)), **errors(ours, truth)}]
    for level, (secs, lux, se, fig) in rad.items():
        rows.append({"method": "radiance", "setting": level, "time_s": secs,
                     "ambient_bounces": fig["ambient_bounces"],
                     "median_rel_stderr": float(np.median(se / lux)), **errors(lux, truth)})
    load1 = open("/proc/loadavg").read().split()[:3]
    fn = write("radiance", rows, {"points": int(len(P)), "truth": a.truth, "resolution": a.res,
                                  "loadavg_start": load0, "loadavg_end": load1,
                                  "mean_truth_lux": float(truth.mean())})
    print(table(rows, ["method", "setting", "time_s", "mean_abs_rel", "max_abs_rel", "mean_rel",
                       "median_rel_stderr"]))
    print(f"{len(P)} floor points, truth: Radiance {a.truth} (mean {truth.mean():.1f} lx); "
          f"load average {' '.join(load0)} -> {' '.join(load1)}; wrote {fn}")


if __name__ == "__main__":
    main()
