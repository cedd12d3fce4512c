"""The Embree module: first hits map quads back to elements; occlusion is scale-free."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.tracing.rays import RayCaster

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
