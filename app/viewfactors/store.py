"""The view-factor stage's part of the run store: per-task pairs, the manifest, the CSR matrix.
   viewfactors/tasks/<task>-ij  (k, 2) int32: facet pairs (i, j), original facet ids, i != j
   viewfactors/tasks/<task>-f   (k, 3) float64: [F_ij (obstructed), F_ij unobstructed, proven
                                bound of the cheap kernel's error on the unobstructed value (0
                                where the exact integral was used)]; F_ji = F_ij A_i / A_j
   viewfactors/tasks/<task>-drop (d, 4) float64: cluster pairs dropped by the cut-off: [node a,
                                node b, bound from any facet of a to b, from any facet of b to a]
   viewfactors/matrix/          indptr (n + 1,) int64, indices (nnz,) int32, data (nnz,) float64:
                                the CSR matrix F (row i: from facet i), balanced if an enclosure;
                                scale (n,) float64: the balancing factors d (F = d_i d_j F_raw)
   RUN_DIR/viewfactors.manifest.jsonl: one line per finished task (crc32, counts), after a head
                                line naming the inputs it belongs to
"""

from __future__ import annotations

import os
import zlib

import numpy as np

from radiosity.errors import StoreError
from radiosity.runtime.store import Manifest, RunStore, chunks_of, create_array, zarr_module

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
