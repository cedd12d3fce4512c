"""The split trees as a hierarchy of polygons (SPEC §8): canonical node names and node tables.

Design notes and measurements: docs/src/design/scene-splittrees.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from radiosity.core.geometry import polygon_properties
from radiosity.scene.subdivide import TIE
from radiosity.core.bundles import Elements, Partition

MAX_DEPTH = 60  # paths are 64-bit; subdivide.py refuses deeper trees too
#: Links per leaf with the defaults, low and high, for estimates before a run (`radiosity
#: plan`). MEASURED by benchmarks/bench_hierarchy.py (epsilon auto, hidden sub-elements split,
#: 4 link rays): Cornell box 37.7 at 64^2, 33.4 at 128^2, 29.5 at 256^2, 25.3 at 512^2;
#: room-2400 (2 400 originals) 48.9 at 256^2.
LINKS_PER_LEAF = (25.0, 49.0)


# ----------------------------------------------------------------------------- codes

def heap_code(path: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """The one-word node code path | 1 << (63 - depth), (k,) uint64."""
    path = np.asarray(path, np.uint64)
    depth = np.asarray(depth, np.int64)
    return path | np.left_shift(np.uint64(1), (63 - depth).astype(np.uint64))


def decode(code: np.ndarray):
    """(path (k,) uint64, depth (k,) int64) of heap codes (inverse of heap_code)."""
    code = np.asarray(code, np.uint64)
    low = code & (~code + np.uint64(1))  # lowest set bit: the sentinel
    depth = 63 - np.floor(np.log2(low.astype(np.float64))).astype(np.int64)
    return code ^ low, depth


@numba.njit(cache=True, nogil=True, inline="always")
def depth_bit(depth):
    return np.uint64(1) << np.uint64(63 - depth)


@numba.njit(cache=True, nogil=True, inline="always")
def _code(path, depth):
    return path | depth_bit(depth)


# ----------------------------------------------------------------------------- geometry

@numba.njit(cache=True, nogil=True, inline="always")
def _norm3(ax, ay, az):
    return np.sqrt(ax * ax + ay * ay + az * az)


@numba.njit(cache=True, nogil=True)
def split_one(v, nv, c0, c1):
    """Split polygon v[:nv] ((4, 3), nv in {3, 4}) by the seed's rule into c0, c1 (4, 3): a
    triangle by the median to the midpoint of its longest edge, a quad by the segment joining
    the midpoints of its two longer opposite sides. Bit-identical to subdivide.split_polygons
    (same operations in the same order; ties within the relative TIE go to the first)."""
    if nv == 3:
        e0 = _norm3(v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2])
        e1 = _norm3(v[2, 0] - v[1, 0], v[2, 1] - v[1, 1], v[2, 2] - v[1, 2])
        e2 = _norm3(v[0, 0] - v[2, 0], v[0, 1] - v[2, 1], v[0, 2] - v[2, 2])
        mx = max(e0, max(e1, e2)) * (1.0 - TIE)
        s = 0 if e0 >= mx else (1 if e1 >= mx else 2)
        i0, i1, i2 = s, (s + 1) % 3, (s + 2) % 3
        for k in range(3):
            mid = 0.5 * (v[i0, k] + v[i1, k])
            c0[0, k] = v[i0, k]
            c0[1, k] = mid
            c0[2, k] = v[i2, k]
            c0[3, k] = v[i2, k]
            c1[0, k] = mid
            c1[1, k] = v[i1, k]
            c1[2, k] = v[i2, k]
            c1[3, k] = v[i2, k]
    else:
        e = np.empty(4)
        for i in range(4):
            j = (i + 1) % 4
            e[i] = _norm3(v[j, 0] - v[i, 0], v[j, 1] - v[i, 1], v[j, 2] - v[i, 2])
        p0 = e[0] + e[2]
        p1 = e[1] + e[3]
        mx = max(p0, p1) * (1.0 - TIE)
        s = 0 if p0 >= mx else 1
        w0, w1, w2, w3 = s, (s + 1) % 4, (s + 2) % 4, (s + 3) % 4
        for k in range(3):
            p = 0.5 * (v[w0, k] + v[w1, k])
            q = 0.5 * (v[w2, k] + v[w3, k])
            c0[0, k] = v[w0, k]
            c0[1, k] = p
            c0[2, k] = q
            c0[3, k] = v[w3, k]
            c1[0, k] = p
            c1[1, k] = v[w1, k]
            c1[2, k] = v[w2, k]
            c1[3, k] = q


@numba.njit(cache=True, nogil=True)
def polygon_area_center(v, out_c):
    """Area and area centroid (into out_c (3,)) of polygon v (4, 3) (a triangle repeats vertex
    2 in slot 3): the two triangles (0, 1, 2), (0, 2, 3), as geometry.polygon_properties."""
    ax, ay, az = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
    bx, by, bz = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1], v[2, 2] - v[0, 2]
    cx, cy, cz = v[3, 0] - v[0, 0], v[3, 1] - v[0, 1], v[3, 2] - v[0, 2]
    a1 = 0.5 * _norm3(ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx)
    a2 = 0.5 * _norm3(by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx)
    area = a1 + a2
    safe = area if area > 0 else 1.0
    for k in range(3):
        g1 = (v[0, k] + v[1, k] + v[2, k]) / 3.0
        g2 = (v[0, k] + v[2, k] + v[3, k]) / 3.0
        out_c[k] = (g1 * a1 + g2 * a2) / safe
    return area


# ----------------------------------------------------------------------------- the partition's tree

@dataclass(frozen=True)
class TreeNodes:
    """Every node of the partition's split trees (k nodes, in the partition's node order, which
    is depth-first pre-order per original).

    orig (k,) int32; depth (k,) int32; path (k,) uint64; parent (k,) int64 (-1 at a root);
    child (k, 2) int32 (-1 at a leaf); verts (k, 4, 3) float64, nverts (k,) int8: the node's
    polygon; area (k,) float64; center (k, 3) float64 (area centroid; equal to the partition's at
    the leaves); lo, hi (k,) int64: the node's sub-elements are lo:hi; leaf (k,) int32 (-1 inside).
    """

    orig: np.ndarray
    depth: np.ndarray
    path: np.ndarray
    parent: np.ndarray
    child: np.ndarray
    verts: np.ndarray
    nverts: np.ndarray
    area: np.ndarray
    center: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    leaf: np.ndarray


@numba.njit(cache=True, nogil=True)
def _tree_walk(root_verts, root_nverts, root, child, leaf, verts, nverts, orig, depth, path,
               parent, lo, hi):
    """Fill the node arrays top-down (parents precede children in the partition's order)."""
    k = child.shape[0]
    for o in range(root.shape[0]):
        r = root[o]
        verts[r] = root_verts[o]
        nverts[r] = root_nverts[o]
        orig[r] = o
        parent[r] = -1
    c0 = np.empty((4, 3))
    c1 = np.empty((4, 3))
    for i in range(k):
        a, b = child[i, 0], child[i, 1]
        if a < 0:
            continue
        split_one(verts[i], nverts[i], c0, c1)
        verts[a] = c0
        verts[b] = c1
        for x in (a, b):
            nverts[x] = nverts[i]
            orig[x] = orig[i]
            depth[x] = depth[i] + 1
            parent[x] = i
        path[a] = path[i]
        path[b] = path[i] | depth_bit(depth[i])
    for i in range(k - 1, -1, -1):  # leaf ranges, bottom-up
        if leaf[i] >= 0:
            lo[i] = leaf[i]
            hi[i] = leaf[i] + 1
        else:
            lo[i] = lo[child[i, 0]]
            hi[i] = hi[child[i, 1]]


def tree_nodes(part: Partition, elements: Elements) -> TreeNodes:
    """The node table of the partition's split trees (polygons re-split from the originals)."""
    k = len(part.child)
    verts = np.zeros((k, 4, 3))
    nverts = np.zeros(k, np.int8)
    orig = np.zeros(k, np.int32)
    depth = np.zeros(k, np.int32)
    path = np.zeros(k, np.uint64)
    parent = np.zeros(k, np.int64)
    lo = np.zeros(k, np.int64)
    hi = np.zeros(k, np.int64)
    _tree_walk(np.ascontiguousarray(elements.verts, float), np.asarray(elements.nverts, np.int8),
               part.root.astype(np.int64), part.child, part.leaf, verts, nverts, orig, depth, path,
               parent, lo, hi)
    area, _, center = polygon_properties(verts, nverts)
    return TreeNodes(orig=orig, depth=depth, path=path, parent=parent, child=part.child,
                     verts=verts, nverts=nverts, area=area, center=center, lo=lo, hi=hi,
                     leaf=part.leaf)


# ----------------------------------------------------------------------------- the union tree

@dataclass(frozen=True)
class NodeTable:
    """All nodes of a hierarchical run: the partition's trees plus the nodes the link tasks split
    off unseen originals (with their siblings, so leaves tile every original), N nodes in
    depth-first pre-order per original, and the M leaves (the unknowns of the solve).

    orig (N,) int32; path (N,) uint64; depth (N,) int32; code (N,) uint64 (heap codes);
    parent (N,) int64 (-1 at a root); verts (N, 4, 3), nverts (N,) int8; area (N,) polygon area;
    lo, hi (N,) int64: the node's leaves are lo:hi; pnode (N,) int64: the partition node (-1:
    split off an unseen original); noff (n + 1,) int64: nodes of original o are noff[o]:noff[o+1].
    leaf_node (M,) int64: node of each leaf; leaf_sub (M,) int64: the partition sub-element a
    leaf lies in (itself for seen originals); leaf_area (M,) float64.
    """

    orig: np.ndarray
    path: np.ndarray
    depth: np.ndarray
    code: np.ndarray
    parent: np.ndarray
    verts: np.ndarray
    nverts: np.ndarray
    area: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    pnode: np.ndarray
    noff: np.ndarray
    leaf_node: np.ndarray
    leaf_sub: np.ndarray
    leaf_area: np.ndarray

    def __len__(self) -> int:
        return len(self.orig)

    @property
    def leaves(self) -> int:
        return len(self.leaf_node)

    def arrays(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def full_trees(orig: np.ndarray, code: np.ndarray):
    """The nodes needed for nodes (orig, code) to sit in full trees: every ancestor and both
    children of every ancestor. Returns (orig, path, depth) of the unique set, depth >= 1."""
    path, depth = decode(code)
    o_all, p_all, d_all = [], [], []
    for d in range(1, int(depth.max(initial=0)) + 1):
        sel = depth >= d
        if not sel.any():
            break
        # the ancestor at depth d - 1, and its two children at depth d
        keep = np.uint64(0) if d == 1 else ~((np.uint64(1) << np.uint64(64 - (d - 1))) - np.uint64(1))
        anc = path[sel] & keep
        bit = np.uint64(1) << np.uint64(63 - (d - 1))
        o_all += [orig[sel], orig[sel]]
        p_all += [anc, anc | bit]
        d_all += [np.full(int(sel.sum()), d), np.full(int(sel.sum()), d)]
    if not o_all:
        return np.zeros(0, np.int32), np.zeros(0, np.uint64), np.zeros(0, np.int32)
    o = np.concatenate(o_all).astype(np.int64)
    c = heap_code(np.concatenate(p_all), np.concatenate(d_all))
    order = np.lexsort((c, o))  # unique (orig, code): a row-wise np.unique took 0.2 s here
    o, c = o[order], c[order]
    first = np.ones(len(o), bool)
    first[1:] = (o[1:] != o[:-1]) | (c[1:] != c[:-1])
    path, depth = decode(c[first])
    return o[first].astype(np.int32), path, depth.astype(np.int32)


@numba.njit(cache=True, nogil=True)
def _find(orig, path, depth, noff, o, p, d):
    """Index of node (o, p, d) in a table sorted by (orig, path, depth), or -1."""
    lo, hi = noff[o], noff[o + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if path[mid] < p or (path[mid] == p and depth[mid] < d):
            lo = mid + 1
        else:
            hi = mid
    if lo < noff[o + 1] and path[lo] == p and depth[lo] == d:
        return lo
    return -1


@numba.njit(cache=True, nogil=True)
def find_codes(orig, path, depth, noff, qo, qcode):
    """Node indices of (qo, qcode) (heap codes) in a node table, (k,) int64 (-1: not found)."""
    out = np.empty(qo.shape[0], np.int64)
    for i in range(qo.shape[0]):
        c = qcode[i]
        low = c & (~c + np.uint64(1))
        d = 0
        while (np.uint64(1) << np.uint64(63 - d)) != low:
            d += 1
        out[i] = _find(orig, path, depth, noff, qo[i], c ^ low, d)
    return out


@numba.njit(cache=True, nogil=True)
def _table_walk(orig, depth, path, noff, verts, nverts, parent, lo, hi, is_leaf):
    """Parents, polygons of split-off nodes (split from their parents), leaf flags and ranges."""
    N = orig.shape[0]
    c0 = np.empty((4, 3))
    c1 = np.empty((4, 3))
    stack = np.full(MAX_DEPTH + 2, -1, np.int64)
    for i in range(N):
        if depth[i] == 0:
            parent[i] = -1
        else:
            parent[i] = stack[depth[i] - 1]
        stack[depth[i]] = i
        is_leaf[i] = not (i + 1 < N and orig[i + 1] == orig[i] and depth[i + 1] == depth[i] + 1)
    for i in range(N):  # children follow parents: fill polygons that are not yet set
        if nverts[i] == 0:
            p = parent[i]
            split_one(verts[p], nverts[p], c0, c1)
            second = (path[i] & depth_bit(depth[p])) != 0
            verts[i] = c1 if second else c0
            nverts[i] = nverts[p]
    nleaf = 0
    for i in range(N):
        lo[i] = nleaf
        if is_leaf[i]:
            nleaf += 1
    for i in range(N):
        hi[i] = lo[i] + 1 if is_leaf[i] else lo[i]
    for i in range(N - 1, 0, -1):
        p = parent[i]
        if p >= 0 and hi[i] > hi[p]:
            hi[p] = hi[i]
    return nleaf


def node_table(tree: TreeNodes, part: Partition, extra_orig: np.ndarray,
               extra_code: np.ndarray) -> NodeTable:
    """The union tree: the partition's nodes plus split-off nodes (extra_orig, extra_code) below
    its leaves (unseen originals, sub-elements no pixel hits) and their ancestors and siblings (full_trees());
    polygons of the new nodes by split_one."""
    n = len(part.offsets) - 1
    eo, ep, ed = full_trees(np.asarray(extra_orig, np.int32), np.asarray(extra_code, np.uint64))
    o = np.concatenate([tree.orig, eo]).astype(np.int32)
    p = np.concatenate([tree.path, ep]).astype(np.uint64)
    d = np.concatenate([tree.depth, ed]).astype(np.int32)
    pnode = np.concatenate([np.arange(len(tree.orig)), np.full(len(eo), -1)])
    # below a seen original's hidden leaf the closure repeats the partition's nodes above it:
    # the partition's copy (sorted first) is kept
    order = np.lexsort((pnode < 0, d, p, o))
    o, p, d, pnode = o[order], p[order], d[order], pnode[order]
    keep = np.ones(len(o), bool)
    keep[1:] = (o[1:] != o[:-1]) | (p[1:] != p[:-1]) | (d[1:] != d[:-1])
    o, p, d, pnode = o[keep], p[keep], d[keep], pnode[keep]
    N = len(o)
    verts = np.zeros((N, 4, 3))
    nverts = np.zeros(N, np.int8)
    known = pnode >= 0
    verts[known] = tree.verts[pnode[known]]
    nverts[known] = tree.nverts[pnode[known]]
    parent = np.zeros(N, np.int64)
    lo = np.zeros(N, np.int64)
    hi = np.zeros(N, np.int64)
    is_leaf = np.zeros(N, np.bool_)
    noff = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(o, minlength=n), out=noff[1:])
    _table_walk(o, d, p, noff, verts, nverts, parent, lo, hi, is_leaf)
    area, _, _ = polygon_properties(verts, nverts)
    leaf_node = np.nonzero(is_leaf)[0]
    anc = pnode.copy()  # the nearest partition node at or above each node
    for _ in range(MAX_DEPTH + 1):  # parents first: one level per step
        up = np.nonzero(anc < 0)[0]
        if not len(up):
            break
        anc[up] = anc[parent[up]]
    leaf_sub = tree.leaf[anc[leaf_node]]
    if np.any(leaf_sub < 0):
        raise ValueError("a leaf of the union tree is an inner node of the camera partition")
    return NodeTable(orig=o, path=p, depth=d, code=heap_code(p, d), parent=parent, verts=verts,
                     nverts=nverts, area=area, lo=lo, hi=hi, pnode=pnode, noff=noff,
                     leaf_node=leaf_node, leaf_sub=leaf_sub.astype(np.int64),
                     leaf_area=area[leaf_node])


def seen_originals(raster_orig: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: originals that some pixel of the raster sees."""
    e = np.asarray(raster_orig).ravel()
    return np.bincount(e[e >= 0], minlength=n) > 0


def footprint_originals(elements: Elements, hit_e: np.ndarray, hit_p: np.ndarray,
                        hit_cam: np.ndarray, eyes: np.ndarray, pixel: float) -> np.ndarray:
    """(n,) bool: the originals a pixel may show, not only those its centre hits: each hit
    original (hit_e (p,) at points hit_p (p, 3), of cameras hit_cam (p,) at eyes (c, 3)), and
    each other one whose centroid lies within its own radius plus `pixel` (a seen pixel's size,
    subdivide.pixel_size) of a hit point and that faces that point's camera (or is two-sided).
    On a mesh finer than the pixels most originals lie between pixel centres; these count as
    seen here. O(n log p)."""
    from scipy.spatial import cKDTree

    n = len(elements)
    out = np.zeros(n, bool)
    out[np.asarray(hit_e, np.int64)] = True
    idx = np.flatnonzero(~out)
    if pixel <= 0.0 or not len(hit_p) or not len(idx):
        return out
    c = np.asarray(elements.center)[idx]
    radius = np.linalg.norm(elements.verts[idx] - c[:, None, :], axis=2).max(axis=1)
    d, j = cKDTree(hit_p).query(c)
    near = d <= radius + pixel
    idx, c, j = idx[near], c[near], j[near]
    eye = np.asarray(eyes, float)[np.asarray(hit_cam)[j]]
    facing = elements.two_sided[idx] | (np.einsum("ic,ic->i", elements.normal[idx], eye - c) > 0)
    out[idx[facing]] = True
    return out
