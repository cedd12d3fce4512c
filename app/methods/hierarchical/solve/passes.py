"""The numba passes of the hierarchical operator (transport.py) on the M leaves of the union tree:

    pull    Lbar_q = sum_{leaves l of q} A_l L_l / A_q            (area-weighted mean, bottom-up)
    gather  G_p    = sum_{links p <- q} F_pq v_pq Lbar_q          (both directions of every link)
    push    H_l    = sum_{ancestors a of l, l included} G_a       (top-down)

plus a block Gauss-Seidel sweep and the final gathers (exact per leaf, or linear per link). The
arrays travel in named tuples: LinkArrays (one link task's links), Ends (link ends grouped by
target original), Nodes (the tree) and Geometry (areas, polygons, centroids, normals)."""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from radiosity.core.exact import point_to_polygon_ff, point_ff

# The linear final gather's far links are those seen from the receiver's centroid at cosines
# above sqrt(FG_FAR_COS2) both ways (and farther than transport.FG_FAR times both sizes).
FG_FAR_COS2 = 0.01

# One link task's links as the passes hold them: node indices p, q (k,) int32, weights
# wpq = F_pq v, wqp = F_qp v (k,), sides sp, sq (k,) int8 and the visible fractions v (k,).
LinkArrays = namedtuple("LinkArrays", "p q wpq wqp sp sq v")
# Every link end grouped by the original of its target: target node tp and side ts, source
# node sn and side ss, weight w, visible fraction v, and ptr (n + 1,) offsets per original.
Ends = namedtuple("Ends", "tp ts sn ss w ptr v")
# The union tree (N nodes, M leaves, n originals): parent (N,), child (N, 2), noff (n + 1,)
# nodes per original, lo / hi (N,) leaf ranges, orig (N,), node_leaf (N,) leaf or -1,
# leaf_node (M,).
Nodes = namedtuple("Nodes", "parent child noff lo hi orig node_leaf leaf_node")
# node_area (N,) (sums of leaf areas), leaf_area (M,), verts (N, 4, 3), nverts (N,),
# node_center (N, 3), leaf_center (M, 3), normal (n, 3) of the originals.
Geometry = namedtuple("Geometry", "node_area leaf_area verts nverts node_center leaf_center normal")


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


@numba.njit(cache=True, nogil=True)
def gs_sweep(L, Le, rho, S, ends, nodes, geo, d, need):
    """One block Gauss-Seidel sweep over the originals in order, in place on L (2, C, M): for
    original e, gather into its nodes from the directed link ends ptr[e]:ptr[e + 1] (target
    node tp / side ts, source node sn / side ss, weight w) with the latest node sums S (A L
    summed up the tree, (2, C, N)), push down e's tree, L = Le + rho H on e's leaves, and
    refresh S on e's nodes. need (n,): originals that gather (empty: all)."""
    tp, ts, sn, ss, w, ptr = ends.tp, ends.ts, ends.sn, ends.ss, ends.w, ends.ptr
    noff, parent, node_leaf = nodes.noff, nodes.parent, nodes.node_leaf
    node_area, leaf_area = geo.node_area, geo.leaf_area
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
def final_gather(Lbar, ends, origs, nodes, geo, levels, ncap, mode, d, y):
    """y (2, C, M) += the irradiance of the leaves of originals `origs`, gathered over the
    directed link ends into them (ptr by target original), each re-evaluated at the leaves it
    reaches: the source is taken `levels` levels down its tree (its descendants c there), and
    leaf l gets v F_l sum_c F(l -> c) Lbar_c / sum_c F(l -> c), with F(l -> c) the exact form
    factor from a differential element at l's centroid to polygon c (exact.py) and F_l the
    link's own form factor for a link into the leaf itself, sum_c F(l -> c) for one into a
    larger node. This undoes the uniform push over coarse receivers and, over coarse sources,
    weighs their parts by how much each leaf sees of them. Returns the evaluations made."""
    tp, ts, sn, ss, w, v, ptr = ends.tp, ends.ts, ends.sn, ends.ss, ends.w, ends.v, ends.ptr
    node_leaf, lo, hi = nodes.node_leaf, nodes.lo, nodes.hi
    node_orig, child = nodes.orig, nodes.child
    leaf_center, normal, verts, nverts = geo.leaf_center, geo.normal, geo.verts, geo.nverts
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
                    f = point_to_polygon_ff(x, n, verts[src[i]], nverts[src[i]])
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


