"""The radiosity operator y = F L, matrix-free, and the executors that apply it.

Design notes and measurements: docs/src/design/methods-pairs-transport.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.core.kernels import get_kernel, kernel_id, sample_points, sampled_pairs
from radiosity.methods.base import CAP_MIN, Operator  # noqa: F401
from radiosity.runtime.executor import GroupExecutor
from radiosity.methods.pairs.passes import (BOTH, Caps, Geometry, Samples, gs_sweep, partial_apply,
                                            sparse_by_target, tiles_apply)
from radiosity.methods.pairs.plan import I, J, TSTART, TBYTES, VisibilityPlan
from radiosity.runtime.packing import pack_groups
from radiosity.settings import sampling_of
from radiosity.runtime.cache import CACHE, BoundedCache  # noqa: F401  (BoundedCache: re-exported)
from radiosity.methods.pairs.store import VisibilityStore, read_partial, read_task_checked


@dataclass(frozen=True)
class SolveInputs:
    """Read-only arrays the pass tasks need (scattered once per solve; `configure` replaces some).

    cx, cy, cz, nx, ny, nz, area (m,) float64; cap (m,) float64 and cmode (passes.CAP_MIN or
    CAP_PRODUCT): the row normalisation; orig (m,) int32; sided (m,) bool; need (n,) bool
    originals that gather (empty = all, effects.py); offsets (n + 1,) int64; tiles, tasks: the
    visibility plan; crc (k, 2) int64 [crc32, nbytes] per plan task; store_path, token; pts, w:
    sample points and weights of the sampled kernels (kernels.sample_points); pcrc (k, 2) int64
    [crc32, length] of each task's partly visible pairs (sampled kernels; else (0, 2)); sparse:
    near-field corrections grouped for Gauss-Seidel (passes.sparse_by_target); cache_bytes: the
    bound of each worker's cache.
    """

    cx: np.ndarray
    cy: np.ndarray
    cz: np.ndarray
    nx: np.ndarray
    ny: np.ndarray
    nz: np.ndarray
    area: np.ndarray
    cap: np.ndarray
    cmode: int
    orig: np.ndarray
    sided: np.ndarray
    need: np.ndarray
    offsets: np.ndarray
    tiles: np.ndarray
    tasks: np.ndarray
    crc: np.ndarray
    store_path: str
    token: str
    pts: np.ndarray
    w: np.ndarray
    pcrc: np.ndarray
    sparse: tuple
    cache_bytes: int

    def geometry(self) -> tuple:
        """The per-sub-element arguments of the pass loops, in their argument order (passes.py):
        Geometry, Caps, sided, Samples."""
        return (Geometry(self.cx, self.cy, self.cz, self.nx, self.ny, self.nz, self.area),
                Caps(self.cap, self.cmode), self.sided, Samples(self.pts, self.w))


def solve_inputs(part, elements, plan: VisibilityPlan, crc, store_path: str, token: str,
                 sampling=None, pcrc=None, cache_bytes: int = 1 << 31) -> SolveInputs:
    """The SolveInputs of a partition and its stored visibility matrix."""
    c, n = part.center, part.normal
    pts, w = sample_points(part.verts, part.nverts, sampling)
    return SolveInputs(
        *(np.ascontiguousarray(c[:, k]) for k in range(3)),
        *(np.ascontiguousarray(n[:, k]) for k in range(3)),
        area=part.area, cap=np.ones(len(part.area)), cmode=CAP_MIN, orig=part.orig,
        sided=elements.two_sided[part.orig], need=np.zeros(0, np.bool_), offsets=part.offsets,
        tiles=plan.tiles, tasks=plan.tasks, crc=crc, store_path=store_path, token=token,
        pts=pts, w=w, pcrc=np.zeros((0, 2), np.int64) if pcrc is None else pcrc,
        sparse=sparse_by_target(None, part.orig, len(part.offsets) - 1),
        cache_bytes=int(cache_bytes))




def _task_bytes(inp: SolveInputs, task: int) -> np.ndarray:
    """The verified bytes of one visibility task, from this worker's cache or the store."""
    t = inp.tasks[task]
    return CACHE.get((inp.store_path, inp.token, task),
                     lambda: read_task_checked(inp.store_path, task, int(t[TSTART]),
                                               int(inp.crc[task, 1]), int(inp.crc[task, 0])),
                     lambda d: d.nbytes, inp.cache_bytes)


