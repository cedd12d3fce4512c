"""Link refinement (SPEC §8) in numba: per round, the open links of a task are refined depth
first until each is kept, dropped or waits for rays (_refine_loop says how a link is judged;
links.refine_pairs casts the rays between rounds). The arrays travel in named tuples grouped by
meaning: the partition's split trees (Tree), the originals (Elements, Occluders), the task's
local node table (localnodes.NodeTable, grown here), the stack (Stack, Entries), the kept and waiting links
(Kept, Waiting) and the scalar settings (RefineParams)."""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from radiosity.methods.hierarchical.links.formfactors import disc_spread, centroid_to_polygon, near_ff
from radiosity.methods.hierarchical.links.nodes import (NodeTable, copy_tree_node, is_forced, grow_rows,
                                                       grown_copy, new_node, part_of)
from radiosity.scene.splittrees import MAX_DEPTH, depth_bit, split_one
from radiosity.tracing.shafts import (HULL_AXES, faces_along, first_in_hull, hull_axes,
                                      outside_hull, same_side_polys, shaft_excludes,
                                      tree_candidates)

# The partition's node table (splittrees.TreeNodes, k nodes): verts (k, 4, 3), nverts, area,
# center, lo / hi (node boxes), child (k, 2), orig, depth, path (uint64); ext (k,): leaves that
# may be split on demand below the camera's partition (links.LinkInputs).
Tree = namedtuple("Tree", "verts nverts area center lo hi child orig depth path ext")
# Per original (n): normal (n, 3), two_sided; the oracle's weights wrho, lhat (n, 2) and lref;
# Per partition node (k) and side, from the solved radiance of refinement rounds (rounds.py);
# (0, 2) arrays: none (the a-priori lhat alone): nhat, a source's radiance, used instead of lhat
# for the nodes of the partition; nvar, the spread of that radiance over the node (half the
# difference of its children's); force, nodes whose leaves' rows of F summed past 1 (their
# links' visibility was taken too coarsely): a link that the oracle would keep, with candidate
# occluders left in its shaft, splits a forced node (or a node split off below one) instead.
Elements = namedtuple("Elements", "normal two_sided wrho lhat lref nhat nvar force")
# Per original as an occluder (shafts.occluders): padded boxes lo / hi, polygons verts /
# nverts, planes normal / offset, the plane tolerance pad, and the tree over them
# (shafts.OccluderTree) that finds a shaft's candidates without visiting every occluder.
Occluders = namedtuple("Occluders", "lo hi verts nverts normal offset pad tree")
# Links to refine: local nodes p, q, candidate occluders pool[c0:c1], visible fraction frac (-1:
# not measured yet); the depth-first stack adds its candidate lists to pool above base_end.
Entries = namedtuple("Entries", "p q c0 c1 frac")
Stack = namedtuple("Stack", "p q c0 c1 frac pool base_end")
# Kept links: nodes, form factors ff (k, 2) F_pq F_qp, visible fraction, sides (k, 2), exact
# flag. Links waiting for rays: nodes and lists (w, 2) [start, length] into pool.
Kept = namedtuple("Kept", "p q ff v sides exact")
Waiting = namedtuple("Waiting", "p q lists pool")
# A link root whose shaft holds more candidate occluders than this leaves its visibility to
# rays (no list, no proof by shafts, for its children too): in a mesh of many small triangles no
# single one blocks a link, and filtering long lists for every link cost more than the rays
# (the tessellated Cornell box: 43 us per evaluated link). Scenes of fewer originals never have
# this many, and are unchanged.
MAX_OCCLUDERS = 64
# The scalar settings (params.LinkParams.kernel_params).
# hull (params.LinkParams.hull_shafts): a link about to wait for rays first tests its candidates
# against its two polygons' planes (1), or the whole tight shaft of the two (2: shafts.hull_axes),
# or also, without a list, walks the occluder tree for one in it (> 2: shafts.first_in_hull, at
# most `hull` tree nodes); 0: off.
RefineParams = namedtuple("RefineParams", "eps shadow near min_size kid exact plane_tol oracle "
                                          "gauss_gap far_polygon occlusion hull")
