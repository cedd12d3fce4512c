"""Several cameras in one scene ([[camera]] entries, issue 28): the subdivision follows every
camera (the union of each camera's partition), one solve, one image per camera. Each camera's
image against a render of a scene with that camera alone, per surface."""

from __future__ import annotations

import os

import numpy as np
import pytest

from helpers import per_surface, scene_path
from radiosity.settings import options as settings_of

R = 32
FRONT = dict(position=[278.0, 273.0, -800.0], look_at=[278.0, 273.0, 0.0], up=[0.0, 1.0, 0.0],
             fov_y=39.3)
ABOVE = dict(position=[278.0, 540.0, 280.0], look_at=[278.0, 0.0, 280.0], up=[0.0, 0.0, 1.0],
             fov_y=80.0)


def table_text(header: str, cam: dict, name: str | None = None) -> str:
    lines = [header] + ([f'name = "{name}"'] if name else [])
    return "\n".join(lines + [f"{k} = {v}" for k, v in cam.items()] + [f"resolution = {R}", ""])


def cornell_with(cameras: str) -> str:
    """The Cornell box's scene file with its [camera] table replaced by `cameras`."""
    src = open(scene_path("cornell-box")).read()
    i = src.index("[camera]")
    j = src.find("\n[", i + 1)
    mesh_dir = os.path.dirname(scene_path("cornell-box"))
    return (src[:i] + cameras + (src[j:] if j >= 0 else "")).replace('path = "',
                                                                     f'path = "{mesh_dir}/')


# ----------------------------------------------------------------------------- the loader

def test_camera_entries_are_named_and_the_first_is_the_runs_own(tmp_path):
    from radiosity.scene.load import load_scene

    f = tmp_path / "two.toml"
    f.write_text(cornell_with(table_text("[[camera]]", FRONT, "front") + "\n"
                              + table_text("[[camera]]", ABOVE)))
    sc = load_scene(str(f), settings=settings_of())
    assert [n for n, _ in sc.views] == ["camera-2"]
    assert np.allclose(sc.camera.center, FRONT["position"])
    assert np.allclose(sc.views[0][1].center, ABOVE["position"])
    assert len(sc.cameras) == 2 and sc.cameras[0] is sc.camera
    one = load_scene(scene_path("cornell-box"), settings=settings_of())
    assert one.views == () and len(one.cameras) == 1


@pytest.mark.parametrize("second, says", [
    (table_text("[[camera]]", ABOVE, "front"), "used twice"),
    (table_text("[[camera]]", ABOVE, "a b"), "letters, digits"),
    ("[[camera]]\nname = \"x\"\nposition = [0, 0, 0]\nresolution = 8\n", "look_at"),
])
def test_bad_camera_entries_are_one_line_naming_the_entry(tmp_path, second, says):
    from radiosity.errors import SceneError
    from radiosity.scene.load import load_scene

    f = tmp_path / "bad.toml"
    f.write_text(cornell_with(table_text("[[camera]]", FRONT, "front") + "\n" + second))
    with pytest.raises(SceneError, match=says) as e:
        load_scene(str(f), settings=settings_of())
    assert str(f) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("look, error, says", [
    (dict(position=[278.0, 273.0, -800.0], look_at=[278.0, 273.0, -1600.0]), "SceneError",
     "sees no element"),
    (dict(position=[278.0, 273.0, 1400.0], look_at=[278.0, 273.0, 0.0]), "OrientationError",
     "only the backs"),
])
def test_a_camera_that_would_make_a_black_image_is_refused_by_name(tmp_path, look, error, says):
    """The checks before any cluster starts cover every camera: one that sees nothing, or only
    the backs of one-sided faces (the Cornell box from behind its back wall), is one line that
    names it."""
    from radiosity.errors import RadiosityError
    from radiosity.runtime.checks import check_scene
    from radiosity.scene.load import load_scene
    from radiosity.settings import resolve

    f = tmp_path / "two.toml"
    f.write_text(cornell_with(table_text("[[camera]]", FRONT, "front") + "\n"
                              + table_text("[[camera]]", {**look, "fov_y": 40.0}, "bad")))
    with pytest.raises(RadiosityError, match=says) as e:
        check_scene(load_scene(str(f), settings=settings_of()), resolve())
    assert type(e.value).__name__ == error and "'bad'" in str(e.value)


# ----------------------------------------------------------------------------- the partition

