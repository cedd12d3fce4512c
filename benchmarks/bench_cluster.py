"""Cluster shapes and scheduler overhead: (a) the visibility stage on the Cornell box with
2 worker processes x 1 thread against 1 worker x 2 threads (and one in-process worker with 2
threads), (b) scheduler overhead: no-op round trips and batch throughput (plain TCP and TLS),
visibility tasks/s and idle time per task for block and stripe task units, (c) the same small
render (three-rectangles) through a real Slurm (workers as Slurm jobs) against a LocalCluster,
if Slurm is up (`bash deploy/slurm-up.sh`).

    python benchmarks/bench_cluster.py [--resolutions 64,96] [--repeat 2] [--rounds 3] [--no-slurm]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time

from common import ROOT, table, write

from radiosity.runtime.cluster import open_client, slurm_unavailable
from radiosity.pipeline import render_scene
from radiosity.stages.preprocess import preprocess
from radiosity.scene.load import load_scene
from radiosity.methods.pairs.visibility import compute_visibility
from radiosity.settings import options as settings_of

CORNELL = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")
THREE = os.path.join(ROOT, "scenes", "three-rectangles", "scene.toml")
SLURM_LOOPBACK = {"scheduler_options": {"host": "127.0.0.1", "dashboard_address": "127.0.0.1:0"},
                  "worker_extra_args": ["--host", "127.0.0.1"]}


def noop(x=None):
    return x


def _inprocess_client(threads):
    """1 worker with `threads` threads inside this process (LocalCluster(processes=False))."""
    import contextlib

    from distributed import Client, LocalCluster

    @contextlib.contextmanager
    def cm():
        with LocalCluster(n_workers=1, threads_per_worker=threads, processes=False,
                          dashboard_address=None, silence_logs=40) as cluster, Client(cluster) as c:
            yield c

    return cm()


SHAPES = {
    "2 processes x 1 thread": lambda: open_client(2, threads_per_worker=1, quiet=True,
                                                  settings=settings_of().cluster),
    "1 process x 2 threads": lambda: open_client(1, threads_per_worker=2, quiet=True,
                                                 settings=settings_of().cluster),
    "in-process 1 x 2 threads": lambda: _inprocess_client(2),
}


def visibility_runs(client, d, repeat, unit=None):
    compute_visibility(d, client, settings_of(), progress=False, unit=unit)  # warm-up: numba cache, Embree scenes
    best = None
    for _ in range(repeat):
        t = time.perf_counter()
        fig = compute_visibility(d, client, settings_of(), progress=False, unit=unit).to_dict()
        fig["wall_s"] = time.perf_counter() - t
        if best is None or fig["wall_s"] < best["wall_s"]:
            best = fig
    return best


def idle_per_task_ms(fig, threads):
    busy = sum(fig["busy_s_per_worker"].values())
    return 1e3 * max(0.0, fig["time_tasks_s"] * threads - busy) / max(1, fig["tasks_computed"])


def bench_shapes(resolutions, repeat, rounds):
    """One cluster at a time, shapes alternated over `rounds` rounds (a fresh cluster and run
    directory each), so that load from other jobs on the shared cores falls on every shape alike;
    best and median of the `rounds * repeat` timed runs. (Keeping all three clients open in one
    process at once hit a tornado iostream assertion here and hung the visibility master.)"""
    import statistics

    times, figs, info = {}, {}, {}
    for _ in range(rounds):
        for res in resolutions:
            sc = load_scene(CORNELL, resolution=res, settings=settings_of())
            for name, make in SHAPES.items():
                with make() as client, tempfile.TemporaryDirectory() as d:
                    threads = sum(client.nthreads().values())
                    pre = preprocess(sc, d, client, settings_of(), progress=False)
                    compute_visibility(d, client, settings_of(), progress=False)  # warm-up: numba cache, Embree
                    for _ in range(repeat):
                        t = time.perf_counter()
                        fig = compute_visibility(d, client, settings_of(), progress=False)
                        dt = time.perf_counter() - t
                        ts = times.setdefault((res, name), [])
                        ts.append(dt)
                        if dt == min(ts):
                            figs[res, name] = fig
                info[res, name] = (threads, pre["sub_elements"])
                print(f"  {res}² {name}: {', '.join(f'{t:.2f}' for t in times[res, name][-repeat:])} s",
                      flush=True)
    rows = []
    for (res, name), ts in times.items():
        threads, m = info[res, name]
        fig = figs[res, name]
        rows.append({"part": "a", "resolution": res, "shape": name, "threads": threads,
                     "sub_elements": m, "tasks": fig["tasks"], "unit": fig["task_unit"],
                     "visibility_s": min(ts), "median_s": statistics.median(ts), "runs": ts,
                     "idle_fraction": idle_per_task_ms(fig, threads) * fig["tasks_computed"]
                     / 1e3 / (fig["time_tasks_s"] * threads)})
    return rows


def bench_overhead(res, repeat):
    rows = []
    for tls in (False, "temporary"):
        with open_client(2, threads_per_worker=1, quiet=True, tls=tls,
                         settings=settings_of().cluster) as client:
            client.submit(noop, 0).result()
            n = 300
            t = time.perf_counter()
            for i in range(n):
                client.submit(noop, i, pure=False).result()
            rt = time.perf_counter() - t
            m = 2000
            t = time.perf_counter()
            futs = client.map(noop, range(m), pure=False)
            client.gather(futs)
            bt = time.perf_counter() - t
            del futs
            rows.append({"part": "b", "shape": "2 processes x 1 thread", "what": "no-op round trip",
                         "tls": bool(tls), "tasks": n, "time_s": rt, "tasks_per_s": n / rt,
                         "ms_per_task": 1e3 * rt / n})
            rows.append({"part": "b", "shape": "2 processes x 1 thread", "what": "no-op batch (map+gather)",
                         "tls": bool(tls), "tasks": m, "time_s": bt, "tasks_per_s": m / bt,
                         "ms_per_task": 1e3 * bt / m})
            if tls:
                continue
            sc = load_scene(CORNELL, resolution=res, settings=settings_of())
            with tempfile.TemporaryDirectory() as d:
                preprocess(sc, d, client, settings_of(), progress=False)
                for unit in ("block", "stripe"):
                    fig = visibility_runs(client, d, repeat, unit=unit)
                    rows.append({"part": "b", "shape": "2 processes x 1 thread",
                                 "what": f"visibility {unit} tasks at {res}²", "tls": False,
                                 "tasks": fig["tasks_computed"], "time_s": fig["time_tasks_s"],
                                 "tasks_per_s": fig["tasks_computed"] / fig["time_tasks_s"],
                                 "ms_per_task": 1e3 * fig["time_tasks_s"] / fig["tasks_computed"],
                                 "idle_ms_per_task": idle_per_task_ms(fig, 2)})
    for r in rows:
        print(f"  {r['what']}{' (TLS)' if r['tls'] else ''}: {r['tasks_per_s']:.0f} tasks/s", flush=True)
    return rows


def _render_timed(open_cm, res):
    sc = load_scene(THREE, resolution=res, settings=settings_of())
    t0 = time.perf_counter()
    with open_cm() as client:
        t_up = time.perf_counter() - t0
        out = {}
        for label in ("first", "second"):
            with tempfile.TemporaryDirectory() as d:
                t = time.perf_counter()
                render_scene(sc, d, client, settings_of(method="pairs"), preview=False,
                             progress=False)
                out[label] = time.perf_counter() - t
        t_close = time.perf_counter()
    closed = time.perf_counter() - t_close
    return {"cluster_up_s": t_up, "render_first_s": out["first"], "render_second_s": out["second"],
            "close_s": closed, "total_s": time.perf_counter() - t0}


def bench_slurm(res):
    rows = [{"part": "c", "cluster": "LocalCluster 2 x 1",
             **_render_timed(lambda: open_client(2, threads_per_worker=1, quiet=True,
                                                 settings=settings_of().cluster), res)}]
    why = slurm_unavailable()
    if why:
        print(f"  Slurm skipped: {why} (start it with bash deploy/slurm-up.sh)")
        return rows, why
    logs = tempfile.mkdtemp(prefix="radiosity-bench-slurm-")
    rows.append({"part": "c", "cluster": "SLURMCluster 2 jobs x 1 worker",
                 **_render_timed(lambda: open_client(2, kind="slurm", quiet=True, cores=1,
                                                     processes=1, memory="1GB",
                                                     walltime="00:10:00", log_directory=logs,
                                                     job_name="radiosity-bench", timeout=120,
                                                     settings=settings_of().cluster,
                                                     **SLURM_LOOPBACK), res)})
    t = time.perf_counter()
    while subprocess.run(["squeue", "-h"], capture_output=True, text=True).stdout.strip():
        if time.perf_counter() - t > 30:
            break
        time.sleep(0.1)
    rows[-1]["queue_empty_after_close_s"] = time.perf_counter() - t
    shutil.rmtree(logs, ignore_errors=True)  # the worker jobs' slurm-*.out
    for r in rows:
        print(f"  {r['cluster']}: up {r['cluster_up_s']:.2f} s, render {r['render_first_s']:.2f} s "
              f"then {r['render_second_s']:.2f} s", flush=True)
    return rows, None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolutions", default="64,96")
    ap.add_argument("--repeat", type=int, default=2, help="timed runs per cluster")
    ap.add_argument("--rounds", type=int, default=3, help="fresh clusters per shape, alternated")
    ap.add_argument("--overhead-res", type=int, default=64)
    ap.add_argument("--render-res", type=int, default=16)
    ap.add_argument("--no-slurm", action="store_true")
    a = ap.parse_args(argv)
    res = [int(r) for r in a.resolutions.split(",") if r]
    load_before = os.getloadavg()

    print("(a) visibility: processes against threads", flush=True)
    ra = bench_shapes(res, a.repeat, a.rounds)
    print("(b) scheduler overhead", flush=True)
    rb = bench_overhead(a.overhead_res, a.repeat)
    print("(c) three-rectangles render: Slurm against LocalCluster", flush=True)
    if a.no_slurm:
        rc, why = [], "--no-slurm"
    else:
        rc, why = bench_slurm(a.render_res)

    print()
    print(table(ra, ["resolution", "shape", "threads", "sub_elements", "tasks", "unit",
                     "visibility_s", "median_s", "idle_fraction"]))
    print()
    print(table(rb, ["what", "tls", "tasks", "time_s", "tasks_per_s", "ms_per_task", "idle_ms_per_task"]))
    if rc:
        print()
        print(table(rc, ["cluster", "cluster_up_s", "render_first_s", "render_second_s", "close_s",
                         "total_s", "queue_empty_after_close_s"]))
    fn = write("bench_cluster", ra + rb + rc, {"render_resolution": a.render_res, "slurm_skipped": why,
                                               "python": sys.executable,
                                               "loadavg_before": load_before,
                                               "loadavg_after": os.getloadavg()})
    print(f"load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f} "
          f"(other jobs on the same cores make single figures noisy)")
    print(f"\nwrote {fn}")


if __name__ == "__main__":
    main()
