"""The solve stage with refinement rounds: run_solve, then, where the run's method refines by the
solved radiance (its `refinement`, methods/base.Refinement: the hierarchical method's
hierarchy.rounds, methods/hierarchical/views/rounds.py: the rule, the weights, the link tasks
made again and the warm start), its rounds, each followed by a warm-started solve. With no
rounds it is run_solve, unchanged.
"""

from __future__ import annotations

import time


def solve_with_rounds(run_dir: str, client, settings, *, unit=None, occlusion: bool = True,
                      progress: bool = True, echo=None, **solve_kw):
    """run_solve (stages/solve.py), then, where the run's method (solve_kw's method, else the
    one the run holds) has a refinement and the settings ask for rounds, the rounds of
    refinement by the solved radiance; returns the last solve's figures. Rounds decided after
    the first solve (count None: hierarchy.rounds auto): the first solve is the plain one, and
    the refinement decides from its answer before the final gather; where it says none, that
    solve goes on as the answer (final gather and all: nothing else runs), else it skips the
    final gather. solve_kw: run_solve's keywords (effects, preview, closure, keep_unconverged,
    method)."""
    from radiosity.methods.base import get_method, method_of_run
    from radiosity.runtime.store import RunStore, update_report
    from radiosity.stages.solve import run_solve

    method = solve_kw.get("method")
    ref = (get_method(method) if method is not None else method_of_run(RunStore(run_dir))).refinement
    n = ref.count(settings) if ref is not None else 0
    if n == 0:
        return run_solve(run_dir, client, settings, progress=progress, **solve_kw)
    t0 = time.perf_counter()
    mid = settings.replace({"hierarchy.final-gather": "none"})
    kw = {**solve_kw, "keep_unconverged": True}
    why = None
    if n is None:
        chose = {}

        def gather(opened, L):  # the final gather only where no round follows
            chose["n"], chose["why"] = ref.decide(RunStore(run_dir), settings, opened.to_sub(L))
            return chose["n"] == 0

        fig = run_solve(run_dir, client, settings, progress=progress, gather_if=gather,
                        **solve_kw)
        n, why = chose["n"], chose["why"]
        if echo is not None and n > 0:  # (none: the summary's rounds line says so)
            echo(f"rounds: {why}")
        if n == 0:
            update_report(run_dir, "rounds", {"why": why, "rounds": [], "solves": 1,
                                              "passes": [fig.iterations],
                                              "time_s": round(time.perf_counter() - t0, 4)})
            return fig
    else:
        fig = run_solve(run_dir, client, mid, progress=progress, **kw)
    passes = [fig.iterations]
    r = ref.start(run_dir, settings, unit, occlusion)
    last = False
    solves = 1
    for k in range(1, n + 1):
        prev = ref.previous(RunStore(run_dir))
        got = r.refine(client, prev, progress=progress)
        if echo is not None:
            echo(f"round {k}: {got['tasks']} link tasks (over {got['originals']} originals) "
                 f"with links above epsilon at the solved radiance or rows of F past 1 "
                 f"({got['forced_nodes']} nodes forced to split)"
                 + (f", {got['links']} links" if got["tasks"] else ""))
        if not got["tasks"]:
            break
        last = k == n
        fig = run_solve(run_dir, client, settings if last else mid, progress=progress,
                        x0=ref.warm_start(prev), **kw)
        passes.append(fig.iterations)
        solves += 1
    if not last:  # the final gather (and the converged answer) on the last links
        prev = ref.previous(RunStore(run_dir))
        fig = run_solve(run_dir, client, settings, progress=progress, x0=ref.warm_start(prev),
                        **solve_kw)
        passes.append(fig.iterations)
        solves += 1
    update_report(run_dir, "rounds", {"why": why or f"stated: {n} round(s)", "rounds": r.figures,
                                      "solves": solves, "passes": passes,
                                      "time_s": round(time.perf_counter() - t0, 4),
                                      "epsilon_factor": r.factor, "change": r.change})
    return fig
