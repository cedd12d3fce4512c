"""The image stage: the solved radiance of a run as image.exr (linear RGB float32, ZIP),
image.png (8-bit sRGB), mesh.glb, mesh.ply and viewer.html (`render_outputs`), and the
dashboard's live preview while the solver runs (`previewer`).

Inputs (a run store): the partition, the elements, the camera, the fine ID raster `raster/sub`
(H*K, W*K) and the solution `solution/radiance` (m, 2, 3) float64, linear RGB radiance
(W sr^-1 m^-2) per sub-element and side (0 front, 1 back). The pixels are made in
stages.pixels and coloured by core.colour; the files are formats/'s (images, meshexport,
viewer); their names are re-exported here.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass

import numpy as np

from radiosity.core.colour import AUTO_KEY, AUTO_PERCENTILE, LUMA, auto_exposure, srgb_encode, tonemap
from radiosity.core.smooth import smooth_mesh
from radiosity.errors import RenderError, StoreError
from radiosity.formats.images import read_exr, write_exr, write_png
from radiosity.formats.meshexport import export_mesh, triangles
from radiosity.formats.viewer import VIEWER_GROW_PX, VIEWER_MAX_TRIANGLES, write_viewer
from radiosity.runtime.store import StageFigures
from radiosity.settings import Settings
from radiosity.stages.grids import black_irradiance
from radiosity.stages.tables import light_tables, write_light_tables
from radiosity.stages.pixels import (SAMPLINGS, downsample, facing_side, pixel_radiance, refine,
                                     sample_raster, samples_radiance, seen_radiance)

__all__ = ["ImageFigures", "render_outputs", "previewer",
           "AUTO_KEY", "AUTO_PERCENTILE", "LUMA", "SAMPLINGS", "RenderError", "sample_raster",
           "auto_exposure", "downsample",
           "facing_side", "pixel_radiance", "read_exr", "srgb_encode", "tonemap", "write_exr",
           "write_png", "VIEWER_GROW_PX", "VIEWER_MAX_TRIANGLES", "export_mesh", "triangles",
           "write_viewer"]



@dataclass(frozen=True)
class ImageFigures(StageFigures):
    """The image stage's figures (report.json, section "render"): outputs, exposure, sizes."""

    SECTION = "render"
    image_exr: str
    image_png: str
    mesh_glb: str
    mesh_ply: str
    viewer_html: str
    exposure: float
    exposure_auto: bool
    width: int
    height: int
    subpixel: int
    sampling: str                # area or point (render.sampling)
    area_samples: int            # rays per side of each fine pixel (1 with point)
    rays: int                    # sample rays cast for the image (0 with point: the raster's)
    edge_pixels: int             # fine pixels on a silhouette or corner, sampled again
    edge_rays: int               # their rays (render.edge-samples per side)
    refined: list                # [rays a side, fine pixels] of each later level (pixels.refine)
    refined_rays: int            # their rays
    filter: str
    sigma: float
    mean_radiance: list
    hit_fraction: float
    sub_elements: int
    triangles: int
    mesh_faces: int
    viewer_triangles: int
    viewer_stride: int
    time_image_s: float
    time_s: float

    def rows(self):
        return [("outputs", "image.exr, image.png, mesh.glb, mesh.ply, viewer.html"),
                ("image", f"{self.width}x{self.height}, {self.sampling} sampling"
                          + (f" ({self.area_samples * self.subpixel}^2 rays a pixel"
                             + (f", {self.edge_rays // max(self.edge_pixels, 1)} at each of "
                                f"{self.edge_pixels} on an edge" if self.edge_pixels else "")
                             + (", then " + ", ".join(f"{side * side} at {n}"
                                                      for side, n in self.refined)
                                if self.refined else "")
                             + ")" if self.sampling == "area" else "")
                          + f", exposure {self.exposure:.3g}")]


# ----------------------------------------------------------------------------- the stage

