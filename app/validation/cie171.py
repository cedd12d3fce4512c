"""CIE 171:2006-style analytic test cases (issue 52) and their exact answers, point by point:
the scenes are scenes/cie171/ (make_scenes.py), the answers computed here by means independent
of the code under test (Howell's closed form B-3, midpoint quadrature over the source or the
reflecting floor, the energy balance of a closed room).

All cases share a 4 x 4 (x, y) room, a 1 x 1 m Lambertian source [1.5, 2.5]^2 in its ceiling,
facing down, of grey radiance LE; illuminance = EFFICACY x irradiance (grey: Y = E).
"""

from __future__ import annotations

import math
import os

import numpy as np

from radiosity.core.colour import EFFICACY
from radiosity.core.exact import differential_to_rectangle

LE = 10.0
SOURCE = (1.5, 2.5, 1.5, 2.5)
#: The plate of the obstruction case: [x0, x1] x [y0, y1] at height z.
PLATE = (2.0, 3.0, 1.5, 2.5, 1.5)
#: Reflectance of the floor in the diffuse-reflection case.
FLOOR_RHO = 0.5
#: Reflectances of the interreflection (closed cube) cases.
INTERREFLECTION = (0.2, 0.5, 0.8, 0.95)
CASES = ("area-source", "diffuse-reflection", "obstruction",
         *(f"interreflection-{round(r * 100):02d}" for r in INTERREFLECTION))


def scene_dir(root: str, case: str) -> str:
    return os.path.join(root, "scenes", "cie171", case)


def rect_ff(px, py, c, rect=SOURCE) -> np.ndarray:
    """F from points (px, py) facing up to the parallel rectangle `rect` c above them (Howell
    B-3 by superposition of the corner rectangles)."""
    x0, x1, y0, y1 = rect
    px, py = np.asarray(px, float), np.asarray(py, float)

    def g(a, b):
        return np.sign(a) * np.sign(b) * differential_to_rectangle(np.abs(a), np.abs(b), c)
    return g(x1 - px, y1 - py) - g(x0 - px, y1 - py) - g(x1 - px, y0 - py) + g(x0 - px, y0 - py)


def source_ff(p, n, height: float, k: int = 600, plate=None) -> float:
    """F from point p (unit normal n) to the source (at z = height, facing down) by the midpoint
    rule on k x k cells; with `plate` (x0, x1, y0, y1, z) the segments through it count 0."""
    x0, x1, y0, y1 = SOURCE
    t = (np.arange(k) + 0.5) / k
    X, Y = np.meshgrid(x0 + (x1 - x0) * t, y0 + (y1 - y0) * t, indexing="ij")
    d = np.stack([X - p[0], Y - p[1], np.full_like(X, height - p[2])], -1)
    r2 = np.sum(d * d, -1)
    ci = np.clip(d @ np.asarray(n, float), 0, None) / np.sqrt(r2)
    cj = d[..., 2] / np.sqrt(r2)
    f = ci * cj / (math.pi * r2)
    if plate is not None:
        a0, a1, b0, b1, z = plate
        s = (z - p[2]) / d[..., 2]
        cx, cy = p[0] + s * d[..., 0], p[1] + s * d[..., 1]
        f = np.where((s > 0) & (s < 1) & (cx > a0) & (cx < a1) & (cy > b0) & (cy < b1), 0.0, f)
    return float(f.sum() * (x1 - x0) * (y1 - y0) / k ** 2)


def floor_reflection(p, n, height: float = 3.0, k: int = 400, size: float = 4.0) -> float:
    """Irradiance at point p (unit normal n) from the floor [0, size]^2 (z = 0, reflectance
    FLOOR_RHO, lit by the source `height` above it): rho / pi E_floor(y) cos cos / r^2 over
    the floor by the midpoint rule on k x k cells, E_floor exact (B-3)."""
    t = (np.arange(k) + 0.5) / k * size
    X, Y = np.meshgrid(t, t, indexing="ij")
    E = math.pi * LE * rect_ff(X, Y, height)
    d = np.stack([X - p[0], Y - p[1], -np.full_like(X, p[2])], -1)
    r2 = np.sum(d * d, -1)
    ci = np.clip(d @ np.asarray(n, float), 0, None) / np.sqrt(r2)
    cj = p[2] / np.sqrt(r2)
    L = FLOOR_RHO * E / math.pi
    return float(np.sum(L * ci * cj / r2) * (size / k) ** 2)


def reference(case: str, grid: str, P: np.ndarray, N: np.ndarray) -> np.ndarray:
    """(k,) lx: the exact illuminance at points P (k, 3), unit normals N (k, 3) of `grid` in
    `case` (the interreflection cases have no per-point answer: NaN)."""
    if case == "area-source":
        if grid == "floor":
            return EFFICACY * math.pi * LE * rect_ff(P[:, 0], P[:, 1], 3.0 - P[:, 2])
        return np.array([EFFICACY * math.pi * LE * source_ff(p, n, 3.0) for p, n in zip(P, N)])
    if case == "obstruction":
        return np.array([EFFICACY * math.pi * LE * source_ff(p, n, 3.0, k=1000, plate=PLATE)
                         for p, n in zip(P, N)])
    if case == "diffuse-reflection":
        direct = np.array([math.pi * LE * source_ff(p, n, 3.0) for p, n in zip(P, N)])
        return EFFICACY * (direct + np.array([floor_reflection(p, n) for p, n in zip(P, N)]))
    return np.full(len(P), np.nan)


def closed_room_mean_indirect(rho: float, side: float = 4.0) -> float:
    """lx: the mean illuminance from reflected light over all the surfaces of a closed room of
    uniform reflectance rho lit by the source (flux Phi = pi LE x 1 m^2): rho Phi / (S (1 -
    rho)), S = 6 side^2 (every bounce's flux lands inside: exact whatever the shape)."""
    phi = math.pi * LE * 1.0
    return EFFICACY * rho * phi / (6 * side * side * (1 - rho))