def _task_partial(inp: SolveInputs, task: int):
    """The verified partly visible pairs of one visibility task (sampled kernels), cached with
    the tiles: pairs (k, 3) int64 [a, b, visible rays], phi (k,)."""
    entry = {"crc": int(inp.pcrc[task, 0]), "n": int(inp.pcrc[task, 1])}
    return CACHE.get((inp.store_path, inp.token, task, "partial"),
                     lambda: read_partial(inp.store_path, task, entry),
                     lambda g: g[0].nbytes + g[1].nbytes, inp.cache_bytes)


def partial_corrections(inp: SolveInputs, kid: int):
    """Every partly visible pair of a sampled kernel as sparse corrections F_ab (phi - 1) on top
    of the unoccluded kernel, grouped for Gauss-Seidel (which holds the whole matrix on one
    worker); made once per worker and kept in its cache."""

    def load():
        got = [_task_partial(inp, t) for t in range(len(inp.pcrc)) if inp.pcrc[t, 1] > 0]
        pairs = np.concatenate([g[0] for g in got]) if got else np.zeros((0, 3), np.int64)
        phi = np.concatenate([g[1] for g in got]) if got else np.zeros(0)
        ia, ib = pairs[:, 0].copy(), pairs[:, 1].copy()
        acc, sa, sb = sampled_pairs(kid, inp.pts, inp.w, inp.cx, inp.cy, inp.cz, inp.nx, inp.ny,
                                    inp.nz, ia, ib)
        return sparse_by_target({"ia": ia, "ib": ib, "sa": sa, "sb": sb,
                                 "dab": (phi - 1.0) * acc * inp.area[ib],
                                 "dba": (phi - 1.0) * acc * inp.area[ia]},
                                inp.orig, len(inp.offsets) - 1)

    return CACHE.get((inp.store_path, inp.token, kid, "gauss-seidel"), load,
                     lambda g: sum(a.nbytes for a in g), inp.cache_bytes)


# ----------------------------------------------------------------------------- task functions

def task_apply(inp: SolveInputs, task_ids: np.ndarray, L: np.ndarray, kid: int, live,
               use_need: bool = True):
    """y = F L restricted to the tiles of these visibility tasks. live: (n,) bool or None, the
    originals whose L is non-zero (tiles with no live source are skipped); with use_need, rows
    of originals that do not gather (inp.need) are skipped. Returns (y, pair terms)."""
    y = np.zeros_like(L)
    terms = 0
    lv = np.zeros(0, np.bool_) if live is None else np.asarray(live, np.bool_)
    need = inp.need if use_need else np.zeros(0, np.bool_)
    geo, caps, sided, smp = inp.geometry()
    for task in task_ids:
        t = inp.tasks[task]
        tiles = inp.tiles[t[0]:t[1]]
        if live is not None and not (lv[tiles[:, I]].any() or lv[tiles[:, J]].any()):
            continue
        data = _task_bytes(inp, int(task))
        terms += tiles_apply(kid, data, int(t[TSTART]), tiles, inp.offsets, geo, caps, sided, smp,
                             L, y, BOTH, lv, need)
        if len(inp.pcrc) and inp.pcrc[task, 1] > 0:  # sampled kernels: the partly visible pairs
            pairs, phi = _task_partial(inp, int(task))
            terms += partial_apply(kid, pairs, phi, geo, caps, smp, L, y, inp.orig, need)
    return y, terms


