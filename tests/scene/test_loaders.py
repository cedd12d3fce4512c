"""Mesh loaders: the cases docs/src/reference/scenes.md promises (glTF doubleSided, binary .glb, duplicate and unnamed
glTF materials, back_emission, n-gons as fans, PLY without a material), each read back element
by element."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

from radiosity.formats.raw import SceneWarning
from radiosity.scene.load import load_scene
from helpers import prepared, radiance, write_scene
from radiosity.settings import options as settings_of

CAMERA = ('[camera]\nposition = [0, 0, 0]\nlook_at = [0, 0, 1]\nup = [0, 1, 0]\nfov_y = 60\n'
          'resolution = 8\n')


def _box(name, colour, double_sided, x, emissive=(0.0, 0.0, 0.0)):
    b = trimesh.creation.box(extents=[1, 1, 1])
    b.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        name=name, baseColorFactor=colour, emissiveFactor=list(emissive), doubleSided=double_sided))
    return b, trimesh.transformations.translation_matrix([x, 0, 5])


def _glb(tmp_path, boxes) -> str:
    s = trimesh.Scene()
    for k, (b, t) in enumerate(boxes):
        s.add_geometry(b, node_name=f"n{k}", transform=t)
    (tmp_path / "m.glb").write_bytes(s.export(file_type="glb"))
    (tmp_path / "scene.toml").write_text('[[mesh]]\npath = "m.glb"\n' + CAMERA)
    return str(tmp_path / "scene.toml")


def _by_box(el):
    """Element indices of each box (by the centre's x: -2, 0, 2)."""
    return {x: np.nonzero(np.abs(el.center[:, 0] - x) <= 0.5 + 1e-9)[0] for x in (-2, 0, 2)}


def test_glb_double_sided_duplicate_and_unnamed_materials(tmp_path):
    """A binary glTF with three boxes: 'paint' (grey, doubleSided false), another 'paint' (red,
    doubleSided true, emissive with KHR strength) and an unnamed green one. Each box keeps its
    own material at full precision (the JSON chunk, not trimesh's 8-bit colours); the second
    'paint' gets a name of its own, with a warning; the unnamed one keeps its colour."""
    path = _glb(tmp_path, [_box("paint", [0.2, 0.2, 0.2, 1.0], False, 0),
                           _box("paint", [0.8, 0.1, 0.1, 1.0], True, 2, emissive=(1.0, 0.5, 0.25)),
                           _box(None, [0.1, 0.7, 0.1, 1.0], False, -2)])
    import json
    import struct

    # the JSON chunk rewritten: full-precision factors (trimesh wrote them rounded to 8 bits)
    # and the emissive strength
    data = bytearray((tmp_path / "m.glb").read_bytes())
    n = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + n])
    for m, c in zip(doc["materials"], ([0.2, 0.2, 0.2, 1.0], [0.8, 0.1, 0.1, 1.0], [0.1, 0.7, 0.1, 1.0])):
        m["pbrMetallicRoughness"]["baseColorFactor"] = c
    doc["materials"][1]["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}}
    body = json.dumps(doc).encode()
    body += b" " * (-len(body) % 4)
    rest = data[20 + n:]
    out = data[:12] + struct.pack("<I", len(body)) + data[16:20] + body + rest
    out[8:12] = struct.pack("<I", len(out))
    (tmp_path / "m.glb").write_bytes(bytes(out))

    with pytest.warns(SceneWarning, match="glTF material 1 reuses the name 'paint'.*'paint#1'"):
        el = load_scene(path, settings=settings_of()).elements
    assert len(el) == 18 and np.all(el.nverts == 4)  # 3 boxes x 6 quads (triangles merged)
    names = np.array(el.material_names)[el.material]
    box = _by_box(el)
    assert set(names[box[0]]) == {"paint"} and set(names[box[2]]) == {"paint#1"}
    assert set(names[box[-2]]) == {"unnamed-2"}
    np.testing.assert_array_equal(el.reflectance[box[0], 0], [[0.2, 0.2, 0.2]] * 6)
    np.testing.assert_array_equal(el.reflectance[box[2], 0], [[0.8, 0.1, 0.1]] * 6)
    np.testing.assert_array_equal(el.reflectance[box[-2], 0], [[0.1, 0.7, 0.1]] * 6)
    np.testing.assert_allclose(el.emission[box[2], 0], [[4.0, 2.0, 1.0]] * 6)
    assert not el.two_sided[box[0]].any() and el.two_sided[box[2]].all()
    assert not el.two_sided[box[-2]].any()
    assert np.all(el.reflectance[box[0], 1] == 0)  # one-sided: nothing on the back


def test_gltf_same_name_same_material_is_one_material(tmp_path):
    """Two glTF materials with the same name and the same properties are one material."""
    path = _glb(tmp_path, [_box("wood", [0.5, 0.4, 0.3, 1.0], False, 0),
                           _box("wood", [0.5, 0.4, 0.3, 1.0], False, 2)])
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)
        el = load_scene(path, settings=settings_of()).elements
    assert el.material_names == ("wood",)


