"""The view-factor stage's part of the run store: per-task pairs (viewfactors/tasks/<task>-ij,
-f, -drop), the CSR matrix (viewfactors/matrix/), and the manifest of finished tasks
(RUN_DIR/viewfactors.manifest.jsonl, one line per task with its crc32); `VFLedger` is that
store and manifest as the ledger of runtime.stage.run_stage. The arrays' shapes and meaning:
docs/src/design/viewfactors-method.md ("Store layout").
"""

from __future__ import annotations

import os
import zlib

import numpy as np

from radiosity.errors import StoreError
from radiosity.runtime.store import (STORE, Manifest, RunStore, chunks_of, create_array,
                                     zarr_module)

#: What the manifest keeps of a task's result (the rest: timing for the busy figures).
ENTRY_KEYS = ("task", "crc", "n", "nd", "counts", "times", "cpu")


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
    zarr = zarr_module()
    ij = np.ascontiguousarray(ij, np.int32).reshape(-1, 2)
    f = np.ascontiguousarray(f, np.float64).reshape(-1, 3)
    drop = np.ascontiguousarray(drop, np.float64).reshape(-1, 4)
    g = zarr.open_group(_vf_tasks(store_path), mode="a")
    for name, a in (("ij", ij), ("f", f), ("drop", drop)):
        create_array(g, f"{task}-{name}", data=a, chunks=chunks_of(a) if a.size else (1,) + a.shape[1:],
                       overwrite=True)
    return {"crc": _vf_crc(ij, f, drop), "n": int(len(ij)), "nd": int(len(drop))}


def read_vf_task(store_path: str, task: int, entry: dict):
    """One task's (ij, f, drop), checked against its manifest entry; StoreError if missing or
    corrupted."""
    zarr = zarr_module()
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


class VFLedger:
    """The view factors of run directory `run_dir` as a runtime.stage.Ledger: the store's
    viewfactors group (its token, its tasks) and the manifest. `rs`: the open RunStore, once
    token() found one or create() made one."""

    def __init__(self, run_dir: str):
        self.run_dir = os.path.abspath(run_dir)
        self.path = os.path.join(self.run_dir, STORE)
        self.manifest = vf_manifest(self.run_dir)
        self.rs: RunStore | None = None

    def token(self) -> str | None:
        if not os.path.exists(self.path):
            return None
        self.rs = RunStore(self.run_dir, "r+")
        return vf_token(self.rs)

    def finished(self, token: str) -> dict:
        return self.manifest.finished(token)

    def verify(self, task: int, entry: dict) -> bool:
        try:
            read_vf_task(self.path, task, entry)
        except StoreError:
            return False
        return True

    def rewrite_manifest(self, token: str, entries: dict) -> None:
        self.manifest.rewrite(token, entries)

    def record(self, task: int, result: dict) -> None:
        self.manifest.record({k: result[k] for k in ENTRY_KEYS})

    def create(self, token: str, attrs: dict, sources, facets: dict) -> None:
        """A fresh store: the facets' arrays (`facets`, name -> array) and an empty
        viewfactors group with its manifest."""
        self.rs = RunStore(self.run_dir, "w")
        self.rs.set_attrs(kind="viewfactors", sources=list(sources))
        self.rs.write_arrays("facets", facets)
        create_vf(self.rs, token, attrs)


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


def kept(rs: RunStore) -> str | None:
    """What a rerun with --resume reuses of the view factors ("14 of 18 view-factor tasks"),
    or None when the store holds none; as the methods' kept (methods/base.py)."""
    token = vf_token(rs)
    if token is None:
        return None
    total = rs.root["viewfactors"].attrs.get("tasks")
    done = len(vf_manifest(rs.run_dir).finished(token))
    return f"{done} of {total} view-factor tasks" if total is not None else f"{done} view-factor tasks"
