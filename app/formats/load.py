"""The mesh readers, by file extension: each format module exports a `loaders` dict (extension ->
reader(path, default_material) -> RawMesh), merged here as trimesh's exchange/load.py merges
its formats. A new format is one module and one line below."""

from __future__ import annotations

import os

from radiosity.errors import SceneError
from radiosity.formats import obj, trimeshes
from radiosity.formats.raw import RawMesh

#: extension (lower case, with the dot) -> reader(path, default_material) -> RawMesh
MESH_LOADERS = {**obj.loaders, **trimeshes.loaders}
#: The mesh file extensions a scene may name (or render as a bare mesh).
MESH_FORMATS = tuple(MESH_LOADERS)


def load_mesh(fn: str, default_material: str = "default") -> RawMesh:
    """The mesh file `fn` read by the reader of its extension; faces without a material of
    their own take `default_material`. One SceneError line for an unknown extension or a
    missing file."""
    ext = os.path.splitext(fn)[1].lower()
    if ext not in MESH_LOADERS:
        raise SceneError(f"unknown mesh format {ext!r} of {fn}: use one of {', '.join(MESH_FORMATS)}")
    if not os.path.exists(fn):
        raise SceneError(f"mesh file not found: {fn}")
    return MESH_LOADERS[ext](fn, default_material)
