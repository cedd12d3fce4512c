"""Solvers of the radiosity equation L = Le + rho (F L) (SPEC §2, §6), matrix-free.

F is never stored: each pass streams the visibility tiles and recomputes F on the fly
(kernels.py). A pass is a set of Dask tasks over groups of the visibility plan's tasks (row
blocks of the store), each pinned to a worker that keeps the tiles it read (bounded cache), so
the solve scales with workers like the visibility stage.

Vectors are (2, 3, m) float64: [side (0 front, 1 back), channel, sub-element]. All solvers
treat the three channels in the same pass over the matrix, share one signature

    solver(op, Le, rho, area, tol, max_iter, callback) -> SolveResult

and stop on a relative residual ||Le + rho F L - L||_A / ||Le||_A <= tol (area-weighted 2-norm);
progressive refinement and Gauss-Seidel stop on their cheaper bounds (unshot radiance, last
update) and every run ends with one true-residual pass for the report.
"""

from __future__ import annotations

import time
import zlib
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from . import config
from .errors import RadiosityError, StoreError
from .kernels import KERNELS, gs_sweep, kernel_id, sampling_of, tiles_apply
from .plan import END, FIRST, I, J, NCOLS, R0, R1, TBYTES, TSTART


@dataclass
class SolveResult:
    radiance: np.ndarray           # (2, 3, m) float64
    iterations: int
    residuals: list = field(default_factory=list)   # relative residual (or bound) per pass
    converged: bool = False
    ambient: np.ndarray | None = None   # (3,) progressive refinement's ambient term (last pass)


def anorm(x: np.ndarray, area: np.ndarray) -> float:
    """Area-weighted 2-norm of a (2, 3, m) vector."""
    return float(np.sqrt(np.sum(area * x * x)))


# ----------------------------------------------------------------------------- solvers

def _fixed_point(step, Le, area, tol, max_iter, callback) -> SolveResult:
    """Iterate L <- step(L) from L = Le until the update is at most tol ||Le||_A."""
    L = Le.copy()
    nb = anorm(Le, area) or 1.0
    res = []
    for k in range(1, max_iter + 1):
        new = step(L)
        res.append(anorm(new - L, area) / nb)
        L = new
        if callback:
            callback(k, res[-1], L)
        if res[-1] <= tol:
            return SolveResult(L, k, res, True)
    return SolveResult(L, max_iter, res, False)


def jacobi(op, Le, rho, area, tol, max_iter, callback=None) -> SolveResult:
    """The seed's iteration of eq. 4: L <- Le + rho F L. Its update is the residual of the
    previous iterate, Le + rho F L - L."""
    return _fixed_point(lambda L: Le + rho * op.apply(L), Le, area, tol, max_iter, callback)


def gauss_seidel(op, Le, rho, area, tol, max_iter, callback=None) -> SolveResult:
    """Block Gauss-Seidel by original element (rows in order, latest values), one Dask task per
    sweep. Stops on the size of the last update, a bound on the residual's decrease."""
    return _fixed_point(lambda L: op.gs_sweep(L, Le, rho), Le, area, tol, max_iter, callback)


def progressive(op, Le, rho, area, tol, max_iter, callback=None) -> SolveResult:
    """Progressive refinement (2nd seed; Cohen et al. 1988): shoot the unshot radiance of the
    sub-elements with the largest unshot power A dL (all within `shoot-fraction` of the largest
    shoot together, one pass). The ambient term (unshot power spread uniformly and reflected
    with the mean reflectance) makes early previews plausible; it is not added to the answer.
    Stops when the unshot radiance ||dL||_A <= tol ||Le||_A."""
    frac = float(config.get("solve.shoot-fraction"))
    L = Le.copy()
    dL = Le.copy()
    nb = anorm(Le, area) or 1.0
    total_area = area.sum()
    nch = Le.shape[1]
    rho_mean = np.array([(area * rho[0, c]).sum() / total_area for c in range(nch)])
    res = []
    ambient = np.zeros(nch)
    for k in range(1, max_iter + 1):
        power = area * np.abs(dL).sum(axis=(0, 1))
        top = power.max(initial=0.0)
        if top <= 0:
            return SolveResult(L, k - 1, res, True, ambient=ambient)
        shoot = power >= frac * top
        x = np.where(shoot, dL, 0.0)
        y = op.apply(x, live=shoot)
        recv = rho * y
        L += recv
        dL = np.where(shoot, 0.0, dL) + recv
        res.append(anorm(dL, area) / nb)
        unshot = np.array([(area * dL[:, c]).sum() for c in range(nch)]) / total_area
        ambient = unshot / np.maximum(1.0 - rho_mean, 1e-12)
        if callback:
            callback(k, res[-1], L + rho * ambient[None, :, None])
        if res[-1] <= tol:
            return SolveResult(L, k, res, True, ambient=ambient)
    return SolveResult(L, max_iter, res, False, ambient=ambient)


