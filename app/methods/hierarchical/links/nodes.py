"""A link task's local node table (refine.py grows it): the nodes its links name, copied from
the partition's split trees (Tree) or split off below them on demand, each with its polygon,
box, name (original, path, depth), children, partition node and whether it can split. The
kernels here fill one node; refine.refine grows the arrays when they are full."""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from radiosity.scene.splittrees import MAX_DEPTH, polygon_area_center

# A task's local node table (grown by refine): polygon, area, centroid, box, original, path and
# depth (the node's name), children (-1: none yet), partition node (split off below partition
# node t: -2 - t; part_of), can split.
NodeTable = namedtuple("NodeTable",
                       "verts nverts area center lo hi orig path depth child pnode can")

def new_table(cap: int) -> NodeTable:
    """An empty local node table for `cap` nodes."""
    return NodeTable(np.zeros((cap, 4, 3)), np.zeros(cap, np.int64), np.zeros(cap),
                     np.zeros((cap, 3)), np.zeros((cap, 3)), np.zeros((cap, 3)),
                     np.zeros(cap, np.int64), np.zeros(cap, np.uint64), np.zeros(cap, np.int64),
                     np.full((cap, 2), -1, np.int64), np.full(cap, -1, np.int64),
                     np.zeros(cap, np.bool_))


@numba.njit(cache=True, nogil=True)
def grow_rows(a, n):
    out = np.zeros((n,) + a.shape[1:], a.dtype)
    out[:a.shape[0]] = a
    return out


def grown_copy(a: np.ndarray, n: int) -> np.ndarray:
    """grow_rows outside the kernels: a copy of `a` with n rows, the new ones zero."""
    out = np.zeros((n,) + a.shape[1:], a.dtype)
    out[:a.shape[0]] = a
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def part_of(pnode):
    """The partition node a local node is (pnode >= 0) or was split off below (pnode <= -2)."""
    return pnode if pnode >= 0 else -2 - pnode


@numba.njit(cache=True, nogil=True, inline="always")
def is_forced(force, pnode, side):
    return force.shape[0] > 0 and force[part_of(pnode), side]


@numba.njit(cache=True, nogil=True)
def new_node(x, verts, nv, orig, path, depth, pnode, can, tab, c):
    """Node x of the local table `tab`: polygon verts[:nv], its name (orig, path, depth), the
    partition node pnode, whether it can split; c (3,): scratch."""
    Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan = tab
    for i in range(4):
        for k in range(3):
            Lv[x, i, k] = verts[i, k]
    Ln[x] = nv
    La[x] = polygon_area_center(verts, c)
    for k in range(3):
        Lc[x, k] = c[k]
    for k in range(3):
        lo, hi = np.inf, -np.inf
        for i in range(nv):
            lo = min(lo, verts[i, k])
            hi = max(hi, verts[i, k])
        Llo[x, k] = lo
        Lhi[x, k] = hi
    Lo[x] = orig
    Lp[x] = path
    Ld[x] = depth
    Lch[x, 0] = -1
    Lch[x, 1] = -1
    Lpn[x] = pnode
    Lcan[x] = can


@numba.njit(cache=True, nogil=True)
def copy_tree_node(x, t, tree, min_size, tab):
    """Node x of the local table `tab`: partition node t of `tree`."""
    t_verts, t_nverts, t_area, t_center, t_lo, t_hi, t_child, t_orig, t_depth, t_path, ext = tree
    Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan = tab
    for i in range(4):
        for k in range(3):
            Lv[x, i, k] = t_verts[t, i, k]
    Ln[x] = t_nverts[t]
    La[x] = t_area[t]
    for k in range(3):
        Lc[x, k] = t_center[t, k]
        Llo[x, k] = t_lo[t, k]
        Lhi[x, k] = t_hi[t, k]
    Lo[x] = t_orig[t]
    Lp[x] = t_path[t]
    Ld[x] = t_depth[t]
    Lch[x, 0] = -1
    Lch[x, 1] = -1
    Lpn[x] = t
    Lcan[x] = t_child[t, 0] >= 0 or (ext[t] and np.sqrt(t_area[t]) > min_size
                                     and t_depth[t] < MAX_DEPTH)
