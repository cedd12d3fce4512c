"""Refinement by the solved radiance (issue 26; Hanrahan, Salzman & Aupperle 1991's "BF
refinement"; SPEC §8): the link oracle weighs a link p <- q by rho_p F_pq L_q / lref with an
a-priori radiance L_q (emission plus an ambient term: params.oracle_weights), which does not know
where indirect light goes. After a first solve, rounds weigh the links by the solved radiance:

1. per node of the partition's split trees and side, the solved radiance (the area-weighted
   mean of its sub-elements, largest channel) divided by hierarchy.rounds-epsilon (the solved
   test's target as a multiple of epsilon), and never below the a-priori weight nor below the
   weight already used: the oracle's weights only rise, so the refinement of a pair only
   deepens (links/refine._refine_loop takes them as nhat); with them the spread of that radiance
   over each node (nvar: a source splits while rho F dL exceeds epsilon) and the nodes above
   leaves whose rows of F v summed past 1 + hierarchy.rounds-row-excess (force: their
   visibility was taken too coarsely, and the solve's cap of those rows loses light);
2. every stored link gets the oracle's error estimate again under the old and the new weights
   and spreads (links_to_refine, from the node table's polygons); a link task is made again,
   with the new weights, when one of its links would now be split (estimate above epsilon, or
   partly visible above the shadow threshold, with a node that can split) and its estimate
   rose by more than hierarchy.rounds-change times the target, or when it holds a pair of an
   original with newly forced nodes. The other tasks keep their links (the
   stage's resume: only the tasks taken out of the manifest run). A task holds whole pairs of
   originals and starts again from their root links (the oracle is deterministic: what met
   the target under the new weights comes out as before);
3. the node table is rebuilt and the system solved again from the previous solution (warm
   start: warm_start), until no link is picked or after hierarchy.rounds rounds; only the last
   solve does the final gather.

The loop of solves and rounds is stages/rounds.solve_with_rounds (a method does not call the
solve stage). The links stay in the store as the link stage writes them (the plan's token
changes to one that names the round), so views, exports and tables read them as any run's.
Design and measurements: docs/src/design/methods-hierarchical-rounds.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np

from radiosity.errors import RadiosityError
from radiosity.methods.hierarchical.links.formfactors import disc_spread
from radiosity.scene.emitters import AreaEmitters
from radiosity.methods.hierarchical.links.master import LinkStage
from radiosity.runtime.stage import StagePlan
from radiosity.runtime.store import StageFigures


#: rounds_of's count for hierarchy.rounds auto (auto_rounds decides after the first solve)
AUTO = -1


def rounds_of(settings) -> tuple[int, float, float]:
    """(rounds, epsilon factor, change) of hierarchy.rounds (AUTO for auto), rounds-epsilon,
    rounds-change, checked."""
    h = settings.hierarchy
    if h.rounds == "auto":
        f, c = float(h.rounds_epsilon), float(h.rounds_change)
        if not f > 0 or not c >= 0 or not float(h.rounds_auto_ratio) > 0 \
                or not 0 <= float(h.rounds_auto_share) <= 1:
            raise RadiosityError(f"radiosity.hierarchy.rounds-epsilon must be > 0, rounds-change "
                                 f">= 0, rounds-auto-ratio > 0 and rounds-auto-share in [0, 1], "
                                 f"got {f}, {c}, {h.rounds_auto_ratio}, {h.rounds_auto_share}")
        return AUTO, f, c
    try:
        n, f, c = int(h.rounds), float(h.rounds_epsilon), float(h.rounds_change)
    except (TypeError, ValueError):
        raise RadiosityError(f"radiosity.hierarchy.rounds (a number or auto), rounds-epsilon and "
                             f"rounds-change must be numbers, got {h.rounds!r}, "
                             f"{h.rounds_epsilon!r}, {h.rounds_change!r}") from None
    if n < 0 or not f > 0 or not c >= 0:
        raise RadiosityError(f"radiosity.hierarchy.rounds must be >= 0, rounds-epsilon > 0 and "
                             f"rounds-change >= 0, got {n}, {f}, {c}")
    return n, f, c


def hot_share(rs, weight: str, ratio: float, radiance: np.ndarray | None = None,
              direct: np.ndarray | None = None) -> float:
    """The share of the solved reflected power (sub-elements' area times the largest channel of
    their reflected radiance, both sides) that leaves sub-elements whose reflected radiance is
    more than `ratio` times the a-priori estimate the oracle weighed their links with (the
    ambient term of params.oracle_weights; `weight` none: the oracle weighs no radiance, 0).
    radiance (m, 2, C) per sub-element; None: the run's solution/radiance. direct (n, 2): the
    emitters' light at points (params.direct_estimate, SPEC §10): `radiance` is then R, the
    light after the emitters', and the estimate the first bounce plus the ambient term."""
    from radiosity.methods.hierarchical.params import oracle_weights

    if weight != "bf":
        return 0.0
    el = rs.load_elements()
    part = rs.read_arrays("partition")
    if radiance is None:
        radiance = previous_solution(rs)["radiance"]
    o = np.asarray(part["orig"], np.int64)
    _, lhat, _ = oracle_weights(el, weight, direct)
    em = np.asarray(AreaEmitters(el).peak(), np.float64)
    if direct is not None:  # R holds no emission, nor does lhat
        em = np.zeros_like(em)
    refl = np.maximum(np.asarray(radiance).max(axis=2) - em[o], 0.0)  # (m, 2)
    power = np.asarray(part["area"], np.float64)[:, None] * refl
    total = power.sum()
    if not total > 0:
        return 0.0
    ambient = np.maximum(lhat - em, 0.0)[o]
    return float(power[refl > ratio * ambient].sum() / total)


