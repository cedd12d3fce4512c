"""Pixel-area against point-sampled images (render.sampling) on the Cornell box, against a
path-traced Mitsuba reference rendered at twice the resolution and box-averaged (issue 26).

    python benchmarks/bench_pixels.py [--res 128] [--spp 4096] [--run DIR] [--reference DIR]

One default render (the solution does not depend on the sampling: only the image stage is
run again for each row), then the image with --sampling point and with --sampling area at
K = 1, 2, 4, 8 rays per side. Errors per pixel as |ours - ref| / ref on the RGB sum, averaged
over: all cells the reference sees; interior cells (compare.interior: wholly inside one
element); edge cells (the others); the light's border cells (edge cells next to the light).
The image stage's time beside each. Writes benchmarks/results/pixels.json.
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

CORNELL = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")


def cell_masks(scene, ref: np.ndarray) -> dict:
    """(H, W) bool masks of the error groups, from the element raster at pixel centres."""
    from radiosity.validation.compare import element_raster, interior

    raster = element_raster(scene)
    inner = interior(raster)
    seen = ref.sum(-1) > 0
    light = np.isin(raster, np.nonzero(scene.elements.emission.max(axis=(1, 2)) > 0)[0])
    near = np.zeros_like(light)
    H, W = light.shape
    pad = np.pad(light, 1)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near |= pad[1 + dy:H + 1 + dy, 1 + dx:W + 1 + dx]
    return {"all": seen, "interior": seen & inner, "edge": seen & ~inner,
            "light_border": seen & ~inner & near}


def errors(img: np.ndarray, ref: np.ndarray, masks: dict) -> dict:
    """Mean of |sum img - sum ref| / sum ref over each mask's pixels; the light's border cells
    also signed (a point sample there is the light or the ceiling, never the mix)."""
    a, b = img.sum(-1), ref.sum(-1)
    rel = np.where(b > 0, (a - b) / np.where(b > 0, b, 1.0), 0.0)
    out = {f"err_{k}": float(np.abs(rel[m]).mean()) for k, m in masks.items()}
    out["light_border_signed"] = float(rel[masks["light_border"]].mean())
    out["light_border_worst"] = float(rel[masks["light_border"]].min())
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=4096, help="reference samples per pixel at 2x res")
    ap.add_argument("--run", help="a solved run of the Cornell box at --res (else rendered)")
    ap.add_argument("--reference", help="a `radiosity reference` directory at 2x --res")
    args = ap.parse_args()

    from radiosity.runtime.cluster import open_client
    from radiosity.pipeline import render_scene
    from radiosity.scene.load import load_scene
    from radiosity.stages.image import read_exr, render_outputs
    from radiosity.validation.compare import box_down
    from radiosity.validation.reference import reference_at

    sc = load_scene(CORNELL, resolution=args.res, settings=settings_of())
    with tempfile.TemporaryDirectory() as d:
        t = time.perf_counter()
        ref_dir = args.reference or os.path.join(d, "reference")
        if args.reference is None:
            reference_at(load_scene(CORNELL, resolution=2 * args.res, settings=settings_of()),
                         ref_dir, args.spp, 8, settings=settings_of())
        ref = box_down(read_exr(os.path.join(ref_dir, "reference.exr")), args.res, args.res)
        ref_s = time.perf_counter() - t
        run = args.run
        if run is None:
            run = os.path.join(d, "run")
            with open_client(2, quiet=True, settings=settings_of().cluster) as client:
                render_scene(sc, run, client, settings_of(), preview=False, progress=False,
                             echo=lambda *a: None)
        masks = cell_masks(sc, ref)
        rows = []
        for sampling, k in [("point", 1), ("area", 1), ("area", 2), ("area", 4), ("area", 8)]:
            fig = render_outputs(run, sampling=sampling, area_samples=k, settings=settings_of())
            img = read_exr(os.path.join(run, "image.exr")).astype(np.float64)
            rows.append({"sampling": sampling, "k": k, "rays": fig.rays,
                         "image_s": fig.time_image_s, **errors(img, ref, masks)})
        render_outputs(run, settings=settings_of())  # leave the default image in the run
    counts = {k: int(m.sum()) for k, m in masks.items()}
    cols = ["sampling", "k", "rays", "image_s", "err_all", "err_interior", "err_edge",
            "err_light_border", "light_border_signed", "light_border_worst"]
    print(f"Cornell box {args.res}^2 against Mitsuba at {2 * args.res}^2 box-averaged "
          f"(reference {ref_s:.0f} s); cells: {counts}")
    print(table(rows, cols))
    print("wrote", write("pixels", rows, {"resolution": args.res, "cells": counts,
                                          "reference": ref_dir}))


if __name__ == "__main__":
    main()
