"""The cluster layer's two sides (design: docs/src/design/methods-hierarchical-clusters.md,
"Two-sided clusters"): where originals are two-sided, a node x sends and receives on two sides,
+ and - of its cone axis a_x. A link uses at each end the side that faces the other end's
centroid (link_sides); an original i below x shows on x's + side its own side that faces a_x
(the front where n_i . a_x >= 0, else the back) and on x's - side the other; a one-sided
original its front on both. The pull (_pull_sides) and the push (_push_sides) use the same
rule, so the transfer stays symmetric (A K symmetric) and conserves energy. Also the final
gather's linear fields pushed down the tree (_push_fields), which clusters/transport.py shares."""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

from radiosity.methods.hierarchical.solve.passes import kernel_gradient


def with_sides(cl, axis: np.ndarray, center: np.ndarray, normal: np.ndarray,
               two_sided: np.ndarray):
    """cl (transport.ClusterLinks) with the arrays of two-sided originals (axis, center (K, 3) the nodes' cone axes and
    area centroids, normal (n, 3), two_sided (n,) bool), or cl itself where none is."""
    two = np.asarray(two_sided, np.bool_)
    if not two.any():
        return cl
    side = link_sides(np.ascontiguousarray(axis, np.float64),
                      np.ascontiguousarray(center, np.float64), cl.p, cl.q)
    return dataclasses.replace(cl, axis=np.ascontiguousarray(axis, np.float64),
                               normal=np.ascontiguousarray(normal, np.float64), two=two,
                               side=side)


@numba.njit(cache=True, nogil=True)
def link_sides(axis, center, p, q):
    """(k,) int8 the sides of links (p, q): bit 0 set where p's end is its - side (a_p . u < 0,
    u from p's centroid to q's), bit 1 where q's is (a_q . -u < 0)."""
    out = np.zeros(p.shape[0], np.int8)
    for k in range(p.shape[0]):
        a, b = p[k], q[k]
        dp = 0.0
        dq = 0.0
        for c in range(3):
            u = center[b, c] - center[a, c]
            dp += axis[a, c] * u
            dq -= axis[b, c] * u
        out[k] = (1 if dp < 0.0 else 0) | (2 if dq < 0.0 else 0)
    return out


@numba.njit(cache=True, nogil=True)
def _pull_sides(Lfront, Lback, parent, leaf_orig, area, axis, normal, two):
    """(2, K, C) each node's mean radiance on its + and - sides (the module's note) from the
    originals' front and back (Lfront, Lback (C, n)), and (K,) 1 / area: one-sided originals
    summed up the tree (the front, on both sides), each two-sided one added to every ancestor
    on the sides its normal takes there (depth of the tree per two-sided original)."""
    K = parent.shape[0]
    C = Lfront.shape[0]
    S = np.zeros((2, K, C))
    inv = np.zeros(K)
    for x in range(K):
        inv[x] = 1.0 / area[x] if area[x] > 0 else 0.0
        o = leaf_orig[x]
        if o >= 0 and not two[o]:
            for c in range(C):
                S[0, x, c] = area[x] * Lfront[c, o]
                S[1, x, c] = S[0, x, c]
    for x in range(K - 1, 0, -1):
        for h in range(2):
            for c in range(C):
                S[h, parent[x], c] += S[h, x, c]
    for x in range(K):
        o = leaf_orig[x]
        if o < 0 or not two[o]:
            continue
        y = x
        while y >= 0:
            up = normal[o, 0] * axis[y, 0] + normal[o, 1] * axis[y, 1] \
                + normal[o, 2] * axis[y, 2] >= 0.0
            for c in range(C):
                f, b = area[x] * Lfront[c, o], area[x] * Lback[c, o]
                S[0, y, c] += f if up else b
                S[1, y, c] += b if up else f
            y = parent[y]
    for h in range(2):
        for x in range(K):
            for c in range(C):
                S[h, x, c] *= inv[x]
    return S, inv


