"""Ground truth from Mitsuba 3 (app/reference.py): the conventions the conversion must keep,
checked with the real Mitsuba at low sample counts.

- pixel rays: Mitsuba's perspective sensor casts the engine's rays (camera.pixel_directions) to
  1e-6, for the look-at form, a right-handed seed-form basis and a non-square image;
- exact answers within 3 standard errors: the furnace (L = Le / (1 - rho) = 2, less the stated
  truncation 2 * 0.5^20), the opposed unit squares (F = 0.19982, Howell C-11, measured with
  irradiance meters);
- two-sided emission and reflectance: a two-sided lamp seen and lighting from its back side
  equals the one-sided lamp facing that way;
- the Cornell box against the engine's radiosity image, per wall (pixels wholly inside one
  original element). Combined error stated: for each wall with at least 20 interior pixels,
  |radiosity / Mitsuba - 1| <= 3 sigma + 5 % (sigma: Mitsuba's relative standard error of the
  wall's mean; 5 %: the engine's own error at 32 x 32, point kernel, which measured up to 3.2 %
  on those walls against 2048 spp); and the pixel-weighted mean of the signed differences
  within 3 sigma + 1.5 % (measured 0.3 %). A flipped image, a wrong side, a swapped channel or a
  factor pi break these by far more.

When Mitsuba is missing these tests skip and say why, except in CI (CI set), where they fail.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from helpers import ROOT, scene_path, write_scene
from radiosity.settings import options as settings_of


@pytest.fixture(scope="module")
def mitsuba():
    """(mitsuba module, variant); skips without Mitsuba, but fails in CI (CI set)."""
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        msg = "Mitsuba 3 is not installed: pip install -e '.[reference]' (or '.[test]')"
        if os.environ.get("CI"):
            pytest.fail(f"{msg}; CI must run the Mitsuba tests")
        pytest.skip(msg)
    from radiosity.validation.reference import load_mitsuba

    return load_mitsuba(echo=print)


def _scene(name, res=None):
    import warnings

    from radiosity.scene.load import load_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_scene(scene_path(name) if "/" not in name else name, resolution=res,
                          settings=settings_of())


def _render(mitsuba, sc, spp, passes, seed=0):
    from radiosity.validation.reference import mitsuba_scene, path_depth, render_passes

    mi, _ = mitsuba
    msc, _ = mitsuba_scene(sc, path_depth(sc, settings_of().reference.truncation)[0], mi=mi)
    m, se, _ = render_passes(mi, msc, spp, passes, seed=seed,
                             max_samples=settings_of().reference.max_samples_per_call)
    return m, se


# ----------------------------------------------------------------------------- the camera

SEED_CAMERA = """
[camera]
center = [-1.5, 0.6, 0.5]
x = [0.0, 0.0, -1.0]
y = [0.0, 1.0, 0.0]
z = [1.0, 0.0, 0.0]
focal_distance = 1.3
resolution = [20, 20]
"""


def _camera_scenes(tmp_path):
    from helpers import FLOOR_AND_TRIANGLE

    seed = write_scene(tmp_path, FLOOR_AND_TRIANGLE, camera=SEED_CAMERA, name="seed.toml")
    return [_scene("cornell-box", (24, 16)), _scene("furnace-cube", 12), _scene(seed)]


def test_pixel_rays_agree_with_the_engine(mitsuba, tmp_path):
    from radiosity.core.camera import pixel_directions
    from radiosity.validation.reference import mitsuba_scene

    mi, variant = mitsuba
    scenes = _camera_scenes(tmp_path)
    cam = scenes[2].camera
    assert np.linalg.det(np.stack([cam.x, cam.y, cam.z])) > 0  # the other handedness
    for sc in scenes:
        msc, _ = mitsuba_scene(sc, 1, mi=mi)
        sensor = msc.sensors()[0]
        W, H = sc.camera.width, sc.camera.height
        assert tuple(int(v) for v in sensor.film().size()) == (W, H)
        rows, cols = np.mgrid[0:H, 0:W]
        u = ((cols + 0.5) / W).ravel().astype(np.float32)
        v = ((rows + 0.5) / H).ravel().astype(np.float32)
        d, o = [], []
        if variant == "scalar_rgb":
            for a, b in zip(u, v):
                ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(a, b), mi.Point2f(0.5))
                d.append(np.array(ray.d))
                o.append(np.array(ray.o))
            d, o = np.array(d), np.array(o)
        else:
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(u, v), mi.Point2f(0.5, 0.5))
            d, o = np.array(ray.d).T, np.array(ray.o).T
        err = np.abs(d - pixel_directions(sc.camera)).max()
        assert err < 1e-6, (sc.name, err)
        size = np.ptp(sc.elements.verts.reshape(-1, 3), axis=0).max()
        assert np.abs(o - sc.camera.center).max() < 1e-5 * size  # near clip 1e-6 of the extent


def test_non_square_pixels_are_refused(mitsuba, tmp_path):
    from radiosity.validation.reference import ReferenceError, sensor_dict
    from helpers import FLOOR_AND_TRIANGLE

    p = write_scene(tmp_path, FLOOR_AND_TRIANGLE, camera=SEED_CAMERA.replace("[20, 20]", "[32, 16]"))
    with pytest.raises(ReferenceError, match="pixels are not square"):
        sensor_dict(_scene(p))


def test_path_depth_bounds_the_truncation():
    from radiosity.validation.reference import path_depth

    d, rho = path_depth(_scene("cornell-box", 8), settings_of().reference.truncation)
    assert rho == 0.78 and d == 56 and 0.78 ** d <= 1e-6 < 0.78 ** (d - 1)
    d, rho = path_depth(_scene("furnace-cube", 8), settings_of().reference.truncation)
    assert (d, rho) == (20, 0.5)
    assert path_depth(_scene("parallel-squares", 8), settings_of().reference.truncation) == (1, 0.0)


# ----------------------------------------------------------------------------- shapes

def test_shape_groups_are_the_materials_and_a_meter_stands_alone():
    from radiosity.validation.reference import shape_groups

    sc = _scene("cornell-box", 8)
    el = sc.elements
    groups = shape_groups(sc)
    assert len(groups) == len(set(el.material.tolist())) == len(el.material_names)
    assert sorted(np.concatenate(groups).tolist()) == list(range(len(el)))
    for g in groups:  # one material, one set of properties a shape
        assert len(set(el.material[g].tolist())) == 1
        assert np.ptp(el.reflectance[g], axis=0).max() == 0 and np.ptp(el.emission[g], axis=0).max() == 0
    white = groups[0]
    metered = shape_groups(sc, meters=[int(white[1])])
    assert len(metered) == len(groups) + 1 and [int(white[1])] in [g.tolist() for g in metered]
    assert len(shape_groups(sc, per_element=True)) == len(el)


def test_one_shape_per_material_renders_as_one_shape_per_element(mitsuba):
    """The grouped export (one Mitsuba shape per material) is the same scene as the one shape
    per element it replaced: with the same seed every pixel agrees within 5 standard errors of
    the difference, and the image means within 3 (both are independent estimates where the
    sample sequences part)."""
    from radiosity.validation.reference import mitsuba_scene, path_depth, render_passes

    mi, _ = mitsuba
    sc = _scene("cornell-box", 24)
    D = path_depth(sc, settings_of().reference.truncation)[0]
    out = []
    for per_element in (False, True):
        msc, _ = mitsuba_scene(sc, D, mi=mi, per_element=per_element)
        out.append((len(msc.shapes()), *render_passes(mi, msc, 64, 4, seed=3,
                                                   max_samples=settings_of().reference.max_samples_per_call)[:2]))
    (n_mat, a, sa), (n_el, b, sb) = out
    assert (n_mat, n_el) == (len(sc.elements.material_names), len(sc.elements)) == (4, 20)
    sd = np.sqrt(sa ** 2 + sb ** 2)
    assert np.all(np.abs(a - b) <= 5 * sd + 1e-6)
    n = a[..., 0].size
    assert np.all(np.abs(a.mean(axis=(0, 1)) - b.mean(axis=(0, 1)))
                  <= 3 * np.sqrt((sd ** 2).sum(axis=(0, 1))) / n + 1e-9)
    assert a.mean() > 0.01  # a lit image, not two black ones


# ----------------------------------------------------------------------------- exact answers

def test_furnace_converges_to_le_over_one_minus_rho(mitsuba):
    sc = _scene("furnace-cube", 16)
    m, se = _render(mitsuba, sc, 64, 8)
    exact = 2.0 * (1.0 - 0.5 ** 20)  # the truncated series: 2 to 1e-6
    n = m[..., 0].size
    for c in range(3):
        mean, sigma = m[..., c].mean(), math.sqrt((se[..., c] ** 2).sum()) / n
        assert abs(mean - exact) < 3 * sigma, (c, mean, sigma)
        assert sigma < 2e-3  # the test can tell 0.3 % apart
    z = (m - exact) / se
    assert np.mean(np.abs(z) > 5) < 0.01  # no pixel far off (t with 7 d.o.f.: 0.2 % beyond 5)


def test_parallel_squares_form_factor(mitsuba):
    from radiosity.validation.reference import form_factor

    sc = _scene("parallel-squares")
    exact = sc.validation["form_factor"]
    f, se = form_factor(sc, sc.validation["from"], sc.validation["to"], 2 ** 19, 32,
                        settings=settings_of())  # t with 31 d.o.f.
    assert abs(f - exact) < 3 * se and se < 0.003 * exact, (f, se, exact)


# ----------------------------------------------------------------------------- two-sided elements

LAMP = """
v 0 0 0
v 1 0 0
v 1 0 1
v 0 0 1
v 0.2 0.5 0.2
v 0.8 0.5 0.2
v 0.8 0.5 0.8
v 0.2 0.5 0.8
usemtl floor
f 1 4 3 2
usemtl lamp
f {lamp}
"""
LAMP_CAMERA = """
[camera]
position = [0.5, 0.25, -1.5]
look_at = [0.5, 0.25, 0.5]
up = [0.0, 1.0, 0.0]
fov_y = 50.0
resolution = [32, 24]
"""


def test_two_sided_lamp_from_behind_equals_the_one_sided_lamp(mitsuba, tmp_path):
    """The floor and the camera see the lamp's downward side. Two-sided lamp facing up: that is
    its back (back_emission, back_reflectance); one-sided lamp facing down: its front, with the
    same values. Same image within the noise."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    two = write_scene(tmp_path / "a", LAMP.format(lamp="5 8 7 6"), """
        [material.floor]
        reflectance = [0.5, 0.5, 0.5]
        [material.lamp]
        two_sided = true
        reflectance = [0.1, 0.6, 0.2]
        emission = [4.0, 5.0, 6.0]
        back_reflectance = [0.6, 0.4, 0.2]
        back_emission = [0.5, 1.0, 1.5]
        """, camera=LAMP_CAMERA)
    one = write_scene(tmp_path / "b", LAMP.format(lamp="5 6 7 8"), """
        [material.floor]
        reflectance = [0.5, 0.5, 0.5]
        [material.lamp]
        reflectance = [0.6, 0.4, 0.2]
        emission = [0.5, 1.0, 1.5]
        """, camera=LAMP_CAMERA)
    sa, sb = _scene(two), _scene(one)
    assert sa.elements.two_sided[1] and sa.elements.normal[1, 1] > 0 > sb.elements.normal[1, 1]
    (a, ea), (b, eb) = _render(mitsuba, sa, 512, 8, seed=1), _render(mitsuba, sb, 512, 8, seed=2)
    assert b.mean() > 0.01
    n = a[..., 0].size
    for c in range(3):
        sigma = math.sqrt((ea[..., c] ** 2 + eb[..., c] ** 2).sum()) / n
        assert abs(a[..., c].mean() - b[..., c].mean()) < 3 * sigma, c
    lit = (eb > 0) & (ea > 0)
    z = (a - b)[lit] / np.sqrt(ea ** 2 + eb ** 2)[lit]
    assert np.mean(z ** 2) < 2.0  # about 1 for independent estimates that agree


# ----------------------------------------------------------------------------- against the engine

def test_cornell_box_walls_agree_with_radiosity(mitsuba, client, tmp_path):
    import warnings

    from radiosity.validation.compare import element_raster, interior
    from radiosity.pipeline import render_scene
    from radiosity.stages.image import read_exr

    sc = _scene("cornell-box", 32)
    import dask.config

    # the conditions the 5 % margin was measured under: the point kernel and the seed's rule
    # for unseen elements. With the pairs method element 19 (the tall block's front face) comes
    # out 5-9 % darker than Mitsuba: a floor sub-element no pixel hits is lost to it whole
    # (test_hidden_sub_elements_are_split_on_demand_so_the_tall_block_face_is_right)
    with warnings.catch_warnings(), dask.config.set({"radiosity.subdivide.unseen": "keep"}):
        warnings.simplefilter("ignore")
        render_scene(sc, str(tmp_path / "run"), client, settings_of(subpixel=1, kernel="point"),
                     preview=False, progress=False, echo=lambda *a: None)
    img = read_exr(str(tmp_path / "run" / "image.exr")).astype(float)
    m, se = _render(mitsuba, sc, 512, 8)
    raster = element_raster(sc)
    mask = interior(raster)
    walls, diffs, weights, var = 0, [], [], []
    for e in np.unique(raster[mask]):
        sel = mask & (raster == e)
        n = int(sel.sum())
        if n < 20:
            continue
        a, b = img[sel].mean(axis=0), m[sel].mean(axis=0)
        sigma = np.sqrt((se[sel] ** 2).sum(axis=0)) / n / b
        rel = a / b - 1.0
        assert np.all(np.abs(rel) <= 3 * sigma + 0.05), (sc.elements.describe(e), rel, sigma)
        walls += 1
        diffs.append(rel)
        weights.append(n)
        var.append(sigma ** 2)
    assert walls >= 6  # floor, ceiling, back, both side walls, block faces
    w = np.array(weights, float) / sum(weights)
    mean = (w[:, None] * np.array(diffs)).sum(axis=0)
    sigma = np.sqrt((w[:, None] ** 2 * np.array(var)).sum(axis=0))
    assert np.all(np.abs(mean) <= 3 * sigma + 0.015), (mean, sigma)


# ----------------------------------------------------------------------------- the command

def test_reference_command(mitsuba, tmp_path):
    from radiosity.cli.commands import main
    from radiosity.stages.image import read_exr

    out = tmp_path / "ref"
    r = CliRunner().invoke(main, ["reference", scene_path("furnace-cube"), "--out", str(out),
                                  "--resolution", "8", "--spp", "32", "--passes", "4"])
    assert r.exit_code == 0, r.output
    assert r.output.count("  pass ") == 4 and "relative std. error" in r.output
    fig = json.loads((out / "reference.json").read_text())
    mean, se = read_exr(str(out / "reference.exr")), read_exr(str(out / "reference-stderr.exr"))
    assert mean.shape == se.shape == (8, 8, 3)
    assert (fig["spp"], fig["passes"], fig["max_depth"], fig["variant"]) == (32, 4, 20, mitsuba[1])
    rel = (se / mean).ravel()
    assert fig["rel_stderr_median"] == pytest.approx(np.median(rel), rel=1e-5)
    assert fig["rel_stderr_p99"] == pytest.approx(np.percentile(rel, 99), rel=1e-5)
    assert abs(mean.mean() - 2.0) < 0.1 and fig["time_s"] > 0 and fig["mitsuba_version"]
    r = CliRunner().invoke(main, ["reference", scene_path("furnace-cube"), "--out", str(out),
                                  "--spp", "2", "--passes", "4"])
    assert r.exit_code == 2 and "error: --spp 2 is fewer than --passes 4" in r.output


def test_without_llvm_it_falls_back_to_scalar_and_says_so(mitsuba, tmp_path):
    out = tmp_path / "ref"
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=str(tmp_path / "no-such-libLLVM.so"))
    r = subprocess.run([sys.executable, "-m", "radiosity.cli", "reference", scene_path("furnace-cube"),
                        "--out", str(out), "--resolution", "4", "--spp", "2", "--passes", "2"],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "using scalar_rgb" in r.stdout
    assert json.loads((out / "reference.json").read_text())["variant"] == "scalar_rgb"


def test_without_mitsuba_the_command_says_how_to_install(monkeypatch, tmp_path):
    from radiosity.validation import reference
    from radiosity.cli.commands import main

    monkeypatch.setattr(reference, "_LOADED", {})
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # import mitsuba raises ImportError
    r = CliRunner().invoke(main, ["reference", scene_path("furnace-cube"), "--out", str(tmp_path),
                                  "--resolution", "4", "--spp", "4", "--passes", "2"])
    assert r.exit_code == 2 and "pip install -e '.[reference]'" in r.output
    assert "Traceback" not in r.output


def test_find_libllvm_takes_the_newest_recent_one(monkeypatch, tmp_path):
    from radiosity.validation import reference

    for name in ("libLLVM-14.so.1", "libLLVM-15.so", "libLLVM.so.19.1", "libLLVM-17.so", "libLLVMCore.a"):
        (tmp_path / name).write_bytes(b"")
    monkeypatch.setattr(reference, "_LLVM_GLOBS", (str(tmp_path),))
    assert reference.find_libllvm() == str(tmp_path / "libLLVM.so.19.1")
    assert reference.find_libllvm(20) is None


# ----------------------------------------------------------------------------- the accuracy study

def test_study_accuracy_against_mitsuba(mitsuba, client, tmp_path):
    import csv

    from radiosity.cli.commands import main
    from radiosity.validation.compare import element_raster, errors, interior
    from radiosity.stages.image import read_exr
    from radiosity.validation.study import accuracy, image_error

    out = tmp_path / "st"
    args = ["study", "accuracy", scene_path("cornell-box"), "--out", str(out), "--resolutions", "12,24",
            "--kernels", "point", "--reference", "auto", "--reference-spp", "256",
            "--path-tracer-spp", "1,16", "--scheduler", client.scheduler.address]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    pt = [x for x in rows if x["kernel"] == "path tracer"]
    rad = [x for x in rows if x["kernel"] == "point"]
    assert len(rad) == 2 and [(int(x["resolution"]), int(x["spp"])) for x in pt] == [(12, 1), (12, 16), (24, 1), (24, 16)]
    assert all(float(x["error"]) > 0 and float(x["noise_floor"]) > 0 and float(x["time_total_s"]) > 0
               and float(x["error_surface"]) > 0 for x in rows)
    for lo, hi in (pt[0:2], pt[2:4]):  # 16x the samples: ~1/4 the noise
        assert float(hi["error"]) < 0.5 * float(lo["error"])
    # the reference at 16 x 16, and 8 x 8 box-filtered from it; one row recomputed by hand
    ref = read_exr(str(out / "reference" / "r24" / "reference.exr"))
    assert json.loads((out / "reference" / "r24" / "reference.json").read_text())["spp"] == 256
    assert not (out / "reference" / "r12").exists()
    sc = _scene("cornell-box", 12)
    img = read_exr(str(out / "runs" / "r12-k1" / "image.exr"))
    small = ref.astype(float).reshape(12, 2, 12, 2, 3).mean(axis=(1, 3))
    want = errors(img, small, interior(element_raster(sc)))["mare"]
    assert float(rad[0]["error"]) == pytest.approx(want, rel=1e-6)
    assert (out / "accuracy.png").stat().st_size > 10_000 and (out / "surfaces.csv").stat().st_size > 100
    md = (out / "results.md").read_text()
    assert "path tracer, 16 spp" in md and "reference's own noise" in md
    # a second study reuses the reference (same scene file, camera, spp and passes)
    from radiosity.validation.reference import reference_at

    said = []
    again, _, fig = reference_at(_scene("cornell-box", 24), str(out / "reference" / "r24"), 256, 8,
                                 said.append, settings=settings_of())
    assert "reusing the reference" in said[0] and np.array_equal(again, ref) and fig["spp"] == 256
    # a user's EXR keeps its meaning: relative RMS difference of the images
    rows = accuracy(scene_path("cornell-box"), str(tmp_path / "st2"), client, [8], [1], ["point"],
                    [1e-6], reference=str(out / "reference" / "r24" / "reference.exr"),
                    echo=lambda *a: None, settings=settings_of())
    img2 = read_exr(str(tmp_path / "st2" / "runs" / "r8-k1" / "image.exr"))
    assert rows[0]["error"] == pytest.approx(image_error(img2, ref), rel=1e-9)
    # validation scenes have their exact answer
    r = CliRunner().invoke(main, ["study", "accuracy", scene_path("parallel-squares"), "--out",
                                  str(tmp_path / "st3"), "--reference", "auto", "--scheduler",
                                  client.scheduler.address])
    assert r.exit_code == 2 and "[validation]" in r.output


def test_render_calls_split_into_equal_chunks():
    from radiosity.validation.reference import _chunks

    assert _chunks(32, 128 * 128, 4_194_304) == [32]
    assert _chunks(2048, 64 * 64, 4_194_304) == [1024, 1024]
    assert _chunks(3, 10, 15) == [1, 1, 1]
    assert _chunks(7, 1, 1) == [1] * 7
    for spp, px, cap in ((2048, 4096, 1 << 22), (96, 1000, 20_000), (5, 10, 25)):
        c = _chunks(spp, px, cap)
        assert sum(c) == spp and len(set(c)) == 1 and (c[0] * px <= cap or c[0] == 1)


def test_hidden_sub_elements_are_split_on_demand_so_the_tall_block_face_is_right(mitsuba, client,
                                                                                  tmp_path):
    """The Cornell box's tall block front face (element 19) is lit by the floor between the
    blocks. The camera leaves a large floor sub-element there that no pixel hits (behind the
    short block), its centroid under the short block: one centroid ray loses it whole to the
    face. With hierarchy.split-hidden (the default) such sub-elements are split on demand like
    unseen originals, and the face agrees with Mitsuba; without, it comes out about 5 % dark.
    (subdivide.hidden: keep here, the camera's partition alone: the preprocessing's rule for
    such sub-elements, on by default, takes it to -2.0 % without split-hidden, measured; it is
    tested in tests/scene/test_hidden.py.)"""
    import dask.config

    from radiosity.validation.compare import element_raster, interior
    from radiosity.pipeline import render_scene
    from radiosity.stages.image import read_exr

    sc = _scene("cornell-box", 64)  # measured: -1.2 % with, -5.3 % without (48^2: -1.1, -3.8)
    m, se = _render(mitsuba, sc, 512, 4)
    sel = interior(element_raster(sc)) & (element_raster(sc) == 19)
    assert sel.sum() >= 100
    b = m[sel].mean(axis=0)
    sigma = np.sqrt((se[sel] ** 2).sum(axis=0)) / sel.sum() / b
    rel = {}
    for hidden in (True, False):
        out = tmp_path / f"run-{hidden}"
        with dask.config.set({"radiosity.hierarchy.split-hidden": hidden,
                              "radiosity.subdivide.hidden": "keep"}):
            rep = render_scene(sc, str(out), client, settings_of(method="hierarchical"),
                               preview=False, progress=False, echo=lambda *a: None)
        rel[hidden] = read_exr(str(out / "image.exr")).astype(float)[sel].mean(axis=0) / b - 1.0
        if hidden:  # some floor sub-elements were split below the camera's partition
            assert rep["links"]["split_off_nodes"] > 0
    assert np.all(np.abs(rel[True]) <= 3 * sigma + 0.025), (rel, sigma)
    assert np.all(rel[False] < -0.035), rel  # the check can tell


def test_cornell_box_inside_with_no_options_against_mitsuba(mitsuba, client, tmp_path):
    """scenes/cornell-box-inside (the light out of view) at 48^2 with no options (hierarchical:
    3 623 sub-elements) against Mitsuba: overall level within 1.5 % and the mean error over the
    pixels wholly inside one element within 2 % (measured: -0.7 % and 1.4 %; the pairs method
    with the light pre-split 16 x 16 in the mesh: -1.7 % and 2.4 %); the seed's method and rule
    (pairs, unseen elements kept whole) is off by more than 3.5 % there (measured 4.2 %)."""
    import dask.config

    from radiosity.validation.compare import element_raster, interior
    from radiosity.pipeline import render_scene
    from radiosity.stages.image import read_exr

    lum = np.array([0.2126, 0.7152, 0.0722])
    sc = _scene("cornell-box-inside", 48)
    m, se = _render(mitsuba, sc, 4096, 4)  # its noise adds about 0.5 % to the mean error
    M = m.astype(float) @ lum
    sel = interior(element_raster(sc)) & (M > 0)
    assert sel.sum() > 1000
    err = {}
    for name, cfg in (("default", {}), ("seed", {"radiosity.visibility.method": "pairs",
                                                 "radiosity.subdivide.unseen": "keep",
                                                 "radiosity.subdivide.hidden": "keep"})):
        with dask.config.set(cfg):
            rep = render_scene(sc, str(tmp_path / name), client, settings_of(), preview=False,
                               progress=False, echo=lambda *a: None)
        img = read_exr(str(tmp_path / name / "image.exr")).astype(float) @ lum
        err[name] = (img[sel].mean() / M[sel].mean() - 1, np.abs(img[sel] / M[sel] - 1).mean())
        if name == "default":
            assert rep["plan"]["method"] == "hierarchical"
    assert abs(err["default"][0]) < 0.015 and err["default"][1] < 0.02, err
    assert err["seed"][1] > 0.035, err
