"""The stages as Dask work: what each stage submits, gathers and stores.

Tasks are module-level functions that take arrays and return arrays; big read-only inputs are
scattered once. The stage masters (this module, visibility.py, solve.py) are the only code that
talks to a Client; planning (plan.py, planner.py) and kernels never do.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from dask.base import tokenize
from distributed import as_completed

from . import config
from .errors import SceneError
from .rays import RayCaster, caster_for
from .store import RunStore, update_report
from .subdivide import (lookup, merge_partitions, raster_band, subdivide, warn_depth_guard)
from .types import Scene


def _progress(total: int, desc: str, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="task", disable=not enabled, leave=False)


def peak_rss_mb(client) -> dict:
    """Peak resident memory of the client process and each worker (MiB)."""
    import resource

    def peak():  # runs on each worker
        import resource as r
        return r.getrusage(r.RUSAGE_SELF).ru_maxrss / 1024.0

    out = {"master": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    try:
        out["workers"] = {k: round(v, 1) for k, v in client.run(peak).items()}
    except Exception:  # a worker that died mid-run has no figure
        pass
    return out


# ----------------------------------------------------------------------------- tasks

def task_raster(elements, camera, subpixel, r0, r1, key):
    """Camera rays of fine-raster rows r0:r1 against the whole scene -> (orig, points)."""
    rc = caster_for(key, elements.verts, elements.nverts)
    return raster_band(rc, elements.normal, elements.center, camera, subpixel, slice(r0, r1))


def task_subdivide(verts, nverts, normal, points, point_elem, max_depth, ids):
    """One subscene: split its elements given the pixels that hit them."""
    return subdivide(verts, nverts, normal, points, point_elem, max_depth, element_ids=ids)


def task_seed_subscene(elements, camera, subpixel, start, stop, max_depth, rows_per_batch):
    """The seed's variant (seed §4.2): render only this subscene on a full-size screen, then split."""
    sl = slice(start, stop)
    rc = RayCaster(elements.verts[sl], elements.nverts[sl])
    h = camera.height * subpixel
    e_all, p_all = [], []
    for r0 in range(0, h, rows_per_batch):
        elem, pts = raster_band(rc, elements.normal[sl], elements.center[sl], camera, subpixel,
                                slice(r0, min(h, r0 + rows_per_batch)))
        hit = elem >= 0
        e_all.append(elem[hit])
        p_all.append(pts[hit])
    return subdivide(elements.verts[sl], elements.nverts[sl], elements.normal[sl],
                     np.concatenate(p_all), np.concatenate(e_all), max_depth,
                     element_ids=np.arange(start, stop))


# ----------------------------------------------------------------------------- planning (pure)

def subscene_ranges(weights: np.ndarray, ntasks: int) -> list[tuple[int, int]]:
    """Cut 0..n into at most `ntasks` contiguous ranges of about equal total weight."""
    n = len(weights)
    ntasks = max(1, min(ntasks, n))
    cum = np.cumsum(weights, dtype=float)
    total = cum[-1] if n else 0.0
    cuts = np.searchsorted(cum, total * np.arange(1, ntasks) / ntasks, side="left") + 1
    bounds = np.unique(np.concatenate([[0], np.clip(cuts, 1, n), [n]]))
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


# ----------------------------------------------------------------------------- the stage

