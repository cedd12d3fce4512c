"""The run directory: one Zarr 3 store (the only zarr import) plus report.json.

Layout of `RUN_DIR/store.zarr` (every array named with its shape and dtype in the README):

    attrs            format, scene path and name, camera, subpixel, settings of each stage
    elements/        original elements (types.Elements): verts, nverts, normal, center, area,
                     reflectance, emission, two_sided, material, source, face
    partition/       sub-elements and their split trees (types.Partition)
    raster/orig      (H*K, W*K) int32: original element seen through each fine pixel (-1: none)
    raster/sub       (H*K, W*K) int32: sub-element seen through each fine pixel (-1: none)
    visibility/bits  (total,) uint8, chunked: bit-packed tiles (layout in plan.py)
    visibility/tiles, tasks, culled: the plan (plan.VisibilityPlan)
    visibility/partial/<task>-pairs (k, 3) int64 [a, b, visible rays], <task>-phi (k,) float64:
                     sampled kernels only: the task's partly visible pairs and their
                     kernel-weighted visible fraction (visibility.py)
    RUN_DIR/visibility.manifest.jsonl: one line per finished task (crc32, counts); the first
                     line names the plan it belongs to
    nearfield/       sparse near-field corrections (nearfield.py): ia, ib, sa, sb, dab, dba
    solution/radiance (m, 2, 3) float64: radiance per sub-element, side and channel

Later stages add their own groups (visibility/, solution/); a stage that is re-run deletes the
groups of the stages after it, so a store never mixes results of different inputs.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import os
import time
import zlib
from typing import ClassVar

import numpy as np

from .errors import StoreError
from .types import Camera, Elements, Partition

FORMAT = "radiosity-run/1"
STORE = "store.zarr"
REPORT = "report.json"
STAGES = ("elements", "partition", "raster", "visibility", "links", "hierarchy", "nearfield",
          "solution")


def _zarr():
    import zarr

    return zarr


# Every array's compressor: zstd at level 1. zarr's default (level 0, i.e. zstd's 3) compresses
# link arrays no smaller (2.45x against 2.46x) and a third slower (MEASURED, a 128^2 link task's
# 8.4 MB: 106 against 78 ms; uncompressed 133 ms, the disk being slower than zstd); the link
# tasks' zstd was 0.3 s of the 128^2 link stage's worker CPU.
COMPRESSORS = ({"name": "zstd", "configuration": {"level": 1, "checksum": False}},)


def record_compressors(itemsize: int) -> tuple:
    """The compressor of records stored as bytes (link tasks): Blosc's byte shuffle by the
    record size, then lz4. MEASURED on the 18 link tasks of the Cornell box at 128^2 (45 MB),
    against zstd level 1 on the raw bytes: write_links 0.63-0.73 s against 0.79-0.90 s (most of
    it zarr's own work per array and this VM's slow fresh file pages), read back as fast,
    2.85x smaller against 2.51x."""
    from zarr.codecs import BloscCodec

    return (BloscCodec(cname="lz4", clevel=5, shuffle="shuffle", typesize=int(itemsize)),)


def _array(group, name: str, **kw):
    """group.create_array with the store's compressor."""
    return group.create_array(name, compressors=COMPRESSORS, **kw)


class RunStore:
    """A run directory's Zarr store. mode: 'r' (read), 'r+' (read and write; both must exist),
    'w' (a fresh store)."""

    def __init__(self, run_dir: str, mode: str = "r"):
        zarr = _zarr()
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
            async def one(name, a):
                z = await g.create_array(name, shape=a.shape, dtype=a.dtype, chunks=_chunks(a),
                                         compressors=COMPRESSORS)
                if a.size:
                    await z.setitem(..., a)

            await asyncio.gather(*(one(name, a) for name, a in arrays.items()))

        self._in_group(group, write)

    def read_arrays(self, group: str) -> dict:
        if group not in self.root:
            make = {"solution": f"radiosity solve {self.run_dir}",
                    "visibility": f"radiosity visibility {self.run_dir}",
                    "nearfield": f"radiosity solve {self.run_dir}"}.get(
                group, f"radiosity preprocess SCENE --out {self.run_dir}")
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
        or written concurrently (zarr costs a few ms per array, mostly waiting: the partition's
        13 arrays read in 26-33 ms against 35-58 ms one after another, the node table's 15
        written in 86-115 against 135-169 ms)."""
        import zarr.api.asynchronous as za
        from zarr.core.sync import sync

        async def run():
            root = await za.open_group(self.path, mode="r" if self.mode == "r" else "r+")
            return await work(await root.getitem(group))

        return sync(run())

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


def _entry(task: int, e: dict) -> dict:
    """A manifest line: task, crc32 and length of its bytes, counters, its partial pairs' checksum."""
    line = {"task": int(task), "crc": int(e["crc"]), "nbytes": int(e["nbytes"]),
            "counts": [int(c) for c in e["counts"]]}
    if "partial" in e:
        line["partial"] = {"crc": int(e["partial"]["crc"]), "n": int(e["partial"]["n"])}
    return line


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


