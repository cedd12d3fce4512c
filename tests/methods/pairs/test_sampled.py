"""The sampled kernels (nxm, mc): sample points, visibility per sample pair with partly visible
pairs stored as fractions, against a brute force; reciprocity, solvers, resume, errors."""

from __future__ import annotations

import json

import dask.config
import numpy as np
import pytest
from click.testing import CliRunner

import naive
from radiosity.cli.commands import main
from radiosity.errors import RadiosityError, StoreError
from radiosity.core.kernels import Sampling, sample_points
from radiosity.settings import resolve, sampling_of
from radiosity.methods.pairs.transport import open_operator
from radiosity.stages.solve import run_solve
from radiosity.runtime.store import RunStore
from radiosity.methods.pairs.store import VisibilityStore, read_partial
from radiosity.methods.pairs.visibility import compute_visibility
from helpers import prepared, scene_path
from radiosity.settings import options as settings_of


def _polys(rng):
    """Triangles, parallelograms and a general planar quad (m, 4, 3), nverts."""
    v = np.zeros((5, 4, 3))
    v[0, :3] = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    v[1, :3] = rng.random((3, 3))
    v[2] = [[0, 0, 0], [2, 0, 0], [2.5, 1, 0], [0.5, 1, 0]]          # parallelogram
    v[3] = [[0, 0, 1], [1, 0, 1], [1, 3, 1], [0, 3, 1]]               # rectangle
    v[4] = [[0, 0, 0], [3, 0, 0], [2, 1, 0], [0, 2, 0]]               # general (planar) quad
    v[:2, 3] = v[:2, 2]  # geometry.py: a triangle repeats vertex 2 in slot 3
    return v, np.array([3, 3, 4, 4, 4])


def _inside(p, verts, nv):
    """Is p (S, 3) inside the convex planar polygon (up to rounding)?"""
    poly = verts[:nv]
    n = np.cross(poly[1] - poly[0], poly[2] - poly[0])
    ok = np.abs((p - poly[0]) @ n) < 1e-9 * np.linalg.norm(n)
    for k in range(nv):
        e = poly[(k + 1) % nv] - poly[k]
        ok &= np.cross(e, p - poly[k]) @ n >= -1e-12
    return ok


@pytest.mark.parametrize("n", [1, 4, 9, 16])
def test_nxm_points_are_cell_centres_with_area_weights(rng, n):
    from radiosity.core.geometry import polygon_properties

    v, nv = _polys(rng)
    _, _, centre = polygon_properties(v, nv)
    pts, w = sample_points(v, nv, Sampling("nxm", n))
    assert pts.shape == (5, n, 3) and w.shape == (5, n)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=1e-14)
    for k in range(5):
        assert _inside(pts[k], v[k], nv[k]).all()
    # triangles and parallelograms: equal cells, so the weights are the missing 1/(N M) factor,
    # and the weighted mean of the points is the centroid
    np.testing.assert_allclose(w[:4], 1.0 / n, rtol=1e-12)
    np.testing.assert_allclose(np.einsum("ms,msc->mc", w[:4], pts[:4]), centre[:4], atol=1e-12)
    if n > 1:  # the general quad's cells differ in area
        assert w[4].std() > 1e-3


def test_mc_points_are_seeded_uniform_samples(rng):
    from radiosity.core.geometry import polygon_properties

    v, nv = _polys(rng)
    _, _, centre = polygon_properties(v, nv)
    a, wa = sample_points(v, nv, Sampling("mc", 4000, seed=3))
    b, _ = sample_points(v, nv, Sampling("mc", 4000, seed=3))
    c, _ = sample_points(v, nv, Sampling("mc", 4000, seed=4))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    np.testing.assert_allclose(wa, 1 / 4000)
    for k in range(5):
        assert _inside(a[k], v[k], nv[k]).all()
        # uniform by area: the mean is the area centroid (5 standard errors)
        assert np.all(np.abs(a[k].mean(0) - centre[k]) <= 5 * a[k].std(0) / np.sqrt(4000) + 1e-15)


def test_sampling_settings_are_checked():
    s = resolve().solve
    assert sampling_of(s, "point") is None and sampling_of(s, "disc-nf") is None
    with dask.config.set({"radiosity.solve.nxm-points": 5}):
        with pytest.raises(RadiosityError, match="nxm-points must be a square"):
            sampling_of(resolve().solve, "nxm")
    with pytest.raises(RadiosityError, match="mc-samples must be at least 1"):
        sampling_of(resolve().replace({"solve.mc-samples": 0}).solve, "mc")
    assert sampling_of(resolve({"solve.nxm-points": 9}).solve, "nxm").rays_per_pair == 81
    assert sampling_of(resolve({"solve.mc-samples": 7, "solve.mc-seed": 2}).solve,
                       "mc") == Sampling("mc", 7, 2)