# Lists longer than this skip the tight shaft: one of their occluders is almost always in it,
# and the test costs more than the rays it saves.
HULL_LIST = 4


# counters of a link task (links.py sums and reports them)
COUNTERS = ("pairs", "links", "evaluated", "refined", "dropped_orientation", "shaft_visible",
            "shaft_blocked", "ray_links", "rays", "ray_blocked", "partial_refined", "exact",
            "split_off_nodes", "rounds", "hull_visible", "hull_blocked")
C_PAIRS, C_LINKS, C_EVAL, C_REFINED, C_ORIENT, C_SVIS, C_SBLOCK, C_RAYLINKS, C_RAYS, C_RBLOCK, \
    C_PARTIAL, C_EXACT, C_SPLITOFF, C_ROUNDS, C_HVIS, C_HBLOCK = range(len(COUNTERS))

@numba.njit(cache=True, nogil=True)
def _blocks(o, V, p, nP, q, nQ, everts, envert, enormal, eoffset, pad, sp, sq):
    """Does occluder o alone cut every segment between polygons V[p, :nP] and V[q, :nQ]? Its
    plane must separate them strictly (beyond pad), and every crossing point of a segment
    between a vertex of P and one of Q must lie inside o (beyond pad): those points span the
    crossing set of all segments (it is conv(P u Q) cut by the plane), and o is convex.
    sp, sq: scratch (4,). Arrays and indices, no rows (shafts.faces_along: views cost)."""
    n0, n1, n2 = enormal[o, 0], enormal[o, 1], enormal[o, 2]
    d0 = eoffset[o]
    pmin, pmax, qmin, qmax = np.inf, -np.inf, np.inf, -np.inf
    for i in range(nP):
        sp[i] = n0 * V[p, i, 0] + n1 * V[p, i, 1] + n2 * V[p, i, 2] - d0
        pmin = min(pmin, sp[i])
        pmax = max(pmax, sp[i])
    for j in range(nQ):
        sq[j] = n0 * V[q, j, 0] + n1 * V[q, j, 1] + n2 * V[q, j, 2] - d0
        qmin = min(qmin, sq[j])
        qmax = max(qmax, sq[j])
    if not ((pmin > pad and qmax < -pad) or (pmax < -pad and qmin > pad)):
        return False
    m = envert[o]
    for i in range(nP):
        for j in range(nQ):
            t = sp[i] / (sp[i] - sq[j])
            x0 = V[p, i, 0] + t * (V[q, j, 0] - V[p, i, 0])
            x1 = V[p, i, 1] + t * (V[q, j, 1] - V[p, i, 1])
            x2 = V[p, i, 2] + t * (V[q, j, 2] - V[p, i, 2])
            for k in range(m):
                l = (k + 1) % m
                ex = everts[o, l, 0] - everts[o, k, 0]
                ey = everts[o, l, 1] - everts[o, k, 1]
                ez = everts[o, l, 2] - everts[o, k, 2]
                wx, wy, wz = x0 - everts[o, k, 0], x1 - everts[o, k, 1], x2 - everts[o, k, 2]
                c = (ey * wz - ez * wy) * n0 + (ez * wx - ex * wz) * n1 + (ex * wy - ey * wx) * n2
                if c <= pad * np.sqrt(ex * ex + ey * ey + ez * ez):
                    return False
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def _pick(prefer, can_p, can_q, other):
    """Which node to split: the preferred one (1: q, 0: p) if it can, else the other if
    `other` (near links, the error oracles, epsilon = 0); -1: keep the link."""
    if prefer == 1:
        return 1 if can_q else (0 if other and can_p else -1)
    return 0 if can_p else (1 if other and can_q else -1)



@numba.njit(cache=True, nogil=True)
def _plane_range(nx, ny, nz, d0, V, x, nv):
    lo, hi = np.inf, -np.inf
    for i in range(nv):
        s = nx * V[x, i, 0] + ny * V[x, i, 1] + nz * V[x, i, 2] - d0
        lo = min(lo, s)
        hi = max(hi, s)
    return lo, hi