def test_back_emission_of_two_sided_elements(client, tmp_path):
    """back_emission gives a two-sided element's back its own emitted radiance (default: the
    front's); a one-sided element has no back at all. Solved: the back of a panel that emits
    only on its back shows exactly that radiance (it reflects nothing), and lights the floor
    its back faces."""
    obj = """
    v -1 0 -1
    v 1 0 -1
    v 1 0 1
    v -1 0 1
    v -0.3 1 -0.3
    v 0.3 1 -0.3
    v 0.3 1 0.3
    v -0.3 1 0.3
    v -0.3 1.5 -0.3
    v 0.3 1.5 -0.3
    v 0.3 1.5 0.3
    usemtl floor
    f 1 4 3 2
    usemtl panel
    f 5 8 7 6
    usemtl twin
    f 9 11 10
    """
    extra = """
    [material.floor]
    reflectance = [0.5, 0.5, 0.5]
    [material.panel]
    reflectance = [0.0, 0.0, 0.0]
    two_sided = true
    emission = [0.0, 0.0, 0.0]
    back_emission = [5.0, 4.0, 3.0]
    [material.twin]
    reflectance = [0.0, 0.0, 0.0]
    two_sided = true
    emission = [1.0, 1.0, 1.0]
    """
    cam = ("[camera]\nposition = [0.2, 3.0, -3.0]\nlook_at = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\n"
           "fov_y = 50.0\nresolution = [12, 12]\n")
    path = write_scene(tmp_path, obj, extra, camera=cam)
    el = load_scene(path, settings=settings_of()).elements
    names = list(np.array(el.material_names)[el.material])
    panel, twin, floor = names.index("panel"), names.index("twin"), names.index("floor")
    np.testing.assert_array_equal(el.emission[panel], [[0, 0, 0], [5, 4, 3]])
    np.testing.assert_array_equal(el.emission[twin], [[1, 1, 1], [1, 1, 1]])  # back = front
    assert el.normal[panel] @ [0, 1, 0] > 0.99  # the front faces up: its back faces the floor
    from radiosity.stages.solve import run_solve

    out = prepared(client, tmp_path, path, 12)
    run_solve(out, client, settings_of(tol=1e-10), progress=False)
    from radiosity.runtime.store import RunStore

    part = RunStore(out).load_partition()
    L = radiance(out)
    on_panel = part.orig == panel
    np.testing.assert_array_equal(L[on_panel, 1], np.broadcast_to([5.0, 4.0, 3.0], (on_panel.sum(), 3)))
    np.testing.assert_array_equal(L[on_panel, 0], 0.0)
    lit = L[part.orig == floor, 0]
    assert lit.min() > 0 and np.all(lit[:, 0] > lit[:, 2])  # the back's warm light, reflected


