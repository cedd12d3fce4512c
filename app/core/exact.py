"""Exact (validation) form factors: Howell's closed forms and the contour integral (SPEC §2, §7).

Design notes and measurements: docs/src/design/core-exact.md.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "parallel_rectangles", "perpendicular_rectangles", "coaxial_discs",
    "differential_to_rectangle", "polygon_form_factor", "polygon_point_form_factor",
    "pair_form_factors_exact", "polygon_area",
]

# ---------------------------------------------------------------- closed forms (Howell's catalogue)


def parallel_rectangles(a, b, c):
    """Howell C-11: between identical, parallel, directly opposed a x b rectangles at distance c.

    a, b, c: lengths (same unit), scalars or broadcastable arrays. Returns F (dimensionless).
    Unit squares at distance 1: 0.19982489569838738."""
    X = np.asarray(a, float) / c
    Y = np.asarray(b, float) / c
    x1, y1 = 1.0 + X * X, 1.0 + Y * Y
    sx, sy = np.sqrt(x1), np.sqrt(y1)
    val = (0.5 * np.log(x1 * y1 / (x1 + Y * Y)) + X * sy * np.arctan(X / sy)
           + Y * sx * np.arctan(Y / sx) - X * np.arctan(X) - Y * np.arctan(Y))
    return 2.0 / (np.pi * X * Y) * val


def perpendicular_rectangles(l, w, h):
    """Howell C-14: from an l x w rectangle to an l x h rectangle sharing the edge of length l,
    at 90 degrees (w, h: the widths away from the common edge). Lengths in one unit.
    Returns F_{w->h}; F_{h->w} = F w / h. Unit squares: 0.20004377607540315."""
    H = np.asarray(h, float) / l
    W = np.asarray(w, float) / l
    H2, W2 = H * H, W * W
    s = np.sqrt(H2 + W2)
    # the logarithm of the catalogue's product, term by term (no overflow for large W, H)
    lg = (np.log((1 + W2) * (1 + H2) / (1 + W2 + H2))
          + W2 * np.log(W2 * (1 + W2 + H2) / ((1 + W2) * (W2 + H2)))
          + H2 * np.log(H2 * (1 + W2 + H2) / ((1 + H2) * (W2 + H2))))
    val = W * np.arctan(1 / W) + H * np.arctan(1 / H) - s * np.arctan(1 / s) + 0.25 * lg
    return val / (np.pi * W)


def coaxial_discs(r1, r2, h):
    """Howell C-41: from a disc of radius r1 to a parallel coaxial disc of radius r2 at distance
    h. Returns F_12; r1 = r2 = h gives (3 - sqrt 5)/2 = 0.3819660112501051."""
    R1 = np.asarray(r1, float) / h
    R2 = np.asarray(r2, float) / h
    X = 1.0 + (1.0 + R2 * R2) / (R1 * R1)
    return 0.5 * (X - np.sqrt(X * X - 4.0 * (R2 / R1) ** 2))


def differential_to_rectangle(a, b, c, perpendicular=False):
    """From a differential plane element to an a x b rectangle with a corner at distance c.

    perpendicular=False (Howell B-3): the rectangle is parallel to the element, whose normal
    passes through a corner; a, b the sides. perpendicular=True (same section, planes at 90
    degrees): the rectangle stands on the element's plane, its side a runs along the element's
    normal, its side b lies in the element's plane with the corner nearest the element at
    distance c, and the element faces the rectangle (it lies on the line through that corner
    perpendicular to b). Returns F (dimensionless)."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    if not perpendicular:
        X, Y = a / c, b / c
        sx, sy = np.sqrt(1 + X * X), np.sqrt(1 + Y * Y)
        return (X / sx * np.arctan(Y / sx) + Y / sy * np.arctan(X / sy)) / (2 * np.pi)
    s = np.sqrt(a * a + c * c)
    return (np.arctan(b / c) - c / s * np.arctan(b / s)) / (2 * np.pi)


# ---------------------------------------------------------------- polygons: the contour integral