def cg(op, Le, rho, area, tol, max_iter, callback=None) -> SolveResult:
    """Conjugate gradients on the symmetric form (SPEC §6): with D = diag(A / rho),
    D (I - rho F) = D - diag(A) F is symmetric by reciprocity (A_a F_ab = A_b F_ba), and positive
    definite when rho < 1 and row sums <= 1. D itself is the preconditioner (it is the diagonal,
    F_aa = 0), which removes the spread of element areas from the conditioning. Entries with
    rho = 0 are known (L = Le) and move to the right-hand side. One product per iteration; the
    three channels are three systems solved in the same passes."""
    if not KERNELS[op.kernel][2]:
        raise RadiosityError(f"the cg solver needs a reciprocal kernel (A_a F_ab = A_b F_ba); "
                             f"'{op.kernel}' is not: use --kernel point, or --solver jacobi, "
                             "gauss-seidel or progressive")
    U = rho > 0
    D = np.where(U, area / np.where(U, rho, 1.0), 0.0)
    Dinv = np.where(U, rho / area, 0.0)
    known = np.where(U, 0.0, Le)
    b = np.where(U, D * Le + area * op.apply(known), 0.0)

    def M(x):
        return np.where(U, D * x - area * op.apply(x), 0.0)

    def dot(u, v):  # per channel
        return (u * v).sum(axis=(0, 2))

    x = np.where(U, Le, 0.0)
    r = b - M(x)
    z = Dinv * r
    p = z.copy()
    rz = dot(r, z)
    nb = anorm(Le, area) or 1.0
    res = []
    for k in range(1, max_iter + 1):
        Mp = M(p)
        pMp = dot(p, Mp)
        alpha = np.where(pMp > 0, rz / np.where(pMp > 0, pMp, 1.0), 0.0)
        x = x + alpha[None, :, None] * p
        r = r - alpha[None, :, None] * Mp
        z = Dinv * r  # also the true residual Le + rho F L - L on U
        res.append(anorm(z, area) / nb)
        L = x + known
        if callback:
            callback(k, res[-1], L)
        if res[-1] <= tol:
            return SolveResult(L, k, res, True)
        rz_new = dot(r, z)
        beta = np.where(rz > 0, rz_new / np.where(rz > 0, rz, 1.0), 0.0)
        p = z + beta[None, :, None] * p
        rz = rz_new
    return SolveResult(x + known, max_iter, res, False)


SOLVERS = {"jacobi": jacobi, "gauss-seidel": gauss_seidel, "progressive": progressive, "cg": cg}


def get_solver(name: str):
    try:
        return SOLVERS[name]
    except KeyError:
        raise RadiosityError(f"unknown solver {name!r}: use one of {', '.join(SOLVERS)}") from None


# ----------------------------------------------------------------------------- worker side

