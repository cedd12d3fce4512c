"""The hierarchical operator (SPEC §8): K = Push Gather Pull over the links, on the M leaves of
the union tree (passes.py has the kernels). With A_p F_pq = A_q F_qp, diag(A) K is symmetric: CG
works. Vectors are (2, C, M) float64 [side, channel, leaf]. Links are read from the store task by
task and kept in the worker's bounded cache (runtime/cache.CACHE); `LinkOperator` runs a pass as
one Dask task per group of link tasks, each pinned to a worker; `LocalLinkOperator` runs the same
task functions in the driver (no round trips, links read once: faster up to
hierarchy.driver-solve-links links). Also here: opening a run's operator (its leaves' vectors:
leaves.py)."""

from __future__ import annotations

import threading

import dask
import numpy as np

from radiosity.errors import RadiosityError, StoreError
from radiosity.methods.base import CAP_MIN, CAP_PRODUCT
from radiosity.runtime.executor import GroupExecutor
from radiosity.methods.hierarchical.clusters.transport import GATHER_PARTS, ClusterGather
from radiosity.methods.hierarchical.solve.passes import (Ends, Geometry, LinkArrays, Nodes, count_ends,
                                                   fill_ends, sum_up, final_gather, gather,
                                                   gs_sweep, linear_gather, linear_push, node_min,
                                                   pull, push)
from radiosity.runtime.packing import pack_groups
from radiosity.runtime.cache import CACHE
from radiosity.runtime.cluster import default_workers, scatterable

LINK_CACHE_KEY = "links"
# The linear final gather takes the point kernel's analytic gradient over a receiver whose
# source lies farther than FG_FAR times both nodes' sizes (and not grazing: passes.FG_FAR_COS2)
# instead of five exact evaluations; 0: never. Measured: docs/src/measurements/hierarchical.md,
# "Hierarchical links".
FG_FAR = 6.0


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
    refinement).

    Row normalisation (stages/solve.normalise_rows) works through `cap` and `cmode`: with
    CAP_MIN a link is scaled by min(cap over the leaves of p, cap over the leaves of q) (the
    pairs' min(cap_a, cap_b) at leaf links); with CAP_PRODUCT (the default cap, leaf by leaf,
    and closed-scene balancing) by d_a d_b, i.e. K -> D K D."""

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
        # what a leaf's radiance weighs in its nodes' means: its area, times the part of it
        # outside solids where some lies inside (stages/solve.py configures it: a node sends its
        # live part's light, as its links' rays see it)
        self.pull_area = self.leaf_area
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
        self.clusters = None  # clusters.ClusterLinks: the layer above the originals, or None
        self._final_layout = None  # the cluster links' final gather layout (final_layout_of)

    def cap_args(self):
        """(mode, node caps (N,), leaf scaling d (M,) or empty) of the current cap."""
        cap = self.cap
        if self.cmode == CAP_PRODUCT:  # closed balancing: K -> D K D
            return 2, np.ones(1), cap
        if np.all(cap == 1.0):
            return 0, np.ones(1), np.zeros(0)
        return 1, node_min(cap, self.lo, self.hi), np.zeros(0)

    def nodes(self) -> Nodes:
        """The union tree as the passes take it (passes.Nodes)."""
        return Nodes(self.parent, self.child, self.noff, self.lo, self.hi, self.orig,
                     self.node_leaf, self.leaf_node)

    def geometry(self) -> Geometry:
        """Areas, polygons, centroids and normals as the passes take them (passes.Geometry)."""
        return Geometry(self.node_area, self.pull_area, self.verts, self.nverts, self.node_center,
                        self.leaf_center, self.normal)


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
    return sum_up(s, parent)


def task_link_arrays(inp: LinkSolveInputs, task: int):
    """The links of one link task as node indices and weights (passes.LinkArrays), verified,
    from this worker's cache or the store: p, q (k,) int32; wpq = F_pq v, wqp = F_qp v (k,);
    sp, sq (k,) int8; v (k,) the visible fractions."""
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
        # with int64; docs/src/measurements/hierarchical.md)
        return LinkArrays(p.astype(np.int32), q.astype(np.int32), links["fpq"] * v,
                          links["fqp"] * v, np.ascontiguousarray(links["sp"]),
                          np.ascontiguousarray(links["sq"]), v)

    return CACHE.get((inp.store_path, inp.token, LINK_CACHE_KEY, task), load,
                     lambda a: sum(x.nbytes for x in a), inp.cache_bytes)


_SCRATCH = threading.local()


def scratch(shape: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Two (2, C, N) node arrays per thread, kept across passes (a fresh array of tens of MiB
    costs more in page faults than the pass's arithmetic: docs/src/measurements/hierarchical.md)."""
    got = getattr(_SCRATCH, "arrays", None)
    if got is None or got[0].shape != shape:
        got = (np.empty(shape), np.empty(shape))
        _SCRATCH.arrays = got
    return got


