"""The cluster layer of a link stage as tasks (SPEC §9): the cluster refinement
(clusters/refine.refine_clusters) cut breadth first into subtrees of links, each a task on the
one stage master (runtime/stage.py: ClusterStage) that refines its links to the end and
computes their form factors and rays (clusters/weights.link_weights), and the figures
`radiosity plan` estimates a clustered scene's cost from.

Design notes and measurements: docs/src/design/methods-hierarchical-clusters.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from radiosity.core.arrays import radix_order
from radiosity.methods.hierarchical.clusters.sides import with_sides
from radiosity.methods.hierarchical.clusters.transport import ClusterLinks
from radiosity.methods.hierarchical.clusters.refine import ClusterTree, cluster_tree, refine_clusters
from radiosity.methods.hierarchical.clusters.weights import clear_links, link_weights, solid_ends
from radiosity.runtime.stage import StageMaster, StagePlan
from radiosity.runtime.store import StageFigures

# What a clustered scene costs, as measured (benchmarks/bench_clusters.py, results/clusters.json:
# terrains of 2 x 10^4 and 2 x 10^5 triangles and the Cornell box cut into 2 000 a face, 128^2,
# the defaults): links in all (cluster and element level) per original, and links made per
# second per worker thread in the link stage (cluster layer and element links); `radiosity
# plan` estimates from them.
LINKS_PER_ORIGINAL = (261.0, 355.0)
LINKS_PER_THREAD_S = (450e3, 588e3)


def refine_all(ct: ClusterTree, eps: float, cap: int = 1024):
    """The whole cluster refinement in this process, from the root's self-link: (links, pairs,
    counts) as refine_clusters gives them."""
    links, pairs, counts, _, _ = refine_clusters(ct.tree, ct.elems, float(eps), ct.lref, cap,
                                                 np.zeros((1, 2), np.int64), 0)
    return links, pairs, counts


#: Links waiting at the cut of the cluster refinement into tasks, per task (about).
CUT_PER_TASK = 16
#: Tasks per worker thread at the cut. 16, not 4: on the 200 000-triangle terrain the cluster
#: layer took the same time (118 s) in 32 tasks as in 8, and a progress bar moves 4x as often
#: (a 10^6-triangle scene's tasks take minutes each).
TASKS_PER_THREAD = 16


@dataclass(frozen=True)
class ClusterInputs:
    """What every cluster task needs (scattered once): the tree, the oracle's epsilon, the rays
    per link (0: nothing can block) and the Embree cache key and ray offset of the originals;
    shadow: the threshold of splitting partly visible links (_shadows); solids: rays inside
    solids left out of the visible fractions (clusters/weights.SolidEnds); probe: links whose
    estimate is below it take PROBE_RAYS rays before they are split (_probe; 0: none)."""

    ct: ClusterTree
    epsilon: float
    rays: int
    key: str
    verts: np.ndarray
    nverts: np.ndarray
    ray_offset: float
    shadow: float = np.inf
    solids: bool = False
    probe: float = 0.0


def task_clusters(inp: ClusterInputs, init: np.ndarray) -> tuple:
    """One task: refine the links `init` to the end, then the kept links' form factors and
    visible fractions -> _compact's (keys, g, pairs, counts, visible sum, rays)."""
    ct = inp.ct
    links, pairs, counts, _, probes = refine_clusters(ct.tree, ct.elems, inp.epsilon, ct.lref,
                                                      max(1024, 8 * len(init)), init, 0,
                                                      inp.probe)
    return _compact(ct, links, pairs, counts, _caster(inp, links, probes), inp.rays,
                    inp.epsilon, inp.shadow, inp.solids, probes, inp.probe)