def test_ngon_becomes_a_fan_of_triangles_with_a_warning(tmp_path):
    """A planar convex hexagon (one OBJ face of 6 vertices): 4 triangles from vertex 0, said
    with a warning, covering the hexagon's area (3 sqrt(3) / 2 for unit sides) facing one way."""
    ang = np.arange(6) * np.pi / 3
    verts = "\n".join(f"v {np.cos(a):.17g} 0 {np.sin(a):.17g}" for a in ang)
    path = write_scene(tmp_path, verts + "\nf 6 5 4 3 2 1\n")
    with pytest.warns(SceneWarning, match="face 1 has 6 vertices; triangulated as a fan"):
        el = load_scene(path, settings=settings_of()).elements
    assert len(el) == 4 and np.all(el.nverts == 3)
    assert el.area.sum() == pytest.approx(3 * np.sqrt(3) / 2, rel=1e-14)
    np.testing.assert_allclose(el.normal, np.broadcast_to([0, 1.0, 0], (4, 3)), atol=1e-15)
    assert np.all(el.face == 0)
    np.testing.assert_allclose(el.verts[:, 0], np.broadcast_to(el.verts[0, 0], (4, 3)))  # a fan


def test_ply_without_material_is_default_grey_and_takes_the_default_override(tmp_path):
    tri = trimesh.Trimesh(vertices=[[0, 0, 1], [1, 0, 1], [0, 1, 1]], faces=[[0, 1, 2]], process=False)
    tri.export(tmp_path / "t.ply")
    cam = ('[camera]\nposition = [0.2, 0.2, 3]\nlook_at = [0.2, 0.2, 0]\nup = [0, 1, 0]\nfov_y = 40\n'
           'resolution = 8\n')
    (tmp_path / "a.toml").write_text('[[mesh]]\npath = "t.ply"\n' + cam)
    el = load_scene(str(tmp_path / "a.toml"), settings=settings_of()).elements
    assert el.material_names == ("default",)
    np.testing.assert_array_equal(el.reflectance[0], [[0.5, 0.5, 0.5], [0, 0, 0]])
    np.testing.assert_array_equal(el.emission[0], 0.0)
    assert not el.two_sided[0]
    (tmp_path / "b.toml").write_text('[[mesh]]\npath = "t.ply"\n[material.default]\n'
                                     'reflectance = [0.1, 0.2, 0.3]\n' + cam)
    el = load_scene(str(tmp_path / "b.toml"), settings=settings_of()).elements
    np.testing.assert_array_equal(el.reflectance[0, 0], [0.1, 0.2, 0.3])


# ----------------------------------------------------------------------------- bulk OBJ reader

def _obj_text(rng, n=400) -> str:
    """An OBJ of plain lines the bulk reader takes: numbers in many spellings, faces of 3 to 6
    vertices (slashes, negative indices), usemtl, comments, unknown statements, blank lines."""
    spell = [lambda x: "%.9g" % x, lambda x: repr(float(x)), lambda x: "%.6f" % x, lambda x: "%.3e" % x,
             lambda x: "%.25e" % x, lambda x: "%d" % round(x), lambda x: "%.17g" % (x * 1e-310),
             lambda x: "%.1fe+300" % x, lambda x: "-0", lambda x: ".5", lambda x: "+7.", lambda x: "0e99999"]
    lines, nv = ["# made up", "mtllib mesh.mtl", "o thing", "vn 0 1 0", "vt 0.5 0.5", ""], 0
    for k in range(n):
        r = rng.random()
        if r < 0.5 or nv < 6:
            xyz = rng.normal(size=3) * 10.0 ** rng.integers(-3, 4)
            lines.append("v " + "\t ".join(spell[rng.integers(len(spell))](x) for x in xyz)
                         + (" 1 0.5 0" if r < 0.05 else ""))
            nv += 1
        elif r < 0.85:
            m = int(rng.choice([3, 3, 4, 4, 5, 6]))
            idx = rng.choice(nv, m, replace=False) + 1
            toks = [str(i - nv - 1) if rng.random() < 0.2 else
                    (f"{i}/{i}/1" if rng.random() < 0.2 else (f"{i}//2" if rng.random() < 0.1 else str(i)))
                    for i in idx]
            lines.append("f  " + " ".join(toks))
        elif r < 0.9:
            lines.append(f"usemtl {rng.choice(['a', 'b', 'a b'])}")
        elif r < 0.95:
            lines.append(rng.choice(["", "   ", "# comment", "s off", "g part_2", "usemtl"]))
        else:
            lines.append("vn 0 0 1  # normal")
    return "\n".join(lines) + "\n"


