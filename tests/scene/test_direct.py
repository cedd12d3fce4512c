"""Direct light at points (scene/direct.py): the exact unoccluded term against the contour
integral and Howell's closed form, the furnace, penumbrae against brute force, determinism,
sides, points on emitters, many-element and many-light emitters."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from radiosity.core.exact import differential_to_rectangle, polygon_point_form_factor
from radiosity.scene import direct
from radiosity.scene.direct import DirectLight
from test_emitters import _elements

LE = np.array([1.0, 2.0, 0.5])
SQ = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
DOWN = SQ[::-1] + [0.0, 0.0, 2.0]                     # the unit square at z = 2, facing -z
FLOOR = np.array([[-3.0, -3.0, 0.0], [3.0, -3.0, 0.0], [3.0, 3.0, 0.0], [-3.0, 3.0, 0.0]])
BLOCKER = np.array([[0.2, 0.2, 1.0], [0.8, 0.2, 1.0], [0.8, 0.8, 1.0], [0.2, 0.8, 1.0]])


def _Le(n, emit, back=None):
    Le = np.zeros((n, 2, 3))
    for i in emit:
        Le[i, 0] = LE
        if back is not None:
            Le[i, 1] = back
    return Le


def _brute(el, P, N, E, k=160):
    """H1 by a k x k midpoint grid on every emitting polygon, one ray each (tracing.rays)."""
    dl = DirectLight(el, 1e-6)
    out = np.zeros((len(P), 3))
    g = (np.arange(k) + 0.5) / k
    u, v = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    for e in dl.ids:
        V, nv = el.verts[e], el.nverts[e]
        tris = [(0, 1, 2)] + ([(0, 2, 3)] if nv == 4 else [])
        for a, b, c in tris:
            su = np.sqrt(u)
            y = V[a] + (su * (1 - v))[:, None] * (V[b] - V[a]) + (su * v)[:, None] * (V[c] - V[a])
            dA = 0.5 * np.linalg.norm(np.cross(V[b] - V[a], V[c] - V[a])) / len(u)
            for i in range(len(P)):
                d = y - P[i]
                r2 = (d * d).sum(1)
                cy = d @ el.normal[e]
                cx = np.maximum(d @ N[i], 0.0)
                side = 0 if el.normal[e] @ (P[i] - V[0]) > 0 else 1
                vis = ~dl.caster.occluded(np.repeat(P[i:i + 1], len(y), 0), y,
                                          np.full(len(y), E[i]), np.full(len(y), e))
                out[i] += el.emission[e, side] * (cx * np.abs(cy) / r2 ** 2 * vis).sum() * dA
    return out


def test_unoccluded_points_are_exact_on_polygons_of_any_tilt(rng):
    tri = np.array([[0.0, 0.0, 0.0], [1.3, 0.2, 0.1], [0.3, 0.9, -0.2]])
    quad = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.2], [1.2, 0.8, 0.5], [0.1, 1.1, 0.3]])
    quad -= quad.mean(0)
    # make the quad planar: project its vertices on its best plane
    nq = np.linalg.svd(quad)[2][-1]
    quad -= np.outer(quad @ nq, nq)
    for poly in (SQ, tri, quad):
        for _ in range(6):
            R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
            Q = poly @ R.T + rng.normal(size=3)
            n = np.cross(Q[1] - Q[0], Q[2] - Q[0])
            n /= np.linalg.norm(n)
            # a large plate behind the emitter (it blocks nothing in front) puts the points
            # inside the scene's box, as points on surfaces are (Embree's float32 frame)
            u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
            u /= np.linalg.norm(u)
            w = np.cross(n, u)
            plate = Q.mean(0) - 0.5 * n + 12.0 * np.array([-u - w, -u + w, u + w, u - w])
            el = _elements([Q, plate], _Le(2, [0]), two_sided=[False, True])
            P = el.center[0] + n * rng.uniform(0.05, 3.0, (40, 1)) + rng.normal(0, 1.5, (40, 3))
            P = P[(P - el.center[0]) @ n > 1e-3]
            N = rng.normal(size=(len(P), 3))
            N /= np.linalg.norm(N, axis=1, keepdims=True)
            H = DirectLight(el, 1e-6).irradiance(P, N, np.full(len(P), -1))
            F = np.array([polygon_point_form_factor(p, m, Q) for p, m in zip(P, N)])
            np.testing.assert_allclose(H, math.pi * F[:, None] * LE, rtol=1e-9, atol=1e-12)


def test_unoccluded_matches_howell_differential_to_rectangle():
    a, b = 1.5, 0.7
    rect = np.array([[0.0, 0.0, 0.0], [0.0, b, 0.0], [a, b, 0.0], [a, 0.0, 0.0]])  # faces -z
    el = _elements([rect], _Le(1, [0]))
    for c in (0.3, 1.0, 4.0):
        H = DirectLight(el, 1e-6).irradiance(np.array([[0.0, 0.0, -c]]), np.array([[0.0, 0.0, 1.0]]),
                                             np.array([-1]))
        np.testing.assert_allclose(H[0], math.pi * differential_to_rectangle(a, b, c) * LE,
                                   rtol=1e-9)


def test_closed_furnace_cube_is_pi_le_everywhere(rng):
    c = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1],
                  [0, 1, 1]], float)
    faces = [[0, 1, 2, 3], [4, 7, 6, 5], [0, 4, 5, 1], [1, 5, 6, 2], [2, 6, 7, 3], [3, 7, 4, 0]]
    el = _elements([c[f] for f in faces], _Le(6, range(6)))
    # every face's front faces into the cube
    assert (np.einsum("ic,ic->i", el.normal, 0.5 - el.center) > 0).all()
    dl = DirectLight(el, 1e-6)
    assert dl.lights == 1
    f = rng.integers(0, 6, 500)
    V = el.verts[f]
    u, v = rng.random((2, 500, 1))
    P = V[:, 0] + u * (V[:, 1] - V[:, 0]) + v * (V[:, 3] - V[:, 0])
    H = dl.irradiance(P, el.normal[f], f)
    np.testing.assert_allclose(H, np.broadcast_to(math.pi * LE, H.shape), rtol=1e-9)


def _blocked_scene():
    return _elements([DOWN, FLOOR, BLOCKER], _Le(3, [0]), two_sided=[False, True, True])


def test_penumbra_agrees_with_brute_force(rng):
    """Points under a square emitter and a square blocker, in umbra, penumbra and light: within
    5 % of the unoccluded value each and 1 % on average (measured 3.5 % and 0.65 %: 16
    first-pass rays, 64 where they disagree; a point whose 16 agree keeps 16); exact where
    nothing blocks."""
    el = _blocked_scene()
    P = np.c_[rng.uniform(-0.8, 1.8, (80, 2)), np.zeros(80)]
    N = np.tile([0.0, 0.0, 1.0], (80, 1))
    E = np.ones(80, np.int64)
    dl = DirectLight(el, 1e-6)
    H, H0 = dl.irradiance(P, N, E), dl.unoccluded(P, N)
    ref = _brute(el, P, N, E)
    err = np.abs(H - ref)[:, 1] / H0[:, 1]
    assert err.max() < 0.05 and err.mean() < 0.01, (err.max(), err.mean())
    shadowed = ref[:, 1] < 0.999 * H0[:, 1]
    assert 10 < shadowed.sum() < 70                   # the case has a shadow and light
    np.testing.assert_allclose(H[~shadowed], H0[~shadowed], rtol=1e-9)
    # more rays, less error: consistent
    H2 = DirectLight(el, 1e-6, samples=256).irradiance(P, N, E)
    assert np.abs(H2 - ref)[:, 1].mean() < 0.5 * np.abs(H - ref)[:, 1].mean() + 1e-4 * H0[:, 1].mean()


def test_same_points_same_bits_in_any_order_and_batch(rng, monkeypatch):
    el = _blocked_scene()
    P = np.c_[rng.uniform(-0.8, 1.8, (300, 2)), np.zeros(300)]
    N = np.tile([0.0, 0.0, 1.0], (300, 1))
    E = np.ones(300, np.int64)
    H = DirectLight(el, 1e-6).irradiance(P, N, E)
    o = rng.permutation(300)
    monkeypatch.setattr(direct, "BATCH_POINTS", 64)
    monkeypatch.setattr(direct, "BATCH_ENTRIES", 1)
    H2 = DirectLight(el, 1e-6).irradiance(P[o], N[o], E[o], index=o)
    assert np.array_equal(H2, H[o])
    H3 = DirectLight(el, 1e-6, seed=1).irradiance(P, N, E)
    assert not np.array_equal(H3, H)                  # the seed moves the samples
    dl = DirectLight(el, 1e-6)
    dl.irradiance(P[:5], N[:5], E[:5])                # its Embree scene built, then pickled
    assert np.array_equal(pickle.loads(pickle.dumps(dl)).irradiance(P, N, E), H)


def test_back_sides_and_two_sided_emitters():
    back = np.array([0.3, 0.2, 0.1])
    P = np.array([[0.5, 0.5, 1.0], [0.5, 0.5, 3.0]])   # below (front side) and above (back)
    up, down = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    F = polygon_point_form_factor(P[0], up, DOWN)
    one = DirectLight(_elements([DOWN], _Le(1, [0]), two_sided=[False]), 1e-6)
    two = DirectLight(_elements([DOWN], _Le(1, [0], back), two_sided=[True]), 1e-6)
    e = np.array([-1, -1])
    H = one.irradiance(P, np.array([up, down]), e)
    np.testing.assert_allclose(H[0], math.pi * F * LE, rtol=1e-12)
    assert (H[1] == 0).all()                            # the back of a one-sided emitter
    H = two.irradiance(P, np.array([up, down]), e)
    np.testing.assert_allclose(H, math.pi * F * np.array([LE, back]), rtol=1e-12)
    # a receiving side that faces away gets nothing
    assert (two.irradiance(P, np.array([down, up]), e) == 0).all()


def test_no_emitter_is_false_and_zero():
    dl = DirectLight(_elements([SQ, FLOOR], np.zeros((2, 2, 3))), 1e-6)
    assert not dl
    H = dl.irradiance(np.ones((3, 3)), np.tile([0.0, 0.0, 1.0], (3, 1)), np.full(3, -1))
    assert H.shape == (3, 3) and (H == 0).all()


def test_points_on_an_emitter_get_nothing_from_it():
    other = DOWN + [3.0, 0.0, 0.0]
    el = _elements([DOWN, other], _Le(2, [0, 1]), two_sided=[True, True])
    P = np.array([[0.5, 0.5, 2.0], [0.2, 0.7, 2.0]])   # on the first emitter
    N = np.tile([0.0, 0.0, -1.0], (2, 1))
    H = DirectLight(el, 1e-6).irradiance(P, N, np.array([0, 0]))
    # the second emitter is in the same plane: the point sees it edge-on, nothing either
    assert (H == 0).all()
    el = _elements([DOWN, SQ + [3.0, 0.0, 1.0]], _Le(2, [0, 1]))   # second: facing up, below
    H = DirectLight(el, 1e-6).irradiance(P, N, np.array([0, 0]))
    F = [polygon_point_form_factor(p, N[0], SQ + [3.0, 0.0, 1.0]) for p in P]
    np.testing.assert_allclose(H, math.pi * np.outer(F, LE), rtol=1e-9)


def _split_square(k, z=2.0):
    """The unit square at height z facing -z, as 2 k^2 triangles."""
    g = np.linspace(0.0, 1.0, k + 1)
    tris = []
    for i in range(k):
        for j in range(k):
            a, b = [g[i], g[j], z], [g[i + 1], g[j], z]
            c, d = [g[i + 1], g[j + 1], z], [g[i], g[j + 1], z]
            tris += [np.array([a, c, b]), np.array([a, d, c])]
    return tris


def test_a_light_of_many_elements_is_one_light_and_agrees_with_one_quad(rng):
    tris = _split_square(4)
    n = len(tris)
    el = _elements(tris + [FLOOR, BLOCKER], _Le(n + 2, range(n)), two_sided=[False] * n + [True, True])
    dl = DirectLight(el, 1e-6)
    assert dl.lights == 1 and len(dl.ids) == 32
    P = np.c_[rng.uniform(-0.8, 1.8, (60, 2)), np.zeros(60)]
    N = np.tile([0.0, 0.0, 1.0], (60, 1))
    E = np.full(60, n)
    H0 = dl.unoccluded(P, N)
    F = np.array([polygon_point_form_factor(p, [0, 0, 1], DOWN) for p in P])
    np.testing.assert_allclose(H0, math.pi * np.outer(F, LE), rtol=1e-9)
    quad = _blocked_scene()
    ref = _brute(quad, P, N, np.ones(60, np.int64))
    H = dl.irradiance(P, N, E)
    err = np.abs(H - ref)[:, 1] / H0[:, 1]
    # measured 7.2 % and 1.5 %: the rays pick a light's elements along one coordinate (a Morton
    # walk), so 32 triangles are stratified less well than one quad (3.5 %, 0.65 %)
    assert err.max() < 0.1 and err.mean() < 0.025, (err.max(), err.mean())
    assert dl.rays < 60 * 16 * 4                        # the budget is per point, not per element


def test_many_small_lights_share_the_budget(rng):
    """25 small separate lights of different colours over a blocker: lights due less than one
    ray are pooled; the answer stays exact where nothing blocks and near brute force elsewhere."""
    polys, Le = [], []
    for i in range(5):
        for j in range(5):
            polys.append(SQ[::-1] * 0.12 + [0.2 * i, 0.2 * j, 2.0])
            Le.append([rng.random(3) + 0.1, np.zeros(3)])
    el = _elements(polys + [FLOOR, BLOCKER], np.array(Le + [np.zeros((2, 3))] * 2),
                   two_sided=[False] * 25 + [True, True])
    dl = DirectLight(el, 1e-6)
    assert dl.lights == 25
    P = np.c_[rng.uniform(-0.8, 1.8, (60, 2)), np.zeros(60)]
    N = np.tile([0.0, 0.0, 1.0], (60, 1))
    E = np.full(60, 25)
    H, H0 = dl.irradiance(P, N, E), dl.unoccluded(P, N)
    # at most samples sqrt(lights) refine a point; 16 a light would be 16 * 25 in the first pass
    assert dl.rays <= 60 * 16 * 5 * 4 and dl.rays < 60 * 16 * 25 / 2
    ref = _brute(el, P, N, E, k=40)
    err = np.abs(H - ref).sum(1) / H0.sum(1)
    # measured 10.7 % at one point and 1.3 %: 16 first-pass rays over 25 lights, most pooled
    assert err.max() < 0.15 and err.mean() < 0.02, (err.max(), err.mean())
    shadowed = ref.sum(1) < 0.999 * H0.sum(1)
    np.testing.assert_allclose(H[~shadowed], H0[~shadowed], rtol=1e-9)


@pytest.mark.parametrize("shafts", [True, False])
def test_shafts_prove_lights_clear_without_changing_the_answer(rng, shafts):
    """A box room lit from its ceiling with a small block on the floor: points whose segments to
    the light pass no occluder box need no ray, and the answer is the same as with rays."""
    room = [np.array(q, float) for q in (
        [[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]], [[0, 0, 3], [0, 4, 3], [4, 4, 3], [4, 0, 3]])]
    light = np.array([[1.5, 1.5, 2.9], [1.5, 2.5, 2.9], [2.5, 2.5, 2.9], [2.5, 1.5, 2.9]])
    block = np.array([[0.2, 0.2, 0.5], [0.6, 0.2, 0.5], [0.6, 0.6, 0.5], [0.2, 0.6, 0.5]])
    el = _elements(room + [light, block], _Le(4, [2]), two_sided=[False, False, False, True])
    P = np.c_[rng.uniform(0.1, 3.9, (200, 2)), np.zeros(200)]
    N = np.tile([0.0, 0.0, 1.0], (200, 1))
    dl = DirectLight(el, 1e-6, shafts=shafts)
    H = dl.irradiance(P, N, np.zeros(200, np.int64))
    H0 = dl.unoccluded(P, N)
    far = (P[:, 0] > 1.0) & (P[:, 1] > 1.0)            # the block can't be between: exact
    np.testing.assert_allclose(H[far], H0[far], rtol=1e-9)
    if shafts:
        assert dl.rays < (~far).sum() * 16 * 4 + 1 and dl.rays < 200 * 16


def test_points_beside_a_large_emitter_agree_with_brute_force(rng):
    """A 4 x 3 window, a wall 15 cm in front of it with the points, and a frame bar between:
    the cos / r^2 weights of area sampling would be dominated by the nearest samples; uniform
    solid-angle sampling keeps them bounded."""
    window = np.array([[0.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 4.0, 3.0], [0.0, 0.0, 3.0]])
    wall = np.array([[0.15, -2.0, -1.0], [0.15, 6.0, -1.0], [0.15, 6.0, 4.0], [0.15, -2.0, 4.0]])
    bar = np.array([[0.05, 1.9, 0.0], [0.05, 2.1, 0.0], [0.05, 2.1, 3.0], [0.05, 1.9, 3.0]])
    el = _elements([window, wall, bar], _Le(3, [0]), two_sided=[False, True, True])
    assert el.normal[0] @ [1.0, 0.0, 0.0] > 0
    n = 40
    P = np.c_[np.full(n, 0.15), rng.uniform(1.0, 3.0, n), rng.uniform(0.5, 2.5, n)]
    N = np.tile([-1.0, 0.0, 0.0], (n, 1))
    E = np.ones(n, np.int64)
    dl = DirectLight(el, 1e-6)
    H, H0 = dl.irradiance(P, N, E), dl.unoccluded(P, N)
    ref = _brute(el, P, N, E, k=300)
    err = np.abs(H - ref)[:, 1] / H0[:, 1]
    assert (ref[:, 1] < 0.9 * H0[:, 1]).sum() > 5           # the bar shades some points
    # measured 5.1 % and 0.9 % (by area instead: the hall's points beside a window, -27 %)
    assert err.max() < 0.08 and err.mean() < 0.015, (err.max(), err.mean())
