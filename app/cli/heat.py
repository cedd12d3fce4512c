"""`radiosity heat SCENE --out DIR`: radiative heat exchange between a mesh's facets (issue 53;
viewfactors/heat.py, docs/src/how-to/heat.md). Added to the `radiosity` group in commands.py."""

from __future__ import annotations

import os

import click

from radiosity.cli.options import POSITIVE, Finite, cluster_options, force_option, \
    run_client, settings_from_flags
from radiosity.cli.summary import (command_line, finish_lines, friendly, mark_started,
                                   record_run, table_text)


@click.command()
@click.argument("scene", type=click.Path())
@click.option("--out", "-o", required=True, type=click.Path(), help="Run directory to create.")
@click.option("--emissivity", type=Finite(min=0.0, max=1.0, min_open=True), default=None,
              help="Every facet's emissivity in (0, 1] (a scene's materials override it).")
@click.option("--temperature", type=Finite(min=0.0), default=None, metavar="K",
              help="Every facet's temperature in kelvin (materials override it).")
@click.option("--heat-flux", type=float, default=None, metavar="W_M2",
              help="Every facet's net heat flux, W m^-2 leaving (0: reradiating).")
@click.option("--environment-temperature", type=Finite(min=0.0), default=None, metavar="K",
              help="What the facets see through openings (default: the scene's "
                   "[environment] temperature_K, else 0 K).")
@click.option("--conductances", type=click.Choice(["auto", "on", "off"]), default=None,
              help="Radiative conductances GR: auto (up to radiosity.heat.conductance-max-"
                   "facets facets), on, off (default: radiosity.heat.conductances).")
@click.option("--conductance-cutoff", type=Finite(min=0.0), default=None,
              help="Drop conductors below this x sqrt(e_i A_i e_j A_j) (default 0: none).")
@click.option("--accuracy", type=POSITIVE, default=None,
              help="Target absolute error of each view factor (radiosity.viewfactors.accuracy).")
@click.option("--enclosure", type=click.Choice(["auto", "on", "off"]), default=None,
              help="Balance view-factor rows to 1 (radiosity.viewfactors.enclosure).")
@click.option("--resume", is_flag=True, help="Keep the finished view-factor tasks in OUT.")
@force_option
@cluster_options
@friendly
def heat(scene, out, emissivity, temperature, heat_flux, environment_temperature, conductances,
         conductance_cutoff, accuracy, enclosure, resume, force, workers, scheduler, cluster_kind):
    """Radiative heat exchange between the facets of SCENE (a scene TOML whose materials carry
    emissivity and temperature_K or heat_flux_W_m2, or a mesh with --emissivity and
    --temperature or --heat-flux): net heat per facet and the conductances GR."""
    from radiosity.runtime.checks import check_new_run_dir
    from radiosity.runtime.runlock import run_lock
    from radiosity.viewfactors.api import load_facets, resolve_params
    from radiosity.viewfactors.heat import compute_heat
    from radiosity.viewfactors.thermal import ThermalDefaults, heat_inputs

    st = settings_from_flags(viewfactors__accuracy=accuracy, viewfactors__enclosure=enclosure,
                             heat__conductances=conductances,
                             heat__conductance_cutoff=conductance_cutoff)
    resolve_params(settings=st)
    defaults = ThermalDefaults(emissivity, temperature, heat_flux, environment_temperature)
    fac = load_facets(scene, settings=st)
    heat_inputs(scene, fac, defaults)  # bad values fail before the cluster starts
    check_new_run_dir(out, force)
    mark_started(out)
    click.echo(f"{len(fac)} facets from {', '.join(fac.sources)}")
    with run_lock(out, command_line()), run_client(workers, scheduler, cluster_kind) as client:
        res = compute_heat(scene, out, client, st, defaults, resume=resume, echo=click.echo)
        record_run(out, os.path.basename(scene))
    click.echo(heat_summary(res.figures.to_dict(), finish_lines(out, [])))
    click.echo(f"wrote {out}/" + f", {out}/".join(res.figures["files"] + ["report.json"])
               + f"; the view factors in {out}/viewfactors")


def heat_summary(fig: dict, extra: list = ()) -> str:
    """The heat command's summary table (report.json's "heat" section; extra: rows after it)."""
    rows = [("facets", f"{fig['live_facets']} taking part of {fig['facets']}"),
            ("environment", f"{fig['environment_K']:g} K, absorbs {fig['environment_absorbed_W']:.6g} W"),
            ("net heat (facets)", f"{fig['net_heat_W']:.6g} W (energy balance "
                                  f"{fig['energy_balance_W']:.3g} W)"),
            ("solve", f"{fig['solve_steps']} steps, residual {fig['solve_residual']:.3g}")]
    for name, m in fig["materials"].items():
        if m["facets"]:
            rows.append((f"material {name}",
                         f"{m['facets']} facets, {m['area_m2']:.6g} m2, net {m['net_heat_W']:.6g} W, "
                         f"{m['temperature_K_min']:.6g} .. {m['temperature_K_max']:.6g} K"))
    c = fig.get("conductances")
    rows.append(("conductances", "not computed" if not c else
                 f"{c['nonzeros']} nonzeros, rows within {c['row_sum_relative_error_max']:.3g} "
                 f"of e A (dropped {c['dropped_relative_max']:.3g}), heat within "
                 f"{c['heat_relative_error_max']:.3g}"))
    rows.append(("time", f"solve {fig['time_solve_s']:.2f} s, conductances "
                         f"{fig['time_conductances_s']:.2f} s"))
    return table_text(rows + list(extra))