@numba.njit(cache=True, nogil=True)
def _side_sums(S, p, q, g, side, H):
    """H[sa, a] += g S[sb, b] and H[sb, b] += g S[sa, a] over the links (a, b) with sides sa, sb
    (link_sides' bits): the power each node's side receives."""
    C = S.shape[2]
    for k in range(p.shape[0]):
        a, b = p[k], q[k]
        sa, sb = side[k] & 1, (side[k] >> 1) & 1
        w = np.float64(g[k])
        for c in range(C):
            H[sa, a, c] += w * S[sb, b, c]
            H[sb, b, c] += w * S[sa, a, c]


@numba.njit(cache=True, nogil=True)
def _push_sides(H, inv, parent, leaf_orig, axis, normal, two, G, Gback):
    """G, Gback (C, n) += the irradiance each leaf's original receives on its front and back
    from the nodes' sides H (2, K, C) (power; consumed): H / A at every node; a one-sided
    original takes both sides of every ancestor on its front (summed down the tree), a
    two-sided one each ancestor's side on its own side that faces it (_pull_sides' mirror)."""
    K, C = H.shape[1], H.shape[2]
    T = np.zeros((K, C))
    for x in range(K):
        for c in range(C):
            H[0, x, c] *= inv[x]
            H[1, x, c] *= inv[x]
            T[x, c] = H[0, x, c] + H[1, x, c]
    for x in range(1, K):
        for c in range(C):
            T[x, c] += T[parent[x], c]
    for x in range(K):
        o = leaf_orig[x]
        if o < 0:
            continue
        if not two[o]:
            for c in range(C):
                G[c, o] += T[x, c]
            continue
        y = x
        while y >= 0:
            up = normal[o, 0] * axis[y, 0] + normal[o, 1] * axis[y, 1] \
                + normal[o, 2] * axis[y, 2] >= 0.0
            for c in range(C):
                G[c, o] += H[0, y, c] if up else H[1, y, c]
                Gback[c, o] += H[1, y, c] if up else H[0, y, c]
            y = parent[y]


@numba.njit(cache=True, nogil=True, inline="always")
def _kernel_gradient(dx, dy, dz, nx, ny, nz, mx, my, mz, reach):
    """passes.kernel_gradient limited so that 1 + g . (y - x) >= 0 within `reach` of x (no
    negative light)."""
    gx, gy, gz = kernel_gradient(dx, dy, dz, nx, ny, nz, mx, my, mz)
    lim = np.sqrt(gx * gx + gy * gy + gz * gz) * reach
    if lim > 1.0:
        gx, gy, gz = gx / lim, gy / lim, gz / lim
    return gx, gy, gz


@numba.njit(cache=True, nogil=True)
def _push_fields(nodes, parent, leaf_orig, off, cen, geo):
    """The nodes' linear fields (value at the centroid, gradient) summed down the tree in place
    (a child's value is the parent's field at the child's centroid), the gradient at each leaf
    taken into its original's plane (geo's row off[x])."""
    K = parent.shape[0]
    C = nodes.shape[1] // 4
    for x in range(1, K):
        pa = parent[x]
        ex, ey, ez = cen[x, 0] - cen[pa, 0], cen[x, 1] - cen[pa, 1], cen[x, 2] - cen[pa, 2]
        for c in range(C):
            nodes[x, c] += nodes[pa, c] + nodes[pa, C + 3 * c] * ex \
                + nodes[pa, C + 3 * c + 1] * ey + nodes[pa, C + 3 * c + 2] * ez
            for j in range(3):
                nodes[x, C + 3 * c + j] += nodes[pa, C + 3 * c + j]
    for x in range(K):
        if leaf_orig[x] < 0:
            continue
        i = off[x]
        nx, ny, nz = geo[i, 3], geo[i, 4], geo[i, 5]
        for c in range(C):
            gx, gy, gz = nodes[x, C + 3 * c], nodes[x, C + 3 * c + 1], nodes[x, C + 3 * c + 2]
            gn = gx * nx + gy * ny + gz * nz
            nodes[x, C + 3 * c] = gx - gn * nx
            nodes[x, C + 3 * c + 1] = gy - gn * ny
            nodes[x, C + 3 * c + 2] = gz - gn * nz


# ----------------------------------------------------------------------------- final gather

