"""The hierarchical operator (SPEC §8): gather over links plus push-pull, on the leaves.

With L on the M leaves of the union tree (hierarchy.NodeTable), one application is

    pull    Lbar_q = sum_{leaves l of q} A_l L_l / A_q            (area-weighted mean, bottom-up)
    gather  G_p    = sum_{links p <- q} F_pq v_pq Lbar_q          (both directions of every link)
    push    H_l    = sum_{ancestors a of l, l included} G_a       (top-down)

K = Push Gather Pull is linear, so every solver of solve.py applies to L = Le + rho K L. With
A_p F_pq = A_q F_qp (A: the sum of the leaf areas below a node), x . diag(A) K y =
sum_links A_p F_pq v (xbar_p ybar_q + xbar_q ybar_p) is symmetric: CG works.

Vectors are (2, C, M) float64 [side, channel, leaf], as in solve.py. Links are read from the
store task by task on the workers and kept in the worker's bounded cache (operator.CACHE); a
pass is one Dask task per group of link tasks, each pinned to a worker. `LocalLinkOperator` runs
the same task functions in the driver, which is faster up to hierarchy.driver-solve-links links
(no round trips, links read once).

Row normalisation (solve.normalise_rows) works through `configure(cap=..., cmode=...)`: with
passes.CAP_MIN a link is scaled by min(cap over the leaves of p, cap over the leaves of q) (the
pairs' min(cap_a, cap_b) at leaf links); with CAP_PRODUCT (closed-scene balancing) by d_a d_b,
i.e. K -> D K D.
"""

from __future__ import annotations

import threading
import time

import dask
import numba
import numpy as np

from radiosity.runtime.cluster import default_workers, scatterable
from radiosity.errors import RadiosityError, StoreError
from radiosity.core.exact import _point_ff, point_ff
from radiosity.runtime.monitor import progress_bar
from radiosity.methods.base import CAP_MIN, CAP_PRODUCT, GroupExecutor
from radiosity.runtime.cache import CACHE

LINK_CACHE_KEY = "links"
# The linear final gather's far links: a source farther than FG_FAR times both nodes' sizes,
# seen from the receiver's centroid at cosines above sqrt(FG_FAR_COS2) both ways, gets the point
# kernel's analytic gradient instead of five exact evaluations. MEASURED, Cornell box 128^2
# against exact evaluations everywhere (6.3 M, 0.85 s on 2 threads): FG_FAR 8: 0.6 s, sub-element
# radiance changed by 0.01 % on average, 0.45 % at most; 6: 2.6 M evaluations, 0.45 s, 0.025 % /
# 0.9 %; 4: 0.8 M, 0.23 s, 0.06 % / 2.1 % (tests/test_hierarchy.py holds 6 to 0.05 % / 1.5 %).
FG_FAR = 6.0
FG_FAR_COS2 = 0.01


# ----------------------------------------------------------------------------- kernels

@numba.njit(cache=True, nogil=True)
def pull(L, leaf_node, leaf_area, parent, node_area, d, S):
    """Area-weighted means of L (2, C, M) over every node's leaves into S (2, C, N), returned:
    leaves' A L summed up the tree (children follow their parents in the table), divided by the
    node's leaf area. d (M,): leaf scaling (closed-scene balancing), empty for none."""
    N = parent.shape[0]
    S[...] = 0.0
    use_d = d.shape[0] > 0
    for l in range(leaf_node.shape[0]):
        w = leaf_area[l] * (d[l] if use_d else 1.0)
        for s in range(L.shape[0]):
            for c in range(L.shape[1]):
                S[s, c, leaf_node[l]] = w * L[s, c, l]
    for i in range(N - 1, 0, -1):
        p = parent[i]
        if p >= 0:
            for s in range(L.shape[0]):
                for c in range(L.shape[1]):
                    S[s, c, p] += S[s, c, i]
    for i in range(N):
        inv = 1.0 / node_area[i] if node_area[i] > 0 else 0.0
        for s in range(L.shape[0]):
            for c in range(L.shape[1]):
                S[s, c, i] *= inv
    return S


@numba.njit(cache=True, nogil=True)
def gather(Lbar, p, q, wpq, wqp, sp, sq, G, ncap, mode):
    """G += the transfer over links (p, q): G[sp, :, p] += w_pq Lbar[sq, :, q] and the reverse.
    mode 1: each link scaled by min(ncap[p], ncap[q]). Returns the number of link terms."""
    for k in range(p.shape[0]):
        a, b = p[k], q[k]
        f = min(ncap[a], ncap[b]) if mode == 1 else 1.0
        x, y = sp[k], sq[k]
        for c in range(G.shape[1]):
            G[x, c, a] += f * wpq[k] * Lbar[y, c, b]
            G[y, c, b] += f * wqp[k] * Lbar[x, c, a]
    return 2 * p.shape[0]


@numba.njit(cache=True, nogil=True)
def push(G, parent, leaf_node, d, y):
    """y[:, :, l] += sum of G over the ancestors of leaf l (itself included), times d[l] (closed
    balancing; empty: none). Top-down: H_i = G_i + H_parent."""
    N = parent.shape[0]
    for i in range(N):
        pa = parent[i]
        if pa >= 0:
            for s in range(G.shape[0]):
                for c in range(G.shape[1]):
                    G[s, c, i] += G[s, c, pa]
    use_d = d.shape[0] > 0
    for l in range(leaf_node.shape[0]):
        f = d[l] if use_d else 1.0
        for s in range(G.shape[0]):
            for c in range(G.shape[1]):
                y[s, c, l] += f * G[s, c, leaf_node[l]]


