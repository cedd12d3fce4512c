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