class SolveInputs:
    """Read-only arrays the product tasks need (scattered once per solve).

    cx, cy, cz, nx, ny, nz, area (m,) float64; sided (m,) bool; offsets (n + 1,) int64;
    tiles, tasks: the visibility plan; crc: (k, 2) int64 [crc32, nbytes] per plan task;
    pts, w: sample points and weights of the sampled kernels (kernels.sample_points); pcrc:
    (k, 2) int64 [crc32, length] of each task's partly visible pairs (sampled kernels; else
    (0, 2)); sparse: near-field corrections grouped for Gauss-Seidel (kernels.sparse_by_target).
    """

    def __init__(self, part, elements, plan, crc, store_path, token, sampling=None, pcrc=None):
        from .kernels import sample_points, sparse_by_target

        c, n = part.center, part.normal
        self.cx, self.cy, self.cz = (np.ascontiguousarray(c[:, k]) for k in range(3))
        self.nx, self.ny, self.nz = (np.ascontiguousarray(n[:, k]) for k in range(3))
        self.area = part.area
        self.cap = np.ones(len(part.area))  # row normalisation (see normalise_rows)
        self.orig = part.orig
        self.sided = elements.two_sided[part.orig]
        self.need = np.zeros(0, np.bool_)  # originals that gather; empty = all (planner.py)
        self.offsets = part.offsets
        self.tiles = plan.tiles
        self.tasks = plan.tasks
        self.crc = crc
        self.store_path = store_path
        self.token = token
        self.pts, self.w = sample_points(part.verts, part.nverts, sampling)
        self.pcrc = np.zeros((0, 2), np.int64) if pcrc is None else pcrc
        self.sparse = sparse_by_target(None, part.orig, len(part.offsets) - 1)


_TILES: "OrderedDict[tuple, tuple]" = OrderedDict()  # key -> (value, bytes)
_TILES_BYTES = [0]


def _cached(key: tuple, load, nbytes):
    """This worker's bounded cache (solve.cache-bytes) of what passes read from the store."""
    got = _TILES.get(key)
    if got is not None:
        _TILES.move_to_end(key)
        return got[0]
    value = load()
    size = nbytes(value)
    cap = int(config.get("solve.cache-bytes"))
    if size <= cap:
        _TILES[key] = (value, size)
        _TILES_BYTES[0] += size
        while _TILES_BYTES[0] > cap:
            _, (_, old) = _TILES.popitem(last=False)
            _TILES_BYTES[0] -= old
    return value


def _task_bytes(inp: SolveInputs, task: int) -> np.ndarray:
    """The verified bytes of one visibility task, from this worker's cache or the store."""

    def load():
        from .store import read_bits

        t = inp.tasks[task]
        data = read_bits(inp.store_path, int(t[TSTART]), int(inp.crc[task, 1]))
        if zlib.crc32(data.tobytes()) != int(inp.crc[task, 0]):
            raise StoreError(f"visibility task {task} in {inp.store_path} is corrupted (checksum): "
                             "run radiosity visibility RUN_DIR --resume")
        return data

    return _cached((inp.store_path, inp.token, task), load, lambda d: d.nbytes)


def _task_partial(inp: SolveInputs, task: int):
    """The verified partly visible pairs of one visibility task (sampled kernels), cached with
    the tiles: pairs (k, 3) int64 [a, b, visible rays], phi (k,)."""
    from .store import read_partial

    entry = {"crc": int(inp.pcrc[task, 0]), "n": int(inp.pcrc[task, 1])}
    return _cached((inp.store_path, inp.token, task, "partial"),
                   lambda: read_partial(inp.store_path, task, entry),
                   lambda g: g[0].nbytes + g[1].nbytes)


def partial_corrections(inp: SolveInputs, kid: int):
    """Every partly visible pair of a sampled kernel as sparse corrections F_ab (phi - 1) on top
    of the unoccluded kernel, grouped for Gauss-Seidel (which holds the whole matrix on one
    worker); made once per worker and kept in its cache."""
    from .kernels import sampled_pairs, sparse_by_target

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

    return _cached((inp.store_path, inp.token, kid, "gauss-seidel"), load,
                   lambda g: sum(a.nbytes for a in g))


def _geometry(inp):
    return (inp.cx, inp.cy, inp.cz, inp.nx, inp.ny, inp.nz, inp.area, inp.cap, inp.sided, inp.pts,
            inp.w)


