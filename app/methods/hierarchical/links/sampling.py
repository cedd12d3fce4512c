"""The sample rays of a link (SPEC §8): k = s^2 stratified points on each node, paired so that
both projections of the 4-D sample set are full grids (ray_pairing), cast in batches between
rounds of the refinement (numba cannot call Embree); a link's visible fraction is the visible
rays' share, each ray weighted by the point kernel between its end points or not."""

from __future__ import annotations

import numba
import numpy as np

from radiosity.tracing.shafts import clear_of


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


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
def clear_pairs(verts, nverts, p, q, lo, hi):
    """(len(p),) bool: the links (p, q) (node ids into verts (N, 4, 3), nverts) that no
    segment between their polygons can block: shafts.clear_of of the polygons' boxes against
    the occluder boxes lo, hi (RayCaster.occluder_boxes)."""
    out = np.zeros(p.shape[0], np.bool_)
    A = np.empty((2, 3))
    B = np.empty((2, 3))
    for a in range(p.shape[0]):
        _polygon_box(verts, nverts, p[a], A)
        _polygon_box(verts, nverts, q[a], B)
        out[a] = clear_of(A, B, lo, hi)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _polygon_box(verts, nverts, x, out):
    """out (2, 3): the box of polygon x's nverts[x] vertices."""
    for c in range(3):
        out[0, c] = verts[x, 0, c]
        out[1, c] = verts[x, 0, c]
        for v in range(1, nverts[x]):
            out[0, c] = min(out[0, c], verts[x, v, c])
            out[1, c] = max(out[1, c], verts[x, v, c])


@numba.njit(cache=True, nogil=True)
def _fractions(occ, pts, e, normal, n, k, void, weighted):
    """Visible fraction of each link from its k rays, (n,): with `weighted`, sum_j K_j V_j /
    sum_j K_j, K_j = |cos_a cos_b| / r^4 of the sample pair (unnormalised cosines), else the
    visible rays' share. Rays with an end inside a solid (void) are left out, unless all are."""
    out = np.empty(n)
    for i in range(n):
        num = 0.0
        den = 0.0
        all_void = True
        for j in range(k):
            a = i * k + j
            if not (void[a] or void[n * k + a]):
                all_void = False
        for j in range(k):
            a = i * k + j
            b = n * k + a
            if not all_void and (void[a] or void[b]):
                continue
            w = 1.0
            if weighted:
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


class SolidPoints:
    """Which of each local node's k sample points lie inside a solid (contact.inside_solid),
    found once per node of a link task's table, and only for nodes of links that have a blocked
    ray: a node straddling the footprint of a block standing on it (a floor node) starts some
    of its rays under the block, where they are all blocked; they are left out of its links'
    visible fractions (docs/src/design/methods-hierarchical-rounds.md#inside-solids)."""

    def __init__(self, caster, normal: np.ndarray, two_sided: np.ndarray):
        self.caster, self.normal, self.two_sided = caster, normal, two_sided
        self.mask = np.full(0, -1, np.int64)  # per local node: bit j = point j inside; -1 unknown

    def void(self, verts, nverts, center, orig, p, q, occ, s, tri_uv, perm) -> np.ndarray:
        """(2 n k,) bool: the rays' ends (link_points' order) inside a solid, for links (p, q)
        with some rays blocked and some not (occ (n k,)); False elsewhere: a link whose rays are
        all blocked has v = 0 whichever are left out (_fractions counts only the visible ones),
        and in a mesh of small triangles most links the refinement hands to rays are."""
        from radiosity.scene.contact import inside_solid

        n, k = len(p), s * s
        void = np.zeros(2 * n * k, np.bool_)
        blocked = occ.reshape(n, k).sum(axis=1)
        hit = np.nonzero((blocked > 0) & (blocked < k))[0]
        if not len(hit) or k > 62:
            return void
        if len(self.mask) < len(verts):
            grown = np.full(len(verts), -1, np.int64)
            grown[:len(self.mask)] = self.mask
            self.mask = grown
        nodes = np.unique(np.concatenate([p[hit], q[hit]]))
        new = nodes[self.mask[nodes] < 0]
        if len(new):
            pts, e = link_points(verts, nverts, center, orig, new, new, s, tri_uv, perm)
            pts, e = pts[:len(new) * k], e[:len(new) * k]
            one = ~self.two_sided[e]
            ins = np.zeros(len(e), bool)
            ins[one] = inside_solid(self.caster, pts[one], self.normal[e[one]], self.two_sided)
            self.mask[new] = (ins.reshape(len(new), k) << np.arange(k)).sum(axis=1)
        bits = np.arange(k)
        mp = self.mask[p[hit]][:, None] >> bits[None, :] & 1
        mq = self.mask[q[hit]][:, None] >> perm[None, :] & 1
        vp = void[:n * k].reshape(n, k)
        vq = void[n * k:].reshape(n, k)
        vp[hit] = mp > 0
        vq[hit] = mq > 0
        return void


def link_fractions(caster, k: int, verts: np.ndarray, nverts: np.ndarray, center: np.ndarray,
                   orig: np.ndarray, p: np.ndarray, q: np.ndarray, keep: list | None = None,
                   normal: np.ndarray | None = None, solid: SolidPoints | None = None,
                   clear: np.ndarray | None = None):
    """Visible fraction of links (p, q) (node ids into verts (N, 4, 3), nverts, center (N, 3),
    orig (N,)), with k rays each: k = 1 one ray between centroids; k = s^2 between the s x s
    stratified points of each node (link_points) paired by ray_pairing; rays weighted by the
    point kernel with `normal` (per original); with `solid`, rays from points inside a solid
    left out (SolidPoints); the rays of the links `clear` (n,) bool (clear_pairs) not cast,
    every one of them visible. Returns (w,) float64."""
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
        if clear is None or not clear[a:a + step].any():
            occ = caster.occluded_pairs(pts, idx, idx + n, e)
        else:
            occ = np.zeros(n, np.bool_)
            cast = np.nonzero(np.repeat(~clear[a:a + step], k))[0]
            if len(cast):
                occ[cast] = caster.occluded_pairs(pts, cast, cast + n, e)
        if (normal is None or k == 1) and solid is None:
            out[a:a + len(pp)] = 1.0 - occ.reshape(len(pp), k).mean(axis=1)
            continue
        void = (solid.void(verts, nverts, center, orig, pp, qq, occ, s, tri_uv, perm)
                if solid is not None and k > 1 else np.zeros(2 * n, np.bool_))
        out[a:a + len(pp)] = _fractions(occ, pts, e, normal if normal is not None
                                        else np.zeros((1, 3)), len(pp), k, void,
                                        normal is not None and k > 1)
    return out