_NG = 12                                   # Gauss-Legendre nodes per panel
# the rules as tuples: their length is known at compile time (one specialisation each)
_GX, _GW = (tuple(float(x) for x in a) for a in np.polynomial.legendre.leggauss(_NG))
# A coarser rule for callers that need far less than the reference's accuracy: 8 nodes a
# panel, about 1e-7 relative on touching polygons in about two thirds of the time (the
# refinement's near links, methods/hierarchical/links/formfactors.near_ff; docs/src/design/core-exact.md).
FAST_GX, FAST_GW = (tuple(float(x) for x in a) for a in np.polynomial.legendre.leggauss(8))
# The fast rule's innermost panel toward a singularity, relative to the interval: below 1e-4 the
# panels change nothing at its accuracy (random touching triangles: the same 1e-5 worst and
# 4e-8 mean relative error as at _EPS) and cost a third of its time.
FAST_FLOOR = 1e-4
_SIGMA = 0.25                              # geometric grading ratio towards a singularity
_EPS = 1e-9                                # innermost panel, relative to the interval
_TWO_PI = 2.0 * np.pi


@numba.njit(cache=True, nogil=True)
def _area_vector(V, n):
    """Area vector of V[:n] ((n, 3)): area times the unit normal, right-handed about the order."""
    ax = ay = az = 0.0
    for k in range(1, n - 1):   # fan from V[0] (no cancellation far from the origin)
        px, py, pz = V[k, 0] - V[0, 0], V[k, 1] - V[0, 1], V[k, 2] - V[0, 2]
        qx, qy, qz = V[k + 1, 0] - V[0, 0], V[k + 1, 1] - V[0, 1], V[k + 1, 2] - V[0, 2]
        ax += py * qz - pz * qy
        ay += pz * qx - px * qz
        az += px * qy - py * qx
    return 0.5 * ax, 0.5 * ay, 0.5 * az


@numba.njit(cache=True, nogil=True)
def _clip(V, n, nx, ny, nz, px, py, pz, tol, out):
    """Sutherland-Hodgman: V[:n] clipped to {x : N . (x - p) >= -tol} into out; returns the count.
    Vertices within tol of the plane are kept as they are (no sliver edges)."""
    m = 0
    for i in range(n):
        j = (i + 1) % n
        da = nx * (V[i, 0] - px) + ny * (V[i, 1] - py) + nz * (V[i, 2] - pz)
        db = nx * (V[j, 0] - px) + ny * (V[j, 1] - py) + nz * (V[j, 2] - pz)
        ain = da >= -tol
        bin_ = db >= -tol
        if ain:
            for k in range(3):
                out[m, k] = V[i, k]
            m += 1
        if ain != bin_ and abs(da) > tol and abs(db) > tol:
            t = da / (da - db)
            for k in range(3):
                out[m, k] = V[i, k] + t * (V[j, k] - V[i, k])
            m += 1
    return m


@numba.njit(cache=True, nogil=True)
def _inner(s, w0x, w0y, w0z, w1x, w1y, w1z, ux, uy, uz, vx, vy, vz, lq, lnr02):
    """int_0^lq ln(r / R0) dt from the point p0 + s u to the segment q0 + t v, less the terms that
    vanish around closed contours (-lq, and lq ln R0 which is absorbed by ln(r^2 / R0^2) / 2).
    w0 = p0 - q0, w1 = p0 - q1; u, v unit; lnr02 = ln R0^2."""
    d0x = w0x + s * ux
    d0y = w0y + s * uy
    d0z = w0z + s * uz
    d1x = w1x + s * ux
    d1y = w1y + s * uy
    d1z = w1z + s * uz
    x0 = -(d0x * vx + d0y * vy + d0z * vz)   # t-coordinate of q0 relative to the foot
    x1 = -(d1x * vx + d1y * vy + d1z * vz)   # ... and of q1 (x1 - x0 = lq)
    r0 = d0x * d0x + d0y * d0y + d0z * d0z
    r1 = d1x * d1x + d1y * d1y + d1z * d1z
    cx = d0y * vz - d0z * vy
    cy = d0z * vx - d0x * vz
    cz = d0x * vy - d0y * vx
    h2 = cx * cx + cy * cy + cz * cz
    g = 0.0
    if r1 > 0.0:
        g += x1 * (math.log(r1) - lnr02)
    if r0 > 0.0:
        g -= x0 * (math.log(r0) - lnr02)
    g *= 0.5
    if h2 > 0.0:
        h = math.sqrt(h2)
        g += h * math.atan2(h * lq, h2 + x0 * x1)   # h (atan(x1/h) - atan(x0/h))
    return g


