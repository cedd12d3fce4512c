"""New views of a solved run (issue 28): another camera's image from the stored solution, with no
re-solve. Each pixel averages K x K sub-pixel rays; every ray's hit point asks the run's method
for the radiance leaving that point (the hierarchical method gathers at the point over its
leaf's links: methods/hierarchical/views.py; the pairs method looks up its sub-element). A view
goes to its own folder, RUN/views/NAME/ (image.exr, image.png, view.json); the run's own image
and files stay as they are."""

from __future__ import annotations

import json
import os
import re
import time
from dataclasses import dataclass

import numpy as np

from radiosity.core.bundles import Camera
from radiosity.errors import RadiosityError
from radiosity.methods.base import method_of_run
from radiosity.runtime.store import RunStore, update_report
from radiosity.stages.pixels import downsample, tonemap, write_exr, write_png
from radiosity.tracing.rays import RayCaster, raster_band

#: Sub-pixel rays per pixel side of a view (K x K per pixel, box-averaged).
VIEW_SAMPLES = 4
#: Fine-raster rows per Embree batch.
ROWS_PER_BATCH = 256


@dataclass(frozen=True)
class View:
    """A rendered view: its folder, the image (H, W, 3) linear radiance, and its figures."""

    out: str
    image: np.ndarray
    figures: dict


def view_camera(run_camera: Camera, path: str | None = None, position=None, look_at=None,
                up=None, fov_y=None, resolution=None) -> Camera:
    """The camera of a new view: the [camera] table of the TOML file `path` (a scene file or a
    file with only that table), then the look-at values given (position, look_at, up, fov_y:
    each replaces the file's), at `resolution` (default: the file's, else the run's)."""
    import tomllib

    from radiosity.scene.load import parse_camera

    cam, where = {}, "the view options"
    if path is not None:
        try:
            with open(path, "rb") as f:
                data = tomllib.load(f)
        except OSError as e:
            raise RadiosityError(f"--camera {path}: {e.strerror}") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise RadiosityError(f"--camera {path}: not valid TOML: {e}") from None
        cam = data.get("camera")
        if not isinstance(cam, dict):
            raise RadiosityError(f"--camera {path}: no [camera] table (position, look_at, fov_y)")
        where = path
    given = {"position": position, "look_at": look_at, "up": up, "fov_y": fov_y}
    if any(v is not None for v in given.values()):
        if "position" not in cam and cam:
            cam = {}  # the seed's form in the file: the look-at values replace it
        cam = {**cam, **{k: v for k, v in given.items() if v is not None}}
        if "fov_y" not in cam:
            cam["fov_y"] = float(np.degrees(2 * np.arctan(run_camera.half_h)))
        for k in ("position", "look_at"):
            if k not in cam:
                raise RadiosityError(f"a new view needs --{k.replace('_', '-')} (or --camera FILE)")
    if not cam:
        raise RadiosityError("a new view needs --camera FILE or --position and --look-at")
    if resolution is None and "resolution" not in cam:
        resolution = (run_camera.width, run_camera.height)
    return parse_camera(cam, where, resolution)


def view_name(name: str | None, run_dir: str) -> str:
    """A folder name for a view: `name` (letters, digits, - and _), or view-N, the next free."""
    if name is not None:
        if not re.fullmatch(r"[A-Za-z0-9_\-]+", name):
            raise RadiosityError(f"--name {name!r}: use letters, digits, - and _ only")
        return name
    k = 1
    while os.path.exists(os.path.join(run_dir, "views", f"view-{k}")):
        k += 1
    return f"view-{k}"


def hit_points(elements, camera: Camera, samples: int, epsilon: float):
    """First hits of the camera's K x K sub-pixel rays: (orig (P,) int, points (P, 3)) in fine
    raster order (H*K rows of W*K)."""
    rc = RayCaster(elements.verts, elements.nverts, epsilon)
    h = camera.height * samples
    orig, pts = [], []
    for r0 in range(0, h, ROWS_PER_BATCH):
        e, p = raster_band(rc, elements.normal, elements.center, camera, samples,
                           slice(r0, min(h, r0 + ROWS_PER_BATCH)))
        orig.append(np.asarray(e, np.int64))
        pts.append(p)
    return np.concatenate(orig), np.concatenate(pts)


