"""Live progress of a run, published to the Dask scheduler for the engine's dashboard page.

Design notes and measurements: docs/src/design/runtime-monitor.md.
"""

from __future__ import annotations

import base64
import io
import time

import numpy as np

BINS = 64


def progress_bar(total, desc: str, enabled: bool = True, initial: int = 0, unit: str = "task",
                 stream=None):
    """Progress of long work on stderr: a tqdm bar on a terminal; where stderr is a file or a
    pipe (logs, batch jobs), one plain line when the work starts and one when it ends, with
    its figures (`PlainProgress`), instead of carriage returns. Nothing when `enabled` is
    False."""
    import sys

    stream = sys.stderr if stream is None else stream
    if enabled and not _isatty(stream):
        return PlainProgress(total, desc, initial, unit, stream)
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit=unit, disable=not enabled,
                leave=False, file=stream)


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except Exception:
        return False


def _plural(unit: str, n) -> str:
    return unit if n == 1 else unit + ("es" if unit.endswith("s") else "s")


class PlainProgress:
    """The part of tqdm's interface the engine uses (update, set_postfix, close, with), as two
    plain lines: `NAME: started (TOTAL UNITs)` and `NAME: done, N UNITs in T s (figures)`."""

    def __init__(self, total, desc: str, initial: int = 0, unit: str = "task", stream=None):
        self.total, self.desc, self.unit, self.stream = total, desc, unit, stream
        self.n, self.initial = initial, initial
        self.postfix: dict = {}
        self.t0 = time.perf_counter()
        self.closed = False
        what = f" ({total - initial} {_plural(unit, total - initial)} to run" + (
            f", {initial} done before" if initial else "") + ")" if total is not None else ""
        self._say(f"{desc}: started{what}")

    def _say(self, line: str) -> None:
        try:
            print(line, file=self.stream, flush=True)
        except (OSError, ValueError):  # a closed or broken stream: progress is never fatal
            pass

    def update(self, n: int = 1) -> None:
        self.n += n

    def set_postfix(self, **kw) -> None:
        self.postfix.update(kw)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        dt = time.perf_counter() - self.t0
        ran = self.n - self.initial
        figs = "".join(f", {k} {v}" for k, v in self.postfix.items())
        rate = f", {ran / dt:.3g} {self.unit}/s" if dt > 0 and ran else ""
        self._say(f"{self.desc}: done, {ran} {_plural(self.unit, ran)} in {dt:.2f} s{rate}{figs}")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if exc[0] is None:
            self.close()
        self.closed = True  # stopped early: the error line says why
        return False


def peak_rss_mib() -> float:
    """This process's own peak resident memory (MiB): VmHWM of /proc/self/status, which a
    spawned worker does not inherit from its parent (getrusage's ru_maxrss survives exec and
    would report the driver's peak for a fresh worker); ru_maxrss where /proc is missing."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def peak_rss_mb(client) -> dict:
    """Peak resident memory (MiB) of the driver ("master") and of each worker, keyed by the
    worker's address."""
    out = {"master": round(peak_rss_mib(), 1)}
    try:
        out["workers"] = {k: round(v, 1) for k, v in client.run(peak_rss_mib).items()}
    except Exception:  # a worker that died mid-run has no figure
        pass
    return out


def worker_address() -> str:
    """The address of the Dask worker running this task (the pid outside a worker): how every
    per-worker figure is keyed."""
    import os

    try:
        from distributed import get_worker

        return get_worker().address
    except Exception:
        return f"pid {os.getpid()}"


def heat_map(tiles_ij: np.ndarray, task_of_tile: np.ndarray, done: np.ndarray, n: int,
             bins: int = BINS) -> np.ndarray:
    """Fraction of visibility tiles done per bin of original-element pairs, (b, b) float64.

    tiles_ij (t, 2) [I, J]; task_of_tile (t,) int; done (k,) bool per task."""
    b = max(1, min(bins, n))
    if len(tiles_ij) == 0:
        return np.ones((b, b))
    bi = tiles_ij[:, 0] * b // n
    bj = tiles_ij[:, 1] * b // n
    tot = np.zeros((b, b))
    fin = np.zeros((b, b))
    np.add.at(tot, (bi, bj), 1.0)
    np.add.at(fin, (bi, bj), done[task_of_tile].astype(float))
    return np.where(tot > 0, fin / np.maximum(tot, 1), np.nan)


