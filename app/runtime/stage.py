"""The one executor of every stage master (seed §4.3's master): resume against the stage's
ledger, the dynamic window of tasks through `runner.run_tasks`, the manifest, the monitor and
the busy/idle figures. A master decides its plan (tasks, costs, token) and its inputs; this
module runs it, so resume, checksums and retries behave the same in every stage.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from radiosity.runtime.runner import run_tasks


class Ledger(Protocol):
    """Where a stage keeps its finished tasks: a store group plus its manifest."""

    def token(self) -> str | None: ...              # the plan the stored tasks belong to
    def finished(self, token: str) -> dict: ...      # task -> manifest entry
    def verify(self, task: int, entry: dict) -> bool: ...  # stored bytes match the entry?
    def rewrite_manifest(self, token: str, entries: dict) -> None: ...
    def record(self, task: int, result: dict) -> None: ...


@dataclass(frozen=True)
class StagePlan:
    """What a master decided: `ntasks` tasks named `name`, their estimated cost (ntasks,) (None:
    in order), the token of everything that determines their results, the store they write to,
    and the command that resumes the stage after a failure."""

    name: str
    token: str
    where: str                   # the store the tasks write to (part of their Dask keys)
    ntasks: int
    cost: np.ndarray | None
    repair: str
    window_per_worker: int = 3
    retries: int = 3


@dataclass
class StageRun:
    """What running a stage's tasks gave: every finished task's manifest entry (reused ones
    included), the counters summed over them, and the figures of the run itself."""

    done: dict
    counts: np.ndarray
    computed: int = 0
    corrupted: int = 0
    wall_s: float = 0.0
    busy: dict = field(default_factory=dict)
    workers: int = 1

    @property
    def reused(self) -> int:
        return len(self.done) - self.computed

    def figures(self) -> dict:
        """The task figures every stage reports (report.json)."""
        return {"tasks_computed": self.computed, "tasks_reused": self.reused,
                "tasks_corrupted_recomputed": self.corrupted,
                "time_tasks_s": round(self.wall_s, 4),
                "busy_s_per_worker": {str(k): round(v, 4) for k, v in self.busy.items()},
                "idle_fraction": (1.0 - sum(self.busy.values()) / (self.workers * self.wall_s))
                if self.wall_s > 0 and self.busy else None,
                "workers": self.workers}


def run_stage(client, plan: StagePlan, task_fn, args_of: Callable, ledger: Ledger, *,
              resume: bool, create: Callable[[], None], ncounters: int,
              on_result: Callable | None = None, on_done: Callable | None = None,
              progress: bool = True) -> StageRun:
    """Run `task_fn(*args_of(task))` for every task of `plan` not already finished.

    resume: keep the ledger's finished tasks when its token is the plan's (each verified
    against its checksum; a corrupted one is recomputed, and the manifest is rewritten clean so
    a torn line never swallows the next); otherwise `create()` starts the ledger afresh. Every
    task result is a dict with "counts" (ncounters,), "worker", "start" and "stop"; it enters
    the manifest (ledger.record) as soon as it arrives, before `on_result(task, result, done)`.
    on_done(n_computed) is for tests."""
    done, corrupted = {}, 0
    if resume and ledger.token() == plan.token:
        found = ledger.finished(plan.token)
        done = {t: e for t, e in found.items() if ledger.verify(t, e)}
        corrupted = len(found) - len(done)
        ledger.rewrite_manifest(plan.token, done)
    else:
        create()
    counts = np.zeros(ncounters, np.int64)
    for e in done.values():
        counts += np.asarray(e["counts"], np.int64)
    run = StageRun(done=done, counts=counts, corrupted=corrupted,
                   workers=len(client.scheduler_info()["workers"]) or 1)

    def finished(task, res):
        ledger.record(task, res)  # in the manifest only after its bytes were written
        done[task] = res
        run.computed += 1
        run.counts += np.asarray(res["counts"], np.int64)
        run.busy[res["worker"]] = run.busy.get(res["worker"], 0.0) + (res["stop"] - res["start"])
        if on_result is not None:
            on_result(task, res, done)
        if on_done is not None:
            on_done(run.computed)

    todo = [t for t in range(plan.ntasks) if t not in done]
    t0 = time.perf_counter()
    if todo:
        from dask.base import tokenize

        threads = sum(client.nthreads().values()) or 1
        run_tasks(client, task_fn, todo, args_of, name=plan.name,
                  token=tokenize(plan.token, plan.where), cost=plan.cost,
                  window=max(1, plan.window_per_worker * threads), retries=plan.retries,
                  on_result=finished, progress=progress, done=len(done), repair=plan.repair)
    run.wall_s = time.perf_counter() - t0
    return run
