"""A bare mesh file as a scene (`radiosity render room.glb`): its materials as the file gives
them (scene.meshes), a default camera that frames it, printed as a `[camera]` table to copy
into a scene file, and a refusal in one line when it has no emitter.

The default camera (`default_camera`), with +y up (glTF's convention; OBJ exporters mostly
follow it):
* inside, if the scene is a room: from 5 % of the way along the longest horizontal axis of the
  bounding box (x or z), at the box's centre in the other two, looking along that axis at the
  far wall, with the vertical field of view (30 to 100 degrees) at which the far wall fills
  the middle 1 / INSIDE_MARGIN of the image. The scene counts as a room when at least
  ROOM_HITS of ENCLOSURE_RAYS rays from that point, in all directions, hit a surface (a room
  with a window or a door open is still a room: the rest leave through its openings), and at
  least ROOM_FRONT of those hit one from its front (or a two-sided one): the camera is not
  inside a solid or behind the room's walls;
* otherwise outside, looking at the centre of the bounding box from 20 degrees above the
  horizontal, on the side (+z, -z, +x or -x) from which a coarse image of SCORE_PIXELS^2 rays
  sees the most surfaces from their front (ties: in that order), at the distance where the
  box's bounding sphere just fills the 40-degree vertical field of view (the horizontal one
  when the image is taller than wide).
The resolution is DEFAULT_RESOLUTION unless --resolution says otherwise.
"""

from __future__ import annotations

import math
import os

import numpy as np

from radiosity.core.bundles import Camera, Elements
from radiosity.errors import SceneError

#: Camera resolution of a mesh without a scene file, a side: the built-in scenes' (the Quick
#: start renders the Cornell box at 128^2).
DEFAULT_RESOLUTION = 128
#: The page that explains meshes as scenes (named by the refusals).
DOCS = "docs/src/how-to/meshes-as-scenes.md"
ENCLOSURE_RAYS = 256
#: Shares of those rays that make a room: hitting a surface (openings let the rest out: the 2 x
#: 1.2 m window of tests/office.py 3 of 256, a whole wall missing from a 4 x 2.5 x 3 m room 31) ...
ROOM_HITS = 0.9
#: ... and of the hits, seeing its lit side
ROOM_FRONT = 0.9
#: Inside, the far wall fills the middle 1 / INSIDE_MARGIN of the image (the side walls, floor
#: and ceiling show around it)
INSIDE_MARGIN = 1.6
SCORE_PIXELS = 24
OUTSIDE_FOV = 40.0
ELEVATION = 20.0
#: What the one-line refusal says to add, by format: where a mesh file keeps emission.
EMISSION_HOWTO = {
    ".glb": "give one material an emissiveFactor (with KHR_materials_emissive_strength for "
            "radiance above 1)",
    ".gltf": "give one material an emissiveFactor (with KHR_materials_emissive_strength for "
             "radiance above 1)",
    ".obj": "give one material of its MTL file a Ke line (emitted radiance, e.g. Ke 10 10 10)",
    ".ply": "a PLY file holds no emission",
    ".stl": "an STL file holds no emission",
}


def is_mesh_path(path: str) -> bool:
    """Whether `path` names a mesh file (formats.load.MESH_FORMATS) rather than a scene file."""
    from radiosity.formats.load import MESH_FORMATS

    return os.path.splitext(path)[1].lower() in MESH_FORMATS and not os.path.isdir(path)


def require_emitter(el: Elements, path: str) -> None:
    """A mesh scene must emit light: SceneError in one line saying what to add otherwise."""
    from radiosity.scene.emitters import AreaEmitters

    if AreaEmitters(el).any():
        return
    ext = os.path.splitext(path)[1].lower()
    name = os.path.basename(path)
    raise SceneError(f"{name} has no emissive material ({', '.join(el.material_names)}): "
                     f"{EMISSION_HOWTO.get(ext, 'give one material an emission')}, or write a "
                     f"scene.toml with [[mesh]] path = \"{name}\" and [material.NAME] emission = "
                     f"[r, g, b] (see {DOCS})")


def _fibonacci(n: int) -> np.ndarray:
    """n unit directions spread evenly over the sphere (n, 3)."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    r = np.sqrt(np.maximum(0.0, 1 - z * z))
    phi = k * math.pi * (3 - math.sqrt(5))
    return np.stack([r * np.cos(phi), z, r * np.sin(phi)], axis=1)


def _front(el: Elements, hit: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Rays (d (k, 3)) whose hit element (hit (k,), -1: none) faces them or is two-sided."""
    ok = hit >= 0
    out = np.zeros(len(hit), bool)
    h = hit[ok]
    out[ok] = (np.einsum("ij,ij->i", el.normal[h], d[ok]) < 0) | el.two_sided[h]
    return out


