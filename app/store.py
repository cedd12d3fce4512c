"""The run directory: one Zarr 3 store (the only zarr import) plus report.json.

Layout of `RUN_DIR/store.zarr` (every array named with its shape and dtype in the README):

    attrs            format, scene path and name, camera, subpixel, settings of each stage
    elements/        original elements (types.Elements): verts, nverts, normal, center, area,
                     reflectance, emission, two_sided, material, source, face
    partition/       sub-elements and their split trees (types.Partition)
    raster/orig      (H*K, W*K) int32: original element seen through each fine pixel (-1: none)
    raster/sub       (H*K, W*K) int32: sub-element seen through each fine pixel (-1: none)

Later stages add their own groups (visibility/, solution/); a stage that is re-run deletes the
groups of the stages after it, so a store never mixes results of different inputs.
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

from .errors import StoreError
from .types import Camera, Elements, Partition

FORMAT = "radiosity-run/1"
STORE = "store.zarr"
REPORT = "report.json"
STAGES = ("elements", "partition", "raster", "visibility", "solution")


def _zarr():
    import zarr

    return zarr


class RunStore:
    """A run directory's Zarr store. mode: 'r' (must exist), 'a' (create if missing), 'w' (fresh)."""

    def __init__(self, run_dir: str, mode: str = "r"):
        zarr = _zarr()
        self.run_dir = os.path.abspath(run_dir)
        self.path = os.path.join(self.run_dir, STORE)
        if mode == "r" and not os.path.exists(self.path):
            raise StoreError(f"{self.run_dir} is not a run directory (no {STORE}); "
                             f"create one with: radiosity preprocess SCENE --out {run_dir}")
        os.makedirs(self.run_dir, exist_ok=True)
        try:
            self.root = zarr.open_group(self.path, mode=mode)
        except Exception as e:
            raise StoreError(f"cannot open the run store {self.path}: {e}") from None
        if mode == "w":
            self.root.attrs.update({"format": FORMAT, "created": time.time()})
        elif self.root.attrs.get("format") != FORMAT:
            raise StoreError(f"{self.path} has format {self.root.attrs.get('format')!r}, "
                             f"this version reads {FORMAT!r}: run preprocess again")

    # ---- generic groups of whole arrays
    @property
    def attrs(self) -> dict:
        return dict(self.root.attrs)

    def set_attrs(self, **kw) -> None:
        self.root.attrs.update(kw)

    def has(self, group: str) -> bool:
        return group in self.root

    def write_arrays(self, group: str, arrays: dict, attrs: dict | None = None) -> None:
        """Replace `group` with these arrays (each written whole, chunked by zarr)."""
        if group in self.root:
            del self.root[group]
        g = self.root.create_group(group)
        for name, a in arrays.items():
            a = np.ascontiguousarray(a)
            g.create_array(name, data=a, chunks=_chunks(a))
        if attrs:
            g.attrs.update(attrs)

    def read_arrays(self, group: str) -> dict:
        if group not in self.root:
            raise StoreError(f"{self.path} has no '{group}' yet: run the stage that writes it first")
        g = self.root[group]
        return {name: arr[...] for name, arr in g.arrays()}

    def group_attrs(self, group: str) -> dict:
        return dict(self.root[group].attrs)

    def drop_after(self, stage: str) -> None:
        """Delete the groups of every stage after `stage` (their inputs changed)."""
        for later in STAGES[STAGES.index(stage) + 1:]:
            if later in self.root:
                del self.root[later]

    # ---- typed helpers
    def save_elements(self, el: Elements) -> None:
        self.write_arrays("elements", el.arrays(), {"material_names": list(el.material_names),
                                                    "sources": list(el.sources)})

    def load_elements(self) -> Elements:
        a = self.read_arrays("elements")
        at = self.group_attrs("elements")
        return Elements(**a, material_names=tuple(at["material_names"]), sources=tuple(at["sources"]))

    def save_partition(self, part: Partition, figures: dict | None = None) -> None:
        self.write_arrays("partition", part.arrays(), figures or {})

    def load_partition(self) -> Partition:
        return Partition(**self.read_arrays("partition"))

    def load_camera(self) -> Camera:
        return Camera.from_dict(self.attrs["camera"])


def _chunks(a: np.ndarray) -> tuple:
    """About 4 MiB per chunk along the first axis, whole along the others."""
    if a.ndim == 0 or a.size == 0:
        return a.shape or ()
    row = max(1, a.nbytes // max(1, a.shape[0]))
    n = max(1, min(a.shape[0], (4 << 20) // row))
    return (n,) + a.shape[1:]


def update_report(run_dir: str, section: str, data: dict) -> dict:
    """Merge `data` into section `section` of RUN_DIR/report.json and return the whole report."""
    fn = os.path.join(run_dir, REPORT)
    report = {}
    if os.path.exists(fn):
        with open(fn) as f:
            try:
                report = json.load(f)
            except json.JSONDecodeError:
                report = {}
    report.setdefault(section, {}).update(data)
    tmp = fn + ".tmp"
    with open(tmp, "w") as f:
        json.dump(report, f, indent=2, default=_json_default)
    os.replace(tmp, fn)
    return report


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")
