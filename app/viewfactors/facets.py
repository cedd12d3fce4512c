"""The user's facets for the view-factor stage: `load_facets` reads a mesh (OBJ, glTF/GLB, PLY), a
scene TOML's [[mesh]] files, a trimesh or (vertices, faces) arrays into `Facets`, one facet per
face, repaired or rejected exactly as the scene loader would (no merging, no subdivision).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from radiosity.errors import SceneError
from radiosity.settings import Settings


@dataclass(frozen=True)
class Facets:
    """The user's facets, in load order.

    verts (n, 4, 3) float64 (a triangle repeats vertex 2), nverts (n,) int8, normal (n, 3)
    unit front normals, center (n, 3) area centroids, area (n,) float64 (mesh unit squared),
    face (n,) int32: the face number in its file (0-based; faces with more than 4 vertices or
    non-planar quads become several facets, with a warning), source (n,) int32 index into
    sources (the mesh files)."""

    verts: np.ndarray
    nverts: np.ndarray
    normal: np.ndarray
    center: np.ndarray
    area: np.ndarray
    face: np.ndarray
    source: np.ndarray
    sources: tuple = ()

    def __len__(self) -> int:
        return len(self.area)

    def describe(self, i: int) -> str:
        src = os.path.basename(self.sources[self.source[i]]) if self.sources else "?"
        return f"facet {i} (face {int(self.face[i])} of {src})"


def _from_polygons(parts: list, sources: list) -> Facets:
    from radiosity.core.geometry import polygon_properties

    verts = np.concatenate([p[0] for p in parts])
    if len(verts) == 0:
        raise SceneError(f"{', '.join(sources) or 'the mesh'}: no faces: nothing to compute")
    nverts = np.concatenate([p[1] for p in parts]).astype(np.int8)
    face = np.concatenate([p[2] for p in parts]).astype(np.int32)
    source = np.concatenate([np.full(len(p[0]), k, np.int32) for k, p in enumerate(parts)])
    area, normal, center = polygon_properties(verts, nverts)
    return Facets(verts, nverts, normal, center, area, face, source, tuple(sources))


def load_facets(mesh, settings: Settings) -> Facets:
    """The facets of `mesh`: a path (OBJ, glTF/GLB, PLY, or a scene TOML / its directory, whose
    [[mesh]] files are read and whose camera and materials are ignored), a trimesh.Trimesh, a
    trimesh.Scene, a (vertices (V, 3), faces) pair, a types.Elements, or Facets. Bad input
    raises SceneError.
    settings: the run's (its scene tolerances)."""
    from radiosity.formats.load import MESH_FORMATS, load_mesh
    from radiosity.formats.raw import RawMesh
    from radiosity.core.bundles import Elements

    if isinstance(mesh, Facets):
        return mesh
    if isinstance(mesh, Elements):
        return Facets(mesh.verts, mesh.nverts, mesh.normal, mesh.center, mesh.area, mesh.face,
                      mesh.source, mesh.sources)
    if isinstance(mesh, (str, os.PathLike)):
        path = os.path.abspath(os.fspath(mesh))
        if os.path.isdir(path) and os.path.exists(os.path.join(path, "scene.toml")):
            path = os.path.join(path, "scene.toml")
        if path.lower().endswith(".toml"):
            files = _toml_meshes(path)
        elif path.lower().endswith(MESH_FORMATS):
            files = [path]
        else:
            raise SceneError(f"{path}: not a mesh ({', '.join(MESH_FORMATS)}) or a scene TOML")
        parts = [_polygons(load_mesh(fn), fn, settings) for fn in files]
        return _from_polygons(parts, files)
    if type(mesh).__name__ == "Scene" and hasattr(mesh, "to_geometry"):  # a trimesh.Scene:
        mesh = mesh.to_geometry()  # its meshes placed by their transforms, as one
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        vertices, faces, name = mesh.vertices, mesh.faces, "mesh"
    elif isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        (vertices, faces), name = mesh, "(vertices, faces)"
    else:
        raise SceneError(f"cannot read facets from a {type(mesh).__name__}: give a mesh path, "
                         "a trimesh.Trimesh or a (vertices, faces) pair")
    V = np.asarray(vertices, float)
    if V.ndim != 2 or V.shape[1] != 3:
        raise SceneError(f"{name}: vertices must be a (V, 3) array, got shape {V.shape}")
    F = [list(map(int, f)) for f in faces]
    for k, f in enumerate(F):
        if len(f) < 3 or min(f) < 0 or max(f) >= len(V):
            raise SceneError(f"{name}: face {k} {f} refers to vertices that do not exist "
                             f"(there are {len(V)})")
    return _from_polygons([_polygons(RawMesh(V, F, ["default"] * len(F)), name, settings)], [name])


def _polygons(raw, fn: str, settings: Settings):
    """(verts (n, 4, 3), nverts (n,), face (n,)) of a raw mesh, one facet per face, as
    scene.polygons_from_raw(merge=False) gives them. Meshes of valid triangles and planar
    convex quads (the usual case) are checked with whole-array operations (with the
    tolerances settings.scene.*); any other mesh goes through polygons_from_raw, which repairs
    (with a warning) or rejects (one line naming the face) exactly as the scene loader does."""
    from radiosity.scene.meshes import polygons_from_raw

    scene = settings.scene

    sizes = np.array([len(f) for f in raw.faces], np.int64)
    if len(sizes) and sizes.min() >= 3 and sizes.max() <= 4:
        V = np.asarray(raw.vertices, float)
        idx = np.array([list(f) + [f[2]] * (4 - len(f)) for f in raw.faces], np.int64)
        p = V[idx]
        if np.isfinite(p).all():
            p0, p1, p2, p3 = (p[:, k] for k in range(4))
            c012 = np.cross(p1 - p0, p2 - p0)
            n = c012 + np.cross(p2 - p0, p3 - p0)
            nn = np.linalg.norm(n, axis=1)
            diam = np.linalg.norm(p[:, :, None] - p[:, None], axis=-1).max(axis=(1, 2))
            quad = sizes == 4
            off = np.abs(np.einsum("ij,ij->i", p3 - p0, c012))
            c = np.linalg.norm(c012, axis=1)
            planar = (c > 0) & (off <= scene.planarity_tolerance * diam
                                * np.maximum(c, 1e-300))
            unit = n / np.where(nn > 0, nn, 1.0)[:, None]
            turns = np.stack([np.einsum("ij,ij->i", np.cross(p[:, (k + 1) % 4] - p[:, k],
                                                             p[:, (k + 2) % 4] - p[:, (k + 1) % 4]), unit)
                              for k in range(4)], 1)
            convex = (turns > 0).all(axis=1)
            area = 0.5 * nn
            ok = (area > scene.min_relative_area * diam ** 2) & (~quad | (planar & convex))
            if ok.all():
                return p, sizes.astype(np.int8), np.arange(len(sizes), dtype=np.int32)
    v, nv, f, _ = polygons_from_raw(raw, fn, settings, merge=False, first_face=0)
    return v, nv, f


def _toml_meshes(path: str) -> list:
    import tomllib

    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise SceneError(f"scene file not found: {path}") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: not valid TOML: {e}") from None
    meshes = doc.get("mesh", [])
    if not isinstance(meshes, list) or not meshes:
        raise SceneError(f"{path}: no [[mesh]] entries: the scene is empty")
    out = []
    for k, m in enumerate(meshes):
        if not isinstance(m, dict) or "path" not in m:
            raise SceneError(f"{path}: [[mesh]] {k + 1} has no 'path'")
        out.append(os.path.join(os.path.dirname(path), m["path"]))
    return out