@numba.njit(cache=True, nogil=True)
def _refine_loop(st, stack, kept, waiting, tab, pmap, tree, elem, occ, prm, counts):
    """refine's loop, until the stack is empty or an array is full (refine grows it and calls
    again; st: [ns, cnt, nk, nw, npool]). No array variable is reassigned here: in a loop that
    reassigns arrays numba updates each one's reference count (an atomic operation) on every
    iteration.

    A link (p, q) popped from the stack is judged in this order:

    1. orientation (exact, from the vertices): q behind p's plane (or p behind q's) -> no link;
       a node straddling the other's plane is split while it can be;
    2. shafts (Haines & Wallace, shafts.py's kernels): the occluders that may cut a segment
       between the boxes of p and q, filtered from the parent link's list; none left -> v = 1
       with no ray (for the children too); one occluder whose plane separates p from q and that
       contains every crossing point of the segments between their vertices (the convex hull of
       all crossing points) -> v = 0 exactly, the link is dropped;
    3. the oracle (hierarchy.oracle): `ff` compares the centroid estimates of F_pq, F_qp with
       epsilon (Hanrahan et al. 1991); `gradient` weighs them by the nodes' size over their
       distance; `spread` (the default) by how much the estimate changes between a node's
       centroid and its vertices. Weighted (`weight: bf`) by the receiver's reflectance and an
       a-priori radiance of the source (emission plus an ambient estimate), or not (`none`).
       Above epsilon, or near (centroids closer than `near-field-factor` node sizes, size =
       sqrt(area)), the node that looks larger from the other is split, if it can be (seen
       originals down to their camera sub-elements, unseen ones down to `min-node-size`);
    4. a kept link not proven visible waits for k stratified sample rays (`link-rays`,
       sampling.py) -> v; a partly visible link (0 < v < 1) with error above `shadow-factor *
       epsilon` is split further while it can be.

    Kept far links carry the exact form factor from the smaller node's centroid to the larger
    node's polygon (`far-kernel: polygon`; or the point / disc kernel between centroids:
    `centroid`); near leaf links with the -nf kernels the exact polygon-to-polygon form factor
    (formfactors.near_ff)."""
    sp_, sq_, sc0, sc1, sfr, stk_pool, base_end = stack
    kp, kq, kf, kv, ks, kx = kept
    wp, wq, wc, wpool = waiting
    Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan = tab
    t_child = tree.child
    normal, two_sided, wrho, lhat, lref, nhat, nvar, force = elem
    by_node = nhat.shape[0] > 0
    elo, ehi, everts, envert, enormal, eoffset, pad = occ.lo, occ.hi, occ.verts, occ.nverts, \
        occ.normal, occ.offset, occ.pad
    eps, shadow, near_f, min_size, kid = prm.eps, prm.shadow, prm.near, prm.min_size, prm.kid
    exact, plane_tol, oracle, gauss_gap = prm.exact, prm.plane_tol, prm.oracle, prm.gauss_gap
    far_polygon = prm.far_polygon
    ns, cnt, nk, nw, npool = st[0], st[1], st[2], st[3], st[4]
    cap, scap, kcap, wcap = Lo.shape[0], sp_.shape[0], kp.shape[0], wp.shape[0]
    A = np.empty((2, 3))
    B = np.empty((2, 3))
    c0 = np.empty((4, 3))
    c1 = np.empty((4, 3))
    cc = np.empty(3)
    s4p = np.empty(4)
    s4q = np.empty(4)
    S = np.empty((4, 3))
    Sc = np.empty((10, 3))
    axes = np.empty((HULL_AXES, 3))
    alo = np.empty(HULL_AXES)
    ahi = np.empty(HULL_AXES)
    walk = np.empty(2 * MAX_DEPTH + 64, np.int64)
    m = 0
    while ns > 0:
        # room for two new nodes, two stack entries, a kept link, a waiting link and its list
        if cnt + 4 > cap or ns + 4 > scap or nk >= kcap or nw >= wcap \
                or npool + (sc1[ns - 1] - sc0[ns - 1]) > wpool.shape[0]:
            break
        ns -= 1
        p, q, l0, l1, frac = sp_[ns], sq_[ns], sc0[ns], sc1[ns], sfr[ns]
        counts[C_EVAL] += 1
        op, oq = Lo[p], Lo[q]
        npx, npy, npz = normal[op, 0], normal[op, 1], normal[op, 2]
        nqx, nqy, nqz = normal[oq, 0], normal[oq, 1], normal[oq, 2]
        # 1. orientation, from the vertices
        dp = npx * Lc[p, 0] + npy * Lc[p, 1] + npz * Lc[p, 2]
        dq = nqx * Lc[q, 0] + nqy * Lc[q, 1] + nqz * Lc[q, 2]
        qlo, qhi = _plane_range(npx, npy, npz, dp, Lv, q, Ln[q])
        plo, phi = _plane_range(nqx, nqy, nqz, dq, Lv, p, Ln[p])
        fq, bq = qhi > plane_tol, qlo < -plane_tol
        fp, bp = phi > plane_tol, plo < -plane_tol
        if not ((fq or (two_sided[op] and bq)) and (fp or (two_sided[oq] and bp))):
            counts[C_ORIENT] += 1
            continue
        q_straddles = fq and bq
        p_straddles = fp and bp
        can_p, can_q = Lcan[p], Lcan[q]
        # centroid geometry: the disc estimates, the sides, the weights
        dx = Lc[q, 0] - Lc[p, 0]
        dy = Lc[q, 1] - Lc[p, 1]
        dz = Lc[q, 2] - Lc[p, 2]
        r2 = dx * dx + dy * dy + dz * dz + 1e-300
        ca = npx * dx + npy * dy + npz * dz
        cb = -(nqx * dx + nqy * dy + nqz * dz)
        g = abs(ca * cb)
        Ap, Aq = La[p], La[q]
        sp = 0 if ca > 0 else 1
        sq = 0 if cb > 0 else 1
        fpq = Aq * g / (r2 * (np.pi * r2 + Aq))
        fqp = Ap * g / (r2 * (np.pi * r2 + Ap))
        if by_node:  # the solved radiance of the source node (rounds.py)
            lq = nhat[Lpn[q], sq] if Lpn[q] >= 0 else lhat[oq, sq]
            lp = nhat[Lpn[p], sp] if Lpn[p] >= 0 else lhat[op, sp]
        else:
            lq, lp = lhat[oq, sq], lhat[op, sp]
        wpq = wrho[op, sp] * lq / lref
        wqp = wrho[oq, sq] * lp / lref
        amount = max(fpq * wpq, fqp * wqp)  # weighted transfer (partly visible links)
        prefer = 1 if Aq >= Ap else 0       # the node that looks larger from the other
        near = np.sqrt(r2) < near_f * max(np.sqrt(Ap), np.sqrt(Aq))
        split = -1  # 0: split p, 1: split q
        if frac < 0.0:
            # 2. shafts: keep the occluders that may cut a segment between the node boxes
            # (l0 < 0: more candidates than MAX_OCCLUDERS at the root: left to rays)
            if l0 >= 0:
                for k in range(3):
                    A[0, k], A[1, k] = Llo[p, k], Lhi[p, k]
                    B[0, k], B[1, k] = Llo[q, k], Lhi[q, k]
                top = max(l1, base_end)
                m0 = top
                blocked = False
                for c in range(l0, l1):
                    o = stk_pool[c]
                    if same_side_polys(Lv, p, Ln[p], q, Ln[q], enormal, eoffset, o, pad) or \
                            shaft_excludes(A, B, elo, ehi, o):
                        continue
                    if _blocks(o, Lv, p, Ln[p], q, Ln[q], everts, envert, enormal, eoffset, pad,
                               s4p, s4q):
                        blocked = True
                        break
                    stk_pool[m0] = o
                    m0 += 1
                if blocked:
                    counts[C_SBLOCK] += 1
                    continue
                l0, l1 = top, m0
            # 3. the oracle (Hanrahan et al. 1991: split the node that looks larger from the
            # other; if it cannot split, keep the link; epsilon = 0 is the all-pairs limit)
            if q_straddles and can_q:
                split = 1
            elif p_straddles and can_p:
                split = 0
            else:  # the error estimate, only here (a blocked or measured link needs none)
                ep = eq = 0.0
                if oracle == 0:
                    err = amount
                elif oracle == 1:  # the transfer's variation over the nodes that can split
                    err = amount * ((np.sqrt(Ap) if can_p else 0.0)
                                    + (np.sqrt(Aq) if can_q else 0.0)) / np.sqrt(r2)
                else:  # the estimate's spread over the vertices of each node that can split
                    gp = 1.0 if sp == 0 else -1.0
                    gq = 1.0 if sq == 0 else -1.0
                    # receiving: how much F(x -> other node) varies over the node's vertices
                    # (first order; what the centroids miss at grazing angles); as a source
                    # approximated at its centroid: the centroid rule's error (second order)
                    if can_p:
                        big, curv = disc_spread(Lv, p, Ln[p], gp * npx, gp * npy, gp * npz, Lc, q,
                                            gq * nqx, gq * nqy, gq * nqz, Aq, fpq)
                        ep = wpq * big
                        if Ap <= Aq or not far_polygon:
                            ep += max(wpq, wqp) * curv
                    if can_q:
                        big, curv = disc_spread(Lv, q, Ln[q], gq * nqx, gq * nqy, gq * nqz, Lc, p,
                                            gp * npx, gp * npy, gp * npz, Ap, fqp)
                        eq = wqp * big
                        if Aq < Ap or not far_polygon:
                            eq += max(wpq, wqp) * curv
                    err = max(ep, eq)
                    if nvar.shape[0] > 0 and not (near or err > eps):
                        # the source's own spread of solved radiance: rho_p F_pq dL_q
                        vq = wrho[op, sp] * fpq * nvar[Lpn[q], sq] / lref \
                            if can_q and Lpn[q] >= 0 else 0.0
                        vp = wrho[oq, sq] * fqp * nvar[Lpn[p], sp] / lref \
                            if can_p and Lpn[p] >= 0 else 0.0
                        if max(vq, vp) > eps:
                            split = 1 if vq >= vp else 0
                if split < 0 and (near or err > eps):
                    # the smaller node only when the larger cannot split and its own error is
                    # above epsilon (splitting a node below the other's size dilutes the error
                    # per link: many small links each under epsilon, summing to a large one)
                    other = eps <= 0.0 or (oracle == 2 and (ep if prefer == 1 else eq) > eps) \
                        or oracle == 1 or (near and oracle == 0)
                    split = _pick(prefer, can_p, can_q, other)
            if split < 0 and (l1 > l0 or l0 < 0):
                # a link to keep with occluders in its shaft at a forced node: split that node,
                # so that the link's visibility is sampled finer there
                fp_ = can_p and is_forced(force, Lpn[p], sp)
                fq_ = can_q and is_forced(force, Lpn[q], sq)
                if fp_ or fq_:
                    split = 0 if fp_ and (Ap >= Aq or not fq_) else 1
        elif 0.0 < frac < 1.0 and amount > shadow:
            split = _pick(prefer, can_p, can_q, oracle > 0 or eps <= 0.0)
            if split >= 0:
                counts[C_PARTIAL] += 1
        if split >= 0:
            counts[C_REFINED] += 1
            x = q if split == 1 else p
            if Lch[x, 0] < 0:  # make the children (partition's, or split off an unseen original)
                t = Lpn[x]
                if t >= 0 and t_child[t, 0] >= 0:
                    for h in range(2):
                        tc = t_child[t, h]
                        if pmap[tc] < 0:
                            pmap[tc] = cnt
                            copy_tree_node(cnt, tc, tree, min_size, tab)
                            cnt += 1
                        Lch[x, h] = pmap[tc]
                else:
                    split_one(Lv[x], Ln[x], c0, c1)
                    d1 = Ld[x] + 1
                    below = -2 - part_of(Lpn[x])
                    for h in range(2):
                        path = Lp[x] | depth_bit(Ld[x]) if h == 1 else Lp[x]
                        cv = c1 if h == 1 else c0
                        new_node(cnt, cv, Ln[x], Lo[x], path, d1, below, False, tab, cc)
                        Lcan[cnt] = np.sqrt(La[cnt]) > min_size and d1 < MAX_DEPTH
                        Lch[x, h] = cnt
                        cnt += 1
                    counts[C_SPLITOFF] += 2
            for h in range(1, -1, -1):  # child 0 popped first
                if split == 1:
                    sp_[ns], sq_[ns] = p, Lch[x, h]
                else:
                    sp_[ns], sq_[ns] = Lch[x, h], q
                sc0[ns], sc1[ns], sfr[ns] = l0, l1, -1.0
                ns += 1
            continue
        # keep the link: the leaf test of the visibility stage (centroids face each other)
        length = np.sqrt(r2)
        if not (faces_along(normal, op, two_sided[op], dx, dy, dz, length)
                and faces_along(normal, oq, two_sided[oq], -dx, -dy, -dz, length)):
            counts[C_ORIENT] += 1
            continue
        if frac < 0.0 and (l1 > l0 or l0 < 0):  # wait for rays, with the filtered occluders
            verdict = 0  # 0: rays, 1: visible, -1: blocked (the tight shaft, prm.hull)
            tight = prm.hull > 2 if l0 < 0 else prm.hull > 0 and l1 - l0 <= HULL_LIST
            if tight:
                m = hull_axes(Lv, p, Ln[p], q, Ln[q], axes, alo, ahi, prm.hull > 1)
            if l0 < 0 and prm.hull > 2:  # no list: one occluder in the tight shaft, from the tree
                for k in range(3):
                    A[0, k], A[1, k] = Llo[p, k], Lhi[p, k]
                    B[0, k], B[1, k] = Llo[q, k], Lhi[q, k]
                o = first_in_hull(A, B, Lv, p, Ln[p], q, Ln[q], occ.tree, elo, ehi, everts,
                                  envert, enormal, eoffset, pad, op, oq, axes, alo, ahi, m,
                                  prm.hull, walk)
                if o == -1:
                    verdict = 1
                elif o >= 0 and _blocks(o, Lv, p, Ln[p], q, Ln[q], everts, envert, enormal,
                                        eoffset, pad, s4p, s4q):
                    verdict = -1
            if verdict == 0:
                wp[nw], wq[nw] = p, q
                if l0 < 0:  # too many to list: the children are left to rays too
                    wc[nw, 0], wc[nw, 1] = -1, 0
                else:  # the list less the occluders outside the tight shaft, up to the
                    n0 = npool  # first one inside it (then rays: the rest are not tested)
                    inside = not tight
                    for c in range(l0, l1):
                        o = stk_pool[c]
                        if inside or not outside_hull(everts, envert, o, axes, alo, ahi, m, pad):
                            wpool[npool] = o
                            npool += 1
                            inside = True
                    wc[nw, 0], wc[nw, 1] = n0, npool - n0
                    if npool == n0:
                        verdict = 1
                if verdict == 0:
                    nw += 1
                    continue
            if verdict < 0:
                counts[C_HBLOCK] += 1
                continue
            counts[C_HVIS] += 1
            frac = 1.0  # proven visible: kept below with v = 1, no ray
        v = 1.0 if frac < 0.0 else frac
        if frac < 0.0:
            counts[C_SVIS] += 1
        if v <= 0.0:
            counts[C_RBLOCK] += 1
            continue
        kp[nk], kq[nk], kv[nk] = p, q, v
        ks[nk, 0], ks[nk, 1] = sp, sq
        if exact and near:
            gp = 1.0 if sp == 0 else -1.0
            gq = 1.0 if sq == 0 else -1.0
            kf[nk, 0], kf[nk, 1] = near_ff(Lv[p], Ln[p], Ap, gp, Lv[q], Ln[q], Aq, gq, npx, npy,
                                           npz, nqx, nqy, nqz,
                                           np.inf if p_straddles or q_straddles else gauss_gap)
            kx[nk] = True
        elif far_polygon == 2:
            gp = 1.0 if sp == 0 else -1.0
            gq = 1.0 if sq == 0 else -1.0
            kf[nk, 0], kf[nk, 1] = near_ff(Lv[p], Ln[p], Ap, gp, Lv[q], Ln[q], Aq, gq, npx, npy,
                                           npz, nqx, nqy, nqz, -1.0)
        elif far_polygon:
            gp = 1.0 if sp == 0 else -1.0
            gq = 1.0 if sq == 0 else -1.0
            kf[nk, 0], kf[nk, 1] = centroid_to_polygon(Lv, Ln, Lc, p, q, Ap, gp, Aq, gq, normal, op,
                                                       oq, S, Sc)
        elif kid == 0:
            w = g / (np.pi * r2 * r2)
            kf[nk, 0], kf[nk, 1] = w * Aq, w * Ap
        else:
            kf[nk, 0] = Aq * g / r2 / (np.pi * r2 + Aq)
            kf[nk, 1] = Ap * g / r2 / (np.pi * r2 + Ap)
        nk += 1
    st[0], st[1], st[2], st[3], st[4] = ns, cnt, nk, nw, npool


