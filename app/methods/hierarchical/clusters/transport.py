"""The cluster layer's links as a solve holds them and their transport (SPEC §9; design:
docs/src/design/methods-hierarchical-clusters.md): in the solve's passes q sends its elements'
area-weighted mean radiance and p receives it uniformly (Sillion's isotropic cluster), one
symmetric weight a link; the final gather shares each link's light out over p by the point
kernel from q and its gradient (cluster_final_gather). Two-sided originals (design: "Two-sided
clusters"): a node x sends and receives on two sides, + and - of its cone axis a_x; a link
uses at each end the side that faces the other end's centroid (sides.link_sides), and an original
i of x shows on x's + side its own side that faces a_x (the front where n_i . a_x >= 0, else
the back) and on x's - side the other (one-sided originals: the front on both)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from radiosity.methods.hierarchical.clusters.sides import (_fields_sides, _final_sides,
                                                          _kernel_gradient, _pull_sides,
                                                          _push_fields, _push_sides, _side_sums,
                                                          _two_layout)


@dataclass(frozen=True)
class ClusterLinks:
    """The cluster layer of a solve: the cluster tree (K nodes; parent (K,), leaf_orig (K,) the
    original of each leaf or -1, area (K,)) and its links p, q (k,) int32 node ids sorted by
    (p, q), each with one weight g (k,) float32 = A_p F_pq v = A_q F_qp v: the transfer is
    symmetric by construction, so energy is conserved whatever g's rounding, in 12 bytes a link
    (the 10^6-triangle terrain keeps 229 M of them). With two-sided originals (two (n,) bool
    any True): the nodes' cone axes axis (K, 3), the originals' normals normal (n, 3) and each
    link's sides side (k,) int8 (link_sides); empty where every original is one-sided (front
    sides only, as before)."""

    parent: np.ndarray
    leaf_orig: np.ndarray
    area: np.ndarray
    p: np.ndarray
    q: np.ndarray
    g: np.ndarray
    axis: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    two: np.ndarray = field(default_factory=lambda: np.zeros(0, np.bool_))
    side: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))

    def arrays(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @property
    def links(self) -> int:
        return len(self.p)

    @property
    def two_sided(self) -> bool:
        """Does the layer hold two-sided originals (and so their sides' arrays)?"""
        return bool(len(self.two)) and bool(np.any(self.two))


#: The cluster links are gathered in this many parts, each into its own buffer, summed in a
#: fixed order (threads share the parts; the same bits on any number of cores: ClusterGather).
GATHER_PARTS = 2


class ClusterGather:
    """One pass of the cluster links' transfer into the originals' roots (front side), from
    Lroot (C, n) the originals' area-weighted mean radiance: pull up the cluster tree (the
    nodes' mean radiance, here), gather over the links (node a receives g Lbar_b / A_a) in
    part(k) for k in range(GATHER_PARTS) (any thread, any order: each into its own buffer, so
    a caller can run them beside other work), push down to the leaves' originals in push(G)
    once all are done (the buffers summed in a fixed order: the same bits whoever ran them).
    With `sides` (Lback (C, n) the originals' back sides, cl: ClusterLinks holding two-sided
    originals) each node's two sides (the module's note), into G and Gback."""

    def __init__(self, Lroot, parent, leaf_orig, area, p, q, g, sides=None):
        self.cl = None if sides is None or not sides[1].two_sided else sides[1]
        if self.cl is None:
            self.S, self.inv = _pull_means(Lroot, parent, leaf_orig, area)
        else:
            c = self.cl
            self.S, self.inv = _pull_sides(Lroot, sides[0], parent, leaf_orig, area, c.axis,
                                           c.normal, c.two)
        self.parent, self.leaf_orig, self.p, self.q, self.g = parent, leaf_orig, p, q, g
        self.cut = np.linspace(0, len(p), GATHER_PARTS + 1).astype(np.int64)
        self.H = [None] * GATHER_PARTS

    def part(self, k: int) -> None:
        a, b = self.cut[k], self.cut[k + 1]
        H = np.zeros_like(self.S)
        if self.cl is None:
            _link_sums(self.S, self.p[a:b], self.q[a:b], self.g[a:b], H)
        else:
            _side_sums(self.S, self.p[a:b], self.q[a:b], self.g[a:b], self.cl.side[a:b], H)
        self.H[k] = H

    def push(self, G, Gback=None) -> int:
        """G (C, n) += the gathered light at the leaves' originals (front sides; their back
        sides into Gback with two-sided originals); returns the link terms."""
        H = self.H[0]
        for h in self.H[1:]:
            H += h
        if self.cl is None:
            _push_down(H, self.inv, self.parent, self.leaf_orig, G)
        else:
            c = self.cl
            _push_sides(H, self.inv, self.parent, self.leaf_orig, c.axis, c.normal, c.two, G,
                        Gback)
        return 2 * len(self.p)


@numba.njit(cache=True, nogil=True)
def _pull_means(Lroot, parent, leaf_orig, area):
    """(K, C) the nodes' area-weighted mean radiance from the originals' (Lroot (C, n)), and
    (K,) 1 / area (0 for no area). One row a node: a link reads and writes whole rows."""
    K = parent.shape[0]
    C = Lroot.shape[0]
    S = np.zeros((K, C))
    inv = np.zeros(K)
    for x in range(K):
        inv[x] = 1.0 / area[x] if area[x] > 0 else 0.0
        o = leaf_orig[x]
        if o >= 0:
            for c in range(C):
                S[x, c] = area[x] * Lroot[c, o]
    for x in range(K - 1, 0, -1):
        for c in range(C):
            S[parent[x], c] += S[x, c]
    for x in range(K):
        for c in range(C):
            S[x, c] *= inv[x]
    return S, inv


@numba.njit(cache=True, nogil=True)
def _link_sums(S, p, q, g, H):
    """H[a] += g Lbar_b and H[b] += g Lbar_a over the links (a, b) (power received, A_a E_a)."""
    C = S.shape[1]
    for k in range(p.shape[0]):
        a, b = p[k], q[k]
        w = np.float64(g[k])
        for c in range(C):
            H[a, c] += w * S[b, c]
            H[b, c] += w * S[a, c]


@numba.njit(cache=True, nogil=True)
def _push_down(H, inv, parent, leaf_orig, G):
    """G[:, o] += the irradiance each leaf's original receives: H / A at every node, summed
    down the tree (parents before children)."""
    K, C = H.shape
    for x in range(K):
        for c in range(C):
            H[x, c] *= inv[x]
    for x in range(1, K):
        for c in range(C):
            H[x, c] += H[parent[x], c]
    for x in range(K):
        o = leaf_orig[x]
        if o >= 0:
            for c in range(C):
                G[c, o] += H[x, c]


#: A receiver whose area-weighted normal sum is at least this fraction of its area (normals
#: within about 8 degrees) takes a link's light as one linear field over the node (its
#: centroid's point kernel and that kernel's gradient in the node's mean plane); others, per
#: original (cluster_final_gather). On the 200 000-triangle terrain and the tessellated Cornell
#: box 99.9 % and 99.6 % of link ends are such nodes.
FLAT = 0.99


@dataclass(frozen=True)
class FinalLayout:
    """What the cluster links' final gather reads of the tree, built once per gather
    (final_layout): cnt (K,) originals under each node, off (K,) where they start in the
    depth-first list, cen (K, 3) the nodes' area centroids, reach (K,) a bound on the distance
    from a node's centroid to its vertices, geo (n, 8) the originals in depth-first order
    (centroid, normal, area, reach), row_node (n,) the leaf node of each row, orig_node (n,) the
    leaf node of each original; unit (K, 3) the nodes' mean normals (their area-weighted normal
    sums normalised, 0 where the sum is 0) and flat (K,) bool: the nodes that take a link's
    light as one linear field (FLAT), each found once instead of once a link."""

    cnt: np.ndarray
    off: np.ndarray
    cen: np.ndarray
    reach: np.ndarray
    geo: np.ndarray
    row_node: np.ndarray
    orig_node: np.ndarray
    unit: np.ndarray
    flat: np.ndarray


def final_layout(parent, leaf_orig, area, ocenter, onormal, oarea, overts, onv) -> FinalLayout:
    """The FinalLayout of a cluster tree over originals with centroids, normals, areas and
    polygons (overts (n, 4, 3), onv (n,))."""
    cnt, off, lst, cen, nrm = _leaf_layout(parent, leaf_orig, area, ocenter, onormal, oarea)
    oreach = _reach(overts, onv, ocenter)
    geo = np.empty((len(lst), 8))
    geo[:, 0:3] = ocenter[lst]
    geo[:, 3:6] = onormal[lst]
    geo[:, 6] = oarea[lst]
    geo[:, 7] = oreach[lst]
    leaves = np.nonzero(leaf_orig >= 0)[0]
    row_node = np.empty(len(lst), np.int64)
    row_node[off[leaves]] = leaves
    orig_node = np.empty(len(oarea), np.int64)
    orig_node[leaf_orig[leaves]] = leaves
    unit, flat = _mean_normals(nrm, area, FLAT)
    return FinalLayout(cnt, off, cen, _node_reach(parent, leaf_orig, cen, oreach), geo,
                       row_node, orig_node, unit, flat)


def cluster_final_gather(Lroot, parent, leaf_orig, area, p, q, g, layout: FinalLayout,
                         part: tuple = (0, 1), sides=None):
    """The final gather of the cluster links (SPEC §9): each link's power g Lbar_q, which the
    solve spreads uniformly over p's originals, shared out by the point kernel from q's
    centroid, A max(0, n . d) max(0, -m_q . d) / r^4 (m_q: q's mean normal), with the kernel's
    gradient for the leaves below each original. A flat receiver (FLAT) takes it as one linear
    field (the uniform irradiance at its centroid, the kernel's relative gradient there), any
    other per original (normalised: the same power). Energy is conserved either way. Links
    part[0] of part[1] equal parts (the parts' sums add up to the whole). Returns fields (K,
    4C): at each leaf node, its original's irradiance at the centroid (C) and gradient in its
    plane (C x 3), push_to_leaves' input. With `sides` (Lback (C, n), cl: ClusterLinks holding
    two-sided originals): (2, K, 4C), the fronts' and the backs' (push_back_to_leaves), each
    end on the side the link uses (_final_sides)."""
    cut = np.linspace(0, len(p), part[1] + 1).astype(np.int64)
    a, b = cut[part[0]], cut[part[0] + 1]
    if sides is not None and sides[1].two_sided:
        cl = sides[1]
        S, _ = _pull_sides(Lroot, sides[0], parent, leaf_orig, area, cl.axis, cl.normal, cl.two)
        ntwo, rtwo = _two_layout(parent, leaf_orig, cl.two, layout.row_node)
        nodes = np.zeros((2, len(parent), 4 * S.shape[2]))
        _final_sides(S, area, p[a:b], q[a:b], g[a:b], cl.side[a:b], layout.cnt, layout.off,
                     layout.cen, layout.unit, layout.flat, layout.reach, layout.geo,
                     layout.row_node, cl.axis, ntwo, rtwo, nodes)
        del S
        return _fields_sides(nodes, parent, leaf_orig, layout.off, layout.cen, layout.geo,
                             cl.axis, cl.normal, cl.two)
    S, _ = _pull_means(Lroot, parent, leaf_orig, area)
    nodes = np.zeros((len(parent), 4 * S.shape[1]))
    _final_links(S, area, p[a:b], q[a:b], g[a:b], layout.cnt, layout.off, layout.cen,
                 layout.unit, layout.flat, layout.reach, layout.geo, layout.row_node, nodes)
    del S
    _push_fields(nodes, parent, leaf_orig, layout.off, layout.cen, layout.geo)
    return nodes


@numba.njit(cache=True, nogil=True)
def _mean_normals(nrm, area, flat):
    """(K, 3) the nodes' area-weighted normal sums normalised (0 where the sum is 0) and (K,)
    bool: the sum's length at least `flat` times the node's area."""
    K = nrm.shape[0]
    unit = np.zeros((K, 3))
    out = np.zeros(K, np.bool_)
    for x in range(K):
        m = np.sqrt(nrm[x, 0] ** 2 + nrm[x, 1] ** 2 + nrm[x, 2] ** 2)
        if m > 0.0:
            for c in range(3):
                unit[x, c] = nrm[x, c] / m
        out[x] = m >= flat * area[x]
    return unit, out


@numba.njit(cache=True, nogil=True)
def _node_reach(parent, leaf_orig, cen, oreach):
    """(K,) a bound on the distance from each node's centroid to its originals' vertices."""
    K = parent.shape[0]
    out = np.zeros(K)
    for x in range(K):
        if leaf_orig[x] >= 0:
            out[x] = oreach[leaf_orig[x]]
    for x in range(K - 1, 0, -1):
        pa = parent[x]
        d = np.sqrt((cen[x, 0] - cen[pa, 0]) ** 2 + (cen[x, 1] - cen[pa, 1]) ** 2
                    + (cen[x, 2] - cen[pa, 2]) ** 2)
        out[pa] = max(out[pa], d + out[x])
    return out


@numba.njit(cache=True, nogil=True)
def _reach(verts, nverts, center):
    """(n,) the largest distance from each polygon's centroid to its vertices."""
    out = np.zeros(verts.shape[0])
    for o in range(verts.shape[0]):
        for j in range(nverts[o]):
            out[o] = max(out[o], np.sqrt((verts[o, j, 0] - center[o, 0]) ** 2
                                         + (verts[o, j, 1] - center[o, 1]) ** 2
                                         + (verts[o, j, 2] - center[o, 2]) ** 2))
    return out


@numba.njit(cache=True, nogil=True)
def _leaf_layout(parent, leaf_orig, area, ocenter, onormal, oarea):
    """The cluster tree's originals in depth-first order: cnt (K,) originals under each node,
    off (K,) where they start in lst, lst (n,) the originals; cen (K, 3) the nodes' area
    centroids, nrm (K, 3) their area-weighted normal sums."""
    K = parent.shape[0]
    cnt = np.zeros(K, np.int64)
    cen = np.zeros((K, 3))
    nrm = np.zeros((K, 3))
    for x in range(K):
        o = leaf_orig[x]
        if o >= 0:
            cnt[x] = 1
            for c in range(3):
                cen[x, c] = oarea[o] * ocenter[o, c]
                nrm[x, c] = oarea[o] * onormal[o, c]
    for x in range(K - 1, 0, -1):
        cnt[parent[x]] += cnt[x]
        for c in range(3):
            cen[parent[x], c] += cen[x, c]
            nrm[parent[x], c] += nrm[x, c]
    for x in range(K):
        if area[x] > 0:
            for c in range(3):
                cen[x, c] /= area[x]
    off = np.zeros(K, np.int64)
    nxt = np.zeros(K, np.int64)
    for x in range(1, K):  # children follow their parents: each takes the next free range
        off[x] = nxt[parent[x]]
        nxt[parent[x]] += cnt[x]
        nxt[x] = off[x]
    lst = np.zeros(cnt[0] if K > 0 else 0, np.int64)
    for x in range(K):
        if leaf_orig[x] >= 0:
            lst[off[x]] = leaf_orig[x]
    return cnt, off, lst, cen, nrm


@numba.njit(cache=True, nogil=True)
def _final_links(S, area, p, q, g, cnt, off, cen, unit, flat, reach, geo, row_node, nodes):
    """Both directions of links (p, q), into nodes (K, 4C): a flat receiver's row (flat) += the
    irradiance at its centroid (C) and its gradient (C x 3); any other receiver's originals'
    leaf rows (row_node of geo's depth-first rows: centroid, normal, area, reach) += the same
    per original (cluster_final_gather). unit: the nodes' mean normals."""
    C = S.shape[1]
    w = np.zeros(geo.shape[0])
    for k in range(p.shape[0]):
        for h in range(2):
            t, s = (p[k], q[k]) if h == 0 else (q[k], p[k])
            mx, my, mz = unit[s, 0], unit[s, 1], unit[s, 2]
            sx, sy, sz = cen[s, 0], cen[s, 1], cen[s, 2]
            f = np.float64(g[k])
            if flat[t]:  # one linear field over the node
                nx, ny, nz = unit[t, 0], unit[t, 1], unit[t, 2]
                dx, dy, dz = sx - cen[t, 0], sy - cen[t, 1], sz - cen[t, 2]
                gx = gy = gz = 0.0
                if nx * dx + ny * dy + nz * dz > 0.0 and mx * dx + my * dy + mz * dz < 0.0:
                    gx, gy, gz = _kernel_gradient(dx, dy, dz, nx, ny, nz, mx, my, mz, reach[t])
                for c in range(C):
                    val = f * S[s, c] / area[t]
                    nodes[t, c] += val
                    nodes[t, C + 3 * c] += val * gx
                    nodes[t, C + 3 * c + 1] += val * gy
                    nodes[t, C + 3 * c + 2] += val * gz
                continue
            lo, n = off[t], cnt[t]
            tot = 0.0
            for i in range(lo, lo + n):
                dx, dy, dz = sx - geo[i, 0], sy - geo[i, 1], sz - geo[i, 2]
                r2 = dx * dx + dy * dy + dz * dz
                ca = geo[i, 3] * dx + geo[i, 4] * dy + geo[i, 5] * dz
                cb = -(mx * dx + my * dy + mz * dz)
                w[i - lo] = ca * cb / (r2 * r2) if ca > 0.0 and cb > 0.0 else 0.0
                tot += geo[i, 6] * w[i - lo]
            for i in range(lo, lo + n):
                fac = w[i - lo] / tot if tot > 0.0 else 1.0 / area[t]
                if fac <= 0.0:
                    continue
                gx = gy = gz = 0.0
                if tot > 0.0:
                    gx, gy, gz = _kernel_gradient(sx - geo[i, 0], sy - geo[i, 1], sz - geo[i, 2],
                                                  geo[i, 3], geo[i, 4], geo[i, 5], mx, my, mz,
                                                  geo[i, 7])
                x = row_node[i]
                for c in range(C):
                    val = f * fac * S[s, c]
                    nodes[x, c] += val
                    nodes[x, C + 3 * c] += val * gx
                    nodes[x, C + 3 * c + 1] += val * gy
                    nodes[x, C + 3 * c + 2] += val * gz


@numba.njit(cache=True, nogil=True)
def push_to_leaves(fields, orig_node, ocenter, leaf_orig, leaf_center, d, y):
    """y (2, C, M) front sides += at every leaf l of original o: its field's value plus its
    gradient . (c_l - c_o) (cluster_final_gather's fields at o's leaf node orig_node[o]),
    times d[l] (closed balancing; empty: none)."""
    use_d = d.shape[0] > 0
    C = fields.shape[1] // 4
    for l in range(leaf_orig.shape[0]):
        o = leaf_orig[l]
        x = orig_node[o]
        f = d[l] if use_d else 1.0
        ex = leaf_center[l, 0] - ocenter[o, 0]
        ey = leaf_center[l, 1] - ocenter[o, 1]
        ez = leaf_center[l, 2] - ocenter[o, 2]
        for c in range(C):
            y[0, c, l] += f * (fields[x, c] + fields[x, C + 3 * c] * ex
                               + fields[x, C + 3 * c + 1] * ey + fields[x, C + 3 * c + 2] * ez)