class PairBins:
    """The link tasks' pairs of originals binned once for the heat map: per (task, bin) the
    count of pairs (task, cell, count), and the pairs per bin (b * b,). A plan of millions of
    pairs is binned once, not at every update (binning them all every half second competed with
    the workers for the driver's cores)."""

    def __init__(self, pairs: np.ndarray, first: np.ndarray, n: int, bins: int = BINS):
        self.b = b = max(1, min(bins, n))
        self.k = k = len(first) - 1
        task = np.repeat(np.arange(k, dtype=np.int64), np.diff(first))
        cell = (pairs[:, 0] * b // n) * b + pairs[:, 1] * b // n
        keys = task * (b * b) + cell
        if k * b * b <= 8 * len(keys) + (1 << 20):  # a count per (task, bin): no sort
            cnt = np.bincount(keys, minlength=k * b * b)
            key = np.nonzero(cnt)[0]
            cnt = cnt[key]
        else:
            key, cnt = np.unique(keys, return_counts=True)
        self.task, self.cell, self.cnt = key // (b * b), key % (b * b), cnt.astype(float)
        self.total = np.bincount(cell, minlength=b * b).astype(float)
        self.pairs = np.diff(first)

    def grid(self, weights: np.ndarray) -> np.ndarray:
        return np.bincount(self.cell, weights, minlength=self.b * self.b).reshape(self.b, self.b)


def link_heat(pairs: np.ndarray, first: np.ndarray, done_tasks: dict, n: int,
              bins: int = BINS, binned: PairBins | None = None):
    """(heat map (b, b), title or None) of the link stage: the fraction of link tasks done per
    bin of original pairs while it runs; once all are done, the links per bin on a log scale
    (log(1 + links) / log(1 + the busiest bin's); a stripe task's links shared evenly by its
    pairs), with a title that says so. binned: the PairBins of (pairs, first, n) (None: made
    here)."""
    pb = binned if binned is not None else PairBins(pairs, first, n, bins)
    done = np.zeros(pb.k, bool)
    done[list(done_tasks)] = True
    if not (pb.k and done.all()):
        if not len(pairs):
            return np.ones((pb.b, pb.b)), None
        fin = pb.grid(done[pb.task] * pb.cnt).ravel()
        frac = np.where(pb.total > 0, fin / np.maximum(pb.total, 1), np.nan)
        return frac.reshape(pb.b, pb.b), None
    per_pair = np.array([done_tasks[t]["n"] for t in range(pb.k)], float) / np.maximum(pb.pairs, 1)
    heat = pb.grid(per_pair[pb.task] * pb.cnt)
    top = float(heat.max(initial=0.0))
    hm = np.where(heat > 0, np.log1p(heat) / np.log1p(max(top, 1.0)), np.nan)
    total = int(sum(e["n"] for e in done_tasks.values()))
    return hm, f"Links per pair of originals: {total} links (log scale; busiest bin {top:.0f})"


def png_base64(img8: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img8, np.uint8)).save(buf, format="PNG")
    return base64.b64encode(buf.getvalue()).decode()


class Monitor:
    """Publishes a run's progress to the scheduler; safe to call from the master's loops."""

    def __init__(self, client, interval: float = 0.5):
        self.client = client
        self.interval = interval
        self._last: dict = {}
        self._binned = None  # (pairs, PairBins) of the link stage's plan

    def _due(self, key: str, force: bool) -> bool:
        now = time.monotonic()
        if force or now - self._last.get(key, -1e9) >= self.interval:
            self._last[key] = now
            return True
        return False

    def _set(self, key: str, value) -> None:
        try:
            self.client.set_metadata(["radiosity", key], value)
        except Exception:  # monitoring never fails a run
            pass

    def stage(self, stage: str, run_dir: str = "", scene: str = "") -> None:
        self._set("run", {"stage": stage, "run_dir": run_dir, "scene": scene, "time": time.time()})

    def visibility(self, plan, done_tasks, n: int, force: bool = False) -> None:
        if not self._due("visibility", force):
            return
        done = np.zeros(len(plan.tasks), bool)
        done[list(done_tasks)] = True
        hm = heat_map(plan.tiles[:, :2], plan.task_of_tile(), done, n)
        self._set("visibility", {"n": int(n), "bins": int(hm.shape[0]),
                                 "done": np.where(np.isnan(hm), -1.0, hm).round(3).tolist(),
                                 "tasks_done": int(done.sum()), "tasks": int(len(done))})

    def links(self, pairs: np.ndarray, first: np.ndarray, done_tasks: dict, n: int,
              force: bool = False) -> None:
        """The link stage on the same heat map: link tasks done per pair of originals while
        it runs; when every task is done, the links per pair of originals (log scale: a pair's
        links over the busiest bin's), where the hierarchy spent its refinement."""
        if not self._due("visibility", force):
            return
        if self._binned is None or self._binned[0] is not pairs:
            self._binned = (pairs, PairBins(pairs, first, n))
        hm, title = link_heat(pairs, first, done_tasks, n, binned=self._binned[1])
        self._set("visibility", {"n": int(n), "bins": int(hm.shape[0]),
                                 "done": np.where(np.isnan(hm), -1.0, hm).round(3).tolist(),
                                 "tasks_done": len(done_tasks), "tasks": len(first) - 1,
                                 **({"title": title} if title else {})})

    def solve(self, solver: str, kernel: str, residuals: list, force: bool = False) -> None:
        if self._due("solve", force):
            self._set("solve", {"solver": solver, "kernel": kernel,
                                "residuals": [float(r) for r in residuals]})

    def preview(self, make_image, force: bool = False) -> None:
        """make_image() -> (h, w, 3) uint8, called only when a preview is due."""
        if self._due("preview", force):
            try:
                img = make_image()
            except Exception:
                return
            self._set("preview", {"width": int(img.shape[1]), "height": int(img.shape[0]),
                                  "png": png_base64(img)})
