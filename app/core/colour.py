"""Colour: the sRGB transfer curve both ways (IEC 61966-2-1), the Rec. 709 luminance, the
automatic exposure and the tone mapping to 8-bit sRGB that the image, the mesh exports and the
viewer share (so all of them show the same colours), and that the mesh readers use to read
8-bit and texture colours as linear reflectance."""

from __future__ import annotations

import math

import numpy as np

#: Rec. 709 / sRGB luminance weights of linear RGB.
LUMA = np.array([0.2126, 0.7152, 0.0722])
#: lm per W of Y (the candela's definition at 555 nm): lux and cd m^-2 from W, everywhere.
EFFICACY = 683.0
#: Automatic exposure maps the 99th percentile of the non-zero luminances to this linear value.
AUTO_KEY = 0.9
AUTO_PERCENTILE = 99.0


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear ones (IEC 61966-2-1), as glTF textures and 8-bit
    colours are encoded."""
    c = np.asarray(c, float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) of linear values in [0, 1] (clipped first)."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def auto_exposure(img: np.ndarray) -> float:
    """Exposure that maps the 99th percentile of the luminance of the non-zero pixels to 0.9.

    img (..., 3) linear RGB. 0.9 is linear (before the sRGB curve: 0.955 encoded), so about 1 %
    of the lit pixels clip. 1.0 when no pixel is lit.
    """
    y = np.asarray(img, np.float64).reshape(-1, 3) @ LUMA
    y = y[y > 0.0]
    if y.size == 0:
        return 1.0
    p = float(np.percentile(y, AUTO_PERCENTILE))
    return AUTO_KEY / p if p > 0.0 and math.isfinite(p) else 1.0


def tonemap(img: np.ndarray, exposure: float | None = None) -> np.ndarray:
    """Linear RGB (..., 3) -> 8-bit sRGB uint8 (..., 3): round(255 srgb(clip(exposure * img))).

    exposure None: `auto_exposure(img)`.
    """
    img = np.asarray(img, np.float64)
    e = auto_exposure(img) if exposure is None else float(exposure)
    return np.rint(srgb_encode(img * e) * 255.0).astype(np.uint8)
