"""The image itself: the radiance each fine pixel sees and its reconstruction to the camera's
grid (box or Gaussian); the tone mapping is core.colour's, the EXR and PNG files formats.images'.

What a fine pixel sees (render.sampling): `area` (the default) averages k x k rays spread over
the pixel's area, each looking up the solved radiance of the sub-element where it lands (the
seed's two-level lookup, seed §3.2), as a camera and a path tracer's box filter do; `point` takes
the sub-element of the ray through the pixel's centre, the preprocessing's ID raster (seed §3),
as the seed does. They differ only where a pixel straddles an edge; measured in
docs/src/how-to/checks-and-images.md.
"""

from __future__ import annotations

import math

import numpy as np

from radiosity.errors import RenderError, StoreError
from radiosity.core.bundles import Camera, Elements, Partition
from radiosity.core.tolerances import TOL

#: What a fine pixel shows (render.sampling): the mean over its area, or its centre's element.
SAMPLINGS = ("area", "point")
#: Sample rays per Embree batch of the pixel-area image (about 60 bytes a ray in flight).
AREA_BATCH = 1 << 20
#: Adaptive sampling (refine): a pixel is cast again with twice the rays a side while its
#: estimated error is above this share of its value. MEASURED (benchmarks/bench_pixels.py
#: --sampling-of RUN, a smooth terrain of 5e4 triangles at 64^2, about 29 triangles a pixel,
#: against 64 x 64 rays a pixel): 0.51 % a pixel before, 0.18 % with refine, 171 rays a pixel
#: (docs/src/how-to/checks-and-images.md).
REFINE_TOLERANCE = 0.01
#: Doublings of the rays a side past render.edge-samples (12 -> 24 -> 48 rays a side).
REFINE_DOUBLINGS = 2
#: The refinement's rays after the first level, at most this many times the image's first
#: rays (area-samples^2 a pixel): the pixels with the largest estimates first. MEASURED (as
#: above, budgets 2, 4, 8, 16): a rough terrain (noise 1.5 grid spacings) 1.7, 1.6, 1.3,
#: 0.89 % at 122, 154, 218, 346 rays a pixel; the smooth one 0.21, 0.18, 0.18, 0.18 %; the
#: Cornell box at 128^2 90, 123, 150, 150 rays a pixel.
REFINE_BUDGET = 8.0
#: A pixel darker than this share of the image's mean is refined as if it were that bright:
#: its error is one nobody sees (the same floor as benchmarks/bench_real.py's metric).
REFINE_FLOOR = 0.05


# ----------------------------------------------------------------------------- the fine image

def facing_side(part: Partition, camera: Camera) -> np.ndarray:
    """Side of each sub-element that faces the camera centre: (m,) intp, 0 front, 1 back.

    Front iff dot(normal, camera.center - center) > 0. Every point of a planar element gives
    the same sign, so the sub-element's centre decides for all its pixels.
    """
    d = np.asarray(camera.center, np.float64)[None, :] - part.center
    return (np.einsum("ij,ij->i", part.normal, d) <= 0.0).astype(np.intp)


def seen_radiance(part: Partition, elements: Elements, camera: Camera,
                  radiance: np.ndarray) -> np.ndarray:
    """The radiance the camera sees on each sub-element: (m, 3) float64, linear RGB.

    radiance (m, 2, 3): [front, back] RGB per sub-element. The side that faces the camera (see
    `facing_side`); the back of a one-sided element is 0 (black) whatever `radiance` holds there.
    """
    radiance = np.asarray(radiance, np.float64)
    m = len(part)
    if radiance.shape != (m, 2, 3):
        raise StoreError(f"the solution has radiance of shape {radiance.shape}, the partition "
                         f"has {m} sub-elements (expected ({m}, 2, 3)): run solve again")
    side = facing_side(part, camera)
    lum = radiance[np.arange(m), side]  # (m, 3)
    lum[(side == 1) & ~np.asarray(elements.two_sided, bool)[part.orig]] = 0.0
    return lum


def pixel_radiance(part: Partition, elements: Elements, camera: Camera, raster_sub: np.ndarray,
                   radiance: np.ndarray) -> np.ndarray:
    """Linear radiance seen through each fine pixel: (H*K, W*K, 3) float64.

    part, elements, camera: from the run store. raster_sub (H*K, W*K) int32: sub-element hit
    by each fine pixel's ray, -1 for none; or (H*K, W*K, S) int32: the sub-elements of S sample
    rays per fine pixel (`sample_raster`), averaged. radiance (m, 2, 3): [front, back] RGB per
    sub-element, shown as `seen_radiance` says; rays that hit nothing are 0 (black, no
    background colour).
    """
    return samples_radiance(seen_radiance(part, elements, camera, radiance), raster_sub)


