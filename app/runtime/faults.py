"""What the CLI says when a run stops early: one line with what was kept and what to run next.

- an interrupted run (Ctrl-C): the command that continues it (cli/summary.kept says what the
  run directory keeps);
- a task that failed on every attempt (runner.TaskFailed): the worker's traceback goes to a log
  file in the run directory (or the temporary directory when that cannot be written), and the
  line names the log;
- a filesystem fault (full disk, read-only, permission, a path through a file): the path, what
  happened and what to do.
"""

from __future__ import annotations

import errno
import os
import tempfile
import time

FAILURE_LOG = "radiosity-error.log"


def write_failure_log(run_dir: str | None, title: str, text: str) -> str:
    """Write a worker's traceback to RUN_DIR/radiosity-error.log (appended, dated); returns the
    path (in the temporary directory when the run directory cannot be written)."""
    entry = f"==== {time.strftime('%Y-%m-%d %H:%M:%S')} {title}\n{text.rstrip()}\n\n"
    for d in ([run_dir] if run_dir and os.path.isdir(run_dir) else []) + [tempfile.gettempdir()]:
        fn = os.path.join(d, FAILURE_LOG)
        existed = os.path.exists(fn)
        try:
            with open(fn, "a") as f:
                f.write(entry)
            return fn
        except OSError:  # a full or read-only filesystem: the next place
            if not existed:
                try:
                    os.remove(fn)
                except OSError:
                    pass
    return "(no log: nothing writable)"


FS_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOTDIR,
             errno.EISDIR, errno.EEXIST, errno.ENOENT}


def fs_error(e: BaseException) -> OSError | None:
    """The filesystem OSError behind e (itself, or its cause / context), or None."""
    seen = 0
    while e is not None and seen < 8:
        if isinstance(e, OSError) and e.errno in FS_ERRNOS:
            return e
        e = e.__cause__ or e.__context__
        seen += 1
    return None


def fs_error_line(e: OSError, where: str | None = None) -> str:
    """One line for a filesystem fault: the path (e's, else `where`), what happened, what to do."""
    from radiosity.runtime.checks import FS_ERRORS, fs_advice

    path = e.filename or where or "the run directory"
    why = FS_ERRORS.get(e.errno, e.strerror or str(e))
    return f"cannot write {path}: {why}; {fs_advice(e.errno)}"
