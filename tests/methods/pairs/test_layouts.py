"""The solvers on every layout of the visibility matrix, and the near-field kernels on
two-sided elements, against the dense direct solves of tests/naive.py."""

from __future__ import annotations

import dask.config
import numpy as np
import pytest

import naive
from radiosity.methods.pairs.plan import I, J
from radiosity.stages.solve import run_solve
from radiosity.runtime.store import RunStore
from radiosity.methods.pairs.store import VisibilityStore
from radiosity.methods.pairs.visibility import compute_visibility
from helpers import prepared, radiance, scene_path
from radiosity.settings import options as settings_of


@pytest.mark.parametrize("unit, max_task_bits", [("stripe", None), ("block", 16), ("stripe", 16)])
def test_every_solver_on_stripe_tasks_and_banded_tiles(client, tmp_path, unit, max_task_bits):
    """Stripe tasks (an original against all later ones) and blocks cut into row bands (tasks
    of at most 16 bits: a few rows each at 8^2): Jacobi, Gauss-Seidel (its own sweep over the
    tiles by row and column) and progressive reach the dense direct solve of the point kernel.
    (CG applies F through the same pass tasks as Jacobi.)"""
    out = prepared(client, tmp_path, scene_path("cornell-box"), 8, visibility=False)
    cfg = {} if max_task_bits is None else {"radiosity.visibility.max-task-bits": max_task_bits}
    with dask.config.set(cfg):
        fig = compute_visibility(out, client, settings_of(), progress=False, unit=unit)
    assert fig["task_unit"] == unit
    rs = RunStore(out)
    plan = VisibilityStore(rs).plan()
    tiles = plan.tiles
    if unit == "stripe":  # tasks hold the tiles of several J for one I (or more I, merged)
        assert any(len(set(tiles[t[0]:t[1], J].tolist())) > 1 for t in plan.tasks)
    if max_task_bits is not None:  # blocks cut into bands: one (I, J) over several tiles
        keys = [tuple(k) for k in tiles[:, [I, J]].tolist()]
        assert len(set(keys)) < len(keys) and (tiles[:, 2] > 0).any()
    part, el = rs.load_partition(), rs.load_elements()
    ref = naive.dense_solution(part, el, naive.visibility(part, el), "point")
    scale = np.abs(ref).max()
    for solver in ("jacobi", "gauss-seidel", "progressive"):
        f = run_solve(out, client, settings_of(solver=solver, kernel="point", tol=1e-11),
                      progress=False)
        assert f["converged"], solver
        err = np.abs(radiance(out) - ref).max() / scale
        # 1e-11 relative residual; Gauss-Seidel and progressive stop on cheaper bounds of it
        assert err < 1e-8, f"{solver} on {unit}/{max_task_bits}: {err:.2e}"


@pytest.mark.parametrize("kernel", ["point-nf", "disc-nf"])
def test_near_field_on_two_sided_elements_matches_the_brute_force(client, tmp_path, kernel):
    """construction-in-wood: two-sided slats whose coloured backs face their neighbours' fronts
    at a few centimetres. The near-field pairs (back sides included) get the exact polygon form
    factor: the solve equals a dense direct solve of F built pair by pair by tests/naive.py
    (base kernel, exact polygon form factors for the near pairs, rows capped as the solve caps
    them); disc-nf (not reciprocal) through Gauss-Seidel, point-nf through CG."""
    out = prepared(client, tmp_path, scene_path("construction-in-wood"), 8)
    fig = run_solve(out, client, settings_of(kernel=kernel, tol=1e-12), progress=False)
    assert fig["converged"] and fig["solver"] == ("cg" if kernel == "point-nf" else "gauss-seidel")
    rs = RunStore(out)
    part, el = rs.load_partition(), rs.load_elements()
    V = naive.visibility(part, el)
    factor = float(dask.config.get("radiosity.solve.near-field-factor"))
    F = naive.near_field_matrix(part, el, V, kernel, factor)
    m = len(part)
    near = rs.read_arrays("nearfield")
    assert fig["near_field"]["pairs"] == len(near["ia"]) > 0
    two = el.two_sided[part.orig]
    back = (near["sa"] == 1) & two[near["ia"]] | (near["sb"] == 1) & two[near["ib"]]
    assert back.sum() > 0  # back sides in the near field: what this test is about
    ref = naive.dense_solution_of(naive.normalised(F, m), el, part)
    L = radiance(out)
    err = np.abs(L - ref).max() / np.abs(ref).max()
    assert err < 1e-8, f"{kernel}: {err:.2e}"
    # and the near field matters here: without it the answer differs
    base = naive.dense_solution(part, el, V, kernel.removesuffix("-nf"))
    assert np.abs(base - ref).max() > 1e-3 * np.abs(ref).max()
