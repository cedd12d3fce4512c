"""Splitting the sub-elements no pixel hits that seen surfaces see at close range
(subdivide.hidden, scene/hidden.py; issue 26): what it costs and what it fixes.

    python benchmarks/bench_hidden.py [--res 128] [--reference DIR] [--skip-counts]
                                      [--skip-renders] [--methods pairs,hierarchical]

1. Sub-element counts with subdivide.hidden keep and refine on every built-in scene
   (scenes/*/scene.toml at its default resolution; the preprocess stage on a 2-worker cluster),
   with the preprocess stage's time.
2. The Cornell box at --res, rendered with each method and hidden keep / refine, against a
   path-traced Mitsuba reference at twice the resolution box-averaged (--reference: a
   `radiosity reference` directory at 2 x --res; else /tmp/h26/ref256 when it is there, else
   rendered here at 1024 spp): per seen surface the ratio of the surface means of the RGB sums
   minus 1 over the pixels whose centre sees it (the run's raster "orig"), and for the tall
   block's front face (element 19) its bottom rows too.

Writes benchmarks/results/hidden.json and prints the tables.
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import ROOT, table, write  # noqa: E402
from radiosity.settings import options as settings_of

CORNELL = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")
STORED_REFERENCE = "/tmp/h26/ref256"
NAMES = {0: "floor", 6: "back wall", 7: "green wall", 8: "red wall (1)", 9: "red wall (2)",
         10: "short top", 11: "short side +x", 12: "short front", 13: "short side -x",
         14: "short back", 15: "tall top", 16: "tall side +x", 17: "tall back",
         18: "tall side -x", 19: "tall front"}


def counts(client, quiet) -> list[dict]:
    """Preprocess every built-in scene with hidden keep and refine."""
    import dask.config

    from radiosity.scene.load import load_scene
    from radiosity.stages.preprocess import preprocess

    rows = []
    for path in sorted(glob.glob(os.path.join(ROOT, "scenes", "*", "scene.toml"))):
        sc = load_scene(path, settings=settings_of())
        row = {"scene": os.path.basename(os.path.dirname(path)),
               "resolution": sc.camera.width, "originals": len(sc.elements)}
        for mode in ("keep", "refine"):
            with tempfile.TemporaryDirectory() as d, \
                    dask.config.set({"radiosity.subdivide.hidden": mode}):
                fig = preprocess(sc, os.path.join(d, "run"), client, settings_of(), progress=False)
            row[f"subs_{mode}"] = fig.sub_elements
            row[f"preprocess_s_{mode}"] = fig.time_total_s
            if mode == "refine":
                row.update(hidden_split=fig.hidden_split, hidden_added=fig.hidden_added,
                           hidden_rays=fig.hidden_rays, hidden_s=fig.time_hidden_s)
        row["ratio"] = row["subs_refine"] / row["subs_keep"]
        rows.append(row)
        if not quiet:
            print(row, flush=True)
    return rows


def surface_errors(img: np.ndarray, ref: np.ndarray, orig: np.ndarray) -> dict:
    """{element: ours / ref - 1} of the surface means of the RGB sums, per original seen."""
    a, b = img.sum(-1), ref.sum(-1)
    return {int(e): float(a[orig == e].mean() / b[orig == e].mean() - 1)
            for e in np.unique(orig[orig >= 0]) if b[orig == e].mean() > 0}


def bottom_rows(img, ref, orig, e: int = 19, rows: int = 8) -> float:
    """ours / ref - 1 over the lowest `rows` pixel rows of element e (its bottom)."""
    sel = orig == e
    r = np.nonzero(sel.any(axis=1))[0]
    band = sel & (np.arange(sel.shape[0])[:, None] > r.max() - rows)
    return float(img.sum(-1)[band].mean() / ref.sum(-1)[band].mean() - 1)


def renders(client, res: int, ref_dir: str | None, methods: list[str]) -> tuple[list, dict]:
    import dask.config

    from radiosity.pipeline import render_scene
    from radiosity.runtime.store import RunStore
    from radiosity.scene.load import load_scene
    from radiosity.stages.image import read_exr
    from radiosity.validation.compare import box_down
    from radiosity.validation.reference import reference_at

    rows, surfaces = [], {}
    with tempfile.TemporaryDirectory() as d:
        if ref_dir is None:
            ref_dir = os.path.join(d, "reference")
            reference_at(load_scene(CORNELL, resolution=2 * res, settings=settings_of()), ref_dir,
                         1024, 8, settings=settings_of())
        ref = box_down(read_exr(os.path.join(ref_dir, "reference.exr")), res, res)
        sc = load_scene(CORNELL, resolution=res, settings=settings_of())
        for method in methods:
            for mode in ("keep", "refine"):
                out = os.path.join(d, f"{method}-{mode}")
                t = time.perf_counter()
                with dask.config.set({"radiosity.subdivide.hidden": mode}):
                    rep = render_scene(sc, out, client, settings_of(method=method), preview=False,
                                       progress=False, echo=lambda *a: None)
                wall = time.perf_counter() - t
                img = read_exr(os.path.join(out, "image.exr")).astype(np.float64)
                orig = RunStore(out).read_arrays("raster")["orig"]
                err = surface_errors(img, ref, orig)
                key = f"{method}-{mode}"
                surfaces[key] = err
                blocks = [e for e in err if 10 <= e <= 19]
                walls = [e for e in err if e in (0, 6, 7, 8, 9)]
                rows.append({"method": method, "hidden": mode,
                             "sub_elements": rep["preprocess"]["sub_elements"],
                             "tall_front": err.get(19), "tall_front_bottom": bottom_rows(img, ref, orig),
                             "worst_block_face": max((abs(err[e]) for e in blocks), default=None),
                             "worst_wall": max((abs(err[e]) for e in walls), default=None),
                             "preprocess_s": rep["preprocess"]["time_total_s"],
                             "wall_s": round(wall, 1)})
                print(rows[-1], flush=True)
    return rows, {"reference": ref_dir, "surfaces": surfaces}


def print_counts(rows: list[dict]) -> None:
    print("sub-elements with subdivide.hidden keep / refine (default resolutions)")
    print(table(rows, ["scene", "resolution", "originals", "subs_keep", "subs_refine", "ratio",
                       "hidden_split", "hidden_added", "preprocess_s_keep", "preprocess_s_refine",
                       "hidden_s"]))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--reference", help="a `radiosity reference` directory at 2x --res")
    ap.add_argument("--methods", default="pairs,hierarchical")
    ap.add_argument("--skip-counts", action="store_true")
    ap.add_argument("--skip-renders", action="store_true")
    args = ap.parse_args()

    from radiosity.runtime.cluster import open_client

    ref_dir = args.reference
    if ref_dir is None and args.res == 128 and os.path.exists(
            os.path.join(STORED_REFERENCE, "reference.exr")):
        ref_dir = STORED_REFERENCE
    extra = {"resolution": args.res}
    count_rows, render_rows = [], []
    with open_client(2, quiet=True, settings=settings_of().cluster) as client:
        if not args.skip_counts:
            count_rows = counts(client, quiet=True)
            print_counts(count_rows)
        if not args.skip_renders:
            render_rows, more = renders(client, args.res, ref_dir, args.methods.split(","))
            extra.update(more)
    if render_rows:
        print(f"Cornell box {args.res}^2 against Mitsuba at {2 * args.res}^2 box-averaged: "
              "surface mean ours / ref - 1")
        print(table(render_rows, ["method", "hidden", "sub_elements", "tall_front",
                                  "tall_front_bottom", "worst_block_face", "worst_wall",
                                  "preprocess_s", "wall_s"]))
        keys = list(extra["surfaces"])
        rows = [{"surface": f"{e} {NAMES.get(e, '')}", **{k: extra["surfaces"][k].get(e) for k in keys}}
                for e in sorted(extra["surfaces"][keys[0]])]
        print(table(rows, ["surface", *keys]))
    print("wrote", write("hidden", {"counts": count_rows, "renders": render_rows}, extra))


if __name__ == "__main__":
    main()
