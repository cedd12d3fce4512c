"""Checks made before any cluster starts: everything about a command's input that can be known
without the workers (solver and kernel, the run directory, the scene's light and camera, and
which way its faces point: check_orientation).

A problem raises RadiosityError (SceneError, StoreError) naming the option, path or scene and
what to do, so the CLI prints one line and exits 2 before anything is created; warnings are
said, not fatal.
"""

from __future__ import annotations

import errno
import os
import warnings

import numpy as np

from radiosity.errors import RadiosityError, SceneError, StoreError
from radiosity.core.kernels import get_kernel
from radiosity.settings import sampling_of

#: Rays of the coarse camera check (a grid over the image); the full raster is cast only when
#: the coarse grid hits nothing, to tell "sees nothing" from "sees only something small".
COARSE_RAYS = 128


def check_solve(settings) -> tuple[str, str]:
    """The solver and kernel a solve will use (settings.solve), checked: a known kernel with
    valid sampling settings, a known solver, and cg only with a reciprocal kernel. Returns
    (solver, kernel)."""
    from radiosity.core.solvers import choose_solver

    kernel = settings.solve.kernel
    k = get_kernel(kernel)
    sampling_of(settings.solve)  # a bad nxm-points / mc-samples fails here
    solver = choose_solver(settings.solve.solver, kernel)
    if solver == "cg" and not k.reciprocal:
        raise RadiosityError(f"the cg solver needs a reciprocal kernel (A_a F_ab = A_b F_ba); "
                             f"'{kernel}' is not: use --kernel point, or --solver jacobi, "
                             "gauss-seidel or progressive")
    closure = settings.solve.closure
    if {True: "on", False: "off", None: "auto"}.get(closure, closure) not in ("auto", "on", "off"):
        raise RadiosityError(f"radiosity.solve.closure must be auto, on or off, got {closure!r}")
    return solver, kernel


# ----------------------------------------------------------------------------- run directories

FS_ERRORS = {errno.ENOSPC: "the filesystem is full", errno.EROFS: "the filesystem is read-only",
             errno.EACCES: "permission denied", errno.EPERM: "permission denied",
             errno.EDQUOT: "the disk quota is exceeded", errno.ENOTDIR: "a part of the path is a file",
             errno.EEXIST: "it exists and is not a directory", errno.EISDIR: "it is a directory"}


def fs_advice(err: int | None, existing: bool = False) -> str:
    """What to do about a filesystem error; `existing`: for a run directory that exists."""
    if err in (errno.ENOSPC, errno.EDQUOT):
        return "free space there (or use a run directory on another filesystem)"
    if err in (errno.EROFS, errno.EACCES, errno.EPERM):
        if existing:
            return "copy the run directory to a writable filesystem (or fix its permissions) " \
                   "and run the command on the copy"
        return "use a run directory on a writable filesystem (or fix its permissions)"
    return "choose another run directory"


def _probe(d: str, what: str, existing: bool = False) -> None:
    """Create and delete a small file in directory d: the only test of writability that also
    holds for root and read-only mounts."""
    fn = os.path.join(d, f".radiosity-probe-{os.getpid()}")
    try:
        with open(fn, "wb") as f:
            f.write(b"\0" * 512)
            f.flush()
            os.fsync(f.fileno())
        os.remove(fn)
    except OSError as e:
        try:
            os.remove(fn)
        except OSError:
            pass
        raise StoreError(f"cannot write {what} {d}: {FS_ERRORS.get(e.errno, e.strerror)}; "
                         f"{fs_advice(e.errno, existing)}") from None


#: What marks a folder as one of ours (a run, a reference, a comparison): a command may write
#: into such a folder again; into any other non-empty folder only with --force.
OURS = ("store.zarr", "report.json", "reference.json", "compare.json", "run.lock",
        "radiosity-error.log")


def check_new_run_dir(out: str, force: bool = False) -> None:
    """A run directory that a command will create or overwrite (preprocess, render --out):
    not a file, not under a file, not a non-empty folder of the user's (unless `force`),
    creatable and writable. Creates it when missing (empty)."""
    path = os.path.abspath(out)
    if os.path.exists(path) and not os.path.isdir(path):
        raise StoreError(f"--out {out} is a file, not a directory: choose another path, or remove "
                         "the file")
    if os.path.isdir(path) and not force:
        try:
            names = sorted(os.listdir(path))
        except OSError:
            names = []
        if names and not any(n in names for n in OURS):
            shown = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
            raise StoreError(f"--out {out} is a folder with other files in it ({shown}), not a run "
                             "directory: choose a new or empty folder, or add --force to write "
                             "into it")
    parent = path
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise StoreError(f"--out {out} lies under {parent}, which is a file: choose another path")
    if not os.path.isdir(path):
        try:
            os.makedirs(path)
        except FileExistsError:
            pass  # made by someone else meanwhile: the lock decides who writes
        except OSError as e:
            raise StoreError(f"cannot create the run directory {out}: "
                             f"{FS_ERRORS.get(e.errno, e.strerror)}; {fs_advice(e.errno)}") from None
    _probe(path, "into the run directory")


