"""What the defaults give, scene by scene, and what the solver's tolerance buys.

1. Every built-in scene rendered with no options (`render_scene` with the defaults, a warm
   LocalCluster of 2 workers; the whole stage times, not the process start): its error against
   the exact answer where one exists, the method, closure and row mode chosen, and the time.
2. The tolerance trade-off: on each scene the same visibility matrix solved at tol 1e-2 .. 1e-6;
   passes, and the image's max and mean relative difference against the 1e-6 solution (pixels
   that see an element).

    python benchmarks/bench_defaults.py [--quick]

Writes benchmarks/results/defaults.json and prints both tables.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

import numpy as np

from common import ROOT, table, write
from radiosity.runtime.cluster import open_client
from radiosity.pipeline import render_scene
from radiosity.stages.image import read_exr, render_outputs
from radiosity.scene.load import load_scene
from radiosity.stages.solve import run_solve
from radiosity.validation.study import form_factor_of_run
from radiosity.methods.pairs.visibility import compute_visibility
from radiosity.settings import options as settings_of

SCENES = ["furnace-cube", "furnace-sphere", "parallel-squares", "perpendicular-squares",
          "coaxial-discs", "unseen-emitter", "cornell-box-inside", "three-rectangles",
          "cornell-box", "construction-in-wood", "room-2400"]
TOLS = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6]


def scene_file(name: str) -> str:
    return os.path.join(ROOT, "scenes", name, "scene.toml")


def error_of(name: str, sc, out: str, client, img, kernel: str) -> tuple[str, float | None]:
    """(what the error is measured against, relative error) of a rendered run."""
    val = sc.validation
    seen = img.sum(-1) > 0
    if name.startswith("furnace"):
        el = sc.elements
        exact = el.emission[0, 0, 0] / (1 - el.reflectance[0, 0, 0])
        return "L = Le / (1 - rho), max over pixels", float(np.abs(img[seen][:, 0] / exact - 1).max())
    if "form_factor" in val:
        # nothing reflects, so the render skipped visibility: make it for the default kernel
        compute_visibility(out, client, settings_of(kernel=kernel), progress=False)
        f = form_factor_of_run(out, client, kernel, val["from"], val["to"], settings=settings_of())
        return "F (Howell), relative", abs(f / val["form_factor"] - 1)
    if val.get("kind") == "point-to-polygon":
        sys.path.insert(0, os.path.join(ROOT, "tests"))
        from test_defaults import _exact_receiver  # the test's exact per-pixel answer

        from radiosity.validation.compare import interior

        ex = _exact_receiver(sc, out)
        # pixels wholly on the receiver: a rim pixel is the mean over its area (half of it
        # background), the exact value is its centre's (as the test measures it)
        m = interior(np.where(np.isfinite(ex), 0, -1))
        return ("rho Le F(dA -> emitter), max over interior pixels",
                float(np.abs(img[..., 0][m] / ex[m] - 1).max()))
    if name == "cornell-box-inside":
        return "pre-split reference, overall level", None  # filled in by main
    return "-", None


def main(quick: bool = False) -> None:
    rows, tol_rows = [], []
    lum = np.array([0.2126, 0.7152, 0.0722])
    with open_client(2, quiet=True, settings=settings_of().cluster) as client, tempfile.TemporaryDirectory() as d:
        # warm numba's caches and the workers once
        render_scene(load_scene(scene_file("three-rectangles"), resolution=8,
                                settings=settings_of()),
                     f"{d}/warm", client, settings_of(), preview=False, progress=False)
        for name in SCENES[:5] if quick else SCENES:
            sc = load_scene(scene_file(name), settings=settings_of())
            out = f"{d}/{name}"
            t = time.perf_counter()
            rep = render_scene(sc, out, client, settings_of(), preview=False, progress=False)
            wall = time.perf_counter() - t
            img = read_exr(f"{out}/image.exr")
            kernel = settings_of().solve.kernel
            against, err = error_of(name, sc, out, client, img, kernel)
            if name == "cornell-box-inside":
                ref = load_scene(os.path.join(ROOT, "scenes", name, "reference.toml"),
                                 settings=settings_of())
                import dask.config

                with dask.config.set({"radiosity.subdivide.unseen": "keep"}):
                    render_scene(ref, f"{d}/ref", client, settings_of(), preview=False,
                                 progress=False)
                r = read_exr(f"{d}/ref/image.exr") @ lum
                m = r > 0
                err = abs(float((img @ lum)[m].mean() / r[m].mean() - 1))
            sol = rep["solve"]
            method = rep["plan"].get("method", "pairs")
            rows.append({"scene": name, "sub_elements": rep["preprocess"]["sub_elements"],
                         "method": method,
                         "unseen_refined": rep["preprocess"]["unseen_refined"],
                         "closure": "closed" if rep["plan"]["closure"]["closed"] else "open",
                         "rows": (sol.get("row_sums") or {}).get("mode", "-"), "solver": sol["solver"],
                         "kernel": kernel if sol["kernel"] == "-" else sol["kernel"],
                         "passes": sol["iterations"],
                         "error": err, "against": against, "time_s": round(wall, 2)})
            print(table(rows[-1:], list(rows[-1])), flush=True)
            if "visibility" in rep and rep["visibility"].get("skipped"):
                continue  # nothing reflects: no solve to stop early
            # the tolerance trade-off on the same visibility
            images = {}
            for tol in TOLS:
                if method == "hierarchical":
                    fig = run_solve(out, client, settings_of(tol=tol), progress=False,
                                    method="hierarchical")
                else:
                    fig = run_solve(out, client, settings_of(tol=tol), progress=False,
                                    closure=None)
                render_outputs(out, settings=settings_of())
                images[tol] = (read_exr(f"{out}/image.exr"), fig.iterations)
            ref_img = images[1e-6][0]
            m = ref_img.sum(-1) > 0
            for tol in TOLS[:-1]:
                diff = np.abs(images[tol][0][m] - ref_img[m]) / np.maximum(ref_img[m], 1e-30)
                tol_rows.append({"scene": name, "tol": tol, "passes": images[tol][1],
                                 "passes_1e-6": images[1e-6][1],
                                 "max_rel_diff": float(diff.max()), "mean_rel_diff": float(diff.mean())})
    cols = ["scene", "sub_elements", "method", "unseen_refined", "closure", "rows", "solver", "kernel",
            "passes", "error", "against", "time_s"]
    print(table(rows, cols))
    print(table(tol_rows, ["scene", "tol", "passes", "passes_1e-6", "max_rel_diff", "mean_rel_diff"]))
    print("wrote", write("defaults", rows, {"tolerance": tol_rows}))


if __name__ == "__main__":
    main("--quick" in sys.argv)
