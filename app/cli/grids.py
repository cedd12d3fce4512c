"""`radiosity grid RUN --grid FILE`: illuminance on calculation grids of a solved run, without
solving again (issue 52; stages/grids.py)."""

from __future__ import annotations

import click

from radiosity.cli.options import settings_from_flags
from radiosity.cli.summary import command_line, friendly, table_text
from radiosity.errors import RadiosityError


@click.command("grid")
@click.argument("run_dir", type=click.Path())
@click.option("--grid", "grid_file", required=True, type=click.Path(),
              help="A TOML file of [[grid]] tables (the scene file's keys; points files relative "
                   "to it).")
@friendly
def grid_command(run_dir, grid_file):
    """Illuminance on calculation grids from a solved RUN_DIR, without solving again:
    RUN_DIR/grids/NAME.csv and NAME.png, and their min / average / max / U0 in report.json."""
    from radiosity.pipeline import render_grids
    from radiosity.runtime.checks import check_run_dir
    from radiosity.runtime.runlock import run_lock
    from radiosity.runtime.store import RunStore
    from radiosity.scene.grids import check_grids, parse_grids
    from radiosity.scene.load import read_toml
    from radiosity.stages.grids import grid_rows
    from radiosity.tracing.rays import caster_of

    st = settings_from_flags()
    check_run_dir(run_dir)
    rs = RunStore(run_dir)
    if not rs.has("solution"):
        raise RadiosityError(f"{run_dir}: not solved yet: run `radiosity solve {run_dir}` (or "
                             "render) first")
    grids = parse_grids(read_toml(grid_file), grid_file)
    if not grids:
        raise RadiosityError(f"{grid_file}: no [[grid]] tables")
    el = rs.load_elements()
    check_grids(grids, el, caster_of(el.verts, el.nverts, float(st.rays.offset)), grid_file)
    with run_lock(run_dir, command_line()):
        fig = render_grids(run_dir, st, grids)
    names = {g.name for g in grids}
    click.echo(table_text(grid_rows({"grids": [g for g in fig.grids if g["name"] in names]})))
    click.echo(f"wrote {run_dir}/" + f", {run_dir}/".join(
        f for g in fig.grids if g["name"] in names for f in g["files"]) + ", report.json")