def preprocess(scene: Scene, out: str, client, subpixel: int | None = None,
               variant: str | None = None, subscenes: int | None = None,
               progress: bool = True) -> dict:
    """Camera-driven subdivision as Dask tasks; writes elements, partition and raster to the store."""
    t0 = time.perf_counter()
    subpixel = int(config.get("subdivide.subpixel", subpixel))
    variant = config.get("subdivide.variant", variant)
    max_depth = int(config.get("subdivide.max-depth"))
    if subpixel < 1:
        raise SceneError(f"--subpixel must be 1 or more, got {subpixel}")
    if variant not in ("exact", "seed", "none"):
        raise SceneError(f"unknown subdivision variant {variant!r}: use exact, seed or none")
    el, cam = scene.elements, scene.camera
    threads = sum(client.nthreads().values()) or 1
    ntasks = int(config.get("subdivide.subscenes", subscenes) or 2 * threads)
    h, w = cam.height * subpixel, cam.width * subpixel
    rows_per_task = max(1, int(config.get("subdivide.rays-per-task")) // w)

    from .monitor import Monitor

    Monitor(client).stage("preprocess", out, scene.name)
    store = RunStore(out, "w")
    store.save_elements(el)
    store.set_attrs(scene=scene.path, scene_name=scene.name, camera=cam.to_dict(), subpixel=subpixel)
    key = tokenize(el.verts, el.nverts)
    [el_f] = client.scatter([el], broadcast=True, hash=False)

    # 1. the ID raster of the original scene (row bands), needed by both variants for the image
    bands = [(r0, min(h, r0 + rows_per_task)) for r0 in range(0, h, rows_per_task)]
    futs = {client.submit(task_raster, el_f, cam, subpixel, a, b, key, pure=False): i
            for i, (a, b) in enumerate(bands)}
    elem = np.empty(h * w, np.int32)
    pts = np.empty((h * w, 3))
    with _progress(len(futs), "raster", progress) as bar:
        for fut, (e, p) in as_completed(futs, with_results=True):
            a, b = bands[futs[fut]]
            elem[a * w:b * w] = e
            pts[a * w:b * w] = p
            bar.update()
    t_raster = time.perf_counter() - t0
    hit = elem >= 0
    if not hit.any():
        raise SceneError(f"{scene.path}: the camera sees no element (at {cam.center.tolist()}, "
                         f"looking along {cam.z.tolist()}): check [camera]")

    # 2. subdivision, one task per subscene (contiguous ranges of original ids)
    t1 = time.perf_counter()
    if variant == "none":  # no preprocessing: every original is one element (seed §6, image 1)
        ranges = [(0, len(el))]
        futs = {client.submit(task_subdivide, el.verts, el.nverts, el.normal, np.zeros((0, 3)),
                              np.zeros(0, np.int64), max_depth, np.arange(len(el)), pure=False): 0}
    elif variant == "exact":
        counts = np.bincount(elem[hit], minlength=len(el))
        ranges = subscene_ranges(counts + 1.0, ntasks)
        order = np.argsort(elem[hit], kind="stable")
        he, hp = elem[hit][order], pts[hit][order]
        starts = np.searchsorted(he, [a for a, _ in ranges] + [len(el)])
        futs = {}
        for i, (a, b) in enumerate(ranges):
            s0, s1 = starts[i], starts[i + 1]
            futs[client.submit(task_subdivide, el.verts[a:b], el.nverts[a:b], el.normal[a:b],
                               hp[s0:s1], he[s0:s1] - a, max_depth, np.arange(a, b), pure=False)] = i
    else:
        ranges = subscene_ranges(np.ones(len(el)), ntasks)
        futs = {client.submit(task_seed_subscene, el_f, cam, subpixel, a, b, max_depth,
                              rows_per_task, pure=False): i for i, (a, b) in enumerate(ranges)}
    pieces = [None] * len(ranges)
    with _progress(len(futs), "subdivide", progress) as bar:
        for fut, (part, fig) in as_completed(futs, with_results=True):
            pieces[futs[fut]] = (part, fig)
            bar.update()
    part = merge_partitions([p for p, _ in pieces], ranges, len(el))
    guarded = sum(f["guarded"] for _, f in pieces)
    firsts = [f["guarded_first"] for _, f in pieces if f["guarded"]]
    warn_depth_guard(guarded, firsts[0] if firsts else -1, max_depth)
    t_sub = time.perf_counter() - t1

    # 3. the sub-element raster (two-level lookup) and the store
    sub = lookup(part, pts, elem)
    per_sub = np.bincount(sub[sub >= 0], minlength=len(part))
    seen = np.zeros(len(el), bool)
    seen[elem[hit]] = True
    figures = {
        "variant": variant, "subpixel": subpixel, "resolution": [cam.width, cam.height],
        "original_elements": len(el), "sub_elements": len(part),
        "max_depth": int(part.depth.max(initial=0)), "levels": max(f["levels"] for _, f in pieces),
        "unseen_unsplit": int((~seen).sum()), "pixels_hit": int(hit.sum()),
        "max_pixels_per_sub_element": int(per_sub.max(initial=0)), "depth_guarded": guarded,
        "sub_elements_per_pixel": len(part) / max(1, int(hit.sum())),
        "subscene_tasks": len(ranges), "raster_tasks": len(bands),
        "time_raster_s": round(t_raster, 4), "time_subdivide_s": round(t_sub, 4),
    }
    if variant == "seed":
        # the exact partition's size, for comparison with the seed's over-refinement
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            exact, _ = subdivide(el.verts, el.nverts, el.normal, pts[hit], elem[hit], max_depth)
        figures["sub_elements_exact"] = len(exact)
        figures["over_refined_elements"] = int(np.sum(np.diff(part.offsets) != np.diff(exact.offsets)))
    store.save_partition(part, figures)
    store.write_arrays("raster", {"orig": elem.reshape(h, w), "sub": sub.reshape(h, w)})
    figures["time_total_s"] = round(time.perf_counter() - t0, 4)
    figures["peak_rss_mb"] = peak_rss_mb(client)
    update_report(out, "preprocess", figures)
    return figures


# ----------------------------------------------------------------------------- the whole run

def scene_plan(scene: Scene, subpixel: int | None = None, tol: float | None = None,
               full: bool = False, run_dir: str | None = None):
    """The effects plan of a scene (planner.py) and figures for its estimates.

    With a preprocessed `run_dir`, the estimates use its partition (sub-elements per original)
    and raster; otherwise one camera raster estimates them (about 1.4 sub-elements per pixel
    hit, seen on the built-in scenes). Returns (plan, figures)."""
    from .planner import plan_effects

    tol = float(config.get("solve.tol", tol))
    el = scene.elements
    if run_dir is not None:
        rs = RunStore(run_dir)
        sizes = np.diff(rs.load_partition().offsets).astype(float)
        elem = rs.read_arrays("raster")["orig"].ravel()
        pix = np.bincount(elem[elem >= 0], minlength=len(el))
        key = "sub_elements"
    else:
        subpixel = int(config.get("subdivide.subpixel", subpixel))
        cam = scene.camera
        rc = RayCaster(el.verts, el.nverts)
        elem, _ = raster_band(rc, el.normal, el.center, cam, subpixel, slice(0, cam.height * subpixel))
        pix = np.bincount(elem[elem >= 0], minlength=len(el))
        sizes = np.maximum(1.0, 1.4 * pix)
        key = "sub_elements_estimate"
    plan = plan_effects(el, tol=tol, full=full, sizes=sizes)
    return plan, {"unseen_unsplit": int((pix == 0).sum()), key: int(sizes.sum())}


def render_scene(scene: Scene, out: str, client, *, subpixel=None, variant=None, unit=None,
                 solver=None, kernel=None, tol=None, filter=None, sigma=None, exposure=None,
                 resume=False, preview=True, progress=True, echo=print, full=False,
                 method=None, epsilon=None, link_rays=None) -> dict:
    """plan -> preprocess -> visibility -> solve -> image (+ the preview from the originals).

    method: "pairs" (the seed's visibility matrix) or "hierarchical" (links between nodes of
    the split trees, links.py; epsilon and link_rays are its settings); default
    radiosity.visibility.method.

    The effects plan (planner.py) decides what is simulated; `full` forces every effect on.
    With `resume`, a run directory whose preprocessing matches (same scene file, camera and
    subpixel) keeps its partition and the finished visibility tasks."""
    import os

    from .render import render_outputs
    from .solve import run_solve
    from .visibility import compute_visibility

    t0 = time.perf_counter()
    stages = {}
    reuse = False
    if resume and os.path.exists(os.path.join(out, "store.zarr")):
        try:
            rs = RunStore(out)
            at = rs.attrs
            reuse = (at.get("scene") == scene.path and at.get("camera") == scene.camera.to_dict()
                     and at.get("subpixel") == int(config.get("subdivide.subpixel", subpixel))
                     and rs.has("raster"))
        except Exception:
            reuse = False
    t = time.perf_counter()
    if reuse:
        echo("preprocess: reusing the partition in the run directory")
    else:
        preprocess(scene, out, client, subpixel=subpixel, variant=variant, progress=progress)
    stages["preprocess_s"] = time.perf_counter() - t
    # decide the effects before the heavy stages, from the partition just made
    effects, est = scene_plan(scene, subpixel, tol, full, run_dir=out)
    update_report(out, "plan", {**effects.to_dict(), **est})
    method = config.get("visibility.method", method)
    if method not in ("pairs", "hierarchical"):
        raise SceneError(f"--method must be pairs or hierarchical, got {method!r}")
    t = time.perf_counter()
    if effects.interreflection and method == "hierarchical":
        from .links import compute_links

        compute_links(out, client, kernel=kernel, epsilon=epsilon, rays=link_rays, unit=unit,
                      resume=resume and reuse, progress=progress, occlusion=effects.occlusion)
    elif effects.interreflection:
        compute_visibility(out, client, unit=unit, resume=resume and reuse, progress=progress,
                           occlusion=effects.occlusion, kernel=kernel)
    else:
        echo("visibility: skipped (no interreflection: reflectance is 0 everywhere)")
        update_report(out, "visibility", {"skipped": True, "rays": 0, "pairs_total": 0})
    stages["visibility_s"] = time.perf_counter() - t
    t = time.perf_counter()
    if effects.interreflection and method == "hierarchical":
        from .linksolve import run_solve_links

        run_solve_links(out, client, solver=solver, tol=tol, progress=progress, effects=effects)
    elif effects.interreflection:
        run_solve(out, client, solver=solver, kernel=kernel, tol=tol, progress=progress,
                  effects=effects)
    else:
        from .solve import write_direct_solution
        write_direct_solution(out)
    stages["solve_s"] = time.perf_counter() - t
    t = time.perf_counter()
    fig = render_outputs(out, filter=filter, sigma=sigma, exposure=exposure)
    stages["image_s"] = time.perf_counter() - t
    if preview:
        t = time.perf_counter()
        stages["preview"] = render_preview(scene, out, client, tol=tol, exposure=fig.get("exposure"))
        stages["preview_s"] = time.perf_counter() - t
    stages["total_s"] = time.perf_counter() - t0
    stages["peak_rss_mb"] = peak_rss_mb(client)
    return update_report(out, "render", {"stages": stages})


def render_preview(scene: Scene, out: str, client, tol=None,
                   exposure=None) -> str:
    """The same scene solved on its original elements only (no preprocessing), as the seed's
    first image: writes OUT/preview.png (and keeps its run in OUT/preview/). Large originals
    close together make the point kernel's rows sum past 1, so the preview uses the bounded
    disc kernel and at most 200 passes."""
    import os
    import shutil

    from .render import render_outputs
    from .solve import run_solve
    from .visibility import compute_visibility

    sub = os.path.join(out, "preview")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        preprocess(scene, sub, client, subpixel=1, variant="none", progress=False)
        compute_visibility(sub, client, progress=False)
        run_solve(sub, client, solver="jacobi", kernel="disc", tol=tol, max_iter=200, progress=False)
        render_outputs(sub, exposure=exposure)
    dst = os.path.join(out, "preview.png")
    shutil.copyfile(os.path.join(sub, "image.png"), dst)
    return dst
