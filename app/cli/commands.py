"""The `radiosity` command: one subcommand per pipeline stage, over a Dask cluster.

Every flag overrides the matching `radiosity.*` setting (radiosity.yaml); the settings are
resolved once per command (options.settings_from_flags) and passed down.
"""

from __future__ import annotations

import os
import sys
import time

import click

from radiosity.cli.options import (POSITIVE, POSITIVE_INT, Finite,
                                   parse_resolution_flag, cluster_options,
                                   force_option, image_options, kernel_options, method_options,
                                   settings_from_flags, solve_options, run_client)
from radiosity.cli.summary import (ARGV, REAL, T0, INTERRUPTED, NOT_CONVERGED, command_line,
                                   finish_lines, friendly, record_run, mark_started, table_text,
                                   viewfactors_summary)
from radiosity.cli.grids import grid_command
from radiosity.cli.studies import study
from radiosity.cli.heat import heat
from radiosity.cli.radiance import radiance_options, radiance_reference
from radiosity.errors import RadiosityError
from radiosity.runtime.precompile import with_helper


def _samples(cameras, subpixel) -> int:
    """Camera samples of a run (width x height x subpixel^2, summed over its cameras): the size
    local_mode weighs."""
    return sum(int(c.width) * int(c.height) for c in cameras) * int(subpixel) ** 2


def _run_samples(rs) -> int | None:
    """_samples of a preprocessed run directory (its store's attributes), None if unknown."""
    a = rs.attrs
    try:
        return int(a["camera"]["width"]) * int(a["camera"]["height"]) * int(a["subpixel"]) ** 2
    except (KeyError, TypeError, ValueError):
        return None


def _load_scene(scene: str, resolution, st):
    """load_scene, saying what it chose where the file said nothing (a mesh file's camera, as
    a [camera] table to copy into a scene file)."""
    from radiosity.scene.load import load_scene

    sc = load_scene(scene, resolution=resolution, settings=st)
    if sc.chosen:
        click.echo(sc.chosen)
    return sc


