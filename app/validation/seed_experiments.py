"""The seed's experiments (`radiosity study seed`): preprocessing and visibility time against
resolution, speedup against workers, and the image series of seed §5 and §6, on any scene.
"""

from __future__ import annotations

import os
import time
import warnings

import numpy as np

from radiosity.settings import Settings


def seed(scene_path: str, out: str, open_cluster, resolutions=(32, 64, 128, 256), workers=(1, 2),
         speedup_res: int = 96, echo=print, *, settings: Settings) -> dict:
    """Reproduce the seed's experiments on SCENE (seed §5, §6): preprocessing time against camera
    resolution (Fig. 3), visibility time against the number of sub-elements (Fig. 4), speedup
    against workers (§5.2 table), and the image series (no preprocessing / 50x50 / 70x70 with a
    Gaussian filter, §6). `open_cluster(n)` is a context manager giving a Client of n workers.
    Writes seed-fig3.png, seed-fig4.png, seed-speedup.png, seed-images.png and seed.md.
    settings: the runs'."""
    os.makedirs(out, exist_ok=True)
    runs = os.path.join(out, "runs")
    with open_cluster(max(workers)) as client:
        rows = _scaling(scene_path, runs, client, resolutions, echo, settings)
        series = _series(scene_path, runs, client, settings)
    speed = []
    for w in workers:
        with open_cluster(w) as client:
            speed.append(_speed(scene_path, runs, client, w, speedup_res, settings))
    for sp in speed:
        sp["speedup"] = speed[0]["visibility_s"] / sp["visibility_s"]
        sp["efficiency"] = sp["speedup"] / sp["workers"]
    name = os.path.basename(os.path.dirname(os.path.abspath(scene_path)))
    m = np.array([r["sub_elements"] for r in rows], float)
    tv = np.array([r["visibility_s"] for r in rows])
    order = float(np.polyfit(np.log(m[-3:]), np.log(tv[-3:]), 1)[0]) if len(m) >= 3 else float("nan")
    _plots(out, name, rows, speed, series, m, tv, order)
    _write_markdown(out, name, rows, speed, order)
    return {"rows": rows, "speedup": speed, "order": order}


def _preprocessed(scene_path: str, run: str, client, res: int, s: Settings):
    """The scene at `res` preprocessed into `run` (warnings off): its PreprocessFigures."""
    from radiosity.scene.load import load_scene
    from radiosity.stages.preprocess import preprocess

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return preprocess(load_scene(scene_path, resolution=res, settings=s), run, client, s,
                          progress=False)


def _scaling(scene_path: str, runs: str, client, resolutions, echo, s: Settings) -> list[dict]:
    """Preprocessing and visibility time at each resolution (seed Figs. 3 and 4), after one
    warm-up run at the smallest."""
    from radiosity.methods.base import all_pairs_method

    compute_visibility = all_pairs_method().build  # the seed's visibility matrix (seed §4.3)
    warm = os.path.join(runs, "warm")
    _preprocessed(scene_path, warm, client, min(resolutions), s)
    compute_visibility(warm, client, s, progress=False)
    rows = []
    for res in resolutions:
        d = os.path.join(runs, f"r{res}")
        t = time.perf_counter()
        pre = _preprocessed(scene_path, d, client, res, s)
        t_pre = time.perf_counter() - t
        t = time.perf_counter()
        vis = compute_visibility(d, client, s, progress=False)
        rows.append({"resolution": res, "sub_elements": pre["sub_elements"], "preprocess_s": t_pre,
                     "visibility_s": time.perf_counter() - t, "rays": vis["rays"]})
        echo(f"  {res}x{res}: {pre['sub_elements']} sub-elements, preprocess {t_pre:.2f} s, "
             f"visibility {rows[-1]['visibility_s']:.2f} s")
    return rows


def _series(scene_path: str, runs: str, client, s: Settings) -> list[tuple[str, str]]:
    """The seed's image series (seed §6): (label, PNG path) for the original elements alone,
    50 x 50 and 70 x 70 with a Gaussian filter."""
    from radiosity.pipeline import render_preview, render_scene
    from radiosity.scene.load import load_scene

    sc = load_scene(scene_path, resolution=70, settings=s)
    render_preview(sc, os.path.join(runs, "series"), client, s)
    series = [("no preprocessing", os.path.join(runs, "series", "preview", "image.png"))]
    for res, k, filt, label in ((50, 1, "box", "50 x 50"), (70, 2, "gaussian", "70 x 70, Gaussian")):
        d = os.path.join(runs, f"series{res}")
        render_scene(load_scene(scene_path, resolution=res, settings=s), d, client,
                     s.replace({"subdivide.subpixel": k, "render.filter": filt}),
                     preview=False, progress=False, echo=lambda *a: None)
        series.append((label, os.path.join(d, "image.png")))
    return series


