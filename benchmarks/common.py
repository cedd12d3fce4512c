"""Shared benchmark plumbing: machine and versions, JSON output, a printed table."""

from __future__ import annotations

import json
import os
import platform
import time
from importlib import metadata

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
RESULTS = os.path.join(HERE, "results")



def machine() -> dict:
    import psutil

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    vers = {}
    for pkg in ("numpy", "numba", "embreex", "dask", "distributed", "zarr", "trimesh"):
        try:
            vers[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            vers[pkg] = None
    return {"cpu": cpu, "cores": os.cpu_count(), "memory_gib": round(psutil.virtual_memory().total / 2**30, 1),
            "python": platform.python_version(), "platform": platform.platform(), "versions": vers,
            "date": time.strftime("%Y-%m-%d %H:%M:%S")}


def write(name: str, rows: list[dict], extra: dict | None = None) -> str:
    os.makedirs(RESULTS, exist_ok=True)
    fn = os.path.join(RESULTS, f"{name}.json")
    with open(fn, "w") as f:
        json.dump({"benchmark": name, "machine": machine(), **(extra or {}), "rows": rows}, f, indent=2)
    return fn


def table(rows: list[dict], cols: list[str]) -> str:
    def fmt(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    w = {c: max(len(c), *(len(fmt(r.get(c, ""))) for r in rows)) for c in cols}
    lines = ["  ".join(c.rjust(w[c]) for c in cols), "  ".join("-" * w[c] for c in cols)]
    lines += ["  ".join(fmt(r.get(c, "")).rjust(w[c]) for c in cols) for r in rows]
    return "\n".join(lines)


def best_of(fn, repeat: int = 3) -> float:
    """Fastest wall time of `repeat` calls (the machine is shared and noisy)."""
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best