class OneLineGroup(click.Group):
    """Usage errors (a bad option value, a missing argument) as one line `error: ...` with
    exit status 2, like every other user error, instead of click's usage block."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        return self._main(args, prog_name, complete_var, standalone_mode, **extra)

    def _main(self, args, prog_name, complete_var, standalone_mode, **extra):
        ARGV[:] = list(sys.argv[1:] if args is None else args)
        T0[0] = time.time()
        REAL[0] = args is None
        if args is None:  # a real command: count the interpreter's start and imports too
            try:
                import psutil

                T0[0] = min(T0[0], psutil.Process().create_time())
            except Exception:
                pass
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, False, **extra)
        try:
            from radiosity.runtime.warmup import recording

            # a first run compiles numba kernels for minutes: say so every few seconds
            with recording(echo=lambda line: click.echo(line, err=True), every_s=5.0):
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
            sys.exit(INTERRUPTED)
        sys.exit(rv if isinstance(rv, int) else 0)


@click.group(cls=OneLineGroup)
@click.version_option(package_name="radiosity")
def main():
    """Radiosity with simplified form factors (Debelov & Sattarov) on Dask."""


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Run directory to create.")
@click.option("--resolution", default=None, metavar="N|WxH", callback=parse_resolution_flag,
              help="Override the camera resolution.")
@click.option("--subpixel", type=int, default=None, help="Criterion on a K-times finer raster.")
@click.option("--variant", type=click.Choice(["exact", "seed", "none"]), default=None,
              help="exact: equals the sequential partition; seed: each subscene renders alone "
                   "(seed §4.2); none: no subdivision (the seed's image without preprocessing).")
@click.option("--subscenes", type=POSITIVE_INT, default=None, help="Number of subscene tasks.")
@force_option
@cluster_options
@friendly
def preprocess(scene, out, resolution, subpixel, variant, subscenes, force, workers, scheduler,
               cluster_kind):
    """Camera-driven subdivision of SCENE (seed §3) into the run directory OUT."""
    from radiosity.methods.base import stated_method
    from radiosity.runtime.checks import check_new_run_dir, check_scene
    from radiosity.runtime.runlock import run_lock
    from radiosity.stages.preprocess import preprocess as run

    st = settings_from_flags(subdivide__subpixel=subpixel, subdivide__variant=variant,
                             subdivide__subscenes=subscenes)
    sc = _load_scene(scene, resolution, st)
    check_scene(sc, st, stated_method(st))
    check_new_run_dir(out, force)
    mark_started(out, resume=False)
    click.echo(f"scene {sc.name}: {len(sc.elements)} original elements, camera "
               f"{sc.camera.width}x{sc.camera.height}")
    with run_lock(out, command_line()), run_client(workers, scheduler, cluster_kind, st,
                                                 _samples(sc.cameras, st.subdivide.subpixel)) as client:
        fig = run(sc, out, client, settings=st)
        record_run(out, sc.name)
    click.echo(table_text(finish_lines(out, fig.rows())))
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
@friendly
def visibility(run_dir, task_unit, resume, kernel, workers, scheduler, cluster_kind):
    """The visibility matrix of a preprocessed RUN_DIR (seed §4.3), bit-packed in its store;
    with --method hierarchical, the links between nodes of its split trees instead."""
    from radiosity.methods.base import choose_method, get_method
    from radiosity.runtime.checks import check_run_dir
    from radiosity.runtime.runlock import run_lock
    from radiosity.runtime.store import RunStore
    from radiosity.scene.luminaires import luminaires_of

    st = settings_from_flags(solve__kernel=kernel, hierarchy__kernel=kernel)
    check_run_dir(run_dir)
    rs = RunStore(run_dir)
    part = rs.load_partition()
    name, why = choose_method(len(part), st, originals=len(part.offsets) - 1,
                              point_sources=len(luminaires_of(rs.load_elements())))
    method = get_method(name)
    click.echo(f"method: {why}")
    method.check(rs, st)  # bad settings fail before a cluster starts
    mark_started(run_dir)
    with run_lock(run_dir, command_line()), run_client(workers, scheduler, cluster_kind, st,
                                                     _run_samples(rs)) as client:
        record_run(run_dir)
        fig = method.build(run_dir, client, st, unit=task_unit, resume=resume)
    click.echo(table_text(finish_lines(run_dir, fig.rows())))


@main.command()
@click.argument("run_dir", type=click.Path())
@solve_options
@lambda fn: method_options(fn, links=False)
@cluster_options
@friendly
def solve(run_dir, solver, kernel, tol, max_iterations, keep_unconverged, workers, scheduler,
          cluster_kind):
    """Solve the radiosity system of RUN_DIR (after visibility): form factors on the fly;
    with --method hierarchical, over its links (the kernel was fixed by the link stage)."""
    from radiosity.methods.base import method_of_run, stated_method
    from radiosity.runtime.checks import check_run_dir, check_solve
    from radiosity.runtime.runlock import run_lock
    from radiosity.runtime.store import RunStore
    from radiosity.stages.image import previewer
    from radiosity.stages.solve import run_solve

    st = settings_from_flags(solve__solver=solver, solve__kernel=kernel, solve__tol=tol,
                             solve__max_iterations=max_iterations)
    check_solve(st)
    check_run_dir(run_dir)
    rs = RunStore(run_dir)
    rs.load_partition()
    method = stated_method(st) or method_of_run(rs)
    method.require(rs)
    mark_started(run_dir, resume=False)
    with run_lock(run_dir, command_line()), run_client(workers, scheduler, cluster_kind, st,
                                                     _run_samples(rs)) as client:
        fig = run_solve(run_dir, client, st, preview=previewer(run_dir),
                        keep_unconverged=keep_unconverged, method=method.name)
        record_run(run_dir)
    click.echo(table_text(finish_lines(run_dir, fig.rows())))
    if not fig.converged:
        sys.exit(NOT_CONVERGED)


def _xyz(ctx, param, value):
    if value is None:
        return None
    try:
        v = [float(x) for x in value.split(",")]
    except ValueError:
        v = []
    if len(v) != 3:
        raise click.BadParameter(f"give three numbers X,Y,Z, got {value!r}")
    return v


@main.command()
@click.argument("run_dir", type=click.Path())
@image_options
@click.option("--camera", "camera_file", type=click.Path(), default=None,
              help="A new view: the [camera] table of this TOML file (a scene file will do).")
@click.option("--position", callback=_xyz, default=None, metavar="X,Y,Z", help="A new view from here.")
@click.option("--look-at", callback=_xyz, default=None, metavar="X,Y,Z", help="A new view towards here.")
@click.option("--up", callback=_xyz, default=None, metavar="X,Y,Z", help="The new view's up (0,1,0).")
@click.option("--fov", type=click.FloatRange(0, 180, min_open=True, max_open=True), default=None,
              help="The new view's vertical field of view, degrees (default: the run's).")
@click.option("--resolution", default=None, metavar="N|WxH", callback=parse_resolution_flag,
              help="The new view's resolution (default: the camera file's, else the run's).")
@click.option("--name", default=None, help="The new view's folder under RUN_DIR/views (default view-N).")
@friendly
def image(run_dir, filter_, sigma, exposure, camera_file, position, look_at, up, fov, resolution,
          name):
    """Write image.exr, image.png, mesh.glb, mesh.ply and viewer.html of a solved RUN_DIR; with
    --camera (or --position/--look-at), a new view of its solution into RUN_DIR/views/NAME/
    instead (no re-solve; the run's own files stay)."""
    from radiosity.runtime.checks import check_run_dir
    from radiosity.stages.image import render_outputs
    from radiosity.runtime.runlock import run_lock

    st = settings_from_flags(render__filter=filter_, render__sigma=sigma, render__exposure=exposure)
    check_run_dir(run_dir)
    if camera_file or position or look_at:
        from radiosity.runtime.store import RunStore
        from radiosity.stages.views import render_view, view_camera

        cam = view_camera(RunStore(run_dir).load_camera(), camera_file, position, look_at, up, fov,
                          resolution)
        with run_lock(run_dir, command_line()):
            v = render_view(run_dir, cam, name, settings=st, exposure=exposure)
        g = v.figures["gather"]
        click.echo(table_text([("view", f"{cam.width}x{cam.height}, {v.figures['samples_per_pixel']} "
                                    f"rays a pixel, {v.figures['method']} solution"),
                           ("gathered", f"{g.get('gathered_points', 0)} points in leaves coarser "
                                        f"than their pixels, {g.get('evaluations', 0)} link "
                                        f"evaluations, {g.get('rays', 0)} rays"),
                           ("time", f"{v.figures['time_s']:.1f} s")]))
        click.echo(f"wrote {v.out}/image.exr, image.png, view.json")
        return
    mark_started(run_dir, resume=False)
    with run_lock(run_dir, command_line()):
        fig = render_outputs(run_dir, filter=filter_, sigma=sigma, exposure=exposure,
                             settings=st, progress=True)
        record_run(run_dir)
        finish_lines(run_dir, [])
    click.echo(f"wrote {run_dir}/image.exr, image.png, mesh.glb, mesh.ply, viewer.html, "
               f"elements.csv, surfaces.csv, materials.csv "
               f"({fig.width}x{fig.height}, exposure {fig.exposure:.3g})")


@main.command()
@click.argument("run_dir", type=click.Path())
@click.option("--path", "path_file", required=True, type=click.Path(),
              help="The camera path: a TOML file of [[keyframe]] tables (position, look_at; "
                   "optional time, up, fov_y) and frames, fps, resolution.")
@click.option("--out", "-o", default=None, type=click.Path(),
              help="The video: .mp4 (also .mkv, .mov, .avi), .gif or .webp (default "
                   "RUN_DIR/walkthroughs/NAME/NAME.mp4).")
@click.option("--name", default=None,
              help="The folder under RUN_DIR/walkthroughs for the frames (default: the path "
                   "file's name).")
@click.option("--frames", type=POSITIVE_INT, default=None, help="Number of frames (replaces the file's).")
@click.option("--fps", type=POSITIVE, default=None, help="Frames per second (replaces the file's).")
@click.option("--resolution", default=None, metavar="N|WxH", callback=parse_resolution_flag,
              help="The frames' resolution (default: the path file's, else the run's).")
@click.option("--exposure", type=POSITIVE, default=None,
              help="Exposure of the frames (default: the run's, so that they match its image).")
@click.option("--keep-frames/--no-keep-frames", default=True, show_default=True,
              help="Keep every frame as a PNG beside walkthrough.json.")
@friendly
def walkthrough(run_dir, path_file, out, name, frames, fps, resolution, exposure, keep_frames):
    """Render a camera path through a solved RUN_DIR into a video: every frame a view of its
    one solution (no re-solve; the run opened once for all frames), with progress."""
    from radiosity.runtime.checks import check_run_dir
    from radiosity.runtime.runlock import run_lock
    from radiosity.stages.walkthrough import check_output, load_path, render_walkthrough

    path = load_path(path_file, {k: v for k, v in (("frames", frames), ("fps", fps),
                                                   ("resolution", resolution)) if v is not None})
    if out is not None:
        check_output(out)
    check_run_dir(run_dir)
    with run_lock(run_dir, command_line()):
        w = render_walkthrough(run_dir, path, out, name, settings=settings_from_flags(),
                               exposure=exposure, keep_frames=keep_frames)
    f = w.figures
    click.echo(table_text([("frames", f"{f['frames']} at {f['resolution'][0]}x{f['resolution'][1]}, "
                                  f"{f['samples_per_pixel']} rays a pixel, {f['method']} solution"),
                       ("gathered", f"{f['gathered_points']} points in leaves coarser than "
                                    "their pixels"),
                       ("time", f"{f['time_s']:.1f} s ({f['time_open_s']:.1f} s opening the run, "
                                f"{f['time_per_frame_s']:.2f} s a frame)")]))
    click.echo(f"wrote {w.video}" + (f" and {w.frames} frames in {w.folder}" if keep_frames
                                     else ""))


@main.command()
@click.option("--methods", default="hierarchical,pairs", metavar="LIST",
              help="The methods whose kernels to compile (comma-separated).")
@click.option("--json", "json_path", type=click.Path(), default=None,
              help="Also write the compile time of every kernel to this JSON file.")
@click.option("--record", is_flag=True,
              help="Developers: render the Quick start (128x128), then the pairs method "
                   "(16x16), with an empty numba cache (NUMBA_CACHE_DIR) and write the kernels "
                   "they compile, in order, into runtime/kernels.txt (the first run's compile "
                   "helper reads it).")
@friendly
def warmup(methods, json_path, record):
    """Compile the kernels of a render into numba's cache now (a tiny render of the built-in
    Cornell box per method, in this process), with progress; later runs load them. Prints
    where the compile time went."""
    import json
    import tempfile

    from radiosity.pipeline import render as render_api
    from radiosity.runtime.warmup import recording

    if record:
        return _record_kernels()

    names = [m for m in methods.split(",") if m]
    scene = _builtin_cornell()
    t0 = time.perf_counter()
    with recording(echo=click.echo) as log, tempfile.TemporaryDirectory() as tmp:
        for m in names:
            click.echo(f"warmup: {m} (a 16x16 render of the built-in Cornell box)")
            render_api(scene, os.path.join(tmp, m), resolution=16, method=m)
    rows = [(name, f"{sec:.2f} s ({n} signature{'s' if n != 1 else ''})")
            for name, sec, n in log.top(10)]
    rows.append(("compiled", f"{len(log.seconds)} kernels, {log.total_s:.1f} s of "
                             f"{time.perf_counter() - t0:.1f} s (0 when the cache was warm)"))
    click.echo(table_text(rows))
    if json_path:
        with open(json_path, "w") as f:
            json.dump(log.to_dict(), f, indent=1)


def _record_kernels():
    """`radiosity warmup --record`: the Quick start in this process, then a pairs render,
    every kernel they compile written to runtime/kernels.txt in order, the pairs method's own
    first (runtime/precompile.py)."""
    import tempfile

    from radiosity.pipeline import render as render_api
    from radiosity.runtime.precompile import SIGNATURES_PATH, recording_order, write_entries

    cache = os.environ.get("NUMBA_CACHE_DIR")
    if not cache or any(files for _, _, files in os.walk(cache)):  # (folders: made at import)
        raise RadiosityError("warmup --record: set NUMBA_CACHE_DIR to an empty folder (the record "
                             "must see every kernel compiled, not loaded from a warm cache)")
    os.environ["RADIOSITY_NO_PRECOMPILE"] = "1"  # no helper: this process compiles them all
    with tempfile.TemporaryDirectory() as tmp:
        with recording_order() as order:
            render_api(_builtin_cornell(), os.path.join(tmp, "run"))
        with recording_order() as pairs:  # what the pairs method compiles beyond those
            render_api(_builtin_cornell(), os.path.join(tmp, "pairs"), resolution=16, method="pairs")
    click.echo(f"wrote {write_entries(pairs + order)} kernel signatures into {SIGNATURES_PATH}")


def _builtin_cornell() -> str:
    scene = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                         "scenes", "cornell-box", "scene.toml")
    if not os.path.isfile(scene):
        raise RadiosityError(f"the built-in Cornell box is not at {scene}: install from the repository")
    return scene


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--resolution", default=None, metavar="N|WxH", callback=parse_resolution_flag,
              help="Override the camera resolution.")
