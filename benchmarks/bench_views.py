"""New views and walkthroughs of a solved run against fresh renders and against Mitsuba 3
(issue 28's targets), in one script:

    python benchmarks/bench_views.py [--res 128] [--frames 30] [--ref-spp 8192] [--quick]

(a) a fresh `radiosity render` of the Cornell box from above (position 278 540 280, looking
    down, fov 80) at --res, as a whole process (subprocess; warm numba cache: one warm-up
    render first);
(b) the second view: `radiosity image RUN --camera above.toml` of a run rendered from the
    box's own camera, as a whole process and as a stage (its view.json time_s); ratio to (a);
(c) a --frames walkthrough of that run (a slow orbit inside the box, looking down at the
    blocks) at --res: `radiosity walkthrough` as a whole process, and in this process for the
    frames' linear images;
(d) Mitsuba 3 (the `radiosity reference` conversion: validation/reference.mitsuba_scene, one
    sensor per frame, scene built once) on the same frames at the same per-pixel error: a
    reference of the middle frame at --ref-spp; our frame's error and Mitsuba's at a ladder of
    sample counts against it (mean over the pixels the reference sees of |sum ours - sum ref| /
    sum ref, RGB sums, as bench_pixels.py); the spp where Mitsuba's error equals ours
    (log-log interpolation on the ladder). Both of Mitsuba's path integrators climb the
    ladder, without Russian roulette (max_depth = rr_depth = the reference's depth, as
    `radiosity reference`) and with Mitsuba's default rr_depth 5; the one faster to that error
    (from the ladder's top rung: time is linear in spp) renders the frames at its spp in one
    process, after untimed warm-up renders that compile its kernels (--mitsuba-frames N:
    N frames evenly spread over the path, the time scaled to all). Ratio ours / Mitsuba.
Also the lattice's spacing (methods/hierarchical/views/points.LATTICE_PIXELS) on the middle frame:
error, time and rays of a fresh view at 0 (one gather per pixel and leaf: the first version),
2 and 4 pixels, with 4 rays for every link not proven visible (ray_far inf) or one beyond 6
source sizes (RAY_FAR).

Writes benchmarks/results/views.json and prints the tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import ROOT, table, write  # noqa: E402
from radiosity.settings import options as settings_of

CORNELL = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")
ABOVE = {"position": [278.0, 540.0, 280.0], "look_at": [278.0, 0.0, 280.0],
         "up": [0.0, 0.0, 1.0], "fov_y": 80.0}
# a slow orbit inside the box, high under the ceiling, looking down between the blocks
ORBIT = """\
# bench_views.py: a slow orbit inside the Cornell box
fov_y = 70
[[keyframe]]
position = [360, 420, 40]
look_at = [278, 150, 330]
[[keyframe]]
position = [278, 460, 20]
look_at = [278, 150, 330]
[[keyframe]]
position = [196, 420, 40]
look_at = [278, 150, 330]
[[keyframe]]
position = [278, 380, 60]
look_at = [278, 150, 330]
"""


CPU: dict = {}  # the CPU seconds (user + system) of the last `whole` command


def whole(cmd: list, cwd: str) -> float:
    """Wall time of a command as a whole process (its CPU time into CPU["s"]: less sensitive
    to the machine's other work); exits with its output if it fails."""
    import resource

    def used():
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r.ru_utime + r.ru_stime

    c = used()
    t = time.perf_counter()
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    dt = time.perf_counter() - t
    CPU["s"] = used() - c
    if r.returncode:
        sys.exit(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
    return dt


def fastest(runs: list) -> tuple[float, float]:
    """(wall, CPU) of the fastest of `runs` [(wall, CPU)]."""
    return min(runs)


def scene_with_camera(d: str, cam: dict, res: int) -> str:
    """The Cornell box's scene file with its [camera] replaced by `cam`, written into d."""
    src = open(CORNELL).read()
    i = src.index("[camera]")
    j = src.find("\n[", i + 1)
    table_ = "[camera]\n" + "\n".join(f"{k} = {v}" for k, v in cam.items()) + f"\nresolution = {res}\n"
    mesh_dir = os.path.dirname(CORNELL)
    fn = os.path.join(d, "above-scene.toml")
    with open(fn, "w") as f:
        f.write((src[:i] + table_ + (src[j:] if j >= 0 else "")).replace('path = "', f'path = "{mesh_dir}/'))
    return fn


def pixel_error(img: np.ndarray, ref: np.ndarray) -> float:
    """Mean over the pixels the reference sees of |sum img - sum ref| / sum ref (RGB sums)."""
    a, b = img.sum(-1), ref.sum(-1)
    seen = b > 0
    return float(np.mean(np.abs(a[seen] - b[seen]) / b[seen]))


def spp_for(error: float, ladder: list[dict]) -> float:
    """The sample count at which Mitsuba's error equals `error`: log-log interpolation between
    the ladder's bracketing rungs, beyond them along the path tracer's 1/sqrt(spp)."""
    s = np.array([r["spp"] for r in ladder], float)
    e = np.array([r["error"] for r in ladder], float)
    if error >= e[0]:
        return float(s[0] * (e[0] / error) ** 2)
    if error <= e[-1]:
        return float(s[-1] * (e[-1] / error) ** 2)
    k = int(np.nonzero(e <= error)[0][0])
    f = (math.log(error) - math.log(e[k - 1])) / (math.log(e[k]) - math.log(e[k - 1]))
    return float(math.exp(math.log(s[k - 1]) + f * (math.log(s[k]) - math.log(s[k - 1]))))


def mark_points(src: str, dst: str, settings) -> None:
    """A copy of the solved run `src` as a run solved with direct light at points stores it
    (tests/stages/test_views._mark_points): leaf_radiance R = L - Le, attrs direct = points."""
    import shutil

    from radiosity.methods.hierarchical.solve.transport import open_link_operator
    from radiosity.runtime.store import RunStore
    from radiosity.scene.emitters import AreaEmitters

    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(src, dst)
    rs = RunStore(dst, "r+")
    op, _, el, _ = open_link_operator(rs, None, "driver", settings)
    sol, attrs = rs.read_arrays("solution"), rs.group_attrs("solution")
    sol["leaf_radiance"] = sol["leaf_radiance"] - AreaEmitters(el).radiance()[op.inp.leaf_orig]
    rs.write_arrays("solution", sol, {**attrs, "direct": "points"})


def points_mode(run: str, d: str, fresh: str) -> list[dict]:
    """(e) the view from above of `run` and of its copy marked as solved with direct light at
    points, in this process (CPU seconds, nothing reused between rows), against the fresh
    render `fresh` from there: H1 at the view's points with PIXEL_SHADOW_RAYS 16, 4, 1 or at
    the lattice's nodes; and a 1024-ray-a-pixel H1 as the rows' noise-free reference. CPU
    seconds of the image alone (the run opened before)."""
    import types

    from radiosity.formats.images import read_exr
    from radiosity.methods.hierarchical.views.points import PointGather
    from radiosity.runtime.store import RunStore
    from radiosity.stages.views import Viewer

    s = settings_of()
    pts = os.path.join(d, "run-points")
    mark_points(run, pts, s)
    ref = read_exr(os.path.join(fresh, "image.exr"))[..., :3].astype(np.float64)
    rs = RunStore(fresh)
    cam, orig = rs.load_camera(), rs.read_arrays("raster")["orig"]
    fine = settings_of()
    fine.direct = types.SimpleNamespace(mode="points", samples=64, leaf_points=4)
    v = Viewer(pts, s)
    v.source = PointGather(v.store, fine, pixel_shadow_rays=16)
    quiet, _ = v.image(cam)
    rows = []
    for name, at, rays in (("links", "points", 16), ("points", "points", 16),
                           ("points", "points", 4), ("points", "points", 1),
                           ("points", "lattice", 16)):
        v = Viewer(run if name == "links" else pts, s)
        v.source = PointGather(v.store, s, direct_at=at, pixel_shadow_rays=rays)
        c = time.process_time()
        img, fig = v.image(cam)
        a, b, q = img.sum(-1), ref.sum(-1), quiet.sum(-1)
        seen = (b > 0) & (q > 0)
        surf = [img[orig == o].sum() / ref[orig == o].sum() - 1 for o in np.unique(orig[orig >= 0])
                if (orig == o).sum() >= 40]
        rows.append({"run": name, "H1_at": at if name == "points" else "-",
                     "pixel_shadow_rays": rays if name == "points" else "-",
                     "cpu_s": round(time.process_time() - c, 3),
                     "error_vs_fresh": round(pixel_error(img, ref), 5),
                     "image_mean": round(float(img.mean() / ref.mean() - 1), 5),
                     "worst_surface": round(float(max(np.abs(surf))), 5),
                     "noise_p99": round(float(np.quantile(np.abs(a[seen] - q[seen]) / q[seen], 0.99)), 4)
                     if name == "points" else "-"})
    print("(e) the view from above, links and points runs (in process)")
    print(table(rows, list(rows[0])), flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--ref-spp", type=int, default=8192, help="Mitsuba reference of one frame")
    ap.add_argument("--ladder", default="16,64,256,1024,4096", help="Mitsuba spp to interpolate in")
    ap.add_argument("--mitsuba-frames", type=int, default=5,
                    help="frames Mitsuba renders at the matched spp, evenly spread over the path "
                         "(default 5; the time is scaled to all frames; 0: all)")
    ap.add_argument("--rung-limit", type=float, default=60.0,
                    help="skip ladder rungs expected to take longer than this (s)")
    ap.add_argument("--repeat", type=int, default=2, help="whole-process runs per command (best of)")
    ap.add_argument("--quick", action="store_true",
                    help="a fast check: 6 frames, reference 2048 spp, ladder 16..1024, 2 Mitsuba "
                         "frames, one run per command")
    ap.add_argument("--keep", default=None, help="keep the runs in this folder")
    ap.add_argument("--second-only", action="store_true",
                    help="only (a, b): the fresh render from above and the second view")
    args = ap.parse_args()
    if args.quick:
        args.frames, args.ref_spp, args.ladder = 6, 2048, "16,64,256,1024"
        args.mitsuba_frames = min(args.mitsuba_frames or 2, 2)
        args.repeat = 1
    R = args.res
    py = [sys.executable, "-m", "radiosity.cli"]

    from radiosity.runtime.store import RunStore
    from radiosity.scene.load import load_scene
    from radiosity.stages.views import Viewer
    from radiosity.stages.walkthrough import load_path, render_walkthrough
    from radiosity.validation.reference import (load_mitsuba, mitsuba_scene, mitsuba_version,
                                                path_depth, sensor_dict)

    d = args.keep or tempfile.mkdtemp(prefix="bench-views-")
    os.makedirs(d, exist_ok=True)
    above_scene = scene_with_camera(d, ABOVE, R)
    above_cam = os.path.join(d, "above.toml")
    with open(above_cam, "w") as f:
        f.write("[camera]\n" + "\n".join(f"{k} = {v}" for k, v in ABOVE.items()) + "\n")
    orbit = os.path.join(d, "orbit.toml")
    with open(orbit, "w") as f:
        f.write(f"frames = {args.frames}\nfps = 24\nresolution = {R}\n" + ORBIT)
    run = os.path.join(d, "run")
    out = {"resolution": R, "frames": args.frames}

    # (a) and (b): fresh render from above, the second view of the run from there
    print(f"(a, b) fresh render from above and the second view, {R}^2, best of {args.repeat}", flush=True)
    whole(py + ["render", CORNELL, "--out", run, "--resolution", str(R), "--force"], d)  # warm-up
    fresh, fresh_cpu = fastest([(whole(py + ["render", above_scene, "--out",
                                          os.path.join(d, f"above-{k}"), "--force"], d), CPU["s"])
                             for k in range(args.repeat)])
    run_render, _ = fastest([(whole(py + ["render", CORNELL, "--out", run, "--resolution", str(R),
                                       "--force"], d), CPU["s"]) for _ in range(args.repeat)])
    views = []
    for k in range(args.repeat):
        t = whole(py + ["image", run, "--camera", above_cam, "--name", f"above-{k}",
                        "--resolution", str(R)], d)
        with open(os.path.join(run, "views", f"above-{k}", "view.json")) as f:
            views.append((t, CPU["s"], json.load(f)))
    t_view, cpu_view, vj = min(views, key=lambda x: x[0])
    with open(os.path.join(d, "above-0", "report.json")) as f:
        stages = json.load(f).get("run", {})
    second = {"fresh_render_s": round(fresh, 3), "fresh_cpu_s": round(fresh_cpu, 3),
              "run_render_s": round(run_render, 3), "view_process_s": round(t_view, 3),
              "view_cpu_s": round(cpu_view, 3), "view_stage_s": vj["time_s"],
              "gathered_points": vj["gather"].get("gathered_points"),
              "ratio_process": round(t_view / fresh, 3),
              "ratio_cpu": round(cpu_view / fresh_cpu, 3)}
    out["fresh_render_run"] = stages  # its report.json "run": wall_s of the command
    out["second_view"] = second
    print(table([second], list(second)), flush=True)
    out["points"] = points_mode(run, d, os.path.join(d, "above-0"))
    if args.second_only:
        print("wrote", write("views-second", [second], out))
        return

    # (c): the walkthrough, as a whole process and in this process
    print(f"(c) walkthrough: {args.frames} frames at {R}^2", flush=True)
    t_walk, cpu_walk = fastest([(whole(py + ["walkthrough", run, "--path", orbit, "--name",
                                          f"orbit-{k}", "--out", os.path.join(d, f"orbit-{k}.mp4")],
                                    d), CPU["s"]) for k in range(args.repeat)])
    frames = {}
    t = time.perf_counter()
    w = render_walkthrough(run, orbit, out=os.path.join(d, "orbit-api.mp4"), name="orbit-api",
                           progress=False, on_frame=lambda k, img, fig: frames.setdefault(k, img),
                           settings=settings_of())
    t_api = time.perf_counter() - t
    walk = {"frames": args.frames, "process_s": round(t_walk, 3),
            "process_cpu_s": round(cpu_walk, 3), "api_s": round(t_api, 3),
            "open_s": w.figures["time_open_s"], "per_frame_s": w.figures["time_per_frame_s"],
            "gathered_points": w.figures["gathered_points"]}
    out["walkthrough"] = walk
    print(table([walk], list(walk)), flush=True)

    # (d): Mitsuba on the same frames at the same per-pixel error
    mi, variant = load_mitsuba(echo=print)
    sc = load_scene(CORNELL, resolution=R, settings=settings_of())
    cams = load_path(orbit).cameras(RunStore(run).load_camera())
    mid = len(cams) // 2
    D, _ = path_depth(sc, settings_of().reference.truncation)
    sensors = [mi.load_dict(sensor_dict(dataclasses.replace(sc, camera=c), 1)) for c in cams]
    integrators = {"no roulette": mi.load_dict({"type": "path", "max_depth": D, "rr_depth": D}),
                   "roulette from 5": mi.load_dict({"type": "path", "max_depth": D, "rr_depth": 5})}
    t = time.perf_counter()
    msc, _ = mitsuba_scene(dataclasses.replace(sc, camera=cams[mid]), D, mi=mi)
    t_build = time.perf_counter() - t

    def render(k, spp, seed, integ):
        return np.asarray(mi.render(msc, sensor=sensors[k], spp=int(spp), seed=seed,
                                    integrator=integrators[integ]), np.float64)

    print(f"(d) Mitsuba {mitsuba_version()} ({variant}), depth {D}: reference of frame {mid + 1} "
          f"at {args.ref_spp} spp", flush=True)
    t = time.perf_counter()
    chunk = 1024  # Russian roulette: unbiased, the same expectation, 6x faster here
    ref = sum(render(mid, min(chunk, args.ref_spp - s), 7919 + s, "roulette from 5")
              * min(chunk, args.ref_spp - s) for s in range(0, args.ref_spp, chunk)) / args.ref_spp
    t_ref = time.perf_counter() - t
    np.save(os.path.join(d, f"reference-frame{mid + 1}.npy"), ref)
    ours = pixel_error(frames[mid], ref)
    # the lattice's spacing on this frame (fresh Viewer each: nothing reused)
    from radiosity.methods.hierarchical.views.points import PointGather

    lattice = []
    v = Viewer(run, settings_of())
    for px, far in ((0.0, math.inf), (2.0, math.inf), (2.0, 6.0), (4.0, 6.0)):
        v.source = PointGather(v.store, v.settings, lattice_pixels=px, ray_far=far)
        c = time.process_time()
        img, fig = v.image(cams[mid])
        lattice.append({"lattice_pixels": px, "ray_far": far,
                        "error": round(pixel_error(img, ref), 5), "view_s": fig["time_s"],
                        "cpu_s": round(time.process_time() - c, 3),
                        "gathered": fig["gather"]["gathered_points"], "rays": fig["gather"]["rays"]})
    print(table(lattice, list(lattice[0])), flush=True)
    rungs = [int(x) for x in args.ladder.split(",")]
    ladder = {}
    mitsuba = {}
    for integ in integrators:
        render(mid, 4, 1, integ)  # warm-up: compiles this integrator's kernel
        ladder[integ] = []
        for s in rungs:
            last = ladder[integ][-1] if ladder[integ] else None
            if last and last["time_s"] / last["spp"] * s > args.rung_limit:
                break  # too slow to climb: the 1/sqrt(spp) extrapolation takes over
            t = time.perf_counter()
            img = render(mid, s, 12345 + s, integ)
            ladder[integ].append({"spp": s, "error": pixel_error(img, ref),
                                  "time_s": time.perf_counter() - t})
        need = max(1, math.ceil(spp_for(ours, ladder[integ])))
        top = ladder[integ][-1]
        mitsuba[integ] = {"spp": need, "estimate_per_frame_s": round(top["time_s"] / top["spp"] * need, 3)}
    # the faster integrator (estimated from the ladder's top rung) renders the frames at its spp
    best = min(mitsuba, key=lambda k: mitsuba[k]["estimate_per_frame_s"])
    n = min(len(cams), args.mitsuba_frames or len(cams))
    timed = np.unique(np.linspace(0, len(cams) - 1, n).round().astype(int))
    print(f"  {best}: {mitsuba[best]['spp']} spp to reach {ours:.4f}; timing frames "
          f"{', '.join(str(k + 1) for k in timed)}", flush=True)
    t = time.perf_counter()
    for k in timed:
        render(int(k), mitsuba[best]["spp"], 99 + int(k), best)
    t_frames = time.perf_counter() - t
    mitsuba[best].update(frames_timed=len(timed), time_timed_s=round(t_frames, 3),
                         time_all_frames_s=round(t_build + t_frames * len(cams) / len(timed), 3))
    rows = [{"integrator": k, **mitsuba[k]} for k in mitsuba]
    print(table(rows, ["integrator", "spp", "estimate_per_frame_s", "frames_timed",
                       "time_timed_s", "time_all_frames_s"]))
    for integ in ladder:
        print(f"  ladder ({integ}): " + ", ".join(f"{r['spp']} spp {r['error']:.4f} ({r['time_s']:.2f} s)"
                                                  for r in ladder[integ]))
    cmp_ = {"our_error": round(ours, 5), "reference_spp": args.ref_spp,
            "reference_s": round(t_ref, 1), "mitsuba_integrator": best,
            "mitsuba_spp": mitsuba[best]["spp"],
            "mitsuba_s": mitsuba[best]["time_all_frames_s"], "ours_process_s": walk["process_s"],
            "ratio_ours_to_mitsuba": round(walk["process_s"] / mitsuba[best]["time_all_frames_s"], 3)}
    out.update(mitsuba={"version": mitsuba_version(), "variant": variant, "depth": D,
                        "build_s": round(t_build, 3), "integrators": mitsuba, "ladder": ladder},
               lattice=lattice, comparison=cmp_)
    print(table([cmp_], list(cmp_)))
    print("wrote", write("views", [second, walk, cmp_], out))


if __name__ == "__main__":
    main()