def task_apply(inp: LinkSolveInputs, task_ids, L: np.ndarray, use_need: bool = True,
               clusters: bool = False):
    """y = K L over the links of these link tasks (pull, gather, push), (2, C, M), with the
    cluster links too if `clusters` (one group of a pass carries them); rows of originals that
    do not gather (inp.need, with use_need) stay 0. Returns (y, link terms)."""
    cap = inp.cap_args()
    S, G = scratch((L.shape[0], L.shape[1], len(inp.parent)))
    G[...] = 0.0
    Lbar = _pull(inp, cap, L, S)
    terms = _gather_tasks(inp, cap, task_ids, Lbar, G)
    if clusters:
        terms += _cluster_gather(inp, Lbar, G)
    return _push(inp, cap, G, L, use_need), terms


def _pull(inp: LinkSolveInputs, cap, L, S):
    """Lbar (2, C, N): the node means of L into S (cap: inp.cap_args())."""
    return pull(L, inp.leaf_node, inp.pull_area, inp.parent, inp.node_area, cap[2], S)


def _gather_tasks(inp: LinkSolveInputs, cap, task_ids, Lbar, G) -> int:
    """G += the gather over the links of these link tasks; returns the link terms."""
    mode, ncap, _ = cap
    terms = 0
    for t in task_ids:
        p, q, wpq, wqp, sp, sq, _ = task_link_arrays(inp, int(t))
        terms += gather(Lbar, p, q, wpq, wqp, sp, sq, G, ncap, mode)
    return terms


def _cluster_gather(inp: LinkSolveInputs, Lbar, G) -> int:
    """G += the cluster links' transfer (front sides) into the originals' roots, from the node
    means Lbar, its parts one after another (clusterlinks.ClusterGather). Returns the link
    terms."""
    cg = _cluster_pass(inp, Lbar)
    if cg is None:
        return 0
    for k in range(GATHER_PARTS):
        cg.part(k)
    return _cluster_push(inp, cg, G)


def _cluster_pass(inp: LinkSolveInputs, Lbar):
    """The cluster links' pass from the node means Lbar (clusterlinks.ClusterGather: its parts
    still to run, then _cluster_push); None without cluster links."""
    cl = inp.clusters
    if cl is None or not cl.links:
        return None
    roots = inp.noff[:-1]
    return ClusterGather(np.ascontiguousarray(Lbar[0][:, roots]), cl.parent, cl.leaf_orig,
                         cl.area, cl.p, cl.q, cl.g,
                         (np.ascontiguousarray(Lbar[1][:, roots]), cl) if cl.two_sided else None)