def _speed(scene_path: str, runs: str, client, w: int, res: int, s: Settings) -> dict:
    """The visibility stage's time on `w` workers (a second run: caches warm)."""
    from radiosity.methods.base import all_pairs_method

    compute_visibility = all_pairs_method().build
    d = os.path.join(runs, f"speed{w}")
    _preprocessed(scene_path, d, client, res, s)
    compute_visibility(d, client, s, progress=False)  # warm
    t = time.perf_counter()
    compute_visibility(d, client, s, progress=False)
    return {"workers": w, "visibility_s": time.perf_counter() - t}


def _plots(out: str, name: str, rows, speed, series, m, tv, order: float) -> None:
    """seed-fig3.png, seed-fig4.png, seed-speedup.png and seed-images.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    fig, ax = plt.subplots(figsize=(5, 3.6), dpi=110)
    ax.plot([r["resolution"] for r in rows], [r["preprocess_s"] for r in rows], "o-")
    ax.set_xlabel("camera resolution (N x N)")
    ax.set_ylabel("preprocessing time (s)")
    ax.set_title(f"{name}: preprocessing (seed Fig. 3)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "seed-fig3.png"))
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(5, 3.6), dpi=110)
    ax.loglog(m, tv, "o-", label=f"measured (slope {order:.2f})")
    ax.loglog(m, tv[0] * (m / m[0]) ** 3, "--", color="grey", label="classical method: cubic")
    ax.set_xlabel("sub-elements")
    ax.set_ylabel("visibility time (s)")
    ax.set_title(f"{name}: visibility (seed Fig. 4)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "seed-fig4.png"))
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(4.2, 3.4), dpi=110)
    ax.plot([sp["workers"] for sp in speed], [sp["speedup"] for sp in speed], "o-", label="measured")
    ax.plot([sp["workers"] for sp in speed], [sp["workers"] for sp in speed], "--", color="grey", label="linear")
    ax.set_xlabel("workers")
    ax.set_ylabel("speedup")
    ax.set_title("visibility speedup (seed §5.2)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "seed-speedup.png"))
    plt.close(fig)
    from PIL import Image

    fig, axs = plt.subplots(1, len(series), figsize=(3.2 * len(series), 3.4), dpi=110)
    for ax, (label, fn) in zip(np.atleast_1d(axs), series):
        ax.imshow(np.asarray(Image.open(fn)), interpolation="nearest")
        ax.set_title(label, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "seed-images.png"))
    plt.close(fig)


def _write_markdown(out: str, name: str, rows, speed, order: float) -> None:
    """seed.md: the tables and the figures."""
    with open(os.path.join(out, "seed.md"), "w") as f:
        f.write(f"# The seed's experiments on {name}\n\n| resolution | sub-elements | preprocess s | "
                "visibility s | rays |\n|---:|---:|---:|---:|---:|\n")
        for r in rows:
            f.write(f"| {r['resolution']} | {r['sub_elements']} | {r['preprocess_s']:.2f} | "
                    f"{r['visibility_s']:.2f} | {r['rays']} |\n")
        f.write(f"\nVisibility time grows as (sub-elements)^{order:.2f} over the last three sizes.\n\n"
                "The first table times the first visibility run of each fresh run directory (what "
                "a user waits for); the speedup table times a second run on a directory already "
                "computed once (caches warm), so the two differ at the same size.\n\n"
                "| workers | visibility s | speedup | efficiency |\n|---:|---:|---:|---:|\n")
        for sp in speed:
            f.write(f"| {sp['workers']} | {sp['visibility_s']:.2f} | {sp['speedup']:.2f} | "
                    f"{sp['efficiency']:.2f} |\n")
        f.write("\n![Fig. 3](seed-fig3.png) ![Fig. 4](seed-fig4.png) ![speedup](seed-speedup.png)\n\n"
                "![images](seed-images.png)\n")
