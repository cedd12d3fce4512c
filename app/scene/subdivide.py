"""Camera-driven subdivision (seed §3): split elements until each covers at most one pixel.

Design notes and measurements: docs/src/design/scene-subdivide.md.
"""

from __future__ import annotations

import warnings

import numba
import numpy as np

from radiosity.core.geometry import diameter, polygon_properties
from radiosity.core.bundles import Partition
from radiosity.core.tolerances import TOL

TIE = TOL.tie  # lengths within this relative difference count as equal (core.tolerances)


class DepthGuardWarning(UserWarning):
    """An element reached the depth guard with more than one pixel on it."""


# ----------------------------------------------------------------------------- kernels

@numba.njit(cache=True, nogil=True, inline="always")
def _side(px, py, pz, a, m):
    return (px - a[0]) * m[0] + (py - a[1]) * m[1] + (pz - a[2]) * m[2] > 0.0


@numba.njit(cache=True, nogil=True)
def sides(points, a, m):
    """For each point k: is it on the second child's side of split (a[k], m[k])? (n,) bool."""
    n = points.shape[0]
    out = np.zeros(n, np.bool_)
    for k in range(n):
        out[k] = _side(points[k, 0], points[k, 1], points[k, 2], a[k], m[k])
    return out


@numba.njit(cache=True, nogil=True)
def locate(points, orig, root, child, split_a, split_m):
    """Two-level lookup (seed §3.2): the leaf node of the split tree holding each point, given
    its original element (`lookup` maps leaf nodes to sub-elements).

    points (n, 3) float64 on the original's plane; orig (n,) int32 (-1: no element); tree
    arrays of a Partition. Returns (n,) int32 node ids, -1 where orig is -1. O(depth) per point.
    """
    n = points.shape[0]
    out = np.full(n, -1, np.int32)
    for k in range(n):
        o = orig[k]
        if o < 0:
            continue
        node = root[o]
        while child[node, 0] >= 0:
            if _side(points[k, 0], points[k, 1], points[k, 2], split_a[node], split_m[node]):
                node = child[node, 1]
            else:
                node = child[node, 0]
        out[k] = node
    return out


# ----------------------------------------------------------------------------- split geometry

def _rotate(verts: np.ndarray, shift: np.ndarray, n: int) -> np.ndarray:
    idx = (np.arange(n)[None, :] + shift[:, None]) % n
    return np.take_along_axis(verts[:, :n], idx[:, :, None], axis=1)


def _first_max(lengths: np.ndarray) -> np.ndarray:
    """Index of the largest length, the first one among near-ties (relative TIE)."""
    mx = lengths.max(axis=1, keepdims=True)
    return np.argmax(lengths >= mx * (1.0 - TIE), axis=1)


def split_polygons(verts: np.ndarray, nverts: np.ndarray):
    """Split each polygon in two by the seed's rules.

    Returns child0, child1 (k, 4, 3), and the split segment as a point a (k, 3) and in-plane
    normal m (k, 3) oriented towards child1.
    """
    k = len(verts)
    c0 = np.empty((k, 4, 3))
    c1 = np.empty((k, 4, 3))
    a = np.empty((k, 3))
    m = np.empty((k, 3))
    tri = nverts == 3
    if tri.any():
        v = verts[tri]
        e = np.linalg.norm(v[:, [1, 2, 0]] - v[:, [0, 1, 2]], axis=-1)  # edge i = (v_i, v_i+1)
        w = _rotate(v, _first_max(e), 3)  # longest edge is (w0, w1)
        mid = 0.5 * (w[:, 0] + w[:, 1])
        c0[tri] = np.stack([w[:, 0], mid, w[:, 2], w[:, 2]], 1)
        c1[tri] = np.stack([mid, w[:, 1], w[:, 2], w[:, 2]], 1)
        a[tri] = mid
        m[tri] = _toward(w[:, 1] - w[:, 0], w[:, 2] - mid)
    quad = ~tri
    if quad.any():
        v = verts[quad]
        e = np.linalg.norm(v[:, [1, 2, 3, 0]] - v, axis=-1)
        pair = np.stack([e[:, 0] + e[:, 2], e[:, 1] + e[:, 3]], 1)
        w = _rotate(v, _first_max(pair), 4)  # longer sides are (w0, w1) and (w2, w3)
        p = 0.5 * (w[:, 0] + w[:, 1])
        q = 0.5 * (w[:, 2] + w[:, 3])
        c0[quad] = np.stack([w[:, 0], p, q, w[:, 3]], 1)
        c1[quad] = np.stack([p, w[:, 1], w[:, 2], q], 1)
        a[quad] = p
        m[quad] = _toward(w[:, 1] - w[:, 0], q - p)
    return c0, c1, a, m