def render_outputs(run_dir: str, filter: str | None = None, sigma: float | None = None,
                   exposure: float | str | None = None, *, settings: Settings,
                   sampling: str | None = None, area_samples: int | None = None,
                   edge_samples: int | None = None, progress: bool = False) -> ImageFigures:
    """Image, meshes and viewer of a solved run: writes image.exr, image.png, mesh.glb,
    mesh.ply and viewer.html into `run_dir` and section "render" of report.json.

    filter, sigma, exposure, sampling, area_samples, edge_samples: None takes `render.filter`,
    `render.sigma`, `render.exposure`, `render.sampling`, `render.area-samples`,
    `render.edge-samples` of `settings`; an exposure of None there (or
    "auto" here) is automatic (`auto_exposure` of the final image). progress: a bar (or a
    started and a done line) over the four outputs: image, meshes, viewer, tables. sampling
    "area": each fine pixel is the mean of ceil(area-samples / subpixel)^2 rays over its area
    (pixels.sample_raster), and one whose rays see two planes or materials, or values far
    apart, the mean of ceil(edge-samples / subpixel)^2, then of twice and four times as many
    a side while its estimated error is above 1 % (pixels.refine); "point": the sub-element at
    its centre (the run's ID raster). Returns the figures: paths, exposure,
    width, height, subpixel, sampling, area_samples, rays, edge_pixels, edge_rays (the pixels
    sampled again and their rays), refined, refined_rays (the later levels), filter, sigma,
    mean_radiance (RGB mean
    over the image, black pixels included), hit_fraction (fine pixels whose centre sees an
    element), triangles, time_s.
    """
    from radiosity.runtime.store import RunStore

    t0 = time.perf_counter()
    sigma_given = sigma is not None
    st = settings.replace({"render.filter": filter, "render.sigma": sigma,
                           "render.exposure": exposure, "render.sampling": sampling,
                           "render.area-samples": area_samples,
                           "render.edge-samples": edge_samples})
    r = st.render
    if r.sampling not in SAMPLINGS:
        raise RenderError(f"radiosity.render.sampling must be one of {', '.join(SAMPLINGS)}, got "
                          f"{r.sampling!r}")
    if not int(r.area_samples) >= 1:
        raise RenderError(f"radiosity.render.area-samples must be a positive integer, got "
                          f"{r.area_samples!r}")
    if not int(r.edge_samples) >= 0:
        raise RenderError(f"radiosity.render.edge-samples must be 0 or a positive integer, got "
                          f"{r.edge_samples!r}")
    filter = r.filter
    sigma = float(r.sigma)
    exposure = r.exposure
    auto = exposure is None or (isinstance(exposure, str) and exposure.lower() == "auto")
    if not auto:
        bad = f"exposure must be a positive number or 'auto', got {exposure!r}"
        try:
            exposure = float(exposure)
        except (TypeError, ValueError):
            raise RenderError(bad) from None
        if not exposure > 0.0 or not math.isfinite(exposure):
            raise RenderError(bad)

    from radiosity.runtime.monitor import progress_bar

    bar = progress_bar(4, "outputs", progress, unit="output")
    rs = RunStore(run_dir, "r")
    part = rs.load_partition()
    elements = rs.load_elements()
    camera = rs.load_camera()
    k = int(rs.attrs.get("subpixel", 1))
    raster = rs.read_arrays("raster")["sub"]
    radiance = rs.read_arrays("solution")["radiance"]
    if filter == "gaussian" and k == 1:
        warnings.warn(f"{run_dir} has no sub-samples (preprocessed with --subpixel 1): the "
                      f"Gaussian filter only blurs the image by sigma = {sigma:g} pixels; "
                      "preprocess with --subpixel 2 or more, or use --filter box", stacklevel=2)
    elif filter == "box" and sigma_given:
        warnings.warn("--sigma is the Gaussian filter's width: ignored with --filter box",
                      stacklevel=2)
    if raster.shape != (camera.height * k, camera.width * k):
        raise StoreError(f"{rs.path}: raster/sub has shape {raster.shape}, the camera and "
                         f"subpixel {k} need {(camera.height * k, camera.width * k)}: run "
                         f"preprocess again")
    # the light tables (elements.csv, surfaces.csv, ...) and the radiance at the mesh's
    # vertices need only the solution: made on threads of their own beside the image (their
    # numba, sorts and file writes let go of the GIL), joined before the figures
    pool = ThreadPoolExecutor(2, thread_name_prefix="outputs")
    smooth = pool.submit(smooth_mesh, part, elements, radiance)
    tables = pool.submit(_tables, rs.run_dir, part, elements, radiance, st)
    pool.shutdown(wait=False)
    try:
        fig = _image_and_meshes(rs, st, part, elements, camera, k, raster, radiance, filter,
                                sigma, auto, exposure, bar, t0, smooth, tables)
    finally:
        wait([smooth, tables])
    tables.result()
    bar.update()
    bar.close()
    fig = ImageFigures(**{**fig, "time_s": round(time.perf_counter() - t0, 4)})
    fig.write(rs.run_dir)
    return fig


def _tables(run_dir: str, part, elements, radiance, st):
    """The light tables written (elements.csv, ...; black surfaces gathered:
    grids.black_irradiance) and the illuminance per sub-element and side (m, 2) lx, 0 where
    a side is not reported (the viewer's lux mode)."""
    t = light_tables(part, elements, radiance,
                     irradiance=black_irradiance(part, elements, radiance, st))
    fig = write_light_tables(run_dir, t)
    lux = np.zeros((len(part), 2))
    el = t.elements
    lux[el["element"], (el["side"] == "back").astype(np.int64)] = np.nan_to_num(el["illuminance"])
    return fig, lux