def _same_raw(a, b):
    assert a.vertices.shape == b.vertices.shape and a.vertices.dtype == b.vertices.dtype
    np.testing.assert_array_equal(a.vertices.view(np.int64), b.vertices.view(np.int64))  # to the bit
    assert a.faces == b.faces and all(type(k) is int for f in a.faces for k in f)
    assert a.face_material == b.face_material and a.materials == b.materials


def test_bulk_obj_reader_reads_what_the_line_reader_reads(tmp_path):
    """The bulk reader (numba scan of v/f lines, Clinger's exact fast path for numbers, the
    rest left to float()) gives the line reader's RawMesh to the bit; with outputs that start
    tiny and grow, the same scan."""
    from radiosity.formats import obj as meshes, objscan

    (tmp_path / "mesh.mtl").write_text("newmtl a\nKd 0.1 0.2 0.3\nnewmtl a b\nKe 1 1 1\n")
    rng = np.random.default_rng(3)
    for trial in range(12):
        text = _obj_text(rng)
        if trial % 3 == 1:
            text = text.replace("\n", "\r\n")
        fn = str(tmp_path / "mesh.obj")
        (tmp_path / "mesh.obj").write_text(text, newline="")
        bulk = meshes._load_obj_bulk(fn, open(fn, encoding="utf-8").read())
        assert bulk is not None  # plain lines only: read in bulk
        _same_raw(bulk, meshes._load_obj_lines(fn, open(fn, encoding="utf-8").read().splitlines()))
        _same_raw(meshes.load_obj(fn), bulk)
        b = np.frombuffer(text.replace("\r\n", "\n").encode(), np.uint8)
        big, small = objscan.scan_obj(b), objscan.scan_obj(b, room=1)
        for x in (big, small):
            x[0][x[1]] = 0.0  # the slots float() fills
        assert all(np.array_equal(x, y) for x, y in zip(big, small))


@pytest.mark.parametrize("bad", [
    "v 1 2\n", "v 1 2 x\n", "v 1 2 nan\n", "v 1_0 2 3\n", "f 1 2 99\n", "f 1 2\n", "f 0 1 2\n",
    "f -9 1 2\n", "f 1/2 /3 2\n", "f +1 2 3\n", "f 1 2 3 # c\n", "v 1 2 3 # c\n", "  f 1 2 3\n",
    "3 4 5\n", "usemtl \x00\n", "v 1 2 3\r", "v 1 2\x0b3\n", "\xe9t\xe9 1\n", "mtllib gone.mtl\n",
    "f 1 2 1234567890123456789012\n", "v 1e\t2 3\n", "v 1.2.3 0 0\n", "v\xa01 2 3\n"])
def test_obj_lines_the_bulk_reader_leaves_read_as_before(tmp_path, bad):
    """A line the bulk reader does not take (or an error anywhere) sends the whole file to the
    line reader: the same mesh or the same error line, naming the first bad line."""
    from radiosity.errors import SceneError
    from radiosity.formats import obj as meshes

    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nusemtl a\n" + bad + "f 2 3 4\nv 1 1 1\n"
    fn = str(tmp_path / "mesh.obj")
    (tmp_path / "mesh.obj").write_text(text, newline="")

    def read(f):
        try:
            return f(), None
        except SceneError as e:
            return None, str(e)

    want, err = read(lambda: meshes._load_obj_lines(fn, open(fn, encoding="utf-8").read().splitlines()))
    got, got_err = read(lambda: meshes.load_obj(fn))
    assert got_err == err
    if want is not None:
        _same_raw(got, want)


# ----------------------------------------------------------------------------- STL

def _stl_box(tmp_path, name: str, ascii: bool, extents=(2.0, 1.0, 3.0), centre=(0.0, 0.5, 1.5),
             inward: bool = False) -> str:
    """A box as an STL file (12 triangles, 3 vertices each as STL stores them), ASCII or
    binary; inward: the faces turned to point into the box (a room)."""
    b = trimesh.creation.box(extents=list(extents))
    b.apply_translation(centre)
    if inward:
        b.invert()
    data = b.export(file_type="stl_ascii" if ascii else "stl")
    (tmp_path / name).write_bytes(data.encode() if isinstance(data, str) else data)
    return str(tmp_path / name)


