"""Cutting work into tasks and groups (pure integer arithmetic on numpy, no Dask): the task
unit, contiguous ranges of about equal weight or under a cap, groups of about equal cost."""

from __future__ import annotations

import numba
import numpy as np


def choose_unit(unit: str, n_originals: int, threshold: int) -> str:
    """auto: stripes when original elements are many (seed §4.3, remark), blocks otherwise."""
    if unit == "auto":
        return "stripe" if n_originals > threshold else "block"
    if unit not in ("block", "stripe"):
        raise ValueError(f"--task-unit must be block, stripe or auto, got {unit!r}")
    return unit


@numba.njit(cache=True, nogil=True)
def capped_starts(cost, cap):
    """The starts of consecutive runs of items (cost (n,) int64), each run closed before the item
    that would take its sum above `cap` (an item above the cap alone is a run): (k + 1,) int64,
    run r holding items starts[r]:starts[r + 1]. In numba: the link stage's pairs of
    originals run to millions on meshes of many triangles."""
    n = cost.shape[0]
    out = np.empty(n + 1, np.int64)
    out[0] = 0
    k = 1
    acc = 0
    for i in range(n):
        if i > 0 and acc + cost[i] > cap:
            out[k] = i
            k += 1
            acc = 0
        acc += cost[i]
    if n == 0:
        return out[:1]
    out[k] = n
    return out[:k + 1]


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
    cost = np.asarray(cost, np.float64)
    group = _least_loaded(np.argsort(-cost, kind="stable"), cost, max(1, ngroups))
    order = np.argsort(group, kind="stable")
    cuts = np.searchsorted(group[order], np.arange(1, max(1, ngroups)))
    return [m.astype(np.int64) for m in np.split(order, cuts) if len(m)]


@numba.njit(cache=True, nogil=True)
def _least_loaded(order, cost, ngroups):
    """The group of each task, taken in `order`, onto the least loaded group (the first of
    equals). In numba: the final gather packs every original, tens of thousands on meshes of
    many triangles."""
    load = np.zeros(ngroups)
    group = np.empty(order.shape[0], np.int64)
    for t in order:
        g = 0
        for h in range(1, ngroups):
            if load[h] < load[g]:
                g = h
        group[t] = g
        load[g] += cost[t]
    return group