def task_apply(inp: SolveInputs, task_ids: np.ndarray, L: np.ndarray, kid: int, live,
               use_need: bool = True):
    """y = F L restricted to the tiles of these visibility tasks. live: (n,) bool or None, the
    originals whose L is non-zero (tiles with no live source are skipped); with use_need, rows
    of originals that do not gather (inp.need) are skipped."""
    from .kernels import BOTH, partial_apply

    y = np.zeros_like(L)
    terms = 0
    lv = np.zeros(0, np.bool_) if live is None else np.asarray(live, np.bool_)
    need = inp.need if use_need else np.zeros(0, np.bool_)
    for task in task_ids:
        t = inp.tasks[task]
        tiles = inp.tiles[t[FIRST]:t[END]]
        if live is not None and not (lv[tiles[:, I]].any() or lv[tiles[:, J]].any()):
            continue
        data = _task_bytes(inp, int(task))
        terms += tiles_apply(kid, data, int(t[TSTART]), tiles, inp.offsets, *_geometry(inp), L, y,
                             BOTH, lv, need)
        if len(inp.pcrc) and inp.pcrc[task, 1] > 0:  # sampled kernels: the partly visible pairs
            pairs, phi = _task_partial(inp, int(task))
            terms += partial_apply(kid, pairs, phi, inp.pts, inp.w, inp.cx, inp.cy, inp.cz, inp.nx,
                                   inp.ny, inp.nz, inp.area, inp.cap, L, y, inp.orig, need)
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
    terms = gs_sweep(kid, data, inp.tiles, row_ptr, row_idx, col_ptr, col_idx, inp.offsets,
                     *_geometry(inp), L, Le, rho, y, inp.need, *sparse)
    return L, terms


# ----------------------------------------------------------------------------- the operator

class DaskOperator:
    """F applied to (2, 3, m) vectors by Dask tasks over groups of visibility tasks.

    Each group is pinned to one worker (its tile cache stays warm across passes); a group that
    fails is resubmitted anywhere."""

    def __init__(self, client, inp_future, inp: SolveInputs, kernel: str, groups: int | None = None):
        self.client = client
        self.inp_f = inp_future
        self.inp = inp
        self.kernel = kernel
        self.kid = kernel_id(kernel)
        self.terms = 0
        self.passes = 0
        workers = sorted(client.scheduler_info()["workers"])
        ngroups = groups or max(1, 2 * (sum(client.nthreads().values()) or 1))
        bits = (inp.tiles[:, R1] - inp.tiles[:, R0]) * inp.tiles[:, NCOLS]
        cum = np.concatenate([[0], np.cumsum(bits)])
        tbits = cum[inp.tasks[:, END]] - cum[inp.tasks[:, FIRST]]
        order = np.argsort(-tbits, kind="stable")
        load = np.zeros(ngroups)
        members = [[] for _ in range(ngroups)]
        for t in order:  # longest first onto the least loaded group
            g = int(np.argmin(load))
            members[g].append(int(t))
            load[g] += tbits[t]
        self.groups = [np.array(sorted(m), np.int64) for m in members if m]
        self.workers = [workers[g % len(workers)] for g in range(len(self.groups))] if workers else None
        self.retries = int(config.get("visibility.retries"))
        self.sparse = None  # near-field corrections (nearfield.py), applied here on the driver
        self._gs_fixed = None  # (Le, [futures of Le, rho]) scattered once for Gauss-Seidel

    def apply(self, L: np.ndarray, live: np.ndarray | None = None, use_need: bool = True) -> np.ndarray:
        """F L; `live` (m,) bool marks the sub-elements whose L may be non-zero; with use_need,
        the rows of originals that do not gather stay 0."""
        live_orig = None
        if live is not None:  # per original: does any of its sub-elements have a source?
            live_orig = np.add.reduceat(live.astype(np.int64), self.inp.offsets[:-1]) > 0
        [Lf] = self.client.scatter([L], broadcast=False, hash=False)
        futs = [self.client.submit(task_apply, self.inp_f, g, Lf, self.kid, live_orig, use_need,
                                   pure=False,
                                   workers=[w] if w else None, allow_other_workers=True,
                                   retries=self.retries)
                for g, w in zip(self.groups, self.workers or [None] * len(self.groups))]
        y = np.zeros_like(L)
        for yp, terms in self.client.gather(futs):
            y += yp
            self.terms += terms
        if self.sparse is not None:
            from . import nearfield

            need = self.inp.need
            need_sub = need[self.inp.orig] if (use_need and len(need)) else None
            self.terms += nearfield.apply(self.sparse, L, y, self.inp.cap, need_sub)
        self.passes += 1
        return y

    def row_sums(self) -> np.ndarray:
        """sum_b F_ab for every sub-element and side, (2, m) (one pass)."""
        m = len(self.inp.area)
        return self.apply(np.ones((2, 1, m)), use_need=False)[:, 0, :]

    def configure(self, **arrays) -> None:
        """Replace input arrays (cap, sided, need) and re-scatter the inputs to the workers."""
        for k, v in arrays.items():
            setattr(self.inp, k, v)
        [self.inp_f] = self.client.scatter([self.inp], broadcast=True, hash=False)

    def gs_sweep(self, L, Le, rho) -> np.ndarray:
        w = self.workers[0] if self.workers else None
        if self._gs_fixed is None or self._gs_fixed[0] is not Le:
            self._gs_fixed = (Le, self.client.scatter([Le, rho], hash=False))
        Lf = self.client.scatter([L], hash=False)[0]
        Lef, rhof = self._gs_fixed[1]
        f = self.client.submit(task_gs_sweep, self.inp_f, Lf, Lef, rhof, self.kid, pure=False,
                               workers=[w] if w else None, allow_other_workers=True,
                               retries=self.retries)
        new, terms = f.result()
        self.terms += terms
        self.passes += 1
        return new


