"""Where the work runs (app/cluster.py): loopback-only local clusters, TLS, adaptive scaling, the
jobqueue configuration of deploy/jobqueue.yaml, and a render through a real Slurm whose workers
are Slurm jobs (`needs("slurm")`: skipped, saying why, when no Slurm runs here; failed under
CI=true, where .ci/run starts one with deploy/slurm-up.sh)."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
import time

import dask.config
import numpy as np
import pytest
import yaml

from radiosity.runtime.cluster import (adaptive_bounds, jobqueue_cluster, jobqueue_kwargs, open_client,
                               tls_mode)
from radiosity.errors import RadiosityError

from helpers import ROOT, scene_path
from radiosity.settings import options as settings_of

LOOPBACK_SCHEDULER = {"host": "127.0.0.1", "dashboard_address": "127.0.0.1:0"}


def _host(address: str) -> str:
    return address.split("://", 1)[-1].rsplit(":", 1)[0]


# ----------------------------------------------------------------------------- local clusters

def test_local_cluster_binds_scheduler_dashboard_and_workers_to_loopback(monkeypatch):
    # what any earlier Dask nanny in this process leaves in os.environ (and a nanny prefers it
    # over its config): ours must still reach the workers
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")
    lines = []
    with dask.config.set({"radiosity.cluster.tls": False}), \
            open_client(1, kind="local", echo=lines.append, settings=settings_of().cluster) as c:
        assert c.scheduler.address.startswith("tcp://127.0.0.1:")
        assert c.dashboard_link.startswith("http://127.0.0.1:")
        workers = c.scheduler_info()["workers"]
        assert workers and all(_host(w) == "127.0.0.1" for w in workers)
        assert c.submit(sum, [1, 2]).result() == 3
        # glibc keeps freed memory for the next task's arrays (radiosity.cluster.malloc-trim-
        # threshold), not Dask's 65536
        env = c.run(os.environ.get, "MALLOC_TRIM_THRESHOLD_")
        assert set(env.values()) == {"67108864"}, env
        # and keeps arrays up to 64 MiB on its heap (radiosity.cluster.malloc-mmap-threshold)
        env = c.run(os.environ.get, "MALLOC_MMAP_THRESHOLD_")
        assert set(env.values()) == {"67108864"}, env
    assert any(line.startswith("dashboard: http://127.0.0.1:") for line in lines)


def test_in_process_workers_have_no_memory_limit_so_they_never_pause():
    """Threads in this process: their memory monitor would weigh the whole process (the
    driver's arrays too) against a share of the machine and pause them; a paused worker takes
    no scatter, and the link stage after a large cluster layer failed with "No valid workers
    found". Worker processes keep Dask's limit."""
    with open_client(2, kind="local", quiet=True, in_process=True, settings=settings_of().cluster) as c:
        limits = [w["memory_limit"] for w in c.scheduler_info()["workers"].values()]
        assert limits == [0, 0]
        big = np.ones(1 << 20)
        [f] = c.scatter([big], broadcast=True)
        assert c.submit(np.sum, f).result() == 1 << 20
    with open_client(1, kind="local", quiet=True, in_process=False, settings=settings_of().cluster) as c:
        assert all(w["memory_limit"] > 0 for w in c.scheduler_info()["workers"].values())


def test_the_driver_gets_the_workers_malloc_thresholds_unless_its_environment_set_them(
        monkeypatch):
    """The driver runs the solve's passes and final gather: glibc's thresholds by mallopt, as
    the workers get them by variable; a variable the process started with wins."""
    import radiosity.runtime.cluster as rc

    monkeypatch.setattr(rc, "_USER_MALLOC", {var: None for _, var in rc._MALLOC})
    assert rc.tune_malloc(settings_of().cluster) == {"MALLOC_TRIM_THRESHOLD_": 67108864,
                                "MALLOC_MMAP_THRESHOLD_": 67108864}
    monkeypatch.setattr(rc, "_USER_MALLOC", {"MALLOC_TRIM_THRESHOLD_": "131072",
                                             "MALLOC_MMAP_THRESHOLD_": None})
    with dask.config.set({"radiosity.cluster.malloc-mmap-threshold": 1 << 25}):
        assert rc.tune_malloc(settings_of().cluster) == {"MALLOC_MMAP_THRESHOLD_": 1 << 25}
    with dask.config.set({"radiosity.cluster.malloc-mmap-threshold": None}):
        assert rc.tune_malloc(settings_of().cluster) == {}


def test_trim_malloc_hands_back_the_pages_of_arrays_freed_in_the_middle_of_the_heap():
    """The cluster merge frees many heap arrays under a kept one (tune_malloc keeps arrays up to
    64 MiB on the heap): without the trim their pages stay with the process."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import os, numpy as np
        import radiosity.runtime.cluster as rc
        from radiosity.settings import options
        rc.tune_malloc(options().cluster)
        def rss():
            return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
        held = [np.ones(1 << 17) for _ in range(400)]   # 400 x 1 MiB on the heap
        top = np.ones(1 << 17)                         # keeps the heap's top in use
        before = rss()
        del held
        freed = rss()
        assert rc.trim_malloc()
        print(before - freed, before - rss())
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    kept_freed, trimmed = (int(x) for x in out.stdout.split())
    assert kept_freed < 100 << 20  # free() alone keeps them
    assert trimmed > 350 << 20


def test_tls_temporary_local_cluster_runs_preprocess_and_visibility(small_scene, tmp_path, client):
    from radiosity.stages.preprocess import preprocess
    from radiosity.scene.load import load_scene
    from radiosity.methods.pairs.visibility import compute_visibility

    sc = load_scene(small_scene, settings=settings_of())
    with dask.config.set({"radiosity.cluster.tls": "temporary"}), \
            open_client(1, kind="local", quiet=True, settings=settings_of().cluster) as c:
        assert c.scheduler.address.startswith("tls://127.0.0.1:")
        assert all(w.startswith("tls://127.0.0.1:") for w in c.scheduler_info()["workers"])
        assert c.security.require_encryption
        preprocess(sc, str(tmp_path / "tls"), c, settings_of(), progress=False)
        fig = compute_visibility(str(tmp_path / "tls"), c, settings_of(), progress=False)
    assert fig["tasks_computed"] == fig["tasks"] > 0
    # the same stages over plain TCP (the session's cluster) give the same answer
    preprocess(sc, str(tmp_path / "tcp"), client, settings_of(), progress=False)
    ref = compute_visibility(str(tmp_path / "tcp"), client, settings_of(), progress=False)
    for k in ("sub_elements", "pairs_facing", "pairs_visible", "rays"):
        assert fig[k] == ref[k], k


def test_adaptive_local_cluster_scales_up_under_load_and_down_when_idle():
    """adaptive (1, 2): one worker while idle; 40 half-second tasks (20 s of work, beyond
    the scheduler's 5 s target per worker) bring the second; once idle again the cluster
    retires back to one."""
    with open_client(2, kind="local", quiet=True, adaptive=(1, 2), timeout=60,
                     settings=settings_of().cluster) as c:
        def workers():
            return len(c.scheduler_info()["workers"])

        def wait_for(pred, timeout, what):
            t = time.perf_counter()
            while not pred():
                assert time.perf_counter() - t < timeout, f"{what}: {workers()} worker(s) after {timeout} s"
                time.sleep(0.2)

        wait_for(lambda: workers() == 1, 60, "at the minimum when idle")
        futs = c.map(time.sleep, [0.5] * 40, pure=False)
        peak = 1
        t = time.perf_counter()
        while not all(f.done() for f in futs) and time.perf_counter() - t < 120:
            peak = max(peak, workers())
            time.sleep(0.2)
        c.gather(futs)
        assert peak == 2, "never scaled up under load"
        wait_for(lambda: workers() == 1, 60, "back to the minimum once idle")
        assert c.submit(lambda: 41 + 1).result() == 42


def test_tls_and_adaptive_settings_parse():
    assert tls_mode(False) is None and tls_mode("false") is None and tls_mode(None) is None
    assert tls_mode("temporary") == "temporary" and tls_mode(True) == "temporary"
    with dask.config.set({"radiosity.cluster.tls": "temporary"}):
        assert tls_mode(settings_of().cluster.tls) == "temporary"
    with pytest.raises(RadiosityError, match="false or temporary"):
        tls_mode("mutual")
    assert adaptive_bounds(False, 4) is None
    assert adaptive_bounds(True, 4) == (1, 4)
    assert adaptive_bounds((0, 8), 4) == (1, 8)  # at least one worker
    assert adaptive_bounds("2:6", 4) == (2, 6)
    assert adaptive_bounds({"minimum": 2}, 5) == (2, 5)
    with pytest.raises(RadiosityError, match="maximum"):
        adaptive_bounds((5, 2), 4)


def test_batch_kind_without_its_submit_command_fails_clearly(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))  # no qsub here
    with pytest.raises(RadiosityError, match="qsub.*not on PATH"):
        with open_client(1, kind="pbs", quiet=True, settings=settings_of().cluster):
            pass
    with pytest.raises(RadiosityError, match="unknown cluster kind"):
        with open_client(1, kind="kubernetes", quiet=True, settings=settings_of().cluster):
            pass
    with dask.config.set({"radiosity.cluster.tls": "temporary"}), \
            pytest.raises(RadiosityError, match="running scheduler over TLS"):
        with open_client(scheduler="tcp://127.0.0.1:1", quiet=True, settings=settings_of().cluster):
            pass


# ----------------------------------------------------------------------------- jobqueue config

@pytest.fixture
def deploy_jobqueue_config():
    import dask_jobqueue  # noqa: F401  registers its defaults first: set() below must not own the key

    with open(os.path.join(ROOT, "deploy", "jobqueue.yaml")) as f:
        cfg = yaml.safe_load(f)
    # as DASK_CONFIG would: merged over dask-jobqueue's defaults (which have keys the file omits)
    merged = dask.config.update(copy.deepcopy(dask.config.get("jobqueue")), cfg["jobqueue"])
    with dask.config.set({"jobqueue": merged}):
        yield cfg


def test_job_scripts_from_deploy_jobqueue_yaml(deploy_jobqueue_config, tmp_path):
    worker = f"{sys.executable} -m distributed.cli.dask_worker"
    with jobqueue_cluster("slurm", scheduler_options=LOOPBACK_SCHEDULER) as cl:
        s = cl.job_script()
    for want in ("#SBATCH -J radiosity-worker", "#SBATCH --cpus-per-task=8", "#SBATCH --mem=15G",
                 "#SBATCH -t 02:00:00", worker, "--nthreads 4", "--nworkers 2", "--memory-limit 7.45GiB",
                 "--lifetime=115m", "OMP_NUM_THREADS=1"):
        assert want in s, (want, s)
    assert "#SBATCH -p" not in s and "#SBATCH -A" not in s  # queue/account null in the YAML

    # keyword overrides win over the YAML
    with jobqueue_cluster("slurm", scheduler_options=LOOPBACK_SCHEDULER, cores=4, memory="8GB",
                          processes=1, walltime="00:30:00", queue="compute", account="proj42") as cl:
        s = cl.job_script()
    for want in ("#SBATCH --cpus-per-task=4", "#SBATCH --mem=8G", "#SBATCH -t 00:30:00",
                 "#SBATCH -p compute", "#SBATCH -A proj42", "--nthreads 4", worker):
        assert want in s, (want, s)
    assert "--nworkers" not in s

    with jobqueue_cluster("pbs", scheduler_options=LOOPBACK_SCHEDULER, account="proj42") as cl:
        s = cl.job_script()
    for want in ("#PBS -N radiosity-worker", "#PBS -l select=1:ncpus=8:mem=15GB",
                 "#PBS -l walltime=02:00:00", "#PBS -A proj42", worker, "--nworkers 2"):
        assert want in s, (want, s)

    # TLS: the workers get the temporary certificate through the shared directory
    from distributed.security import Security

    with jobqueue_cluster("slurm", scheduler_options=LOOPBACK_SCHEDULER, security=Security.temporary(),
                          shared_temp_directory=str(tmp_path)) as cl:
        s = cl.job_script()
        assert cl.scheduler_address.startswith("tls://127.0.0.1:")
    assert "--tls-ca-file" in s and str(tmp_path) in s


def test_jobqueue_kwargs_python_threads_and_account_mapping():
    kw = jobqueue_kwargs("slurm", cores=8, memory="16GB", queue=None)
    assert kw["python"] == sys.executable and "queue" not in kw
    assert jobqueue_kwargs("slurm", threads_per_worker=2, cores=8)["processes"] == 4
    assert jobqueue_kwargs("slurm", threads_per_worker=2, cores=8, processes=1)["processes"] == 1
    assert jobqueue_kwargs("sge", account="p1")["project"] == "p1"
    assert jobqueue_kwargs("lsf", account="p1")["project"] == "p1"
    with dask.config.set({"jobqueue.slurm.python": "/opt/env/bin/python"}):
        assert "python" not in jobqueue_kwargs("slurm")  # configured: left to dask-jobqueue


# ----------------------------------------------------------------------------- a real Slurm

def _squeue() -> list[str]:
    return subprocess.run(["squeue", "-h", "-o", "%i"], capture_output=True, text=True, timeout=15).stdout.split()


def _wait_queue_empty(timeout=30.0) -> list[str]:
    t = time.perf_counter()
    left = _squeue()
    while left and time.perf_counter() - t < timeout:
        time.sleep(0.2)
        left = _squeue()
    return left


@pytest.mark.needs("slurm")
def test_render_through_slurm_jobs_equals_local_render(client, tmp_path):
    from radiosity.pipeline import render_scene
    from radiosity.scene.load import load_scene
    from radiosity.runtime.store import RunStore

    sc = load_scene(scene_path("three-rectangles"), resolution=12, settings=settings_of())
    logs = tmp_path / "slurm-logs"
    logs.mkdir()
    lines = []
    t0 = time.perf_counter()
    with dask.config.set({"radiosity.cluster.tls": False}), \
            open_client(2, kind="slurm", echo=lines.append, cores=1, processes=1, memory="1GB",
                        walltime="00:10:00", timeout=120, job_name=f"radiosity-test-{os.getpid()}",
                        log_directory=str(logs), scheduler_options=LOOPBACK_SCHEDULER,
                        worker_extra_args=["--host", "127.0.0.1"], settings=settings_of().cluster) as c:
        t_up = time.perf_counter() - t0
        assert c.scheduler.address.startswith("tcp://127.0.0.1:")
        assert len(_squeue()) == 2  # the two workers are Slurm jobs
        assert len(c.scheduler_info()["workers"]) == 2
        render_scene(sc, str(tmp_path / "slurm"), c, settings_of(), preview=False, progress=False)
    t_render = time.perf_counter() - t0 - t_up
    left = _wait_queue_empty()
    assert not left, f"jobs left in the queue: {left}"
    assert any("worker(s) connected" in line for line in lines)

    render_scene(sc, str(tmp_path / "local"), client, settings_of(), preview=False, progress=False)
    a = RunStore(str(tmp_path / "slurm")).read_arrays("solution")["radiance"]
    b = RunStore(str(tmp_path / "local")).read_arrays("solution")["radiance"]
    assert a.shape == b.shape and len(a) > 3
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=0)
    print(f"slurm: workers up {t_up:.1f} s, render {t_render:.1f} s")


@pytest.mark.needs("slurm")
def test_tls_with_slurm_workers_runs_the_stages(small_scene, client, tmp_path):
    """TLS with jobqueue workers: the temporary certificate reaches the Slurm jobs through the
    shared temporary directory; scheduler and worker speak tls:// only, and the stages give the
    answer of the plain-TCP LocalCluster."""
    from radiosity.stages.preprocess import preprocess
    from radiosity.scene.load import load_scene
    from radiosity.methods.pairs.visibility import compute_visibility

    sc = load_scene(small_scene, settings=settings_of())
    certs = tmp_path / "certs"
    certs.mkdir()
    with dask.config.set({"radiosity.cluster.tls": "temporary"}), \
            open_client(1, kind="slurm", quiet=True, cores=1, processes=1, memory="1GB",
                        walltime="00:10:00", timeout=120, job_name=f"radiosity-test-{os.getpid()}",
                        log_directory=str(tmp_path), shared_temp_directory=str(certs),
                        scheduler_options=LOOPBACK_SCHEDULER,
                        worker_extra_args=["--host", "127.0.0.1"], settings=settings_of().cluster) as c:
        assert c.scheduler.address.startswith("tls://127.0.0.1:")
        workers = c.scheduler_info()["workers"]
        assert len(workers) == 1 and all(w.startswith("tls://127.0.0.1:") for w in workers)
        assert c.security.require_encryption and len(_squeue()) == 1  # the worker is a Slurm job
        preprocess(sc, str(tmp_path / "tls"), c, settings_of(), progress=False)
        fig = compute_visibility(str(tmp_path / "tls"), c, settings_of(), progress=False)
    left = _wait_queue_empty()
    assert not left, f"jobs left in the queue: {left}"
    preprocess(sc, str(tmp_path / "tcp"), client, settings_of(), progress=False)
    ref = compute_visibility(str(tmp_path / "tcp"), client, settings_of(), progress=False)
    for k in ("sub_elements", "pairs_facing", "pairs_visible", "rays"):
        assert fig[k] == ref[k], k


@pytest.mark.needs("slurm")
def test_unsatisfiable_slurm_jobs_fail_with_what_to_check(tmp_path):
    with pytest.raises(RadiosityError) as e:
        with open_client(1, kind="slurm", quiet=True, cores=1, processes=1, memory="1GB",
                         walltime="00:05:00", timeout=4, log_directory=str(tmp_path),
                         job_name=f"radiosity-test-{os.getpid()}",
                         job_extra_directives=["--begin=now+1hour"],
                         scheduler_options=LOOPBACK_SCHEDULER,
                         worker_extra_args=["--host", "127.0.0.1"], settings=settings_of().cluster):
            pass
    msg = str(e.value)
    assert "0 of 1 Dask workers connected within 4 s" in msg
    assert "squeue" in msg and str(tmp_path) in msg and "scheduler at tcp://127.0.0.1:" in msg
    assert "PENDING" in msg and "BeginTime" in msg  # the job's state, from squeue
    left = _wait_queue_empty()
    assert not left, f"jobs left in the queue: {left}"


def _held(inp):
    """On a worker: the checksums of a scattered LinkInputs' arrays and its type."""
    return type(inp).__name__, float(inp.t_verts.sum()), int(inp.t_child.sum())


def test_a_broadcast_reaches_every_local_worker_straight_and_by_attributes(client):
    """cluster.scatter: to a LocalCluster straight from the driver, a broadcast sent to each
    worker in turn under one key (no worker-to-worker copy), and a scatterable class rebuilt
    from its attributes on the other side; with direct-scatter false, through the scheduler."""
    from distributed.protocol import deserialize, serialize

    from radiosity.runtime.cluster import _direct, scatter
    from radiosity.methods.hierarchical.links.master import LinkInputs

    rng = np.random.default_rng(7)
    inp = LinkInputs.__new__(LinkInputs)
    inp.__dict__.update({"t_verts": rng.random((1000, 4, 3)), "t_child": np.arange(2000).reshape(-1, 2),
                         "key": "k", "epsilon": 1e-6})
    header, frames = serialize(inp)
    assert header["serializer"] == "dask" and len(frames) >= 2  # the arrays as buffers of their own
    back = deserialize(header, frames)
    assert isinstance(back, LinkInputs) and np.array_equal(back.t_verts, inp.t_verts)
    assert _direct(client)
    want = ("LinkInputs", float(inp.t_verts.sum()), int(inp.t_child.sum()))
    workers = sorted(client.scheduler_info()["workers"])
    for direct in (True, False):
        with dask.config.set({"radiosity.cluster.direct-scatter": direct}):
            [f] = scatter(client, [inp], broadcast=True)
            assert sorted(client.who_has(f)[f.key]) == workers
            got = [client.submit(_held, f, workers=[w], allow_other_workers=False, pure=False)
                   for w in workers]
            assert client.gather(got) == [want] * len(workers)
            del f, got


def test_a_broadcast_lost_with_its_workers_is_sent_again():
    """cluster.Scattered: the stages' one-time inputs are sent once while a copy lives, and
    again when every copy died with its worker (the workers restarted), so that a retried task
    gets its input instead of failing on "lost dependencies" at every attempt."""
    from distributed import Client, LocalCluster

    from radiosity.runtime.cluster import Scattered

    value = np.arange(100_000.0)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0", silence_logs=50) as cluster, \
            Client(cluster) as c:
        shared = Scattered(c, value)
        f = shared.future()
        assert shared.future() is f and shared.sent == 1  # alive: not sent again
        assert c.submit(np.sum, f, pure=False).result() == value.sum()
        c.restart()
        assert f.status != "finished"  # every copy gone with the old worker processes
        g = shared.future()
        assert g is not f and shared.sent == 2
        assert c.submit(np.sum, g, pure=False).result() == value.sum()
