"""A bare mesh file as a scene (issue 27): its materials (glTF factors and texture means, MTL
Kd/Ke, PLY colours), the default camera (inside a closed room, outside an open one; the printed
[camera] table is the camera used), and the one-line refusal without an emitter."""

from __future__ import annotations

import tomllib
import warnings

import numpy as np
import pytest
import trimesh

from radiosity.errors import SceneError
from radiosity.scene.load import load_scene, parse_camera
from radiosity.core.colour import srgb_to_linear
from radiosity.scene.meshscene import DEFAULT_RESOLUTION

from helpers import edit_glb, glb_room  # noqa: E402
from radiosity.settings import options as settings_of

L, H, D = 4.0, 2.5, 3.0


def write_room(tmp_path, name="room.glb", **kw) -> str:
    fn = tmp_path / name
    fn.write_bytes(glb_room(**kw))
    return str(fn)


def _table_of(chosen: str) -> dict:
    """The [camera] table printed in Scene.chosen, read as TOML."""
    return tomllib.loads(chosen[chosen.index("[camera]"):])["camera"]


def _same_camera(a, b):
    for k in ("center", "x", "y", "z"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
    assert (a.focal, a.width, a.height, a.half_w, a.half_h) == \
        (b.focal, b.width, b.height, b.half_w, b.half_h)


def test_a_closed_glb_room_is_a_scene_seen_from_inside(tmp_path):
    fn = write_room(tmp_path, strength=4.0)
    sc = load_scene(fn, settings=settings_of())
    el = sc.elements
    assert sc.name == "room" and sc.path == fn
    assert set(el.material_names) == {"lamp", "red", "white"}
    m = {name: i for i, name in enumerate(el.material_names)}
    lamp = el.material == m["lamp"]
    np.testing.assert_allclose(el.emission[lamp, 0], 4.0)  # emissiveFactor x strength
    np.testing.assert_allclose(el.reflectance[el.material == m["red"], 0], [[0.7, 0.1, 0.1]],
                               atol=1 / 255)
    assert not el.emission[~lamp].any()
    # the camera: inside, along x (the longest horizontal axis), the whole far wall in view
    assert "inside: a closed room, looking along +x" in sc.chosen
    cam = sc.camera
    assert 0 < cam.center[0] < 0.1 * L and 0 < cam.center[1] < H and 0 < cam.center[2] < D
    np.testing.assert_allclose(cam.z, [1, 0, 0])
    assert (cam.width, cam.height) == (DEFAULT_RESOLUTION, DEFAULT_RESOLUTION)
    # what is printed is the camera used, to the bit, as parse_camera reads it
    table = _table_of(sc.chosen)
    _same_camera(parse_camera(table, "printed"), cam)
    assert table["resolution"] == [DEFAULT_RESOLUTION, DEFAULT_RESOLUTION]


def test_an_open_room_is_seen_from_its_open_side_and_resolution_overrides(tmp_path):
    from radiosity.settings import resolve
    from radiosity.runtime.checks import check_scene

    sc = load_scene(write_room(tmp_path, closed=False), resolution=(24, 16),
                    settings=settings_of())
    assert "outside: not a room (" in sc.chosen and "); from the -z side" in sc.chosen
    assert sc.camera.center[2] < 0 and (sc.camera.width, sc.camera.height) == (24, 16)
    _same_camera(parse_camera(_table_of(sc.chosen), "printed"), sc.camera)
    assert check_scene(sc, resolve())["hits"] > 0  # it sees the room


def test_a_mesh_without_an_emitter_is_refused_in_one_line(tmp_path):
    with pytest.raises(SceneError) as e:
        load_scene(write_room(tmp_path, name="dark.glb", emissive=(0.0, 0.0, 0.0)),
                   settings=settings_of())
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith("dark.glb has no emissive material (lamp, red, white): give one "
                          "material an emissiveFactor")
    assert 'write a scene.toml with [[mesh]] path = "dark.glb"' in msg
    assert "meshes-as-scenes.md" in msg


def test_obj_with_mtl_takes_kd_and_ke_and_says_what_is_missing(tmp_path):
    obj = ("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nv 0 1 0\nv 1 1 0\nv 1 1 1\nv 0 1 1\n"
           "usemtl floor\nf 1 4 3 2\nusemtl lamp\nf 5 6 7 8\n")
    (tmp_path / "box.obj").write_text(obj)
    (tmp_path / "m.mtl").write_text("newmtl floor\nKd 0.3 0.4 0.5\nnewmtl lamp\nKd 0.1 0.1 0.1\n"
                                    "Ke 5 4 3\n")
    sc = load_scene(str(tmp_path / "box.obj"), settings=settings_of())
    el = sc.elements
    f, lamp = (el.material_names.index(n) for n in ("floor", "lamp"))
    np.testing.assert_array_equal(el.reflectance[el.material == f, 0], [[0.3, 0.4, 0.5]])
    np.testing.assert_array_equal(el.emission[el.material == lamp, 0], [[5, 4, 3]])
    assert "outside" in sc.chosen  # two facing quads are no closed room
    (tmp_path / "m.mtl").write_text("newmtl floor\nKd 0.3 0.4 0.5\nnewmtl lamp\nKd 0.1 0.1 0.1\n")
    with pytest.raises(SceneError, match=r"box.obj has no emissive material \(floor, lamp\): give "
                                         r"one material of its MTL file a Ke line"):
        load_scene(str(tmp_path / "box.obj"), settings=settings_of())


def test_ply_colours_become_materials(tmp_path):
    """Face colours (8-bit sRGB) -> one material per colour, its reflectance the linear colour;
    a PLY holds no emission, which the refusal says."""
    m = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1], [0, 1, 0], [1, 1, 0]],
                        [[0, 3, 2], [0, 2, 1], [0, 1, 5], [0, 5, 4]], process=False)
    m.visual.face_colors = [[200, 30, 30, 255]] * 2 + [[128, 128, 128, 255]] * 2
    m.export(tmp_path / "c.ply")
    with pytest.raises(SceneError, match="c.ply has no emissive material .*a PLY file holds no "
                                         "emission, or write a scene.toml"):
        load_scene(str(tmp_path / "c.ply"), settings=settings_of())
    # in a scene file the colour materials can be given an emission
    (tmp_path / "s.toml").write_text(
        '[[mesh]]\npath = "c.ply"\n[material.colour-808080]\nemission = [1, 1, 1]\n'
        '[camera]\nposition = [0.5, 0.5, 3]\nlook_at = [0.5, 0.5, 0]\nfov_y = 60\nresolution = 8\n')
    el = load_scene(str(tmp_path / "s.toml"), settings=settings_of()).elements
    assert el.material_names == ("colour-808080", "colour-c81e1e")
    np.testing.assert_allclose(el.reflectance[el.material == 1, 0],
                               [srgb_to_linear(np.array([200, 30, 30]) / 255)])
    np.testing.assert_array_equal(el.emission[el.material == 0, 0], [[1, 1, 1]])