# ----------------------------------------------------------------------------- the stage

def normalise_rows(op, mode="cap"):
    """Detect rows of F that sum to more than 1 (the point kernel near large elements close
    together, where 1/r^2 blows up) and decide how to handle them. Returns (figures, cap):
    what was found and done, and the `cap` (m,) to configure the operator with (None: none).

    cap (default): scale each pair by min(cap_a, cap_b), cap = 1 / row sum on the rows above 1:
        rows then sum to at most 1 and reciprocity still holds (A_a F'_ab = A_b F'_ba), so every
        solver converges for rho < 1.
    closed: for closed scenes, where every row must sum to exactly 1: scale pairs by d_a d_b
        with d from the symmetric balancing iteration d <- sqrt(d / (F d)) (reciprocity kept);
        what is left of the kernel's error no longer decides the answer when rho -> 1.
    off (or False): only report.
    """
    mode = {True: "cap", False: "off", None: "cap"}.get(mode, mode)
    if mode not in ("cap", "closed", "off"):
        raise RadiosityError(f"radiosity.solve.normalise-rows must be cap, closed or off, got {mode!r}")
    sums = op.row_sums()
    rs = sums.max(axis=0)
    over = rs > 1.0 + 1e-12
    out = {"rows_over_1": int(over.sum()), "max_row_sum": float(rs.max(initial=0.0)),
           "min_row_sum": float(sums.sum(axis=0).min(initial=0.0)), "mode": mode,
           "normalised": bool(mode == "cap" and over.any())}
    cap = None
    if out["normalised"]:
        cap = np.where(over, 1.0 / np.where(over, rs, 1.0), 1.0)
    elif mode == "closed":
        total = sums.sum(axis=0)
        if np.any(total <= 0):
            raise RadiosityError("normalise-rows=closed needs a closed scene: some element sees "
                                 "nothing")
        d = 1.0 / np.sqrt(total)
        m = len(d)
        for it in range(100):
            Fd = op.apply(np.broadcast_to(d, (2, 1, m)).copy(), use_need=False)[:, 0, :].sum(axis=0)
            err = np.abs(d * Fd - 1.0).max()
            if err < 1e-12:
                break
            d = np.sqrt(d / Fd)
        cap = -d  # negative: the kernels scale pairs by the product d_a d_b
        out.update({"normalised": True, "balancing_passes": it + 1, "balancing_error": float(err)})
    return out, cap