def _toward(v: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Component of v orthogonal to the segment direction: in-plane, pointing to v's side."""
    s = seg / np.linalg.norm(seg, axis=1, keepdims=True)
    return v - np.sum(v * s, axis=1, keepdims=True) * s


# ----------------------------------------------------------------------------- the loop

def subdivide(verts: np.ndarray, nverts: np.ndarray, normal: np.ndarray, points: np.ndarray,
              point_elem: np.ndarray, max_depth: int = 48, element_ids: np.ndarray | None = None,
              point_group: np.ndarray | None = None):
    """Split elements until no sub-element holds two points (seed §3.2, the basic criterion).

    verts (n, 4, 3), nverts (n,), normal (n, 3): the elements of one subscene.
    points (p, 3) float64: hit points of the pixels on these elements; point_elem (p,) int: the
    element (0..n-1) of each point. element_ids (n,): global ids, only for warnings.
    point_group (p,) int (None: all one): the camera of each point; a sub-element is split while
    it holds two points of one group, so the partition is the union of each camera's own (the
    split of a polygon depends on its shape only).
    Returns a Partition whose `orig` is local (0..n-1), and a dict of figures.
    """
    n = len(verts)
    if max_depth > 60:
        raise ValueError("max-depth must be at most 60 (split paths are kept in 64-bit integers)")
    # growing node table; leaves of the current partition
    node_orig = [np.arange(n, dtype=np.int64)]
    node_depth = [np.zeros(n, np.int64)]
    node_path = [np.zeros(n, np.uint64)]
    node_a, node_m, node_child = {}, {}, {}
    leaf_node = np.arange(n, dtype=np.int64)
    leaf_v = np.asarray(verts, float).copy()
    leaf_n = np.asarray(nverts, np.int8).copy()
    leaf_depth = np.zeros(n, np.int64)
    pts = np.ascontiguousarray(points, float)
    pleaf = np.asarray(point_elem, np.int64).copy()
    total_nodes = n
    levels = 0
    guarded = np.zeros(0, np.int64)
    group = None if point_group is None else np.asarray(point_group, np.int64)
    G = 1 if group is None or not len(group) else int(group.max()) + 1
    while True:
        if G == 1:
            over = np.bincount(pleaf, minlength=len(leaf_node)) > 1
        else:
            over = (np.bincount(pleaf * G + group, minlength=len(leaf_node) * G)
                    .reshape(-1, G) > 1).any(axis=1)
        split = over & (leaf_depth < max_depth)
        guarded = np.nonzero(over & ~split)[0]
        if not split.any():
            break
        levels += 1
        S = np.nonzero(split)[0]
        c0, c1, a, m = split_polygons(leaf_v[S], leaf_n[S])
        parents = leaf_node[S]
        ids0 = total_nodes + 2 * np.arange(len(S))
        ids1 = ids0 + 1
        total_nodes += 2 * len(S)
        for j, p in enumerate(parents.tolist()):
            node_child[p] = (ids0[j], ids1[j])
            node_a[p] = a[j]
            node_m[p] = m[j]
        d = leaf_depth[S]
        ppath = np.concatenate(node_path)[parents]
        bit = np.left_shift(np.uint64(1), (63 - d).astype(np.uint64))
        node_orig.append(np.repeat(np.concatenate(node_orig)[parents], 2))
        node_depth.append(np.repeat(d + 1, 2))
        node_path.append(np.stack([ppath, ppath | bit], 1).reshape(-1))
        # new leaf list: kept leaves first, then the children pairs
        keep = np.nonzero(~split)[0]
        remap = np.full(len(leaf_node), -1, np.int64)
        remap[keep] = np.arange(len(keep))
        slot = np.full(len(leaf_node), -1, np.int64)
        slot[S] = len(keep) + 2 * np.arange(len(S))
        moving = split[pleaf]
        newp = remap[pleaf]
        if moving.any():
            which = sides(pts[moving], a[np.searchsorted(S, pleaf[moving])],
                          m[np.searchsorted(S, pleaf[moving])])
            newp[moving] = slot[pleaf[moving]] + which
        pleaf = newp
        kids_v = np.stack([c0, c1], 1).reshape(-1, 4, 3)
        leaf_v = np.concatenate([leaf_v[keep], kids_v])
        leaf_n = np.concatenate([leaf_n[keep], np.repeat(leaf_n[S], 2)])
        leaf_node = np.concatenate([leaf_node[keep], np.stack([ids0, ids1], 1).reshape(-1)])
        leaf_depth = np.concatenate([leaf_depth[keep], np.repeat(d + 1, 2)])
    ids = element_ids if element_ids is not None else np.arange(n)
    first = -1
    if len(guarded):
        first = int(ids[np.concatenate(node_orig)[leaf_node[guarded[0]]]])

    # canonical numbering: nodes and leaves in depth-first pre-order per original
    n_orig = np.concatenate(node_orig)
    n_depth = np.concatenate(node_depth)
    n_path = np.concatenate(node_path)
    order = np.lexsort((n_depth, n_path, n_orig))
    rank = np.empty(total_nodes, np.int64)
    rank[order] = np.arange(total_nodes)
    child = np.full((total_nodes, 2), -1, np.int32)
    split_a = np.zeros((total_nodes, 3))
    split_m = np.zeros((total_nodes, 3))
    for p, (i0, i1) in node_child.items():
        r = rank[p]
        child[r] = rank[i0], rank[i1]
        split_a[r] = node_a[p]
        split_m[r] = node_m[p]
    lorder = np.lexsort((leaf_depth, n_path[leaf_node], n_orig[leaf_node]))
    leaf_node = leaf_node[lorder]
    sub_v = leaf_v[lorder]
    sub_n = leaf_n[lorder]
    leaf = np.full(total_nodes, -1, np.int32)
    leaf[rank[leaf_node]] = np.arange(len(leaf_node), dtype=np.int32)
    orig = n_orig[leaf_node].astype(np.int32)
    area, _, center = polygon_properties(sub_v, sub_n)
    offsets = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(orig, minlength=n), out=offsets[1:])
    part = Partition(orig=orig, verts=sub_v, nverts=sub_n, center=center,
                     normal=np.asarray(normal, float)[orig], area=area,
                     depth=leaf_depth[lorder].astype(np.int16), offsets=offsets,
                     root=rank[:n].astype(np.int32), child=child,
                     leaf=leaf, split_a=split_a, split_m=split_m)
    figures = {"levels": levels, "guarded": int(len(guarded)), "guarded_first": first}
    return part, figures


