"""Bad input caught before anything starts: every numeric option, the run directory, the
scene's light and camera. One line `error: ...`, exit status 2, no traceback, no cluster and no
half-made run directory (issue 15)."""

from __future__ import annotations

import os

import pytest
from click.testing import CliRunner

from radiosity.cli.commands import main
from helpers import scene_path
from radiosity.settings import options as settings_of

S = scene_path("three-rectangles")


def one_line_error(r, *fragments):
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    assert len(errors) == 1, r.output
    assert "Traceback" not in r.output and "dashboard:" not in r.output, r.output
    for f in fragments:
        assert f in errors[0], r.output
    return errors[0]


OUT = ["--out", "OUT"]
CASES = [
    # (command line after `radiosity`, fragments of the one error line)
    (["plan", S, "--tol", "-1"], ["--tol", "-1"]),
    (["plan", S, "--tol", "nan"], ["--tol", "not a finite number"]),
    (["plan", S, "--tol", "1"], ["--tol"]),
    (["plan", S, "--subpixel", "0"], ["--subpixel", "0"]),
    (["plan", S, "--resolution", "0x5"], ["--resolution", "positive"]),
    (["plan", S, "--resolution", "64.5"], ["--resolution", "whole number of pixels", "'64.5'"]),
    (["render", S, *OUT, "--resolution", "64x32.5"], ["--resolution", "whole number"]),
    (["render", S, *OUT, "--tol", "-1"], ["--tol"]),
    (["render", S, *OUT, "--max-iterations", "-3"], ["--max-iterations", "-3"]),
    (["render", S, *OUT, "--max-iterations", "0"], ["--max-iterations"]),
    (["render", S, *OUT, "--workers", "-1"], ["--workers", "-1"]),
    (["render", S, *OUT, "--workers", "0"], ["--workers"]),
    (["render", S, *OUT, "--subpixel", "0"], ["--subpixel"]),
    (["render", S, *OUT, "--resolution", "abc"], ["--resolution"]),
    (["render", S, *OUT, "--sigma", "0"], ["--sigma"]),
    (["render", S, *OUT, "--sigma", "inf"], ["--sigma"]),
    (["render", S, *OUT, "--exposure", "-2"], ["--exposure"]),
    (["render", S, *OUT, "--nxm-points", "0"], ["--nxm-points"]),
    (["render", S, *OUT, "--mc-samples", "-4"], ["--mc-samples"]),
    (["render", S, *OUT, "--mc-seed", "-1"], ["--mc-seed"]),
    (["render", S, *OUT, "--cores", "0"], ["--cores"]),
    (["render", S, *OUT, "--adaptive", "4:2"], ["--adaptive", "maximum 2 < minimum 4"]),
    (["render", S, *OUT, "--kernel", "nxm", "--nxm-points", "5"], ["nxm-points", "square"]),
    (["render", S, *OUT, "--solver", "cg", "--kernel", "disc"], ["needs a reciprocal kernel"]),
    (["render", S], ["--out"]),
    (["preprocess", S, *OUT, "--subscenes", "0"], ["--subscenes"]),
    (["preprocess", S, *OUT, "--workers", "-2"], ["--workers"]),
    (["solve", "RUN", "--tol", "-1"], ["--tol"]),
    (["solve", "RUN", "--max-iterations", "-3"], ["--max-iterations"]),
    (["image", "RUN", "--sigma", "-1"], ["--sigma"]),
    (["study", "accuracy", S, *OUT, "--tols", "1e-3,-1"], ["--tols"]),
    (["study", "accuracy", S, *OUT, "--resolutions", "8,0"], ["--resolutions"]),
    (["study", "seed", S, *OUT, "--max-workers", "0"], ["--max-workers"]),
    (["reference", S, *OUT, "--spp", "0"], ["--spp"]),
    (["reference", S, *OUT, "--passes", "0"], ["--passes"]),
    (["reference", S, *OUT, "--seed", "-1"], ["--seed"]),
    (["reference", S, *OUT, "--resolution", "0"], ["--resolution"]),
    (["viewfactors", S, *OUT, "--accuracy", "-1"], ["--accuracy"]),
    (["viewfactors", S, *OUT, "--accuracy", "nan"], ["--accuracy"]),
    (["viewfactors", S, *OUT, "--cutoff", "-1"], ["--cutoff"]),
    (["viewfactors", S, *OUT, "--workers", "0"], ["--workers"]),
]


