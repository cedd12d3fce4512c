"""Image comparison (app/compare.py, `radiosity compare`): figures checked against hand-made
images whose errors are known exactly; masks of pixels wholly inside one element."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner


def _pair(rng, h=8, w=12):
    b = rng.uniform(0.5, 2.0, (h, w, 3))
    rel = rng.uniform(-0.2, 0.2, (h, w, 3))
    return b * (1 + rel), b, rel


def test_errors_are_the_relative_errors(rng):
    from radiosity.validation.compare import errors

    a, b, rel = _pair(rng)
    b[0, 0] = 0.0  # undefined there: left out
    fig = errors(a, b)
    keep = np.ones(b.shape, bool)
    keep[0, 0] = False
    assert fig["mare"] == pytest.approx(np.abs(rel[keep]).mean(), rel=1e-12)
    assert fig["max"] == pytest.approx(np.abs(rel[keep]).max(), rel=1e-12)
    assert fig["rms"] == pytest.approx(np.sqrt((rel[keep] ** 2).mean()), rel=1e-12)
    for k, c in enumerate("RGB"):
        assert fig["per_channel"][c] == pytest.approx(np.abs(rel[..., k][keep[..., k]]).mean(), rel=1e-12)
    assert fig["pixels"] == 8 * 12 - 1 and fig["entries"] == 3 * (8 * 12 - 1)
    mask = np.zeros(b.shape[:2], bool)
    mask[2:4, 3:7] = True
    assert errors(a, b, mask)["mare"] == pytest.approx(np.abs(rel[2:4, 3:7]).mean(), rel=1e-12)


def test_noise_floor_is_what_an_exact_image_shows(rng):
    """An exact image against a noisy reference (Gaussian, known standard error): the mean
    absolute relative error converges to the stated floor sqrt(2/pi) mean(se/ref)."""
    from radiosity.validation.compare import errors, noise_floor

    truth = rng.uniform(1.0, 3.0, (200, 200, 3))
    se = 0.01 * truth * rng.uniform(0.5, 1.5, truth.shape)
    ref = truth + se * rng.standard_normal(truth.shape)
    floor = noise_floor(ref, se)
    assert floor == pytest.approx(math.sqrt(2 / math.pi) * np.mean(se / ref), rel=1e-12)
    assert errors(truth, ref)["mare"] == pytest.approx(floor, rel=0.02)


def test_box_down_and_its_standard_error(rng):
    from radiosity.validation.compare import CompareError, box_down, box_down_stderr

    img = rng.uniform(size=(8, 12, 3))
    small = box_down(img, 2, 3)
    assert small[1, 2] == pytest.approx(img[4:8, 8:12].mean(axis=(0, 1)))
    se = rng.uniform(size=(8, 12, 3))
    assert box_down_stderr(se, 2, 3)[0, 0] == pytest.approx(np.sqrt((se[:4, :4] ** 2).sum(axis=(0, 1))) / 16)
    with pytest.raises(CompareError, match="not an integer factor"):
        box_down(img, 3, 3)


def test_interior_keeps_pixels_whose_neighbourhood_is_one_element():
    from radiosity.validation.compare import interior

    r = np.full((6, 7), -1)
    r[0:6, 0:4] = 0
    r[0:6, 4:7] = 1
    r[5, 1] = -1
    m = interior(r)
    expect = np.zeros((6, 7), bool)
    expect[1:5, 1:3] = True  # left of the boundary column 3 | 4
    expect[1:5, 5] = True
    expect[4, 0:3] = False  # next to the hole at (5, 1)
    assert np.array_equal(m, expect)
    assert not interior(np.zeros((2, 9), int)).any()


def test_surface_errors_average_before_comparing(rng):
    from radiosity.validation.compare import surface_errors

    raster = np.zeros((6, 6), int)
    raster[:, 3:] = 1
    b = np.ones((6, 6, 3))
    a = b.copy()
    a[:, :3] *= 1.0 + np.where(np.arange(6)[:, None, None] % 2, 0.1, -0.1)  # +-10 %, mean 0
    a[:, 3:] *= 1.05
    se = np.full(b.shape, 0.02)
    s = surface_errors(a, b, raster, np.ones((6, 6), bool), se)
    assert s[0]["error"] == pytest.approx(0.0, abs=1e-12) and s[0]["pixels"] == 18
    assert s[1]["error"] == pytest.approx(0.05) and s[1]["stderr"] == pytest.approx(0.02 / math.sqrt(18))


def test_compare_command(tmp_path, rng):
    from radiosity.cli.commands import main
    from radiosity.stages.image import write_exr

    a, b, rel = _pair(rng, 16, 16)
    fine = np.repeat(np.repeat(a, 2, axis=0), 2, axis=1)  # A at twice the resolution, same means
    write_exr(str(tmp_path / "a.exr"), fine)
    write_exr(str(tmp_path / "ref.exr"), b)
    se = np.full(b.shape, 0.01, np.float32)
    write_exr(str(tmp_path / "ref-stderr.exr"), se)
    r = CliRunner().invoke(main, ["compare", str(tmp_path / "a.exr"), str(tmp_path / "ref.exr"),
                                  "--out", str(tmp_path / "cmp")])
    assert r.exit_code == 0, r.output
    fig = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    b32 = b.astype(np.float32).astype(float)
    a32 = fine.astype(np.float32).astype(float).reshape(16, 2, 16, 2, 3).mean(axis=(1, 3))
    assert fig["mare"] == pytest.approx(np.mean(np.abs(a32 - b32) / b32), rel=1e-6)
    assert fig["noise_floor"] == pytest.approx(math.sqrt(2 / math.pi) * np.mean(0.01 / b32), rel=1e-5)
    assert "mean abs. relative error" in r.output and "B's own noise" in r.output
    from PIL import Image

    png = np.asarray(Image.open(tmp_path / "cmp" / "compare.png").convert("RGB")).astype(int)
    assert png.shape[0] > 100 and (png[..., 0] - png[..., 2] > 100).any() and (png[..., 2] - png[..., 0] > 100).any()
    write_exr(str(tmp_path / "odd.exr"), np.ones((10, 10, 3)))
    r = CliRunner().invoke(main, ["compare", str(tmp_path / "odd.exr"), str(tmp_path / "ref.exr")])
    assert r.exit_code == 2 and "integer multiple" in r.output and "Traceback" not in r.output
