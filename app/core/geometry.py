"""Vectorised polygon geometry shared by the scene loader and the subdivision.

Polygons are `verts (n, 4, 3) float64` with `nverts (n,) int8` (a triangle repeats vertex 2 in
slot 3), counter-clockwise seen from the front.
"""

from __future__ import annotations

import numba
import numpy as np

from radiosity.core.tolerances import TOL


def tri_cross(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(b - a) x (c - a), row-wise; (n, 3)."""
    return np.cross(b - a, c - a)


def element_triangles(verts: np.ndarray, nverts: np.ndarray):
    """Triangles (t, 3, 3) of the elements and the element of each triangle (t,) int32."""
    quad = np.nonzero(nverts == 4)[0]
    tris = np.concatenate([verts[:, [0, 1, 2]], verts[quad][:, [0, 2, 3]]])
    owner = np.concatenate([np.arange(len(verts)), quad]).astype(np.int32)
    return tris, owner


def tangent_basis(n: np.ndarray):
    """Two unit vectors (k, 3) spanning the plane normal to each unit n (k, 3)."""
    ref = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(n, ref)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(n, t1)


def polygon_properties(verts: np.ndarray, nverts: np.ndarray):
    """Area (n,), unit normal (n, 3) and area centroid (n, 3) of triangles and convex quads.

    A quad is the two triangles (0, 1, 2) and (0, 2, 3); for a triangle the second is empty.
    One numba loop: numpy's dozen (n, 3) temporaries were fresh pages on first touch, many
    times slower for the same values to the bit (docs/src/measurements/choices.md).
    """
    verts = np.ascontiguousarray(verts, np.float64)
    n = len(verts)
    area, normal, center = np.empty(n), np.empty((n, 3)), np.empty((n, 3))
    _properties(verts.reshape(n, 4, 3), area, normal, center)
    return area, normal, center


@numba.njit(cache=True, nogil=True)
def _properties(verts, area, normal, center):
    for i in range(verts.shape[0]):
        v = verts[i]
        ax, ay, az = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
        bx, by, bz = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1], v[2, 2] - v[0, 2]
        cx, cy, cz = v[3, 0] - v[0, 0], v[3, 1] - v[0, 1], v[3, 2] - v[0, 2]
        p = (ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx)  # (1 - 0) x (2 - 0)
        q = (by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx)  # (2 - 0) x (3 - 0)
        a1 = 0.5 * np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
        a2 = 0.5 * np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
        area[i] = a1 + a2
        s = (p[0] + q[0], p[1] + q[1], p[2] + q[2])
        norm = np.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
        safe = area[i] if area[i] > 0 else 1.0
        for k in range(3):
            normal[i, k] = s[k] / (norm if norm > 0 else 1.0)
            g1 = (v[0, k] + v[1, k] + v[2, k]) / 3.0
            g2 = (v[0, k] + v[2, k] + v[3, k]) / 3.0
            center[i, k] = (g1 * a1 + g2 * a2) / safe


def diameter(verts: np.ndarray, nverts: np.ndarray | None = None) -> np.ndarray:
    """Largest vertex-to-vertex distance of each polygon (n, 4, 3), (n,) (a triangle's fourth
    slot repeats a vertex, so nverts is not needed)."""
    return _diameter(np.ascontiguousarray(verts, np.float64))


@numba.njit(cache=True, nogil=True)
def _diameter(verts):
    """diameter without (n, 4, 4, 3) temporaries: each norm sums the squares x, y, z left to
    right, as numpy's norm over the last axis does (the same values to the bit)."""
    n = verts.shape[0]
    out = np.empty(n)
    for p in range(n):
        m = 0.0
        for i in range(4):
            for j in range(i + 1, 4):
                dx = verts[p, i, 0] - verts[p, j, 0]
                dy = verts[p, i, 1] - verts[p, j, 1]
                dz = verts[p, i, 2] - verts[p, j, 2]
                d = np.sqrt(dx * dx + dy * dy + dz * dz)
                if d > m:
                    m = d
        out[p] = m
    return out


# |cos| below this (relative to the segment length) counts as coplanar (core.tolerances: cos)
COS_TOL = TOL.cos


def on_hull_planes(verts: np.ndarray, nverts: np.ndarray, normal: np.ndarray,
                   tol: float = 1e-7) -> np.ndarray:
    """(n,) bool: the polygons whose plane supports the convex hull of all the vertices (every
    vertex on one side, within tol times the hull's diagonal): the walls, floor and ceiling of a
    room. No open segment between two points of the polygons can cross such a polygon except
    within tol of its plane, i.e. when it runs in that plane from one end to the other, where
    it carries no light (tracing.rays.RayCaster leaves them out of segment queries)."""
    from scipy.spatial import ConvexHull, QhullError

    n = len(verts)
    if n == 0:
        return np.zeros(0, bool)
    V = np.concatenate([verts[nverts == 4].reshape(-1, 3), verts[nverts == 3][:, :3].reshape(-1, 3)])
    c = 0.5 * (V.min(0) + V.max(0))
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    try:
        H = V[ConvexHull(V - c).vertices]
    except (QhullError, ValueError):  # flat (or a line): every polygon lies in the one plane
        return np.ones(n, bool)
    offset = np.einsum("ij,ij->i", normal, verts[:, 0])
    return _supports(np.ascontiguousarray(normal, np.float64), offset, np.ascontiguousarray(H),
                     tol * diag)


@numba.njit(cache=True, nogil=True)
def _supports(normal, offset, H, tol):
    """Is every point of H within tol of one side of each plane (normal[i], offset[i])? Stops
    at the first point on each side."""
    out = np.zeros(normal.shape[0], np.bool_)
    for i in range(normal.shape[0]):
        above = False
        below = False
        for h in range(H.shape[0]):
            s = normal[i, 0] * H[h, 0] + normal[i, 1] * H[h, 1] + normal[i, 2] * H[h, 2] - offset[i]
            if s > tol:
                above = True
            elif s < -tol:
                below = True
            if above and below:
                break
        out[i] = not (above and below)
    return out