@numba.njit(cache=True)
def gs_sweep(L, Le, rho, S, tp, ts, sn, ss, w, ptr, noff, parent, node_area, leaf_node,
             leaf_area, node_leaf, lo, hi, d, need):
    """One block Gauss-Seidel sweep over the originals in order, in place on L (2, C, M): for
    original e, gather into its nodes from the directed link ends ptr[e]:ptr[e + 1] (target
    node tp / side ts, source node sn / side ss, weight w) with the latest node sums S (A L
    summed up the tree, (2, C, N)), push down e's tree, L = Le + rho H on e's leaves, and
    refresh S on e's nodes. need (n,): originals that gather (empty: all)."""
    C = L.shape[1]
    n = noff.shape[0] - 1
    use_d = d.shape[0] > 0
    terms = 0
    for e in range(n):
        if need.shape[0] > 0 and not need[e]:
            continue
        n0, n1 = noff[e], noff[e + 1]
        if n1 <= n0:
            continue
        H = np.zeros((2, C, n1 - n0))
        for k in range(ptr[e], ptr[e + 1]):
            t, s = tp[k], sn[k]
            inv = 1.0 / node_area[s] if node_area[s] > 0 else 0.0
            for c in range(C):
                H[ts[k], c, t - n0] += w[k] * S[ss[k], c, s] * inv
        terms += ptr[e + 1] - ptr[e]
        for i in range(n0, n1):  # push: parents precede children
            pa = parent[i]
            if pa >= n0:
                for s_ in range(2):
                    for c in range(C):
                        H[s_, c, i - n0] += H[s_, c, pa - n0]
        for i in range(n0, n1):
            l = node_leaf[i]
            if l < 0:
                continue
            f = d[l] if use_d else 1.0
            for s_ in range(2):
                for c in range(C):
                    L[s_, c, l] = Le[s_, c, l] + rho[s_, c, l] * f * H[s_, c, i - n0]
        # refresh the node sums of e (bottom-up)
        for i in range(n1 - 1, n0 - 1, -1):
            l = node_leaf[i]
            if l >= 0:
                wl = leaf_area[l] * (d[l] if use_d else 1.0)
                for s_ in range(2):
                    for c in range(C):
                        S[s_, c, i] = wl * L[s_, c, l]
            else:
                for s_ in range(2):
                    for c in range(C):
                        S[s_, c, i] = 0.0
        for i in range(n1 - 1, n0, -1):
            pa = parent[i]
            if pa >= n0:
                for s_ in range(2):
                    for c in range(C):
                        S[s_, c, pa] += S[s_, c, i]
    return terms


@numba.njit(cache=True, nogil=True)
def final_gather(Lbar, tp, ts, sn, ss, w, v, ptr, origs, node_leaf, lo, hi, leaf_center, normal,
                 node_orig, verts, nverts, child, levels, ncap, mode, d, y):
    """y (2, C, M) += the irradiance of the leaves of originals `origs`, gathered over the
    directed link ends into them (ptr by target original), each re-evaluated at the leaves it
    reaches: the source is taken `levels` levels down its tree (its descendants c there), and
    leaf l gets v F_l sum_c F(l -> c) Lbar_c / sum_c F(l -> c), with F(l -> c) the exact form
    factor from a differential element at l's centroid to polygon c (exact.py) and F_l the
    link's own form factor for a link into the leaf itself, sum_c F(l -> c) for one into a
    larger node. This undoes the uniform push over coarse receivers and, over coarse sources,
    weighs their parts by how much each leaf sees of them. Returns the evaluations made."""
    from_d = d.shape[0] > 0
    C = Lbar.shape[1]
    n = np.empty(3)
    evals = 0
    src = np.empty(1 << max(levels, 0), np.int64)
    nxt = np.empty(1 << max(levels, 0), np.int64)
    acc = np.empty(C)
    for e in origs:
        for k in range(ptr[e], ptr[e + 1]):
            t, s = tp[k], sn[k]
            f0 = min(ncap[t], ncap[s]) if mode == 1 else 1.0
            leaf_t = node_leaf[t] >= 0
            # the source's descendants `levels` down (or its leaves, if sooner)
            ns = 1
            src[0] = s
            for _ in range(levels):
                m = 0
                for i in range(ns):
                    c0 = child[src[i], 0]
                    if c0 < 0:
                        nxt[m] = src[i]
                        m += 1
                    else:
                        nxt[m] = c0
                        nxt[m + 1] = child[src[i], 1]
                        m += 2
                for i in range(m):
                    src[i] = nxt[i]
                ns = m
            if leaf_t and ns == 1:  # nothing to re-evaluate: the link as in the solve
                l = node_leaf[t]
                g = f0 * w[k] * (d[l] if from_d else 1.0)
                for c in range(C):
                    y[ts[k], c, l] += g * Lbar[ss[k], c, s]
                continue
            gt = 1.0 if ts[k] == 0 else -1.0
            gs = 1.0 if ss[k] == 0 else -1.0
            ot, os_ = node_orig[t], node_orig[s]
            n[0], n[1], n[2] = gt * normal[ot, 0], gt * normal[ot, 1], gt * normal[ot, 2]
            mx, my, mz = gs * normal[os_, 0], gs * normal[os_, 1], gs * normal[os_, 2]
            S = verts[s]
            m0 = mx * S[0, 0] + my * S[0, 1] + mz * S[0, 2]
            l0, l1 = (node_leaf[t], node_leaf[t] + 1) if leaf_t else (lo[t], hi[t])
            for l in range(l0, l1):
                x = leaf_center[l]
                if mx * x[0] + my * x[1] + mz * x[2] <= m0:
                    continue
                tot = 0.0
                for c in range(C):
                    acc[c] = 0.0
                for i in range(ns):
                    f = _point_ff(x, n, verts[src[i]], nverts[src[i]])
                    evals += 1
                    tot += f
                    for c in range(C):
                        acc[c] += f * Lbar[ss[k], c, src[i]]
                if tot <= 0.0:
                    continue
                F = (w[k] / v[k] if v[k] > 0 else 0.0) if leaf_t else tot
                g = f0 * v[k] * F / tot * (d[l] if from_d else 1.0)
                for c in range(C):
                    y[ts[k], c, l] += g * acc[c]
    return evals


