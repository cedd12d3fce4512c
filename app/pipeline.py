"""The whole run in one cluster: plan -> preprocess -> the method's stage -> solve -> image, and
the preview from the original elements (the seed's first image). The stages (stages/) and the
method chosen by name (methods/base.py) do the work; this module only strings them together.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from radiosity.core.bundles import Scene
from radiosity.methods.base import all_pairs_method, choose_method, get_method, stated_method
from radiosity.runtime.monitor import peak_rss_mb
from radiosity.runtime.precompile import with_helper
from radiosity.runtime.store import RunStore, StageFigures, update_report
from radiosity.scene.effects import plan_effects
from radiosity.scene.luminaires import luminaires_of
from radiosity.settings import OPTIONS, Settings, options
from radiosity.stages.grids import grid_rows
from radiosity.stages.image import previewer, render_outputs
from radiosity.stages.preprocess import preprocess
from radiosity.stages.solve import resolve_closure, run_solve, write_direct_solution
from radiosity.stages.tables import summary_rows as light_rows
from radiosity.tracing.rays import RayCaster, raster_band


@dataclass(frozen=True)
class RenderFigures(StageFigures):
    """A whole render: the time of each stage (report.json, section "render") and the report
    every stage wrote, read by section (fig["solve"], fig["visibility"], ...)."""

    SECTION = "render"
    stages: dict
    report: dict

    def to_dict(self) -> dict:
        return {"stages": self.stages}

    def __getitem__(self, key: str):
        return self.report[key]

    def __contains__(self, key: str) -> bool:
        return key in self.report

    def rows(self):
        pre, sol = self.report["preprocess"], self.report["solve"]
        st = self.stages
        return [
            ("sub-elements", f"{pre['sub_elements']} (from {pre['original_elements']} originals)"),
            (("visibility", "skipped (no interreflection)")
             if (self.report.get("visibility") or {}).get("skipped")
             else get_method(sol["method"]).summary_row(self.report)),
            ("solve", f"{sol['solver']}/{sol['kernel']}: {sol['iterations']} passes, residual "
                      f"{sol['final_residual']:.2g}, {sol['channels']} channel(s)"
                      + ("" if sol.get("converged", True) else f", NOT converged: solution "
                         f"{sol.get('solution', 'written')}")),
            *([("direct light", self.report["plan"]["direct_reason"])]
              if "direct_reason" in self.report.get("plan", {}) else []),
            ("closure", (sol.get("closure") or self.report.get("plan", {}).get("closure")
                         or {}).get("reason", "-")),
            *([("rounds", self.report["rounds"]["why"])]
              if (self.report.get("rounds") or {}).get("why") else []),
            *([("views", f"{len(st['views'])} more camera(s): "
                         + ", ".join(f"views/{n}/image.png" for n in st["views"]))]
              if st.get("views") else []),
            ("times", f"preprocess {st['preprocess_s']:.1f} s, visibility {st['visibility_s']:.1f} s, "
                      f"solve {st['solve_s']:.1f} s, image {st['image_s']:.1f} s, "
                      + (f"views {st['views_s']:.1f} s, " if "views_s" in st else "")
                      + f"total {st['total_s']:.1f} s"),
            *light_rows(self.report.get("light")),  # per material: lux, cd/m^2 (tables.py)
            *grid_rows(self.report.get("grids"))]  # per grid: min / average / max lx, U0


@dataclass(frozen=True)
class PlanFigures(StageFigures):
    """The effects plan of a scene and the size estimates behind it (report.json, "plan")."""

    SECTION = "plan"
    effects: object              # effects.EffectsPlan
    closure: object              # closure.Closure: closed or open, and why
    unseen_unsplit: int          # originals the camera does not see (left as one element)
    sub_elements: int            # from the partition, or estimated from one camera raster
    estimated: bool

    def to_dict(self) -> dict:
        key = "sub_elements_estimate" if self.estimated else "sub_elements"
        return {**self.effects.to_dict(), "closure": self.closure.to_dict(),
                "unseen_unsplit": self.unseen_unsplit, key: self.sub_elements}


def scene_plan(scene: Scene, settings: Settings, full: bool = False, run_dir: str | None = None,
               closure=None):
    """The effects plan of a scene (effects.py) and figures for its estimates.

    With a preprocessed `run_dir`, the estimates use its partition (sub-elements per original)
    and raster; otherwise one camera raster estimates them (about 1.4 sub-elements per pixel
    hit, seen on the built-in scenes). closure: the scene's closure.Closure where the caller
    resolved it (render_scene, during the preprocess), else resolved here. Returns
    PlanFigures."""
    s = settings
    el = scene.elements
    if run_dir is not None:
        rs = RunStore(run_dir)
        sizes = np.diff(rs.load_partition().offsets).astype(float)
        elem = rs.read_arrays("raster")["orig"].ravel()
        pix = np.bincount(elem[elem >= 0], minlength=len(el))
    else:
        k = int(s.subdivide.subpixel)
        cam = scene.camera
        rc = RayCaster(el.verts, el.nverts, float(s.rays.offset))
        elem, _ = raster_band(rc, el.normal, el.center, cam, k, slice(0, cam.height * k))
        pix = np.bincount(elem[elem >= 0], minlength=len(el))
        sizes = np.maximum(1.0, 1.4 * pix)
    return PlanFigures(plan_effects(el, tol=float(s.solve.tol), full=full, sizes=sizes,
                                    max_pairs=int(s.plan.max_facing_pairs),
                                    leaf=int(s.plan.leaf_size), where=scene.path),
                       closure if closure is not None
                       else resolve_closure(s.solve.closure, el, s.rays.offset),
                       int((pix == 0).sum()), int(sizes.sum()), estimated=run_dir is None)


def direct_choice(method: str, elements, settings: Settings) -> tuple[str, str]:
    """(mode, why): where method `method` takes the emitters' light (SPEC §10;
    radiosity.direct.mode): the hierarchical method by the scene (params.choose_direct), the
    pairs method through its pairs (the seed's way)."""
    return get_method(method).direct(elements, settings)


def scene_digest(scene: Scene) -> str:
    """sha256 of what a run is made from: the bytes of the scene file and of every mesh file,
    and the element arrays they resolved to (so materials from an MTL file or a glTF buffer
    count too). `render --resume` reuses a run only with the same digest."""
    h = hashlib.sha256()
    for fn in (scene.path, *scene.elements.sources):
        if fn and os.path.isfile(fn):
            with open(fn, "rb") as f:
                h.update(f.read())
    el = scene.elements
    for a in (el.verts, el.nverts, el.reflectance, el.emission, el.two_sided):
        h.update(np.ascontiguousarray(a).tobytes())
    if luminaires_of(el):  # their photometric files' tables included
        h.update(luminaires_of(el).digest().encode())
    return h.hexdigest()


def render_scene(scene: Scene, out: str, client, settings: Settings, *, resume=False,
                 preview=False, progress=True, echo=print, full=False,
                 keep_unconverged=False) -> RenderFigures:
    """plan -> preprocess -> the method's stage -> solve -> image (+ the preview when asked).

    settings: the run's settings.Settings, resolved by the caller (the CLI, `render`); its
    visibility.method chooses the method: "pairs" (the seed's visibility matrix),
    "hierarchical" (links between nodes of the split trees) or "auto" (methods/base.py).

    The effects plan (effects.py) decides what is simulated; `full` forces every effect on.
    With `resume`, a run directory whose preprocessing matches (the same scene: file, contents
    and meshes by scene_digest; the same camera and subpixel) keeps its partition and the
    finished tasks of the method's stage."""
    s = resolve_receiver(settings, scene)
    t0 = time.perf_counter()
    stages = {}
    digest = scene_digest(scene)
    reuse = resume and _reusable(out, scene, digest, int(s.subdivide.subpixel))
    t = time.perf_counter()
    # the closure test needs only the scene: its rays run beside the preprocess, whose driver
    # steps leave a core idle (docs/src/design/pipeline.md: what it saves)
    pool = ThreadPoolExecutor(1, thread_name_prefix="closure")
    closure = pool.submit(resolve_closure, s.solve.closure, scene.elements, s.rays.offset)
    pool.shutdown(wait=False)
    if reuse:
        echo("preprocess: reusing the partition in the run directory")
    else:
        if resume:
            echo("preprocess: nothing to reuse (no run, or another scene, camera or sub-pixel "
                 "factor): starting again")
        preprocess(scene, out, client, s, progress=progress)
        RunStore(out, "r+").set_attrs(scene_digest=digest)
    stages["preprocess_s"] = time.perf_counter() - t
    # decide the effects before the heavy stages, from the partition just made
    planned = scene_plan(scene, s, full=full, run_dir=out, closure=closure.result())
    planned.write(out)
    effects = planned.effects
    est = effects.estimates
    name, why = choose_method(len(RunStore(out).load_partition()), s, originals=len(scene.elements),
                              facing_pairs=est.get("facing_original_pairs",
                                                   est.get("facing_original_pairs_estimate")),
                              point_sources=len(luminaires_of(scene.elements)))
    impl = get_method(name)
    echo(f"method: {why}")
    direct, direct_why = direct_choice(name, scene.elements, s)
    update_report(out, "plan", {"method": name, "method_reason": why, "direct": direct,
                                "direct_reason": direct_why})
    update_report(out, "plan", {"receiver": s.hierarchy.receiver})  # the oracle's weighting
    t = time.perf_counter()
    if effects.interreflection:
        impl.build(out, client, s, resume=resume and reuse, progress=progress,
                   occlusion=effects.occlusion)
    else:
        echo("visibility: skipped (no interreflection: reflectance is 0 everywhere)")
        update_report(out, "visibility", {"skipped": True, "rays": 0, "pairs_total": 0})
    stages["visibility_s"] = time.perf_counter() - t
    t = time.perf_counter()
    if effects.interreflection:
        from radiosity.stages.rounds import solve_with_rounds

        # hierarchy.rounds: refinement by the solved radiance after the first solve (stages/rounds.py)
        solve_with_rounds(out, client, s, occlusion=effects.occlusion,
                          progress=progress, echo=echo, effects=effects, preview=previewer(out),
                          closure=planned.closure, keep_unconverged=keep_unconverged, method=name)
    else:
        write_direct_solution(out)
    stages["solve_s"] = time.perf_counter() - t
    t = time.perf_counter()
    fig = render_outputs(out, settings=s, progress=progress)
    stages["image_s"] = time.perf_counter() - t
    if scene.grids:  # calculation grids: illuminance at their points (stages/grids.py)
        t = time.perf_counter()
        render_grids(out, s, scene.grids)
        stages["grids_s"] = time.perf_counter() - t
    if scene.views:  # the other cameras: views of the one solution (stages/views.py)
        t = time.perf_counter()
        stages["views"] = _render_views(scene, out, s, fig.exposure)
        stages["views_s"] = time.perf_counter() - t
    if preview:
        t = time.perf_counter()
        stages["preview"] = render_preview(scene, out, client, s, exposure=fig.exposure)
        stages["preview_s"] = time.perf_counter() - t
    stages["total_s"] = time.perf_counter() - t0
    stages["peak_rss_mb"] = peak_rss_mb(client)
    report = update_report(out, "render", {"stages": stages})
    return RenderFigures(stages, report)


def resolve_receiver(settings: Settings, scene: Scene) -> Settings:
    """hierarchy.receiver auto resolved: arriving (the oracle weighs the light that arrives at
    a receiver, not what it reflects) when the scene has calculation grids, else reflected."""
    import dataclasses

    h = settings.hierarchy
    if h.receiver != "auto":
        return settings
    return dataclasses.replace(settings, hierarchy=dataclasses.replace(
        h, receiver="arriving" if scene.grids else "reflected"))


def render_grids(out: str, settings: Settings, grids):
    """Illuminance on `grids` (scene/grids.Grid) from the solved run `out`: RUN/grids/ and
    report.json "grids" (stages/grids.py). Returns GridFigures."""
    from radiosity.stages.grids import illuminate, write_grids

    return write_grids(out, illuminate(RunStore(out, "r"), settings, grids))


def read_grids(run_dir: str, names) -> dict:
    """name -> the columns of RUN/grids/NAME.csv, (k,) float64 arrays."""
    out = {}
    for n in names:
        a = np.genfromtxt(os.path.join(run_dir, "grids", f"{n}.csv"), delimiter=",", names=True)
        out[n] = {k: np.atleast_1d(a[k]).astype(np.float64) for k in a.dtype.names}
    return out


def _reusable(out: str, scene: Scene, digest: str, subpixel: int) -> bool:
    """Whether `out` holds a preprocessed run of this scene (file, contents and meshes by
    scene_digest), camera, views and sub-pixel factor: what `render --resume` keeps."""
    if not os.path.exists(os.path.join(out, "store.zarr")):
        return False
    try:
        rs = RunStore(out)
        at = rs.attrs
        return (at.get("scene") == scene.path and at.get("scene_digest") == digest
                and at.get("camera") == scene.camera.to_dict()
                and at.get("views", {}) == {n: c.to_dict() for n, c in scene.views}
                and at.get("subpixel") == subpixel and rs.has("raster"))
    except Exception:
        return False


def _render_views(scene: Scene, out: str, settings: Settings, exposure: float) -> list:
    """The scene's other cameras ([[camera]] entries) as views of the one solution, at the
    run's exposure; returns their names."""
    from radiosity.stages.views import Viewer

    viewer = Viewer(out, settings)
    for name, cam in scene.views:
        viewer.render(cam, name, exposure=exposure)
    return [name for name, _ in scene.views]


def render_preview(scene: Scene, out: str, client, settings: Settings, exposure=None) -> str:
    """The same scene solved on its original elements only (no preprocessing), as the seed's
    first image: writes OUT/preview.png (and keeps its run in OUT/preview/), by the method that
    takes every pair as it is (methods/base.all_pairs_method). Large originals close together
    make the point kernel's rows sum past 1, so the preview uses the bounded disc kernel and at
    most 200 passes."""
    s = settings.replace({"subdivide.subpixel": 1, "subdivide.variant": "none",
                          "solve.solver": "jacobi", "solve.kernel": "disc",
                          "solve.max-iterations": 200, "render.exposure": exposure})
    sub = os.path.join(out, "preview")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        preprocess(scene, sub, client, s, progress=False)
        exact = all_pairs_method()
        exact.build(sub, client, s, progress=False)
        run_solve(sub, client, s, progress=False, method=exact.name)
        render_outputs(sub, settings=s)
    dst = os.path.join(out, "preview.png")
    shutil.copyfile(os.path.join(sub, "image.png"), dst)
    return dst


@dataclass(frozen=True)
class Rendered:
    """What `render` gives back: the run directory (None when it was temporary), the image as
    linear radiance (H, W, 3) and in sRGB (H, W, 3) uint8, the figures of every stage, the
    report (report.json) as a dict, for a mesh file the camera the loader chose, the image
    (linear radiance) of each of the scene's other cameras by name ([[camera]] entries), and
    each calculation grid's columns by name ([[grid]] entries: RUN/grids/NAME.csv's x, y, z,
    nx, ny, nz, illuminance_lux, direct_lux, indirect_lux as numpy arrays)."""

    out: str | None
    image: np.ndarray
    image_srgb: np.ndarray
    figures: RenderFigures
    report: dict
    chosen: str = ""  # what the loader chose for a mesh file: its camera, as a [camera] table
    views: dict = field(default_factory=dict)  # name -> (H, W, 3) linear radiance
    # calculation grids: name -> the columns of RUN/grids/NAME.csv as (k,) numpy arrays (x, y,
    # z, nx, ny, nz, illuminance_lux, direct_lux, indirect_lux; pandas.DataFrame takes it)
    grids: dict = field(default_factory=dict)

    def summary(self) -> str:
        """The table the CLI prints."""
        return "\n".join(f"  {k:<13} {v}" for k, v in self.figures.rows())


# render()'s options that are render_scene's own keywords; the others are settings (OPTIONS)
_RUN_KEYWORDS = ("resume", "preview", "full", "keep_unconverged")


def scene_of(scene, resolution, settings: Settings) -> Scene:
    """The Scene of `scene`: a scene TOML or mesh path, a loaded Scene, or a trimesh.Trimesh /
    trimesh.Scene (written to a temporary GLB, with its materials and colours, and read as a
    mesh file: the same loader, the same checks)."""
    import tempfile

    from radiosity.errors import RadiosityError
    from radiosity.scene.load import load_scene

    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, (str, os.PathLike)):
        return load_scene(scene, resolution=resolution, settings=settings)
    if type(scene).__module__.split(".")[0] == "trimesh" and hasattr(scene, "export"):
        with tempfile.TemporaryDirectory(prefix="radiosity-mesh-") as tmp:
            fn = os.path.join(tmp, f"{type(scene).__name__.lower()}.glb")
            scene.export(fn, file_type="glb")
            return load_scene(fn, resolution=resolution, settings=settings)
    raise RadiosityError(f"radiosity.render: cannot render a {type(scene).__name__}: give a scene "
                         "TOML or mesh path, a trimesh.Trimesh or a trimesh.Scene")


