"""The solve stage with refinement rounds (hierarchy.rounds): run_solve, then on a hierarchical
run the rounds of refinement by the solved radiance (methods/hierarchical/views/rounds.py: the rule,
the weights, the link tasks made again and the warm start), each followed by a warm-started
solve. With rounds off it is run_solve, unchanged.
"""

from __future__ import annotations

import time

from radiosity.methods.hierarchical.views.rounds import (AUTO, Rounds, auto_rounds, previous_solution,
                                                   rounds_of, warm_start)


def solve_with_rounds(run_dir: str, client, settings, *, unit=None, occlusion: bool = True,
                      progress: bool = True, echo=None, **solve_kw):
    """run_solve (stages/solve.py), then with hierarchy.rounds > 0 the rounds of refinement by
    the solved radiance (methods/hierarchical/views/rounds.py) on a hierarchical run; returns the last
    solve's figures. hierarchy.rounds auto: the first solve is the plain one, and auto_rounds
    decides from its answer before the final gather; where it says none, that solve goes on as
    the answer (final gather and all: nothing else runs), else it skips the final gather.
    solve_kw: run_solve's keywords (effects, preview, closure, keep_unconverged, method)."""
    from radiosity.runtime.store import RunStore, update_report
    from radiosity.stages.solve import run_solve

    n, _, _ = rounds_of(settings)
    if n == 0 or solve_kw.get("method") not in (None, "hierarchical"):
        return run_solve(run_dir, client, settings, progress=progress, **solve_kw)
    t0 = time.perf_counter()
    mid = settings.replace({"hierarchy.final-gather": "none"})
    kw = {**solve_kw, "keep_unconverged": True}
    why = None
    if n == AUTO:
        chose = {}

        def gather(opened, L):  # the final gather only where no round follows
            chose["n"], chose["why"] = auto_rounds(RunStore(run_dir), settings, opened.to_sub(L))
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
    r = Rounds(run_dir, settings, unit, occlusion)
    last = False
    solves = 1
    for k in range(1, n + 1):
        prev = previous_solution(RunStore(run_dir))
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
                        x0=warm_start(prev), **kw)
        passes.append(fig.iterations)
        solves += 1
    if not last:  # the final gather (and the converged answer) on the last links
        prev = previous_solution(RunStore(run_dir))
        fig = run_solve(run_dir, client, settings, progress=progress, x0=warm_start(prev),
                        **solve_kw)
        passes.append(fig.iterations)
        solves += 1
    update_report(run_dir, "rounds", {"why": why or f"stated: {n} round(s)", "rounds": r.figures,
                                      "solves": solves, "passes": passes,
                                      "time_s": round(time.perf_counter() - t0, 4),
                                      "epsilon_factor": r.factor, "change": r.change})
    return fig
