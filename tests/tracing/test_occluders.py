"""tracing/occluders.py: flat faces of many elements as one occluder polygon, and segment
queries that answer as they did with every element."""

from __future__ import annotations

import numpy as np

from radiosity.tracing import occluders
from radiosity.tracing.rays import RayCaster


def _plate(origin, u, v, n, skip=lambda i, j: False):
    """A square plate origin + [0, 1]^2 (u, v) cut into n x n cells of two triangles each, the
    cells where skip(i, j) left out; coordinates rounded to float32 as a mesh file holds them."""
    tris = []
    for i in range(n):
        for j in range(n):
            if skip(i, j):
                continue
            p = [origin + (i + a) / n * u + (j + b) / n * v for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))]
            tris += [[p[0], p[1], p[2], p[2]], [p[0], p[2], p[3], p[3]]]
    return np.asarray(tris, np.float32).astype(np.float64)


def _room_with_plates():
    """A room (its six walls the hull's planes, 800 triangles each) holding a tilted plate of 288
    triangles, a plate with a hole in its middle and an L-shaped one: (verts, nverts, slices of
    the three plates)."""
    o, x, y, z = np.zeros(3), np.array([4.0, 0, 0]), np.array([0, 4.0, 0]), np.array([0, 0, 4.0])
    room = np.concatenate([_plate(o, y, x, 20), _plate(z, x, y, 20), _plate(o, z, y, 20),
                           _plate(x, y, z, 20), _plate(o, x, z, 20), _plate(y, z, x, 20)])
    c, s = np.cos(0.3), np.sin(0.3)
    tilted = _plate(np.array([1.2, 0.5, 1.0]), np.array([1.5 * c, 0, 1.5 * s]),
                    np.array([0, 1.4, 0.0]), 12)
    holed = _plate(np.array([0.5, 2.2, 2.0]), np.array([1.5, 0, 0.0]), np.array([0, 1.5, 0.2]), 8,
                   lambda i, j: 3 <= i <= 4 and 3 <= j <= 4)
    ell = _plate(np.array([2.2, 2.2, 1.0]), np.array([1.5, 0, 0.0]), np.array([0, 0, 1.5]), 8,
                 lambda i, j: i >= 4 and j >= 4)
    verts = np.concatenate([room, tilted, holed, ell])
    nverts = np.full(len(verts), 3, np.int8)
    a = len(room) + len(tilted)
    b = a + len(holed)
    return verts, nverts, (slice(len(room), a), slice(a, b), slice(b, len(verts)))


def test_a_flat_convex_face_of_many_triangles_is_one_occluder_and_holes_and_notches_are_not():
    from radiosity.core.geometry import polygon_properties

    verts, nverts, (tilted, holed, ell) = _room_with_plates()
    area, normal, _ = polygon_properties(verts, nverts)
    tris, owner, group = occluders.merged_faces(verts, nverts, normal, area, 5.0)
    assert len(np.unique(group[tilted])) == 1  # one face
    assert len(np.unique(group[holed])) == holed.stop - holed.start  # each its own
    assert len(np.unique(group[ell])) == ell.stop - ell.start
    assert (owner == group[tilted][0]).sum() <= 8  # a fan over the plate's rectangle
    # the triangles cover the same area: the room, the merged plate, the other two as they were
    t_area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]),
                                  axis=1)
    assert t_area.sum() == np.float64(area.sum()) or abs(t_area.sum() - area.sum()) < 1e-9 * \
        area.sum()


def test_segment_queries_answer_as_with_every_element(monkeypatch, rng):
    """Segments between random points on the room's walls and the plates (grazing ones aside),
    with the merged occluders and with every triangle as its own: the same answers, some of
    them through the hole and past the L's notch; and a hit on the merged plate from its own
    element is stepped over as a hit on that element was."""
    verts, nverts, (tilted, holed, ell) = _room_with_plates()
    n = 20000
    a, b = rng.integers(0, len(verts), n), rng.integers(0, len(verts), n)
    w = rng.dirichlet(np.ones(3), 2 * n)
    ids = np.concatenate([a, b])
    pts = np.einsum("kj,kjc->kc", w, verts[ids][:, :3])
    idx = np.arange(n)
    merged = RayCaster(verts, nverts)
    got = merged.occluded_pairs(pts, idx, idx + n, ids)
    assert len(merged._inner_scene()[1]) < 0.5 * (len(verts) - tilted.start)  # fewer triangles
    monkeypatch.setattr(occluders, "MIN_ELEMENTS", 10 ** 9)
    each = RayCaster(verts, nverts)
    want = each.occluded_pairs(pts, idx, idx + n, ids)
    d = pts[n:] - pts[:n]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    normal = merged.normal
    clear = (np.abs(np.einsum("ij,ij->i", normal[a], d)) > 0.1) & \
        (np.abs(np.einsum("ij,ij->i", normal[b], d)) > 0.1)
    assert 0.1 < want[clear].mean() < 0.9
    np.testing.assert_array_equal(got[clear], want[clear])
    # from the merged plate's own triangles out into the room: not blocked by the plate
    own = np.nonzero(clear & (a >= tilted.start) & (a < tilted.stop))[0]
    assert len(own) > 100 and (got[own] == want[own]).all()
    # floor to ceiling through the hole, and wall to wall past the L's notch and through the L
    p = np.array([[1.25, 2.95, 0.0], [3.3, 0.0, 2.1], [2.5, 0.0, 1.3]])
    q = np.array([[1.25, 2.95, 4.0], [3.3, 4.0, 2.1], [2.5, 4.0, 1.3]])
    ep, eq = np.array([0, 3200, 3200]), np.array([800, 4000, 4000])  # floor, ceiling, walls
    for rc in (merged, each):
        assert rc.occluded(p, q, ep, eq).tolist() == [False, False, True]