@click.option("--subpixel", type=int, default=None, help="Criterion on a K-times finer raster.")
@click.option("--tol", type=float, default=None, help="Solver tolerance (for the pass estimate).")
@lambda fn: method_options(fn, links=False)
@friendly
def plan(scene, resolution, subpixel, tol):
    """Print which effects SCENE calls for, which are skipped and why, before any heavy work."""
    from radiosity.methods.base import choose_method, get_method, stated_method
    from radiosity.pipeline import direct_choice, scene_plan
    from radiosity.scene.effects import describe
    from radiosity.scene.luminaires import luminaires_of
    from radiosity.runtime.checks import check_scene

    st = settings_from_flags(subdivide__subpixel=subpixel, solve__tol=tol)
    sc = _load_scene(scene, resolution, st)
    check_scene(sc, st, stated_method(st))
    planned = scene_plan(sc, settings=st)
    click.echo(f"scene {sc.name}: {len(sc.elements)} original elements, camera "
               f"{sc.camera.width}x{sc.camera.height}")
    click.echo(describe(planned.effects, planned.unseen_unsplit, planned.sub_elements,
                        planned.closure))
    est = planned.effects.estimates
    method, why = choose_method(planned.sub_elements, st, originals=len(sc.elements),
                                facing_pairs=est.get("facing_original_pairs",
                                                     est.get("facing_original_pairs_estimate")),
                                point_sources=len(luminaires_of(sc.elements)))
    click.echo(f"method: {why}")
    click.echo(f"direct light: {direct_choice(method, sc.elements, st)[1]}")
    for line in get_method(method).plan_lines(st, planned.sub_elements, len(sc.elements), why):
        click.echo(line)