@numba.njit(cache=True, nogil=True)
def _two_layout(parent, leaf_orig, two, row_node):
    """(K,) bool the nodes holding a two-sided original, (n,) bool the depth-first rows' (the
    final gather's geo rows) two-sided flags."""
    K = parent.shape[0]
    ntwo = np.zeros(K, np.bool_)
    for x in range(K):
        if leaf_orig[x] >= 0:
            ntwo[x] = two[leaf_orig[x]]
    for x in range(K - 1, 0, -1):
        if ntwo[x]:
            ntwo[parent[x]] = True
    rtwo = np.zeros(row_node.shape[0], np.bool_)
    for i in range(row_node.shape[0]):
        rtwo[i] = two[leaf_orig[row_node[i]]]
    return ntwo, rtwo


@numba.njit(cache=True, nogil=True, inline="always")
def _side_normal(unit, axis, ntwo, x, h):
    """Node x's mean normal as its side h (0: +, 1: -) shows it: turned to that side of the
    cone axis where x holds a two-sided original, as it is otherwise."""
    mx, my, mz = unit[x, 0], unit[x, 1], unit[x, 2]
    if ntwo[x]:
        sg = 1.0 if mx * axis[x, 0] + my * axis[x, 1] + mz * axis[x, 2] >= 0.0 else -1.0
        if h == 1:
            sg = -sg
        mx, my, mz = sg * mx, sg * my, sg * mz
    return mx, my, mz


@numba.njit(cache=True, nogil=True)
def _final_sides(S, area, p, q, g, side, cnt, off, cen, unit, flat, reach, geo, row_node, axis,
                 ntwo, rtwo, nodes):
    """_final_links with sides: the source s sends S[hs, s] (hs its end's side), a flat
    receiver t takes it on its side ht (nodes[ht, t]), any other receiver per original, a
    two-sided original on its side that faces the source (|cos|), into its leaf row's side
    that holds it (its normal against the leaf's axis)."""
    C = S.shape[2]
    w = np.zeros(geo.shape[0])
    for k in range(p.shape[0]):
        for h in range(2):
            t, s = (p[k], q[k]) if h == 0 else (q[k], p[k])
            ht = (side[k] >> h) & 1
            hs = (side[k] >> (1 - h)) & 1
            mx, my, mz = _side_normal(unit, axis, ntwo, s, hs)
            sx, sy, sz = cen[s, 0], cen[s, 1], cen[s, 2]
            f = np.float64(g[k])
            if flat[t]:  # one linear field over the node's side ht
                nx, ny, nz = _side_normal(unit, axis, ntwo, t, ht)
                dx, dy, dz = sx - cen[t, 0], sy - cen[t, 1], sz - cen[t, 2]
                gx = gy = gz = 0.0
                cb = mx * dx + my * dy + mz * dz
                if nx * dx + ny * dy + nz * dz > 0.0 and (cb < 0.0 or (ntwo[s] and cb > 0.0)):
                    gx, gy, gz = _kernel_gradient(dx, dy, dz, nx, ny, nz,
                                                  -mx if cb > 0.0 else mx,
                                                  -my if cb > 0.0 else my,
                                                  -mz if cb > 0.0 else mz, reach[t])
                for c in range(C):
                    val = f * S[hs, s, c] / area[t]
                    nodes[ht, t, c] += val
                    nodes[ht, t, C + 3 * c] += val * gx
                    nodes[ht, t, C + 3 * c + 1] += val * gy
                    nodes[ht, t, C + 3 * c + 2] += val * gz
                continue
            lo, n = off[t], cnt[t]
            tot = 0.0
            for i in range(lo, lo + n):
                dx, dy, dz = sx - geo[i, 0], sy - geo[i, 1], sz - geo[i, 2]
                r2 = dx * dx + dy * dy + dz * dz
                ca = geo[i, 3] * dx + geo[i, 4] * dy + geo[i, 5] * dz
                cb = -(mx * dx + my * dy + mz * dz)
                if rtwo[i]:
                    ca = abs(ca)
                if ntwo[s]:
                    cb = abs(cb)
                w[i - lo] = ca * cb / (r2 * r2) if ca > 0.0 and cb > 0.0 else 0.0
                tot += geo[i, 6] * w[i - lo]
            for i in range(lo, lo + n):
                fac = w[i - lo] / tot if tot > 0.0 else 1.0 / area[t]
                if fac <= 0.0:
                    continue
                dx, dy, dz = sx - geo[i, 0], sy - geo[i, 1], sz - geo[i, 2]
                ca = geo[i, 3] * dx + geo[i, 4] * dy + geo[i, 5] * dz
                sg = -1.0 if rtwo[i] and ca < 0.0 else 1.0  # the side facing the source
                x = row_node[i]
                if tot > 0.0:
                    cb = mx * dx + my * dy + mz * dz
                    sm = -1.0 if ntwo[s] and cb > 0.0 else 1.0
                    gx, gy, gz = _kernel_gradient(dx, dy, dz, sg * geo[i, 3], sg * geo[i, 4],
                                                  sg * geo[i, 5], sm * mx, sm * my, sm * mz,
                                                  geo[i, 7])
                else:
                    gx = gy = gz = 0.0
                up = geo[i, 3] * axis[x, 0] + geo[i, 4] * axis[x, 1] + geo[i, 5] * axis[x, 2] \
                    >= 0.0
                r = 0 if (sg > 0.0) == up else 1
                if not rtwo[i]:
                    r = 0
                for c in range(C):
                    val = f * fac * S[hs, s, c]
                    nodes[r, x, c] += val
                    nodes[r, x, C + 3 * c] += val * gx
                    nodes[r, x, C + 3 * c + 1] += val * gy
                    nodes[r, x, C + 3 * c + 2] += val * gz


