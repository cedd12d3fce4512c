"""The pairs method's part of the run store: the packed visibility bits, the partly visible
pairs of sampled kernels, and the visibility task manifest (layout: docs/src/reference/run-directory.md).

    visibility/bits  (total,) uint8, chunked: bit-packed tiles (bit order in plan.py)
    visibility/tiles, tasks, culled: the plan (plan.VisibilityPlan)
    visibility/partial/<task>-pairs (k, 3) int64 [a, b, visible rays], <task>-phi (k,) float64
    RUN_DIR/visibility.manifest.jsonl: one line per finished task (crc32, counts)
"""

from __future__ import annotations

import os
import zlib

import numpy as np

from radiosity.errors import StoreError
from radiosity.runtime.store import Manifest, RunStore, chunks_of, create_array, fsync_paths, zarr_module
def _entry(task: int, e: dict) -> dict:
    """A manifest line: task, crc32 and length of its bytes, counters, its partial pairs' checksum."""
    line = {"task": int(task), "crc": int(e["crc"]), "nbytes": int(e["nbytes"]),
            "counts": [int(c) for c in e["counts"]]}
    if "partial" in e:
        line["partial"] = {"crc": int(e["partial"]["crc"]), "n": int(e["partial"]["n"])}
    return line


def bits_path(store_path: str) -> str:
    return os.path.join(store_path, "visibility", "bits")


def write_bits(store_path: str, start: int, buf: np.ndarray) -> None:
    """Write a task's bytes at `start` (chunk-aligned, whole chunks) and make them durable
    (fsync of its chunk files and their folder) before the task reports back: a task enters
    the manifest only after its bytes are on disk. Called on the workers."""
    zarr = zarr_module()
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
        zarr = zarr_module()
        g = zarr.open_group(partial_path(store_path), mode="r+")
        create_array(g, f"{task}-pairs", data=pairs, chunks=chunks_of(pairs), overwrite=True)
        create_array(g, f"{task}-phi", data=phi, chunks=chunks_of(phi), overwrite=True)
    return {"crc": _partial_crc(pairs, phi), "n": int(len(pairs))}


def read_partial(store_path: str, task: int, entry: dict):
    """The partly visible pairs of one task, checked against its manifest entry {crc, n}:
    pairs (k, 3) int64 [a, b, visible rays], phi (k,). Called on the workers."""
    if entry["n"] == 0:
        pairs, phi = np.zeros((0, 3), np.int64), np.zeros(0)
    else:
        zarr = zarr_module()
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
    zarr = zarr_module()
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
        create_array(g, "bits", shape=(max(plan.total, 1),), dtype="uint8", chunks=(plan.chunk,),
                       fill_value=0)
        for name in ("tiles", "tasks", "culled"):
            a = getattr(plan, name)
            create_array(g, name, data=np.ascontiguousarray(a), chunks=chunks_of(a))
        g.create_group("partial")
        g.update_attributes({"token": token, "chunk": plan.chunk, "total": plan.total,
                        "unit": plan.unit, "blocks_culled": plan.blocks_culled, **attrs})
        Manifest(self.manifest).create(token)

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
        from radiosity.methods.pairs.plan import VisibilityPlan

        g = self.rs.root["visibility"]
        at = g.attrs
        culled = g["culled"][...]
        return VisibilityPlan(tiles=g["tiles"][...], tasks=g["tasks"][...], culled=culled,
                              chunk=int(at["chunk"]), total=int(at["total"]), unit=at["unit"],
                              blocks_culled=int(at.get("blocks_culled", len(culled))))

    def rewrite_manifest(self, token: str, entries: dict) -> None:
        """Keep only `entries` (task -> entry) in the manifest."""
        Manifest(self.manifest).rewrite(token, {t: _entry(t, e) for t, e in entries.items()})

    def record(self, task: int, result: dict) -> None:
        """Append one finished task to the manifest (the master is its only writer)."""
        Manifest(self.manifest).record(_entry(task, result))

    def finished(self, token: str) -> dict:
        """task -> manifest entry, for the plan `token` (a torn last line is ignored)."""
        return Manifest(self.manifest).finished(token)

    def read_task(self, plan, task: int, nbytes: int | None = None) -> np.ndarray:
        """The bytes of one task (unpadded if nbytes is given)."""
        from radiosity.methods.pairs.plan import TBYTES, TSTART

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
        from radiosity.methods.pairs.plan import TSTART

        return read_task_checked(self.rs.path, task, int(plan.tasks[task, TSTART]),
                                 int(entry["nbytes"]), int(entry["crc"]))

    def iter_tiles(self):
        """Yield (I, J, r0, r1, bits (r1 - r0, nJ) bool) for every stored tile, task by task
        (the bit layout is in plan.py; every task's bytes are verified first)."""
        from radiosity.methods.pairs.plan import I, J, NBYTES, NCOLS, R0, R1, START, TSTART

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
        from radiosity.methods.pairs.plan import START, TSTART

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
        from radiosity.core.kernels import Sampling

        d = self.rs.root["visibility"].attrs.get("sampling") if "visibility" in self.rs.root else None
        return None if d is None else Sampling(**d)