def refine(entries, pool, base_end, tab, cnt, pmap, tree, elem, occ, prm, counts):
    """One round of refinement from `entries` (Entries: local node ids p, q; candidate
    occluders pool[c0:c1]; frac: the visible fraction measured by rays, or -1 not yet measured).

    The local node table (tab, cnt nodes; pmap: partition node -> local id) grows as nodes are
    split and is returned. Returns (tab, cnt, the kept links (Kept), the links waiting for rays
    (Waiting)). The loop itself is the kernel _refine_loop; this driver of it is plain Python
    (it only allocates, and grows the arrays the few times the loop stops because one is full:
    a kernel here cost compile time on a first run, for nothing measurable per call:
    docs/src/measurements/choices.md)."""
    e_p, e_q, e_c0, e_c1, e_frac = entries
    Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan = tab
    # kept links
    kcap = 1024
    kp = np.empty(kcap, np.int64)
    kq = np.empty(kcap, np.int64)
    kf = np.zeros((kcap, 2))
    kv = np.zeros(kcap)
    ks = np.zeros((kcap, 2), np.int8)
    kx = np.zeros(kcap, np.bool_)
    nk = 0
    # links waiting for rays, with their filtered occluder lists
    wcap = 1024
    wp = np.empty(wcap, np.int64)
    wq = np.empty(wcap, np.int64)
    wc = np.zeros((wcap, 2), np.int64)
    nw = 0
    wpool = np.empty(4096, np.int64)
    npool = 0
    # the depth-first stack; candidate lists live LIFO in `stk_pool` above base_end
    n = e_p.shape[0]
    maxlen = max(0, int((e_c1 - e_c0).max())) if n else 0
    scap = n + 4 * (2 * MAX_DEPTH + 8)
    sp_ = np.empty(scap, np.int64)
    sq_ = np.empty(scap, np.int64)
    sc0 = np.empty(scap, np.int64)
    sc1 = np.empty(scap, np.int64)
    sfr = np.empty(scap)
    stk_pool = np.empty(base_end + (2 * MAX_DEPTH + 8) * maxlen + 1, np.int64)
    stk_pool[:base_end] = pool[:base_end]
    # reversed: the first entry is popped first
    sp_[:n], sq_[:n], sc0[:n], sc1[:n], sfr[:n] = (e_p[::-1], e_q[::-1], e_c0[::-1], e_c1[::-1],
                                                   e_frac[::-1])
    st = np.array([n, cnt, nk, nw, npool], np.int64)
    while True:
        _refine_loop(st, Stack(sp_, sq_, sc0, sc1, sfr, stk_pool, base_end),
                     Kept(kp, kq, kf, kv, ks, kx), Waiting(wp, wq, wc, wpool),
                     NodeTable(Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan), pmap, tree,
                     elem, occ, prm, counts)
        ns, cnt, nk, nw, npool = st[0], st[1], st[2], st[3], st[4]
        if ns == 0:
            break
        if cnt + 4 > Lo.shape[0]:
            cap = 2 * Lo.shape[0]
            Lv, Ln, La, Lc = grown_copy(Lv, cap), grown_copy(Ln, cap), grown_copy(La, cap), grown_copy(Lc, cap)
            Llo, Lhi, Lo, Lp = grown_copy(Llo, cap), grown_copy(Lhi, cap), grown_copy(Lo, cap), grown_copy(Lp, cap)
            Ld, Lch, Lpn, Lcan = grown_copy(Ld, cap), grown_copy(Lch, cap), grown_copy(Lpn, cap), grown_copy(Lcan, cap)
        if ns + 4 > sp_.shape[0]:
            scap = 2 * sp_.shape[0]
            sp_, sq_, sc0, sc1, sfr = (grown_copy(sp_, scap), grown_copy(sq_, scap), grown_copy(sc0, scap),
                                       grown_copy(sc1, scap), grown_copy(sfr, scap))
        if nk >= kp.shape[0]:
            kcap = 2 * kp.shape[0]
            kp, kq, kf, kv, ks, kx = (grown_copy(kp, kcap), grown_copy(kq, kcap), grown_copy(kf, kcap),
                                      grown_copy(kv, kcap), grown_copy(ks, kcap), grown_copy(kx, kcap))
        if nw >= wp.shape[0]:
            wcap = 2 * wp.shape[0]
            wp, wq, wc = grown_copy(wp, wcap), grown_copy(wq, wcap), grown_copy(wc, wcap)
        while npool + (sc1[ns - 1] - sc0[ns - 1]) > wpool.shape[0]:
            wpool = grown_copy(wpool, 2 * wpool.shape[0])
    return (NodeTable(Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan), cnt,
            Kept(kp[:nk], kq[:nk], kf[:nk], kv[:nk], ks[:nk], kx[:nk]),
            Waiting(wp[:nw], wq[:nw], wc[:nw], wpool[:npool]))


