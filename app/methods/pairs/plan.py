"""The pairs method's visibility task plan: pure integer arithmetic on numpy, no Dask. Blocks
(I, J), I < J, of sub-elements of two originals, cut into tiles of rows and tasks of tiles.

Bit order: a tile's bits are packed row-major (bit k is pair (r0 + k // nJ, k % nJ) of the
block), little-endian within each byte (bit k is `(byte[k >> 3] >> (k & 7)) & 1`), from a byte
boundary; every task starts on a chunk boundary. Details: docs/src/design/methods-pairs-plan.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radiosity.scene.originals import TOL

# tile columns
I, J, R0, R1, NCOLS, START, NBYTES = range(7)
# task columns
FIRST, END, TSTART, TBYTES = range(4)


@dataclass(frozen=True)
class VisibilityPlan:
    """tiles : (t, 7) int64 [I, J, r0, r1, ncols, byte start, nbytes], in task order (columns
        named by the module constants I, J, R0, R1, NCOLS, START, NBYTES, which the numba pass
        loops index directly)
    tasks : (k, 4) int64 [first tile, end tile, byte start, padded nbytes] (FIRST, END, TSTART,
        TBYTES)
    culled : (0, 2) int64, kept for the store's layout: the block pairs skipped whole are no
        longer listed (there can be n^2 of them), only counted in `blocks_culled`
    chunk : bytes per Zarr chunk; total : bytes of the array; unit : 'block' or 'stripe'
    blocks_culled : block pairs I < J skipped whole (they cannot face each other)
    """

    tiles: np.ndarray
    tasks: np.ndarray
    culled: np.ndarray
    chunk: int
    total: int
    unit: str
    blocks_culled: int = 0

    def __len__(self) -> int:
        return len(self.tasks)

    def tiles_of(self, task: int) -> np.ndarray:
        """The tiles of one task, (t_k, 7) int64 (a view)."""
        t = self.tasks[task]
        return self.tiles[t[FIRST]:t[END]]

    def tile_bits(self) -> np.ndarray:
        """Pairs (bits) in each tile, (t,) int64."""
        return (self.tiles[:, R1] - self.tiles[:, R0]) * self.tiles[:, NCOLS]

    def task_of_tile(self) -> np.ndarray:
        """The task each tile belongs to, (t,) int64."""
        return np.repeat(np.arange(len(self.tasks)), self.tasks[:, END] - self.tasks[:, FIRST])

    def task_bits(self) -> np.ndarray:
        """Estimated cost of each task: the number of pairs (bits) it holds, (k,) int64."""
        c = np.concatenate([[0], np.cumsum(self.tile_bits())])
        return c[self.tasks[:, END]] - c[self.tasks[:, FIRST]]

    def tile_of_pairs(self, offsets: np.ndarray, a: np.ndarray, b: np.ndarray):
        """Where the bits of pairs (a, b) of sub-elements lie (any order).

        offsets (n + 1,) sub-element offsets of the originals. Returns found (k,) bool (False
        for pairs of one original or of a block culled whole: their bit is 0), and for the
        found pairs the tile (k_f,) and the bit index within the tile (k_f,), both int64."""
        orig = np.searchsorted(offsets, np.concatenate([a, b]), side="right") - 1
        oa, ob = orig[:len(a)], orig[len(a):]
        lo = np.where(oa < ob, a, b)
        hi = np.where(oa < ob, b, a)
        I_, J_ = np.minimum(oa, ob), np.maximum(oa, ob)
        r = lo - offsets[I_]
        tiles = self.tiles
        n = len(offsets)
        stride = int(offsets[-1]) + 1
        tkey = (tiles[:, I] * n + tiles[:, J]) * stride + tiles[:, R0]
        order = np.argsort(tkey, kind="stable")
        pos = np.searchsorted(tkey[order], (I_ * n + J_) * stride + r, side="right") - 1
        t = order[np.maximum(pos, 0)] if len(order) else np.zeros(len(a), np.int64)
        if len(order) == 0:
            return np.zeros(len(a), bool), t[:0], t[:0]
        found = ((I_ != J_) & (tiles[t, I] == I_) & (tiles[t, J] == J_) & (tiles[t, R0] <= r)
                 & (r < tiles[t, R1]))
        t, r, hi, J_ = t[found], r[found], hi[found], J_[found]
        bit = (r - tiles[t, R0]) * tiles[t, NCOLS] + (hi - offsets[J_])
        return found, t, bit

    def cost_order(self) -> np.ndarray:
        """Task ids, most expensive first (long tasks start early); ties by id (deterministic)."""
        return np.lexsort((np.arange(len(self.tasks)), -self.task_bits()))


def facing_blocks(verts: np.ndarray, nverts: np.ndarray, normal: np.ndarray, center: np.ndarray,
                  two_sided: np.ndarray, tol: float | None = None) -> np.ndarray:
    """(n, n) bool: can any point of J lie strictly in front of I (either side if I is two-sided)?
    Distances below tol (originals.TOL) times the scene's diagonal count as 0.

    A block (I, J) needs work only if J is in front of I *and* I is in front of J; otherwise every
    pair in it has cos <= 0 on one side and V = 0 without a ray (SPEC §5).
    """
    # signed distances of every vertex of J to the plane of I: (n_I, n_J, 4)
    d = np.einsum("ic,jkc->ijk", normal, verts) - np.einsum("ic,ic->i", normal, center)[:, None, None]
    scale = np.linalg.norm(verts.reshape(-1, 3).max(0) - verts.reshape(-1, 3).min(0))
    eps = (TOL if tol is None else tol) * scale
    front = (d > eps).any(axis=2)
    back = (d < -eps).any(axis=2)
    return front | (two_sided[:, None] & back)


def make_plan(offsets: np.ndarray, facing, unit: str = "block",
              max_task_bits: int = 1 << 26, chunk: int | None = None,
              min_task_bits: int = 0) -> VisibilityPlan:
    """Tiles and tasks for the blocks I < J that face each other both ways.

    offsets : (n + 1,) sub-element offsets of the originals; facing : the pairs (bi, bj)
    (p,) int64, I < J, sorted by (I, J) (originals.facing_pairs: no n x n array), or for small
    scenes and tests an (n, n) bool facing_blocks matrix. In stripe mode, consecutive stripes
    share a task until it holds `min_task_bits` (many small originals would otherwise cost
    more in scheduling than in work). Memory and time are linear in the tiles.
    """
    if unit not in ("block", "stripe"):
        raise ValueError(f"task unit must be block or stripe, got {unit!r}")
    n = len(offsets) - 1
    size = np.diff(offsets).astype(np.int64)
    if isinstance(facing, tuple):
        bi, bj = (np.asarray(x, np.int64) for x in facing)
    else:
        iu, ju = np.triu_indices(n, 1)
        both = facing[iu, ju] & facing[ju, iu]
        bi, bj = iu[both].astype(np.int64), ju[both].astype(np.int64)
    culled = n * (n - 1) // 2 - len(bi)
    # never fewer than ~64 tasks because of the merging: the master needs work to balance
    min_task_bits = min(min_task_bits, int((size[bi] * size[bj]).sum()) // 64)
    # the row bands of every block: `rows` rows each, so that none holds more than max_task_bits
    ni, nj = size[bi], size[bj]
    rows = np.maximum(1, max_task_bits // np.maximum(nj, 1))
    nband = -(-ni // rows)
    tb = np.repeat(np.arange(len(bi)), nband)                  # block of each tile
    first = np.concatenate([[0], np.cumsum(nband)[:-1]]) if len(bi) else np.zeros(0, np.int64)
    r0 = (np.arange(len(tb)) - first[tb]) * rows[tb]
    r1 = np.minimum(ni[tb], r0 + rows[tb])
    t = np.column_stack([bi[tb], bj[tb], r0, r1]).astype(np.int64).reshape(-1, 4)
    bits = (r1 - r0) * nj[tb]
    if unit == "block":  # one task per tile
        task_of = np.arange(len(t), dtype=np.int64)
    else:  # stripes, merged greedily up to min_task_bits, cut at max_task_bits
        task_of = _stripe_tasks(bi[tb].tolist(), bits.tolist(), int(min_task_bits),
                                int(max_task_bits))
    nbytes = ((t[:, 3] - t[:, 2]) * size[t[:, 1]] + 7) // 8
    ntasks = int(task_of[-1]) + 1 if len(task_of) else 0
    # task boundaries and sizes
    first = np.searchsorted(task_of, np.arange(ntasks), side="left")
    end = np.searchsorted(task_of, np.arange(ntasks), side="right")
    tbytes = np.add.reduceat(nbytes, first) if ntasks else np.zeros(0, np.int64)
    if chunk is None:
        chunk = choose_chunk(tbytes)
    padded = -(-tbytes // chunk) * chunk
    tstart = np.concatenate([[0], np.cumsum(padded)[:-1]]) if ntasks else np.zeros(0, np.int64)
    # tile byte starts: consecutive within their task
    within = np.concatenate([[0], np.cumsum(nbytes)[:-1]]) if len(nbytes) else np.zeros(0, np.int64)
    within = within - within[first][task_of] if len(nbytes) else within
    start = tstart[task_of] + within if len(nbytes) else within
    ncols = size[t[:, 1]] if len(t) else np.zeros(0, np.int64)
    tiles7 = np.column_stack([t, ncols, start, nbytes]).astype(np.int64).reshape(-1, 7)
    tasks = np.column_stack([first, end, tstart, padded]).astype(np.int64).reshape(-1, 4)
    return VisibilityPlan(tiles=tiles7, tasks=tasks, culled=np.zeros((0, 2), np.int64),
                          chunk=int(chunk), total=int(padded.sum()), unit=unit,
                          blocks_culled=int(culled))


def _stripe_tasks(keys: list, bits: list, min_task_bits: int, max_task_bits: int) -> np.ndarray:
    """Task of each tile in stripe mode: a new task when the stripe (row element) changes and
    the current task holds min_task_bits, or when the tile would take it past max_task_bits."""
    out = np.empty(len(keys), np.int64)
    task, cur, key0 = -1, 0, None
    for k, (key, b) in enumerate(zip(keys, bits)):
        if task < 0 or (key != key0 and cur >= min_task_bits) or cur + b > max_task_bits:
            task += 1
            cur = 0
        out[k] = task
        key0 = key
        cur += b
    return out


def choose_chunk(task_bytes: np.ndarray) -> int:
    """A power of two between 4 KiB and 4 MiB, near the median task size (few, not huge, chunks)."""
    if len(task_bytes) == 0:
        return 4096
    med = float(np.median(task_bytes))
    c = 1 << int(np.clip(np.ceil(np.log2(max(med, 1.0))), 12, 22))
    return int(c)

