"""Calculation grids (issue 52): the points where a lighting engineer asks for illuminance,
seen by a camera or not. A scene file's `[[grid]]` tables (docs/src/reference/scenes.md):

- `name`; `origin`, `u`, `v` (the grid's corner and its two edges, scene units) with `spacing`
  (a scalar or [su, sv]: points at the centres of the cells, ceil(|u| / su) x ceil(|v| / sv)
  cells spread evenly over the edges), or `points = "file.csv"` (a header `x,y,z,nx,ny,nz`,
  one point a line, relative to the scene file);
- `normal` (default u x v, normalised): the side the light is measured on;
- `maintenance_factor` (default the scene's top-level `maintenance_factor`, else 1): the
  lighting engineer's MF, which scales the grid's computed illuminance (nothing else).

`grid_points(table, base)` turns one table into (points, normals) arrays: the one function
other tools (a Radiance reference) call to get the same points.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numba
import numpy as np

from radiosity.core.exact import point_ff
from radiosity.errors import SceneError

GRID_KEYS = {"name", "origin", "u", "v", "spacing", "points", "normal", "maintenance_factor"}
#: Points per grid at most (a grid is an output, not a mesh: 1000 x 1000).
MAX_POINTS = 1_000_000
#: Directions of the inside-a-solid test: the axes and the diagonals, both ways.
_AXES = np.concatenate([np.eye(3), -np.eye(3), np.array(
    [[a, b, c] for a in (1, -1) for b in (1, -1) for c in (1, -1)], float) / math.sqrt(3)])


@dataclass(frozen=True)
class Grid:
    """One calculation grid: points (k, 3) and unit normals (k, 3) float64; shape (nu, nv) for
    a regular grid (points in row-major order, u the slow axis), () for a point file;
    maintenance_factor scales its illuminance."""

    name: str
    points: np.ndarray
    normals: np.ndarray
    shape: tuple = ()
    maintenance_factor: float = 1.0
    origin: tuple = ()
    u: tuple = ()
    v: tuple = ()


def _vec(val, what: str, where: str) -> np.ndarray:
    try:
        a = np.asarray(val, np.float64).reshape(3)
    except (TypeError, ValueError):
        raise SceneError(f"{where}: {what} must be three numbers, got {val!r}") from None
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{where}: {what} must be finite, got {val!r}")
    return a


def _positive(val, what: str, where: str) -> float:
    try:
        x = float(val)
    except (TypeError, ValueError):
        raise SceneError(f"{where}: {what} must be a number, got {val!r}") from None
    if not (x > 0 and math.isfinite(x)):
        raise SceneError(f"{where}: {what} must be a positive number, got {val!r}")
    return x


def _read_points(fn: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(points, normals) of a grid's point file: header x,y,z,nx,ny,nz, then one point a line."""
    try:
        with open(fn) as f:
            head = [h.strip().lower() for h in f.readline().split(",")]
            rows = [ln for ln in f.read().splitlines() if ln.strip()]
    except OSError as e:
        raise SceneError(f"{where}: cannot read points file {fn}: {e.strerror}") from None
    if head != ["x", "y", "z", "nx", "ny", "nz"]:
        raise SceneError(f"{where}: {fn} must start with the header x,y,z,nx,ny,nz")
    try:
        a = np.array([[float(x) for x in r.split(",")] for r in rows], np.float64).reshape(-1, 6)
    except ValueError:
        raise SceneError(f"{where}: {fn}: every line must hold six numbers x,y,z,nx,ny,nz") \
            from None
    if not len(a):
        raise SceneError(f"{where}: {fn} holds no points")
    return a[:, :3], a[:, 3:]


def grid_points(table: dict, base: str = ".", where: str = "[[grid]]") -> tuple[np.ndarray,
                                                                             np.ndarray]:
    """(points (k, 3), unit normals (k, 3)) float64 of one [[grid]] table (module docstring);
    base: the folder `points` files are relative to. Bad keys raise SceneError (one line)."""
    return _build(table, base, where)[:2]


