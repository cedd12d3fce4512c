"""Scene files (TOML), or a bare mesh file (scene/meshscene.py) -> original elements,
materials and camera (`load_scene`).

The mesh files a scene names are read by formats.load's readers and validated by scene.meshes
(their names re-exported here). Every problem with user
input raises `SceneError` naming the file and the face, material or option, so the CLI can print
one clear line.
"""

from __future__ import annotations

import math
import os
import re
import tomllib

import numpy as np

from radiosity.errors import SceneError
from radiosity.core.geometry import polygon_properties
from radiosity.core.bundles import Camera, Elements, Scene
from radiosity.core.tolerances import TOL
from radiosity.scene.emitters import area_emission
from radiosity.scene.orientation import orient_mesh
from radiosity.formats.load import MESH_FORMATS, load_mesh
from radiosity.formats.raw import warn
from radiosity.scene.meshes import MAX_COORD, polygons_from_raw
from radiosity.scene.meshscene import (DEFAULT_RESOLUTION, DOCS as MESH_DOCS, camera_toml,
                                       default_camera, is_mesh_path, require_emitter)
from radiosity.settings import Settings

__all__ = ["MAX_RESOLUTION", "DEFAULT_REFLECTANCE", "parse_resolution", "parse_camera",
           "parse_cameras", "load_scene"]

#: Largest camera resolution a side (a raster of 65536^2 int32 is 16 GiB already).
MAX_RESOLUTION = 65536
DEFAULT_REFLECTANCE = (0.5, 0.5, 0.5)

_MESH_KEYS = {"path", "material", "two_sided", "orient"}
_MATERIAL_KEYS = {"reflectance", "emission", "two_sided", "back_reflectance", "back_emission"}
_LOOKAT_KEYS = {"position", "look_at", "up", "fov_y", "resolution"}
_SEED_KEYS = {"center", "x", "y", "z", "focal_distance", "resolution"}
_TOP_KEYS = {"name", "description", "mesh", "material", "camera", "validation"}
_TOP_KEYS |= {"luminaire"}  # [[luminaire]] tables: scene/luminaires.py
_VALIDATION_KEYS = {"form_factor", "from", "to", "radiance", "kind", "emitter", "receiver"}
# radiosity heat's keys (viewfactors/thermal.py): a render ignores them, so that one scene
# file serves both (docs/src/reference/scenes.md#heat)
_HEAT_KEYS = {"emissivity", "temperature_K", "heat_flux_W_m2"}
_MESH_KEYS |= _HEAT_KEYS
_MATERIAL_KEYS |= _HEAT_KEYS
_TOP_KEYS |= {"environment", "heat"}


# ----------------------------------------------------------------------------- scene file

def _vec(val, what: str, fn: str, n: int = 3) -> np.ndarray:
    try:
        a = np.asarray(val, float)
    except (TypeError, ValueError):
        raise SceneError(f"{fn}: {what} must be a list of {n} numbers, got {val!r}") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise SceneError(f"{fn}: {what} must be a list of {n} finite numbers, got {val!r}")
    if np.abs(a).max(initial=0.0) > MAX_COORD:
        raise SceneError(f"{fn}: {what} {val!r} is beyond {MAX_COORD:g}: rescale the scene")
    return a


