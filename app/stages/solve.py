"""The solve stage, one for every method: open the run's operator through the method's seam,
handle rows that sum past 1, run a solver (core/solvers.py), let the method finish (a final
gather, or nothing), write solution/ and the report (SPEC §2, §6, §8).
"""

from __future__ import annotations

import dataclasses
import functools
import time
import warnings
from dataclasses import dataclass

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.scene.closure import Closure, detect_closure
from radiosity.core.balancing import RowTargets, balance_rows  # noqa: F401  (RowTargets: re-exported)
from radiosity.core.kernels import get_kernel
from radiosity.runtime.monitor import Monitor, progress_bar
from radiosity.methods.base import CAP_MIN, CAP_PRODUCT
from radiosity.core.solvers import SOLVERS, anorm, choose_solver, get_solver  # noqa: F401  (SOLVERS: re-exported)
from radiosity.runtime.store import RunStore, StageFigures
from radiosity.settings import Settings


@dataclass(frozen=True)
class SolveFigures(StageFigures):
    """The solve stage's figures (report.json, section "solve")."""

    SECTION = "solve"
    solver: str
    kernel: str
    iterations: int
    converged: bool
    residuals: list                  # relative residual (or the solver's bound) per pass
    final_residual: float            # one true-residual pass, the same measure for every solver
    passes: int                      # operator products, residual and row-sum passes included
    pair_terms: int
    pair_terms_per_s: float          # in the solver's own passes, over their own time
    time_s: float
    sub_elements: int
    channels: int
    tol: float | None = None
    row_sums: dict | None = None
    near_field: dict | None = None
    partial_visibility: dict | None = None
    two_sided_sub_elements: int = 0
    gathering_elements: int = 0
    channel_terms: int = 0
    ambient: list | None = None      # progressive refinement's ambient term
    closure: dict | None = None      # closure.Closure: closed or open, and why
    solution: str = "written"        # written | kept previous (not converged) | written unconverged
    method: str = "-"                # the transport method (methods/base.py METHODS); "-": none
    hierarchy: dict | None = None    # --method hierarchical: leaves, link terms, final gather
    direct: str = "links"            # the emitters' light at points or through the links (SPEC §10)

    def rows(self):
        return [("solver", f"{self.solver} ({self.kernel} kernel, {self.method} method)"),
                ("passes", f"{self.iterations} ({'converged' if self.converged else 'NOT converged'})"),
                *([("solution", self.solution)] if not self.converged else []),
                ("final residual", f"{self.final_residual:.3g}"),
                *([("closure", self.closure["reason"])] if self.closure else []),
                *([("direct light", "at points (SPEC §10)")] if self.direct == "points" else []),
                ("pair terms/s", f"{self.pair_terms_per_s / 1e6:.1f} M"),
                ("time", f"{self.time_s:.2f} s")]


class _PassClock:
    """The operator as a solver sees it, with the time of its passes (apply, gs_sweep) summed:
    the solver's throughput counts its own passes only, not the monitor's and the preview's
    callbacks between them."""

    def __init__(self, op):
        self.op = op
        self.seconds = 0.0

    def __getattr__(self, name):
        return getattr(self.op, name)

    def _timed(self, fn, *args, **kw):
        t = time.perf_counter()
        try:
            return fn(*args, **kw)
        finally:
            self.seconds += time.perf_counter() - t

    def apply(self, *args, **kw):
        return self._timed(self.op.apply, *args, **kw)

    def gs_sweep(self, *args, **kw):
        return self._timed(self.op.gs_sweep, *args, **kw)


def row_mode(mode, closure) -> str:
    """The row handling to use: `mode` (radiosity.solve.normalise-rows) unless it is auto, then
    closed for a closed scene and cap for an open one (closure: a closure.Closure). open (the
    rows of the sides that lost no ray balanced, the others capped) is asked for by name: not
    yet the default (docs/src/design/scene-closure.md, "Open scenes")."""
    mode = {True: "cap", False: "off", None: "auto"}.get(mode, mode)
    if mode == "auto":
        return "closed" if closure is not None and closure.closed else "cap"
    return mode


