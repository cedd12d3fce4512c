"""The `radiosity` command: one subcommand per pipeline stage, over a Dask cluster.

Every flag overrides the matching `radiosity.*` key of dask.config (see app/radiosity.yaml).
"""

from __future__ import annotations

import functools
import sys
import warnings

import click

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
    from .kernels import KERNELS

    for name, key, help2 in (
            ("--mc-seed", "mc-seed", "mc kernel: seed of the random sample points."),
            ("--mc-samples", "mc-samples", "mc kernel: random sample pairs (rays) per pair."),
            ("--nxm-points", "nxm-points", "nxm kernel: sample points per element (a square).")):
        fn = click.option(name, type=int, default=None, expose_value=False, help=help2,
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
            ("--cores", "cores", int, "Batch jobs: cores per job.")):
        fn = click.option(name, type=kind, default=None, expose_value=False, help=help_,
                          callback=_set_config(_jobqueue(key)))(fn)
    fn = click.option("--tls", is_flag=True, default=False, expose_value=False,
                      help="TLS with temporary certificates (multi-host runs).",
                      callback=_set_config(lambda v: {"radiosity.cluster.tls": "temporary"}))(fn)
    fn = click.option("--adaptive", default=None, metavar="MIN:MAX", expose_value=False,
                      help="Scale the cluster adaptively between MIN and MAX workers.",
                      callback=_set_config(lambda v: {"radiosity.cluster.adaptive": v}))(fn)
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
@click.option("--variant", type=click.Choice(["exact", "seed", "none"]), default=None,
              help="exact: equals the sequential partition; seed: each subscene renders alone "
                   "(seed §4.2); none: no subdivision (the seed's image without preprocessing).")
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
@lambda fn: kernel_options(fn, "The kernel the matrix is for: nxm and mc cast one ray per "
                                "sample pair (default: radiosity.solve.kernel).")
@cluster_options
@_friendly
def visibility(run_dir, task_unit, resume, kernel, workers, scheduler, cluster_kind):
    """The visibility matrix of a preprocessed RUN_DIR (seed §4.3), bit-packed in its store."""
    from . import config
    from .cluster import open_client
    from .kernels import sampling_of
    from .store import RunStore
    from .visibility import compute_visibility

    RunStore(run_dir).load_partition()  # fail before starting a cluster
    sampling_of(config.get("solve.kernel", kernel))  # a bad nxm-points / mc-samples fails here
    with open_client(workers, scheduler, cluster_kind, echo=click.echo) as client:
        fig = compute_visibility(run_dir, client, unit=task_unit, resume=resume, kernel=kernel)
    click.echo(_visibility_summary(fig))


def _visibility_summary(fig: dict) -> str:
    pt = max(1, fig["pairs_total"])
    rows = [("sub-elements", fig["sub_elements"]),
            ("pairs", fig["pairs_total"]),
            ("culled by orientation", f"{fig['pairs_culled_by_orientation']} ({fig['pairs_culled_by_orientation'] / pt:.1%})"),
            ("proven visible by shafts", f"{fig['pairs_shaft_visible']} ({fig['pairs_shaft_visible'] / pt:.1%})"),
            ("rays cast", f"{fig['rays']} ({fig['rays'] / pt:.1%} of pairs, "
                          f"{fig.get('rays_per_pair', 1)} per pair)"),
            ("visible pairs", fig["pairs_visible"]),
            ("tasks", f"{fig['tasks']} {fig['task_unit']} ({fig['tasks_computed']} computed, "
                      f"{fig['tasks_reused']} reused)"),
            ("idle fraction", "-" if fig["idle_fraction"] is None else f"{fig['idle_fraction']:.1%}"),
            ("time", f"{fig['time_s']:.2f} s")]
    return _table(rows)


def solve_options(fn):
    """--solver / --kernel (and its sampling) / --tol / --max-iterations."""
    from .solve import SOLVERS

    fn = click.option("--max-iterations", type=int, default=None, help="Pass limit.")(fn)
    fn = click.option("--tol", type=float, default=None, help="Relative residual to stop at.")(fn)
    fn = kernel_options(fn)
    fn = click.option("--solver", type=click.Choice(list(SOLVERS)), default=None,
                      help="Solver (default: radiosity.solve.solver).")(fn)
    return fn


def image_options(fn):
    fn = click.option("--exposure", default=None, help="Exposure for PNG/mesh colours, or 'auto'.")(fn)
    fn = click.option("--sigma", type=float, default=None, help="Gaussian sigma in fine pixels.")(fn)
    fn = click.option("--filter", "filter_", type=click.Choice(["box", "gaussian"]), default=None,
                      help="Sub-pixel reconstruction filter.")(fn)
    return fn


