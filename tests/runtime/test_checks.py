"""The orientation checks before any cluster starts (runtime/checks.check_orientation): a room
whose normals point out, a camera inside a wall, a lamp outside the room stop `radiosity render`
with one line and exit 2 before anything starts, where they used to render black with exit 0
(issue 26); the documented fix (`orient = "inward"`) renders the room as an inward one; the
built-in scenes, a two-sided shell and an open box raise nothing."""

from __future__ import annotations

import glob
import json
import os
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

from radiosity.cli.commands import main
from helpers import SCENES, box_polygons
from radiosity.settings import options as settings_of

ROOM = ((0.0, 0.0, 0.0), (4.0, 3.0, 5.0))
CAMERA = """
[camera]
position = [2.0, 1.5, 4.5]
look_at = [2.0, 1.2, 0.0]
up = [0.0, 1.0, 0.0]
fov_y = 70.0
resolution = [16, 16]
"""


def obj(quads, material: str) -> str:
    """OBJ text of quads (k, 4, 3) in one material."""
    lines = [f"usemtl {material}"]
    for q in quads:
        lines += [f"v {p[0]:.6g} {p[1]:.6g} {p[2]:.6g}" for p in q]
    lines += [f"f {4 * i + 1} {4 * i + 2} {4 * i + 3} {4 * i + 4}" for i in range(len(quads))]
    return "\n".join(lines) + "\n"


def lamp(y: float):
    """A 1 x 1 quad at height y in the middle of the room, facing down."""
    return box_polygons((1.5, y - 1.0, 2.0), (2.5, y, 3.0), inward=True, faces=[3])[0]


def room_scene(tmp_path, inward=True, orient=None, two_sided=False, lamp_y=2.95, camera=CAMERA,
               faces=range(6), more: str = "") -> str:
    """room.obj (a box: its own [[mesh]] entry) and lamp.obj (another), their materials, the
    camera; `more`: further [[mesh]] entries, first in the file."""
    (tmp_path / "room.obj").write_text(obj(box_polygons(*ROOM, inward=inward, faces=faces)[0],
                                           "white"))
    (tmp_path / "lamp.obj").write_text(obj(lamp(lamp_y), "light"))
    entry = '[[mesh]]\npath = "room.obj"\n'
    if orient:
        entry += f'orient = "{orient}"\n'
    if two_sided:
        entry += "two_sided = true\n"
    text = (more + entry + '[[mesh]]\npath = "lamp.obj"\n'
            "[material.white]\nreflectance = [0.7, 0.7, 0.7]\n"
            "[material.light]\nreflectance = [0.0, 0.0, 0.0]\nemission = [10.0, 10.0, 10.0]\n"
            + camera)
    p = tmp_path / "scene.toml"
    p.write_text(text)
    return str(p)


def stopped_up_front(tmp_path, path, *fragments) -> str:
    """`radiosity render` stops with one line, exit 2, no cluster and no run directory."""
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["render", path, "--out", str(out)])
    assert r.exit_code == 2, r.output
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1, r.output
    assert "Traceback" not in r.output and "dashboard:" not in r.output, r.output
    assert not out.exists()  # before anything was made
    for f in fragments:
        assert f in errors[0], errors[0]
    return errors[0]


def test_a_room_with_its_normals_out_stops_before_any_cluster_with_the_fix(tmp_path):
    line = stopped_up_front(tmp_path, room_scene(tmp_path, inward=False), "room.obj",
                            "[[mesh]] 1", "closed (watertight)", "normals point outward",
                            'orient = "inward"', "two_sided = true")
    assert len(line) < 500


def test_a_camera_inside_a_wall_stops_before_any_cluster(tmp_path):
    """Behind the back wall (outside the room, the wall in front): it sees only the wall's back."""
    cam = CAMERA.replace("position = [2.0, 1.5, 4.5]", "position = [2.0, 1.5, 5.2]")
    stopped_up_front(tmp_path, room_scene(tmp_path, camera=cam),
                     "the camera sees only the backs of one-sided elements", "image would be black",
                     "room.obj", "inside a wall")


def test_a_camera_inside_a_solid_wall_is_told_to_move(tmp_path):
    """A wall modelled as a solid slab (normals out, its own mesh) with the camera inside it."""
    (tmp_path / "slab.obj").write_text(obj(box_polygons((0.0, 0.0, 4.8), (4.0, 3.0, 5.0),
                                                        inward=False)[0], "white"))
    path = room_scene(tmp_path, camera=CAMERA.replace("4.5]", "4.9]"),
                      more='[[mesh]]\npath = "slab.obj"\n')
    stopped_up_front(tmp_path, path, "slab.obj", "[[mesh]] 1", "move the camera")


def test_a_lamp_outside_the_room_stops_before_any_cluster(tmp_path):
    stopped_up_front(tmp_path, room_scene(tmp_path, lamp_y=3.5),
                     "no emitter's light reaches any element", "lamp.obj", "image would be black")


def test_a_lamp_outside_among_lamps_that_light_is_a_warning(tmp_path):
    from radiosity.runtime.checks import check_scene
    from radiosity.scene.load import load_scene
    from radiosity.settings import resolve

    path = room_scene(tmp_path)
    # a second lamp outside the room, as another material of lamp.obj
    (tmp_path / "lamp.obj").write_text(obj(np.concatenate([lamp(2.95), lamp(3.5)]), "light")
                                       .replace("f 5 6 7 8", "usemtl light2\nf 5 6 7 8"))
    with open(path, "a") as f:
        f.write("\n[material.light2]\nemission = [5.0, 5.0, 5.0]\nreflectance = [0.0, 0.0, 0.0]\n")
    said = (r"light of material 'light2' of lamp.obj \(\[\[mesh\]\] 2\) reaches no element "
            r"\(\d+ of 256 rays meet the backs")
    with pytest.warns(UserWarning, match=said):
        fig = check_scene(load_scene(path, settings=settings_of()), resolve())
    assert {e["material"]: e["reached"] > 0 for e in fig["orientation"]["emitters"]} == \
        {"light": True, "light2": False}


