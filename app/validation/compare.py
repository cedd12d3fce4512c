"""Image against reference: error figures (`errors`), masks of pixels wholly inside one element,
and a false-colour picture of the relative difference (`radiosity compare A.exr B.exr`).

Images are linear RGB radiance (H, W, 3); B is the reference.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from radiosity.errors import RadiosityError

CHANNELS = ("R", "G", "B")


class CompareError(RadiosityError):
    """Images that cannot be compared: unreadable, or of sizes that are not multiples."""


# ----------------------------------------------------------------------------- resampling

def box_down(img: np.ndarray, h: int, w: int) -> np.ndarray:
    """(H, W, c) -> (h, w, c) by the mean of each (H/h) x (W/w) block (integer factors only)."""
    img = np.asarray(img, np.float64)
    H, W = img.shape[:2]
    if H % h or W % w:
        raise CompareError(f"cannot box-filter a {W}x{H} image to {w}x{h}: not an integer factor")
    return img.reshape(h, H // h, w, W // w, -1).mean(axis=(1, 3))


def box_down_stderr(se: np.ndarray, h: int, w: int) -> np.ndarray:
    """Standard error of the block means of independent pixels: sqrt(sum se^2) / n."""
    se = np.asarray(se, np.float64)
    H, W = se.shape[:2]
    n = (H // h) * (W // w)
    return np.sqrt(box_down(se ** 2, h, w) / n)


def common_grid(a: np.ndarray, b: np.ndarray):
    """Both images on the coarser grid (box filter); sizes must divide."""
    h, w = min(a.shape[0], b.shape[0]), min(a.shape[1], b.shape[1])
    return box_down(a, h, w), box_down(b, h, w)


# ----------------------------------------------------------------------------- masks

def element_raster(scene) -> np.ndarray:
    """Original element seen through each pixel centre of the scene's camera: (H, W) int32, -1
    for none (the engine's camera rays and Embree)."""
    from radiosity.tracing.rays import RayCaster
    from radiosity.tracing.rays import raster_band

    cam = scene.camera
    rc = RayCaster(scene.elements.verts, scene.elements.nverts)
    orig, _ = raster_band(rc, scene.elements.normal, scene.elements.center, cam, 1,
                          slice(0, cam.height))
    return np.asarray(orig, np.int32).reshape(cam.height, cam.width)


def interior(raster: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose 3 x 3 neighbourhood sees one element (border pixels: False).

    The pixel's footprint lies in the convex hull of its eight neighbours' centres, and an
    element (convex) that holds all nine centres holds that hull: the pixel is wholly inside
    the element, so point samples and area averages of it differ only by the radiance's
    variation inside one pixel."""
    r = np.asarray(raster)
    H, W = r.shape
    out = np.zeros((H, W), bool)
    if H < 3 or W < 3:
        return out
    c = r[1:-1, 1:-1]
    ok = c >= 0
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            ok &= r[1 + dy:H - 1 + dy, 1 + dx:W - 1 + dx] == c
    out[1:-1, 1:-1] = ok
    return out


# ----------------------------------------------------------------------------- figures

def _entries(a, b, mask):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise CompareError(f"images of shapes {a.shape} and {b.shape} cannot be compared")
    m = b > 0
    if mask is not None:
        m &= np.asarray(mask, bool)[..., None]
    return a, b, m


def errors(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None,
           stderr: np.ndarray | None = None) -> dict:
    """Error figures of image `a` against reference `b`. The relative error of a pixel and
    channel is |a - b| / b, defined where b > 0; figures are over those entries (and over
    `mask` when one is given):

    - `mare`: mean absolute relative error; `max`: the largest; `rms`: root mean square;
    - `per_channel`: the mean for R, G and B;
    - `noise_floor` (when the reference's per-pixel standard error `stderr` is given): the mean
      absolute relative error an *exact* image would show against this reference,
      sqrt(2/pi) * mean(se / b) (the mean of |N(0, se)|); errors near it are the reference's
      noise, not the image's.
    """
    a, b, m = _entries(a, b, mask)
    rel = np.abs(a - b)[m] / b[m]
    out = {"pixels": int(m.any(axis=-1).sum()), "entries": int(m.sum())}
    if not rel.size:
        out.update(mare=float("nan"), max=float("nan"), rms=float("nan"),
                   per_channel=dict.fromkeys(CHANNELS, float("nan")))
    else:
        per = {}
        for k, c in enumerate(CHANNELS):
            mk = m[..., k]
            per[c] = float(np.mean(np.abs(a[..., k] - b[..., k])[mk] / b[..., k][mk])) if mk.any() else float("nan")
        out.update(mare=float(rel.mean()), max=float(rel.max()), rms=float(np.sqrt(np.mean(rel ** 2))),
                   per_channel=per)
    if stderr is not None:
        out["noise_floor"] = noise_floor(b, stderr, mask)
    return out


def noise_floor(ref: np.ndarray, stderr: np.ndarray, mask: np.ndarray | None = None) -> float:
    """sqrt(2/pi) * mean(se / ref): the expected mean absolute relative error of an exact image
    against a reference with per-pixel standard error `stderr`."""
    _, b, m = _entries(ref, ref, mask)
    se = np.asarray(stderr, np.float64)
    return float(math.sqrt(2.0 / math.pi) * np.mean(se[m] / b[m])) if m.any() else float("nan")


def surface_errors(a: np.ndarray, b: np.ndarray, raster: np.ndarray, mask: np.ndarray,
                   stderr: np.ndarray | None = None) -> dict:
    """Per original element seen in `mask`: {element: {"pixels", "error", "stderr"}} where error
    is the mean over channels (with a positive reference) of |mean a - mean b| / mean b over the
    element's masked pixels, and stderr the same relative standard error of mean b (when the
    reference's `stderr` is given). Averaging over a surface removes most of the reference's
    noise, so this sees smaller errors than the per-pixel figure."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    r = np.where(np.asarray(mask, bool), np.asarray(raster), -1)
    out = {}
    for e in np.unique(r[r >= 0]):
        sel = r == e
        ma, mb = a[sel].mean(axis=0), b[sel].mean(axis=0)
        ok = mb > 0
        if not ok.any():
            continue
        d = {"pixels": int(sel.sum()), "error": float(np.mean(np.abs(ma - mb)[ok] / mb[ok]))}
        if stderr is not None:
            s = np.sqrt((np.asarray(stderr, np.float64)[sel] ** 2).sum(axis=0)) / sel.sum()
            d["stderr"] = float(np.mean(s[ok] / mb[ok]))
        out[int(e)] = d
    return out


# ----------------------------------------------------------------------------- the command

def relative_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) signed relative difference of the luminances, (a - b) / b; NaN where b = 0."""
    from radiosity.stages.image import LUMA

    ya, yb = np.asarray(a, np.float64) @ LUMA, np.asarray(b, np.float64) @ LUMA
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(yb > 0, (ya - yb) / yb, np.nan)


def write_difference_png(path: str, rel: np.ndarray, title: str = "") -> float:
    """False-colour PNG of a signed relative difference (H, W): blue below, red above the
    reference, white equal, grey where undefined; the scale is symmetric, up to the 99th
    percentile of |rel| (at least 1e-6). Returns that scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    finite = np.abs(rel[np.isfinite(rel)])
    lim = max(float(np.percentile(finite, 99)) if finite.size else 0.0, 1e-6)
    H, W = rel.shape
    fig, ax = plt.subplots(figsize=(5.2, 4.4 * H / W + 0.4), dpi=110)
    cmap = matplotlib.colormaps["RdBu_r"].copy()
    cmap.set_bad("0.6")
    im = ax.imshow(np.ma.masked_invalid(rel), cmap=cmap, vmin=-lim, vmax=lim, interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title or "relative difference (A - B) / B, luminance", fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return lim


def compare_files(a_path: str, b_path: str, out: str | None = None) -> dict:
    """Figures of image A against reference B (EXR files; the finer one is box-filtered to the
    coarser grid). B's standard error is used when `<B without .exr>-stderr.exr` exists (what
    `radiosity reference` writes). With `out`: compare.json and compare.png there."""
    from radiosity.stages.image import read_exr

    a, b = read_exr(a_path), read_exr(b_path)
    stem = b_path[:-4] if b_path.lower().endswith(".exr") else b_path
    se_path = stem + "-stderr.exr"
    se = read_exr(se_path) if os.path.isfile(se_path) else None
    try:
        a, b2 = common_grid(a, b)
    except CompareError:
        raise CompareError(f"{a_path} is {a.shape[1]}x{a.shape[0]} and {b_path} is "
                           f"{b.shape[1]}x{b.shape[0]}: the larger must be an integer multiple of "
                           "the smaller in each direction") from None
    if se is not None:
        se = box_down_stderr(se, *b2.shape[:2]) if se.shape == b.shape else None
    fig = {"a": os.path.abspath(a_path), "b": os.path.abspath(b_path), "width": int(b2.shape[1]),
           "height": int(b2.shape[0]), **errors(a, b2, stderr=se)}
    if out:
        os.makedirs(out, exist_ok=True)
        fig["scale"] = write_difference_png(os.path.join(out, "compare.png"), relative_difference(a, b2),
                                            f"{os.path.basename(a_path)} vs {os.path.basename(b_path)}: "
                                            "(A - B) / B")
        with open(os.path.join(out, "compare.json"), "w") as f:
            json.dump(fig, f, indent=1)
    return fig