@dataclasses.dataclass(frozen=True)
class StageFigures:
    """What a stage measured: a frozen dataclass that writes its section of report.json and the
    rows of the CLI's summary. Reads like the report section too (fig["key"]), for callers that
    hold a report key (studies, tests)."""

    SECTION: ClassVar[str] = ""

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def write(self, run_dir: str) -> dict:
        """Merge these figures into report.json's section; returns the whole report."""
        return update_report(run_dir, self.SECTION, self.to_dict())

    def rows(self) -> list[tuple[str, object]]:
        """(label, value) rows of the CLI's summary table."""
        return []

    def __getitem__(self, key: str):
        if key not in self.__dataclass_fields__:
            raise KeyError(key)
        return getattr(self, key)

    def __contains__(self, key: str) -> bool:
        return key in self.__dataclass_fields__

    def get(self, key: str, default=None):
        return getattr(self, key, default) if key in self else default


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


# ----------------------------------------------------------------------------- visibility bits

def bits_path(store_path: str) -> str:
    return os.path.join(store_path, "visibility", "bits")


def write_bits(store_path: str, start: int, buf: np.ndarray) -> None:
    """Write a task's bytes at `start` (chunk-aligned, whole chunks) and make them durable
    (fsync of its chunk files and their folder) before the task reports back: a task enters
    the manifest only after its bytes are on disk. Called on the workers."""
    zarr = _zarr()
    arr = zarr.open_array(bits_path(store_path), mode="r+")
    try:
        arr[start:start + len(buf)] = buf
    except OSError as e:  # zarr's error names no file: name the array
        raise OSError(e.errno, e.strerror, bits_path(store_path)) from None
    if len(buf):
        chunk = int(arr.chunks[0])
        files = [os.path.join(bits_path(store_path), arr.metadata.encode_chunk_key((i,)))
                 for i in range(start // chunk, (start + len(buf) - 1) // chunk + 1)]
        fsync_paths(files + [os.path.dirname(files[0])])


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


def partial_path(store_path: str) -> str:
    return os.path.join(store_path, "visibility", "partial")


def _partial_crc(pairs: np.ndarray, phi: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(phi, np.float64).tobytes(),
                      zlib.crc32(np.ascontiguousarray(pairs, np.int64).tobytes()))


def write_partial(store_path: str, task: int, a, b, count, phi) -> dict:
    """Write a task's partly visible pairs (called on the workers); returns {crc, n} for the
    manifest. Nothing is written for none."""
    pairs = np.stack([a, b, count], axis=1).astype(np.int64).reshape(-1, 3)
    phi = np.asarray(phi, np.float64)
    if len(pairs):
        zarr = _zarr()
        g = zarr.open_group(partial_path(store_path), mode="r+")
        _array(g, f"{task}-pairs", data=pairs, chunks=_chunks(pairs), overwrite=True)
        _array(g, f"{task}-phi", data=phi, chunks=_chunks(phi), overwrite=True)
    return {"crc": _partial_crc(pairs, phi), "n": int(len(pairs))}


def read_partial(store_path: str, task: int, entry: dict):
    """The partly visible pairs of one task, checked against its manifest entry {crc, n}:
    pairs (k, 3) int64 [a, b, visible rays], phi (k,). Called on the workers."""
    if entry["n"] == 0:
        pairs, phi = np.zeros((0, 3), np.int64), np.zeros(0)
    else:
        zarr = _zarr()
        try:
            g = zarr.open_group(partial_path(store_path), mode="r")
            pairs, phi = g[f"{task}-pairs"][...], g[f"{task}-phi"][...]
        except Exception:  # missing or unreadable
            pairs, phi = np.zeros((0, 3), np.int64), np.zeros(0)
    if len(pairs) != entry["n"] or _partial_crc(pairs, phi) != entry["crc"]:
        run_dir = os.path.dirname(store_path)
        raise StoreError(f"the partly visible pairs of visibility task {task} of {run_dir} are "
                         f"corrupted (checksum): run radiosity visibility {run_dir} --resume "
                         "to recompute them")
    return pairs, phi


def read_bits(store_path: str, start: int, nbytes: int) -> np.ndarray:
    """Bytes [start, start + nbytes) of the packed visibility bits: called on the workers."""
    zarr = _zarr()
    arr = zarr.open_array(bits_path(store_path), mode="r")
    return arr[start:start + nbytes]


def _corrupted(run_dir: str, task: int, why: str) -> StoreError:
    return StoreError(f"visibility task {task} of {run_dir} is corrupted ({why}): run radiosity "
                      f"visibility {run_dir} --resume to recompute it")


def read_task_checked(store_path: str, task: int, start: int, nbytes: int, crc: int) -> np.ndarray:
    """The bytes of one visibility task, checked against the crc32 recorded when it finished;
    a mismatch or an unreadable (corrupted) chunk raises StoreError with the repair command.
    Called on the workers."""
    run_dir = os.path.dirname(store_path)
    try:
        data = read_bits(store_path, start, nbytes)
    except Exception as e:  # a chunk that no longer decodes is corrupted like a bad checksum
        raise _corrupted(run_dir, task, f"unreadable chunk: {type(e).__name__}") from None
    if zlib.crc32(data.tobytes()) != int(crc):
        raise _corrupted(run_dir, task, "checksum")
    return data


class VisibilityStore:
    """The visibility group of a run store: plan arrays, packed bits and the task manifest."""

    def __init__(self, rs: RunStore):
        self.rs = rs
        self.manifest = os.path.join(rs.run_dir, "visibility.manifest.jsonl")

    def create(self, plan, token: str, attrs: dict) -> None:
        """A fresh visibility group for `plan` (drops an old one and its manifest)."""
        root = self.rs.root
        if "visibility" in root:
            del root["visibility"]
        g = root.create_group("visibility")
        _array(g, "bits", shape=(max(plan.total, 1),), dtype="uint8", chunks=(plan.chunk,),
                       fill_value=0)
        for name in ("tiles", "tasks", "culled"):
            a = getattr(plan, name)
            _array(g, name, data=np.ascontiguousarray(a), chunks=_chunks(a))
        g.create_group("partial")
        g.update_attributes({"token": token, "chunk": plan.chunk, "total": plan.total,
                        "unit": plan.unit, "blocks_culled": plan.blocks_culled, **attrs})
        with open(self.manifest, "w") as f:
            f.write(json.dumps({"plan": token}) + "\n")

    def require(self):
        """(token, plan, finished entries) of the visibility matrix, or a StoreError saying what
        to run when there is none."""
        token = self.token()
        if token is None:
            raise StoreError(f"{self.rs.run_dir} has no visibility matrix yet: run radiosity "
                             f"visibility {self.rs.run_dir}")
        return token, self.plan(), self.finished(token)

    def token(self) -> str | None:
        if "visibility" not in self.rs.root:
            return None
        return self.rs.root["visibility"].attrs.get("token")

    def plan(self):
        from .plan import VisibilityPlan

        g = self.rs.root["visibility"]
        at = g.attrs
        culled = g["culled"][...]
        return VisibilityPlan(tiles=g["tiles"][...], tasks=g["tasks"][...], culled=culled,
                              chunk=int(at["chunk"]), total=int(at["total"]), unit=at["unit"],
                              blocks_culled=int(at.get("blocks_culled", len(culled))))

    def rewrite_manifest(self, token: str, entries: dict) -> None:
        """Keep only `entries` (task -> entry) in the manifest."""
        tmp = self.manifest + ".tmp"
        with open(tmp, "w") as f:
            f.write(json.dumps({"plan": token}) + "\n")
            for task, e in sorted(entries.items()):
                f.write(json.dumps(_entry(task, e)) + "\n")
        os.replace(tmp, self.manifest)

    def record(self, task: int, result: dict) -> None:
        """Append one finished task to the manifest (the master is its only writer)."""
        line = _entry(task, result)
        with open(self.manifest, "a") as f:
            f.write(json.dumps(line) + "\n")
            f.flush()
            os.fsync(f.fileno())

    def finished(self, token: str) -> dict:
        """task -> manifest entry, for the plan `token` (a torn last line is ignored)."""
        if not os.path.exists(self.manifest):
            return {}
        done = {}
        with open(self.manifest) as f:
            lines = f.read().splitlines()
        if not lines:
            return {}
        try:
            head = json.loads(lines[0])
        except json.JSONDecodeError:
            return {}
        if head.get("plan") != token:
            return {}
        for line in lines[1:]:
            try:
                e = json.loads(line)
            except json.JSONDecodeError:
                continue
            done[int(e["task"])] = e
        return done

    def read_task(self, plan, task: int, nbytes: int | None = None) -> np.ndarray:
        """The bytes of one task (unpadded if nbytes is given)."""
        from .plan import TBYTES, TSTART

        arr = self.rs.root["visibility"]["bits"]
        s = int(plan.tasks[task, TSTART])
        n = int(plan.tasks[task, TBYTES]) if nbytes is None else int(nbytes)
        return arr[s:s + n]

    def verify(self, plan, task: int, entry: dict) -> bool:
        """Do the stored bytes of `task` (and its partly visible pairs) match the checksums
        recorded when it finished?"""
        try:
            data = self.read_task(plan, task, entry["nbytes"])
            if "partial" in entry:
                read_partial(self.rs.path, task, entry["partial"])
        except Exception:  # an unreadable (corrupted) chunk, a missing or altered partial list
            return False
        return zlib.crc32(data.tobytes()) == entry["crc"]

    def task_bytes(self, plan, task: int, entry: dict | None) -> np.ndarray:
        """The verified (unpadded) bytes of one finished task; a missing or corrupted task
        raises StoreError naming the command that repairs it (never used silently)."""
        if entry is None:
            raise StoreError(f"visibility task {task} of {self.rs.run_dir} is missing: "
                             f"run radiosity visibility {self.rs.run_dir} --resume")
        from .plan import TSTART

        return read_task_checked(self.rs.path, task, int(plan.tasks[task, TSTART]),
                                 int(entry["nbytes"]), int(entry["crc"]))

    def iter_tiles(self):
        """Yield (I, J, r0, r1, bits (r1 - r0, nJ) bool) for every stored tile, task by task
        (the bit layout is in plan.py; every task's bytes are verified first)."""
        from .plan import I, J, NBYTES, NCOLS, R0, R1, START, TSTART

        _, plan, done = self.require()
        for task in range(len(plan.tasks)):
            data = self.task_bytes(plan, task, done.get(task))
            base = int(plan.tasks[task, TSTART])
            for tile in plan.tiles_of(task):
                off = int(tile[START]) - base
                rows, cols = int(tile[R1] - tile[R0]), int(tile[NCOLS])
                bits = np.unpackbits(data[off:off + int(tile[NBYTES])], count=rows * cols,
                                     bitorder="little")
                yield int(tile[I]), int(tile[J]), int(tile[R0]), int(tile[R1]), \
                    bits.reshape(rows, cols).astype(bool)

    def dense(self, offsets: np.ndarray) -> np.ndarray:
        """The whole matrix as (m, m) bool, symmetric: for small scenes and tests only."""
        m = int(offsets[-1])
        V = np.zeros((m, m), bool)
        for i, j, r0, r1, bits in self.iter_tiles():
            V[offsets[i] + r0:offsets[i] + r1, offsets[j]:offsets[j + 1]] = bits
        return V | V.T

    def pair_bits(self, offsets: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
        """The stored bit of each pair (ia, ib) of sub-elements (any order), (k,) bool; reads
        (and verifies) each task that holds one of the pairs once."""
        from .plan import START, TSTART

        _, plan, done = self.require()
        found, t, bit = plan.tile_of_pairs(offsets, np.asarray(ia, np.int64),
                                           np.asarray(ib, np.int64))
        pos = plan.tiles[t, START] + (bit >> 3)  # byte in the whole bits array
        task_of = plan.task_of_tile()[t]
        got = np.zeros(len(t), bool)
        for task in np.unique(task_of):
            k = task_of == task
            data = self.task_bytes(plan, int(task), done.get(int(task)))
            got[k] = ((data[pos[k] - plan.tasks[task, TSTART]] >> (bit[k] & 7)) & 1).astype(bool)
        out = np.zeros(len(found), bool)
        out[found] = got
        return out

    def sampling(self):
        """The kernels.Sampling the matrix was computed with (None: one ray between centres)."""
        from .kernels import Sampling

        d = self.rs.root["visibility"].attrs.get("sampling") if "visibility" in self.rs.root else None
        return None if d is None else Sampling(**d)


# ----------------------------------------------------------------------------- view factors
#
#   viewfactors/tasks/<task>-ij  (k, 2) int32: facet pairs (i, j), original facet ids, i != j
#   viewfactors/tasks/<task>-f   (k, 3) float64: [F_ij (obstructed), F_ij unobstructed, proven
#                                bound of the cheap kernel's error on the unobstructed value (0
#                                where the exact integral was used)]; F_ji = F_ij A_i / A_j
#   viewfactors/tasks/<task>-drop (d, 4) float64: cluster pairs dropped by the cut-off: [node a,
#                                node b, bound from any facet of a to b, from any facet of b to a]
#   viewfactors/matrix/          indptr (n + 1,) int64, indices (nnz,) int32, data (nnz,) float64:
#                                the CSR matrix F (row i: from facet i), balanced if an enclosure;
#                                scale (n,) float64: the balancing factors d (F = d_i d_j F_raw)
#   RUN_DIR/viewfactors.manifest.jsonl: one line per finished task (crc32, counts), after a head
#                                line naming the inputs it belongs to


def _vf_tasks(store_path: str) -> str:
    return os.path.join(store_path, "viewfactors", "tasks")


def _vf_crc(ij: np.ndarray, f: np.ndarray, drop: np.ndarray) -> int:
    c = zlib.crc32(np.ascontiguousarray(ij, np.int32).tobytes())
    c = zlib.crc32(np.ascontiguousarray(f, np.float64).tobytes(), c)
    return zlib.crc32(np.ascontiguousarray(drop, np.float64).tobytes(), c)


def write_vf_task(store_path: str, task: int, ij: np.ndarray, f: np.ndarray,
                  drop: np.ndarray) -> dict:
    """Write one view-factor task's pairs (called on the workers); returns {crc, n, nd} for the
    manifest."""
    zarr = _zarr()
    ij = np.ascontiguousarray(ij, np.int32).reshape(-1, 2)
    f = np.ascontiguousarray(f, np.float64).reshape(-1, 3)
    drop = np.ascontiguousarray(drop, np.float64).reshape(-1, 4)
    g = zarr.open_group(_vf_tasks(store_path), mode="a")
    for name, a in (("ij", ij), ("f", f), ("drop", drop)):
        _array(g, f"{task}-{name}", data=a, chunks=_chunks(a) if a.size else (1,) + a.shape[1:],
                       overwrite=True)
    return {"crc": _vf_crc(ij, f, drop), "n": int(len(ij)), "nd": int(len(drop))}


def read_vf_task(store_path: str, task: int, entry: dict):
    """One task's (ij, f, drop), checked against its manifest entry; StoreError if missing or
    corrupted."""
    zarr = _zarr()
    try:
        g = zarr.open_group(_vf_tasks(store_path), mode="r")
        ij, f, drop = (g[f"{task}-{k}"][...] for k in ("ij", "f", "drop"))
    except Exception:  # missing or unreadable chunk
        ij = None
    if ij is None or len(ij) != entry["n"] or _vf_crc(ij, f, drop) != entry["crc"]:
        run_dir = os.path.dirname(store_path)
        raise StoreError(f"view-factor task {task} of {run_dir} is missing or corrupted "
                         f"(checksum): run radiosity viewfactors again with --resume --out {run_dir}")
    return ij, f, drop


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
            f.write(json.dumps(entry, default=_json_default) + "\n")
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
                f.write(json.dumps(e, default=_json_default) + "\n")
        os.replace(tmp, self.path)


def vf_manifest(run_dir: str) -> Manifest:
    return Manifest(os.path.join(run_dir, "viewfactors.manifest.jsonl"))


def vf_token(rs: RunStore) -> str | None:
    """The inputs token of the view factors in this store (None: none started)."""
    if "viewfactors" not in rs.root:
        return None
    return rs.root["viewfactors"].attrs.get("token")


def create_vf(rs: RunStore, token: str, attrs: dict) -> None:
    """A fresh viewfactors group (an old one and its manifest are dropped)."""
    if "viewfactors" in rs.root:
        del rs.root["viewfactors"]
    g = rs.root.create_group("viewfactors")
    g.create_group("tasks")
    g.update_attributes({"token": token, **attrs})
    vf_manifest(rs.run_dir).create(token)


def write_vf_matrix(rs: RunStore, indptr, indices, data, scale, attrs: dict) -> None:
    """The assembled CSR matrix (and balancing factors) into viewfactors/matrix."""
    rs.write_arrays("viewfactors/matrix", {"indptr": np.asarray(indptr, np.int64),
                                            "indices": np.asarray(indices, np.int32),
                                            "data": np.asarray(data, np.float64),
                                            "scale": np.asarray(scale, np.float64)}, attrs)


def read_vf_matrix(rs: RunStore) -> dict:
    """indptr, indices, data, scale of the stored matrix (StoreError if there is none)."""
    if "viewfactors/matrix" not in rs.root:
        raise StoreError(f"{rs.run_dir} has no view-factor matrix: run radiosity viewfactors")
    return rs.read_arrays("viewfactors/matrix")


# ----------------------------------------------------------------------------- hierarchical links
# (--method hierarchical, links.py). Per link task, in group `links/`:
#   <task>-links  (k,) LINK_DTYPE, 46 bytes a link: both nodes as (original, heap code; see
#                 hierarchy.py), F_pq, F_qp (unoccluded form factors, p -> q and q -> p), the
#                 visible fraction v and the sides sp, sq (0 front, 1 back) that face
#   <task>-nodes  (j,) NODE_DTYPE: the nodes the task split below the camera's partition (12 bytes each)
# one array each per task (so a task writes only its own chunks), checked by a crc32 over both in
# RUN_DIR/links.manifest.jsonl (first line: the plan token; then one line per finished task).
# Group `hierarchy/`: the node table of the union tree and the leaves (hierarchy.NodeTable).

LINK_DTYPE = np.dtype([("po", "<i4"), ("pc", "<u8"), ("qo", "<i4"), ("qc", "<u8"),
                       ("fpq", "<f8"), ("fqp", "<f8"), ("v", "<f4"), ("sp", "i1"), ("sq", "i1")])
NODE_DTYPE = np.dtype([("o", "<i4"), ("c", "<u8")])
LINKS_MANIFEST = "links.manifest.jsonl"


def links_path(store_path: str) -> str:
    return os.path.join(store_path, "links")


def _links_crc(links: np.ndarray, nodes: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(nodes).view(np.uint8).tobytes(),
                      zlib.crc32(np.ascontiguousarray(links).view(np.uint8).tobytes()))


def write_links(store_path: str, task: int, links: np.ndarray, nodes: np.ndarray) -> dict:
    """Write one link task's links (k,) LINK_DTYPE and split-off nodes (j,) NODE_DTYPE (called
    on the workers); returns {crc, n, nx} for the manifest."""
    links = np.ascontiguousarray(links, LINK_DTYPE)
    nodes = np.ascontiguousarray(nodes, NODE_DTYPE)
    zarr = _zarr()
    g = zarr.open_group(links_path(store_path), mode="r+")
    for name, a in (("links", links), ("nodes", nodes)):
        if name == "nodes" and not len(a):  # most tasks split nothing off: no array (15 ms)
            continue
        raw = a.view(np.uint8).reshape(-1)
        g.create_array(f"{task}-{name}", data=raw, chunks=_chunks(raw) if len(raw) else (1,),
                       overwrite=True, compressors=record_compressors(a.dtype.itemsize))
    return {"crc": _links_crc(links, nodes), "n": int(len(links)), "nx": int(len(nodes))}


def read_links(store_path: str, task: int, entry: dict):
    """One link task's (links (k,) LINK_DTYPE, nodes (j,) NODE_DTYPE), checked against its
    manifest entry {crc, n, nx}; a missing or altered task raises StoreError. Called on the
    workers."""
    zarr = _zarr()
    links = nodes = None
    try:
        g = zarr.open_group(links_path(store_path), mode="r")
        links = np.ascontiguousarray(g[f"{task}-links"][...]).view(LINK_DTYPE)
        nodes = (np.ascontiguousarray(g[f"{task}-nodes"][...]).view(NODE_DTYPE) if entry["nx"]
                 else np.zeros(0, NODE_DTYPE))
    except Exception:  # missing, unreadable, or of a length that is no whole record
        pass
    if links is None or len(links) != entry["n"] or len(nodes) != entry["nx"] \
            or _links_crc(links, nodes) != entry["crc"]:
        run_dir = os.path.dirname(store_path)
        raise StoreError(f"link task {task} of {run_dir} is missing or corrupted (checksum): run "
                         f"radiosity visibility {run_dir} --method hierarchical --resume")
    return links, nodes


class LinkStore:
    """The links group of a run store: the task plan (pairs of originals per task), the links
    of each task, the manifest, and the node table (group hierarchy)."""

    def __init__(self, rs: RunStore):
        self.rs = rs
        self.manifest = os.path.join(rs.run_dir, LINKS_MANIFEST)

    def create(self, pairs: np.ndarray, first: np.ndarray, token: str, attrs: dict) -> None:
        """A fresh links group for tasks over `pairs` (t, 2) int64 [I, J]; task k holds pairs
        first[k]:first[k + 1]. Drops old links, node table, solution and manifest."""
        root = self.rs.root
        for g in ("links", "hierarchy", "solution"):
            if g in root:
                del root[g]
        g = root.create_group("links")
        for name, a in (("pairs", pairs), ("first", first)):
            a = np.ascontiguousarray(a, np.int64)
            _array(g, name, data=a, chunks=_chunks(a) if a.size else a.shape or (1,))
        g.update_attributes({"token": token, **attrs})
        Manifest(self.manifest).create(token)

    def token(self) -> str | None:
        if "links" not in self.rs.root:
            return None
        return self.rs.root["links"].attrs.get("token")

    def attrs(self) -> dict:
        return dict(self.rs.root["links"].attrs)

    def plan(self):
        """(pairs (t, 2) int64, first (k + 1,) int64) of the stored task plan."""
        g = self.rs.root["links"]
        return g["pairs"][...], g["first"][...]

    @staticmethod
    def _line(task: int, e: dict) -> dict:
        return {"task": int(task), "crc": int(e["crc"]), "n": int(e["n"]), "nx": int(e["nx"]),
                "counts": [int(c) for c in e["counts"]]}

    def record(self, task: int, result: dict) -> None:
        """Append one finished task to the manifest (the master is its only writer)."""
        Manifest(self.manifest).record(self._line(task, result))

    def rewrite_manifest(self, token: str, entries: dict) -> None:
        Manifest(self.manifest).rewrite(token, {t: self._line(t, e) for t, e in entries.items()})

    def finished(self, token: str) -> dict:
        """task -> manifest entry, for the plan `token` (a torn last line is ignored)."""
        return Manifest(self.manifest).finished(token)

    def verify(self, task: int, entry: dict) -> bool:
        try:
            read_links(self.rs.path, task, entry)
        except StoreError:
            return False
        return True

    def require(self):
        """(token, (pairs, first), finished entries), or a StoreError saying what to run."""
        token = self.token()
        if token is None:
            raise StoreError(f"{self.rs.run_dir} has no links yet: run radiosity visibility "
                             f"{self.rs.run_dir} --method hierarchical")
        return token, self.plan(), self.finished(token)

    def write_nodes(self, table: dict, attrs: dict) -> None:
        """The node table and leaves (hierarchy.NodeTable.arrays()) of the finished links."""
        self.rs.write_arrays("hierarchy", table, attrs)

    def read_nodes(self) -> dict:
        return self.rs.read_arrays("hierarchy")

