"""The hierarchical method's part of the run store: links and split-off nodes per link task,
the task plan, the manifest, and the node table.
 (--method hierarchical, links.py). Per link task, in group `links/`:
   <task>-links  (k,) LINK_DTYPE, 46 bytes a link: both nodes as (original, heap code; see
                 hierarchy.py), F_pq, F_qp (unoccluded form factors, p -> q and q -> p), the
                 visible fraction v and the sides sp, sq (0 front, 1 back) that face
   <task>-nodes  (j,) NODE_DTYPE: the nodes the task split below the camera's partition (12 bytes each)
 The leaves' first bounce (solve/direct.py), per direct task, in group `direct/`:
   <task>        (n, 2, 3) float64 L1 of the task's leaves, per side and colour

Design notes and measurements: docs/src/design/methods-hierarchical-store.md.
"""

from __future__ import annotations

import os
import zlib

import numpy as np

from radiosity.errors import StoreError
from radiosity.runtime.store import (ARRAY_CONFIG, Manifest, RunStore, chunks_of, create_array,
                                     record_compressors, zarr_module)

LINK_DTYPE = np.dtype([("po", "<i4"), ("pc", "<u8"), ("qo", "<i4"), ("qc", "<u8"),
                       ("fpq", "<f8"), ("fqp", "<f8"), ("v", "<f4"), ("sp", "i1"), ("sq", "i1")])
NODE_DTYPE = np.dtype([("o", "<i4"), ("c", "<u8")])
LINKS_MANIFEST = "links.manifest.jsonl"
DIRECT_MANIFEST = "direct.manifest.jsonl"


#: The cluster layer that this process last wrote, handed to the next read of the same store
#: and token (the render's solve right after its link stage) instead of decompressed again
#: (docs/src/design/methods-hierarchical-clusters.md, "Less work a link"). One entry, held
#: until that read or the next create: later reads go to the store.
_HANDOFF: dict = {}


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
    zarr = zarr_module()
    g = zarr.open_group(links_path(store_path), mode="r+")
    for name, a in (("links", links), ("nodes", nodes)):
        if name == "nodes" and not len(a):  # most tasks split nothing off: no array (15 ms)
            continue
        raw = a.view(np.uint8).reshape(-1)
        g.create_array(f"{task}-{name}", data=raw, chunks=chunks_of(raw) if len(raw) else (1,),
                       overwrite=True, compressors=record_compressors(a.dtype.itemsize),
                       config=ARRAY_CONFIG)
    return {"crc": _links_crc(links, nodes), "n": int(len(links)), "nx": int(len(nodes))}


def read_links(store_path: str, task: int, entry: dict):
    """One link task's (links (k,) LINK_DTYPE, nodes (j,) NODE_DTYPE), checked against its
    manifest entry {crc, n, nx}; a missing or altered task raises StoreError. Called on the
    workers."""
    zarr = zarr_module()
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


class _TaskLedger:
    """The finished tasks of a stage, one manifest line each (runtime Manifest), and a check
    that a task's stored chunk still reads back: what LinkStore and DirectStore share. A
    subclass says what a line keeps (`_line`) and how its chunk is read (`_read`, raising
    StoreError)."""

    manifest: str
    rs = None

    @staticmethod
    def _line(task: int, e: dict) -> dict:
        raise NotImplementedError

    @staticmethod
    def _read(store_path: str, task: int, entry: dict):
        raise NotImplementedError

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
            self._read(self.rs.path, task, entry)
        except StoreError:
            return False
        return True


