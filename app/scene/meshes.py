"""Mesh files (OBJ+MTL, glTF/GLB, PLY) -> RawMesh -> validated polygons.

Quads stay quads: an OBJ face with four vertices is one element, and two coplanar triangles that
share a diagonal and form a parallelogram are merged back into one (seed §3.2 splits rectangles
across their longer sides). Every problem raises `SceneError` naming the file and the face.
"""

from __future__ import annotations

import json
import os
import re
import struct
import warnings
from dataclasses import dataclass, field

import numpy as np

from radiosity.errors import SceneError
from radiosity.core.geometry import diameter, polygon_properties
from radiosity.settings import Settings, resolve

MESH_FORMATS = (".obj", ".gltf", ".glb", ".ply")
#: Largest vertex coordinate accepted: fourth powers of lengths (|cross product|^2, r^4 in
#: the sampled kernels) must stay finite in float64 (1e75^4 = 1e300 < 1.8e308).
MAX_COORD = 1e75
_KEYWORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_GARBLED = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ufffd]")


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


def polygons_from_raw(raw: RawMesh, fn: str, merge: bool = True, settings: Settings | None = None):
    """Validate faces and turn them into polygons: (verts (n,4,3), nverts (n,), face (n,), material names).

    Non-planar or non-convex quads become two triangles, n-gons a triangle fan; each with a warning.
    merge=False keeps triangle pairs that form parallelograms apart (view factors between the
    user's own facets). settings: its scene.* tolerances (None: resolved here).
    """
    sc = resolve(base=settings).scene
    tol = sc.planarity_tolerance
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
        verts, nverts, face, out_m = merge_parallelograms(verts, nverts, face, out_m,
                                                          sc.merge_tolerance)
    area, _, _ = polygon_properties(verts, nverts)
    diam = diameter(verts, nverts)
    bad = np.nonzero(~(area > sc.min_relative_area * diam ** 2))[0]
    if len(bad):
        raise SceneError(f"{fn}: face {face[bad[0]] + 1} (material '{out_m[bad[0]]}') has zero area"
                         + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""))
    return verts, nverts, face, out_m


def merge_parallelograms(verts, nverts, face, mats, tol: float | None = None):
    """Merge pairs of coplanar triangles that share a diagonal and form a parallelogram into quads.

    Greedy in file order, each triangle merges at most once; keeps the winding (front side).
    tol: scene.merge-tolerance (None: resolved here).
    """
    if tol is None:
        tol = resolve().scene.merge_tolerance
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
