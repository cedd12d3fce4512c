"""Fault injection with real processes (issue 15): two runs into one run directory, a lock left
by a killed run, a full and a read-only filesystem, a corrupted compressed chunk, a worker and
the driver killed during solve. Each ends in one clear line, and the run can be continued."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from helpers import scene_path
from radiosity.settings import options as settings_of

S = scene_path("three-rectangles")
from helpers import ROOT  # noqa: E402


def env():
    e = dict(os.environ)
    e.setdefault("PYTHONPATH", "")
    return e


def start(*args, **kw) -> subprocess.Popen:
    """`radiosity ARGS` as a process of its own (its own process group, so that it and its
    workers can be signalled together)."""
    return subprocess.Popen([sys.executable, "-m", "radiosity.cli", *map(str, args)], cwd=ROOT,
                            env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kw)


def run(*args, timeout=300) -> subprocess.CompletedProcess:
    p = start(*args)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate()
        raise AssertionError(f"radiosity {' '.join(map(str, args))} timed out:\n{err[-3000:]}")
    return subprocess.CompletedProcess(p.args, p.returncode, out, err)


def wait_for(pred, timeout=120, what="condition", proc=None):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if pred():
            return
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the process ended before {what}: {proc.stderr.read()[-3000:]}")
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def error_lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.startswith("error:")]


def kill_group(p: subprocess.Popen, sig=signal.SIGKILL) -> None:
    try:
        os.killpg(p.pid, sig)
    except ProcessLookupError:
        pass
    p.wait(60)


SMALL = ["--resolution", "8", "--workers", "1", "--no-preview"]


# ----------------------------------------------------------------------------- the lock

def test_run_lock_refuses_a_live_owner_and_takes_over_a_dead_one(tmp_path):
    from radiosity.errors import StoreError
    from radiosity.runtime.runlock import LOCK, run_lock

    d = tmp_path / "run"
    d.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom radiosity.runtime.runlock import run_lock\n"
         f"with run_lock({str(d)!r}, 'radiosity holder'):\n    print('held', flush=True)\n"
         "    time.sleep(120)\n"], env=env(), stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(StoreError, match=f"in use by another radiosity run \\(pid {holder.pid} "
                                             f"on {socket.gethostname()}, `radiosity holder`"):
            with run_lock(str(d)):
                pass
    finally:
        holder.kill()  # SIGKILL: its lock file stays behind
        holder.wait()
    assert (d / LOCK).exists()
    with pytest.warns(UserWarning, match=f"taking over the lock of a run that is no longer "
                                         f"running \\(pid {holder.pid}"):
        with run_lock(str(d), "radiosity next"):
            assert json.loads((d / LOCK).read_text())["pid"] == os.getpid()
    assert not (d / LOCK).exists()  # a clean exit removes it


def test_a_lock_from_another_host_names_the_file_to_delete(tmp_path):
    from radiosity.errors import StoreError
    from radiosity.runtime.runlock import LOCK, run_lock

    (tmp_path / LOCK).write_text(json.dumps({"pid": 1, "host": "node-17", "started": time.time(),
                                             "command": "radiosity render x"}))
    with pytest.raises(StoreError, match=f"on node-17.*delete {tmp_path / LOCK}"):
        with run_lock(str(tmp_path)):
            pass


def test_two_concurrent_renders_into_one_out_one_is_refused(tmp_path):
    out = tmp_path / "run"
    a = start("render", S, "--out", out, *SMALL)
    try:
        wait_for(lambda: (out / "run.lock").exists() and (out / "run.lock").stat().st_size > 0,
                 120, "the first run's lock", a)
        b = run("render", S, "--out", out, *SMALL, timeout=120)
        assert b.returncode == 2, b.stderr
        [line] = error_lines(b.stderr)
        assert f"in use by another radiosity run (pid {a.pid} on {socket.gethostname()}" in line
        assert "Traceback" not in b.stderr and "dashboard" not in b.stdout
        out_a, err_a = a.communicate(timeout=300)
        assert a.returncode == 0, err_a
        assert "Traceback" not in err_a
    finally:
        if a.poll() is None:
            kill_group(a)
    assert (out / "image.png").exists() and not (out / "run.lock").exists()


# ----------------------------------------------------------------------------- filesystems

@pytest.fixture
def tmpfs(tmp_path):
    """A small tmpfs of our own (4 MiB): full and read-only filesystems for real. Skips only
    where mounting is refused outside CI; under CI=true it must work."""
    d = tmp_path / "fs"
    d.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(d)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        msg = f"cannot mount a tmpfs here: {(r.stderr or r.stdout).strip()}"
        if os.environ.get("CI") == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    try:
        yield d
    finally:
        subprocess.run(["umount", "-l", str(d)], capture_output=True)


def remount(d, mode: str) -> None:
    subprocess.run(["mount", "-o", f"remount,{mode}", str(d)], check=True, capture_output=True)


def fill(d, leave_pages: int) -> str:
    """Fill the filesystem of d, then give back `leave_pages` pages of 4 KiB."""
    fn = os.path.join(d, "filler")
    block = b"\0" * (1 << 16)
    with open(fn, "wb") as f:
        try:
            while True:
                f.write(block)
                f.flush()
        except OSError:
            pass
    size = os.path.getsize(fn)
    os.truncate(fn, max(0, size - leave_pages * 4096))
    return fn


def cli(args, client=None):
    from click.testing import CliRunner

    from radiosity.cli.commands import main

    extra = ["--scheduler", client.scheduler.address] if client is not None else []
    return CliRunner().invoke(main, [str(a) for a in args] + extra)


def one_error(r, *fragments) -> str:
    assert r.exit_code == 2, r.output
    [line] = error_lines(r.output)
    assert "Traceback" not in r.output, r.output
    for f in fragments:
        assert f in line, r.output
    return line


def test_out_on_a_read_only_filesystem(tmpfs):
    remount(tmpfs, "ro")
    r = cli(["render", S, "--out", tmpfs / "run", *SMALL])
    one_error(r, f"cannot create the run directory {tmpfs / 'run'}", "read-only",
              "writable filesystem")
    r = cli(["render", S, "--out", tmpfs, *SMALL])  # exists, but nothing can be written there
    one_error(r, f"cannot write into the run directory {tmpfs}", "read-only")


def test_solve_and_image_on_a_read_only_run(client, tmpfs):
    from helpers import prepared

    run_dir = prepared(client, tmpfs, S, 8)
    remount(tmpfs, "ro")
    try:
        for args in (["solve", run_dir], ["image", run_dir], ["visibility", run_dir, "--resume"]):
            r = cli(args, client if args[0] != "image" else None)
            one_error(r, f"cannot write into the run directory {run_dir}", "read-only",
                      "copy the run directory to a writable filesystem")
            assert "dashboard" not in r.output  # before any cluster
    finally:
        remount(tmpfs, "rw")


def test_full_disk_during_visibility_then_resume(client, tmpfs, tmp_path):
    """ENOSPC while the workers write visibility chunks: one line naming the path, the
    manifest holds only tasks whose bytes are on disk, and --resume completes the matrix
    (equal to one computed on a roomy disk)."""
    from helpers import prepared
    from radiosity.runtime.store import RunStore
    from radiosity.methods.pairs.store import VisibilityStore
    from radiosity.methods.pairs.visibility import dense_visibility

    cornell = scene_path("cornell-box")
    run_dir = prepared(client, tmpfs, cornell, 16, visibility=False)
    ref = prepared(client, tmp_path, cornell, 16, name="ref")
    filler = fill(tmpfs, leave_pages=24)
    r = cli(["visibility", run_dir], client)
    line = one_error(r, f"cannot write {run_dir}/store.zarr/visibility/bits: the filesystem is full",
                     f"then: radiosity visibility {run_dir}", "--resume", "worker traceback in")
    rs = RunStore(run_dir)
    vs = VisibilityStore(rs)
    token, plan, done = vs.token(), vs.plan(), vs.finished(vs.token())
    assert 0 < len(done) < len(plan.tasks), line
    assert all(vs.verify(plan, t, e) for t, e in done.items())
    os.remove(filler)
    r = cli(["visibility", run_dir, "--resume"], client)
    assert r.exit_code == 0, r.output
    rep = json.loads(open(os.path.join(run_dir, "report.json")).read())["visibility"]
    assert rep["tasks_reused"] == len(done) and rep["tasks_computed"] == len(plan.tasks) - len(done)
    np.testing.assert_array_equal(dense_visibility(RunStore(run_dir)), dense_visibility(RunStore(ref)))


# ----------------------------------------------------------------------------- corruption

def corrupt_a_chunk(run_dir: str) -> str:
    """Flip bytes inside the zstd frame header of the largest stored visibility chunk."""
    d = os.path.join(run_dir, "store.zarr", "visibility", "bits", "c")
    fn = max((os.path.join(d, f) for f in os.listdir(d)), key=os.path.getsize)
    b = bytearray(open(fn, "rb").read())
    assert b[:4] == b"\x28\xb5\x2f\xfd"  # a zstd frame
    for k in range(4, 8):
        b[k] ^= 0xFF
    open(fn, "wb").write(bytes(b))
    return fn


def test_corrupted_zstd_frame_stops_solve_in_one_line_and_resume_recomputes_it(client, tmp_path):
    from helpers import prepared
    from radiosity.runtime.store import RunStore
    from radiosity.methods.pairs.visibility import compute_visibility, dense_visibility

    run_dir = prepared(client, tmp_path, scene_path("cornell-box"), 12)
    before = dense_visibility(RunStore(run_dir))
    corrupt_a_chunk(run_dir)
    r = cli(["solve", run_dir], client)
    one_error(r, f"of {run_dir} is corrupted (unreadable chunk",
              f"run radiosity visibility {run_dir} --resume")
    fig = compute_visibility(run_dir, client, settings_of(), resume=True, progress=False)
    assert fig.tasks_corrupted_recomputed == 1 and fig.tasks_computed == 1
    np.testing.assert_array_equal(dense_visibility(RunStore(run_dir)), before)
    r = cli(["solve", run_dir], client)
    assert r.exit_code == 0, r.output


# ----------------------------------------------------------------------------- retries

def _count_and_fail(path: str, kind: str, fail_times: int = 99):
    """A task that records each attempt in `path`, then fails `fail_times` times."""
    import errno as _errno

    from radiosity.errors import StoreError

    with open(path, "a") as f:
        f.write("x")
    n = os.path.getsize(path)
    if n > fail_times:
        return n
    if kind == "store":
        raise StoreError("visibility task 3 of /somewhere is corrupted (checksum)")
    if kind == "enospc":
        raise OSError(_errno.ENOSPC, "No space left on device", "/somewhere/bits")
    if kind == "same":
        raise ValueError("always the same")
    raise ValueError(f"attempt {n}")  # a different message each time


@pytest.mark.parametrize("kind,attempts", [("store", 1), ("enospc", 1), ("same", 2), ("varies", 4)])
def test_runner_stops_deterministic_failures_at_once(client, tmp_path, kind, attempts):
    from radiosity.runtime.runner import TaskFailed, run_tasks

    path = str(tmp_path / "attempts")
    with pytest.raises(TaskFailed) as ei:
        run_tasks(client, _count_and_fail, [0], lambda t: (path, kind), name="t", token=kind,
                  retries=3, progress=False, repair="rerun with: radiosity x --resume")
    assert os.path.getsize(path) == attempts
    assert "_count_and_fail" in ei.value.worker_traceback  # the worker's own traceback
    assert ei.value.args[0].endswith("rerun with: radiosity x --resume")


def test_operator_gather_raises_corruption_at_once_and_retries_the_rest(client, tmp_path):
    from radiosity.errors import StoreError
    from radiosity.runtime.runner import TaskFailed, gather_retrying

    path = str(tmp_path / "a")

    def submit(kind, fail_times=99):
        return lambda i, attempt: client.submit(_count_and_fail, path, kind, fail_times, pure=False)

    with pytest.raises(StoreError, match="corrupted"):
        gather_retrying(client, submit("store"), 1, retries=3)
    assert os.path.getsize(path) == 1
    os.remove(path)
    assert gather_retrying(client, submit("varies", fail_times=2), 1, retries=3) == [3]
    os.remove(path)
    with pytest.raises(TaskFailed, match="failed 4 times"):
        gather_retrying(client, submit("varies"), 1, retries=3)


def test_a_failed_task_prints_one_line_naming_its_log(tmp_path):
    """The CLI keeps a TaskFailed's worker traceback in RUN_DIR/radiosity-error.log."""
    import click
    from click.testing import CliRunner

    from radiosity.cli import commands as cli_mod
    from radiosity.runtime.runner import TaskFailed

    @click.command()
    @cli_mod.friendly
    def boom():
        cli_mod.mark_started(str(tmp_path))
        raise TaskFailed("visibility task 7 failed (the same error twice): ValueError: x; the "
                         "finished tasks are kept", "Traceback (most recent call last):\n  worker "
                         "frames\nValueError: x\n")

    r = CliRunner().invoke(boom, [])
    assert r.exit_code == 2
    log = tmp_path / "radiosity-error.log"
    [line] = error_lines(r.output)
    assert line.endswith(f"(worker traceback in {log})") and "Traceback" not in r.output
    assert "worker frames" in log.read_text() and "visibility task 7" in log.read_text()