def check_run_dir(run_dir: str, write: bool = True) -> None:
    """An existing run directory a stage reads (and, with `write`, writes: solve, image,
    visibility). Missing stores say which command makes one (store.RunStore)."""
    from radiosity.runtime.store import STORE, RunStore

    RunStore(run_dir)  # exists, right format
    if write:
        _probe(os.path.abspath(run_dir), "into the run directory", True)
        _probe(os.path.join(os.path.abspath(run_dir), STORE), "into the run store", True)


# ----------------------------------------------------------------------------- the scene

def check_scene(scene, settings, method=None) -> dict:
    """Light and camera of a scene, before any cluster starts. A camera that sees no element is
    an error (the image would be empty); a scene without an emitter is a warning (it renders
    black, which is what it is, e.g. for a geometry check); faces that point the wrong way are
    errors or warnings as `check_orientation` says; with a method stated (`method`: a
    methods.base.TransportMethod, methods.base.stated_method), what its stage would refuse is
    refused (its check_scene: the pairs method's facing pairs of originals past
    plan.max-facing-pairs) (settings: a settings.Settings; its subdivide.subpixel sets the
    raster). Returns {"hits": rays that hit, "facing_pairs_estimate": the stated method's
    check_scene estimates (None: none), "orientation": check_orientation's figures}."""
    from radiosity.scene.emitters import AreaEmitters
    from radiosity.tracing.rays import caster_of

    el, cam = scene.elements, scene.camera
    emitters = AreaEmitters(el)
    if not emitters.any() and not _luminaires(el):  # [[luminaire]] point sources count too
        warnings.warn(f"{scene.path}: {emitters.describe()}: the image will be black; give a "
                      "material an emission ([material.NAME] emission = [r, g, b])", stacklevel=2)
    est = method.check_scene(scene, settings) if method is not None else None
    if method is not None and _luminaires(el):  # can it carry point sources? (one line if not)
        method.direct(el, settings)
    subpixel = int(settings.subdivide.subpixel)
    rc = caster_of(el.verts, el.nverts, float(settings.rays.offset))
    seen = _camera_hits(scene, rc, cam, subpixel)
    for name, view in scene.views:  # the other cameras ([[camera]] entries): seen and lit
        _check_view(scene, rc, view, name, _camera_hits(scene, rc, view, subpixel, name))
    return {"hits": int(len(seen)), "facing_pairs_estimate": est,
            "orientation": check_orientation(scene, rc, seen)}


