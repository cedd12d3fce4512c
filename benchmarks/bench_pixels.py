"""Pixel-area against point-sampled images (render.sampling) on the Cornell box, against a
path-traced Mitsuba reference rendered at twice the resolution and box-averaged (issue 26).

    python benchmarks/bench_pixels.py [--res 128] [--spp 4096] [--run DIR] [--reference DIR]

One default render (the solution does not depend on the sampling: only the image stage is
run again for each row), then the image with --sampling point and with --sampling area at
K = 1, 2, 4, 8 rays per side. Errors per pixel as |ours - ref| / ref on the RGB sum, averaged
over: all cells the reference sees; interior cells (compare.interior: wholly inside one
element); edge cells (the others); the light's border cells (edge cells next to the light).
The image stage's time beside each. Writes benchmarks/results/pixels.json.

    python benchmarks/bench_pixels.py --sampling-of RUN [--truth 64]

The image's own sampling error alone (no light error) on a solved run, e.g. a terrain of
benchmarks/scenes_generated.py, whose pixels cover many small triangles: the pixel-area image
with 4 x 4 rays, with the edge pass (12 x 12) and with pixels.refine at budgets 2, 8 (the
default) and unbounded, against --truth x --truth rays a pixel of the same solution; per pixel
|A - B| / max(B, 5 % of the mean) on the RGB sum (bench_real's floor) and plain. Writes
benchmarks/results/pixels-sampling.json.
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


def sampling_rows(run: str, truth: int) -> list[dict]:
    """The rows of --sampling-of (see the module's docstring)."""
    from radiosity.runtime.store import RunStore
    from radiosity.stages import pixels as P
    from radiosity.tracing.rays import RayCaster

    rs = RunStore(run, "r")
    part, el, cam = rs.load_partition(), rs.load_elements(), rs.load_camera()
    k = int(rs.attrs.get("subpixel", 1))
    lum = P.seen_radiance(part, el, cam, rs.read_arrays("solution")["radiance"])
    rc = RayCaster(el.verts, el.nverts, 1e-6)
    t = time.perf_counter()
    b = P.samples_radiance(lum, P.sample_raster(part, el, cam, k, truth, 1e-6, caster=rc)).sum(-1)
    truth_s = time.perf_counter() - t
    seen = b > 0
    floor = 0.05 * b[seen].mean()
    rows = []
    for name, edge, budget in (("4x4", 0, 0.0), ("edges 12x12", 12, 0.0),
                               ("refine, budget 2", 12, 2.0), ("refine, budget 8", 12, 8.0),
                               ("refine, unbounded", 12, 1e9)):
        t = time.perf_counter()
        s = P.sample_raster(part, el, cam, k, 4, 1e-6, caster=rc)
        fine = P.samples_radiance(lum, s)
        levels = P.refine(part, el, cam, k, lum, fine, s, edge, rc, budget=budget) if edge else []
        dt = time.perf_counter() - t
        a = fine.sum(-1)
        rows.append({"sampling": name, "levels": levels,
                     "rays_a_pixel": round((s.size + sum(n * q * q for q, n in levels))
                                           / a.size, 1),
                     "time_s": round(dt, 2),
                     "error": float(np.mean(np.abs(a[seen] - b[seen])
                                            / np.maximum(b[seen], floor))),
                     "error_plain": float(np.mean(np.abs(a[seen] - b[seen]) / b[seen]))})
    print(f"{run}: {len(el)} elements, {cam.width}x{cam.height}; truth {truth}^2 rays a pixel "
          f"({truth_s:.0f} s)")
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sampling-of", metavar="RUN", help="a solved run: its sampling error alone")
    ap.add_argument("--truth", type=int, default=64, help="rays a side of --sampling-of's truth")
    ap.add_argument("--out", default="pixels-sampling", help="--sampling-of's results/NAME.json")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=4096, help="reference samples per pixel at 2x res")
    ap.add_argument("--run", help="a solved run of the Cornell box at --res (else rendered)")
    ap.add_argument("--reference", help="a `radiosity reference` directory at 2x --res")
    args = ap.parse_args()
    if args.sampling_of:
        rows = sampling_rows(args.sampling_of, args.truth)
        print(table(rows, ["sampling", "rays_a_pixel", "time_s", "error", "error_plain", "levels"]))
        print("wrote", write(args.out, rows, {"run": args.sampling_of, "truth": args.truth,
                                                        "floor": 0.05}))
        return

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
