"""Faults during a solve: visibility bits corrupted on disk (the solver's checksum stops it, the
repair command it names fixes it), and a worker killed in the middle of a solve (its pass tasks
are resubmitted; the answer is the same)."""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import numpy as np
import pytest
from click.testing import CliRunner

from radiosity.cli.commands import main
from radiosity.methods.pairs.plan import TSTART
from radiosity.stages.solve import run_solve
from radiosity.runtime.store import RunStore
from radiosity.methods.pairs.store import VisibilityStore
from helpers import prepared, radiance, scene_path
from radiosity.settings import options as settings_of


def test_corrupted_bits_stop_the_solve_and_visibility_resume_repairs_them(client, tmp_path):
    """solve -> (bits corrupted) -> solve fails with one line naming the repair ->
    `radiosity visibility RUN --resume` recomputes the task -> solve gives the first answer."""
    sched = ["--scheduler", client.scheduler.address]
    ref = prepared(client, tmp_path, scene_path("cornell-box"), 10, name="ref")
    run_solve(ref, client, settings_of(), progress=False)
    out = prepared(client, tmp_path, scene_path("cornell-box"), 10, name="run")
    rs = RunStore(out, "r+")
    plan = VisibilityStore(rs).plan()
    task = int(plan.cost_order()[0])
    arr = rs.root["visibility"]["bits"]
    s = int(plan.tasks[task, TSTART])
    arr[s:s + 8] = arr[s:s + 8] ^ 0x5A  # valid zarr chunks, wrong bits
    r = CliRunner().invoke(main, ["solve", out] + sched)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert f"visibility task {task} of {out} is corrupted (checksum)" in r.output
    assert f"run radiosity visibility {out} --resume" in r.output
    r = CliRunner().invoke(main, ["visibility", out, "--resume"] + sched)
    assert r.exit_code == 0, r.output
    rep = json.loads(open(os.path.join(out, "report.json")).read())["visibility"]
    assert rep["tasks_corrupted_recomputed"] == 1 and rep["tasks_computed"] == 1
    r = CliRunner().invoke(main, ["solve", out] + sched)
    assert r.exit_code == 0 and "converged" in r.output, r.output
    np.testing.assert_allclose(radiance(out), radiance(ref), rtol=1e-12, atol=0)


@pytest.fixture(scope="module")
def killable():
    """A cluster of its own whose workers may be killed (the nanny restarts them)."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=50) as cluster, Client(cluster) as c:
        yield c


@pytest.mark.parametrize("method", ["pairs", "hierarchical"])
@pytest.mark.parametrize("solver", ["cg", "gauss-seidel"])
def test_worker_killed_during_solve_gives_the_same_answer(killable, tmp_path, solver, method):
    """SIGKILL one worker shortly after the second pass has started (Gauss-Seidel runs each sweep
    on the first worker: that one is killed), for both methods (the hierarchical one with its
    passes on the workers). The pass tasks it held are resubmitted and the data it held is sent
    again; the solve converges to the answer of an undisturbed run, pass for pass the same
    arithmetic."""
    from radiosity.methods.base import get_method

    c = killable
    c.cluster.scale(2)  # the last run's victim: its nanny restarts it (or, if it gave up, this)
    c.wait_for_workers(2, timeout=180)  # a worker's start takes long on a loaded machine
    out = prepared(c, tmp_path, scene_path("cornell-box"), 12, visibility=False)
    get_method(method).build(out, c, settings_of(), progress=False)
    ref = run_solve(out, c, settings_of(solver=solver, tol=1e-10), progress=False, where="cluster")
    L_ref = radiance(out)
    workers = sorted(c.scheduler_info()["workers"])
    pids = c.run(os.getpid)
    victim = pids[workers[0]]
    killed = []

    def kill_soon(k, r, L):
        if k == 1 and not killed:
            def later():
                time.sleep(0.02)  # inside the next pass
                os.kill(victim, signal.SIGKILL)
            killed.append(threading.Thread(target=later))
            killed[0].start()

    fig = run_solve(out, c, settings_of(solver=solver, tol=1e-10), progress=False,
                    callback=kill_soon, where="cluster")
    killed[0].join()
    assert victim not in c.run(os.getpid).values()  # it really died (the nanny started another)
    assert fig["converged"] and fig["iterations"] == ref["iterations"]
    np.testing.assert_allclose(radiance(out), L_ref, rtol=1e-12, atol=0)