def _build(table: dict, base: str, where: str):
    unknown = set(table) - GRID_KEYS
    if unknown:
        raise SceneError(f"{where} has unknown key(s) {sorted(unknown)}; allowed: "
                         f"{sorted(GRID_KEYS)}")
    shape, frame = (), ((), (), ())
    if "points" in table:
        if "spacing" in table or "origin" in table:
            raise SceneError(f"{where}: give either points = \"file.csv\" or origin, u, v and "
                             "spacing, not both")
        P, N = _read_points(os.path.join(base, str(table["points"])), where)
        if "normal" in table:
            N = np.broadcast_to(_vec(table["normal"], "normal", where), P.shape).copy()
    else:
        missing = [k for k in ("origin", "u", "v", "spacing") if k not in table]
        if missing:
            raise SceneError(f"{where}: missing {', '.join(missing)} (or give points = "
                             "\"file.csv\")")
        o = _vec(table["origin"], "origin", where)
        u = _vec(table["u"], "u", where)
        v = _vec(table["v"], "v", where)
        sp = table["spacing"]
        sp = list(sp) if isinstance(sp, (list, tuple)) else [sp, sp]
        if len(sp) != 2:
            raise SceneError(f"{where}: spacing must be one number or two, got {table['spacing']!r}")
        su, sv = (_positive(s, "spacing", where) for s in sp)
        lu, lv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        if lu <= 0 or lv <= 0 or np.linalg.norm(np.cross(u, v)) <= 1e-12 * lu * lv:
            raise SceneError(f"{where}: u and v must be two edges that are not parallel")
        nu, nv = max(1, math.ceil(lu / su - 1e-9)), max(1, math.ceil(lv / sv - 1e-9))
        if nu * nv > MAX_POINTS:
            raise SceneError(f"{where}: {nu} x {nv} points is more than {MAX_POINTS}: raise "
                             "spacing")
        a = (np.arange(nu) + 0.5) / nu
        b = (np.arange(nv) + 0.5) / nv
        P = o + a[:, None, None] * u + b[None, :, None] * v
        P = P.reshape(-1, 3)
        n = np.cross(u, v)
        if "normal" in table:
            n = _vec(table["normal"], "normal", where)
        N = np.broadcast_to(n, P.shape).copy()
        shape, frame = (nu, nv), (tuple(o), tuple(u), tuple(v))
    ln = np.linalg.norm(N, axis=1, keepdims=True)
    if not np.all(ln > 0):
        raise SceneError(f"{where}: a normal is zero")
    return np.ascontiguousarray(P), np.ascontiguousarray(N / ln), shape, frame


def parse_grids(doc: dict, path: str) -> tuple:
    """The Grids of a scene (or grid) TOML document `doc` read from `path`: its [[grid]]
    tables, names unique; the top-level maintenance_factor is every grid's default."""
    tables = doc.get("grid", [])
    if isinstance(tables, dict):
        tables = [tables]
    if not isinstance(tables, list):
        raise SceneError(f"{path}: [[grid]] must be a list of tables")
    mf0 = doc.get("maintenance_factor", 1.0)
    base = os.path.dirname(os.path.abspath(path))
    out, names = [], set()
    for i, t in enumerate(tables):
        if not isinstance(t, dict):
            raise SceneError(f"{path}: [[grid]] {i + 1} must be a table")
        name = str(t.get("name", f"grid{i + 1}"))
        where = f"{path}: [[grid]] {name!r}"
        if not name or not all(c.isalnum() or c in "-_" for c in name):
            raise SceneError(f"{where}: use letters, digits, - and _ in the name")
        if name in names:
            raise SceneError(f"{where}: the name is used twice")
        names.add(name)
        P, N, shape, frame = _build(t, base, where)
        mf = _positive(t.get("maintenance_factor", mf0), "maintenance_factor", where)
        if mf > 1:
            raise SceneError(f"{where}: maintenance_factor must be in (0, 1], got {mf}")
        out.append(Grid(name, P, N, shape, mf, *frame))
    return tuple(out)