def side_vectors(part, elements):
    """Le, rho (2, 3, m) float64 and area (m,) of the sub-elements, per side."""
    Le = np.ascontiguousarray(np.transpose(elements.emission[part.orig], (1, 2, 0)))
    rho = np.ascontiguousarray(np.transpose(elements.reflectance[part.orig], (1, 2, 0)))
    return Le, rho, part.area


def open_operator(rs, client, kernel: str):
    """Scatter the solve inputs of run store `rs` and return a DaskOperator over them, with the
    kernel's near-field corrections (the partly visible pairs of the sampled kernels are read
    and applied on the workers, task by task, like the bits)."""
    from .kernels import base_kernel, sparse_by_target
    from .store import VisibilityStore

    vs = VisibilityStore(rs)
    token, plan, done = vs.require()
    missing = [t for t in range(len(plan.tasks)) if t not in done]
    if missing:
        raise RadiosityError(f"the visibility matrix of {rs.run_dir} is incomplete ({len(missing)} "
                             f"of {len(plan.tasks)} tasks missing): run radiosity visibility "
                             f"{rs.run_dir} --resume")
    sampling = sampling_of(kernel)
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
    inp = SolveInputs(part, el, plan, crc, rs.path, token, sampling, pcrc)
    sparse = None
    if KERNELS[kernel][3]:
        from . import nearfield

        sparse = nearfield.corrections(rs, base_kernel(kernel),
                                       float(config.get("solve.near-field-factor")))
        inp.sparse = sparse_by_target(sparse, part.orig, len(part.offsets) - 1)
    [inp_f] = client.scatter([inp], broadcast=True, hash=False)
    op = DaskOperator(client, inp_f, inp, kernel)
    op.sparse = sparse
    return op, part, el


def _previewer(rs, part, el):
    """A function (2, 3, m) radiance -> small sRGB image of the camera view (for the dashboard)."""
    from .render import downsample, pixel_radiance, tonemap

    if not rs.has("raster"):
        return lambda L: np.zeros((1, 1, 3), np.uint8)
    sub = rs.read_arrays("raster")["sub"]
    camera = rs.load_camera()
    K = int(rs.attrs.get("subpixel", 1))

    def make(L):
        L = np.broadcast_to(L, (2, 3, L.shape[2]))
        rad = np.ascontiguousarray(np.transpose(L, (2, 0, 1)))
        img = downsample(pixel_radiance(part, el, camera, sub, rad), K, "box")
        return tonemap(img)

    return make


def write_direct_solution(run_dir: str) -> dict:
    """No interreflection (reflectance 0 everywhere, planner.py): L = Le, without a pass."""
    from .store import RunStore, update_report

    rs = RunStore(run_dir, "r+")
    part, el = rs.load_partition(), rs.load_elements()
    rs.drop_after("nearfield")
    rs.write_arrays("solution", {"radiance": el.emission[part.orig]}, {"solver": "direct"})
    fig = {"solver": "direct (L = Le)", "kernel": "-", "iterations": 0, "converged": True,
           "residuals": [], "final_residual": 0.0, "passes": 0, "pair_terms": 0,
           "pair_terms_per_s": 0.0, "time_s": 0.0, "sub_elements": len(part), "channels": 0}
    update_report(run_dir, "solve", fig)
    return fig