def _cluster_push(inp: LinkSolveInputs, cg, G) -> int:
    """G += a cluster pass's gathered light at the originals' roots (front sides), its parts
    done; returns the link terms. Not capped: the row caps tame the point kernel near
    contact; cluster links are far field (boxes apart, error below epsilon), and the min of
    the caps over a whole cluster would darken all of its light (the tessellated Cornell box:
    3 %)."""
    roots = inp.noff[:-1]
    Gc = np.zeros((2, G.shape[1], len(roots)))
    terms = cg.push(Gc[0], Gc[1])
    G[0][:, roots] += Gc[0]
    if cg.cl is not None:  # two-sided originals' backs
        G[1][:, roots] += Gc[1]
    return terms


def _push(inp: LinkSolveInputs, cap, G, L, use_need: bool):
    """y (2, C, M) from the gathered G (push; G is consumed), rows that do not gather zeroed."""
    y = np.zeros_like(L)
    push(G, inp.parent, inp.leaf_node, cap[2], y)
    if use_need and len(inp.need):
        y[:, :, ~inp.need[inp.leaf_orig]] = 0.0
    return y


def directed_ends(inp: LinkSolveInputs):
    """Every link end as a directed entry grouped by the original of its target (for
    Gauss-Seidel and the final gather), from all link tasks, by a counting sort (no
    concatenated copies: each costs page faults); cached on the worker. Returns passes.Ends:
    target node and side, source node and side, weight, (n + 1,) offsets per target original,
    visible fraction."""
    def load():
        n = len(inp.noff) - 1
        cnt = np.zeros(n + 1, np.int64)
        for t in range(len(inp.entries)):
            p, q = task_link_arrays(inp, t)[:2]
            count_ends(p, q, inp.orig, cnt)
        ptr = np.zeros(n + 1, np.int64)
        np.cumsum(cnt[:n], out=ptr[1:])
        total = int(ptr[-1])
        tp, sn = np.empty(total, np.int64), np.empty(total, np.int64)
        ts, ss = np.empty(total, np.int64), np.empty(total, np.int64)
        w, v = np.empty(total), np.empty(total)
        cur = ptr[:-1].copy()
        for t in range(len(inp.entries)):
            fill_ends(*task_link_arrays(inp, t), inp.orig, cur, tp, ts, sn, ss, w, v)
        return Ends(tp, ts, sn, ss, w, ptr, v)

    return CACHE.get((inp.store_path, inp.token, LINK_CACHE_KEY, "directed"), load,
                     lambda a: sum(x.nbytes for x in a), inp.cache_bytes)


def cluster_final(inp: LinkSolveInputs, Lbar: np.ndarray, d: np.ndarray, y: np.ndarray,
                  part: tuple = (0, 1)) -> None:
    """y (2, C, M) += the final gather of the cluster links part[0] of part[1] into every leaf
    (front sides; clusterlinks.cluster_final_gather), from the node means Lbar (2, C, N); d
    (M,) leaf scaling (closed balancing), empty for none. Nothing without cluster links."""
    if inp.clusters is None or not inp.clusters.links:
        return
    from radiosity.methods.hierarchical.clusters.transport import cluster_final_gather, push_to_leaves

    cl = inp.clusters
    roots = inp.noff[:-1]
    lay = final_layout_of(inp)
    sides = (np.ascontiguousarray(Lbar[1][:, roots]), cl) if cl.two_sided else None
    fields = cluster_final_gather(np.ascontiguousarray(Lbar[0][:, roots]), cl.parent,
                                  cl.leaf_orig, cl.area, cl.p, cl.q, cl.g, lay, part, sides)
    for s, f in enumerate(fields if sides is not None else [fields]):
        push_to_leaves(f, lay.orig_node, np.ascontiguousarray(inp.node_center[roots]),
                       inp.leaf_orig, inp.leaf_center, d, y[s:s + 1])


def final_layout_of(inp: LinkSolveInputs):
    """The cluster tree's clusterlinks.FinalLayout, built once per inputs (the final gather's
    parts share it)."""
    if inp._final_layout is None:
        from radiosity.methods.hierarchical.clusters.transport import final_layout

        cl = inp.clusters
        roots = inp.noff[:-1]
        inp._final_layout = final_layout(cl.parent, cl.leaf_orig, cl.area,
                                         np.ascontiguousarray(inp.node_center[roots]),
                                         inp.normal, np.ascontiguousarray(inp.node_area[roots]),
                                         np.ascontiguousarray(inp.verts[roots]),
                                         np.ascontiguousarray(inp.nverts[roots]))
    return inp._final_layout