def _compact(ct: ClusterTree, links, pairs, counts, caster, rays: int, eps: float,
             shadow: float = np.inf, solids: bool = False, probes=None,
             probe: float = 0.0) -> tuple:
    """Links and pairs as the driver keeps them, each sorted here (so that the driver merges
    sorted runs): the keys p K + q (int64) with g = A_p F_pq v (float32, the one weight a link
    keeps: clusters.ClusterLinks), the pairs of originals sorted by (I, J), the counts, the
    visible fractions' sum and the rays cast (link_weights; one ray for links that carry at
    most eps; partly visible links that carry more than `shadow` refined: _shadows; links
    with every ray blocked left out); the `probes` decided first (_probe: counts grows to
    [.., probed, dropped])."""
    links, pairs, counts, prays, seen = _probe(ct, links, pairs, counts, caster, eps, solids,
                                               probes, probe)
    links, pairs, counts, F, v, nrays = _shadows(ct, links, pairs, counts, caster, rays, eps,
                                                 shadow, solids)
    if seen is not None and len(seen[0]):  # probed links kept with their rays' visible fraction
        links, F, v = (np.concatenate([a, b]) for a, b in zip((links, F, v), seen))
    key, g = _keys_weights(links, F, v, np.asarray(ct.tree.area), np.int64(ct.nodes))
    # links whose every ray is blocked (g = 0) carry nothing in any pass: not kept (the same
    # bits; on the all-two-sided hall 80 % of the cluster links: design page, "Two-sided
    # clusters")
    live = g > 0
    if not live.all():
        key, g, v = key[live], g[live], v[live]
        counts = np.array(counts, np.int64)
        counts[2] -= int((~live).sum())
    # the keys (and the pairs) are unique: any sort gives one order
    order = radix_order(key, int(ct.nodes * ct.nodes).bit_length())
    n = np.int64(len(ct.elems.area))
    pairs = pairs[radix_order(pairs[:, 0] * n + pairs[:, 1], int(n * n).bit_length())]
    return key[order], g[order], pairs, counts, float(v.sum()), nrays + prays


@numba.njit(cache=True, nogil=True)
def _keys_weights(links, F, v, area, K):
    """The sort keys p K + q (int64) and weights g = A_p F_pq v (float32) of links (p, q)."""
    m = links.shape[0]
    key = np.empty(m, np.int64)
    g = np.empty(m, np.float32)
    for a in range(m):
        p = links[a, 0]
        key[a] = p * K + links[a, 1]
        g[a] = F[a, 0] * area[p] * v[a]
    return key, g


@numba.njit(cache=True, nogil=True)
def _partial(links, F, v, rho, lhat, lref, shadow):
    """(m,) bool: the links partly visible (0 < v < 1) that carry more than `shadow` in the
    oracle's weighting, max(rho_p F_pq Lhat_q, rho_q F_qp Lhat_p) / lref (lref 0: every one)."""
    m = links.shape[0]
    out = np.zeros(m, np.bool_)
    for a in range(m):
        if 0.0 < v[a] < 1.0:
            p, q = links[a, 0], links[a, 1]
            if lref <= 0.0:
                out[a] = True
            else:
                out[a] = max(rho[p] * F[a, 0] * lhat[q], rho[q] * F[a, 1] * lhat[p]) / lref \
                    > shadow
    return out


@numba.njit(cache=True, nogil=True)
def _put_kept(links, F, v, part, at, L_out, F_out, v_out):
    """Copy the rows of (links, F, v) that are not `part` into the outputs from row `at` on;
    returns the next free row."""
    for a in range(links.shape[0]):
        if not part[a]:
            L_out[at, 0], L_out[at, 1] = links[a, 0], links[a, 1]
            F_out[at, 0], F_out[at, 1] = F[a, 0], F[a, 1]
            v_out[at] = v[a]
            at += 1
    return at