def test_gltf_texture_means_and_a_material_without_base_colour(tmp_path):
    """baseColorTexture: the factor times the texture's mean linear colour; a material with no
    baseColorFactor (glTF's default is 1, which would create energy): the default 0.5."""
    from PIL import Image

    img = Image.new("RGB", (4, 4), (188, 188, 94))
    fn = tmp_path / "t.glb"
    fn.write_bytes(edit_glb(glb_room(baseColorTexture=img), lambda doc: [
        m["pbrMetallicRoughness"].pop("baseColorFactor")
        for m in doc["materials"] if m.get("name") == "white"]))
    el = load_scene(str(fn), settings=settings_of()).elements
    names = el.material_names
    lamp = el.material == names.index("lamp")
    want = 0.5 * srgb_to_linear(np.array([188, 188, 94]) / 255)
    np.testing.assert_allclose(el.reflectance[lamp, 0], [want], rtol=1 / 250)  # 8-bit factor
    np.testing.assert_array_equal(el.reflectance[el.material == names.index("white"), 0][0],
                                  [0.5, 0.5, 0.5])


def test_resolution_must_be_whole_pixels_in_a_scene_file(tmp_path):
    from helpers import FLOOR_AND_TRIANGLE, write_scene

    cam = ('[camera]\nposition = [0, 2, 0]\nlook_at = [0, 0, 0]\nup = [0, 0, 1]\nfov_y = 60\n'
           'resolution = 64.5\n')
    fn = write_scene(tmp_path, FLOOR_AND_TRIANGLE, "[material.default]\nemission = [1, 1, 1]\n",
                     camera=cam)
    with pytest.raises(SceneError, match=r"scene.toml \[camera\]: resolution must be a whole "
                                         r"number of pixels: N, \[W, H\] or 'WxH', got 64.5"):
        load_scene(fn, settings=settings_of())