@numba.njit(cache=True, nogil=True)
def linear_gather(Lbar, p, q, wpq, wqp, sp, sq, sel, node_leaf, node_center, normal, node_orig,
                  verts, nverts, ncap, mode, S0, S1, node_area, far):
    """The final gather to first order, link by link: for both directions of links (p, q) into
    a node t of a selected original (sel[orig]), S0 (2, C, N) += the link's value f w Lbar and,
    for t above the leaves, the value times the gradient of the exact form factor F(x ->
    source) over t (least squares through t's centroid and vertices, in t's plane, relative to
    F at the centroid) into S1 (2, C, 3, N) (and its part at t's centroid out of S0). A leaf l
    then gets sum over its ancestors a of (S0_a + S1_a . c_l) (linear_push). Four or five exact
    point-to-polygon evaluations per link instead of one per link and leaf; none where the
    source lies farther than `far` times both nodes' sizes (sqrt area) in front of t and not
    grazing: there the point kernel's gradient, analytic (0: never). Returns the evaluations
    made."""
    C = Lbar.shape[1]
    evals = 0
    S = np.empty((4, 3))   # the source's polygon, and its clipped copy: scratch, no allocation
    Sc = np.empty((10, 3))  # per evaluation and no row views (shafts._faces)
    for k in range(p.shape[0]):
        for h in range(2):
            t, s = (p[k], q[k]) if h == 0 else (q[k], p[k])
            ot, os_ = node_orig[t], node_orig[s]
            if not sel[ot]:
                continue
            st, ss = (sp[k], sq[k]) if h == 0 else (sq[k], sp[k])
            w = wpq[k] if h == 0 else wqp[k]
            f0 = min(ncap[t], ncap[s]) if mode == 1 else 1.0
            for c in range(C):
                S0[st, c, t] += f0 * w * Lbar[ss, c, s]
            if node_leaf[t] >= 0:
                continue
            gt = 1.0 if st == 0 else -1.0
            gs = 1.0 if ss == 0 else -1.0
            nx, ny, nz = gt * normal[ot, 0], gt * normal[ot, 1], gt * normal[ot, 2]
            mx, my, mz = gs * normal[os_, 0], gs * normal[os_, 1], gs * normal[os_, 2]
            ct0, ct1, ct2 = node_center[t, 0], node_center[t, 1], node_center[t, 2]
            dx = node_center[s, 0] - ct0
            dy = node_center[s, 1] - ct1
            dz = node_center[s, 2] - ct2
            r2 = dx * dx + dy * dy + dz * dz
            ca = nx * dx + ny * dy + nz * dz
            cb = -(mx * dx + my * dy + mz * dz)
            if far > 0.0 and r2 > far * far * max(node_area[s], node_area[t]) \
                    and ca * ca > FG_FAR_COS2 * r2 and cb * cb > FG_FAR_COS2 * r2 \
                    and ca > 0.0 and cb > 0.0:
                # far: the point kernel's gradient, exactly (no evaluation): F ~ ca cb / r^4,
                # grad log F = -n / ca + m / cb + 4 d / r^2, in t's plane
                hx = -nx / ca + mx / cb + 4.0 * dx / r2
                hy = -ny / ca + my / cb + 4.0 * dy / r2
                hz = -nz / ca + mz / cb + 4.0 * dz / r2
                hn = hx * normal[ot, 0] + hy * normal[ot, 1] + hz * normal[ot, 2]
                gx, gy, gz = hx - hn * normal[ot, 0], hy - hn * normal[ot, 1], hz - hn * normal[ot, 2]
            else:
                ns_ = nverts[s]
                for i in range(ns_):
                    for c in range(3):
                        S[i, c] = verts[s, i, c]
                m0 = mx * S[0, 0] + my * S[0, 1] + mz * S[0, 2]
                F0 = point_ff(ct0, ct1, ct2, nx, ny, nz, S, ns_, Sc) \
                    if mx * ct0 + my * ct1 + mz * ct2 > m0 else 0.0
                evals += 1
                if F0 <= 0.0:
                    continue
                # in-plane basis of t and the least-squares gradient through the vertices
                ex = verts[t, 1, 0] - verts[t, 0, 0]
                ey = verts[t, 1, 1] - verts[t, 0, 1]
                ez = verts[t, 1, 2] - verts[t, 0, 2]
                le = np.sqrt(ex * ex + ey * ey + ez * ez)
                ex, ey, ez = ex / le, ey / le, ez / le
                fx = normal[ot, 1] * ez - normal[ot, 2] * ey
                fy = normal[ot, 2] * ex - normal[ot, 0] * ez
                fz = normal[ot, 0] * ey - normal[ot, 1] * ex
                a11 = a12 = a22 = b1 = b2 = 0.0
                for j in range(nverts[t]):
                    x0, x1, x2 = verts[t, j, 0], verts[t, j, 1], verts[t, j, 2]
                    Fv = point_ff(x0, x1, x2, nx, ny, nz, S, ns_, Sc) \
                        if mx * x0 + my * x1 + mz * x2 > m0 else 0.0
                    evals += 1
                    u = (x0 - ct0) * ex + (x1 - ct1) * ey + (x2 - ct2) * ez
                    v_ = (x0 - ct0) * fx + (x1 - ct1) * fy + (x2 - ct2) * fz
                    a11 += u * u
                    a12 += u * v_
                    a22 += v_ * v_
                    b1 += u * (Fv - F0)
                    b2 += v_ * (Fv - F0)
                det = a11 * a22 - a12 * a12
                if det <= 0.0:
                    continue
                gu = (a22 * b1 - a12 * b2) / det / F0  # relative gradient
                gv = (a11 * b2 - a12 * b1) / det / F0
                gx, gy, gz = gu * ex + gv * fx, gu * ey + gv * fy, gu * ez + gv * fz
            # limited so that 1 + g . (x - c_t) >= 0 at t's vertices, hence at every leaf of t
            # (t is convex): a link adds no negative light anywhere (where F0 is small against
            # the vertices' values the unlimited plane dives below zero: room-2400 had 2 % of
            # its sub-elements negative, down to -90)
            lowest = 0.0
            for j in range(nverts[t]):
                lowest = min(lowest, gx * (verts[t, j, 0] - ct0) + gy * (verts[t, j, 1] - ct1)
                             + gz * (verts[t, j, 2] - ct2))
            if lowest < -1.0:
                gx, gy, gz = -gx / lowest, -gy / lowest, -gz / lowest
            for c in range(C):
                val = f0 * w * Lbar[ss, c, s]
                S1[st, c, 0, t] += val * gx
                S1[st, c, 1, t] += val * gy
                S1[st, c, 2, t] += val * gz
                S0[st, c, t] -= val * (gx * ct0 + gy * ct1 + gz * ct2)
    return evals