def _solve_summary(fig: dict) -> str:
    return _table([("solver", f"{fig['solver']} ({fig['kernel']} kernel)"),
                   ("passes", f"{fig['iterations']} ({'converged' if fig['converged'] else 'NOT converged'})"),
                   ("final residual", f"{fig['final_residual']:.3g}"),
                   ("pair terms/s", f"{fig['pair_terms_per_s'] / 1e6:.1f} M"),
                   ("time", f"{fig['time_s']:.2f} s")])


@main.command()
@click.argument("run_dir", type=click.Path())
@solve_options
@cluster_options
@_friendly
def solve(run_dir, solver, kernel, tol, max_iterations, workers, scheduler, cluster_kind):
    """Solve the radiosity system of RUN_DIR (after visibility): form factors on the fly."""
    from .cluster import open_client
    from .solve import run_solve
    from .store import RunStore

    RunStore(run_dir).load_partition()
    with open_client(workers, scheduler, cluster_kind, echo=click.echo) as client:
        fig = run_solve(run_dir, client, solver=solver, kernel=kernel, tol=tol, max_iter=max_iterations)
    click.echo(_solve_summary(fig))


@main.command()
@click.argument("run_dir", type=click.Path())
@image_options
@_friendly
def image(run_dir, filter_, sigma, exposure):
    """Write image.exr, image.png, mesh.glb, mesh.ply and viewer.html of a solved RUN_DIR."""
    from .render import render_outputs

    fig = render_outputs(run_dir, filter=filter_, sigma=sigma, exposure=exposure)
    click.echo(f"wrote {run_dir}/image.exr, image.png, mesh.glb, mesh.ply, viewer.html "
               f"({fig['width']}x{fig['height']}, exposure {fig['exposure']:.3g})")


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--resolution", default=None, metavar="N|WxH", help="Override the camera resolution.")
@click.option("--subpixel", type=int, default=None, help="Criterion on a K-times finer raster.")
@click.option("--tol", type=float, default=None, help="Solver tolerance (for the pass estimate).")
@_friendly
def plan(scene, resolution, subpixel, tol):
    """Print which effects SCENE calls for, which are skipped and why, before any heavy work."""
    from .pipeline import scene_plan
    from .planner import describe
    from .scene import load_scene

    sc = load_scene(scene, resolution=resolution)
    p, est = scene_plan(sc, subpixel, tol)
    click.echo(f"scene {sc.name}: {len(sc.elements)} original elements, camera "
               f"{sc.camera.width}x{sc.camera.height}")
    click.echo(describe(p, est["unseen_unsplit"], est["sub_elements_estimate"]))


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Run directory.")
@click.option("--resolution", default=None, metavar="N|WxH", help="Override the camera resolution.")
@click.option("--subpixel", type=int, default=None, help="Criterion on a K-times finer raster.")
@click.option("--task-unit", type=click.Choice(["block", "stripe", "auto"]), default=None)
@click.option("--resume", is_flag=True, help="Reuse the partition and finished visibility tasks in OUT.")
@click.option("--no-preview", is_flag=True, help="Skip preview.png (the original elements only).")
@click.option("--full", is_flag=True, help="Simulate every effect, whatever the plan says.")
@solve_options
@image_options
@cluster_options
@_friendly
def render(scene, out, resolution, subpixel, task_unit, resume, no_preview, full, solver, kernel,
           tol, max_iterations, filter_, sigma, exposure, workers, scheduler, cluster_kind):
    """Preprocess, visibility, solve and image of SCENE into the run directory OUT."""
    from .cluster import open_client
    from .pipeline import render_scene
    from .scene import load_scene

    sc = load_scene(scene, resolution=resolution)
    click.echo(f"scene {sc.name}: {len(sc.elements)} original elements, camera "
               f"{sc.camera.width}x{sc.camera.height}")
    if max_iterations is not None:
        import dask.config
        dask.config.set({"radiosity.solve.max-iterations": max_iterations})
    with open_client(workers, scheduler, cluster_kind, echo=click.echo) as client:
        rep = render_scene(sc, out, client, subpixel=subpixel, unit=task_unit, solver=solver,
                           kernel=kernel, tol=tol, filter=filter_, sigma=sigma, exposure=exposure,
                           resume=resume, preview=not no_preview, echo=click.echo, full=full)
    pre, vis, sol = rep["preprocess"], rep["visibility"], rep["solve"]
    st = rep["render"]["stages"]
    click.echo(_table([
        ("sub-elements", f"{pre['sub_elements']} (from {pre['original_elements']} originals)"),
        ("rays cast", f"{vis['rays']} ({vis['rays'] / max(1, vis['pairs_total']):.1%} of pairs)"),
        ("solve", f"{sol['solver']}/{sol['kernel']}: {sol['iterations']} passes, residual "
                  f"{sol['final_residual']:.2g}, {sol['channels']} channel(s)"),
        ("times", f"preprocess {st['preprocess_s']:.1f} s, visibility {st['visibility_s']:.1f} s, "
                  f"solve {st['solve_s']:.1f} s, image {st['image_s']:.1f} s, total {st['total_s']:.1f} s"),
    ]))
    click.echo(f"wrote {out}/image.exr, image.png, preview.png, mesh.glb, mesh.ply, viewer.html, report.json"
               if not no_preview else f"wrote {out}/image.exr, image.png, mesh.glb, mesh.ply, viewer.html, report.json")