@pytest.mark.parametrize("kind", ["builtin", "two-sided shell", "open box"])
def test_no_false_alarm(tmp_path, kind):
    """The built-in scenes (every TOML in scenes/), a closed room with its normals out but
    two-sided, and an open box seen from outside: no orientation error and no warning."""
    from radiosity.runtime.checks import check_scene
    from radiosity.scene.load import load_scene
    from radiosity.settings import resolve

    if kind == "builtin":
        paths = sorted(glob.glob(os.path.join(SCENES, "*", "*.toml")))
        assert len(paths) >= 11
    elif kind == "two-sided shell":
        paths = [room_scene(tmp_path, inward=False, two_sided=True)]
    else:
        cam = CAMERA.replace("position = [2.0, 1.5, 4.5]", "position = [2.0, 1.5, 9.0]")
        paths = [room_scene(tmp_path, faces=range(5), camera=cam)]  # no +z wall: open to the camera
    for p in paths:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the scenes' own (non-planar quads split)
            sc = load_scene(p, settings=settings_of())
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            fig = check_scene(sc, resolve())["orientation"]
        assert not [w for w in said if "reaches no element" in str(w.message)], (p, said)
        assert fig["camera_lit"] > 0 and all(e["reached"] > 0 for e in fig["emitters"]), (p, fig)


def test_orient_inward_renders_the_outward_room_as_the_inward_one(client, tmp_path):
    """The documented fix: the outward room with `orient = "inward"` on its [[mesh]] entry gives
    the inward room's image (means within 1 %)."""
    from radiosity.stages.image import read_exr

    means = {}
    for name, kw in (("inward", {"inward": True}),
                     ("fixed", {"inward": False, "orient": "inward"})):
        d = tmp_path / name
        d.mkdir()
        path = room_scene(d, **kw)
        out = d / "out"
        r = CliRunner().invoke(main, ["render", path, "--out", str(out),
                                      "--scheduler", client.scheduler.address])
        assert r.exit_code == 0, r.output
        img = read_exr(str(out / "image.exr")).astype(float)
        assert (img.sum(-1) > 0).mean() > 0.95
        means[name] = img.mean()
        assert json.loads((out / "report.json").read_text())["solve"]["converged"]
    assert means["fixed"] == pytest.approx(means["inward"], rel=0.01), means


def test_a_lamp_box_wound_inside_out_stops_before_any_cluster(tmp_path):
    """The office (tests/office.py) whose ceiling lamp, a closed box, is wound inside out: its
    light stays inside the box, which used to count as lighting the scene (a black image, exit
    0); in a scene file `orient` is as-is, so nothing turns it."""
    from office import glb_office

    (tmp_path / "office.glb").write_bytes(glb_office(flipped={"panel"}))
    (tmp_path / "scene.toml").write_text('[[mesh]]\npath = "office.glb"\n' + CAMERA.replace(
        "position = [2.0, 1.5, 4.5]", "position = [0.3, 1.5, 2.0]").replace(
        "look_at = [2.0, 1.2, 0.0]", "look_at = [5.0, 1.2, 2.0]"))
    stopped_up_front(tmp_path, str(tmp_path / "scene.toml"),
                     "no emitter's light reaches any element", "office.glb ([[mesh]] 1)")


def test_a_mesh_alone_is_told_to_write_a_scene_file(tmp_path):
    """A bare mesh file whose lamp sits above the ceiling: the check stops it, and the fix it
    offers is a scene file naming the mesh (it has no [[mesh]] entry to edit)."""
    from office import glb_office

    fn = tmp_path / "office.glb"
    fn.write_bytes(glb_office(panel=((2.0, 3.2, 1.5), (3.0, 3.25, 2.5))))
    line = stopped_up_front(tmp_path, str(fn), "no emitter's light reaches any element",
                            "(material 'lamp' of office.glb:",
                            'write a scene.toml with [[mesh]] path = "office.glb" and orient = '
                            '"inward" (or two_sided = true) (see docs/src/how-to/'
                            'meshes-as-scenes.md)')
    assert "[[mesh]] 1" not in line


def test_an_office_exported_inside_out_renders_as_the_right_one(client, tmp_path):
    """`radiosity render office.glb` with no scene file, the office as modelled and inside out:
    the same image, means within 1 % (the inside-out file used to give a black one with exit 0
    and no word), seen
    from inside the room with its window, lit, and the turn said in one warning line."""
    from office import glb_office
    from radiosity.stages.image import read_exr

    imgs = {}
    for name, flipped in (("office", False), ("flipped", True)):
        fn = tmp_path / f"{name}.glb"
        fn.write_bytes(glb_office(flipped=flipped))
        out = tmp_path / name
        r = CliRunner().invoke(main, ["render", str(fn), "--out", str(out), "--resolution", "16",
                                      "--scheduler", client.scheduler.address])
        assert r.exit_code == 0, r.output
        assert "inside: a room with openings" in r.output
        assert ("turned 3 of its 3 connected parts" in r.output) == flipped, r.output
        imgs[name] = read_exr(str(out / "image.exr")).astype(float)
    # the turned polygons start their corners elsewhere, so their subdivision differs a little
    for img in imgs.values():
        assert (img.sum(-1) > 0).mean() > 0.95
    assert imgs["flipped"].mean() == pytest.approx(imgs["office"].mean(), rel=0.01)
