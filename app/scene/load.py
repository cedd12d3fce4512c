"""Scene files (TOML) and meshes (OBJ+MTL, glTF/GLB, PLY) -> original elements and camera.

Every problem with user input raises `SceneError` naming the file and the face, material or
option, so the CLI can print one clear line. Quads stay quads: an OBJ face with four vertices
is one element, and two coplanar triangles that share a diagonal and form a parallelogram are
merged back into one (seed §3.2 splits rectangles across their longer sides).
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import tomllib
import warnings
from dataclasses import dataclass, field

import numpy as np

from radiosity import config
from radiosity.errors import SceneError
from radiosity.core.geometry import diameter, polygon_properties
from radiosity.core.bundles import Camera, Elements, Scene

MESH_FORMATS = (".obj", ".gltf", ".glb", ".ply")
#: Largest vertex coordinate accepted: fourth powers of lengths (|cross product|^2, r^4 in
#: the sampled kernels) must stay finite in float64 (1e75^4 = 1e300 < 1.8e308).
MAX_COORD = 1e75
#: Largest camera resolution a side (a raster of 65536^2 int32 is 16 GiB already).
MAX_RESOLUTION = 65536
#: Smallest length taken for a direction (camera vectors): below it squares underflow to 0.
TINY = 1e-150
_KEYWORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_GARBLED = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ufffd]")
DEFAULT_REFLECTANCE = (0.5, 0.5, 0.5)

_MESH_KEYS = {"path", "material", "two_sided"}
_MATERIAL_KEYS = {"reflectance", "emission", "two_sided", "back_reflectance", "back_emission"}
_LOOKAT_KEYS = {"position", "look_at", "up", "fov_y", "resolution"}
_SEED_KEYS = {"center", "x", "y", "z", "focal_distance", "resolution"}
_TOP_KEYS = {"name", "description", "mesh", "material", "camera", "validation"}
_VALIDATION_KEYS = {"form_factor", "from", "to", "radiance", "kind", "emitter", "receiver"}


class SceneWarning(UserWarning):
    """Input the loader repaired (non-planar or non-convex quad, n-gon): said, not silent."""


@dataclass
class RawMesh:
    """What a mesh loader returns before validation.

    vertices : (V, 3) float64; faces : list of vertex-index lists (3 or more each);
    face_material : material name per face; materials : name -> dict of file-given properties.
    """

    vertices: np.ndarray
    faces: list
    face_material: list
    materials: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- loaders

def _floats(parts, fn, lineno, n=3):
    try:
        vals = [float(p) for p in parts[:n]]
    except ValueError:
        raise SceneError(f"{fn}:{lineno}: expected {n} numbers, got {' '.join(parts)!r}") from None
    if len(vals) < n:
        raise SceneError(f"{fn}:{lineno}: expected {n} numbers, got {' '.join(parts)!r}")
    return vals


def _check_line(fn: str, lineno: int, line: str, key: str, kind: str) -> None:
    """A text line of an OBJ or MTL file starts with a keyword and holds no binary bytes
    (unknown keywords are skipped, as other readers do; garbage is not)."""
    if _GARBLED.search(line) or not _KEYWORD.match(key):
        raise SceneError(f"{fn} could not be parsed as {kind} (line {lineno}): "
                         f"{line.strip()[:40]!r} is not an {kind} statement")


def _read_text(fn: str) -> list[str]:
    try:
        with open(fn, encoding="utf-8", errors="replace") as f:
            return f.read().splitlines()
    except FileNotFoundError:
        raise SceneError(f"mesh file not found: {fn}") from None
    except OSError as e:
        raise SceneError(f"cannot read mesh file {fn}: {e.strerror}") from None


def _load_mtl(fn: str) -> dict:
    mats: dict = {}
    cur = None
    for lineno, line in enumerate(_read_text(fn), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key, args = parts[0], parts[1:]
        _check_line(fn, lineno, line.split("#", 1)[0], key, "MTL")
        if key == "newmtl":
            cur = " ".join(args)
            mats[cur] = {}
        elif cur is not None and key == "Kd":
            mats[cur]["reflectance"] = _floats(args, fn, lineno)
        elif cur is not None and key == "Ke":
            mats[cur]["emission"] = _floats(args, fn, lineno)
    return mats


def load_obj(fn: str) -> RawMesh:
    """Minimal OBJ reader (v, f, usemtl, mtllib) that keeps quads as quads.

    trimesh triangulates on load, which would lose the seed's quad elements.
    """
    verts, faces, fmat, mats = [], [], [], {}
    cur = "default"
    base = os.path.dirname(fn)
    for lineno, line in enumerate(_read_text(fn), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key, args = parts[0], parts[1:]
        _check_line(fn, lineno, line.split("#", 1)[0], key, "OBJ")
        if key == "v":
            verts.append(_floats(args, fn, lineno))
        elif key == "f":
            idx = []
            for a in args:
                try:
                    k = int(a.split("/")[0])
                except ValueError:
                    raise SceneError(f"{fn}:{lineno}: bad face index {a!r}") from None
                k = k - 1 if k > 0 else len(verts) + k
                if not 0 <= k < len(verts):
                    raise SceneError(f"{fn}:{lineno}: face refers to vertex {a} that does not exist")
                idx.append(k)
            if len(idx) < 3:
                raise SceneError(f"{fn}:{lineno}: a face needs at least 3 vertices")
            faces.append(idx)
            fmat.append(cur)
        elif key == "usemtl":
            cur = " ".join(args) or "default"
        elif key == "mtllib":
            mfn = os.path.join(base, " ".join(args))
            if not os.path.exists(mfn):
                raise SceneError(f"{fn}:{lineno}: material library not found: {mfn}")
            mats.update(_load_mtl(mfn))
    return RawMesh(np.array(verts, float).reshape(-1, 3), faces, fmat, mats)


def _gltf_json(fn: str) -> dict:
    """The glTF JSON document (for factors trimesh rounds or drops, e.g. emissive strength)."""
    with open(fn, "rb") as f:
        data = f.read()
    if data[:4] == b"glTF":
        n = struct.unpack("<I", data[12:16])[0]
        return json.loads(data[20:20 + n])
    return json.loads(data)


def load_trimesh(fn: str, default_material: str) -> RawMesh:
    """glTF/GLB and PLY through trimesh (node transforms applied)."""
    import trimesh

    try:
        loaded = trimesh.load(fn, force="scene", process=False)
    except Exception as e:  # trimesh raises many types for corrupt files
        raise SceneError(f"cannot read mesh file {fn}: {e}") from None
    gmats = {}
    gltf, gnames = [], []
    if fn.lower().endswith((".gltf", ".glb")):
        try:
            doc = _gltf_json(fn)
        except Exception as e:
            raise SceneError(f"cannot parse glTF JSON of {fn}: {e}") from None
        gltf = doc.get("materials", [])
        gnames = _gltf_material_names(gltf, fn)
        for name, m in zip(gnames, gltf):
            pbr = m.get("pbrMetallicRoughness", {})
            props = {"reflectance": list(pbr.get("baseColorFactor", [1, 1, 1, 1]))[:3]}
            strength = m.get("extensions", {}).get("KHR_materials_emissive_strength", {})
            e = np.asarray(m.get("emissiveFactor", [0, 0, 0]), float) * float(
                strength.get("emissiveStrength", 1.0))
            props["emission"] = e.tolist()
            props["two_sided"] = bool(m.get("doubleSided", False))
            gmats[name] = props
    verts, faces, fmat = [], [], []
    base = 0
    for node in loaded.graph.nodes_geometry:
        transform, gname = loaded.graph[node]
        mesh = loaded.geometry[gname]
        if not hasattr(mesh, "faces"):
            continue
        v = trimesh.transformations.transform_points(np.asarray(mesh.vertices, float), transform)
        name = default_material
        mat = getattr(getattr(mesh, "visual", None), "material", None)
        if gltf and mat is not None:
            idx = _gltf_material_of(mat, gltf, fn)
            if idx is not None:
                name = gnames[idx]
        verts.append(v)
        for f in np.asarray(mesh.faces):
            faces.append([int(k) + base for k in f])
            fmat.append(name)
        base += len(v)
    v = np.concatenate(verts) if verts else np.zeros((0, 3))
    return RawMesh(v, faces, fmat, gmats)


def _gltf_material_names(gltf: list, fn: str) -> list[str]:
    """A distinct name per glTF material (by index): its own name; `unnamed-<i>` for one without
    a name; `<name>#<i>` for a later material that reuses a name with other properties (said,
    with a warning: the TOML overrides materials by these names)."""
    names, first = [], {}
    for i, m in enumerate(gltf):
        name = m.get("name") or f"unnamed-{i}"
        props = {k: v for k, v in m.items() if k != "name"}
        if name in first and first[name] != props:
            new = f"{name}#{i}"
            _warn(f"{fn}: glTF material {i} reuses the name '{name}' with other properties; "
                  f"it is called '{new}' here (override it as [material.\"{new}\"])")
            name = new
        first.setdefault(name, props)
        names.append(name)
    return names


def _gltf_material_of(mat, gltf: list, fn: str) -> int | None:
    """The index of the glTF material trimesh made `mat` (a PBRMaterial) from: the one of that
    name (or of no name), and among several of the same name the one whose factors match
    (trimesh keeps baseColorFactor to 8 bits only). None if no glTF material matches."""
    name = getattr(mat, "name", None) or None
    cands = [i for i, m in enumerate(gltf) if (m.get("name") or None) == name]
    if len(cands) <= 1:
        return cands[0] if cands else None

    def distance(i):
        m = gltf[i]
        pbr = m.get("pbrMetallicRoughness", {})
        want = np.asarray(pbr.get("baseColorFactor", [1, 1, 1, 1]), float)
        got = getattr(mat, "baseColorFactor", None)
        got = np.ones(4) if got is None else np.asarray(got, float) / (
            255.0 if np.asarray(got).dtype.kind in "ui" else 1.0)
        e_want = np.asarray(m.get("emissiveFactor", [0, 0, 0]), float)
        e_got = getattr(mat, "emissiveFactor", None)
        e_got = np.zeros(3) if e_got is None else np.asarray(e_got, float)[:3]
        sided = bool(m.get("doubleSided", False)) == bool(getattr(mat, "doubleSided", False))
        return float(np.abs(want - got).max() + np.abs(e_want - e_got).max()) + (0.0 if sided else 10.0)

    d = np.array([distance(i) for i in cands])
    tied = [cands[k] for k in np.nonzero(d <= d.min() + 1.0 / 255)[0]]
    if any(gltf[t] != gltf[tied[0]] for t in tied[1:]):
        raise SceneError(f"{fn}: glTF materials {', '.join(map(str, tied))} are all named "
                         f"'{name}' and differ by less than 1/255: give them distinct names")
    return tied[0]


def load_mesh(fn: str, default_material: str = "default") -> RawMesh:
    ext = os.path.splitext(fn)[1].lower()
    if ext not in MESH_FORMATS:
        raise SceneError(f"unknown mesh format {ext!r} of {fn}: use one of {', '.join(MESH_FORMATS)}")
    if not os.path.exists(fn):
        raise SceneError(f"mesh file not found: {fn}")
    if ext == ".obj":
        raw = load_obj(fn)
        if default_material != "default":
            raw.face_material = [default_material if m == "default" else m for m in raw.face_material]
        return raw
    return load_trimesh(fn, default_material)


# ----------------------------------------------------------------------------- polygons

def _warn(msg: str) -> None:
    warnings.warn(msg, SceneWarning, stacklevel=3)


def _is_convex(q: np.ndarray, n: np.ndarray) -> bool:
    s = [np.dot(np.cross(q[(k + 1) % 4] - q[k], q[(k + 2) % 4] - q[(k + 1) % 4]), n) for k in range(4)]
    return all(x > 0 for x in s)


def polygons_from_raw(raw: RawMesh, fn: str, merge: bool = True):
    """Validate faces and turn them into polygons: (verts (n,4,3), nverts (n,), face (n,), material names).

    Non-planar or non-convex quads become two triangles, n-gons a triangle fan; each with a warning.
    merge=False keeps triangle pairs that form parallelograms apart (view factors between the
    user's own facets).
    """
    tol = config.get("scene.planarity-tolerance")
    out_v, out_n, out_f, out_m = [], [], [], []
    V = raw.vertices
    for fi, idx in enumerate(raw.faces):
        bad = [k for k in idx if not 0 <= k < len(V)]
        if bad:
            raise SceneError(f"{fn}: face {fi + 1} refers to vertex {bad[0]}, which does not exist "
                             f"({len(V)} vertices)")
        if len(idx) < 3:
            raise SceneError(f"{fn}: face {fi + 1} has {len(idx)} vertices; a face needs at least 3")
        p = V[idx]
        if not np.all(np.isfinite(p)):
            raise SceneError(f"{fn}: face {fi + 1} has a NaN or infinite vertex coordinate")
        if np.abs(p).max() > MAX_COORD:
            raise SceneError(f"{fn}: face {fi + 1} has a vertex coordinate of {np.abs(p).max():.3g}: "
                             f"beyond {MAX_COORD:g}, lengths to the fourth power overflow; "
                             "rescale the mesh")
        mat = raw.face_material[fi]
        polys = []
        if len(idx) == 3:
            polys = [p[[0, 1, 2, 2]]]
        elif len(idx) == 4:
            n = np.cross(p[1] - p[0], p[2] - p[0]) + np.cross(p[2] - p[0], p[3] - p[0])
        if len(idx) == 4:
            nn = np.linalg.norm(n)
            diam = np.max(np.linalg.norm(p[:, None] - p[None], axis=-1))
            off = abs(np.dot(p[3] - p[0], np.cross(p[1] - p[0], p[2] - p[0])))
            c012 = np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0]))
            planar = nn > 0 and c012 > 0 and off / c012 <= tol * max(diam, 1e-300)
            if planar and _is_convex(p, n / nn):
                polys = [p]
            else:
                what = "non-planar" if not planar else "non-convex"
                _warn(f"{fn}: face {fi + 1} (material '{mat}') is a {what} quad; "
                      "split into two triangles")
                # split along the diagonal whose triangles have consistent normals
                a, b = p[[0, 1, 2, 2]], p[[0, 2, 3, 3]]
                if planar and np.dot(np.cross(p[2] - p[0], p[3] - p[0]), np.cross(p[1] - p[0], p[2] - p[0])) <= 0:
                    a, b = p[[1, 2, 3, 3]], p[[1, 3, 0, 0]]
                polys = [a, b]
        elif len(idx) > 4:
            _warn(f"{fn}: face {fi + 1} has {len(idx)} vertices; triangulated as a fan")
            polys = [p[[0, k, k + 1, k + 1]] for k in range(1, len(idx) - 1)]
        for q in polys:
            out_v.append(q)
            out_n.append(3 if np.array_equal(q[3], q[2]) else 4)
            out_f.append(fi)
            out_m.append(mat)
    if not out_v:
        return np.zeros((0, 4, 3)), np.zeros(0, np.int8), np.zeros(0, np.int32), []
    verts = np.array(out_v, float)
    nverts = np.array(out_n, np.int8)
    face = np.array(out_f, np.int32)
    if merge:
        verts, nverts, face, out_m = merge_parallelograms(verts, nverts, face, out_m)
    area, _, _ = polygon_properties(verts, nverts)
    diam = diameter(verts, nverts)
    bad = np.nonzero(~(area > config.get("scene.min-relative-area") * diam ** 2))[0]
    if len(bad):
        raise SceneError(f"{fn}: face {face[bad[0]] + 1} (material '{out_m[bad[0]]}') has zero area"
                         + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""))
    return verts, nverts, face, out_m


def merge_parallelograms(verts, nverts, face, mats):
    """Merge pairs of coplanar triangles that share a diagonal and form a parallelogram into quads.

    Greedy in file order, each triangle merges at most once; keeps the winding (front side).
    """
    tol = config.get("scene.merge-tolerance")
    tri = np.nonzero(nverts == 3)[0]
    if len(tri) < 2:
        return verts, nverts, face, mats
    # vertex identity by exact coordinates
    pts = verts[tri, :3].reshape(-1, 3)
    _, vid = np.unique(pts, axis=0, return_inverse=True)
    vid = vid.reshape(-1, 3)
    edges: dict = {}
    for k in range(len(tri)):
        for e in range(3):
            a, b = vid[k, e], vid[k, (e + 1) % 3]
            edges.setdefault((min(a, b), max(a, b)), []).append((k, e))
    partner = -np.ones(len(tri), np.int64)
    quads = {}
    for k in range(len(tri)):
        if partner[k] >= 0:
            continue
        for e in range(3):
            a, b = vid[k, e], vid[k, (e + 1) % 3]
            for (j, ej) in edges[(min(a, b), max(a, b))]:
                if j == k or partner[j] >= 0 or mats[tri[j]] != mats[tri[k]]:
                    continue
                # consistent winding: the shared edge runs the other way in j
                if vid[j, ej] != b:
                    continue
                P = verts[tri[k]]
                Q = verts[tri[j]]
                pa, pb, px = P[e], P[(e + 1) % 3], P[(e + 2) % 3]
                qy = Q[(ej + 2) % 3]
                d = max(np.linalg.norm(pa - pb), np.linalg.norm(px - qy))
                if np.linalg.norm((pa + pb) - (px + qy)) > tol * d:
                    continue  # diagonals do not bisect each other: not a parallelogram
                n1 = np.cross(pb - pa, px - pa)
                n2 = np.cross(pa - pb, qy - pb)
                if np.dot(n1, n2) <= 0 or np.linalg.norm(np.cross(n1, n2)) > tol * np.linalg.norm(n1) * np.linalg.norm(n2):
                    continue
                partner[k], partner[j] = j, k
                quads[k] = np.array([pb, px, pa, qy])
                break
            if partner[k] >= 0:
                break
    if not quads:
        return verts, nverts, face, mats
    drop = set()
    verts = verts.copy()
    nverts = nverts.copy()
    for k, q in quads.items():
        verts[tri[k]] = q
        nverts[tri[k]] = 4
        drop.add(int(tri[partner[k]]))
    keep = np.array([i for i in range(len(verts)) if i not in drop])
    return verts[keep], nverts[keep], face[keep], [mats[i] for i in keep]


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


def parse_resolution(val, where: str) -> tuple[int, int]:
    """`N`, `[W, H]` or `"WxH"` -> (W, H), both positive."""
    try:
        if isinstance(val, str):
            parts = val.lower().split("x")
            w, h = (int(parts[0]), int(parts[-1]))
        elif isinstance(val, (list, tuple)):
            if len(val) != 2:
                raise ValueError
            w, h = int(val[0]), int(val[1])
        else:
            w = h = int(val)
    except (TypeError, ValueError, OverflowError):
        raise SceneError(f"{where}: resolution must be N, [W, H] or 'WxH', got {val!r}") from None
    if w <= 0 or h <= 0:
        raise SceneError(f"{where}: resolution must be positive, got {w}x{h}")
    if max(w, h) > MAX_RESOLUTION:
        raise SceneError(f"{where}: resolution {w}x{h} is beyond {MAX_RESOLUTION} pixels a side")
    return w, h


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
        if not np.linalg.norm(z) > TINY:
            raise SceneError(f"{fn}: camera.look_at equals camera.position")
        z /= np.linalg.norm(z)
        if not np.linalg.norm(up) > TINY:
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


def load_scene(path: str, resolution=None) -> Scene:
    """Read a scene TOML (or a folder holding scene.toml) into a Scene: its meshes, material
    overrides and camera. A bare mesh file is not a scene (it has no camera): write a TOML with
    one [[mesh]] entry and a [camera] table."""
    path = os.path.abspath(path)
    if os.path.isdir(path) and os.path.exists(os.path.join(path, "scene.toml")):
        path = os.path.join(path, "scene.toml")
    if not os.path.exists(path):
        raise SceneError(f"scene file not found: {path}")
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: not valid TOML: {e}") from None
    except UnicodeDecodeError as e:
        raise SceneError(f"{path}: not valid TOML: not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise SceneError(f"cannot read scene file {path}: {e.strerror}") from None
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        raise SceneError(f"{path}: unknown key(s) {sorted(unknown)}; a scene file has {sorted(_TOP_KEYS)}")
    meshes = doc.get("mesh", [])
    if not isinstance(meshes, list) or not meshes:
        raise SceneError(f"{path}: no [[mesh]] entries: the scene is empty")
    overrides = doc.get("material", {})
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
        v, n, f, mats = polygons_from_raw(raw, fn)
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
    nverts = np.concatenate(all_n)
    names = sorted(set(mat_of))
    for name in overrides:
        if name not in names:
            _warn(f"{path}: [material.{name}] matches no face (materials in the meshes: {names})")
    index = {name: i for i, name in enumerate(names)}
    material = np.array([index[m] for m in mat_of], np.int32)

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
                                 "(a reflectance of 1 or more creates energy)")
        for what, val in (("emission", e), ("back_emission", eb)):
            if np.any(val < 0):
                raise SceneError(f"{where}: material '{name}' {what} {val.tolist()} is negative")
        refl[i] = r, rb
        emis[i] = e, eb
        if "two_sided" in over or "two_sided" in props:
            mat_two[i] = bool(over.get("two_sided", props.get("two_sided", False)))
            mat_two_set[i] = True
    two_sided = np.where(mat_two_set[material], mat_two[material], np.array(two_default, bool))
    reflectance = refl[material].copy()
    emission = emis[material].copy()
    reflectance[~two_sided, 1] = 0.0
    emission[~two_sided, 1] = 0.0

    area, normal, center = polygon_properties(verts, nverts)
    elements = Elements(verts=verts, nverts=nverts, normal=normal, center=center, area=area,
                        reflectance=reflectance, emission=emission, two_sided=two_sided,
                        material=material, source=np.concatenate(all_src),
                        face=np.concatenate(all_f), material_names=tuple(names),
                        sources=tuple(sources))
    camera = parse_camera(doc.get("camera"), path, resolution)
    name = doc.get("name", os.path.basename(base))
    validation = doc.get("validation", {})
    unknown = set(validation) - _VALIDATION_KEYS
    if unknown:
        raise SceneError(f"{path}: [validation] has unknown key(s) {sorted(unknown)}; allowed: "
                         f"{sorted(_VALIDATION_KEYS)}")
    for k in ("from", "to", "emitter", "receiver"):
        if k in validation and validation[k] not in names:
            raise SceneError(f"{path}: [validation] {k} = {validation[k]!r} is not a material of "
                             f"the scene ({names})")
    return Scene(name=str(name), path=path, elements=elements, camera=camera,
                 validation=dict(validation))
