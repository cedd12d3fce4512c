"""Fuzzing the scene loader (issue 15): mutated OBJ, MTL, TOML and PLY bytes must give either a
Scene with finite arrays or a SceneError (the CLI's one line), never another exception, and no
overflow on the way (RuntimeWarnings are errors here)."""

from __future__ import annotations

import os
import tempfile
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radiosity.errors import SceneError
from radiosity.scene.load import load_scene
from radiosity.core.bundles import Scene
from radiosity.settings import options as settings_of

OBJ = b"""mtllib mesh.mtl
v 0 0 0
v 1 0 0
v 1 0 1
v 0 0 1
v 0 0.5 0.2
v 0.5 0.6 0.2
v 0.2 0.9 0.3
usemtl floor
f 1 4 3 2
usemtl light
f 5 6 7
"""
MTL = b"""newmtl floor
Kd 0.5 0.5 0.5
newmtl light
Kd 0.2 0.2 0.2
Ke 4 4 4
"""
TOML = b"""name = "fuzz"
[[mesh]]
path = "mesh.obj"
[[mesh]]
path = "mesh.ply"
material = "plate"
[material.plate]
reflectance = [0.3, 0.4, 0.5]
[camera]
position = [0.5, 2.0, -1.5]
look_at = [0.5, 0.0, 0.5]
up = [0.0, 1.0, 0.0]
fov_y = 50.0
resolution = [8, 6]
"""
PLY = b"""ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
element face 2
property list uchar int vertex_indices
end_header
0 1 0
1 1 0
1 1 1
0 1 1
3 0 2 1
3 0 3 2
"""
FILES = {"mesh.obj": OBJ, "mesh.mtl": MTL, "scene.toml": TOML, "mesh.ply": PLY}
NUMBERS = [b"1e309", b"-1e309", b"nan", b"inf", b"1e300", b"-1e300", b"1e-320", b"0",
           b"-0", b"99999999999999999999", b"-1", b"1.0000001", b"", b"0x1F", b"1e75"]


@st.composite
def mutated(draw, data: bytes) -> bytes:
    """`data` after a few byte-level or token-level mutations."""
    b = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "insert", "delete", "truncate", "number", "dup"]))
        if not b:
            b = bytearray(draw(st.binary(max_size=8)))
            continue
        i = draw(st.integers(0, len(b) - 1))
        if kind == "flip":
            b[i] ^= draw(st.integers(1, 255))
        elif kind == "insert":
            b[i:i] = draw(st.binary(min_size=1, max_size=8))
        elif kind == "delete":
            del b[i:i + draw(st.integers(1, 16))]
        elif kind == "truncate":
            del b[i:]
        elif kind == "number":  # replace a numeric token by an extreme one
            toks = [k for k, c in enumerate(b) if chr(c).isdigit()]
            if toks:
                k = draw(st.sampled_from(toks))
                j = k
                while j < len(b) and (chr(b[j]).isdigit() or b[j] in b".eE-+"):
                    j += 1
                b[k:j] = draw(st.sampled_from(NUMBERS))
        else:  # duplicate a line
            lines = bytes(b).split(b"\n")
            k = draw(st.integers(0, len(lines) - 1))
            lines.insert(k, lines[k])
            b = bytearray(b"\n".join(lines))
    return bytes(b)


def _load(files: dict) -> None:
    with tempfile.TemporaryDirectory() as d:
        for name, data in files.items():
            with open(os.path.join(d, name), "wb") as f:
                f.write(data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")        # the loader's SceneWarnings are fine
            warnings.simplefilter("error", RuntimeWarning)  # overflow or NaN arithmetic is not
            try:
                sc = load_scene(os.path.join(d, "scene.toml"), settings=settings_of())
            except SceneError as e:
                assert "\n" not in str(e).strip(), str(e)  # one line
                return
    assert isinstance(sc, Scene)
    el = sc.elements
    for a in (el.verts, el.normal, el.center, el.area, el.reflectance, el.emission):
        assert np.all(np.isfinite(a))
    assert np.all(el.area > 0) and len(el) > 0


SETTINGS = settings(max_examples=120, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def test_the_unmutated_files_load():
    _load(FILES)


@pytest.mark.parametrize("name", sorted(FILES))
def test_mutated_bytes_give_a_scene_or_one_scene_error(name):
    @SETTINGS
    @given(mutated(FILES[name]))
    def check(data):
        _load({**FILES, name: data})

    check()
