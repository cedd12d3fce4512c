"""A hierarchy over the original elements, so that nothing is n x n in them (SPEC §5's block
culling, the effects planner): blocks are classified cluster against cluster, and only the pairs
that may face each other are ever listed, sparsely. The view factors walk the same tree over
their facets (viewfactors/master.make_inputs).

Design notes and measurements: docs/src/design/scene-originals.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from radiosity.core import tolerances
from radiosity.errors import RadiosityError

# Facing and behind tests: distances below TOL times the scene's diagonal count as 0 (as in
# plan.facing_blocks and effects; core.tolerances: facing, and
# docs/src/design/methods-hierarchical-clusters.md, "Flat faces").
TOL = tolerances.TOL.facing
LEAF = 16             # elements per leaf
BATCH = 1 << 14       # node pairs classified per batch
ESTIMATE_NODE_PAIRS = 1 << 16  # node pairs counted before the budget check samples the rest
LEAF_BATCH = 256      # leaf pairs tested exactly per batch


class FacingPairsError(RadiosityError):
    """More pairs of original elements face each other than the configured budget allows
    (`estimate`: how many, estimated or counted)."""

    def __init__(self, message: str, estimate: float = 0.0):
        super().__init__(message)
        self.estimate = float(estimate)


@dataclass(frozen=True)
class OriginalsTree:
    """Nodes of the hierarchy (K of them; node 0 is the root). Element arrays are (n, ...).

    order (n,) int64: elements in leaf order; start, end (K,) int64: a node's range in order;
    left, right (K,) int64 (-1 for a leaf); lo, hi (K, 3): vertex box; clo, chi (K, 3): box
    of the centres; axis (K, 3) unit; spread (K,) >= max |n_I - axis|; two (K,) any two-sided.
    normal, verts4 (n, 4, 3) (triangles repeat vertex 2), offset (n,) = n . centre, two_sided,
    eps (the tolerance in scene units)."""

    order: np.ndarray
    start: np.ndarray
    end: np.ndarray
    left: np.ndarray
    right: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    clo: np.ndarray
    chi: np.ndarray
    axis: np.ndarray
    spread: np.ndarray
    two: np.ndarray
    normal: np.ndarray
    verts: np.ndarray
    offset: np.ndarray
    two_sided: np.ndarray
    eps: float
    leaf: int

    @property
    def n(self) -> int:
        return len(self.order)

    @property
    def size(self) -> np.ndarray:
        return self.end - self.start

    def leaves(self) -> np.ndarray:
        """The leaf node ids in leaf order (their ranges tile 0:n), (l,) int64."""
        lf = np.nonzero(self.left < 0)[0]
        return lf[np.argsort(self.start[lf], kind="stable")]

    def node_sums(self, x: np.ndarray) -> np.ndarray:
        """The sum of x (n,) (per element, in element order) over each node's elements, (K,)."""
        return _sums(np.asarray(x, np.float64)[self.order][:, None], self.start, self.end)[:, 0]

    def nbytes(self) -> int:
        return int(sum(getattr(self, f).nbytes for f in (
            "order", "start", "end", "left", "right", "lo", "hi", "clo", "chi", "axis", "spread",
            "two", "offset")))


def scene_eps(verts: np.ndarray, tol: float = TOL) -> float:
    """The facing tolerance in scene units (plan.facing_blocks': tol times the box diagonal)."""
    v = verts.reshape(-1, 3)
    return tol * float(np.linalg.norm(v.max(0) - v.min(0))) if len(v) else 0.0


