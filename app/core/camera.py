"""The seed's camera (seed §2.1, SPEC §3): rays from the centre through pixel centres."""

from __future__ import annotations

import numba
import numpy as np

from radiosity.core.bundles import Camera


@numba.njit(cache=True, nogil=True)
def _pixel_dir(cam, w, h, row, col):
    """Unit float64 direction through the centre of pixel (row, col) of a w x h raster.

    cam = [x(3), y(3), z(3), focal, half_w, half_h] as one float64 array (few signatures).
    """
    u = cam[10] * (2.0 * (col + 0.5) / w - 1.0)
    v = cam[11] * (1.0 - 2.0 * (row + 0.5) / h)
    dx = cam[9] * cam[6] + u * cam[0] + v * cam[3]
    dy = cam[9] * cam[7] + u * cam[1] + v * cam[4]
    dz = cam[9] * cam[8] + u * cam[2] + v * cam[5]
    n = np.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / n, dy / n, dz / n


@numba.njit(cache=True, nogil=True)
def _directions32(cam, w, h, r0, r1):
    out = np.empty(((r1 - r0) * w, 3), np.float32)
    k = 0
    for r in range(r0, r1):
        for c in range(w):
            dx, dy, dz = _pixel_dir(cam, w, h, r, c)
            out[k, 0] = dx
            out[k, 1] = dy
            out[k, 2] = dz
            k += 1
    return out


@numba.njit(cache=True, nogil=True)
def _hit_points(cam, origin, w, h, r0, elem, normal, center):
    """Exact float64 intersection of pixel k's ray with the plane of the element it hit."""
    n = elem.shape[0]
    out = np.zeros((n, 3))
    for k in range(n):
        e = elem[k]
        if e < 0:
            continue
        dx, dy, dz = _pixel_dir(cam, w, h, r0 + k // w, k % w)
        num = (normal[e, 0] * (center[e, 0] - origin[0]) + normal[e, 1] * (center[e, 1] - origin[1])
               + normal[e, 2] * (center[e, 2] - origin[2]))
        t = num / (normal[e, 0] * dx + normal[e, 1] * dy + normal[e, 2] * dz)
        out[k, 0] = origin[0] + t * dx
        out[k, 1] = origin[1] + t * dy
        out[k, 2] = origin[2] + t * dz
    return out


def _packed(camera: Camera) -> np.ndarray:
    return np.concatenate([camera.x, camera.y, camera.z,
                           [camera.focal, camera.half_w, camera.half_h]]).astype(np.float64)


def ray_directions32(camera: Camera, subpixel: int, r0: int, r1: int) -> np.ndarray:
    """Unit float32 directions (n, 3) of fine-raster rows r0:r1, for Embree."""
    return _directions32(_packed(camera), camera.width * subpixel, camera.height * subpixel, r0, r1)


def hit_points(camera: Camera, subpixel: int, r0: int, elem: np.ndarray, normal: np.ndarray,
               center: np.ndarray) -> np.ndarray:
    """Exact (float64) hit points (n, 3) of the rays of rows r0.. on the planes of `elem` (n,).

    Embree finds *which* element (float32); the point is recomputed in float64 from the
    element's plane, so the subdivision depends neither on Embree's rounding nor on scale.
    """
    return _hit_points(_packed(camera), np.asarray(camera.center, np.float64), camera.width * subpixel,
                       camera.height * subpixel, r0, np.ascontiguousarray(elem, np.int32),
                       np.ascontiguousarray(normal, np.float64), np.ascontiguousarray(center, np.float64))


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
