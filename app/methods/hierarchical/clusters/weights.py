"""Form factors and visible fractions of cluster links (SPEC §9; the links themselves:
clusters.refine_clusters). F_pq = S_p(u) S_q(-u) / (pi r^2 A_p) times a sampled correction,
from pairs of elements drawn by their projected area toward the other end (_weights); the
visible fraction from k rays between points of k of those pairs (link_weights, _visible).

Design notes and measurements: docs/src/design/methods-hierarchical-clusters.md.
"""

from __future__ import annotations

import threading
import weakref

import numba
import numpy as np

from radiosity.methods.hierarchical.clusters.refine import HI, LO, ClusterTree
from radiosity.tracing.shafts import clear_of


@numba.njit(cache=True, nogil=True, inline="always")
def _facing(ona, m, ux, uy, uz):
    """Element m's (tree order) cosine toward u as it shows itself: max(0, n . u), |n . u| for a
    two-sided element (the side that faces u)."""
    c = ona[m, 0] * ux + ona[m, 1] * uy + ona[m, 2] * uz
    return abs(c) if ona[m, 7] > 0 else max(0.0, c)


@numba.njit(cache=True, nogil=True, inline="always")
def _pick(start, end, area, ona, x, ux, uy, uz, k, out):
    """k elements of node x stratified by their projected area toward u (A_i max(0, n_i . u),
    A_i |n_i . u| two-sided: _facing), into out[:k] as positions in the tree's order
    (ascending); by area where no element faces u. Returns S_x(u) = the sum of those projected
    areas (0 where none faces u). Plain arrays, not the tree's named tuple (clusters.py's note
    on the kernels' arguments)."""
    s0, s1 = start[x], end[x]
    if s1 - s0 == 1:  # one element: every pick is it
        for j in range(k):
            out[j] = s0
        return ona[s0, 3] * _facing(ona, s0, ux, uy, uz)
    total = 0.0
    for m in range(s0, s1):
        total += ona[m, 3] * _facing(ona, m, ux, uy, uz)
    by_area = total <= 0.0
    if by_area:
        total = area[x]
    step = total / k  # the strata's width: the j-th pick is where the sum passes (j + 0.5) step
    acc = 0.0
    j = 0
    for m in range(s0, s1):
        if by_area:
            acc += ona[m, 3]
        else:
            acc += ona[m, 3] * _facing(ona, m, ux, uy, uz)
        while j < k and (j + 0.5) * step <= acc:
            out[j] = m
            j += 1
    while j < k:  # rounding at the end
        out[j] = s1 - 1
        j += 1
    return 0.0 if by_area else total


FF_SAMPLES = 16  # sample pairs of elements per cluster link for its form factors


@numba.njit(cache=True, nogil=True, inline="always")
def _kernel_over(ona, i, j, wi, wj, si, sj):
    """max(0, cos_i) max(0, cos_j) / (pi r^2) between the centroids of the elements at tree
    positions i and j (CElems.ona), divided by their sampling weights' cosines wi, wj > 0 (one
    division: the cosines' 1 / r each folded into it). A two-sided element's cosine on the
    side that the sampling weight's direction u faces (the sign of wi, wj before their |.|:
    si, sj = +-1), so that it sends and receives on the side the link uses."""
    dx = ona[j, 4] - ona[i, 4]
    dy = ona[j, 5] - ona[i, 5]
    dz = ona[j, 6] - ona[i, 6]
    r2 = dx * dx + dy * dy + dz * dz
    ci = si * (ona[i, 0] * dx + ona[i, 1] * dy + ona[i, 2] * dz)
    cj = -sj * (ona[j, 0] * dx + ona[j, 1] * dy + ona[j, 2] * dz)
    if r2 <= 0.0 or ci <= 0.0 or cj <= 0.0:
        return 0.0
    return ci * cj / (np.pi * r2 * r2 * wi * wj)


