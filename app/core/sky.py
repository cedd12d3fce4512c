"""Sky luminance distributions of daylight (issue 52): the CIE standard overcast sky (Moon and
Spencer 1942, CIE S 011 type 1: L(theta) = Lz (1 + 2 cos theta) / 3) and the uniform sky, scaled
by their unobstructed horizontal illuminance Eh, over a uniform ground of reflectance rho_g
(luminance rho_g Eh / pi below the horizon). Pure functions of directions; the sky emitter and
the Radiance reference (validation/radiance.py) both read them."""

from __future__ import annotations

import math

import numpy as np

SKY_TYPES = ("cie-overcast", "uniform")


def zenith_luminance(kind: str, horizontal: float) -> float:
    """Lz such that the sky gives `horizontal` on an unobstructed horizontal plane:
    Eh = int L cos dw = 7 pi Lz / 9 (overcast), pi L (uniform).
    Same unit as `horizontal` per steradian (lx -> cd m^-2, W m^-2 -> W sr^-1 m^-2)."""
    if kind == "cie-overcast":
        return 9.0 * float(horizontal) / (7.0 * math.pi)
    if kind == "uniform":
        return float(horizontal) / math.pi
    raise ValueError(f"sky type {kind!r}: one of {', '.join(SKY_TYPES)}")


def luminance(kind: str, horizontal: float, ground_reflectance: float,
              up_cosine: np.ndarray) -> np.ndarray:
    """Luminance toward directions whose cosine to the zenith is `up_cosine` (k,): the sky
    above the horizon, the ground (rho_g Eh / pi) below it. Same unit as zenith_luminance."""
    c = np.asarray(up_cosine, np.float64)
    Lz = zenith_luminance(kind, horizontal)
    sky = Lz * (1.0 + 2.0 * c) / 3.0 if kind == "cie-overcast" else np.full_like(c, Lz)
    return np.where(c > 0, sky, float(ground_reflectance) * float(horizontal) / math.pi)
