"""The visibility matrix (seed §4.3, SPEC §5): one bit per pair of sub-elements, computed by a
dynamic master that keeps every worker busy, written as bit-packed tiles into the run's store.

Per pair (a, b): V = 1 iff the two face each other (cos > 0 on a side that exists: both sides of a
two-sided element) and the open segment between their centres hits nothing. Work is culled before
any ray is cast:

1. orientation, per block (plan.facing_blocks) and per pair (cos <= 0 -> 0, no ray);
2. shafts (Haines & Wallace 1991), hierarchically: a block's rows and columns are halved
   recursively (sub-elements are in depth-first split order, so a range is a compact patch);
   each pair of ranges keeps only the occluder boxes that enter the shaft between their boxes;
   a range pair with no occluder left is all visible without rays;
3. at the leaves, a pair whose segment misses every remaining occluder box is visible; only the
   others get an Embree ray.

Sampled kernels (kernels.py: nxm, mc) cast one ray per sample pair instead: at the leaves a pair
is visible without rays only when no occluder enters the shaft between the two sub-elements'
boxes (then every sample pair sees); the others get all their sample rays. The bit is "some
sample pair sees"; pairs that only partly see are kept sparsely per task (pairs a < b, the
number of visible sample rays and the kernel-weighted visible fraction phi, store.py).
"""

from __future__ import annotations

import os
import time
import zlib

import numba
import numpy as np

from . import config
from .plan import END, FIRST, I, J, NBYTES, NCOLS, R0, R1, START, TBYTES, TSTART

COS_TOL = 1e-9   # |cos| below this (relative) counts as coplanar: exactly zero, not noise
BOX_PAD = 1e-6   # occluder boxes grow by this fraction of the scene size (conservative)
LEAF = 64        # range pairs with at most this many pairs are tested pair by pair
SMALL_TILE_FACTOR = 8  # tiles with pairs * this < number of elements skip the shaft search


# ----------------------------------------------------------------------------- kernels

@numba.njit(cache=True, inline="always")
def _faces(n, ts, dx, dy, dz, length):
    """Does an element with normal n (two-sided if ts) face along d? cos beyond +-tol."""
    c = n[0] * dx + n[1] * dy + n[2] * dz
    t = COS_TOL * length
    return c > t or (ts and c < -t)


@numba.njit(cache=True, inline="always")
def _seg_box(px, py, pz, qx, qy, qz, lo, hi):
    """Does the segment p-q touch the closed box [lo, hi]? (slab test)"""
    t0, t1 = 0.0, 1.0
    p = (px, py, pz)
    d = (qx - px, qy - py, qz - pz)
    for k in range(3):
        if d[k] == 0.0:
            if p[k] < lo[k] or p[k] > hi[k]:
                return False
        else:
            inv = 1.0 / d[k]
            ta = (lo[k] - p[k]) * inv
            tb = (hi[k] - p[k]) * inv
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
            if t0 > t1:
                return False
    return True


@numba.njit(cache=True, inline="always")
def _box_side(X, n, d, pad):
    """+1 if box X lies entirely in front of plane (n, d) (beyond pad), -1 behind, 0 neither."""
    lo = 0.0
    hi = 0.0
    for k in range(3):
        if n[k] > 0:
            lo += n[k] * X[0, k]
            hi += n[k] * X[1, k]
        else:
            lo += n[k] * X[1, k]
            hi += n[k] * X[0, k]
    if lo - d > pad:
        return 1
    if hi - d < -pad:
        return -1
    return 0


@numba.njit(cache=True, inline="always")
def _same_side(A, B, n, d, pad):
    """Do boxes A and B lie strictly on one side of the occluder's plane? Then no segment
    between them can cross the (planar) occluder."""
    sa = _box_side(A, n, d, pad)
    return sa != 0 and sa == _box_side(B, n, d, pad)


@numba.njit(cache=True)
def _range_box(lo, hi, a0, a1, out):
    for k in range(3):
        out[0, k] = np.inf
        out[1, k] = -np.inf
    for i in range(a0, a1):
        for k in range(3):
            if lo[i, k] < out[0, k]:
                out[0, k] = lo[i, k]
            if hi[i, k] > out[1, k]:
                out[1, k] = hi[i, k]


