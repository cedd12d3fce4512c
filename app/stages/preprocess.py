"""The preprocessing stage (seed §3, §4.2): the camera's ID raster and the camera-driven
subdivision, as Dask tasks (raster bands, then one task per subscene) run by the one runner.

Writes elements, partition and raster to the run's store.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
from dask.base import tokenize

from radiosity.runtime.cluster import Scattered
from radiosity.errors import SceneError
from radiosity.runtime.monitor import Monitor, peak_rss_mb
from radiosity.runtime.packing import subscene_ranges
from radiosity.tracing.rays import RayCaster, caster_for, raster_band
from radiosity.runtime.runner import run_tasks
from radiosity.runtime.store import RunStore, StageFigures
from radiosity.scene.hidden import anchors, split_hidden
from radiosity.scene.splittrees import footprint_originals
from radiosity.scene.subdivide import (importance_points, lookup, merge_partitions, pixel_size,
                                       subdivide, warn_depth_guard)
from radiosity.core.bundles import Scene


@dataclass(frozen=True)
class RasterInputs:
    """What every preprocessing task needs (scattered once): the original elements, the cameras
    (the run's own first), the sub-pixel factor, the Embree cache key and the ray offset
    (resolved on the driver)."""

    elements: object
    cameras: tuple
    subpixel: int
    key: str
    ray_offset: float

    @property
    def camera(self):
        return self.cameras[0]


@dataclass(frozen=True)
class PreprocessFigures(StageFigures):
    """The preprocessing stage's figures (report.json, section "preprocess")."""

    SECTION = "preprocess"
    variant: str
    subpixel: int
    resolution: list
    original_elements: int
    sub_elements: int
    max_depth: int
    levels: int
    unseen_unsplit: int
    unseen_refined: int          # unseen originals split for the seen ones' sake
    unseen_sub_elements: int
    unseen_mode: str             # refine or keep (the seed's rule)
    pixels_hit: int
    max_pixels_per_sub_element: int
    depth_guarded: int
    sub_elements_per_pixel: float
    subscene_tasks: int
    raster_tasks: int
    time_raster_s: float
    time_subdivide_s: float
    time_total_s: float
    peak_rss_mb: dict
    sub_elements_exact: int | None = None     # seed variant: the exact partition's size
    over_refined_elements: int | None = None  # seed variant: originals split differently
    cameras: int = 1             # cameras the subdivision followed ([[camera]] entries)
    hidden_mode: str = "keep"    # refine: sub-elements no pixel hits split where seen ones see them
    hidden_split: int = 0        # sub-elements no pixel hits that were split (scene/hidden.py)
    hidden_added: int = 0        # sub-elements that added
    hidden_rays: int = 0
    time_hidden_s: float = 0.0

    def rows(self):
        rows = [("original elements", self.original_elements), ("sub-elements", self.sub_elements),
                ("max depth", self.max_depth),
                ("unseen", f"{self.unseen_refined} refined into {self.unseen_sub_elements} "
                           f"sub-elements, {self.unseen_unsplit} left whole ({self.unseen_mode})"),
                ("hidden", f"{self.hidden_split} split into {self.hidden_added} more "
                           f"sub-elements ({self.hidden_mode})"),
                ("pixels hit", self.pixels_hit), ("time", f"{self.time_total_s:.2f} s")]
        if self.sub_elements_exact is not None:
            rows.insert(2, ("sub-elements (exact variant)", self.sub_elements_exact))
        return rows


# ----------------------------------------------------------------------------- tasks

def task_raster(inp: RasterInputs, c: int, r0: int, r1: int):
    """Rays of camera c's fine-raster rows r0:r1 against the whole scene -> (orig, points)."""
    el = inp.elements
    rc = caster_for(inp.key, el.verts, el.nverts, inp.ray_offset)
    return raster_band(rc, el.normal, el.center, inp.cameras[c], inp.subpixel, slice(r0, r1))


def task_subdivide(verts, nverts, normal, points, point_elem, max_depth, ids, group=None):
    """One subscene: split its elements given the pixels that hit them (group: the camera of
    each point, None for one camera)."""
    return subdivide(verts, nverts, normal, points, point_elem, max_depth, element_ids=ids,
                     point_group=group)


def task_seed_subscene(inp: RasterInputs, start, stop, max_depth, rows_per_batch):
    """The seed's variant (seed §4.2): render only this subscene on a full-size screen, then split."""
    el, camera, subpixel = inp.elements, inp.camera, inp.subpixel
    sl = slice(start, stop)
    rc = RayCaster(el.verts[sl], el.nverts[sl], inp.ray_offset)
    h = camera.height * subpixel
    e_all, p_all = [], []
    for r0 in range(0, h, rows_per_batch):
        elem, pts = raster_band(rc, el.normal[sl], el.center[sl], camera, subpixel,
                                slice(r0, min(h, r0 + rows_per_batch)))
        hit = elem >= 0
        e_all.append(elem[hit])
        p_all.append(pts[hit])
    return subdivide(el.verts[sl], el.nverts[sl], el.normal[sl],
                     np.concatenate(p_all), np.concatenate(e_all), max_depth,
                     element_ids=np.arange(start, stop))


# ----------------------------------------------------------------------------- the stage

def subscene_args(el, ranges, points, point_elem, max_depth, group=None):
    """task_subdivide's arguments for each subscene (ranges of original ids): its elements and
    the points (pixels, unseen and hidden importance points) on them, in local ids, with the
    camera of each point where there are several (group, None for one)."""
    order = np.argsort(point_elem, kind="stable")
    he, hp = point_elem[order], points[order]
    hg = None if group is None else np.asarray(group)[order]
    starts = np.searchsorted(he, [a for a, _ in ranges] + [len(el)])
    return [(el.verts[a:b], el.nverts[a:b], el.normal[a:b], hp[starts[i]:starts[i + 1]],
             he[starts[i]:starts[i + 1]] - a, max_depth, np.arange(a, b),
             None if hg is None else hg[starts[i]:starts[i + 1]])
            for i, (a, b) in enumerate(ranges)]


def _scattered(client, args: list):
    """args_of for run_tasks: task i's arguments with its arrays scattered when it is submitted
    (again on a retry), not sent inside the task graph, which large scenes made tens of MiB
    (docs/src/measurements/choices.md)."""
    from radiosity.runtime.cluster import scatter

    def args_of(i):
        a = list(args[i])
        big = [k for k, x in enumerate(a) if isinstance(x, np.ndarray)]
        for k, f in zip(big, scatter(client, [a[k] for k in big])):
            a[k] = f
        return a

    return args_of


@dataclass(frozen=True)
class _Tasks:
    """How this stage runs its tasks: run_tasks' arguments that every step shares."""

    client: object
    token: str
    window: int
    retries: int
    progress: bool
    repair: str

    def run(self, fn, ids, args_of, name: str, on_result) -> None:
        run_tasks(self.client, fn, ids, args_of, name=name, token=self.token,
                  window=self.window, retries=self.retries, on_result=on_result,
                  progress=self.progress, repair=self.repair)


def _check_options(subpixel: int, variant: str, sd) -> None:
    """One line for a subdivide setting out of range (sd: the settings' subdivide section)."""
    if subpixel < 1:
        raise SceneError(f"--subpixel must be 1 or more, got {subpixel}")
    if variant not in ("exact", "seed", "none"):
        raise SceneError(f"unknown subdivision variant {variant!r}: use exact, seed or none")
    for key_, mode in (("unseen", sd.unseen), ("hidden", sd.hidden)):
        if mode not in ("refine", "keep"):
            raise SceneError(f"radiosity.subdivide.{key_} must be refine or keep, got {mode!r}")


def _rasters(tasks: _Tasks, shared, scene: Scene, subpixel: int, rays_per_task: int):
    """Step 1: the ID raster of the original scene (row bands of every camera), needed by
    every variant for the image. Returns per camera (hit original (h w,) int32, -1 for none;
    hit points (h w, 3); raster width) and the number of band tasks."""
    cams = scene.cameras
    bands, rasters = [], []
    for c, cm in enumerate(cams):
        hc, wc = cm.height * subpixel, cm.width * subpixel
        rpt = max(1, rays_per_task // wc)
        bands += [(c, r0, min(hc, r0 + rpt)) for r0 in range(0, hc, rpt)]
        rasters.append((np.full(hc * wc, -1, np.int32), np.zeros((hc * wc, 3)), wc))

    def got_band(i, res):
        c, a, b = bands[i]
        e_c, p_c, wc = rasters[c]
        e_c[a * wc:b * wc], p_c[a * wc:b * wc] = res

    tasks.run(task_raster, range(len(bands)), lambda i: (shared.future(), *bands[i]), "raster",
              got_band)
    for (e_c, _, _), cm, name in zip(rasters, cams, ("", *(n for n, _ in scene.views))):
        if not (e_c >= 0).any():
            raise SceneError(f"{scene.path}: the camera{f' {name!r}' if name else ''} sees no "
                             f"element (at {cm.center.tolist()}, looking along {cm.z.tolist()}): "
                             "check [camera]")
    return rasters, len(bands)


@dataclass(frozen=True)
class _Points:
    """What the split follows: every camera's hit points (seen_e originals (k,), seen_p (k, 3),
    seen_g camera (k,)), the originals they hit (seen (n,) bool), the sub-elements no pixel
    hits may add (budget), a seen pixel's size, and for the exact variant the points it
    splits by (p_all, e_all, g_all: the seen ones and the unseen rule's, ue_count of those)."""

    seen_e: np.ndarray
    seen_p: np.ndarray
    seen_g: np.ndarray
    seen: np.ndarray
    budget: int
    pixel: float
    p_all: np.ndarray | None
    e_all: np.ndarray | None
    g_all: np.ndarray | None
    ue_count: int


def _split_points(el, rasters, sd, variant: str, max_depth: int, ncams: int) -> _Points:
    """The points the subdivision follows: every camera's hit points, and the unseen
    originals' importance points of their own (subdivide.importance_points)."""
    seen_e = np.concatenate([e_c[e_c >= 0] for e_c, _, _ in rasters])
    seen_p = np.concatenate([p_c[e_c >= 0] for e_c, p_c, _ in rasters])
    seen_g = np.concatenate([np.full(int((e_c >= 0).sum()), c, np.int64)
                             for c, (e_c, _, _) in enumerate(rasters)])
    seen = np.zeros(len(el), bool)
    seen[seen_e] = True
    up, ue = np.zeros((0, 3)), np.zeros(0, np.int64)
    budget = int(float(sd.unseen_budget) * len(seen_e))  # sub-elements no pixel hits may add
    pixel = 0.0  # a seen pixel's size: where the two rules stop splitting
    if variant == "exact" and ((sd.unseen == "refine" and (~seen).any()) or sd.hidden == "refine"):
        pixel = pixel_size(seen_p)
    if sd.unseen == "refine" and variant == "exact" and (~seen).any():
        up, ue = importance_points(el.verts, el.nverts, el.normal, el.two_sided,
                                   np.nonzero(~seen)[0], seen_p, el.normal[seen_e],
                                   float(sd.unseen_factor), pixel,
                                   budget + int((~seen).sum()), max_depth)
    p_all = e_all = g_all = None
    if variant == "exact":
        # the unseen rule's points join the run's own camera's (group 0), where its hidden
        # rule's points go too: the rules make leaves of one point per group (hidden.py)
        e_all = np.concatenate([seen_e, ue]).astype(np.int64)
        p_all = np.concatenate([seen_p, up])
        g_all = np.concatenate([seen_g, np.zeros(len(ue), np.int64)]) if ncams > 1 else None
    return _Points(seen_e, seen_p, seen_g, seen, budget, pixel, p_all, e_all, g_all, len(ue))


def _subdivide(tasks: _Tasks, shared, el, variant: str, max_depth: int, ntasks: int,
               rows_per_task: int, pts: _Points):
    """Step 2: the subdivision, one task per subscene (contiguous ranges of original ids).
    Returns the ranges and each task's (partition, figures)."""
    client = tasks.client
    if variant == "none":  # no preprocessing: every original is one element (seed §6, image 1)
        ranges = [(0, len(el))]
        args = [(el.verts, el.nverts, el.normal, np.zeros((0, 3)), np.zeros(0, np.int64),
                 max_depth, np.arange(len(el)))]
        fn, args_of = task_subdivide, _scattered(client, args)
    elif variant == "exact":
        ranges = subscene_ranges(np.bincount(pts.e_all, minlength=len(el)) + 1.0, ntasks)
        args = subscene_args(el, ranges, pts.p_all, pts.e_all, max_depth, pts.g_all)
        fn, args_of = task_subdivide, _scattered(client, args)
    else:
        ranges = subscene_ranges(np.ones(len(el)), ntasks)
        fn = task_seed_subscene

        def args_of(i):
            return (shared.future(), *ranges[i], max_depth, rows_per_task)
    pieces = [None] * len(ranges)
    tasks.run(fn, range(len(ranges)), args_of, "subdivide", pieces.__setitem__)
    return ranges, pieces


def _split_hidden(tasks: _Tasks, el, cams, part, pieces: list, ranges, pts: _Points, sd,
                  rc, max_depth: int, subpixel: int):
    """Step 2b: the sub-elements no pixel hits that seen surfaces see at close range
    (scene/hidden.py), unseen originals' only with subdivide.unseen: refine; the subscenes
    they lie in run again (their pieces replaced). Returns the partition and the counts."""
    hfig = {"split": 0, "added": 0, "rays": 0}
    room = pts.budget - max(0, pts.ue_count - int((~pts.seen).sum()))
    hps, hes, hgs = [], [], []
    for c, cm in enumerate(cams):  # each camera's own points and hidden parts
        mine = (pts.g_all == c) if pts.g_all is not None else slice(None)
        count, anchor = anchors(part, pts.p_all[mine], pts.e_all[mine])
        if sd.unseen != "refine":  # the seed's rule for unseen originals: they stay whole
            count[np.isin(part.orig, np.nonzero(~pts.seen)[0])] = 2  # (as if made by two points)
        hp_c, he_c, f_c = split_hidden(part, count, anchor, el, cm, rc,
                                       float(sd.hidden_factor), pts.pixel, room, max_depth,
                                       int(sd.hidden_rays), subpixel)
        room -= int(f_c["added"])
        hps.append(hp_c)
        hes.append(he_c)
        hgs.append(np.full(len(he_c), c, np.int64))
        hfig = {k: hfig[k] + int(f_c.get(k, 0)) for k in hfig}
    hp, he = np.concatenate(hps), np.concatenate(hes)
    if len(hp):
        args = subscene_args(el, ranges, np.concatenate([pts.p_all, hp]),
                             np.concatenate([pts.e_all, he]), max_depth,
                             None if pts.g_all is None else np.concatenate([pts.g_all, *hgs]))
        again = [i for i, (a, b) in enumerate(ranges) if np.any((he >= a) & (he < b))]
        tasks.run(task_subdivide, again, _scattered(tasks.client, args), "subdivide-hidden",
                  pieces.__setitem__)
        part = merge_partitions([p for p, _ in pieces], ranges, len(el))
    return part, hfig


def preprocess(scene: Scene, out: str, client, settings, progress: bool = True) -> PreprocessFigures:
    """Camera-driven subdivision as Dask tasks; writes elements, partition and raster to the
    store. With several cameras (scene.views) each sub-element is small enough for every
    camera that sees it (the union of each camera's partition); the raster stored is the run's
    own camera's. settings: the run's settings.Settings (its subdivide section)."""
    st = settings
    sd = st.subdivide
    t0 = time.perf_counter()
    subpixel, variant, max_depth = int(sd.subpixel), sd.variant, int(sd.max_depth)
    _check_options(subpixel, variant, sd)
    el, cam, cams = scene.elements, scene.camera, scene.cameras
    threads = sum(client.nthreads().values()) or 1
    ntasks = int(sd.subscenes or 2 * threads)
    h, w = cam.height * subpixel, cam.width * subpixel
    rows_per_task = max(1, int(sd.rays_per_task) // w)

    Monitor(client).stage("preprocess", out, scene.name)
    store = RunStore(out, "w")
    store.save_elements(el)
    store.set_attrs(scene=scene.path, scene_name=scene.name, camera=cam.to_dict(),
                    subpixel=subpixel, views={name: c.to_dict() for name, c in scene.views})
    key = tokenize(el.verts, el.nverts)
    inp = RasterInputs(el, tuple(cams), subpixel, key, float(st.rays.offset))
    shared = Scattered(client, inp)
    # task keys: deterministic per run directory and inputs (never shared between two runs)
    token = tokenize(key, [c.to_dict() for c in cams], subpixel, variant, max_depth, ntasks,
                     rows_per_task, inp.ray_offset, store.path, sd.unseen, sd.unseen_factor,
                     sd.unseen_budget, sd.hidden, sd.hidden_factor, sd.hidden_rays)
    tasks = _Tasks(client, token, max(1, int(st.visibility.window_per_worker) * threads),
                   int(st.visibility.retries), progress, f"run radiosity preprocess again into {out}")

    rasters, nbands = _rasters(tasks, shared, scene, subpixel, int(sd.rays_per_task))
    t_raster = time.perf_counter() - t0
    elem, pts = rasters[0][0], rasters[0][1]
    hit = elem >= 0

    t1 = time.perf_counter()
    points = _split_points(el, rasters, sd, variant, max_depth, len(cams))
    ranges, pieces = _subdivide(tasks, shared, el, variant, max_depth, ntasks, rows_per_task,
                                points)
    part = merge_partitions([p for p, _ in pieces], ranges, len(el))
    hfig = {"split": 0, "added": 0, "rays": 0}
    t_hidden = time.perf_counter()
    if sd.hidden == "refine" and variant == "exact":
        part, hfig = _split_hidden(tasks, el, cams, part, pieces, ranges, points, sd,
                                   caster_for(key, el.verts, el.nverts, inp.ray_offset),
                                   max_depth, subpixel)
    t_hidden = time.perf_counter() - t_hidden
    guarded = sum(f["guarded"] for _, f in pieces)
    firsts = [f["guarded_first"] for _, f in pieces if f["guarded"]]
    warn_depth_guard(guarded, firsts[0] if firsts else -1, max_depth)
    t_sub = time.perf_counter() - t1

    # 3. the sub-element raster (two-level lookup) and the store
    sub = lookup(part, pts, elem)
    seen = points.seen
    per_sub = np.bincount(sub[sub >= 0], minlength=len(part))
    unseen_subs = int(np.diff(part.offsets)[~seen].sum())
    refined = int((np.diff(part.offsets)[~seen] > 1).sum())
    figures = {
        "variant": variant, "subpixel": subpixel, "resolution": [cam.width, cam.height],
        "original_elements": len(el), "sub_elements": len(part),
        "max_depth": int(part.depth.max(initial=0)), "levels": max(f["levels"] for _, f in pieces),
        "unseen_unsplit": int((~seen).sum()) - refined, "unseen_refined": refined,
        "unseen_sub_elements": unseen_subs, "unseen_mode": sd.unseen, "pixels_hit": int(hit.sum()),
        "max_pixels_per_sub_element": int(per_sub.max(initial=0)), "depth_guarded": guarded,
        "sub_elements_per_pixel": len(part) / max(1, int(hit.sum())),
        "subscene_tasks": len(ranges), "raster_tasks": nbands, "cameras": len(cams),
        "time_raster_s": round(t_raster, 4), "time_subdivide_s": round(t_sub, 4),
        "hidden_mode": sd.hidden, "hidden_split": int(hfig["split"]),
        "hidden_added": int(hfig["added"]), "hidden_rays": int(hfig["rays"]),
        "time_hidden_s": round(t_hidden, 4),
    }
    if variant == "seed":
        # the exact partition's size, for comparison with the seed's over-refinement
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            exact, _ = subdivide(el.verts, el.nverts, el.normal, pts[hit], elem[hit], max_depth)
        figures["sub_elements_exact"] = len(exact)
        figures["over_refined_elements"] = int(np.sum(np.diff(part.offsets) != np.diff(exact.offsets)))
    store.save_partition(part, figures)
    # seen: the originals any camera's pixel hits (the cluster layer's importance, links.py);
    # footprint: those a pixel may show (the cluster layer keeps the others coarse)
    eyes = np.array([cm.center for cm in cams])
    foot = footprint_originals(el, points.seen_e, points.seen_p, points.seen_g, eyes,
                               points.pixel or pixel_size(points.seen_p))
    store.write_arrays("raster", {"orig": elem.reshape(h, w), "sub": sub.reshape(h, w),
                                  "seen": seen, "footprint": foot})
    fig = PreprocessFigures(**figures, time_total_s=round(time.perf_counter() - t0, 4),
                            peak_rss_mb=peak_rss_mb(client))
    fig.write(out)
    return fig
