"""The view-factor task (worker side): all pairs of a run of leaves, from the cluster walk to
the unobstructed factors, the shafts and the sampled visibility, written into the run store.
Everything it needs comes in its arguments (Inputs, Params): no configuration, no client.
The method: docs/src/design/viewfactors-method.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from radiosity.runtime.monitor import worker_address

COUNTERS = ("pairs_total", "pairs_culled_cluster", "pairs_dropped_cutoff", "pairs_facing_away",
            "pairs_facing", "pairs_zero_unobstructed", "pairs_cheap_kernel", "pairs_exact_kernel",
            "pairs_proven_unobstructed", "pairs_sampled", "pairs_one_ray", "pairs_at_max_points",
            "pairs_unresolved", "rays", "shaft_tests", "pairs_blocked", "pairs_stored")
(_TOTAL, _CULLED, _DROPPED, _AWAY, _FACING, _ZERO, _CHEAP, _EXACT, _PROVEN, _SAMPLED, _ONE,
 _CAPPED, _UNRES, _RAYS, _TESTS, _BLOCKED, _STORED) = range(len(COUNTERS))
STAGES = ("enumerate_s", "unobstructed_s", "shafts_s", "visibility_s")


@dataclass(frozen=True)
class Params:
    """Tunables resolved on the driver (worker code never reads configuration).

    accuracy: target absolute error of a factor; cheap_rel: the cheap kernel is used where its
    bound <= cheap_rel x its value; smax: largest sample points per side; seed: of the jitter;
    cutoff: cluster form-factor bound below which cluster pairs are dropped (0: never);
    batch_pairs: pairs per batch in a task; ray_batch: rays per Embree batch."""

    accuracy: float
    cheap_rel: float
    smax: int
    seed: int
    cutoff: float
    batch_pairs: int
    ray_batch: int


@dataclass(frozen=True)
class Inputs:
    """Read-only arrays every task needs, in the tree's leaf order (scattered to the workers once).

    verts (n, 4, 3), nv (n,) int64, normal, center (n, 3), area (n,), doff (n,) = n . c,
    flo, fhi (n, 3) facet boxes, padded as the render pads occluders (tracing/shafts.occluders),
    gid (n,) int64 original facet ids, J, R (n,) second moments and radii
    (loops.second_moments), qn (n, MAXQ, 3), qw (n, MAXQ), qc (n,) quadrature;
    nodes: the tree's node arrays (loops.Nodes), n_leaves its leaves; tol: the facing
    tolerance, pad: the plane tolerance (lengths); key: Embree cache key."""

    verts: np.ndarray
    nv: np.ndarray
    normal: np.ndarray
    center: np.ndarray
    area: np.ndarray
    doff: np.ndarray
    flo: np.ndarray
    fhi: np.ndarray
    gid: np.ndarray
    J: np.ndarray
    R: np.ndarray
    qn: np.ndarray
    qw: np.ndarray
    qc: np.ndarray
    nodes: tuple  # loops.Nodes
    n_leaves: int
    tol: float
    pad: float
    key: str
    ray_offset: float  # the ray offset (radiosity.rays.epsilon), resolved on the driver


def task_viewfactors(inp: Inputs, prm: Params, leaves: np.ndarray, store_path: str,
                     task: int) -> dict:
    """All pairs (i, j), i in the given leaves, i < j in tree order: compute, write to the
    store (store.write_vf_task), and return the manifest entry: task, crc, n, nd, counts
    (len(COUNTERS),), times (len(STAGES),) seconds, cpu seconds, start, stop, pid."""
    from radiosity.tracing.rays import caster_for
    from radiosity.viewfactors.store import write_vf_task

    t0, c0 = time.time(), time.process_time()
    caster = caster_for(inp.key, inp.verts, inp.nv, inp.ray_offset)
    counts = np.zeros(len(COUNTERS), np.int64)
    times = np.zeros(len(STAGES))
    parts, drops = [], []
    for a in np.asarray(leaves).tolist():
        p, d = _leaf(inp, prm, caster, a, counts, times)
        parts += p
        drops.append(d)
    if parts:
        ij = np.stack([np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])], 1)
        f = np.stack([np.concatenate([p[k] for p in parts]) for k in (2, 3, 4)], 1)
    else:
        ij, f = np.zeros((0, 2), np.int32), np.zeros((0, 3))
    drop = np.concatenate(drops) if drops else np.zeros((0, 4))
    counts[_STORED] = len(ij)
    res = write_vf_task(store_path, task, ij, f, drop)
    res.update(task=int(task), counts=counts.tolist(), times=times.tolist(), start=t0,
               stop=time.time(), cpu=time.process_time() - c0, worker=worker_address())
    return res


def _leaf(inp: Inputs, prm: Params, caster, a: int, counts: np.ndarray, times: np.ndarray):
    """The pairs of leaf a against every later facet: list of (i, j, F, F_unobstructed, bound)
    batches (original ids) and the dropped cluster pairs (d, 4)."""
    from radiosity.viewfactors.loops import near_leaves

    t = time.perf_counter()
    n = len(inp.area)
    nodes = inp.nodes
    buf = np.empty(inp.n_leaves, np.int64)
    k = len(nodes.start)
    dn, dab, dba = np.empty(k, np.int64), np.empty(k), np.empty(k)
    nl, culled, dropped, nd = near_leaves(nodes, a, inp.tol, prm.cutoff, buf, dn, dab, dba)
    a0, a1 = int(nodes.start[a]), int(nodes.end[a])
    na = a1 - a0
    counts[_TOTAL] += na * (na - 1) // 2 + na * (n - a1)
    counts[_CULLED] += culled
    counts[_DROPPED] += dropped
    drop = np.column_stack([np.full(nd, a, np.float64), dn[:nd], dab[:nd], dba[:nd]])
    bl = buf[:nl]
    times[0] += time.perf_counter() - t
    out = []
    sizes = na * (nodes.end[bl] - nodes.start[bl])
    s = 0
    while s < nl:
        e, acc = s, 0
        while e < nl and (e == s or acc + sizes[e] <= prm.batch_pairs):
            acc += sizes[e]
            e += 1
        out.append(_batch(inp, prm, caster, a, bl[s:e], counts, times))
        s = e
    return out, drop


def _batch(inp: Inputs, prm: Params, caster, a: int, bl: np.ndarray, counts: np.ndarray,
           times: np.ndarray):
    """Leaf a against the leaves bl: facing pairs, unobstructed F (cheap or exact), shafts,
    sampled visibility. Returns (i, j) original ids (int32), F, F unobstructed, cheap bound."""
    from radiosity.core.exact import pair_form_factors_exact
    from radiosity.viewfactors.loops import cheap_ff, facing_pairs
    from radiosity.viewfactors.occlusion import prove_unobstructed

    t = time.perf_counter()
    start, end = inp.nodes.start, inp.nodes.end
    a0, a1 = int(start[a]), int(end[a])
    cap = int((a1 - a0) * (end[bl] - start[bl]).sum())
    ia, ib, blk = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
    full = np.empty(cap, np.bool_)
    m, away = facing_pairs(inp.verts, inp.nv, inp.normal, inp.doff, a0, a1, start[bl], end[bl],
                           inp.tol, ia, ib, blk, full)
    counts[_AWAY] += away
    counts[_FACING] += m
    ia, ib, blk, full = ia[:m], ib[:m], blk[:m], full[:m]
    t1 = time.perf_counter()
    times[0] += t1 - t
    f, bnd = np.empty(m), np.empty(m)
    cheap_ff(ia, ib, full, inp.normal, inp.center, inp.area, inp.J, inp.R, inp.flo, inp.fhi,
             inp.qn, inp.qw, inp.qc, f, bnd)
    cheap = bnd <= prm.cheap_rel * f
    ex = np.nonzero(~cheap)[0]
    if len(ex):
        f[ex] = pair_form_factors_exact(inp.verts[ia[ex]], inp.nv[ia[ex]], inp.verts[ib[ex]],
                                        inp.nv[ib[ex]], two_sided=False)
        bnd[ex] = 0.0
    counts[_CHEAP] += m - len(ex)
    counts[_EXACT] += len(ex)
    keep = np.nonzero(f > 0)[0]
    counts[_ZERO] += m - len(keep)
    ia, ib, blk, f, bnd = ia[keep], ib[keep], blk[keep], f[keep], bnd[keep]
    t2 = time.perf_counter()
    times[1] += t2 - t1
    # the accuracy holds for both directions: F_ji = F_ij A_i / A_j may be the larger one
    fmax = f * np.maximum(1.0, inp.area[ia] / inp.area[ib])
    proven = np.zeros(len(ia), np.bool_)
    counts[_TESTS] += prove_unobstructed(ia, ib, blk, fmax > prm.accuracy, bl, a, inp.nodes,
                                         inp.verts, inp.nv, inp.flo, inp.fhi, inp.normal, inp.doff,
                                         inp.pad, proven)
    t3 = time.perf_counter()
    times[2] += t3 - t2
    phi = np.ones(len(ia))
    un = np.nonzero(~proven)[0]
    counts[_PROVEN] += len(ia) - len(un)
    if len(un):
        phi[un] = _sampled(inp, prm, caster, ia[un], ib[un], fmax[un], f[un], counts)
    times[3] += time.perf_counter() - t3
    F = f * phi
    nz = np.nonzero(F > 0)[0]
    counts[_BLOCKED] += len(F) - len(nz)
    return (inp.gid[ia[nz]].astype(np.int32), inp.gid[ib[nz]].astype(np.int32), F[nz], f[nz],
            bnd[nz])


def _sampled(inp: Inputs, prm: Params, caster, fi, fj, fu, fij, counts) -> np.ndarray:
    """Visible fractions (k,) of pairs (fi, fj) (tree order) whose larger unobstructed factor
    (of F_ij, F_ji) is fu and whose unobstructed F_ij is fij: a pair
    with fu <= accuracy takes level 1 (one ray between centroids); a larger one starts at
    the level s0 where one sample pair carries at most the accuracy (fu / s0^4 <= accuracy)
    and doubles s until two successive levels agree (fu |phi_s - phi_s/2| <= accuracy) or s
    reaches smax."""
    k = len(fi)
    counts[_SAMPLED] += k
    phi = np.zeros(k)
    prev = np.full(k, np.nan)
    small = fu <= prm.accuracy
    lev = np.ones(k, np.int64)
    big = np.nonzero(~small)[0]
    s0 = np.ceil((fu[big] / prm.accuracy) ** 0.25 - 1e-9)
    lev[big] = np.minimum(2 ** np.ceil(np.log2(np.maximum(s0, 1.0))).astype(np.int64), prm.smax)
    active = np.arange(k)
    while len(active):
        ph = np.empty(len(active))
        la = lev[active]
        for s in np.unique(la).tolist():
            g = np.nonzero(la == s)[0]
            ph[g] = _level(inp, prm, caster, fi[active[g]], fj[active[g]], fij[active[g]], int(s),
                           counts)
        has = ~np.isnan(ph)
        sm = small[active]
        pp = prev[active]
        agree = has & ~np.isnan(pp) & (fu[active] * np.abs(ph - pp) <= prm.accuracy)
        # (a first level that is unanimous, every sample pair visible or none, is not enough:
        # a thin occluder, a shelf board, hides a part of many cell pairs and can miss all the
        # samples; rows of the walls around one reached 1.011 at accuracy 1e-3)
        last = la >= prm.smax
        accept = has & (sm | agree | last)
        counts[_ONE] += int(np.count_nonzero(accept & sm & (la == 1)))
        counts[_CAPPED] += int(np.count_nonzero(has & ~sm & ~agree & last))
        phi[active[accept]] = ph[accept]
        # no sample pair with a positive kernel even at the finest level (facets that barely
        # face each other): keep the last level that had one, else 0
        gone = ~accept & last
        rest = active[gone]
        phi[rest] = np.where(np.isnan(prev[rest]), 0.0, prev[rest])
        counts[_UNRES] += len(rest)
        upd = has & ~accept
        prev[active[upd]] = ph[upd]
        active = active[~accept & ~gone]
        lev[active] *= 2
    return phi


def _level(inp: Inputs, prm: Params, caster, fi, fj, fij, s: int, counts) -> np.ndarray:
    """phi at level s (s x s points per facet, s^4 rays per pair) for pairs (fi, fj) of
    unobstructed factors fij (the control variate of occlusion.visible_fraction); NaN where
    no sample pair has a positive kernel."""
    from radiosity.viewfactors.occlusion import sample_facets, sample_rays, visible_fraction

    S = s * s
    per = S * S
    out = np.empty(len(fi))
    step = max(1, prm.ray_batch // per)
    for c0 in range(0, len(fi), step):
        a, b = fi[c0:c0 + step], fj[c0:c0 + step]
        kk = len(a)
        # each pair's own points on both facets (sample_facets: errors independent pair by
        # pair), keyed by the ordered pair of original ids
        U = np.concatenate([a, b])
        ga, gb = inp.gid[a].astype(np.int64), inp.gid[b].astype(np.int64)
        n = np.int64(len(inp.gid))
        key = np.concatenate([ga * n + gb, gb * n + ga])
        pts, w = np.empty((len(U) * S, 3)), np.empty(len(U) * S)
        sample_facets(U, key, s, prm.seed, inp.verts, inp.nv, inp.center, inp.area, pts, w)
        ptr = np.empty(kk + 1, np.int64)
        ra, rb, term = np.empty(kk * per, np.int64), np.empty(kk * per, np.int64), np.empty(kk * per)
        own = np.arange(kk, dtype=np.int64)
        nr = sample_rays(own, own + kk, S, pts, w, inp.normal, a, b, ptr, ra, rb, term)
        vis = ~caster.occluded_pairs(pts, ra[:nr], rb[:nr], np.repeat(U, S))
        ph = np.empty(kk)
        # E[sum of a pair's terms] = pi F_ij / A_j (sample_facets' weights sum to 1 a facet)
        visible_fraction(ptr, term[:nr], vis, np.pi * fij[c0:c0 + step] / inp.area[b], ph)
        out[c0:c0 + kk] = ph
        counts[_RAYS] += nr
    return out