def pixel_footprints(camera: Camera, samples: int, pts: np.ndarray, normal: np.ndarray):
    """For the fine raster's samples (H*K x W*K, in order) hitting `pts` on planes of `normal`:
    the pixel (H x W raster index) each belongs to, and that pixel's footprint there (m^2:
    its solid angle times distance^2 over the cosine at the surface, floored at 0.05)."""
    K, W, H = int(samples), camera.width, camera.height
    rows, cols = np.divmod(np.arange(H * K * W * K), W * K)
    pixel = (rows // K) * W + cols // K
    d = pts - camera.center[None, :]
    t = np.linalg.norm(d, axis=1)
    u = d / np.where(t > 0, t, 1.0)[:, None]
    cos_axis = np.clip(u @ (camera.z / np.linalg.norm(camera.z)), 1e-3, 1.0)
    omega = (2 * camera.half_w / W) * (2 * camera.half_h / H) / camera.focal ** 2 * cos_axis ** 3
    cos_surf = np.maximum(np.abs(np.einsum("ij,ij->i", u, normal)), 0.05)
    return pixel, omega * t * t / cos_surf


def render_view(run_dir: str, camera: Camera, name: str | None = None, settings=None,
                samples: int = VIEW_SAMPLES, exposure: float | None = None) -> View:
    """The image of `camera` from the solved run in `run_dir`, into RUN/views/NAME/."""
    from radiosity.settings import resolve

    s = resolve(base=settings)
    t0 = time.perf_counter()
    rs = RunStore(run_dir)
    if not rs.has("solution"):
        raise RadiosityError(f"{run_dir} has no solution yet: run radiosity render (or solve) first")
    method = method_of_run(rs)
    el = rs.load_elements()
    folder = os.path.join(run_dir, "views", view_name(name, run_dir))
    os.makedirs(folder, exist_ok=True)
    orig, pts = hit_points(el, camera, samples, float(s.rays.epsilon))
    hit = orig >= 0
    o = np.maximum(orig, 0)
    side = (np.einsum("ij,ij->i", el.normal[o], camera.center[None, :] - pts) <= 0.0).astype(np.int64)
    t_rays = time.perf_counter() - t0
    pixel, footprint = pixel_footprints(camera, samples, pts, el.normal[o])
    L, gathered = method.radiance_at(rs, s, pts, np.where(hit, orig, -1), side, pixel, footprint)
    back = hit & (side == 1) & ~np.asarray(el.two_sided, bool)[o]
    L[back | ~hit] = 0.0
    fine = L.reshape(camera.height * samples, camera.width * samples, 3)
    img = downsample(fine, samples, "box")
    if exposure is None:  # the run's own exposure, so that views of one run compare
        rep = _report(run_dir)
        exposure = rep.get("render", {}).get("exposure")
    write_exr(os.path.join(folder, "image.exr"), img.astype(np.float32))
    write_png(os.path.join(folder, "image.png"), tonemap(img, exposure))
    figures = {"camera": camera.to_dict(), "samples_per_pixel": samples * samples,
               "method": method.name, "rays": int(len(orig)), "hit_fraction": float(hit.mean()),
               "mean_radiance": img.reshape(-1, 3).mean(0).tolist(), "exposure": exposure,
               "time_rays_s": round(t_rays, 4), "gather": gathered,
               "time_s": round(time.perf_counter() - t0, 4)}
    with open(os.path.join(folder, "view.json"), "w") as f:
        json.dump(figures, f, indent=1)
    update_report(run_dir, "views", {os.path.basename(folder): {
        k: figures[k] for k in ("time_s", "rays", "mean_radiance")}})
    return View(folder, img, figures)


def _report(run_dir: str) -> dict:
    try:
        with open(os.path.join(run_dir, "report.json")) as f:
            return json.load(f)
    except (OSError, ValueError):
        return {}