@numba.njit(cache=True, nogil=True)
def _graded(e, length, sgn, D, seg, gx, gw, floor):
    """Integral of _inner over [e, e + sgn length] by Gauss-Legendre panels (nodes gx, weights
    gw) shrinking by _SIGMA towards e down to D (the distance from e to the nearest complex
    singularity) or `floor` times the length. seg: _inner's arguments after s, (w0x, w0y,
    w0z, w1x, w1y, w1z, ux, uy, uz, vx, vy, vz, lq, lnr02)."""
    w0x, w0y, w0z, w1x, w1y, w1z, ux, uy, uz, vx, vy, vz, lq, lnr02 = seg
    lowest = max(D, floor * length)
    acc = 0.0
    hi = length
    while True:
        lo = hi * _SIGMA if hi > lowest else 0.0
        half = 0.5 * (hi - lo)
        mid = e + sgn * 0.5 * (hi + lo)
        pan = 0.0
        for k in range(len(gx)):
            pan += gw[k] * _inner(mid + sgn * half * gx[k], w0x, w0y, w0z, w1x, w1y, w1z,
                                  ux, uy, uz, vx, vy, vz, lq, lnr02)
        acc += pan * half
        if lo == 0.0:
            break
        hi = lo
    return acc


@numba.njit(cache=True, nogil=True)
def _edge_pair(P, i, j, Q, k, l, lnr02, gx, gw, floor):
    """(e_hat . f_hat) int_e int_f ln(r / R0) ds dt for the segments e = P[i]P[j], f = Q[k]Q[l]
    (less the closed-contour-null terms, see _inner)."""
    ux = P[j, 0] - P[i, 0]
    uy = P[j, 1] - P[i, 1]
    uz = P[j, 2] - P[i, 2]
    vx = Q[l, 0] - Q[k, 0]
    vy = Q[l, 1] - Q[k, 1]
    vz = Q[l, 2] - Q[k, 2]
    lp = math.sqrt(ux * ux + uy * uy + uz * uz)
    lq = math.sqrt(vx * vx + vy * vy + vz * vz)
    if lp == 0.0 or lq == 0.0:
        return 0.0
    ux /= lp
    uy /= lp
    uz /= lp
    vx /= lq
    vy /= lq
    vz /= lq
    c = ux * vx + uy * vy + uz * vz
    if abs(c) < 1e-15:
        return 0.0
    w0x = P[i, 0] - Q[k, 0]
    w0y = P[i, 1] - Q[k, 1]
    w0z = P[i, 2] - Q[k, 2]
    w1x = P[i, 0] - Q[l, 0]
    w1y = P[i, 1] - Q[l, 1]
    w1z = P[i, 2] - Q[l, 2]
    # complex singularities s + i d of the integrand in s: nearest approach to q0, to q1 ...
    s0 = -(w0x * ux + w0y * uy + w0z * uz)
    d0 = math.sqrt(max(w0x * w0x + w0y * w0y + w0z * w0z - s0 * s0, 0.0))
    s1 = -(w1x * ux + w1y * uy + w1z * uz)
    d1 = math.sqrt(max(w1x * w1x + w1y * w1y + w1z * w1z - s1 * s1, 0.0))
    # ... and h(s) = |A + s B| = 0, the foot on f's line (A = w0 x v, B = u x v); none if parallel
    Ax = w0y * vz - w0z * vy
    Ay = w0z * vx - w0x * vz
    Az = w0x * vy - w0y * vx
    Bx = uy * vz - uz * vy
    By = uz * vx - ux * vz
    Bz = ux * vy - uy * vx
    b2 = Bx * Bx + By * By + Bz * Bz
    s2 = s0
    d2 = d0
    if b2 > 1e-24:
        s2 = -(Ax * Bx + Ay * By + Az * Bz) / b2
        Cx = Ay * Bz - Az * By
        Cy = Az * Bx - Ax * Bz
        Cz = Ax * By - Ay * Bx
        d2 = math.sqrt(Cx * Cx + Cy * Cy + Cz * Cz) / b2
    # break points: the real parts inside (0, lp), sorted; closer than _EPS lp count as one
    tiny = _EPS * lp
    b0 = min(s0, s1, s2)
    b2_ = max(s0, s1, s2)
    b1 = s0 + s1 + s2 - b0 - b2_
    seg = (w0x, w0y, w0z, w1x, w1y, w1z, ux, uy, uz, vx, vy, vz, lq, lnr02)
    acc = 0.0
    prev = 0.0
    for t in range(4):
        cur = lp
        if t == 0:
            cur = b0
        elif t == 1:
            cur = b1
        elif t == 2:
            cur = b2_
        if cur <= prev + tiny or (t < 3 and cur >= lp - tiny):
            continue
        half = 0.5 * (cur - prev)
        da = min(math.hypot(s0 - prev, d0), math.hypot(s1 - prev, d1), math.hypot(s2 - prev, d2))
        db = min(math.hypot(s0 - cur, d0), math.hypot(s1 - cur, d1), math.hypot(s2 - cur, d2))
        acc += _graded(prev, half, 1.0, da, seg, gx, gw, floor)
        acc += _graded(cur, half, -1.0, db, seg, gx, gw, floor)
        prev = cur
    return c * acc