@numba.njit(cache=True)
def _shaft_excludes(A, B, clo, chi):
    """Is box C = [clo, chi] outside the shaft (convex hull) of boxes A and B? (A[0]=lo, A[1]=hi)

    Haines & Wallace: the union's bounding box, cut by the planes through box edges where one
    box sticks out on one axis and the other on a second axis. Conservative: False may be wrong,
    True never is.
    """
    for k in range(3):
        if chi[k] < min(A[0, k], B[0, k]) or clo[k] > max(A[1, k], B[1, k]):
            return True
    for i in range(3):
        for j in range(i + 1, 3):
            for si in range(2):
                for sj in range(2):
                    # corner direction (+-1 on i, +-1 on j); box extremes on that corner
                    gi = 1.0 if si == 1 else -1.0
                    gj = 1.0 if sj == 1 else -1.0
                    ai, aj = A[si, i], A[sj, j]
                    bi, bj = B[si, i], B[sj, j]
                    a_out_i = gi * (ai - bi) > 0
                    a_out_j = gj * (aj - bj) > 0
                    if a_out_i == a_out_j:
                        continue  # one box is outermost on both axes: the bounding box suffices
                    # plane through (ai, aj) and (bi, bj) in the (i, j) plane, normal outward
                    ni = -(bj - aj)
                    nj = bi - ai
                    if ni * gi + nj * gj < 0:
                        ni, nj = -ni, -nj
                    d = ni * ai + nj * aj
                    # nearest corner of C to the inside: minimise ni*x + nj*y
                    x = clo[i] if ni > 0 else chi[i]
                    y = clo[j] if nj > 0 else chi[j]
                    if ni * x + nj * y > d + 1e-12 * (abs(d) + abs(ni) + abs(nj)):
                        return True
    return False


@numba.njit(cache=True)
def classify(ca, na, tsa, la, ha, cb, nb, tsb, lb, hb, olo, ohi, on, od, pad, cand, sampled):
    """Classify every pair of a tile without rays.

    Rows: centres ca (ra, 3), normals na, two-sided flags tsa (ra,), boxes la/ha (ra, 3);
    columns likewise (rb); occluder boxes olo/ohi (k, 3), planes on (k, 3) / od (k,), the plane
    tolerance pad, and the ids `cand` of those that may block this block. sampled: the leaf
    test is the shaft between the pair's boxes (every point pair), not the centres' segment.
    Returns code (ra * rb,) uint8: 0 facing away (V = 0), 1 visible without a ray, 2 needs
    rays; and the number of shaft tests made.
    """
    ra, rb = ca.shape[0], cb.shape[0]
    code = np.zeros(ra * rb, np.uint8)
    # explicit stack of range pairs; candidate lists live in a pool, LIFO
    pool = np.empty(len(cand) * 130 + 1, np.int64)
    pool[:len(cand)] = cand
    st_a0 = np.empty(256, np.int64)
    st_a1 = np.empty(256, np.int64)
    st_b0 = np.empty(256, np.int64)
    st_b1 = np.empty(256, np.int64)
    st_c0 = np.empty(256, np.int64)
    st_c1 = np.empty(256, np.int64)
    sp = 0
    st_a0[0], st_a1[0], st_b0[0], st_b1[0], st_c0[0], st_c1[0] = 0, ra, 0, rb, 0, len(cand)
    sp = 1
    A = np.empty((2, 3))
    B = np.empty((2, 3))
    tests = 0
    while sp > 0:
        sp -= 1
        a0, a1, b0, b1, c0, c1 = st_a0[sp], st_a1[sp], st_b0[sp], st_b1[sp], st_c0[sp], st_c1[sp]
        top = c1
        # keep the occluders that enter the shaft of this range pair
        _range_box(la, ha, a0, a1, A)
        _range_box(lb, hb, b0, b1, B)
        k = top
        for c in range(c0, c1):
            o = pool[c]
            tests += 1
            if not (_same_side(A, B, on[o], od[o], pad) or _shaft_excludes(A, B, olo[o], ohi[o])):
                pool[k] = o
                k += 1
        n0, n1 = top, k
        npairs = (a1 - a0) * (b1 - b0)
        if n1 == n0 or npairs <= LEAF:
            for a in range(a0, a1):
                for b in range(b0, b1):
                    dx = cb[b, 0] - ca[a, 0]
                    dy = cb[b, 1] - ca[a, 1]
                    dz = cb[b, 2] - ca[a, 2]
                    length = np.sqrt(dx * dx + dy * dy + dz * dz)
                    if not (_faces(na[a], tsa[a], dx, dy, dz, length)
                            and _faces(nb[b], tsb[b], -dx, -dy, -dz, length)):
                        continue
                    hit = False
                    if sampled:
                        _range_box(la, ha, a, a + 1, A)
                        _range_box(lb, hb, b, b + 1, B)
                    for c in range(n0, n1):
                        o = pool[c]
                        if sampled:
                            tests += 1
                            if not (_same_side(A, B, on[o], od[o], pad)
                                    or _shaft_excludes(A, B, olo[o], ohi[o])):
                                hit = True
                                break
                            continue
                        sp_ = (on[o, 0] * ca[a, 0] + on[o, 1] * ca[a, 1] + on[o, 2] * ca[a, 2]) - od[o]
                        sq_ = (on[o, 0] * cb[b, 0] + on[o, 1] * cb[b, 1] + on[o, 2] * cb[b, 2]) - od[o]
                        if (sp_ > pad and sq_ > pad) or (sp_ < -pad and sq_ < -pad):
                            continue  # both ends on one side of the occluder's plane
                        if _seg_box(ca[a, 0], ca[a, 1], ca[a, 2], cb[b, 0], cb[b, 1], cb[b, 2],
                                    olo[o], ohi[o]):
                            hit = True
                            break
                    code[a * rb + b] = 2 if hit else 1
            continue
        # split the longer range in two and push both halves with the filtered list
        if a1 - a0 >= b1 - b0:
            m = (a0 + a1) // 2
            halves = ((a0, m, b0, b1), (m, a1, b0, b1))
        else:
            m = (b0 + b1) // 2
            halves = ((a0, a1, b0, m), (a0, a1, m, b1))
        for h in halves:
            st_a0[sp], st_a1[sp], st_b0[sp], st_b1[sp] = h
            st_c0[sp], st_c1[sp] = n0, n1
            sp += 1
    return code, tests


