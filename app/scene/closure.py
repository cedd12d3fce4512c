"""Is the scene a closed enclosure? Decided from the geometry, for the solver's row handling.

Design notes and measurements: docs/src/design/scene-closure.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radiosity.core.kernels import Sampling, sample_points
from radiosity.tracing.rays import RayCaster
from radiosity.core.bundles import Elements

POINTS = 16       # stratified points per element (nxm cells)
DIRECTIONS = 16   # cosine-weighted directions per point and side
LEAK = 1e-4       # fraction of rays that may escape through cracks in a closed scene
MAX_RAYS = 1 << 22  # beyond this many, fewer points per element (a square: 9, 4, 1); a mesh of
                    # many small elements samples its hemisphere through their number instead


@dataclass(frozen=True)
class Closure:
    """closed: the decision; escaped: rays that escaped; rays: rays cast; worst: the element
    that lost the largest fraction (-1: none) and that fraction; reason: one line."""

    closed: bool
    escaped: int
    rays: int
    worst: int
    worst_fraction: float
    reason: str

    def to_dict(self) -> dict:
        return {"closed": self.closed, "escaped_rays": self.escaped, "rays": self.rays,
                "worst_element": self.worst, "worst_escaped_fraction": self.worst_fraction,
                "reason": self.reason}


def _directions(k: int, rng) -> np.ndarray:
    """k cosine-weighted unit directions around +z, stratified in sqrt(k) x sqrt(k) cells."""
    s = int(np.ceil(np.sqrt(k)))
    i, j = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    u = (i.ravel() + rng.random(s * s)) / s
    v = (j.ravel() + rng.random(s * s)) / s
    r, phi = np.sqrt(u), 2 * np.pi * v
    d = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1 - u))], 1)
    return d[:k]


def _frame(n: np.ndarray):
    """Two unit tangents (k, 3) orthogonal to unit normals n (k, 3)."""
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t = np.cross(n, a)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t)


def detect_closure(elements: Elements, epsilon: float, points: int = POINTS,
                   directions: int = DIRECTIONS, leak: float = LEAK, seed: int = 0) -> Closure:
    """The closure test above; epsilon: the ray offset (radiosity.rays.epsilon)."""
    n = len(elements)
    while points > 1 and n * points * directions > MAX_RAYS:
        points = (int(round(np.sqrt(points))) - 1) ** 2
    rc = RayCaster(elements.verts, elements.nverts, epsilon)
    pts, _ = sample_points(elements.verts, elements.nverts, Sampling("nxm", points))
    rng = np.random.default_rng(seed)
    lost = np.zeros(n)
    cast = np.zeros(n)
    lo = elements.verts.reshape(-1, 3).min(0)
    hi = elements.verts.reshape(-1, 3).max(0)
    step = 1e3 * epsilon * float(np.linalg.norm(hi - lo))  # off the surface, beyond rounding
    for side in (1.0, -1.0):
        ids = np.arange(n) if side > 0 else np.nonzero(elements.two_sided)[0]
        if not len(ids):
            continue
        loc = _directions(directions, rng)                           # (D, 3)
        # elements in batches of about 1 M rays: memory stays bounded however many there are
        batch = max(1, (1 << 20) // (pts.shape[1] * directions))
        for s0 in range(0, len(ids), batch):
            sub = ids[s0:s0 + batch]
            nrm = side * elements.normal[sub]
            t1, t2 = _frame(nrm)
            dirs = (loc[None, :, :1] * t1[:, None] + loc[None, :, 1:2] * t2[:, None]
                    + loc[None, :, 2:] * nrm[:, None])                  # (k, D, 3)
            o = pts[sub][:, :, None, :] + step * nrm[:, None, None, :]  # (k, P, 1, 3)
            o = np.broadcast_to(o, (len(sub), pts.shape[1], directions, 3)).reshape(-1, 3)
            d = np.broadcast_to(dirs[:, None], (len(sub), pts.shape[1], directions, 3)).reshape(-1, 3)
            hit = rc.first_hit(np.ascontiguousarray(o), np.ascontiguousarray(d))
            # a hit on a one-sided element from behind is black: the light is lost there too
            back = np.zeros(len(hit), bool)
            h = hit >= 0
            back[h] = (np.einsum("ij,ij->i", elements.normal[hit[h]], d[h]) > 0) & \
                ~elements.two_sided[hit[h]]
            # a point whose every ray meets a back face lies inside a solid (the part of a floor
            # under a block standing on it): it takes no part in the transport, and is not counted
            P = pts.shape[1]
            miss = (~h).reshape(len(sub), P, directions)
            back = back.reshape(len(sub), P, directions)
            buried = back.all(axis=2)
            esc = np.where(buried[..., None], False, miss | back).sum(axis=(1, 2))
            np.add.at(lost, sub, esc)
            np.add.at(cast, sub, (~buried).sum(axis=1) * directions)
    frac = lost / np.maximum(cast, 1)
    worst = int(np.argmax(frac)) if n else -1
    total, escaped = int(cast.sum()), int(lost.sum())
    closed = escaped <= leak * total
    if closed:
        reason = (f"closed: {escaped} of {total} hemisphere rays from the {n} original elements "
                  "escape (an enclosure): rows balanced to exactly 1, reciprocity kept")
    else:
        reason = (f"open: {escaped} of {total} hemisphere rays escape ({escaped / max(total, 1):.1%}; "
                  f"most from {elements.describe(worst)}, {frac[worst]:.0%} of its rays): rows "
                  "are not balanced, only capped at 1")
    return Closure(closed, escaped, total, worst if escaped else -1,
                   float(frac[worst]) if n else 0.0, reason)