@numba.njit(cache=True, nogil=True)
def linear_push(S0, S1, origs, noff, parent, node_leaf, leaf_center, d, y):
    """y (2, C, M) += for the leaves l of originals `origs`: the sum over l's ancestors a (l
    included) of S0_a + S1_a . c_l (linear_gather's sums, accumulated down the tree in place;
    parents precede children), times d[l] (closed balancing; empty: none)."""
    from_d = d.shape[0] > 0
    C = S0.shape[1]
    for e in origs:
        for i in range(noff[e], noff[e + 1]):
            pa = parent[i]
            if pa >= noff[e]:
                for s_ in range(2):
                    for c in range(C):
                        S0[s_, c, i] += S0[s_, c, pa]
                        for q in range(3):
                            S1[s_, c, q, i] += S1[s_, c, q, pa]
            l = node_leaf[i]
            if l >= 0:
                x = leaf_center[l]
                f = d[l] if from_d else 1.0
                for s_ in range(2):
                    for c in range(C):
                        y[s_, c, l] += f * (S0[s_, c, i] + S1[s_, c, 0, i] * x[0]
                                            + S1[s_, c, 1, i] * x[1] + S1[s_, c, 2, i] * x[2])


@numba.njit(cache=True)
def node_min(leaf_value, lo, hi):
    """Minimum of leaf_value over each node's leaves lo:hi, (N,)."""
    out = np.empty(lo.shape[0])
    for i in range(lo.shape[0]):
        m = np.inf
        for l in range(lo[i], hi[i]):
            m = min(m, leaf_value[l])
        out[i] = m
    return out


# ----------------------------------------------------------------------------- worker side

@scatterable
class LinkSolveInputs:
    """Read-only arrays the pass tasks need (scattered once per solve).

    Node table (N nodes): orig, parent (N,) int64, lo, hi (N,) leaf ranges, path (N,) uint64,
    depth (N,) int32, noff (n + 1,), node_area (N,) the sum of the leaf areas below, node_leaf
    (N,) leaf index or -1; leaves: leaf_node (M,), leaf_area (M,), leaf_orig (M,). Link tasks:
    entries (k, 3) int64 [crc, n, nx] of the manifest, store_path, token. Settings: cap (M,)
    (ones: none; see the module docstring), need (n,) bool originals that gather (empty: all),
    sided (M,) two-sided leaves (kept for the operator protocol: link sides are fixed by the
    refinement)."""

    def __init__(self, table: dict, entries: np.ndarray, store_path: str, token: str,
                 normal: np.ndarray, memory: list | None = None):
        self.orig = table["orig"].astype(np.int64)
        self.parent = table["parent"].astype(np.int64)
        self.lo = table["lo"].astype(np.int64)
        self.hi = table["hi"].astype(np.int64)
        self.path = table["path"]
        self.depth = table["depth"].astype(np.int64)
        self.noff = table["noff"].astype(np.int64)
        self.leaf_node = table["leaf_node"].astype(np.int64)
        self.leaf_area = table["leaf_area"]
        self.leaf_orig = self.orig[self.leaf_node]
        # node areas as sums of their leaves' (what pull divides by), summed bottom-up
        self.node_area = _node_sums(self.leaf_area, self.leaf_node, self.parent)
        self.normal = np.asarray(normal, np.float64)  # (n, 3) of the originals
        self.verts = table["verts"]
        self.nverts = table["nverts"].astype(np.int64)
        from radiosity.core.geometry import polygon_properties

        self.node_center = polygon_properties(self.verts, table["nverts"])[2]
        self.leaf_center = self.node_center[self.leaf_node]
        self.child = _children(self.parent)
        self.fg_levels = 0  # final gather: levels below a link's source (set by the stage)
        self.fg_mode = "exact"  # final gather: exact (per leaf) or linear
        self.node_leaf = np.full(len(self.orig), -1, np.int64)
        self.node_leaf[self.leaf_node] = np.arange(len(self.leaf_node))
        self.entries = entries
        self.memory = memory  # link arrays per task held in memory (in-process use), or None
        self.store_path = store_path
        self.token = token
        self.cap = np.ones(len(self.leaf_node))
        self.cmode = CAP_MIN
        self.cache_bytes = 1 << 31  # the worker cache's bound (radiosity.solve.cache-bytes)
        self.need = np.zeros(0, np.bool_)
        self.sided = np.zeros(len(self.leaf_node), np.bool_)
        self._ncap = None

    def cap_args(self):
        """(mode, node caps (N,), leaf scaling d (M,) or empty) of the current cap."""
        cap = self.cap
        if self.cmode == CAP_PRODUCT:  # closed balancing: K -> D K D
            return 2, np.ones(1), cap
        if np.all(cap == 1.0):
            return 0, np.ones(1), np.zeros(0)
        return 1, node_min(cap, self.lo, self.hi), np.zeros(0)


