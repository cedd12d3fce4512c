"""The one dynamic master (seed §4.3): a bounded window of Dask tasks, most expensive first.

Design notes and measurements: docs/src/design/runtime-runner.md.
"""

from __future__ import annotations

import errno
import time
import traceback as tb
from dataclasses import dataclass, field

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.runtime.monitor import progress_bar


class TaskFailed(RadiosityError):
    """A task that failed on every attempt; `worker_traceback` holds the worker's traceback."""

    def __init__(self, message: str, worker_traceback: str = "", cause: BaseException | None = None):
        super().__init__(message)
        self.worker_traceback = worker_traceback
        self.cause = cause


@dataclass
class RunStats:
    """What a run of tasks did: submitted, finished and resubmitted counts, its wall time."""

    finished: int = 0
    resubmitted: int = 0
    wall_s: float = 0.0
    attempts: dict = field(default_factory=dict)


def cost_order(tasks, cost=None) -> list[int]:
    """Task ids, most expensive first (long tasks start early); ties by id (deterministic)."""
    tasks = np.asarray(list(tasks), np.int64)
    if cost is None or len(tasks) == 0:
        return tasks.tolist()
    c = np.asarray(cost)[tasks]
    return tasks[np.lexsort((tasks, -c))].tolist()


#: Filesystem errors a retry would only repeat (full, read-only, no permission, quota).
_FS_ERRNOS = (errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT)


def deterministic(exc: BaseException) -> bool:
    """A failure that is the same wherever and whenever it runs: bad or corrupted input (a
    RadiosityError) or a filesystem that cannot take the bytes. Not retried."""
    return isinstance(exc, RadiosityError) or (isinstance(exc, OSError) and exc.errno in _FS_ERRNOS)


def _describe(exc: BaseException, trace) -> tuple[str, str]:
    """(one-line summary, full traceback text) of a task's exception."""
    text = "".join(tb.format_exception(type(exc), exc, trace)) if trace is not None else repr(exc)
    return f"{type(exc).__name__}: {exc}", text


def run_tasks(client, fn, tasks, args_of, *, name: str, token: str, cost=None, window: int = 1,
              retries: int = 3, on_result=None, progress: bool = True, repair: str = "",
              kwargs_of=None, done: int = 0) -> RunStats:
    """Run fn(*args_of(task)) for every task in `tasks` on the cluster, at most `window` at a
    time, most expensive first by `cost` (array indexed by task id; None keeps the order).

    on_result(task, result) is called on the driver as each task finishes, in completion order.
    Task keys are deterministic (`name-token-task-attempt`), so a resumed run resubmits exactly
    the missing tasks; `done` tasks finished earlier only start the progress bar further on.
    kwargs_of(task) -> extra client.submit keywords (workers=...). repair: what the user should run after a failure (e.g. the --resume
    command), appended to the error message."""
    from distributed import as_completed

    stats = RunStats()
    order = cost_order(tasks, cost)
    if not order:
        return stats
    t0 = time.perf_counter()
    pending = iter(order)
    ac = as_completed()
    futs = {}
    last_error: dict = {}

    def submit(task: int) -> None:
        attempt = stats.attempts.get(task, 0)
        kw = kwargs_of(task) if kwargs_of is not None else {}
        f = client.submit(fn, *args_of(task), key=f"{name}-{token[:12]}-{task}-{attempt}",
                          retries=0, pure=False, **kw)
        futs[f.key] = task
        ac.add(f)

    for task in pending:
        submit(task)
        if len(futs) >= max(1, window):
            break
    with progress_bar(len(order) + done, name, progress, initial=done) as bar:
        for fut in ac:
            task = futs.pop(fut.key)
            try:
                res = fut.result()
            except Exception as e:  # worker died, or the task raised: resubmit, within limits
                summary, text = _describe(e, fut.traceback() if fut.status == "error" else None)
                fut.release()
                stats.attempts[task] = stats.attempts.get(task, 0) + 1
                same = last_error.get(task) == summary or deterministic(e)
                last_error[task] = summary
                if stats.attempts[task] > retries or same:
                    for f in list(ac.futures):
                        f.cancel()
                    why = (f"{stats.attempts[task]} times" if not same else "the same error twice"
                           if stats.attempts[task] > 1 else "an error that a retry would repeat")
                    raise TaskFailed(f"{name} task {task} failed ({why}): {summary}; the finished "
                                     f"tasks are kept{': ' + repair if repair else ''}", text, e) from None
                stats.resubmitted += 1
                submit(task)
                continue
            fut.release()
            if on_result is not None:
                on_result(task, res)
            stats.finished += 1
            bar.update()
            nxt = next(pending, None)
            if nxt is not None:
                submit(nxt)
    stats.wall_s = time.perf_counter() - t0
    return stats


def gather_retrying(client, submit, count: int, retries: int = 3, name: str = "task",
                    repair: str = "") -> list:
    """Results of the futures submit(i, attempt) for i in range(count), in order. A task that
    raises is resubmitted (attempt + 1) up to `retries` times, unless the failure is
    deterministic (`deterministic`: a RadiosityError such as a corrupted chunk, a full or
    read-only filesystem), which is raised at once as it is; one that keeps failing raises
    TaskFailed with the worker's traceback. (A dead worker's tasks are rescheduled by the
    scheduler itself and cost no attempt; a task cancelled because a scattered input died with
    its worker costs one, and `submit` should scatter that input again when attempt > 0.)"""
    from concurrent.futures import CancelledError

    from distributed import wait

    pending = {i: submit(i, 0) for i in range(count)}
    out: list = [None] * count
    attempts = [0] * count
    while pending:
        try:
            wait(list(pending.values()))
        except Exception:  # some were cancelled: an input's only copy died with a worker
            pass
        for i, f in list(pending.items()):
            if f.status == "finished":
                out[i] = f.result()
                del pending[i]
                continue
            if f.status not in ("error", "cancelled", "lost"):
                continue  # still running: the next round waits for it
            try:
                exc, trace = f.exception(), f.traceback()
            except Exception as e:  # cancelled: no exception object to fetch
                exc, trace = e, None
            attempts[i] += 1
            if deterministic(exc) or attempts[i] > retries:
                for g in pending.values():
                    g.cancel()
                if deterministic(exc):
                    raise exc
                if isinstance(exc, CancelledError):  # lost inputs: the caller scatters again
                    raise exc
                summary, text = _describe(exc, trace)
                raise TaskFailed(f"{name} {i} failed {attempts[i]} times: {summary}"
                                 f"{': ' + repair if repair else ''}", text, exc) from None
            f.release()
            pending[i] = submit(i, attempts[i])
    return out