def _num(x: float) -> float:
    """x to 6 significant digits (the printed table is the camera used, to the bit)."""
    return float(f"{x:.6g}") + 0.0


def _table(position, look_at, fov_y: float, resolution) -> dict:
    return {"position": [_num(v) for v in position], "look_at": [_num(v) for v in look_at],
            "up": [0.0, 1.0, 0.0], "fov_y": _num(fov_y), "resolution": list(resolution)}


def _score(rc, el: Elements, cam: Camera) -> int:
    """Rays of a coarse SCORE_PIXELS^2 image of `cam` that see a surface from its front."""
    from radiosity.core.camera import pixel_directions

    c = cam.with_resolution(SCORE_PIXELS, SCORE_PIXELS)
    d = pixel_directions(c, 1, np.arange(SCORE_PIXELS)).reshape(-1, 3)
    hit = rc.first_hit(np.asarray(c.center, np.float64), np.ascontiguousarray(d))
    return int(_front(el, hit, d).sum())


def default_camera(el: Elements, resolution: tuple[int, int], ray_offset: float, where: str,
                   parse_camera):
    """The default camera of a mesh scene (the rule in the module docstring): (Camera, its
    [camera] table as a dict, why in a few words). ray_offset: radiosity.rays.epsilon; where: the
    file, for errors; parse_camera: scene.load's reader of [camera] tables (passed in: the
    camera used is the table read as a scene file's would be, so the printed table gives the
    same camera to the bit)."""
    from radiosity.tracing.rays import RayCaster

    pts = el.verts.reshape(-1, 3)  # a triangle's slot 3 repeats its vertex 2
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    size = np.maximum(hi - lo, 1e-12 * max(1.0, float(np.abs(pts).max())))
    center = (lo + hi) / 2
    w, h = resolution
    aspect = w / h
    rc = RayCaster(el.verts, el.nverts, float(ray_offset))

    # inside: near one end of the longest horizontal axis, looking at the far wall
    a = 0 if size[0] >= size[2] else 2
    b = 2 - a
    pos = center.copy()
    pos[a] = lo[a] + 0.05 * size[a]
    look = center.copy()
    look[a] = hi[a]
    dist = hi[a] - pos[a]
    half = INSIDE_MARGIN * max(size[1] / 2, size[b] / 2 / aspect)
    fov = min(100.0, max(30.0, 2 * math.degrees(math.atan(half / dist))))
    d = _fibonacci(ENCLOSURE_RAYS)
    hit = rc.first_hit(pos, d)
    met = int((hit >= 0).sum())
    if met >= ROOM_HITS * len(d) and _front(el, hit, d).sum() >= ROOM_FRONT * met:
        table = _table(pos, look, fov, (w, h))
        axis = "xz"[a // 2]
        what = "a closed room" if met == len(d) else (
            f"a room with openings ({len(d) - met} of {len(d)} rays from the camera leave "
            "through them)")
        return (parse_camera(table, where), table,
                f"inside: {what}, looking along +{axis} (its longest horizontal axis)")

    # outside: the side that sees the most surfaces from their front
    front = int(_front(el, hit, d).sum())
    why = (f"{len(d) - met} of {len(d)} rays from inside leave it" if met < ROOM_HITS * len(d)
           else f"{met - front} of {met} rays from inside meet backs of faces")
    r = float(np.linalg.norm(size)) / 2
    half_v = math.radians(OUTSIDE_FOV) / 2
    half_h = math.atan(math.tan(half_v) * aspect)
    dist = r / math.sin(min(half_v, half_h))
    best = None
    e = math.radians(ELEVATION)
    for name, v in (("+z", (0, 0, 1)), ("-z", (0, 0, -1)), ("+x", (1, 0, 0)), ("-x", (-1, 0, 0))):
        u = np.array(v, float) * math.cos(e) + np.array([0.0, math.sin(e), 0.0])
        table = _table(center + dist * u, center, OUTSIDE_FOV, (w, h))
        cam = parse_camera(table, where)
        score = _score(rc, el, cam)
        if best is None or score > best[0]:
            best = (score, cam, table, name)
    _, cam, table, name = best
    return (cam, table, f"outside: not a room ({why}); from the {name} side, which sees the most "
                        "surfaces from their front")


def camera_toml(table: dict) -> str:
    """The [camera] table as TOML text (parse_camera reads it back to the same camera)."""

    def num(x):
        return repr(int(x)) if isinstance(x, int) else repr(float(x))

    lines = ["[camera]"]
    for k in ("position", "look_at", "up", "fov_y", "resolution"):
        v = table[k]
        lines.append(f"{k} = " + (f"[{', '.join(num(x) for x in v)}]" if isinstance(v, list)
                                  else num(v)))
    return "\n".join(lines)
