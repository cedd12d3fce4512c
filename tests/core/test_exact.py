"""Exact form factors (app/exact.py): Howell's closed forms against published values and against
the polygon contour integral, reciprocity, the cube's sum rule, the point-kernel limit."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.core.exact import (coaxial_discs, differential_to_rectangle, pair_form_factors_exact,
                       parallel_rectangles, perpendicular_rectangles, polygon_area,
                       polygon_form_factor, polygon_point_form_factor)
from radiosity.core.kernels import pair_form_factors

# 40-digit evaluations (mpmath) of the catalogue's formulas, written to 20 digits; regenerated and
# checked by tests/data/exact_constants.py
OPPOSED_UNIT = 0.19982489569838738304   # C-11, unit squares at distance 1
ADJACENT_UNIT = 0.20004377607540315424  # C-14, unit squares sharing an edge
DISCS_UNIT = 0.38196601125010515180     # C-41, r1 = r2 = h: (3 - sqrt 5) / 2
# unit square to a unit square hinged on its edge at 1 radian: the Lambert point formula
# integrated over the first square by 2-D tanh-sinh quadrature (mpmath, 20 digits)
HINGED_1RAD = 0.38967590320197956784


def rect(o, e1, e2):
    """Rectangle o, o + e1, o + e1 + e2, o + e2 (front normal e1 x e2)."""
    o, e1, e2 = (np.asarray(v, float) for v in (o, e1, e2))
    return np.array([o, o + e1, o + e1 + e2, o + e2])


FLOOR = rect([0, 0, 0], [1, 0, 0], [0, 1, 0])  # faces +z


def test_closed_forms_published_values():
    assert parallel_rectangles(1, 1, 1) == pytest.approx(0.199825, abs=1e-6)
    assert perpendicular_rectangles(1, 1, 1) == pytest.approx(0.200044, abs=1e-6)
    assert coaxial_discs(1, 1, 1) == pytest.approx(0.381966, abs=1e-6)
    assert parallel_rectangles(1, 1, 1) == pytest.approx(OPPOSED_UNIT, rel=1e-14)
    assert perpendicular_rectangles(1, 1, 1) == pytest.approx(ADJACENT_UNIT, rel=1e-14)
    assert coaxial_discs(1, 1, 1) == pytest.approx(DISCS_UNIT, rel=1e-14)
    # limits: huge plates face each other entirely; reciprocity of C-14 and C-41
    assert parallel_rectangles(1e4, 1e4, 1) == pytest.approx(1, abs=2e-4)
    assert perpendicular_rectangles(2, 0.5, 3) * 0.5 == pytest.approx(
        perpendicular_rectangles(2, 3, 0.5) * 3, rel=1e-13)
    assert coaxial_discs(0.5, 2, 1) * 0.25 == pytest.approx(coaxial_discs(2, 0.5, 1) * 4, rel=1e-13)
    # vectorised
    np.testing.assert_allclose(parallel_rectangles([1, 2], [1, 2], [1, 2]), OPPOSED_UNIT,
                               rtol=1e-14)


def test_unit_squares_by_contour_integral():
    top = rect([0, 0, 1], [0, 1, 0], [1, 0, 0])   # faces -z
    wall = rect([0, 0, 0], [0, 0, 1], [1, 0, 0])  # y = 0, faces +y, shares the edge y = z = 0
    assert polygon_form_factor(FLOOR, top) == pytest.approx(OPPOSED_UNIT, rel=1e-13)
    assert polygon_form_factor(FLOOR, wall) == pytest.approx(ADJACENT_UNIT, rel=1e-13)


@pytest.mark.parametrize("a,b,c", [(1, 1, 1), (2, 0.5, 0.3), (1, 1, 0.01), (5, 2, 1e-3),
                                   (0.1, 3, 5), (1, 1, 20)])
def test_polygon_vs_parallel_rectangles(a, b, c):
    P = rect([0, 0, 0], [a, 0, 0], [0, b, 0])
    Q = rect([0, 0, c], [0, b, 0], [a, 0, 0])
    assert polygon_form_factor(P, Q) == pytest.approx(parallel_rectangles(a, b, c), rel=1e-10)


@pytest.mark.parametrize("l,w,h", [(1, 1, 1), (1, 0.1, 3), (2, 1, 0.01), (0.01, 1, 1),
                                   (1, 1e-3, 1), (3, 0.7, 0.2)])
def test_polygon_vs_perpendicular_rectangles(l, w, h):
    P = rect([0, 0, 0], [l, 0, 0], [0, w, 0])
    W = rect([0, 0, 0], [0, 0, h], [l, 0, 0])
    expect = perpendicular_rectangles(l, w, h)
    assert polygon_form_factor(P, W) == pytest.approx(expect, rel=1e-10)
    assert polygon_form_factor(W, P) == pytest.approx(expect * w / h, rel=1e-10)


def test_touching_edges_vertices_and_gaps():
    """T-junctions, triangles meeting at a vertex and a vanishing gap (form-factor algebra)."""
    for x in (0.4, 1e-5):  # the wall in two pieces: each touches part of the floor's edge
        W1 = rect([0, 0, 0], [0, 0, 1], [x, 0, 0])
        W2 = rect([x, 0, 0], [0, 0, 1], [1 - x, 0, 0])
        f = polygon_form_factor(FLOOR, W1) + polygon_form_factor(FLOOR, W2)
        assert f == pytest.approx(ADJACENT_UNIT, rel=1e-12)
    W = rect([0, 0, 0], [0, 0, 1], [1, 0, 0])
    f = polygon_form_factor(FLOOR, W[[0, 1, 2]]) + polygon_form_factor(FLOOR, W[[0, 2, 3]])
    assert f == pytest.approx(ADJACENT_UNIT, rel=1e-12)
    f = 0.5 * (polygon_form_factor(FLOOR[[0, 1, 2]], W) + polygon_form_factor(FLOOR[[0, 2, 3]], W))
    assert f == pytest.approx(ADJACENT_UNIT, rel=1e-12)
    for d in (1e-2, 1e-6):  # floor moved away from the wall by d: C-14 of (1 + d) less C-14 of d
        P = rect([0, d, 0], [1, 0, 0], [0, 1, 0])
        expect = ((1 + d) * perpendicular_rectangles(1, 1 + d, 1)
                  - d * perpendicular_rectangles(1, d, 1))
        assert polygon_form_factor(P, W) == pytest.approx(expect, rel=1e-12)
    th = 1.0  # hinged at 1 radian
    H = np.array([[0, 0, 0], [0, np.cos(th), np.sin(th)], [1, np.cos(th), np.sin(th)], [1, 0, 0]])
    assert polygon_form_factor(FLOOR, H) == pytest.approx(HINGED_1RAD, rel=1e-12)


@pytest.mark.parametrize("r1,r2,h", [(1, 1, 1), (0.5, 2, 1), (1, 0.3, 0.2)])
def test_64gons_vs_coaxial_discs(r1, r2, h):
    n = 64
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    k = np.sqrt(2 * np.pi / (n * np.sin(2 * np.pi / n)))  # the 64-gons keep the discs' areas
    D1 = np.c_[k * r1 * np.cos(t), k * r1 * np.sin(t), 0 * t]         # faces +z
    D2 = np.c_[k * r2 * np.cos(t), -k * r2 * np.sin(t), h + 0 * t]    # faces -z
    assert polygon_form_factor(D1, D2) == pytest.approx(coaxial_discs(r1, r2, h), rel=1e-5)


def test_unit_cube_sum_rule():
    faces = [rect([0, 0, 1], [0, 1, 0], [1, 0, 0]), rect([0, 0, 0], [0, 0, 1], [1, 0, 0]),
             rect([0, 1, 0], [1, 0, 0], [0, 0, 1]), rect([0, 0, 0], [0, 1, 0], [0, 0, 1]),
             rect([1, 0, 0], [0, 0, 1], [0, 1, 0])]
    F = [polygon_form_factor(FLOOR, f, two_sided=False) for f in faces]
    assert sum(F) == pytest.approx(1.0, abs=1e-9)
    assert F[0] == pytest.approx(OPPOSED_UNIT, rel=1e-12)
    np.testing.assert_allclose(F[1:], ADJACENT_UNIT, rtol=1e-12)


def _random_polygon(rng, k):
    """A planar convex k-gon (points on an ellipse) in a random plane and place."""
    c = rng.normal(size=3)
    A = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    t = np.sort(rng.uniform(0, 2 * np.pi, k))
    pts = np.c_[rng.uniform(0.3, 1) * np.cos(t), rng.uniform(0.3, 1) * np.sin(t), np.zeros(k)]
    return c + pts @ A.T


def test_reciprocity_random_pairs(rng):
    n_checked = 0
    for _ in range(150):
        P = _random_polygon(rng, int(rng.integers(3, 6)))
        Q = _random_polygon(rng, int(rng.integers(3, 6)))
        gp = polygon_area(P) * polygon_form_factor(P, Q)
        gq = polygon_area(Q) * polygon_form_factor(Q, P)
        # absolute where clipped slivers have tiny F, relative where F is not small
        assert gp >= 0 and abs(gp - gq) <= 1e-15 + 1e-10 * gp
        n_checked += gp > 1e-4
    assert n_checked > 30


def test_the_fast_rule_matches_the_reference_on_touching_triangles(rng):
    """The near links' rule (8 Gauss nodes a panel, panels graded down to FAST_FLOOR) against the
    reference (12 nodes, down to 1e-9) on triangles of random height fields that share an edge
    or a vertex, or nearly touch: the contour integral's hardest cases."""
    from radiosity.core.exact import (_GW, _GX, _EPS, FAST_FLOOR, FAST_GW, FAST_GX,
                                      polygon_ff_rule)

    fast, ref = [], []
    for k in range(200):
        h = rng.normal(scale=0.5, size=(3, 3))

        def P(i, j):
            return [i, j, h[i, j]]

        A = np.array([P(0, 0), P(1, 0), P(1, 1)], float)
        B = np.array([[P(0, 0), P(1, 1), P(0, 1)], [P(1, 1), P(2, 1), P(2, 2)],
                      [P(1, 0), P(2, 1), P(1, 1)]][k % 3], float) + [0.02 * (k % 4 == 3), 0, 0]
        fast.append(polygon_ff_rule(A, 3, B, 3, True, FAST_GX, FAST_GW, FAST_FLOOR))
        ref.append(polygon_ff_rule(A, 3, B, 3, True, _GX, _GW, _EPS))
    fast, ref = np.array(fast), np.array(ref)
    assert (ref > 1e-3).sum() > 100
    err = np.abs(fast - ref) / np.maximum(ref, 1e-3)
    assert err.max() < 1e-7 and err.mean() < 1e-8, (err.max(), err.mean())  # 0.01: 2e-7, 2e-8


