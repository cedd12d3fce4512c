"""`radiosity study`: what accuracy costs in time (sweeps of settings against a reference,
and the seed paper's experiments), added to the `radiosity` group by commands.py."""

from __future__ import annotations

import os

import click

from radiosity.cli.options import (POSITIVE_INT, run_client, number_list, cluster_options,
                                   force_option, settings_from_flags)
from radiosity.cli.summary import friendly
from radiosity.errors import RadiosityError


@click.group()
def study():
    """Studies: what accuracy costs in time."""


def _check_study_out(out: str, force: bool, summary: str) -> None:
    """A study's --out: as every command's (check_new_run_dir), where a folder holding the
    study's `summary` file or its runs/ (run directories) is one of ours, written again."""
    from radiosity.runtime.checks import check_new_run_dir

    runs = os.path.join(out, "runs")
    ours = os.path.isfile(os.path.join(out, summary)) or (os.path.isdir(runs) and any(
        os.path.exists(os.path.join(runs, d, "report.json")) for d in os.listdir(runs)))
    check_new_run_dir(out, force or ours)


def _floats(s: str, kind=float):
    return [kind(x) for x in s.split(",") if x.strip()]


@study.command("accuracy")
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Directory for results.")
@click.option("--resolutions", default="8,16,32", show_default=True, help="Camera resolutions.",
              callback=number_list(int, 0, "positive integers"))
@click.option("--subpixels", default="1", show_default=True, help="Sub-pixel factors.",
              callback=number_list(int, 0, "positive integers"))
@click.option("--kernels", default="point,disc", show_default=True,
              help="Form-factor kernels; the sampled ones may name their sample count: nxm:16, mc:64.")
@click.option("--tols", default="1e-6", show_default=True, help="Solver tolerances.",
              callback=number_list(float, 0.0, "tolerances > 0"))
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
              callback=number_list(float, -1e-300, "numbers >= 0"),
              help="Also sweep --method hierarchical at these epsilons (x --link-rays).")
@click.option("--link-rays", "link_rays", default="4", show_default=True, metavar="K,K,...",
              callback=number_list(int, 0, "positive integers"),
              help="With --epsilons: the hierarchical method's rays per link (squares).")
@click.option("--direct-modes", "direct_modes", default="links,points", show_default=True,
              metavar="MODE,MODE",
              help="With --epsilons: where the emitters' light is taken (radiosity.direct.mode), "
                   "each a row: links (the old way) beside points (SPEC §10), or auto.")
@click.option("--solver", default=None, help="Solver (default: radiosity.solve.solver).")
@force_option
@cluster_options
@friendly
def study_accuracy(scene, out, resolutions, subpixels, kernels, tols, reference, reference_spp,
                   path_tracer_spp, epsilons, link_rays, direct_modes, solver, force, workers,
                   scheduler, cluster_kind):
    """Sweep resolution x sub-pixel x kernel x tolerance on SCENE (and, with --epsilons, the
    hierarchical method's epsilon x link rays x --direct-modes); time every stage, measure the
    error; write results.csv, results.md and accuracy.png (error against time, Pareto front)."""
    from radiosity.validation.study import HIER, accuracy, kernel_setting

    ks = [k for k in kernels.split(",") if k]
    if epsilons:
        ks += [f"{HIER}:{e:g}:{k}:{m}" for e in _floats(epsilons) for k in _floats(link_rays, int)
               for m in direct_modes.split(",") if m]
    st = settings_from_flags(solve__solver=solver)
    for k in ks:
        kernel_setting(k, st)  # a bad name or count fails before the cluster starts
    if reference == "auto":
        from radiosity.validation.reference import load_mitsuba

        load_mitsuba(st.reference.variant, echo=click.echo)  # Mitsuba missing fails first
    elif reference is not None and not os.path.isfile(reference):
        raise RadiosityError(f"--reference {reference}: no such file (give an EXR image, or auto)")
    pts = _floats(path_tracer_spp, int) if path_tracer_spp else None
    _check_study_out(out, force, "results.md")
    with run_client(workers, scheduler, cluster_kind) as client:
        rows = accuracy(scene, out, client, _floats(resolutions, int), _floats(subpixels, int), ks,
                        _floats(tols), reference=reference, solver=solver, echo=click.echo,
                        reference_spp=reference_spp, path_tracer_spp=pts, settings=st)
    best = [r for r in rows if r["pareto"]]
    click.echo(f"wrote {out}/results.csv, results.md, accuracy.png; {len(best)} settings on the Pareto front")


@study.command("seed")
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Directory for plots and tables.")
@click.option("--resolutions", default="32,64,128,256", show_default=True,
              callback=number_list(int, 0, "positive integers"))
@click.option("--speedup-resolution", type=POSITIVE_INT, default=96, show_default=True)
@click.option("--max-workers", type=POSITIVE_INT, default=None, help="Largest LocalCluster for the speedup.")
@force_option
@friendly
def study_seed(scene, out, resolutions, speedup_resolution, max_workers, force):
    """Reproduce the seed's experiments on SCENE: Fig. 3, Fig. 4, the speedup table and the image
    series; writes PNG plots and seed.md into OUT."""
    from radiosity.runtime.cluster import default_workers, open_client
    from radiosity.validation.study import seed

    _check_study_out(out, force, "seed.md")
    n = max_workers or default_workers()
    st = settings_from_flags()
    res = seed(scene, out, lambda w: open_client(w, quiet=True, settings=st.cluster),
               _floats(resolutions, int), list(range(1, n + 1)), speedup_resolution,
               echo=click.echo, settings=st)
    click.echo(f"wrote {out}/seed.md and its plots; visibility time ~ m^{res['order']:.2f}")
