"""Spherical triangles (core/spherical.py): the solid angle against Van Oosterom and Strackee's
formula, and Arvo's sampling: every sample inside, and uniform (the share of a stratified grid
of samples in a sub-triangle is its share of the solid angle)."""

from __future__ import annotations

import math

import numba
import numpy as np

from radiosity.core.spherical import arvo, spherical_triangle


@numba.njit
def _omega(A, B, C):
    return spherical_triangle((A[0], A[1], A[2]), (B[0], B[1], B[2]), (C[0], C[1], C[2]))


@numba.njit
def _draw(A, B, C, k, out):
    a = (A[0], A[1], A[2])
    b = (B[0], B[1], B[2])
    c = (C[0], C[1], C[2])
    om, al, cc = spherical_triangle(a, b, c)
    for i in range(k):
        for j in range(k):
            w = arvo(a, b, c, om, al, cc, (i + 0.5) / k, (j + 0.5) / k)
            for q in range(3):
                out[i * k + j, q] = w[q]


def _tri(rng, spread):
    V = rng.normal(size=3) * 3 + rng.normal(size=(3, 3)) * spread
    return V / np.linalg.norm(V, axis=1, keepdims=True)


def _vos(A, B, C):
    """Van Oosterom & Strackee (1983): tan(omega / 2) = |A.(B x C)| / (1 + A.B + B.C + C.A)."""
    num = abs(A @ np.cross(B, C))
    return 2 * math.atan2(num, 1 + A @ B + B @ C + C @ A)


def test_solid_angle_matches_van_oosterom_strackee(rng):
    for spread in (0.05, 0.5, 2.0):
        for _ in range(20):
            A, B, C = _tri(rng, spread)
            assert abs(_omega(A, B, C)[0] - _vos(A, B, C)) < 1e-9 * max(1.0, _vos(A, B, C)) + 1e-12


def test_arvo_samples_are_inside_and_uniform(rng):
    k = 64
    for spread in (0.3, 1.0, 3.0):
        for _ in range(5):
            A, B, C = _tri(rng, spread)
            if np.linalg.det(np.array([A, B, C])) < 0:
                B, C = C, B
            W = np.zeros((k * k, 3))
            _draw(A, B, C, k, W)
            np.testing.assert_allclose(np.linalg.norm(W, axis=1), 1.0, atol=1e-9)
            # inside: on the inner side of the three great circles
            for P, Q in ((A, B), (B, C), (C, A)):
                assert (W @ np.cross(P, Q) > -1e-9).all()
            # the sub-triangle A B M (M: the middle of arc B C) holds its share of the samples
            M = (B + C) / np.linalg.norm(B + C)
            share = _vos(A, B, M) / _vos(A, B, C)
            inside = (W @ np.cross(A, B) >= 0) & (W @ np.cross(B, M) >= 0) & (W @ np.cross(M, A) >= 0)
            assert abs(inside.mean() - share) < 0.01, (inside.mean(), share)
