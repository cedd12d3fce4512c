"""Spherical triangles: solid angle and uniform, stratified sampling (Arvo 1995, "Stratified
sampling of spherical triangles"). Direct light at points draws its shadow rays to an emitter
that subtends much uniformly in solid angle (scene/direct.py), where sampling by area gives
weights that grow like 1 / r^4 near the point.
"""

from __future__ import annotations

import math

import numba


@numba.njit(cache=True, nogil=True, inline="always")
def unit3(x, y, z):
    """(x, y, z) / its length, as a tuple ((0, 0, 0) stays)."""
    r = math.sqrt(x * x + y * y + z * z)
    return (x / r, y / r, z / r) if r > 0.0 else (0.0, 0.0, 0.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _norm(a):
    return unit3(a[0], a[1], a[2])


@numba.njit(cache=True, nogil=True, inline="always")
def cross(a, b):
    """a x b of 3-tuples."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@numba.njit(cache=True, nogil=True, inline="always")
def dot(a, b):
    """a . b of 3-tuples."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(cache=True, nogil=True, inline="always")
def spherical_triangle(A, B, C):
    """Solid angle of the spherical triangle of unit vectors A, B, C and its angle at A and the
    cosine of its side AB (Arvo 1995's inputs)."""
    ab, ac = _norm(cross(A, B)), _norm(cross(A, C))
    ba, bc = _norm(cross(B, A)), _norm(cross(B, C))
    ca, cb = _norm(cross(C, A)), _norm(cross(C, B))
    al = math.acos(min(1.0, max(-1.0, dot(ab, ac))))
    be = math.acos(min(1.0, max(-1.0, dot(bc, ba))))
    ga = math.acos(min(1.0, max(-1.0, dot(ca, cb))))
    return max(al + be + ga - math.pi, 0.0), al, dot(A, B)


@numba.njit(cache=True, nogil=True, inline="always")
def arvo(A, B, C, area, al, cos_c, u1, u2):
    """A unit direction uniform in solid angle over the spherical triangle A B C (area, the
    angle al at A, cos_c = A.B), from (u1, u2) in the unit square (Arvo 1995, stratified)."""
    ah = u1 * area
    s, t = math.sin(ah - al), math.cos(ah - al)
    u = t - math.cos(al)
    v = s + math.sin(al) * cos_c
    den = (v * s + u * t) * math.sin(al)
    q = ((v * t - u * s) * math.cos(al) - v) / den if den != 0.0 else 1.0
    q = min(1.0, max(-1.0, q))
    d = dot(C, A)
    e = unit3(C[0] - d * A[0], C[1] - d * A[1], C[2] - d * A[2])
    r = math.sqrt(max(0.0, 1.0 - q * q))
    Cp = (q * A[0] + r * e[0], q * A[1] + r * e[1], q * A[2] + r * e[2])
    z = 1.0 - u2 * (1.0 - dot(Cp, B))
    d = dot(Cp, B)
    f = unit3(Cp[0] - d * B[0], Cp[1] - d * B[1], Cp[2] - d * B[2])
    r = math.sqrt(max(0.0, 1.0 - z * z))
    return (z * B[0] + r * f[0], z * B[1] + r * f[1], z * B[2] + r * f[2])
