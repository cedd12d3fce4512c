"""The visibility matrix (seed §4.3, SPEC §5): one bit per pair of sub-elements, computed by a
dynamic master that keeps every worker busy, written as bit-packed tiles into the run's store.

Design notes and measurements: docs/src/design/methods-pairs-visibility.md.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass

import numpy as np
from dask.base import tokenize

from radiosity.core.kernels import MC, NXM, Sampling, sample_points, sample_rays
from radiosity.runtime.monitor import peak_rss_mb, worker_address
from radiosity.methods.pairs.plan import I, J, NBYTES, NCOLS, R0, R1, START, TBYTES, TSTART, make_plan
from radiosity.runtime.packing import choose_unit
from radiosity.tracing.rays import caster_for
from radiosity.runtime.stage import StageMaster, StagePlan, TaskFigures
from radiosity.settings import sampling_of
from radiosity.tracing.shafts import block_candidates, classify, occluders, set_bits, small_tile_pairs
from radiosity.runtime.store import RunStore
from radiosity.methods.pairs.store import VisibilityStore, write_bits, write_partial

SMALL_TILE_FACTOR = 8  # tiles with pairs * this < number of elements skip the shaft search


@dataclass(frozen=True)
class VisibilityFigures(TaskFigures):
    """The visibility stage's figures (report.json, section "visibility"); pair counts are of
    unordered pairs of sub-elements."""

    SECTION = "visibility"
    task_unit: str
    tasks: int
    tiles: int
    chunk_bytes: int
    store_bytes: int
    sub_elements: int
    blocks_culled: int
    pairs_total: int
    pairs_in_blocks: int
    pairs_facing: int
    pairs_shaft_visible: int
    rays: int
    pairs_visible: int
    shaft_tests: int
    pairs_partial: int
    pairs_culled_by_orientation: int
    rays_fraction_of_pairs: float
    naive_ordered_rays: int
    time_s: float
    occlusion: bool
    sampling: str | None
    rays_per_pair: int
    peak_rss_mb: dict

    def rows(self):
        pt = max(1, self.pairs_total)
        culled = self.pairs_culled_by_orientation
        return [("sub-elements", self.sub_elements), ("pairs", self.pairs_total),
                ("culled by orientation", f"{culled} ({culled / pt:.1%})"),
                ("proven visible by shafts",
                 f"{self.pairs_shaft_visible} ({self.pairs_shaft_visible / pt:.1%})"),
                ("rays cast", f"{self.rays} ({self.rays / pt:.1%} of pairs, "
                              f"{self.rays_per_pair} per pair)"),
                ("visible pairs", self.pairs_visible),
                ("tasks", f"{self.tasks} {self.task_unit} ({self.tasks_computed} computed, "
                          f"{self.tasks_reused} reused)"),
                ("idle fraction", "-" if self.idle_fraction is None else f"{self.idle_fraction:.1%}"),
                ("time", f"{self.time_s:.2f} s")]


# ----------------------------------------------------------------------------- inputs

@dataclass(frozen=True)
class VisInputs:
    """Read-only arrays every visibility task needs; scattered to the workers once.

    center, normal (m, 3) float64; two_sided (m,) bool; orig (m,) int32; lo, hi (m, 3) float64
    sub-element boxes; offsets (n + 1,) int64; elo, ehi (n, 3) padded boxes of the originals
    (the occluders), enormal (n, 3), eoffset (n,) their planes, pad the plane tolerance;
    verts (n, 4, 3), nverts (n,) for the Embree scene; key: the Embree cache key; ray_offset: the
    ray offset; occlusion: False when nothing can block (effects.py); sampling (kernels.Sampling
    or None) with kid, pts (m, S, 3), w (m, S): the sample points of a sampled kernel.
    """

    center: np.ndarray
    normal: np.ndarray
    two_sided: np.ndarray
    orig: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    offsets: np.ndarray
    elo: np.ndarray
    ehi: np.ndarray
    enormal: np.ndarray
    eoffset: np.ndarray
    pad: float
    verts: np.ndarray
    nverts: np.ndarray
    key: str
    ray_offset: float
    occlusion: bool
    sampling: Sampling | None
    kid: int
    pts: np.ndarray
    w: np.ndarray

    @property
    def pts_flat(self) -> np.ndarray:
        return self.pts.reshape(-1, 3)

    @property
    def pts_orig(self) -> np.ndarray:
        return np.repeat(self.orig, self.pts.shape[1])


def vis_inputs(part, elements, key: str, ray_offset: float, occlusion: bool = True,
               sampling: Sampling | None = None) -> VisInputs:
    """The VisInputs of a partition (all values resolved here, on the driver)."""
    v = np.where(part.nverts[:, None, None] == 3, part.verts[:, [0, 1, 2, 2]], part.verts)
    elo, ehi, enormal, eoffset, pad = occluders(elements)
    pts, w = sample_points(part.verts, part.nverts, sampling)
    return VisInputs(
        center=part.center, normal=part.normal, two_sided=elements.two_sided[part.orig],
        orig=part.orig, lo=v.min(axis=1), hi=v.max(axis=1), offsets=part.offsets,
        elo=elo, ehi=ehi, enormal=enormal, eoffset=eoffset, pad=pad, verts=elements.verts, nverts=elements.nverts,
        key=key, ray_offset=float(ray_offset), occlusion=occlusion, sampling=sampling,
        kid=0 if sampling is None else (NXM if sampling.kind == "nxm" else MC), pts=pts, w=w)


def tile_bits(inp: VisInputs, caster, i: int, j: int, r0: int, r1: int):
    """The bits of rows r0:r1 of block (i, j): (r1 - r0) * nJ bool, row-major, and counters.

    Without occlusion (effects.py: nothing can block), facing pairs are visible: no shafts, no rays."""
    a0, b0, b1 = inp.offsets[i] + r0, inp.offsets[j], inp.offsets[j + 1]
    a1 = inp.offsets[i] + r1
    A = np.empty((2, 3))
    B = np.empty((2, 3))
    A[0], A[1] = inp.lo[a0:a1].min(0), inp.hi[a0:a1].max(0)
    B[0], B[1] = inp.lo[b0:b1].min(0), inp.hi[b0:b1].max(0)
    pad = inp.pad
    if inp.occlusion:
        cand = block_candidates(A, B, inp.elo, inp.ehi, inp.enormal, inp.eoffset, pad, i, j)
    else:
        cand = np.zeros(0, np.int64)
    code, tests = classify((inp.center[a0:a1], inp.normal[a0:a1], inp.two_sided[a0:a1],
                            inp.lo[a0:a1], inp.hi[a0:a1]),
                           (inp.center[b0:b1], inp.normal[b0:b1], inp.two_sided[b0:b1],
                            inp.lo[b0:b1], inp.hi[b0:b1]),
                           (inp.elo, inp.ehi, inp.enormal, inp.eoffset, pad), cand,
                           inp.sampling is not None)
    bits = code == 1
    need = np.nonzero(code == 2)[0]
    nb = b1 - b0
    partial = _NO_PARTIAL
    rays = len(need)
    if len(need) and inp.sampling is None:
        occ = caster.occluded_pairs(inp.center, a0 + need // nb, b0 + need % nb, inp.orig)
        bits[need] = ~occ
    elif len(need):
        bits[need], partial, rays = sampled_visibility(inp, caster, a0 + need // nb, b0 + need % nb)
    counts = np.array([len(code), int(np.count_nonzero(code)), int(np.count_nonzero(code == 1)),
                       rays, int(bits.sum()), tests, len(partial[0])], np.int64)
    return bits, counts, partial


COUNTERS = ("pairs_in_blocks", "pairs_facing", "pairs_shaft_visible", "rays", "pairs_visible",
            "shaft_tests", "pairs_partial")
_NO_PARTIAL = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
SAMPLED_BATCH = 1 << 16  # pairs per batch of sample rays (bounds the per-ray arrays)


def sampled_visibility(inp: VisInputs, caster, ia: np.ndarray, ib: np.ndarray):
    """One ray per sample pair of each pair (ia, ib) (kernels.sample_rays). Returns whether
    some sample pair sees (k,) bool, the partly visible pairs (a, b, visible rays, phi) with
    phi the kernel-weighted visible fraction, and the number of rays cast."""
    seen = np.zeros(len(ia), bool)
    parts = []
    P = inp.sampling.rays_per_pair
    for s in range(0, len(ia), SAMPLED_BATCH):
        a, b = ia[s:s + SAMPLED_BATCH], ib[s:s + SAMPLED_BATCH]
        ra, rb, term = sample_rays(inp.kid, inp.pts, inp.w, inp.center, inp.normal, a, b)
        V = ~caster.occluded_pairs(inp.pts_flat, ra, rb, inp.pts_orig).reshape(len(a), P)
        count = V.sum(axis=1)
        seen[s:s + len(a)] = count > 0
        part = (count > 0) & (count < P)
        tot = term[part].sum(axis=1)
        vis = (term[part] * V[part]).sum(axis=1)
        phi = np.where(tot > 0, vis / np.where(tot > 0, tot, 1.0), count[part] / P)
        parts.append((a[part], b[part], count[part], phi))
    if not parts:
        return seen, _NO_PARTIAL, 0
    return seen, tuple(np.concatenate(x) for x in zip(*parts)), len(ia) * P


# ----------------------------------------------------------------------------- the task

def task_visibility(inp: VisInputs, tiles: np.ndarray, store_path: str, tstart: int, tbytes: int,
                    task: int = 0):
    """Compute the tiles of one task, write their packed bits as whole chunks (and, for sampled
    kernels, the task's partly visible pairs), return a summary.

    Returns dict: crc (crc32 of the unpadded bytes), nbytes, counts (len(COUNTERS),), partial
    (crc32 and length of the partial pairs), worker (its address), start, stop.
    """
    t0 = time.time()
    caster = caster_for(inp.key, inp.verts, inp.nverts, inp.ray_offset)
    buf = np.zeros(tbytes, np.uint8)
    counts = np.zeros(len(COUNTERS), np.int64)
    partials = []
    used = int((tiles[:, START] + tiles[:, NBYTES]).max() - tstart) if len(tiles) else 0
    # small tiles: one batched pass, every facing pair gets a ray
    pairs = (tiles[:, R1] - tiles[:, R0]) * tiles[:, NCOLS]
    small = pairs * SMALL_TILE_FACTOR < len(inp.elo)
    if small.any():
        ia, ib, bit = small_tile_pairs(tiles[small], inp.offsets, inp.center, inp.normal,
                                       inp.two_sided, tstart)
        rays, npart = 0, 0
        if not inp.occlusion:
            vis = np.ones(len(ia), bool)
        elif inp.sampling is None:
            vis = ~caster.occluded_pairs(inp.center, ia, ib, inp.orig)
            rays = len(ia)
        else:
            vis, part, rays = sampled_visibility(inp, caster, ia, ib)
            partials.append(part)
            npart = len(part[0])
        set_bits(buf, bit[vis])
        counts += np.array([int(pairs[small].sum()), len(ia), len(ia) if rays == 0 else 0, rays,
                            int(vis.sum()), 0, npart])
    for t in tiles[~small]:
        bits, c, part = tile_bits(inp, caster, int(t[I]), int(t[J]), int(t[R0]), int(t[R1]))
        packed = np.packbits(bits, bitorder="little")
        off = int(t[START]) - tstart
        buf[off:off + int(t[NBYTES])] = packed
        counts += c
        partials.append(part)
    write_bits(store_path, tstart, buf)
    out = {"crc": zlib.crc32(buf[:used].tobytes()), "nbytes": used, "counts": counts,
           "start": t0, "stop": time.time(), "worker": worker_address()}
    if inp.sampling is not None:
        part = tuple(np.concatenate(x) for x in zip(*partials)) if partials else _NO_PARTIAL
        out["partial"] = write_partial(store_path, task, *part)
    return out


# ----------------------------------------------------------------------------- the master

def plan_for(part, elements, unit: str | None, settings, where: str = "the scene"):
    """The visibility plan of a partition, with the task unit and sizes from `settings`. The
    blocks that face each other come from the hierarchy over the originals (originals.py):
    nothing n x n, and at most plan.max-facing-pairs of them (refused beyond)."""
    from radiosity.scene.originals import pairs_within_budget, tree_of

    vis = settings.visibility
    unit = choose_unit(unit or vis.task_unit, len(elements), int(vis.stripe_threshold))
    tree = tree_of(elements, int(settings.plan.leaf_size))
    bi, bj, _ = pairs_within_budget(tree, int(settings.plan.max_facing_pairs), where)
    return make_plan(part.offsets, (bi, bj), unit, int(vis.max_task_bits),
                     min_task_bits=int(vis.min_task_bits))


class _Ledger:
    """The visibility group as run_stage's ledger (verify needs the plan)."""

    def __init__(self, vs: VisibilityStore, plan):
        self.vs, self.plan = vs, plan

    def token(self):
        return self.vs.token()

    def finished(self, token):
        return self.vs.finished(token)

    def verify(self, task, entry):
        return self.vs.verify(self.plan, task, entry)

    def rewrite_manifest(self, token, entries):
        self.vs.rewrite_manifest(token, entries)

    def record(self, task, result):
        self.vs.record(task, result)


class VisibilityStage(StageMaster):
    """The visibility matrix on the one stage master: the plan of tiles and tasks (plan_for),
    the inputs (vis_inputs), one task_visibility per task, the store's visibility group as the
    ledger, VisibilityFigures."""

    task = staticmethod(task_visibility)
    counters = COUNTERS
    monitor_stage = "visibility"
    straight = False

    def __init__(self, run_dir: str, client, s, unit: str | None, occlusion: bool, **kw):
        super().__init__(client, report_dir=run_dir, **kw)
        self.s, self.unit, self.occlusion = s, unit, occlusion
        self.sampling = sampling_of(s.solve)
        self.ray_offset = float(s.rays.offset)

    def plan(self) -> StagePlan:
        s, run_dir = self.s, self.report_dir
        self.rs = rs = RunStore(run_dir, "r+")
        self.part, self.el = part, el = rs.load_partition(), rs.load_elements()
        self.vplan = plan = plan_for(part, el, self.unit, s, where=rs.attrs.get("scene") or run_dir)
        self.sampled = None if self.sampling is None else self.sampling.to_dict()
        self.token = tokenize(plan.tiles, plan.tasks, plan.chunk, part.center, part.normal,
                              el.verts, self.ray_offset, self.occlusion, self.sampled)
        self.vs = VisibilityStore(rs)
        return StagePlan("visibility", self.token, rs.path, len(plan.tasks), plan.task_bits(),
                         f"rerun with: radiosity visibility {run_dir} --resume",
                         int(s.visibility.window_per_worker), int(s.visibility.retries))

    def create(self) -> None:
        self.rs.drop_after("raster")
        self.vs.create(self.vplan, self.token, {"rays_epsilon": self.ray_offset,
                                                "sampling": self.sampled})

    def ledger(self):
        return _Ledger(self.vs, self.vplan)

    def inputs(self) -> VisInputs:
        el = self.el
        return vis_inputs(self.part, el, tokenize(el.verts, el.nverts), self.ray_offset,
                          self.occlusion, self.sampling)

    def args(self, task: int, shared) -> tuple:
        t = self.vplan.tasks[task]
        return (shared, self.vplan.tiles_of(task), self.rs.path, int(t[TSTART]), int(t[TBYTES]),
                task)

    def on_result(self, task, result, done) -> None:
        self.monitor.visibility(self.vplan, done, len(self.el))

    def figures(self, run) -> VisibilityFigures:
        plan, sampling = self.vplan, self.sampling
        self.monitor.visibility(plan, run.done, len(self.el), force=True)
        c = dict(zip(COUNTERS, run.counts.tolist()))
        m = len(self.part)
        pairs = m * (m - 1) // 2
        return VisibilityFigures(
            task_unit=plan.unit, tasks=int(len(plan.tasks)), **run.figures(),
            tiles=int(len(plan.tiles)), chunk_bytes=plan.chunk, store_bytes=plan.total,
            sub_elements=m, blocks_culled=int(plan.blocks_culled), pairs_total=pairs, **c,
            pairs_culled_by_orientation=pairs - c["pairs_facing"],
            rays_fraction_of_pairs=c["rays"] / max(1, pairs),
            naive_ordered_rays=m * (m - 1),  # ordered pairs a brute force would trace
            time_s=round(time.perf_counter() - self.t_start, 4), occlusion=self.occlusion,
            sampling=None if sampling is None else sampling.describe(),
            rays_per_pair=1 if sampling is None else sampling.rays_per_pair,
            peak_rss_mb=peak_rss_mb(self.client))


def compute_visibility(run_dir: str, client, settings, *, unit: str | None = None,
                       resume: bool = False, progress: bool = True, on_done=None,
                       occlusion: bool = True) -> VisibilityFigures:
    """The dynamic master (seed §4.3) on the one stage master (runtime/stage.py): a bounded
    window of tasks per worker thread, most expensive first, failed tasks resubmitted, every
    finished task recorded with its checksum, so `resume` recomputes only what is missing or
    corrupted. occlusion=False (effects.py: nothing can block) makes the bits orientation
    alone. settings: the run's settings.Settings; its solve.kernel's sampled kernels (nxm, mc)
    cast one ray per sample pair."""
    return VisibilityStage(run_dir, client, settings, unit, occlusion, resume=resume,
                           progress=progress, on_done=on_done).run()


# ----------------------------------------------------------------------------- readers

def iter_tiles(rs):
    """Yield (I, J, r0, r1, bits (r1 - r0, nJ) bool) for every stored tile (store.py decodes
    and verifies them)."""
    return VisibilityStore(rs).iter_tiles()


def dense_visibility(rs) -> np.ndarray:
    """The whole matrix as (m, m) bool, for small scenes and tests only."""
    return VisibilityStore(rs).dense(rs.load_partition().offsets)