def _shadows(ct: ClusterTree, links, pairs, counts, caster, rays: int, eps: float,
             shadow: float, solids: bool = False) -> tuple:
    """The kept links' form factors and visible fractions (link_weights), with the partly
    visible ones (0 < v < 1) that carry more than `shadow` (the oracle's weighting, as `faint`)
    split and refined again, as the element level splits its partly visible links (SPEC §8):
    one visible fraction over a link that a shadow crosses gives every pair of its elements the
    mean (the tessellated Cornell box's blocks). A split link's larger end is split (the other
    where that one is an original); a link between two originals goes to the element level
    (refine_clusters at epsilon 0: a pair of originals if they face each other). Repeats on the
    new links until none is partly visible or all reached the originals. Returns (links, pairs,
    counts, F, v, rays)."""
    solid = solid_ends(caster, ct.elems) if solids and caster is not None and rays > 1 else None
    F, v, nrays = link_weights(ct, links, caster, rays, faint=eps, solid=solid)
    if caster is None or rays <= 1 or not np.isfinite(shadow) or not len(links):
        return links, pairs, counts, F, v, nrays
    t = ct.tree
    rounds, out_pairs = [], [pairs]  # (links, F, v, part) of each round
    counts = np.array(counts, np.int64)
    while len(links):
        part = _partial(links, F, v, t.rho, t.lhat, ct.lref, shadow)
        rounds.append((links, F, v, part))
        if not part.any():
            break
        counts[2] -= int(part.sum())
        kids, both = _split_links(t, links[part])
        for init, e in ((kids, eps), (both, 0.0)):
            if len(init):
                new, npairs, c, _, _ = refine_clusters(t, ct.elems, e, ct.lref,
                                                       max(1024, 8 * len(init)), init, 0)
                counts[:4] += c
                out_pairs.append(npairs)
                if e > 0.0:
                    links = new
        if not len(kids):
            break
        F, v, r = link_weights(ct, links, caster, rays, faint=eps, solid=solid)
        nrays += r
    kept = sum(len(r[3]) - int(r[3].sum()) for r in rounds)
    L_out, F_out, v_out = np.empty((kept, 2), np.int64), np.empty((kept, 2)), np.empty(kept)
    at = 0
    for r in rounds:
        at = _put_kept(*r, at, L_out, F_out, v_out)
    return L_out, np.concatenate(out_pairs).reshape(-1, 2), counts, F_out, v_out, nrays


#: Rays a probed link takes (_probe): a link whose estimate is below PROBE_BAND times epsilon
#: takes PROBE_RAYS rays before it is split; it is dropped where all are blocked and its
#: transfer without visibility is at most PROBE_RAYS epsilon, and kept with its rays' visible
#: fraction where some but not all are blocked and that fraction of its transfer is at most
#: epsilon. 0, no probes: with 4 rays in a band of 4 and dropping only, the rough
#: 2e4-triangle terrain kept 22 % fewer cluster links and 40 % fewer pairs but rendered in 33 s
#: against 25 s (docs/src/design/methods-hierarchical-clusters.md, "Rough surfaces").
PROBE_RAYS = 0
#: The probes' band, in epsilons (0: PROBE_RAYS).
PROBE_BAND = 0.0
#: Probed links partly blocked whose visible share of their transfer is within epsilon are kept
#: (with that share) instead of split.
PROBE_KEEP = True


def probe_band() -> float:
    """The probes' band in epsilons (0 where there are no probes)."""
    return (PROBE_BAND or float(PROBE_RAYS)) if PROBE_RAYS > 0 else 0.0


@numba.njit(cache=True, nogil=True)
def _carried(links, F, rho, lhat, lref):
    """(m,) the light links carry in the oracle's weighting, max(rho_p F_pq Lhat_q, rho_q F_qp
    Lhat_p) / lref."""
    m = links.shape[0]
    out = np.empty(m)
    for a in range(m):
        p, q = links[a, 0], links[a, 1]
        out[a] = max(rho[p] * F[a, 0] * lhat[q], rho[q] * F[a, 1] * lhat[p]) / lref
    return out


