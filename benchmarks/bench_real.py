"""Real scenes against a path tracer (issue 50's benchmark): our whole `radiosity render` and
Mitsuba 3's time to the same per-pixel error, in one run, on public interiors and on generated
terrains.

    python benchmarks/bench_real.py [--only a,b] [--resolution N|WxH] [--keep DIR] [--ref-spp 4096]

Scenes (`--only` or `--scenes`, default all; a scene file's path is a scene too): the converted
public interiors of benchmarks/real/ (README.md there: sources, licences, what the conversion
changed) and the terrains of
scenes_generated.terrain, smooth and rough (per-vertex noise of 1.5 grid spacings), of 2e5 and
1e6 triangles, generated into the work directory.

For each scene:
1. Ours: `radiosity render SCENE --out D --force`, no options (the scene's 128^2 camera), as a
   whole process: wall and CPU time, peak memory of the process tree (the sum of the resident
   sets of the command and all its descendants, the Dask workers included, sampled every
   0.2 s), and from report.json links, links a leaf, rays, the stage times and the direct
   light's mode where the report names one (`direct`: points or links, issue 50). A render past
   --timeout seconds or --mem-limit GiB is stopped and said so.
2. A Mitsuba reference of the same scene and camera (the `radiosity reference` conversion:
   one shape per material; path tracer with Russian roulette from depth 5, unbiased;
   max_depth from path_depth) at --ref-spp in --passes independent passes (per-pixel standard
   error from their spread).
3. Errors of our image against it: per pixel (`rel_error`: the mean over the pixels it sees
   of |sum ours - sum ref| / max(sum ref, FLOOR * its mean over the image), RGB sums: a floor
   of 5 % of the image mean under near-black pixels; with the reference's own noise taken out
   in quadrature, so that neither renderer is charged for it; `pixel_error_plain` is the same
   without the floor, `pixel_mean_abs_error` without the floor nor the noise correction), the
   image mean (signed, luminance), and per object: a material the engine's own pixel-centre rays see in
   at least 100 pixels (compare.element_raster), the signed relative error of its mean
   luminance, with the reference's standard error of that mean.
4. Mitsuba's per-pixel error (the same floored figure) at a ladder of sample counts, the count
   at which it equals ours (log-log interpolation; 1/sqrt(spp) beyond the ladder), and Mitsuba
   at that count as a user runs it, in a fresh process: the scene's conversion and load plus
   the render, the kernel compilation left out (a warm-up render first, as the engine's numba cache is warm).

Each scene's row is kept in DIR/NAME/row.json, so a later run with the same --keep skips the
scenes it holds (--redo to measure them again; the Mitsuba reference and ladder are kept in
DIR/NAME/reference.npz and ladder.json and reused with --redo, --redo-reference remakes
them). Writes benchmarks/results/real.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_views import pixel_error, spp_for  # noqa: E402
from common import HERE, table, write  # noqa: E402

REAL = os.path.join(HERE, "real")
INTERIORS = ("modern-hall", "white-room", "wooden-staircase", "veach-ajar")
TERRAINS = {"terrain-smooth-200k": (200_000, 0.0), "terrain-rough-200k": (200_000, 1.5),
            "terrain-smooth-1m": (1_000_000, 0.0), "terrain-rough-1m": (1_000_000, 1.5)}
#: the order they run in: the quick ones first
ALL = ("veach-ajar", "terrain-smooth-200k", "modern-hall", "terrain-rough-200k", "white-room",
       "wooden-staircase", "terrain-smooth-1m", "terrain-rough-1m")
LUMA = np.array([0.2126, 0.7152, 0.0722])
MIN_OBJECT_PIXELS = 100

MITSUBA_PROCESS = """
import json, sys, time, warnings
import numpy as np
warnings.simplefilter("ignore")
from radiosity.formats.images import write_exr
from radiosity.scene.load import load_scene
from radiosity.settings import options
from radiosity.validation.reference import load_mitsuba, mitsuba_scene, path_depth
scene, spp, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
res = json.loads(sys.argv[4]) if len(sys.argv) > 4 else None
st = options()
mi, _ = load_mitsuba()
t = time.perf_counter()
sc = load_scene(scene, resolution=res, settings=st)
t_ours = time.perf_counter() - t
D, _ = path_depth(sc, st.reference.truncation)
integ = mi.load_dict({"type": "path", "max_depth": D, "rr_depth": 5})
t = time.perf_counter()
msc, _ = mitsuba_scene(sc, D, mi=mi)
t_load = time.perf_counter() - t
np.asarray(mi.render(msc, spp=1, seed=1, integrator=integ))  # compiles the kernel: not counted
t = time.perf_counter()
img = np.asarray(mi.render(msc, spp=spp, seed=4242, integrator=integ), np.float32)
t_render = time.perf_counter() - t
write_exr(out, img)
print(json.dumps({"load_s": t_load, "render_s": t_render, "our_loader_s": t_ours}))
"""


# ----------------------------------------------------------------------------- scenes

def scene_file(name: str, work: str) -> str:
    if name.endswith(".toml"):  # any scene file (a quick check of the harness)
        return os.path.abspath(name)
    if name in INTERIORS:
        return os.path.join(REAL, name, "scene.toml")
    from scenes_generated import terrain

    tris, rough = TERRAINS[name]
    folder = os.path.join(work, "scenes", name)
    toml = os.path.join(folder, "scene.toml")
    if not os.path.isfile(toml):
        terrain(folder, tris, 128, rough=rough, seed=0)
    return toml


# ----------------------------------------------------------------------------- ours

def tree_rss(proc) -> int:
    """Resident bytes of a psutil process and all its descendants (0 for those gone)."""
    import psutil

    total = 0
    try:
        procs = [proc] + proc.children(recursive=True)
    except psutil.Error:
        return 0
    for p in procs:
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total


def run_measured(cmd: list, cwd: str, timeout: float, mem_limit: float, log: str) -> dict:
    """Run `cmd` as a whole process: wall and CPU seconds (its descendants' included), the
    process tree's peak resident memory sampled every 0.2 s; stopped past `timeout` seconds or
    `mem_limit` bytes. Returns {"wall_s", "cpu_s", "peak_bytes", "rc", "stopped"}."""
    import psutil

    with open(log, "w") as out:
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, cwd=cwd, stdout=out, stderr=subprocess.STDOUT,
                             start_new_session=True)
        ps = psutil.Process(p.pid)
        peak, cpu, stopped = 0, {}, None
        while p.poll() is None:
            rss = tree_rss(ps)
            peak = max(peak, rss)
            try:
                for c in [ps] + ps.children(recursive=True):
                    t = c.cpu_times()
                    cpu[c.pid] = t.user + t.system + t.children_user + t.children_system
            except psutil.Error:
                pass
            if time.perf_counter() - t0 > timeout:
                stopped = f"past the {timeout:.0f} s limit"
            elif rss > mem_limit:
                stopped = f"past the {mem_limit / 2**30:.1f} GiB limit"
            if stopped:
                os.killpg(p.pid, 9)
                p.wait()
                break
            time.sleep(0.2)
        wall = time.perf_counter() - t0
    return {"wall_s": wall, "cpu_s": sum(cpu.values()), "peak_bytes": peak, "rc": p.returncode,
            "stopped": stopped}


def report_figures(run: str) -> dict:
    """Links, links a leaf, rays and stage times from a run's report.json (what it has)."""
    try:
        with open(os.path.join(run, "report.json")) as f:
            rep = json.load(f)
    except (OSError, ValueError):
        return {}
    out: dict = {"stages_s": {}}
    for sec, d in rep.items():
        if not isinstance(d, dict):
            continue
        for k in ("wall_s", "time_s", "seconds"):
            if isinstance(d.get(k), (int, float)):
                out["stages_s"][sec] = round(float(d[k]), 2)
                break
        for k in ("links", "links_per_leaf", "rays", "leaves", "sub_elements", "method"):
            if k in d and k not in out:
                out[k] = d[k]
        mode = direct_mode(d)
        if mode is not None and "direct" not in out:
            out["direct"] = mode
    return out


def direct_mode(section: dict):
    """The direct-light mode a report section names (settings.direct.mode's choice: points or
    links, with "auto"'s reason where given), or None: read defensively, reports before
    issue 50 have none; a dict {"mode": ..., ...} or a string under "direct" or
    "direct_mode"."""
    for k in ("direct", "direct_mode"):
        v = section.get(k)
        if isinstance(v, str):
            return v
        if isinstance(v, dict) and isinstance(v.get("mode"), str):
            why = v.get("reason") or v.get("why")
            return v["mode"] + (f" ({why})" if isinstance(why, str) else "")
    return None


# ----------------------------------------------------------------------------- Mitsuba

def mitsuba_reference(sc, spp: int, passes: int, limit_s: float, seed: int = 7919):
    """(mean (H, W, 3), stderr (H, W, 3), stderr of the RGB sum (H, W), seconds, depth, spp
    done, handle): `passes`
    independent renders of spp / passes samples each, Russian roulette from depth 5; fewer
    passes (at least 4) when they would run past `limit_s` seconds."""
    from radiosity.validation.reference import load_mitsuba, mitsuba_scene, path_depth

    from radiosity.settings import options

    mi, _ = load_mitsuba()
    D, _ = path_depth(sc, options().reference.truncation)
    msc, _ = mitsuba_scene(sc, D, mi=mi)
    integ = mi.load_dict({"type": "path", "max_depth": D, "rr_depth": 5})
    per = max(1, spp // passes)
    chunk = max(1, min(per, 4_194_304 // (sc.camera.width * sc.camera.height)))
    t = time.perf_counter()
    imgs = []
    for k in range(passes):
        acc, done = 0.0, 0
        while done < per:
            c = min(chunk, per - done)
            acc = acc + np.asarray(mi.render(msc, spp=c, seed=seed + 1000 * k + done,
                                             integrator=integ), np.float64) * c
            done += c
        imgs.append(acc / per)
        el = time.perf_counter() - t
        if len(imgs) >= 4 and el * (len(imgs) + 1) / len(imgs) > limit_s:
            break
    a = np.stack(imgs)
    se = a.std(0, ddof=1) / math.sqrt(len(imgs))
    se_sum = a.sum(-1).std(0, ddof=1) / math.sqrt(len(imgs))  # the channels share paths
    return (a.mean(0), se, se_sum, time.perf_counter() - t, D, per * len(imgs), (mi, msc, integ))


#: The per-pixel error's floor under its denominator, a share of the reference image's mean
#: (over the pixels it sees): a near-black pixel (a self-shadowed pit of the rough terrain, a
#: dark corner) is measured against FLOOR * mean(B) instead of its own B, so that an error
#: nobody sees there does not dominate the mean (411 % on the rough terrain without it).
FLOOR = 0.05


def rel_error(img: np.ndarray, ref: np.ndarray, se_sum: np.ndarray, floor: float = FLOOR) -> float:
    """Per-pixel error against the truth, estimated against a noisy reference: with m the mean
    over the pixels the reference sees of |A - B| / D (A, B the RGB sums of the image and the
    reference, D = max(B, floor * mean(B)): a floor under near-black pixels, 0 for the plain
    figure) and n = sqrt(2/pi) mean(s / D) the part of it an exact image would show (s the
    reference's standard error of B: the mean of |N(0, s)|), sqrt(max(0, m^2 - n^2)). The
    mean absolute errors of independent normal errors add in quadrature, so this takes the
    reference's own noise out, and a path tracer's error falls as 1/sqrt(spp) instead of to
    the reference's noise floor."""
    a, b = img.sum(-1), ref.sum(-1)
    seen = b > 0
    if not seen.any():
        return 0.0
    a, b, s = a[seen], b[seen], se_sum[seen]
    d = np.maximum(b, floor * float(b.mean()))
    m = float(np.mean(np.abs(a - b) / d))
    n = math.sqrt(2.0 / math.pi) * float(np.mean(s / d))
    return math.sqrt(max(0.0, m * m - n * n))


def ladder(handle, ref, se_sum, rungs, limit_s: float) -> list[dict]:
    mi, msc, integ = handle
    np.asarray(mi.render(msc, spp=1, seed=3, integrator=integ))  # compiles (drjit is lazy)
    out = []
    for s in rungs:
        t = time.perf_counter()
        img = np.asarray(mi.render(msc, spp=int(s), seed=12345 + s, integrator=integ), np.float64)
        dt = time.perf_counter() - t
        out.append({"spp": int(s), "error": rel_error(img, ref, se_sum),
                    "error_plain": rel_error(img, ref, se_sum, 0.0),
                    "mean_abs_error": pixel_error(img, ref), "time_s": dt})
        if dt * 4 > limit_s:  # the next rung would take about 4x longer
            break
    return out


# ----------------------------------------------------------------------------- errors

def object_errors(sc, ours, ref, se) -> list[dict]:
    """Per material seen by the engine's pixel-centre rays in >= MIN_OBJECT_PIXELS pixels: the
    signed relative error of its mean luminance and the reference's standard error of it."""
    from radiosity.validation.compare import element_raster

    raster = element_raster(sc)
    el = sc.elements
    mat = np.where(raster >= 0, el.material[np.maximum(raster, 0)], -1)
    ya, yb, ys = ours @ LUMA, ref @ LUMA, np.sqrt((se ** 2) @ (LUMA ** 2))
    out = []
    for m in np.unique(mat[mat >= 0]):
        sel = mat == m
        n = int(sel.sum())
        if n < MIN_OBJECT_PIXELS or yb[sel].mean() <= 0:
            continue
        b = float(yb[sel].mean())
        out.append({"object": el.material_names[m], "pixels": n,
                    "error": float(ya[sel].mean() / b - 1.0),
                    "ref_stderr": float(np.sqrt((ys[sel] ** 2).sum()) / n / b)})
    return sorted(out, key=lambda r: -abs(r["error"]))


# ----------------------------------------------------------------------------- one scene

def _resolution(text: str) -> tuple[int, int]:
    """--resolution N or WxH -> (W, H)."""
    w, _, h = text.lower().partition("x")
    try:
        size = (int(w), int(h or w))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--resolution must be N or WxH, got {text!r}") from None
    if min(size) < 1:
        raise argparse.ArgumentTypeError(f"--resolution must be positive, got {text!r}")
    return size


def _label(name: str) -> str:
    """A scene's row name: its suite name, or the folder of a scene file."""
    return os.path.basename(os.path.dirname(os.path.abspath(name))) if name.endswith(".toml") else name


def reference_and_ladder(sc, d: str, args):
    """The Mitsuba reference and its ladder of sample counts, kept in d/reference.npz and
    d/ladder.json for the same --ref-spp, --passes, --ladder and resolution (neither depends on
    our render: a re-measured engine is compared with the same reference; --redo-reference
    makes them again). Returns ref, se, se_sum, t_ref, depth, spp done, ladder rows."""
    key = {"ref_spp": args.ref_spp, "passes": args.passes, "ladder": args.ladder,
           "resolution": list(args.resolution) if args.resolution else None}
    npz, lj = os.path.join(d, "reference.npz"), os.path.join(d, "ladder.json")
    if os.path.isfile(npz) and os.path.isfile(lj) and not args.redo_reference:
        with open(lj) as f:
            kept = json.load(f)
        if kept.get("key") == key:
            z = np.load(npz)
            return (z["ref"], z["se"], z["se_sum"], kept["t_ref"], kept["depth"], kept["spp"],
                    kept["ladder"])
    ref, se, se_sum, t_ref, D, done_spp, handle = mitsuba_reference(sc, args.ref_spp, args.passes,
                                                                    args.ref_limit)
    lad = ladder(handle, ref, se_sum, [int(x) for x in args.ladder.split(",")], args.rung_limit)
    np.savez(npz, ref=ref, se=se, se_sum=se_sum)
    with open(lj, "w") as f:
        json.dump({"key": key, "t_ref": t_ref, "depth": D, "spp": done_spp, "ladder": lad}, f)
    return ref, se, se_sum, t_ref, D, done_spp, lad


def measure(name: str, work: str, args) -> dict:
    import warnings

    from radiosity.formats.images import read_exr
    from radiosity.scene.load import load_scene
    from radiosity.settings import options

    d = os.path.join(work, _label(name))
    os.makedirs(d, exist_ok=True)
    toml = scene_file(name, work)
    res = list(args.resolution) if args.resolution else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc = load_scene(toml, resolution=res, settings=options())
    el = sc.elements
    row = {"scene": name, "triangles": int(np.sum(el.nverts.astype(np.int64) - 2)),
           "elements": len(el),
           "emitting_elements": int(np.sum(np.any(el.emission > 0, axis=(1, 2))))}
    print(f"{_label(name)}: {len(sc.elements)} elements; ours", flush=True)
    run = os.path.join(d, "ours")
    kept = os.path.join(d, "ours.json")  # a finished render is kept across interrupted runs
    if os.path.isfile(kept) and not args.redo:
        with open(kept) as f:
            ours = json.load(f)
    else:
        size = ["--resolution", f"{res[0]}x{res[1]}"] if res else []
        ours = run_measured([sys.executable, "-m", "radiosity.cli", "render", toml, "--out", run,
                             "--force", *size], d, args.timeout, args.mem_limit * 2**30,
                            os.path.join(d, "ours.log"))
        ours["loadavg"] = [round(x, 2) for x in os.getloadavg()]
        if ours["rc"] == 0 or ours["stopped"]:  # not one killed from outside
            with open(kept, "w") as f:
                json.dump(ours, f)
    row.update(ours_s=round(ours["wall_s"], 1), ours_cpu_s=round(ours["cpu_s"], 1),
               ours_loadavg=ours.get("loadavg"),
               peak_gib=round(ours["peak_bytes"] / 2**30, 2), stopped=ours["stopped"],
               **report_figures(run))
    done = ours["rc"] == 0 and os.path.isfile(os.path.join(run, "image.exr"))
    if not done and not ours["stopped"]:
        row["stopped"] = f"exit {ours['rc']} (see {os.path.join(d, 'ours.log')})"
    why = f", {row['stopped']}" if row["stopped"] else ""
    print(f"  ours: {row['ours_s']} s, {row['peak_gib']} GiB{why}", flush=True)
    print(f"  Mitsuba reference at {args.ref_spp} spp", flush=True)
    ref, se, se_sum, t_ref, D, done_spp, lad = reference_and_ladder(sc, d, args)
    seen = ref.sum(-1) > 0
    row.update(ref_spp=done_spp, ref_s=round(t_ref, 1), depth=D,
               ref_noise=round(float(np.mean(se_sum[seen] / ref.sum(-1)[seen])), 5))
    row["ladder"] = [{k: round(v, 5) if isinstance(v, float) else v for k, v in r.items()} for r in lad]
    if not done:
        return row
    img = read_exr(os.path.join(run, "image.exr")).astype(np.float64)
    err = rel_error(img, ref, se_sum)
    objs = object_errors(sc, img, ref, se)
    row.update(pixel_error=round(err, 5),
               pixel_error_plain=round(rel_error(img, ref, se_sum, 0.0), 5),
               pixel_mean_abs_error=round(pixel_error(img, ref), 5),
               image_mean=round(float((img @ LUMA).mean() / (ref @ LUMA).mean() - 1.0), 5),
               worst_object=objs[0]["object"] if objs else None,
               worst_object_error=round(objs[0]["error"], 5) if objs else None,
               objects=[{k: round(v, 5) if isinstance(v, float) else v for k, v in o.items()}
                        for o in objs])
    rungs = [r for r in lad if r["error"] > 0]
    need = max(1, math.ceil(spp_for(err, rungs))) if err > 0 and rungs else 1
    print(f"  our per-pixel error {err:.4f}: Mitsuba needs {need} spp; timing it", flush=True)
    script = os.path.join(work, "mitsuba_render.py")
    with open(script, "w") as f:
        f.write(MITSUBA_PROCESS)
    exr = os.path.join(d, "mitsuba.exr")
    t = time.perf_counter()
    r = subprocess.run([sys.executable, script, toml, str(need), exr, json.dumps(res)], cwd=d,
                       capture_output=True, text=True)
    whole = time.perf_counter() - t
    if r.returncode:
        row["mitsuba_failed"] = r.stderr[-500:]
        return row
    m = json.loads(r.stdout.strip().splitlines()[-1])
    mit_s = m["load_s"] + m["render_s"]
    row.update(mitsuba_spp=need, mitsuba_s=round(mit_s, 2), mitsuba_process_s=round(whole, 1),
               mitsuba_error=round(rel_error(read_exr(exr).astype(np.float64), ref, se_sum), 5),
               ratio=round(ours["wall_s"] / mit_s, 2))
    return row


def _pct(v) -> str:
    return "" if v is None else f"{100 * v:+.2f} %"


def _load(avg) -> str:
    return f"{avg[0]:.0f}" if avg else "?"


def markdown(rows: list[dict]) -> str:
    """The docs page's table (docs/src/measurements/real-scenes.md)."""
    cols = ["scene", "triangles", "ours, whole process", "peak memory", "links (a leaf)", "rays",
            "per-pixel error", "image mean", "worst object (>= 100 px)",
            "Mitsuba to the same error", "ours / Mitsuba", "load (ours; Mitsuba)"]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        num = isinstance(r.get("links"), (int, float)) and isinstance(r.get("links_per_leaf"), (int, float))
        cells = [
            r["scene"], f"{r['triangles']:,}".replace(",", " "),
            f"{r['ours_s']:.0f} s" + (f" (stopped {r['stopped']})" if r.get("stopped") else ""),
            f"{r['peak_gib']:.2f} GiB",
            f"{r['links'] / 1e6:.2f} M ({r['links_per_leaf']:.0f})" if num else "",
            f"{r['rays']:.3g}" if isinstance(r.get("rays"), (int, float)) else "",
            f"{100 * r['pixel_error']:.2f} %" if r.get("pixel_error") is not None else "",
            _pct(r.get("image_mean")),
            f"{r['worst_object']} {_pct(r['worst_object_error'])}" if r.get("worst_object") else "",
            f"{r['mitsuba_s']:.1f} s ({r['mitsuba_spp']} spp)" if r.get("mitsuba_s") is not None else "",
            f"{r['ratio']:.2f}" if r.get("ratio") is not None else "",
            f"{_load(r.get('ours_loadavg'))}; {_load(r.get('loadavg'))}"]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def export_timing(work: str, triangles: int = 200_000, spp: int = 32) -> dict:
    """`radiosity reference`'s export, one Mitsuba shape per material against one per original
    element (`per_element`, the export before issue 50), on the smooth terrain: the conversion
    and load, and one pass of `spp` samples after a warm-up. Returns the figures."""
    import warnings

    from radiosity.scene.load import load_scene
    from radiosity.settings import options
    from radiosity.validation.reference import load_mitsuba, mitsuba_scene, path_depth

    mi, _ = load_mitsuba()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc = load_scene(scene_file("terrain-smooth-1m" if triangles > 200_000 else
                                   "terrain-smooth-200k", work), settings=options())
    D, _ = path_depth(sc, options().reference.truncation)
    out = {"elements": len(sc.elements), "spp": spp}
    for per_element in (False, True):
        t = time.perf_counter()
        msc, _ = mitsuba_scene(sc, D, mi=mi, per_element=per_element)
        build = time.perf_counter() - t
        np.asarray(mi.render(msc, spp=1, seed=1))  # compiles (np.asarray: drjit evaluates lazily)
        t = time.perf_counter()
        np.asarray(mi.render(msc, spp=spp, seed=2))
        key = "per_element" if per_element else "per_material"
        out[key] = {"shapes": len(msc.shapes()), "build_s": round(build, 2),
                    "pass_s": round(time.perf_counter() - t, 2)}
        print(key, out[key], flush=True)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", "--only", default=",".join(ALL),
                    help=f"comma-separated, of {', '.join(ALL)}, or scene files")
    ap.add_argument("--resolution", type=_resolution, default=None, metavar="N|WxH",
                    help="override the scenes' camera resolution (ours and Mitsuba's)")
    ap.add_argument("--keep", default=None, help="work directory (default: a temporary one)")
    ap.add_argument("--redo", action="store_true", help="measure scenes the work directory holds")
    ap.add_argument("--redo-reference", action="store_true",
                    help="make the kept Mitsuba reference and ladder again")
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--passes", type=int, default=8)
    ap.add_argument("--ref-limit", type=float, default=600.0,
                    help="fewer reference passes (at least 4) past this time (s)")
    ap.add_argument("--ladder", default="4,16,64,256,1024,4096")
    ap.add_argument("--rung-limit", type=float, default=120.0,
                    help="stop the ladder when its next rung would take longer (s)")
    ap.add_argument("--timeout", type=float, default=1500.0, help="stop our render after (s)")
    ap.add_argument("--mem-limit", type=float, default=16.0,
                    help="stop our render past this peak of its process tree (GiB)")
    ap.add_argument("--out", default="real", help="results/NAME.json")
    ap.add_argument("--export", action="store_true",
                    help="only time `radiosity reference`'s export, per material against per element, "
                         "on the smooth 2e5-triangle terrain (results/real-export.json)")
    args = ap.parse_args()
    if args.export:
        work = args.keep or tempfile.mkdtemp(prefix="bench-real-")
        fig = export_timing(work)
        print("wrote", write("real-export", [fig], {"loadavg": list(os.getloadavg())}))
        return
    names = [s for s in args.scenes.split(",") if s]
    for s in names:
        if s not in ALL and not s.endswith(".toml"):
            ap.error(f"unknown scene {s!r}: use {', '.join(ALL)}")
    work = args.keep or tempfile.mkdtemp(prefix="bench-real-")
    os.makedirs(work, exist_ok=True)
    rows = []
    for name in names:
        fn = os.path.join(work, _label(name), "row.json")
        if os.path.isfile(fn) and not args.redo:
            with open(fn) as f:
                rows.append(json.load(f))
            print(f"{name}: kept from {fn}")
            continue
        row = measure(name, work, args)
        row["scene"] = _label(name)
        row["loadavg"] = [round(x, 2) for x in os.getloadavg()]
        row["date"] = time.strftime("%Y-%m-%d %H:%M:%S")
        with open(fn, "w") as f:
            json.dump(row, f, indent=1)
        rows.append(row)
    cols = ["scene", "triangles", "direct", "ours_s", "peak_gib", "links", "links_per_leaf", "rays",
            "pixel_error", "pixel_error_plain", "image_mean", "worst_object_error", "mitsuba_spp",
            "mitsuba_s", "ratio"]
    print(table(rows, cols))
    print(markdown(rows))
    from radiosity.validation.reference import load_mitsuba, mitsuba_version

    _, variant = load_mitsuba()
    print("wrote", write(args.out, rows, {
        "resolution": list(args.resolution) if args.resolution else "the scenes' own (128^2)",
        "floor": FLOOR, "reference_spp": args.ref_spp, "passes": args.passes,
        "mitsuba": mitsuba_version(), "variant": variant, "ladder": args.ladder,
        "min_object_pixels": MIN_OBJECT_PIXELS, "work": work}))


if __name__ == "__main__":
    main()
