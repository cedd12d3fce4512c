"""The hierarchical method behind the methods' seam (methods/base.py): the link stage, the
push-pull operator on the leaves, the final gather after the solve, and rounds of refinement
by the solved radiance (views/rounds.py, run by stages/rounds.py)."""

from __future__ import annotations

import os

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.methods.base import CAP_MIN, Opened, Refinement, TransportMethod


class HierarchicalRounds(Refinement):
    """hierarchy.rounds through the seam: views/rounds.py's rule, weights and warm start."""

    def count(self, settings) -> int | None:
        from radiosity.methods.hierarchical.views.rounds import AUTO, rounds_of

        n, _, _ = rounds_of(settings)
        return None if n == AUTO else n

    def decide(self, rs, settings, radiance):
        from radiosity.methods.hierarchical.views.rounds import auto_rounds

        return auto_rounds(rs, settings, radiance)

    def previous(self, rs) -> dict:
        from radiosity.methods.hierarchical.views.rounds import previous_solution

        return previous_solution(rs)

    def warm_start(self, prev: dict):
        from radiosity.methods.hierarchical.views.rounds import warm_start

        return warm_start(prev)

    def start(self, run_dir, settings, unit, occlusion):
        from radiosity.methods.hierarchical.views.rounds import Rounds

        return Rounds(run_dir, settings, unit, occlusion)


#: The solve's `where` (the link operator's: driver, cluster, auto) for the first bounce's stage.
FIRST_BOUNCE_WHERE = {"driver": "driver", "cluster": "workers"}