def samples_radiance(lum: np.ndarray, raster_sub: np.ndarray) -> np.ndarray:
    """pixel_radiance from the seen radiance lum (m, 3) (seen_radiance): raster_sub (..., ) or
    (..., S) sub-elements, -1 for none -> (..., 3), the mean over the S samples."""
    sub = np.asarray(raster_sub)
    if sub.ndim == 3:
        out = np.zeros(sub.shape[:2] + (3,), np.float64)
        for s in range(sub.shape[2]):  # one sample plane at a time: memory as the image's
            out += _gather(lum, sub[:, :, s])
        return out / sub.shape[2]
    return _gather(lum, sub)


def _gather(lum: np.ndarray, sub: np.ndarray) -> np.ndarray:
    """lum (m, 3) at the sub-elements `sub` (any shape, -1: black) -> sub.shape + (3,)."""
    out = np.zeros(sub.shape + (3,), np.float64)
    hit = sub >= 0
    out[hit] = lum[sub[hit]]
    return out


# ----------------------------------------------------------------------------- pixel areas

def area_offsets(k: int) -> np.ndarray:
    """Where the k x k rays of the pixel-area image cross a pixel: (k*k, 2) float64 offsets
    (x to the right, y down) in (0, 1), the pixel's top-left corner at (0, 0).

    A sheared lattice: sample (i, j) at ((i + (j + 1/2) / k) / k, (j + (i + 1/2) / k) / k). It is
    stratified (one sample in each of the k x k cells) and n-rooks (one in each of the pixel's
    k^2 columns and k^2 rows), so the covered fraction of a pixel cut by a vertical or horizontal
    edge is exact to 1 / (2 k^2), where a k x k grid of cell centres is only exact to 1 / (2 k);
    and it is deterministic (the same image on every run, no noise). k = 1: the pixel's centre.
    """
    k = int(k)
    if k < 1:
        raise RenderError(f"render.area-samples must be a positive integer, got {k}")
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    x = (i + (j + 0.5) / k) / k
    y = (j + (i + 0.5) / k) / k
    return np.stack([x.ravel(), y.ravel()], 1)


def sample_directions(camera: Camera, subpixel: int, offsets: np.ndarray, r0: int,
                      r1: int) -> np.ndarray:
    """Unit directions (r1 - r0, W*K, S, 3) float64 of the rays through fine pixels' rows r0:r1
    of the K-times finer raster (K = subpixel), S rays each at `offsets` (S, 2) (x right, y down,
    in pixels from the fine pixel's top-left corner; (0.5, 0.5) is the centre, as
    camera.pixel_directions)."""
    w = camera.width * subpixel
    ox, oy = offsets[:, 0], offsets[:, 1]
    return _through(camera, subpixel, np.arange(w)[None, :, None] + ox[None, None, :],
                    np.arange(r0, r1)[:, None, None] + oy[None, None, :])