@pytest.mark.parametrize("kernel", ["nxm", "mc"])
def test_sampled_operator_equals_brute_force_with_a_ray_per_sample_pair(client, tmp_path, rng, kernel):
    """three-rectangles has a shadow: some pairs are only partly visible. The operator (bits +
    stored fractions + on-the-fly kernel) must equal a brute force that traces every sample pair
    of every ordered pair, and stay reciprocal."""
    out = prepared(client, tmp_path, scene_path("three-rectangles"), 12, visibility=False)
    fig = compute_visibility(out, client, settings_of(kernel=kernel), progress=False)
    assert fig["pairs_partial"] > 10 and fig["rays_per_pair"] == 16
    rs = RunStore(out)
    op, part, el = open_operator(rs, client, kernel, settings_of())
    assert op.inp.pcrc[:, 1].sum() == fig["pairs_partial"]
    pts, w = sample_points(part.verts, part.nverts, sampling_of(resolve().solve, kernel))
    F = naive.sampled_form_factor_matrix(part, el, kernel, pts, w)
    m = len(part)
    for _ in range(3):
        x = rng.random((2, 1, m))
        y = op.apply(x, use_need=False)
        ref = (F @ x[:, 0].ravel()).reshape(2, m)
        assert np.abs(y[:, 0] - ref).max() <= 1e-12 * np.abs(ref).max()
    # fractions matter: with every partly visible pair counted whole, F would differ
    op.configure(pcrc=np.zeros((0, 2), np.int64))
    y = op.apply(x, use_need=False)
    assert np.abs(y[:, 0] - ref).max() > 1e-3 * np.abs(ref).max()
    # reciprocity, partial pairs included
    op, part, el = open_operator(rs, client, kernel, settings_of())
    x, z = np.zeros((2, 3, m)), np.zeros((2, 3, m))
    x[0], z[0] = rng.random((3, m)), rng.random((3, m))
    lhs = np.sum(x * part.area * op.apply(z))
    rhs = np.sum(z * part.area * op.apply(x))
    assert lhs == pytest.approx(rhs, rel=1e-12)


@pytest.mark.parametrize("kernel", ["nxm", "point-nf"])
def test_every_solver_applies_the_sparse_corrections(client, tmp_path, kernel):
    """Jacobi, Gauss-Seidel (its own sweep on one worker), progressive and CG reach the same
    radiance with sparse corrections (partial visibility, near field), and nxm matches a dense
    direct solve of the brute-force F."""
    out = prepared(client, tmp_path, scene_path("cornell-box"), 8, visibility=False)
    compute_visibility(out, client, settings_of(kernel=kernel), progress=False)
    rs = RunStore(out)
    part, el = rs.load_partition(), rs.load_elements()
    got = {}
    for solver in ("jacobi", "gauss-seidel", "progressive", "cg"):
        run_solve(out, client, settings_of(solver=solver, kernel=kernel, tol=1e-11),
                  progress=False)
        got[solver] = RunStore(out).read_arrays("solution")["radiance"]
    rep = json.loads((tmp_path / "run" / "report.json").read_text())["solve"]
    assert rep["partial_visibility" if kernel == "nxm" else "near_field"]["pairs"] > 0
    scale = np.abs(got["cg"]).max()
    for solver, L in got.items():
        assert np.abs(L - got["cg"]).max() < 1e-8 * scale, solver
    if kernel == "nxm":
        pts, w = sample_points(part.verts, part.nverts, sampling_of(resolve().solve, kernel))
        F = naive.sampled_form_factor_matrix(part, el, kernel, pts, w)
        ref = naive.dense_solution_of(naive.normalised(F, len(part)), el, part)  # rows capped as run_solve does
        assert np.abs(got["cg"] - ref).max() < 1e-8 * scale


