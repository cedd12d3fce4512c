"""The Quick start as a user meets it: `radiosity render scenes/cornell-box/scene.toml --out DIR`
timed as a whole process (interpreter start, imports, LocalCluster start, every stage, the
preview, the outputs, shutdown), first with an empty numba cache (what the first render after
an install pays: every kernel compiles into the cache, with the compile helper of
runtime/precompile.py; --no-helper-too also times it without) and then again with that cache
warm (the OS file cache is warm too). With --install, a fresh virtual environment is made first and
`pip install -e .` into it is timed as well (needs the package index).

    python benchmarks/bench_quickstart.py [--resolution N] [--repeat 3] [--install] [--no-helper-too]

The Quick start times (docs/src/measurements/index.md, "Quick start") come from this script.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

from common import ROOT, table, write

SCENE = os.path.join("scenes", "cornell-box", "scene.toml")


def timed(cmd, env, cwd) -> float:
    t = time.perf_counter()
    r = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True)
    dt = time.perf_counter() - t
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
    return dt


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--resolution", type=int, default=None,
                    help="override the scene's 128x128 (to check the script quickly)")
    ap.add_argument("--repeat", type=int, default=3, help="warm runs (median and range)")
    ap.add_argument("--install", action="store_true",
                    help="time `pip install -e .` into a fresh venv and render with it")
    ap.add_argument("--no-helper-too", action="store_true",
                    help="also time the first render with the compile helper turned off "
                         "(runtime/precompile.py; RADIOSITY_NO_PRECOMPILE=1), in its own empty cache")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, "numba-cache"))
        python = sys.executable
        if args.install:
            venv = os.path.join(tmp, "venv")
            t_venv = timed([sys.executable, "-m", "venv", venv], env, ROOT)
            python = os.path.join(venv, "bin", "python")
            t_pip = timed([python, "-m", "pip", "install", "-q", "-e", "."], env, ROOT)
            rows.append({"what": "python -m venv", "runs": 1, "median_s": t_venv})
            rows.append({"what": "pip install -e .", "runs": 1, "median_s": t_pip})
            env.pop("PYTHONPATH", None)  # the venv's own install, nothing else
        render = [python, "-m", "radiosity.cli", "render", SCENE]
        if args.resolution:
            render += ["--resolution", str(args.resolution)]
        if args.no_helper_too:  # the same first render with the compile helper turned off
            alone = dict(env, NUMBA_CACHE_DIR=os.path.join(tmp, "numba-cache-alone"),
                         RADIOSITY_NO_PRECOMPILE="1")
            t = timed(render + ["--out", os.path.join(tmp, "cold-alone")], alone, ROOT)
            rows.append({"what": "render, numba cache empty, no compile helper", "runs": 1,
                         "median_s": t, "min_s": t, "max_s": t})
        t = timed(render + ["--out", os.path.join(tmp, "cold")], env, ROOT)
        rows.append({"what": "render, numba cache empty", "runs": 1, "median_s": t, "min_s": t, "max_s": t})
        warm = [timed(render + ["--out", os.path.join(tmp, f"warm{k}")], env, ROOT)
                for k in range(args.repeat)]
        rows.append({"what": "render, numba cache warm", "runs": len(warm),
                     "median_s": statistics.median(warm), "min_s": min(warm), "max_s": max(warm)})
    if args.install:
        first = next(r for r in rows if r["what"] == "render, numba cache empty")
        rows.append({"what": "install + first render", "runs": 1,
                     "median_s": sum(r["median_s"] for r in rows[:2]) + first["median_s"]})
    print(f"radiosity render {SCENE}" + (f" --resolution {args.resolution}" if args.resolution else "")
          + f", whole processes, {os.cpu_count()} cores")
    print(table(rows, ["what", "runs", "median_s", "min_s", "max_s"]))
    print("wrote", write("quickstart", rows, {"resolution": args.resolution or 128,
                                               "install": args.install,
                                               "loadavg": list(os.getloadavg())}))


if __name__ == "__main__":
    main()
