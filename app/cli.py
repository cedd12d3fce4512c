"""The `radiosity` command: one subcommand per pipeline stage, over a Dask cluster.

Every flag overrides the matching `radiosity.*` key of dask.config (see app/radiosity.yaml).
"""

from __future__ import annotations

import functools
import sys
import warnings

import click

from . import config
from .errors import RadiosityError


def _showwarning(message, category, filename, lineno, file=None, line=None):
    click.echo(f"warning: {message}", err=True)


def _friendly(fn):
    """Print RadiosityError as one line and exit 2; show our warnings without source lines."""

    @functools.wraps(fn)
    def wrapper(*a, **kw):
        old = warnings.showwarning
        warnings.showwarning = _showwarning
        try:
            return fn(*a, **kw)
        except RadiosityError as e:
            click.echo(f"error: {e}", err=True)
            sys.exit(2)
        finally:
            warnings.showwarning = old

    return wrapper


def cluster_options(fn):
    """--workers / --scheduler / --cluster, shared by every heavy command."""
    fn = click.option("--cluster", "cluster_kind", type=click.Choice(["local", "slurm", "pbs", "sge", "lsf"]),
                      default=None, help="Where workers run (default: radiosity.cluster.kind, local).")(fn)
    fn = click.option("--scheduler", default=None, metavar="ADDRESS",
                      help="Use a running Dask scheduler instead of starting a cluster.")(fn)
    fn = click.option("--workers", type=int, default=None,
                      help="Number of workers (default: one per core).")(fn)
    return fn


def _table(rows: list[tuple[str, object]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


@click.group()
@click.version_option(package_name="radiosity")
def main():
    """Radiosity with simplified form factors (Debelov & Sattarov) on Dask."""


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Run directory to create.")
@click.option("--resolution", default=None, metavar="N|WxH", help="Override the camera resolution.")
@click.option("--subpixel", type=int, default=None, help="Criterion on a K-times finer raster.")
@click.option("--variant", type=click.Choice(["exact", "seed"]), default=None,
              help="exact: equals the sequential partition; seed: each subscene renders alone (seed §4.2).")
@click.option("--subscenes", type=int, default=None, help="Number of subscene tasks.")
@cluster_options
@_friendly
def preprocess(scene, out, resolution, subpixel, variant, subscenes, workers, scheduler, cluster_kind):
    """Camera-driven subdivision of SCENE (seed §3) into the run directory OUT."""
    from .cluster import open_client
    from .pipeline import preprocess as run
    from .scene import load_scene

    sc = load_scene(scene, resolution=resolution)
    click.echo(f"scene {sc.name}: {len(sc.elements)} original elements, camera "
               f"{sc.camera.width}x{sc.camera.height}")
    with open_client(workers, scheduler, cluster_kind, echo=click.echo) as client:
        fig = run(sc, out, client, subpixel=subpixel, variant=variant, subscenes=subscenes)
    rows = [("original elements", fig["original_elements"]), ("sub-elements", fig["sub_elements"]),
            ("max depth", fig["max_depth"]), ("unseen, left unsplit", fig["unseen_unsplit"]),
            ("pixels hit", fig["pixels_hit"]), ("time", f"{fig['time_total_s']:.2f} s")]
    if "sub_elements_exact" in fig:
        rows.insert(2, ("sub-elements (exact variant)", fig["sub_elements_exact"]))
    click.echo(_table(rows))
    click.echo(f"wrote {out}/store.zarr and {out}/report.json")


@main.command()
@click.argument("run_dir", type=click.Path())
@click.option("--task-unit", type=click.Choice(["block", "stripe", "auto"]), default=None,
              help="One task per pair of originals (block), per original (stripe), or auto.")
@click.option("--resume", is_flag=True, help="Keep the finished tasks of an interrupted run.")
@cluster_options
@_friendly
def visibility(run_dir, task_unit, resume, workers, scheduler, cluster_kind):
    """The visibility matrix of a preprocessed RUN_DIR (seed §4.3), bit-packed in its store."""
    from .cluster import open_client
    from .store import RunStore
    from .visibility import compute_visibility

    RunStore(run_dir).load_partition()  # fail before starting a cluster
    with open_client(workers, scheduler, cluster_kind, echo=click.echo) as client:
        fig = compute_visibility(run_dir, client, unit=task_unit, resume=resume)
    click.echo(_visibility_summary(fig))


def _visibility_summary(fig: dict) -> str:
    pt = max(1, fig["pairs_total"])
    rows = [("sub-elements", fig["sub_elements"]),
            ("pairs", fig["pairs_total"]),
            ("culled by orientation", f"{fig['pairs_culled_by_orientation']} ({fig['pairs_culled_by_orientation'] / pt:.1%})"),
            ("proven visible by shafts", f"{fig['pairs_shaft_visible']} ({fig['pairs_shaft_visible'] / pt:.1%})"),
            ("rays cast", f"{fig['rays']} ({fig['rays'] / pt:.1%})"),
            ("visible pairs", fig["pairs_visible"]),
            ("tasks", f"{fig['tasks']} {fig['task_unit']} ({fig['tasks_computed']} computed, "
                      f"{fig['tasks_reused']} reused)"),
            ("idle fraction", "-" if fig["idle_fraction"] is None else f"{fig['idle_fraction']:.1%}"),
            ("time", f"{fig['time_s']:.2f} s")]
    return _table(rows)


if __name__ == "__main__":  # pragma: no cover
    main()
