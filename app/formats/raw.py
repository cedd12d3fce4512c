"""What a mesh reader returns (`RawMesh`), before scene.meshes validates it into polygons, and
the warning for input a reader or the loader repaired (`SceneWarning`, said through `warn`)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np


class SceneWarning(UserWarning):
    """Input the loader repaired (non-planar or non-convex quad, n-gon): said, not silent."""


@dataclass
class RawMesh:
    """What a mesh loader returns before validation.

    vertices : (V, 3) float64; faces : list of vertex-index lists (3 or more each);
    face_material : material name per face; materials : name -> dict of file-given properties.
    """

    vertices: np.ndarray
    faces: list
    face_material: list
    materials: dict = field(default_factory=dict)


def warn(msg: str) -> None:
    """Say a repair (a SceneWarning), attributed to the caller's caller."""
    warnings.warn(msg, SceneWarning, stacklevel=3)