def _probe(ct: ClusterTree, links, pairs, counts, caster, eps: float, solids: bool, probes,
           probe: float) -> tuple:
    """Decide the links refine_clusters probed (`probes`: not near, estimate below `probe`):
    PROBE_RAYS rays each (link_weights, every stratum). With c the link's sampled transfer
    without visibility in the oracle's weighting and v its rays' visible fraction:
    - every ray blocked and c at most PROBE_RAYS * eps: dropped (what it loses, its visible
      share times c, is about epsilon at most: a share above 1 / PROBE_RAYS rarely leaves every
      stratified ray blocked);
    - some blocked (0 < v < 1) and c v at most eps: kept as a cluster link with that v (its
      error is within what it carries; PROBE_KEEP), as a link below eps would have been;
    - otherwise split once (_split_links) and refined again, probing again; two originals go
      to the element level.
    On a rough surface most links between its parts are blocked by the bumps between them, so
    whole subtrees of links are never made. Returns (links, pairs, counts + [probed, dropped],
    rays, (links, F, v) of the probed links kept, or None)."""
    counts = np.concatenate([np.asarray(counts, np.int64), np.zeros(2, np.int64)])
    if probes is None or not len(probes) or caster is None:
        return links, pairs, counts, 0, None
    t = ct.tree
    solid = solid_ends(caster, ct.elems) if solids else None
    out_links, out_pairs, nrays = [links], [pairs], 0
    seen_l, seen_F, seen_v = [np.zeros((0, 2), np.int64)], [np.zeros((0, 2))], [np.zeros(0)]
    boxes = caster.occluder_boxes()
    while len(probes):
        # links no segment between their boxes can block (clear_links) are split at once
        ask = np.ones(len(probes), np.bool_) if boxes is None else \
            ~clear_links(t.rec, probes, *boxes)
        drop = np.zeros(len(probes), np.bool_)
        keep = np.zeros(len(probes), np.bool_)
        asked = probes[ask]
        F, v, r = link_weights(ct, asked, caster, PROBE_RAYS, solid=solid)
        nrays += r
        c = _carried(asked, F, t.rho, t.lhat, ct.lref)
        drop[ask] = (v <= 0.0) & (c <= PROBE_RAYS * eps)
        if PROBE_KEEP:
            kept = (v > 0.0) & (v < 1.0) & (c * v <= eps)
            keep[ask] = kept
            seen_l.append(asked[kept])
            seen_F.append(F[kept])
            seen_v.append(v[kept])
            counts[2] += int(kept.sum())
        counts[4] += len(probes)
        counts[5] += int(drop.sum())
        kids, both = _split_links(t, probes[~drop & ~keep])
        if len(both):  # two originals (they face each other: refine_clusters tested it)
            i, j = t.order[t.start[both[:, 0]]], t.order[t.start[both[:, 1]]]
            out_pairs.append(np.stack([np.minimum(i, j), np.maximum(i, j)], 1))
            counts[3] += len(both)
        probes = np.zeros((0, 2), np.int64)
        if len(kids):
            new, npairs, c4, _, probes = refine_clusters(t, ct.elems, eps, ct.lref,
                                                         max(1024, 8 * len(kids)), kids, 0, probe)
            counts[:4] += c4
            out_links.append(new)
            out_pairs.append(npairs)
    seen = (np.concatenate(seen_l).reshape(-1, 2), np.concatenate(seen_F).reshape(-1, 2),
            np.concatenate(seen_v))
    return (np.concatenate(out_links).reshape(-1, 2), np.concatenate(out_pairs).reshape(-1, 2),
            counts, nrays, seen)


def _split_links(t, links: np.ndarray) -> tuple:
    """The links one level below each of `links` (s, 2): its end with more area split into
    its two children (the other end where that one is a leaf or stays whole, t.stop); and the
    links neither of whose ends can split, as they are."""
    p, q = links[:, 0], links[:, 1]
    inner_p, inner_q = (t.left[p] >= 0) & ~t.stop[p], (t.left[q] >= 0) & ~t.stop[q]
    sp = inner_p & (~inner_q | (t.area[p] >= t.area[q]))
    sq = inner_q & ~sp
    kids = [np.stack([t.left[p[sp]], q[sp]], 1), np.stack([t.right[p[sp]], q[sp]], 1),
            np.stack([p[sq], t.left[q[sq]]], 1), np.stack([p[sq], t.right[q[sq]]], 1)]
    return (np.ascontiguousarray(np.concatenate(kids).astype(np.int64)),
            np.ascontiguousarray(links[~inner_p & ~inner_q].astype(np.int64)))