def run_solve(run_dir: str, client, solver: str | None = None, kernel: str | None = None,
              tol: float | None = None, max_iter: int | None = None, progress: bool = True,
              callback=None, normalise: bool | None = None, effects=None) -> dict:
    """Solve the run's radiosity system; write solution/radiance (m, 2, 3) and report figures.

    effects: a planner.EffectsPlan (grey scenes solve one channel, dead rows skip gathering,
    two-sided elements reached from one side are solved one-sided)."""
    from tqdm.auto import tqdm

    from .store import RunStore, update_report

    solver = config.get("solve.solver", solver)
    kernel = config.get("solve.kernel", kernel)
    tol = float(config.get("solve.tol", tol))
    max_iter = int(config.get("solve.max-iterations", max_iter))
    fn = get_solver(solver)
    kernel_id(kernel)
    t0 = time.perf_counter()
    rs = RunStore(run_dir, "r+")
    op, part, el = open_operator(rs, client, kernel)
    Le, rho, area = side_vectors(part, el)
    rows, cap = normalise_rows(op, config.get("solve.normalise-rows", normalise))
    changes = {} if cap is None else {"cap": cap}
    channels = 3
    if effects is not None:
        changes["sided"] = effects.two_sided[part.orig]
        changes["need"] = effects.gather if not effects.gather.all() else np.zeros(0, np.bool_)
    if changes:
        op.configure(**changes)  # one scatter of the inputs
    if effects is not None:
        if not effects.colour:  # grey: one channel, broadcast at the end
            channels = 1
            Le, rho = Le[:, :1].copy(), rho[:, :1].copy()
    from .monitor import Monitor

    mon = Monitor(client)
    mon.stage("solve", run_dir)
    history = []
    make_image = _previewer(rs, part, el)
    bar = tqdm(total=None, desc=f"solve ({solver})", unit="pass", disable=not progress, leave=False)

    def cb(k, r, L):
        if not np.isfinite(r) or r > 1e8:
            bar.close()
            raise RadiosityError(
                f"{solver} diverged after {k} passes (residual {r:.3g}): rows of F sum to more "
                f"than 1/rho with the {kernel} kernel (large elements close together); keep "
                "radiosity.solve.normalise-rows on, use --kernel disc, or subdivide more")
        bar.update()
        bar.set_postfix(residual=f"{r:.2e}")
        history.append(r)
        mon.solve(solver, kernel, history)
        mon.preview(lambda: make_image(L))
        if callback:
            callback(k, r, L)

    t_iter, terms0 = time.perf_counter(), op.terms  # the solver's own passes, for the throughput
    res = fn(op, Le, rho, area, tol, max_iter, cb)
    t_iter, iter_terms = time.perf_counter() - t_iter, op.terms - terms0
    bar.close()
    mon.solve(solver, kernel, history, force=True)
    mon.preview(lambda: make_image(res.radiance), force=True)
    t_solve = time.perf_counter() - t0
    # one true-residual pass, the same measure for every solver
    y = op.apply(res.radiance)
    final = anorm(Le + rho * y - res.radiance, area) / (anorm(Le, area) or 1.0)
    L3 = np.broadcast_to(res.radiance, (2, 3, len(area))) if channels == 1 else res.radiance
    radiance = np.ascontiguousarray(np.transpose(L3, (2, 0, 1)))  # (m, 2, 3)
    figures = {
        "solver": solver, "kernel": kernel, "tol": tol, "iterations": res.iterations,
        "converged": bool(res.converged), "residuals": [float(r) for r in res.residuals],
        "final_residual": final, "passes": op.passes, "pair_terms": int(op.terms),
        "pair_terms_per_s": iter_terms / max(t_iter, 1e-9), "time_s": round(t_solve, 4),
        "sub_elements": len(part), "row_sums": rows, "channels": channels,
        "near_field": op.sparse["figures"] if op.sparse is not None else None,
        "partial_visibility": ({"pairs": int(op.inp.pcrc[:, 1].sum()),
                                "rays_per_pair": sampling_of(kernel).rays_per_pair}
                               if len(op.inp.pcrc) else None),
        "two_sided_sub_elements": int(op.inp.sided.sum()),
        "gathering_elements": int(op.inp.need.sum()) if len(op.inp.need) else len(part.offsets) - 1,
        "channel_terms": int(op.terms) * channels,
    }
    if res.ambient is not None:
        figures["ambient"] = res.ambient.tolist()
    rs.drop_after("nearfield")
    rs.write_arrays("solution", {"radiance": radiance},
                    {k: v for k, v in figures.items() if k != "residuals"})
    update_report(run_dir, "solve", figures)
    if not res.converged:
        import warnings

        warnings.warn(f"{solver} did not reach tol={tol:g} in {max_iter} passes (residual "
                      f"{res.residuals[-1] if res.residuals else float('nan'):.3g})", stacklevel=2)
    return figures
