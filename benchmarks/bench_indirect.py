"""The Cornell box lit only indirectly (scenes/cornell-box-indirect; issue 26): every surface
against a Mitsuba reference, and the whole command's time, with and without refinement rounds.

    radiosity reference scenes/cornell-box-indirect --out REF --spp 16384     (about 3 minutes)
    python benchmarks/bench_indirect.py --reference REF [--runs 3] [--variants default,rounds0]
        [--then CHECKOUT] [--set key=value ...] [--name indirect]

Variants, each a whole `radiosity render` process at the scene's 128^2 (warm numba cache; one
render first that is not counted), run in turns --runs times so that the machine's noise falls
on all alike:
  default   the settings as they are (hierarchy.rounds auto: one round on this scene)
  rounds0   DASK_RADIOSITY__HIERARCHY__ROUNDS=0: the first solve alone
  eps1e-4   the default with --epsilon 1e-4
  then      the default of another checkout of this repository (--then, e.g. `git worktree add
            /tmp/then 35e7dcb`, the code of the day issue 26 was filed), run from its own app/
            folder with its own numba cache
Per original element and per surface (the ceiling's five pieces together, the red wall's two
triangles together, each other original alone): the signed error of the mean of the RGB sums
over the interior pixels (those whose 3 x 3 neighbourhood sees the same element:
validation.compare.interior) against the reference, and the reference's standard error of that
mean (from reference-stderr.exr, channels taken as fully correlated: an upper bound).

Writes benchmarks/results/<name>.json and prints the tables.
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
from common import ROOT, table, write  # noqa: E402
from radiosity.settings import options as settings_of

SCENE = os.path.join(ROOT, "scenes", "cornell-box-indirect")
VARIANTS = {"default": ({}, []), "rounds0": ({"DASK_RADIOSITY__HIERARCHY__ROUNDS": "0"}, []),
            "eps1e-4": ({}, ["--epsilon", "1e-4"])}
# the originals as scenes/cornell-box-indirect numbers them (the published box's faces, then
# the lamp)
LABELS = {0: "floor", 1: "ceiling above the lamp", 2: "ceiling in front", 3: "ceiling behind",
          4: "ceiling beside (x > 343)", 5: "ceiling beside (x < 213)", 6: "back wall",
          7: "green wall", 8: "red wall, lower triangle", 9: "red wall, upper triangle",
          10: "short block top", 11: "short block side", 12: "short block front",
          13: "short block side", 14: "short block back", 15: "tall block top",
          16: "tall block side", 17: "tall block back", 18: "tall block side",
          19: "tall block front", 20: "lamp (its black underside)"}
# surfaces of more than one original (the published box cuts its ceiling around the light)
GROUPS = {"ceiling": (1, 2, 3, 4, 5), "red wall": (8, 9)}


def render(out: str, env: dict, args: list, then: str | None = None) -> float:
    cmd = ["radiosity"]
    if then is not None:  # another checkout's package, as `python -m radiosity.cli`
        pkg = os.path.join(os.path.dirname(out), "then-pkg")
        if not os.path.isdir(pkg):
            os.makedirs(pkg)
            os.symlink(os.path.join(then, "app"), os.path.join(pkg, "radiosity"))
        env = {**env, "PYTHONPATH": pkg, "NUMBA_CACHE_DIR": os.path.join(pkg, "numba")}
        cmd = [sys.executable, "-m", "radiosity.cli"]
    t = time.perf_counter()
    res = subprocess.run([*cmd, "render", SCENE, "-o", out, *args],
                         env={**os.environ, **env}, capture_output=True, text=True,
                         cwd=then or None)
    if res.returncode != 0:
        raise SystemExit(f"radiosity render failed:\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return time.perf_counter() - t


def errors(out: str, ref: np.ndarray, se: np.ndarray, raster: np.ndarray, mask: np.ndarray,
           names: dict) -> list[dict]:
    from radiosity.formats.images import read_exr

    img = read_exr(os.path.join(out, "image.exr")).astype(np.float64).sum(-1)
    rows = []
    single = [(names[e], (e,)) for e in np.unique(raster[mask]) if e >= 0]
    for name, els in single + list(GROUPS.items()):
        sel = mask & np.isin(raster, els) & (ref > 0)
        if sel.sum() < 4:
            continue
        b = ref[sel].mean()
        rows.append({"surface": name, "pixels": int(sel.sum()),
                     "error_pct": round(100 * (img[sel].mean() / b - 1), 2),
                     "ref_stderr_pct": round(100 * np.sqrt((se[sel] ** 2).sum()) / sel.sum() / b, 2)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reference", required=True, help="a `radiosity reference` output folder")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--variants", default="default,rounds0")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="hierarchy settings for every variant, e.g. rounds-row-excess=0.06")
    ap.add_argument("--then", help="a checkout of an older commit: its default as variant then")
    ap.add_argument("--name", default="indirect")
    a = ap.parse_args()
    from radiosity.scene.load import load_scene
    from radiosity.formats.images import read_exr
    from radiosity.validation.compare import element_raster, interior

    sc = load_scene(SCENE, settings=settings_of())
    raster = element_raster(sc)
    mask = interior(raster)
    names = {e: f"{e}: {LABELS.get(e, 'element')}" for e in range(len(sc.elements))}
    ref = read_exr(os.path.join(a.reference, "reference.exr")).astype(np.float64).sum(-1)
    se = read_exr(os.path.join(a.reference, "reference-stderr.exr")).astype(np.float64).sum(-1)
    spp = json.load(open(os.path.join(a.reference, "reference.json"))).get("spp")
    env = {f"DASK_RADIOSITY__HIERARCHY__{k.split('=')[0].upper().replace('-', '_')}":
           k.split("=", 1)[1] for k in a.set}
    variants = a.variants.split(",") + (["then"] if a.then else [])
    times = {v: [] for v in variants}
    links = {}
    with tempfile.TemporaryDirectory() as tmp:
        render(os.path.join(tmp, "warm"), env, [])
        if a.then:
            render(os.path.join(tmp, "warm-then"), {}, [], a.then)
        for k in range(a.runs):
            for v in variants:
                venv, vargs = VARIANTS.get(v, ({}, []))
                times[v].append(render(os.path.join(tmp, f"{v}-{k}"),
                                       {} if v == "then" else {**env, **venv}, vargs,
                                       a.then if v == "then" else None))
        per = {}
        for v in variants:
            last = os.path.join(tmp, f"{v}-{a.runs - 1}")
            links[v] = json.load(open(os.path.join(last, "report.json")))["links"]["links"]
            per[v] = {r["surface"]: r for r in errors(last, ref, se, raster, mask, names)}
    rows = []
    for s in per[variants[0]]:
        r = {"surface": s, "pixels": per[variants[0]][s]["pixels"],
             "ref_se_pct": per[variants[0]][s]["ref_stderr_pct"]}
        for v in variants:
            r[f"{v}_pct"] = per[v][s]["error_pct"]
        rows.append(r)
    grouped = {e for els in GROUPS.values() for e in els}
    surfaces = [s for s in per[variants[0]] if s in GROUPS or int(s.split(":")[0]) not in grouped]
    summary = [{"variant": v, "links": links[v], "render_s": [round(t, 2) for t in times[v]],
                "median_s": round(float(np.median(times[v])), 2),
                "worst_surface_pct": max(abs(per[v][s]["error_pct"]) for s in surfaces),
                "worst_piece_pct": max(abs(per[v][s]["error_pct"]) for s in per[v]
                                       if s not in GROUPS)}
               for v in variants]
    if "rounds0" in variants:
        t0 = summary[variants.index("rounds0")]["median_s"]
        for r in summary:
            r["x_rounds0"] = round(r["median_s"] / t0, 2)
    print(table(rows, list(rows[0].keys())))
    print()
    print(table(summary, list(summary[0].keys())))
    print(write(a.name, rows, {"summary": summary, "reference": a.reference, "spp": spp,
                               "settings": a.set, "then": a.then}))


if __name__ == "__main__":
    main()