class HierarchicalMethod(TransportMethod):
    name = "hierarchical"
    section = "links"
    store_groups = ("links", "clusters", "hierarchy", "direct")
    all_pairs = False
    refinement = HierarchicalRounds()

    def check_scene(self, scene, settings) -> dict | None:
        """Nothing to refuse: scenes of many originals are clustered (SPEC §9)."""
        return None

    def direct(self, elements, settings) -> tuple[str, str]:
        """The emitters' light at points or through the links (params.choose_direct)."""
        from radiosity.methods.hierarchical.params import choose_direct

        return choose_direct(elements, settings)

    def plan_lines(self, settings, sub_elements, originals, why) -> list[str]:
        """The cluster tree and its links (estimated per original) where the originals are
        clustered, else the links estimated per sub-element."""
        from radiosity.methods.hierarchical.store import LINK_DTYPE
        from radiosity.scene.splittrees import LINKS_PER_LEAF

        n = int(originals)
        if settings.hierarchy.clustered(n)[0] or "(clustered)" in why:
            from radiosity.methods.hierarchical.clusters.tasks import LINKS_PER_ORIGINAL, LINKS_PER_THREAD_S

            lo, hi = (k * n for k in LINKS_PER_ORIGINAL)
            threads = os.cpu_count() or 1
            return [f"clusters: a tree of {2 * n - 1} clusters over the {n} originals; links "
                    f"start at its root (SPEC §9): about {lo:.2g} to {hi:.2g} links "
                    f"({LINKS_PER_ORIGINAL[0]:g}-{LINKS_PER_ORIGINAL[1]:g} per original as "
                    f"measured on a terrain and a tessellated box), a link stage of about "
                    f"{lo / (LINKS_PER_THREAD_S[1] * threads):.2g} to "
                    f"{hi / (LINKS_PER_THREAD_S[0] * threads):.2g} s on {threads} local thread(s)"]
        lo, hi = (k * sub_elements for k in LINKS_PER_LEAF)
        return [f"links: about {lo:.2g} to {hi:.2g} ({LINKS_PER_LEAF[0]:g}-{LINKS_PER_LEAF[1]:g} "
                f"per sub-element as measured, {LINK_DTYPE.itemsize} bytes each)"]

    def gathers(self, settings) -> bool:
        """hierarchy.final-gather other than none."""
        return settings.hierarchy.final_gather not in (False, None, "none")

    def check(self, rs, settings) -> None:
        """Settings that would fail the stage, failed before any cluster starts."""
        from radiosity.methods.hierarchical.params import resolve_params

        resolve_params(rs.load_elements(), settings)

    def build(self, run_dir, client, settings, *, resume=False, progress=True, occlusion=True,
              unit=None, on_done=None):
        from radiosity.methods.hierarchical.links.master import compute_links

        return compute_links(run_dir, client, settings, unit=unit, resume=resume,
                             progress=progress, occlusion=occlusion, on_done=on_done)

    def built(self, rs) -> bool:
        from radiosity.methods.hierarchical.store import LinkStore

        return LinkStore(rs).token() is not None

    def require(self, rs) -> None:
        from radiosity.methods.hierarchical.store import LinkStore

        LinkStore(rs).require()

    def open(self, rs, client, settings, where: str = "auto", **options) -> Opened:
        """The link operator over the leaves. With the emitters' light at points (SPEC §10,
        params.choose_direct), the right-hand side is the leaves' first bounce L1
        (solve/direct.first_bounce), so that the solve's fixed point is R = L1 + rho K R, the
        light after the emitters' (state["Le"] keeps their emission for finish)."""
        from radiosity.methods.hierarchical.params import choose_direct
        from radiosity.methods.hierarchical.solve.leaves import leaf_vectors, live_leaves, to_sub_elements
        from radiosity.methods.hierarchical.solve.transport import open_link_operator

        op, table, el, part = open_link_operator(rs, client, where, settings)
        Le, rho, area = leaf_vectors(table, el)
        m = len(part)
        s = settings
        live = live_leaves(table, el, s.rays.offset) if s.hierarchy.inside_solids else None
        direct, _ = choose_direct(el, s)
        state = {"table": table, "direct": direct}
        if direct == "points":
            from radiosity.methods.hierarchical.solve.direct import first_bounce

            state["Le"] = Le
            Le = np.asarray(first_bounce(table, el, s, k=int(s.direct.leaf_points), rs=rs,
                                         client=client,
                                         where=FIRST_BOUNCE_WHERE.get(where, "auto")), np.float64)
            if live is not None:  # H1 is 0 at points inside solids: L1 of the leaf's live part
                # (live_leaves: the share of 4 stratified points outside solids, the same 4)
                Le = Le / np.where(live > 0, live, 1.0)
            Le = np.ascontiguousarray(Le)
        return Opened(op, Le, rho, area, table["orig"][table["leaf_node"]], m,
                      lambda L: to_sub_elements(L, table, m), originals=len(el), live=live,
                      state=state)

    def finish(self, opened: Opened, L: np.ndarray, rows: dict, settings) -> tuple[dict, dict]:
        """With hierarchy.final-gather, one final gather that re-evaluates every link into a
        node above the leaves at each of its leaves (the uniform push leaves a saw-tooth over
        coarse receivers): solution/radiance per sub-element comes from it, and
        solution/leaf_radiance (M, 2, 3) keeps the solver's fixed point L = Le + rho K L;
        solution/leaf_rows (M, 2) the leaves' rows of F v before any scaling (views/rounds.py).
        With the emitters' light at points (open), Le is the first bounce L1: leaf_radiance is
        R = L1 + Lr, without the emission, which solution/radiance adds back (the attrs say
        direct: points)."""
        import time

        from radiosity.methods.hierarchical.solve.transport import LocalLinkOperator

        op, Le, rho = opened.op, opened.Le[:, :L.shape[1]], opened.rho[:, :L.shape[1]]
        M = L.shape[2]
        t_fg = time.perf_counter()
        fg = settings.hierarchy.final_gather
        gather_final = self.gathers(settings)
        Lf = L
        if gather_final:
            if fg not in ("exact", "linear"):
                raise RadiosityError(f"radiosity.hierarchy.final-gather must be none, linear or "
                                     f"exact, got {fg!r}")
            # the final gather evaluates form factors afresh (exact, from each leaf's centroid):
            # the solve's row caps and balancing, made for the links' approximate form factors,
            # do not apply to them (docs/src/measurements/hierarchical.md); in a closed scene its rows are
            # balanced to 1 in turn (every leaf sees the whole enclosure; else rho -> 1 turns
            # their row error into the answer's)
            op.configure(fg_levels=int(settings.hierarchy.final_gather_levels), fg_mode=fg,
                         cap=np.ones(M), cmode=CAP_MIN)
            G = op.final_gather(L)
            if rows.get("mode") == "closed":
                r = op.final_gather(np.ones_like(L[:, :1]))
                G = G / np.where(r > 0, r, 1.0)
            elif rows.get("mode") == "open":  # only the leaves whose rows were balanced
                G = _balanced_gather(op, G, L, opened)
            Lf = Le + rho * G
        t_fg = time.perf_counter() - t_fg
        L3 = np.broadcast_to(L, (2, 3, M)) if L.shape[1] == 1 else L
        F3 = np.broadcast_to(Lf, (2, 3, M)) if Lf.shape[1] == 1 else Lf
        direct = opened.state.get("direct", "links")
        if direct == "points":  # R plus the emission: what the leaves send towards a camera
            F3 = F3 + opened.state["Le"]
        arrays = {"radiance": opened.to_sub(F3),
                  "leaf_radiance": np.ascontiguousarray(np.transpose(L3, (2, 0, 1)))}
        if opened.row_sums is not None:  # the rows of F v per leaf and side, unscaled (M, 2)
            arrays["leaf_rows"] = np.ascontiguousarray(opened.row_sums.T)
        figures = {"hierarchy": {"leaves": M, "link_terms": int(op.terms),
                                 "passes_on": "driver" if isinstance(op, LocalLinkOperator)
                                 else "workers",
                                 "final_gather": fg if gather_final else "none",
                                 "final_gather_evaluations": int(getattr(op, "evals", 0)),
                                 "time_final_gather_s": round(t_fg, 4)},
                   "direct": direct}
        return arrays, figures

    def radiance_at(self, rs, settings, pts, porig, side, pixel, footprint):
        """Radiance (K, 3) leaving points on originals `porig`, side `side`: leaves coarser
        than the view's pixels gathered at the points over their links (views/points.radiance_at)."""
        from radiosity.methods.hierarchical.views.points import radiance_at

        return radiance_at(rs, settings, pts, porig, side, pixel, footprint)

    def open_views(self, rs, settings):
        """The run's links opened once for many views (views/points.PointGather): its
        radiance_at(pts, porig, side, pixel, footprint) is radiance_at's, without the opening."""
        from radiosity.methods.hierarchical.views.points import PointGather

        return PointGather(rs, settings)

    def kept(self, rs) -> str | None:
        from radiosity.methods.hierarchical.store import LinkStore

        ls = LinkStore(rs)
        token = ls.token()
        if token is None:
            return None
        return f"{len(ls.finished(token))} of {len(ls.plan()[1]) - 1} link tasks"

    def summary_row(self, report: dict) -> tuple[str, str]:
        lk = report["links"]
        return ("links", f"{lk['links']} ({lk['links_per_leaf']:.1f} per leaf), {lk['rays']} rays")


def _balanced_gather(op, G, L, opened):
    """G (2, C, M) with the leaves whose rows the solve balanced (normalise-rows open: every
    side exact, RowTargets.balance, and not far below its target, core.balancing) normalised
    by their final-gather rows, as a closed scene's are: the others keep their own rows."""
    from radiosity.core.balancing import BALANCE_MIN

    rt, sums = opened.row_targets, opened.row_sums
    if rt is None or sums is None:
        return G
    bal = rt.balance & ~rt.dead & (sums.sum(axis=0) >= BALANCE_MIN * rt.target)
    if not bal.any():
        return G
    r = op.final_gather(np.ones_like(L[:, :1]))
    # per side, where it sees surfaces at all (a void back's row is near 0: left as it is)
    ok = bal[None, None, :] & (r >= BALANCE_MIN)
    scale = np.where(ok, 1.0 / np.where(ok, r, 1.0), 1.0)
    return G * scale


HIERARCHICAL = HierarchicalMethod()