@numba.njit(cache=True)
def block_candidates(A, B, olo, ohi, on, od, pad, skip_a, skip_b):
    """Occluders (ids) that may cut a segment between boxes A and B: their plane separates the
    boxes and their box enters the shaft. The block's own two elements never can."""
    out = np.empty(olo.shape[0], np.int64)
    k = 0
    for o in range(olo.shape[0]):
        if o == skip_a or o == skip_b:
            continue
        if not (_same_side(A, B, on[o], od[o], pad) or _shaft_excludes(A, B, olo[o], ohi[o])):
            out[k] = o
            k += 1
    return out[:k]


@numba.njit(cache=True)
def small_tile_pairs(tiles, offsets, center, normal, two_sided, base):
    """Facing pairs of many small tiles at once (no shaft search: for a handful of pairs a ray is
    cheaper than looking for occluders among all elements). Returns ia, ib (sub-elements) and the
    bit index of each pair in the task's buffer (tiles' byte starts relative to `base`)."""
    total = 0
    for t in range(tiles.shape[0]):
        total += (tiles[t, 3] - tiles[t, 2]) * tiles[t, 4]
    ia = np.empty(total, np.int64)
    ib = np.empty(total, np.int64)
    bit = np.empty(total, np.int64)
    k = 0
    for t in range(tiles.shape[0]):
        i, j, r0, r1, nj = tiles[t, 0], tiles[t, 1], tiles[t, 2], tiles[t, 3], tiles[t, 4]
        first = (tiles[t, 5] - base) * 8
        for r in range(r1 - r0):
            a = offsets[i] + r0 + r
            for c in range(nj):
                b = offsets[j] + c
                dx = center[b, 0] - center[a, 0]
                dy = center[b, 1] - center[a, 1]
                dz = center[b, 2] - center[a, 2]
                length = np.sqrt(dx * dx + dy * dy + dz * dz)
                if _faces(normal[a], two_sided[a], dx, dy, dz, length) and \
                        _faces(normal[b], two_sided[b], -dx, -dy, -dz, length):
                    ia[k] = a
                    ib[k] = b
                    bit[k] = first + r * nj + c
                    k += 1
    return ia[:k], ib[:k], bit[:k]


@numba.njit(cache=True)
def set_bits(buf, bits):
    """Set bit positions `bits` in the uint8 buffer (little-endian within bytes)."""
    for k in range(bits.shape[0]):
        buf[bits[k] >> 3] |= np.uint8(1 << (bits[k] & 7))


# ----------------------------------------------------------------------------- inputs

