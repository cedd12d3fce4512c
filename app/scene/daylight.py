"""Daylight at points: the sky's direct light through openings (emitters.SkyEmitter, issue
52), by one shadow ray per point and sky direction. Kept apart from scene/direct.py's
DirectLight until scenes carry a `[sky]`."""

from __future__ import annotations

import numpy as np


def sky_irradiance(caster, sky, points: np.ndarray, normals: np.ndarray, n: int = 16) -> np.ndarray:
    """(p, 3) W m^-2: the sky's direct light (emitters.SkyEmitter, issue 52) at `points` (p, 3)
    facing unit `normals` (p, 3): sum over its 2 n^2 stratified directions d of L(d) w cos+,
    where a ray from the point (moved the caster's offset along its normal) along d leaves the
    scene without a hit (an opening, the open sky). The term `DirectLight.irradiance` adds once
    scenes carry a sky (not wired yet)."""
    P = np.asarray(points, np.float64)
    N = np.asarray(normals, np.float64)
    s = sky.sample(int(n))
    d = (s.position - sky.centre) / sky.radius                         # (k, 3) unit
    L = sky.radiance(d) * s.weight                                      # (k,) W m^-2 per channel
    cos = np.maximum(N @ d.T, 0.0)                                      # (p, k)
    pi, ki = np.nonzero(cos > 0)
    out = np.zeros((len(P), 3))
    if not len(pi):
        return out
    origins = P[pi] + caster.ray_offset * caster.scale * N[pi]
    free = caster.first_hit(origins, d[ki], unit=True) < 0
    np.add.at(out, pi[free], (L[ki[free]] * cos[pi[free], ki[free]])[:, None])
    return out