@main.command()
@click.argument("mesh", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Run directory to create.")
@click.option("--accuracy", type=float, default=None,
              help="Target absolute error of each factor (default: radiosity.viewfactors.accuracy).")
@click.option("--enclosure", type=click.Choice(["auto", "on", "off"]), default=None,
              help="Balance rows to 1 keeping reciprocity: auto (closed meshes with inward "
                   "normals), on, off (default: radiosity.viewfactors.enclosure).")
@click.option("--format", "fmt", type=click.Choice(["npz", "csv"]), default="npz", show_default=True,
              help="viewfactors.npz always; csv adds viewfactors.csv (small meshes).")
@click.option("--cutoff", type=float, default=None,
              help="Drop cluster pairs whose form-factor bound is at most this (default 0: none).")
@click.option("--resume", is_flag=True, help="Keep the finished tasks of an interrupted run in OUT.")
@cluster_options
@_friendly
def viewfactors(mesh, out, accuracy, enclosure, fmt, cutoff, resume, workers, scheduler, cluster_kind):
    """View factors between the facets of MESH (OBJ, glTF, PLY or a scene TOML): sparse,
    obstructed, reciprocal; rows balanced to 1 for enclosures."""
    from .cluster import open_client
    from .viewfactor import compute_viewfactors, load_facets, resolve_params

    resolve_params(accuracy, cutoff)  # bad values fail before the cluster starts
    fac = load_facets(mesh)
    click.echo(f"{len(fac)} facets from {', '.join(fac.sources)}")
    with open_client(workers, scheduler, cluster_kind, echo=click.echo) as client:
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
@click.option("--resolutions", default="8,16,32", show_default=True, help="Camera resolutions.")
@click.option("--subpixels", default="1", show_default=True, help="Sub-pixel factors.")
@click.option("--kernels", default="point,disc", show_default=True,
              help="Form-factor kernels; the sampled ones may name their sample count: nxm:16, mc:64.")
@click.option("--tols", default="1e-6", show_default=True, help="Solver tolerances.")
@click.option("--reference", type=click.Path(exists=True), default=None,
              help="A reference image (EXR) to measure the error against.")
@click.option("--solver", default=None, help="Solver (default: radiosity.solve.solver).")
@cluster_options
@_friendly
def study_accuracy(scene, out, resolutions, subpixels, kernels, tols, reference, solver, workers,
                   scheduler, cluster_kind):
    """Sweep resolution x sub-pixel x kernel x tolerance on SCENE; time every stage, measure the
    error; write results.csv, results.md and accuracy.png (error against time, Pareto front)."""
    from .cluster import open_client
    from .study import accuracy, kernel_setting

    ks = [k for k in kernels.split(",") if k]
    for k in ks:
        kernel_setting(k)  # a bad name or count fails before the cluster starts
    with open_client(workers, scheduler, cluster_kind, echo=click.echo) as client:
        rows = accuracy(scene, out, client, _floats(resolutions, int), _floats(subpixels, int), ks,
                        _floats(tols), reference=reference, solver=solver, echo=click.echo)
    best = [r for r in rows if r["pareto"]]
    click.echo(f"wrote {out}/results.csv, results.md, accuracy.png; {len(best)} settings on the Pareto front")


@study.command("seed")
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Directory for plots and tables.")
@click.option("--resolutions", default="32,64,128,256", show_default=True)
@click.option("--speedup-resolution", type=int, default=96, show_default=True)
@click.option("--max-workers", type=int, default=None, help="Largest LocalCluster for the speedup.")
@_friendly
def study_seed(scene, out, resolutions, speedup_resolution, max_workers):
    """Reproduce the seed's experiments on SCENE: Fig. 3, Fig. 4, the speedup table and the image
    series; writes PNG plots and seed.md into OUT."""
    from .cluster import default_workers, open_client
    from .study import seed

    n = max_workers or default_workers()
    res = seed(scene, out, lambda w: open_client(w, quiet=True), _floats(resolutions, int),
               list(range(1, n + 1)), speedup_resolution, echo=click.echo)
    click.echo(f"wrote {out}/seed.md and its plots; visibility time ~ m^{res['order']:.2f}")


if __name__ == "__main__":  # pragma: no cover
    main()