def auto_rounds(rs, settings, radiance: np.ndarray | None = None) -> tuple[int, str]:
    """hierarchy.rounds auto after the first solve: (1, why) where more than rounds-auto-share of
    the reflected light leaves sub-elements over rounds-auto-ratio times brighter than the
    a-priori estimate (hot_share: the a-priori weights were wrong there, as in a room lit by
    light bounced off its ceiling), else (0, why). radiance: as hot_share takes it."""
    h = settings.hierarchy
    ratio, share = float(h.rounds_auto_ratio), float(h.rounds_auto_share)
    if rs.has("clusters"):  # the links start at clusters, which rounds leave as they are
        return 0, ("auto: none: the links start at clusters above the originals, which rounds "
                   "do not refine")
    from radiosity.methods.hierarchical.params import choose_direct, direct_estimate

    el = rs.load_elements()
    est = direct_estimate(el, settings.rays.offset) \
        if choose_direct(el, settings)[0] == "points" else None
    got = hot_share(rs, h.weight, ratio, radiance, est)
    on = got > share
    return int(on), (f"auto: {'one round' if on else 'none'}: {got:.0%} of the reflected light "
                     f"leaves surfaces over {ratio:g}x brighter than the a-priori estimate "
                     f"({'above' if on else 'not above'} rounds-auto-share {share:g})")


def node_radiance(tree, area: np.ndarray, radiance: np.ndarray) -> np.ndarray:
    """(k, 2): per node of the partition's split trees (splittrees.TreeNodes: its sub-elements
    lo:hi) and side, the largest channel of the area-weighted mean of the sub-elements'
    radiance (m, 2, C)."""
    w = area[:, None, None] * radiance
    cs = np.concatenate([np.zeros((1,) + w.shape[1:]), np.cumsum(w, axis=0)])
    ca = np.concatenate([[0.0], np.cumsum(area)])
    lo, hi = np.asarray(tree.lo, np.int64), np.asarray(tree.hi, np.int64)
    a = ca[hi] - ca[lo]
    mean = (cs[hi] - cs[lo]) / np.where(a > 0, a, 1.0)[:, None, None]
    return mean.max(axis=2)