def _camera_hits(scene, rc, cam, subpixel: int, name: str = "") -> np.ndarray:
    """The elements (k,) int hit by a coarse grid of the camera's fine pixels (the whole raster
    when that grid hits nothing); a camera that sees no element is a SceneError."""
    h, w = cam.height * subpixel, cam.width * subpixel
    # a coarse grid of fine pixels first (cheap), the whole raster only when it hits nothing
    ys = np.unique(np.linspace(0, h - 1, min(h, COARSE_RAYS)).round().astype(np.int64))
    xs = np.unique(np.linspace(0, w - 1, min(w, COARSE_RAYS)).round().astype(np.int64))
    seen = _hits(rc, cam, subpixel, ys, xs)
    if not (seen >= 0).any() and (len(ys) < h or len(xs) < w):
        band = max(1, (1 << 20) // max(w, 1))
        for r0 in range(0, h, band):
            seen = _hits(rc, cam, subpixel, np.arange(r0, min(h, r0 + band)), np.arange(w))
            if (seen >= 0).any():
                break
    if not (seen >= 0).any():
        raise SceneError(f"{scene.path}: the camera{f' {name!r}' if name else ''} sees no "
                         f"element (at {cam.center.tolist()}, looking along {cam.z.tolist()}): "
                         "check [camera]")
    return seen[seen >= 0]


def _check_view(scene, rc, cam, name: str, seen: np.ndarray) -> None:
    """Another camera of the scene (a [[camera]] entry): one that sees only the backs of
    one-sided elements would make a black image: an OrientationError naming it."""
    from radiosity.scene.orientation import OrientationError, facing

    if len(seen) and not facing(scene.elements, seen, cam.center).any():
        e = int(np.bincount(seen).argmax())
        raise OrientationError(
            f"{scene.path}: the camera {name!r} sees only the backs of one-sided elements (most "
            f"on {scene.elements.describe(e)}): its image would be black. Move it ([[camera]] "
            f"{name!r} position), or turn the faces it looks at ({FIX})")


def _hits(rc, cam, subpixel, ys, xs) -> np.ndarray:
    """The element hit by each ray through fine pixels rows ys x columns xs: (k,) int32, -1
    for none."""
    from radiosity.core.camera import pixel_directions

    w = cam.width * subpixel
    d = pixel_directions(cam, subpixel, ys).reshape(len(ys), w, 3)[:, xs].reshape(-1, 3)
    return rc.first_hit(np.asarray(cam.center, np.float64), d)


# ----------------------------------------------------------------------------- orientation

#: The fix every orientation message offers, for the [[mesh]] entry it names (a mesh file
#: given alone: a scene file that names it with the same keys).
FIX = "set `orient = \"inward\"` (flips its faces) or `two_sided = true` on its [[mesh]] entry"


def check_orientation(scene, caster, seen: np.ndarray) -> dict:
    """Faces that point the wrong way for the camera or the lights, before any heavy work
    (scene/orientation.py has the facts): a mesh whose one-sided faces enclose the camera with
    their normals out; a camera that sees only backs of one-sided elements; light that reaches
    no element. Each is an OrientationError (one line naming the mesh and the fix) when the
    image would be black or the mesh is seen from inside out; an emitter whose light reaches
    nothing while others light the scene is a warning. caster: a RayCaster of the scene's
    elements; seen (k,) int: the elements hit by a grid of camera rays (none -1).

    Returns {"camera_rays", "camera_lit": rays that see a lit side, "emitters": [{source,
    material, rays, reached, backs, escaped}]}."""
    from radiosity.scene.emitters import AreaEmitters
    from radiosity.scene.meshscene import DOCS, is_mesh_path
    from radiosity.scene.orientation import (OrientationError, emitter_reach, facing,
                                             outward_enclosures)

    el, cam = scene.elements, scene.camera
    where = scene.path
    bare = bool(where) and is_mesh_path(where)  # a mesh file alone: no [[mesh]] entry to edit
    fix = (f"write a scene.toml with [[mesh]] path = \"{os.path.basename(where)}\" and "
            f"orient = \"inward\" (or two_sided = true) (see {DOCS})") if bare else FIX

    def mesh(src: int) -> str:
        """The mesh file as its [[mesh]] entry names it (relative to the scene file)."""
        if bare:
            return os.path.basename(where)
        fn = el.sources[src] if el.sources else "?"
        rel = os.path.relpath(fn, os.path.dirname(where)) if where else fn
        return f"{fn if rel.startswith('..') else rel} ([[mesh]] {src + 1})"

    for enc in outward_enclosures(el, cam.center):
        closed = "closed (watertight)" if enc.watertight else "nearly closed"
        raise OrientationError(
            f"{where}: the camera is inside {mesh(enc.source)}, a {closed} mesh whose normals "
            f"point outward (winding number {enc.winding:+.2f} at the camera), and sees only "
            f"the black backs of its faces. If it is the room, {fix}; if it is a solid (a wall, "
            f"furniture), move the camera out of it")
    lit = facing(el, seen, cam.center)
    if len(seen) and not lit.any():
        e = int(np.bincount(seen).argmax())
        raise OrientationError(
            f"{where}: the camera sees only the backs of one-sided elements ({len(seen)} of "
            f"{len(seen)} camera rays, most on {el.describe(e)}): the image would be black. Is "
            f"the camera inside a wall or outside a closed room? Move it ([camera] position), "
            f"or for {mesh(int(el.source[e]))} {fix}")
    emitters = emitter_reach(el, caster)
    dark = [g for g in emitters if g.reached == 0]
    if emitters and len(dark) == len(emitters) and not _luminaires(el):
        sees_light = bool((lit & AreaEmitters(el).emitting()[seen]).any())
        g = max(dark, key=lambda g: g.elements)
        what = (f"{g.backs} of {g.rays} of its rays meet the backs of one-sided elements, "
                f"{g.escaped} meet nothing")
        if not sees_light:
            raise OrientationError(
                f"{where}: no emitter's light reaches any element (material "
                f"'{el.material_names[g.material]}' of {mesh(g.source)}: {what}) and the camera "
                f"sees no emitter: the image would be black. Is the lamp outside the room or "
                f"facing away? Move or turn it (its front is counter-clockwise), or for the "
                f"mesh it faces, {fix}")
    # a scene of emitters alone (a geometry check) has nothing to light: nothing to say
    others = bool((~AreaEmitters(el).emitting()).any())
    for g in dark if others else [g for g in dark if g.backs]:
        warnings.warn(f"{where}: the light of material '{el.material_names[g.material]}' of "
                      f"{mesh(g.source)} reaches no element ({g.backs} of {g.rays} rays meet "
                      f"the backs of one-sided elements, {g.escaped} meet nothing): is the lamp "
                      "outside the room or facing away?", stacklevel=3)
    return {"camera_rays": int(len(seen)), "camera_lit": int(lit.sum()),
            "emitters": [{"source": g.source, "material": el.material_names[g.material],
                          "rays": g.rays, "reached": g.reached, "backs": g.backs,
                          "escaped": g.escaped} for g in emitters]}


def _luminaires(elements) -> int:
    """How many [[luminaire]] point sources light the scene (scene/luminaires.py)."""
    from radiosity.scene.luminaires import luminaires_of

    return len(luminaires_of(elements))
