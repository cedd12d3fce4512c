"""Which way faces point (scene/orientation.py): flipping, the `orient` key of a [[mesh]] entry,
the winding number that tells a mesh enclosing the camera with its normals out, and where an
emitter's rays go. Pure: no cluster (the CLI-level checks are in tests/runtime/test_checks.py)."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.core.geometry import polygon_properties
from radiosity.errors import SceneError
from radiosity.scene.orientation import (ORIENTS, facing_volume, flip_polygons, orient_polygons,
                                         outward_enclosures, winding_number)
from helpers import box_polygons


def test_flip_reverses_every_normal_and_keeps_the_polygons(rng):
    verts, nverts = box_polygons()
    tri = np.concatenate([verts[:2, [0, 1, 2, 2]], verts[2:]])
    nv = np.array([3, 3, 4, 4, 4, 4], np.int8)
    a0, n0, c0 = polygon_properties(tri, nv)
    a1, n1, c1 = polygon_properties(flip_polygons(tri, nv), nv)
    np.testing.assert_allclose(n1, -n0)
    np.testing.assert_allclose(a1, a0)
    np.testing.assert_allclose(c1, c0)
    flipped = flip_polygons(tri, nv)
    assert np.array_equal(flipped[:2, 3], flipped[:2, 2])  # a triangle's slot 3 repeats its last
    np.testing.assert_array_equal(flip_polygons(flipped, nv), tri)


def test_facing_volume_is_the_volume_with_the_sign_of_the_normals():
    v_in, n = box_polygons((0, 0, 0), (2, 3, 4), inward=True)
    v_out, _ = box_polygons((0, 0, 0), (2, 3, 4), inward=False)
    assert facing_volume(v_out, n) == pytest.approx(24.0)
    assert facing_volume(v_in, n) == pytest.approx(-24.0)
    # an open box (no front) still tells which way its faces point
    v_open, n5 = box_polygons(inward=True, faces=range(5))
    assert facing_volume(v_open, n5) < 0


@pytest.mark.parametrize("inward", [True, False])
def test_orient_inward_and_outward_whatever_the_file_says(inward):
    verts, n = box_polygons(inward=inward)
    assert facing_volume(orient_polygons(verts, n, "inward", "x"), n) < 0
    assert facing_volume(orient_polygons(verts, n, "outward", "x"), n) > 0
    assert orient_polygons(verts, n, "as-is", "x") is verts
    np.testing.assert_array_equal(orient_polygons(verts, n, "flip", "x"), flip_polygons(verts, n))


def test_an_unknown_orient_names_the_entry_and_the_values():
    verts, n = box_polygons()
    with pytest.raises(SceneError,
                       match=r"scene.toml: \[\[mesh\]\] 2: orient = 'in' is not one of"):
        orient_polygons(verts, n, "in", "scene.toml: [[mesh]] 2")
    assert ORIENTS[0] == "as-is"


def test_winding_number_inside_outside_and_open():
    v_out, n = box_polygons(inward=False)
    v_in, _ = box_polygons(inward=True)
    mid, far = np.array([0.3, 0.6, 0.5]), np.array([3.0, 0.5, 0.5])
    assert winding_number(v_out, n, mid) == pytest.approx(1.0)
    assert winding_number(v_in, n, mid) == pytest.approx(-1.0)
    assert winding_number(v_out, n, far) == pytest.approx(0.0, abs=1e-12)
    # five walls around the camera: it still winds most of the way
    v5, n5 = box_polygons(inward=False, faces=range(5))
    assert 0.5 < winding_number(v5, n5, mid) < 1.0


def _elements(parts):
    """Elements from [(verts, nverts, two_sided)] as separate [[mesh]] entries."""
    from radiosity.core.bundles import Elements

    verts = np.concatenate([p[0] for p in parts])
    nverts = np.concatenate([p[1] for p in parts])
    area, normal, center = polygon_properties(verts, nverts)
    k = len(verts)
    return Elements(verts=verts, nverts=nverts, normal=normal, center=center, area=area,
                    reflectance=np.full((k, 2, 3), 0.5), emission=np.zeros((k, 2, 3)),
                    two_sided=np.concatenate([np.full(len(p[1]), p[2]) for p in parts]),
                    material=np.zeros(k, np.int32),
                    source=np.concatenate([np.full(len(p[1]), i, np.int32)
                                           for i, p in enumerate(parts)]),
                    face=np.arange(k, dtype=np.int32), material_names=("m",),
                    sources=tuple(f"mesh{i}.obj" for i in range(len(parts))))


def test_outward_enclosures_names_the_mesh_that_holds_the_camera_inside_out():
    room_out = box_polygons((0, 0, 0), (4, 3, 5), inward=False)
    room_in = box_polygons((0, 0, 0), (4, 3, 5), inward=True)
    table = box_polygons((1, 0, 1), (2, 1, 2), inward=False)  # a solid: normals out, camera outside
    cam = np.array([3.0, 1.5, 4.0])
    found = outward_enclosures(_elements([(*room_out, False), (*table, False)]), cam)
    assert [(e.source, e.watertight, e.faces) for e in found] == [(0, True, 6)]
    assert found[0].winding == pytest.approx(1.0)
    assert outward_enclosures(_elements([(*room_in, False), (*table, False)]), cam) == []
    # a two-sided shell is lit from both sides: nothing to say
    assert outward_enclosures(_elements([(*room_out, True), (*table, False)]), cam) == []
    # the camera inside the table (a solid): it is found, as it should be
    assert [e.source for e in outward_enclosures(_elements([(*room_in, False), (*table, False)]),
                                                 np.array([1.5, 0.5, 1.5]))] == [1]


# ----------------------------------------------------------------------------- per connected part

def _normals(verts, nverts):
    return polygon_properties(verts, nverts)[1]


def test_connected_parts_and_their_kinds_in_an_office():
    """The office GLB's triangles (tests/office.py): the room's shell with its window (one part,
    not closed), the table (a top and four legs meeting at corners: closed) and the lamp box."""
    from office import office_polygons
    from radiosity.scene.orientation import connected_parts, part_kinds

    verts, nverts, names = office_polygons()
    label, count = connected_parts(verts, nverts)
    assert count == 3
    parts = {n: set(label[names == n]) for n in set(names)}
    assert all(len(v) == 1 for v in parts.values())
    assert parts["top"] == parts["leg0"] == parts["leg3"] != parts["room"] != parts["panel"]
    room, top, panel = (next(iter(parts[n])) for n in ("room", "top", "panel"))
    for how in ("largest", "holds"):
        kinds = part_kinds(verts, nverts, label, count, room=how)
        assert [kinds[p] for p in (room, top, panel)] == ["room", "solid", "solid"]
    assert part_kinds(verts, nverts, label, count, room="none")[room] == "solid"
    # the lamp above the ceiling: the shell no longer holds the rest (auto's test), but asked
    # for a room (inward), the largest part with a volume is it
    up = verts.copy()
    up[names == "panel"] += [0.0, 0.5, 0.0]
    assert part_kinds(up, nverts, label, count, room="holds")[room] == "solid"
    assert part_kinds(up, nverts, label, count, room="largest")[room] == "room"


@pytest.mark.parametrize("orient", ["inward", "auto"])
def test_inward_turns_the_room_in_and_its_furniture_out(orient):
    """One mesh holding the room and its furniture, exported inside out: `inward` (and a bare
    mesh's `auto`) turns the shell in and the table and lamp out of their own volumes, where
    turning the whole mesh by its total volume (the room's dominates) left them inside out."""
    from office import office_polygons
    from radiosity.scene.orientation import orient_mesh

    good, nverts, names = office_polygons()
    bad, _, _ = office_polygons(flipped=True)
    np.testing.assert_allclose(_normals(bad, nverts), -_normals(good, nverts))
    fixed, turned = orient_mesh(bad, nverts, orient, "x")
    np.testing.assert_allclose(_normals(fixed, nverts), _normals(good, nverts), atol=1e-12)
    assert sum(turned.turned) == 3 and "turned 3 of its 3 connected parts" in turned.describe("o")
    # the file as modelled is left as it is
    same, turned = orient_mesh(good, nverts, orient, "x")
    np.testing.assert_array_equal(same, good)
    assert not any(turned.turned) and turned.describe("o") == ""
    # only the table inside out (an exporter's per-object mistake): only the table is turned
    mixed = np.where(np.isin(names, ["top", "leg0", "leg1", "leg2", "leg3"])[:, None, None],
                     bad, good)
    fixed, turned = orient_mesh(mixed, nverts, orient, "x")
    np.testing.assert_allclose(_normals(fixed, nverts), _normals(good, nverts), atol=1e-12)
    assert sum(turned.turned) == 1


def test_outward_turns_every_solid_out_of_its_own_volume():
    """Three boxes, one inside out: outward turns that one alone (the whole mesh's volume
    would have said: leave all)."""
    from radiosity.scene.orientation import orient_mesh

    boxes = [box_polygons((3 * i, 0, 0), (3 * i + 1, 1, 1), inward=(i == 1)) for i in range(3)]
    verts = np.concatenate([b[0] for b in boxes])
    nverts = np.concatenate([b[1] for b in boxes])
    fixed, turned = orient_mesh(verts, nverts, "outward", "x")
    assert turned.turned == (False, True, False) and turned.kinds == ("solid",) * 3
    for i in range(3):
        assert facing_volume(fixed[6 * i:6 * i + 6], nverts[:6]) == pytest.approx(1.0)


def test_sheets_face_the_middle_for_inward_and_auto_turns_only_a_room_with_things_in_it():
    """A room of six separate walls (sheets: no shared corners) facing out and a table facing
    out: inward turns the walls toward the middle and leaves the table. auto turns nothing
    where it finds no room holding the rest (here none holds a volume), nor in a mesh of one
    part (a room? a solid?); in the office it turns an open lamp panel with the rest."""
    from office import office_polygons
    from radiosity.scene.orientation import orient_mesh

    walls, wn = box_polygons((0, 0, 0), (4, 3, 5), inward=False)
    mid = walls.mean(axis=1, keepdims=True)
    walls = mid + 0.99 * (walls - mid)  # each a hair smaller: no two walls share a corner
    table, tn = box_polygons((1, 0, 1), (2, 1, 2), inward=False)
    verts, nverts = np.concatenate([walls, table]), np.concatenate([wn, tn])
    fixed, turned = orient_mesh(verts, nverts, "inward", "x")
    assert turned.kinds == ("sheet",) * 6 + ("solid",) and turned.turned == (True,) * 6 + (False,)
    assert facing_volume(fixed[:6], wn) < 0 and facing_volume(fixed[6:], tn) > 0
    for v in (verts, flip_polygons(verts, nverts)):
        fixed, turned = orient_mesh(v, nverts, "auto", "x")
        assert not any(turned.turned) and fixed is v
    v_out, n = box_polygons(inward=False)
    for v in (v_out, flip_polygons(v_out, n)):
        assert orient_mesh(v, n, "auto", "x")[0] is v
    # the office inside out with a flat lamp (one quad, a sheet) under the ceiling
    good, n3, names = office_polygons()
    keep = names != "panel"
    lamp = np.array([[[2.0, 2.9, 1.5], [3.0, 2.9, 1.5], [3.0, 2.9, 2.5], [2.0, 2.9, 2.5]]])
    good = np.concatenate([good[keep], lamp])
    n4 = np.concatenate([n3[keep], [4]])
    assert polygon_properties(lamp, n4[-1:])[1][0, 1] == pytest.approx(-1.0)  # faces down
    fixed, turned = orient_mesh(flip_polygons(good, n4), n4, "auto", "x")
    assert turned.kinds == ("room", "solid", "sheet") and all(turned.turned)
    np.testing.assert_allclose(fixed, good)
    assert "1 open part (with the rest)" in turned.describe("o")


def test_a_lamp_box_inside_out_lights_only_itself_and_reaches_nothing():
    """A closed emitting box wound inside out sends its light into its own inside: it counted
    as reaching the scene (every ray met a lit face: its own), so a black image passed."""
    from radiosity.core.bundles import Elements
    from radiosity.scene.orientation import emitter_reach
    from radiosity.tracing.rays import RayCaster

    room, rn = box_polygons((0, 0, 0), (4, 3, 5), inward=True)
    for inside_out, reached in ((False, True), (True, False)):
        lamp, ln = box_polygons((1.5, 2.8, 2), (2.5, 2.9, 3), inward=inside_out)
        el = _elements([(room, rn, False), (lamp, ln, False)])
        el = Elements(**{**el.__dict__, "emission": np.where(
            (el.source == 1)[:, None, None], np.array([[1.0] * 3, [0.0] * 3]), 0.0)})
        [g] = emitter_reach(el, RayCaster(el.verts, el.nverts, 1e-6))
        assert (g.reached > 0) == reached, g