# ----------------------------------------------------------------------------- convergence

def test_an_unconverged_solve_exits_3_and_keeps_the_converged_solution(client, tmp_path):
    from helpers import prepared, radiance

    run_dir = prepared(client, tmp_path, S, 8)
    r = cli(["solve", run_dir, "--tol", "1e-9"], client)
    assert r.exit_code == 0, r.output
    good = radiance(run_dir)
    r = cli(["solve", run_dir, "--solver", "jacobi", "--max-iterations", "1"], client)
    assert r.exit_code == 3, r.output
    assert "NOT converged" in r.output and "kept the previous converged solution" in r.output
    np.testing.assert_array_equal(radiance(run_dir), good)
    rep = json.loads(open(os.path.join(run_dir, "report.json")).read())["solve"]
    assert rep["converged"] is False and rep["solution"].startswith("kept the previous")
    r = cli(["solve", run_dir, "--solver", "jacobi", "--max-iterations", "1", "--keep-unconverged"],
            client)
    assert r.exit_code == 3 and "written, NOT converged" in r.output, r.output
    assert not np.array_equal(radiance(run_dir), good)
    # and nothing to keep: the unconverged one is written, still exit 3
    r = cli(["render", S, "--out", tmp_path / "r2", "--resolution", "8", "--no-preview",
             "--solver", "jacobi", "--max-iterations", "1"], client)
    assert r.exit_code == 3 and "NOT converged" in r.output, r.output
    assert (tmp_path / "r2" / "image.png").exists()