def previous_solution(rs) -> dict:
    """The run's solution and node table, read once for a round and the warm start after it:
    radiance per sub-element (m, 2, C), per leaf (M, 2, C), the leaves' names (original, node
    code), their rows of F v before scaling (M, 2; None where the solve kept none) and the
    solve's row mode, and the node table ("table": the hierarchy group's arrays). With the
    emitters' light at points (the solution's attrs say direct: points), "radiance" is R, the
    light after the emitters' as leaf_radiance is: the rounds weigh links by what they carry
    and the warm start starts from the solve's own unknowns."""
    sol = rs.read_arrays("solution")
    t = rs.read_arrays("hierarchy")
    leaf = t["leaf_node"]
    radiance = sol["radiance"]
    if rs.group_attrs("solution").get("direct") == "points":
        orig = rs.read_arrays("partition")["orig"]
        radiance = radiance - AreaEmitters(rs.load_elements()).radiance(orig)[..., :radiance.shape[2]]
    return {"radiance": radiance, "leaf_radiance": sol["leaf_radiance"],
            "orig": t["orig"][leaf], "code": t["code"][leaf], "leaf_rows": sol.get("leaf_rows"),
            "row_mode": (rs.group_attrs("solution").get("row_sums") or {}).get("mode"),
            "table": t}


def warm_start(prev: dict):
    """x0 for run_solve (previous_solution's `prev`): each leaf of the opened hierarchical
    method starts at its own previous radiance when it was a leaf before, else at the previous
    radiance of its sub-element."""
    def x0(opened):
        t = opened.state["table"]
        leaf = t["leaf_node"]
        out = np.array(prev["radiance"][t["leaf_sub"]], dtype=float)  # (M, 2, C)
        where = {(int(o), int(c)): i for i, (o, c) in enumerate(zip(prev["orig"], prev["code"]))}
        lr = prev["leaf_radiance"]
        for j, (o, c) in enumerate(zip(t["orig"][leaf].tolist(), t["code"][leaf].tolist())):
            i = where.get((o, c))
            if i is not None:
                out[j] = lr[i]
        return np.ascontiguousarray(np.transpose(out, (1, 2, 0)))

    return x0


@numba.njit(cache=True, nogil=True)
def _weighted(a, b, sa, sb, V, NV, A, C, orig, normal, wrho, wnode, vnode, can, lref, oracle,
              far_polygon):
    """(transfer, error estimate) of link a <- b (sides sa, sb) under the node weights wnode
    and radiance spreads vnode (N, 2): refine._refine_loop's, from the node table's
    polygons."""
    op, oq = orig[a], orig[b]
    gp = 1.0 if sa == 0 else -1.0
    gq = 1.0 if sb == 0 else -1.0
    npx, npy, npz = normal[op, 0], normal[op, 1], normal[op, 2]
    nqx, nqy, nqz = normal[oq, 0], normal[oq, 1], normal[oq, 2]
    dx, dy, dz = C[b, 0] - C[a, 0], C[b, 1] - C[a, 1], C[b, 2] - C[a, 2]
    r2 = dx * dx + dy * dy + dz * dz + 1e-300
    g = abs((npx * dx + npy * dy + npz * dz) * (nqx * dx + nqy * dy + nqz * dz))
    Ap, Aq = A[a], A[b]
    fpq = Aq * g / (r2 * (np.pi * r2 + Aq))
    fqp = Ap * g / (r2 * (np.pi * r2 + Ap))
    wpq = wrho[op, sa] * wnode[b, sb] / lref
    wqp = wrho[oq, sb] * wnode[a, sa] / lref
    amount = max(fpq * wpq, fqp * wqp)
    if oracle == 0:
        return amount, amount
    if oracle == 1:
        return amount, amount * ((np.sqrt(Ap) if can[a] else 0.0)
                                 + (np.sqrt(Aq) if can[b] else 0.0)) / np.sqrt(r2)
    ep = eq = 0.0
    if can[a]:
        big, curv = disc_spread(V, a, NV[a], gp * npx, gp * npy, gp * npz, C, b, gq * nqx,
                            gq * nqy, gq * nqz, Aq, fpq)
        ep = wpq * big
        if Ap <= Aq or not far_polygon:
            ep += max(wpq, wqp) * curv
    if can[b]:
        big, curv = disc_spread(V, b, NV[b], gq * nqx, gq * nqy, gq * nqz, C, a, gp * npx,
                            gp * npy, gp * npz, Ap, fqp)
        eq = wqp * big
        if Aq < Ap or not far_polygon:
            eq += max(wpq, wqp) * curv
    # the source's spread of solved radiance (refine: rho_p F_pq dL_q)
    vq = wrho[op, sa] * fpq * vnode[b, sb] / lref if can[b] else 0.0
    vp = wrho[oq, sb] * fqp * vnode[a, sa] / lref if can[a] else 0.0
    return amount, max(ep, eq, vq, vp)