def task_final_gather(inp: LinkSolveInputs, origs: np.ndarray, L: np.ndarray,
                      part: tuple = (0, 1)):
    """The final gather into the leaves of originals `origs`, from the solved L (2, C, M):
    (y (2, C, M), evaluations). linear (linear_gather): link by link from the link tasks as the
    passes hold them; exact (final_gather): over the link ends grouped by target original
    (directed_ends). The cluster links' part `part` (i of k, split by links: the k groups' y add
    up to every cluster link once) goes to the leaves of every original
    (clusterlinks.cluster_final_gather)."""
    mode, ncap, d = inp.cap_args()
    origs = np.asarray(origs, np.int64)
    S, G = scratch((L.shape[0], L.shape[1], len(inp.parent)))
    Lbar = pull(L, inp.leaf_node, inp.pull_area, inp.parent, inp.node_area, d, S)
    y = np.zeros_like(L)
    if inp.fg_mode == "linear":
        sel = np.zeros(len(inp.noff) - 1, np.bool_)
        sel[origs] = True
        G[...] = 0.0
        S1 = np.zeros((L.shape[0], L.shape[1], 3, len(inp.parent)))
        evals = 0
        nodes, geo = inp.nodes(), inp.geometry()
        for t in range(len(inp.entries)):
            evals += linear_gather(Lbar, task_link_arrays(inp, t), sel, nodes, geo, ncap, mode,
                                   G, S1, FG_FAR)
        linear_push(G, S1, origs, inp.noff, inp.parent, inp.node_leaf, inp.leaf_center, d, y)
        del S1
    else:
        evals = final_gather(Lbar, directed_ends(inp), origs, inp.nodes(), inp.geometry(),
                             inp.fg_levels, ncap, mode, d, y)
    cluster_final(inp, Lbar, d, y, part)
    if len(inp.need):
        y[:, :, ~inp.need[inp.leaf_orig]] = 0.0
    return y, evals


def task_gs_sweep(inp: LinkSolveInputs, L, Le, rho):
    """One block Gauss-Seidel sweep (all links on this worker). Returns (L, link terms)."""
    if inp.clusters is not None and inp.clusters.links:
        raise RadiosityError("gauss-seidel sweeps original by original and cannot take cluster "
                             "links: use --solver cg (the default) or jacobi, or "
                             "radiosity.hierarchy.clusters: off")
    ends = directed_ends(inp)
    mode, ncap, d = inp.cap_args()
    if mode == 1:
        ends = ends._replace(w=ends.w * np.minimum(ncap[ends.tp], ncap[ends.sn]))
    L = L.copy()
    S = pull(L, inp.leaf_node, inp.pull_area, inp.parent, inp.node_area, d,
             np.empty((L.shape[0], L.shape[1], len(inp.parent))))
    S *= inp.node_area  # pull returns means; the sweep keeps sums
    terms = gs_sweep(L, Le, rho, S, ends, inp.nodes(), inp.geometry(), d, inp.need)
    return L, terms


# ----------------------------------------------------------------------------- operators

