"""A bounding-volume tree over facets (pure numpy): the spatial structure the view-factor stage
uses instead of anything n x n.

Facets are reordered so that every node is a contiguous range: first by the dominant direction
of their normal (six classes), then by recursive median splits of their centroids, down to
leaves of at most `leaf_size` facets. Each node stores its facet range, its box, the area of
its facets and a cone of their normals (axis, spread; loops.behind uses it). The details:
docs/src/design/viewfactors-method.md ("The facet tree").
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass

import numpy as np

#: The node arrays of a FacetTree as one argument of the numba kernels (loops, occlusion).
Nodes = namedtuple("Nodes", "start end left right lo hi axis spread area root")


@dataclass(frozen=True)
class FacetTree:
    """perm : (n,) int64, original facet index of each position of the tree order
    start, end : (k,) int64, the node's facets are tree positions start:end
    left, right : (k,) int64, children (-1 at a leaf)
    lo, hi : (k, 3) float64, the node's box (of its facets' vertices)
    axis : (k, 3) float64, unit axis of the normal cone; spread : (k,) float64, max |n - axis|
    area : (k,) float64, total facet area of the node
    leaves : (l,) int64, leaf node ids in tree order (their ranges tile 0:n)
    root : int
    """

    perm: np.ndarray
    start: np.ndarray
    end: np.ndarray
    left: np.ndarray
    right: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    axis: np.ndarray
    spread: np.ndarray
    area: np.ndarray
    leaves: np.ndarray
    root: int

    def __len__(self) -> int:
        return len(self.start)

    def nodes(self) -> Nodes:
        """The node arrays as one Nodes tuple (the tree argument of the numba kernels)."""
        return Nodes(self.start, self.end, self.left, self.right, self.lo, self.hi, self.axis,
                     self.spread, self.area, self.root)


def normal_class(normal: np.ndarray) -> np.ndarray:
    """Dominant direction of each unit normal (n, 3): 2 * axis + (component < 0), (n,) int64."""
    ax = np.argmax(np.abs(normal), axis=1)
    neg = normal[np.arange(len(normal)), ax] < 0
    return 2 * ax + neg


def build_tree(lo: np.ndarray, hi: np.ndarray, center: np.ndarray, normal: np.ndarray,
               area: np.ndarray, leaf_size: int) -> FacetTree:
    """The tree of n facets from their boxes lo, hi (n, 3), centroids (n, 3), unit normals (n, 3)
    and areas (n,). Leaves hold at most leaf_size facets. O(n log n)."""
    n = len(center)
    if n == 0:
        raise ValueError("no facets")
    leaf_size = max(1, int(leaf_size))
    cls = normal_class(normal)
    perm = np.argsort(cls, kind="stable")
    bounds = np.searchsorted(cls[perm], np.arange(7))
    nodes: list = []   # [start, end, left, right]

    def split(s: int, e: int) -> int:
        """Build the subtree of tree positions s:e (perm reordered in place); its node id."""
        stack = [(s, e, -1, 0)]
        first = None
        while stack:
            s0, e0, parent, side = stack.pop()
            me = len(nodes)
            nodes.append([s0, e0, -1, -1])
            if parent >= 0:
                nodes[parent][2 + side] = me
            else:
                first = me
            if e0 - s0 <= leaf_size:
                continue
            idx = perm[s0:e0]
            c = center[idx]
            axis = int(np.argmax(c.max(0) - c.min(0)))
            mid = (e0 - s0) // 2
            order = np.argpartition(c[:, axis], mid, kind="introselect")
            perm[s0:e0] = idx[order]
            stack.append((s0 + mid, e0, me, 1))
            stack.append((s0, s0 + mid, me, 0))
        return first

    roots = [split(int(bounds[k]), int(bounds[k + 1])) for k in range(6) if bounds[k + 1] > bounds[k]]
    # join the class subtrees pairwise (their ranges are consecutive)
    while len(roots) > 1:
        nxt = []
        for k in range(0, len(roots) - 1, 2):
            a, b = roots[k], roots[k + 1]
            nxt.append(len(nodes))
            nodes.append([nodes[a][0], nodes[b][1], a, b])
        if len(roots) % 2:
            nxt.append(roots[-1])
        roots = nxt
    root = roots[0]
    nd = np.array(nodes, np.int64)
    start, end, left, right = nd.T.copy()
    k = len(nd)
    # node boxes, areas and normal-cone axes bottom-up (post-order: children before parents)
    nlo = np.empty((k, 3))
    nhi = np.empty((k, 3))
    narea = np.empty(k)
    nsum = np.empty((k, 3))
    order = _postorder(left, right, root)
    plo, phi, parea, pn = lo[perm], hi[perm], area[perm], normal[perm]
    for v in order:
        if left[v] < 0:
            s, e = start[v], end[v]
            nlo[v] = plo[s:e].min(0)
            nhi[v] = phi[s:e].max(0)
            narea[v] = parea[s:e].sum()
            nsum[v] = (pn[s:e] * parea[s:e, None]).sum(0)
        else:
            a, b = left[v], right[v]
            nlo[v] = np.minimum(nlo[a], nlo[b])
            nhi[v] = np.maximum(nhi[a], nhi[b])
            narea[v] = narea[a] + narea[b]
            nsum[v] = nsum[a] + nsum[b]
    norm = np.linalg.norm(nsum, axis=1)
    axis = np.where(norm[:, None] > 1e-12 * np.maximum(narea, 1e-300)[:, None],
                    nsum / np.where(norm > 0, norm, 1.0)[:, None], np.array([0.0, 0.0, 1.0]))
    # spread: max over the node's facets of |n - axis| (each tree level touches every facet once)
    spread = np.zeros(k)
    for v in order:
        s, e = start[v], end[v]
        spread[v] = float(np.linalg.norm(pn[s:e] - axis[v], axis=1).max())
    leaves = np.array([v for v in _preorder(left, right, root) if left[v] < 0], np.int64)
    return FacetTree(perm=perm.astype(np.int64), start=start, end=end, left=left, right=right,
                     lo=nlo, hi=nhi, axis=axis, spread=spread, area=narea, leaves=leaves,
                     root=int(root))


def _postorder(left, right, root) -> list:
    out, stack = [], [(root, False)]
    while stack:
        v, done = stack.pop()
        if done or left[v] < 0:
            out.append(v)
            continue
        stack.append((v, True))
        stack.append((right[v], False))
        stack.append((left[v], False))
    return out


def _preorder(left, right, root) -> list:
    out, stack = [], [root]
    while stack:
        v = stack.pop()
        out.append(v)
        if left[v] >= 0:
            stack.append(right[v])
            stack.append(left[v])
    return out