@numba.njit(cache=True, nogil=True)
def links_to_refine(p, q, sp, sq, v, V, NV, A, C, orig, normal, wrho, old, new, vold, vnew,
                    can, lref, eps, shadow, change, oracle, far_polygon):
    """(k,) bool: the stored links p <- q (node table indices, sides, visible fractions) that
    the oracle would split under the new node weights and spreads (k nodes, 2) and whose
    estimate grew by more than `change` times its target since the old ones: error above
    epsilon, or partly visible with a transfer above `shadow`, and a node that can split."""
    out = np.zeros(p.shape[0], np.bool_)
    for k in range(p.shape[0]):
        a, b = p[k], q[k]
        if not (can[a] or can[b]):
            continue
        am1, e1 = _weighted(a, b, sp[k], sq[k], V, NV, A, C, orig, normal, wrho, new, vnew, can,
                            lref, oracle, far_polygon)
        am0, e0 = _weighted(a, b, sp[k], sq[k], V, NV, A, C, orig, normal, wrho, old, vold, can,
                            lref, oracle, far_polygon)
        if 0.0 < v[k] < 1.0:
            out[k] = am1 > shadow and am1 - am0 > change * shadow
        else:
            out[k] = e1 > eps and e1 - e0 > change * eps
    return out


class Rounds:
    """The state of the rounds of one run: the weights the links were made with per partition
    node (k, 2), the a-priori ones, and the figures of each round."""

    def __init__(self, run_dir: str, settings, unit=None, occlusion: bool = True):
        from radiosity.methods.hierarchical.links.master import LinkInputs, plan_links
        from radiosity.runtime.store import RunStore
        from radiosity.scene.splittrees import tree_nodes

        self.run_dir, self.s, self.unit, self.occlusion = run_dir, settings, unit, occlusion
        self.rounds, self.factor, self.change = rounds_of(settings)
        rs = RunStore(run_dir)
        self.part, self.el = rs.load_partition(), rs.load_elements()
        self.tree = tree_nodes(self.part, self.el)
        self.lp = plan_links(rs, self.part, self.el, settings, unit, occlusion)
        # the stored task plan is the one the rounds refine (the same as lp's unless a
        # setting changed since the link stage)
        from radiosity.methods.hierarchical.store import LinkStore

        self.pairs, self.first = LinkStore(rs).plan()
        same = (np.array_equal(self.pairs, self.lp.pairs)
                and np.array_equal(self.first, self.lp.first))
        self.cost = self.lp.cost if same else np.diff(self.first).astype(np.int64)
        from dask.base import tokenize

        k = int(settings.hierarchy.rounds_rays) or self.lp.prm.rays
        if k < 1 or int(round(np.sqrt(k))) ** 2 != k:
            raise RadiosityError(f"radiosity.hierarchy.rounds-rays must be 0 or a square (1, 4, "
                                 f"9, 16, ...), got {k}")
        import dataclasses

        prm = dataclasses.replace(self.lp.prm, rays=k)  # the rays of the links made again
        self.inp = LinkInputs(self.tree, self.part, self.el, self.lp.seen, prm,
                              self.lp.weight, tokenize(self.el.verts, self.el.nverts),
                              settings.rays.offset, self.lp.hit)
        self.apriori = self.inp.lhat[np.asarray(self.tree.orig, np.int64)]  # (k, 2)
        self.used = self.apriori.copy()
        self.used_var = np.zeros_like(self.used)
        self.force = np.zeros(self.used.shape, np.bool_)
        self.excess = float(settings.hierarchy.rounds_row_excess)
        if not self.excess >= 0:
            raise RadiosityError(f"radiosity.hierarchy.rounds-row-excess must be >= 0, got "
                                 f"{settings.hierarchy.rounds_row_excess!r}")
        self.figures: list[RoundFigures] = []

    def weights(self, radiance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The new weights and spreads (k, 2) from the solved radiance per sub-element (m, 2,
        C): the solved node radiance / rounds-epsilon, and half the difference of its two
        children's (0 at the partition's leaves), each never below what was used so far."""
        solved = node_radiance(self.tree, self.part.area, radiance)
        if self.inp.smooth is not None:  # weighed as the a-priori ones (params.smooth_weights)
            from radiosity.methods.hierarchical.params import smooth_source

            solved = smooth_source(solved, *self.inp.smooth)
        solved = solved / self.factor
        ch = np.asarray(self.tree.child, np.int64)
        inner = ch[:, 0] >= 0
        var = np.zeros_like(solved)
        var[inner] = 0.5 * np.abs(solved[ch[inner, 0]] - solved[ch[inner, 1]])
        return np.maximum(self.used, solved), np.maximum(self.used_var, var)

    def row_flags(self, prev: dict) -> np.ndarray:
        """(k, 2) bool: the partition nodes (and sides) above a leaf whose row of F v summed
        past 1 + rounds-row-excess in the last solve (previous_solution's leaf_rows, before the
        rows were capped): a row past 1 proves that some of its links' visibility or form factors were
        taken too large, as where a coarse node's rays pass an occluder's edge that hides part of
        it (a lamp just under a ceiling). Split-off leaves count for the partition node they
        were split off below. Only where the solve capped its rows (an open scene): a closed
        one's are balanced to their targets, which loses nothing."""
        out = np.zeros(self.used.shape, np.bool_)
        if prev["row_mode"] not in ("cap", "open") or prev["leaf_rows"] is None:
            return out
        rows, t = np.asarray(prev["leaf_rows"]), prev["table"]
        leaf, side = np.nonzero(rows > 1.0 + self.excess)
        node = np.asarray(t["leaf_node"])[leaf]
        tpar, pnode = np.asarray(t["parent"]), np.asarray(t["pnode"])
        while np.any(pnode[node] < 0):  # up to the partition
            up = pnode[node] < 0
            node[up] = tpar[node[up]]
        k = pnode[node]
        par = np.asarray(self.tree.parent, np.int64)
        while len(k):  # and every partition node above
            out[k, side] = True
            keep = par[k] >= 0
            k, side = par[k[keep]], side[keep]
            new = ~out[k, side]
            k, side = k[new], side[new]
        return out

    def tasks(self, new: np.ndarray, var: np.ndarray, force: np.ndarray,
              t: dict) -> tuple[np.ndarray, np.ndarray]:
        """(the link tasks to refine again, the originals whose links they hold): those with a
        stored link that the oracle would split under the new weights and spreads and whose
        error estimate grew by more than rounds-change times the target (links_to_refine), and
        those holding a pair of an original with nodes newly forced to split. t: the run's node
        table (previous_solution's)."""
        from radiosity.core.geometry import polygon_properties
        from radiosity.methods.hierarchical.store import LinkStore, read_links
        from radiosity.runtime.store import RunStore
        from radiosity.scene.splittrees import MAX_DEPTH, find_codes

        rs = RunStore(self.run_dir)
        ls = LinkStore(rs)
        done = ls.finished(ls.token())
        orig, path = t["orig"].astype(np.int64), t["path"]
        depth, noff, pnode = t["depth"].astype(np.int64), t["noff"].astype(np.int64), t["pnode"]
        V, NV = t["verts"], t["nverts"].astype(np.int64)
        A, _, C = polygon_properties(V, t["nverts"])
        inp, prm = self.inp, self.lp.prm
        # can a node split (links/nodes.copy_tree_node, and split-off nodes)?
        pn = np.maximum(pnode, 0)
        can = np.where(pnode >= 0,
                       (inp.t_child[pn, 0] >= 0) | (inp.ext[pn] & (np.sqrt(inp.t_area[pn])
                                                                   > prm.min_size)
                                                    & (inp.t_depth[pn] < MAX_DEPTH)),
                       (np.sqrt(A) > prm.min_size) & (depth < MAX_DEPTH))
        # node weights as the kernel takes them: partition nodes nhat, split-off nodes lhat
        per_orig = inp.lhat[orig]
        old = np.where((pnode >= 0)[:, None], self.used[pn], per_orig)
        nw = np.where((pnode >= 0)[:, None], new[pn], per_orig)
        vold = np.where((pnode >= 0)[:, None], self.used_var[pn], 0.0)
        vnew = np.where((pnode >= 0)[:, None], var[pn], 0.0)
        touched = np.zeros(len(self.el), bool)
        forced = np.unique(np.asarray(self.tree.orig)[(force & ~self.force).any(axis=1)])
        hold = np.isin(self.pairs[:, 0], forced) | np.isin(self.pairs[:, 1], forced)
        todo = set((np.searchsorted(self.first, np.nonzero(hold)[0], side="right") - 1).tolist())
        for task in sorted(done):
            if task in todo:
                continue
            links, _ = read_links(rs.path, task, done[task])
            p = find_codes(orig, path, depth, noff, links["po"].astype(np.int64), links["pc"])
            q = find_codes(orig, path, depth, noff, links["qo"].astype(np.int64), links["qc"])
            hit = links_to_refine(p, q, links["sp"].astype(np.int64),
                                  links["sq"].astype(np.int64), links["v"].astype(np.float64),
                                  V, NV, A, C, orig, inp.normal, inp.wrho, old, nw, vold, vnew,
                                  can.astype(np.bool_), float(inp.lref), prm.epsilon, prm.shadow,
                                  self.change, prm.oracle, prm.far_polygon)
            if hit.any():
                todo.add(task)
        todo = np.array(sorted(todo), np.int64)
        for t in todo:  # the originals whose links are made again
            touched[self.pairs[self.first[t]:self.first[t + 1]].ravel()] = True
        return todo, touched

    def refine(self, client, prev: dict, progress: bool = False) -> "RoundFigures":
        """One round from the last solve (previous_solution's `prev`): new weights and spreads
        from the solved radiance, the nodes above rows past one forced, the link tasks they
        raise refined again (RoundStage), the node table rebuilt. Returns the round's figures
        (tasks 0: nothing to refine)."""
        from dask.base import tokenize

        from radiosity.methods.hierarchical.store import LinkStore
        from radiosity.runtime.store import RunStore

        t0 = time.perf_counter()
        new, var = self.weights(prev["radiance"])
        force = self.force | self.row_flags(prev)
        todo, raised = self.tasks(new, var, force, prev["table"])
        head = dict(round=len(self.figures) + 1, originals=int(raised.sum()), tasks=int(len(todo)),
                    forced_nodes=int(force.sum()))
        # what the links not made again were checked against, too
        self.used, self.used_var, self.force = new, var, force
        if not len(todo):
            fig = RoundFigures(**head, time_s=round(time.perf_counter() - t0, 4))
            self.figures.append(fig)
            return fig
        rs = RunStore(self.run_dir, "r+")
        ls = LinkStore(rs)
        old = ls.token()
        token = tokenize(old, "rounds", head["round"], new)
        done = ls.finished(old)
        keep = {t: e for t, e in done.items() if t not in set(todo.tolist())}
        # the plan's token names the round: the stage's resume keeps the other tasks
        rs.root["links"].update_attributes({"token": token})
        if "clusters" in rs.root:
            rs.root["clusters"].update_attributes({"token": token})
        ls.rewrite_manifest(token, keep)
        self.inp.nhat = np.ascontiguousarray(new)
        self.inp.nvar = np.ascontiguousarray(var)
        self.inp.force = np.ascontiguousarray(force)
        links = RoundStage(self, rs, ls, token, client, progress=progress).run()
        fig = RoundFigures(**head, links=int(links.links), leaves=int(links.leaves),
                           rays=int(links.rays), time_s=round(time.perf_counter() - t0, 4))
        self.figures.append(fig)
        return fig


