"""Contact: element sides covered by a coincident or touching surface (a table leg's top face
lying on the underside of the table top, a shelf's bottom on the floor, two boxes pressed
together). Such a side sees nothing but the surface lying on it; it takes no part in the
transport (it neither receives nor sends) and is left out of the closure statistics
(closure.py). Design notes and measurements: docs/src/design/scene-closure.md.

The test is one short ray per sample point and side, along the side's normal, against the
elements that face the other way: from p + w n towards -n, a hit within 2 w (w: the contact
window, relative to the scene's size) is a surface within w in front of the point, coincident
with it, or at most w behind it (a slight interpenetration). The elements are split in two
Embree scenes by the sign of their normal against a fixed generic direction, so that a side's
ray is cast only into the scene of the elements that face it: the side's own element (and
every coplanar neighbour facing the same way, which ties with a coincident cover at the same
distance) is never there. Two-sided elements are in both scenes. Nothing is O(n^2).
"""

from __future__ import annotations

import numpy as np

from radiosity.core.bundles import Elements
from radiosity.tracing.rays import RayCaster

#: A generic direction: no axis-aligned or 45-degree normal is perpendicular to it.
_G = np.array([0.5773502, 0.6123724, 0.5400617])
WINDOW = 5e-5       # the contact window w, relative to the scene's bounding-box diagonal
FACING = -0.5       # a cover's normal against the side's: at most this (roughly opposite)
COVERED = 0.999     # a side is a contact side when this fraction of its points is covered


def scene_scale(elements: Elements) -> float:
    """The diagonal of the elements' bounding box (1 for an empty scene)."""
    v = elements.verts.reshape(-1, 3)
    return float(np.linalg.norm(v.max(0) - v.min(0))) if len(v) else 1.0


def contact_points(elements: Elements, pts: np.ndarray, epsilon: float,
                   window: float = WINDOW) -> np.ndarray:
    """Which sample points are covered, (n, P, 2) bool [element, point, side]: pts (n, P, 3)
    on the elements; side 0 the front, 1 the back (two-sided elements only; one-sided backs
    are never covered: they take no part anyway). window: relative to the scene's size."""
    n, P = pts.shape[:2]
    out = np.zeros((n, P, 2), bool)
    if not n or not P:
        return out
    w = window * scene_scale(elements)
    nrm = elements.normal
    pos = nrm @ _G > 0
    ts = elements.two_sided.astype(bool)
    groups = {}
    for key, members in ((True, pos | ts), (False, ~pos | ts)):
        ids = np.nonzero(members)[0]
        if len(ids):
            groups[key] = (ids, RayCaster(elements.verts[ids], elements.nverts[ids], epsilon))
    for side in (0, 1):
        els = np.arange(n) if side == 0 else np.nonzero(ts)[0]
        if not len(els):
            continue
        sn = nrm[els] * (1.0 if side == 0 else -1.0)           # the side's normal
        facing_pos = (sn @ _G) <= 0                            # covers face -sn: their class
        for key in (True, False):
            sel = np.nonzero(facing_pos == key)[0]
            if not len(sel) or key not in groups:
                continue
            ids, rc = groups[key]
            e = els[sel]
            d = -np.repeat(sn[sel], P, axis=0)
            o = pts[e].reshape(-1, 3) - w * d
            hit, t = rc.first_hit(np.ascontiguousarray(o), np.ascontiguousarray(d), distances=True)
            ok = (hit >= 0) & (t <= 2 * w)
            b = ids[np.maximum(hit, 0)]
            ok &= b != np.repeat(e, P)
            cosb = np.einsum("ij,ij->i", nrm[b], -d)          # cover normal . side normal
            ok &= (cosb <= FACING) | (ts[b] & (cosb >= -FACING))
            out[e, :, side] = ok.reshape(len(e), P)
    return out


def find_contacts(elements: Elements, epsilon: float, points: int = 16,
                  window: float = WINDOW) -> np.ndarray:
    """Contact sides (n, 2) bool [front, back]: sides of which at least COVERED of `points`
    stratified sample points are covered (contact_points)."""
    from radiosity.core.kernels import Sampling, sample_points

    pts, _ = sample_points(elements.verts, elements.nverts, Sampling("nxm", points))
    return contact_points(elements, pts, epsilon, window).mean(axis=1) >= COVERED
