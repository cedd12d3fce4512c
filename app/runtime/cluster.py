"""Where the work runs: a LocalCluster bound to 127.0.0.1 by default, a batch-system cluster
(Slurm, PBS, SGE, LSF through dask-jobqueue), or an existing scheduler.

Design notes and measurements: docs/src/design/runtime-cluster.md.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import subprocess
import sys
import time
import warnings

from radiosity import config
from radiosity.errors import RadiosityError
from radiosity.runtime.dashboard import dashboard_link
from radiosity.runtime.interrupt import drop_workers, start_shielded

JOBQUEUE_KINDS = {"slurm": "SLURMCluster", "pbs": "PBSCluster", "sge": "SGECluster",
                  "lsf": "LSFCluster"}
SUBMIT_COMMANDS = {"slurm": "sbatch", "pbs": "qsub", "sge": "qsub", "lsf": "bsub"}
STATUS_COMMANDS = {"slurm": ["squeue", "-h", "-o", "%i %T %R", "-j"], "pbs": ["qstat"],
                   "sge": ["qstat", "-j"], "lsf": ["bjobs"]}
DEFAULT_WORKER_TIMEOUT = 300.0


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def tls_mode(tls) -> str | None:
    """None (plain TCP) or "temporary", from `tls` (radiosity.cluster.tls, or --tls)."""
    v = tls
    if v is None or v is False or (isinstance(v, str) and v.strip().lower() in ("", "false", "no", "off", "none")):
        return None
    if v is True or (isinstance(v, str) and v.strip().lower() in ("temporary", "true", "yes", "on")):
        return "temporary"
    raise RadiosityError(f"radiosity.cluster.tls must be false or temporary, not {v!r}")


def make_security(tls):
    """A `distributed.security.Security` for a new cluster, or None for plain TCP."""
    if tls_mode(tls) is None:
        return None
    from distributed.security import Security

    try:
        return Security.temporary()
    except ImportError as e:  # pragma: no cover - cryptography is a declared dependency
        raise RadiosityError(f"radiosity.cluster.tls: temporary needs the cryptography package: {e}") from None


def adaptive_bounds(adaptive, n: int) -> tuple[int, int] | None:
    """(minimum, maximum) workers for `cluster.adapt`, or None for a fixed size.

    `adaptive` (radiosity.cluster.adaptive, or --adaptive): false; true (1 .. n); [min, max];
    {minimum: .., maximum: ..}; or "min:max". The minimum is at least 1: the engine sizes its
    task windows by the workers it sees when a stage starts."""
    v = adaptive
    if v is None or v is False or (isinstance(v, str) and v.strip().lower() in ("", "false", "no", "off")):
        return None
    if v is True or (isinstance(v, str) and v.strip().lower() in ("true", "yes", "on")):
        lo, hi = 1, n
    elif isinstance(v, dict):
        lo, hi = v.get("minimum", 1), v.get("maximum", n)
    elif isinstance(v, str) and ":" in v:
        a, b = v.split(":", 1)
        lo, hi = (int(a) if a.strip() else 1), (int(b) if b.strip() else n)
    elif isinstance(v, (list, tuple)) and len(v) == 2:
        lo, hi = v
    else:
        raise RadiosityError(f"radiosity.cluster.adaptive must be false, true, [minimum, maximum] or "
                             f"'minimum:maximum', not {v!r}")
    try:
        lo, hi = max(1, int(lo)), int(hi)
    except (TypeError, ValueError):
        raise RadiosityError(f"radiosity.cluster.adaptive: bad bounds {v!r}") from None
    if hi < lo:
        raise RadiosityError(f"radiosity.cluster.adaptive: maximum {hi} < minimum {lo}")
    return lo, hi


def jobqueue_kwargs(kind: str, threads_per_worker: int | None = None, security=None, **overrides) -> dict:
    """Keyword arguments for the dask-jobqueue cluster of `kind`: the overrides that are not None
    (config supplies the rest), the driver's interpreter unless configured, and `security`."""
    section = f"jobqueue.{kind}"
    kw = {k.replace("-", "_"): v for k, v in overrides.items() if v is not None}
    if kind in ("sge", "lsf") and "account" in kw:  # their keyword is `project`
        kw.setdefault("project", kw.pop("account"))
    if "python" not in kw and config.dask_get(f"{section}.python") is None:
        kw["python"] = sys.executable
    if threads_per_worker and "processes" not in kw:
        cores = kw.get("cores") or config.dask_get(f"{section}.cores")
        if cores:
            kw["processes"] = max(1, int(cores) // int(threads_per_worker))
    if security is not None:
        kw["security"] = security
    # the engine's dashboard page on the batch cluster's scheduler too (merged with the config's
    # scheduler options, which an explicit scheduler_options would otherwise replace)
    so = dict(kw.get("scheduler_options") or config.dask_get(f"{section}.scheduler-options", {}) or {})
    if "radiosity.runtime.dashboard" not in so.get("preload", []):
        so["preload"] = [*so.get("preload", []), "radiosity.runtime.dashboard"]
    kw["scheduler_options"] = so
    return kw


def jobqueue_cluster(kind: str, threads_per_worker: int | None = None, security=None, **overrides):
    """A dask-jobqueue cluster of `kind` (no jobs submitted yet): config + overrides."""
    try:
        import dask_jobqueue
    except ImportError:  # pragma: no cover - dependency of the package
        raise RadiosityError(f"--cluster {kind} needs dask-jobqueue: pip install dask-jobqueue") from None
    cls = getattr(dask_jobqueue, JOBQUEUE_KINDS[kind])
    kw = jobqueue_kwargs(kind, threads_per_worker, security, **overrides)
    try:
        cluster = cls(**kw)
    except ValueError as e:  # e.g. no cores/memory anywhere
        raise RadiosityError(f"cannot configure the {kind} workers: {e} (set jobqueue.{kind}.cores and "
                             f".memory in deploy/jobqueue.yaml, via DASK_CONFIG or ~/.config/dask/)") from None
    except TypeError as e:
        raise RadiosityError(f"bad {JOBQUEUE_KINDS[kind]} option: {e}") from None
    cluster.radiosity_python = kw.get("python") or config.dask_get(f"jobqueue.{kind}.python")
    return cluster


#: glibc's malloc settings the workers get from radiosity.cluster.* (config key, variable); a
#: variable in the environment the process started with wins
_MALLOC = (("malloc-trim-threshold", "MALLOC_TRIM_THRESHOLD_"),
           ("malloc-mmap-threshold", "MALLOC_MMAP_THRESHOLD_"))
_USER_MALLOC = {var: os.environ.get(var) for _, var in _MALLOC}


def tune_malloc(settings) -> dict:
    """This process's glibc malloc thresholds from `settings` (a settings.ClusterSettings:
    radiosity.cluster.malloc-*; as the local
    workers get them by variable), unless the process started with the variable: the driver
    runs the solve's passes, its final gather and the node table, whose large arrays would
    otherwise be fresh mappings that page-fault on first touch (measured:
    docs/src/measurements/choices.md). Returns {variable: value} of what was set (empty
    without glibc's mallopt)."""
    import ctypes

    params = {"MALLOC_TRIM_THRESHOLD_": -1, "MALLOC_MMAP_THRESHOLD_": -3}  # M_TRIM_, M_MMAP_
    mallopt = getattr(_libc(), "mallopt", None)
    if mallopt is None:
        return {}
    done = {}
    for key, var in _MALLOC:
        value = getattr(settings, key.replace("-", "_"))
        if value is not None and _USER_MALLOC[var] is None \
                and mallopt(ctypes.c_int(params[var]), ctypes.c_int(int(value))) == 1:
            done[var] = int(value)
    return done


def trim_malloc() -> bool:
    """Hand the heap's free pages back to the system (glibc's malloc_trim(0), all arenas):
    tune_malloc keeps arrays up to 64 MiB on the heap, and a heap freed in its middle keeps its
    pages, so a stage that frees many such arrays calls this once they are gone. False without
    glibc."""
    import ctypes

    trim = getattr(_libc(), "malloc_trim", None)
    if trim is None:
        return False
    trim(ctypes.c_size_t(0))
    return True


@functools.lru_cache(maxsize=1)
def _libc():
    """The C library (find_library runs ldconfig: once a process), None where it cannot load."""
    import ctypes
    import ctypes.util

    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None


def scatterable(cls):
    """Class decorator: distributed serializes an instance by its attributes, each array as a
    buffer of its own, instead of pickling the whole object into one message (its fallback for
    classes it does not know), which is faster for large arrays (docs/src/measurements/choices.md)."""
    from distributed.protocol import dask_deserialize, dask_serialize, deserialize, serialize

    @dask_serialize.register(cls)
    def _dumps(obj):
        return serialize(dict(vars(obj)), iterate_collection=True, on_error="raise")

    @dask_deserialize.register(cls)
    def _loads(header, frames):
        obj = cls.__new__(cls)
        obj.__dict__.update(deserialize(header, frames))
        return obj

    return cls


def _direct(client) -> bool:
    """Whether scatter() sends straight to the workers: radiosity.cluster.direct-scatter (as
    open_client recorded it on the client; auto for other clients) true or false, or auto: when
    every worker listens on this machine's loopback (a LocalCluster)."""
    mode = getattr(client, "radiosity_direct_scatter", "auto")
    if mode != "auto":
        return bool(mode)
    try:
        addrs = list(client.scheduler_info()["workers"])
    except Exception:  # noqa: BLE001 - no scheduler info: the safe path
        return False
    local = ("127.0.0.1", "localhost", "[::1]", "::1")
    return bool(addrs) and all(a.startswith("inproc://")
                               or a.split("://", 1)[-1].rsplit(":", 1)[0] in local
                               for a in addrs)


def scatter(client, items: list, broadcast: bool = False) -> list:
    """client.scatter(items) (futures, unhashed). Where _direct says so, straight to the
    workers, and a broadcast as the same keys sent to each worker in turn: distributed sends
    the bytes through the scheduler, or with direct=True to one worker and then from worker to
    worker, both slower for local workers than each in turn (docs/src/measurements/choices.md)."""
    if not _direct(client):
        return client.scatter(items, broadcast=broadcast, hash=False)
    if not broadcast:
        return client.scatter(items, hash=False, direct=True)
    import uuid

    keys = [f"scatter-{uuid.uuid4().hex}" for _ in items]
    out = None
    for w in client.scheduler_info()["workers"]:
        got = client.scatter(dict(zip(keys, items)), workers=[w], hash=False, direct=True)
        out = out or [got[k] for k in keys]
    return out if out is not None else client.scatter(items, broadcast=True, hash=False)


class Scattered:
    """A value broadcast to the workers once (scatter), sent again when its copies are lost:
    `future()` before every submit. A worker killed mid-run takes its copy with it; where that
    was the last one the scheduler marks the key lost, and a retried task that named it would
    fail the same way ("lost dependencies") however often it ran. straight: scatter()'s direct
    path where _direct allows (else distributed's own, through the scheduler)."""

    def __init__(self, client, value, straight: bool = True):
        self.client = client
        self.value = value
        self.straight = straight
        self.sent = 0
        self._future = None

    def future(self):
        f = self._future
        if f is None or f.status != "finished":
            if self.straight:
                [f] = scatter(self.client, [self.value], broadcast=True)
            else:
                [f] = self.client.scatter([self.value], broadcast=True, hash=False)
            self._future = f
            self.sent += 1
        return f


def _mode(value) -> str:
    """radiosity.cluster.processes as auto | on | off (YAML booleans, environment strings)."""
    text = str(value).strip().lower()
    for mode, words in (("on", ("true", "on", "yes", "1")), ("off", ("false", "off", "no", "0")),
                        ("auto", ("auto", "none"))):
        if text in words:
            return mode
    raise RadiosityError(f"radiosity.cluster.processes must be auto, true or false, got {value!r}")


def local_mode(processes, samples: int | None, limit: int) -> tuple[bool, str]:
    """(in_process, why) for a local cluster: `processes` is the setting (auto | true | false),
    `samples` the camera samples of the scene (width x height x subpixel^2; None: unknown),
    `limit` radiosity.cluster.in-process-samples. Small scenes run on threads in this process:
    no worker start, no pickling, one numba cache load (every kernel releases the GIL)."""
    mode = _mode(processes)
    if mode != "auto":
        return mode == "off", f"stated (processes: {'true' if mode == 'on' else 'false'})"
    if samples is None:
        return False, "auto, scene size unknown here"
    if samples <= limit:
        return True, f"auto, {samples} camera samples <= {limit}"
    return False, f"auto, {samples} camera samples > {limit}"


def local_cluster(n: int, settings, threads_per_worker: int | None = None, security=None,
                  processes: bool | None = None):
    """A LocalCluster on `settings.host` (radiosity.cluster.*: 127.0.0.1) with its dashboard on
    loopback."""
    from distributed import LocalCluster

    if processes is None:
        processes = _mode(settings.processes) != "off"
    processes = bool(processes)
    kw = {}
    if security is not None:
        kw.update(security=security, protocol="tls://", host=settings.host)
    elif processes:
        kw.update(host=settings.host)
    else:
        # in-process workers talk over inproc://, which binds no socket (and takes no host).
        # No memory limit: their monitor would measure this whole process (the driver's arrays
        # too) against a share of the machine and pause them, and a paused worker takes no
        # task and no scatter ("No valid workers found" after a 10^6-triangle cluster layer)
        kw.update(memory_limit=0)
    env = {}
    for key, var in _MALLOC:
        value = getattr(settings, key.replace("-", "_"))
        if value is not None and _USER_MALLOC[var] is None:
            # a nanny takes the variable from os.environ over its config, and puts Dask's
            # 65536 there for the trim threshold when it starts a worker: set ours in both
            # (workers added later find it too)
            os.environ[var] = str(int(value))
            env[f"distributed.nanny.pre-spawn-environ.{var}"] = int(value)
    with config.dask_set(env):
        return LocalCluster(n_workers=n,
                            threads_per_worker=(settings.threads_per_worker if threads_per_worker
                                                is None else threads_per_worker),
                            processes=processes,
                            dashboard_address=settings.dashboard_address,
                            # a failed task's traceback goes to the run's log file (faults.py),
                            # not to the terminal from every worker that tried it
                            silence_logs=50, scheduler_kwargs={"preload": [  # dashboard.py's page
                                *config.dask_get("distributed.scheduler.preload", []),
                                "radiosity.runtime.dashboard"]},
                            **kw)


@contextlib.contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None, kind: str | None = None,
                threads_per_worker: int | None = None, quiet: bool = False, echo=print, *,
                adaptive=None, timeout: float | None = None, tls=None, in_process: bool | None = None,
                where: str | None = None, settings, **jobqueue_overrides):
    """Yield a Client: to `scheduler` if given, else a new cluster of `kind` with `workers` workers.

    settings: the run's settings.ClusterSettings (radiosity.cluster.*), which every keyword
    given here overrides. `kind`: local (default: `radiosity.cluster.kind`), slurm, pbs, sge or lsf.
    `adaptive`: false | true | (minimum, maximum) (default `radiosity.cluster.adaptive`); with it
    `workers` is the maximum. `timeout`: seconds to wait for the workers (default
    `radiosity.cluster.worker-timeout`, 300). `tls`: false | "temporary" (default
    `radiosity.cluster.tls`). `in_process`: a local cluster's workers as threads in this process
    (None: radiosity.cluster.processes; local_mode decides it per scene), `where` its reason for
    the first line. `jobqueue_overrides`: cores, memory, processes, walltime, queue,
    account or any keyword of the dask-jobqueue cluster class; None values are ignored.
    """
    from distributed import Client

    cs = settings
    tune_malloc(cs)
    kind = kind or cs.kind
    tls = cs.tls if tls is None else tls
    if scheduler:
        if tls_mode(tls) is not None:
            raise RadiosityError("radiosity.cluster.tls: temporary makes certificates for a cluster that "
                                 "this run starts; to reach a running scheduler over TLS, set "
                                 "distributed.comm.tls.* (ca-file, client cert and key) instead")
        try:
            client = Client(scheduler, timeout="20s")
        except OSError as e:
            raise RadiosityError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
        with client:
            client.radiosity_direct_scatter = cs.direct_scatter
            if not quiet:
                echo(f"dashboard: {dashboard_link(client)}")
            yield client
        return
    n = workers or cs.workers or default_workers()
    bounds = adaptive_bounds(cs.adaptive if adaptive is None else adaptive, n)
    wait_s = float(timeout if timeout is not None else (cs.worker_timeout or DEFAULT_WORKER_TIMEOUT))
    security = make_security(tls)
    given = {k: v for k, v in jobqueue_overrides.items() if v is not None}
    if kind == "local":
        if given:
            warnings.warn(f"{', '.join(sorted(given))} only apply to batch-system clusters "
                          f"(--cluster slurm|pbs|sge|lsf); ignored for the local cluster")
        if in_process is None:
            in_process = _mode(cs.processes) == "off"
        processes = not in_process
        build = functools.partial(local_cluster, 0 if bounds else n, cs, threads_per_worker,
                                  security, processes)
        cluster = start_shielded(build) if processes else build()  # Ctrl-C: the driver only
    elif kind in JOBQUEUE_KINDS:
        submit = SUBMIT_COMMANDS[kind]
        if shutil.which(submit) is None:
            raise RadiosityError(f"--cluster {kind} submits the workers with `{submit}`, which is not on "
                                 f"PATH here: run on a login or compute node of the cluster")
        cluster = jobqueue_cluster(kind, threads_per_worker, security, **given)
    else:
        raise RadiosityError(f"unknown cluster kind {kind!r}: use one of local, "
                             + ", ".join(JOBQUEUE_KINDS))
    with cluster, Client(cluster, security=security) as client:
        client.radiosity_direct_scatter = cs.direct_scatter
        if not quiet:
            if kind == "local":
                echo(f"cluster: {n} local worker{'s' if n != 1 else ''} as "
                     f"{'threads in this process' if in_process else 'processes'}"
                     + (f" ({where})" if where else ""))
            echo(f"dashboard: {dashboard_link(client)}")
            if kind == "local" and cs.dashboard_address:
                from radiosity.runtime.dashboard import page_url

                echo(f"radiosity page: {page_url(client)}")
        if bounds:
            cluster.adapt(minimum=bounds[0], maximum=bounds[1])
            need = bounds[0]
        else:
            if kind != "local":
                cluster.scale(n)
            need = n
        if kind != "local" and not quiet:
            job = cluster._dummy_job
            echo(f"{kind}: {'adaptive ' + str(bounds[0]) + '..' + str(bounds[1]) if bounds else n} "
                 f"worker(s), {job.worker_processes} per job ({job.worker_process_threads} thread(s) "
                 f"each, {job.worker_process_memory}), scheduler {cluster.scheduler_address}")
        _wait_for_workers(client, cluster, kind, need, wait_s, echo=None if quiet else echo)
        stop = _retire_workers
        try:
            yield client
        except KeyboardInterrupt:
            stop = drop_workers  # Ctrl-C: stop now, not after the running tasks
            raise
        finally:
            if kind == "local":
                stop(cluster)