def test_kernel_needs_its_own_visibility_and_mc_is_seeded(client, tmp_path):
    out = prepared(client, tmp_path, scene_path("three-rectangles"), 12, visibility=False)
    compute_visibility(out, client, settings_of(), progress=False)
    with pytest.raises(RadiosityError, match="one ray between centres; the nxm kernel needs 4 points "
                                             "per element .*radiosity visibility .* --kernel nxm"):
        run_solve(out, client, settings_of(kernel="nxm"), progress=False)
    compute_visibility(out, client, settings_of(kernel="mc"), progress=False)
    with pytest.raises(RadiosityError, match="--kernel point"):
        run_solve(out, client, settings_of(kernel="point"), progress=False)
    run_solve(out, client, settings_of(kernel="mc"), progress=False)
    a = RunStore(out).read_arrays("solution")["radiance"]
    run_solve(out, client, settings_of(kernel="mc"), progress=False)
    assert np.array_equal(a, RunStore(out).read_arrays("solution")["radiance"])
    with dask.config.set({"radiosity.solve.mc-seed": 1}):
        with pytest.raises(RadiosityError, match="random sample pairs \\(seed 0\\)"):
            run_solve(out, client, settings_of(kernel="mc"), progress=False)
        compute_visibility(out, client, settings_of(kernel="mc"), progress=False)
        run_solve(out, client, settings_of(kernel="mc"), progress=False)
    b = RunStore(out).read_arrays("solution")["radiance"]
    assert not np.array_equal(a, b) and np.abs(a - b).max() < 0.2 * np.abs(a).max()


def test_corrupted_partial_pairs_are_detected_and_recomputed(client, tmp_path):
    out = prepared(client, tmp_path, scene_path("three-rectangles"), 12, visibility=False)
    compute_visibility(out, client, settings_of(kernel="nxm"), progress=False, unit="block")
    rs = RunStore(out, "r+")
    _, _, done = VisibilityStore(rs).require()
    ref = {t: read_partial(rs.path, t, e["partial"]) for t, e in done.items()}
    task = next(t for t, e in done.items() if e["partial"]["n"] > 0)
    arr = rs.root["visibility"]["partial"][f"{task}-phi"]
    arr[0] = arr[0] * 0.5
    op, part, _ = open_operator(RunStore(out), client, "nxm", settings_of())
    with pytest.raises(StoreError, match=f"visibility task {task} .* corrupted"):
        op.apply(np.ones((2, 1, len(part))))
    fig = compute_visibility(out, client, settings_of(kernel="nxm"), progress=False, unit="block",
                             resume=True)
    assert fig["tasks_corrupted_recomputed"] == 1 and fig["tasks_computed"] == 1
    _, _, done = VisibilityStore(RunStore(out)).require()
    for t, e in done.items():  # the recomputed task wrote the same pairs again
        for a, b in zip(read_partial(rs.path, t, e["partial"]), ref[t]):
            assert np.array_equal(a, b)


def test_render_with_the_nxm_kernel_from_the_cli(client, tmp_path):
    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["render", scene_path("three-rectangles"), "--out", str(out),
                                  "--resolution", "12", "--no-preview", "--kernel", "nxm",
                                  "--nxm-points", "9", "--scheduler", client.scheduler.address])
    assert r.exit_code == 0, r.output
    rep = json.loads((out / "report.json").read_text())
    assert rep["visibility"]["rays_per_pair"] == 81 and rep["visibility"]["pairs_partial"] > 0
    assert rep["solve"]["kernel"] == "nxm" and rep["solve"]["partial_visibility"]["pairs"] > 0
    r = CliRunner().invoke(main, ["solve", str(out), "--kernel", "nxm", "--nxm-points", "4",
                                  "--scheduler", client.scheduler.address])
    assert r.exit_code == 2 and "--kernel nxm" in r.output and "9 points per element" in r.output


def test_study_sweeps_sample_counts(client, tmp_path):
    from radiosity.validation.study import accuracy, kernel_setting

    assert kernel_setting("nxm:16", settings_of()) == ("nxm", {"radiosity.solve.nxm-points": 16})
    assert kernel_setting("point", settings_of()) == ("point", {})
    for bad in ("point:4", "mc:x", "nope:3"):
        with pytest.raises(RadiosityError):
            kernel_setting(bad, settings_of())
    rows = accuracy(scene_path("parallel-squares"), str(tmp_path / "st"), client, [8], [1],
                    ["nxm:16", "point", "nxm:4", "mc:16"], [1e-6], echo=lambda *a: None,
                    settings=settings_of())
    err = {r["kernel"]: r["error"] for r in rows}
    assert set(err) == {"point", "nxm:4", "nxm:16", "mc:16"}
    # more sample points, less error (measured: 2.7e-2, 6.5e-3, 1.6e-3; mc:16 1.2e-2)
    assert err["nxm:16"] < 0.5 * err["nxm:4"] < 0.25 * err["point"]
    assert err["mc:16"] < 0.6 * err["point"]