class _Base:
    """What the two operators share: the kernel name (solvers check reciprocity by it), the
    pass and term counters, row_sums and the groups of link tasks."""

    # rows past 1 are capped leaf by leaf (stages/solve.normalise_rows: CAP_PRODUCT, d = 1 / row
    # sum): CAP_MIN's minimum over the leaves below a coarse link would cap all of them for one
    # leaf's row (the Cornell box against Mitsuba: cells 0.97 -> 0.86 %,
    # docs/src/design/methods-hierarchical-rounds.md#inside-solids)
    leaf_caps = True

    def __init__(self, inp: LinkSolveInputs, kernel: str, ngroups: int):
        self.inp = inp
        self.kernel = kernel
        self.terms = 0
        self.passes = 0
        self.sparse = None  # the pairs' near-field corrections: none here (links carry them)
        n = np.asarray(inp.entries[:, 1], np.int64) if len(inp.entries) else np.zeros(0, np.int64)
        self.groups = pack_groups(n + 1, ngroups)  # a task costs its links (+1: never 0)

    def orig_groups(self, k: int) -> list:
        """The originals cut into k groups of about equal leaf counts (final gather)."""
        n = len(self.inp.noff) - 1
        return pack_groups(np.bincount(self.inp.leaf_orig, minlength=n) + 1, k)

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

        cg = _cluster_pass(inp, Lbar)
        ng = len(self.groups)
        # each thread gathers its group's links, then its share of the cluster links' parts:
        # one join a pass (the parts' sums do not depend on who ran them)
        ncl = 0 if cg is None else GATHER_PARTS

        def part(k):
            terms = 0
            if k < ng:
                bufs[k][...] = 0.0
                terms = _gather_tasks(inp, cap, self.groups[k], Lbar, bufs[k])
            for j in range(k, ncl, max(ng, 1)):
                cg.part(j)
            return terms

        self.terms += sum(self._threads(part, list(range(max(ng, 1 if ncl else 0)))))
        G = bufs[0] if bufs else np.zeros(shape)
        for extra in bufs[1:]:
            G += extra
        if cg is not None:
            self.terms += _cluster_push(inp, cg, G)
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
            directed_ends(self.inp)  # built once, before the threads share it
        if self.inp.clusters is not None and self.inp.clusters.links:
            final_layout_of(self.inp)  # the same
        # every group's links read (in its thread) before the threads share them
        self._threads(lambda g: [task_link_arrays(self.inp, int(t)) for t in g], self.groups)
        groups = self.orig_groups(default_workers())
        parts = self._threads(
            lambda ig: task_final_gather(self.inp, ig[1], L, (ig[0], len(groups))),
            list(enumerate(groups)))
        self.evals = sum(e for _, e in parts)
        return sum(y for y, _ in parts)

    def gs_sweep(self, L, Le, rho):
        new, t = task_gs_sweep(self.inp, L, Le, rho)
        self.terms += t
        self.passes += 1
        return new


class LinkOperator(_Base):
    """K by Dask tasks over groups of link tasks, run by runtime.executor.GroupExecutor (each group
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
        for yp, t in self.executor.run(task_apply,
                                       lambda i, Lf: (self.groups[i], Lf, use_need, i == 0),
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
        for yp, e in self.executor.run(task_final_gather,
                                       lambda i, Lf: (groups[i], Lf, (i, len(groups))), (L,),
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
    arrays = ls.read_clusters(token)
    if arrays is not None:
        from radiosity.methods.hierarchical.clusters.transport import ClusterLinks

        inp.clusters = ClusterLinks(**arrays)
    return inp, table, ls.attrs().get("kernel")


def memory_inputs(table: dict, tasks: list, normal: np.ndarray) -> LinkSolveInputs:
    """LinkSolveInputs over link arrays held in memory (one (k,) LINK_DTYPE array per task),
    for in-process use without a store."""
    entries = np.array([[0, len(t), 0] for t in tasks], np.int64).reshape(-1, 3)
    import uuid

    return LinkSolveInputs(table, entries, "memory", f"memory-{uuid.uuid4().hex}", normal,
                           memory=list(tasks))


def open_link_operator(rs, client, where: str, settings):
    """The operator of a run's links: in this process (client None, or where "driver", or
    "auto" with at most hierarchy.driver-solve-links links: no round trips per pass) or a
    LinkOperator over `client` (where "cluster", or "auto" above that). settings: the run's
    settings.Settings. Returns (op, table, elements, partition)."""
    s = settings
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