def _caster(inp: ClusterInputs, links: np.ndarray, probes: np.ndarray | None = None):
    """The originals' RayCaster (one per process, cached), None where no ray is needed."""
    if inp.rays <= 0 or not (len(links) or (probes is not None and len(probes))):
        return None
    from radiosity.tracing.rays import caster_for

    return caster_for(inp.key, inp.verts, inp.nverts, inp.ray_offset)


#: Buckets of p in which the driver sorts the cluster links, MERGE_THREADS buckets at a time: the
#: sort's temporaries are those buckets', not all links' (docs/src/design/
#: methods-hierarchical-clusters.md).
SORT_BUCKETS = 32
MERGE_THREADS = 2
#: The driver hands the heap's free pages back once the tasks' results it has copied and freed
#: reach this many bytes (each malloc_trim walks the whole heap: 6 ms after each of the
#: tessellated box's 32 tasks, on the thread that feeds the workers).
TRIM_BYTES = 64 << 20


class _Runs:
    """The tasks' sorted runs of links (keys p K + q, weights g), kept split by bucket of p as
    they arrive, and merged bucket by bucket into the sorted cluster links."""

    def __init__(self, K: np.int64, buckets: int = SORT_BUCKETS):
        self.K = K
        self.bounds = (np.arange(1, buckets, dtype=np.int64) * K // buckets) * K
        self.runs = [[] for _ in range(buckets)]
        self.n = 0

    def add(self, key: np.ndarray, g: np.ndarray) -> None:
        cut = np.concatenate([[0], np.searchsorted(key, self.bounds), [len(key)]])
        for b, (lo, hi) in enumerate(zip(cut[:-1], cut[1:])):
            if hi > lo:  # copies: the task's arrays are freed once split
                self.runs[b].append((key[lo:hi].copy(), g[lo:hi].copy()))
        self.n += len(key)

    def merged(self, chunk: int = 1 << 22,
               threads: int = MERGE_THREADS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(p, q) int32 and g float32 sorted by (p, q), `threads` buckets at a time (numpy's
        sorts and gathers let go of the GIL); each bucket's runs are freed as it is merged,
        and their heap pages handed back (the keys are unique, so the order does not depend on
        the runs' arrival)."""
        from concurrent.futures import ThreadPoolExecutor

        from radiosity.runtime.cluster import trim_malloc

        p = np.empty(self.n, np.int32)
        q = np.empty(self.n, np.int32)
        g = np.empty(self.n, np.float32)
        sizes = [sum(len(r[0]) for r in runs) for runs in self.runs]
        starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

        def one(b):
            runs, self.runs[b] = self.runs[b], []
            if not runs:
                return
            at = int(starts[b])
            key = np.concatenate([r[0] for r in runs])
            gb = np.concatenate([r[1] for r in runs])
            del runs
            order = np.argsort(key, kind="stable")
            g[at:at + len(key)] = gb[order]
            del gb
            for a in range(0, len(key), chunk):
                pa, qa = np.divmod(key[order[a:a + chunk]], self.K)
                p[at + a:at + a + len(pa)], q[at + a:at + a + len(pa)] = pa, qa
            del key, order
            trim_malloc()

        with ThreadPoolExecutor(max(1, threads)) as pool:
            list(pool.map(one, range(len(self.runs))))
        return p, q, g


@dataclass(frozen=True)
class ClusterFigures(StageFigures):
    """The cluster layer's figures (report.json, section "links", under "clusters"): its nodes
    and links, the pairs of originals it leaves to the element links, the oracle's evaluations
    and culls, rays, the mean visible fraction, tasks and times; the link stage adds why it ran
    (or only why not: every other figure None) and what it ran at."""

    OPTIONAL = ("nodes", "links", "pairs_to_elements", "evaluated", "culled_orientation",
                "rays", "visible_mean", "tasks", "time_refine_s", "time_s", "why", "epsilon",
                "unseen_importance", "unseen", "outside_footprint", "probed", "dropped_blocked")
    nodes: int | None = None
    links: int | None = None
    pairs_to_elements: int | None = None
    evaluated: int | None = None
    culled_orientation: int | None = None
    rays: int | None = None
    visible_mean: float | None = None
    tasks: int | None = None
    time_refine_s: float | None = None
    time_s: float | None = None
    why: str | None = None
    epsilon: float | None = None
    unseen_importance: float | None = None
    unseen: int | None = None
    outside_footprint: int | None = None
    probed: int | None = None           # links that took PROBE_RAYS rays before a split (_probe)
    dropped_blocked: int | None = None  # of them, dropped: every ray blocked

    def row(self) -> str:
        """The link stage's summary row "clusters"."""
        if self.links is None:
            return self.why or "off"
        extra = "" if self.epsilon is None else f"; epsilon {self.epsilon:.3g}"
        if self.unseen:
            extra += (f", the light to the {self.unseen} originals no pixel hits weighed "
                      f"{self.unseen_importance:g}")
        return (f"{self.links} cluster links over {self.nodes} nodes, {self.pairs_to_elements} "
                f"pairs of originals refined below them ({self.why}{extra}; {self.time_s:.2f} s)")


class ClusterStage(StageMaster):
    """The cluster layer on the one stage master: the plan refines from the root's self-link
    until the cut (and keeps what it refined to the end), every waiting link's subtree is a
    task_clusters, nothing is stored (no ledger: the layer is made again, in a second or so per
    10^5 links, rather than resumed) and the figures merge the tasks' sorted runs."""

    task = staticmethod(task_clusters)

    def __init__(self, elements, epsilon: float, weights, rays: int, occlusion: bool,
                 ray_offset: float, client, progress: bool, shadow: float, solids: bool,
                 unseen: np.ndarray | None, min_size: float):
        super().__init__(client, progress=progress)
        self.elements, self.epsilon, self.weights = elements, epsilon, weights
        self.rays, self.occlusion, self.ray_offset = rays, occlusion, ray_offset
        self.shadow, self.solids, self.unseen, self.min_size = shadow, solids, unseen, min_size
        self.rest = []  # (pairs, counts, visible sum, rays) of each task
        self.freed = 0  # bytes of the tasks' results copied (runs.add) and freed since a trim

    def keep(self, res) -> None:
        """Copy a task's (or the driver's) sorted run into the merge, free what it held."""
        from radiosity.runtime.cluster import trim_malloc

        key, g, *other = res
        self.runs.add(key, g)
        self.rest.append(other)
        self.freed += key.nbytes + g.nbytes
        if self.freed >= TRIM_BYTES:
            trim_malloc()
            self.freed = 0

    def plan(self) -> StagePlan:
        from dask.base import tokenize

        el, client = self.elements, self.client
        self.ct = ct = cluster_tree(el, *self.weights, unseen=self.unseen, min_size=self.min_size)
        n = len(el)
        root = np.zeros((1, 2), np.int64)
        threads = sum(client.nthreads().values()) if client is not None else 0
        self.inp = inp = ClusterInputs(ct, float(self.epsilon),
                                       int(self.rays) if self.occlusion else 0,
                                       tokenize(el.verts, el.nverts), el.verts, el.nverts,
                                       float(self.ray_offset), float(self.shadow),
                                       bool(self.solids),
                                       probe_band() * float(self.epsilon) if self.occlusion
                                       and self.rays > 0 else 0.0)
        frontier = CUT_PER_TASK * TASKS_PER_THREAD * threads if threads > 1 else 0
        links, pairs, counts, pending, probes = refine_clusters(
            ct.tree, ct.elems, inp.epsilon, ct.lref, max(1024, 8 * n), root, frontier, inp.probe)
        self.runs = _Runs(np.int64(ct.nodes))
        self.keep(_compact(ct, links, pairs, counts, _caster(inp, links, probes), inp.rays,
                           inp.epsilon, inp.shadow, inp.solids, probes, inp.probe))
        del links, pairs
        # every ntasks-th waiting link to a task: neighbours in the breadth-first order are
        # subtrees of one node and cost alike, so contiguous runs make tasks of very unequal
        # cost (docs/src/design/methods-hierarchical-clusters.md, "Tasks")
        ntasks = max(1, len(pending) // CUT_PER_TASK) if len(pending) else 0
        self.cuts = [np.ascontiguousarray(pending[i::ntasks]) for i in range(ntasks)]
        token = tokenize(inp.key, inp.epsilon, inp.rays, ct.lref, inp.shadow, ct.tree.stop,
                         inp.probe, pending) if ntasks else ""
        return StagePlan("clusters", token, "", ntasks, None, "run the render again",
                         window_per_worker=2)

    def inputs(self) -> ClusterInputs:
        return self.inp

    def args(self, task: int, shared) -> tuple:
        return (shared, self.cuts[task])

    def on_result(self, task, result, done) -> None:
        self.keep(result)

    def figures(self, run) -> ClusterFigures:
        import time

        ct, rest, n = self.ct, self.rest, len(self.elements)
        counts = np.sum([x[1] for x in rest], axis=0)
        vsum = sum(x[2] for x in rest)
        nrays = sum(x[3] for x in rest)
        pairs = np.concatenate([x[0] for x in rest]).reshape(-1, 2)
        self.rest = rest = None
        t1 = time.perf_counter()
        # sorted by (p, q): the cluster layer does not depend on the cut or the workers (a
        # merge of the tasks' sorted runs, bucket by bucket)
        order = radix_order(pairs[:, 0] * np.int64(n) + pairs[:, 1], int(n * n).bit_length())
        self.pairs = np.ascontiguousarray(pairs[order]).reshape(-1, 2)
        del order, pairs  # the merge below is the stage's peak of memory
        # two-sided originals: each link's sides (clusters/transport.with_sides)
        self.cl = cl = with_sides(ClusterLinks(ct.parent, ct.leaf_orig, np.asarray(ct.tree.area),
                                               *self.runs.merged()),
                                  ct.tree.axis, ct.tree.center, self.elements.normal,
                                  self.elements.two_sided)
        self.runs = None
        return ClusterFigures(nodes=ct.nodes, links=cl.links,
                              pairs_to_elements=int(len(self.pairs)),
                              evaluated=int(counts[0]), culled_orientation=int(counts[1]),
                              probed=int(counts[4]), dropped_blocked=int(counts[5]),
                              rays=int(nrays),
                              visible_mean=vsum / cl.links if cl.links else 1.0,
                              tasks=len(self.cuts), time_refine_s=round(t1 - self.t_start, 4),
                              time_s=round(time.perf_counter() - self.t_start, 4))


def plan_clusters(elements, epsilon: float, weights, rays: int, occlusion: bool,
                  ray_offset: float, client=None, progress: bool = False,
                  shadow: float = np.inf, solids: bool = False,
                  unseen: np.ndarray | None = None, min_size: float = 0.0):
    """The cluster layer of a link stage: the tree, its refinement at `epsilon` with the oracle's
    weights (wrho, lhat, lref: params.oracle_weights), the kept links' form factors and visible
    fractions (`rays` rays each; 1 when nothing can block; partly visible links that carry
    more than `shadow` refined further: _shadows; `solids`: rays inside solids left out,
    clusters/weights.SolidEnds; nodes wholly `unseen` and at most `min_size` across stay whole
    where they can: clusters/refine.cluster_tree). With a `client`, the refinement is cut
    where CUT_PER_TASK x TASKS_PER_THREAD links per worker thread wait, and every waiting
    link's subtree is a task (refinement, form factors, rays) on the cluster (ClusterStage);
    the links come out sorted, so the result does not depend on the cut or the workers.
    Returns (ClusterLinks, pairs (t, 2) int64 of originals I < J sorted, for the
    element-level refinement; ClusterFigures)."""
    stage = ClusterStage(elements, epsilon, weights, rays, occlusion, ray_offset, client,
                         progress, shadow, solids, unseen, min_size)
    fig = stage.run()
    return stage.cl, stage.pairs, fig
