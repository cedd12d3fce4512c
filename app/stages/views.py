"""New views of a solved run (issue 28): another camera's image from the stored solution, with no
re-solve. Each pixel averages K x K rays over its area; every ray's hit point asks the run's method
for the radiance leaving that point (the hierarchical method gathers at the point over its
leaf's links: methods/hierarchical/views/points.py; the pairs method looks up its sub-element). A view
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
from radiosity.core.colour import tonemap
from radiosity.formats.images import write_exr, write_png
from radiosity.stages.pixels import area_offsets, sample_directions
from radiosity.tracing.rays import caster_of

#: Rays per pixel side of a view (K x K per pixel on the image stage's sheared lattice,
#: box-averaged: the render.area-samples default).
VIEW_SAMPLES = 4
#: Rays per Embree batch is about ROWS_PER_BATCH * 64.
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
    from radiosity.scene.load import parse_camera, read_toml

    cam, where = {}, "the view options"
    if path is not None:
        data = read_toml(path, "--camera", RadiosityError)
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


def hit_points(elements, camera: Camera, samples: int, ray_offset: float, caster=None):
    """First hits of the camera's `samples` x `samples` rays per pixel, on the image stage's
    sheared lattice (pixels.area_offsets): (orig (P,) int, points (P, 3), pixel (P,)) in
    pixel-major order (the S = samples^2 rays of pixel 0, then of pixel 1, ...). caster: a
    RayCaster of `elements` to reuse (None: built here)."""
    offsets = area_offsets(samples)
    S = len(offsets)
    rc = caster if caster is not None else caster_of(elements.verts, elements.nverts, ray_offset)
    origin = np.asarray(camera.center, np.float64)
    band = max(1, ROWS_PER_BATCH * 64 // (camera.width * S))
    orig, pts = [], []
    for r0 in range(0, camera.height, band):
        r1 = min(camera.height, r0 + band)
        d = sample_directions(camera, 1, offsets, r0, r1).reshape(-1, 3)
        e = np.asarray(rc.first_hit(origin, d.astype(np.float32), unit=True), np.int64)
        hit = e >= 0
        t = np.zeros(len(e))
        with np.errstate(divide="ignore", invalid="ignore"):  # the exact hit on its plane
            t[hit] = (np.einsum("ij,ij->i", elements.normal[e[hit]], elements.center[e[hit]] - origin)
                      / np.einsum("ij,ij->i", elements.normal[e[hit]], d[hit]))
        orig.append(e)
        pts.append(origin + t[:, None] * d)
    pixel = np.repeat(np.arange(camera.width * camera.height), S)
    return np.concatenate(orig), np.concatenate(pts), pixel


def pixel_footprints(camera: Camera, pts: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The footprint (m^2) of a pixel of `camera` at points `pts` on planes of `normal`: its
    solid angle times distance^2 over the cosine at the surface (floored at 0.05)."""
    W, H = camera.width, camera.height
    d = pts - camera.center[None, :]
    t = np.linalg.norm(d, axis=1)
    u = d / np.where(t > 0, t, 1.0)[:, None]
    cos_axis = np.clip(u @ (camera.z / np.linalg.norm(camera.z)), 1e-3, 1.0)
    omega = (2 * camera.half_w / W) * (2 * camera.half_h / H) / camera.focal ** 2 * cos_axis ** 3
    cos_surf = np.maximum(np.abs(np.einsum("ij,ij->i", u, normal)), 0.05)
    return omega * t * t / cos_surf