def test_the_cornell_box_loads_without_a_warning():
    from helpers import scene_path

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        el = load_scene(scene_path("cornell-box"), settings=settings_of()).elements
    assert len(el) == 20 and (el.nverts == 3).sum() == 2  # the red wall's two triangles


# ----------------------------------------------------------------------------- as users bring them

def _office(tmp_path, name="office.glb", **kw) -> str:
    from office import glb_office

    fn = tmp_path / name
    fn.write_bytes(glb_office(**kw))
    return str(fn)


def test_a_room_with_a_window_is_seen_from_inside(tmp_path):
    """A window opening lets a few of the camera's rays out: still a room, the camera goes
    inside (it used to go outside, "not a closed room", and look at the walls' backs); the
    summary says why."""
    from office import OFFICE
    from radiosity.runtime.checks import check_scene
    from radiosity.settings import resolve

    sc = load_scene(_office(tmp_path), settings=settings_of())
    assert "inside: a room with openings (" in sc.chosen, sc.chosen
    assert "rays from the camera leave through them), looking along +x" in sc.chosen
    assert np.all((sc.camera.center > 0) & (sc.camera.center < OFFICE))
    _same_camera(parse_camera(_table_of(sc.chosen), "printed"), sc.camera)
    fig = check_scene(sc, resolve())["orientation"]
    assert fig["camera_lit"] == fig["camera_rays"] > 0  # only fronts: no wall backs


def test_a_mesh_wound_inside_out_is_turned_and_said(tmp_path):
    """The office exported inside out, given alone: its parts are turned by what they are (the
    room in, the table and lamp out: the elements are the right file's), in one warning line
    naming the file; it used to render black with exit 0 and no word."""
    good = load_scene(_office(tmp_path), settings=settings_of())
    with pytest.warns(UserWarning) as said:
        bad = load_scene(_office(tmp_path, "flipped.glb", flipped=True), settings=settings_of())
    lines = [str(w.message) for w in said if "turned" in str(w.message)]
    assert len(lines) == 1 and "\n" not in lines[0], lines
    assert "flipped.glb: turned 3 of its 3 connected parts that were wound inside out: the " \
           "room's shell (its normals pointed out), 2 closed solids (normals in)" in lines[0]
    assert 'orient = "as-is" keeps the file' in lines[0]
    a, b = good.elements, bad.elements
    np.testing.assert_allclose(_by_centre(b), _by_centre(a), atol=1e-12)
    ia, ib = (np.lexsort(np.round(e.center, 9).T) for e in (a, b))
    np.testing.assert_array_equal(b.emission[ib], a.emission[ia])
    _same_camera(bad.camera, good.camera)


@pytest.mark.parametrize("flipped", [{"room"}, True])
def test_orient_inward_in_a_scene_file_turns_each_part(tmp_path, flipped):
    """`orient = "inward"` in a scene file on the office whose room's shell points out (a box
    turned into a room; the furniture as modelled) or that is inside out as a whole: the shell
    in, the table and the lamp out of their own volumes (turning the whole mesh at once by its
    total volume, the room's, turned the right furniture inside out)."""
    from office import TABLE

    _office(tmp_path, "flipped.glb", flipped=flipped)
    good = load_scene(_office(tmp_path), settings=settings_of()).elements
    (tmp_path / "scene.toml").write_text(
        '[[mesh]]\npath = "flipped.glb"\norient = "inward"\n[camera]\nposition = [0.3, 1.5, 2]\n'
        'look_at = [5, 1.2, 2]\nfov_y = 60\nresolution = 16\n')
    el = load_scene(str(tmp_path / "scene.toml"), settings=settings_of()).elements
    lo, hi = np.array(TABLE)
    top = np.isclose(el.center[:, 1], hi[1]) & np.all((el.center > lo) & (el.center < hi + 1e-9),
                                                    axis=1)
    assert top.any() and np.allclose(el.normal[top], [0, 1, 0])  # the table top faces up
    np.testing.assert_allclose(_by_centre(el), _by_centre(good), atol=1e-12)


def _by_centre(el) -> np.ndarray:
    """The elements' normals in the order of their centres (two loads of one geometry)."""
    return el.normal[np.lexsort(np.round(el.center, 9).T)]