@numba.njit(cache=True, nogil=True)
def roots(pairs, rays_only, root, pmap, tree, tab, cnt, occ, prm):
    """The first entries of a task: the root link of each pair (I, J) with the occluders that
    may cut a segment between the two originals (shafts.tree_candidates), or none searched (left
    to rays) where rays_only[k], as between a mesh's small triangles: there the search almost
    never proves a link visible and costs about ten links' rays
    (docs/src/design/methods-hierarchical-clusters.md). Returns the entries (p, q, c0, c1), the
    pool, and the count of local nodes."""
    Llo, Lhi = tab.lo, tab.hi
    elo, ehi, enormal, eoffset, pad = occ.lo, occ.hi, occ.normal, occ.offset, occ.pad
    t = pairs.shape[0]
    e_p = np.empty(t, np.int64)
    e_q = np.empty(t, np.int64)
    e_c0 = np.empty(t, np.int64)
    e_c1 = np.empty(t, np.int64)
    pool = np.empty(1024, np.int64)
    npool = 0
    A = np.empty((2, 3))
    B = np.empty((2, 3))
    for k in range(t):
        ends = np.empty(2, np.int64)
        for h in range(2):
            r = root[pairs[k, h]]
            if pmap[r] < 0:
                pmap[r] = cnt
                copy_tree_node(cnt, r, tree, prm.min_size, tab)
                cnt += 1
            ends[h] = pmap[r]
        e_p[k], e_q[k] = ends[0], ends[1]
        for j in range(3):
            A[0, j], A[1, j] = Llo[ends[0], j], Lhi[ends[0], j]
            B[0, j], B[1, j] = Llo[ends[1], j], Lhi[ends[1], j]
        if prm.occlusion and rays_only[k]:
            e_c0[k], e_c1[k] = -1, -1
            continue
        if prm.occlusion:
            cand = tree_candidates(A, B, tab.verts, ends[0], tab.nverts[ends[0]], ends[1],
                                   tab.nverts[ends[1]], occ.tree, elo, ehi, enormal, eoffset,
                                   pad, pairs[k, 0], pairs[k, 1], MAX_OCCLUDERS)
        else:
            cand = np.zeros(0, np.int64)
        if cand.shape[0] > MAX_OCCLUDERS:  # left to rays (l0 = -1, see _refine_loop)
            e_c0[k], e_c1[k] = -1, -1
            continue
        while npool + cand.shape[0] > pool.shape[0]:
            pool = grow_rows(pool, 2 * pool.shape[0])
        e_c0[k] = npool
        pool[npool:npool + cand.shape[0]] = cand
        npool += cand.shape[0]
        e_c1[k] = npool
    return e_p, e_q, e_c0, e_c1, pool[:npool], cnt
