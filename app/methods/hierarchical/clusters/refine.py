"""Clustering above the original elements (SPEC §9; Smits, Arvo & Greenberg 1994): the tree over
the originals (scene/originals.build_tree with one original per leaf) is the top of the
hierarchy. Refinement starts at the root's self-link; a link between clusters is kept while a
bound on the light it carries stays below epsilon, and pairs of originals it reaches go on to
the element-level refinement (links.py). Nothing is ever listed per pair of originals that the
refinement did not reach.

Form factors of a cluster link p <- q (computed in clusterweights.py; transport:
clusterlinks.py; design: docs/src/design/methods-hierarchical-clusters.md):
F_pq = S_p(u) S_q(-u) / (pi r^2 A_p), S_x(u) = sum over x's elements of A_i max(0, n_i . u)
(A_i |n_i . u| for a two-sided element: it shows the side that faces u), u and r between the
area centroids; q sends its elements' area-weighted mean radiance and p receives uniformly
(Sillion's isotropic model; a two-sided element sends and receives on the side that faces the
other end: clusters/transport.py); A_p F_pq = A_q F_qp, so energy is conserved.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass

import numba
import numpy as np

from radiosity.core.tolerances import TOL

from radiosity.scene.originals import faces

# A link is near when its ends' box diagonals summed exceed this many times the distance
# between the boxes: never kept between clusters (the estimate from sample pairs, and the
# receivers' uniform share, fail there; docs/src/design/methods-hierarchical-clusters.md).
ADMISSIBLE = 2.0
# The cluster tree (K nodes, node 0 the root, children after parents; leaves hold one original):
# left, right (K,) (-1 at a leaf), start, end (K,) ranges into order (n,); lo, hi (K, 3) vertex
# boxes; axis (K, 3), spread (K,) the normal cone; two (K,) any two-sided element; area (K,);
# center (K, 3) area centroid; rho, lhat (K,): the largest reflectance and a-priori radiance
# of the elements below (the oracle's weights, front side); rec (K, 26) what the refinement
# reads of both ends of every link, one row a node (it waits on memory more than it computes:
# docs/src/design/methods-hierarchical-clusters.md): lo, hi, clo, chi, axis (3 each), spread,
# two, the vertex box's diagonal, area, rho, lhat, the slab along the axis (the least and
# the largest axis . v over the vertices: _may_face) and the area centroid; stop (K,) bool: an
# inner node that stays whole where a link to it can be kept (refine_clusters: no camera's
# pixel shows it and it is small, as the element level leaves unseen originals).
CTree = namedtuple("CTree", "left right start end order lo hi clo chi axis spread two area center "
                            "rho lhat rec stop")
LO, HI, CLO, CHI, AXIS, SPREAD, TWO, DIAG, AREA, RHO, LHAT = 0, 3, 6, 9, 12, 15, 16, 17, 18, 19, 20
SLO, SHI = 21, 22
CEN = 23  # the area centroid (3): the estimate reads it with the rest of the row
# The originals as the refinement reads them: normal (n, 3), offset (n,) = n . centre, verts
# (n, 4, 3) (triangles repeat vertex 2), area (n,), center (n, 3), two_sided (n,), eps (the
# facing tolerance in scene units); ona (n, 8) normal, area, centre and two-sided (1.0 or 0.0)
# in the tree's order (a node's elements contiguous: the sums and samples over them read
# memory in order).
CElems = namedtuple("CElems", "normal offset verts area center two_sided eps ona")


#: build_tree's normal_weight (the normals against the centres) and `separate` (nodes whose
#: orientations interleave split by centre) for the cluster tree: a rough surface's clusters,
#: split by normal, interleave and are never admissible; both cut its links but cost rooms
#: (docs/src/design/methods-hierarchical-clusters.md, "The tree weighs normals less").
NORMAL_WEIGHT = 1.0
SEPARATE = False


@dataclass(frozen=True)
class ClusterTree:
    """The cluster tree of a scene's originals and what the refinement needs of them."""

    tree: CTree
    elems: CElems
    lref: float

    @property
    def nodes(self) -> int:
        return len(self.tree.left)

    @property
    def parent(self) -> np.ndarray:
        """(K,) int64 parent of each node (-1 at the root)."""
        par = np.full(self.nodes, -1, np.int64)
        inner = np.nonzero(self.tree.left >= 0)[0]
        par[self.tree.left[inner]] = inner
        par[self.tree.right[inner]] = inner
        return par

    @property
    def leaf_orig(self) -> np.ndarray:
        """(K,) int64: the original of each leaf, -1 at inner nodes."""
        t = self.tree
        out = np.full(self.nodes, -1, np.int64)
        leaf = t.left < 0
        out[leaf] = t.order[t.start[leaf]]
        return out


