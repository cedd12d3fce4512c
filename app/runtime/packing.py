"""Cutting work into tasks and groups (pure integer arithmetic on numpy, no Dask): the task
unit, contiguous ranges of about equal weight, groups of about equal cost."""

from __future__ import annotations

import numpy as np


def choose_unit(unit: str, n_originals: int, threshold: int) -> str:
    """auto: stripes when original elements are many (seed §4.3, remark), blocks otherwise."""
    if unit == "auto":
        return "stripe" if n_originals > threshold else "block"
    if unit not in ("block", "stripe"):
        raise ValueError(f"--task-unit must be block, stripe or auto, got {unit!r}")
    return unit


def subscene_ranges(weights: np.ndarray, ntasks: int) -> list[tuple[int, int]]:
    """Cut 0..n into at most `ntasks` contiguous ranges of about equal total weight (the
    preprocessing's subscene tasks, seed §4.2)."""
    n = len(weights)
    ntasks = max(1, min(ntasks, n))
    cum = np.cumsum(weights, dtype=float)
    total = cum[-1] if n else 0.0
    cuts = np.searchsorted(cum, total * np.arange(1, ntasks) / ntasks, side="left") + 1
    bounds = np.unique(np.concatenate([[0], np.clip(cuts, 1, n), [n]]))
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def pack_groups(cost: np.ndarray, ngroups: int) -> list[np.ndarray]:
    """Tasks with estimated `cost` (k,) packed into at most `ngroups` groups of about equal
    total cost (longest first onto the least loaded group); each group's task ids sorted.
    The solver pins one group to one worker, whose cache keeps the group's tiles."""
    order = np.argsort(-np.asarray(cost), kind="stable")
    load = np.zeros(max(1, ngroups))
    members = [[] for _ in range(len(load))]
    for t in order:
        g = int(np.argmin(load))
        members[g].append(int(t))
        load[g] += cost[t]
    return [np.array(sorted(m), np.int64) for m in members if m]