# ----------------------------------------------------------------------------- whole runs

class Watched:
    """A `radiosity` process whose stderr is read line by line as it comes."""

    def __init__(self, *args):
        import threading

        self.p = start(*args)
        self.err: list[str] = []
        self.t = threading.Thread(target=self._read, daemon=True)
        self.t.start()

    def _read(self):
        for line in self.p.stderr:
            self.err.append(line)

    def wait_line(self, fragment: str, timeout=240):
        wait_for(lambda: any(fragment in ln for ln in self.err), timeout, repr(fragment), self.p)

    def finish(self, timeout=300):
        out = self.p.stdout.read()  # stderr belongs to the reader thread
        self.p.wait(timeout)
        self.t.join(10)
        return self.p.returncode, out, "".join(self.err)

    def workers(self):
        """The worker processes (children of the driver that are not multiprocessing helpers)."""
        import psutil

        kids = psutil.Process(self.p.pid).children(recursive=True)
        return [k for k in kids if "resource_tracker" not in " ".join(k.cmdline())]


CORNELL = scene_path("cornell-box")
# worker processes: these tests kill workers (a small scene would run them as threads)
LONG = ["--resolution", "16", "--workers", "2", "--processes", "true", "--solver", "jacobi",
        "--tol", "1e-10"]


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory):
    """A successful render as a user runs it (its own process and cluster), stderr a pipe."""
    out = tmp_path_factory.mktemp("ref") / "run"
    w = Watched("render", CORNELL, "--out", out, *LONG)
    rc, stdout, stderr = w.finish()
    return out, rc, stdout, stderr