@numba.njit(cache=True, nogil=True)
def _fields_sides(nodes, parent, leaf_orig, off, cen, geo, axis, normal, two):
    """(2, K, 4C) the fronts' and backs' fields at the leaves from the nodes' sides' fields
    (2, K, 4C): a one-sided original's front takes both sides of every ancestor
    (_push_fields), a two-sided one's front each ancestor's side its normal takes there and
    its back the other, walked up the tree (_push_fields' sum written out: the value at the
    leaf's centroid of every ancestor's linear field)."""
    K = parent.shape[0]
    C4 = nodes.shape[2]
    C = C4 // 4
    out = np.zeros((2, K, C4))
    for x in range(K):
        for j in range(C4):
            out[0, x, j] = nodes[0, x, j] + nodes[1, x, j]
    _push_fields(out[0], parent, leaf_orig, off, cen, geo)
    for x in range(K):
        o = leaf_orig[x]
        if o < 0 or not two[o]:
            continue
        for j in range(C4):
            out[0, x, j] = 0.0
        y = x
        while y >= 0:
            up = normal[o, 0] * axis[y, 0] + normal[o, 1] * axis[y, 1] \
                + normal[o, 2] * axis[y, 2] >= 0.0
            ex, ey, ez = cen[x, 0] - cen[y, 0], cen[x, 1] - cen[y, 1], cen[x, 2] - cen[y, 2]
            for b in range(2):
                h = b if up else 1 - b
                for c in range(C):
                    gx, gy, gz = nodes[h, y, C + 3 * c], nodes[h, y, C + 3 * c + 1], \
                        nodes[h, y, C + 3 * c + 2]
                    out[b, x, c] += nodes[h, y, c] + gx * ex + gy * ey + gz * ez
                    out[b, x, C + 3 * c] += gx
                    out[b, x, C + 3 * c + 1] += gy
                    out[b, x, C + 3 * c + 2] += gz
            y = parent[y]
        i = off[x]
        nx, ny, nz = geo[i, 3], geo[i, 4], geo[i, 5]
        for b in range(2):
            for c in range(C):
                gx, gy, gz = out[b, x, C + 3 * c], out[b, x, C + 3 * c + 1], \
                    out[b, x, C + 3 * c + 2]
                gn = gx * nx + gy * ny + gz * nz
                out[b, x, C + 3 * c] = gx - gn * nx
                out[b, x, C + 3 * c + 1] = gy - gn * ny
                out[b, x, C + 3 * c + 2] = gz - gn * nz
    return out