class LinkStore(_TaskLedger):
    """The links group of a run store: the task plan (pairs of originals per task), the links
    of each task, the manifest, and the node table (group hierarchy)."""

    def __init__(self, rs: RunStore):
        self.rs = rs
        self.manifest = os.path.join(rs.run_dir, LINKS_MANIFEST)

    def create(self, pairs: np.ndarray, first: np.ndarray, token: str, attrs: dict,
               clusters: dict | None = None) -> None:
        """A fresh links group for tasks over `pairs` (t, 2) int64 [I, J]; task k holds pairs
        first[k]:first[k + 1]; with `clusters` (clusters.ClusterLinks.arrays()), the cluster
        layer in group clusters/. Drops old links, cluster links, node table, solution and
        manifest."""
        root = self.rs.root
        for g in ("links", "clusters", "hierarchy", "solution"):
            if g in root:
                del root[g]
        _HANDOFF.clear()
        if clusters is not None:
            self.rs.write_arrays("clusters", clusters, {"token": token})
            _HANDOFF[(os.path.realpath(self.rs.path), token)] = dict(clusters)
        g = root.create_group("links")
        for name, a in (("pairs", pairs), ("first", first)):
            a = np.ascontiguousarray(a, np.int64)
            create_array(g, name, data=a, chunks=chunks_of(a) if a.size else a.shape or (1,))
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

    _read = staticmethod(read_links)

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

    def read_clusters(self, token: str) -> dict | None:
        """The cluster layer's arrays (clusters.ClusterLinks fields) of the links `token`, or
        None when the run has none."""
        if "clusters" not in self.rs.root:
            return None
        if self.rs.group_attrs("clusters").get("token") != token:
            raise StoreError(f"{self.rs.run_dir} has cluster links of other links: run radiosity "
                             f"visibility {self.rs.run_dir} --method hierarchical")
        handed = _HANDOFF.pop((os.path.realpath(self.rs.path), token), None)
        return handed if handed is not None else self.rs.read_arrays("clusters")


# ----------------------------------------------------------------------------- the first bounce

def direct_path(store_path: str) -> str:
    return os.path.join(store_path, "direct")


def _crc(a: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(a).view(np.uint8).tobytes())


def write_direct(store_path: str, task: int, l1: np.ndarray) -> dict:
    """Write one direct task's L1 (n, 2, 3) float64 as one chunk (called on the workers);
    returns {crc, n} for the manifest."""
    a = np.ascontiguousarray(l1, np.float64)
    g = zarr_module().open_group(direct_path(store_path), mode="r+")
    create_array(g, str(task), data=a, chunks=a.shape if a.size else (1, 2, 3), overwrite=True)
    return {"crc": _crc(a), "n": int(len(a))}


def read_direct(store_path: str, task: int, entry: dict) -> np.ndarray:
    """One direct task's L1 (n, 2, 3), checked against its manifest entry {crc, n}; a missing or
    altered task raises StoreError."""
    a = None
    try:
        a = np.ascontiguousarray(zarr_module().open_group(direct_path(store_path), mode="r")
                                 [str(task)][...], np.float64)
    except Exception:  # missing or unreadable
        pass
    if a is None or len(a) != entry["n"] or _crc(a) != entry["crc"]:
        raise StoreError(f"direct task {task} of {os.path.dirname(store_path)} is missing or "
                         "corrupted (checksum): it is computed again on the next solve")
    return a


class DirectStore(_TaskLedger):
    """The direct group of a run store (solve/direct.py's ledger): the task plan (first leaf of
    each task), one array of L1 per task, the manifest."""

    def __init__(self, rs: RunStore):
        self.rs = rs
        self.manifest = os.path.join(rs.run_dir, DIRECT_MANIFEST)

    def create(self, first: np.ndarray, token: str, attrs: dict) -> None:
        """A fresh direct group for tasks over leaves first[k]:first[k + 1]."""
        root = self.rs.root
        if "direct" in root:
            del root["direct"]
        g = root.create_group("direct")
        a = np.ascontiguousarray(first, np.int64)
        create_array(g, "first", data=a, chunks=chunks_of(a))
        g.update_attributes({"token": token, **attrs})
        Manifest(self.manifest).create(token)

    def token(self) -> str | None:
        if "direct" not in self.rs.root:
            return None
        return self.rs.root["direct"].attrs.get("token")

    @staticmethod
    def _line(task: int, e: dict) -> dict:
        return {"task": int(task), "crc": int(e["crc"]), "n": int(e["n"]),
                "counts": [int(c) for c in e["counts"]]}

    _read = staticmethod(read_direct)
