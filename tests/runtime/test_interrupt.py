"""Ctrl-C at any moment (issue 27): `radiosity render` in a process of its own, SIGINT to its
whole process group as a terminal sends it, (a) while the worker processes start, (b) during
the visibility stage on worker processes, (c) during the link stage on in-process workers. Each
stops within 2 s with exit status 130 and one line that says what was kept, as the ledger on
disk holds it, and --resume then reuses exactly that; no worker outlives the driver."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

from helpers import ROOT, scene_path

pytestmark = pytest.mark.cluster

CORNELL = scene_path("cornell-box")
STOP_S = 2.0  # the promise: Ctrl-C stops the command within this


class Run:
    """`radiosity ARGS` in its own process group, stdout and stderr read line by line."""

    def __init__(self, args, processes: bool):
        env = dict(os.environ, DASK_RADIOSITY__CLUSTER__PROCESSES=str(processes).lower())
        self.p = subprocess.Popen([sys.executable, "-m", "radiosity.cli", *map(str, args)],
                                  cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, start_new_session=True)
        self.out: list[str] = []
        self.err: list[str] = []
        self.readers = [threading.Thread(target=self._read, args=(s, d), daemon=True)
                        for s, d in ((self.p.stdout, self.out), (self.p.stderr, self.err))]
        for t in self.readers:
            t.start()

    @staticmethod
    def _read(stream, lines):
        for line in stream:
            lines.append(line.rstrip("\n"))

    def wait_for(self, pred, what, timeout=240):
        t0 = time.monotonic()
        while not pred():
            if self.p.poll() is not None:
                raise AssertionError(f"ended before {what}:\n" + "\n".join(self.err[-30:]))
            if time.monotonic() - t0 > timeout:
                self.kill()
                raise AssertionError(f"timed out waiting for {what}")
            time.sleep(0.01)

    def interrupt(self) -> float:
        """SIGINT to the group; the seconds until the driver exited."""
        t0 = time.monotonic()
        os.killpg(self.p.pid, signal.SIGINT)
        try:
            self.p.wait(30)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError("still running 30 s after Ctrl-C:\n" + "\n".join(self.err[-30:]))
        took = time.monotonic() - t0
        for t in self.readers:
            t.join(10)
        return took

    def kill(self):
        try:
            os.killpg(self.p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.p.wait(30)


def _group_gone(pgid: int, timeout: float = 5.0) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def _finished(manifest) -> int:
    """Tasks in a stage's manifest (a head line, then one line per finished task)."""
    if not manifest.exists():
        return 0
    n = 0
    for line in manifest.read_text().splitlines()[1:]:
        try:
            n += "task" in json.loads(line)
        except ValueError:
            pass
    return n


def _clean(run: Run) -> str:
    """The last stderr line, after checking that nothing else went wrong."""
    err = "\n".join(run.err)
    assert "Traceback" not in err and "KeyboardInterrupt" not in err and "Error" not in err, err
    assert "leaked semaphore" not in err, err
    return run.err[-1]


def test_ctrl_c_while_the_workers_start(tmp_path):
    """Once ignored (SIGINT was ignored while the worker processes were spawned: the run went
    on); now it stops at once, and no half-started worker is left behind."""
    out = tmp_path / "run"
    args = ["render", CORNELL, "--out", out, "--resolution", "16", "--workers", "2", "--no-preview"]
    run = Run(args, processes=True)
    run.wait_for(lambda: any(ln.startswith("scene cornell-box:") for ln in run.out),
                 "the cluster start")
    took = run.interrupt()
    assert run.p.returncode == 130, "\n".join(run.err)
    assert not any(ln.startswith("cluster:") for ln in run.out), "the workers were up already"
    assert _clean(run) == ("interrupted; continue with: radiosity render " + " ".join(map(str, args[1:]))
                           + " --resume")
    assert took < STOP_S, f"{took:.2f} s"
    assert _group_gone(run.p.pid), "a worker process outlived the driver"


@pytest.mark.parametrize("processes, method, res, manifest, phrase", [
    (True, "pairs", 24, "visibility.manifest.jsonl", "visibility tasks"),
    (False, "hierarchical", 96, "links.manifest.jsonl", "link tasks")])
def test_ctrl_c_during_a_stage_keeps_what_the_ledger_holds(tmp_path, processes, method, res,
                                                          manifest, phrase):
    out = tmp_path / "run"
    args = ["render", CORNELL, "--out", out, "--resolution", res, "--workers", "2",
            "--no-preview", "--method", method]
    run = Run(args, processes)
    run.wait_for(lambda: _finished(out / manifest) >= 1, "a finished task")
    took = run.interrupt()
    assert run.p.returncode == 130, "\n".join(run.err)
    kept = _finished(out / manifest)
    last = _clean(run)
    m = re.fullmatch(rf"interrupted: kept in {re.escape(str(out))}: the partition, (\d+) of (\d+) "
                     rf"{phrase}; continue with: (.*)", last)
    assert m, last
    assert int(m[1]) == kept and 1 <= kept < int(m[2]), (last, kept)
    assert m[3] == "radiosity render " + " ".join(map(str, args[1:])) + " --resume"
    assert took < STOP_S, f"{took:.2f} s"
    assert _group_gone(run.p.pid), "a worker process outlived the driver"
    # --resume continues: exactly the kept tasks are reused
    r = subprocess.run([sys.executable, "-m", "radiosity.cli", *map(str, args), "--resume"],
                       cwd=ROOT, capture_output=True, text=True, timeout=600,
                       env=dict(os.environ,
                                DASK_RADIOSITY__CLUSTER__PROCESSES=str(processes).lower()))
    assert r.returncode == 0, r.stderr
    assert "reusing the partition" in r.stdout, r.stdout
    section = json.loads((out / "report.json").read_text())["visibility" if method == "pairs"
                                                             else "links"]
    assert section["tasks_reused"] == kept and section["tasks_computed"] == int(m[2]) - kept