def all_task_bytes(inp: SolveInputs) -> np.ndarray:
    """Every visibility task's verified bytes at their places in one array (the whole packed
    matrix: bits, not floats), as Gauss-Seidel needs it."""
    total = int(inp.tasks[-1, TSTART] + inp.tasks[-1, TBYTES]) if len(inp.tasks) else 0
    data = np.zeros(max(total, 1), np.uint8)
    for task in range(len(inp.tasks)):
        b = _task_bytes(inp, task)
        s = int(inp.tasks[task, TSTART])
        data[s:s + len(b)] = b
    return data


def task_gs_sweep(inp: SolveInputs, L: np.ndarray, Le: np.ndarray, rho: np.ndarray, kid: int):
    """One block Gauss-Seidel sweep over the originals in order, with the latest values.

    Needs every tile, so the worker running it holds the whole packed matrix (bits, not floats)."""
    L = L.copy()
    n = len(inp.offsets) - 1
    data = all_task_bytes(inp)
    rows = inp.tiles[:, I]
    cols = inp.tiles[:, J]
    row_idx = np.argsort(rows, kind="stable")
    col_idx = np.argsort(cols, kind="stable")
    row_ptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))])
    col_ptr = np.concatenate([[0], np.cumsum(np.bincount(cols, minlength=n))])
    y = np.zeros_like(L)
    # sampled kernels: the partly visible pairs, as sparse corrections (else the near field)
    sparse = partial_corrections(inp, kid) if len(inp.pcrc) else inp.sparse
    terms = gs_sweep(kid, data, inp.tiles, (row_ptr, row_idx, col_ptr, col_idx), inp.offsets,
                     *inp.geometry(), L, Le, rho, y, inp.need, tuple(sparse))
    return L, terms


# ----------------------------------------------------------------------------- executors

class _Base:
    """What both executors share: the inputs, the groups, the near-field corrections applied on
    the driver, and the counters."""

    def __init__(self, inp: SolveInputs, kernel: str, ngroups: int):
        self.inp = inp
        self.kernel = kernel
        self.kid = kernel_id(kernel)
        self.terms = 0
        self.passes = 0
        plan = VisibilityPlan(inp.tiles, inp.tasks, np.zeros((0, 2), np.int64), 1, 0, "block")
        self.groups = pack_groups(plan.task_bits(), max(1, ngroups))
        self.sparse = None  # near-field corrections (nearfield.py), applied on the driver

    def _run_groups(self, L, live_orig, use_need) -> list:
        raise NotImplementedError

    def apply(self, L: np.ndarray, live: np.ndarray | None = None, use_need: bool = True) -> np.ndarray:
        live_orig = None
        if live is not None:  # per original: does any of its sub-elements have a source?
            live_orig = np.add.reduceat(live.astype(np.int64), self.inp.offsets[:-1]) > 0
        y = np.zeros_like(L)
        for yp, terms in self._run_groups(L, live_orig, use_need):
            y += yp
            self.terms += terms
        if self.sparse is not None:
            from radiosity.methods.pairs import nearfield

            need = self.inp.need
            need_sub = need[self.inp.orig] if (use_need and len(need)) else None
            self.terms += nearfield.apply(self.sparse, L, y, self.inp.cap, self.inp.cmode, need_sub)
        self.passes += 1
        return y

    def row_sums(self) -> np.ndarray:
        m = len(self.inp.area)
        return self.apply(np.ones((2, 1, m)), use_need=False)[:, 0, :]

    def configure(self, **arrays) -> None:
        """Replace input arrays (cap and cmode, sided, need, sparse)."""
        self.inp = replace(self.inp, **arrays)


class LocalOperator(_Base):
    """The task functions run in this process, group after group (no cluster)."""

    def __init__(self, inp: SolveInputs, kernel: str, groups: int = 1):
        super().__init__(inp, kernel, groups)

    def _run_groups(self, L, live_orig, use_need) -> list:
        return [task_apply(self.inp, g, L, self.kid, live_orig, use_need) for g in self.groups]

    def gs_sweep(self, L, Le, rho) -> np.ndarray:
        new, terms = task_gs_sweep(self.inp, L, Le, rho, self.kid)
        self.terms += terms
        self.passes += 1
        return new


