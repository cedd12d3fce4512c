"""The effects planner: every skip computes the same answer with measurably less work."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from radiosity.cli.commands import main
from radiosity.pipeline import render_scene
from radiosity.scene.effects import plan_effects
from radiosity.scene.load import load_scene
from radiosity.runtime.store import RunStore
from helpers import scene_path, write_scene
from radiosity.settings import options as settings_of

CAM_ABOVE = """
[camera]
position = [0.3, 3.0, -2.5]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov_y = 55.0
resolution = [12, 12]
"""

# a floor, a lamp above it facing down, a wall beside them, and a panel under the floor facing
# down (no light can reach it); materials set per test
SCENE = """
v -1 0 -1
v 1 0 -1
v 1 0 1
v -1 0 1
v -0.3 1 -0.3
v 0.3 1 -0.3
v 0.3 1 0.3
v -0.3 1 0.3
v -1 0 1.2
v 1 0 1.2
v 1 1.5 1.2
v -1 1.5 1.2
v -0.5 -0.5 -0.5
v 0.5 -0.5 -0.5
v 0.5 -0.5 0.5
v -0.5 -0.5 0.5
usemtl floor
f 1 4 3 2
usemtl lamp
f 5 6 7 8
usemtl wall
f 9 12 11 10
usemtl under
f 13 14 15 16
"""


def _both(client, tmp_path, path, **kw):
    """(planned report, planned radiance, full report, full radiance)."""
    out = []
    for full in (False, True):
        d = str(tmp_path / ("full" if full else "planned"))
        rep = render_scene(load_scene(path, settings=settings_of()), d, client,
                           settings_of(tol=1e-12, **kw), preview=False, progress=False,
                           full=full, echo=lambda *a: None)
        out += [rep, RunStore(d).read_arrays("solution")["radiance"]]
    return out


def _same(a, b):
    scale = np.abs(b).max()
    assert scale > 0
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * scale)


def _scene(tmp_path, mats: str):
    return write_scene(tmp_path, SCENE, mats, camera=CAM_ABOVE)


COLOURED = """
[material.floor]
reflectance = [0.6, 0.5, 0.4]
[material.lamp]
reflectance = [0.0, 0.0, 0.0]
emission = [4.0, 3.0, 2.0]
[material.wall]
reflectance = [0.3, 0.7, 0.3]
[material.under]
reflectance = [0.5, 0.5, 0.5]
"""


def test_occlusion_off_in_a_convex_enclosure(client, tmp_path):
    path = scene_path("furnace-cube")
    p = plan_effects(load_scene(path, settings=settings_of()).elements)
    assert not p.occlusion and "convex" in p.reasons["occlusion"]
    plan_rep, L, full_rep, Lf = _both(client, tmp_path, path)
    _same(L, Lf)
    assert plan_rep["visibility"]["rays"] == 0 and plan_rep["visibility"]["shaft_tests"] == 0
    # forced on, the shafts prove every facing pair visible: in a convex enclosure every
    # wall's plane holds both ends of a pair on its closed front side, so none is a candidate
    assert full_rep["visibility"]["pairs_shaft_visible"] > 0 and full_rep["visibility"]["rays"] == 0


def test_no_interreflection_solves_direct_emission_only(client, tmp_path):
    mats = COLOURED.replace("[0.6, 0.5, 0.4]", "[0.0, 0.0, 0.0]").replace("[0.3, 0.7, 0.3]", "[0, 0, 0]") \
        .replace("reflectance = [0.5, 0.5, 0.5]", "reflectance = [0.0, 0.0, 0.0]")
    path = _scene(tmp_path, mats)
    assert not plan_effects(load_scene(path, settings=settings_of()).elements).interreflection
    plan_rep, L, full_rep, Lf = _both(client, tmp_path, path)
    _same(L, Lf)
    assert plan_rep["solve"]["pair_terms"] == 0 and plan_rep["visibility"]["skipped"]
    assert plan_rep["visibility"]["pairs_total"] == 0
    assert full_rep["solve"]["pair_terms"] > 0 and full_rep["visibility"]["pairs_total"] > 0


def test_grey_scene_solves_one_channel(client, tmp_path):
    mats = COLOURED.replace("[0.6, 0.5, 0.4]", "[0.6, 0.6, 0.6]").replace("[4.0, 3.0, 2.0]", "[3.0, 3.0, 3.0]") \
        .replace("[0.3, 0.7, 0.3]", "[0.4, 0.4, 0.4]")
    path = _scene(tmp_path, mats)
    assert not plan_effects(load_scene(path, settings=settings_of()).elements).colour
    plan_rep, L, full_rep, Lf = _both(client, tmp_path, path)
    _same(L, Lf)
    assert plan_rep["solve"]["channels"] == 1 and full_rep["solve"]["channels"] == 3
    assert plan_rep["solve"]["channel_terms"] < full_rep["solve"]["channel_terms"] / 2


def test_two_sided_element_with_nothing_behind_is_solved_one_sided(client, tmp_path):
    # nothing lies behind the wall (z > 1.2): its back side can neither receive nor send light
    mats = COLOURED.replace("[material.wall]", "[material.wall]\ntwo_sided = true")
    path = _scene(tmp_path, mats)
    p = plan_effects(load_scene(path, settings=settings_of()).elements)
    assert p.two_sided.sum() == 0 and "solved as one-sided" in p.reasons["two_sided"]
    plan_rep, L, full_rep, Lf = _both(client, tmp_path, path)
    _same(L, Lf)
    assert plan_rep["solve"]["two_sided_sub_elements"] == 0
    assert full_rep["solve"]["two_sided_sub_elements"] > 0


def test_dead_rows_drop_out_of_the_iteration(client, tmp_path):
    path = _scene(tmp_path, COLOURED)
    p = plan_effects(load_scene(path, settings=settings_of()).elements)
    el = load_scene(path, settings=settings_of()).elements
    names = [el.material_names[m] for m in el.material]
    assert not p.gather[names.index("lamp")]     # an emitter that reflects nothing
    assert not p.gather[names.index("under")]    # no light reaches it
    assert p.gather[names.index("floor")]
    plan_rep, L, full_rep, Lf = _both(client, tmp_path, path)
    _same(L, Lf)
    assert plan_rep["solve"]["pair_terms"] < full_rep["solve"]["pair_terms"]
    assert plan_rep["solve"]["gathering_elements"] == 2


def test_plan_command_prints_the_plan_before_heavy_work():
    r = CliRunner().invoke(main, ["plan", scene_path("furnace-cube")])
    assert r.exit_code == 0, r.output
    assert "occlusion          OFF" in r.output and "colour             OFF" in r.output
    assert "rays saved" in r.output and "stay unsplit" in r.output
    r = CliRunner().invoke(main, ["plan", scene_path("cornell-box")])
    assert "occlusion          on" in r.output and "passes to tolerance" in r.output


def test_render_records_the_plan(client, tmp_path):
    import json

    r = CliRunner().invoke(main, ["render", scene_path("three-rectangles"), "--out", str(tmp_path / "r"),
                                  "--resolution", "12", "--no-preview", "--scheduler", client.scheduler.address])
    assert r.exit_code == 0, r.output
    rep = json.loads((tmp_path / "r" / "report.json").read_text())
    assert rep["plan"]["colour"] is False and "reasons" in rep["plan"]
    assert rep["solve"]["channels"] == 1


@pytest.mark.parametrize("solver", ["jacobi", "gauss-seidel", "progressive"])
def test_every_skip_gives_the_full_answer_with_the_other_solvers(client, tmp_path, solver):
    """The planned skips change the operator each solver sees (one channel for a grey scene,
    rows that do not gather, a two-sided wall solved one-sided): Jacobi, Gauss-Seidel (its own
    sweep honours `need`) and progressive must reach the full run's answer too."""
    mats = COLOURED.replace("[0.6, 0.5, 0.4]", "[0.6, 0.6, 0.6]").replace("[4.0, 3.0, 2.0]", "[3.0, 3.0, 3.0]") \
        .replace("[0.3, 0.7, 0.3]", "[0.4, 0.4, 0.4]").replace("[material.wall]", "[material.wall]\ntwo_sided = true")
    path = _scene(tmp_path, mats)
    p = plan_effects(load_scene(path, settings=settings_of()).elements)
    assert not p.colour and p.two_sided.sum() == 0 and not p.gather.all()
    plan_rep, L, full_rep, Lf = _both(client, tmp_path, path, solver=solver)
    assert plan_rep["solve"]["solver"] == full_rep["solve"]["solver"] == solver
    assert plan_rep["solve"]["channels"] == 1 and plan_rep["solve"]["two_sided_sub_elements"] == 0
    assert plan_rep["solve"]["gathering_elements"] == 2
    assert plan_rep["solve"]["channel_terms"] < full_rep["solve"]["channel_terms"] / 2
    _same(L, Lf)