def build_tree(verts: np.ndarray, nverts: np.ndarray, normal: np.ndarray, center: np.ndarray,
               two_sided: np.ndarray, leaf: int = LEAF, tol: float = TOL,
               normal_weight: float = 1.0, separate: bool = False) -> OriginalsTree:
    """The hierarchy over n original elements: verts (n, 4, 3) (a triangle repeats vertex 2),
    normal, center (n, 3), two_sided (n,) bool. Built level by level (one sort of the elements
    per level, no Python loop over nodes): O(n log n) time, O(n) memory. Each node splits at the
    median of the feature that spreads most: the centres relative to the scene's size or the
    normals times `normal_weight`. `separate`: a node split by normal whose halves' centres
    spread as far as its own along every axis but a tenth (orientations interleaved over the
    same ground, as on a rough surface) is split by its centres instead (the cluster tree:
    clusters/refine.py)."""
    n = len(verts)
    verts = np.asarray(verts, np.float64)
    normal = np.asarray(normal, np.float64)
    center = np.asarray(center, np.float64)
    two_sided = np.asarray(two_sided, bool)
    vmin = verts.min(axis=1) if n else np.zeros((0, 3))
    vmax = verts.max(axis=1) if n else np.zeros((0, 3))
    size = float(np.linalg.norm(vmax.max(0) - vmin.min(0))) if n else 1.0
    feat = np.concatenate([center / max(size, 1e-300), normal * normal_weight], axis=1)
    order = np.arange(n, dtype=np.int64)
    start, end = [np.array([0], np.int64)], [np.array([n], np.int64)]
    left, right = [np.array([-1], np.int64)], [np.array([-1], np.int64)]
    K = 1
    ids = np.array([0], np.int64) if n > leaf else np.zeros(0, np.int64)  # nodes to split
    S, E = start[0][:len(ids)], end[0][:len(ids)]
    levels = []  # the nodes split at each level (parents), for the bottom-up pass
    while len(ids):
        srt = np.argsort(S, kind="stable")  # disjoint ranges in order: reduceat stays O(n)
        ids, S, E = ids[srt], S[srt], E[srt]
        levels.append(ids)
        # each node splits at the median of the feature that spreads most within it
        fl, fh = _ranges(feat[order], S, E)
        dim = np.argmax(fh - fl, axis=1)
        cnt = E - S
        node = np.repeat(np.arange(len(ids)), cnt)
        pos = np.arange(len(node)) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(S, cnt)
        key = feat[order[pos], dim[node]]
        perm = np.lexsort((key, node))
        order[pos] = order[pos][perm]
        mid = S + cnt // 2
        if separate:
            _separate(feat, order, S, E, mid, dim, fl, fh, node, pos)
        cs = np.concatenate([S, mid])
        ce = np.concatenate([mid, E])
        child = K + np.arange(2 * len(ids))
        left.append(np.full(len(child), -1, np.int64))
        right.append(np.full(len(child), -1, np.int64))
        start.append(cs)
        end.append(ce)
        _set(left, ids, child[:len(ids)])  # the children of this level's nodes
        _set(right, ids, child[len(ids):])
        K += len(child)
        big = (ce - cs) > leaf
        ids, S, E = child[big], cs[big], ce[big]
    start, end = np.concatenate(start), np.concatenate(end)
    left, right = np.concatenate(left)[:K], np.concatenate(right)[:K]
    # the leaves' boxes directly (they partition the leaf order), then the parents', level by
    # level from the bottom
    o = order
    lf = np.nonzero(left < 0)[0]
    lf = lf[np.argsort(start[lf])]
    lo, hi = np.zeros((K, 3)), np.zeros((K, 3))
    clo, chi = np.zeros((K, 3)), np.zeros((K, 3))
    nlo, nhi = np.zeros((K, 3)), np.zeros((K, 3))
    nsum = np.zeros((K, 3))
    two = np.zeros(K, bool)
    if n:
        lo[lf], hi[lf] = _ranges(vmin[o], start[lf], end[lf], vmax[o])
        clo[lf], chi[lf] = _ranges(center[o], start[lf], end[lf])
        nlo[lf], nhi[lf] = _ranges(normal[o], start[lf], end[lf])
        nsum[lf] = _sums(normal[o], start[lf], end[lf])
        two[lf] = _sums(two_sided[o].astype(np.float64)[:, None], start[lf], end[lf])[:, 0] > 0
    for P in reversed(levels):
        a, b = left[P], right[P]
        lo[P], hi[P] = np.minimum(lo[a], lo[b]), np.maximum(hi[a], hi[b])
        clo[P], chi[P] = np.minimum(clo[a], clo[b]), np.maximum(chi[a], chi[b])
        nlo[P], nhi[P] = np.minimum(nlo[a], nlo[b]), np.maximum(nhi[a], nhi[b])
        nsum[P] = nsum[a] + nsum[b]
        two[P] = two[a] | two[b]
    axis = _unit(nsum)
    spread = np.minimum(2.0, np.linalg.norm(np.maximum(np.abs(nlo - axis), np.abs(nhi - axis)), axis=1))
    offset = np.einsum("ic,ic->i", normal, center)
    return OriginalsTree(order=order, start=start, end=end, left=left, right=right, lo=lo, hi=hi,
                         clo=clo, chi=chi, axis=axis, spread=spread, two=two, normal=normal,
                         verts=verts, offset=offset, two_sided=two_sided,
                         eps=tol * size if n else 0.0, leaf=leaf)


