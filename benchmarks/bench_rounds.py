"""Refinement by the solved radiance (hierarchy.rounds, methods/hierarchical/views/rounds.py; issue
26): what rounds fix and what they cost.

    python benchmarks/bench_rounds.py [--res 64] [--rounds 1] [--set key=value ...]
        [--scenes cornell-box-indirect,cornell-box] [--variants default,rounds,eps1e-4]
        [--mitsuba SCENE=DIR ...] [--name rounds]

The numbers in docs/src/design/methods-hierarchical-rounds.md: --res 64 --rounds 1 (rounds.json)
and --res 128 --rounds 1 --name rounds-128, each with --mitsuba cornell-box-indirect=DIR
--mitsuba cornell-box=DIR (`radiosity reference` at 128^2: 2048 spp for the indirect box, 512
for the Cornell box). About 2 minutes at 64^2, 3 at 128^2 on 2 cores.

Per scene (scenes/<name>/scene.toml at --res), the hierarchical method rendered whole
(render_scene on a 2-worker cluster, warm: one small render first) with:
  default   the settings as they are, hierarchy.rounds 0 (the a-priori oracle alone)
  rounds    hierarchy.rounds --rounds (with the --set settings)
  eps1e-4   hierarchy.epsilon 1e-4, rounds 0: the reference (4x the links of the default)
Per seen surface: the ratio of the surface means of the RGB sums (over the pixels whose centre
sees it, the run's raster "orig") against the eps1e-4 run's, minus 1. Reports the worst surface,
the links and the whole render_scene's time.

Writes benchmarks/results/rounds.json and prints the tables.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import ROOT, table, write  # noqa: E402
from radiosity.settings import options as settings_of

REFERENCE = "eps1e-4"


def variant_settings(name: str, rounds: int, extra: dict) -> dict:
    if name == "default":
        return {"radiosity.hierarchy.rounds": 0}
    if name == "rounds":
        return {"radiosity.hierarchy.rounds": rounds, **extra}
    if name == REFERENCE:
        return {"radiosity.hierarchy.rounds": 0, "radiosity.hierarchy.epsilon": 1e-4}
    raise SystemExit(f"unknown variant {name!r}")


def surface_means(img: np.ndarray, orig: np.ndarray) -> dict:
    a = img.sum(-1)
    return {int(e): float(a[orig == e].mean()) for e in np.unique(orig[orig >= 0])}


def render_one(client, sc, out: str, config: dict) -> dict:
    import dask.config

    from radiosity.pipeline import render_scene
    from radiosity.runtime.store import RunStore
    from radiosity.stages.image import read_exr

    t = time.perf_counter()
    with dask.config.set(config):
        rep = render_scene(sc, out, client, settings_of(method="hierarchical"), preview=False,
                           progress=False, echo=lambda *a: None)
    wall = time.perf_counter() - t
    img = read_exr(os.path.join(out, "image.exr")).astype(np.float64)
    orig = RunStore(out).read_arrays("raster")["orig"]
    rounds = rep.report.get("rounds", {})
    return {"means": surface_means(img, orig), "orig": orig, "wall_s": round(wall, 2),
            "links": int(rep["links"]["links"]), "leaves": int(rep["links"]["leaves"]),
            "stages": {k: round(v, 2) for k, v in rep["render"]["stages"].items()
                       if isinstance(v, float)},
            "rounds": rounds.get("rounds"), "rounds_time_s": rounds.get("time_s")}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--scenes", default="cornell-box-indirect,cornell-box")
    ap.add_argument("--variants", default=f"default,rounds,{REFERENCE}")
    ap.add_argument("--set", action="append", default=[],
                    help="radiosity.hierarchy.KEY=VALUE for the rounds variant")
    ap.add_argument("--name", default="rounds")
    ap.add_argument("--mitsuba", action="append", default=[],
                    help="SCENE=DIR: a `radiosity reference` directory of that scene at a "
                         "multiple of --res (surface means against it too)")
    args = ap.parse_args()
    extra = {}
    for kv in args.set:
        k, v = kv.split("=", 1)
        extra[k if k.startswith("radiosity.") else f"radiosity.hierarchy.{k}"] = float(v)

    from radiosity.runtime.cluster import open_client
    from radiosity.scene.load import load_scene
    from radiosity.stages.image import read_exr
    from radiosity.validation.compare import box_down

    mitsuba = dict(kv.split("=", 1) for kv in args.mitsuba)

    variants = args.variants.split(",")
    rows, surfaces = [], {}
    with open_client(2, quiet=True, settings=settings_of().cluster) as client, tempfile.TemporaryDirectory() as d:
        # warm: the numba cache loaded, the workers' imports done
        render_one(client, load_scene(os.path.join(ROOT, "scenes", "cornell-box", "scene.toml"),
                                      resolution=16, settings=settings_of()), os.path.join(d, "warm"), {})
        for name in args.scenes.split(","):
            sc = load_scene(os.path.join(ROOT, "scenes", name, "scene.toml"), resolution=args.res,
                            settings=settings_of())
            got = {}
            for v in variants:
                got[v] = render_one(client, sc, os.path.join(d, f"{name}-{v}"),
                                    variant_settings(v, args.rounds, extra))
                print(name, v, {k: got[v][k] for k in ("wall_s", "links")}, flush=True)
            ref = got.get(REFERENCE)
            base = got.get("default")
            mref = None
            if name in mitsuba:
                m = read_exr(os.path.join(mitsuba[name], "reference.exr"))
                mref = box_down(m, args.res, args.res)
            for v in variants:
                g = got[v]
                err = ({e: g["means"][e] / ref["means"][e] - 1 for e in ref["means"]
                        if ref["means"][e] > 0 and e in g["means"]} if ref else {})
                surfaces[f"{name}/{v}"] = err
                merr = {}
                if mref is not None:
                    mm = surface_means(mref, g["orig"])
                    merr = {e: g["means"][e] / mm[e] - 1 for e in mm if mm[e] > 0}
                    surfaces[f"{name}/{v}/mitsuba"] = merr
                rows.append({"scene": name, "variant": v, "links": g["links"],
                             "leaves": g["leaves"],
                             "worst_surface": max((abs(x) for x in err.values()), default=None),
                             "mean_abs": float(np.mean([abs(x) for x in err.values()]))
                             if err else None,
                             "worst_vs_mitsuba": max((abs(x) for x in merr.values()),
                                                     default=None),
                             "worst_surface_vs_mitsuba": max(merr, key=lambda e: abs(merr[e]))
                             if merr else None,
                             "wall_s": g["wall_s"],
                             "time_vs_default": g["wall_s"] / base["wall_s"] if base else None,
                             "stages": g["stages"], "rounds": g["rounds"],
                             "rounds_time_s": g["rounds_time_s"]})
    print(f"hierarchical, {args.res}^2, surface means against {REFERENCE} (rounds: {args.rounds}, "
          f"{extra or 'defaults'})")
    print(table(rows, ["scene", "variant", "links", "leaves", "worst_surface", "mean_abs",
                       "worst_vs_mitsuba", "worst_surface_vs_mitsuba", "wall_s",
                       "time_vs_default"]))
    keys = list(surfaces)
    allsurf = sorted({e for k in keys for e in surfaces[k]})
    print(table([{"surface": e, **{k: surfaces[k].get(e) for k in keys}} for e in allsurf],
                ["surface", *keys]))
    print("wrote", write(args.name, rows, {"resolution": args.res, "rounds": args.rounds,
                                           "settings": extra, "surfaces": {
                                               k: {str(e): x for e, x in v.items()}
                                               for k, v in surfaces.items()}}))


if __name__ == "__main__":
    main()
