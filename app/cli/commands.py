"""The `radiosity` command: one subcommand per pipeline stage, over a Dask cluster.

Every flag overrides the matching `radiosity.*` key of dask.config (see radiosity.yaml).
"""

from __future__ import annotations

import functools
import math
import os
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
        from radiosity.runtime.faults import fs_error, fs_error_line, kept, write_failure_log
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


class _Finite(click.FloatRange):
    """A float in a range that is also finite (click's FloatRange lets NaN through)."""

    def convert(self, value, param, ctx):
        v = super().convert(value, param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return v


POSITIVE_INT = click.IntRange(min=1)
POSITIVE = _Finite(min=0.0, min_open=True)
TOL = _Finite(min=0.0, max=1.0, min_open=True, max_open=True)


def _resolution(ctx, param, value):
    """--resolution N|WxH, checked before anything starts (the scene loader takes the pair)."""
    from radiosity.errors import SceneError
    from radiosity.scene.load import parse_resolution

    if value is None:
        return None
    try:
        return parse_resolution(value, "--resolution")
    except SceneError as e:
        raise click.UsageError(str(e), ctx) from None


def _exposure(ctx, param, value):
    if value is None or str(value).lower() == "auto":
        return value
    try:
        v = float(value)
    except ValueError:
        v = float("nan")
    if not (math.isfinite(v) and v > 0):
        raise click.BadParameter(f"must be a positive number or 'auto', got {value!r}", ctx, param)
    return v


def _adaptive(ctx, param, value):
    from radiosity.runtime.cluster import adaptive_bounds

    if value is not None:
        try:
            adaptive_bounds(value, 1)
        except RadiosityError as e:
            raise click.BadParameter(str(e), ctx, param) from None
        import dask.config

        dask.config.set({"radiosity.cluster.adaptive": value})
    return value


def _number_list(kind, lo, what):
    """A callback for comma-separated lists (study accuracy): every item a `kind` > lo."""

    def cb(ctx, param, value):
        if value is None:  # an optional list not given
            return None
        try:
            items = [kind(x) for x in value.split(",") if x.strip()]
        except ValueError:
            raise click.BadParameter(f"expected comma-separated {what}, got {value!r}", ctx, param) from None
        bad = [x for x in items if not (math.isfinite(x) and x > lo)]
        if not items or bad:
            raise click.BadParameter(f"expected comma-separated {what}, got {value!r}", ctx, param)
        return value

    return cb


class OneLineGroup(click.Group):
    """Usage errors (a bad option value, a missing argument) as one line `error: ...` with
    exit status 2, like every other user error, instead of click's usage block."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """The flags write dask.config; what they wrote is undone when the command ends, so a
        command run in-process (tests, notebooks) leaves no setting behind for the next one."""
        import copy

        import dask.config

        saved = copy.deepcopy(dask.config.config)
        try:
            return self._main(args, prog_name, complete_var, standalone_mode, **extra)
        finally:
            dask.config.config.clear()
            dask.config.config.update(saved)
            for d in dask.config.defaults:  # defaults registered meanwhile (a first import of distributed)
                dask.config.update(dask.config.config, copy.deepcopy(d), priority="old")

    def _main(self, args, prog_name, complete_var, standalone_mode, **extra):
        _ARGV[:] = list(sys.argv[1:] if args is None else args)
        _T0[0] = time.time()
        if args is None:  # a real command: count the interpreter's start and imports too
            try:
                import psutil

                _T0[0] = min(_T0[0], psutil.Process().create_time())
            except Exception:
                pass
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, False, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, False, **extra)
        except click.ClickException as e:
            hint = ""
            if isinstance(e, click.UsageError) and e.ctx is not None:
                hint = f" (see: {e.ctx.command_path} --help)"
            msg = " ".join(e.format_message().split())
            click.echo(f"error: {msg}{hint}", err=True)
            sys.exit(e.exit_code)
        except click.Abort:  # Ctrl-C outside a command (commands say what they kept)
            click.echo("interrupted", err=True)
            sys.exit(130)
        sys.exit(rv if isinstance(rv, int) else 0)


def _set_config(key_fn):
    """A click callback that writes a flag's value into dask.config (None leaves it alone)."""

    def cb(ctx, param, value):
        import dask.config

        if value is not None and value is not False:
            dask.config.set(key_fn(value))
        return value

    return cb


_JQ = ("slurm", "pbs", "sge", "lsf")


def _jobqueue(key):
    def keys(v):
        out = {}
        for kind in _JQ:
            k = "project" if key == "account" and kind in ("sge", "lsf") else key
            out[f"jobqueue.{kind}.{k}"] = v
        return out
    return keys


def kernel_options(fn, help_="Form-factor kernel (default: radiosity.solve.kernel)."):
    """--kernel and the sampled kernels' --nxm-points / --mc-samples / --mc-seed."""
    from radiosity.core.kernels import KERNELS

    for name, key, help2 in (
            ("--mc-seed", "mc-seed", "mc kernel: seed of the random sample points."),
            ("--mc-samples", "mc-samples", "mc kernel: random sample pairs (rays) per pair."),
            ("--nxm-points", "nxm-points", "nxm kernel: sample points per element (a square).")):
        kind = click.IntRange(min=0) if key == "mc-seed" else POSITIVE_INT
        fn = click.option(name, type=kind, default=None, expose_value=False, help=help2,
                          callback=_set_config(lambda v, k=key: {f"radiosity.solve.{k}": v}))(fn)
    return click.option("--kernel", type=click.Choice(list(KERNELS)), default=None, help=help_)(fn)


def cluster_options(fn):
    """--workers / --scheduler / --cluster and the batch-job and security flags, shared by every
    heavy command; the flags write dask.config (radiosity.cluster.*, jobqueue.<kind>.*)."""
    for name, key, kind, help_ in (
            ("--account", "account", str, "Batch jobs: account (project on SGE/LSF)."),
            ("--queue", "queue", str, "Batch jobs: queue / partition."),
            ("--walltime", "walltime", str, "Batch jobs: walltime, e.g. 02:00:00."),
            ("--memory", "memory", str, "Batch jobs: memory per job, e.g. 16GB."),
            ("--cores", "cores", POSITIVE_INT, "Batch jobs: cores per job.")):
        fn = click.option(name, type=kind, default=None, expose_value=False, help=help_,
                          callback=_set_config(_jobqueue(key)))(fn)
    fn = click.option("--tls", is_flag=True, default=False, expose_value=False,
                      help="TLS with temporary certificates (multi-host runs).",
                      callback=_set_config(lambda v: {"radiosity.cluster.tls": "temporary"}))(fn)
    fn = click.option("--adaptive", default=None, metavar="MIN:MAX", expose_value=False,
                      help="Scale the cluster adaptively between MIN and MAX workers.",
                      callback=_adaptive)(fn)
    fn = click.option("--cluster", "cluster_kind", type=click.Choice(["local", "slurm", "pbs", "sge", "lsf"]),
                      default=None, help="Where workers run (default: radiosity.cluster.kind, local).")(fn)
    fn = click.option("--scheduler", default=None, metavar="ADDRESS",
                      help="Use a running Dask scheduler instead of starting a cluster.")(fn)
    fn = click.option("--workers", type=POSITIVE_INT, default=None,
                      help="Number of workers (default: one per core).")(fn)
    return fn


def method_options(fn, links: bool = True):
    """--method pairs|hierarchical, and the hierarchical method's --epsilon / --link-rays
    (they write radiosity.visibility.method and radiosity.hierarchy.*)."""
    if links:
        fn = click.option("--link-rays", type=POSITIVE_INT, default=None, expose_value=False,
                          help="hierarchical: sample rays per link not proven visible (a square).",
                          callback=_set_config(lambda v: {"radiosity.hierarchy.link-rays": v}))(fn)
        fn = click.option("--epsilon", type=click.FloatRange(min=0.0), default=None, expose_value=False,
                          help="hierarchical: refine links while their error estimate exceeds this.",
                          callback=_set_config(lambda v: {"radiosity.hierarchy.epsilon": v}))(fn)
    return click.option("--method", type=click.Choice(["auto", "pairs", "hierarchical"]), default=None,
                        expose_value=False,
                        help="pairs: one visibility bit per pair of sub-elements (the seed's); "
                             "hierarchical: links between nodes of the split trees; auto (the "
                             "default, radiosity.visibility.method): hierarchical above "
                             "radiosity.visibility.hierarchical-above sub-elements.",
                        callback=_set_config(lambda v: {"radiosity.visibility.method": v}))(fn)


def _method(rs, kernel: str | None = None) -> tuple[str, str]:
    """(method, why) of a run: --method / radiosity.visibility.method, auto by its size."""
    from radiosity.settings import choose_method

    part = rs.load_partition()
    return choose_method(len(part), kernel=kernel, originals=len(part.offsets) - 1)


def _solved_method(rs) -> str:
    """The method a solve takes: the stated one, else the one whose stage ran (each stage
    drops the other's output, so a run holds links or a visibility matrix, not both)."""
    from radiosity import config
    from radiosity.methods.hierarchical.store import LinkStore

    stated = config.get("visibility.method")
    if stated in ("pairs", "hierarchical"):
        return stated
    return "hierarchical" if LinkStore(rs).token() is not None else "pairs"


def _table(rows: list[tuple[str, object]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


@click.group(cls=OneLineGroup)
@click.version_option(package_name="radiosity")
def main():
    """Radiosity with simplified form factors (Debelov & Sattarov) on Dask."""


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Run directory to create.")
@click.option("--resolution", default=None, metavar="N|WxH", callback=_resolution,
              help="Override the camera resolution.")
@click.option("--subpixel", type=POSITIVE_INT, default=None, help="Criterion on a K-times finer raster.")
@click.option("--variant", type=click.Choice(["exact", "seed", "none"]), default=None,
              help="exact: equals the sequential partition; seed: each subscene renders alone "
                   "(seed §4.2); none: no subdivision (the seed's image without preprocessing).")
@click.option("--subscenes", type=POSITIVE_INT, default=None, help="Number of subscene tasks.")
@cluster_options
@_friendly
def preprocess(scene, out, resolution, subpixel, variant, subscenes, workers, scheduler, cluster_kind):
    """Camera-driven subdivision of SCENE (seed §3) into the run directory OUT."""
    from radiosity.runtime.cluster import open_client
    from radiosity.runtime.checks import check_new_run_dir, check_scene
    from radiosity.stages.preprocess import preprocess as run
    from radiosity.runtime.runlock import run_lock
    from radiosity.scene.load import load_scene

    sc = load_scene(scene, resolution=resolution)
    check_scene(sc, subpixel)
    check_new_run_dir(out)
    _started(out, resume=False)
    click.echo(f"scene {sc.name}: {len(sc.elements)} original elements, camera "
               f"{sc.camera.width}x{sc.camera.height}")
    with run_lock(out, _command_line()), open_client(workers, scheduler, cluster_kind,
                                                     echo=click.echo) as client:
        fig = run(sc, out, client, subpixel=subpixel, variant=variant, subscenes=subscenes)
        _record_run(out, sc.name)
    click.echo(_table(_finish(out, fig.rows())))
    click.echo(f"wrote {out}/store.zarr and {out}/report.json")


@main.command()
@click.argument("run_dir", type=click.Path())
@click.option("--task-unit", type=click.Choice(["block", "stripe", "auto"]), default=None,
              help="One task per pair of originals (block), per original (stripe), or auto.")
@click.option("--resume", is_flag=True, help="Keep the finished tasks of an interrupted run.")
@lambda fn: kernel_options(fn, "The kernel the matrix is for: nxm and mc cast one ray per "
                                "sample pair (default: radiosity.solve.kernel).")
@method_options
@cluster_options
@_friendly
def visibility(run_dir, task_unit, resume, kernel, workers, scheduler, cluster_kind):
    """The visibility matrix of a preprocessed RUN_DIR (seed §4.3), bit-packed in its store;
    with --method hierarchical, the links between nodes of its split trees instead."""
    from radiosity import config
    from radiosity.runtime.cluster import open_client
    from radiosity.runtime.checks import check_run_dir
    from radiosity.runtime.runlock import run_lock
    from radiosity.settings import sampling_of
    from radiosity.runtime.store import RunStore
    from radiosity.methods.pairs.visibility import compute_visibility

    check_run_dir(run_dir)
    method, why = _method(RunStore(run_dir), kernel)  # fails before starting a cluster
    click.echo(f"method: {why}")
    if method == "hierarchical":
        from radiosity.methods.hierarchical.links import compute_links, links_rows, resolve_params

        resolve_params(RunStore(run_dir).load_elements(), kernel)  # bad settings fail here
        _started(run_dir)
        with run_lock(run_dir, _command_line()), open_client(workers, scheduler, cluster_kind,
                                                             echo=click.echo) as client:
            _record_run(run_dir)
            fig = compute_links(run_dir, client, kernel=kernel, unit=task_unit, resume=resume)
        click.echo(_table(_finish(run_dir, links_rows(fig))))
        return
    sampling_of(config.get("solve.kernel", kernel))  # a bad nxm-points / mc-samples fails here
    _started(run_dir)
    with run_lock(run_dir, _command_line()), open_client(workers, scheduler, cluster_kind,
                                                         echo=click.echo) as client:
        _record_run(run_dir)
        fig = compute_visibility(run_dir, client, unit=task_unit, resume=resume, kernel=kernel)
    click.echo(_table(_finish(run_dir, fig.rows())))


def solve_options(fn):
    """--solver / --kernel (and its sampling) / --tol / --max-iterations / --closure."""
    from radiosity.core.solvers import SOLVERS

    fn = click.option("--closure", type=click.Choice(["auto", "on", "off"]), default=None,
                      expose_value=False,
                      help="Is the scene closed (rows balanced to exactly 1)? auto: from the geometry.",
                      callback=_set_config(lambda v: {"radiosity.solve.closure": v}))(fn)
    fn = click.option("--keep-unconverged", is_flag=True,
                      help="Write the solution even when the solver did not converge (by default "
                           "a converged solution already in the run is kept; exit status 3 "
                           "either way).")(fn)
    fn = click.option("--max-iterations", type=POSITIVE_INT, default=None, help="Pass limit.")(fn)
    fn = click.option("--tol", type=TOL, default=None,
                      help="Relative residual to stop at, in (0, 1).")(fn)
    fn = kernel_options(fn)
    fn = click.option("--solver", type=click.Choice(["auto", *SOLVERS]), default=None,
                      help="Solver (default: radiosity.solve.solver, auto: CG for reciprocal "
                           "kernels, Gauss-Seidel otherwise).")(fn)
    return fn


def image_options(fn):
    fn = click.option("--exposure", default=None, callback=_exposure,
                      help="Exposure for PNG/mesh colours, or 'auto'.")(fn)
    fn = click.option("--sigma", type=POSITIVE, default=None, help="Gaussian sigma in fine pixels.")(fn)
    fn = click.option("--filter", "filter_", type=click.Choice(["box", "gaussian"]), default=None,
                      help="Sub-pixel reconstruction filter.")(fn)
    return fn


@main.command()
@click.argument("run_dir", type=click.Path())
@solve_options
@lambda fn: method_options(fn, links=False)
@cluster_options
@_friendly
def solve(run_dir, solver, kernel, tol, max_iterations, keep_unconverged, workers, scheduler,
          cluster_kind):
    """Solve the radiosity system of RUN_DIR (after visibility): form factors on the fly;
    with --method hierarchical, over its links (the kernel was fixed by the link stage)."""
    from radiosity.runtime.cluster import open_client
    from radiosity.runtime.checks import check_run_dir, check_solve
    from radiosity.stages.image import previewer
    from radiosity.runtime.runlock import run_lock
    from radiosity.stages.solve import run_solve
    from radiosity.runtime.store import RunStore
    from radiosity.methods.pairs.store import VisibilityStore

    check_solve(solver, kernel)
    check_run_dir(run_dir)
    rs = RunStore(run_dir)
    rs.load_partition()
    hierarchical = _solved_method(rs) == "hierarchical"
    if hierarchical:
        from radiosity.methods.hierarchical.operator import run_solve_links
        from radiosity.methods.hierarchical.store import LinkStore

        LinkStore(rs).require()
    else:
        VisibilityStore(rs).require()
    _started(run_dir, resume=False)
    with run_lock(run_dir, _command_line()), open_client(workers, scheduler, cluster_kind,
                                                         echo=click.echo) as client:
        if hierarchical:
            fig = run_solve_links(run_dir, client, solver=solver, tol=tol, max_iter=max_iterations,
                                  keep_unconverged=keep_unconverged)
        else:
            fig = run_solve(run_dir, client, solver=solver, kernel=kernel, tol=tol,
                            max_iter=max_iterations, preview=previewer(run_dir),
                            keep_unconverged=keep_unconverged)
        _record_run(run_dir)
    click.echo(_table(_finish(run_dir, fig.rows())))
    if not fig.converged:
        sys.exit(NOT_CONVERGED)


@main.command()
@click.argument("run_dir", type=click.Path())
@image_options
@_friendly
def image(run_dir, filter_, sigma, exposure):
    """Write image.exr, image.png, mesh.glb, mesh.ply and viewer.html of a solved RUN_DIR."""
    from radiosity.runtime.checks import check_run_dir
    from radiosity.stages.image import render_outputs
    from radiosity.runtime.runlock import run_lock

    check_run_dir(run_dir)
    _started(run_dir, resume=False)
    with run_lock(run_dir, _command_line()):
        fig = render_outputs(run_dir, filter=filter_, sigma=sigma, exposure=exposure)
        _record_run(run_dir)
        _finish(run_dir, [])
    click.echo(f"wrote {run_dir}/image.exr, image.png, mesh.glb, mesh.ply, viewer.html "
               f"({fig.width}x{fig.height}, exposure {fig.exposure:.3g})")


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--resolution", default=None, metavar="N|WxH", callback=_resolution,
              help="Override the camera resolution.")
@click.option("--subpixel", type=POSITIVE_INT, default=None, help="Criterion on a K-times finer raster.")
@click.option("--tol", type=TOL, default=None, help="Solver tolerance (for the pass estimate).")
@_friendly
def plan(scene, resolution, subpixel, tol):
    """Print which effects SCENE calls for, which are skipped and why, before any heavy work."""
    from radiosity.pipeline import scene_plan
    from radiosity.scene.effects import describe
    from radiosity.runtime.checks import check_scene
    from radiosity.scene.load import load_scene

    sc = load_scene(scene, resolution=resolution)
    check_scene(sc, subpixel)
    planned = scene_plan(sc, subpixel, tol)
    click.echo(f"scene {sc.name}: {len(sc.elements)} original elements, camera "
               f"{sc.camera.width}x{sc.camera.height}")
    click.echo(describe(planned.effects, planned.unseen_unsplit, planned.sub_elements,
                        planned.closure))
    from radiosity.scene.splittrees import LINKS_PER_LEAF
    from radiosity.settings import choose_method
    from radiosity.methods.hierarchical.store import LINK_DTYPE

    method, why = choose_method(planned.sub_elements, originals=len(sc.elements))
    lo, hi = (k * planned.sub_elements for k in LINKS_PER_LEAF)
    click.echo(f"method: {why}; the hierarchical method would keep {lo:.2g} to {hi:.2g} links "
               f"({LINKS_PER_LEAF[0]:g}-{LINKS_PER_LEAF[1]:g} per sub-element as measured, "
               f"{LINK_DTYPE.itemsize} bytes each), where pairs needs one bit per facing pair")


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Run directory.")
@click.option("--resolution", default=None, metavar="N|WxH", callback=_resolution,
              help="Override the camera resolution.")
@click.option("--subpixel", type=POSITIVE_INT, default=None, help="Criterion on a K-times finer raster.")
@click.option("--task-unit", type=click.Choice(["block", "stripe", "auto"]), default=None)
@click.option("--resume", is_flag=True, help="Reuse the partition and finished visibility tasks in OUT.")
@click.option("--no-preview", is_flag=True, help="Skip preview.png (the original elements only).")
@click.option("--full", is_flag=True, help="Simulate every effect, whatever the plan says.")
@solve_options
@method_options
@image_options
@cluster_options
@_friendly
def render(scene, out, resolution, subpixel, task_unit, resume, no_preview, full, solver, kernel,
           tol, max_iterations, keep_unconverged, filter_, sigma, exposure, workers, scheduler,
           cluster_kind):
    """Preprocess, visibility, solve and image of SCENE into the run directory OUT."""
    from radiosity.runtime.cluster import open_client
    from radiosity.pipeline import render_scene
    from radiosity.runtime.checks import check_new_run_dir, check_scene, check_solve
    from radiosity.runtime.runlock import run_lock
    from radiosity.scene.load import load_scene

    sc = load_scene(scene, resolution=resolution)
    check_solve(solver, kernel)
    check_scene(sc, subpixel)
    check_new_run_dir(out)
    _started(out)
    click.echo(f"scene {sc.name}: {len(sc.elements)} original elements, camera "
               f"{sc.camera.width}x{sc.camera.height}")
    if max_iterations is not None:
        import dask.config
        dask.config.set({"radiosity.solve.max-iterations": max_iterations})
    with run_lock(out, _command_line()), open_client(workers, scheduler, cluster_kind,
                                                     echo=click.echo) as client:
        rep = render_scene(sc, out, client, subpixel=subpixel, unit=task_unit, solver=solver,
                           kernel=kernel, tol=tol, filter=filter_, sigma=sigma, exposure=exposure,
                           resume=resume, preview=not no_preview, echo=click.echo, full=full,
                           keep_unconverged=keep_unconverged)
        _record_run(out, sc.name)
    click.echo(_table(_finish(out, rep.rows())))
    click.echo(f"wrote {out}/image.exr, image.png, preview.png, mesh.glb, mesh.ply, viewer.html, report.json"
               if not no_preview else f"wrote {out}/image.exr, image.png, mesh.glb, mesh.ply, viewer.html, report.json")
    if not rep["solve"].get("converged", True):
        sys.exit(NOT_CONVERGED)


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Directory for reference.exr, "
              "reference-stderr.exr and reference.json.")
@click.option("--spp", type=click.IntRange(min=1), default=None,
              help="Samples per pixel in all (default: radiosity.reference.spp).")
@click.option("--passes", type=POSITIVE_INT, default=None,
              help="Independent passes the samples are split into, for the standard error "
                   "(default: radiosity.reference.passes).")
@click.option("--resolution", default=None, metavar="N|WxH", callback=_resolution,
              help="Override the camera resolution.")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Seed of the first pass.")
@click.option("--variant", type=click.Choice(["auto", "llvm_ad_rgb", "scalar_rgb"]), default=None,
              help="Mitsuba variant (default: radiosity.reference.variant, auto).")
@_friendly
def reference(scene, out, spp, passes, resolution, seed, variant):
    """Ground truth: SCENE path-traced by Mitsuba 3 (the same elements, materials, sides and
    camera); mean radiance, per-pixel standard error and figures into OUT."""
    from radiosity.runtime.checks import check_new_run_dir
    from radiosity.validation.reference import make_reference
    from radiosity.scene.load import load_scene

    sc = load_scene(scene, resolution=resolution)
    check_new_run_dir(out)
    fig = make_reference(sc, out, spp=spp, passes=passes, seed=seed, variant=variant, echo=click.echo)
    click.echo(_table([
        ("samples", f"{fig['spp']} spp in {fig['passes']} passes ({fig['variant']}, Mitsuba "
                    f"{fig['mitsuba_version']})"),
        ("path depth", f"{fig['max_depth']} (max reflectance {fig['max_reflectance']:.3g}: light "
                       f"dropped <= {fig['truncation_bound']:.2g} of the largest radiance)"),
        ("relative std. error", f"median {fig['rel_stderr_median']:.3g}, 99th percentile "
                                f"{fig['rel_stderr_p99']:.3g}"),
        ("time", f"{fig['time_s']:.1f} s")]))
    click.echo(f"wrote {out}/reference.exr, reference-stderr.exr, reference.json")


@main.command()
@click.argument("a", type=click.Path())
@click.argument("b", type=click.Path())
@click.option("--out", "-o", default=None, type=click.Path(),
              help="Directory for compare.png (false-colour relative difference) and compare.json.")
@_friendly
def compare(a, b, out):
    """Error of image A against reference B (EXR, linear RGB): mean absolute relative error,
    max, per channel; B's noise when B-stderr.exr lies beside it."""
    from radiosity.validation.compare import compare_files
    from radiosity.runtime.checks import check_new_run_dir

    if out:
        check_new_run_dir(out)
    fig = compare_files(a, b, out)
    pc = fig["per_channel"]
    rows = [("pixels", f"{fig['pixels']} of {fig['width']}x{fig['height']} (where B > 0)"),
            ("mean abs. relative error", f"{fig['mare']:.4g}"),
            ("max relative error", f"{fig['max']:.4g}"),
            ("per channel R, G, B", f"{pc['R']:.4g}, {pc['G']:.4g}, {pc['B']:.4g}")]
    if "noise_floor" in fig:
        rows.append(("B's own noise", f"{fig['noise_floor']:.4g} (the error an exact image would show)"))
    click.echo(_table(rows))
    if out:
        click.echo(f"wrote {out}/compare.png (scale +-{fig['scale']:.3g}), {out}/compare.json")


@main.command()
@click.argument("mesh", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Run directory to create.")
@click.option("--accuracy", type=POSITIVE, default=None,
              help="Target absolute error of each factor (default: radiosity.viewfactors.accuracy).")
@click.option("--enclosure", type=click.Choice(["auto", "on", "off"]), default=None,
              help="Balance rows to 1 keeping reciprocity: auto (closed meshes with inward "
                   "normals), on, off (default: radiosity.viewfactors.enclosure).")
@click.option("--format", "fmt", type=click.Choice(["npz", "csv"]), default="npz", show_default=True,
              help="viewfactors.npz always; csv adds viewfactors.csv (small meshes).")
@click.option("--cutoff", type=_Finite(min=0.0), default=None,
              help="Drop cluster pairs whose form-factor bound is at most this (default 0: none).")
@click.option("--resume", is_flag=True, help="Keep the finished tasks of an interrupted run in OUT.")
@cluster_options
@_friendly
def viewfactors(mesh, out, accuracy, enclosure, fmt, cutoff, resume, workers, scheduler, cluster_kind):
    """View factors between the facets of MESH (OBJ, glTF, PLY or a scene TOML): sparse,
    obstructed, reciprocal; rows balanced to 1 for enclosures."""
    from radiosity.runtime.cluster import open_client
    from radiosity.viewfactors.api import compute_viewfactors, load_facets, resolve_params

    from radiosity.runtime.checks import check_new_run_dir
    from radiosity.runtime.runlock import run_lock

    resolve_params(accuracy, cutoff)  # bad values fail before the cluster starts
    fac = load_facets(mesh)
    check_new_run_dir(out)
    _started(out)
    click.echo(f"{len(fac)} facets from {', '.join(fac.sources)}")
    with run_lock(out, _command_line()), open_client(workers, scheduler, cluster_kind,
                                                     echo=click.echo) as client:
        res = compute_viewfactors(fac, out, client, accuracy=accuracy, enclosure=enclosure,
                                  fmt=fmt, cutoff=cutoff, resume=resume)
    click.echo(_viewfactors_summary(res.figures))
    click.echo(f"wrote {out}/" + f", {out}/".join(res.figures["files"] + ["report.json"]))


def _viewfactors_summary(fig: dict) -> str:
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
            ("time", f"{fig['time_s']:.2f} s")]
    return _table(rows)


@main.group()
def study():
    """Studies: what accuracy costs in time."""


def _floats(s: str, kind=float):
    return [kind(x) for x in s.split(",") if x.strip()]


@study.command("accuracy")
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Directory for results.")
@click.option("--resolutions", default="8,16,32", show_default=True, help="Camera resolutions.",
              callback=_number_list(int, 0, "positive integers"))
@click.option("--subpixels", default="1", show_default=True, help="Sub-pixel factors.",
              callback=_number_list(int, 0, "positive integers"))
@click.option("--kernels", default="point,disc", show_default=True,
              help="Form-factor kernels; the sampled ones may name their sample count: nxm:16, mc:64.")
@click.option("--tols", default="1e-6", show_default=True, help="Solver tolerances.",
              callback=_number_list(float, 0.0, "tolerances > 0"))
@click.option("--reference", default=None, metavar="auto|PATH.exr",
              help="auto: ground truth path-traced by Mitsuba 3 (made once in OUT/reference, "
                   "reused), and the path tracer itself in the sweep; or a reference image (EXR).")
@click.option("--reference-spp", type=click.IntRange(min=1), default=None,
              help="--reference auto: samples per pixel of the reference "
                   "(default: radiosity.reference.study-spp).")
@click.option("--path-tracer-spp", default=None, metavar="N,N,...",
              help="--reference auto: the path tracer's sample counts (default: 1, 4, 16, ... "
                   "up to the reference's / 16).")
@click.option("--epsilons", default=None, metavar="E,E,...",
              callback=_number_list(float, -1e-300, "numbers >= 0"),
              help="Also sweep --method hierarchical at these epsilons (x --link-rays).")
@click.option("--link-rays", "link_rays", default="4", show_default=True, metavar="K,K,...",
              callback=_number_list(int, 0, "positive integers"),
              help="With --epsilons: the hierarchical method's rays per link (squares).")
@click.option("--solver", default=None, help="Solver (default: radiosity.solve.solver).")
@cluster_options
@_friendly
def study_accuracy(scene, out, resolutions, subpixels, kernels, tols, reference, reference_spp,
                   path_tracer_spp, epsilons, link_rays, solver, workers, scheduler, cluster_kind):
    """Sweep resolution x sub-pixel x kernel x tolerance on SCENE (and, with --epsilons, the
    hierarchical method's epsilon x link rays); time every stage, measure the error; write
    results.csv, results.md and accuracy.png (error against time, Pareto front)."""
    from radiosity.runtime.cluster import open_client
    from radiosity.validation.study import HIER, accuracy, kernel_setting

    ks = [k for k in kernels.split(",") if k]
    if epsilons:
        ks += [f"{HIER}:{e:g}:{k}" for e in _floats(epsilons) for k in _floats(link_rays, int)]
    for k in ks:
        kernel_setting(k)  # a bad name or count fails before the cluster starts
    if reference == "auto":
        from radiosity.validation.reference import load_mitsuba

        load_mitsuba(echo=click.echo)  # Mitsuba missing fails before the sweep
    elif reference is not None and not os.path.isfile(reference):
        raise RadiosityError(f"--reference {reference}: no such file (give an EXR image, or auto)")
    pts = _floats(path_tracer_spp, int) if path_tracer_spp else None
    with open_client(workers, scheduler, cluster_kind, echo=click.echo) as client:
        rows = accuracy(scene, out, client, _floats(resolutions, int), _floats(subpixels, int), ks,
                        _floats(tols), reference=reference, solver=solver, echo=click.echo,
                        reference_spp=reference_spp, path_tracer_spp=pts)
    best = [r for r in rows if r["pareto"]]
    click.echo(f"wrote {out}/results.csv, results.md, accuracy.png; {len(best)} settings on the Pareto front")


@study.command("seed")
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Directory for plots and tables.")
@click.option("--resolutions", default="32,64,128,256", show_default=True,
              callback=_number_list(int, 0, "positive integers"))
@click.option("--speedup-resolution", type=POSITIVE_INT, default=96, show_default=True)
@click.option("--max-workers", type=POSITIVE_INT, default=None, help="Largest LocalCluster for the speedup.")
@_friendly
def study_seed(scene, out, resolutions, speedup_resolution, max_workers):
    """Reproduce the seed's experiments on SCENE: Fig. 3, Fig. 4, the speedup table and the image
    series; writes PNG plots and seed.md into OUT."""
    from radiosity.runtime.cluster import default_workers, open_client
    from radiosity.validation.study import seed

    n = max_workers or default_workers()
    res = seed(scene, out, lambda w: open_client(w, quiet=True), _floats(resolutions, int),
               list(range(1, n + 1)), speedup_resolution, echo=click.echo)
    click.echo(f"wrote {out}/seed.md and its plots; visibility time ~ m^{res['order']:.2f}")


if __name__ == "__main__":  # pragma: no cover
    main()
