"""Image files: the linear image as OpenEXR (float32 R, G, B, ZIP: lossless) and its 8-bit sRGB
tone mapping (core.colour) as PNG; and reading an EXR back (references, comparisons)."""

from __future__ import annotations

import os

import numpy as np

from radiosity.errors import RenderError
from radiosity.formats.files import temp_path


def write_exr(path: str, img: np.ndarray) -> None:
    """Linear RGB (H, W, 3) -> OpenEXR scanline file, float32 channels R, G, B, ZIP (lossless)."""
    import OpenEXR

    a = np.ascontiguousarray(np.asarray(img, np.float32))
    if a.ndim != 3 or a.shape[2] != 3:
        raise RenderError(f"write_exr needs an (H, W, 3) image, got shape {a.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    tmp = temp_path(path)
    with OpenEXR.File(header, {"RGB": a}) as f:
        f.write(tmp)
    os.replace(tmp, path)


def read_exr(path: str) -> np.ndarray:
    """An OpenEXR file's RGB (its data window) as (H, W, 3) float32, linear.

    Reads R, G, B (also 'layer.R' names of the first layer); a grey file (Y only) is repeated
    into three channels; half and uint channels are converted to float32.
    """
    import OpenEXR

    if not os.path.isfile(path):
        raise RenderError(f"{path}: no such EXR file")
    try:
        with OpenEXR.File(path, separate_channels=True) as f:
            ch = {k: np.asarray(v.pixels) for k, v in f.channels().items()}
    except Exception as e:
        raise RenderError(f"{path}: cannot read as OpenEXR ({e})") from None

    def find(c):
        if c in ch:
            return ch[c]
        named = sorted(k for k in ch if k.endswith("." + c))
        return ch[named[0]] if named else None

    rgb = [find(c) for c in "RGB"]
    if any(x is None for x in rgb):
        y = find("Y")
        if y is None:
            raise RenderError(f"{path}: no R, G, B (or Y) channels, only {sorted(ch)}")
        rgb = [y, y, y]
    return np.stack([np.asarray(x, np.float32) for x in rgb], axis=-1)


def write_png(path: str, img8: np.ndarray) -> None:
    """8-bit sRGB (H, W, 3) uint8 -> PNG (no timestamp: identical input, identical bytes)."""
    from PIL import Image

    a = np.ascontiguousarray(img8)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3:
        raise RenderError(f"write_png needs an (H, W, 3) uint8 image, got {a.dtype} {a.shape}")
    tmp = temp_path(path)
    Image.fromarray(a, "RGB").save(tmp, format="PNG")
    os.replace(tmp, path)