def _set(chunks: list, idx: np.ndarray, values: np.ndarray) -> None:
    """chunks (a list of arrays, concatenated = one array) [idx] = values."""
    off = 0
    for c in chunks:
        k = (idx >= off) & (idx < off + len(c))
        c[idx[k] - off] = values[k]
        off += len(c)


def _separate(feat, order, S, E, mid, dim, fl, fh, node, pos) -> None:
    """Re-split by centre (in place: order) the nodes [S, E) that build_tree split by normal
    (dim >= 3) whose halves [S, mid), [mid, E) each spread along every axis at least 0.9 times
    as far as the node: their orientations interleave over the same ground."""
    bysn = dim >= 3
    if not bysn.any():
        return
    c = feat[order, :3]
    span = fh[:, :3] - fl[:, :3]
    lo1, hi1 = _ranges(c, S, mid)
    lo2, hi2 = _ranges(c, mid, E)
    tight = ((hi1 - lo1) >= 0.9 * span).all(axis=1) & ((hi2 - lo2) >= 0.9 * span).all(axis=1)
    redo = bysn & tight & (span.max(axis=1) > 0)
    if not redo.any():
        return
    sdim = np.argmax(span, axis=1)
    sel = redo[node]
    p, nd = pos[sel], node[sel]
    key = feat[order[p], sdim[nd]]
    perm = np.lexsort((key, nd))
    order[p] = order[p][perm]
    dim[redo] = sdim[redo]


def _ranges(a: np.ndarray, S: np.ndarray, E: np.ndarray, b: np.ndarray | None = None):
    """Minimum of a and maximum of b (default a) over the rows [S_k, E_k) of each range:
    (len(S), d) each; the ranges are disjoint and sorted (reduceat on interleaved bounds: the
    gaps between them are reduced too, O(len(a)) in all; one padding row)."""
    b = a if b is None else b
    if len(S) == 0:
        return np.zeros((0, a.shape[1])), np.zeros((0, b.shape[1]))
    idx = np.empty(2 * len(S), np.int64)
    idx[0::2], idx[1::2] = S, E
    pa = np.concatenate([a, a[:1]])
    pb = np.concatenate([b, b[:1]])
    return np.minimum.reduceat(pa, idx)[0::2], np.maximum.reduceat(pb, idx)[0::2]


def _sums(a: np.ndarray, S: np.ndarray, E: np.ndarray) -> np.ndarray:
    c = np.concatenate([np.zeros((1, a.shape[1])), np.cumsum(a, axis=0)])
    return c[E] - c[S]


def tree_of(elements, leaf: int = LEAF) -> OriginalsTree:
    """build_tree of a types.Elements."""
    return build_tree(elements.verts, elements.nverts, elements.normal, elements.center,
                      elements.two_sided, leaf)


def _unit(v: np.ndarray) -> np.ndarray:
    nrm = np.linalg.norm(v, axis=1, keepdims=True)
    out = np.zeros_like(v)
    ok = nrm[:, 0] > 1e-12
    out[ok] = v[ok] / nrm[ok]
    out[~ok] = (1.0, 0.0, 0.0)  # no mean direction: any axis, the spread covers it (<= 2)
    return out


# ----------------------------------------------------------------------------- bounds

def _bounds(t: OriginalsTree, A: np.ndarray, B: np.ndarray):
    """Upper and lower bounds of n_I . (x - c_I) over I in node A, x a vertex of node B."""
    dlo = t.lo[B] - t.chi[A]
    dhi = t.hi[B] - t.clo[A]
    a = t.axis[A]
    up = np.where(a > 0, a * dhi, a * dlo).sum(1)
    low = np.where(a > 0, a * dlo, a * dhi).sum(1)
    vmax = np.linalg.norm(np.maximum(np.abs(dlo), np.abs(dhi)), axis=1)
    s = t.spread[A] * vmax
    return up + s, low - s


