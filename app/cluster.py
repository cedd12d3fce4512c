"""Where the work runs: a LocalCluster bound to 127.0.0.1 by default, or an existing scheduler.

This is the only module that creates clusters (and, for HPC batch systems, the only one that
imports dask_jobqueue). Everything else receives a `distributed.Client`.
"""

from __future__ import annotations

import contextlib
import os

from . import config
from .errors import RadiosityError

JOBQUEUE_KINDS = {"slurm": "SLURMCluster", "pbs": "PBSCluster", "sge": "SGECluster",
                  "lsf": "LSFCluster"}


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


@contextlib.contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None, kind: str | None = None,
                threads_per_worker: int | None = None, quiet: bool = False, echo=print):
    """Yield a Client: to `scheduler` if given, else a new cluster of `kind` with `workers` workers."""
    from distributed import Client, LocalCluster

    kind = config.get("cluster.kind", kind)
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except OSError as e:
            raise RadiosityError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
        with client:
            if not quiet:
                echo(f"dashboard: {client.dashboard_link}")
            yield client
        return
    n = workers or config.get("cluster.workers") or default_workers()
    if kind == "local":
        cluster = LocalCluster(n_workers=n,
                               threads_per_worker=config.get("cluster.threads-per-worker", threads_per_worker),
                               processes=True, host=config.get("cluster.host"),
                               dashboard_address=config.get("cluster.dashboard-address"),
                               silence_logs=40)
    elif kind in JOBQUEUE_KINDS:
        cluster = _jobqueue_cluster(kind, n)
    else:
        raise RadiosityError(f"unknown cluster kind {kind!r}: use one of local, "
                             + ", ".join(JOBQUEUE_KINDS))
    with cluster, Client(cluster) as client:
        if not quiet:
            echo(f"dashboard: {client.dashboard_link}")
        if kind != "local":
            client.wait_for_workers(n, timeout=300)
        yield client


def _jobqueue_cluster(kind: str, n: int):
    try:
        import dask_jobqueue
    except ImportError:  # pragma: no cover - dependency of the package
        raise RadiosityError("--cluster %s needs dask-jobqueue: pip install dask-jobqueue" % kind) from None
    cls = getattr(dask_jobqueue, JOBQUEUE_KINDS[kind])
    cluster = cls()
    cluster.scale(n)
    return cluster
