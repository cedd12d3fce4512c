"""The `radiosity` command end to end, against the session's real LocalCluster."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from radiosity.cli.commands import main
from radiosity.stages.image import read_exr
from helpers import FLOOR_AND_TRIANGLE, ROOT, scene_path, write_scene
from radiosity.settings import options as settings_of

DATA = os.path.join(ROOT, "tests", "data")
# built-in scenes with an exact answer at every pixel: closed, uniform Le = 1 and rho = 0.5, so
# with the rows balanced to 1 (closure auto: closed) L = Le / (1 - rho) = 2 exactly
EXACT = {"furnace-cube": 2.0, "furnace-sphere": 2.0}

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


def test_a_hierarchical_render_says_when_its_final_gather_and_outputs_run(client, tmp_path):
    """The stages after the solve's passes, a minute or more on large scenes, have their
    started and done lines where stderr is no terminal."""
    r = CliRunner().invoke(main, ["render", scene_path("cornell-box"), "--out", str(tmp_path / "r"),
                                  "--resolution", "16", "--method", "hierarchical",
                                  "--scheduler", client.scheduler.address])
    assert r.exit_code == 0, r.output
    out = r.output
    for stage in ("solve (cg)", "final gather", "outputs"):
        assert f"{stage}: started" in out and f"{stage}: done" in out, out
    assert out.index("final gather: done") < out.index("outputs: started")


@pytest.mark.parametrize("name", BUILTIN)
def test_render_end_to_end_on_every_builtin_scene(client, tmp_path, name):
    """Every output file, and the image: the exact answer where the scene has one (furnaces),
    otherwise the stored coarse reference tests/data/render16-<scene>.npy (made by
    tests/data/make_references.py with this very command)."""
    out = tmp_path / "run"
    # --tol 1e-6: the tolerance the stored references were made with (the default is 1e-5)
    r = CliRunner().invoke(main, ["render", scene_path(name), "--out", str(out), "--resolution", "16",
                                  "--tol", "1e-6", "--preview", "--scheduler", client.scheduler.address])
    assert r.exit_code == 0, r.output
    for f in ("image.exr", "image.png", "preview.png", "mesh.glb", "mesh.ply", "viewer.html", "report.json"):
        assert (out / f).stat().st_size > 0, f
    rep = json.loads((out / "report.json").read_text())
    stage = {"pairs": "visibility", "hierarchical": "links"}[rep["plan"]["method"]]
    for section in ("preprocess", stage, "solve", "render"):
        assert section in rep
    # one started and one done line per stage (stderr is no terminal here), the outputs too
    assert "outputs: started" in r.output and "outputs: done" in r.output, r.output
    assert rep["solve"]["converged"] and rep["solve"]["final_residual"] <= 1e-6
    assert "workers" in rep["render"]["stages"]["peak_rss_mb"]
    img = read_exr(str(out / "image.exr"))
    if name in EXACT:
        seen = img.sum(-1) > 0
        assert seen.mean() > 0.9  # the camera is inside: nearly every pixel sees a wall
        # solver tolerance 1e-6 (relative residual); the balanced rows make 2 the exact discrete
        # answer, so what is left is the iteration's error, a few times the tolerance
        np.testing.assert_allclose(img[seen], EXACT[name], rtol=1e-5)
    else:
        ref = np.load(os.path.join(DATA, f"render16-{name}.npy"))
        assert img.shape == ref.shape
        # the run is deterministic (the same bits, the same CG iterates; reruns agree to 1e-12 on
        # this machine). Margins: 1e-5 on the image's mean (ten times the solver's tolerance:
        # any change of the answer shows there); 1e-3 per pixel, for a ray that another CPU's
        # Embree rounds the other way (one pair of sub-elements more or less in the shadow)
        assert img.mean() == pytest.approx(float(ref.mean()), rel=1e-5)
        np.testing.assert_allclose(img, ref, rtol=1e-3, atol=1e-3 * float(ref.max()))


def test_coaxial_discs_through_the_pipeline_against_the_exact_form_factor(client, tmp_path):
    """The real coaxial-discs scene (two 64-gons as triangle fans; F = 0.381691 between the
    polygons by the contour integral): `radiosity render` with every effect on (the receiver
    reflects nothing, so the plan would skip visibility), then the form factor of the run's
    operator (default kernel, point-nf) against the exact value. The fans' triangles are slivers
    (length 1, width 0.1) that the camera splits slowly, so the error falls slowly: measured
    +6.0 % at 8^2, +5.27 % at 16^2 (+3.8 % at 32^2, +0.97 % at 64^2). Deterministic (no
    occluder): the figure to 1e-3, and smaller than at 8^2."""
    from radiosity.scene.load import load_scene
    from radiosity.validation.study import form_factor_of_run

    val = load_scene(scene_path("coaxial-discs"), settings=settings_of()).validation
    errs = []
    for res in (8, 16):
        out = tmp_path / f"r{res}"
        r = CliRunner().invoke(main, ["render", scene_path("coaxial-discs"), "--out", str(out), "--resolution",
                                      str(res), "--full", "--no-preview", "--scheduler", client.scheduler.address])
        assert r.exit_code == 0, r.output
        f = form_factor_of_run(str(out), client, "point-nf", val["from"], val["to"],
                               settings=settings_of())
        errs.append(f / val["form_factor"] - 1)
    print(f"coaxial discs: F error {errs}")
    assert errs[1] == pytest.approx(0.0527, abs=1e-3) and errs[1] < errs[0]
    # the emitter shows Le = 1 exactly where it fills a pixel, a share of it on its rim (each
    # pixel the mean over its area); the receiver (rho = 0) is black
    img = read_exr(str(out / "image.exr"))
    lit = img[..., 0] > 0
    assert lit.any() and np.all(img[lit] <= 1.0) and (img[lit] == 1.0).sum() >= 0.25 * lit.sum()


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
    assert r.exit_code == 0 and "cg (point-nf kernel, pairs method)" in r.output and "converged" in r.output
    r = CliRunner().invoke(main, ["image", str(out), "--filter", "gaussian", "--exposure", "2"])
    assert r.exit_code == 0 and "exposure 2" in r.output
    r = CliRunner().invoke(main, ["solve", str(out), "--solver", "cg", "--kernel", "disc"] + sched)
    assert r.exit_code == 2 and "needs a reciprocal kernel" in r.output


def test_cluster_flags_reach_open_client_not_the_config(tmp_path, monkeypatch):
    """--tls and the batch-job flags reach open_client as its keywords (no flag writes
    dask.config); a local TLS run works end to end; the process's config is untouched."""
    import copy

    import dask.config

    from radiosity.runtime import cluster

    seen = {}
    real = cluster.open_client

    def spy(*a, **kw):
        seen.update({k: kw[k] for k in ("tls", "cores", "account") if k in kw})
        return real(*a, **kw)

    monkeypatch.setattr(cluster, "open_client", spy)
    before = copy.deepcopy({k: dask.config.config.get(k) for k in ("radiosity", "jobqueue")})
    r = CliRunner().invoke(main, ["preprocess", scene_path("three-rectangles"), "--out", str(tmp_path / "r"),
                                  "--resolution", "8", "--workers", "1", "--tls", "--cores", "4",
                                  "--account", "proj1"])
    assert r.exit_code == 0, r.output
    assert seen == {"tls": "temporary", "cores": 4, "account": "proj1"}
    assert "only apply to batch-system clusters" in r.output  # said, not silently dropped
    assert {k: dask.config.config.get(k) for k in ("radiosity", "jobqueue")} == before