def warn_depth_guard(guarded: int, first: int, max_depth: int) -> None:
    """Say that the depth guard stopped splitting (the partition is still valid, just coarser)."""
    if guarded:
        warnings.warn(f"depth guard: {guarded} sub-element(s) (first in element {first}) still cover "
                      f"more than one pixel after {max_depth} splits; raise "
                      "radiosity.subdivide.max-depth or check for degenerate geometry",
                      DepthGuardWarning, stacklevel=2)


def merge_partitions(pieces: list, element_ranges: list, n_elements: int) -> Partition:
    """Concatenate the partitions of subscenes that cover contiguous ranges of original ids.

    pieces[i] covers originals element_ranges[i] = (start, stop), in increasing order, so the
    result is identical to subdividing all elements in one call.
    """
    sub_off, node_off = 0, 0
    cols = {k: [] for k in ("orig", "verts", "nverts", "center", "normal", "area", "depth",
                            "root", "child", "leaf", "split_a", "split_m")}
    for part, (start, stop) in zip(pieces, element_ranges):
        cols["orig"].append(part.orig + start)
        for k in ("verts", "nverts", "center", "normal", "area", "depth", "split_a", "split_m"):
            cols[k].append(getattr(part, k))
        cols["root"].append(part.root + node_off)
        cols["child"].append(np.where(part.child >= 0, part.child + node_off, -1))
        cols["leaf"].append(np.where(part.leaf >= 0, part.leaf + sub_off, -1))
        sub_off += len(part)
        node_off += len(part.child)
    arr = {k: np.concatenate(v) for k, v in cols.items()}
    offsets = np.zeros(n_elements + 1, np.int64)
    np.cumsum(np.bincount(arr["orig"], minlength=n_elements), out=offsets[1:])
    return Partition(orig=arr["orig"].astype(np.int32), verts=arr["verts"], nverts=arr["nverts"],
                     center=arr["center"], normal=arr["normal"], area=arr["area"],
                     depth=arr["depth"], offsets=offsets, root=arr["root"].astype(np.int32),
                     child=arr["child"].astype(np.int32), leaf=arr["leaf"].astype(np.int32),
                     split_a=arr["split_a"], split_m=arr["split_m"])


# ----------------------------------------------------------------------------- the sequential stage

def subdivide_scene(elements, camera, subpixel: int = 1, max_depth: int = 48, caster=None):
    """The sequential preprocessing: full raster, then every element in one call.

    Returns (Partition, raster_orig (H*K, W*K) int32, points (H*K*W*K, 3), figures).
    (scene/hidden.subdivide_scene_hidden adds the rule for sub-elements no pixel hits.)
    """
    from radiosity.tracing.rays import RayCaster, raster_band

    rc = caster or RayCaster(elements.verts, elements.nverts)
    h = camera.height * subpixel
    elem, pts = raster_band(rc, elements.normal, elements.center, camera, subpixel, slice(0, h))
    hit = elem >= 0
    part, fig = subdivide(elements.verts, elements.nverts, elements.normal, pts[hit], elem[hit],
                          max_depth)
    warn_depth_guard(fig["guarded"], fig["guarded_first"], max_depth)
    return part, elem.reshape(h, -1), pts, fig