@main.command()
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Run directory.")
@click.option("--resolution", default=None, metavar="N|WxH", callback=parse_resolution_flag,
              help="Override the camera resolution.")
@click.option("--subpixel", type=int, default=None, help="Criterion on a K-times finer raster.")
@click.option("--task-unit", type=click.Choice(["block", "stripe", "auto"]), default=None)
@click.option("--resume", is_flag=True, help="Reuse the partition and finished visibility tasks in OUT.")
@click.option("--preview/--no-preview", default=False,
              help="Also write preview.png: the original elements alone, the seed's first image.")
@click.option("--full", is_flag=True, help="Simulate every effect, whatever the plan says.")
@force_option
@solve_options
@method_options
@image_options
@cluster_options
@friendly
@with_helper  # a first run: a helper process compiles from the other end of the kernels
def render(scene, out, resolution, subpixel, task_unit, resume, preview, full, force, solver, kernel,
           tol, max_iterations, keep_unconverged, filter_, sigma, exposure, workers, scheduler,
           cluster_kind):
    """Preprocess, visibility, solve and image of SCENE into the run directory OUT."""
    from radiosity.methods.base import stated_method
    from radiosity.pipeline import render_scene
    from radiosity.runtime.checks import check_new_run_dir, check_scene, check_solve
    from radiosity.runtime.runlock import run_lock

    st = settings_from_flags(subdivide__subpixel=subpixel, solve__solver=solver,
                             solve__kernel=kernel, solve__tol=tol,
                             solve__max_iterations=max_iterations, render__filter=filter_,
                             render__sigma=sigma, render__exposure=exposure,
                             visibility__task_unit=task_unit, hierarchy__task_unit=task_unit)
    sc = _load_scene(scene, resolution, st)
    check_solve(st)
    check_scene(sc, st, stated_method(st))
    check_new_run_dir(out, force)
    mark_started(out)
    click.echo(f"scene {sc.name}: {len(sc.elements)} original elements, camera "
               f"{sc.camera.width}x{sc.camera.height}")
    with run_lock(out, command_line()), run_client(workers, scheduler, cluster_kind, st,
                                                 _samples(sc.cameras, st.subdivide.subpixel)) as client:
        rep = render_scene(sc, out, client, st, resume=resume, preview=preview, echo=click.echo,
                           full=full, keep_unconverged=keep_unconverged)
        record_run(out, sc.name)
    click.echo(table_text(finish_lines(out, rep.rows())))
    click.echo(f"wrote {out}/image.exr, image.png, {'preview.png, ' if preview else ''}mesh.glb, "
               "mesh.ply, viewer.html, elements.csv, surfaces.csv, materials.csv, report.json")
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
@click.option("--resolution", default=None, metavar="N|WxH", callback=parse_resolution_flag,
              help="Override the camera resolution.")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Seed of the first pass.")