def cluster_tree(elements, wrho: np.ndarray, lhat: np.ndarray, lref: float,
                 unseen: np.ndarray | None = None, min_size: float = 0.0) -> ClusterTree:
    """The cluster tree over `elements` (types.Elements) with the oracle's per-original weights
    wrho, lhat (n, 2) and lref (params.oracle_weights; the weights of the front sides). Inner nodes whose originals are all
    `unseen` (n,) bool (outside every camera's footprint: links.plan_links) and whose
    sqrt(area) is at most `min_size` (scene units; the element level's
    hierarchy.min-node-size) stay whole where a link to them can be kept (`stop`)."""
    from radiosity.scene.originals import build_tree

    t = build_tree(elements.verts, elements.nverts, elements.normal, elements.center,
                   elements.two_sided, leaf=1, normal_weight=NORMAL_WEIGHT,
                   separate=SEPARATE)
    K = len(t.left)
    o = t.order
    area = np.asarray(elements.area, np.float64)
    cum = np.concatenate([[0.0], np.cumsum(area[o])])
    A = cum[t.end] - cum[t.start]
    wc = np.concatenate([np.zeros((1, 3)), np.cumsum(area[o, None] * elements.center[o], axis=0)])
    center = (wc[t.end] - wc[t.start]) / np.where(A > 0, A, 1.0)[:, None]
    # a two-sided original's weights: its larger side's (either may face a link's other end)
    two = np.asarray(elements.two_sided, bool)
    rho = _range_max(np.where(two, wrho.max(axis=1), wrho[:, 0])[o], t.start, t.end, t.left,
                     t.right)
    lh = _range_max(np.where(two, lhat.max(axis=1), lhat[:, 0])[o], t.start, t.end, t.left,
                    t.right)
    verts = np.where(elements.nverts[:, None, None] == 3, elements.verts[:, [0, 1, 2, 2]],
                     elements.verts)
    new = _preorder(t.left, t.right)  # new -> old: subtrees contiguous (memory locality)
    old = np.empty_like(new)
    old[new] = np.arange(K)
    kid = lambda c: np.where(c[new] >= 0, old[np.maximum(c[new], 0)], -1)  # noqa: E731
    diag = np.linalg.norm(t.hi - t.lo, axis=1)
    slab = _slabs(t.start, t.end, o, verts, t.axis)
    rec = np.concatenate([t.lo, t.hi, t.clo, t.chi, t.axis, t.spread[:, None], t.two[:, None],
                          diag[:, None], A[:, None], rho[:, None], lh[:, None], slab, center],
                         axis=1)[new]
    tree = CTree(kid(t.left), kid(t.right), t.start[new], t.end[new], o, t.lo[new], t.hi[new],
                 t.clo[new], t.chi[new], t.axis[new], t.spread[new], t.two[new], A[new],
                 center[new], rho[new], lh[new], np.ascontiguousarray(rec),
                 _stops(t, A, unseen, min_size)[new])
    ona = np.concatenate([np.asarray(elements.normal, np.float64), area[:, None],
                          np.asarray(elements.center, np.float64),
                          np.asarray(t.two_sided, np.float64)[:, None]], axis=1)[o]
    elems = CElems(np.asarray(elements.normal, np.float64), t.offset, verts, area,
                   np.asarray(elements.center, np.float64), t.two_sided, float(t.eps),
                   np.ascontiguousarray(ona))
    assert K == len(A)
    return ClusterTree(tree, elems, float(lref))


@numba.njit(cache=True, nogil=True)
def _slabs(start, end, order, verts, axis):
    """(K, 2): the least and the largest axis_x . v over the vertices v of node x's elements."""
    K = start.shape[0]
    out = np.empty((K, 2))
    for x in range(K):
        lo, hi = np.inf, -np.inf
        for m in range(start[x], end[x]):
            i = order[m]
            for k in range(verts.shape[1]):
                s = axis[x, 0] * verts[i, k, 0] + axis[x, 1] * verts[i, k, 1] \
                    + axis[x, 2] * verts[i, k, 2]
                lo = min(lo, s)
                hi = max(hi, s)
        out[x, 0], out[x, 1] = lo, hi
    return out


