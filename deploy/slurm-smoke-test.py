#!/usr/bin/env python3
"""Smoke test: Dask workers as real Slurm jobs via dask-jobqueue.

Run after deploy/slurm-up.sh (needs sbatch/squeue on PATH and a Slurm that
accepts jobs). Starts a SLURMCluster on loopback, scales to N workers, runs a
trivial task, closes the cluster and checks that the queue is empty again.
Prints the timings. Exit code 0 on success, 1 on failure.

    python3 deploy/slurm-smoke-test.py [--workers 1] [--timeout 60]
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time


def squeue_ids() -> list[str]:
    out = subprocess.run(["squeue", "-h", "-o", "%i"], capture_output=True, text=True, check=True)
    return out.stdout.split()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=60.0)
    args = ap.parse_args()

    os.environ.setdefault("SLURM_CONF", "/etc/slurm/slurm.conf")
    from dask.distributed import Client
    from dask_jobqueue import SLURMCluster

    # Worker job logs (slurm-<id>.out) go here, not into the current directory.
    logdir = tempfile.mkdtemp(prefix="radiosity-smoke-logs-")
    t = {}
    t0 = time.perf_counter()
    cluster = SLURMCluster(
        cores=1,
        processes=1,
        memory="1GB",
        python=sys.executable,
        walltime="00:10:00",
        scheduler_options={"host": "127.0.0.1", "dashboard_address": "127.0.0.1:0"},
        worker_extra_args=["--host", "127.0.0.1"],
        # A unique name so the check below only concerns our own jobs.
        job_name=f"radiosity-smoke-{os.getpid()}",
        log_directory=logdir,
    )
    client = Client(cluster)
    t["cluster_start_s"] = time.perf_counter() - t0
    print("job script:\n" + cluster.job_script(), flush=True)
    ok = False
    try:
        t1 = time.perf_counter()
        cluster.scale(args.workers)
        client.wait_for_workers(args.workers, timeout=args.timeout)
        t["workers_connected_after_scale_s"] = time.perf_counter() - t1
        print("squeue while running:", squeue_ids(), flush=True)

        t2 = time.perf_counter()
        result = client.submit(lambda x: x + 1, 1).result(timeout=args.timeout)
        t["first_task_s"] = time.perf_counter() - t2
        print("result:", result, flush=True)
        ok = result == 2
    finally:
        t3 = time.perf_counter()
        client.close()
        cluster.close()
        t["close_s"] = time.perf_counter() - t3
        t4 = time.perf_counter()
        left = squeue_ids()
        while left and time.perf_counter() - t4 < args.timeout:
            time.sleep(0.2)
            left = squeue_ids()
        t["queue_empty_after_close_s"] = time.perf_counter() - t4
    if left:
        print(f"FAIL: squeue not empty after close: {left}", file=sys.stderr)
        ok = False
    if ok:
        shutil.rmtree(logdir, ignore_errors=True)
    else:
        print(f"worker job logs kept in {logdir}", file=sys.stderr)
    for k, v in t.items():
        print(f"timing {k} = {v:.2f}")
    print("OK" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