class Viewer:
    """A solved run opened once for many views (a walkthrough's frames): its elements, an
    Embree scene of them, the method's opened solution (methods' open_views: for the
    hierarchical method the links, node table and solution's node means) and the run's
    exposure. `image` renders a camera without writing files; `render` writes a view folder
    as render_view does. What was opened is read-only: one Viewer serves any number of
    cameras, with the same images as separate render_view calls."""

    def __init__(self, run_dir: str, settings):
        t0 = time.perf_counter()
        self.run_dir = run_dir
        self.settings = s = settings
        self.store = rs = RunStore(run_dir)
        if not rs.has("solution"):
            raise RadiosityError(f"{run_dir} has no solution yet: run radiosity render (or solve) "
                                 "first")
        self.method = method_of_run(rs)
        self.elements = el = rs.load_elements()
        self.ray_offset = float(s.rays.offset)
        self.caster = caster_of(el.verts, el.nverts, self.ray_offset)
        self.two_sided = np.asarray(el.two_sided, bool)
        self.source = self.method.open_views(rs, s)
        # the run's own exposure, so that views of one run compare
        self.exposure = _report(run_dir).get("render", {}).get("exposure")
        self.time_open_s = round(time.perf_counter() - t0, 4)

    def image(self, camera: Camera, samples: int = VIEW_SAMPLES) -> tuple[np.ndarray, dict]:
        """The image (H, W, 3) float64 linear radiance of `camera` (samples x samples rays a
        pixel, box-averaged) and its figures; no files written."""
        t0 = time.perf_counter()
        el = self.elements
        orig, pts, pixel = hit_points(el, camera, samples, self.ray_offset, self.caster)
        hit = orig >= 0
        o = np.maximum(orig, 0)
        side = (np.einsum("ij,ij->i", el.normal[o], camera.center[None, :] - pts) <= 0.0
                ).astype(np.int64)
        t_rays = time.perf_counter() - t0
        footprint = pixel_footprints(camera, pts, el.normal[o])
        L, gathered = self.source.radiance_at(pts, np.where(hit, orig, -1), side, pixel,
                                              footprint)
        back = hit & (side == 1) & ~self.two_sided[o]
        L[back | ~hit] = 0.0
        img = L.reshape(camera.height, camera.width, samples * samples, 3).mean(axis=2)
        figures = {"camera": camera.to_dict(), "samples_per_pixel": samples * samples,
                   "method": self.method.name, "rays": int(len(orig)),
                   "hit_fraction": float(hit.mean()),
                   "mean_radiance": img.reshape(-1, 3).mean(0).tolist(),
                   "time_rays_s": round(t_rays, 4), "gather": gathered,
                   "time_s": round(time.perf_counter() - t0, 4)}
        return img, figures

    def render(self, camera: Camera, name: str | None = None, samples: int = VIEW_SAMPLES,
               exposure: float | None = None) -> View:
        """The view of `camera` into RUN/views/NAME/ (image.exr, image.png, view.json) and the
        run's report.json "views" section; exposure None: the run's."""
        t0 = time.perf_counter()
        run_dir = self.run_dir
        folder = os.path.join(run_dir, "views", view_name(name, run_dir))
        os.makedirs(folder, exist_ok=True)
        img, figures = self.image(camera, samples)
        if exposure is None:
            exposure = self.exposure
        write_exr(os.path.join(folder, "image.exr"), img.astype(np.float32))
        write_png(os.path.join(folder, "image.png"), tonemap(img, exposure))
        figures = {**figures, "exposure": exposure,
                   "time_s": round(time.perf_counter() - t0, 4)}
        with open(os.path.join(folder, "view.json"), "w") as f:
            json.dump(figures, f, indent=1)
        update_report(run_dir, "views", {os.path.basename(folder): {
            k: figures[k] for k in ("time_s", "rays", "mean_radiance")}})
        return View(folder, img, figures)


def render_view(run_dir: str, camera: Camera, name: str | None = None, *, settings,
                samples: int = VIEW_SAMPLES, exposure: float | None = None) -> View:
    """The image of `camera` from the solved run in `run_dir`, into RUN/views/NAME/ (a Viewer
    opened for this one view; open a Viewer for many)."""
    t0 = time.perf_counter()
    v = Viewer(run_dir, settings).render(camera, name, samples, exposure)
    v.figures["time_s"] = round(time.perf_counter() - t0, 4)  # the opening included, as before
    with open(os.path.join(v.out, "view.json"), "w") as f:
        json.dump(v.figures, f, indent=1)
    return v


def _report(run_dir: str) -> dict:
    try:
        with open(os.path.join(run_dir, "report.json")) as f:
            return json.load(f)
    except (OSError, ValueError):
        return {}
