"""Radiance at any point of a solved run, for views the solution was not refined for (issue 28):
each point is located in the leaves of the union tree and gathers over the links into its leaf
and the leaf's ancestors, with the exact point-to-polygon form factor from the point itself (the
exact final gather of solve/passes.final_gather, at points instead of leaf centroids). A region
the first camera left coarse thus gets the light that reaches each of its points, not its
leaf's mean: no re-solve, no new links; cluster links add their final gather at each leaf's
centroid (as the render's image).
The points gathered at are the nodes of a lattice on each original's plane (about
LATTICE_PIXELS pixels apart, dyadic levels that nest), interpolated bilinearly at the view's
points: a PointGather keeps them, so the frames of a walkthrough gather each node once.
A run solved with direct light at points (SPEC §10: the solution's attrs say direct =
points, its leaves hold R = L1 + Lr) is gathered the same way over R, and each point adds its
own first bounce rho / pi H1(x), shadow rays from the point itself (scene/direct.DirectLight):
the gathered light after the first bounce is smooth, the shadows stay as sharp as the pixels.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from radiosity.core.exact import point_ff
from radiosity.scene.direct import DirectLight
from radiosity.scene.emitters import AreaEmitters


@numba.njit(cache=True, nogil=True)
def _inside(p, V, nv, n) -> bool:
    """p in the convex polygon V[:nv] (plane normal n), with a tolerance relative to its size."""
    size = 0.0
    for k in range(nv):
        size = max(size, abs(V[k, 0] - V[0, 0]) + abs(V[k, 1] - V[0, 1]) + abs(V[k, 2] - V[0, 2]))
    tol = 1e-9 * size * size
    pos = 0
    neg = 0
    for k in range(nv):
        a, b = V[k], V[(k + 1) % nv]
        ex, ey, ez = b[0] - a[0], b[1] - a[1], b[2] - a[2]
        qx, qy, qz = p[0] - a[0], p[1] - a[1], p[2] - a[2]
        s = n[0] * (ey * qz - ez * qy) + n[1] * (ez * qx - ex * qz) + n[2] * (ex * qy - ey * qx)
        if s > tol:
            pos += 1
        elif s < -tol:
            neg += 1
    return pos == 0 or neg == 0


@numba.njit(cache=True, nogil=True)
def locate_leaves(pts, porig, noff, child, verts, nverts, normal, node_leaf, out):
    """out[i] = the leaf (M-index) of the union tree holding point i on original porig[i]: down
    from the original's root, into the child whose polygon holds the point (the other child
    when neither holds it within tolerance: points on a split line). A point that the previous
    point's leaf holds takes that leaf without the descent (a pixel's rays, a lattice's
    neighbouring nodes: most of them)."""
    last, last_o = -1, -1
    for i in range(pts.shape[0]):
        o = porig[i]
        if o < 0:
            out[i] = -1
            continue
        if o == last_o and _inside(pts[i], verts[last], nverts[last], normal[o]):
            out[i] = node_leaf[last]
            continue
        t = noff[o]
        while child[t, 0] >= 0:
            c0 = child[t, 0]
            t = c0 if _inside(pts[i], verts[c0], nverts[c0], normal[o]) else child[t, 1]
        out[i] = node_leaf[t]
        last, last_o = t, o


@numba.njit(cache=True, nogil=True)
def point_pairs(ends, origs, nodes, geo, pts, pside, lptr, far, fill, I, E, F):
    """The (point, link end) pairs of a gather at points pts (K, 3), sorted by leaf (lptr
    (M + 1,): the points of leaf l are lptr[l]:lptr[l + 1]), on side pside (K,): the directed
    link ends into originals `origs` whose target node holds the point's leaf, whose source
    the point is in front of, with F the exact form factor from a differential element at the
    point (its side's normal) to the source polygon (the point-to-disc kernel beyond `far`
    times the source's size). Counts them (fill False) or writes them into I (point), E
    (end), F (fill True). Returns the count."""
    tp, ts, sn, ss, v, ptr = ends.tp, ends.ts, ends.sn, ends.ss, ends.v, ends.ptr
    node_leaf, lo, hi, node_orig = nodes.node_leaf, nodes.lo, nodes.hi, nodes.orig
    normal, verts, nverts = geo.normal, geo.verts, geo.nverts
    node_center, node_area = geo.node_center, geo.node_area
    far2 = far * far
    Qc = np.empty((2 * verts.shape[1] + 2, 3))
    n = 0
    for e in origs:
        for k in range(ptr[e], ptr[e + 1]):
            t, s = tp[k], sn[k]
            l0, l1 = (node_leaf[t], node_leaf[t] + 1) if node_leaf[t] >= 0 else (lo[t], hi[t])
            if lptr[l1] == lptr[l0]:
                continue
            gt = 1.0 if ts[k] == 0 else -1.0
            gs = 1.0 if ss[k] == 0 else -1.0
            ot, os_ = node_orig[t], node_orig[s]
            nx, ny, nz = gt * normal[ot, 0], gt * normal[ot, 1], gt * normal[ot, 2]
            mx, my, mz = gs * normal[os_, 0], gs * normal[os_, 1], gs * normal[os_, 2]
            S = verts[s]
            m0 = mx * S[0, 0] + my * S[0, 1] + mz * S[0, 2]
            for i in range(lptr[l0], lptr[l1]):
                if pside[i] != ts[k]:
                    continue
                x = pts[i]
                if mx * x[0] + my * x[1] + mz * x[2] <= m0:  # behind the source
                    continue
                if fill:
                    c = node_center[s]
                    dx, dy, dz = c[0] - x[0], c[1] - x[1], c[2] - x[2]
                    d2 = dx * dx + dy * dy + dz * dz
                    if d2 > far2 * node_area[s]:  # far: the point-to-disc kernel, to O(A/d^2)
                        ci = (nx * dx + ny * dy + nz * dz) / math.sqrt(d2)
                        cj = -(mx * dx + my * dy + mz * dz) / math.sqrt(d2)
                        f = node_area[s] * ci * cj / (math.pi * d2) if ci > 0 and cj > 0 else 0.0
                    else:
                        f = point_ff(x[0], x[1], x[2], nx, ny, nz, S, nverts[s], Qc)
                    if f <= 0.0:
                        continue
                    I[n], E[n], F[n] = i, k, f
                n += 1
    return n


@numba.njit(cache=True, nogil=True)
def visibility_queries(pts, I, E, sn, verts, nverts, node_center, P, Q, owner, far=np.inf,
                       node_area=np.zeros(0)):
    """Segments from each pair's point to up to 4 points of its source (halfway from the
    source's centroid to its vertices), or to its centroid alone where the source is beyond
    `far` times its size (sqrt of node_area) from the point: P, Q (R, 3) filled, owner (R,)
    the pair. Returns R."""
    R = 0
    far2 = far * far
    for j in range(I.shape[0]):
        s = sn[E[j]]
        c = node_center[s]
        x = pts[I[j]]
        one = False
        if far2 < np.inf:
            d2 = (c[0] - x[0]) ** 2 + (c[1] - x[1]) ** 2 + (c[2] - x[2]) ** 2
            one = d2 > far2 * node_area[s]
        for a in range(1 if one else min(nverts[s], 4)):
            for d in range(3):
                P[R, d] = x[d]
                Q[R, d] = c[d] if one else c[d] + 0.5 * (verts[s, a, d] - c[d])
            owner[R] = j
            R += 1
    return R


@numba.njit(cache=True, nogil=True)
def accumulate(I, E, F, vis, Lbar, ss, sn, y, r):
    """y (G, C) += vis F Lbar[source side, :, source], r (G,) += vis F, pair by pair."""
    C = y.shape[1]
    for j in range(I.shape[0]):
        w = vis[j] * F[j]
        if w == 0.0:
            continue
        i, k = I[j], E[j]
        r[i] += w
        for c in range(C):
            y[i, c] += w * Lbar[ss[k], c, sn[k]]


#: Beyond this many times a source's size (sqrt of its area) a point gathers from it with the
#: point-to-disc kernel instead of the exact point-to-polygon form factor (as FG_FAR does for
#: the linear final gather).
FAR = 6.0
#: Originals per batch of (point, link) pairs (bounds the pairs held at once).
ORIGINALS_PER_BATCH = 64
#: A leaf is gathered at the view's points when its area exceeds this many pixel footprints
#: there (the camera-driven rule refines each seen leaf to at most one pixel of its camera).
COARSE_FOOTPRINTS = 2.0
#: Points in coarse leaves take their radiance from a lattice on their original, gathered at
#: its nodes and interpolated bilinearly, with nodes about this many pixels apart (the
#: dyadic level whose spacing is at most LATTICE_PIXELS times the pixel's footprint side);
#: 0: one gather per (pixel, leaf), at the mean of its points. Lattice nodes are the same for
#: every view (nested levels), so the frames of a walkthrough reuse them: Lattice.
#: MEASURED: see docs/src/how-to/views.md (bench_views.py).
LATTICE_PIXELS = 2.0
#: Beyond this many times a source's size a point's visibility of a link not proven visible
#: is one ray to the source's centroid instead of 4 (inf: always 4).
#: MEASURED: see docs/src/how-to/views.md (bench_views.py).
RAY_FAR = 6.0
#: Where a run solved with direct light at points (SPEC §10) takes H1 for the points of coarse
#: leaves: "points", at each of the view's points (shadows as sharp as the pixels), or
#: "lattice", at the lattice's nodes, interpolated with the gathered light.
#: MEASURED: see docs/src/measurements/views.md (bench_views.py).
DIRECT_AT = "points"
#: A view's pixel takes this many times settings.direct.samples shadow rays per emitting
#: element, shared among its points (each point at least one, at most direct.samples; a
#: square): the pixel's points are stratified by their own hashed offsets, so the pixel's
#: mean is as smooth as one point's with all the rays.
#: MEASURED: see docs/src/measurements/views.md (bench_views.py).
PIXEL_SHADOW_RAYS = 16.0
#: Finest lattice level (2^LEVELS nodes along an original's longer side).
LEVELS = 18


def radiance_at(rs, settings, pts: np.ndarray, porig: np.ndarray, side: np.ndarray,
                pixel: np.ndarray, footprint: np.ndarray) -> tuple[np.ndarray, dict]:
    """Radiance (K, 3) leaving points `pts` (K, 3) on originals `porig` (K,) (-1: nothing: 0) on
    side `side` (K,) (0 front, 1 back), and the figures: `PointGather(rs, settings)` for one
    view (see PointGather.radiance_at)."""
    return PointGather(rs, settings).radiance_at(pts, porig, side, pixel, footprint)


class PointGather:
    """A solved run's links opened once for gathers at the points of many views (a
    walkthrough's frames; stages/views.Viewer): the link operator's inputs, the node means of
    the solution (pulled once), the directed link ends, the cluster links' share per leaf
    (point-independent: computed once), the occlusion caster, and the Lattice of nodes
    gathered so far (radiance_at adds to it: one caller at a time)."""

    def __init__(self, rs, settings, lattice_pixels: float = LATTICE_PIXELS,
                 ray_far: float = RAY_FAR, direct_at: str = DIRECT_AT,
                 pixel_shadow_rays: float = PIXEL_SHADOW_RAYS):
        import time

        from radiosity.methods.hierarchical.solve.passes import pull
        from radiosity.methods.hierarchical.solve.transport import (directed_ends, cluster_final,
                                                             open_link_operator, scratch)
        from radiosity.tracing.rays import caster_of

        t0 = time.perf_counter()
        op, table, el, part = open_link_operator(rs, None, "driver", settings)
        inp = self.inp = op.inp
        self.table, self.el = table, el
        self.Le = AreaEmitters(el).radiance()  # (n, 2, 3): what the originals emit
        sol = rs.read_arrays("solution")
        self.radiance = sol["radiance"]
        self.M = len(inp.leaf_node)
        # leaves the run's own camera saw (their stored radiance is kept where fine enough)
        seen = np.zeros(len(part), bool)
        raster = rs.read_arrays("raster")["sub"].ravel()
        seen[raster[raster >= 0]] = True
        self.leaf_seen = seen[table["leaf_sub"]]
        self.closed = (rs.group_attrs("solution").get("row_sums") or {}).get("mode") == "closed"
        L = np.ascontiguousarray(np.transpose(sol["leaf_radiance"], (1, 2, 0)))  # (2, C, M)
        self.C = L.shape[1]
        Sbuf, _ = scratch((L.shape[0], L.shape[1], len(inp.parent)))
        self.Lbar = pull(L, inp.leaf_node, inp.leaf_area, inp.parent, inp.node_area,
                         np.zeros(0), Sbuf).copy()
        self.ends = directed_ends(inp)
        self.nodes, self.geo = inp.nodes(), inp.geometry()
        self.caster = caster_of(el.verts, el.nverts, float(settings.rays.offset))  # the Viewer's
        # cluster links add their final gather at each leaf's centroid, as the render's image
        # (solve/transport.cluster_final), once per leaf here (and their share of the rows, for
        # balancing)
        self.yc = self.rc = None
        if inp.clusters is not None and inp.clusters.links:
            self.yc = np.zeros_like(L)
            cluster_final(inp, self.Lbar, np.zeros(0), self.yc)
            rc = np.zeros_like(L[:, :1])
            cluster_final(inp, np.ones_like(self.Lbar[:, :1]), np.zeros(0), rc)
            self.rc = rc[:, 0, :]
        self.lattice_pixels = float(lattice_pixels)
        self.ray_far = float(ray_far)
        # SPEC §10: a run solved with direct light at points stores R = L1 + Lr at its leaves;
        # a point then shows Le + rho (gather(R) + H1 / pi), H1 at the point itself
        self.light, self.lights = None, {}
        if rs.group_attrs("solution").get("direct") == "points":
            self.light = DirectLight(el, float(settings.rays.offset),
                                     samples=int(settings.direct.samples))
            self.lights[self.light.samples] = self.light
        self.direct_at = direct_at
        self.pixel_shadow_rays = float(pixel_shadow_rays)
        self.lattice = Lattice(inp.verts[inp.noff[:-1]], inp.nverts[inp.noff[:-1]], inp.normal)
        self.time_open_s = round(time.perf_counter() - t0, 4)

    def radiance_at(self, pts: np.ndarray, porig: np.ndarray, side: np.ndarray,
                    pixel: np.ndarray, footprint: np.ndarray) -> tuple[np.ndarray, dict]:
        """Radiance (K, 3) leaving points `pts` (K, 3) on originals `porig` (K,) (-1: nothing:
        0) on side `side` (K,) (0 front, 1 back), and the figures. A point whose leaf is at
        most COARSE_FOOTPRINTS times its pixel's footprint there (`footprint` (K,), m^2) and
        was seen by the run's camera takes the leaf's stored radiance (the solve's final
        gather); the others interpolate the Lattice's nodes gathered over their leaf's links
        (point_pairs; LATTICE_PIXELS 0: the points of one pixel (`pixel` (K,)) share one
        gather at their mean), and in a run with direct light at points add rho / pi H1 at
        the point itself (DIRECT_AT)."""
        import time

        t0 = time.perf_counter()
        inp, M = self.inp, self.M
        K = len(pts)
        leaf = np.full(K, -1, np.int64)
        hit = porig >= 0
        found = np.empty(int(hit.sum()), np.int64)
        locate_leaves(np.ascontiguousarray(pts[hit], float), porig[hit].astype(np.int64),
                      inp.noff, inp.child, inp.verts, inp.nverts, inp.normal, inp.node_leaf, found)
        leaf[hit] = found
        ok = leaf >= 0
        side = np.asarray(side, np.int64)
        out = np.zeros((K, 3))
        # leaves the run's own camera saw and refined to its pixels keep their solved value
        # where they are no larger than this view's pixels; the others (coarser, or never
        # seen: their links' visibility was judged from their centroids) are gathered at the
        # view's points
        lf = np.maximum(leaf, 0)
        coarse = ok & ((inp.leaf_area[lf] > COARSE_FOOTPRINTS * footprint) | ~self.leaf_seen[lf])
        flat = ok & ~coarse
        out[flat] = self.radiance[self.table["leaf_sub"][leaf[flat]], side[flat]]
        idx = np.nonzero(coarse)[0]
        per_pixel = K / max(1, len(np.unique(pixel))) if len(idx) and self.light else 1.0
        evals = rays = G = reused = 0
        if len(idx) and self.lattice_pixels > 0:
            # coarse leaves: the lattice nodes around each point, gathered once (for every view
            # of this PointGather), interpolated bilinearly
            o, sd = np.asarray(porig, np.int64)[idx], side[idx]
            keys, w = self.lattice.corners(pts[idx], o, sd,
                                           self.lattice_pixels * np.sqrt(footprint[idx]))
            uk, inv = np.unique(keys.ravel(), return_inverse=True)
            have = self.lattice.find(uk)
            new = np.nonzero(have < 0)[0]
            G, reused = len(new), len(uk) - len(new)
            if G:
                P, no, ns = self.lattice.nodes(uk[new])
                nl = np.empty(G, np.int64)
                locate_leaves(P, no, inp.noff, inp.child, inp.verts, inp.nverts, inp.normal,
                              inp.node_leaf, nl)
                val, evals, rays = self.gather(P, nl, ns)
                if self.light and self.direct_at == "lattice":
                    val += self.direct(P, no, ns, uk[new])
                self.lattice.add(uk[new], val)
            vals = self.lattice.values(uk)[inv].reshape(len(idx), 4, 3)
            out[idx] = np.einsum("kc,kcj->kj", w, vals)
            if self.light and self.direct_at == "points":
                out[idx] += self.direct(pts[idx], o, sd, idx, per_pixel)
        elif len(idx):
            # one gather per (pixel, leaf, side), at the mean of its points
            key = (np.asarray(pixel, np.int64)[idx] * M + leaf[idx]) * 2 + side[idx]
            uk, inv = np.unique(key, return_inverse=True)
            G = len(uk)
            P = np.zeros((G, 3))
            np.add.at(P, inv, pts[idx])
            P /= np.bincount(inv, minlength=G)[:, None]
            val, evals, rays = self.gather(P, (uk // 2) % M, uk % 2)
            out[idx] = val[inv]
            if self.light and self.direct_at == "points":
                out[idx] += self.direct(pts[idx], np.asarray(porig, np.int64)[idx], side[idx], idx,
                                        per_pixel)
        return out, {"points": K, "gathered_points": int(G), "reused_points": int(reused),
                     "coarse_samples": int(len(idx)), "evaluations": evals, "rays": int(rays),
                     "time_s": round(time.perf_counter() - t0, 4)}

    def direct(self, P: np.ndarray, orig: np.ndarray, side: np.ndarray, index: np.ndarray,
               per_pixel: float = 1.0) -> np.ndarray:
        """rho / pi H1 (G, 3): the first bounce at points P (G, 3) on originals `orig` (G,),
        sides `side` (G,), H1 from the run's emitters (scene/direct.DirectLight; `index` (G,):
        the points' stable numbers for its sample offsets). Points that share a pixel
        `per_pixel` at a time take fewer shadow rays each (PIXEL_SHADOW_RAYS)."""
        full = self.light.samples
        k = max(1, min(full, round(self.pixel_shadow_rays * full / max(per_pixel, 1.0))))
        k = max(1, math.isqrt(k)) ** 2
        if k not in self.lights:
            self.lights[k] = DirectLight(self.el, self.light.ray_offset, samples=k,
                                         seed=self.light.seed)
        sign = np.where(side == 0, 1.0, -1.0)[:, None]
        H = self.lights[k].irradiance(P, sign * self.el.normal[orig], orig,
                                  index=np.asarray(index, np.int64) * 2 + side)
        return self.el.reflectance[orig, side] * H / math.pi

    def gather(self, P: np.ndarray, gleaf: np.ndarray, gside: np.ndarray):
        """Radiance (G, 3) leaving points P (G, 3) in leaves `gleaf` (G,) on sides `gside`
        (G,), gathered over the links into each leaf and its ancestors (point_pairs), with
        rays from the point for links not proven visible; and (link evaluations, rays)."""
        import dask

        inp, M, ends = self.inp, self.M, self.ends
        G = len(P)
        order = np.argsort(gleaf, kind="stable")
        lptr = np.zeros(M + 1, np.int64)
        np.cumsum(np.bincount(gleaf, minlength=M), out=lptr[1:])
        Po, So, lo_ = np.ascontiguousarray(P[order]), np.ascontiguousarray(gside[order]), gleaf[order]
        origs = np.unique(inp.leaf_orig[lo_]).astype(np.int64)
        nodes, geo, caster = self.nodes, self.geo, self.caster
        pside_orig = inp.leaf_orig[lo_]

        def batch(g):
            y, r = np.zeros((G, self.C)), np.zeros(G)
            z = np.zeros(0, np.int64)
            n = point_pairs(ends, g, nodes, geo, Po, So, lptr, FAR, False, z, z, np.zeros(0))
            I, E, F = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n)
            n = point_pairs(ends, g, nodes, geo, Po, So, lptr, FAR, True, I, E, F)
            I, E, F = I[:n], E[:n], F[:n]
            vis = ends.v[E].astype(np.float64)
            partial = np.nonzero(vis < 1.0)[0]  # not proven visible: rays from the point itself
            R = 0
            if len(partial):
                P_, Q_ = np.empty((4 * len(partial), 3)), np.empty((4 * len(partial), 3))
                own = np.empty(4 * len(partial), np.int64)
                R = visibility_queries(Po, I[partial], E[partial], ends.sn, inp.verts, inp.nverts,
                                       inp.node_center, P_, Q_, own, self.ray_far, inp.node_area)
                own = own[:R]
                blocked = caster.occluded(P_[:R], Q_[:R], pside_orig[I[partial]][own],
                                          inp.orig[ends.sn[E[partial]]][own])
                seen = np.bincount(own, ~blocked, minlength=len(partial))
                vis[partial] = seen / np.maximum(np.bincount(own, minlength=len(partial)), 1)
            accumulate(I, E, F, vis, self.Lbar, ends.ss, ends.sn, y, r)
            return y, r, n, R

        batches = np.array_split(origs, max(2, -(-len(origs) // ORIGINALS_PER_BATCH)))
        parts = dask.compute(*[dask.delayed(batch)(g) for g in batches if len(g)],
                             scheduler="threads", num_workers=2)
        y = sum(p[0] for p in parts)
        r = sum(p[1] for p in parts)
        evals = int(sum(p[2] for p in parts))
        rays = int(sum(p[3] for p in parts))
        if self.yc is not None:  # the cluster links' final gather, as in the render's image
            y = y + self.yc[So, :, lo_]
            r = r + self.rc[So, lo_]
        if self.closed:  # rows balanced to 1, as in the solve's final gather
            y = y / np.where(r > 0, r, 1.0)[:, None]
        o = inp.leaf_orig[lo_]
        val = np.zeros((G, 3))
        val[order] = self.Le[o, So] + self.el.reflectance[o, So] * y
        return val, evals, rays


class Lattice:
    """Dyadic lattices on the originals' planes and the radiance gathered at their nodes. On
    original o (local axes e1 along its first edge, e2 = n x e1, origin at the corner of its
    bounding rectangle, side h0 the rectangle's longer side) level L has nodes at
    (i, j) h0 / 2^L, i, j = 0 .. 2^L; a node is keyed by its place on the finest level, so
    levels nest and every view finds the nodes earlier views gathered. Key bits (int64, most
    significant first): original * 2 + side, then i and j at level LEVELS (`bits` each).
    Nodes outside the original's polygon are gathered at the nearest point inside it."""

    def __init__(self, verts: np.ndarray, nverts: np.ndarray, normal: np.ndarray):
        n = len(verts)
        e1 = verts[:, 1] - verts[:, 0]
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(normal, e1)
        e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
        mask = np.arange(verts.shape[1])[None, :] < nverts[:, None]
        u = np.einsum("nkd,nd->nk", verts, e1)
        v = np.einsum("nkd,nd->nk", verts, e2)
        big = np.where(mask, 0.0, np.inf)
        u0, v0 = np.min(u + big, axis=1), np.min(v + big, axis=1)
        self.h0 = np.maximum(np.max(u - big, axis=1) - u0, np.max(v - big, axis=1) - v0)
        self.origin = u0[:, None] * e1 + v0[:, None] * e2 + (
            np.einsum("nd,nd->n", verts[:, 0], normal)[:, None] * normal)
        self.e1, self.e2, self.normal = e1, e2, normal
        # the polygons in lattice units (0..1 along h0), for clamping nodes into them
        self.poly = np.stack([(u - u0[:, None]), (v - v0[:, None])], -1) / self.h0[:, None, None]
        self.nverts = np.asarray(nverts, np.int64)
        self.bits = min(LEVELS + 1, (62 - int(2 * n).bit_length()) // 2)
        self.levels = self.bits - 1
        self.keys = np.zeros(0, np.int64)
        self.vals = np.zeros((0, 3))

    def corners(self, pts: np.ndarray, orig: np.ndarray, side: np.ndarray, spacing: np.ndarray):
        """Keys (K, 4) int64 of the lattice nodes around points pts (K, 3) on originals
        `orig` (K,), sides `side` (K,), on the coarsest level whose node spacing is at most
        `spacing` (K,) (world units), and their bilinear weights (K, 4) float64."""
        d = pts - self.origin[orig]
        h0 = self.h0[orig]
        u = np.einsum("kd,kd->k", d, self.e1[orig]) / h0
        v = np.einsum("kd,kd->k", d, self.e2[orig]) / h0
        with np.errstate(divide="ignore"):
            lev = np.ceil(np.log2(h0 / np.maximum(spacing, 1e-300)))
        lev = np.clip(lev, 0, self.levels).astype(np.int64)
        n = (1 << lev).astype(np.float64)
        x, y = np.clip(u, 0.0, 1.0) * n, np.clip(v, 0.0, 1.0) * n
        ci = np.minimum(np.floor(x), n - 1)
        cj = np.minimum(np.floor(y), n - 1)
        fx, fy = x - ci, y - cj
        shift = self.levels - lev
        i0, j0 = ci.astype(np.int64) << shift, cj.astype(np.int64) << shift
        step = np.int64(1) << shift
        head = ((orig.astype(np.int64) * 2 + side) << (2 * self.bits))
        keys = np.stack([head | (i0 << self.bits) | j0,
                         head | ((i0 + step) << self.bits) | j0,
                         head | (i0 << self.bits) | (j0 + step),
                         head | ((i0 + step) << self.bits) | (j0 + step)], 1)
        w = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
        return keys, w

    def nodes(self, keys: np.ndarray):
        """The gather points (G, 3) of nodes `keys` (G,) (clamped into their original's
        polygon), their originals (G,) and sides (G,)."""
        mask = (np.int64(1) << self.bits) - 1
        j = (keys & mask).astype(np.float64) / (1 << self.levels)
        i = ((keys >> self.bits) & mask).astype(np.float64) / (1 << self.levels)
        head = keys >> (2 * self.bits)
        o, sd = head // 2, head % 2
        q = clamp_into(np.stack([i, j], 1), self.poly[o], self.nverts[o])
        h0 = self.h0[o][:, None]
        P = self.origin[o] + h0 * (q[:, :1] * self.e1[o] + q[:, 1:] * self.e2[o])
        return np.ascontiguousarray(P), o, sd

    def find(self, keys: np.ndarray) -> np.ndarray:
        """Index of each of `keys` (sorted, unique) among the gathered nodes, -1 where none."""
        if not len(self.keys):
            return np.full(len(keys), -1, np.int64)
        at = np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)
        return np.where(self.keys[at] == keys, at, -1)

    def add(self, keys: np.ndarray, vals: np.ndarray) -> None:
        """Nodes `keys` (G,) not yet held, with their radiance vals (G, 3)."""
        k = np.concatenate([self.keys, keys])
        order = np.argsort(k, kind="stable")
        self.keys = k[order]
        self.vals = np.concatenate([self.vals, vals])[order]

    def values(self, keys: np.ndarray) -> np.ndarray:
        """Radiance (G, 3) of held nodes `keys` (G,)."""
        return self.vals[np.searchsorted(self.keys, keys)]


def clamp_into(q: np.ndarray, poly: np.ndarray, nverts: np.ndarray,
               inset: float = 1e-6) -> np.ndarray:
    """Points q (G, 2) moved to the nearest point of their convex polygons poly (G, V, 2)
    (nverts (G,) corners, either orientation) where outside, then `inset` (polygon units)
    towards the polygon's centroid so that they lie strictly inside. (G, 2) float64."""
    G, V = poly.shape[:2]
    k = np.arange(V)[None, :]
    valid = k < nverts[:, None]
    nxt = np.where(k + 1 < nverts[:, None], k + 1, 0)
    a = poly
    b = np.take_along_axis(poly, nxt[..., None], 1)
    e = b - a
    cross = e[..., 0] * (q[:, None, 1] - a[..., 1]) - e[..., 1] * (q[:, None, 0] - a[..., 0])
    area = np.sum(np.where(valid, a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0], 0.0), axis=1)
    sgn = np.where(area >= 0, 1.0, -1.0)[:, None]
    inside = np.all(~valid | (sgn * cross >= 0), axis=1)
    t = np.clip(np.einsum("gvd,gvd->gv", q[:, None, :] - a, e)
                / np.maximum(np.einsum("gvd,gvd->gv", e, e), 1e-300), 0.0, 1.0)
    near = a + t[..., None] * e
    d2 = np.where(valid, np.sum((near - q[:, None, :]) ** 2, -1), np.inf)
    best = np.take_along_axis(near, np.argmin(d2, 1)[:, None, None], 1)[:, 0]
    out = np.where(inside[:, None], q, best)
    c = np.sum(np.where(valid[..., None], poly, 0.0), 1) / nverts[:, None]
    step = c - out
    dist = np.linalg.norm(step, axis=1, keepdims=True)
    return out + np.where(dist > inset, inset / np.maximum(dist, 1e-300), 1.0) * step