class VisInputs:
    """Read-only arrays every visibility task needs; scattered to the workers once.

    center, normal (m, 3) float64; two_sided (m,) bool; lo, hi (m, 3) float64 sub-element boxes;
    offsets (n + 1,) int64; elo, ehi (n, 3) padded boxes of the originals (the occluders);
    verts (n, 4, 3), nverts (n,) for the Embree scene; key: the Embree cache key; sampling
    (kernels.Sampling or None): the sample points (m, S, 3) and weights of a sampled kernel.
    """

    def __init__(self, part, elements, key: str, occlusion: bool = True, sampling=None):
        from .kernels import NXM, MC, sample_points

        self.center = part.center
        self.normal = part.normal
        self.two_sided = elements.two_sided[part.orig]
        self.orig = part.orig
        v = np.where(part.nverts[:, None, None] == 3, part.verts[:, [0, 1, 2, 2]], part.verts)
        self.lo = v.min(axis=1)
        self.hi = v.max(axis=1)
        self.offsets = part.offsets
        ev = elements.verts
        lo, hi = ev.min(axis=1), ev.max(axis=1)
        pad = BOX_PAD * float(np.linalg.norm(ev.reshape(-1, 3).max(0) - ev.reshape(-1, 3).min(0)))
        self.elo = lo - pad
        self.ehi = hi + pad
        self.enormal = elements.normal
        self.eoffset = np.einsum("ic,ic->i", elements.normal, elements.center)
        # non-planar input was split, so every element is planar to rounding: the plane test
        # tolerance is the same pad, plus the element's own (tiny) deviation from its plane
        dev = np.abs(np.einsum("ic,ikc->ik", elements.normal, ev) - self.eoffset[:, None]).max(1)
        self.pad = pad
        self.eoffset_pad = dev
        self.verts = elements.verts
        self.nverts = elements.nverts
        self.key = key
        self.occlusion = occlusion
        self.sampling = sampling
        self.kid = 0 if sampling is None else (NXM if sampling.kind == "nxm" else MC)
        self.pts, self.w = sample_points(part.verts, part.nverts, sampling)
        self.pts_flat = self.pts.reshape(-1, 3)
        self.pts_orig = np.repeat(part.orig, self.pts.shape[1])