def _image_and_meshes(rs, st, part, elements, camera, k: int, raster, radiance, filter: str,
                      sigma: float, auto: bool, exposure, bar, t0: float, smooth,
                      tables=None) -> dict:
    """render_outputs' image, meshes and viewer (smooth: the future of the radiance at the
    mesh's vertices, smooth.smooth_mesh; tables: the future of _tables, whose illuminance the
    viewer's lux mode shows); returns its figures but the total time."""
    r = st.render
    per_side = 1
    if r.sampling == "area":
        # about area-samples^2 rays per pixel whatever the sub-pixel factor
        per_side = max(1, -(-int(r.area_samples) // k))
        from radiosity.tracing.rays import caster_of

        # the link stage's caster where this process built it (in-process workers)
        caster = caster_of(elements.verts, elements.nverts, float(st.rays.offset))
        raster_or_samples = sample_raster(part, elements, camera, k, per_side,
                                          float(st.rays.offset), caster=caster)
    else:
        raster_or_samples = raster
    lum = seen_radiance(part, elements, camera, radiance)
    fine = samples_radiance(lum, raster_or_samples)
    levels = []
    edge_side = max(0, -(-int(r.edge_samples) // k))
    if r.sampling == "area" and edge_side > per_side:
        # pixels on an edge, or over pieces of different brightness: more rays, adaptively
        levels = refine(part, elements, camera, k, lum, fine, raster_or_samples, edge_side,
                        caster)
    edges, edge_rays = (levels[0][1], levels[0][1] * levels[0][0] ** 2) if levels else (0, 0)
    img = downsample(fine, k, filter, sigma)
    e = auto_exposure(img) if auto else exposure
    t_image = time.perf_counter() - t0

    d = rs.run_dir
    paths = {name: os.path.join(d, name) for name in
             ("image.exr", "image.png", "mesh.glb", "mesh.ply", "viewer.html")}
    write_exr(paths["image.exr"], img)
    write_png(paths["image.png"], tonemap(img, e))
    bar.update()
    two = np.asarray(elements.two_sided, bool)[part.orig]
    smooth = smooth.result()  # radiance at vertices: mesh and viewer
    mesh = export_mesh(paths["mesh.glb"], paths["mesh.ply"], part, radiance, e, two_sided=two,
                       smooth=smooth)
    bar.update()
    title = rs.attrs.get("scene_name") or os.path.basename(d)
    viewer = write_viewer(paths["viewer.html"], part, radiance, e, title, camera=camera,
                          two_sided=two, smooth=smooth,
                          lux=None if tables is None else tables.result()[1])
    bar.update()
    return {
        "image_exr": paths["image.exr"], "image_png": paths["image.png"],
        "mesh_glb": paths["mesh.glb"], "mesh_ply": paths["mesh.ply"],
        "viewer_html": paths["viewer.html"],
        "exposure": float(e), "exposure_auto": bool(auto),
        "width": int(img.shape[1]), "height": int(img.shape[0]), "subpixel": k,
        "sampling": r.sampling, "area_samples": per_side,
        "rays": int(raster_or_samples.size) if r.sampling == "area" else 0,
        "edge_pixels": edges, "edge_rays": edge_rays,
        "refined": [[int(side), int(n)] for side, n in levels[1:]],
        "refined_rays": int(sum(n * side ** 2 for side, n in levels[1:])),
        "filter": filter, "sigma": sigma,
        "mean_radiance": [float(x) for x in img.reshape(-1, 3).mean(axis=0)],
        "hit_fraction": float(np.mean(raster >= 0)),
        "sub_elements": len(part), "triangles": mesh["triangles"], "mesh_faces": mesh["faces"],
        "viewer_triangles": viewer["triangles"], "viewer_stride": viewer["stride"],
        "time_image_s": round(t_image, 4),
    }


def previewer(run_dir: str):
    """A function (2, C, m) radiance -> small sRGB image (h, w, 3) uint8 of the run's camera
    view, for the dashboard's live preview while the solver runs. It reads no setting (box
    filter, automatic exposure)."""
    from radiosity.runtime.store import RunStore

    rs = RunStore(run_dir)
    if not rs.has("raster"):
        return lambda L: np.zeros((1, 1, 3), np.uint8)
    part, el = rs.load_partition(), rs.load_elements()
    sub = rs.read_arrays("raster")["sub"]
    camera = rs.load_camera()
    K = int(rs.attrs.get("subpixel", 1))

    def make(L):
        L = np.broadcast_to(L, (2, 3, L.shape[2]))
        rad = np.ascontiguousarray(np.transpose(L, (2, 0, 1)))
        return tonemap(downsample(pixel_radiance(part, el, camera, sub, rad), K, "box"))

    return make