def test_point_kernel_limit():
    """Small far polygons: F -> A_Q cos cos / (pi r^2), the point kernel of app/kernels.py."""
    Q0 = rect([-0.5, -0.5, 0], [0, 1, 0], [1, 0, 0])  # faces -z
    rot = np.array([[1, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]])
    errs = []
    for s in (0.1, 0.01):
        P = s * (FLOOR - 0.5)
        Q = s * Q0 @ rot.T + [1.0, 0.5, 3.0]
        f = polygon_form_factor(P, Q)
        nq = np.cross(Q[1] - Q[0], Q[2] - Q[0])
        nq /= np.linalg.norm(nq)
        area = np.array([s * s])
        fab, fba = pair_form_factors("point", P.mean(0)[None], np.array([[0, 0, 1.0]]), area,
                                     Q.mean(0)[None], nq[None], area)
        errs.append(abs(f / fab[0] - 1))
        assert polygon_form_factor(Q, P) == pytest.approx(fba[0], rel=10 * s * s)
    assert errs[0] < 1e-2 and errs[1] < 1e-4 and errs[1] < errs[0] / 50  # O(s^2)


def test_point_form_factor_vs_closed_forms():
    for a, b, c in [(1, 1, 1), (2, 0.3, 0.5), (0.1, 5, 2)]:
        R = rect([0, 0, c], [a, 0, 0], [0, b, 0])  # parallel, a corner above the element
        assert polygon_point_form_factor([0, 0, 0], [0, 0, 1], R) == pytest.approx(
            differential_to_rectangle(a, b, c), rel=1e-13)
        R = rect([c, 0, 0], [0, b, 0], [0, 0, a])  # standing on the element's plane at x = c
        assert polygon_point_form_factor([0, 0, 0], [0, 0, 1], R) == pytest.approx(
            differential_to_rectangle(a, b, c, perpendicular=True), rel=1e-13)
    # the element's half-space clips: a wall reaching below the element's plane
    tall = rect([1, 0, -1], [0, 1, 0], [0, 0, 2])
    upper = rect([1, 0, 0], [0, 1, 0], [0, 0, 1])
    assert polygon_point_form_factor([0, 0, 0], [0, 0, 1], tall) == pytest.approx(
        differential_to_rectangle(1, 1, 1, perpendicular=True), rel=1e-13)
    assert polygon_point_form_factor([0, 0, 0], [0, 0, 1], upper) == pytest.approx(
        differential_to_rectangle(1, 1, 1, perpendicular=True), rel=1e-13)
    # a shrinking polygon tends to the differential element at its centre
    top = rect([0, 0, 1], [0, 1, 0], [1, 0, 0])
    s = 1e-3
    small = rect([0.3, 0.2, 0], [s, 0, 0], [0, s, 0])
    assert polygon_form_factor(small, top) == pytest.approx(
        polygon_point_form_factor(small.mean(0), [0, 0, 1], top), rel=1e-6)