def pixel_size(points: np.ndarray) -> float:
    """A seen pixel's size: the median distance from a camera hit point (p, 3) to its nearest
    neighbour (over at most about 4096 of them), in world units; 0 with fewer than two."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 0.0
    sample = points[:: max(1, len(points) // 4096)]
    return float(np.median(cKDTree(points).query(sample, k=2)[0][:, 1]))


def lookup(part: Partition, points: np.ndarray, orig: np.ndarray) -> np.ndarray:
    """Sub-element (m-index) of each point on original `orig` (-1 where orig is -1), (n,) int32."""
    node = locate(np.ascontiguousarray(points, float), np.ascontiguousarray(orig, np.int32),
                  part.root, part.child, part.split_a, part.split_m)
    return np.where(node >= 0, part.leaf[np.maximum(node, 0)], -1).astype(np.int32)


# ----------------------------------------------------------------------------- unseen elements

def importance_points(verts: np.ndarray, nverts: np.ndarray, normal: np.ndarray,
                      two_sided: np.ndarray, ids: np.ndarray, seen_points: np.ndarray,
                      seen_normal: np.ndarray, factor: float, min_size: float, budget: int,
                      max_depth: int = 48):
    """Where to split the originals the camera does not see (they still send and reflect light).

    A node of an unseen original is split by the seed's rule while its diameter exceeds
    `factor` times its distance to the nearest seen surface point that faces it (camera hit
    points `seen_points` (p, 3) with their elements' normals `seen_normal` (p, 3)) and exceeds
    `min_size`; nodes no seen point faces stay whole. verts (n, 4, 3), nverts, normal (n, 3),
    two_sided (n,) of the originals; ids (u,): the unseen ones. At most `budget` leaves in all
    (the most important splits first, level by level).

    Returns points (q, 3) and their originals (q,): one point per leaf (its centroid), to be
    fed to `subdivide` with the camera's pixels, which then makes exactly these leaves (every
    split separates the centroids of the children's leaves), so the partition keeps one kind of
    split tree and its canonical order.
    """
    from scipy.spatial import cKDTree

    if len(ids) == 0 or len(seen_points) == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    tree = cKDTree(seen_points)
    k = min(16, len(seen_points))
    node_v = np.asarray(verts, float)[ids]
    node_n = np.asarray(nverts, np.int8)[ids]
    node_o = np.asarray(ids, np.int64)
    depth = 0
    done_v, done_n, done_o = [], [], []
    while len(node_o):
        area, _, c = polygon_properties(node_v, node_n)
        diam = diameter(node_v, node_n)
        dist, idx = tree.query(c, k=k)
        dist, idx = dist.reshape(len(c), k), idx.reshape(len(c), k)
        d = seen_points[idx] - c[:, None, :]                           # (q, k, 3)
        nq = normal[node_o][:, None, :]
        side = np.einsum("qkc,qkc->qk", d, np.broadcast_to(nq, d.shape))
        front = (side > 0) | (two_sided[node_o][:, None] & (side < 0))
        back = np.einsum("qkc,qkc->qk", d, seen_normal[idx]) < 0       # the point's side faces c
        facing = front & back
        near = np.where(facing.any(axis=1), np.where(facing, dist, np.inf).min(axis=1), np.inf)
        want = (diam > factor * near) & (diam > min_size) & (depth < max_depth)
        room = budget - (sum(len(o) for o in done_o) + len(node_o))
        if want.sum() > room:  # over budget: split the most important nodes only
            order = np.argsort(-(diam / np.maximum(near, 1e-300)), kind="stable")
            keep = np.zeros(len(want), bool)
            keep[order[:max(room, 0)]] = True
            want &= keep
        done_v.append(node_v[~want])
        done_n.append(node_n[~want])
        done_o.append(node_o[~want])
        if not want.any():
            break
        c0, c1, _, _ = split_polygons(node_v[want], node_n[want])
        node_v = np.stack([c0, c1], 1).reshape(-1, 4, 3)
        node_n = np.repeat(node_n[want], 2)
        node_o = np.repeat(node_o[want], 2)
        depth += 1
    leaf_v, leaf_n = np.concatenate(done_v), np.concatenate(done_n)
    _, _, centre = polygon_properties(leaf_v, leaf_n)
    return centre, np.concatenate(done_o)