@pytest.mark.parametrize("args,fragments", CASES, ids=[" ".join(a[:1] + a[2:]) for a, _ in CASES])
def test_every_numeric_option_is_checked_before_anything_starts(tmp_path, args, fragments):
    args = [str(tmp_path / "out") if a == "OUT" else str(tmp_path / "run") if a == "RUN" else a
            for a in args]
    r = CliRunner().invoke(main, args)
    one_line_error(r, *fragments)
    assert not os.path.exists(tmp_path / "out"), "a refused command made its run directory"


def test_out_that_is_a_file_or_under_a_file(tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    r = CliRunner().invoke(main, ["render", S, "--out", str(f)])
    one_line_error(r, f"--out {f} is a file, not a directory")
    r = CliRunner().invoke(main, ["preprocess", S, "--out", str(f / "sub" / "run")])
    one_line_error(r, f"lies under {f}, which is a file")
    assert f.read_text() == "x"


#: every command that writes into --out, with the rest of a command line that gets that far
OUT_COMMANDS = {
    "render": ["render", S], "preprocess": ["preprocess", S], "reference": ["reference", S],
    "compare": ["compare", "A.exr", "B.exr"], "viewfactors": ["viewfactors", S],
    "study accuracy": ["study", "accuracy", S], "study seed": ["study", "seed", S]}


@pytest.mark.parametrize("command", OUT_COMMANDS)
def test_out_into_a_folder_of_the_users_is_refused_in_one_line(tmp_path, command):
    """--out into a non-empty folder that is not one of ours: refused before anything starts,
    the user's files untouched (it once overwrote their image.png and report.json)."""
    d = tmp_path / "mine"
    d.mkdir()
    (d / "image.png").write_text("the user's")
    r = CliRunner().invoke(main, [*OUT_COMMANDS[command], "--out", str(d)])
    one_line_error(r, f"--out {d} is a folder with other files in it (image.png), not a run "
                      "directory: choose a new or empty folder, or add --force to write into it")
    assert sorted(os.listdir(d)) == ["image.png"] and (d / "image.png").read_text() == "the user's"


def test_force_writes_into_a_folder_of_the_users(tmp_path):
    import numpy as np

    from radiosity.formats.images import write_exr

    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    write_exr(str(a), np.full((4, 4, 3), 1.0, np.float32))
    write_exr(str(b), np.full((4, 4, 3), 2.0, np.float32))
    d = tmp_path / "mine"
    d.mkdir()
    (d / "notes.txt").write_text("the user's")
    r = CliRunner().invoke(main, ["compare", str(a), str(b), "--out", str(d), "--force"])
    assert r.exit_code == 0, r.output
    assert {"notes.txt", "compare.json", "compare.png"} <= set(os.listdir(d))
    r = CliRunner().invoke(main, ["compare", str(a), str(b), "--out", str(d)])  # ours now
    assert r.exit_code == 0, r.output


def test_a_study_folder_is_written_again_without_force(tmp_path):
    """A study's own folder (its summary, or run directories in runs/) is not the user's."""
    from radiosity.cli.studies import _check_study_out

    d = tmp_path / "study"
    (d / "runs" / "r8-kpoint").mkdir(parents=True)
    (d / "runs" / "r8-kpoint" / "report.json").write_text("{}")
    (d / "accuracy.png").write_text("png")
    _check_study_out(str(d), False, "results.md")
    e = tmp_path / "other"
    e.mkdir()
    (e / "results.csv").write_text("the user's")
    from radiosity.errors import StoreError

    with pytest.raises(StoreError, match="or add --force"):
        _check_study_out(str(e), False, "results.md")


# ----------------------------------------------------------------------------- the scene

from helpers import FLOOR_AND_TRIANGLE, write_scene  # noqa: E402

LIGHT = "[material.default]\nreflectance = [0.5, 0.5, 0.5]\nemission = [1.0, 1.0, 1.0]\n"
AWAY = """
[camera]
position = [0.5, 2.0, -1.5]
look_at = [0.5, 4.0, -5.0]
up = [0.0, 1.0, 0.0]
fov_y = 30.0
resolution = [32, 24]
"""


def test_a_camera_that_sees_nothing_is_caught_before_any_cluster(tmp_path):
    path = write_scene(tmp_path, FLOOR_AND_TRIANGLE, LIGHT, camera=AWAY)
    r = CliRunner().invoke(main, ["plan", path])
    one_line_error(r, "the camera sees no element", "check [camera]")
    for cmd in (["render", path, "--out", str(tmp_path / "out")],
                ["preprocess", path, "--out", str(tmp_path / "out")]):
        r = CliRunner().invoke(main, cmd)
        one_line_error(r, "the camera sees no element")
        assert not os.path.exists(tmp_path / "out")  # no half-made run directory


def test_a_scene_without_an_emitter_is_said_up_front(tmp_path):
    path = write_scene(tmp_path, FLOOR_AND_TRIANGLE, "[material.default]\nreflectance = [0.5, 0.5, 0.5]\n")
    r = CliRunner().invoke(main, ["plan", path])
    assert r.exit_code == 0, r.output
    assert "warning:" in r.output and "no element emits light" in r.output and "black" in r.output


def test_a_camera_that_sees_one_small_thing_is_not_refused(tmp_path):
    """The coarse ray grid misses a tiny element; the full raster then finds it."""
    from radiosity.runtime.checks import COARSE_RAYS, check_scene
    from radiosity.settings import resolve
    from radiosity.scene.load import load_scene

    # wound to face the camera (its front towards -z): from behind it would be black, an error
    obj = "v 0.499 0.499 0\nv 0.501 0.499 0\nv 0.5 0.501 0\nf 1 3 2\n"
    cam = """
    [camera]
    position = [0.5, 0.5, -1.0]
    look_at = [0.5, 0.5, 0.0]
    up = [0.0, 1.0, 0.0]
    fov_y = 60.0
    resolution = [600, 600]
    """
    path = write_scene(tmp_path, obj, "[material.default]\nemission = [1.0, 1.0, 1.0]\n"
                                      "reflectance = [0.0, 0.0, 0.0]\n", camera=cam)
    sc = load_scene(path, settings=settings_of())
    assert 600 > COARSE_RAYS
    assert check_scene(sc, resolve())["hits"] >= 1


# ----------------------------------------------------------------------------- meshes

def test_garbage_bytes_in_an_obj_name_the_line(tmp_path):
    path = write_scene(tmp_path, "v 0 0 0\nv 1 0 0\nv 0 1 0\n", LIGHT)
    with open(tmp_path / "mesh.obj", "ab") as f:
        f.write(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\xff\xfe garbage\nf 1 2 3\n")
    r = CliRunner().invoke(main, ["plan", path])
    one_line_error(r, "mesh.obj could not be parsed as OBJ (line 4)")


def test_a_huge_coordinate_is_rejected_up_front(tmp_path):
    import warnings

    from radiosity.errors import SceneError
    from radiosity.scene.load import load_scene

    path = write_scene(tmp_path, "v 0 0 0\nv 1e300 0 0\nv 1 0 1\nv 0 0 1\nf 1 4 3 2\n", LIGHT)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warning, no "non-convex quad" on the way
        with pytest.raises(SceneError, match="face 1 has a vertex coordinate of 1e.300"):
            load_scene(path, settings=settings_of())


def test_plan_dead_rows_add_up_on_coaxial_discs():
    import re

    r = CliRunner().invoke(main, ["plan", scene_path("coaxial-discs"), "--resolution", "8"])
    assert r.exit_code == 0, r.output
    [line] = [ln for ln in r.output.splitlines() if ln.startswith("dead rows")]
    m = re.search(r"(\d+) of (\d+) elements drop out of the iteration \((\d+) emitters that "
                  r"reflect nothing, (\d+) other elements that reflect nothing, (\d+) that no "
                  r"light can reach\)", line)
    assert m, line
    dropped, total, a, b, c = map(int, m.groups())
    assert dropped == a + b + c and total == 128 and dropped > 0


def test_a_command_run_in_process_leaves_dask_config_as_it_found_it():
    """Flags are overrides of the command's own settings, never writes to dask.config: an
    in-process invocation (a test, a notebook) leaves nothing behind for the next command (a
    leaked --nxm-points 5 once failed every later nxm test)."""
    import copy

    import dask.config

    before = copy.deepcopy(dask.config.config.get("radiosity"))
    r = CliRunner().invoke(main, ["render", S, "--out", "unused-dir", "--kernel", "nxm", "--nxm-points", "5",
                                  "--max-iterations", "1"])
    assert r.exit_code == 2 and "nxm-points must be a square" in r.output, r.output
    assert dask.config.config.get("radiosity") == before