@click.option("--variant", type=click.Choice(["auto", "llvm_ad_rgb", "scalar_rgb"]), default=None,
              help="Mitsuba variant (default: radiosity.reference.variant, auto).")
@radiance_options
@force_option
@friendly
def reference(scene, out, spp, passes, resolution, seed, variant, engine, points_csv, quality,
              emitters, processes, force):
    """Ground truth: SCENE path-traced by Mitsuba 3 (the same elements, materials, sides and
    camera); mean radiance, per-pixel standard error and figures into OUT. With --engine
    radiance: illuminance at the --points by Radiance instead (OUT/points.csv)."""
    from radiosity.runtime.checks import check_new_run_dir
    from radiosity.validation.reference import make_reference

    if engine == "radiance" or points_csv is not None:
        return radiance_reference(scene, out, engine, points_csv, quality, emitters, processes,
                                  force, {"--spp": spp, "--passes": passes, "--seed": seed,
                                          "--variant": variant, "--resolution": resolution})
    st = settings_from_flags()
    sc = _load_scene(scene, resolution, st)
    check_new_run_dir(out, force)
    fig = make_reference(sc, out, spp=spp, passes=passes, seed=seed, variant=variant,
                         echo=click.echo, settings=st)
    click.echo(table_text([
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
@force_option
@friendly
def compare(a, b, out, force):
    """Error of image A against reference B (EXR, linear RGB): mean absolute relative error,
    max, per channel; B's noise when B-stderr.exr lies beside it."""
    from radiosity.validation.compare import compare_files
    from radiosity.runtime.checks import check_new_run_dir

    if out:
        check_new_run_dir(out, force)
    fig = compare_files(a, b, out)
    pc = fig["per_channel"]
    rows = [("pixels", f"{fig['pixels']} of {fig['width']}x{fig['height']} (where B > 0)"),
            ("mean abs. relative error", f"{fig['mare']:.4g}"),
            ("max relative error", f"{fig['max']:.4g}"),
            ("per channel R, G, B", f"{pc['R']:.4g}, {pc['G']:.4g}, {pc['B']:.4g}")]
    if "noise_floor" in fig:
        rows.append(("B's own noise", f"{fig['noise_floor']:.4g} (the error an exact image would show)"))
    click.echo(table_text(rows))
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
@click.option("--cutoff", type=Finite(min=0.0), default=None,
              help="Drop cluster pairs whose form-factor bound is at most this (default 0: none).")
@click.option("--resume", is_flag=True, help="Keep the finished tasks of an interrupted run in OUT.")
@force_option
@cluster_options
@friendly
def viewfactors(mesh, out, accuracy, enclosure, fmt, cutoff, resume, force, workers, scheduler,
                cluster_kind):
    """View factors between the facets of MESH (OBJ, glTF, PLY, STL or a scene TOML): sparse,
    obstructed, reciprocal; rows balanced to 1 for enclosures."""
    from radiosity.runtime.checks import check_new_run_dir
    from radiosity.runtime.runlock import run_lock
    from radiosity.viewfactors.api import (compute_viewfactors, in_process_mode, load_facets,
                                           resolve_params)

    st = settings_from_flags(viewfactors__accuracy=accuracy, viewfactors__cutoff=cutoff,
                             viewfactors__enclosure=enclosure)
    resolve_params(settings=st)  # bad values fail before the cluster starts
    fac = load_facets(mesh, settings=st)
    check_new_run_dir(out, force)
    mark_started(out)
    click.echo(f"{len(fac)} facets from {', '.join(fac.sources)}")
    # small meshes on threads in this process, as small renders (no worker processes to start)
    in_process, where = in_process_mode(st, len(fac))
    with run_lock(out, command_line()), run_client(workers, scheduler, cluster_kind,
                                                   in_process=in_process, where=where) as client:
        res = compute_viewfactors(fac, out, client, fmt=fmt, resume=resume, settings=st)
        record_run(out, os.path.basename(mesh))
    click.echo(viewfactors_summary(res.figures, finish_lines(out, [])))
    click.echo(f"wrote {out}/" + f", {out}/".join(res.figures["files"] + ["report.json"]))


main.add_command(study)  # studies.py
main.add_command(grid_command)  # grids.py: calculation grids on a solved run
main.add_command(heat)  # heat.py


if __name__ == "__main__":  # pragma: no cover
    main()