def _nodes(part) -> set:
    """Every node of a partition's split trees as (original, path of 0/1 choices)."""
    out = set()
    stack = [(o, int(r), "") for o, r in enumerate(part.root)]
    while stack:
        o, n, path = stack.pop()
        out.add((o, path))
        if part.child[n, 0] >= 0:
            stack += [(o, int(part.child[n, 0]), path + "0"), (o, int(part.child[n, 1]), path + "1")]
    return out


def test_the_partition_of_two_cameras_is_the_union_of_each_cameras():
    """A node is split iff one camera alone would split it: the nodes of the two-camera
    partition are those of the two one-camera partitions together (no node more: points of
    two cameras on one sub-element do not split it)."""
    from radiosity.scene.load import load_scene, parse_camera
    from radiosity.scene.subdivide import subdivide
    from radiosity.tracing.rays import RayCaster, raster_band

    sc = load_scene(scene_path("cornell-box"), resolution=R, settings=settings_of())
    el = sc.elements
    rc = RayCaster(el.verts, el.nverts)
    cams = [sc.camera, parse_camera({**ABOVE, "resolution": R}, "test")]
    pts, elem = [], []
    for cam in cams:
        e, p = raster_band(rc, el.normal, el.center, cam, 1, slice(0, cam.height))
        pts.append(p[e >= 0])
        elem.append(e[e >= 0])
    one = [subdivide(el.verts, el.nverts, el.normal, p, e)[0] for p, e in zip(pts, elem)]
    both, _ = subdivide(el.verts, el.nverts, el.normal, np.concatenate(pts), np.concatenate(elem),
                        point_group=np.repeat([0, 1], [len(e) for e in elem]))
    merged, _ = subdivide(el.verts, el.nverts, el.normal, np.concatenate(pts), np.concatenate(elem))
    assert _nodes(both) == _nodes(one[0]) | _nodes(one[1])
    assert len(merged) > len(both)  # one group: the cameras' points would split each other


# ----------------------------------------------------------------------------- whole renders

@pytest.mark.cluster
def test_each_cameras_image_matches_its_single_camera_render(tmp_path):
    """One render of a scene with two cameras (front, above: the floor behind the blocks and
    the light seen only from above) against a render of each camera alone: every surface
    within 2 %, from one solve. The hierarchical method (the default at the built-in size):
    at this small size `auto` would pick pairs, whose answer on the floor moves by about 3 %
    between the one-camera and the finer two-camera partition (its discretisation error)."""
    import radiosity
    from radiosity.runtime.store import RunStore

    two = tmp_path / "two.toml"
    two.write_text(cornell_with(table_text("[[camera]]", FRONT, "front") + "\n"
                                + table_text("[[camera]]", ABOVE, "above")))
    alone = tmp_path / "above.toml"
    alone.write_text(cornell_with(table_text("[camera]", ABOVE)))
    kw = dict(method="hierarchical")
    both = radiosity.render(str(two), out=str(tmp_path / "both"), **kw)
    front = radiosity.render(scene_path("cornell-box"), out=str(tmp_path / "front"), resolution=R,
                             **kw)
    above = radiosity.render(str(alone), out=str(tmp_path / "above"), **kw)

    assert set(both.views) == {"above"} and both.report["render"]["stages"]["views"] == ["above"]
    assert (tmp_path / "both" / "views" / "above" / "image.png").stat().st_size > 0
    assert both.report["preprocess"]["cameras"] == 2
    # the union partition is finer than either camera's own
    assert both.report["preprocess"]["sub_elements"] > max(
        front.report["preprocess"]["sub_elements"], above.report["preprocess"]["sub_elements"])
    # the originals seen (the cluster layer's importance): those any camera's pixel hits
    ras = RunStore(str(tmp_path / "both")).read_arrays("raster")
    own = np.zeros(len(ras["seen"]), bool)
    own[ras["orig"][ras["orig"] >= 0]] = True
    assert (ras["seen"] | ~own).all() and (ras["seen"] & ~own).any()
    assert (ras["footprint"] | ~ras["seen"]).all()   # every hit original is in the footprint
    for img, ref, run in ((both.image, front.image, "front"), (both.views["above"], above.image,
                                                               "above")):
        orig = RunStore(str(tmp_path / run)).read_arrays("raster")["orig"]
        diffs = per_surface(img, ref, orig, min_pixels=20)
        assert len(diffs) >= 5, (run, diffs)
        assert max(abs(x) for x in diffs.values()) < 0.02, (run, diffs)
        assert abs(img.mean() / ref.mean() - 1) < 0.01, run