def _children(parent: np.ndarray) -> np.ndarray:
    """(N, 2) int64 children of each node from the parents (children follow in table order)."""
    child = np.full((len(parent), 2), -1, np.int64)
    idx = np.nonzero(parent >= 0)[0]
    par = parent[idx]
    first = np.ones(len(idx), bool)
    first[1:] = par[1:] != par[:-1]
    # in pre-order the second child of p comes after the first's subtree: sort by parent
    order = np.argsort(par, kind="stable")
    idx, par = idx[order], par[order]
    first = np.ones(len(idx), bool)
    first[1:] = par[1:] != par[:-1]
    child[par[first], 0] = idx[first]
    child[par[~first], 1] = idx[~first]
    return child


def _node_sums(leaf_value, leaf_node, parent):
    """Sum of leaf_value (M,) over each node's leaves, (N,)."""
    s = np.zeros(len(parent))
    s[leaf_node] = leaf_value
    return _sum_up(s, parent)


@numba.njit(cache=True)
def _sum_up(s, parent):
    for i in range(parent.shape[0] - 1, 0, -1):
        if parent[i] >= 0:
            s[parent[i]] += s[i]
    return s


def task_link_arrays(inp: LinkSolveInputs, task: int):
    """The links of one link task as node indices and weights, verified, from this worker's
    cache or the store: p, q (k,) int32; wpq = F_pq v, wqp = F_qp v (k,); sp, sq (k,) int8;
    v (k,) the visible fractions."""
    def load():
        from radiosity.scene.splittrees import find_codes
        from radiosity.methods.hierarchical.store import read_links

        e = inp.entries[task]
        if inp.memory is not None:
            links = inp.memory[task]
        else:
            links, _ = read_links(inp.store_path, task, {"crc": int(e[0]), "n": int(e[1]),
                                                         "nx": int(e[2])})
        p = find_codes(inp.orig, inp.path, inp.depth, inp.noff, links["po"].astype(np.int64),
                       links["pc"])
        q = find_codes(inp.orig, inp.path, inp.depth, inp.noff, links["qo"].astype(np.int64),
                       links["qc"])
        if np.any(p < 0) or np.any(q < 0):
            raise StoreError(f"link task {task} of {inp.store_path} names nodes that are not in "
                             "the node table: run the link stage again")
        v = links["v"].astype(np.float64)
        # node indices as int32 and sides as int8: 34 bytes a link as the passes hold them (56
        # with int64), 190 MB less in the driver's solve at 512^2
        return (p.astype(np.int32), q.astype(np.int32), links["fpq"] * v, links["fqp"] * v,
                np.ascontiguousarray(links["sp"]), np.ascontiguousarray(links["sq"]), v)

    return CACHE.get((inp.store_path, inp.token, LINK_CACHE_KEY, task), load,
                     lambda a: sum(x.nbytes for x in a), inp.cache_bytes)


_SCRATCH = threading.local()


