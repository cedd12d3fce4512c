"""benchmarks/bench_real.py's metric and reading of a run's report (issue 50): the per-pixel
error's floor under near-black pixels, the noise correction, the direct mode read
defensively, --only and --resolution."""

from __future__ import annotations

import json
import math
import os
import sys

import numpy as np
import pytest

from helpers import ROOT


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    import bench_real

    return bench_real


def _img(values):
    v = np.asarray(values, float)
    return np.repeat(v[:, None, None] / 3.0, 3, axis=2)  # (n, 1, 3): RGB sum = values


def test_the_floor_keeps_a_near_black_pixel_from_ruling_the_mean(bench):
    """Nine pixels of 1.0 exact, one near-black pixel of 1e-4 shown as 1e-3 (an error nobody
    sees, 900 % of itself): plain, the mean is 90 %; with the floor 5 % of the image's mean
    (0.9 here) the pixel counts 9e-4 / 0.045 = 2 % and the mean 0.2 %. A pixel above the floor
    counts as before."""
    ref = _img([1.0] * 9 + [1e-4])
    ours = _img([1.0] * 9 + [1e-3])
    zero = np.zeros(ref.shape[:2])
    assert bench.rel_error(ours, ref, zero, 0.0) == pytest.approx(0.9, rel=1e-9)
    floor = 0.05 * float(ref.sum(-1).mean())
    assert bench.FLOOR == 0.05
    assert bench.rel_error(ours, ref, zero) == pytest.approx(9e-4 / floor / 10, rel=1e-9)
    bright = _img([1.1] + [1.0] * 8 + [1e-4])
    assert bench.rel_error(bright, ref, zero) == pytest.approx(0.1 / 10, rel=1e-9)
    # pixels the reference does not see are left out; nothing seen: 0
    assert bench.rel_error(_img([5.0, 1.0]), _img([0.0, 1.0]), np.zeros((2, 1)), 0.0) == 0.0
    assert bench.rel_error(_img([1.0]), _img([0.0]), np.zeros((1, 1))) == 0.0


def test_the_noise_correction_uses_the_same_floor(bench, rng):
    """An image equal to the truth, against a reference with normal noise of standard error s:
    the corrected error is about 0 (the noise taken out in quadrature), with and without the
    floor, where the uncorrected mean is about sqrt(2/pi) s / D; an image 3 % off: about 3 %
    of what each pixel is measured against."""
    n = 200_000
    truth = np.where(np.arange(n) % 10 == 0, 0.002, 1.0)  # one pixel in ten near-black
    s = 0.01 * np.ones(n)
    ref = truth + s * rng.standard_normal(n)
    ref = np.maximum(ref, 1e-6)
    for f in (0.0, bench.FLOOR):
        d = np.maximum(ref, f * ref.mean())
        raw = float(np.mean(np.abs(truth - ref) / d))
        got = bench.rel_error(_img(truth), _img(ref), s[:, None], f)
        assert raw > 0.005 and got < 0.15 * raw, (f, raw, got)
        # an image 3 % off: the corrected figure is the noise-free one (the floor under the
        # noise term as under the error: else the near-black pixels' s / B hides it)
        off = truth * 1.03
        exact = float(np.mean(np.abs(off - truth) / np.maximum(truth, f * truth.mean())))
        got = bench.rel_error(_img(off), _img(ref), s[:, None], f)
        if f:
            assert got == pytest.approx(exact, rel=0.1), (f, got, exact)
        else:  # plain: the near-black pixels' noise (s / B = 5) swamps a 3 % error
            assert got < 0.01, got


def test_the_direct_mode_is_read_defensively(bench, tmp_path):
    """report.json's direct light mode, where some section names one: a string, or a dict
    with mode (and reason); none before issue 50."""
    assert bench.direct_mode({"links": 3}) is None
    assert bench.direct_mode({"direct": "points"}) == "points"
    assert bench.direct_mode({"direct": {"mode": "links", "reason": "a furnace"}}) == \
        "links (a furnace)"
    assert bench.direct_mode({"direct_mode": "points"}) == "points"
    assert bench.direct_mode({"direct": 3}) is None
    (tmp_path / "report.json").write_text(json.dumps(
        {"links": {"links": 10, "links_per_leaf": 2.5, "wall_s": 1.0},
         "solve": {"direct": {"mode": "points"}, "time_s": 2.0}, "summary": "text"}))
    fig = bench.report_figures(str(tmp_path))
    assert fig["direct"] == "points" and fig["links"] == 10
    assert fig["stages_s"] == {"links": 1.0, "solve": 2.0}
    assert bench.report_figures(str(tmp_path / "missing")) == {}


def test_resolution_flag(bench):
    import argparse

    assert bench._resolution("64") == (64, 64) and bench._resolution("64x32") == (64, 32)
    for bad in ("x", "0", "64xq"):
        with pytest.raises(argparse.ArgumentTypeError, match="--resolution"):
            bench._resolution(bad)
    assert not math.isnan(bench.FLOOR)
