"""One run at a time per run directory: `RUN_DIR/run.lock`.

Design notes and measurements: docs/src/design/runtime-runlock.md.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import time
import warnings

from radiosity.errors import StoreError

LOCK = "run.lock"


def _create_time(pid: int) -> float | None:
    try:
        import psutil

        return psutil.Process(pid).create_time()
    except Exception:
        return None


def _alive(owner: dict) -> bool:
    """Is the process in a lock file (on this host) still the one that wrote it?"""
    pid = owner.get("pid")
    if not isinstance(pid, int):
        return False
    ct = _create_time(pid)
    if ct is None:
        return False
    want = owner.get("create_time")
    return want is None or abs(ct - float(want)) < 1.0  # a recycled pid is another process


def _describe(owner: dict) -> str:
    started = owner.get("started")
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(started)) if started else "?"
    cmd = owner.get("command") or "?"
    return f"pid {owner.get('pid', '?')} on {owner.get('host', '?')}, `{cmd}` since {when}"


def _read(fd: int) -> dict | None:
    os.lseek(fd, 0, os.SEEK_SET)
    data = b""
    while chunk := os.read(fd, 65536):
        data += chunk
    if not data.strip():
        return None
    try:
        d = json.loads(data)
        return d if isinstance(d, dict) else {}
    except (ValueError, UnicodeDecodeError):
        return {}


@contextlib.contextmanager
def run_lock(run_dir: str, command: str = ""):
    """Hold the lock of `run_dir` (an existing directory) for the body of the `with`.

    Raises StoreError (one line: who holds it, what to do) when another live run holds it."""
    path = os.path.join(os.path.abspath(run_dir), LOCK)
    host = socket.gethostname()
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            from radiosity.runtime.checks import FS_ERRORS, fs_advice

            raise StoreError(f"cannot create the lock file {path}: "
                             f"{FS_ERRORS.get(e.errno, e.strerror)}; {fs_advice(e.errno)}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            owner = _read(fd) or {}
            os.close(fd)
            raise StoreError(f"{run_dir} is in use by another radiosity run ({_describe(owner)}): "
                             "wait for it to finish, or use another run directory") from None
        # the file may have been unlinked by its last owner between our open and our flock
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        owner = _read(fd)
        if owner is not None:
            if owner.get("host") not in (None, host) and owner.get("pid") is not None:
                raise StoreError(f"{run_dir} is locked by a run on another host ({_describe(owner)}); "
                                 f"if no run is using it, delete {path}")
            if owner.get("host") == host and _alive(owner) and owner.get("pid") != os.getpid():
                raise StoreError(f"{run_dir} is in use by another radiosity run ({_describe(owner)}): "
                                 "wait for it to finish, or use another run directory")
            warnings.warn(f"{run_dir}: taking over the lock of a run that is no longer running "
                          f"({_describe(owner)}); its finished work is kept")
        me = {"pid": os.getpid(), "host": host, "started": time.time(), "command": command,
              "create_time": _create_time(os.getpid())}
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, json.dumps(me).encode())
        os.fsync(fd)
    except BaseException:
        with contextlib.suppress(OSError):
            os.close(fd)
        raise
    try:
        yield path
    finally:
        # unlink while still holding the flock, so nobody reads an owner that has gone
        with contextlib.suppress(OSError):
            os.unlink(path)
        with contextlib.suppress(OSError):
            os.close(fd)