@numba.njit(cache=True, nogil=True)
def _polygon_ff(P, nP, Q, nQ, two_sided):
    """F_PQ for convex planar polygons P[:nP], Q[:nQ] ((k, 3) float64), unoccluded."""
    return polygon_ff_rule(P, nP, Q, nQ, two_sided, _GX, _GW, _EPS)


@numba.njit(cache=True, nogil=True)
def polygon_ff_rule(P, nP, Q, nQ, two_sided, gx, gw, floor):
    """_polygon_ff with the Gauss-Legendre rule (gx, gw) of the contour integral's panels, graded
    toward each singularity down to `floor` times the interval (_GX, _GW, _EPS: the reference;
    FAST_GX, FAST_GW, FAST_FLOOR: about 1e-7)."""
    apx, apy, apz = _area_vector(P, nP)
    aqx, aqy, aqz = _area_vector(Q, nQ)
    AP = math.sqrt(apx * apx + apy * apy + apz * apz)
    AQ = math.sqrt(aqx * aqx + aqy * aqy + aqz * aqz)
    if AP == 0.0 or AQ == 0.0:
        return 0.0
    nPx, nPy, nPz = apx / AP, apy / AP, apz / AP
    nQx, nQy, nQz = aqx / AQ, aqy / AQ, aqz / AQ
    dx = dy = dz = 0.0   # vertex centroid of Q less that of P
    for k in range(nQ):
        dx += Q[k, 0] / nQ
        dy += Q[k, 1] / nQ
        dz += Q[k, 2] / nQ
    for k in range(nP):
        dx -= P[k, 0] / nP
        dy -= P[k, 1] / nP
        dz -= P[k, 2] / nP
    r02 = dx * dx + dy * dy + dz * dz
    scale = math.sqrt(max(AP, AQ))
    tol = 1e-11 * max(scale, math.sqrt(r02))
    sP = 1.0
    sQ = 1.0
    # Q in P's plane (or P in Q's): cos_P (or cos_Q) vanishes everywhere
    hiP = loP = 0.0
    for k in range(nQ):
        g = nPx * (Q[k, 0] - P[0, 0]) + nPy * (Q[k, 1] - P[0, 1]) + nPz * (Q[k, 2] - P[0, 2])
        hiP = max(hiP, g)
        loP = min(loP, g)
    hiQ = loQ = 0.0
    for k in range(nP):
        g = nQx * (P[k, 0] - Q[0, 0]) + nQy * (P[k, 1] - Q[0, 1]) + nQz * (P[k, 2] - Q[0, 2])
        hiQ = max(hiQ, g)
        loQ = min(loQ, g)
    if max(hiP, -loP) <= tol or max(hiQ, -loQ) <= tol:
        return 0.0
    if two_sided:   # the side facing the other's centroid; front if that lies in the plane
        gp = nPx * dx + nPy * dy + nPz * dz
        gq = -(nQx * dx + nQy * dy + nQz * dz)
        sP = -1.0 if gp < -tol else 1.0
        sQ = -1.0 if gq < -tol else 1.0
    # each polygon clipped to the (chosen) front half-space of the other
    Pc = np.empty((2 * nP + 2, 3))   # room even for warped input
    Qc = np.empty((2 * nQ + 2, 3))
    mQ = _clip(Q, nQ, sP * nPx, sP * nPy, sP * nPz, P[0, 0], P[0, 1], P[0, 2], tol, Qc)
    mP = _clip(P, nP, sQ * nQx, sQ * nQy, sQ * nQz, Q[0, 0], Q[0, 1], Q[0, 2], tol, Pc)
    if mP < 3 or mQ < 3:
        return 0.0
    lnr02 = math.log(max(r02, 1e-300))
    acc = 0.0
    for i in range(mP):
        for j in range(mQ):
            acc += _edge_pair(Pc, i, (i + 1) % mP, Qc, j, (j + 1) % mQ, lnr02, gx, gw, floor)
    # contours counter-clockwise about their own (chosen) normals: F = sum / (2 pi A_P)
    return sP * sQ * acc / (_TWO_PI * AP)