def _retire_workers(cluster, timeout: float = 10.0) -> None:
    """Close the workers before the client and the scheduler: a worker's heartbeat can then no
    longer meet a scheduler that is closing (the intermittent CommClosedError traceback at
    the end of a successful run)."""
    try:
        cluster.scale(0)
        t0 = time.monotonic()
        while cluster.workers and time.monotonic() - t0 < timeout:
            time.sleep(0.02)
    except Exception:  # shutting down: nothing here may turn a finished run into a failure
        pass


def slurm_unavailable(partition_idle: bool = True) -> str | None:
    """None if a Slurm controller answers here and (with `partition_idle`) a node is idle and
    the queue is empty; otherwise why not (for skipping tests and benchmarks)."""
    if shutil.which("sinfo") is None or shutil.which("sbatch") is None:
        return "sinfo/sbatch are not installed"
    try:
        out = subprocess.run(["sinfo", "-h", "-o", "%T"], capture_output=True, text=True, timeout=15)
    except (OSError, subprocess.SubprocessError) as e:
        return f"sinfo failed: {e}"
    if out.returncode != 0:
        lines = (out.stderr or out.stdout).strip().splitlines()
        return f"sinfo failed: {lines[-1] if lines else 'exit status %d' % out.returncode}"
    states = out.stdout.split()
    if not partition_idle:
        return None
    if "idle" not in states:
        return f"no idle Slurm node (sinfo says {' '.join(states) or 'nothing'})"
    q = subprocess.run(["squeue", "-h", "-o", "%i"], capture_output=True, text=True, timeout=15)
    if q.returncode != 0 or q.stdout.strip():
        return f"the Slurm queue is not empty: {q.stdout.split() or q.stderr.strip()}"
    return None