def _may_face(t: OriginalsTree, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Can some J in B face some I in A (a vertex of J strictly in front of I's plane, or behind
    it for a two-sided I)? False only where certainly not (half the tolerance as margin)."""
    up, low = _bounds(t, A, B)
    half = 0.5 * t.eps
    return (up > half) | (t.two[A] & (low < -half))


def _split(t: OriginalsTree, A: np.ndarray, B: np.ndarray):
    """Children pairs of distinct node pairs: the larger non-leaf node is split."""
    la, lb = t.left[A] < 0, t.left[B] < 0
    split_a = ~la & (lb | (t.size[A] >= t.size[B]))
    na = np.concatenate([t.left[A[split_a]], t.right[A[split_a]], A[~split_a], A[~split_a]])
    nb = np.concatenate([B[split_a], B[split_a], t.left[B[~split_a]], t.right[B[~split_a]]])
    return na, nb


# ----------------------------------------------------------------------------- facing pairs

def facing_pairs(t: OriginalsTree, cap: int | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """Every pair I < J of original elements that face each other both ways (plan.make_plan's
    blocks), as bi, bj (p,) int64 sorted by (I, J), and figures: node pairs classified, leaf
    pairs tested exactly, peak node pairs held. Equals the upper triangle of
    facing_blocks & facing_blocks.T, without any n x n array. More than `cap` pairs raises
    FacingPairsError."""
    out_i, out_j = [], []
    total = 0
    stats = {"node_pairs": 0, "leaf_pairs": 0, "peak_frontier": 0}
    if t.n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), stats
    # self pairs (A, A) and distinct pairs (A, B) on two stacks of arrays
    selfs = [np.array([0], np.int64)]
    pairs: list = []
    leaf_self, leaf_a, leaf_b = [], [], []

    def flush(force=False):
        nonlocal total
        for kind in ("self", "pair"):
            if kind == "self" and leaf_self and (force or sum(map(len, leaf_self)) >= LEAF_BATCH):
                L = np.concatenate(leaf_self)
                leaf_self.clear()
                for s in range(0, len(L), LEAF_BATCH):
                    i, j = _exact_self(t, L[s:s + LEAF_BATCH])
                    out_i.append(i)
                    out_j.append(j)
                    total += len(i)
            if kind == "pair" and leaf_a and (force or sum(map(len, leaf_a)) >= LEAF_BATCH):
                A, B = np.concatenate(leaf_a), np.concatenate(leaf_b)
                leaf_a.clear()
                leaf_b.clear()
                for s in range(0, len(A), LEAF_BATCH):
                    i, j = _exact_pairs(t, A[s:s + LEAF_BATCH], B[s:s + LEAF_BATCH])
                    out_i.append(i)
                    out_j.append(j)
                    total += len(i)
        if cap is not None and total > cap:
            raise FacingPairsError(f"more than {cap} pairs of original elements face each other")

    while selfs or pairs:
        if selfs:
            S = selfs.pop()
            leaf = t.left[S] < 0
            stats["leaf_pairs"] += int(leaf.sum())
            leaf_self.append(S[leaf])
            P = S[~leaf]
            if len(P):
                selfs.append(np.concatenate([t.left[P], t.right[P]]))
                pairs.append((t.left[P], t.right[P]))
        else:
            A, B = pairs.pop()
            if len(A) > BATCH:  # keep batches bounded: the rest waits on the stack
                pairs.append((A[BATCH:], B[BATCH:]))
                A, B = A[:BATCH], B[:BATCH]
            stats["node_pairs"] += len(A)
            keep = _may_face(t, A, B) & _may_face(t, B, A)
            A, B = A[keep], B[keep]
            leaf = (t.left[A] < 0) & (t.left[B] < 0)
            stats["leaf_pairs"] += int(leaf.sum())
            leaf_a.append(A[leaf])
            leaf_b.append(B[leaf])
            if (~leaf).any():
                pairs.append(_split(t, A[~leaf], B[~leaf]))
        stats["peak_frontier"] = max(stats["peak_frontier"], sum(len(p[0]) for p in pairs))
        flush()
    flush(force=True)
    bi = np.concatenate(out_i) if out_i else np.zeros(0, np.int64)
    bj = np.concatenate(out_j) if out_j else np.zeros(0, np.int64)
    o = np.lexsort((bj, bi))
    return bi[o], bj[o], stats


def _leaf_members(t: OriginalsTree, nodes: np.ndarray):
    """Element ids of each leaf, padded with -1: (len(nodes), t.leaf)."""
    L = max(1, int(t.size[nodes].max(initial=1)))
    k = np.arange(L)
    pos = t.start[nodes][:, None] + k[None, :]
    ok = k[None, :] < t.size[nodes][:, None]
    ids = np.where(ok, t.order[np.minimum(pos, t.n - 1)], -1)
    return ids, ok


def _exact_pairs(t: OriginalsTree, A: np.ndarray, B: np.ndarray):
    """The facing pairs between leaves A[p] and B[p] (distinct), as (min, max) element ids."""
    A = np.ascontiguousarray(A, np.int64)
    return _leaf_pairs(A, np.ascontiguousarray(B, np.int64), False, t.order, t.start, t.end,
                       t.normal, t.verts, t.offset, t.two_sided, float(t.eps))


def _exact_self(t: OriginalsTree, S: np.ndarray):
    """The facing pairs within each leaf S[p], as (min, max) element ids."""
    S = np.ascontiguousarray(S, np.int64)
    return _leaf_pairs(S, S, True, t.order, t.start, t.end, t.normal, t.verts, t.offset,
                       t.two_sided, float(t.eps))


@numba.njit(cache=True, nogil=True, inline="always")
def faces(normal, verts, offset, two_sided, eps, i, j) -> bool:
    """Does element j have a vertex strictly in front of element i's plane (behind it, for a
    two-sided i)? The arithmetic of plan.facing_blocks; verts (n, 4, 3), a triangle repeating
    a vertex. Also the cluster refinement's test of two originals (clusters.py)."""
    front = False
    back = False
    for k in range(verts.shape[1]):
        d = (normal[i, 0] * verts[j, k, 0] + normal[i, 1] * verts[j, k, 1]
             + normal[i, 2] * verts[j, k, 2]) - offset[i]
        front |= d > eps
        back |= d < -eps
    return front or (two_sided[i] and back)