@numba.njit(cache=True, nogil=True)
def point_to_polygon_ff(p, n, Q, nQ):
    """Differential element at p (normal n, unit) to the polygon Q[:nQ], clipped to n's side."""
    return point_ff(p[0], p[1], p[2], n[0], n[1], n[2], Q, nQ, np.empty((2 * nQ + 2, 3)))


@numba.njit(cache=True, nogil=True)
def point_ff(px, py, pz, nx, ny, nz, Q, nQ, Qc):
    """point_to_polygon_ff with the point and normal as scalars and the clipped polygon in the caller's
    scratch Qc (at least (2 nQ + 2, 3)): no allocation, for loops over millions of links."""
    scale = 0.0
    for k in range(nQ):
        scale = max(scale, math.sqrt((Q[k, 0] - px) ** 2 + (Q[k, 1] - py) ** 2
                                     + (Q[k, 2] - pz) ** 2))
    m = _clip(Q, nQ, nx, ny, nz, px, py, pz, 1e-12 * scale, Qc)
    acc = 0.0
    for k in range(m if m >= 3 else 0):
        l = (k + 1) % m
        ax, ay, az = Qc[k, 0] - px, Qc[k, 1] - py, Qc[k, 2] - pz
        bx, by, bz = Qc[l, 0] - px, Qc[l, 1] - py, Qc[l, 2] - pz
        cx = ay * bz - az * by
        cy = az * bx - ax * bz
        cz = ax * by - ay * bx
        cn = math.sqrt(cx * cx + cy * cy + cz * cz)
        if cn > 0.0:
            gamma = math.atan2(cn, ax * bx + ay * by + az * bz)
            acc += gamma * (nx * cx + ny * cy + nz * cz) / cn
    return abs(acc) / _TWO_PI


@numba.njit(cache=True, nogil=True)
def _pairs(Pv, Pn, Qv, Qn, two_sided, out):
    for k in range(Pv.shape[0]):
        out[k] = _polygon_ff(Pv[k], Pn[k], Qv[k], Qn[k], two_sided)


def _poly(P) -> np.ndarray:
    P = np.ascontiguousarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or P.shape[0] < 3:
        raise ValueError(f"a polygon is a (k >= 3, 3) array of vertices, got shape {P.shape}")
    return P


def polygon_area(P) -> float:
    """Area of the planar polygon P (k, 3)."""
    P = _poly(P)
    return float(np.linalg.norm(_area_vector(P, len(P))))


def polygon_form_factor(P, Q, two_sided: bool = True) -> float:
    """Exact unoccluded F_PQ from convex planar polygon P (k, 3) to Q (l, 3), by the double
    contour integral (Sparrow; Schroeder & Hanrahan 1993), accurate to ~1e-13 relative,
    including polygons sharing an edge or a vertex. Vertices counter-clockwise about the front
    normal. two_sided: use the sides facing each other (by centroids); else fronts only.
    Returns F_PQ (dimensionless); A_P F_PQ = A_Q F_QP."""
    P, Q = _poly(P), _poly(Q)
    return float(_polygon_ff(P, len(P), Q, len(Q), bool(two_sided)))


def polygon_point_form_factor(p, n, Q) -> float:
    """Exact unoccluded form factor from a differential element at p (3,) with normal n (3,) to
    the convex planar polygon Q (l, 3) (Lambert's contour formula; either side of Q counts; the
    part of Q behind the element's plane is clipped off)."""
    n = np.asarray(n, float)
    n = np.ascontiguousarray(n / np.linalg.norm(n))
    return float(point_to_polygon_ff(np.ascontiguousarray(p, dtype=np.float64), n, _poly(Q), len(Q)))


def pair_form_factors_exact(Pverts, Pnv, Qverts, Qnv, two_sided: bool = True) -> np.ndarray:
    """polygon_form_factor over k pairs stored as in app/types.py.

    Pverts, Qverts: (k, 4, 3) float64; Pnv, Qnv: (k,) vertex counts in {3, 4} (a triangle's
    slot 3 repeats slot 2 and is ignored). Returns F_PQ (k,) float64; F_QP = F_PQ A_P / A_Q."""
    Pv = np.ascontiguousarray(Pverts, dtype=np.float64)
    Qv = np.ascontiguousarray(Qverts, dtype=np.float64)
    Pn = np.ascontiguousarray(Pnv, dtype=np.int64)
    Qn = np.ascontiguousarray(Qnv, dtype=np.int64)
    out = np.empty(Pv.shape[0])
    _pairs(Pv, Pn, Qv, Qn, bool(two_sided), out)
    return out