def tile_bits(inp: VisInputs, caster, i: int, j: int, r0: int, r1: int):
    """The bits of rows r0:r1 of block (i, j): (r1 - r0) * nJ bool, row-major, and counters.

    Without occlusion (planner.py: nothing can block), facing pairs are visible: no shafts, no rays."""
    a0, b0, b1 = inp.offsets[i] + r0, inp.offsets[j], inp.offsets[j + 1]
    a1 = inp.offsets[i] + r1
    A = np.empty((2, 3))
    B = np.empty((2, 3))
    A[0], A[1] = inp.lo[a0:a1].min(0), inp.hi[a0:a1].max(0)
    B[0], B[1] = inp.lo[b0:b1].min(0), inp.hi[b0:b1].max(0)
    pad = inp.pad + float(inp.eoffset_pad.max(initial=0.0))
    if inp.occlusion:
        cand = block_candidates(A, B, inp.elo, inp.ehi, inp.enormal, inp.eoffset, pad, i, j)
    else:
        cand = np.zeros(0, np.int64)
    code, tests = classify(inp.center[a0:a1], inp.normal[a0:a1], inp.two_sided[a0:a1],
                           inp.lo[a0:a1], inp.hi[a0:a1], inp.center[b0:b1], inp.normal[b0:b1],
                           inp.two_sided[b0:b1], inp.lo[b0:b1], inp.hi[b0:b1], inp.elo, inp.ehi,
                           inp.enormal, inp.eoffset, pad, cand, inp.sampling is not None)
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
    from .kernels import sample_rays

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

    Returns dict: crc (crc32 of the unpadded bytes), counts (len(COUNTERS),), partial (crc32
    and length of the partial pairs), worker, start, stop.
    """
    from .rays import caster_for
    from .store import write_bits, write_partial

    t0 = time.time()
    caster = caster_for(inp.key, inp.verts, inp.nverts)
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
           "start": t0, "stop": time.time(), "pid": os.getpid()}
    if inp.sampling is not None:
        part = tuple(np.concatenate(x) for x in zip(*partials)) if partials else _NO_PARTIAL
        out["partial"] = write_partial(store_path, task, *part)
    return out


# ----------------------------------------------------------------------------- the master

def _plan_for(part, elements, unit: str | None):
    from .plan import choose_unit, facing_blocks, make_plan

    unit = choose_unit(config.get("visibility.task-unit", unit), len(elements),
                       int(config.get("visibility.stripe-threshold")))
    facing = facing_blocks(elements.verts, elements.nverts, elements.normal, elements.center,
                           elements.two_sided)
    return make_plan(part.offsets, facing, unit, int(config.get("visibility.max-task-bits")),
                     min_task_bits=int(config.get("visibility.min-task-bits")))


def compute_visibility(run_dir: str, client, unit: str | None = None, resume: bool = False,
                       progress: bool = True, on_done=None, occlusion: bool = True,
                       kernel: str | None = None) -> dict:
    """The dynamic master (seed §4.3): a bounded window of tasks in flight per worker thread,
    the next task submitted as each one completes, most expensive first; failed tasks are
    resubmitted; every finished task is recorded with its checksum, so `resume` recomputes only
    what is missing or corrupted. `on_done(n_finished)` is called after each task (for tests).
    occlusion=False (planner.py: nothing can block) makes the bits orientation alone.
    kernel: the form-factor kernel the matrix is for (default radiosity.solve.kernel): the
    sampled ones (nxm, mc) cast one ray per sample pair (kernels.sampling_of).
    """
    from dask.base import tokenize
    from distributed import as_completed
    from tqdm.auto import tqdm

    from .errors import RadiosityError
    from .kernels import sampling_of
    from .store import RunStore, VisibilityStore, update_report

    sampling = sampling_of(config.get("solve.kernel", kernel))

    t_start = time.perf_counter()
    rs = RunStore(run_dir, "r+")
    part = rs.load_partition()
    el = rs.load_elements()
    plan = _plan_for(part, el, unit)
    token = tokenize(plan.tiles, plan.tasks, plan.chunk, part.center, part.normal, el.verts,
                     config.get("rays.epsilon"), occlusion,
                     None if sampling is None else sampling.to_dict())
    vs = VisibilityStore(rs)
    done = {}
    corrupted = 0
    if resume and vs.token() == token:
        done = vs.finished(token)
        good = {}
        for task, entry in done.items():
            if vs.verify(plan, task, entry):
                good[task] = entry
            else:
                corrupted += 1
        done = good
        if corrupted:
            vs.rewrite_manifest(token, done)  # corrupted entries are never trusted again
    else:
        rs.drop_after("raster")
        vs.create(plan, token, {"rays_epsilon": config.get("rays.epsilon"),
                                "sampling": None if sampling is None else sampling.to_dict()})
    order = [t for t in plan.cost_order().tolist() if t not in done]
    key = tokenize(el.verts, el.nverts)
    inp = VisInputs(part, el, key, occlusion, sampling)
    threads = sum(client.nthreads().values()) or 1
    window = max(1, int(config.get("visibility.window-per-worker")) * threads)
    retries = int(config.get("visibility.retries"))
    counts = np.zeros(len(COUNTERS), np.int64)
    for e in done.values():
        counts += np.asarray(e["counts"], np.int64)
    busy: dict = {}
    attempts = {}
    computed = 0
    t_loop = time.perf_counter()
    from .monitor import Monitor

    mon = Monitor(client)
    mon.stage("visibility", run_dir)
    mon.visibility(plan, done, len(el), force=True)
    if order:
        [inp_f] = client.scatter([inp], broadcast=True, hash=False)
        pending = iter(order)
        ac = as_completed()
        futs = {}

        def submit(task: int):
            a = attempts.get(task, 0)
            t = plan.tasks[task]
            tiles = plan.tiles[t[FIRST]:t[END]]
            f = client.submit(task_visibility, inp_f, tiles, rs.path, int(t[TSTART]), int(t[TBYTES]),
                              task, key=f"visibility-{token[:12]}-{task}-{a}", retries=0)
            futs[f.key] = task
            ac.add(f)

        for task in pending:
            submit(task)
            if len(futs) >= window:
                break
        bar = tqdm(total=len(plan.tasks), initial=len(done), desc="visibility", unit="task",
                   disable=not progress, leave=False)
        for fut in ac:
            task = futs.pop(fut.key)
            try:
                res = fut.result()
            except Exception as e:  # worker died, or the task failed: resubmit
                attempts[task] = attempts.get(task, 0) + 1
                if attempts[task] > retries:
                    bar.close()
                    raise RadiosityError(f"visibility task {task} failed {attempts[task]} times: {e!r}; "
                                         f"the finished tasks are kept: rerun with --resume") from None
                submit(task)
                continue
            finally:
                fut.release()
            vs.record(task, res)
            done[task] = res
            computed += 1
            counts += res["counts"]
            busy[res["pid"]] = busy.get(res["pid"], 0.0) + (res["stop"] - res["start"])
            bar.update()
            mon.visibility(plan, done, len(el))
            if on_done is not None:
                on_done(computed)
            nxt = next(pending, None)
            if nxt is not None:
                submit(nxt)
        bar.close()
    mon.visibility(plan, done, len(el), force=True)
    wall = time.perf_counter() - t_loop
    c = dict(zip(COUNTERS, counts.tolist()))
    m = len(part)
    naive = m * (m - 1)  # ordered pairs a brute force would trace
    nworkers = len(client.scheduler_info()["workers"]) or 1
    figures = {
        "task_unit": plan.unit, "tasks": int(len(plan.tasks)), "tasks_computed": computed,
        "tasks_reused": int(len(plan.tasks) - computed), "tasks_corrupted_recomputed": corrupted,
        "tiles": int(len(plan.tiles)), "chunk_bytes": plan.chunk, "store_bytes": plan.total,
        "sub_elements": m, "blocks_culled": int(len(plan.culled)),
        "pairs_total": m * (m - 1) // 2, **c,
        "pairs_culled_by_orientation": m * (m - 1) // 2 - c["pairs_facing"],
        "rays_fraction_of_pairs": c["rays"] / max(1, m * (m - 1) // 2),
        "naive_ordered_rays": naive,
        "time_s": round(time.perf_counter() - t_start, 4), "time_tasks_s": round(wall, 4),
        "busy_s_per_worker": {str(k): round(v, 4) for k, v in busy.items()},
        "idle_fraction": (1.0 - sum(busy.values()) / (nworkers * wall)) if wall > 0 and busy else None,
        "workers": nworkers, "occlusion": occlusion,
        "sampling": None if sampling is None else sampling.describe(),
        "rays_per_pair": 1 if sampling is None else sampling.rays_per_pair,
    }
    from .pipeline import peak_rss_mb
    figures["peak_rss_mb"] = peak_rss_mb(client)
    update_report(run_dir, "visibility", figures)
    return figures


# ----------------------------------------------------------------------------- readers

def iter_tiles(rs, verify: bool = True):
    """Yield (I, J, r0, r1, bits (r1 - r0, nJ) bool) for every stored tile, task by task.

    Each task's bytes are checked against the manifest's crc32: a missing or corrupted task
    raises StoreError (never used silently).
    """
    from .errors import StoreError
    from .store import VisibilityStore

    vs = VisibilityStore(rs)
    token, plan, done = vs.require()
    for task in range(len(plan.tasks)):
        entry = done.get(task)
        if entry is None:
            raise StoreError(f"visibility task {task} of {rs.run_dir} is missing: "
                             f"run radiosity visibility {rs.run_dir} --resume")
        data = vs.read_task(plan, task, entry["nbytes"])
        if verify and zlib.crc32(data.tobytes()) != entry["crc"]:
            raise StoreError(f"visibility task {task} of {rs.run_dir} is corrupted (checksum): "
                             f"run radiosity visibility {rs.run_dir} --resume to recompute it")
        t = plan.tasks[task]
        for tile in plan.tiles[t[FIRST]:t[END]]:
            off = int(tile[START] - t[TSTART])
            n = int((tile[R1] - tile[R0]) * tile[NCOLS])
            bits = np.unpackbits(data[off:off + int(tile[NBYTES])], count=n, bitorder="little")
            yield int(tile[I]), int(tile[J]), int(tile[R0]), int(tile[R1]), \
                bits.reshape(int(tile[R1] - tile[R0]), int(tile[NCOLS])).astype(bool)


def dense_visibility(rs) -> np.ndarray:
    """The whole matrix as (m, m) bool, for small scenes and tests only."""
    part = rs.load_partition()
    off = part.offsets
    m = len(part)
    V = np.zeros((m, m), bool)
    for i, j, r0, r1, bits in iter_tiles(rs):
        V[off[i] + r0:off[i] + r1, off[j]:off[j + 1]] = bits
    return V | V.T
