"""Hierarchical radiosity links (SPEC §8, --method hierarchical): per pair of original elements,
refine the link of their roots down the split trees until each link carries little light.

A link p <- q between nodes of two originals (hierarchy.py) carries the unoccluded form
factors F_pq, F_qp (A_p F_pq = A_q F_qp) and the visible fraction v. One task per pair of
originals I < J that face each other (originals.facing_pairs: nothing n x n), or per stripe
of pairs, run through the one runner (runner.run_tasks) like the visibility matrix: bounded
window, most expensive first, retries, a manifest with a crc per task, resume.

Refinement of a link (p, q), depth first:

1. orientation (exact, from the vertices): q behind p's plane (or p behind q's) -> no link;
   a node straddling the other's plane is split while it can be;
2. shafts (Haines & Wallace, shafts.py's kernels): the occluders that may cut a segment
   between the boxes of p and q, filtered from the parent link's list; none left -> v = 1 with
   no ray (for the children too); one occluder whose plane separates p from q and that contains
   every crossing point of the segments between their vertices (the convex hull of all crossing
   points) -> v = 0 exactly, the link is dropped;
3. the oracle (radiosity.hierarchy.oracle): `ff` compares the centroid estimates of F_pq,
   F_qp with epsilon (Hanrahan et al. 1991); `gradient` weighs them by the nodes' size over
   their distance; `spread` (the default) by how much the estimate changes between a node's
   centroid and its vertices. Weighted (`weight: bf`) by the receiver's reflectance and an
   a-priori radiance of the source (emission plus an ambient estimate), or not (`none`). Above
   epsilon, or near (centroids closer than `near-field-factor` node sizes, size = sqrt(area)),
   the node that looks larger from the other is split, if it can be (seen originals down to
   their camera sub-elements, unseen ones down to `min-node-size`);
4. a kept link not proven visible gets k stratified sample rays (`link-rays`; k = 1: one ray
   between centroids, the seed's) -> v = the visible rays' share, each ray weighted by the
   point kernel between its end points (`kernel-weighted-rays`); a partly visible link
   (0 < v < 1) with error above `shadow-factor * epsilon` is split further while it can be.

Kept far links carry the exact form factor from the smaller node's centroid to the larger
node's polygon (`far-kernel: polygon`; or the point / disc kernel between centroids:
`centroid`); near leaf links with the -nf kernels the exact polygon-to-polygon form factor
(exact.py: Gauss points over the smaller node when it lies `near-gauss-gap` of its sizes away,
else the double contour integral). Rays are cast in batches between rounds of the depth-first
refinement (numba cannot call Embree): each round refines until every open link is kept or
waits for rays.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np

from radiosity import config
from radiosity.runtime.cluster import Scattered, scatterable
from radiosity.errors import RadiosityError
from radiosity.core.exact import _point_ff, _polygon_ff, point_ff
from radiosity.core.geometry import COS_TOL
from radiosity.scene.splittrees import MAX_DEPTH, _bit, polygon_area_center, split_one
from radiosity.runtime.monitor import Monitor, worker_address
from radiosity.runtime.runner import run_tasks
from radiosity.tracing.shafts import _faces, _same_side, _shaft_excludes, block_candidates, occluders

# counters of a link task
COUNTERS = ("pairs", "links", "evaluated", "refined", "dropped_orientation", "shaft_visible",
            "shaft_blocked", "ray_links", "rays", "ray_blocked", "partial_refined", "exact",
            "split_off_nodes", "rounds")
C_PAIRS, C_LINKS, C_EVAL, C_REFINED, C_ORIENT, C_SVIS, C_SBLOCK, C_RAYLINKS, C_RAYS, C_RBLOCK, \
    C_PARTIAL, C_EXACT, C_SPLITOFF, C_ROUNDS = range(len(COUNTERS))
WEIGHTS = ("none", "bf")
ORACLES = ("ff", "gradient", "spread")


FAR_KERNELS = ("centroid", "polygon", "gauss")


def _far_kernel(name: str) -> int:
    if name not in FAR_KERNELS:
        raise RadiosityError(f"radiosity.hierarchy.far-kernel must be one of "
                             f"{', '.join(FAR_KERNELS)}, got {name!r}")
    return FAR_KERNELS.index(name)


def _oracle_id(name: str) -> int:
    if name not in ORACLES:
        raise RadiosityError(f"radiosity.hierarchy.oracle must be one of {', '.join(ORACLES)}, "
                             f"got {name!r}")
    return ORACLES.index(name)


# ----------------------------------------------------------------------------- inputs

@dataclass(frozen=True)
class LinkParams:
    """The refinement settings (resolved on the driver).

    epsilon: oracle threshold; shadow: threshold for splitting partly visible links; near:
    near-field factor (node sizes); min_size: size limit (sqrt of area, scene units) for
    splitting unseen originals; rays: sample rays per link (1: centroids); kid: 0 point, 1 disc
    (kept far links); exact: kept near links get the exact polygon form factor; plane_tol:
    distance (scene units) within which a vertex counts as on a plane; occlusion: False when
    nothing can block (planner.py)."""

    epsilon: float
    shadow: float
    near: float
    min_size: float
    rays: int
    kid: int
    exact: bool
    plane_tol: float
    occlusion: bool = True
    oracle: int = 2
    gauss_gap: float = 2.0
    far_polygon: int = 1
    weighted_rays: bool = True

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@scatterable
class LinkInputs:
    """Read-only arrays every link task needs (scattered to the workers once).

    The partition's node table (hierarchy.TreeNodes, k nodes): t_verts (k, 4, 3), t_nverts (k,),
    t_area (k,), t_center (k, 3), t_lo / t_hi (k, 3) node boxes, t_child (k, 2), t_orig,
    t_depth (k,), t_path (k,) uint64. Per original (n): normal (n, 3), two_sided, root
    (partition node), wrho (n, 2) and lhat (n, 2) the oracle's weights per side, elo / ehi / enormal / eoffset / pad: padded
    occluder boxes and planes (shafts.occluders), verts / nverts: polygons (occluders and
    Embree), key: the Embree cache key; lref: the reference radiance of the weights. ext (k,):
    partition leaves that may be split on demand below the camera's partition: those no pixel
    hits (hit (m,) per sub-element), or without `hit` the one sub-element of an unseen
    original.
    """

    def __init__(self, tree, part, elements, seen, params: LinkParams, weight: str, key: str,
                 epsilon: float, hit: np.ndarray | None = None):
        self.t_verts = tree.verts
        self.t_nverts = tree.nverts.astype(np.int64)
        self.t_area = tree.area
        self.t_center = tree.center
        v = np.where(tree.nverts[:, None, None] == 3, tree.verts[:, [0, 1, 2, 2]], tree.verts)
        self.t_lo = v.min(axis=1)
        self.t_hi = v.max(axis=1)
        self.t_child = tree.child.astype(np.int64)
        self.t_orig = tree.orig.astype(np.int64)
        self.t_depth = tree.depth.astype(np.int64)
        self.t_path = tree.path
        n = len(elements)
        self.normal = elements.normal
        self.two_sided = elements.two_sided.astype(np.bool_)
        leaf = np.asarray(tree.leaf, np.int64)
        if hit is None:  # the unseen originals' one sub-element
            unseen = (~np.asarray(seen, bool)) & (np.diff(part.offsets) == 1)
            self.ext = (leaf >= 0) & unseen[tree.orig]
        else:  # every sub-element no pixel hits (hierarchy.split-hidden)
            self.ext = (leaf >= 0) & ~np.asarray(hit, bool)[np.maximum(leaf, 0)]
        self.root = part.root.astype(np.int64)
        self.wrho, self.lhat, self.lref = oracle_weights(elements, weight)
        self.elo, self.ehi, self.enormal, self.eoffset, self.pad = occluders(elements)
        self.verts = elements.verts
        self.nverts = elements.nverts
        self.envert = elements.nverts.astype(np.int64)
        self.key = key
        self.epsilon = float(epsilon)  # the rays' self-intersection offset (rays.caster_for)
        self.params = params
        self.n = n


def oracle_weights(elements, weight: str):
    """The oracle's weights: link p <- q counts F_pq * wrho[p, side] * lhat[q, side] / lref.

    none: all 1 (form factors alone). bf: wrho = the largest channel of the reflectance of that
    side; lhat = the largest channel of the emission plus an ambient estimate
    La = E rho / (1 - rho) (E, rho: area-weighted means over the scene); lref = E + La, the
    mean radiance one expects. Returns wrho (n, 2), lhat (n, 2), lref."""
    n = len(elements)
    if weight == "none":
        return np.ones((n, 2)), np.ones((n, 2)), 1.0
    if weight != "bf":
        raise RadiosityError(f"radiosity.hierarchy.weight must be one of {', '.join(WEIGHTS)}, "
                             f"got {weight!r}")
    A = elements.area
    rho = elements.reflectance.max(axis=2)   # (n, 2)
    em = elements.emission.max(axis=2)
    E = float((A * em.sum(axis=1)).sum() / A.sum())
    r = float(min((A * rho[:, 0]).sum() / A.sum(), 0.99))
    La = E * r / (1.0 - r)
    lref = E + La
    if lref <= 0:
        return np.ones((n, 2)), np.ones((n, 2)), 1.0
    return rho, em + La, lref


# ----------------------------------------------------------------------------- kernels

@numba.njit(cache=True)
def _grow(a, n):
    out = np.zeros((n,) + a.shape[1:], a.dtype)
    out[:a.shape[0]] = a
    return out


@numba.njit(cache=True)
def _blocks(o, V, p, nP, q, nQ, everts, envert, enormal, eoffset, pad, sp, sq):
    """Does occluder o alone cut every segment between polygons V[p, :nP] and V[q, :nQ]? Its
    plane must separate them strictly (beyond pad), and every crossing point of a segment
    between a vertex of P and one of Q must lie inside o (beyond pad): those points span the
    crossing set of all segments (it is conv(P u Q) cut by the plane), and o is convex.
    sp, sq: scratch (4,). Arrays and indices, no rows (shafts._faces: views cost)."""
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


@numba.njit(cache=True, inline="always")
def _pick(prefer, can_p, can_q, other):
    """Which node to split: the preferred one (1: q, 0: p) if it can, else the other if
    `other` (near links, the error oracles, epsilon = 0); -1: keep the link."""
    if prefer == 1:
        return 1 if can_q else (0 if other and can_p else -1)
    return 0 if can_p else (1 if other and can_q else -1)


@numba.njit(cache=True)
def _spread(V, x, nv, nx, ny, nz, C, y, mx, my, mz, As, fc):
    """The disc estimate F(v -> c) between the point c = C[y] (normal m, area As) and the
    vertices v of polygon V[x, :nv] (normal n), against its value fc at the polygon's centroid: (largest change, change
    of the mean). The first is how much a receiver's irradiance varies over it (first order,
    and what the centroids miss at grazing angles near a shared edge); the second the error of
    the centroid rule over a source (second order: the linear part averages out)."""
    big = 0.0
    mean = 0.0
    for i in range(nv):
        dx, dy, dz = C[y, 0] - V[x, i, 0], C[y, 1] - V[x, i, 1], C[y, 2] - V[x, i, 2]
        r2 = dx * dx + dy * dy + dz * dz + 1e-300
        a = max(nx * dx + ny * dy + nz * dz, 0.0)
        b = max(-(mx * dx + my * dy + mz * dz), 0.0)
        f = As * a * b / (r2 * (np.pi * r2 + As))
        big = max(big, abs(f - fc))
        mean += f
    return big, abs(mean / nv - fc)


G2 = 0.5 / np.sqrt(3.0)  # 2 x 2 Gauss-Legendre on [0, 1]: 0.5 -+ G2


@numba.njit(cache=True)
def near_ff(P, nP, Ap, gp, Q, nQ, Aq, gq, npx, npy, npz, nqx, nqy, nqz, gap_factor):
    """F_pq, F_qp of a near link, exact to quadrature accuracy: where the smaller polygon is
    farther from the larger one's box than gap_factor times its size, Lambert's exact
    point-to-polygon form factor (exact.py) integrated over the smaller one by Gauss rules
    (2 x 2 on a quad's bilinear map, 3 points on a triangle: smooth integrand there); otherwise
    (touching, or about to) the double contour integral (exact.py). gp, gq: +-1, the sides
    that face."""
    small_is_p = Ap <= Aq
    S, nS = (P, nP) if small_is_p else (Q, nQ)
    L, nL = (Q, nQ) if small_is_p else (P, nP)
    As, Al = (Ap, Aq) if small_is_p else (Aq, Ap)
    gap2 = 0.0
    for k in range(3):
        slo = shi = S[0, k]
        llo = lhi = L[0, k]
        for i in range(1, 4):
            slo, shi = min(slo, S[i, k]), max(shi, S[i, k])
            llo, lhi = min(llo, L[i, k]), max(lhi, L[i, k])
        d = max(llo - shi, slo - lhi, 0.0)
        gap2 += d * d
    if gap_factor >= 0.0 and gap2 <= gap_factor * gap_factor * As:
        f = _polygon_ff(P, nP, Q, nQ, True)
        return f, f * Ap / Aq
    n = np.empty(3)
    m = np.empty(3)  # the larger one's facing side: points behind it see none of it
    if small_is_p:
        n[0], n[1], n[2] = gp * npx, gp * npy, gp * npz
        m[0], m[1], m[2] = gq * nqx, gq * nqy, gq * nqz
    else:
        n[0], n[1], n[2] = gq * nqx, gq * nqy, gq * nqz
        m[0], m[1], m[2] = gp * npx, gp * npy, gp * npz
    m0 = m[0] * L[0, 0] + m[1] * L[0, 1] + m[2] * L[0, 2]
    x = np.empty(3)
    acc = 0.0
    wsum = 0.0
    if nS == 3:
        for j in range(3):
            u = 2.0 / 3.0 if j == 1 else 1.0 / 6.0
            v = 2.0 / 3.0 if j == 2 else 1.0 / 6.0
            for c in range(3):
                x[c] = S[0, c] + u * (S[1, c] - S[0, c]) + v * (S[2, c] - S[0, c])
            if m[0] * x[0] + m[1] * x[1] + m[2] * x[2] > m0:
                acc += _point_ff(x, n, L, nL)
            wsum += 1.0
    else:
        for j in range(4):
            u = 0.5 + (G2 if j // 2 else -G2)
            v = 0.5 + (G2 if j % 2 else -G2)
            # the Jacobian of the bilinear map at (u, v): |dx/du x dx/dv|
            du = (1 - v) * (S[1] - S[0]) + v * (S[2] - S[3])
            dv = (1 - u) * (S[3] - S[0]) + u * (S[2] - S[1])
            w = np.sqrt((du[1] * dv[2] - du[2] * dv[1]) ** 2 + (du[2] * dv[0] - du[0] * dv[2]) ** 2
                        + (du[0] * dv[1] - du[1] * dv[0]) ** 2)
            for c in range(3):
                x[c] = ((1 - u) * (1 - v) * S[0, c] + u * (1 - v) * S[1, c] + u * v * S[2, c]
                        + (1 - u) * v * S[3, c])
            if m[0] * x[0] + m[1] * x[1] + m[2] * x[2] > m0:
                acc += w * _point_ff(x, n, L, nL)
            wsum += w
    fs = acc / wsum if wsum > 0 else 0.0  # F from the smaller to the larger
    if small_is_p:
        return fs, fs * Ap / Aq
    return fs * Aq / Ap, fs


@numba.njit(cache=True)
def centroid_to_polygon(Lv, Ln, Lc, p, q, Ap, gp, Aq, gq, npx, npy, npz, nqx, nqy, nqz, S, Sc):
    """F_pq, F_qp of a far link (p, q): the exact form factor from a differential element at
    the smaller node's centroid Lc to the larger polygon Lv (Lambert's formula, exact.py), the
    other by reciprocity. Exact over the larger node: only the smaller one's extent is
    approximated (to second order), where the point kernel errs over both. S (4, 3), Sc
    (10, 3): scratch."""
    if Ap <= Aq:
        a, b, g, nx, ny, nz, mx, my, mz = p, q, gp, npx, npy, npz, gq * nqx, gq * nqy, gq * nqz
    else:
        a, b, g, nx, ny, nz, mx, my, mz = q, p, gq, nqx, nqy, nqz, gp * npx, gp * npy, gp * npz
    if mx * (Lc[a, 0] - Lv[b, 0, 0]) + my * (Lc[a, 1] - Lv[b, 0, 1]) \
            + mz * (Lc[a, 2] - Lv[b, 0, 2]) <= 0:
        return 0.0, 0.0
    for i in range(Ln[b]):
        for c in range(3):
            S[i, c] = Lv[b, i, c]
    f = point_ff(Lc[a, 0], Lc[a, 1], Lc[a, 2], g * nx, g * ny, g * nz, S, Ln[b], Sc)
    if Ap <= Aq:
        return f, f * Ap / Aq
    return f * Aq / Ap, f


@numba.njit(cache=True)
def _plane_range(nx, ny, nz, d0, V, x, nv):
    lo, hi = np.inf, -np.inf
    for i in range(nv):
        s = nx * V[x, i, 0] + ny * V[x, i, 1] + nz * V[x, i, 2] - d0
        lo = min(lo, s)
        hi = max(hi, s)
    return lo, hi


@numba.njit(cache=True)
def _new_node(x, verts, nv, orig, path, depth, pnode, can, Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld,
              Lch, Lpn, Lcan, c):
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


@numba.njit(cache=True)
def _copy_tree_node(x, t, t_verts, t_nverts, t_area, t_center, t_lo, t_hi, t_child, t_orig,
                    t_depth, t_path, ext, min_size, Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch,
                    Lpn, Lcan):
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


@numba.njit(cache=True)
def _refine_loop(st, sp_, sq_, sc0, sc1, sfr, stk_pool, base_end, kp, kq, kf, kv, ks, kx, wp, wq,
                 wc, wpool, Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan, pmap,
                 t_verts, t_nverts, t_area, t_center, t_lo, t_hi, t_child, t_orig, t_depth, t_path,
                 normal, two_sided, ext, wrho, lhat, lref, elo, ehi, everts, envert, enormal,
                 eoffset, pad, eps, shadow, near_f, min_size, kid, exact, plane_tol, oracle,
                 gauss_gap, far_polygon, counts):
    """refine's loop, until the stack is empty or an array is full (refine grows it and calls
    again; st: [ns, cnt, nk, nw, npool]). No array variable is reassigned here: in a loop that
    reassigns arrays numba updates each one's reference count (an atomic operation) on every
    iteration."""
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
    while ns > 0:
        # room for two new nodes, two stack entries, a kept link, a waiting link and its list
        if cnt + 4 > cap or ns + 4 > scap or nk >= kcap or nw >= wcap \
                or npool + (sc1[ns - 1] - sc0[ns - 1]) > wpool.shape[0]:
            break
        ns -= 1
        p, q, l0, l1, frac = sp_[ns], sq_[ns], sc0[ns], sc1[ns], sfr[ns]
        counts[2] += 1
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
            counts[4] += 1
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
        wpq = wrho[op, sp] * lhat[oq, sq] / lref
        wqp = wrho[oq, sq] * lhat[op, sp] / lref
        amount = max(fpq * wpq, fqp * wqp)  # weighted transfer (partly visible links)
        prefer = 1 if Aq >= Ap else 0       # the node that looks larger from the other
        near = np.sqrt(r2) < near_f * max(np.sqrt(Ap), np.sqrt(Aq))
        split = -1  # 0: split p, 1: split q
        if frac < 0.0:
            # 2. shafts: keep the occluders that may cut a segment between the node boxes
            for k in range(3):
                A[0, k], A[1, k] = Llo[p, k], Lhi[p, k]
                B[0, k], B[1, k] = Llo[q, k], Lhi[q, k]
            top = max(l1, base_end)
            m0 = top
            blocked = False
            for c in range(l0, l1):
                o = stk_pool[c]
                if _same_side(A, B, enormal, eoffset, o, pad) or \
                        _shaft_excludes(A, B, elo, ehi, o):
                    continue
                if _blocks(o, Lv, p, Ln[p], q, Ln[q], everts, envert, enormal, eoffset, pad, s4p,
                           s4q):
                    blocked = True
                    break
                stk_pool[m0] = o
                m0 += 1
            if blocked:
                counts[6] += 1
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
                        big, curv = _spread(Lv, p, Ln[p], gp * npx, gp * npy, gp * npz, Lc, q,
                                            gq * nqx, gq * nqy, gq * nqz, Aq, fpq)
                        ep = wpq * big
                        if Ap <= Aq or not far_polygon:
                            ep += max(wpq, wqp) * curv
                    if can_q:
                        big, curv = _spread(Lv, q, Ln[q], gq * nqx, gq * nqy, gq * nqz, Lc, p,
                                            gp * npx, gp * npy, gp * npz, Ap, fqp)
                        eq = wqp * big
                        if Aq < Ap or not far_polygon:
                            eq += max(wpq, wqp) * curv
                    err = max(ep, eq)
                if near or err > eps:
                    # the smaller node only when the larger cannot split and its own error is
                    # above epsilon (splitting a node below the other's size dilutes the error
                    # per link: many small links each under epsilon, summing to a large one)
                    other = eps <= 0.0 or (oracle == 2 and (ep if prefer == 1 else eq) > eps) \
                        or oracle == 1 or (near and oracle == 0)
                    split = _pick(prefer, can_p, can_q, other)
        elif 0.0 < frac < 1.0 and amount > shadow:
            split = _pick(prefer, can_p, can_q, oracle > 0 or eps <= 0.0)
            if split >= 0:
                counts[10] += 1
        if split >= 0:
            counts[3] += 1
            x = q if split == 1 else p
            if Lch[x, 0] < 0:  # make the children (partition's, or split off an unseen original)
                t = Lpn[x]
                if t >= 0 and t_child[t, 0] >= 0:
                    for h in range(2):
                        tc = t_child[t, h]
                        if pmap[tc] < 0:
                            pmap[tc] = cnt
                            _copy_tree_node(cnt, tc, t_verts, t_nverts, t_area, t_center, t_lo,
                                            t_hi, t_child, t_orig, t_depth, t_path, ext, min_size,
                                            Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan)
                            cnt += 1
                        Lch[x, h] = pmap[tc]
                else:
                    split_one(Lv[x], Ln[x], c0, c1)
                    d1 = Ld[x] + 1
                    for h in range(2):
                        path = Lp[x] | _bit(Ld[x]) if h == 1 else Lp[x]
                        cv = c1 if h == 1 else c0
                        _new_node(cnt, cv, Ln[x], Lo[x], path, d1, -1, False, Lv, Ln, La, Lc, Llo,
                                  Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan, cc)
                        Lcan[cnt] = np.sqrt(La[cnt]) > min_size and d1 < MAX_DEPTH
                        Lch[x, h] = cnt
                        cnt += 1
                    counts[12] += 2
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
        if not (_faces(normal, op, two_sided[op], dx, dy, dz, length)
                and _faces(normal, oq, two_sided[oq], -dx, -dy, -dz, length)):
            counts[4] += 1
            continue
        if frac < 0.0 and l1 > l0:  # wait for rays, with the filtered occluder list
            wp[nw], wq[nw] = p, q
            wc[nw, 0], wc[nw, 1] = npool, l1 - l0
            for c in range(l0, l1):
                wpool[npool] = stk_pool[c]
                npool += 1
            nw += 1
            continue
        v = 1.0 if frac < 0.0 else frac
        if frac < 0.0:
            counts[5] += 1
        if v <= 0.0:
            counts[9] += 1
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
            kf[nk, 0], kf[nk, 1] = centroid_to_polygon(Lv, Ln, Lc, p, q, Ap, gp, Aq, gq, npx, npy,
                                                       npz, nqx, nqy, nqz, S, Sc)
        elif kid == 0:
            w = g / (np.pi * r2 * r2)
            kf[nk, 0], kf[nk, 1] = w * Aq, w * Ap
        else:
            kf[nk, 0] = Aq * g / r2 / (np.pi * r2 + Aq)
            kf[nk, 1] = Ap * g / r2 / (np.pi * r2 + Ap)
        nk += 1
    st[0], st[1], st[2], st[3], st[4] = ns, cnt, nk, nw, npool


@numba.njit(cache=True)
def refine(e_p, e_q, e_c0, e_c1, e_frac, pool, base_end,
           Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan, cnt, pmap,
           t_verts, t_nverts, t_area, t_center, t_lo, t_hi, t_child, t_orig, t_depth, t_path,
           normal, two_sided, ext, wrho, lhat, lref, elo, ehi, everts, envert, enormal, eoffset,
           pad, eps, shadow, near_f, min_size, kid, exact, plane_tol, oracle, gauss_gap, far_polygon,
           counts):
    """One round of refinement from the entries (e_p, e_q local node ids; candidate occluders
    pool[e_c0:e_c1]; e_frac: the visible fraction measured by rays, or -1 not yet measured).

    The local node table (L*, cnt nodes; pmap: partition node -> local id) grows as nodes are
    split and is returned. Returns (local table..., cnt, kept links (kp, kq, kf (k, 2) F_pq F_qp,
    kv, ks (k, 2) sides, kx exact flag, nk), links waiting for rays (wp, wq, wc (w, 2) [start,
    length] into wpool, nw), wpool). The loop itself is _refine_loop."""
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
    maxlen = 0
    for i in range(e_p.shape[0]):
        maxlen = max(maxlen, e_c1[i] - e_c0[i])
    scap = e_p.shape[0] + 4 * (2 * MAX_DEPTH + 8)
    sp_ = np.empty(scap, np.int64)
    sq_ = np.empty(scap, np.int64)
    sc0 = np.empty(scap, np.int64)
    sc1 = np.empty(scap, np.int64)
    sfr = np.empty(scap)
    stk_pool = np.empty(base_end + (2 * MAX_DEPTH + 8) * maxlen + 1, np.int64)
    stk_pool[:base_end] = pool[:base_end]
    ns = 0
    for i in range(e_p.shape[0] - 1, -1, -1):  # reversed: the first entry is popped first
        sp_[ns] = e_p[i]
        sq_[ns] = e_q[i]
        sc0[ns] = e_c0[i]
        sc1[ns] = e_c1[i]
        sfr[ns] = e_frac[i]
        ns += 1
    st = np.array([ns, cnt, nk, nw, npool], np.int64)
    while True:
        _refine_loop(st, sp_, sq_, sc0, sc1, sfr, stk_pool, base_end, kp, kq, kf, kv, ks, kx, wp,
                     wq, wc, wpool, Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan, pmap,
                     t_verts, t_nverts, t_area, t_center, t_lo, t_hi, t_child, t_orig, t_depth,
                     t_path, normal, two_sided, ext, wrho, lhat, lref, elo, ehi, everts, envert,
                     enormal, eoffset, pad, eps, shadow, near_f, min_size, kid, exact, plane_tol,
                     oracle, gauss_gap, far_polygon, counts)
        ns, cnt, nk, nw, npool = st[0], st[1], st[2], st[3], st[4]
        if ns == 0:
            break
        if cnt + 4 > Lo.shape[0]:
            cap = 2 * Lo.shape[0]
            Lv, Ln, La, Lc = _grow(Lv, cap), _grow(Ln, cap), _grow(La, cap), _grow(Lc, cap)
            Llo, Lhi, Lo, Lp = _grow(Llo, cap), _grow(Lhi, cap), _grow(Lo, cap), _grow(Lp, cap)
            Ld, Lch, Lpn, Lcan = _grow(Ld, cap), _grow(Lch, cap), _grow(Lpn, cap), _grow(Lcan, cap)
        if ns + 4 > sp_.shape[0]:
            scap = 2 * sp_.shape[0]
            sp_, sq_, sc0, sc1, sfr = (_grow(sp_, scap), _grow(sq_, scap), _grow(sc0, scap),
                                       _grow(sc1, scap), _grow(sfr, scap))
        if nk >= kp.shape[0]:
            kcap = 2 * kp.shape[0]
            kp, kq, kf, kv, ks, kx = (_grow(kp, kcap), _grow(kq, kcap), _grow(kf, kcap),
                                      _grow(kv, kcap), _grow(ks, kcap), _grow(kx, kcap))
        if nw >= wp.shape[0]:
            wcap = 2 * wp.shape[0]
            wp, wq, wc = _grow(wp, wcap), _grow(wq, wcap), _grow(wc, wcap)
        while npool + (sc1[ns - 1] - sc0[ns - 1]) > wpool.shape[0]:
            wpool = _grow(wpool, 2 * wpool.shape[0])
    return (Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan, cnt,
            kp[:nk], kq[:nk], kf[:nk], kv[:nk], ks[:nk], kx[:nk],
            wp[:nw], wq[:nw], wc[:nw], wpool[:npool])


@numba.njit(cache=True)
def roots(pairs, root, pmap, t_verts, t_nverts, t_area, t_center, t_lo, t_hi, t_child, t_orig,
          t_depth, t_path, ext, min_size, Lv, Ln, La, Lc, Llo, Lhi, Lo, Lp, Ld, Lch, Lpn, Lcan,
          cnt, elo, ehi, enormal, eoffset, pad, occlusion):
    """The first entries of a task: the root link of each pair (I, J) with the occluders that
    may cut a segment between the two originals (shafts.block_candidates). Returns the
    entries (p, q, c0, c1), the pool, and the count of local nodes."""
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
                _copy_tree_node(cnt, r, t_verts, t_nverts, t_area, t_center, t_lo, t_hi, t_child,
                                t_orig, t_depth, t_path, ext, min_size, Lv, Ln, La, Lc, Llo, Lhi,
                                Lo, Lp, Ld, Lch, Lpn, Lcan)
                cnt += 1
            ends[h] = pmap[r]
        e_p[k], e_q[k] = ends[0], ends[1]
        for j in range(3):
            A[0, j], A[1, j] = Llo[ends[0], j], Lhi[ends[0], j]
            B[0, j], B[1, j] = Llo[ends[1], j], Lhi[ends[1], j]
        if occlusion:
            cand = block_candidates(A, B, elo, ehi, enormal, eoffset, pad, pairs[k, 0], pairs[k, 1])
        else:
            cand = np.zeros(0, np.int64)
        while npool + cand.shape[0] > pool.shape[0]:
            pool = _grow(pool, 2 * pool.shape[0])
        e_c0[k] = npool
        pool[npool:npool + cand.shape[0]] = cand
        npool += cand.shape[0]
        e_c1[k] = npool
    return e_p, e_q, e_c0, e_c1, pool[:npool], cnt


# ----------------------------------------------------------------------------- sample rays

def ray_pairing(k: int) -> np.ndarray:
    """The sample of Q each of the k = s^2 stratified points of P is paired with, (k,) int64:
    cell (i, j) of P with cell (j, i) of Q (s odd) or (j, (i + 2 j + 1) mod s) (s even). Both
    projections (u_P, u_Q) and (v_P, v_Q) of the 4-D sample set are then full s x s grids
    (stratified across a shadow boundary), and the set is symmetric under the central reflection
    of both polygons, so a symmetric half occlusion gets exactly half of the rays."""
    s = int(round(np.sqrt(k)))
    i, j = np.divmod(np.arange(k), s)
    second = i if s % 2 else (i + 2 * j + 1) % s
    return (j * s + second).astype(np.int64)


def triangle_strata(k: int) -> np.ndarray:
    """Barycentric (u, v) of the centroids of the s^2 equal sub-triangles of a triangle (the
    regular subdivision, as kernels.sample_points), (k, 2) float64, k = s^2."""
    s = int(round(np.sqrt(k)))
    uv = []
    for i in range(s):
        for j in range(s - i):
            uv.append(((i + 1 / 3) / s, (j + 1 / 3) / s))
            if i + j <= s - 2:
                uv.append(((i + 2 / 3) / s, (j + 2 / 3) / s))
    return np.array(uv, np.float64)


@numba.njit(cache=True)
def _strata(V, nv, s, tri_uv, out, at):
    """The k = s^2 stratified points of polygon V into out[at:at + k]: a quad's s x s cell
    centres of its bilinear map, a triangle's sub-triangle centroids."""
    k = s * s
    for j in range(k):
        if nv == 3:
            u, v = tri_uv[j, 0], tri_uv[j, 1]
            for c in range(3):
                out[at + j, c] = V[0, c] + u * (V[1, c] - V[0, c]) + v * (V[2, c] - V[0, c])
        else:
            u = ((j // s) + 0.5) / s
            v = ((j % s) + 0.5) / s
            for c in range(3):
                out[at + j, c] = ((1 - u) * (1 - v) * V[0, c] + u * (1 - v) * V[1, c]
                                  + u * v * V[2, c] + (1 - u) * v * V[3, c])


@numba.njit(cache=True)
def link_points(Lv, Ln, Lc, Lo, p, q, s, tri_uv, perm):
    """Ray end points of links (p, q): (2 n k, 3) points (the k samples of each p, then the k
    samples of each q in the order perm pairs them with p's) and their originals (2 n k,)."""
    n = p.shape[0]
    k = s * s
    pts = np.empty((2 * n * k, 3))
    orig = np.empty(2 * n * k, np.int64)
    tmp = np.empty((k, 3))
    for i in range(n):
        if k == 1:
            pts[i] = Lc[p[i]]
            pts[n + i] = Lc[q[i]]
        else:
            _strata(Lv[p[i]], Ln[p[i]], s, tri_uv, pts, i * k)
            _strata(Lv[q[i]], Ln[q[i]], s, tri_uv, tmp, 0)
            for j in range(k):
                pts[n * k + i * k + j] = tmp[perm[j]]
        for j in range(k):
            orig[i * k + j] = Lo[p[i]]
            orig[n * k + i * k + j] = Lo[q[i]]
    return pts, orig


@numba.njit(cache=True)
def _weighted(occ, pts, e, normal, n, k):
    """Kernel-weighted visible fraction of each link: sum_j K_j V_j / sum_j K_j over its k
    rays, K_j = |cos_a cos_b| / r^4 of the sample pair (unnormalised cosines), (n,)."""
    out = np.empty(n)
    for i in range(n):
        num = 0.0
        den = 0.0
        for j in range(k):
            a = i * k + j
            b = n * k + a
            dx = pts[b, 0] - pts[a, 0]
            dy = pts[b, 1] - pts[a, 1]
            dz = pts[b, 2] - pts[a, 2]
            r2 = dx * dx + dy * dy + dz * dz + 1e-300
            ca = normal[e[a], 0] * dx + normal[e[a], 1] * dy + normal[e[a], 2] * dz
            cb = normal[e[b], 0] * dx + normal[e[b], 1] * dy + normal[e[b], 2] * dz
            w = abs(ca * cb) / (r2 * r2)
            den += w
            if not occ[a]:
                num += w
        out[i] = num / den if den > 0 else 0.0
    return out


def link_fractions(caster, k: int, verts: np.ndarray, nverts: np.ndarray, center: np.ndarray,
                   orig: np.ndarray, p: np.ndarray, q: np.ndarray, keep: list | None = None,
                   normal: np.ndarray | None = None):
    """Visible fraction of links (p, q) (node ids into verts (N, 4, 3), nverts, center (N, 3),
    orig (N,)), with k rays each: k = 1 one ray between centroids; k = s^2 between the s x s
    stratified points of each node (link_points) paired by ray_pairing. Returns (w,) float64."""
    if len(p) == 0:
        return np.zeros(0)
    s = int(round(np.sqrt(k)))
    tri_uv, perm = triangle_strata(k), ray_pairing(k)
    out = np.empty(len(p))
    step = max(1, (1 << 19) // k)
    for a in range(0, len(p), step):
        pp, qq = p[a:a + step], q[a:a + step]
        n = len(pp) * k
        pts, e = link_points(verts, nverts, center, orig, pp, qq, s, tri_uv, perm)
        idx = np.arange(n)
        if keep is not None:
            keep.append((pts, e))
        occ = caster.occluded_pairs(pts, idx, idx + n, e)
        if normal is None or k == 1:
            out[a:a + len(pp)] = 1.0 - occ.reshape(len(pp), k).mean(axis=1)
        else:
            out[a:a + len(pp)] = _weighted(occ, pts, e, normal, len(pp), k)
    return out


# ----------------------------------------------------------------------------- the task

class _Table:
    """A task's local node table (grows inside refine)."""

    FIELDS = ("Lv", "Ln", "La", "Lc", "Llo", "Lhi", "Lo", "Lp", "Ld", "Lch", "Lpn", "Lcan")

    def __init__(self, cap: int):
        self.Lv = np.zeros((cap, 4, 3))
        self.Ln = np.zeros(cap, np.int64)
        self.La = np.zeros(cap)
        self.Lc = np.zeros((cap, 3))
        self.Llo = np.zeros((cap, 3))
        self.Lhi = np.zeros((cap, 3))
        self.Lo = np.zeros(cap, np.int64)
        self.Lp = np.zeros(cap, np.uint64)
        self.Ld = np.zeros(cap, np.int64)
        self.Lch = np.full((cap, 2), -1, np.int64)
        self.Lpn = np.full(cap, -1, np.int64)
        self.Lcan = np.zeros(cap, np.bool_)
        self.cnt = 0

    def arrays(self):
        return tuple(getattr(self, f) for f in self.FIELDS)

    def update(self, arrays, cnt):
        for f, a in zip(self.FIELDS, arrays):
            setattr(self, f, a)
        self.cnt = int(cnt)


def _tree_args(inp: LinkInputs):
    return (inp.t_verts, inp.t_nverts, inp.t_area, inp.t_center, inp.t_lo, inp.t_hi, inp.t_child,
            inp.t_orig, inp.t_depth, inp.t_path)


def refine_pairs(inp: LinkInputs, pairs: np.ndarray, caster, keep_rays: list | None = None,
                 polygons: bool = False):
    """All links of the original pairs (t, 2) [I, J]: the rounds of `refine` with the rays cast
    between them. Returns (links (k,) store.LINK_DTYPE, split-off nodes (j,) store.NODE_DTYPE,
    counts (len(COUNTERS),) int64), and with `polygons` the split-off nodes' polygons (j, 4, 3)
    as this task made them. keep_rays: a list that receives every batch of rays as the
    (points, originals) given to the caster (benchmarks only)."""
    from radiosity.scene.splittrees import heap_code
    from radiosity.methods.hierarchical.store import LINK_DTYPE, NODE_DTYPE

    prm = inp.params
    counts = np.zeros(len(COUNTERS), np.int64)
    counts[C_PAIRS] = len(pairs)
    tab = _Table(max(64, 4 * len(pairs)))
    pmap = np.full(len(inp.t_orig), -1, np.int64)
    pairs = np.ascontiguousarray(pairs, np.int64).reshape(-1, 2)
    *ent, pool, cnt = roots(pairs, inp.root, pmap, *_tree_args(inp), inp.ext, prm.min_size,
                            *tab.arrays(), tab.cnt, inp.elo, inp.ehi, inp.enormal, inp.eoffset,
                            inp.pad, prm.occlusion)
    tab.cnt = int(cnt)
    frac = np.full(len(pairs), -1.0)
    kept = []
    while len(ent[0]):
        counts[C_ROUNDS] += 1
        out = refine(*ent, frac, pool, len(pool), *tab.arrays(), tab.cnt, pmap, *_tree_args(inp),
                     inp.normal, inp.two_sided, inp.ext, inp.wrho, inp.lhat, inp.lref, inp.elo,
                     inp.ehi, inp.verts, inp.envert, inp.enormal, inp.eoffset,
                     inp.pad, prm.epsilon, prm.shadow, prm.near, prm.min_size, prm.kid,
                     prm.exact, prm.plane_tol, prm.oracle, prm.gauss_gap, prm.far_polygon, counts)
        tab.update(out[:12], out[12])
        kept.append(out[13:19])
        wp, wq, wc, wpool = out[19:]
        if not len(wp):
            break
        f = link_fractions(caster, prm.rays, tab.Lv, tab.Ln, tab.Lc, tab.Lo, wp, wq, keep_rays,
                           inp.normal if prm.weighted_rays else None)
        counts[C_RAYLINKS] += len(wp)
        counts[C_RAYS] += len(wp) * prm.rays
        ent = [wp, wq, wc[:, 0].copy(), (wc[:, 0] + wc[:, 1]).copy()]
        frac = f
        pool = wpool
    kp, kq, kf, kv, ks, kx = (np.concatenate(c) for c in zip(*kept))
    counts[C_EXACT] = int(kx.sum())
    links = np.zeros(len(kp), LINK_DTYPE)
    links["po"], links["pc"] = tab.Lo[kp], heap_code(tab.Lp[kp], tab.Ld[kp])
    links["qo"], links["qc"] = tab.Lo[kq], heap_code(tab.Lp[kq], tab.Ld[kq])
    links["fpq"], links["fqp"] = kf[:, 0], kf[:, 1]
    links["v"] = kv
    links["sp"], links["sq"] = ks[:, 0], ks[:, 1]
    counts[C_LINKS] = len(links)
    # split-off nodes the links use (the node table adds their ancestors and siblings)
    used = np.unique(np.concatenate([kp, kq]))
    used = used[tab.Lpn[used] < 0]
    nodes = np.zeros(len(used), NODE_DTYPE)
    nodes["o"], nodes["c"] = tab.Lo[used], heap_code(tab.Lp[used], tab.Ld[used])
    if polygons:
        return links, nodes, counts, tab.Lv[used].copy()
    return links, nodes, counts


def task_links(inp: LinkInputs, pairs: np.ndarray, store_path: str, task: int) -> dict:
    """One link task: refine the pairs, write the links and split-off nodes into the store,
    return {crc, n, nx, counts, start, stop, worker, nodes}."""
    from radiosity.tracing.rays import caster_for
    from radiosity.methods.hierarchical.store import write_links

    t0 = time.time()
    c0 = time.thread_time()
    caster = caster_for(inp.key, inp.verts, inp.nverts, inp.epsilon)
    links, nodes, counts = refine_pairs(inp, pairs, caster)
    c1, w1 = time.thread_time(), time.time()
    out = write_links(store_path, task, links, nodes)
    out.update({"counts": counts, "start": t0, "stop": time.time(), "worker": worker_address(),
                "nodes": nodes,  # for the node table, without reading them back
                "cpu": (c1 - c0, time.thread_time() - c1, w1 - t0)})  # refine + rays, write
    return out


# ----------------------------------------------------------------------------- the plan (pure)

def link_plan(offsets: np.ndarray, bi: np.ndarray, bj: np.ndarray, unit: str, max_task_cost: int,
              min_tasks: int = 16):
    """The link tasks: the pairs I < J that face each other both ways (bi, bj sorted by (I, J),
    originals.facing_pairs), in I-major order; unit 'block': one task per pair; 'stripe':
    consecutive pairs, cut so that no task costs more than max_task_cost nor more than 1 /
    min_tasks of the whole (estimated cost of a pair: the sub-elements of both). Returns pairs
    (t, 2) int64, first (k + 1,) int64 (task k holds pairs first[k]:first[k+1]), cost (k,)
    int64."""
    size = np.diff(offsets)
    pairs = np.stack([np.asarray(bi, np.int64), np.asarray(bj, np.int64)], 1).reshape(-1, 2)
    pc = size[pairs[:, 0]] + size[pairs[:, 1]]
    if unit == "block":
        first = np.arange(len(pairs) + 1, dtype=np.int64)
    elif unit == "stripe":
        # consecutive pairs share a task up to the cost cap, across originals too (thousands
        # of small originals would otherwise be thousands of tasks at ~50 ms each), and the cap
        # leaves at least `min_tasks` tasks for the master to balance
        cap = max(1, min(max_task_cost, int(pc.sum()) // max(1, min_tasks)))
        starts = [0]
        acc = 0
        for k in range(len(pairs)):
            if k > 0 and acc + pc[k] > cap:
                starts.append(k)
                acc = 0
            acc += int(pc[k])
        first = np.array(starts + [len(pairs)], np.int64) if len(pairs) else np.zeros(1, np.int64)
    else:
        raise ValueError(f"task unit must be block or stripe, got {unit!r}")
    cum = np.concatenate([[0], np.cumsum(pc)])
    cost = (cum[first[1:]] - cum[first[:-1]]).astype(np.int64)
    return pairs, first, cost


# ----------------------------------------------------------------------------- the master

def choose_epsilon(epsilon: float | str | None = None, pixels: int | None = None) -> tuple[float, str]:
    """The links' epsilon and why: a number (argument or radiosity.hierarchy.epsilon) as given;
    `auto`: epsilon-base for a criterion raster of up to epsilon-resolution^2 pixels, times
    epsilon-resolution / sqrt(pixels) above. A link's error estimate is first order in its
    nodes' size and the leaves shrink like 1 / sqrt(pixels): at a fixed epsilon a finer image
    keeps the same links over smaller leaves, so its error stops falling (MEASURED in
    radiosity.yaml). pixels None (before the camera's raster exists): the base."""
    v = config.get("hierarchy.epsilon", epsilon)
    if v != "auto":
        try:
            eps = float(v)
        except (TypeError, ValueError):
            raise RadiosityError(f"radiosity.hierarchy.epsilon must be a number >= 0 or auto, "
                                 f"got {v!r}") from None
        if not eps >= 0:
            raise RadiosityError(f"--epsilon must be >= 0, got {eps}")
        return eps, "stated"
    base = float(config.get("hierarchy.epsilon-base"))
    res0 = float(config.get("hierarchy.epsilon-resolution"))
    if not (base >= 0 and res0 > 0):
        raise RadiosityError(f"radiosity.hierarchy.epsilon-base must be >= 0 and epsilon-resolution "
                             f"> 0, got {base} and {res0}")
    r = float(np.sqrt(pixels)) if pixels else 0.0
    if r <= res0:
        return base, f"auto: {base:g} up to {res0:g}^2 pixels"
    return base * res0 / r, (f"auto: {base:g} x {res0:g} / {r:.0f} (finer leaves than at "
                             f"{res0:g}^2 pixels get finer links)")


def resolve_params(elements, kernel: str | None = None, epsilon: float | None = None,
                   rays: int | None = None, occlusion: bool = True) -> tuple[LinkParams, str]:
    """The link settings from radiosity.hierarchy.* (arguments win), checked; returns
    (LinkParams, weight). epsilon `auto` (the default): choose_epsilon's base; compute_links
    passes the value for the run's raster."""
    from radiosity.core.kernels import KERNELS, base_kernel, kernel_id

    kernel = config.get("hierarchy.kernel", kernel)
    kernel_id(kernel)
    if base_kernel(kernel) not in ("point", "disc"):
        raise RadiosityError(f"--method hierarchical supports the kernels point, disc, point-nf "
                             f"and disc-nf (links sample their own rays: --link-rays), not {kernel!r}")
    eps, _ = choose_epsilon(epsilon)
    k = int(config.get("hierarchy.link-rays", rays))
    if k < 1 or int(round(np.sqrt(k))) ** 2 != k:
        raise RadiosityError(f"--link-rays must be a square (1, 4, 9, 16, ...), got {k}")
    weight = config.get("hierarchy.weight")
    if weight not in WEIGHTS:
        raise RadiosityError(f"radiosity.hierarchy.weight must be one of {', '.join(WEIGHTS)}, "
                             f"got {weight!r}")
    v = elements.verts.reshape(-1, 3)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    prm = LinkParams(epsilon=eps, shadow=eps * float(config.get("hierarchy.shadow-factor")),
                     near=float(config.get("solve.near-field-factor")),
                     min_size=float(config.get("hierarchy.min-node-size")) * diag, rays=k,
                     kid=0 if base_kernel(kernel) == "point" else 1,
                     exact=bool(KERNELS[kernel].near_field), plane_tol=COS_TOL * diag,
                     occlusion=bool(occlusion),
                     oracle=_oracle_id(config.get("hierarchy.oracle")),
                     gauss_gap=float(config.get("hierarchy.near-gauss-gap")),
                     far_polygon=_far_kernel(config.get("hierarchy.far-kernel")),
                     weighted_rays=bool(config.get("hierarchy.kernel-weighted-rays")))
    return prm, weight


def links_rows(fig: dict) -> list[tuple[str, object]]:
    """The CLI summary rows of the link stage's figures (report.json section "links")."""
    return [("sub-elements", f"{fig['sub_elements']} ({fig['leaves']} leaves, "
                             f"{fig['split_off_nodes']} nodes split below the camera's partition)"),
            ("epsilon", f"{fig['epsilon']:.3g} ({fig.get('epsilon_reason', 'stated')})"),
            ("links", f"{fig['links']} ({fig['links_per_leaf']:.1f} per leaf, "
                      f"{fig['bytes_per_link']} bytes each)"),
            ("proven by shafts", f"{fig['shaft_visible']} visible, {fig['shaft_blocked']} "
                                 "blocked (no ray)"),
            ("rays cast", f"{fig['rays']} ({fig['link_rays']} per link on {fig['ray_links']} links)"),
            ("tasks", f"{fig['tasks']} ({fig['task_unit']}), {fig['tasks_reused']} reused"),
            ("time", f"{fig['time_s']:.2f} s")]


def compute_links(run_dir: str, client, kernel: str | None = None, epsilon: float | None = None,
                  rays: int | None = None, unit: str | None = None, resume: bool = False,
                  progress: bool = True, on_done=None, occlusion: bool = True) -> dict:
    """The link stage through the one runner (runner.py): a bounded window of link tasks per
    worker thread, most expensive first, failed tasks resubmitted, every finished task recorded
    with its crc so `resume` recomputes only what is missing or corrupted; then the node table
    of the union tree. Writes section "links" of report.json and returns its figures."""
    from dask.base import tokenize

    from radiosity.scene.splittrees import node_table, seen_originals, tree_nodes
    from radiosity.runtime.monitor import peak_rss_mb
    from radiosity.scene.originals import pairs_within_budget, tree_of
    from radiosity.methods.pairs.plan import choose_unit
    from radiosity.methods.hierarchical.store import LINK_DTYPE, LinkStore, read_links
    from radiosity.runtime.store import RunStore, update_report

    t_start = time.perf_counter()
    rs = RunStore(run_dir, "r+")
    part = rs.load_partition()
    el = rs.load_elements()
    raster = rs.read_arrays("raster")  # orig, sub: (H, W) per criterion pixel
    eps, eps_why = choose_epsilon(epsilon, raster["orig"].size)
    prm, weight = resolve_params(el, kernel, eps, rays, occlusion)
    unit = config.get("hierarchy.task-unit", unit)
    if unit == "auto":
        unit = choose_unit(config.get("visibility.task-unit"), len(el),
                           int(config.get("visibility.stripe-threshold")))
    otree = tree_of(el, int(config.get("plan.leaf-size")))
    bi, bj, _ = pairs_within_budget(otree, int(float(config.get("plan.max-facing-pairs"))),
                                    rs.attrs.get("scene") or run_dir)
    pairs, first, cost = link_plan(part.offsets, bi, bj, unit,
                                   int(config.get("hierarchy.max-task-cost")))
    seen = seen_originals(raster["orig"], len(el))
    hit = None
    if config.get("hierarchy.split-hidden"):
        sub = raster["sub"]
        hit = np.zeros(len(part), bool)
        hit[sub[sub >= 0]] = True
    token = tokenize(pairs, first, part.center, part.offsets, el.verts, el.reflectance,
                     el.emission, seen, hit, prm.to_dict(), weight, config.get("rays.epsilon"))
    ls = LinkStore(rs)
    done, corrupted = {}, 0
    if resume and ls.token() == token:
        done = ls.finished(token)
        good = {t: e for t, e in done.items() if ls.verify(t, e)}
        corrupted = len(done) - len(good)
        done = good
        ls.rewrite_manifest(token, done)  # a torn or corrupted line is never trusted again
    else:
        rs.drop_after("raster")
        ls.create(pairs, first, token, {"params": prm.to_dict(), "weight": weight,
                                        "kernel": config.get("hierarchy.kernel", kernel),
                                        "unit": unit})
    tree = tree_nodes(part, el)
    key = tokenize(el.verts, el.nverts)
    inp = LinkInputs(tree, part, el, seen, prm, weight, key, float(config.get("rays.epsilon")),
                     hit)
    ntasks = len(first) - 1
    todo = [t for t in range(ntasks) if t not in done]
    threads = sum(client.nthreads().values()) or 1
    counts = np.zeros(len(COUNTERS), np.int64)
    for e in done.values():
        counts += np.asarray(e["counts"], np.int64)
    busy: dict = {}
    cpu = [0.0, 0.0, 0.0]  # tasks' thread CPU: refinement + rays, store writes; refinement's wall
    computed = [0]
    mon = Monitor(client)
    mon.stage("links", run_dir)
    mon.links(pairs, first, done, len(el), force=True)

    def finished(task, res):
        nonlocal counts
        ls.record(task, res)  # in the manifest only after its bytes were written
        done[task] = res
        mon.links(pairs, first, done, len(el))
        computed[0] += 1
        counts += res["counts"]
        busy[res["worker"]] = busy.get(res["worker"], 0.0) + (res["stop"] - res["start"])
        for k, v in enumerate(res["cpu"]):
            cpu[k] += v
        if on_done is not None:
            on_done(computed[0])

    t_loop = time.perf_counter()
    if todo:
        shared = Scattered(client, inp)
        run_tasks(client, task_links, todo,
                  lambda task: (shared.future(), pairs[first[task]:first[task + 1]], rs.path, task),
                  name="links", token=tokenize(token, rs.path), cost=cost,
                  window=max(1, int(config.get("visibility.window-per-worker")) * threads),
                  retries=int(config.get("visibility.retries")), on_result=finished,
                  progress=progress, done=len(done),
                  repair=f"rerun with: radiosity visibility {run_dir} --method hierarchical --resume")
    mon.links(pairs, first, done, len(el), force=True)
    wall = time.perf_counter() - t_loop
    # the node table: the partition's trees and every node split off an unseen original
    t_nodes = time.perf_counter()
    xs = [done[t]["nodes"] if "nodes" in done[t] else read_links(rs.path, t, done[t])[1]
          for t in range(ntasks) if done[t]["nx"]]
    xn = np.concatenate(xs) if xs else np.zeros(0, [("o", "<i4"), ("c", "<u8")])
    table = node_table(tree, part, xn["o"], xn["c"])
    ls.write_nodes(table.arrays(), {"token": token})
    t_nodes = time.perf_counter() - t_nodes
    c = dict(zip(COUNTERS, counts.tolist()))
    nworkers = len(client.scheduler_info()["workers"]) or 1
    figures = {
        "method": "hierarchical", "task_unit": unit, "tasks": int(ntasks),
        "tasks_computed": computed[0], "tasks_reused": int(ntasks - computed[0]),
        "tasks_corrupted_recomputed": corrupted, "sub_elements": len(part),
        "nodes": len(table), "leaves": table.leaves,
        "split_off_nodes": int(np.count_nonzero(table.pnode < 0)),
        "originals_split": int(len(np.unique(xn["o"]))),  # below the camera's partition
        **c, "links_per_leaf": c["links"] / max(1, table.leaves),
        "bytes_per_link": LINK_DTYPE.itemsize, "link_bytes": c["links"] * LINK_DTYPE.itemsize,
        "epsilon": prm.epsilon, "epsilon_reason": eps_why, "link_rays": prm.rays, "weight": weight,
        "min_node_size": prm.min_size, "kernel": config.get("hierarchy.kernel", kernel),
        "time_s": round(time.perf_counter() - t_start, 4), "time_tasks_s": round(wall, 4),
        "time_node_table_s": round(t_nodes, 4),
        "rays_per_s": c["rays"] / wall if wall > 0 else 0.0,
        "busy_s_per_worker": {str(k): round(v, 4) for k, v in busy.items()},
        "cpu_refine_s": round(cpu[0], 4), "cpu_write_s": round(cpu[1], 4), "wall_refine_s": round(cpu[2], 4),
        "idle_fraction": (1.0 - sum(busy.values()) / (nworkers * wall)) if wall > 0 and busy else None,
        "workers": nworkers, "occlusion": occlusion, "peak_rss_mb": peak_rss_mb(client),
    }
    update_report(run_dir, "links", figures)
    return figures