@dataclass(frozen=True)
class RoundFigures(StageFigures):
    """One refinement round (report.json, section "rounds", one of "rounds"): the originals
    whose links were made again, the link tasks, the nodes forced to split, and where tasks
    ran the links, leaves and rays after it."""

    OPTIONAL = ("links", "leaves", "rays")
    round: int
    originals: int
    tasks: int
    forced_nodes: int
    links: int | None = None
    leaves: int | None = None
    rays: int | None = None
    time_s: float = 0.0


@dataclass(frozen=True)
class RoundLinkFigures(StageFigures):
    """What a round changes in the link stage's figures (report.json, section "links")."""

    SECTION = "links"
    links: int
    links_per_leaf: float
    leaves: int
    nodes: int
    split_off_nodes: int
    rays: int
    ray_links: int
    refined: int
    evaluated: int
    exact: int
    shaft_visible: int
    shaft_blocked: int


class RoundStage(LinkStage):
    """A round's link tasks on the one stage master: the link stage's tasks, inputs (with the
    round's node weights) and ledger, under the round's token, resuming every task the round
    keeps; reports RoundLinkFigures."""

    monitor_stage = None

    def __init__(self, rounds: Rounds, rs, ls, token: str, client, progress: bool):
        super().__init__(rounds.run_dir, client, rounds.s, rounds.unit, rounds.occlusion,
                         resume=True, progress=progress)
        self.rounds, self.rs, self.ls, self.token = rounds, rs, ls, token

    def plan(self) -> StagePlan:
        r, s = self.rounds, self.s
        self.part, self.el, self.tree, self.lp = r.part, r.el, r.tree, r.lp
        self.pairs, self.first = r.pairs, r.first
        return StagePlan("links (round)", self.token, self.rs.path, len(r.first) - 1, r.cost,
                         f"rerun with: radiosity visibility {self.run_dir} --method hierarchical",
                         int(s.visibility.window_per_worker), int(s.visibility.retries))

    def create(self) -> None:  # never: the token was just written
        raise RadiosityError(f"rounds: the links of {self.run_dir} changed under the round")

    def inputs(self):
        return self.rounds.inp

    def report(self, fig) -> None:
        RoundLinkFigures(links=fig.links, links_per_leaf=fig.links_per_leaf, leaves=fig.leaves,
                         nodes=fig.nodes, split_off_nodes=fig.split_off_nodes, rays=fig.rays,
                         ray_links=fig.ray_links, refined=fig.refined, evaluated=fig.evaluated,
                         exact=fig.exact, shaft_visible=fig.shaft_visible,
                         shaft_blocked=fig.shaft_blocked).write(self.run_dir)