def _stops(t, area: np.ndarray, unseen: np.ndarray | None, min_size: float) -> np.ndarray:
    """(K,) bool: inner nodes of tree t whose originals are all unseen and whose sqrt(area) is
    at most min_size."""
    if unseen is None or min_size <= 0.0:
        return np.zeros(len(t.left), np.bool_)
    cum = np.concatenate([[0], np.cumsum(np.asarray(unseen, bool)[t.order])])
    whole = cum[t.end] - cum[t.start] == t.end - t.start
    return whole & (t.left >= 0) & (np.sqrt(area) <= min_size)


def _preorder(left, right) -> np.ndarray:
    """The nodes of a tree (root 0) in depth-first preorder: parents before children, every
    subtree contiguous. The refinement visits links between nearby nodes one after another, so
    this order keeps their records close in memory."""
    out = np.empty(len(left), np.int64)
    stack = [0]
    k = 0
    while stack:
        x = stack.pop()
        out[k] = x
        k += 1
        if left[x] >= 0:
            stack.append(right[x])
            stack.append(left[x])
    return out


def _range_max(values, start, end, left, right):
    """max of values[start:end] per node, bottom-up (children follow their parents)."""
    K = len(start)
    out = np.zeros(K)
    leaf = left < 0
    out[leaf] = values[start[leaf]]
    for k in range(K - 1, -1, -1):
        if left[k] >= 0:
            out[k] = max(out[left[k]], out[right[k]])
    return out


# ----------------------------------------------------------------------------- refinement
# The kernels below take plain arrays (rec, start, end, ona, ...), never the CTree / CElems
# namedtuples: numba counts a reference to every member of a namedtuple each time one is passed
# or read, and on the 200 000-triangle terrain that cost more than the arithmetic
# (docs/src/design/methods-hierarchical-clusters.md).

@numba.njit(cache=True, nogil=True, inline="always")
def _may_face(rec, A, B, eps, gap):
    """Can some element of node B lie in front of (or, two-sided, behind) the plane of some
    element of node A? False only where certainly not: the least of originals._may_face's
    bound from the boxes and the same from the slabs along the axes (gap = |a_A - a_B|, the
    two cone axes apart). The slabs prove nodes of one flat face coplanar where it is tilted
    (its box corners lie off the plane): without them, every pair of nodes on such a face was
    refined as if they faced, down to links that carry nothing
    (docs/src/design/methods-hierarchical-clusters.md, "Flat faces")."""
    up = 0.0
    low = 0.0
    vmax2 = 0.0
    # the same from the slabs: a_A . v <= a_A . m_B + a_B . (v - m_B) + |a_A - a_B| |v - m_B|
    # for v in B (m_B its box centre, |v - m_B| at most half its diagonal), and A's centres lie
    # in A's slab
    am = 0.0
    bm = 0.0
    for k in range(3):
        dlo = rec[B, LO + k] - rec[A, CHI + k]
        dhi = rec[B, HI + k] - rec[A, CLO + k]
        a = rec[A, AXIS + k]
        if a > 0:
            up += a * dhi
            low += a * dlo
        else:
            up += a * dlo
            low += a * dhi
        m = max(abs(dlo), abs(dhi))
        vmax2 += m * m
        m = 0.5 * (rec[B, LO + k] + rec[B, HI + k])
        am += a * m
        bm += rec[B, AXIS + k] * m
    wob = gap * 0.5 * rec[B, DIAG]
    up = min(up, am + rec[B, SHI] - bm + wob - rec[A, SLO])
    low = max(low, am + rec[B, SLO] - bm - wob - rec[A, SHI])
    s = rec[A, SPREAD] * np.sqrt(vmax2)
    # eps as originals.faces takes it (a leaf's vertex must lie more than eps off the plane):
    # up + s bounds that distance over every pair, so up + s <= eps leaves no facing pair
    return (up + s > eps) or (rec[A, TWO] > 0 and low - s < -eps)