def test_sides_clipping_and_coplanar():
    below = rect([0, 0, -1], [1, 0, 0], [0, 1, 0])
    assert polygon_form_factor(FLOOR, below) == pytest.approx(OPPOSED_UNIT, rel=1e-13)  # backs
    assert polygon_form_factor(FLOOR, below, two_sided=False) == 0.0
    assert polygon_form_factor(FLOOR, FLOOR + [1, 0, 0]) == 0.0   # coplanar, sharing an edge
    assert polygon_form_factor(FLOOR, FLOOR + [2, 0.5, 0]) == 0.0
    straddling = rect([2, 0, -1], [0, 0, 2], [0, 1, 0])   # half below the floor's plane
    upper = rect([2, 0, 0], [0, 0, 1], [0, 1, 0])
    assert polygon_form_factor(FLOOR, straddling) == pytest.approx(
        polygon_form_factor(FLOOR, upper), rel=1e-12)


def test_pair_form_factors_exact_matches_and_sums():
    n = 8  # floor and wall of the unit cube, each in n x n squares: sum of A F is C-14
    h = 1.0 / n
    fl, wl = [], []
    for i in range(n):
        for j in range(n):
            fl.append(rect([i * h, j * h, 0], [h, 0, 0], [0, h, 0]))
            wl.append(rect([i * h, 0, j * h], [0, 0, h], [h, 0, 0]))
    fl, wl = np.array(fl), np.array(wl)
    Pv = np.repeat(fl, len(wl), axis=0)
    Qv = np.tile(wl, (len(fl), 1, 1))
    nv = np.full(len(Pv), 4, np.int8)
    F = pair_form_factors_exact(Pv, nv, Qv, nv)
    assert F.shape == (len(Pv),) and np.all(F > 0)
    assert (F * h * h).sum() == pytest.approx(ADJACENT_UNIT, rel=1e-12)
    for k in (0, 7, 100, len(Pv) - 1):
        assert F[k] == polygon_form_factor(Pv[k], Qv[k])
    # triangles as stored in app/types.py: slot 3 repeats slot 2
    T = Pv[:50].copy()
    T[:, 3] = T[:, 2]
    nt = np.full(50, 3, np.int8)
    F3 = pair_form_factors_exact(T, nt, Qv[:50], nv[:50])
    F3q = pair_form_factors_exact(T, nv[:50], Qv[:50], nv[:50])   # degenerate edge: harmless
    for k in (0, 9, 49):
        assert F3[k] == pytest.approx(polygon_form_factor(T[k, :3], Qv[k]), rel=1e-14)
    np.testing.assert_allclose(F3q, F3, rtol=1e-10, atol=1e-15)
