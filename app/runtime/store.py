"""The run directory: one Zarr 3 store (the only module that imports zarr for the whole run; each
method's own groups live in its folder's store module, through the helpers here) plus report.json.

Groups of `RUN_DIR/store.zarr`: elements/, partition/, raster/ (here); the transport method's
own (each method's `store_groups`, registered from the methods' registry, methods/base.py:
visibility/ and nearfield/, or links/, clusters/ and hierarchy/), viewfactors/
(viewfactors/store.py), solution/ (stages/solve.py). A stage that is re-run deletes the groups
of the stages after it, so a store never mixes results of different inputs.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import os
import time
from typing import ClassVar

import numpy as np

from radiosity.errors import StoreError
from radiosity.core.bundles import Camera, Elements, Partition

FORMAT = "radiosity-run/1"
STORE = "store.zarr"
REPORT = "report.json"
#: The groups before the transport method's and after it, in stage order; drop_after takes the
#: method's groups (any method's: a run holds one) as one stage between the two.
BEFORE_METHOD = ("elements", "partition", "raster")
AFTER_METHOD = ("solution",)
_method_groups = tuple  # () -> every registered method's groups (register_method_groups)


def register_method_groups(source) -> None:
    """Where the run store learns the transport methods' groups: `source`, a function () ->
    tuple of group names (methods/base.store_groups, registered when radiosity.methods is
    imported: this layer does not import the methods)."""
    global _method_groups
    _method_groups = source


def stages() -> list[tuple[str, ...]]:
    """The run's groups by stage, in order: each preprocessing group, the method's, solution."""
    return [(g,) for g in BEFORE_METHOD] + [tuple(_method_groups())] + [(g,) for g in AFTER_METHOD]


def zarr_module():
    import zarr

    return zarr


# Every array's compressor: zstd at level 1. zarr's default (level 0, i.e. zstd's 3) compresses
# link arrays no smaller (2.45x against 2.46x) and a third slower (MEASURED, a 128^2 link task's
# 8.4 MB: 106 against 78 ms; uncompressed 133 ms, the disk being slower than zstd); the link
# tasks' zstd was 0.3 s of the 128^2 link stage's worker CPU.
COMPRESSORS = ({"name": "zstd", "configuration": {"level": 1, "checksum": False}},)


def record_compressors(itemsize: int) -> tuple:
    """The compressor of records stored as bytes (link tasks): Blosc's byte shuffle by the
    record size, then lz4: faster to write and smaller than zstd on the raw bytes, read back
    as fast (docs/src/measurements/choices.md)."""
    from zarr.codecs import BloscCodec

    return (BloscCodec(cname="lz4", clevel=5, shuffle="shuffle", typesize=int(itemsize)),)


# Every chunk is written, even one that equals the fill value: zarr otherwise compares each
# chunk with it first. MEASURED: 18 arrays of 2.5 MB written with record_compressors, 0.31-0.36 s
# -> 0.15-0.17 s; a link task's writes were 0.2-0.3 s of the tessellated box's worker CPU.
ARRAY_CONFIG = {"write_empty_chunks": True}
#: Chunks of one RunStore.write_arrays being compressed or written at once (zarr's own default
#: concurrency is 10): each holds its compressed copy until written, so unbounded, a 2.7 GB
#: cluster layer would hold most of itself twice.
WRITE_CHUNKS = 8


def create_array(group, name: str, **kw):
    """group.create_array with the store's compressor (`name`: the array's name in `group`)."""
    return group.create_array(name, compressors=COMPRESSORS, config=ARRAY_CONFIG, **kw)


class RunStore:
    """A run directory's Zarr store. mode: 'r' (read), 'r+' (read and write; both must exist),
    'w' (a fresh store)."""

    def __init__(self, run_dir: str, mode: str = "r"):
        zarr = zarr_module()
        self.run_dir = os.path.abspath(run_dir)
        self.path = os.path.join(self.run_dir, STORE)
        self.mode = mode
        if mode in ("r", "r+") and not os.path.exists(self.path):
            raise StoreError(f"{self.run_dir} is not a run directory (no {STORE}); "
                             f"create one with: radiosity preprocess SCENE --out {run_dir}")
        os.makedirs(self.run_dir, exist_ok=True)
        try:
            self.root = zarr.open_group(self.path, mode=mode)
        except Exception as e:
            raise StoreError(f"cannot open the run store {self.path}: {e}") from None
        if mode == "w":
            self.root.update_attributes({"format": FORMAT, "created": time.time()})
        elif self.root.attrs.get("format") != FORMAT:
            raise StoreError(f"{self.path} has format {self.root.attrs.get('format')!r}, "
                             f"this version reads {FORMAT!r}: run preprocess again")

    # ---- generic groups of whole arrays
    @property
    def attrs(self) -> dict:
        return dict(self.root.attrs)

    def set_attrs(self, **kw) -> None:
        self.root.update_attributes(kw)

    def has(self, group: str) -> bool:
        return group in self.root

    def write_arrays(self, group: str, arrays: dict, attrs: dict | None = None) -> None:
        """Replace `group` with these arrays (each written whole, chunked by zarr)."""
        if group in self.root:
            del self.root[group]
        # the attributes with the group: attrs.update writes the group's metadata once per key
        self.root.create_group(group, attributes=dict(attrs or {}))
        arrays = {name: np.ascontiguousarray(a) for name, a in arrays.items()}

        async def write(g):
            gate = asyncio.Semaphore(WRITE_CHUNKS)

            async def put(z, sel, value):
                async with gate:
                    await z.setitem(sel, value)

            async def one(name, a):
                chunks = chunks_of(a)
                z = await g.create_array(name, shape=a.shape, dtype=a.dtype, chunks=chunks,
                                         compressors=COMPRESSORS, config=ARRAY_CONFIG)
                if a.size == 0:
                    return
                if a.ndim == 0 or len(a) <= chunks[0]:
                    await z.setitem(..., a)
                else:  # chunk by chunk: a write of several chunks copies each into a new
                    n = chunks[0]  # buffer first (zarr's _merge_chunk_array)
                    await asyncio.gather(*(put(z, slice(i, i + n), a[i:i + n])
                                           for i in range(0, len(a), n)))

            await asyncio.gather(*(one(name, a) for name, a in arrays.items()))

        self._in_group(group, write)

    def read_arrays(self, group: str) -> dict:
        if group not in self.root:
            make = (f"radiosity solve {self.run_dir}" if group in AFTER_METHOD else
                    f"radiosity preprocess SCENE --out {self.run_dir}" if group in BEFORE_METHOD
                    else f"radiosity visibility {self.run_dir}")
            raise StoreError(f"{self.run_dir} has no {group} yet: run {make} first")

        async def read(g):
            names, arrays = [], []
            async for name, arr in g.arrays():
                names.append(name)
                arrays.append(arr)
            return dict(zip(names, await asyncio.gather(*(a.getitem(...) for a in arrays))))

        return self._in_group(group, read)

    def _in_group(self, group: str, work):
        """work(async group) run to completion on zarr's event loop: every array of a group read
        or written concurrently (zarr's cost per array is mostly waiting; docs/src/measurements/choices.md)."""
        import zarr.api.asynchronous as za
        from zarr.core.sync import sync

        async def run():
            root = await za.open_group(self.path, mode="r" if self.mode == "r" else "r+")
            return await work(await root.getitem(group))

        return sync(run())

    def group_attrs(self, group: str) -> dict:
        return dict(self.root[group].attrs)

    def drop_after(self, stage: str) -> None:
        """Delete the groups of every stage after the one that writes group `stage` (their
        inputs changed); a method's groups are one stage (stages())."""
        order = stages()
        at = next((i for i, groups in enumerate(order) if stage in groups), None)
        if at is None:
            raise StoreError(f"{stage!r} is no group of the run store (groups: "
                             f"{', '.join(g for groups in order for g in groups)})")
        for groups in order[at + 1:]:
            for later in groups:
                if later in self.root:
                    del self.root[later]

    # ---- typed helpers
    def save_elements(self, el: Elements) -> None:
        from radiosity.scene.luminaires import luminaires_of

        self.write_arrays("elements", el.arrays(), {"material_names": list(el.material_names),
                                                    "sources": list(el.sources),
                                                    "luminaires": luminaires_of(el).to_dict()})

    def load_elements(self) -> Elements:
        from radiosity.scene.luminaires import Luminaires

        a = self.read_arrays("elements")
        at = self.group_attrs("elements")
        return Elements(**a, material_names=tuple(at["material_names"]), sources=tuple(at["sources"]),
                        luminaires=Luminaires.from_dict(at.get("luminaires")) or None)

    def save_partition(self, part: Partition, figures: dict | None = None) -> None:
        self.write_arrays("partition", part.arrays(), figures or {})

    def load_partition(self) -> Partition:
        return Partition(**self.read_arrays("partition"))

    def load_camera(self) -> Camera:
        return Camera.from_dict(self.attrs["camera"])



def chunks_of(a: np.ndarray) -> tuple:
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
        json.dump(report, f, indent=2, default=json_default)
    os.replace(tmp, fn)
    return report


@dataclasses.dataclass(frozen=True)
class StageFigures:
    """What a stage measured: a frozen dataclass that writes its section of report.json and the
    rows of the CLI's summary. Reads like the report section too (fig["key"]), for callers that
    hold a report key (studies, tests). OPTIONAL fields are left out of the section while None
    (keys the section has only sometimes); FLAT fields are dicts whose items the section holds
    in their place (figures named by another module, such as a task's counters); a field that
    holds figures writes their section as its value."""

    SECTION: ClassVar[str] = ""
    OPTIONAL: ClassVar[tuple] = ()
    FLAT: ClassVar[tuple] = ()

    def to_dict(self) -> dict:
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in self.FLAT:
                out.update(v)
            elif not (v is None and f.name in self.OPTIONAL):
                out[f.name] = v.to_dict() if isinstance(v, StageFigures) else v
        return out

    def write(self, run_dir: str) -> dict:
        """Merge these figures into report.json's section; returns the whole report."""
        return update_report(run_dir, self.SECTION, self.to_dict())

    def rows(self) -> list[tuple[str, object]]:
        """(label, value) rows of the CLI's summary table."""
        return []

    def __getitem__(self, key: str):
        if key in self.__dataclass_fields__ and key not in self.FLAT:
            if key in self.OPTIONAL and getattr(self, key) is None:
                raise KeyError(key)
            return getattr(self, key)
        for name in self.FLAT:
            if key in getattr(self, name):
                return getattr(self, name)[key]
        raise KeyError(key)

    def __contains__(self, key: str) -> bool:
        try:
            self[key]
        except KeyError:
            return False
        return True

    def get(self, key: str, default=None):
        return self[key] if key in self else default


def json_default(o):
    if isinstance(o, StageFigures):  # figures within figures (the rounds' list)
        return o.to_dict()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def fsync_paths(paths) -> None:
    """fsync files and folders that exist (a chunk that equals the fill value is not written)."""
    for p in paths:
        try:
            fd = os.open(p, os.O_RDONLY)
        except FileNotFoundError:
            continue
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class Manifest:
    """A JSON-lines record of finished tasks: a head line {"plan": token}, then one line per
    task. The master is its only writer; a torn last line is ignored."""

    def __init__(self, path: str):
        self.path = path

    def create(self, token: str) -> None:
        with open(self.path, "w") as f:
            f.write(json.dumps({"plan": token}) + "\n")

    def record(self, entry: dict) -> None:
        with open(self.path, "a") as f:
            f.write(json.dumps(entry, default=json_default) + "\n")
            f.flush()
            os.fsync(f.fileno())

    def finished(self, token: str) -> dict:
        """task -> entry for the plan `token` ({} for another plan or none)."""
        if not os.path.exists(self.path):
            return {}
        with open(self.path) as f:
            lines = f.read().splitlines()
        try:
            if not lines or json.loads(lines[0]).get("plan") != token:
                return {}
        except json.JSONDecodeError:
            return {}
        done = {}
        for line in lines[1:]:
            try:
                e = json.loads(line)
            except json.JSONDecodeError:
                continue
            done[int(e["task"])] = e
        return done

    def rewrite(self, token: str, entries: dict) -> None:
        tmp = self.path + ".tmp"
        with open(tmp, "w") as f:
            f.write(json.dumps({"plan": token}) + "\n")
            for _, e in sorted(entries.items()):
                f.write(json.dumps(e, default=json_default) + "\n")
        os.replace(tmp, self.path)