def scratch(shape: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Two (2, C, N) node arrays per thread, kept across passes (a fresh array of tens of MiB
    costs more in page faults than the pass's arithmetic: measured 48 ms per array at 512^2,
    2.1 s of a 12 s solve)."""
    got = getattr(_SCRATCH, "arrays", None)
    if got is None or got[0].shape != shape:
        got = (np.empty(shape), np.empty(shape))
        _SCRATCH.arrays = got
    return got


def task_apply(inp: LinkSolveInputs, task_ids, L: np.ndarray, use_need: bool = True):
    """y = K L over the links of these link tasks (pull, gather, push), (2, C, M); rows of
    originals that do not gather (inp.need, with use_need) stay 0. Returns (y, link terms)."""
    cap = inp.cap_args()
    S, G = scratch((L.shape[0], L.shape[1], len(inp.parent)))
    G[...] = 0.0
    terms = _gather_tasks(inp, cap, task_ids, _pull(inp, cap, L, S), G)
    return _push(inp, cap, G, L, use_need), terms


def _pull(inp: LinkSolveInputs, cap, L, S):
    """Lbar (2, C, N): the node means of L into S (cap: inp.cap_args())."""
    return pull(L, inp.leaf_node, inp.leaf_area, inp.parent, inp.node_area, cap[2], S)


def _gather_tasks(inp: LinkSolveInputs, cap, task_ids, Lbar, G) -> int:
    """G += the gather over the links of these link tasks; returns the link terms."""
    mode, ncap, _ = cap
    terms = 0
    for t in task_ids:
        p, q, wpq, wqp, sp, sq, _ = task_link_arrays(inp, int(t))
        terms += gather(Lbar, p, q, wpq, wqp, sp, sq, G, ncap, mode)
    return terms


def _push(inp: LinkSolveInputs, cap, G, L, use_need: bool):
    """y (2, C, M) from the gathered G (push; G is consumed), rows that do not gather zeroed."""
    y = np.zeros_like(L)
    push(G, inp.parent, inp.leaf_node, cap[2], y)
    if use_need and len(inp.need):
        y[:, :, ~inp.need[inp.leaf_orig]] = 0.0
    return y


def _directed(inp: LinkSolveInputs):
    """Every link end as a directed entry grouped by the original of its target (for
    Gauss-Seidel and the final gather), from all link tasks, by a counting sort (no
    concatenated copies: each costs page faults); cached on the worker. Returns tp, ts, sn, ss,
    w, ptr, v: target node and side, source node and side, weight, (n + 1,) offsets per target
    original, visible fraction."""
    def load():
        n = len(inp.noff) - 1
        cnt = np.zeros(n + 1, np.int64)
        for t in range(len(inp.entries)):
            p, q = task_link_arrays(inp, t)[:2]
            _count_ends(p, q, inp.orig, cnt)
        ptr = np.zeros(n + 1, np.int64)
        np.cumsum(cnt[:n], out=ptr[1:])
        total = int(ptr[-1])
        tp, sn = np.empty(total, np.int64), np.empty(total, np.int64)
        ts, ss = np.empty(total, np.int64), np.empty(total, np.int64)
        w, v = np.empty(total), np.empty(total)
        cur = ptr[:-1].copy()
        for t in range(len(inp.entries)):
            _fill_ends(*task_link_arrays(inp, t), inp.orig, cur, tp, ts, sn, ss, w, v)
        return tp, ts, sn, ss, w, ptr, v

    return CACHE.get((inp.store_path, inp.token, LINK_CACHE_KEY, "directed"), load,
                     lambda a: sum(x.nbytes for x in a), inp.cache_bytes)


@numba.njit(cache=True)
def _count_ends(p, q, orig, cnt):
    for k in range(p.shape[0]):
        cnt[orig[p[k]]] += 1
        cnt[orig[q[k]]] += 1


@numba.njit(cache=True)
def _fill_ends(p, q, wpq, wqp, sp, sq, v, orig, cur, tp, ts, sn, ss, w, vv):
    """Both ends of links (p, q) into their target originals' slots (cur: next free slot)."""
    for k in range(p.shape[0]):
        a, b = p[k], q[k]
        i = cur[orig[a]]
        cur[orig[a]] = i + 1
        tp[i], sn[i], ts[i], ss[i], w[i], vv[i] = a, b, sp[k], sq[k], wpq[k], v[k]
        j = cur[orig[b]]
        cur[orig[b]] = j + 1
        tp[j], sn[j], ts[j], ss[j], w[j], vv[j] = b, a, sq[k], sp[k], wqp[k], v[k]


def task_final_gather(inp: LinkSolveInputs, origs: np.ndarray, L: np.ndarray):
    """The final gather into the leaves of originals `origs`, from the solved L (2, C, M):
    (y (2, C, M) nonzero on those leaves only, evaluations). linear (linear_gather): link by
    link from the link tasks as the passes hold them; exact (final_gather): over the link ends
    grouped by target original (_directed)."""
    mode, ncap, d = inp.cap_args()
    origs = np.asarray(origs, np.int64)
    S, G = scratch((L.shape[0], L.shape[1], len(inp.parent)))
    Lbar = pull(L, inp.leaf_node, inp.leaf_area, inp.parent, inp.node_area, d, S)
    y = np.zeros_like(L)
    if inp.fg_mode == "linear":
        sel = np.zeros(len(inp.noff) - 1, np.bool_)
        sel[origs] = True
        G[...] = 0.0
        S1 = np.zeros((L.shape[0], L.shape[1], 3, len(inp.parent)))
        evals = 0
        for t in range(len(inp.entries)):
            p, q, wpq, wqp, sp, sq, _ = task_link_arrays(inp, t)
            evals += linear_gather(Lbar, p, q, wpq, wqp, sp, sq, sel, inp.node_leaf,
                                   inp.node_center, inp.normal, inp.orig, inp.verts, inp.nverts,
                                   ncap, mode, G, S1, inp.node_area, FG_FAR)
        linear_push(G, S1, origs, inp.noff, inp.parent, inp.node_leaf, inp.leaf_center, d, y)
    else:
        tp, ts, sn, ss, w, ptr, v = _directed(inp)
        evals = final_gather(Lbar, tp, ts, sn, ss, w, v, ptr, origs, inp.node_leaf, inp.lo,
                             inp.hi, inp.leaf_center, inp.normal, inp.orig, inp.verts,
                             inp.nverts, inp.child, inp.fg_levels, ncap, mode, d, y)
    if len(inp.need):
        y[:, :, ~inp.need[inp.leaf_orig]] = 0.0
    return y, evals


def task_gs_sweep(inp: LinkSolveInputs, L, Le, rho):
    """One block Gauss-Seidel sweep (all links on this worker). Returns (L, link terms)."""
    tp, ts, sn, ss, w, ptr, _ = _directed(inp)
    mode, ncap, d = inp.cap_args()
    if mode == 1:
        w = w * np.minimum(ncap[tp], ncap[sn])
    L = L.copy()
    S = pull(L, inp.leaf_node, inp.leaf_area, inp.parent, inp.node_area, d,
             np.empty((L.shape[0], L.shape[1], len(inp.parent))))
    S *= inp.node_area  # pull returns means; the sweep keeps sums
    terms = gs_sweep(L, Le, rho, S, tp, ts, sn, ss, w, ptr, inp.noff, inp.parent, inp.node_area,
                     inp.leaf_node, inp.leaf_area, inp.node_leaf, inp.lo, inp.hi, d, inp.need)
    return L, terms


# ----------------------------------------------------------------------------- operators

class _Base:
    """What the two operators share: the kernel name (solvers check reciprocity by it), the
    pass and term counters, row_sums and the groups of link tasks."""

    def __init__(self, inp: LinkSolveInputs, kernel: str, ngroups: int):
        self.inp = inp
        self.kernel = kernel
        self.terms = 0
        self.passes = 0
        self.sparse = None  # the pairs' near-field corrections: none here (links carry them)
        n = np.asarray(inp.entries[:, 1], np.int64) if len(inp.entries) else np.zeros(0, np.int64)
        order = np.argsort(-n, kind="stable")
        load = np.zeros(max(1, ngroups))
        members = [[] for _ in range(len(load))]
        for t in order:  # the largest first onto the least loaded group
            g = int(np.argmin(load))
            members[g].append(int(t))
            load[g] += n[t] + 1
        self.groups = [np.array(sorted(m), np.int64) for m in members if m]

    def orig_groups(self, k: int) -> list:
        """The originals cut into k groups of about equal leaf counts (final gather)."""
        n = len(self.inp.noff) - 1
        leaves = np.bincount(self.inp.leaf_orig, minlength=n)
        order = np.argsort(-leaves, kind="stable")
        load = np.zeros(max(1, k))
        members = [[] for _ in range(len(load))]
        for o in order:
            g = int(np.argmin(load))
            members[g].append(int(o))
            load[g] += leaves[o] + 1
        return [np.array(sorted(m), np.int64) for m in members if m]

    def row_sums(self) -> np.ndarray:
        """sum over the links of F v for every leaf and side, pushed down, (2, M) (one pass)."""
        M = len(self.inp.leaf_area)
        return self.apply(np.ones((2, 1, M)), use_need=False)[:, 0, :]


class LocalLinkOperator(_Base):
    """K in this process (the same task functions, no cluster): the driver's solve up to
    hierarchy.driver-solve-links links, and tests. The link tasks are cut into one group per
    core this process may use (cgroups, Slurm); each pass pulls once, gathers the groups in
    threads of dask's local scheduler into a buffer each (the kernels release the GIL; the
    workers sit idle meanwhile; the first pass reads each group's links in its thread), sums
    them and pushes once."""

    def __init__(self, inp: LinkSolveInputs, kernel: str, groups: int | None = None):
        super().__init__(inp, kernel, groups or default_workers())
        self._buffers: dict = {}  # (2, C, N) shape -> one gather buffer per group

    def _threads(self, fn, items) -> list:
        """[fn(x) for x in items], one thread each (inline for one)."""
        if len(items) <= 1:
            return [fn(x) for x in items]
        return list(dask.compute(*[dask.delayed(fn)(x) for x in items], scheduler="threads",
                                 num_workers=len(items)))

    def apply(self, L, live=None, use_need: bool = True):
        inp = self.inp
        cap = inp.cap_args()
        shape = (L.shape[0], L.shape[1], len(inp.parent))
        bufs = self._buffers.setdefault(shape, [np.empty(shape) for _ in self.groups])
        Lbar = _pull(inp, cap, L, scratch(shape)[0])

        def part(k):
            bufs[k][...] = 0.0
            return _gather_tasks(inp, cap, self.groups[k], Lbar, bufs[k])

        self.terms += sum(self._threads(part, list(range(len(self.groups)))))
        G = bufs[0] if bufs else np.zeros(shape)
        for extra in bufs[1:]:
            G += extra
        self.passes += 1
        return _push(inp, cap, G, L, use_need)

    def configure(self, **arrays) -> None:
        for k, v in arrays.items():
            setattr(self.inp, k, v)

    def final_gather(self, L):
        """The final gather of the solved L (task_final_gather), (2, C, M): groups of originals
        on this machine's cores, as threads of dask's local scheduler (the kernels release the
        GIL; the workers sit idle meanwhile)."""
        if self.inp.fg_mode != "linear":
            _directed(self.inp)  # built once, before the threads share it
        # every group's links read (in its thread) before the threads share them
        self._threads(lambda g: [task_link_arrays(self.inp, int(t)) for t in g], self.groups)
        parts = self._threads(lambda g: task_final_gather(self.inp, g, L),
                              self.orig_groups(default_workers()))
        self.evals = sum(e for _, e in parts)
        return sum(y for y, _ in parts)

    def gs_sweep(self, L, Le, rho):
        new, t = task_gs_sweep(self.inp, L, Le, rho)
        self.terms += t
        self.passes += 1
        return new


class LinkOperator(_Base):
    """K by Dask tasks over groups of link tasks, run by the methods' GroupExecutor (each group
    pinned to one worker, so its link cache stays warm across passes; a failed group is
    resubmitted anywhere; data lost with a worker is sent again)."""

    def __init__(self, client, inp: LinkSolveInputs, kernel: str, groups: int | None = None,
                 retries: int = 3):
        ngroups = groups or max(1, 2 * (sum(client.nthreads().values()) or 1))
        super().__init__(inp, kernel, ngroups)
        self.client = client
        self.executor = GroupExecutor(client, inp, len(self.groups), retries)

    def apply(self, L, live=None, use_need: bool = True):
        y = np.zeros_like(L)
        for yp, t in self.executor.run(task_apply, lambda i, Lf: (self.groups[i], Lf, use_need),
                                       (L,), name="solve group"):
            y += yp
            self.terms += t
        self.passes += 1
        return y

    def configure(self, **arrays) -> None:
        for k, v in arrays.items():
            setattr(self.inp, k, v)
        self.executor.replace_inputs(self.inp)

    def final_gather(self, L):
        """The final gather of the solved L, one task per group of originals."""
        groups = self.orig_groups(len(self.groups))
        y = np.zeros_like(L)
        self.evals = 0
        for yp, e in self.executor.run(task_final_gather, lambda i, Lf: (groups[i], Lf), (L,),
                                       name="final gather", count=len(groups)):
            y += yp
            self.evals += e
        return y

    def gs_sweep(self, L, Le, rho):
        [(new, t)] = self.executor.run(task_gs_sweep, lambda i, Lf, Lef, rhof: (Lf, Lef, rhof),
                                       (L, Le, rho), name="Gauss-Seidel sweep", count=1)
        self.terms += t
        self.passes += 1
        return new


# ----------------------------------------------------------------------------- the stage

def solve_inputs(rs, elements, cache_bytes: int) -> tuple:
    """(LinkSolveInputs, node table dict, kernel) of a run whose link stage finished; the
    workers' link caches hold at most `cache_bytes` each."""
    from radiosity.methods.hierarchical.store import LinkStore

    ls = LinkStore(rs)
    token, (pairs, first), done = ls.require()
    ntasks = len(first) - 1
    missing = [t for t in range(ntasks) if t not in done]
    if missing:
        raise RadiosityError(f"the links of {rs.run_dir} are incomplete ({len(missing)} of "
                             f"{ntasks} tasks missing): run radiosity visibility {rs.run_dir} "
                             "--method hierarchical --resume")
    if not rs.has("hierarchy") or rs.group_attrs("hierarchy").get("token") != token:
        raise StoreError(f"{rs.run_dir} has links but no node table for them: run radiosity "
                         f"visibility {rs.run_dir} --method hierarchical --resume")
    table = ls.read_nodes()
    entries = np.array([[done[t]["crc"], done[t]["n"], done[t]["nx"]] for t in range(ntasks)],
                       np.int64).reshape(-1, 3)
    inp = LinkSolveInputs(table, entries, rs.path, token, elements.normal)
    inp.cache_bytes = int(cache_bytes)
    return inp, table, ls.attrs().get("kernel")


def memory_inputs(table: dict, tasks: list, normal: np.ndarray) -> LinkSolveInputs:
    """LinkSolveInputs over link arrays held in memory (one (k,) LINK_DTYPE array per task),
    for in-process use without a store."""
    entries = np.array([[0, len(t), 0] for t in tasks], np.int64).reshape(-1, 3)
    import uuid

    return LinkSolveInputs(table, entries, "memory", f"memory-{uuid.uuid4().hex}", normal,
                           memory=list(tasks))


def leaf_vectors(table: dict, elements):
    """Le, rho (2, 3, M) and area (M,) of the leaves, per side."""
    o = table["orig"][table["leaf_node"]]
    Le = np.ascontiguousarray(np.transpose(elements.emission[o], (1, 2, 0)))
    rho = np.ascontiguousarray(np.transpose(elements.reflectance[o], (1, 2, 0)))
    return Le, rho, table["leaf_area"]


def to_sub_elements(L: np.ndarray, table: dict, m: int) -> np.ndarray:
    """Leaf radiance (2, C, M) -> sub-element radiance (m, 2, C): identical for seen originals,
    the area-weighted mean of the split-off leaves for an unseen original's one sub-element."""
    sub = table["leaf_sub"]
    A = table["leaf_area"]
    out = np.zeros((m, L.shape[0], L.shape[1]))
    wsum = np.bincount(sub, A, minlength=m)
    for s in range(L.shape[0]):
        for c in range(L.shape[1]):
            out[:, s, c] = np.bincount(sub, A * L[s, c], minlength=m) / np.where(wsum > 0, wsum, 1)
    return out


def open_link_operator(rs, client=None, where: str = "auto", settings=None):
    """The operator of a run's links: in this process (client None, or where "driver", or
    "auto" with at most hierarchy.driver-solve-links links: no round trips per pass) or a
    LinkOperator over `client` (where "cluster", or "auto" above that). settings: a
    settings.Settings (None: resolved here). Returns (op, table, elements, partition)."""
    from radiosity.settings import resolve

    s = settings if settings is not None else resolve()
    el = rs.load_elements()
    inp, table, kernel = solve_inputs(rs, el, s.solve.cache_bytes)
    links = int(inp.entries[:, 1].sum()) if len(inp.entries) else 0
    if where not in ("auto", "driver", "cluster"):
        raise ValueError(f"where must be auto, driver or cluster, got {where!r}")
    if where == "auto":
        where = "driver" if links <= int(s.hierarchy.driver_solve_links) else "cluster"
    if client is None or where == "driver":
        op = LocalLinkOperator(inp, kernel)
    else:
        op = LinkOperator(client, inp, kernel, retries=int(s.visibility.retries))
    return op, table, el, rs.load_partition()
