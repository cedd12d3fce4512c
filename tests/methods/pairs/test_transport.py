"""Solvers are pure and executors swappable: every solver through the Dask and the in-process
operator, against the dense direct solve of tests/naive.py (STYLE: rechunker's pattern)."""

from __future__ import annotations

import numpy as np
import pytest

import naive
from radiosity.methods.pairs.transport import BoundedCache, DaskOperator, LocalOperator, open_operator
from radiosity.methods.pairs.passes import CAP_MIN
from radiosity.methods.pairs.method import side_vectors
from radiosity.stages.solve import normalise_rows
from radiosity.core.solvers import SOLVERS
from radiosity.runtime.store import RunStore
from helpers import prepared, scene_path
from radiosity.settings import options as settings_of


@pytest.fixture(scope="module")
def three(client, tmp_path_factory):
    out = prepared(client, tmp_path_factory.mktemp("op"), scene_path("three-rectangles"), 8)
    rs = RunStore(out)
    part, el = rs.load_partition(), rs.load_elements()
    return out, part, el, naive.visibility(part, el)


@pytest.mark.parametrize("executor", ["dask", "local"])
@pytest.mark.parametrize("solver", list(SOLVERS))
def test_every_solver_through_every_executor_matches_the_dense_solve(client, three, executor, solver):
    out, part, el, V = three
    op, _, _ = open_operator(RunStore(out), client if executor == "dask" else None, "point",
                             settings_of())
    assert isinstance(op, DaskOperator if executor == "dask" else LocalOperator)
    rows, scaling = normalise_rows(op, "cap")
    if scaling:
        op.configure(**scaling)
    Le, rho, area = side_vectors(part, el)
    res = SOLVERS[solver](op, Le, rho, area, 1e-11, 2000)
    assert res.converged
    ref = naive.dense_solution(part, el, V, "point")          # (m, 2, 3)
    L = np.transpose(res.radiance, (2, 0, 1))
    err = np.abs(L - ref).max() / np.abs(ref).max()
    # 1e-11 relative residual; Gauss-Seidel and progressive stop on cheaper bounds of it
    assert err < 1e-8, f"{solver}/{executor}: {err:.2e}"


def test_both_executors_compute_the_same_product_and_counts(client, three, rng):
    out, part, *_ = three
    dask_op, _, _ = open_operator(RunStore(out), client, "disc", settings_of())
    local_op, _, _ = open_operator(RunStore(out), None, "disc", settings_of())
    x = rng.random((2, 3, len(part)))
    np.testing.assert_allclose(dask_op.apply(x), local_op.apply(x), rtol=1e-12, atol=0)
    assert dask_op.terms == local_op.terms > 0
    assert dask_op.inp.cmode == local_op.inp.cmode == CAP_MIN


def test_worker_cache_stays_bounded_and_consistent_under_threads():
    """Several threads per worker (deploy/jobqueue.yaml uses 4) share the cache: the byte count
    must equal the sum of what it holds and never exceed the bound."""
    from concurrent.futures import ThreadPoolExecutor

    cache = BoundedCache()
    cap = 10_000

    def work(i):
        for k in range(400):
            key = (i * 7 + k) % 37
            v = cache.get(key, lambda: np.zeros(100 + key * 10, np.uint8), lambda a: a.nbytes, cap)
            assert len(v) == 100 + key * 10
        return True

    with ThreadPoolExecutor(8) as ex:
        assert all(ex.map(work, range(16)))
    held = sum(size for _, size in cache._items.values())
    assert cache.nbytes == held <= cap