def resolve_closure(setting, elements, ray_offset: float):
    """closure.Closure for solve.closure = auto (detected with rays offset by `ray_offset`, the
    rays.epsilon setting), on or off (stated; contact sides are found all the same)."""
    from radiosity.scene.contact import find_contacts

    setting = {True: "on", False: "off", None: "auto"}.get(setting, setting)
    if setting not in ("auto", "on", "off"):
        raise RadiosityError(f"radiosity.solve.closure must be auto, on or off, got {setting!r}")
    if setting == "auto":
        return detect_closure(elements, float(ray_offset))
    closed = setting == "on"
    contact = find_contacts(elements, float(ray_offset)) if len(elements) else np.zeros((0, 2), bool)
    k = int(contact.sum())
    return Closure(closed, 0, 0, -1, 0.0, f"{'closed' if closed else 'open'}: stated "
                   f"(closure: {setting})" + (f"; {k} contact sides take no part" if k else "")
                   + (": rows balanced to exactly 1" if closed else ""),
                   contact=contact, counts={"contact_sides": k})


def _balance(op, sums, target, balance, dead):
    """core.balancing.balance_rows on the operator `op` (its two sides' rows)."""
    m = sums.shape[1]

    def apply(d):
        y = op.apply(np.broadcast_to(d, (2, 1, m)).copy(), use_need=False)[:, 0, :]
        return y.sum(axis=0), y.max(axis=0)

    return balance_rows(apply, sums, target, balance, dead)


