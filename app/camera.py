"""The seed's camera (seed §2.1, SPEC §3): rays from the centre through pixel centres."""

from __future__ import annotations

import numpy as np

from .types import Camera


def pixel_directions(camera: Camera, subpixel: int = 1, rows: slice | None = None) -> np.ndarray:
    """Unit directions of the rays through the pixel centres of the K-times finer raster.

    Returns (h * w, 3) float64 in row-major order (row 0 at the top), for the raster of
    `camera.height * subpixel` rows and `camera.width * subpixel` columns, restricted to `rows`.
    """
    w, h = camera.width * subpixel, camera.height * subpixel
    r = np.arange(h)[rows] if rows is not None else np.arange(h)
    c = np.arange(w)
    u = camera.half_w * (2.0 * (c + 0.5) / w - 1.0)
    v = camera.half_h * (1.0 - 2.0 * (r + 0.5) / h)
    d = (camera.focal * camera.z[None, None, :] + u[None, :, None] * camera.x[None, None, :]
         + v[:, None, None] * camera.y[None, None, :])
    d = d.reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def project(camera: Camera, points: np.ndarray, subpixel: int = 1):
    """World points (n, 3) -> fractional pixel coordinates (col, row) on the K-times raster, and depth.

    The inverse of `pixel_directions`: pixel centres land on integer + 0.5.
    """
    d = points - camera.center
    zc = d @ camera.z
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.focal * (d @ camera.x) / zc
        v = camera.focal * (d @ camera.y) / zc
    w, h = camera.width * subpixel, camera.height * subpixel
    col = (u / camera.half_w + 1.0) * 0.5 * w
    row = (1.0 - v / camera.half_h) * 0.5 * h
    return col, row, zc