@with_helper  # a first run: a helper process compiles from the other end of the kernels
def render(scene, out: str | None = None, *, client=None, workers: int | None = None,
           scheduler: str | None = None, processes: bool | str | None = None,
           resolution=None, settings: Settings | None = None, progress: bool = False, echo=None,
           force: bool = False, **options_) -> Rendered:
    """Render `scene` (a scene TOML or mesh path, a loaded Scene, a trimesh.Trimesh or
    trimesh.Scene) into the run directory `out` (None: a temporary one, removed afterwards; the
    arrays stay) and return a `Rendered`.

    Options are the CLI's `render` flags as keywords (resolution=64, tol=1e-6, method="pairs",
    epsilon=..., preview=True, ...), checked as the CLI checks them (settings.check: the same
    one-line RadiosityError). settings: a base settings.Settings (default: dask.config's). The
    cluster: `client` if given, else a new one of `workers` at `scheduler`, or local workers
    as threads in this process: no worker processes are started unless processes=True (which
    needs the `if __name__ == "__main__":` guard of any multiprocessing script), so a plain
    script needs no guard."""
    import tempfile

    from radiosity.errors import RadiosityError
    from radiosity.runtime.checks import check_new_run_dir, check_scene, check_solve
    from radiosity.runtime.cluster import local_mode, open_client
    from radiosity.core.colour import tonemap
    from radiosity.formats.images import read_exr

    unknown = sorted(set(options_) - set(OPTIONS) - set(_RUN_KEYWORDS))
    if unknown:
        raise RadiosityError(f"radiosity.render: unknown option(s) {', '.join(unknown)} (options: "
                             f"resolution, {', '.join([*_RUN_KEYWORDS, *OPTIONS])})")
    run_kw = {k: options_.pop(k) for k in _RUN_KEYWORDS if k in options_}
    st = options(settings, processes=False if processes is None else processes, **options_)
    sc = scene_of(scene, resolution, st)
    check_solve(st)
    check_scene(sc, st, stated_method(st))
    say = echo or (lambda *a, **k: None)
    if sc.chosen:
        say(sc.chosen)
    with contextlib.ExitStack() as stack:
        run = out if out is not None else stack.enter_context(
            tempfile.TemporaryDirectory(prefix="radiosity-render-"))
        if out is not None:
            check_new_run_dir(out, force or bool(run_kw.get("resume")))
        if client is None:
            samples = sum(c.width * c.height for c in sc.cameras) * int(st.subdivide.subpixel) ** 2
            inproc, why = local_mode(st.cluster.processes, samples, st.cluster.in_process_samples)
            client = stack.enter_context(open_client(workers, scheduler, quiet=echo is None,
                                                     echo=say, in_process=inproc, where=why,
                                                     settings=st.cluster))
        fig = render_scene(sc, run, client, st, progress=progress, echo=say, **run_kw)
        image = read_exr(os.path.join(run, "image.exr"))
        srgb = tonemap(image, fig["render"].get("exposure"))
        views = {n: read_exr(os.path.join(run, "views", n, "image.exr")) for n, _ in sc.views}
        return Rendered(out, image, srgb, fig, dict(fig.report), sc.chosen, views,
                        read_grids(run, [g.name for g in sc.grids]))
