"""The high-precision constants of tests/test_exact.py, evaluated with mpmath (40 digits for the
closed forms, 20 for the quadrature), and checked against the values written in that file.

    python tests/data/exact_constants.py

OPPOSED_UNIT   Howell C-11: two directly opposed parallel unit squares at distance 1
ADJACENT_UNIT  Howell C-14: two unit squares sharing an edge at a right angle
DISCS_UNIT     Howell C-41: coaxial discs r1 = r2 = h = 1: (3 - sqrt 5) / 2
HINGED_1RAD    a unit square to a unit square hinged on its edge at 1 radian: Lambert's
               point-to-polygon formula (exact for a differential element) integrated over the
               first square by 2-D tanh-sinh quadrature (mp.quad); no closed form is used
"""

from __future__ import annotations

import os
import re
import sys

import mpmath as mp

HERE = os.path.dirname(os.path.abspath(__file__))


def opposed(a, b, c):
    """Howell C-11: parallel, directly opposed rectangles a x b at distance c."""
    X, Y = mp.mpf(a) / c, mp.mpf(b) / c
    return 2 / (mp.pi * X * Y) * (
        mp.log(mp.sqrt((1 + X**2) * (1 + Y**2) / (1 + X**2 + Y**2)))
        + X * mp.sqrt(1 + Y**2) * mp.atan(X / mp.sqrt(1 + Y**2))
        + Y * mp.sqrt(1 + X**2) * mp.atan(Y / mp.sqrt(1 + X**2))
        - X * mp.atan(X) - Y * mp.atan(Y))


def adjacent(l, w, h):
    """Howell C-14: from the rectangle l x w to the rectangle l x h sharing its edge of length
    l, at a right angle."""
    H, W = mp.mpf(h) / l, mp.mpf(w) / l
    S = H**2 + W**2
    a = (1 + W**2) * (1 + H**2) / (1 + S)
    b = (W**2 * (1 + S) / ((1 + W**2) * S)) ** (W**2)
    c = (H**2 * (1 + S) / ((1 + H**2) * S)) ** (H**2)
    return 1 / (mp.pi * W) * (W * mp.atan(1 / W) + H * mp.atan(1 / H)
                              - mp.sqrt(S) * mp.atan(1 / mp.sqrt(S)) + mp.log(a * b * c) / 4)


def discs(r1, r2, h):
    """Howell C-41: coaxial parallel discs."""
    R1, R2 = mp.mpf(r1) / h, mp.mpf(r2) / h
    X = 1 + (1 + R2**2) / R1**2
    return (X - mp.sqrt(X**2 - 4 * (R2 / R1) ** 2)) / 2


def point_to_polygon(p, n, Q):
    """Lambert's formula: F from a differential element at p with normal n to the polygon Q,
    (1 / 2 pi) |sum_k gamma_k n . (R_k x R_k+1) / |R_k x R_k+1||, R_k = Q_k - p."""
    total = mp.mpf(0)
    k = len(Q)
    for i in range(k):
        a = [Q[i][j] - p[j] for j in range(3)]
        b = [Q[(i + 1) % k][j] - p[j] for j in range(3)]
        cr = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
        ncr = mp.sqrt(sum(x * x for x in cr))
        if ncr == 0:
            continue
        dot = sum(x * y for x, y in zip(a, b))
        gamma = mp.atan2(ncr, dot)
        total += gamma * sum(x * y for x, y in zip(n, cr)) / ncr
    return abs(total) / (2 * mp.pi)


def hinged(theta):
    """Unit square y in [0, 1] on z = 0 (normal +z) to the unit square hinged on its edge along
    x (y = z = 0), rising at angle theta: the point formula averaged over the first square."""
    c, s = mp.cos(theta), mp.sin(theta)
    Q = [[0, 0, 0], [0, c, s], [1, c, s], [1, 0, 0]]
    return mp.quad(lambda x, y: point_to_polygon([x, y, 0], [0, 0, 1], Q), [0, 1], [0, 1])


def written() -> dict:
    """The constants as tests/test_exact.py writes them."""
    src = open(os.path.join(HERE, "..", "test_exact.py")).read()
    return {k: v for k, v in re.findall(r"^([A-Z_0-9]+) = ([0-9.]+)", src, re.M)}


def main() -> int:
    mp.mp.dps = 45
    values = {"OPPOSED_UNIT": opposed(1, 1, 1), "ADJACENT_UNIT": adjacent(1, 1, 1),
              "DISCS_UNIT": discs(1, 1, 1)}
    assert abs(values["DISCS_UNIT"] - (3 - mp.sqrt(5)) / 2) < mp.mpf(10) ** -40
    mp.mp.dps = 25  # the quadrature: 20 digits wanted
    values["HINGED_1RAD"] = hinged(1)
    mp.mp.dps = 45
    ok = True
    for name, v in values.items():
        have = written().get(name)
        digits = 40 if name != "HINGED_1RAD" else 20
        agree = have is not None and abs(mp.mpf(have) - v) <= mp.mpf(10) ** -(len(have) - 3)
        ok &= agree
        print(f"{name:14s} {mp.nstr(v, digits)}   test_exact.py: {have}  {'ok' if agree else 'DIFFERS'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