def normalise_rows(op, mode="cap", rows: RowTargets | None = None, sums=None):
    """Detect rows of F that sum to more than 1 (the point kernel near large elements close
    together, where 1/r^2 blows up) and decide how to handle them. Returns (figures, scaling):
    what was found and done, and the operator inputs to configure ({} for none: cap (m,) and
    cmode, passes.CAP_MIN or CAP_PRODUCT).

    cap (default): scale each pair by min(cap_a, cap_b), cap = 1 / row sum on the rows above 1:
        rows then sum to at most 1 and reciprocity still holds (A_a F'_ab = A_b F'_ba), so every
        solver converges for rho < 1. An operator with `leaf_caps` (links at nodes above the
        leaves) scales by cap_a cap_b instead (K -> D K D, the same bounds): no pass either.
    closed: for closed scenes, where every row must sum to exactly its target (1; the sides'
        targets summed, RowTargets): scale pairs by d_a d_b with d from the symmetric
        balancing iteration d <- sqrt(d t / (F d)) (reciprocity kept); what is left of the
        kernel's error no longer decides the answer when rho -> 1. Rows whose target is not
        exact (a side that sees out) are capped in the same iteration instead.
    open: for open scenes, the same with the targets of an open scene (RowTargets: exact only
        on the sides that lost no ray of the closure test): capping alone keeps every row's
        kernel error below 1 and none above, a loss the walls' reflectance multiplies (a hall
        whose rooms are closed but for a few openings: -2 % to -3 %,
        docs/src/design/scene-closure.md); as cap where no row can be balanced.
    off (or False): only report.
    rows: the closure's RowTargets; with dead unknowns (rows.dead: contact sides, sub-elements
    inside solids) every mode scales by d_a d_b, d = 0 on them: they neither receive nor send.
    sums: op.row_sums() when the caller
    has them already.
    """
    mode = {True: "cap", False: "off", None: "cap", "auto": "cap"}.get(mode, mode)
    if mode not in ("cap", "closed", "off", "open"):
        raise RadiosityError(f"radiosity.solve.normalise-rows must be cap, closed, open or off, "
                             f"got {mode!r}")
    if mode == "open" and (rows is None or not (rows.balance & ~rows.dead).any()
                           or not getattr(op, "leaf_caps", False)):
        # no side known to see no way out; or the pairs method, whose rows hardly pass 1
        # (capping costs it nothing; balancing moved a room with a hole from +1.1 % to +3.3 %)
        mode = "cap"
    sums = op.row_sums() if sums is None else sums
    rs = sums.max(axis=0)
    over = rs > 1.0 + 1e-12
    out = {"rows_over_1": int(over.sum()), "max_row_sum": float(rs.max(initial=0.0)),
           "min_row_sum": float(sums.sum(axis=0).min(initial=0.0)), "mode": mode,
           "normalised": bool(mode == "cap" and over.any())}
    m = sums.shape[1]
    dead = rows.dead if rows is not None else np.zeros(m, bool)
    scaling = {}
    # an operator whose links sit at nodes above the leaves caps each leaf's row on its own
    # (K -> D K D, d = 1 / row sum): the min over a node's leaves would cap every leaf below
    # a coarse link for one leaf's row (transport.py's leaf_caps)
    leaf_caps = bool(getattr(op, "leaf_caps", False))
    if dead.any():
        out["contact_unknowns"] = int(dead.sum())
        if mode == "off":
            scaling = {"cap": np.where(dead, 0.0, 1.0), "cmode": CAP_PRODUCT}
            return out, scaling
        if mode == "cap" and leaf_caps:
            d = np.where(over, 1.0 / np.where(over, rs, 1.0), 1.0)
            d[dead] = 0.0
            out["normalised"] = True
            return out, {"cap": d, "cmode": CAP_PRODUCT}
        target = rows.target if mode in ("closed", "open") else np.ones(m)
        balance = rows.balance if mode in ("closed", "open") else np.zeros(m, bool)
        d, passes, err, stuck = _balance(op, sums, target, balance, dead)
        scaling = {"cap": d, "cmode": CAP_PRODUCT}
        out.update({"normalised": True, "balancing_passes": passes, "balancing_error": err,
                    "rows_at_scaling_bound": stuck})
    elif out["normalised"]:
        scaling = {"cap": np.where(over, 1.0 / np.where(over, rs, 1.0), 1.0),
                   "cmode": CAP_PRODUCT if leaf_caps else CAP_MIN}
    elif mode in ("closed", "open"):
        # sub-elements that see nothing (under a block standing on the floor) keep their empty
        # rows; every other row is balanced to its target (1 unless the closure says otherwise)
        if mode == "closed" and not (sums.sum(axis=0) > 0).any():
            raise RadiosityError("normalise-rows=closed needs a closed scene: no element sees "
                                 "another")
        target = rows.target if rows is not None else np.ones(m)
        balance = rows.balance if rows is not None else np.ones(m, bool)
        d, passes, err, stuck = _balance(op, sums, target, balance, dead)
        scaling = {"cap": d, "cmode": CAP_PRODUCT}  # pairs scaled by the product d_a d_b
        out.update({"normalised": True, "balancing_passes": passes, "balancing_error": err,
                    "rows_at_scaling_bound": stuck})
    return out, scaling


def write_direct_solution(run_dir: str) -> SolveFigures:
    """No interreflection (reflectance 0 everywhere, effects.py): L = Le, without a pass."""
    from radiosity.scene.emitters import AreaEmitters

    rs = RunStore(run_dir, "r+")
    part, el = rs.load_partition(), rs.load_elements()
    rs.drop_after("nearfield")
    rs.write_arrays("solution", {"radiance": AreaEmitters(el).radiance(part.orig)},
                    {"solver": "direct"})
    fig = SolveFigures(solver="direct (L = Le)", kernel="-", iterations=0, converged=True,
                       residuals=[], final_residual=0.0, passes=0, pair_terms=0,
                       pair_terms_per_s=0.0, time_s=0.0, sub_elements=len(part), channels=0)
    fig.write(run_dir)
    return fig


