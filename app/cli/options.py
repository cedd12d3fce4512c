"""The CLI's options: validators, the shared option groups, and flags as overrides of the
settings (recorded on the click context, resolved once by settings_from_flags; no flag writes
dask.config). A flag that sets a setting is checked where `radiosity.render`'s keyword is:
settings.check, one RadiosityError (exit 2) with the same line for both."""

from __future__ import annotations

import math

import click

from radiosity.errors import RadiosityError

OVERRIDES = "radiosity.overrides"  # ctx.meta key: {"section.key": value} of the flags given
CLUSTER = "radiosity.cluster"      # ctx.meta key: open_client keywords of the cluster flags


class Finite(click.FloatRange):
    """A float in a range that is also finite (click's FloatRange lets NaN through)."""

    def convert(self, value, param, ctx):
        v = super().convert(value, param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return v


POSITIVE_INT = click.IntRange(min=1)
POSITIVE = Finite(min=0.0, min_open=True)


def parse_resolution_flag(ctx, param, value):
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
        ctx.meta.setdefault(CLUSTER, {})["adaptive"] = value
    return value


def number_list(kind, lo, what):
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



def _setting(key: str):
    """A click callback that records a flag's value as the override of radiosity.<key>
    (None or an unset flag: not given); settings_from_flags() resolves them once."""

    def cb(ctx, param, value):
        if value is not None and value is not False:
            ctx.meta.setdefault(OVERRIDES, {})[key] = value
        return value

    return cb


def _cluster(key: str, value=None):
    """A click callback that records a cluster flag for open_client (cluster_from_flags)."""

    def cb(ctx, param, v):
        if v is not None and v is not False:
            ctx.meta.setdefault(CLUSTER, {})[key] = v if value is None else value
        return v

    return cb


def settings_from_flags(**explicit):
    """The command's settings: dask.config's radiosity.* with the flags applied, checked
    (resolved once, here; `explicit` adds section__key=value for flags the command reads
    itself)."""
    from radiosity.settings import resolve

    ctx = click.get_current_context(silent=True)
    given = dict(ctx.meta.get(OVERRIDES, {})) if ctx is not None else {}
    return resolve({**given, **{k.replace("__", "."): v for k, v in explicit.items()}})


def cluster_from_flags() -> dict:
    """open_client's keywords from the cluster flags (adaptive, tls, batch-job options)."""
    ctx = click.get_current_context(silent=True)
    return dict(ctx.meta.get(CLUSTER, {})) if ctx is not None else {}


def kernel_options(fn, help_="Form-factor kernel (default: radiosity.solve.kernel)."):
    """--kernel and the sampled kernels' --nxm-points / --mc-samples / --mc-seed."""
    from radiosity.core.kernels import KERNELS

    for name, key, help2 in (
            ("--mc-seed", "mc-seed", "mc kernel: seed of the random sample points."),
            ("--mc-samples", "mc-samples", "mc kernel: random sample pairs (rays) per pair."),
            ("--nxm-points", "nxm-points", "nxm kernel: sample points per element (a square).")):
        fn = click.option(name, type=int, default=None, expose_value=False, help=help2,
                          callback=_setting(f"solve.{key}"))(fn)
    return click.option("--kernel", type=click.Choice(list(KERNELS)), default=None, help=help_)(fn)


def cluster_options(fn):
    """--workers / --scheduler / --cluster and the batch-job and security flags, shared by every
    heavy command; the flags reach open_client as its keywords (cluster_from_flags)."""
    for name, key, kind, help_ in (
            ("--account", "account", str, "Batch jobs: account (project on SGE/LSF)."),
            ("--queue", "queue", str, "Batch jobs: queue / partition."),
            ("--walltime", "walltime", str, "Batch jobs: walltime, e.g. 02:00:00."),
            ("--memory", "memory", str, "Batch jobs: memory per job, e.g. 16GB."),
            ("--cores", "cores", POSITIVE_INT, "Batch jobs: cores per job.")):
        fn = click.option(name, type=kind, default=None, expose_value=False, help=help_,
                          callback=_cluster(key))(fn)
    fn = click.option("--tls", is_flag=True, default=False, expose_value=False,
                      help="TLS with temporary certificates (multi-host runs).",
                      callback=_cluster("tls", "temporary"))(fn)
    fn = click.option("--adaptive", default=None, metavar="MIN:MAX", expose_value=False,
                      help="Scale the cluster adaptively between MIN and MAX workers.",
                      callback=_adaptive)(fn)
    fn = click.option("--processes", type=click.Choice(["auto", "true", "false"]), default=None,
                      expose_value=False, callback=_setting("cluster.processes"),
                      help="Local workers as processes (true), as threads in this process (false), "
                           "or by the scene's size (auto: radiosity.cluster.processes).")(fn)
    fn = click.option("--cluster", "cluster_kind", type=click.Choice(["local", "slurm", "pbs", "sge", "lsf"]),
                      default=None, help="Where workers run (default: radiosity.cluster.kind, local).")(fn)
    fn = click.option("--scheduler", default=None, metavar="ADDRESS",
                      help="Use a running Dask scheduler instead of starting a cluster.")(fn)
    fn = click.option("--workers", type=POSITIVE_INT, default=None,
                      help="Number of workers (default: one per core).")(fn)
    return fn


def method_options(fn, links: bool = True):
    """--method pairs|hierarchical, --direct, and the hierarchical method's --epsilon /
    --link-rays (overrides of radiosity.visibility.method, radiosity.direct.mode and
    radiosity.hierarchy.*)."""
    if links:
        fn = click.option("--link-rays", type=int, default=None, expose_value=False,
                          help="hierarchical: sample rays per link not proven visible (a square).",
                          callback=_setting("hierarchy.link-rays"))(fn)
        fn = click.option("--epsilon", type=float, default=None, expose_value=False,
                          help="hierarchical: refine links while their error estimate exceeds this.",
                          callback=_setting("hierarchy.epsilon"))(fn)
    fn = click.option("--direct", type=click.Choice(["auto", "points", "links"]), default=None,
                      expose_value=False,
                      help="hierarchical: the emitters' light at points, the links carrying only "
                           "light after its first bounce (points), through the links as all "
                           "light (links, the seed's way), or per scene (auto, the default: "
                           "radiosity.direct.mode).",
                      callback=_setting("direct.mode"))(fn)
    from radiosity.methods.base import METHODS

    return click.option("--method", type=click.Choice(["auto", *METHODS]), default=None,
                        expose_value=False,
                        help="pairs: one visibility bit per pair of sub-elements (the seed's); "
                             "hierarchical: links between nodes of the split trees; auto (the "
                             "default, radiosity.visibility.method): hierarchical above "
                             "radiosity.visibility.hierarchical-above sub-elements.",
                        callback=_setting("visibility.method"))(fn)



def solve_options(fn):
    """--solver / --kernel (and its sampling) / --tol / --max-iterations / --closure."""
    from radiosity.core.solvers import SOLVERS

    fn = click.option("--closure", type=click.Choice(["auto", "on", "off"]), default=None,
                      expose_value=False,
                      help="Is the scene closed (rows balanced to exactly 1)? auto: from the geometry.",
                      callback=_setting("solve.closure"))(fn)
    fn = click.option("--keep-unconverged", is_flag=True,
                      help="Write the solution even when the solver did not converge (by default "
                           "a converged solution already in the run is kept; exit status 3 "
                           "either way).")(fn)
    fn = click.option("--max-iterations", type=int, default=None, help="Pass limit.")(fn)
    fn = click.option("--tol", type=float, default=None,
                      help="Relative residual to stop at, in (0, 1).")(fn)
    fn = kernel_options(fn)
    fn = click.option("--solver", type=click.Choice(["auto", *SOLVERS]), default=None,
                      help="Solver (default: radiosity.solve.solver, auto: CG for reciprocal "
                           "kernels, Gauss-Seidel otherwise).")(fn)
    return fn


def image_options(fn):
    fn = click.option("--edge-samples", type=int, default=None,
                      expose_value=False,
                      help="--sampling area: K x K rays again for each pixel on a silhouette or "
                           "corner (default: radiosity.render.edge-samples; 0: none).",
                      callback=_setting("render.edge-samples"))(fn)
    fn = click.option("--area-samples", type=int, default=None, expose_value=False,
                      help="--sampling area: K x K rays per pixel (default: "
                           "radiosity.render.area-samples).",
                      callback=_setting("render.area-samples"))(fn)
    fn = click.option("--sampling", type=click.Choice(["area", "point"]), default=None,
                      expose_value=False,
                      help="area: each pixel the mean over its area, as a camera sees it (the "
                           "default, radiosity.render.sampling); point: the element at its "
                           "centre (the seed's).",
                      callback=_setting("render.sampling"))(fn)
    fn = click.option("--exposure", default=None, callback=_exposure,
                      help="Exposure for PNG/mesh colours, or 'auto'.")(fn)
    fn = click.option("--sigma", type=float, default=None, help="Gaussian sigma in fine pixels.")(fn)
    fn = click.option("--filter", "filter_", type=click.Choice(["box", "gaussian"]), default=None,
                      help="Sub-pixel reconstruction filter.")(fn)
    return fn


def force_option(fn):
    """--force: write into a non-empty folder that is not a run directory (refused otherwise)."""
    return click.option("--force", is_flag=True,
                        help="Write into OUT even when it is a non-empty folder that is not a "
                             "run directory (its files of the same names are replaced).")(fn)


def run_client(workers, scheduler, cluster_kind, st=None, samples: int | None = None, **kw):
    """open_client with the cluster flags (adaptive, tls, batch-job options) and the command's
    settings `st` (None: the flags' own, settings_from_flags); with `st`, a local cluster's
    workers are threads or processes by radiosity.cluster.processes for a scene of `samples`
    camera samples (runtime/cluster.local_mode)."""
    from radiosity.runtime.cluster import local_mode, open_client

    if st is not None:
        kw["in_process"], kw["where"] = local_mode(st.cluster.processes, samples,
                                                   st.cluster.in_process_samples)
    cl = (st if st is not None else settings_from_flags()).cluster
    return open_client(workers, scheduler, cluster_kind, echo=click.echo, settings=cl,
                       **{**cluster_from_flags(), **kw})
