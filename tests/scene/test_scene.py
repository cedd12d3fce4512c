"""Scene files and meshes: loaders keep quads, materials resolve, bad input says what is wrong."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from radiosity.errors import SceneError
from radiosity.scene.load import SceneWarning, load_scene, merge_parallelograms, parse_camera
from helpers import FLOOR_AND_TRIANGLE, write_scene

QUAD = """
v 0 0 0
v 1 0 0
v 1 0 1
v 0 0 1
f 1 4 3 2
"""


def test_obj_quads_stay_quads_and_normals_follow_winding(small_scene):
    sc = load_scene(small_scene)
    el = sc.elements
    assert list(el.nverts) == [4, 3]
    np.testing.assert_allclose(el.normal[0], [0, 1, 0])
    np.testing.assert_allclose(el.area[0], 1.0)
    np.testing.assert_allclose(el.center[0], [0.5, 0, 0.5])
    np.testing.assert_allclose(el.reflectance[0, 0], 0.5)
    assert not el.two_sided.any()
    assert np.all(el.reflectance[:, 1] == 0) and np.all(el.emission[:, 1] == 0)


def test_mtl_materials_and_overrides_two_sided_back_material(tmp_path):
    obj = "mtllib mesh.mtl\n" + QUAD.replace("f 1", "usemtl panel\nf 1") + \
          "v 0 1 0\nv 1 1 0\nv 1 1 1\nusemtl lamp\nf 5 6 7\n"
    mtl = "newmtl panel\nKd 0.2 0.3 0.4\nnewmtl lamp\nKd 0.1 0.1 0.1\nKe 5 6 7\n"
    extra = """
    [material.panel]
    two_sided = true
    back_reflectance = [0.9, 0.1, 0.1]
    [material.lamp]
    emission = [1.0, 2.0, 3.0]
    """
    sc = load_scene(write_scene(tmp_path, obj, extra, mtl=mtl))
    el = sc.elements
    names = [el.material_names[m] for m in el.material]
    i, j = names.index("panel"), names.index("lamp")
    assert el.two_sided[i] and not el.two_sided[j]
    np.testing.assert_allclose(el.reflectance[i], [[0.2, 0.3, 0.4], [0.9, 0.1, 0.1]])
    np.testing.assert_allclose(el.emission[j, 0], [1, 2, 3])  # TOML wins over Ke
    np.testing.assert_allclose(el.emission[j, 1], 0)


def test_parallelogram_triangle_pairs_merge_into_quads(tmp_path):
    # a 2x1 rectangle as two triangles sharing the diagonal, plus an unrelated triangle
    obj = """
    v 0 0 0
    v 2 0 0
    v 2 0 1
    v 0 0 1
    v 5 0 0
    v 6 0 0
    v 5 0 1
    f 1 4 3
    f 1 3 2
    f 5 7 6
    """
    sc = load_scene(write_scene(tmp_path, obj))
    el = sc.elements
    assert sorted(el.nverts.tolist()) == [3, 4]
    q = np.nonzero(el.nverts == 4)[0][0]
    np.testing.assert_allclose(el.area[q], 2.0)
    np.testing.assert_allclose(el.normal[q], [0, 1, 0])  # winding kept


def test_non_parallelogram_pairs_do_not_merge():
    tri = np.array([[[0, 0, 0], [1, 0, 1], [1, 0, 0], [1, 0, 0]],
                    [[0, 0, 0], [0.3, 0, 1.2], [1, 0, 1], [1, 0, 1]]], float)
    v, n, f, m = merge_parallelograms(tri, np.array([3, 3], np.int8), np.array([0, 1]), ["a", "a"])
    assert list(n) == [3, 3]


def test_non_planar_quad_is_split_with_warning(tmp_path):
    obj = QUAD.replace("v 1 0 1", "v 1 0.2 1")
    with pytest.warns(SceneWarning, match="face 1 .*non-planar quad; split into two triangles"):
        sc = load_scene(write_scene(tmp_path, obj))
    assert list(sc.elements.nverts) == [3, 3]


def test_non_convex_quad_is_split_with_warning(tmp_path):
    obj = """
    v 0 0 0
    v 0 0 1
    v 0.2 0 0.2
    v 1 0 0
    f 1 2 3 4
    """
    with pytest.warns(SceneWarning, match="non-convex"):
        sc = load_scene(write_scene(tmp_path, obj))
    el = sc.elements
    assert list(el.nverts) == [3, 3]
    # both halves face the same way and cover the quad's area
    assert np.all(el.normal @ el.normal[0] > 0.999)


def test_gltf_materials_emissive_strength_and_double_sided(tmp_path):
    import trimesh  # a dependency: never skipped
    box = trimesh.creation.box(extents=[1, 1, 1])
    box.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        name="glow", baseColorFactor=[0.2, 0.4, 0.6, 1.0], emissiveFactor=[1.0, 0.5, 0.25],
        doubleSided=True))
    s = trimesh.Scene()
    s.add_geometry(box, node_name="n", transform=trimesh.transformations.translation_matrix([0, 0, 5]))
    files = s.export(file_type="gltf")
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    doc = json.loads((tmp_path / "model.gltf").read_text())
    doc["materials"][0].setdefault("extensions", {})["KHR_materials_emissive_strength"] = {"emissiveStrength": 4.0}
    (tmp_path / "model.gltf").write_text(json.dumps(doc))
    (tmp_path / "scene.toml").write_text(
        '[[mesh]]\npath = "model.gltf"\n[camera]\nposition = [0, 0, 0]\nlook_at = [0, 0, 1]\n'
        'up = [0, 1, 0]\nfov_y = 40\nresolution = 8\n')
    sc = load_scene(str(tmp_path / "scene.toml"))
    el = sc.elements
    assert len(el) == 6 and np.all(el.nverts == 4)  # 12 triangles merged back into 6 quads
    np.testing.assert_allclose(el.reflectance[:, 0], [[0.2, 0.4, 0.6]] * 6)
    np.testing.assert_allclose(el.emission[:, 0], [[4.0, 2.0, 1.0]] * 6)
    assert el.two_sided.all()
    np.testing.assert_allclose(el.center.mean(0), [0, 0, 5], atol=1e-12)  # node transform applied


def test_ply_with_mesh_material(tmp_path):
    import trimesh  # a dependency: never skipped
    tri = trimesh.Trimesh(vertices=[[0, 0, 1], [1, 0, 1], [0, 1, 1]], faces=[[0, 1, 2]], process=False)
    tri.export(tmp_path / "t.ply")
    (tmp_path / "scene.toml").write_text(
        '[[mesh]]\npath = "t.ply"\nmaterial = "screen"\n[material.screen]\nreflectance = [0.3, 0.3, 0.3]\n'
        '[camera]\nposition = [0.2, 0.2, 3]\nlook_at = [0.2, 0.2, 0]\nup = [0, 1, 0]\nfov_y = 40\nresolution = 8\n')
    el = load_scene(str(tmp_path / "scene.toml")).elements
    assert el.material_names == ("screen",)
    np.testing.assert_allclose(el.reflectance[0, 0], 0.3)


def test_both_camera_forms_agree():
    a = parse_camera({"position": [0, 0, 0], "look_at": [0, 0, 5], "up": [0, 1, 0], "fov_y": 90.0,
                      "resolution": [16, 16]}, "x.toml")
    b = parse_camera({"center": [0, 0, 0], "x": a.x.tolist(), "y": [0, 1, 0], "z": [0, 0, 1],
                      "focal_distance": 1.0, "resolution": [16, 16]}, "x.toml")
    from radiosity.core.camera import pixel_directions
    np.testing.assert_allclose(pixel_directions(a), pixel_directions(b), atol=1e-12)


# ----------------------------------------------------------------------------- bad input

CAM = """
[camera]
position = [0.5, 2.0, -1.5]
look_at = [0.5, 0.0, 0.5]
up = [0.0, 1.0, 0.0]
fov_y = 50.0
resolution = [8, 8]
"""


@pytest.mark.parametrize("obj, extra, camera, match", [
    (QUAD.replace("v 1 0 1", "v nan 0 1"), "", CAM, r"mesh.obj: face 1 has a NaN or infinite"),
    (QUAD.replace("v 1 0 1", "v inf 0 1"), "", CAM, r"mesh.obj: face 1 has a NaN or infinite"),
    (QUAD + "f 1 2 1\n", "", CAM, r"mesh.obj: face 2 .* has zero area"),
    (QUAD, "[material.default]\nreflectance = [0.5, 1.0, 0.5]\n", CAM,
     r"material 'default' reflectance .* outside \[0, 1\)"),
    (QUAD, "[material.default]\nreflectance = [0.5, -0.1, 0.5]\n", CAM, r"outside \[0, 1\)"),
    (QUAD, "[material.default]\nemission = [1, -1, 0]\n", CAM, r"material 'default' emission .* negative"),
    ("# nothing\n", "", CAM, r"meshes hold no faces: the scene is empty"),
    (QUAD, "", CAM.replace("resolution = [8, 8]", "resolution = [0, 8]"), r"resolution must be positive"),
    (QUAD, "", CAM.replace("resolution = [8, 8]", "resolution = -4"), r"resolution must be positive"),
    (QUAD, "", "[camera]\ncenter=[0,1,0]\nx=[1,0,0]\ny=[0,1,0.1]\nz=[0,0,1]\nfocal_distance=1\nresolution=8\n",
     r"camera basis x, y, z is not orthonormal"),
    (QUAD, "", "", r"\[camera\] is missing"),
    (QUAD, "[material.default]\ncolour = [1, 1, 1]\n", CAM, r"\[material.default\] has unknown key"),
    ("f 1 2 3\n", "", CAM, r"mesh.obj:1: face refers to vertex 1 that does not exist"),
])
def test_bad_input_names_the_culprit(tmp_path, obj, extra, camera, match):
    with pytest.raises(SceneError, match=match):
        load_scene(write_scene(tmp_path, obj, extra, camera=camera))


def test_missing_unreadable_and_unknown_files(tmp_path):
    with pytest.raises(SceneError, match="scene file not found"):
        load_scene(str(tmp_path / "nope.toml"))
    (tmp_path / "a.toml").write_text('[[mesh]]\npath = "gone.obj"\n' + CAM)
    with pytest.raises(SceneError, match=r"mesh file not found: .*gone.obj"):
        load_scene(str(tmp_path / "a.toml"))
    (tmp_path / "b.toml").write_text('[[mesh]]\npath = "m.stl"\n' + CAM)
    (tmp_path / "m.stl").write_text("solid x\n")
    with pytest.raises(SceneError, match=r"unknown mesh format '.stl' of .*m.stl"):
        load_scene(str(tmp_path / "b.toml"))
    os.mkdir(tmp_path / "dir.obj")
    (tmp_path / "c.toml").write_text('[[mesh]]\npath = "dir.obj"\n' + CAM)
    with pytest.raises(SceneError, match=r"cannot read mesh file .*dir.obj"):
        load_scene(str(tmp_path / "c.toml"))
    (tmp_path / "d.toml").write_text("[[mesh]\npath=")
    with pytest.raises(SceneError, match=r"d.toml: not valid TOML"):
        load_scene(str(tmp_path / "d.toml"))
    (tmp_path / "e.toml").write_text(CAM)
    with pytest.raises(SceneError, match=r"no \[\[mesh\]\] entries: the scene is empty"):
        load_scene(str(tmp_path / "e.toml"))


def test_camera_that_sees_nothing(tmp_path, client):
    from radiosity.stages.preprocess import preprocess

    cam = CAM.replace("look_at = [0.5, 0.0, 0.5]", "look_at = [0.5, 4.0, -5.0]")
    sc = load_scene(write_scene(tmp_path, FLOOR_AND_TRIANGLE, camera=cam))
    with pytest.raises(SceneError, match="the camera sees no element"):
        preprocess(sc, str(tmp_path / "run"), client, progress=False)