def run_solve(run_dir: str, client, settings: Settings, *, progress: bool = True,
              callback=None, effects=None, preview=None, closure=None,
              keep_unconverged: bool = False, method: str | None = None, where: str = "auto",
              x0=None, gather_if=None) -> SolveFigures:
    """Solve the run's radiosity system with the method whose stage it holds (or `method`);
    write solution/ and the report's "solve" section.

    settings: the run's settings.Settings (solve.solver, kernel, tol, max-iterations,
    normalise-rows, ...). A solve that does not reach tol does not replace a converged solution
    already in the store (fig.solution says "kept previous"), unless `keep_unconverged`; with
    none to keep it is written, marked converged = False.

    effects: an effects.EffectsPlan (grey scenes solve one channel, dead rows skip gathering,
    two-sided elements reached from one side are solved one-sided). preview: a function
    (2, C, m) radiance per sub-element -> (h, w, 3) uint8 image for the dashboard
    (image.previewer), or None. closure: a closure.Closure already decided (the plan's), else
    solve.closure. where: the hierarchical method's driver / cluster choice. x0: a warm start,
    a function of the opened method (methods.base.Opened) -> (2, C, M) (Refinement.warm_start).
    gather_if: a function (opened, solved L) -> False where the method's final gather is to be
    skipped (stages/rounds.py: a round follows)."""
    from radiosity.methods.base import get_method, method_of_run

    s = settings
    get_kernel(s.solve.kernel)
    t0 = time.perf_counter()
    rs = RunStore(run_dir, "r+")
    impl = get_method(method) if method is not None else method_of_run(rs)
    opened = impl.open(rs, client, s, where=where)
    op = opened.op
    solver = choose_solver(s.solve.solver, op.kernel)
    fn = get_solver(solver)
    if solver == "progressive":
        fn = functools.partial(fn, shoot_fraction=float(s.solve.shoot_fraction))
    tol, max_iter = float(s.solve.tol), int(s.solve.max_iterations)
    Le, rho, area = opened.Le, opened.rho, opened.area
    mode = s.solve.normalise_rows
    if mode in ("auto", None, "open") and closure is None:  # open: the sides it balances
        closure = resolve_closure(s.solve.closure, rs.load_elements(), s.rays.offset)
    sided = (effects.two_sided if effects is not None
             else rs.load_elements().two_sided.astype(bool))[opened.orig]
    targets = RowTargets.of(closure, opened.orig, sided)
    live = opened.live
    if live is not None and (live < 1.0).any():  # sub-elements inside solids, wholly or partly
        buried = live <= 0.0
        targets = RowTargets.burying(targets, buried, sided)
        op.configure(pull_area=opened.area * live)  # they send their live part's light
        area = area * live  # the solvers' weights: the operator is symmetric in these
        rho = np.where(buried, 0.0, rho)  # known (L = Le): no weight to divide by
    if targets is not None and (targets.sided != sided).any():
        op.configure(sided=targets.sided)  # contact backs: those elements solved one-sided
    sums = op.row_sums()  # (2, M), before any scaling: the methods may keep them (Opened.row_sums)
    opened.row_sums = sums
    opened.row_targets = targets
    rows, changes = normalise_rows(op, row_mode(mode, closure), targets, sums)
    channels = 3
    if effects is not None:
        changes["sided"] = effects.two_sided[opened.orig] & (
            targets.sided if targets is not None else True)
        changes["need"] = effects.gather if not effects.gather.all() else np.zeros(0, np.bool_)
        if not effects.colour:  # grey: one channel, broadcast at the end
            channels = 1
            Le, rho = Le[:, :1].copy(), rho[:, :1].copy()
    if changes:
        op.configure(**changes)  # one scatter of the inputs
    mon = Monitor(client)
    mon.stage("solve", run_dir)
    history = []
    make_image = ((lambda L: preview(opened.to_sub(L).transpose(1, 2, 0))) if preview is not None
                  else (lambda L: np.zeros((1, 1, 3), np.uint8)))
    bar = progress_bar(None, f"solve ({solver})", progress, unit="pass")

    def cb(k, r, L):
        if not np.isfinite(r) or r > 1e8:
            bar.close()
            raise RadiosityError(
                f"{solver} diverged after {k} passes (residual {r:.3g}): rows of F sum to more "
                f"than 1/rho with the {op.kernel} kernel (large elements close together); keep "
                "radiosity.solve.normalise-rows on, use --kernel disc, or subdivide more")
        bar.update()
        bar.set_postfix(residual=f"{r:.2e}")
        history.append(r)
        mon.solve(solver, op.kernel, history)
        mon.preview(lambda: make_image(L))
        if callback:
            callback(k, r, L)

    clock, terms0 = _PassClock(op), op.terms  # the solver's own passes, for the throughput
    warm = {} if x0 is None else {"x0": np.ascontiguousarray(x0(opened)[:, :Le.shape[1]])}
    res = fn(clock, Le, rho, area, tol, max_iter, cb, **warm)
    t_iter, iter_terms = clock.seconds, op.terms - terms0
    bar.close()
    mon.solve(solver, op.kernel, history, force=True)
    mon.preview(lambda: make_image(res.radiance), force=True)
    t_solve = time.perf_counter() - t0
    # one true-residual pass, the same measure for every solver
    y = op.apply(res.radiance)
    final = anorm(Le + rho * y - res.radiance, area) / (anorm(Le, area) or 1.0)
    fin = s if gather_if is None or gather_if(opened, res.radiance) else \
        s.replace({"hierarchy.final-gather": "none"})
    # a final gather (the hierarchical method's re-evaluates every link at the leaves): a stage
    gathers = impl.gathers(fin)
    with progress_bar(1, "final gather", progress and gathers, unit="pass") as fbar:
        arrays, extra = impl.finish(opened, res.radiance, rows, fin)
        fbar.update()
    need = changes.get("need", np.zeros(0, np.bool_))  # the originals that gather (empty: all)
    fig = SolveFigures(**{
        "solver": solver, "kernel": op.kernel, "tol": tol, "iterations": res.iterations,
        "converged": bool(res.converged), "residuals": [float(r) for r in res.residuals],
        "final_residual": final, "passes": op.passes, "pair_terms": int(op.terms),
        "pair_terms_per_s": iter_terms / max(t_iter, 1e-9), "time_s": round(t_solve, 4),
        "sub_elements": opened.sub_elements, "row_sums": rows, "channels": channels,
        "gathering_elements": int(need.sum()) if len(need) else opened.originals,
        "channel_terms": int(op.terms) * channels,
        "ambient": None if res.ambient is None else res.ambient.tolist(),
        "closure": None if closure is None else closure.to_dict(), "method": impl.name, **extra,
    })
    return store_solution(rs, fig, res, arrays, keep_unconverged, max_iter)