def _through(camera: Camera, subpixel: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Unit directions (..., 3) float64 of the rays through the points (x right, y down, in
    fine pixels from the K-times finer raster's top-left corner; x and y broadcast)."""
    w, h = camera.width * subpixel, camera.height * subpixel
    u, v = np.broadcast_arrays(camera.half_w * (2.0 * x / w - 1.0),
                               camera.half_h * (1.0 - 2.0 * y / h))
    d = camera.focal * camera.z + u[..., None] * camera.x + v[..., None] * camera.y
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def sample_raster(part: Partition, elements: Elements, camera: Camera, subpixel: int, k: int,
                  ray_offset: float, caster=None) -> np.ndarray:
    """Sub-element seen by each of the k x k `area_offsets` rays of every fine pixel:
    (H*K, W*K, k*k) int32 (K = subpixel), -1 where a ray hits nothing.

    Embree finds the original element each ray hits (tracing.rays, against the original
    elements: subdividing never changes the geometry), the hit point is recomputed in float64
    on that element's plane, and the split tree gives the sub-element under it (seed §3.2, the
    two-level lookup): any sub-element, also one that no pixel centre hits. caster: a
    RayCaster of the original elements (None: built here with `ray_offset`).
    """
    from radiosity.tracing.rays import RayCaster

    rc = caster if caster is not None else RayCaster(elements.verts, elements.nverts, ray_offset)
    offsets = area_offsets(k)
    s = len(offsets)
    w, h = camera.width * subpixel, camera.height * subpixel
    out = np.full((h, w, s), -1, np.int32)
    band = max(1, AREA_BATCH // (w * s))
    for r0 in range(0, h, band):
        r1 = min(h, r0 + band)
        d = sample_directions(camera, subpixel, offsets, r0, r1).reshape(-1, 3)
        out[r0:r1] = _seen(part, elements, camera, rc, d).reshape(r1 - r0, w, s)
    return out


def _seen(part: Partition, elements: Elements, camera: Camera, rc, d: np.ndarray) -> np.ndarray:
    """The sub-element seen along each unit direction d (r, 3) from the camera, (r,) int32, -1
    where nothing is hit: Embree's original, the hit point on its plane in float64, the split
    tree's sub-element there."""
    from radiosity.scene.subdivide import lookup

    origin = np.asarray(camera.center, np.float64)
    orig = rc.first_hit(origin, d.astype(np.float32), unit=True)
    hit = orig >= 0
    e = orig[hit]
    dh = d[hit]
    normal = np.asarray(elements.normal, np.float64)
    center = np.asarray(elements.center, np.float64)
    # the exact hit point on the element's plane (float64), as camera.hit_points does (a ray
    # Embree says hits a plane it runs along lands anywhere: the lookup stays in bounds)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", normal[e], center[e] - origin) / \
            np.einsum("ij,ij->i", normal[e], dh)
    sub = np.full(len(orig), -1, np.int32)
    sub[hit] = lookup(part, origin + t[:, None] * dh, e)
    return sub


def plane_ids(elements: Elements) -> np.ndarray:
    """(n,) int64: one id per plane and material of the original elements (normal and offset
    rounded to TOL.plane_digits decimals, the offset relative to the scene's size): a surface
    cut into many elements is one, so edge pixels do not depend on how it was cut; a lamp in
    its ceiling's plane is another."""
    from radiosity.scene.contact import scene_scale

    n = np.asarray(elements.normal, np.float64)
    off = np.einsum("ij,ij->i", n, np.asarray(elements.center, np.float64)) / \
        (scene_scale(elements) or 1.0)
    scale = 10.0 ** TOL.plane_digits
    key = np.column_stack([np.round(np.column_stack([n, off]) * scale).astype(np.int64),
                           np.asarray(elements.material, np.int64)])
    return np.unique(key, axis=0, return_inverse=True)[1].ravel().astype(np.int64)


def edge_pixels(samples: np.ndarray, part: Partition, plane: np.ndarray) -> np.ndarray:
    """(H, W) bool: the fine pixels whose sample rays (samples (H, W, S) sub-elements, -1 for
    none) see more than one plane or material (plane_ids), or some and nothing: a silhouette,
    a corner, a lamp's border; and their eight neighbours, where an edge that cuts off a sliver
    may have passed between all of a pixel's rays."""
    from scipy.ndimage import binary_dilation

    orig = np.asarray(part.orig)
    pl = np.where(samples >= 0, plane[orig[np.maximum(samples, 0)]], -1)
    return binary_dilation((pl != pl[:, :, :1]).any(axis=2), np.ones((3, 3), bool))


def busy_pixels(samples: np.ndarray, part: Partition, plane: np.ndarray, y: np.ndarray,
                tol: float = REFINE_TOLERANCE, floor: float = REFINE_FLOOR) -> np.ndarray:
    """(H, W) bool: the fine pixels to sample again, from their k x k rays (samples (H, W, k*k)
    sub-elements, -1 for none): the edges of `edge_pixels` (two planes or materials, or some
    and nothing), and the pixels whose rays see values y (m,) (the seen radiance's RGB sum)
    that differ by more than 2 k^2 tol of max(their mean, floor * the image's mean): a shadow's
    border on one plane, many small triangles of different brightness. (The n-rooks lattice
    puts an edge's covered fraction within 1 / (2 k^2) of the pixel, so a pixel of two values
    a contrast d apart is within d / (2 k^2) already.) With their eight neighbours, where the
    rays may have passed between the pieces."""
    from scipy.ndimage import binary_dilation

    k2 = samples.shape[2]
    ys = np.where(samples >= 0, np.asarray(y, np.float64)[np.maximum(samples, 0)], 0.0)
    mean = ys.mean(axis=2)
    ref = np.maximum(mean, floor * _seen_mean(mean))
    busy = ys.max(axis=2) - ys.min(axis=2) > 2.0 * k2 * tol * ref
    return edge_pixels(samples, part, plane) | binary_dilation(busy, np.ones((3, 3), bool))


def _seen_mean(y: np.ndarray) -> float:
    """The mean of y over its positive entries (the pixels that see something lit), 0 if none."""
    pos = y[y > 0]
    return float(pos.mean()) if len(pos) else 0.0


def refine(part: Partition, elements: Elements, camera: Camera, subpixel: int, lum: np.ndarray,
           fine: np.ndarray, samples: np.ndarray, edge_side: int, rc,
           doublings: int = REFINE_DOUBLINGS, tol: float = REFINE_TOLERANCE,
           floor: float = REFINE_FLOOR, budget: float = REFINE_BUDGET) -> list:
    """Adaptive sampling of the pixel-area image: `fine` (H, W, 3), the mean of the k x k rays
    `samples` (H, W, k*k) of each fine pixel (lum (m, 3): seen_radiance), is updated in place.

    The busy_pixels are cast again with edge_side x edge_side rays; then, for up to `doublings`
    rounds, those whose estimated error is above tol * max(value, floor * the image's mean)
    with twice the rays per side. The estimate of a level of K rays a side is |m_K - m_k| k / K
    (m_k its previous level): the change between two levels, scaled as a mean of K^2 samples
    converges when a pixel holds many small pieces (1 / K); an edge's converges faster (1 /
    K^2), so the estimate is safe there; a second estimate, half the difference between the
    means of the lattice's two halves, catches two levels that agree by chance. The rounds
    after the first cast at most `budget` times the rays of `samples`, the largest estimates
    first. Every level is the `area_offsets` lattice, shifted per pixel and level
    (lattice_shift): stratified and deterministic. Returns [(rays a side, fine pixels cast)]
    per level.
    """
    y = lum.sum(axis=1)
    rows, cols = np.nonzero(busy_pixels(samples, part, plane_ids(elements), y, tol, floor))
    done = []
    prev, side = fine[rows, cols].sum(axis=1), samples.shape[2] ** 0.5
    ref_floor = floor * _seen_mean(fine.sum(axis=2))
    budget = int(budget * samples.size)
    for level in range(doublings + 1):
        if not len(rows):
            break
        K = edge_side << level
        sub = sample_pixels(part, elements, camera, subpixel, K, rows, cols, rc,
                            lattice_shift(rows, cols, level))
        m = samples_radiance(lum, sub[:, None, :])[:, 0]
        fine[rows, cols] = m
        done.append((K, len(rows)))
        ms = m.sum(axis=1)
        # the two halves of the lattice (even and odd i): a second estimate, independent of
        # the first, so that a pixel whose two levels agree by chance is still caught
        ys = np.where(sub >= 0, y[np.maximum(sub, 0)], 0.0).reshape(len(sub), K, K)
        split = np.abs(ys[:, 0::2].mean(axis=(1, 2)) - ys[:, 1::2].mean(axis=(1, 2))) / 2.0
        est = np.maximum(np.abs(ms - prev) * side / K, split) / np.maximum(ms, ref_floor or 1.0)
        again = np.nonzero(est > tol)[0]
        # within the budget: the largest estimates first (stable: deterministic)
        fits = max(0, budget) // (4 * K * K)
        if len(again) > fits:
            again = np.sort(again[np.argsort(-est[again], kind="stable")[:fits]])
        budget -= 4 * K * K * len(again)
        rows, cols, prev, side = rows[again], cols[again], ms[again], K
    return done


def sample_pixels(part: Partition, elements: Elements, camera: Camera, subpixel: int, k: int,
                  rows: np.ndarray, cols: np.ndarray, rc, shift: np.ndarray | None = None
                  ) -> np.ndarray:
    """As sample_raster, for the fine pixels (rows, cols) only: (n, k*k) int32. shift (n, 2):
    each pixel's lattice moved by it, modulo the pixel (a toroidal shift keeps the lattice
    stratified and n-rooks); None: none."""
    offsets = area_offsets(k)
    s = len(offsets)
    out = np.full((len(rows), s), -1, np.int32)
    step = max(1, AREA_BATCH // s)
    for a in range(0, len(rows), step):
        r, c = rows[a:a + step, None], cols[a:a + step, None]
        ox, oy = offsets[None, :, 0], offsets[None, :, 1]
        if shift is not None:
            ox = np.mod(ox + shift[a:a + step, 0, None], 1.0)
            oy = np.mod(oy + shift[a:a + step, 1, None], 1.0)
        d = _through(camera, subpixel, c + ox, r + oy)
        out[a:a + len(r)] = _seen(part, elements, camera, rc, d.reshape(-1, 3)).reshape(len(r), s)
    return out


def lattice_shift(rows: np.ndarray, cols: np.ndarray, level: int) -> np.ndarray:
    """(n, 2) float64 in [0, 1): the shift of a pixel's lattice at a refinement level, from the
    R2 sequence (Roberts 2018) at a hash of (row, col, level): deterministic, different from
    pixel to pixel and level to level, so that a mesh as regular as the lattice (a grid
    terrain) cannot alias the same way in every pixel, nor two levels agree by chance."""
    idx = (np.asarray(rows, np.int64) * 73856093 ^ np.asarray(cols, np.int64) * 19349663
           ^ (int(level) + 1) * 83492791) & 0xFFFFF
    return np.mod(np.stack([idx * 0.7548776662466927, idx * 0.5698402909980532], 1), 1.0)


# ----------------------------------------------------------------------------- reconstruction

def _gauss_taps(n_out: int, k: int, sigma: float):
    """Gather indices (n_out, T) and weights (n_out, T) of a Gaussian sampled at block centres.

    Output b sits at the centre of fine block b, x = (b + 0.5) k in fine-pixel units (fine
    pixel i has its centre at i + 0.5), so even K has no half-pixel shift. Taps within
    4 sigma (+ half a pixel); weights normalised to 1; indices folded back by half-sample
    reflection (d c b a | a b c d | d c b a), which is scipy.ndimage's 'reflect'.
    """
    n = n_out * k
    c = (np.arange(n_out) + 0.5) * k
    r = int(math.ceil(4.0 * sigma)) + 1
    t = np.floor(c).astype(np.int64)[:, None] + np.arange(-r, r + 1)[None, :]
    d = t + 0.5 - c[:, None]
    w = np.exp(-0.5 * (d / sigma) ** 2)
    w[np.abs(d) > 4.0 * sigma + 0.5] = 0.0
    w /= w.sum(axis=1, keepdims=True)
    t = np.mod(t, 2 * n)
    t = np.where(t >= n, 2 * n - 1 - t, t)
    return t, w


def downsample(fine: np.ndarray, K: int, filter: str = "box", sigma: float = 1.5) -> np.ndarray:
    """K x K supersampled image (H*K, W*K, 3) -> (H, W, 3) float64.

    box: the mean of each K x K block. gaussian: a Gaussian of standard deviation `sigma` in
    FINE pixels (separable, reflecting boundary, truncated at 4 sigma, weights normalised)
    evaluated at the centre of each K x K block; with K = 1 this just blurs the image by sigma
    pixels. The seed uses sigma > 1 (default 1.5, `render.sigma`).
    """
    fine = np.asarray(fine, np.float64)
    K = int(K)
    if K < 1 or fine.ndim != 3 or fine.shape[0] % K or fine.shape[1] % K:
        raise RenderError(f"cannot downsample an image of shape {fine.shape} by K = {K}")
    h, w = fine.shape[0] // K, fine.shape[1] // K
    if filter == "box":
        if K == 1:
            return fine.copy()
        return fine.reshape(h, K, w, K, fine.shape[2]).mean(axis=(1, 3))
    if filter != "gaussian":
        raise RenderError(f"unknown render filter {filter!r}: use box or gaussian")
    sigma = float(sigma)
    if not sigma > 0.0 or not math.isfinite(sigma):
        raise RenderError(f"the Gaussian filter needs sigma > 0 (fine pixels), got {sigma}")
    ti, wi = _gauss_taps(h, K, sigma)
    rows = np.zeros((h, fine.shape[1], fine.shape[2]))
    for j in range(ti.shape[1]):
        rows += wi[:, j, None, None] * fine[ti[:, j]]
    tj, wj = _gauss_taps(w, K, sigma)
    out = np.zeros((h, w, fine.shape[2]))
    for j in range(tj.shape[1]):
        out += wj[None, :, j, None] * rows[:, tj[:, j]]
    return out


