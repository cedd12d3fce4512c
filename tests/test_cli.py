"""The `radiosity` command end to end, against the session's real LocalCluster."""

from __future__ import annotations

import json
import os

import pytest
from click.testing import CliRunner

from app.cli import main
from conftest import FLOOR_AND_TRIANGLE, scene_path, write_scene

BUILTIN = ["cornell-box", "three-rectangles", "construction-in-wood", "room-2400", "furnace-cube",
           "furnace-sphere"]


@pytest.mark.parametrize("name", BUILTIN)
def test_preprocess_every_builtin_scene(client, tmp_path, name):
    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["preprocess", scene_path(name), "--out", str(out), "--resolution", "32",
                                  "--scheduler", client.scheduler.address])
    assert r.exit_code == 0, r.output
    assert "sub-elements" in r.output and "dashboard:" in r.output
    rep = json.loads((out / "report.json").read_text())["preprocess"]
    assert rep["sub_elements"] >= rep["original_elements"]
    assert rep["max_pixels_per_sub_element"] <= 1
    assert os.path.isdir(out / "store.zarr" / "partition")


def test_bad_input_is_one_line_not_a_traceback(tmp_path):
    path = write_scene(tmp_path, FLOOR_AND_TRIANGLE.replace("v 1 0 0", "v 1 nan 0"))
    r = CliRunner().invoke(main, ["preprocess", path, "--out", str(tmp_path / "r")])
    assert r.exit_code == 2
    assert "error:" in r.output and "face 1 has a NaN" in r.output
    assert "Traceback" not in r.output


def test_bad_resolution_flag(tmp_path, small_scene):
    r = CliRunner().invoke(main, ["preprocess", small_scene, "--out", str(tmp_path / "r"), "--resolution", "0x5"])
    assert r.exit_code == 2 and "--resolution: resolution must be positive" in r.output


def test_visibility_command_and_resume(client, tmp_path):
    out = tmp_path / "run"
    sched = ["--scheduler", client.scheduler.address]
    r = CliRunner().invoke(main, ["preprocess", scene_path("three-rectangles"), "--out", str(out),
                                  "--resolution", "12"] + sched)
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["visibility", str(out), "--task-unit", "stripe"] + sched)
    assert r.exit_code == 0, r.output
    assert "rays cast" in r.output and "stripe" in r.output
    rep = json.loads((out / "report.json").read_text())
    assert rep["visibility"]["task_unit"] == "stripe" and "preprocess" in rep
    r = CliRunner().invoke(main, ["visibility", str(out), "--task-unit", "stripe", "--resume"] + sched)
    assert r.exit_code == 0 and "0 computed" in r.output


def test_visibility_on_a_directory_that_is_not_a_run(tmp_path):
    r = CliRunner().invoke(main, ["visibility", str(tmp_path / "nothing")])
    assert r.exit_code == 2 and "is not a run directory" in r.output
