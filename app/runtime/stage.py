"""The one stage master (seed §4.3's master) and its executor. `StageMaster` holds the sequence
every stage shares (plan, monitor, inputs scattered once, the run, figures, report), as
distributed's shuffle `ShuffleRun` holds a shuffle's; a stage (pairs visibility, links, the
cluster layer, a refinement round, view factors) fills in its hooks. `run_stage` executes a
plan: resume against the stage's ledger, the dynamic window of tasks through
`runner.run_tasks`, the manifest and the busy/idle figures, so resume, checksums and retries
behave the same in every stage.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, ClassVar, Protocol

import numpy as np

from radiosity.runtime.runner import run_tasks
from radiosity.runtime.store import StageFigures


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


@dataclass(frozen=True)
class TaskFigures(StageFigures):
    """The task figures every stage master reports (StageRun.figures): a stage's figures class
    derives from this and adds its own."""

    tasks_computed: int
    tasks_reused: int
    tasks_corrupted_recomputed: int
    time_tasks_s: float
    busy_s_per_worker: dict
    idle_fraction: float | None
    workers: int


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


def run_stage(client, plan: StagePlan, task_fn, args_of: Callable, ledger: Ledger | None, *,
              resume: bool, create: Callable[[], None], ncounters: int,
              on_result: Callable | None = None, on_done: Callable | None = None,
              progress: bool = True) -> StageRun:
    """Run `task_fn(*args_of(task))` for every task of `plan` not already finished.

    resume: keep the ledger's finished tasks when its token is the plan's (each verified
    against its checksum; a corrupted one is recomputed, and the manifest is rewritten clean so
    a torn line never swallows the next); otherwise `create()` starts the ledger afresh. Every
    task result is a dict with "counts" (ncounters,), "worker", "start" and "stop"; it enters
    the manifest (ledger.record) as soon as it arrives, before `on_result(task, result, done)`.
    on_done(n_computed) is for tests. Without a ledger (a stage that keeps nothing: the cluster
    layer) every task runs, results go to `on_result` only and nothing is summed."""
    done, corrupted = {}, 0
    if ledger is not None and resume and ledger.token() == plan.token:
        found = ledger.finished(plan.token)
        done = {t: e for t, e in found.items() if ledger.verify(t, e)}
        corrupted = len(found) - len(done)
        ledger.rewrite_manifest(plan.token, done)
    else:
        create()
    counts = np.zeros(ncounters, np.int64)
    for e in done.values():
        counts += np.asarray(e["counts"], np.int64)
    todo = [t for t in range(plan.ntasks) if t not in done]
    workers = (len(client.scheduler_info()["workers"]) or 1) if client is not None else 1
    run = StageRun(done=done, counts=counts, corrupted=corrupted, workers=workers)

    def finished(task, res):
        run.computed += 1
        if ledger is None:
            done[task] = None  # the result is on_result's to keep (or free)
        else:
            ledger.record(task, res)  # in the manifest only after its bytes were written
            done[task] = res
            run.counts += np.asarray(res["counts"], np.int64)
            run.busy[res["worker"]] = (run.busy.get(res["worker"], 0.0)
                                       + (res["stop"] - res["start"]))
        if on_result is not None:
            on_result(task, res, done)
        if on_done is not None:
            on_done(run.computed)

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


class StageMaster:
    """The sequence every stage master shares, its own work in hooks (distributed's shuffle
    `ShuffleRun` is the pattern). `run()`: `plan()` decides the tasks (pure where it can be),
    the monitor names the stage, `inputs()` is scattered to the workers once, `run_stage` runs
    the tasks `task(*args(t, shared))` against `ledger()` (resume, checksums, retries, progress),
    `on_result` sees each result on the driver, `figures(run)` sums them up and `report(fig)`
    writes them (report.json's section). A stage sets `task` (a module-level function, as a
    staticmethod), `counters` (the names of its tasks' "counts") and what it reports to."""

    task: ClassVar[Callable]
    counters: ClassVar[tuple] = ()
    #: the monitor's stage name (None: the stage does not publish one)
    monitor_stage: ClassVar[str | None] = None
    #: Scattered's direct path for the inputs (runtime.cluster.Scattered)
    straight: ClassVar[bool] = True

    def __init__(self, client, *, resume: bool = False, progress: bool = True, on_done=None,
                 report_dir: str | None = None):
        self.client, self.resume, self.progress, self.on_done = client, resume, progress, on_done
        self.report_dir = report_dir
        self.monitor = None
        self.t_start = 0.0

    # ------------------------------------------------------------------ hooks

    def plan(self) -> StagePlan:
        """What the stage runs: its tasks, their cost and token, its store and repair command."""
        raise NotImplementedError

    def inputs(self):
        """The read-only value every task needs, scattered once (None: nothing to scatter)."""
        return None

    def args(self, task: int, shared) -> tuple:
        """task's arguments; `shared` is the scattered inputs' future (None without inputs)."""
        raise NotImplementedError

    def ledger(self) -> Ledger | None:
        """Where finished tasks are kept (None: nowhere, no resume)."""
        return None

    def create(self) -> None:
        """Start the ledger afresh (no resume, or a plan of other inputs)."""

    def on_result(self, task: int, result, done: dict) -> None:
        """A finished task's result on the driver, as it arrives."""

    def figures(self, run: StageRun):
        """The stage's figures (a runtime.store.StageFigures) from its run."""
        raise NotImplementedError

    def report(self, fig) -> None:
        """Write the figures (default: their section of report_dir's report.json)."""
        if self.report_dir is not None and fig is not None:
            fig.write(self.report_dir)

    # ------------------------------------------------------------------ the sequence

    def run(self):
        """Plan, scatter, run, sum up, report; returns the figures."""
        self.t_start = time.perf_counter()
        plan = self.plan()
        if self.monitor_stage is not None:
            from radiosity.runtime.monitor import Monitor

            self.monitor = Monitor(self.client)
            self.monitor.stage(self.monitor_stage, self.report_dir or "")
        value = self.inputs() if plan.ntasks else None
        shared = None
        if value is not None:
            from radiosity.runtime.cluster import Scattered

            shared = Scattered(self.client, value, straight=self.straight)
        task = type(self).task
        run = run_stage(self.client, plan, task,
                        lambda t: self.args(t, None if shared is None else shared.future()),
                        self.ledger(), resume=self.resume, create=self.create,
                        ncounters=len(self.counters), on_result=self.on_result,
                        on_done=self.on_done, progress=self.progress)
        fig = self.figures(run)
        self.report(fig)
        return fig