@numba.njit(cache=True, nogil=True, inline="always")
def kernel_gradient(dx, dy, dz, nx, ny, nz, mx, my, mz):
    """grad log K of the point kernel K = (n . d)(-m . d) / r^4 with respect to the receiving
    point x (d = source - x, r = |d|; n, m unit normals of receiver and source, both cosines
    positive): -n / ca + m / cb + 4 d / r^2, taken into the plane of n."""
    r2 = dx * dx + dy * dy + dz * dz
    ca = nx * dx + ny * dy + nz * dz
    cb = -(mx * dx + my * dy + mz * dz)
    hx = -nx / ca + mx / cb + 4.0 * dx / r2
    hy = -ny / ca + my / cb + 4.0 * dy / r2
    hz = -nz / ca + mz / cb + 4.0 * dz / r2
    hn = hx * nx + hy * ny + hz * nz
    return hx - hn * nx, hy - hn * ny, hz - hn * nz


@numba.njit(cache=True, nogil=True)
def linear_gather(Lbar, links, sel, nodes, geo, ncap, mode, S0, S1, far):
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
    p, q, wpq, wqp, sp, sq = links.p, links.q, links.wpq, links.wqp, links.sp, links.sq
    node_leaf, node_orig = nodes.node_leaf, nodes.orig
    node_center, normal, verts, nverts = geo.node_center, geo.normal, geo.verts, geo.nverts
    node_area = geo.node_area
    C = Lbar.shape[1]
    evals = 0
    S = np.empty((4, 3))   # the source's polygon, and its clipped copy: scratch, no allocation
    Sc = np.empty((10, 3))  # per evaluation and no row views (shafts.faces_along)
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
                # far: the point kernel's gradient, exactly (no evaluation)
                gx, gy, gz = kernel_gradient(dx, dy, dz, nx, ny, nz, mx, my, mz)
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
            # the vertices' values the unlimited plane dives below zero: docs/src/measurements/hierarchical.md)
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


@numba.njit(cache=True, nogil=True)
def node_min(leaf_value, lo, hi):
    """Minimum of leaf_value over each node's leaves lo:hi, (N,)."""
    out = np.empty(lo.shape[0])
    for i in range(lo.shape[0]):
        m = np.inf
        for l in range(lo[i], hi[i]):
            m = min(m, leaf_value[l])
        out[i] = m
    return out



@numba.njit(cache=True, nogil=True)
def sum_up(s, parent):
    for i in range(parent.shape[0] - 1, 0, -1):
        if parent[i] >= 0:
            s[parent[i]] += s[i]
    return s



@numba.njit(cache=True, nogil=True)
def count_ends(p, q, orig, cnt):
    for k in range(p.shape[0]):
        cnt[orig[p[k]]] += 1
        cnt[orig[q[k]]] += 1


@numba.njit(cache=True, nogil=True)
def fill_ends(p, q, wpq, wqp, sp, sq, v, orig, cur, tp, ts, sn, ss, w, vv):
    """Both ends of links (p, q) into their target originals' slots (cur: next free slot)."""
    for k in range(p.shape[0]):
        a, b = p[k], q[k]
        i = cur[orig[a]]
        cur[orig[a]] = i + 1
        tp[i], sn[i], ts[i], ss[i], w[i], vv[i] = a, b, sp[k], sq[k], wpq[k], v[k]
        j = cur[orig[b]]
        cur[orig[b]] = j + 1
        tp[j], sn[j], ts[j], ss[j], w[j], vv[j] = b, a, sq[k], sp[k], wqp[k], v[k]

