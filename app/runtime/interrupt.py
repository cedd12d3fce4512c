"""Ctrl-C around a local cluster: its start shielded so that the signal reaches the driver only
(not every worker process), and its workers dropped at once when the user interrupts (not after
their running tasks). Used by runtime/cluster.open_client."""

from __future__ import annotations

import contextlib
import os
import time


def start_shielded(build):
    """`build()` (a LocalCluster of worker processes) on a thread of its own that blocks SIGINT:
    every thread distributed starts from it, and so every worker process those spawn (a
    restarted or an adaptive one too), inherits the blocked signal, so that Ctrl-C in a
    terminal, which signals the whole process group, reaches the driver only (no worker prints
    its own KeyboardInterrupt traceback; the driver stops them). This thread keeps SIGINT and
    waits in short joins, so Ctrl-C while the workers start raises KeyboardInterrupt at once
    (ignoring SIGINT meanwhile, as before, lost it: the run went on). Then the worker processes
    spawned so far are killed (one still unpickling its start-up data would outlive the driver,
    or fail with a traceback once the driver's semaphores are gone), and a cluster finished
    after that is closed by its thread."""
    import signal
    import threading

    box: dict = {}
    lock = threading.Lock()

    def run():
        try:
            cluster = build()
        except BaseException as e:  # noqa: BLE001 - handed to the caller
            box["error"] = e
            return
        with lock:
            box["cluster"] = cluster
            abandoned = box.get("abandoned", False)
        if abandoned:
            drop_workers(cluster)
            with contextlib.suppress(Exception):
                cluster.close()

    # multiprocessing starts its resource tracker from the first thread that needs it, and
    # unblocks SIGINT in that thread afterwards (whatever it was): started here first
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    before = _children()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        t = threading.Thread(target=run, name="radiosity cluster start", daemon=True)
        t.start()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
    try:
        while t.is_alive():
            t.join(0.05)
    except KeyboardInterrupt:
        with lock:
            box["abandoned"] = True
            cluster = box.get("cluster")
        if cluster is not None:  # finished just now: closed here instead
            drop_workers(cluster)
            with contextlib.suppress(Exception):
                cluster.close()
        _quiet_teardown()
        # the processes spawned so far, killed until the start has failed for want of them and
        # no new one came for 0.1 s (a spawn under way shows up a few ms later: its start-up
        # data must be written, not cut off by our exit); at most 1 s
        t0 = last = time.monotonic()
        while time.monotonic() - t0 < 1.0:
            new = _children() - before
            for pid in new:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
            before |= new
            if new:
                last = time.monotonic()
            elif not t.is_alive() and time.monotonic() - last > 0.1:
                break
            time.sleep(0.01)
        raise
    if "error" in box:
        raise box["error"]
    return box["cluster"]


def _children() -> set:
    """The process ids of this process's children (forked ones included that multiprocessing
    does not list yet: their start-up data is still being written)."""
    import psutil  # a dependency of distributed

    try:
        return {c.pid for c in psutil.Process().children()}
    except psutil.Error:
        return set()


def drop_workers(cluster) -> None:
    """Ctrl-C: stop the local workers now, neither retired nor waited for (their running tasks
    are not in any ledger: a resume computes them again). A worker process is killed, its
    nanny told first not to start another; an in-process worker is closed without waiting for
    its threads, which finish their kernel call in the background (the CLI then exits without
    waiting for them). Retiring them waited for their tasks (docs/src/measurements/choices.md)."""
    import signal

    from distributed import Nanny

    _quiet_teardown()
    for w in list(getattr(cluster, "workers", {}).values()):
        try:
            if isinstance(w, Nanny):
                w.close_gracefully(reason="interrupted")  # no restart when its process dies
                if w.pid:
                    os.kill(w.pid, signal.SIGKILL)
            else:
                cluster.sync(w.close, executor_wait=False, reason="interrupted")
        except Exception:  # noqa: BLE001 - stopping anyway: the rest still goes
            pass


def _quiet_teardown() -> None:
    """After Ctrl-C: the asyncio and distributed loggers silenced for the rest of the process.
    The calls to the workers cut short (a scatter's update_data, a gather, the batched stream)
    end in CommClosedError, which asyncio ("Task exception was never retrieved") and
    distributed (its handlers are silenced by local_cluster only until the cluster closes)
    report with tracebacks around the one line that says what was kept."""
    import logging

    for name in ("asyncio", "distributed"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
