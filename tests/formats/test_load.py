"""The mesh readers' registry (formats/load.py) and the whole-file writers (formats/files.py,
csvtext.write_csv): every extension has its reader, an unknown one is refused in one line that
lists them, and a file is written whole or not at all."""

from __future__ import annotations

import os

import numpy as np
import pytest

from radiosity.errors import SceneError
from radiosity.formats import load, obj, trimeshes
from radiosity.formats.csvtext import write_csv
from radiosity.formats.files import temp_path, write_bytes


def test_every_format_module_is_merged_into_the_registry():
    assert load.MESH_LOADERS == {**obj.loaders, **trimeshes.loaders}
    assert set(load.MESH_FORMATS) == {".obj", ".gltf", ".glb", ".ply", ".stl"}
    assert all(callable(f) for f in load.MESH_LOADERS.values())


def test_an_unknown_extension_is_refused_naming_the_readers(tmp_path):
    fn = tmp_path / "part.step"
    fn.write_text("ISO-10303-21;\n")
    with pytest.raises(SceneError, match=r"unknown mesh format '.step' of .*part.step: use one of "
                                         r"\.obj, \.gltf, \.glb, \.ply, \.stl"):
        load.load_mesh(str(fn))
    with pytest.raises(SceneError, match="mesh file not found"):
        load.load_mesh(str(tmp_path / "gone.STL"))  # the extension in any case


def test_the_obj_reader_gives_faces_without_a_material_the_default_one(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nusemtl red\nf 3 2 1\n")
    raw = load.load_mesh(str(tmp_path / "m.obj"), "paint")
    assert raw.face_material == ["paint", "red"]
    assert load.load_mesh(str(tmp_path / "m.obj")).face_material == ["default", "red"]


def test_files_are_written_whole(tmp_path):
    fn = str(tmp_path / "out.bin")
    write_bytes(fn, b"abc")
    assert open(fn, "rb").read() == b"abc"
    assert temp_path(fn) != fn and os.path.dirname(temp_path(fn)) == str(tmp_path)
    write_csv(str(tmp_path / "t.csv"), {"name": np.array(["a,b", 'say "x"']),
                                        "n": np.array([1, -2]), "x": np.array([0.5, np.nan])})
    assert (tmp_path / "t.csv").read_text() == 'name,n,x\n"a,b",1,0.5\n"say ""x""",-2,nan\n'
    assert sorted(os.listdir(tmp_path)) == ["out.bin", "t.csv"]  # no temporary file left
