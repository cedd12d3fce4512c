"""Scene files and meshes: loaders keep quads, materials resolve, bad input says what is wrong."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from radiosity.errors import SceneError
from radiosity.formats.raw import SceneWarning
from radiosity.scene.load import load_scene, parse_camera
from radiosity.scene.meshes import merge_parallelograms
from helpers import FLOOR_AND_TRIANGLE, write_scene
from radiosity.settings import options as settings_of

QUAD = """
v 0 0 0
v 1 0 0
v 1 0 1
v 0 0 1
f 1 4 3 2
"""


def test_obj_quads_stay_quads_and_normals_follow_winding(small_scene):
    sc = load_scene(small_scene, settings=settings_of())
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
    sc = load_scene(write_scene(tmp_path, obj, extra, mtl=mtl), settings=settings_of())
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
    sc = load_scene(write_scene(tmp_path, obj), settings=settings_of())
    el = sc.elements
    assert sorted(el.nverts.tolist()) == [3, 4]
    q = np.nonzero(el.nverts == 4)[0][0]
    np.testing.assert_allclose(el.area[q], 2.0)
    np.testing.assert_allclose(el.normal[q], [0, 1, 0])  # winding kept


def test_non_parallelogram_pairs_do_not_merge():
    tri = np.array([[[0, 0, 0], [1, 0, 1], [1, 0, 0], [1, 0, 0]],
                    [[0, 0, 0], [0.3, 0, 1.2], [1, 0, 1], [1, 0, 1]]], float)
    v, n, f, m = merge_parallelograms(tri, np.array([3, 3], np.int8), np.array([0, 1]), ["a", "a"],
                                      settings_of().scene.merge_tolerance)
    assert list(n) == [3, 3]


def test_non_planar_quad_is_split_with_warning(tmp_path):
    obj = QUAD.replace("v 1 0 1", "v 1 0.2 1")
    with pytest.warns(SceneWarning, match="face 1 .*non-planar quad; split into two triangles"):
        sc = load_scene(write_scene(tmp_path, obj), settings=settings_of())
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
        sc = load_scene(write_scene(tmp_path, obj), settings=settings_of())
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
    sc = load_scene(str(tmp_path / "scene.toml"), settings=settings_of())
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
    el = load_scene(str(tmp_path / "scene.toml"), settings=settings_of()).elements
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
        load_scene(write_scene(tmp_path, obj, extra, camera=camera), settings=settings_of())


def test_missing_unreadable_and_unknown_files(tmp_path):
    with pytest.raises(SceneError, match="scene file not found"):
        load_scene(str(tmp_path / "nope.toml"), settings=settings_of())
    (tmp_path / "a.toml").write_text('[[mesh]]\npath = "gone.obj"\n' + CAM)
    with pytest.raises(SceneError, match=r"mesh file not found: .*gone.obj"):
        load_scene(str(tmp_path / "a.toml"), settings=settings_of())
    (tmp_path / "b.toml").write_text('[[mesh]]\npath = "m.step"\n' + CAM)
    (tmp_path / "m.step").write_text("ISO-10303-21;\n")
    with pytest.raises(SceneError, match=r"unknown mesh format '.step' of .*m.step: use one of "
                                         r"\.obj, .*\.stl"):
        load_scene(str(tmp_path / "b.toml"), settings=settings_of())
    os.mkdir(tmp_path / "dir.obj")
    (tmp_path / "c.toml").write_text('[[mesh]]\npath = "dir.obj"\n' + CAM)
    with pytest.raises(SceneError, match=r"cannot read mesh file .*dir.obj"):
        load_scene(str(tmp_path / "c.toml"), settings=settings_of())
    (tmp_path / "d.toml").write_text("[[mesh]\npath=")
    with pytest.raises(SceneError, match=r"d.toml: not valid TOML"):
        load_scene(str(tmp_path / "d.toml"), settings=settings_of())
    (tmp_path / "e.toml").write_text(CAM)
    with pytest.raises(SceneError, match=r"no \[\[mesh\]\] entries: the scene is empty"):
        load_scene(str(tmp_path / "e.toml"), settings=settings_of())


def test_camera_that_sees_nothing(tmp_path, client):
    from radiosity.stages.preprocess import preprocess

    cam = CAM.replace("look_at = [0.5, 0.0, 0.5]", "look_at = [0.5, 4.0, -5.0]")
    sc = load_scene(write_scene(tmp_path, FLOOR_AND_TRIANGLE, camera=cam), settings=settings_of())
    with pytest.raises(SceneError, match="the camera sees no element"):
        preprocess(sc, str(tmp_path / "run"), client, settings_of(), progress=False)


# ----------------------------------------------------------------------------- whole-array loader

def _reference_polygons(V, faces, mats, tol):
    """polygons_from_raw(merge=False) as the per-face loop it replaced: (polygons, warnings) or
    (the error line, warnings)."""
    from radiosity.settings import resolve

    out, said = [], []
    for fi, idx in enumerate(faces):
        bad = [k for k in idx if not 0 <= k < len(V)]
        if bad:
            return f"face {fi + 1} refers to vertex {bad[0]}", said
        if len(idx) < 3:
            return f"face {fi + 1} has {len(idx)} vertices", said
        p = V[idx]
        if not np.all(np.isfinite(p)):
            return f"face {fi + 1} has a NaN", said
        if np.abs(p).max() > 1e75:
            return f"face {fi + 1} has a vertex coordinate of {np.abs(p).max():.3g}", said
        if len(idx) == 3:
            polys = [p[[0, 1, 2, 2]]]
        elif len(idx) == 4:
            n = np.cross(p[1] - p[0], p[2] - p[0]) + np.cross(p[2] - p[0], p[3] - p[0])
            nn = np.linalg.norm(n)
            diam = np.max(np.linalg.norm(p[:, None] - p[None], axis=-1))
            off = abs(np.dot(p[3] - p[0], np.cross(p[1] - p[0], p[2] - p[0])))
            c012 = np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0]))
            planar = nn > 0 and c012 > 0 and off / c012 <= tol * max(diam, 1e-300)
            convex = planar and all(np.dot(np.cross(p[(k + 1) % 4] - p[k], p[(k + 2) % 4] - p[(k + 1) % 4]),
                                           n / nn) > 0 for k in range(4))
            if convex:
                polys = [p]
            else:
                said.append(f"face {fi + 1} (material '{mats[fi]}') is a "
                            f"{'non-planar' if not planar else 'non-convex'} quad")
                polys = [p[[0, 1, 2, 2]], p[[0, 2, 3, 3]]]
                if planar and np.dot(np.cross(p[2] - p[0], p[3] - p[0]), np.cross(p[1] - p[0], p[2] - p[0])) <= 0:
                    polys = [p[[1, 2, 3, 3]], p[[1, 3, 0, 0]]]
        else:
            said.append(f"face {fi + 1} has {len(idx)} vertices; triangulated as a fan")
            polys = [p[[0, k, k + 1, k + 1]] for k in range(1, len(idx) - 1)]
        out += [(q, fi) for q in polys]
    from radiosity.core.geometry import diameter, polygon_properties

    v = np.array([q for q, _ in out]).reshape(-1, 4, 3)
    n = np.array([3 if np.array_equal(q[3], q[2]) else 4 for q, _ in out], np.int8)
    area = polygon_properties(v, n)[0]
    bad = np.nonzero(~(area > resolve().scene.min_relative_area * diameter(v, n) ** 2))[0]
    if len(bad):
        fi = out[bad[0]][1]
        return (f"face {fi + 1} (material '{mats[fi]}') has zero area"
                + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else "")), said
    return out, said


def _reference_merge(verts, nverts, mats, tol):
    """merge_parallelograms as the dict-of-edges loop it replaced: the kept rows and the quads."""
    tri = np.nonzero(nverts == 3)[0]
    _, vid = np.unique(verts[tri, :3].reshape(-1, 3), axis=0, return_inverse=True)
    vid = vid.reshape(-1, 3)
    edges: dict = {}
    for k in range(len(tri)):
        for e in range(3):
            a, b = vid[k, e], vid[k, (e + 1) % 3]
            edges.setdefault((min(a, b), max(a, b)), []).append((k, e))
    partner, quads = -np.ones(len(tri), int), {}
    for k in range(len(tri)):
        for e in range(3 if partner[k] < 0 else 0):
            a, b = vid[k, e], vid[k, (e + 1) % 3]
            for j, ej in edges[(min(a, b), max(a, b))]:
                if j == k or partner[j] >= 0 or mats[tri[j]] != mats[tri[k]] or vid[j, ej] != b:
                    continue
                P, Q = verts[tri[k]], verts[tri[j]]
                pa, pb, px, qy = P[e], P[(e + 1) % 3], P[(e + 2) % 3], Q[(ej + 2) % 3]
                d = max(np.linalg.norm(pa - pb), np.linalg.norm(px - qy))
                n1, n2 = np.cross(pb - pa, px - pa), np.cross(pa - pb, qy - pb)
                if (np.linalg.norm((pa + pb) - (px + qy)) > tol * d or np.dot(n1, n2) <= 0
                        or np.linalg.norm(np.cross(n1, n2)) > tol * np.linalg.norm(n1) * np.linalg.norm(n2)):
                    continue
                partner[k], partner[j] = j, k
                quads[int(tri[k])] = np.array([pb, px, pa, qy])
                break
            if partner[k] >= 0:
                break
    drop = {int(tri[partner[k]]) for k in range(len(tri)) if int(tri[k]) in quads}
    return [i for i in range(len(verts)) if i not in drop], quads


def test_whole_array_polygons_match_the_per_face_loop(monkeypatch):
    """Random meshes (grid points: coplanar, collinear, repeated; NaN, huge and missing
    vertices; 2 to 6 vertices a face): the same polygons to the bit, the same repairs said in
    face order (every one: no cap here), the same first bad face named."""
    import warnings

    from radiosity.scene import meshes
    from radiosity.scene.meshes import RawMesh, polygons_from_raw
    from radiosity.settings import resolve

    monkeypatch.setattr(meshes, "MAX_FACE_WARNINGS", 10 ** 9)

    rng = np.random.default_rng(11)
    for trial in range(400):
        nv = int(rng.integers(0, 14))
        V = rng.integers(-2, 3, size=(nv, 3)).astype(float) if trial % 2 else rng.normal(size=(nv, 3))
        if nv and trial % 7 == 0:
            V[rng.integers(nv), rng.integers(3)] = rng.choice([np.nan, np.inf, 3e80])
        faces = [[int(k) for k in rng.integers(0, max(nv, 1), int(rng.choice([3, 3, 4, 4, 4, 5, 6, 2])))]
                 for _ in range(int(rng.integers(1, 12)))]
        if trial % 11 == 0:
            faces[int(rng.integers(len(faces)))][0] = nv + 3
        mats = [str(rng.choice(["a", "b"])) for _ in faces]
        want, said = _reference_polygons(V, faces, mats, resolve().scene.planarity_tolerance)
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            try:
                v, n, f, m = polygons_from_raw(RawMesh(V, faces, mats), "m.obj", settings_of(),
                                               merge=False)
                got = None
            except SceneError as e:
                got = str(e)
        assert [str(x.message).split("; split")[0] for x in w] == [f"m.obj: {s}" for s in said]
        if isinstance(want, str):
            assert got is not None and got.startswith(f"m.obj: {want}"), (got, want)
            continue
        assert got is None, got
        assert len(v) == len(want)
        np.testing.assert_array_equal(v, np.array([q for q, _ in want]).reshape(-1, 4, 3))
        np.testing.assert_array_equal(f, [fi for _, fi in want])
        assert n.dtype == np.int8 and list(n) == [3 if np.array_equal(q[3], q[2]) else 4 for q, _ in want]
        assert m == [mats[fi] for _, fi in want]


def test_merge_matches_the_edge_dictionary_loop():
    """Triangle soups on a few grid points, flat, tilted (rounding noise) or bumped by 1e-12,
    with quads and two materials among them: the same greedy pairs (the first valid partner,
    edges 0, 1, 2, candidates in file order) and the same arrays, to the bit."""
    rng = np.random.default_rng(12)
    for trial in range(60):
        t = int(rng.integers(2, 200))
        verts = np.zeros((t, 4, 3))
        verts[:, :3, :2] = rng.integers(0, 4, size=(t, 3, 2))
        if trial % 3 == 1:
            verts[:, :3] = verts[:, :3] @ np.array([[0.6, 0.8, 0.1], [-0.8, 0.6, 0.3], [0, 0, 1.0]])
        if trial % 3 == 2:
            verts[:, :3, 2] += rng.choice([0, 0, 1e-12], size=(t, 3))
        verts[:, 3] = verts[:, 2]
        nverts = np.where(rng.random(t) < 0.1, 4, 3).astype(np.int8)
        mats = [str(x) for x in rng.choice(["a", "a", "b"], t)]
        face = np.arange(t, dtype=np.int32)
        for tol in (1e-9, 0.3):
            keep, quads = _reference_merge(verts, nverts, mats, tol)
            v, n, f, m = merge_parallelograms(verts, nverts, face, mats, tol)
            want = verts.copy()
            want_n = nverts.copy()
            for i, q in quads.items():
                want[i], want_n[i] = q, 4
            np.testing.assert_array_equal(v, want[keep])
            np.testing.assert_array_equal(n, want_n[keep])
            np.testing.assert_array_equal(f, face[keep])
            assert m == [mats[i] for i in keep]


def test_a_grid_of_triangle_pairs_merges_back_into_quads(tmp_path):
    """300 x 300 squares of a plane, each as two triangles sharing a diagonal (as
    benchmarks/scenes_generated writes them, a vertex per corner of each triangle): every
    triangle finds a partner, 90 000 quads covering the square."""
    n = 300
    x = np.linspace(0, 3.0, n + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    P = np.stack([X, np.zeros_like(X), Y], -1)
    a, b, c, d = P[:-1, :-1], P[1:, :-1], P[1:, 1:], P[:-1, 1:]
    tris = np.concatenate([np.stack([a, c, b], -2).reshape(-1, 3, 3),
                           np.stack([a, d, c], -2).reshape(-1, 3, 3)])
    lines = ["v %.17g %.17g %.17g" % tuple(p) for p in tris.reshape(-1, 3)]
    lines += ["f %d %d %d" % (3 * k + 1, 3 * k + 2, 3 * k + 3) for k in range(len(tris))]
    el = load_scene(write_scene(tmp_path, "\n".join(lines) + "\n"), settings=settings_of()).elements
    assert len(el) == n * n and np.all(el.nverts == 4)
    assert el.area.sum() == pytest.approx(9.0, rel=1e-12)
    np.testing.assert_allclose(el.normal, np.broadcast_to([0, 1.0, 0], (n * n, 3)))


def test_many_repairs_are_said_ten_times_then_counted(tmp_path):
    """25 non-planar quads: the first 10 named one by one, then one line for the other 15."""
    import warnings

    rows = []
    for k in range(25):
        rows += [f"v {k} 0 0", f"v {k + 1} 0.3 0", f"v {k + 1} 0 1", f"v {k} 0 1",
                 f"f {4 * k + 1} {4 * k + 4} {4 * k + 3} {4 * k + 2}"]
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        el = load_scene(write_scene(tmp_path, "\n".join(rows) + "\n"), settings=settings_of()).elements
    said = [str(x.message) for x in w if issubclass(x.category, SceneWarning)]
    assert len(said) == 11 and len(el) == 50
    assert all(f"face {k + 1} (material 'default') is a non-planar quad" in s for k, s in enumerate(said[:10]))
    assert said[10].endswith("and 15 more faces split into triangles likewise "
                             "(non-planar or non-convex quads, n-gons)")


def test_the_first_bad_face_is_named_and_the_repairs_before_it_said(tmp_path):
    """A non-convex quad (face 1), a missing coordinate (face 3: NaN) and a huge one (face 4):
    face 3 is named, face 1's repair said before the error."""
    obj = ("v 0 0 0\nv 0 0 1\nv 0.2 0 0.2\nv 1 0 0\nv nan 0 0\nv 1e80 0 0\n"
           "f 1 2 3 4\nf 1 2 4\nf 1 5 2\nf 1 6 2\n")
    with pytest.warns(SceneWarning, match="face 1 .*non-convex quad"):
        with pytest.raises(SceneError, match=r"mesh.obj: face 3 has a NaN or infinite vertex coordinate"):
            load_scene(write_scene(tmp_path, obj), settings=settings_of())


def test_a_quad_with_three_collinear_vertices_is_split_along_the_other_diagonal(tmp_path):
    """Vertex 3 on the diagonal 0-2 (the halves (0, 1, 2) and (0, 2, 3) do not face opposite
    ways: one is empty): not convex, split along 1-3 into two proper triangles, not into one
    with zero area."""
    obj = "v 0 0 0\nv 1 0 1\nv 2 0 0\nv 1 0 0\nf 1 2 3 4\n"
    with pytest.warns(SceneWarning, match="face 1 .*non-convex quad"):
        el = load_scene(write_scene(tmp_path, obj), settings=settings_of()).elements
    assert list(el.nverts) == [3, 3]
    np.testing.assert_array_equal(el.verts[:, 0], [[1, 0, 1], [1, 0, 1]])  # both from vertex 1
    assert el.area.sum() == pytest.approx(1.0)
