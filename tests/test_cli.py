"""The `radiosity` command end to end, against the session's real LocalCluster."""

from __future__ import annotations

import json
import os

import pytest
from click.testing import CliRunner

from radiosity.cli import main
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


@pytest.mark.parametrize("name", BUILTIN)
def test_render_end_to_end_on_every_builtin_scene(client, tmp_path, name):
    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["render", scene_path(name), "--out", str(out), "--resolution", "16",
                                  "--scheduler", client.scheduler.address])
    assert r.exit_code == 0, r.output
    for f in ("image.exr", "image.png", "preview.png", "mesh.glb", "mesh.ply", "viewer.html", "report.json"):
        assert (out / f).stat().st_size > 0, f
    rep = json.loads((out / "report.json").read_text())
    for section in ("preprocess", "visibility", "solve", "render"):
        assert section in rep
    assert rep["solve"]["converged"]
    st = rep["render"]["stages"]
    assert st["total_s"] >= st["preprocess_s"] + st["visibility_s"] + st["solve_s"]
    assert "workers" in st["peak_rss_mb"]


def test_solve_and_image_commands_and_resume(client, tmp_path):
    out = tmp_path / "run"
    sched = ["--scheduler", client.scheduler.address]
    r = CliRunner().invoke(main, ["render", scene_path("three-rectangles"), "--out", str(out),
                                  "--resolution", "12", "--no-preview"] + sched)
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["render", scene_path("three-rectangles"), "--out", str(out),
                                  "--resolution", "12", "--no-preview", "--resume"] + sched)
    assert r.exit_code == 0 and "reusing the partition" in r.output
    assert json.loads((out / "report.json").read_text())["visibility"]["tasks_computed"] == 0
    r = CliRunner().invoke(main, ["solve", str(out), "--solver", "cg", "--tol", "1e-9"] + sched)
    assert r.exit_code == 0 and "cg (point-nf kernel)" in r.output and "converged" in r.output
    r = CliRunner().invoke(main, ["image", str(out), "--filter", "gaussian", "--exposure", "2"])
    assert r.exit_code == 0 and "exposure 2" in r.output
    r = CliRunner().invoke(main, ["solve", str(out), "--solver", "cg", "--kernel", "disc"] + sched)
    assert r.exit_code == 2 and "needs a reciprocal kernel" in r.output


def test_cluster_flags_reach_the_config(tmp_path):
    """--tls and the batch-job flags write dask.config; a local TLS run works end to end."""
    import copy

    import dask.config
    import dask_jobqueue  # noqa: F401  both register their defaults on import: snapshot after them
    import distributed  # noqa: F401

    saved = copy.deepcopy(dask.config.config)  # the flags set the process's config: restore it
    try:
        r = CliRunner().invoke(main, ["preprocess", scene_path("three-rectangles"), "--out", str(tmp_path / "r"),
                                      "--resolution", "8", "--workers", "1", "--tls", "--cores", "4",
                                      "--account", "proj1"])
        assert r.exit_code == 0, r.output
        assert dask.config.get("radiosity.cluster.tls") == "temporary"
        assert dask.config.get("jobqueue.slurm.cores") == 4
        assert dask.config.get("jobqueue.sge.project") == "proj1"
    finally:
        dask.config.config.clear()
        dask.config.config.update(saved)