@numba.njit(cache=True, nogil=True)
def _leaf_pairs(A, B, same, order, start, end, normal, verts, offset, two_sided, eps):
    """The pairs of elements (one of leaf A[p], one of leaf B[p]; within A[p] when `same`) that
    face each other both ways, as (min, max) element ids in leaf-pair order."""
    total = 0
    for p in range(len(A)):
        a = end[A[p]] - start[A[p]]
        total += a * (a - 1) // 2 if same else a * (end[B[p]] - start[B[p]])
    lo = np.empty(total, np.int64)
    hi = np.empty(total, np.int64)
    m = 0
    for p in range(len(A)):
        for x in range(start[A[p]], end[A[p]]):
            i = order[x]
            for y in range(x + 1 if same else start[B[p]], end[B[p]]):
                j = order[y]
                if faces(normal, verts, offset, two_sided, eps, i, j) and \
                        faces(normal, verts, offset, two_sided, eps, j, i):
                    lo[m] = min(i, j)
                    hi[m] = max(i, j)
                    m += 1
    return lo[:m], hi[:m]


@numba.njit(cache=True, nogil=True)
def _face_each_other(I, J, normal, verts, offset, two_sided, eps):
    """(k,) bool: elements I[k] and J[k] face each other both ways."""
    out = np.empty(len(I), np.bool_)
    for k in range(len(I)):
        out[k] = faces(normal, verts, offset, two_sided, eps, I[k], J[k]) and \
            faces(normal, verts, offset, two_sided, eps, J[k], I[k])
    return out


# ----------------------------------------------------------------------------- behind

