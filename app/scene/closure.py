"""Is the scene a closed enclosure? Decided from the geometry, for the solver's row handling.

Design notes and measurements: docs/src/design/scene-closure.md.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from radiosity.core.kernels import Sampling, sample_points
from radiosity.tracing.rays import caster_of
from radiosity.core.bundles import Elements
from radiosity.core.tolerances import TOL

POINTS = 16       # stratified points per element (nxm cells)
DIRECTIONS = 16   # cosine-weighted directions per point and side
LEAK = 1e-4       # fraction of rays that may escape through cracks in a closed scene
SIDE_LEAK = 0.02  # a side that loses at most this fraction of its rays has target 1
VOID = 0.98       # ... at least this fraction: it sees only the void, target 0
MAX_RAYS = 1 << 22  # beyond this many, fewer points per element (a square: 9, 4, 1); a mesh of
                    # many small elements samples its hemisphere through their number instead


@dataclass(frozen=True)
class Closure:
    """closed: the decision; escaped: rays that escaped; rays: rays cast; worst: the element
    that lost the largest fraction (-1: none) and that fraction; reason: one line.

    Per element side (arrays (n, 2) [front, back], None when the closure was stated, not
    measured; never in to_dict()): target, the row target, the fraction of the side's
    hemisphere that reaches geometry, snapped to 1 where no more rays escape than cracks
    explain and to 0 where (almost) all do (the outward back of a two-sided shell); exact,
    where it was snapped (those rows may be balanced; in an open scene a side snapped to 1 is
    exact only where none of its rays escaped); contact, sides covered by a touching
    surface (contact.py: they take no part in the transport); inside, the fraction of the
    side's sample points that lie inside a solid (every ray meets a back face: a floor under a
    block whose bottom faces up), left out of the count like covered points; lost, the
    fraction of the side's counted rays that escaped or met a back face (0: closed on that
    side, whatever the rest of the scene)."""

    closed: bool
    escaped: int
    rays: int
    worst: int
    worst_fraction: float
    reason: str
    target: np.ndarray | None = field(default=None, repr=False, compare=False)
    exact: np.ndarray | None = field(default=None, repr=False, compare=False)
    contact: np.ndarray | None = field(default=None, repr=False, compare=False)
    inside: np.ndarray | None = field(default=None, repr=False, compare=False)
    lost: np.ndarray | None = field(default=None, repr=False, compare=False)
    counts: dict | None = None       # contact_sides, void_sides, open_sides (measured only)

    def to_dict(self) -> dict:
        out = {"closed": self.closed, "escaped_rays": self.escaped, "rays": self.rays,
               "worst_element": self.worst, "worst_escaped_fraction": self.worst_fraction,
               "reason": self.reason}
        out.update(self.counts or {})
        return out


def stratified_directions(k: int, rng) -> np.ndarray:
    """k cosine-weighted unit directions around +z, stratified in sqrt(k) x sqrt(k) cells."""
    s = int(np.ceil(np.sqrt(k)))
    i, j = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    u = (i.ravel() + rng.random(s * s)) / s
    v = (j.ravel() + rng.random(s * s)) / s
    r, phi = np.sqrt(u), 2 * np.pi * v
    d = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1 - u))], 1)
    return d[:k]


def tangent_frame(n: np.ndarray):
    """Two unit tangents (k, 3) orthogonal to unit normals n (k, 3)."""
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t = np.cross(n, a)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t)


def detect_closure(elements: Elements, ray_offset: float, points: int = POINTS,
                   directions: int = DIRECTIONS, leak: float = LEAK, seed: int = 0,
                   contact: bool = True, threads: int = 2) -> Closure:
    """The closure test above, per element side; ray_offset: rays.epsilon.
    contact: find contact sides first (contact.py) and leave their covered points out; the
    rays go in batches of about 256 k on `threads` threads (the driver's, before any link
    task runs)."""
    from radiosity.scene.contact import COVERED, contact_points, scene_scale

    n = len(elements)
    while points > 1 and n * points * directions > MAX_RAYS:
        points = (int(round(np.sqrt(points))) - 1) ** 2
    rc = caster_of(elements.verts, elements.nverts, ray_offset)
    pts, _ = sample_points(elements.verts, elements.nverts, Sampling("nxm", points))
    P = pts.shape[1]
    covered = (contact_points(elements, pts, ray_offset) if contact and n
               else np.zeros((n, P, 2), bool))
    rng = np.random.default_rng(seed)
    lost = np.zeros((n, 2))
    cast = np.zeros((n, 2))
    inside = np.zeros((n, 2))
    # off the surface, beyond float32 rounding, and well inside the contact window: a point
    # nearer than that to another surface is covered (contact.py), never stepped through it
    step = (TOL.closure_step * max(1.0, ray_offset / TOL.ray_offset_unit) * scene_scale(elements)
            if n else 0.0)
    jobs = []
    for side in (1.0, -1.0):
        k = 0 if side > 0 else 1
        ids = np.arange(n) if side > 0 else np.nonzero(elements.two_sided)[0]
        if not len(ids):
            continue
        loc = stratified_directions(directions, rng)                           # (D, 3)
        # elements in batches of about 256 k rays: memory stays bounded however many there are
        batch = max(1, (1 << 18) // (P * directions))
        jobs += [(ids[s0:s0 + batch], k, side, loc) for s0 in range(0, len(ids), batch)]

    def run(job):  # the batches hold disjoint elements: each writes its own rows
        sub, k, side, loc = job
        nrm = side * elements.normal[sub]
        t1, t2 = tangent_frame(nrm)
        dirs = (loc[None, :, :1] * t1[:, None] + loc[None, :, 1:2] * t2[:, None]
                + loc[None, :, 2:] * nrm[:, None])                  # (k, D, 3)
        o = pts[sub][:, :, None, :] + step * nrm[:, None, None, :]  # (k, P, 1, 3)
        o = np.broadcast_to(o, (len(sub), P, directions, 3)).reshape(-1, 3)
        d = np.broadcast_to(dirs[:, None], (len(sub), P, directions, 3)).reshape(-1, 3)
        hit = rc.first_hit(np.ascontiguousarray(o), np.ascontiguousarray(d))
        # a hit on a one-sided element from behind is black: the light is lost there too
        back = np.zeros(len(hit), bool)
        h = hit >= 0
        back[h] = (np.einsum("ij,ij->i", elements.normal[hit[h]], d[h]) > 0) & \
            ~elements.two_sided[hit[h]]
        # a point whose every ray meets a back face lies inside a solid (the part of a floor
        # under a block standing on it), a covered point (contact.py) sees only its cover:
        # neither takes part in the transport, and neither is counted
        miss = (~h).reshape(len(sub), P, directions)
        back = back.reshape(len(sub), P, directions)
        solid = back.all(axis=2)
        skip = solid | covered[sub, :, k]
        inside[sub, k] = (solid & ~covered[sub, :, k]).sum(axis=1) / P
        lost[sub, k] += np.where(skip[..., None], False, miss | back).sum(axis=(1, 2))
        cast[sub, k] += (~skip).sum(axis=1) * directions

    with ThreadPoolExecutor(threads) as pool:  # Embree and numpy's big loops let go of the GIL
        list(pool.map(run, jobs))
    frac = lost / np.maximum(cast, 1)
    cover = covered.mean(axis=1)                      # (n, 2): the covered fraction
    touching = cover >= COVERED
    touching[:, 1] &= elements.two_sided.astype(bool)
    sides = np.zeros((n, 2), bool)
    sides[:, 0] = True
    sides[:, 1] = elements.two_sided.astype(bool)
    live = sides & ~touching
    void = live & (cast > 0) & (frac >= VOID)         # sees (almost) only the void
    counted = live & ~void
    total, escaped = int(cast[counted].sum()), int(lost[counted].sum())
    closed = bool(counted.any()) and escaped <= leak * total
    # per-side targets: measured, snapped where the measure cannot tell them from 1 or 0
    # (a partly covered side: its uncovered part's fraction, times that part; not exact, as its
    # sub-elements differ: the covered ones see nothing, the others their whole hemisphere)
    target = np.where(cast > 0, 1.0 - frac, 1.0) * (1.0 - cover)
    one = counted & (frac <= SIDE_LEAK) & (cover == 0)
    target[one] = 1.0
    if not closed:  # in an open scene a side that lost a ray may see out: its row is not known
        one &= frac == 0.0
    target[void] = 0.0
    target[~sides] = 0.0
    target[touching] = 0.0
    exact = one | void | ~sides | touching | (live & (cast == 0) & (cover == 0))
    ef = np.where(counted, frac, -1.0).max(axis=1) if n else np.zeros(0)
    worst = int(np.argmax(ef)) if n else -1
    wf = float(max(ef[worst], 0.0)) if n else 0.0
    extra = ""
    if touching.any():
        extra += f"; {int(touching.sum())} contact sides (covered by a touching surface) take no part"
    if void.any():
        extra += f"; {int(void.sum())} sides see only the void (target 0)"
    if closed:
        reason = (f"closed: {escaped} of {total} hemisphere rays from the {n} original elements "
                  f"escape (an enclosure){extra}: rows balanced to their targets (1), "
                  "reciprocity kept")
    else:
        reason = (f"open: {escaped} of {total} hemisphere rays escape ({escaped / max(total, 1):.1%}; "
                  f"most from {elements.describe(worst)}, {wf:.0%} of its rays){extra}: rows "
                  "are not balanced, only capped at 1 (normalise-rows: open would balance the "
                  f"{int(one.sum())} sides that lost no ray)")
    return Closure(closed, escaped, total, worst if escaped else -1, wf, reason,
                   target=target, exact=exact, contact=touching, inside=inside, lost=frac,
                   counts={"contact_sides": int(touching.sum()), "void_sides": int(void.sum()),
                           "partly_covered_sides": int((live & (cover > 0)).sum()),
                           "open_sides": int((counted & (frac > SIDE_LEAK)).sum())})
