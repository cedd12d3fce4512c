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
from radiosity.core.tolerances import TOL
from radiosity.tracing.rays import RayCaster

#: A generic direction: no axis-aligned or 45-degree normal is perpendicular to it.
_G = np.array([0.5773502, 0.6123724, 0.5400617])
FACING = -0.5       # a cover's normal against the side's: at most this (roughly opposite)
COVERED = 0.999     # a side is a contact side when this fraction of its points is covered


def scene_scale(elements: Elements) -> float:
    """The diagonal of the elements' bounding box (1 for an empty scene)."""
    v = elements.verts.reshape(-1, 3)
    return float(np.linalg.norm(v.max(0) - v.min(0))) if len(v) else 1.0


def contact_points(elements: Elements, pts: np.ndarray, ray_offset: float,
                   window: float = TOL.contact_window) -> np.ndarray:
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
            groups[key] = (ids, RayCaster(elements.verts[ids], elements.nverts[ids],
                                          ray_offset))
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


def find_contacts(elements: Elements, ray_offset: float, points: int = 16,
                  window: float = TOL.contact_window) -> np.ndarray:
    """Contact sides (n, 2) bool [front, back]: sides of which at least COVERED of `points`
    stratified sample points are covered (contact_points)."""
    from radiosity.core.kernels import Sampling, sample_points

    pts, _ = sample_points(elements.verts, elements.nverts, Sampling("nxm", points))
    return contact_points(elements, pts, ray_offset, window).mean(axis=1) >= COVERED


#: Hemisphere rays per point of the inside-a-solid test (inside_solid), stratified.
SOLID_RAYS = 8


#: and this many grazing ones, GRAZING degrees off the normal: a thin gap (a one-sided panel
#: hung close under a ceiling) lets them out where the cosine-weighted ones all meet its back.
SOLID_GRAZING = 4
GRAZING = 85.0


def _solid_directions(k: int) -> np.ndarray:
    """k fixed cosine-weighted directions around +z, one per cell of a ceil(sqrt k)^2 grid, then
    SOLID_GRAZING grazing ones."""
    s = int(np.ceil(np.sqrt(k)))
    i, j = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    u, v = (i.ravel() + 0.5) / s, (j.ravel() + 0.5) / s
    r, phi = np.sqrt(u), 2 * np.pi * v
    d = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1 - u))], 1)[:k]
    t = np.radians(GRAZING)
    a = 2 * np.pi * (np.arange(SOLID_GRAZING) + 0.5) / SOLID_GRAZING
    g = np.stack([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.full(len(a), np.cos(t))], 1)
    return np.concatenate([d, g])


def inside_solid(caster: RayCaster, pts: np.ndarray, normal: np.ndarray, two_sided: np.ndarray,
                 rays: int = SOLID_RAYS) -> np.ndarray:
    """Which points (n, 3) on one-sided surfaces with front normals `normal` (n, 3) lie inside
    a solid, (n,) bool: every one of `rays` hemisphere rays and SOLID_GRAZING grazing ones from
    the point (TOL.solid_step of the scene's size off the surface) first meets the back of a
    one-sided element (the part of a floor under a block standing on it, without a bottom
    face): the closure's test (closure.py) for single points. One ray along the normal first,
    the others only where it met a back. The links leave such points out of their visible
    fractions and the solve such parts of sub-elements out of the transport. `caster` holds
    the scene's originals; `two_sided` (originals,) their flags (a hit on a two-sided element
    is never a back)."""
    n = len(pts)
    if not n:
        return np.zeros(0, bool)
    step = TOL.solid_step * max(1.0, caster.ray_offset / TOL.ray_offset_unit) * caster.scale
    o = pts + step * normal
    out = _backs(caster, o, normal, two_sided)  # first along the normal: most points end here
    c = np.nonzero(out)[0]
    if len(c):
        loc = _solid_directions(rays)
        nc = normal[c]
        a = np.where(np.abs(nc[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
        t1 = np.cross(nc, a)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(nc, t1)
        d = (loc[None, :, :1] * t1[:, None] + loc[None, :, 1:2] * t2[:, None]
             + loc[None, :, 2:] * nc[:, None]).reshape(-1, 3)
        out[c] = _backs(caster, np.repeat(o[c], len(loc), axis=0), d, two_sided) \
            .reshape(len(c), len(loc)).all(axis=1)
    return out


def _backs(caster: RayCaster, o: np.ndarray, d: np.ndarray, two_sided: np.ndarray) -> np.ndarray:
    """Whether each ray (origins o, unit directions d) first meets the back of a one-sided
    element, (n,) bool."""
    hit = caster.first_hit(np.ascontiguousarray(o), np.ascontiguousarray(d))
    back = hit >= 0
    h = np.nonzero(back)[0]
    back[h] = (np.einsum("ij,ij->i", caster.normal[hit[h]], d[h]) > 0) & ~two_sided[hit[h]]
    return back