@pytest.mark.parametrize("change", ["toml", "mesh"])
def test_render_resume_refuses_a_run_whose_scene_changed(client, tmp_path, change):
    """`render --resume` reuses a partition only for the same scene: same scene file contents
    and the same meshes, not only the same path, camera and sub-pixel factor. After a material
    (TOML) or a vertex (mesh file) changes, the run is made again and shows the change."""
    import shutil

    src = os.path.dirname(scene_path("three-rectangles"))
    d = tmp_path / "scene"
    shutil.copytree(src, d)
    toml, obj = d / "scene.toml", d / "three-rectangles.obj"
    out = tmp_path / "run"
    cmd = ["render", str(toml), "--out", str(out), "--resolution", "12", "--no-preview",
           "--scheduler", client.scheduler.address]
    r = CliRunner().invoke(main, cmd)
    assert r.exit_code == 0, r.output
    before = read_exr(str(out / "image.exr"))
    r = CliRunner().invoke(main, cmd + ["--resume"])  # unchanged: reused
    assert r.exit_code == 0 and "reusing the partition" in r.output
    if change == "toml":  # the screen reflects less
        toml.write_text(toml.read_text().replace("reflectance = [0.7, 0.7, 0.7]", "reflectance = [0.35, 0.35, 0.35]"))
    else:  # the occluder moves up by 0.3 (its vertices are the only ones at y = 1)
        obj.write_text(obj.read_text().replace(" 1.0 ", " 1.3 "))
    r = CliRunner().invoke(main, cmd + ["--resume"])
    assert r.exit_code == 0, r.output
    assert "reusing the partition" not in r.output
    rep = json.loads((out / "report.json").read_text())
    assert rep["visibility"]["tasks_reused"] == 0
    after = read_exr(str(out / "image.exr"))
    assert np.abs(after - before).max() > 0.01 * before.max()
    # and what the fresh run computed is what a new directory gives
    r = CliRunner().invoke(main, cmd[:3] + [str(tmp_path / "fresh")] + cmd[4:])
    assert r.exit_code == 0, r.output
    np.testing.assert_allclose(after, read_exr(str(tmp_path / "fresh" / "image.exr")), rtol=1e-9, atol=0)
