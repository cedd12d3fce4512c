"""`radiosity reference --engine radiance`: Radiance's illuminance at the points of a CSV file
(validation/radiance.py), the options only it reads, added to `reference` by commands.py."""

from __future__ import annotations

import click

from radiosity.cli.options import POSITIVE_INT, settings_from_flags
from radiosity.cli.summary import table_text
from radiosity.errors import RadiosityError


#: --quality's choices: validation.radiance.QUALITIES (not imported here: the CLI starts fast).
QUALITIES = ("draft", "medium", "high", "reference")


def radiance_options(f):
    """The options of `radiosity reference` that only --engine radiance reads."""
    options = [
        click.option("--engine", type=click.Choice(["mitsuba", "radiance"]), default="mitsuba",
                     show_default=True, help="mitsuba: the camera's image, path-traced; "
                     "radiance: illuminance at --points with Radiance's rtrace (pyradiance)."),
        click.option("--points", "points_csv", default=None, type=click.Path(),
                     help="Radiance: CSV of the points, header x,y,z,nx,ny,nz; writes "
                          "OUT/points.csv."),
        click.option("--quality", type=click.Choice(QUALITIES), default="reference",
                     show_default=True, help="Radiance: settings level (how-to: Ground truth)."),
        click.option("--emitters", type=click.Choice(["sources", "glow"]), default="sources",
                     show_default=True, help="Radiance: emitters as light sources (direct "
                     "sampling) or as glowing surfaces found by ambient rays only (large "
                     "emitters)."),
        click.option("--processes", type=POSITIVE_INT, default=1, show_default=True,
                     help="Radiance: rtrace processes (-n)."),
    ]
    for option in reversed(options):  # as if stacked above the command, in this order
        f = option(f)
    return f


def radiance_reference(scene, out, engine, points_csv, quality, emitters, processes, force,
                       mitsuba_only: dict) -> None:
    """`radiosity reference --engine radiance`: illuminance at the points of a CSV file."""
    import numpy as np

    from radiosity.runtime.checks import check_new_run_dir
    from radiosity.validation.radiance import make_radiance_reference, radiance_env, read_points

    if engine != "radiance":
        raise RadiosityError("--points is for --engine radiance (Mitsuba renders the camera's image)")
    given = [k for k, v in mitsuba_only.items() if v is not None]
    if given:
        raise RadiosityError(f"{given[0]} is for --engine mitsuba (Radiance traces --points)")
    radiance_env()  # one line saying how to install it, before anything is loaded
    st = settings_from_flags()
    sc = _load(scene, st)
    grids = ()
    if points_csv is not None:
        P, N = read_points(points_csv)
    elif sc.grids:  # the scene's [[grid]] tables, one after another
        P = np.concatenate([g.points for g in sc.grids])
        N = np.concatenate([g.normals for g in sc.grids])
        grids = tuple((g.name, len(g.points)) for g in sc.grids)
    else:
        raise RadiosityError("--engine radiance needs --points FILE.csv (header x,y,z,nx,ny,nz) "
                             "or a scene with [[grid]] tables")
    check_new_run_dir(out, force)
    fig = make_radiance_reference(sc, P, N, out, quality=quality, emitters=emitters,
                                  processes=processes, echo=click.echo, grids=grids)
    med = fig["rel_stderr_median"]
    click.echo(table_text([
        ("points", f"{fig['points']} x {fig['quality']['repeats']} repeats ({fig['radiance_version']})"),
        ("settings", f"{quality}: {fig['rtrace']}"),
        ("ambient bounces", f"{fig['ambient_bounces']} (max reflectance {fig['max_reflectance']:.3g}: "
                            f"light dropped <= {fig['truncation_bound']:.2g})"),
        ("illuminance", f"min {fig['lux_min']:.4g}, mean {fig['lux_mean']:.4g}, max "
                        f"{fig['lux_max']:.4g} lx"),
        ("relative std. error", "-" if med is None else
         f"median {med:.3g}, max {fig['rel_stderr_max']:.3g}"),
        ("time", f"{fig['time_s']:.1f} s")]))
    per_grid = "".join(f", grids/{name}.csv" for name, _ in grids)
    click.echo(f"wrote {out}/points.csv{per_grid}, radiance.json, scene.rad, scene.oct")


def _load(scene: str, st):
    from radiosity.scene.load import load_scene

    sc = load_scene(scene, settings=st)
    if sc.chosen:
        click.echo(sc.chosen)
    return sc
