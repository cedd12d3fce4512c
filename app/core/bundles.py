"""Plain array bundles passed between pipeline stages (frozen dataclasses of numpy arrays).

Polygons are stored as `verts (n, 4, 3) float64` with `nverts (n,) int8` in {3, 4}; a triangle
repeats its third vertex in slot 3, so no slot is ever uninitialised. Vertex order is
counter-clockwise seen from the front; the front normal is `(v1 - v0) x (v2 - v0)` normalised.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np


def _arrays(obj) -> dict:
    return {f.name: getattr(obj, f.name) for f in fields(obj) if isinstance(getattr(obj, f.name), np.ndarray)}


@dataclass(frozen=True)
class Elements:
    """Original finite elements of a scene.

    verts : (n, 4, 3) float64, metres or the scene's unit
    nverts : (n,) int8, 3 or 4
    normal : (n, 3) float64, unit front normal
    center : (n, 3) float64, area centroid
    area : (n,) float64
    reflectance : (n, 2, 3) float64, [front, back] RGB in [0, 1); back is 0 for one-sided
    emission : (n, 2, 3) float64, [front, back] RGB radiance (W sr^-1 m^-2); back 0 if one-sided
    two_sided : (n,) bool
    material : (n,) int32, index into `material_names`
    source : (n,) int32, index into `sources` (the mesh file)
    face : (n,) int32, face number in that file (0-based), for error messages
    luminaires : the scene's point and IES luminaires (scene/luminaires.Luminaires; None: none)
    """

    verts: np.ndarray
    nverts: np.ndarray
    normal: np.ndarray
    center: np.ndarray
    area: np.ndarray
    reflectance: np.ndarray
    emission: np.ndarray
    two_sided: np.ndarray
    material: np.ndarray
    source: np.ndarray
    face: np.ndarray
    material_names: tuple = ()
    sources: tuple = ()
    luminaires: object = None

    def __len__(self) -> int:
        return len(self.area)

    def arrays(self) -> dict:
        return _arrays(self)

    def describe(self, i: int) -> str:
        """Human name of element i: file, face and material."""
        src = self.sources[self.source[i]] if self.sources else "?"
        mat = self.material_names[self.material[i]] if self.material_names else "?"
        return f"element {i} (face {self.face[i] + 1} of {src}, material '{mat}')"


@dataclass(frozen=True)
class Camera:
    """The seed's camera (r, x, y, z, Nx, Ny, d), generalised to a rectangular image.

    The image plane is spanned by `x` (right) and `y` (up) at distance `focal` along `z` (the
    viewing direction); it covers [-half_w, half_w] x [-half_h, half_h]. The seed's form has
    half_w = half_h = 1. Pixel (row, col) has its centre at
    u = half_w * (2 (col + 0.5) / width - 1),  v = half_h * (1 - 2 (row + 0.5) / height).
    """

    center: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    focal: float
    width: int
    height: int
    half_w: float = 1.0
    half_h: float = 1.0

    def with_resolution(self, width: int, height: int) -> "Camera":
        return Camera(self.center, self.x, self.y, self.z, self.focal, int(width), int(height),
                      self.half_w, self.half_h)

    def to_dict(self) -> dict:
        return {"center": self.center.tolist(), "x": self.x.tolist(), "y": self.y.tolist(),
                "z": self.z.tolist(), "focal": self.focal, "width": self.width,
                "height": self.height, "half_w": self.half_w, "half_h": self.half_h}

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        return cls(np.asarray(d["center"], float), np.asarray(d["x"], float),
                   np.asarray(d["y"], float), np.asarray(d["z"], float), float(d["focal"]),
                   int(d["width"]), int(d["height"]), float(d["half_w"]), float(d["half_h"]))


@dataclass(frozen=True)
class Scene:
    """A loaded scene: its elements, its camera and where it came from."""

    name: str
    path: str
    elements: Elements
    camera: Camera
    validation: dict = field(default_factory=dict)  # exact answers of validation scenes
    chosen: str = ""  # what the loader chose where the file said nothing (a mesh file's camera)
    # more cameras ([[camera]] entries after the first): (name, Camera) pairs; the subdivision
    # follows every camera, and each gets its image from the one solution (RUN/views/NAME/)
    views: tuple = ()
    # calculation grids ([[grid]] tables: scene/grids.Grid): illuminance at points (issue 52)
    grids: tuple = ()

    @property
    def cameras(self) -> tuple:
        """Every camera: the run's own (`camera`) first, then the named `views`."""
        return (self.camera, *(c for _, c in self.views))


@dataclass(frozen=True)
class Partition:
    """The camera-driven subdivision of the original elements (seed §3).

    Sub-elements of one original are contiguous, in depth-first order of its split tree:
    sub-elements of original i are `offsets[i]:offsets[i + 1]`.

    orig : (m,) int32, original element of each sub-element
    verts : (m, 4, 3) float64 and nverts : (m,) int8, as in Elements
    center : (m, 3) float64, area centroid
    normal : (m, 3) float64, the original's front normal
    area : (m,) float64
    depth : (m,) int16, number of splits from the original
    offsets : (n + 1,) int64

    The split tree, for the two-level lookup (seed §3.2), k nodes:
    root : (n,) int32, the root node of each original
    child : (k, 2) int32, the node's two children [first, second], -1 at a leaf
    leaf : (k,) int32, sub-element index at a leaf, -1 elsewhere
    split_a : (k, 3) float64, a point on the node's split segment (0 at a leaf)
    split_m : (k, 3) float64, in-plane normal of the split segment; a point p goes to the second
        child iff (p - split_a) . split_m > 0
    """

    orig: np.ndarray
    verts: np.ndarray
    nverts: np.ndarray
    center: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    depth: np.ndarray
    offsets: np.ndarray
    root: np.ndarray
    child: np.ndarray
    leaf: np.ndarray
    split_a: np.ndarray
    split_m: np.ndarray

    def __len__(self) -> int:
        return len(self.area)

    def arrays(self) -> dict:
        return _arrays(self)