def check_grids(grids, elements, caster, path: str = "") -> None:
    """One clear line (SceneError) for a grid with a point outside the model: outside the box of
    the scene's elements (with a margin of 1e-6 of its size), or inside a solid (more than half
    of 14 rays from the point, along the axes and the diagonals, meet the back of a one-sided
    element: a box standing open side down on the floor is a solid too)."""
    if not grids:
        return
    V = elements.verts.reshape(-1, 3)
    lo, hi = V.min(0), V.max(0)
    pad = 1e-6 * float(np.ptp(V, axis=0).max() or 1.0)
    two = np.asarray(elements.two_sided, bool)
    for g in grids:
        where = f"{path + ': ' if path else ''}[[grid]] {g.name!r}"
        out = np.any((g.points < lo - pad) | (g.points > hi + pad), axis=1)
        if out.any():
            p = g.points[int(np.argmax(out))]
            raise SceneError(f"{where}: point {np.round(p, 6).tolist()} is outside the model "
                             f"(its box is {np.round(lo, 6).tolist()} .. "
                             f"{np.round(hi, 6).tolist()})")
        P = g.points + 1e-6 * (hi - lo).max() * g.normals
        k = len(P)
        o = np.repeat(P, len(_AXES), axis=0)
        d = np.tile(_AXES, (k, 1))
        e = caster.first_hit(o, d)
        e = np.asarray(e[0] if isinstance(e, tuple) else e, np.int64)
        hit = e >= 0
        ee = np.maximum(e, 0)
        back = hit & ~two[ee] & (np.einsum("kd,kd->k", d, elements.normal[ee]) > 0)
        inside = 2 * back.reshape(k, len(_AXES)).sum(axis=1) > len(_AXES)
        if inside.any():
            p = g.points[int(np.argmax(inside))]
            raise SceneError(f"{where}: point {np.round(p, 6).tolist()} is inside a solid of "
                             "the model (most rays from it meet the backs of faces)")


# ----------------------------------------------------------------------------- indirect light

@numba.njit(cache=True, nogil=True)
def point_form_factors(P, N, V, nv, center, normal, area, Lr, far, F, S):
    """F[i, j] (p, m): the form factor from a differential element at point P[i] (unit normal
    N[i]) to polygon j (V (m, 4, 3), nv (m,)), 0 where polygon j shows P[i] a side whose
    reflected radiance Lr[j, side] (m, 2, 3) is zero; S[i, j] the side it shows (0 front).
    Exact (point-to-polygon contour integral, clipped to the point's horizon) within `far`
    times the polygon's size (sqrt of its area), the point-to-disc kernel beyond."""
    Qc = np.empty((2 * V.shape[1] + 2, 3))
    far2 = far * far
    for j in range(V.shape[0]):
        a = V[j, 0]
        for i in range(P.shape[0]):
            s = ((P[i, 0] - a[0]) * normal[j, 0] + (P[i, 1] - a[1]) * normal[j, 1]
                 + (P[i, 2] - a[2]) * normal[j, 2])
            if s == 0.0:
                continue
            side = 0 if s > 0.0 else 1
            if Lr[j, side, 0] <= 0.0 and Lr[j, side, 1] <= 0.0 and Lr[j, side, 2] <= 0.0:
                continue
            dx = center[j, 0] - P[i, 0]
            dy = center[j, 1] - P[i, 1]
            dz = center[j, 2] - P[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > far2 * area[j]:
                r = math.sqrt(d2)
                ci = (N[i, 0] * dx + N[i, 1] * dy + N[i, 2] * dz) / r
                cj = abs(normal[j, 0] * dx + normal[j, 1] * dy + normal[j, 2] * dz) / r
                f = area[j] * ci * cj / (math.pi * d2) if ci > 0.0 else 0.0
            else:
                f = point_ff(P[i, 0], P[i, 1], P[i, 2], N[i, 0], N[i, 1], N[i, 2], V[j], nv[j],
                             Qc)
            if f > 0.0:
                F[i, j] = f
                S[i, j] = side