@numba.njit(cache=True, nogil=True)
def _weights(t, e, links, samples, cols, lref, faint, F, ep, eq, few):
    """One pass over cluster links (p, q): F[a] = F_pq, F_qp from `samples` pairs of elements
    drawn in proportion to A_i max(0, n_i . u) at each end (_pick; the second end's picks
    rotated by half a stride): the point kernel between the pair's centroids divided by the
    sampling weights' cosines toward u, averaged, times S_p(u) S_q(-u), an estimate of
    sum_ij A_i A_j K_ij without the bias of one distance and one direction between centroids
    (1 / r^2 is convex: at the centroid distance it is too small). The ray ends ep[a], eq[a]
    (k = ep.shape[1]): the pairs at `cols` (one per stratum of samples / k), or where cols is
    empty k pairs picked anew. few[a]: the link carries at most `faint` in the oracle's
    weighting, max(rho_p F_pq Lhat_q, rho_q F_qp Lhat_p) / lref <= faint (lref 0: never)."""
    k = ep.shape[1]
    start, end, area, order, center, rho, lhat = t.start, t.end, t.area, t.order, t.center, \
        t.rho, t.lhat
    ona = e.ona
    sp = np.empty(max(samples, k), np.int64)
    sq = np.empty(max(samples, k), np.int64)
    half = samples // 2
    for a in range(links.shape[0]):
        p, q = links[a, 0], links[a, 1]
        dx = center[q, 0] - center[p, 0]
        dy = center[q, 1] - center[p, 1]
        dz = center[q, 2] - center[p, 2]
        r = np.sqrt(dx * dx + dy * dy + dz * dz)
        rr = max(r, 1e-300)
        ux, uy, uz = dx / rr, dy / rr, dz / rr
        Sp = _pick(start, end, area, ona, p, ux, uy, uz, samples, sp)
        Sq = _pick(start, end, area, ona, q, -ux, -uy, -uz, samples, sq)
        F[a, 0] = F[a, 1] = 0.0
        if r > 0.0 and Sp > 0.0 and Sq > 0.0:
            acc = term = 0.0
            i0 = j0 = -1
            mq = half  # q's pick paired with p's m-th: (m + half) mod samples
            for m in range(samples):
                i, j = sp[m], sq[mq]
                mq = mq + 1 if mq + 1 < samples else 0
                if i != i0 or j != j0:  # picks repeat in small nodes: one kernel per pair
                    i0, j0 = i, j
                    wi = ona[i, 0] * ux + ona[i, 1] * uy + ona[i, 2] * uz
                    wj = -(ona[j, 0] * ux + ona[j, 1] * uy + ona[j, 2] * uz)
                    si = -1.0 if ona[i, 7] > 0 and wi < 0.0 else 1.0  # the side facing u
                    sj = -1.0 if ona[j, 7] > 0 and wj < 0.0 else 1.0
                    wi, wj = si * wi, sj * wj
                    term = _kernel_over(ona, i, j, wi, wj, si, sj) if wi > 0.0 and wj > 0.0 \
                        else 0.0
                acc += term
            g = Sp * Sq * acc / samples
            F[a, 0] = g / area[p]
            F[a, 1] = g / area[q]
        if cols.shape[0] > 0:
            for c in range(k):
                ep[a, c] = order[sp[cols[c]]]
                eq[a, c] = order[sq[(cols[c] + half) % samples]]
        elif k > 0:
            _pick(start, end, area, ona, p, ux, uy, uz, k, sp)
            _pick(start, end, area, ona, q, -ux, -uy, -uz, k, sq)
            for c in range(k):
                ep[a, c] = order[sp[c]]
                eq[a, c] = order[sq[(c + k // 2) % k]]
        few[a] = lref > 0.0 and max(rho[p] * F[a, 0] * lhat[q], rho[q] * F[a, 1] * lhat[p]) \
            / lref <= faint


#: Cluster links per chunk of the form factors and rays (bounds the sample arrays: 2^16 links
#: x 16 samples x 2 ends x 8 bytes = 16 MiB).
CHUNK = 1 << 16


def link_form_factors(ct: ClusterTree, links: np.ndarray, samples: int = FF_SAMPLES) -> np.ndarray:
    """F_pq, F_qp (len(links), 2) of cluster links (p, q): sum_ij A_i A_j K_ij / A_p and / A_q
    estimated from `samples` stratified pairs of elements (_weights); A_p F_pq = A_q F_qp."""
    return link_weights(ct, links, None, 0, samples)[0]


@numba.njit(cache=True, nogil=True)
def _ends(verts, ids, cols, out):
    """out[r] = point cols[r] % 4 of element ids[r]'s four: the centroids of a triangle's four
    midpoint sub-triangles (verts repeat vertex 2), the centres of a quad's four sub-quads
    (bilinear at 1/4 and 3/4). Each stands for a quarter of the element's area (a triangle's
    exactly, a quad's where it is a parallelogram)."""
    for r in range(ids.shape[0]):
        i = ids[r]
        s = cols[r] % 4
        tri = verts[i, 3, 0] == verts[i, 2, 0] and verts[i, 3, 1] == verts[i, 2, 1] \
            and verts[i, 3, 2] == verts[i, 2, 2]
        for c in range(3):
            a, b, d, e = verts[i, 0, c], verts[i, 1, c], verts[i, 2, c], verts[i, 3, c]
            if tri:
                if s == 3:
                    out[r, c] = (a + b + d) / 3.0
                else:
                    out[r, c] = (a + b + d + 3.0 * (a if s == 0 else b if s == 1 else d)) / 6.0
            else:
                u = 0.25 if (s == 0 or s == 3) else 0.75
                v = 0.25 if s < 2 else 0.75
                out[r, c] = (1 - u) * (1 - v) * a + u * (1 - v) * b + u * v * d + (1 - u) * v * e


class SolidEnds:
    """Which of each original's four ray ends (_ends) lie inside a solid (contact.inside_solid),
    found once per original and process (solid_ends), for links that have a blocked ray: a
    cluster or an original straddling the footprint of a block standing on it starts some rays
    under the block, where they are all blocked; they are left out of its visible fraction (as
    the element level's sampling.SolidPoints). Threads may share one: two that test the same
    end at once write the same flag."""

    def __init__(self, caster, e):
        self.caster, self.e = caster, e
        self.flags = np.full((len(e.area), 4), -1, np.int8)  # 1 inside, 0 not, -1 unknown

    def void(self, rows: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """(len(rows),) bool: the ends inside a solid, given as rows 4 i + s of the end table
        pts (end_table: point s of element i)."""
        from radiosity.scene.contact import inside_solid

        ids, s = rows // 4, rows % 4
        f = self.flags[ids, s]
        new = np.nonzero(f < 0)[0]
        if len(new):
            key = np.unique(ids[new] * 4 + s[new], return_index=True)[1]
            u = new[key]
            one = ~self.e.two_sided[ids[u]]
            ins = np.zeros(len(u), bool)
            ins[one] = inside_solid(self.caster, pts[rows[u[one]]], self.e.normal[ids[u[one]]],
                                    self.e.two_sided)
            self.flags[ids[u], s[u]] = ins
            f = self.flags[ids, s]
        return f > 0


def end_table(caster, e) -> tuple[np.ndarray, np.ndarray]:
    """(4 n, 3) the four ray ends of each of the originals `e` (_ends; row 4 i + s: point s of
    element i) and (4 n,) the element of each row, made once per caster and process: the rays
    index it (RayCaster.occluded_pairs) instead of copying two points a ray."""
    with _PER_CASTER_LOCK:
        t = _TABLES.get(caster)
        if t is None or len(t[1]) != 4 * len(e.area):
            n = len(e.area)
            owner = np.repeat(np.arange(n, dtype=np.int64), 4)
            pts = np.empty((4 * n, 3))
            _ends(e.verts, owner, np.tile(np.arange(4, dtype=np.int64), n), pts)
            t = _TABLES[caster] = (pts, owner)
        return t


#: end_table's and solid_ends' per caster (and so per process), behind one lock
_TABLES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_SOLIDS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_PER_CASTER_LOCK = threading.Lock()


def solid_ends(caster, e) -> SolidEnds:
    """The process's SolidEnds of the originals `e` that `caster` was built from (one per
    caster: every cluster task of a run shares what the others found; on the tessellated
    Cornell box each ray end was otherwise tested in about 4.6 tasks)."""
    with _PER_CASTER_LOCK:
        s = _SOLIDS.get(caster)
        if s is None or len(s.flags) != len(e.area):
            s = _SOLIDS[caster] = SolidEnds(caster, e)
        return s


@numba.njit(cache=True, nogil=True)
def clear_links(rec, links, lo, hi):
    """(len(links),) bool: the cluster links (p, q) that no segment between their boxes can
    block (shafts.clear_of against the occluder boxes lo, hi: RayCaster.occluder_boxes). Their
    rays would all find the link visible."""
    out = np.zeros(links.shape[0], np.bool_)
    A = np.empty((2, 3))
    B = np.empty((2, 3))
    for a in range(links.shape[0]):
        p, q = links[a, 0], links[a, 1]
        for c in range(3):
            A[0, c], A[1, c] = rec[p, LO + c], rec[p, HI + c]
            B[0, c], B[1, c] = rec[q, LO + c], rec[q, HI + c]
        out[a] = clear_of(A, B, lo, hi)
    return out


@numba.njit(cache=True, nogil=True)
def _ray_ends(ep, eq, few, clear, col, ia, ib, first):
    """The rays of links whose k picks are ep, eq (L, k), flat and in link order: k for a link,
    one (column col[a]) for a faint one (few[a]), none for a clear one (clear[a]). ia, ib (n,)
    each ray's two ends as rows of the end table (end_table: 4 i + s, point s of element i):
    the ray in column c from point c % 4 of ep's element to point (c + 2) % 4 of eq's;
    first[a] link a's first ray."""
    L, k = ep.shape
    r = 0
    for a in range(L):
        first[a] = r
        if clear[a]:
            continue
        c0, c1 = (col[a], col[a] + 1) if few[a] else (0, k)
        for c in range(c0, c1):
            ia[r] = 4 * ep[a, c] + c % 4
            ib[r] = 4 * eq[a, c] + (c + 2) % 4
            r += 1


@numba.njit(cache=True, nogil=True)
def _fractions(occ, few, clear, first, k, v):
    """v[a] = 1 - the blocked share of link a's rays (occ from first[a]: k, or one if few[a]);
    1 where clear[a]."""
    for a in range(few.shape[0]):
        if clear[a]:
            v[a] = 1.0
        elif few[a]:
            v[a] = 1.0 - (1.0 if occ[first[a]] else 0.0)
        else:
            blocked = 0
            for c in range(k):
                if occ[first[a] + c]:
                    blocked += 1
            v[a] = 1.0 - blocked / k


def _visible(caster, e, ep: np.ndarray, eq: np.ndarray, few: np.ndarray, clear: np.ndarray,
             col: np.ndarray, solid: SolidEnds | None = None) -> tuple[np.ndarray, int]:
    """(v, rays cast): 1 - the blocked fraction of each link's rays (one row of ep, eq: (L, k)
    elements; one ray, column col[a], where few[a]; none, and v = 1, where clear[a]). The ray
    in column c runs between point c % 4 of ep's element and point (c + 2) % 4 of eq's
    (_ends, end_table), so a link between two originals, whose k picks are the same two
    elements, casts k different rays, and sees a shadow that crosses them (its centroids
    alone say 0 or 1). With `solid`, the rays of a link (of k rays) with a blocked ray that
    start or end inside a solid are left out of its fraction, unless all do (SolidEnds)."""
    L, k = ep.shape
    nclear = int(clear.sum())
    nfew = int((few & ~clear).sum())
    n = k * (L - nfew - nclear) + nfew
    v = np.ones(L)
    if n == 0:
        return v, 0
    ia = np.empty(n, np.int64)
    ib = np.empty(n, np.int64)
    first = np.empty(L, np.int64)
    _ray_ends(ep, eq, few, clear, col, ia, ib, first)
    pts, owner = end_table(caster, e)
    occ = caster.occluded_pairs(pts, ia, ib, owner)
    _fractions(occ, few, clear, first, k, v)
    if solid is None or k == 1:
        return v, n
    hit = np.nonzero(~few & (v < 1.0))[0]
    if not len(hit):
        return v, n
    r = (first[hit][:, None] + np.arange(k)[None, :]).ravel()
    void = (solid.void(ia[r], pts) | solid.void(ib[r], pts)).reshape(len(hit), k)
    live = (~void).sum(axis=1)
    some = live > 0
    free = (~occ[r].reshape(len(hit), k) & ~void).sum(axis=1)
    v[hit[some]] = free[some] / live[some]
    return v, n


def _one_of(links: np.ndarray, k: int) -> np.ndarray:
    """(len(links),) a column in [0, k) for each link (p, q), from a hash of the two ends: the
    same for the same link in any task."""
    h = (links[:, 0].astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)) \
        ^ (links[:, 1].astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F))
    return ((h >> np.uint64(29)) % np.uint64(k)).astype(np.int64)


def link_weights(ct: ClusterTree, links: np.ndarray, caster, k: int,
                 samples: int = FF_SAMPLES, faint: float = 0.0,
                 solid: SolidEnds | None = None) -> tuple:
    """Form factors (len(links), 2) and visible fractions (len(links),) of cluster links, CHUNK
    links at a time (_weights). The visible fraction from k rays between points on the
    elements of k sample pairs (_visible), taken from the form factors' samples (every
    samples/k-th: one per stratum of the k) where k divides `samples`. A link whose carried
    light in the oracle's weighting, max(rho_p F_pq Lhat_q, rho_q F_qp Lhat_p) / lref, is at
    most `faint` gets one ray, one of its k picked by a hash of the link (_one_of): wholly
    wrong, its visibility errs by no more than the oracle lets a link err, and over many links
    the rays cover every stratum (one fixed stratum put every ray's ends at the same place in
    each node, a bias: rows 0.3-0.6 % short at 4 epsilon on the tessellated Cornell box).
    Links that no segment between their boxes can block (clear_links against the caster's
    occluder_boxes) take no ray. caster None or k = 0: every link fully visible; `solid`:
    rays inside solids left out (_visible). Returns (F, v, rays: the number of rays cast)."""
    F = np.zeros((len(links), 2))
    v = np.ones(len(links))
    rays = 0
    if len(links) == 0:
        return F, v, rays
    k = k if caster is not None and k > 0 else 0
    cols = np.zeros(0, np.int64)
    if 0 < k <= samples and samples % k == 0:
        cols = np.arange(k) * (samples // k) + samples // k // 2  # each stratum's middle
    lref = ct.lref if faint > 0 and k > 1 else 0.0
    boxes = caster.occluder_boxes() if k > 0 else None
    for a in range(0, len(links), CHUNK):
        lk = np.ascontiguousarray(links[a:a + CHUNK])
        ep = np.empty((len(lk), k), np.int64)
        eq = np.empty((len(lk), k), np.int64)
        few = np.empty(len(lk), np.bool_)
        _weights(ct.tree, ct.elems, lk, samples, cols, lref, faint, F[a:a + len(lk)], ep, eq, few)
        if k == 0:
            continue
        clear = np.zeros(len(lk), np.bool_) if boxes is None else \
            clear_links(ct.tree.rec, lk, *boxes)
        v[a:a + len(lk)], n = _visible(caster, ct.elems, ep, eq, few, clear, _one_of(lk, k),
                                       solid)
        rays += n
    return F, v, rays