def store_solution(rs, fig: SolveFigures, res, arrays: dict, keep_unconverged: bool,
                   max_iter: int) -> SolveFigures:
    """Write a solve's arrays into solution/ and its figures into report.json, unless it did
    not converge and a converged solution is already there (kept, unless keep_unconverged);
    an unconverged solve is said in fig.solution and in a warning. Both methods' stages end
    here. Returns the figures as written."""
    previous = rs.group_attrs("solution") if rs.has("solution") else {}
    keep = not res.converged and not keep_unconverged and previous.get("converged") is True
    if not res.converged:
        fig = dataclasses.replace(fig, solution=(
            f"kept the previous converged solution ({previous.get('solver')}, "
            f"{previous.get('kernel')} kernel, final residual {previous.get('final_residual', float('nan')):.3g}); "
            "--keep-unconverged replaces it" if keep else "written, NOT converged"))
    if not keep:
        rs.drop_after("nearfield")
        rs.write_arrays("solution", arrays, {k: v for k, v in fig.to_dict().items() if k != "residuals"})
    fig.write(rs.run_dir)
    if not res.converged:
        warnings.warn(f"{fig.solver} did not reach tol={fig.tol:g} in {max_iter} passes (residual "
                      f"{res.residuals[-1] if res.residuals else float('nan'):.3g}): "
                      + ("the previous converged solution is kept" if keep else
                         "its solution is written, marked not converged"), stacklevel=3)
    return fig
