"""Vectorised polygon geometry shared by the scene loader and the subdivision.

Polygons are `verts (n, 4, 3) float64` with `nverts (n,) int8` (a triangle repeats vertex 2 in
slot 3), counter-clockwise seen from the front.
"""

from __future__ import annotations

import numpy as np


def tri_cross(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(b - a) x (c - a), row-wise; (n, 3)."""
    return np.cross(b - a, c - a)


def polygon_properties(verts: np.ndarray, nverts: np.ndarray):
    """Area (n,), unit normal (n, 3) and area centroid (n, 3) of triangles and convex quads.

    A quad is the two triangles (0, 1, 2) and (0, 2, 3); for a triangle the second is empty.
    """
    v0, v1, v2, v3 = verts[:, 0], verts[:, 1], verts[:, 2], verts[:, 3]
    c1 = tri_cross(v0, v1, v2)
    c2 = tri_cross(v0, v2, v3)  # zero for triangles (v3 == v2)
    a1 = 0.5 * np.linalg.norm(c1, axis=1)
    a2 = 0.5 * np.linalg.norm(c2, axis=1)
    area = a1 + a2
    n = c1 + c2
    norm = np.linalg.norm(n, axis=1)
    normal = n / np.where(norm > 0, norm, 1.0)[:, None]
    g1 = (v0 + v1 + v2) / 3.0
    g2 = (v0 + v2 + v3) / 3.0
    safe = np.where(area > 0, area, 1.0)
    center = (g1 * a1[:, None] + g2 * a2[:, None]) / safe[:, None]
    return area, normal, center


def diameter(verts: np.ndarray, nverts: np.ndarray) -> np.ndarray:
    """Largest vertex-to-vertex distance of each polygon, (n,)."""
    d = np.linalg.norm(verts[:, :, None, :] - verts[:, None, :, :], axis=-1)
    return d.reshape(len(verts), -1).max(axis=1)


# |cos| below this (relative to the segment length) counts as coplanar: exactly zero, not noise.
# One value for every stage that asks "do these two elements face each other?" (visibility,
# shafts, near field), so that they all agree on which pairs exist.
COS_TOL = 1e-9
