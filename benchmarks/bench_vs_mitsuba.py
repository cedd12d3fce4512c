"""Our Quick start render against Mitsuba 3 at the same per-pixel error, whole processes on one
machine in one script (issue 27's target: ours / Mitsuba at most 0.5).

    python benchmarks/bench_vs_mitsuba.py [--res 128] [--ref-spp 8192] [--repeat 2]

1. Ours: `radiosity render scenes/cornell-box/scene.toml --out D --force` (defaults) as a whole
   process, once to warm the numba cache, then --repeat times; the fastest counts.
2. A Mitsuba reference of the same camera at --ref-spp (path tracer, Russian roulette from
   depth 5: unbiased, 2-6x faster than without here), box-filtered pixels as ours.
3. Our per-pixel error against it (mean over the pixels it sees of |sum ours - sum ref| / sum
   ref, RGB sums; the reference's own noise is in it), and Mitsuba's at a ladder of sample
   counts; the spp where Mitsuba's error equals ours (log-log interpolation, 1/sqrt(spp) past
   the ladder's ends).
4. Mitsuba at that spp as a whole process: a Python interpreter that imports Mitsuba, builds
   the scene from our loader (as `radiosity reference` does), renders and writes an EXR; the
   fastest of --repeat.

Writes benchmarks/results/vs_mitsuba.json and prints a table.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_views import CPU, pixel_error, spp_for, whole  # noqa: E402
from common import ROOT, table, write  # noqa: E402
from radiosity.settings import options as settings_of

SCENE = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")

MITSUBA_PROCESS = """
import sys, numpy as np
from radiosity.scene.load import load_scene
from radiosity.validation.reference import load_mitsuba, mitsuba_scene, path_depth
from radiosity.formats.images import write_exr
scene, res, spp, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
mi, _ = load_mitsuba()
sc = load_scene(scene, resolution=res)
D, _ = path_depth(sc)
msc, _ = mitsuba_scene(sc, D, mi=mi)
integ = mi.load_dict({"type": "path", "max_depth": D, "rr_depth": 5})
img = np.asarray(mi.render(msc, spp=spp, seed=4242, integrator=integ), np.float32)
write_exr(out, img)
"""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=8192)
    ap.add_argument("--ladder", default="16,64,256,1024,4096")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--keep", default=None, help="work directory to keep (default: temporary)")
    args = ap.parse_args()

    from radiosity.scene.load import load_scene
    from radiosity.formats.images import read_exr
    from radiosity.validation.reference import (load_mitsuba, mitsuba_scene, mitsuba_version,
                                                path_depth)

    d = args.keep or tempfile.mkdtemp(prefix="bench-vs-mitsuba-")
    os.makedirs(d, exist_ok=True)
    R = args.res
    radiosity = [sys.executable, "-m", "radiosity.cli", "render", SCENE, "--resolution", str(R),
                 "--force"]

    print(f"ours: radiosity render at {R}^2 (defaults), a warm-up then {args.repeat} timed",
          flush=True)
    whole(radiosity + ["--out", os.path.join(d, "warm")], d)
    runs = []
    for k in range(args.repeat):
        out = os.path.join(d, f"ours-{k}")
        runs.append((whole(radiosity + ["--out", out], d), CPU["s"], out))
    ours_s, ours_cpu, ours_run = min(runs)
    ours_img = read_exr(os.path.join(ours_run, "image.exr")).astype(np.float64)

    mi, variant = load_mitsuba(echo=print)
    sc = load_scene(SCENE, resolution=R, settings=settings_of())
    D, _ = path_depth(sc, settings_of().reference.truncation)
    msc, _ = mitsuba_scene(sc, D, mi=mi)
    integ = mi.load_dict({"type": "path", "max_depth": D, "rr_depth": 5})

    def render(spp, seed):
        return np.asarray(mi.render(msc, spp=int(spp), seed=seed, integrator=integ), np.float64)

    print(f"Mitsuba {mitsuba_version()} ({variant}), depth {D}: reference at {args.ref_spp} spp",
          flush=True)
    t = time.perf_counter()
    chunk = 1024
    ref = sum(render(min(chunk, args.ref_spp - s), 7919 + s) * min(chunk, args.ref_spp - s)
              for s in range(0, args.ref_spp, chunk)) / args.ref_spp
    t_ref = time.perf_counter() - t
    ours_err = pixel_error(ours_img, ref)
    render(4, 1)  # compiles the kernel
    ladder = []
    for s in [int(x) for x in args.ladder.split(",")]:
        t = time.perf_counter()
        img = render(s, 12345 + s)
        ladder.append({"spp": s, "error": round(pixel_error(img, ref), 5),
                       "time_s": round(time.perf_counter() - t, 3)})
        print(f"  {s} spp: error {ladder[-1]['error']:.4f} in {ladder[-1]['time_s']:.2f} s",
              flush=True)
    need = max(1, math.ceil(spp_for(ours_err, ladder)))
    print(f"Mitsuba needs {need} spp for our error {ours_err:.4f}; timing it as a process",
          flush=True)
    script = os.path.join(d, "mitsuba_render.py")
    with open(script, "w") as f:
        f.write(MITSUBA_PROCESS)
    mruns = []
    for k in range(args.repeat):
        exr = os.path.join(d, f"mitsuba-{k}.exr")
        mruns.append((whole([sys.executable, script, SCENE, str(R), str(need), exr], d),
                      CPU["s"], exr))
    mit_s, mit_cpu, mit_exr = min(mruns)
    mit_err = pixel_error(read_exr(mit_exr).astype(np.float64), ref)
    row = {"resolution": R, "our_error": round(ours_err, 5), "ours_process_s": round(ours_s, 2),
           "ours_cpu_s": round(ours_cpu, 2), "mitsuba_spp": need,
           "mitsuba_error": round(mit_err, 5), "mitsuba_process_s": round(mit_s, 2),
           "mitsuba_cpu_s": round(mit_cpu, 2), "ratio_wall": round(ours_s / mit_s, 3),
           "ratio_cpu": round(ours_cpu / mit_cpu, 3)}
    print(table([row], list(row)))
    print("wrote", write("vs_mitsuba", [row], {
        "resolution": R, "reference_spp": args.ref_spp, "reference_s": round(t_ref, 1),
        "variant": variant, "depth": D, "ladder": ladder, "loadavg": list(os.getloadavg()),
        "ours_runs_s": [round(r[0], 2) for r in runs],
        "mitsuba_runs_s": [round(r[0], 2) for r in mruns]}))


if __name__ == "__main__":
    main()
