"""The Embree module: first hits map quads back to elements; occlusion is scale-free."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.tracing.rays import RayCaster
from radiosity.settings import options as settings_of

# a unit quad at z = 1 (facing -z) and a small occluding triangle at z = 0.5
VERTS = np.array([[[0, 0, 1], [0, 1, 1], [1, 1, 1], [1, 0, 1]],
                  [[0.4, 0.4, 0.5], [0.6, 0.4, 0.5], [0.5, 0.6, 0.5], [0.5, 0.6, 0.5]]], float)
NV = np.array([4, 3], np.int8)


def test_first_hit_maps_both_triangles_of_a_quad_to_the_element():
    rc = RayCaster(VERTS, NV)
    o = np.array([[0.1, 0.9, 0], [0.9, 0.1, 0], [0.5, 0.45, 0], [2, 2, 0]], float)
    d = np.tile([0, 0, 1.0], (4, 1))
    elem, t = rc.first_hit(o, d, distances=True)
    assert elem.tolist() == [0, 0, 1, -1]
    np.testing.assert_allclose(t[:3], [1, 1, 0.5], rtol=1e-6)
    assert np.isinf(t[3])


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_occlusion_segments_are_scale_free(rng, scale):
    rc = RayCaster(VERTS * scale, NV)
    # segments from the floor z = 0 to points on the quad: blocked iff they cross the triangle
    p = np.column_stack([rng.random(500), rng.random(500), np.zeros(500)])
    q = np.column_stack([rng.random(500), rng.random(500), np.ones(500)])
    occ = rc.occluded(p * scale, q * scale)
    # exact answer: where the segment crosses z = 0.5, is it inside the triangle?
    m = 0.5 * (p + q)
    a, b, c = VERTS[1, 0], VERTS[1, 1], VERTS[1, 2]

    def cross2(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    s1 = cross2(b - a, m - a)
    s2 = cross2(c - b, m - b)
    s3 = cross2(a - c, m - c)
    inside = (s1 > 1e-6) & (s2 > 1e-6) & (s3 > 1e-6)
    outside = (s1 < -1e-6) | (s2 < -1e-6) | (s3 < -1e-6)
    assert np.all(occ[inside]) and not np.any(occ[outside])
    # the segment ending on the quad does not hit the quad itself (epsilon)
    assert not rc.occluded(np.array([[0.9, 0.9, 0.0]]) * scale, np.array([[0.9, 0.9, 1.0]]) * scale)[0]


def test_degenerate_segments_are_not_occluded():
    rc = RayCaster(VERTS, NV)
    p = np.array([[0.5, 0.5, 0.5]])
    assert not rc.occluded(p, p)[0]


def test_the_hull_planes_are_a_rooms_walls_and_never_block_a_segment_between_elements(rng):
    """core.geometry.on_hull_planes flags the polygons in the supporting planes of the scene's
    convex hull (the Cornell box's walls, floor, ceiling and the light in it; not the blocks'
    faces), and segment queries between points on elements, which leave those out, answer as
    the whole scene does wherever the answer is not a grazing one."""
    from radiosity.core.geometry import on_hull_planes
    from radiosity.scene.load import load_scene

    el = load_scene("scenes/cornell-box", settings=settings_of()).elements
    hull = on_hull_planes(el.verts, el.nverts, el.normal)
    names = np.array(el.material_names)[el.material]
    assert hull[names != "white"].all()  # the coloured walls and the light
    v = el.verts.reshape(-1, 3)
    top = el.verts[:, :, 1].min(axis=1) > v[:, 1].max() - 1e-6   # the ceiling and the light
    bottom = el.verts[:, :, 1].max(axis=1) < v[:, 1].min() + 1e-6
    assert hull[top].all() and hull[bottom].all()
    inner = np.nonzero(~hull)[0]
    assert len(inner) == 10  # the two blocks' five faces each (the scene has none under them)
    assert on_hull_planes(VERTS[:1], NV[:1], np.array([[0, 0, -1.0]])).all()  # one quad: flat

    rc = RayCaster(el.verts, el.nverts)
    n = 4000
    a, b = rng.integers(0, len(el), n), rng.integers(0, len(el), n)
    w = rng.dirichlet(np.ones(3), 2 * n)
    ids = np.concatenate([a, b])
    pts = np.einsum("kj,kjc->kc", w, el.verts[ids][:, :3])
    idx = np.arange(n)
    part = rc.occluded_pairs(pts, idx, idx + n, ids)
    assert rc._inner_scene()[0] is not None
    rc._inner = (rc._scene, rc.owner, None)  # the whole scene
    whole = rc.occluded_pairs(pts, idx, idx + n, ids)
    d = pts[n:] - pts[:n]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    clear = (np.abs(np.einsum("ij,ij->i", el.normal[a], d)) > 0.1) & \
        (np.abs(np.einsum("ij,ij->i", el.normal[b], d)) > 0.1)
    assert 0.05 < whole[clear].mean() < 0.95
    np.testing.assert_array_equal(part[clear], whole[clear])
    # without the ends' elements the ends may lie outside the hull: the whole scene, whose
    # walls block a segment from outside the box to its middle
    rc._inner = (None, None, None)  # as if nothing inside could block
    mid = 0.5 * (v.min(axis=0) + v.max(axis=0))
    out = mid + np.array([0.0, 2.0, 0.0]) * (v.max(axis=0) - v.min(axis=0))  # above, below
    assert rc.occluded(np.array([out, 2 * mid - out]), np.array([mid, mid])).all()
    assert not rc.occluded_pairs(pts, idx, idx + n, ids).any()