def _wait_for_workers(client, cluster, kind: str, n: int, timeout: float, echo=None) -> None:
    t0 = time.perf_counter()
    try:
        client.wait_for_workers(n, timeout=timeout)
    except (TimeoutError, OSError) as e:
        have = len(client.scheduler_info().get("workers", {}))
        raise RadiosityError(_no_workers_message(cluster, kind, have, n, timeout, e)) from None
    if kind != "local" and echo is not None:
        echo(f"{kind}: {n} worker(s) connected after {time.perf_counter() - t0:.1f} s")


def _no_workers_message(cluster, kind: str, have: int, n: int, timeout: float, err) -> str:
    addr = getattr(cluster, "scheduler_address", "?")
    msg = f"only {have} of {n} Dask workers connected within {timeout:g} s ({kind} cluster, scheduler {addr})."
    if kind == "local":
        return msg + f" Check the machine's memory and the worker logs; underlying error: {err}"
    job = getattr(cluster, "_dummy_job", None)
    ids = [w.job_id for w in getattr(cluster, "workers", {}).values() if getattr(w, "job_id", None)]
    state = ""
    if ids:
        cmd = STATUS_COMMANDS[kind] + ([",".join(ids)] if kind == "slurm" else ids)
        try:
            out = subprocess.run(cmd, capture_output=True, text=True, timeout=10)
            state = (out.stdout or out.stderr).strip()
        except (OSError, subprocess.SubprocessError):
            state = ""
    logdir = getattr(job, "log_directory", None) or os.getcwd()
    python = getattr(cluster, "radiosity_python", None) or sys.executable
    parts = [msg,
             f"Jobs: {', '.join(ids) if ids else 'none submitted (see the error above)'}"
             + (f"; `{' '.join(STATUS_COMMANDS[kind][:1])}` says: {state}" if state else "") + ".",
             "Check: (1) are the jobs still pending (queue, partition, account, walltime, cores or memory "
             f"larger than a node)? see `{STATUS_COMMANDS[kind][0]}`;",
             f"(2) the worker job logs in {logdir} (e.g. python {python} missing on the compute nodes, "
             "`radiosity` not importable, out of memory);",
             f"(3) can the compute nodes reach the scheduler at {addr}? set `interface:` (e.g. ib0) in "
             "jobqueue.yaml, check firewalls;"]
    if getattr(getattr(cluster, "security", None), "tls_ca_file", None):
        parts.append("(4) TLS: shared-temp-directory must be shared storage that the workers can read;")
    parts.append("for a busy queue raise radiosity.cluster.worker-timeout or use adaptive scaling.")
    return " ".join(parts)