@numba.njit(cache=True, nogil=True, inline="always")
def _may_face_both(rec, p, q, eps):
    """_may_face both ways (p toward q and q toward p), the cone axes' distance found once."""
    dd = 0.0
    for k in range(3):
        g = rec[p, AXIS + k] - rec[q, AXIS + k]
        dd += g * g
    gap = np.sqrt(dd)
    return _may_face(rec, p, q, eps, gap) and _may_face(rec, q, p, eps, gap)


@numba.njit(cache=True, nogil=True, inline="always")
def _box_distance2(rec, p, q):
    d2 = 0.0
    for k in range(3):
        g = max(rec[q, LO + k] - rec[p, HI + k], rec[p, LO + k] - rec[q, HI + k], 0.0)
        d2 += g * g
    return d2


@numba.njit(cache=True, nogil=True, inline="always")
def _near(rec, p, q, d2):
    """Is the link between nodes p, q (boxes sqrt(d2) apart) near: its ends' box diagonals
    summed above ADMISSIBLE times the distance (touching boxes included)? Never kept between
    clusters: the point kernel between samples is no estimate there."""
    s = rec[p, DIAG] + rec[q, DIAG]
    return s * s > ADMISSIBLE * ADMISSIBLE * d2


@numba.njit(cache=True, nogil=True, inline="always")
def _relative_error(rec, p, q, d):
    """The relative error of carrying a link between nodes p, q (boxes d apart, not _near)
    through the clusters: (diam_p + diam_q) / d for the distances and directions taken between
    centroids, plus both normal cones' spread for the receivers' uniform share, at most 1."""
    return min((rec[p, DIAG] + rec[q, DIAG]) / d + rec[p, SPREAD] + rec[q, SPREAD], 1.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _cos_bound(rec, p, q, d):
    """The largest cosine between a normal of node p (in its cone: axis a, spread s >= |n - a|)
    and a direction from a point of p's box to a point of q's box (all at least d apart):
    a . v / |v| + s <= max(0, max_v a . v) / d + s, at most 1; |a . v| where p holds a
    two-sided element (it shows either side)."""
    up = 0.0
    low = 0.0
    for k in range(3):
        a = rec[p, AXIS + k]
        lo = rec[q, LO + k] - rec[p, HI + k]
        hi = rec[q, HI + k] - rec[p, LO + k]
        up += a * hi if a > 0 else a * lo
        low += a * lo if a > 0 else a * hi
    if rec[p, TWO] > 0:
        up = max(up, -low)
    return min(1.0, max(0.0, up) / d + rec[p, SPREAD])


@numba.njit(cache=True, nogil=True, inline="always")
def _all_face(rec, p, q):
    """Does every element of node p face every point of node q's box, and every element of q
    every point of p's box (n . v > 0 for every normal in the node's cone and every direction v
    from its box to the other's)? n . v / |v| >= min_v a . v / max |v| - spread, where the
    offsets from q's box to p's are those from p's to q's negated, and so is the largest |v|.
    Then the centroid direction's cosines are an estimate of every pair's. A node holding a
    two-sided element passes where all its normals see the other box from one side, the same
    or the opposite (n . v of one sign: it shows that side to all of it)."""
    lowp = 0.0
    lowq = 0.0
    upp = 0.0
    upq = 0.0
    vmax2 = 0.0
    for k in range(3):
        a = rec[p, AXIS + k]
        b = rec[q, AXIS + k]
        lo = rec[q, LO + k] - rec[p, HI + k]
        hi = rec[q, HI + k] - rec[p, LO + k]
        lowp += a * lo if a > 0 else a * hi
        lowq += b * (-hi) if b > 0 else b * (-lo)
        upp += a * hi if a > 0 else a * lo
        upq += b * (-lo) if b > 0 else b * (-hi)
        m = max(abs(lo), abs(hi))
        vmax2 += m * m
    if rec[p, TWO] > 0:
        lowp = max(lowp, -upp)
    if rec[q, TWO] > 0:
        lowq = max(lowq, -upq)
    if lowp <= 0.0 or lowq <= 0.0:
        return False
    v = np.sqrt(vmax2)
    return lowp / v > rec[p, SPREAD] and lowq / v > rec[q, SPREAD]


@numba.njit(cache=True, nogil=True, inline="always")
def _error_bound(rec, p, q, d2, lref):
    """The oracle of a link between nodes p, q whose boxes are d = sqrt(d2) apart: the bound on
    the light it carries, max(rho_p A_q Lhat_q, rho_q A_p Lhat_p) c_p c_q / (pi d^2 lref) (the
    cosines at most what the normal cones allow, _cos_bound; every distance at least d), times
    the relative error of carrying it through the
    clusters: (diam_p + diam_q) / d for the distances and directions taken between centroids,
    plus both normal cones' spread for the cosines taken as the cluster's mean (isotropic)."""
    if _near(rec, p, q, d2):  # never kept
        return np.inf
    d = np.sqrt(d2)
    cp = _cos_bound(rec, p, q, d)
    cq = _cos_bound(rec, q, p, d)
    carried = max(rec[p, RHO] * rec[q, AREA] * rec[q, LHAT],
                  rec[q, RHO] * rec[p, AREA] * rec[p, LHAT]) * cp * cq / (np.pi * d2 * lref)
    return carried * _relative_error(rec, p, q, d)


@numba.njit(cache=True, nogil=True, inline="always")
def _cosine_along(ona, k, ux, uy, uz):
    """Element k's cosine n_k . u toward the direction u (the centroids' direction); |n_k . u|
    for a two-sided element."""
    c = ona[k, 0] * ux + ona[k, 1] * uy + ona[k, 2] * uz
    return abs(c) if ona[k, 7] > 0 else c


@numba.njit(cache=True, nogil=True, inline="always")
def _cosine_toward(rec, ona, k, y, d2):
    """min(1, max_w n_k . (w - c_k) / max(d, |c_k - box y|)) for element k (centre c_k) and
    node y's box (d^2 = d2, the boxes' distance): the cosine between the element's normal and
    the direction from its centre toward the point w of y's box it faces most (the numerator
    holds for every point of the element: n_k . x = n_k . c_k on its plane); 0 where it faces
    none of y's box. A two-sided element's either side: the larger of n's and -n's."""
    up = 0.0
    low = 0.0
    for c in range(3):
        n = ona[k, c]
        up += n * ((rec[y, HI + c] if n > 0 else rec[y, LO + c]) - ona[k, 4 + c])
        low += n * ((rec[y, LO + c] if n > 0 else rec[y, HI + c]) - ona[k, 4 + c])
    if ona[k, 7] > 0:
        up = max(up, -low)
    if up <= 0.0:
        return 0.0
    g2 = 0.0
    for c in range(3):
        w = ona[k, 4 + c]
        g = max(rec[y, LO + c] - w, w - rec[y, HI + c], 0.0)
        g2 += g * g
    return min(1.0, up / np.sqrt(max(g2, d2)))


#: A node's normal cone at most this wide (rec's SPREAD) counts as one normal in the estimate
#: (its exposure A_x max(0, a . u) to within A_x times the spread; core.tolerances: flat_spread).
FLAT_SPREAD = TOL.flat_spread


@numba.njit(cache=True, nogil=True, inline="always")
def _carried(rec, p, q, sp, cp, sq, cq, r2, lref, rel):
    """The estimate from the ends' exposures sp, sq and largest cosines cp, cq (the light the
    link carries to either end's most exposed element, weighted, times the relative error)."""
    return max(rec[p, RHO] * sq * cp * rec[q, LHAT],
               rec[q, RHO] * sp * cq * rec[p, LHAT]) / (np.pi * r2 * lref) * rel


@numba.njit(cache=True, nogil=True, inline="always")
def _error_estimate(rec, start, end, ona, p, q, d2, lref, stop):
    """The oracle's estimate where the bound (_error_bound) says split: the light the link
    carries to the most exposed element of either end, from the other end's projected area
    toward it, S_q(-u) max_i cos_i / (pi r^2) (exact sums over the elements, at the centroids'
    distance), weighted as the bound is and times the same relative error.

    The cosines are taken along the centroid direction u where every element of each end
    faces the other's box (_all_face; a node whose normals are one, spread at most
    FLAT_SPREAD, from its area and cone axis), else each element's toward the other's box
    (_cosine_toward): a cluster mixing faces (a block's corner, a block and the floor) may face
    the other end only away from the centroid direction
    (docs/src/design/methods-hierarchical-clusters.md).

    Costs the two nodes' element counts, but the sums only grow, element by element, and so
    does the estimate from them (each float operation is monotone in non-negative operands):
    once it reaches `stop` (the caller's epsilon) the loop ends and returns that lower bound,
    which splits the link as the whole sum would (np.inf: the whole estimate)."""
    dx = rec[q, CEN] - rec[p, CEN]
    dy = rec[q, CEN + 1] - rec[p, CEN + 1]
    dz = rec[q, CEN + 2] - rec[p, CEN + 2]
    r2 = dx * dx + dy * dy + dz * dz
    if r2 <= d2 or r2 <= 0.0:
        return np.inf
    if _near(rec, p, q, d2):  # never kept (and the element sums below not spent on it)
        return np.inf
    d = np.sqrt(d2)
    rel = _relative_error(rec, p, q, d)
    d2 = d * d  # as the cosines toward the boxes always took it
    r = np.sqrt(r2)
    ux, uy, uz = dx / r, dy / r, dz / r
    along = _all_face(rec, p, q)
    sp = cp = sq = cq = 0.0
    i, j = start[p], start[q]
    if along and rec[p, SPREAD] <= FLAT_SPREAD:
        cp = rec[p, AXIS] * ux + rec[p, AXIS + 1] * uy + rec[p, AXIS + 2] * uz
        cp = max(0.0, abs(cp) if rec[p, TWO] > 0 else cp)
        sp = rec[p, AREA] * cp
        i = end[p]
    if along and rec[q, SPREAD] <= FLAT_SPREAD:
        cq = rec[q, AXIS] * -ux + rec[q, AXIS + 1] * -uy + rec[q, AXIS + 2] * -uz
        cq = max(0.0, abs(cq) if rec[q, TWO] > 0 else cq)
        sq = rec[q, AREA] * cq
        j = end[q]
    # both ends' sums in their own order, a step of each at a time
    while i < end[p] or j < end[q]:
        if i < end[p]:
            c = _cosine_along(ona, i, ux, uy, uz) if along else \
                _cosine_toward(rec, ona, i, q, d2)
            if c > 0.0:
                sp += ona[i, 3] * c
                cp = max(cp, c)
            i += 1
        if j < end[q]:
            c = _cosine_along(ona, j, -ux, -uy, -uz) if along else \
                _cosine_toward(rec, ona, j, p, d2)
            if c > 0.0:
                sq += ona[j, 3] * c
                cq = max(cq, c)
            j += 1
        if _carried(rec, p, q, sp, cp, sq, cq, r2, lref, rel) >= stop:
            break
    return _carried(rec, p, q, sp, cp, sq, cq, r2, lref, rel)


@numba.njit(cache=True, nogil=True)
def refine_clusters(t, e, eps, lref, cap, init, frontier, probe=0.0, two=True):
    """The cluster refinement from the links `init` (s, 2) int64 (the root's self-link (0, 0):
    the whole refinement): (links (k, 2) int64 node pairs kept as cluster links, pairs (j, 2)
    int64 originals I < J handed to the element-level refinement, counts [evaluated, culled by
    orientation, kept, pairs], pending (r, 2) int64). A link between nodes p, q (boxes apart;
    holding two-sided originals only with `two`: clusters/transport.py) is kept when its error bound (_error_bound) is at
    most eps (two originals: one link over both, as the element-level refinement's root link);
    otherwise the end with more area (the larger solid angle from the other) is split, but not
    an end that stays whole (t.stop) where the link could be kept: then the other end, or
    where neither can split the link is kept (as the element level keeps a link between nodes
    it cannot split). eps = 0 lists exactly the facing pairs of originals. frontier > 0:
    breadth first, stop once that many links wait to be refined and return them as `pending`
    (the cut into tasks: refining each of them on its own gives the same links and pairs); 0:
    depth first to the end (pending empty). probe > eps: a link that could be kept but for its
    estimate, which is below `probe`, is neither kept nor split but listed in `probes` (r, 2)
    int64, for rays to decide (clusters/tasks._probe: dropped where every ray is blocked)."""
    left, right, start, end, order, rec, stop = t.left, t.right, t.start, t.end, t.order, \
        t.rec, t.stop
    normal, verts, offset, two_sided, ona, feps = e.normal, e.verts, e.offset, e.two_sided, \
        e.ona, e.eps
    links = np.empty((max(cap, 16), 2), np.int64)
    pairs = np.empty((max(cap, 16), 2), np.int64)
    probes = np.empty((16, 2), np.int64)
    nl = 0
    npr = 0
    nb = 0
    counts = np.zeros(4, np.int64)
    stack = np.empty((max(1024, 2 * init.shape[0]), 2), np.int64)
    ns = init.shape[0]
    stack[:ns] = init
    head = 0  # breadth first (frontier > 0): links are taken from stack[head], else from the top
    while ns > head:
        if frontier > 0:
            if ns - head >= frontier:
                break
            p, q = stack[head, 0], stack[head, 1]
            head += 1
        else:
            ns -= 1
            p, q = stack[ns, 0], stack[ns, 1]
        if ns + 3 >= stack.shape[0]:
            grown = np.empty((2 * stack.shape[0], 2), np.int64)
            grown[:stack.shape[0]] = stack
            stack = grown
        counts[0] += 1
        lp, lq = left[p] < 0, left[q] < 0
        if p == q:
            if lp:
                continue
            a, b = left[p], right[p]
            stack[ns, 0], stack[ns, 1] = a, a
            stack[ns + 1, 0], stack[ns + 1, 1] = b, b
            stack[ns + 2, 0], stack[ns + 2, 1] = a, b
            ns += 3
            continue
        if not _may_face_both(rec, p, q, feps):
            counts[1] += 1
            continue
        d2 = _box_distance2(rec, p, q)
        ok = d2 > 0.0 and (two or (rec[p, TWO] == 0 and rec[q, TWO] == 0)) \
            and not _near(rec, p, q, d2)
        keep = False
        est = np.inf
        if ok:
            keep = _error_bound(rec, p, q, d2, lref) <= eps
            if not keep:
                # stops at max(eps, probe): below eps the whole estimate, to the bit
                est = _error_estimate(rec, start, end, ona, p, q, d2, lref, max(eps, probe))
                keep = est < eps
        probe_it = probe > eps and est < probe
        # an end that stays whole (stop) is not split where the link could be kept: the other
        # end is, and where neither can split the link is kept above epsilon (eps > 0 only:
        # epsilon 0 still lists every facing pair of originals)
        fp = lp or (ok and eps > 0.0 and stop[p])
        fq = lq or (ok and eps > 0.0 and stop[q])
        if fp and fq and not (lp and lq):
            keep = True
        if lp and lq:  # two originals: a link over both, or a pair for the element level
            i, j = order[start[p]], order[start[q]]
            if not (faces(normal, verts, offset, two_sided, feps, i, j)
                    and faces(normal, verts, offset, two_sided, feps, j, i)):
                counts[1] += 1
                continue
            if not keep and probe_it:
                probes, nb = _push(probes, nb, p, q)
                continue
            if not keep:
                if npr == pairs.shape[0]:
                    grown = np.empty((2 * npr, 2), np.int64)
                    grown[:npr] = pairs
                    pairs = grown
                pairs[npr, 0], pairs[npr, 1] = min(i, j), max(i, j)
                npr += 1
                continue
        if keep:
            if nl == links.shape[0]:
                grown = np.empty((2 * nl, 2), np.int64)
                grown[:nl] = links
                links = grown
            links[nl, 0], links[nl, 1] = p, q
            nl += 1
            continue
        if probe_it:
            probes, nb = _push(probes, nb, p, q)
            continue
        # split the end with more area (the larger solid angle seen from the other)
        split_p = (not fp) and (fq or rec[p, AREA] >= rec[q, AREA])
        if split_p:
            stack[ns, 0], stack[ns, 1] = left[p], q
            stack[ns + 1, 0], stack[ns + 1, 1] = right[p], q
        else:
            stack[ns, 0], stack[ns, 1] = p, left[q]
            stack[ns + 1, 0], stack[ns + 1, 1] = p, right[q]
        ns += 2
    counts[2] = nl
    counts[3] = npr
    return links[:nl], pairs[:npr], counts, stack[head:ns].copy(), probes[:nb]


@numba.njit(cache=True, nogil=True, inline="always")
def _push(rows, n, a, b):
    """Append (a, b) to rows (m, 2) holding n, grown twice where full: (rows, n + 1)."""
    if n == rows.shape[0]:
        grown = np.empty((2 * n, 2), np.int64)
        grown[:n] = rows
        rows = grown
    rows[n, 0], rows[n, 1] = a, b
    return rows, n + 1
