"""Hierarchical radiosity links (SPEC §8, --method hierarchical): per pair of original elements,
refine the link of their roots down the split trees until each link carries little light.

A link p <- q between nodes of two originals (scene/splittrees.py) carries the unoccluded form
factors F_pq, F_qp (A_p F_pq = A_q F_qp) and the visible fraction v. One task per pair of
originals I < J that face each other (originals.facing_pairs: nothing n x n), or per stripe of
pairs, run on the one stage master (runtime/stage.py: LinkStage) like the visibility matrix.
Here: the task's inputs, the task plan, the task (links/refine.py's rounds, links/sampling.py's
rays between them), the stage and its figures; the settings are params.py's.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from radiosity.core.arrays import unique
from radiosity.methods.hierarchical.links.nodes import new_table
from radiosity.methods.hierarchical.params import (LinkParams, choose_epsilon, cluster_weights,
                                                   direct_estimate, oracle_weights, resolve_params)
from radiosity.methods.hierarchical.params import ambient
from radiosity.methods.hierarchical.links.refine import (C_EXACT, C_LINKS, C_PAIRS, C_RAYLINKS, C_RAYS,
                                                   C_ROUNDS, COUNTERS, Elements, Entries, Occluders,
                                                   Tree, refine, roots)
from radiosity.methods.hierarchical.clusters.tasks import ClusterFigures, plan_clusters
from radiosity.methods.hierarchical.links.sampling import SolidPoints, clear_pairs, link_fractions
from radiosity.runtime.cluster import scatterable
from radiosity.runtime.monitor import worker_address
from radiosity.runtime.packing import capped_starts, choose_unit
from radiosity.runtime.stage import StageMaster, StagePlan, TaskFigures
from radiosity.tracing.shafts import OccluderTree, node_boxes, occluders

@scatterable
class LinkInputs:
    """Read-only arrays every link task needs (scattered to the workers once).

    The partition's node table (splittrees.TreeNodes, k nodes): t_verts (k, 4, 3), t_nverts
    (k,), t_area (k,), t_center (k, 3), t_lo / t_hi (k, 3) node boxes, t_child (k, 2), t_orig,
    t_depth (k,), t_path (k,) uint64. Per original (n): normal (n, 3), two_sided, root
    (partition node), wrho (n, 2) and lhat (n, 2) the oracle's weights per side, elo / ehi /
    enormal / eoffset / pad: padded occluder boxes and planes (shafts.occluders), verts /
    nverts: polygons (occluders and Embree), key: the Embree cache key; lref: the reference
    radiance of the weights; ray_offset: the rays' self-intersection offset (rays.caster_for,
    radiosity.rays.epsilon; not the refinement's epsilon, which is params.epsilon). ext (k,):
    partition leaves that may be split on demand below the camera's partition: those no pixel
    hits (hit (m,) per sub-element), or without `hit` the one sub-element of an unseen
    original.
    """

    def __init__(self, tree, part, elements, seen, params: LinkParams, weight: str, key: str,
                 ray_offset: float, hit: np.ndarray | None = None):
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
        self.reach = leaves_within_reach(tree, part, self.ext, params.min_size)
        self.wrho, self.lhat, self.lref = oracle_weights(
            elements, weight, direct_estimate(elements, ray_offset) if params.direct else None,
            params.smooth_args())
        # the mean R and floor a source's solved radiance is weighed by in rounds (views/rounds.py):
        # as params.smooth_weights weighs the a-priori one; None: by itself
        sm = params.smooth_args()
        self.smooth = ((ambient(elements, True)[2], sm)
                       if sm is not None and weight in ("bf", "arriving") else None)
        self.elo, self.ehi, self.enormal, self.eoffset, self.pad = occluders(elements)
        self.otree = occluder_tree(elements, self.elo, self.ehi)
        self.verts = elements.verts
        self.nverts = elements.nverts
        self.envert = elements.nverts.astype(np.int64)
        self.key = key
        self.ray_offset = float(ray_offset)
        self.params = params
        self.n = n
        # per partition node and side (k, 2), from refinement rounds (views/rounds.py; refine.Elements):
        # the solved radiance, its spread over the node, the nodes forced to split; (0, 2): none
        self.nhat = np.zeros((0, 2))
        self.nvar = np.zeros((0, 2))
        self.force = np.zeros((0, 2), np.bool_)

    def kernel_arrays(self) -> tuple[Tree, Elements, Occluders]:
        """The arrays as the refinement kernels take them (refine.py's named tuples)."""
        return (Tree(self.t_verts, self.t_nverts, self.t_area, self.t_center, self.t_lo,
                     self.t_hi, self.t_child, self.t_orig, self.t_depth, self.t_path, self.ext),
                Elements(self.normal, self.two_sided, self.wrho, self.lhat, self.lref,
                         self.nhat, self.nvar, self.force),
                Occluders(self.elo, self.ehi, self.verts, self.envert, self.enormal,
                          self.eoffset, self.pad, self.otree))


def occluder_tree(elements, elo: np.ndarray, ehi: np.ndarray, leaf: int = 8) -> OccluderTree:
    """The tree over the originals as occluders (shafts.tree_candidates): node boxes hold their
    padded occluder boxes elo, ehi (shafts.occluders)."""
    from radiosity.scene.originals import build_tree

    t = build_tree(elements.verts, elements.nverts, elements.normal, elements.center,
                   elements.two_sided, leaf=leaf)
    lo, hi = node_boxes(t.left, t.right, t.start, t.end, t.order, elo, ehi)
    return OccluderTree(t.left, t.right, t.start, t.end, t.order, lo, hi)


# ----------------------------------------------------------------------------- the task

#: A pair of originals whose leaves within reach multiply to fewer than this skips the shaft
#: search and leaves its visibility to rays: the search costs about as much as ten links' rays
#: and, between small originals, almost never proves a link visible
#: (docs/src/design/methods-hierarchical-clusters.md).
SHAFT_MIN_LEAVES = 1024


def leaves_within_reach(tree, part, ext: np.ndarray, min_size: float) -> np.ndarray:
    """(n,) float64 per original: how many leaves its refinement can reach, its sub-elements
    plus, for each leaf that may be split on demand (ext), area / min_size^2 - 1."""
    reach = np.diff(part.offsets).astype(np.float64)
    more = np.maximum(np.asarray(tree.area, np.float64)[ext] / max(min_size, 1e-300) ** 2 - 1.0,
                      0.0)
    np.add.at(reach, np.asarray(tree.orig, np.int64)[ext], more)
    return reach


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
    kprm = prm.kernel_params()
    tree, elem, occ = inp.kernel_arrays()
    counts = np.zeros(len(COUNTERS), np.int64)
    counts[C_PAIRS] = len(pairs)
    pairs = np.ascontiguousarray(pairs, np.int64).reshape(-1, 2)
    # room for the roots (one node per original of the pairs) and as many again; refine grows
    # the table when it fills (4 nodes a pair zeroed far more than a task of many pairs uses)
    tab = new_table(max(64, 2 * len(np.unique(pairs)) + 4))
    pmap = np.full(len(inp.t_orig), -1, np.int64)
    rays_only = inp.reach[pairs[:, 0]] * inp.reach[pairs[:, 1]] < SHAFT_MIN_LEAVES
    *ent, pool, cnt = roots(pairs, rays_only, inp.root, pmap, tree, tab, 0, occ, kprm)
    frac = np.full(len(pairs), -1.0)
    solid = SolidPoints(caster, inp.normal, inp.two_sided) \
        if prm.solids and caster is not None and prm.rays > 1 else None
    kept = []
    while len(ent[0]):
        counts[C_ROUNDS] += 1
        tab, cnt, k, w = refine(Entries(*ent, frac), pool, len(pool), tab, cnt, pmap, tree, elem,
                                occ, kprm, counts)
        kept.append(k)
        if not len(w.p):
            break
        # (asked only where a link takes rays: the boxes build the occluders' scene)
        boxes = caster.occluder_boxes() if caster is not None else None
        clear = None if boxes is None else clear_pairs(tab.verts, tab.nverts, w.p, w.q, *boxes)
        f = link_fractions(caster, prm.rays, tab.verts, tab.nverts, tab.center, tab.orig, w.p,
                           w.q, keep_rays, inp.normal if prm.weighted_rays else None, solid,
                           clear)
        counts[C_RAYLINKS] += len(w.p)
        counts[C_RAYS] += (len(w.p) - (0 if clear is None else int(clear.sum()))) * prm.rays
        ent = [w.p, w.q, w.lists[:, 0].copy(), (w.lists[:, 0] + w.lists[:, 1]).copy()]
        frac = f
        pool = w.pool
    kp, kq, kf, kv, ks, kx = (np.concatenate(c) for c in zip(*kept))
    counts[C_EXACT] = int(kx.sum())
    links = np.zeros(len(kp), LINK_DTYPE)
    links["po"], links["pc"] = tab.orig[kp], heap_code(tab.path[kp], tab.depth[kp])
    links["qo"], links["qc"] = tab.orig[kq], heap_code(tab.path[kq], tab.depth[kq])
    links["fpq"], links["fqp"] = kf[:, 0], kf[:, 1]
    links["v"] = kv
    links["sp"], links["sq"] = ks[:, 0], ks[:, 1]
    counts[C_LINKS] = len(links)
    # split-off nodes the links use (the node table adds their ancestors and siblings)
    used = unique(np.concatenate([kp, kq]))
    used = used[tab.pnode[used] < 0]
    nodes = np.zeros(len(used), NODE_DTYPE)
    nodes["o"], nodes["c"] = tab.orig[used], heap_code(tab.path[used], tab.depth[used])
    if polygons:
        return links, nodes, counts, tab.verts[used].copy()
    return links, nodes, counts


def task_links(inp: LinkInputs, pairs: np.ndarray, store_path: str, task: int) -> dict:
    """One link task: refine the pairs, write the links and split-off nodes into the store,
    return {crc, n, nx, counts, start, stop, worker, nodes}."""
    from radiosity.tracing.rays import caster_for
    from radiosity.methods.hierarchical.store import write_links

    t0 = time.time()
    c0 = time.thread_time()
    caster = caster_for(inp.key, inp.verts, inp.nverts, inp.ray_offset)
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
        first = capped_starts(np.ascontiguousarray(pc, np.int64), np.int64(cap))
    else:
        raise ValueError(f"task unit must be block or stripe, got {unit!r}")
    cum = np.concatenate([[0], np.cumsum(pc)])
    cost = (cum[first[1:]] - cum[first[:-1]]).astype(np.int64)
    return pairs, first, cost


# ----------------------------------------------------------------------------- the master

@dataclass(frozen=True)
class LinkPlan:
    """What the master decided before any task runs: the tasks (pairs (t, 2) of originals,
    first (k + 1,), estimated cost (k,)), the task unit, the link settings, the originals the
    camera sees, the sub-elements a pixel hits (hierarchy.split-hidden, else None) and the
    token of everything that determines the links."""

    pairs: np.ndarray
    first: np.ndarray
    cost: np.ndarray
    unit: str
    prm: LinkParams
    weight: str
    epsilon_reason: str
    seen: np.ndarray
    hit: np.ndarray | None
    token: str
    clusters: object = None      # clusters.ClusterLinks, or None without clustering
    cluster_figures: ClusterFigures | None = None


def plan_links(rs, part, el, s, unit: str | None, occlusion: bool, client=None,
               progress: bool = False) -> LinkPlan:
    """The link stage's plan for run store `rs` (its partition, elements) under settings `s`;
    with a `client`, the cluster layer runs as tasks on it (clusters/tasks.plan_clusters)."""
    from dask.base import tokenize

    from radiosity.scene.emitters import AreaEmitters
    from radiosity.scene.originals import FacingPairsError, pairs_within_budget, tree_of
    from radiosity.scene.splittrees import seen_originals

    raster = rs.read_arrays("raster")  # orig, sub: (H, W) per criterion pixel; seen (n,)
    seen = seen_originals(raster["orig"], len(el))  # by the run's own camera
    _, why = choose_epsilon(s, raster["orig"].size)
    prm, weight = resolve_params(el, s, occlusion, pixels=raster["orig"].size)
    unit = s.hierarchy.task_unit if unit is None else unit
    if unit == "auto":
        unit = choose_unit(s.visibility.task_unit, len(el), int(s.visibility.stripe_threshold))
    cl, cfig, cl_inputs = None, None, ()
    on, why_clusters = s.hierarchy.clustered(len(el))
    if not on:  # every facing pair of originals starts a link (SPEC §8), within the budget
        try:
            bi, bj, _ = pairs_within_budget(tree_of(el, int(s.plan.leaf_size)),
                                            int(s.plan.max_facing_pairs),
                                            rs.attrs.get("scene") or rs.run_dir)
            cfig = ClusterFigures(why=why_clusters)
        except FacingPairsError as e:
            if s.hierarchy.clusters in ("off", False):
                raise
            on, why_clusters = True, (f"on: auto, about {e.estimate:.3g} facing pairs of "
                                      f"originals > plan.max-facing-pairs")
    if on:  # links start at the root of the tree over the originals (SPEC §9)
        ce, imp = float(s.hierarchy.clusters_epsilon), float(s.hierarchy.unseen_importance)
        seen_any = raster.get("seen", seen)  # by any camera (older stores: the run's own)
        # no pixel shows them: their clusters stay whole below min-node-size
        outside = ~np.asarray(raster.get("footprint", seen_any), bool)
        est = direct_estimate(el, s.rays.offset) if prm.direct else None  # SPEC §10
        cl, cpairs, cfig = plan_clusters(el, prm.epsilon * ce,
                                         cluster_weights(el, weight, seen_any, imp, est,
                                                         prm.smooth_args()), prm.rays,
                                         occlusion, s.rays.offset, client, progress,
                                         prm.shadow * ce, prm.solids, unseen=outside,
                                         min_size=prm.min_size)
        cfig = dataclasses.replace(cfig, why=why_clusters, epsilon=prm.epsilon * ce,
                                   unseen_importance=imp,
                                   unseen=int((~np.asarray(seen_any, bool)).sum()),
                                   outside_footprint=int(outside.sum()))
        bi, bj = cpairs[:, 0], cpairs[:, 1]
        # what the cluster layer is made from besides the elements and prm (it does not depend
        # on the cut or the workers): hashed instead of its links (0.07 s for 8.9 M)
        cl_inputs = ("clusters", ce, imp, np.asarray(seen_any, bool), outside, occlusion)
    pairs, first, cost = link_plan(part.offsets, bi, bj, unit, int(s.hierarchy.max_task_cost))
    hit = None
    if s.hierarchy.split_hidden:
        sub = raster["sub"]
        hit = np.zeros(len(part), bool)
        hit[sub[sub >= 0]] = True
    token = tokenize(pairs, first, part.center, part.offsets, el.verts, el.reflectance,
                     AreaEmitters(el).radiance(), seen, hit, prm.to_dict(), weight, s.rays.offset,
                     *cl_inputs)
    return LinkPlan(pairs, first, cost, unit, prm, weight, why, seen, hit, token, cl, cfig)


class LinkStage(StageMaster):
    """The link stage on the one stage master: the plan (plan_links: the cluster layer, then
    the pairs of originals and their tasks), LinkInputs, one task_links per task, the store's
    links group as the ledger, then the node table of the union tree and LinkFigures."""

    task = staticmethod(task_links)
    counters = COUNTERS
    monitor_stage = "links"

    def __init__(self, run_dir: str, client, s, unit: str | None, occlusion: bool, **kw):
        super().__init__(client, report_dir=run_dir, **kw)
        self.run_dir, self.s, self.unit, self.occlusion = run_dir, s, unit, occlusion
        self.cpu = [0.0, 0.0, 0.0]  # tasks' thread CPU: refine + rays, writes; refine's wall

    def plan(self) -> StagePlan:
        from radiosity.methods.hierarchical.store import LinkStore
        from radiosity.runtime.store import RunStore
        from radiosity.scene.splittrees import tree_nodes

        s = self.s
        self.rs = rs = RunStore(self.run_dir, "r+")
        self.part, self.el = part, el = rs.load_partition(), rs.load_elements()
        self.lp = lp = plan_links(rs, part, el, s, self.unit, self.occlusion, self.client,
                                  self.progress)
        self.ls = LinkStore(rs)
        self.tree = tree_nodes(part, el)
        self.pairs, self.first, self.token = lp.pairs, lp.first, lp.token
        return StagePlan("links", lp.token, rs.path, len(lp.first) - 1, lp.cost,
                         f"rerun with: radiosity visibility {self.run_dir} --method hierarchical "
                         "--resume", int(s.visibility.window_per_worker),
                         int(s.visibility.retries))

    def create(self) -> None:
        lp = self.lp
        self.rs.drop_after("raster")
        self.ls.create(lp.pairs, lp.first, lp.token,
                       {"params": lp.prm.to_dict(), "weight": lp.weight,
                        "kernel": self.s.hierarchy.kernel, "unit": lp.unit},
                       clusters=None if lp.clusters is None else lp.clusters.arrays())

    def ledger(self):
        return self.ls

    def inputs(self) -> LinkInputs:
        from dask.base import tokenize

        lp, el = self.lp, self.el
        return LinkInputs(self.tree, self.part, el, lp.seen, lp.prm, lp.weight,
                          tokenize(el.verts, el.nverts), self.s.rays.offset, lp.hit)

    def args(self, task: int, shared) -> tuple:
        return (shared, self.pairs[self.first[task]:self.first[task + 1]], self.rs.path, task)

    def on_result(self, task, result, done) -> None:
        if self.monitor is not None:
            self.monitor.links(self.pairs, self.first, done, len(self.el))
        for k, v in enumerate(result["cpu"]):
            self.cpu[k] += v

    def figures(self, run) -> "LinkFigures":
        if self.monitor is not None:
            self.monitor.links(self.pairs, self.first, run.done, len(self.el), force=True)
        t_nodes = time.perf_counter()
        table, split = node_table_of(self.rs, self.tree, self.part, run.done,
                                     len(self.first) - 1, self.token)
        t_nodes = time.perf_counter() - t_nodes
        return link_figures(self.s, self.lp, run, len(self.part), table, split, self.cpu,
                            self.occlusion, self.client, self.t_start, t_nodes)


def compute_links(run_dir: str, client, settings, *, unit: str | None = None,
                  resume: bool = False, progress: bool = True, on_done=None,
                  occlusion: bool = True) -> "LinkFigures":
    """The link stage on the one stage master (runtime/stage.py): a bounded window of link
    tasks per worker thread, most expensive first, failed tasks resubmitted, every finished task
    recorded with its crc so `resume` recomputes only what is missing or corrupted; then the node
    table of the union tree. settings: the run's settings.Settings (hierarchy.kernel,
    epsilon, link-rays, ...). Writes section "links" of report.json and
    returns its figures."""
    return LinkStage(run_dir, client, settings, unit, occlusion, resume=resume,
                     progress=progress, on_done=on_done).run()


def node_table_of(rs, tree, part, done: dict, ntasks: int, token: str):
    """The node table of the finished links (the partition's trees and every node split off
    below it), written to the store; returns (table, split-off nodes (j,) NODE_DTYPE)."""
    from radiosity.methods.hierarchical.store import LinkStore, NODE_DTYPE, read_links
    from radiosity.scene.splittrees import node_table

    xs = [done[t]["nodes"] if "nodes" in done[t] else read_links(rs.path, t, done[t])[1]
          for t in range(ntasks) if done[t]["nx"]]
    xn = np.concatenate(xs) if xs else np.zeros(0, NODE_DTYPE)
    table = node_table(tree, part, xn["o"], xn["c"])
    LinkStore(rs).write_nodes(table.arrays(), {"token": token})
    return table, xn


@dataclass(frozen=True)
class LinkFigures(TaskFigures):
    """The link stage's figures (report.json, section "links"); the counters are the tasks'
    (refine.COUNTERS) summed; clusters: the cluster layer's (clusters/tasks.ClusterFigures)."""

    SECTION = "links"
    method: str
    task_unit: str
    tasks: int
    sub_elements: int
    nodes: int
    leaves: int
    split_off_nodes: int
    originals_split: int
    pairs: int
    links: int
    evaluated: int
    refined: int
    dropped_orientation: int
    shaft_visible: int
    shaft_blocked: int
    ray_links: int
    rays: int
    ray_blocked: int
    partial_refined: int
    exact: int
    rounds: int
    links_per_leaf: float
    bytes_per_link: int
    link_bytes: int
    epsilon: float
    epsilon_reason: str
    link_rays: int
    weight: str
    min_node_size: float
    kernel: str
    rays_per_s: float
    cpu_refine_s: float
    cpu_write_s: float
    wall_refine_s: float
    occlusion: bool
    clusters: ClusterFigures | None
    cluster_links: int
    peak_rss_mb: dict
    time_s: float
    time_node_table_s: float
    hull_visible: int = 0
    hull_blocked: int = 0

    def rows(self):
        return [("sub-elements", f"{self.sub_elements} ({self.leaves} leaves, "
                                 f"{self.split_off_nodes} nodes split below the camera's "
                                 "partition)"),
                ("epsilon", f"{self.epsilon:.3g} ({self.epsilon_reason})"),
                ("links", f"{self.links} ({self.links_per_leaf:.1f} per leaf, "
                          f"{self.bytes_per_link} bytes each)"),
                ("clusters", "off" if self.clusters is None else self.clusters.row()),
                ("proven by shafts", f"{self.shaft_visible + self.hull_visible} visible, "
                                     f"{self.shaft_blocked + self.hull_blocked} blocked (no "
                                     "ray" + (f"; {self.hull_visible + self.hull_blocked} by "
                                              "the polygons' tight shafts)"
                                              if self.hull_visible + self.hull_blocked
                                              else ")")),
                ("rays cast", f"{self.rays} ({self.link_rays} per link on {self.ray_links} "
                              "links)"),
                ("tasks", f"{self.tasks} ({self.task_unit}), {self.tasks_reused} reused"),
                ("time", f"{self.time_s:.2f} s")]


def link_figures(s, lp: LinkPlan, run, sub_elements: int, table, xn, cpu: list, occlusion: bool,
                 client, t_start: float, t_nodes: float) -> LinkFigures:
    """The link stage's figures: the plan, the stage run (runtime/stage.StageRun), the node
    table and split-off nodes xn, the tasks' CPU seconds [refine + rays, writes, refine's wall],
    the stage's start (perf_counter) and the node table's seconds."""
    from radiosity.methods.hierarchical.store import LINK_DTYPE
    from radiosity.runtime.monitor import peak_rss_mb

    c = dict(zip(COUNTERS, run.counts.tolist()))
    wall = run.wall_s
    nclusters = 0 if lp.clusters is None else lp.clusters.links
    return LinkFigures(
        method="hierarchical", task_unit=lp.unit, tasks=len(lp.first) - 1, **run.figures(),
        sub_elements=sub_elements, nodes=len(table), leaves=table.leaves,
        split_off_nodes=c["split_off_nodes"],  # made by the tasks (the counter, as before)
        originals_split=int(len(np.unique(xn["o"]))),  # below the camera's partition
        pairs=c["pairs"], links=c["links"], evaluated=c["evaluated"], refined=c["refined"],
        dropped_orientation=c["dropped_orientation"], shaft_visible=c["shaft_visible"],
        shaft_blocked=c["shaft_blocked"], ray_links=c["ray_links"], rays=c["rays"],
        ray_blocked=c["ray_blocked"], partial_refined=c["partial_refined"], exact=c["exact"],
        rounds=c["rounds"], hull_visible=c["hull_visible"], hull_blocked=c["hull_blocked"],
        links_per_leaf=(c["links"] + nclusters) / max(1, table.leaves),
        bytes_per_link=LINK_DTYPE.itemsize, link_bytes=c["links"] * LINK_DTYPE.itemsize,
        epsilon=lp.prm.epsilon, epsilon_reason=lp.epsilon_reason, link_rays=lp.prm.rays,
        weight=lp.weight, min_node_size=lp.prm.min_size, kernel=s.hierarchy.kernel,
        rays_per_s=c["rays"] / wall if wall > 0 else 0.0,
        cpu_refine_s=round(cpu[0], 4), cpu_write_s=round(cpu[1], 4),
        wall_refine_s=round(cpu[2], 4), occlusion=occlusion, clusters=lp.cluster_figures,
        cluster_links=nclusters, peak_rss_mb=peak_rss_mb(client),
        time_s=round(time.perf_counter() - t_start, 4), time_node_table_s=round(t_nodes, 4))