def test_a_successful_run_prints_plain_progress_and_no_traceback(reference_run):
    out, rc, stdout, stderr = reference_run
    assert rc == 0, stderr
    assert "Traceback" not in stderr and "CommClosedError" not in stderr, stderr
    assert "\r" not in stderr  # no progress bar carriage returns into a pipe
    for stage in ("raster", "subdivide", "visibility", "solve (jacobi)", "outputs"):
        assert f"{stage}: started" in stderr and f"{stage}: done" in stderr, stderr
    assert "wall time" in stdout
    rep = json.loads((out / "report.json").read_text())
    run = rep["run"]
    assert run["scene"] == "cornell-box" and run["command"].startswith("radiosity render ")
    assert run["version"] and run["date"][:2] == "20" and run["wall_s"] > rep["render"]["stages"]["total_s"]
    workers = set(rep["render"]["stages"]["peak_rss_mb"]["workers"])
    assert set(rep["visibility"]["busy_s_per_worker"]) <= workers  # keyed by address everywhere
    assert all(k.startswith("tcp://") for k in workers)


def test_kill_a_worker_during_solve_the_answer_is_unchanged(reference_run, tmp_path):
    from helpers import radiance

    ref = reference_run[0]
    out = tmp_path / "run"
    w = Watched("render", CORNELL, "--out", out, *LONG)
    try:
        w.wait_line("solve (jacobi): started")
        time.sleep(0.3)
        victim = w.workers()[0]
        victim.kill()
        rc, stdout, stderr = w.finish()
    finally:
        if w.p.poll() is None:
            kill_group(w.p)
    assert rc == 0, stderr
    assert "Traceback" not in stderr
    np.testing.assert_allclose(radiance(str(out)), radiance(str(ref)), rtol=1e-12, atol=0)