def behind_any(t: OriginalsTree, wanted: np.ndarray | None = None, first: bool = False) -> np.ndarray:
    """(n,) bool: does any vertex of any element lie strictly behind the plane of I? (The rows
    of effects' old (n, n) `behind` matrix, or-ed, without it.) Only for the elements `wanted`
    ((n,) bool; None: all; the others are False); with `first`, the search stops at the first
    element found (is there any?)."""
    want = np.ones(t.n, bool) if wanted is None else np.asarray(wanted, bool)
    found = ~want  # the elements not wanted count as found: their nodes are pruned
    if t.n == 0 or not want.any():
        return np.zeros(t.n, bool)
    stack = [(np.array([0], np.int64), np.array([0], np.int64))]
    while stack:
        A, B = stack.pop()
        if len(A) > BATCH:
            stack.append((A[BATCH:], B[BATCH:]))
            A, B = A[:BATCH], B[:BATCH]
        _, low = _bounds(t, A, B)
        keep = low < -0.5 * t.eps
        A, B = A[keep], B[keep]
        if len(A) == 0:
            continue
        done = _all_found(t, found, A)
        A, B = A[~done], B[~done]
        leaf = (t.left[A] < 0) & (t.left[B] < 0)
        for s in range(0, int(leaf.sum()), LEAF_BATCH):
            la, lb = A[leaf][s:s + LEAF_BATCH], B[leaf][s:s + LEAF_BATCH]
            ia, oka = _leaf_members(t, la)
            ib, okb = _leaf_members(t, lb)
            IA, IB = np.maximum(ia, 0), np.maximum(ib, 0)
            n_ = t.normal[IA]
            v = t.verts[IB]
            d = (n_[:, :, None, None, :] * v[:, None, :, :, :]).sum(-1) - t.offset[IA][:, :, None, None]
            hit = ((d < -t.eps).any(axis=3) & okb[:, None, :]).any(axis=2) & oka
            found[IA[hit]] = True
            if first and (found & want).any():
                return found & want
        if (~leaf).any():
            stack.append(_split(t, A[~leaf], B[~leaf]))
    return found & want


