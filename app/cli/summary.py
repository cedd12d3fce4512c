"""What the CLI prints and records around every command: the one-line endings of a run that
stops early (errors, Ctrl-C, filesystem faults), report.json's "run" section, the summary table.
"""

from __future__ import annotations

import functools
import sys
import time
import warnings

import click

from radiosity.errors import RadiosityError


def _showwarning(message, category, filename, lineno, file=None, line=None):
    click.echo(f"warning: {message}", err=True)


#: Exit status of a solve (or render) whose solver did not reach the tolerance (docs/src/reference/errors.md).
NOT_CONVERGED = 3

#: What the running command works on, for the line an interrupted or failed run prints:
#: run_dir, and again: the command that continues it (set by each command as it starts).
_RUN: dict = {}
ARGV: list = []
REAL: list = [False]  # a real command (the `radiosity` process), not a test's CliRunner
T0: list = [time.time()]  # when the command started (the process's start for a real command)


def command_line(resume: bool = False) -> str:
    """The command being run, as the user can type it again (with --resume if asked)."""
    import shlex

    args = list(ARGV)
    if resume and "--resume" not in args:
        args.append("--resume")
    return "radiosity " + shlex.join(args)


def friendly(fn):
    """Every way a command can stop, as one line: RadiosityError (exit 2; a failed task's
    worker traceback goes to a log file the line names), a filesystem fault (exit 2), Ctrl-C
    (exit INTERRUPTED, 130: what was kept and the command that continues). Our warnings
    without source lines."""

    @functools.wraps(fn)
    def wrapper(*a, **kw):
        from radiosity.runtime.faults import fs_error, fs_error_line, write_failure_log
        from radiosity.runtime.runner import TaskFailed

        old = warnings.showwarning
        warnings.showwarning = _showwarning
        old_hook = sys.unraisablehook
        sys.unraisablehook = functools.partial(_unraisable, old_hook)
        _RUN.clear()
        try:
            return fn(*a, **kw)
        except RadiosityError as e:
            msg = str(e)
            if isinstance(e, TaskFailed) and e.worker_traceback:
                log = write_failure_log(_RUN.get("run_dir"), msg, e.worker_traceback)
                err = fs_error(e.cause) if e.cause is not None else None
                if err is not None:
                    msg = fs_error_line(err, _RUN.get("run_dir")) + (f"; then: {_RUN['again']}" if _RUN.get("again") else "")
                msg += f" (worker traceback in {log})"
            click.echo(f"error: {msg}", err=True)
            sys.exit(2)
        except KeyboardInterrupt:
            _ignore_sigint()
            what = kept(_RUN.get("run_dir"))
            again = _RUN.get("again")
            click.echo("interrupted" + (f": kept in {_RUN['run_dir']}: {what}" if what else "")
                       + (f"; continue with: {again}" if again else ""), err=True)
            _exit_interrupted()
        except OSError as e:
            err = fs_error(e)
            if err is None:
                raise
            click.echo(f"error: {fs_error_line(err, _RUN.get('run_dir'))}"
                       + (f"; then: {_RUN['again']}" if _RUN.get("again") else ""), err=True)
            sys.exit(2)
        finally:
            warnings.showwarning = old
            sys.unraisablehook = old_hook

    return wrapper


def _unraisable(hook, unraisable) -> None:
    """sys.unraisablehook while a command runs: a KeyboardInterrupt that Python could not raise
    (Ctrl-C handled inside a garbage-collector callback, such as distributed installs, or a
    __del__) is raised again in the main thread instead of printed and lost (the run went on)."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        import _thread
        import threading

        # from another thread: raised here, it would be lost the same way
        threading.Timer(0.01, _thread.interrupt_main).start()
        return
    hook(unraisable)


def _ignore_sigint() -> None:
    """A second Ctrl-C while the real command says what it kept: ignored (no traceback)."""
    import signal
    import threading

    if REAL[0] and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


#: Exit status of a command stopped by Ctrl-C (SIGINT), as shells report it (128 + 2).
INTERRUPTED = 130


def _exit_interrupted() -> None:
    """End an interrupted command with INTERRUPTED. The real command ends with os._exit once its
    line is out: the lock is released and the workers stopped by then, but an in-process
    worker's threads may still be in a kernel call, or a cluster still starting, and Python's
    shutdown would wait for them (seconds to minutes) where Ctrl-C must stop within 2 s."""
    if not REAL[0]:
        sys.exit(INTERRUPTED)
    import os
    from multiprocessing import util

    try:  # the semaphores of worker processes still starting: else the resource tracker
        util._run_finalizers(0)  # removes them itself, with a warning after our line
    except Exception:  # noqa: BLE001 - exiting all the same
        pass
    for f in (sys.stdout, sys.stderr):
        try:
            f.flush()
        except Exception:  # noqa: BLE001 - a closed pipe: nothing more to say
            pass
    os._exit(INTERRUPTED)


def mark_started(run_dir: str, resume: bool = True) -> None:
    """Say which run directory the command works on and how to continue it if it stops."""
    _RUN.update(run_dir=run_dir, again=command_line(resume))


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("radiosity")
    except Exception:
        return "unknown"


def record_run(run_dir: str, scene_name: str | None = None) -> None:
    """report.json's "run" section: who made this run directory and how (version, command
    line, date, scene); the command's wall time is added when it ends (finish_lines)."""
    import datetime
    import socket

    from radiosity.runtime.store import RunStore, update_report

    if scene_name is None:
        try:
            scene_name = RunStore(run_dir).attrs.get("scene_name")
        except Exception:
            scene_name = None
    update_report(run_dir, "run", {
        "version": _version(), "command": command_line(), "stage": ARGV[0] if ARGV else "",
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "scene": scene_name, "host": socket.gethostname()})