@pytest.mark.parametrize("ascii", [True, False], ids=["ascii", "binary"])
def test_stl_is_read_as_the_same_triangles_in_obj(tmp_path, ascii):
    """An STL box (ASCII and binary) in a scene: its 12 triangles merged back into 6 quads, of
    the [[mesh]]'s material, to the bit the elements of the same triangles written as an OBJ."""
    from radiosity.formats.load import MESH_FORMATS

    assert ".stl" in MESH_FORMATS
    fn = _stl_box(tmp_path, "box.stl", ascii)
    tris = trimesh.load(fn, force="mesh", process=False)
    assert len(tris.faces) == 12
    v = np.asarray(tris.vertices)[np.asarray(tris.faces)].reshape(-1, 3)
    (tmp_path / "box.obj").write_text(
        "".join("v %r %r %r\n" % tuple(map(float, p)) for p in v)
        + "".join(f"f {3 * k + 1} {3 * k + 2} {3 * k + 3}\n" for k in range(12)))
    got, want = (load_scene(str(tmp_path / f"{s}.toml"), settings=settings_of()).elements for s in ("stl", "obj")
                 if (tmp_path / f"{s}.toml").write_text(
                     f'[[mesh]]\npath = "box.{s}"\nmaterial = "grey"\n'
                     '[material.grey]\nreflectance = [0.3, 0.4, 0.5]\n' + CAMERA) or True)
    assert len(got) == 6 and np.all(got.nverts == 4)
    assert got.material_names == ("grey",)
    np.testing.assert_array_equal(got.reflectance[:, 0], np.tile([0.3, 0.4, 0.5], (6, 1)))
    for k in ("verts", "nverts", "normal", "area", "face"):
        np.testing.assert_array_equal(getattr(got, k), getattr(want, k))


def test_a_bare_stl_is_refused_in_one_line_it_has_no_emission(tmp_path):
    from click.testing import CliRunner

    from radiosity.cli.commands import main

    fn = _stl_box(tmp_path, "part.stl", ascii=False)
    r = CliRunner().invoke(main, ["render", fn, "--out", str(tmp_path / "run")])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "an STL file holds no emission" in lines[0], r.output


@pytest.mark.cluster
def test_radiosity_render_of_a_scene_of_stl_files(tmp_path):
    """`radiosity render` of a scene whose room is a binary STL and whose lamp an ASCII one:
    the lamp's emission comes from the scene's [material] table, the run converges and the
    room is lit."""
    import json

    from click.testing import CliRunner

    from radiosity.cli.commands import main

    _stl_box(tmp_path, "room.stl", ascii=False, extents=(4.0, 2.5, 3.0), centre=(2.0, 1.25, 1.5),
             inward=True)
    _stl_box(tmp_path, "lamp.stl", ascii=True, extents=(1.0, 0.02, 1.0), centre=(2.0, 2.3, 1.5))
    (tmp_path / "scene.toml").write_text(
        '[[mesh]]\npath = "room.stl"\nmaterial = "walls"\n'
        '[[mesh]]\npath = "lamp.stl"\nmaterial = "lamp"\n'
        '[material.walls]\nreflectance = [0.6, 0.6, 0.6]\n'
        '[material.lamp]\nreflectance = [0.5, 0.5, 0.5]\nemission = [5, 5, 5]\n'
        '[camera]\nposition = [2.0, 1.25, 0.2]\nlook_at = [2.0, 1.25, 3.0]\nup = [0, 1, 0]\n'
        'fov_y = 70\nresolution = 16\n')
    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["render", str(tmp_path / "scene.toml"), "--out", str(out),
                                  "--workers", "1", "--no-preview"])
    assert r.exit_code == 0, r.output
    rep = json.loads((out / "report.json").read_text())
    assert rep["solve"]["converged"]
    assert radiance(str(out))[:, 0].max() > 0
    mats = {m["material"]: m for m in rep["light"]["materials"]}
    assert mats["walls"]["illuminance"] > 0