def test_kill_the_driver_during_solve_and_rerun_reuses_visibility(reference_run, tmp_path):
    from helpers import radiance

    out = tmp_path / "run"
    w = Watched("render", CORNELL, "--out", out, *LONG)
    try:
        w.wait_line("solve (jacobi): started")
    finally:
        kill_group(w.p)  # SIGKILL: the driver and its workers, no cleanup at all
    assert (out / "run.lock").exists()
    r = run("render", CORNELL, "--out", out, *LONG, "--resume")
    assert r.returncode == 0, r.stderr
    assert "taking over the lock of a run that is no longer running" in r.stderr
    assert "reusing the partition" in r.stdout and "Traceback" not in r.stderr
    vis = json.loads((out / "report.json").read_text())["visibility"]
    assert vis["tasks_computed"] == 0 and vis["tasks_reused"] == vis["tasks"] > 0
    np.testing.assert_allclose(radiance(str(out)), radiance(str(reference_run[0])), rtol=1e-12)


def test_ctrl_c_says_what_was_kept_in_one_line_and_resume_continues(tmp_path):
    out = tmp_path / "run"
    args = ["render", CORNELL, "--out", out, "--resolution", "16", "--workers", "2", "--no-preview"]
    w = Watched(*args)
    try:
        w.wait_line("visibility: started")
        os.killpg(w.p.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole group
        rc, stdout, stderr = w.finish(120)
    finally:
        if w.p.poll() is None:
            kill_group(w.p)
    assert rc == 130, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr and "Aborted" not in stderr, stderr
    last = stderr.strip().splitlines()[-1]
    assert last.startswith(f"interrupted: kept in {out}: the partition, "), stderr
    assert last.endswith(f"; continue with: radiosity render {CORNELL} --out {out} --resolution 16 "
                         "--workers 2 --no-preview --resume"), last
    r = run(*args, "--resume")
    assert r.returncode == 0 and "reusing the partition" in r.stdout, r.stderr


def _total(x):
    return float(np.sum(x))


def test_a_pass_survives_losing_its_scattered_input_with_a_worker():
    """The solver scatters L to one worker per pass; when that worker dies, the pass's tasks
    are cancelled: gather_retrying resubmits them and the operator scatters L again."""
    from distributed import Client, LocalCluster

    from radiosity.runtime.runner import gather_retrying

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=50) as cl, Client(cl) as c:
        a, b = sorted(c.scheduler_info()["workers"])
        x = np.arange(10.0)
        Lf = c.scatter([x], workers=[a], broadcast=False, hash=False)
        try:
            c.run(os._exit, 1, workers=[a])  # the only copy of L dies
        except Exception:  # the worker could not answer: it is gone
            pass
        wait_for(lambda: Lf[0].status != "finished", 60, "the lost input")
        scattered = [1]

        def submit(i, attempt):
            if attempt and Lf[0].status != "finished":
                Lf[:] = c.scatter([x], broadcast=False, hash=False)
                scattered[0] += 1
            return c.submit(_total, Lf[0], pure=False)

        assert gather_retrying(c, submit, 2, retries=3) == [45.0, 45.0]
        assert scattered[0] == 2


def test_image_names_the_solve_command_and_warns_about_idle_filters(client, tmp_path):
    from helpers import prepared
    from radiosity.stages.solve import run_solve

    run_dir = prepared(client, tmp_path, S, 8)
    r = cli(["image", run_dir])
    one_error(r, f"{run_dir} has no solution yet: run radiosity solve {run_dir} first")
    run_solve(run_dir, client, settings_of(), progress=False)
    r = cli(["image", run_dir, "--filter", "gaussian"])
    assert r.exit_code == 0 and "warning:" in r.output and "has no sub-samples" in r.output, r.output
    r = cli(["image", run_dir, "--sigma", "2"])
    assert r.exit_code == 0 and "--sigma is the Gaussian filter's width: ignored" in r.output, r.output
    r = cli(["image", run_dir])
    assert r.exit_code == 0 and "warning" not in r.output, r.output
