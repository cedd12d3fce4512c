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


#: Exit status of a solve (or render) whose solver did not reach the tolerance (README).
NOT_CONVERGED = 3

#: What the running command works on, for the line an interrupted or failed run prints:
#: run_dir, and again: the command that continues it (set by each command as it starts).
_RUN: dict = {}
_ARGV: list = []
_T0: list = [time.time()]  # when the command started (the process's start for a real command)


def _command_line(resume: bool = False) -> str:
    """The command being run, as the user can type it again (with --resume if asked)."""
    import shlex

    args = list(_ARGV)
    if resume and "--resume" not in args:
        args.append("--resume")
    return "radiosity " + shlex.join(args)


def _friendly(fn):
    """Every way a command can stop, as one line: RadiosityError (exit 2; a failed task's
    worker traceback goes to a log file the line names), a filesystem fault (exit 2), Ctrl-C
    (exit 130: what was kept and the command that continues). Our warnings without source
    lines."""

    @functools.wraps(fn)
    def wrapper(*a, **kw):
        from radiosity.runtime.faults import fs_error, fs_error_line, write_failure_log
        from radiosity.runtime.runner import TaskFailed

        old = warnings.showwarning
        warnings.showwarning = _showwarning
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
            what = kept(_RUN.get("run_dir"))
            again = _RUN.get("again")
            click.echo("interrupted" + (f": kept in {_RUN['run_dir']}: {what}" if what else "")
                       + (f"; continue with: {again}" if again else ""), err=True)
            sys.exit(130)
        except OSError as e:
            err = fs_error(e)
            if err is None:
                raise
            click.echo(f"error: {fs_error_line(err, _RUN.get('run_dir'))}"
                       + (f"; then: {_RUN['again']}" if _RUN.get("again") else ""), err=True)
            sys.exit(2)
        finally:
            warnings.showwarning = old

    return wrapper


def _started(run_dir: str, resume: bool = True) -> None:
    """Say which run directory the command works on and how to continue it if it stops."""
    _RUN.update(run_dir=run_dir, again=_command_line(resume))


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("radiosity")
    except Exception:
        return "unknown"


def _record_run(run_dir: str, scene_name: str | None = None) -> None:
    """report.json's "run" section: who made this run directory and how (version, command
    line, date, scene); the command's wall time is added when it ends (_finish)."""
    import datetime
    import socket

    from radiosity.runtime.store import RunStore, update_report

    if scene_name is None:
        try:
            scene_name = RunStore(run_dir).attrs.get("scene_name")
        except Exception:
            scene_name = None
    update_report(run_dir, "run", {
        "version": _version(), "command": _command_line(), "stage": _ARGV[0] if _ARGV else "",
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "scene": scene_name, "host": socket.gethostname()})


def _finish(run_dir: str | None, rows: list) -> list:
    """The summary's last row: the wall time of the whole command (start-up, imports, cluster
    start and stop, every stage), also written to report.json's "run" section."""
    wall = time.time() - _T0[0]
    if run_dir is not None:
        from radiosity.runtime.store import update_report

        update_report(run_dir, "run", {"wall_s": round(wall, 3)})
    return [*rows, ("wall time", f"{wall:.1f} s (the whole command)")]


def kept(run_dir: str | None) -> str:
    """What run_dir holds that a rerun reuses, as a short phrase ("" when nothing): the
    partition, every method's finished tasks, the last solution."""
    import os

    from radiosity.methods.base import METHODS, get_method
    from radiosity.runtime.store import RunStore

    if not run_dir or not os.path.isdir(os.path.join(run_dir, "store.zarr")):
        return ""
    parts = []
    try:
        rs = RunStore(run_dir)
        if rs.has("raster"):
            parts.append("the partition")
        parts += [k for k in (get_method(name).kept(rs) for name in METHODS) if k]
        if rs.has("solution"):
            parts.append("the last solution")
    except Exception:  # a half-written store: say nothing rather than something wrong
        return ""
    return ", ".join(parts)


def _table(rows: list[tuple[str, object]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)



def _viewfactors_summary(fig: dict, extra: list = ()) -> str:
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
            ("row sums", f"{fig['row_sum_min']:.12g} .. {fig['row_sum_max']:.12g}"
             + (f", balanced: {fig['row_sum_final_min']:.15g} .. {fig['row_sum_final_max']:.15g}"
                if fig["balanced"] else "")),
            ("row sum histogram", ", ".join(f"{k}: {v}" for k, v in hist.items() if v)),
            ("reciprocity residual", f"{fig['reciprocity_residual_max']:.3g}"),
            ("obstructed > unobstructed", fig["obstructed_over_unobstructed"]),
            ("time", f"{fig['time_s']:.2f} s"), *extra]
    return _table(rows)