class DaskOperator(_Base):
    """The task functions as Dask tasks over groups of visibility tasks, run by the methods'
    GroupExecutor (groups pinned to workers, failed groups resubmitted, data lost with a worker
    sent again)."""

    def __init__(self, client, inp: SolveInputs, kernel: str, groups: int | None = None,
                 retries: int = 3):
        ngroups = groups or max(1, 2 * (sum(client.nthreads().values()) or 1))
        super().__init__(inp, kernel, ngroups)
        self.client = client
        self.executor = GroupExecutor(client, inp, len(self.groups), retries)

    def _run_groups(self, L, live_orig, use_need) -> list:
        return self.executor.run(
            task_apply, lambda i, Lf: (self.groups[i], Lf, self.kid, live_orig, use_need), (L,),
            name="solve group")

    def configure(self, **arrays) -> None:
        """Replace input arrays and re-scatter the inputs to the workers (one scatter)."""
        super().configure(**arrays)
        self.executor.replace_inputs(self.inp)

    def gs_sweep(self, L, Le, rho) -> np.ndarray:
        [(new, terms)] = self.executor.run(
            task_gs_sweep, lambda i, Lf, Lef, rhof: (Lf, Lef, rhof, self.kid), (L, Le, rho),
            name="Gauss-Seidel sweep", count=1)
        self.terms += terms
        self.passes += 1
        return new


# ----------------------------------------------------------------------------- opening a run

def open_operator(rs, client, kernel: str, settings, *, sampling=...):
    """The operator of run store `rs` for `kernel`: a DaskOperator on `client`, or a
    LocalOperator when client is None; with the kernel's near-field corrections (the partly
    visible pairs of the sampled kernels are read and applied on the workers, task by task, like
    the bits). settings: a settings.Settings (solve.cache-bytes, near-field-factor,
    visibility.retries). Returns (operator, partition, elements)."""
    s = settings
    vs = VisibilityStore(rs)
    token, plan, done = vs.require()
    missing = [t for t in range(len(plan.tasks)) if t not in done]
    if missing:
        raise RadiosityError(f"the visibility matrix of {rs.run_dir} is incomplete ({len(missing)} "
                             f"of {len(plan.tasks)} tasks missing): run radiosity visibility "
                             f"{rs.run_dir} --resume")
    if sampling is ...:
        sampling = sampling_of(s.solve, kernel)
    stored = vs.sampling()
    if stored != sampling:
        have = stored.describe() if stored else "one ray between centres"
        need = sampling.describe() if sampling else "one ray between centres"
        raise RadiosityError(f"the visibility of {rs.run_dir} was computed with {have}; the "
                             f"{kernel} kernel needs {need}: run radiosity visibility "
                             f"{rs.run_dir} --kernel {kernel}")
    crc = np.array([[done[t]["crc"], done[t]["nbytes"]] for t in range(len(plan.tasks))],
                   np.int64).reshape(-1, 2)
    pcrc = None
    if sampling is not None:
        pcrc = np.array([[done[t]["partial"]["crc"], done[t]["partial"]["n"]]
                         for t in range(len(plan.tasks))], np.int64).reshape(-1, 2)
    part = rs.load_partition()
    el = rs.load_elements()
    cache = int(s.solve.cache_bytes)
    inp = solve_inputs(part, el, plan, crc, rs.path, token, sampling, pcrc, cache)
    sparse = None
    k = get_kernel(kernel)
    if k.near_field:
        from radiosity.methods.pairs import nearfield

        sparse = nearfield.corrections(rs, k.base, float(s.solve.near_field_factor))
        inp = replace(inp, sparse=sparse_by_target(sparse, part.orig, len(part.offsets) - 1))
    if client is None:
        op = LocalOperator(inp, kernel)
    else:
        op = DaskOperator(client, inp, kernel, retries=int(s.visibility.retries))
    op.sparse = sparse
    return op, part, el