def finish_lines(run_dir: str | None, rows: list) -> list:
    """The summary's last row: the wall time of the whole command (start-up, imports, cluster
    start and stop, every stage), also written to report.json's "run" section."""
    wall = time.time() - T0[0]
    if run_dir is not None:
        from radiosity.runtime.store import update_report

        update_report(run_dir, "run", {"wall_s": round(wall, 3)})
    return [*rows, ("wall time", f"{wall:.1f} s (the whole command)")]


def kept(run_dir: str | None) -> str:
    """What run_dir holds that a rerun reuses, as a short phrase ("" when nothing): the
    partition, every stage's finished tasks as its ledger (manifest) holds them (each method's
    visibility or link tasks, the view-factor tasks), the last solution. Read after the
    cluster stopped: the driver alone records a task, so nothing is added meanwhile."""
    import os

    from radiosity.methods.base import METHODS, get_method
    from radiosity.runtime.store import RunStore

    if not run_dir or not os.path.isdir(os.path.join(run_dir, "store.zarr")):
        return ""
    from radiosity.viewfactors.store import kept as vf_kept

    parts = []
    try:
        rs = RunStore(run_dir)
        if rs.has("raster"):
            parts.append("the partition")
        parts += [k for k in (get_method(name).kept(rs) for name in METHODS) if k]
        if rs.has("solution"):
            parts.append("the last solution")
        if (k := vf_kept(rs)):
            parts.append(k)
    except Exception:  # a half-written store: say nothing rather than something wrong
        return ""
    return ", ".join(parts)


def table_text(rows: list[tuple[str, object]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)



def viewfactors_summary(fig: dict, extra: list = ()) -> str:
    """The view-factor stage's summary table (extra: rows after it, e.g. the wall time)."""
    pt = max(1, fig["pairs_total"])

    def part(k):
        return f"{fig[k]} ({fig[k] / pt:.1%})"

    hist = fig["row_sum_final_histogram"]
    rows = [("facets", fig["facets"]), ("pairs", fig["pairs_total"]),
            ("culled (face away)", f"{fig['pairs_culled_cluster'] + fig['pairs_facing_away']} "
                                   f"({(fig['pairs_culled_cluster'] + fig['pairs_facing_away']) / pt:.1%})"),
            ("dropped by cut-off", part("pairs_dropped_cutoff")),
            ("unobstructed, proven by shafts", part("pairs_proven_unobstructed")),
            ("sampled with rays", f"{part('pairs_sampled')}, {fig['rays']} rays"),
            ("exact / cheap kernel", f"{fig['pairs_exact_kernel']} / {fig['pairs_cheap_kernel']}"),
            ("nonzeros", fig["nonzeros"]),
            ("enclosure", ("balanced" if fig["balanced"] else "not balanced")
             + ("" if fig["enclosure"] else f" ({fig['not_enclosure_because']})")),
            *([("contact", f"{fig['contact_facets']} facets covered by a touching surface take "
                           f"no part; {fig.get('partly_covered_facets', 0)} partly covered: "
                           "capped, not balanced")] if fig.get("contact_facets") else []),
            ("row sums", f"{fig['row_sum_min']:.12g} .. {fig['row_sum_max']:.12g}"
             + (f", balanced: {fig['row_sum_final_min']:.15g} .. {fig['row_sum_final_max']:.15g}"
                if fig["balanced"] else "")),
            ("row sum histogram", ", ".join(f"{k}: {v}" for k, v in hist.items() if v)),
            ("reciprocity residual", f"{fig['reciprocity_residual_max']:.3g}"),
            ("obstructed > unobstructed", fig["obstructed_over_unobstructed"]),
            ("time", f"{fig['time_s']:.2f} s"), *extra]
    return table_text(rows)
