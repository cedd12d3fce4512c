"""The leaves' first bounce when emitters are handled at points (SPEC §10): L1 of a leaf is the
mean over stratified points of the leaf of rho H1 / pi, H1 from scene/direct.DirectLight, per
side. The solve then takes L1 as its right-hand side in place of Le (the links carry only
light after its first bounce) and Le is added back at the end.
"""

from __future__ import annotations

import math

import numpy as np

from radiosity.scene.direct import DirectLight

#: Stratified points per leaf (a square).
LEAF_POINTS = 4


def leaf_points(table: dict, k: int = LEAF_POINTS):
    """(M k, 3) points and (M k,) originals: k stratified points on each leaf of the link table
    (the leaves' own order, k consecutive points a leaf)."""
    from radiosity.methods.hierarchical.links.sampling import link_points, ray_pairing, triangle_strata

    ln = np.asarray(table["leaf_node"], np.int64)
    verts, nverts = table["verts"], table["nverts"].astype(np.int64)
    s = int(math.isqrt(k))
    pts, e = link_points(verts, nverts, np.zeros((len(verts), 3)), table["orig"].astype(np.int64),
                         ln, ln, s, triangle_strata(s * s), ray_pairing(s * s))
    return pts[:len(ln) * s * s], e[:len(ln) * s * s]


def first_bounce(table: dict, elements, settings, k: int = LEAF_POINTS) -> np.ndarray:
    """L1 (2, 3, M) float64: rho / pi times the mean direct irradiance H1 over k points of each
    leaf, per side (a side that reflects nothing gets 0). In process, one batch at a time."""
    M = len(table["leaf_node"])
    out = np.zeros((2, 3, M))
    light = DirectLight(elements, settings.rays.offset)
    if not light:
        return out
    pts, e = leaf_points(table, k)
    kk = len(pts) // max(M, 1)
    rho = np.asarray(elements.reflectance, np.float64)
    for side, sign in ((0, 1.0), (1, -1.0)):
        r = rho[table["orig"][table["leaf_node"]], side]                       # (M, 3)
        on = np.repeat(r.max(axis=1) > 0, kk)
        if not on.any():
            continue
        idx = np.flatnonzero(on)
        H = light.irradiance(pts[idx], sign * elements.normal[e[idx]], e[idx], index=idx * 2 + side)
        Hm = np.zeros((M * kk, 3))
        Hm[idx] = H
        out[side] = (r * Hm.reshape(M, kk, 3).mean(axis=1) / math.pi).T
    return out