def _pixels(v) -> int:
    """A whole number of pixels: an integer, an integral float (64.0) or its text; anything
    else (64.5, true, "64.5") raises ValueError instead of being truncated."""
    if isinstance(v, bool):
        raise ValueError
    if isinstance(v, str):
        return int(v.strip())
    if isinstance(v, float):
        if not v.is_integer():
            raise ValueError
        return int(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    raise TypeError


def read_toml(path: str, what: str = "", error=SceneError,
              unreadable: str = "{name}: {why}") -> dict:
    """The TOML document at `path`, or one line (`error`) naming the file (after `what`, e.g.
    the flag that gave it) and what is wrong with it."""
    name = f"{what} {path}" if what else path
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{name}: not valid TOML: {e}") from None
    except UnicodeDecodeError as e:
        raise error(f"{name}: not valid TOML: not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise error(unreadable.format(name=name, path=path, why=e.strerror)) from None


def parse_resolution(val, where: str) -> tuple[int, int]:
    """`N`, `[W, H]` or `"WxH"` -> (W, H), both positive whole numbers (`where` names the
    option or the file in the error)."""
    try:
        if isinstance(val, str):
            parts = val.lower().split("x")
            if len(parts) > 2:
                raise ValueError
            w, h = (_pixels(parts[0]), _pixels(parts[-1]))
        elif isinstance(val, (list, tuple)):
            if len(val) != 2:
                raise ValueError
            w, h = _pixels(val[0]), _pixels(val[1])
        else:
            w = h = _pixels(val)
    except (TypeError, ValueError, OverflowError):
        raise SceneError(f"{where}: resolution must be a whole number of pixels: N, [W, H] or "
                         f"'WxH', got {val!r}") from None
    if w <= 0 or h <= 0:
        raise SceneError(f"{where}: resolution must be positive, got {w}x{h}")
    if max(w, h) > MAX_RESOLUTION:
        raise SceneError(f"{where}: resolution {w}x{h} is beyond {MAX_RESOLUTION} pixels a side")
    return w, h


def parse_cameras(cams, fn: str, resolution=None) -> tuple[Camera, tuple]:
    """A scene's cameras: one [camera] table, or [[camera]] entries, each with an optional
    `name` (letters, digits, - and _; default camera-N). Returns the first camera (the run's
    own image) and the others as (name, Camera) pairs; `resolution` applies to all of them."""
    if not isinstance(cams, list):
        return parse_camera(cams, fn, resolution), ()
    if not cams:
        raise SceneError(f"{fn}: [[camera]] has no entries")
    out, seen = [], set()
    for i, cam in enumerate(cams):
        if not isinstance(cam, dict):
            raise SceneError(f"{fn}: [[camera]] {i + 1} must be a table")
        name = cam.get("name", f"camera-{i + 1}")
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_\-]+", name):
            raise SceneError(f"{fn}: [[camera]] {i + 1} name {name!r}: use letters, digits, - and _")
        if name in seen:
            raise SceneError(f"{fn}: [[camera]] {i + 1}: the name {name!r} is used twice")
        seen.add(name)
        table = {k: v for k, v in cam.items() if k != "name"}
        out.append((name, parse_camera(table, f"{fn} [[camera]] {name!r}", resolution)))
    return out[0][1], tuple(out[1:])


def parse_camera(cam: dict, fn: str, resolution=None) -> Camera:
    """The look-at form (position, look_at, up, fov_y) or the seed's (center, x, y, z, focal_distance)."""
    if not isinstance(cam, dict):
        raise SceneError(f"{fn}: [camera] is missing; give position/look_at/up/fov_y/resolution "
                         "or center/x/y/z/focal_distance/resolution")
    keys = set(cam)
    res = parse_resolution(resolution if resolution is not None else cam.get("resolution"),
                           f"{fn} [camera]" if resolution is None else "--resolution")
    if "position" in keys:
        unknown = keys - _LOOKAT_KEYS
        if unknown:
            raise SceneError(f"{fn}: unknown [camera] key(s) {sorted(unknown)}; the look-at form "
                             f"takes {sorted(_LOOKAT_KEYS)}")
        for k in ("look_at", "fov_y"):
            if k not in cam:
                raise SceneError(f"{fn}: [camera] needs '{k}' with 'position'")
        pos = _vec(cam["position"], "camera.position", fn)
        at = _vec(cam["look_at"], "camera.look_at", fn)
        up = _vec(cam.get("up", [0, 1, 0]), "camera.up", fn)
        fov = _num(cam["fov_y"], "camera.fov_y", fn)
        if not 0 < fov < 180:
            raise SceneError(f"{fn}: camera.fov_y must be in (0, 180) degrees, got {fov}")
        z = at - pos
        if not np.linalg.norm(z) > TOL.tiny_length:
            raise SceneError(f"{fn}: camera.look_at equals camera.position")
        z /= np.linalg.norm(z)
        if not np.linalg.norm(up) > TOL.tiny_length:
            raise SceneError(f"{fn}: camera.up must be a non-zero vector, got {cam.get('up')!r}")
        up = up / np.linalg.norm(up)
        x = np.cross(z, up)
        if np.linalg.norm(x) < 1e-9:
            raise SceneError(f"{fn}: camera.up is parallel to the viewing direction")
        x /= np.linalg.norm(x)
        y = np.cross(x, z)
        half_h = math.tan(math.radians(fov) / 2)
        return Camera(pos, x, y, z, 1.0, res[0], res[1], half_h * res[0] / res[1], half_h)
    if "center" in keys:
        unknown = keys - _SEED_KEYS
        if unknown:
            raise SceneError(f"{fn}: unknown [camera] key(s) {sorted(unknown)}; the seed's form "
                             f"takes {sorted(_SEED_KEYS)}")
        for k in ("x", "y", "z", "focal_distance"):
            if k not in cam:
                raise SceneError(f"{fn}: [camera] needs '{k}' with 'center'")
        r = _vec(cam["center"], "camera.center", fn)
        x, y, z = (_vec(cam[k], f"camera.{k}", fn) for k in "xyz")
        B = np.stack([x, y, z])
        if not np.allclose(B @ B.T, np.eye(3), atol=1e-6):
            raise SceneError(f"{fn}: camera basis x, y, z is not orthonormal (x.y={x @ y:.3g}, "
                             f"y.z={y @ z:.3g}, x.z={x @ z:.3g}, |x|={np.linalg.norm(x):.6g}, "
                             f"|y|={np.linalg.norm(y):.6g}, |z|={np.linalg.norm(z):.6g})")
        d = _num(cam["focal_distance"], "camera.focal_distance", fn)
        if not d > 0:
            raise SceneError(f"{fn}: camera.focal_distance must be positive, got {d}")
        return Camera(r, x, y, z, d, res[0], res[1], 1.0, 1.0)
    raise SceneError(f"{fn}: [camera] needs either 'position' (look-at form) or 'center' (seed's form)")


def _num(val, what: str, fn: str) -> float:
    """A finite number within MAX_COORD, or a SceneError naming the key."""
    try:
        v = float(val)
    except (TypeError, ValueError):
        raise SceneError(f"{fn}: {what} must be a number, got {val!r}") from None
    if not math.isfinite(v) or abs(v) > MAX_COORD:
        raise SceneError(f"{fn}: {what} must be a finite number below {MAX_COORD:g}, got {val!r}")
    return v


def _rgb(val, what, fn) -> np.ndarray:
    return _vec(val, what, fn, 3)


def _scene_document(path: str) -> tuple[str, dict, bool]:
    """The scene file's absolute path, its TOML document (a bare mesh file: one [[mesh]] entry,
    nothing overridden) and whether it is a bare mesh file."""
    path = os.path.abspath(path)
    if os.path.isdir(path) and os.path.exists(os.path.join(path, "scene.toml")):
        path = os.path.join(path, "scene.toml")
    if not os.path.exists(path):
        raise SceneError(f"scene file not found: {path}")
    mesh_scene = is_mesh_path(path)
    if mesh_scene:  # one [[mesh]] entry, nothing overridden, the camera chosen by load_scene
        stem, _ = os.path.splitext(os.path.basename(path))
        doc = {"name": stem, "mesh": [{"path": os.path.basename(path), "orient": "auto"}]}
    else:
        doc = read_toml(path, unreadable="cannot read scene file {path}: {why}")
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        raise SceneError(f"{path}: unknown key(s) {sorted(unknown)}; a scene file has {sorted(_TOP_KEYS)}")
    return path, doc, mesh_scene


def _read_meshes(meshes: list, path: str, s: Settings):
    """The [[mesh]] entries' polygons, in entry order: verts (n, 4, 3), nverts (n,), face (n,),
    source (n,) int32 (the entry), the material name per polygon, each polygon's two_sided
    default, the materials the files give (name -> (file, properties), the first file's
    wins) and the files' paths."""
    base = os.path.dirname(path)
    all_v, all_n, all_f, all_src, mat_of, two_default = [], [], [], [], [], []
    file_mats: dict = {}
    sources = []
    for mi, m in enumerate(meshes):
        unknown = set(m) - _MESH_KEYS
        if unknown:
            raise SceneError(f"{path}: [[mesh]] {mi + 1} has unknown key(s) {sorted(unknown)}; "
                             f"allowed: {sorted(_MESH_KEYS)}")
        if "path" not in m:
            raise SceneError(f"{path}: [[mesh]] {mi + 1} has no 'path'")
        fn = os.path.join(base, m["path"])
        raw = load_mesh(fn, m.get("material", "default"))
        for name, props in raw.materials.items():
            file_mats.setdefault(name, (fn, props))
        v, n, f, mats = polygons_from_raw(raw, fn, s)
        # which way the faces point: as in the file, or fixed (scene/orientation.py, ORIENTS)
        v, turned = orient_mesh(v, n, m.get("orient", "as-is"), f"{path}: [[mesh]] {mi + 1}")
        if m.get("orient") == "auto" and any(turned.turned):  # said: the user asked for nothing
            warn(turned.describe(os.path.basename(fn) if is_mesh_path(path)
                                 else f"{path}: [[mesh]] {mi + 1}"))
        sources.append(fn)
        all_v.append(v)
        all_n.append(n)
        all_f.append(f)
        all_src.append(np.full(len(n), mi, np.int32))
        mat_of.extend(mats)
        two_default.extend([bool(m.get("two_sided", False))] * len(n))
    verts = np.concatenate(all_v)
    if len(verts) == 0:
        raise SceneError(f"{path}: the meshes hold no faces: the scene is empty")
    return (verts, np.concatenate(all_n), np.concatenate(all_f), np.concatenate(all_src), mat_of,
            two_default, file_mats, sources)


def _materials(names: list, file_mats: dict, overrides: dict, path: str, mesh_scene: bool):
    """Per material (in `names` order): reflectance and emission (nm, 2, 3) [front, back], its
    two_sided and whether the file or the scene set that (nm,) bool; the scene's
    [material.NAME] tables override what the mesh files give."""
    nm = len(names)
    refl = np.zeros((nm, 2, 3))
    emis = np.zeros((nm, 2, 3))
    mat_two = np.zeros(nm, bool)
    mat_two_set = np.zeros(nm, bool)
    for i, name in enumerate(names):
        src, props = file_mats.get(name, (path, {}))
        over = overrides.get(name, {})
        if not isinstance(over, dict):
            raise SceneError(f"{path}: [material.{name}] must be a table")
        unknown = set(over) - _MATERIAL_KEYS
        if unknown:
            raise SceneError(f"{path}: [material.{name}] has unknown key(s) {sorted(unknown)}; "
                             f"allowed: {sorted(_MATERIAL_KEYS)}")
        where = path if over else src
        r = _rgb(over.get("reflectance", props.get("reflectance", DEFAULT_REFLECTANCE)),
                 f"material '{name}' reflectance", where)
        e = _rgb(over.get("emission", props.get("emission", [0, 0, 0])), f"material '{name}' emission", where)
        rb = _rgb(over.get("back_reflectance", r), f"material '{name}' back_reflectance", where)
        eb = _rgb(over.get("back_emission", e), f"material '{name}' back_emission", where)
        for what, val in (("reflectance", r), ("back_reflectance", rb)):
            if np.any(val < 0) or np.any(val >= 1):
                raise SceneError(f"{where}: material '{name}' {what} {val.tolist()} is outside [0, 1) "
                                 "(a reflectance of 1 or more creates energy)"
                                 + (f": lower it in the mesh, or write a scene.toml that sets "
                                    f"[material.{name}] reflectance (see {MESH_DOCS})"
                                    if mesh_scene else ""))
        for what, val in (("emission", e), ("back_emission", eb)):
            if np.any(val < 0):
                raise SceneError(f"{where}: material '{name}' {what} {val.tolist()} is negative")
        refl[i] = r, rb
        emis[i] = e, eb
        if "two_sided" in over or "two_sided" in props:
            mat_two[i] = bool(over.get("two_sided", props.get("two_sided", False)))
            mat_two_set[i] = True
    return refl, emis, mat_two, mat_two_set


def _validation(doc: dict, path: str, names: list) -> dict:
    """The scene's [validation] table, its keys and the materials it names checked."""
    validation = doc.get("validation", {})
    unknown = set(validation) - _VALIDATION_KEYS
    if unknown:
        raise SceneError(f"{path}: [validation] has unknown key(s) {sorted(unknown)}; allowed: "
                         f"{sorted(_VALIDATION_KEYS)}")
    for k in ("from", "to", "emitter", "receiver"):
        if k in validation and validation[k] not in names:
            raise SceneError(f"{path}: [validation] {k} = {validation[k]!r} is not a material of "
                             f"the scene ({names})")
    return dict(validation)


def _with_luminaires(elements: Elements, doc: dict, path: str, s: Settings) -> Elements:
    """The elements with the scene's [[luminaire]] tables (scene/luminaires.py), each checked to
    be outside every wall and closed solid (the same elements when it has none)."""
    import dataclasses

    from radiosity.scene.luminaires import check_placement, parse_luminaires, scene_up
    from radiosity.tracing.rays import caster_of

    lums = parse_luminaires(doc.get("luminaire"), path, scene_up(doc))
    if not lums:
        return elements
    check_placement(lums, elements, caster_of(elements.verts, elements.nverts,
                                              float(s.rays.offset)), path)
    return dataclasses.replace(elements, luminaires=lums)


def load_scene(path: str, resolution=None, *, settings: Settings) -> Scene:
    """Read a scene TOML (or a folder holding scene.toml) into a Scene: its meshes, material
    overrides and camera. A bare mesh file (any of formats.load.MESH_FORMATS) is a scene too:
    its own materials, which must include an emitter, and a default camera
    (scene/meshscene.py; the Scene's `chosen` says which, as a [camera] table to copy).
    settings: the run's settings.Settings (its scene.* tolerances and the ray offset,
    rays.epsilon)."""
    s = settings
    path, doc, mesh_scene = _scene_document(path)
    meshes = doc.get("mesh", [])
    if not isinstance(meshes, list) or not meshes:
        raise SceneError(f"{path}: no [[mesh]] entries: the scene is empty")
    overrides = doc.get("material", {})
    verts, nverts, face, source, mat_of, two_default, file_mats, sources = \
        _read_meshes(meshes, path, s)
    names = sorted(set(mat_of))
    for name in overrides:
        if name not in names:
            warn(f"{path}: [material.{name}] matches no face (materials in the meshes: {names})")
    index = {name: i for i, name in enumerate(names)}
    material = np.array([index[m] for m in mat_of], np.int32)

    refl, emis, mat_two, mat_two_set = _materials(names, file_mats, overrides, path, mesh_scene)
    two_sided = np.where(mat_two_set[material], mat_two[material], np.array(two_default, bool))
    reflectance = refl[material].copy()
    reflectance[~two_sided, 1] = 0.0
    emission = area_emission(emis, material, two_sided)

    area, normal, center = polygon_properties(verts, nverts)
    elements = Elements(verts=verts, nverts=nverts, normal=normal, center=center, area=area,
                        reflectance=reflectance, emission=emission, two_sided=two_sided,
                        material=material, source=source, face=face,
                        material_names=tuple(names), sources=tuple(sources))
    elements = _with_luminaires(elements, doc, path, s)
    chosen = ""
    views = ()
    if mesh_scene:
        require_emitter(elements, path)
        res = (DEFAULT_RESOLUTION,) * 2 if resolution is None else \
            parse_resolution(resolution, "resolution")
        camera, table, why = default_camera(elements, res, float(s.rays.offset), path,
                                            parse_camera)
        chosen = (f"camera: {os.path.basename(path)} has none, so {why}; to change it, put this "
                  f"in a scene file (see {MESH_DOCS}):\n{camera_toml(table)}")
    else:
        camera, views = parse_cameras(doc.get("camera"), path, resolution)
    name = doc.get("name", os.path.basename(os.path.dirname(path)))
    return Scene(name=str(name), path=path, elements=elements, camera=camera,
                 validation=_validation(doc, path, names), chosen=chosen, views=views,
                 grids=_grids(doc, path, elements, s))


# calculation grids (scene/grids.py): [[grid]] tables and their default maintenance factor
_TOP_KEYS |= {"grid", "maintenance_factor"}


def _grids(doc: dict, path: str, elements, s: Settings) -> tuple:
    """The scene's [[grid]] tables (scene/grids.py), each checked inside the model."""
    from radiosity.scene.grids import check_grids, parse_grids
    from radiosity.tracing.rays import caster_of

    grids = parse_grids(doc, path)
    if grids:
        check_grids(grids, elements, caster_of(elements.verts, elements.nverts,
                                               float(s.rays.offset)), path)
    return grids