def _all_found(t: OriginalsTree, found: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Are all elements of each node in A already found? (cumulative sums over leaf order)"""
    c = np.concatenate([[0], np.cumsum(found[t.order])])
    return c[t.end[A]] - c[t.start[A]] == t.size[A]


# ----------------------------------------------------------------------------- estimate

def _must_face(t: OriginalsTree, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Does every J in B face every I in A? True only where certainly so: J's centre (a convex
    combination of its vertices) strictly in front of every plane of A, with margin."""
    dlo = t.clo[B] - t.chi[A]
    dhi = t.chi[B] - t.clo[A]
    a = t.axis[A]
    low = np.where(a > 0, a * dlo, a * dhi).sum(1)
    vmax = np.linalg.norm(np.maximum(np.abs(dlo), np.abs(dhi)), axis=1)
    return low - t.spread[A] * vmax > 2.0 * t.eps


def estimate_facing_pairs(t: OriginalsTree, max_node_pairs: int = 1 << 20, samples: int = 8,
                          seed: int = 0) -> dict:
    """How many pairs of originals face each other both ways, before listing any: counted on
    the hierarchy, where a node pair whose bounds show that all of it faces counts |A| |B| at
    once, one that cannot face counts 0, and leaves are counted exactly. After
    `max_node_pairs` node pairs the rest is estimated from `samples` random element pairs per
    node pair. Returns {"estimate", "exact" (no sampling was needed), "node_pairs"}. Memory:
    bounded batches; time: about the node pairs (dense and sparse scenes alike are cheap)."""
    rng = np.random.default_rng(seed)
    count = 0.0
    visited = 0
    exact = True
    if t.n < 2:
        return {"estimate": 0.0, "exact": True, "node_pairs": 0}
    selfs = [np.array([0], np.int64)]
    pairs: list = []
    while selfs or pairs:
        if selfs:
            S = selfs.pop()
            leaf = t.left[S] < 0
            for s0 in range(0, int(leaf.sum()), LEAF_BATCH):
                count += len(_exact_self(t, S[leaf][s0:s0 + LEAF_BATCH])[0])
            P = S[~leaf]
            if len(P):
                selfs.append(np.concatenate([t.left[P], t.right[P]]))
                pairs.append((t.left[P], t.right[P]))
            continue
        A, B = pairs.pop()
        if len(A) > BATCH:
            pairs.append((A[BATCH:], B[BATCH:]))
            A, B = A[:BATCH], B[:BATCH]
        visited += len(A)
        may = _may_face(t, A, B) & _may_face(t, B, A)
        A, B = A[may], B[may]
        must = _must_face(t, A, B) & _must_face(t, B, A)
        count += float((t.size[A[must]] * t.size[B[must]]).sum())
        A, B = A[~must], B[~must]
        leaf = (t.left[A] < 0) & (t.left[B] < 0)
        for s0 in range(0, int(leaf.sum()), LEAF_BATCH):
            count += len(_exact_pairs(t, A[leaf][s0:s0 + LEAF_BATCH], B[leaf][s0:s0 + LEAF_BATCH])[0])
        A, B = A[~leaf], B[~leaf]
        if not len(A):
            continue
        if visited > max_node_pairs:  # enough: sample what is left
            exact = False
            count += _sampled(t, A, B, samples, rng)
            continue
        pairs.append(_split(t, A, B))
    return {"estimate": count, "exact": exact, "node_pairs": visited}


def _sampled(t: OriginalsTree, A: np.ndarray, B: np.ndarray, k: int, rng) -> float:
    """Facing pairs between nodes A[p], B[p], estimated from k random element pairs each."""
    total = 0.0
    for s0 in range(0, len(A), LEAF_BATCH):
        a, b = A[s0:s0 + LEAF_BATCH], B[s0:s0 + LEAF_BATCH]
        I = t.order[t.start[a][:, None] + (rng.random((len(a), k)) * t.size[a][:, None]).astype(np.int64)]
        J = t.order[t.start[b][:, None] + (rng.random((len(b), k)) * t.size[b][:, None]).astype(np.int64)]
        f = _face_each_other(I.ravel(), J.ravel(), t.normal, t.verts, t.offset, t.two_sided,
                             float(t.eps)).reshape(len(a), k)
        total += float((f.mean(axis=1) * t.size[a] * t.size[b]).sum())
    return total


#: Driver memory per facing pair of originals in a visibility plan: a tile (7 int64), its
#: task (4 int64 in block mode), the pair list while building (2 int64) and the effects
#: planner's sparse graph (2 x (int32 + bool) both ways); measured plans come within this.
BYTES_PER_PAIR = 7 * 8 + 4 * 8 + 2 * 8 + 2 * 5


def check_budget(t: OriginalsTree, cap: int, where: str) -> dict:
    """Refuse, before any pair is listed, a scene whose facing pairs of originals (counted on
    the hierarchy, estimate_facing_pairs) exceed `cap` (radiosity.plan.max-facing-pairs);
    returns the estimate."""
    est = estimate_facing_pairs(t, max_node_pairs=ESTIMATE_NODE_PAIRS)
    if est["estimate"] > cap:
        raise FacingPairsError(budget_message(where, t.n, est["estimate"], cap), est["estimate"])
    return est


def pairs_within_budget(t: OriginalsTree, cap: int | None, where: str):
    """facing_pairs of the tree, refused up front (by the estimate) and during the traversal
    (by the count) beyond `cap` pairs; returns (bi, bj, figures) with the estimate in the
    figures."""
    est = check_budget(t, cap, where) if cap is not None else None
    try:
        bi, bj, stats = facing_pairs(t, cap)
    except FacingPairsError:  # the estimate was low: the count says so
        guess = max(float(cap), est["estimate"] if est else 0.0)
        raise FacingPairsError(budget_message(where, t.n, guess, cap, more=True), guess) from None
    return bi, bj, {**stats, "estimate": est}


def budget_message(where: str, n: int, estimate: float, cap: int, more: bool = False) -> str:
    gib = estimate * BYTES_PER_PAIR / 2 ** 30
    return (f"{where}: {'more than' if more else 'about'} {estimate:.3g} pairs of its {n} original elements face each other "
            f"(visibility plan about {gib:.3g} GiB on the driver), beyond "
            f"radiosity.plan.max-facing-pairs = {cap:g}: raise it (e.g. "
            f"DASK_RADIOSITY__PLAN__MAX_FACING_PAIRS={max(cap, estimate) * 1.5:.2g}) if the memory "
            "is there, or use --method hierarchical (it clusters the originals)")
