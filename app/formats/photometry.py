"""Photometric files: IES LM-63 (1986, 1991, 1995, 2002) and EULUMDAT (.ldt) -> a candela table
(`Photometry`) with its symmetry unfolded, interpolated bilinearly in the file's two angles.

The angles of each photometric type, for a unit direction with components (x, y, z) along the
luminaire's C0 axis p, C90 axis q and aim (photometric nadir / beam axis) f:

- type C (polar axis f): vertical gamma = acos z (0 at the nadir), horizontal C = atan2(y, x)
  (0 along p, 90 along q);
- type B (polar axis q): vertical V = atan2(x, z) (the plane through q, positive toward p),
  horizontal H = asin(-y) (the angle in that plane, positive toward -q);
- type A (polar axis p): horizontal H = atan2(-y, z) (the plane through p), vertical V = asin x.

These are Radiance's axes (source.cal: src_theta, src_phi; srcB_vert, srcB_horiz), so a file
converted by `ies2rad` points the same way. Between the table's angles the intensity is
bilinear in the angles (LM-63 and EN 13032-1 leave the method open; bilinear is what Radiance
and the common tools do); outside its vertical range it is 0. Horizontal symmetries are
unfolded when the file is read: one angle (rotational), 0-90 (quadrants), 0-180 and 90-270
(bilateral), 0-<360 (full, wrapped to 360); types A and B: 0-90 mirrored to -90-90.
Every problem is one PhotometryError naming the file and the line or field.
Design note: docs/src/design/scene-emitters.md.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from radiosity.errors import SceneError

#: Photometric types by their LM-63 number.
TYPES = {1: "C", 2: "B", 3: "A"}
#: Angles closer than this (degrees) are the same angle.
ANGLE_TOL = 1e-6


class PhotometryError(SceneError):
    """A photometric file that cannot be read: the message names the file and line or field."""


@dataclass(frozen=True)
class Photometry:
    """A luminous intensity distribution, absolute (candela), symmetry unfolded.

    kind : "C", "B" or "A"
    horizontal : (nh,) float64 degrees, ascending (type C: 0 .. 360 inclusive; A, B: -90 .. 90)
    vertical : (nv,) float64 degrees, ascending
    candela : (nh, nv) float64, cd (the file's multiplier and ballast factors applied)
    source : the file it came from (messages)
    """

    kind: str
    horizontal: np.ndarray
    vertical: np.ndarray
    candela: np.ndarray
    source: str = ""

    def angles(self, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(h, v) degrees of unit directions `local` (k, 3) in the luminaire's (p, q, f) frame."""
        x, y, z = (np.clip(local[:, i], -1.0, 1.0) for i in range(3))
        if self.kind == "C":
            return np.degrees(np.arctan2(y, x)) % 360.0, np.degrees(np.arccos(z))
        if self.kind == "B":
            return np.degrees(np.arcsin(-y)), np.degrees(np.arctan2(x, z))
        return np.degrees(np.arctan2(-y, z)), np.degrees(np.arcsin(x))

    def at(self, h: np.ndarray, v: np.ndarray) -> np.ndarray:
        """cd at angles (h, v) (degrees, same shape), bilinear; 0 outside the table."""
        H, V, T = self.horizontal, self.vertical, self.candela
        h = np.asarray(h, np.float64)
        v = np.asarray(v, np.float64)
        i, s, hin = _cell(H, h)
        j, t, vin = _cell(V, v)
        val = ((1 - s) * ((1 - t) * T[i, j] + t * T[i, j + 1])
               + s * ((1 - t) * T[i + 1, j] + t * T[i + 1, j + 1]))
        return np.where(hin & vin, val, 0.0)

    def intensity(self, local: np.ndarray) -> np.ndarray:
        """cd toward unit directions `local` (k, 3) in the luminaire's frame."""
        return self.at(*self.angles(np.asarray(local, np.float64)))

    def flux(self) -> float:
        """Total luminous flux (lm) of the interpolated distribution, exact for the bilinear
        interpolant: per cell, the integral of a linear function times the solid angle's weight
        (sin of gamma for type C, cos of the latitude for A and B), and trapezoids in the other
        angle."""
        h, v = np.radians(self.horizontal), np.radians(self.vertical)
        if self.kind == "C":          # d omega = sin(gamma) d gamma dC
            wh, wv = _node_weights(h, None), _node_weights(v, "sin")
        elif self.kind == "B":        # H the latitude: d omega = cos H dH dV
            wh, wv = _node_weights(h, "cos"), _node_weights(v, None)
        else:                         # V the latitude: d omega = cos V dH dV
            wh, wv = _node_weights(h, None), _node_weights(v, "cos")
        return float(wh @ self.candela @ wv)

    def peak(self) -> float:
        return float(self.candela.max(initial=0.0))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "horizontal": self.horizontal.tolist(),
                "vertical": self.vertical.tolist(), "candela": self.candela.tolist(),
                "source": self.source}

    @classmethod
    def from_dict(cls, d: dict) -> "Photometry":
        return cls(d["kind"], np.asarray(d["horizontal"], np.float64),
                   np.asarray(d["vertical"], np.float64),
                   np.asarray(d["candela"], np.float64).reshape(len(d["horizontal"]),
                                                                len(d["vertical"])),
                   d.get("source", ""))


def _node_weights(x: np.ndarray, kernel: str | None) -> np.ndarray:
    """(n,) w with sum_i f_i w_i = the integral over [x_0, x_n-1] (radians) of the piecewise
    linear interpolant of f times 1, sin or cos (`kernel` None, "sin", "cos"), exactly."""
    w = np.zeros(len(x))
    if len(x) < 2:
        return w
    a, b = x[:-1], x[1:]
    d = b - a
    if kernel is None:
        S, M = d, 0.5 * (b * b - a * a)                        # int 1, int t
    elif kernel == "sin":
        S = np.cos(a) - np.cos(b)
        M = (np.sin(b) - b * np.cos(b)) - (np.sin(a) - a * np.cos(a))
    else:
        S = np.sin(b) - np.sin(a)
        M = (np.cos(b) + b * np.sin(b)) - (np.cos(a) + a * np.sin(a))
    w1 = (M - a * S) / d                                       # the weight of the right node
    np.add.at(w, np.arange(1, len(x)), w1)
    np.add.at(w, np.arange(len(x) - 1), S - w1)
    return w


def _cell(grid: np.ndarray, x: np.ndarray):
    """(i, s, inside): x lies in [grid[i], grid[i + 1]] at fraction s; inside: within the grid."""
    if len(grid) == 1:
        return (np.zeros(x.shape, np.int64), np.zeros(x.shape),
                np.abs(x - grid[0]) <= ANGLE_TOL)
    i = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, len(grid) - 2)
    s = np.clip((x - grid[i]) / (grid[i + 1] - grid[i]), 0.0, 1.0)
    inside = (x >= grid[0] - ANGLE_TOL) & (x <= grid[-1] + ANGLE_TOL)
    return i, s, inside


# ----------------------------------------------------------------------------- unfolding

def _mirror(h: np.ndarray, T: np.ndarray, about: float):
    """The table with its mirror image about the plane at angle `about` (h -> 2 about - h)."""
    return np.concatenate([h, 2 * about - h[::-1]]), np.concatenate([T, T[::-1]])


def _merge(h: np.ndarray, T: np.ndarray):
    """Sorted unique angles (the first of equal ones kept) and their rows."""
    o = np.argsort(h, kind="stable")
    h, T = h[o], T[o]
    keep = np.concatenate([[True], np.diff(h) > ANGLE_TOL])
    return h[keep], T[keep]


def unfold_c(h: np.ndarray, T: np.ndarray, where: str):
    """Type C horizontal angles (C planes) unfolded to 0 .. 360 inclusive."""
    h0, h1 = float(h[0]), float(h[-1])
    if len(h) == 1:
        return np.array([0.0, 360.0]), np.concatenate([T, T])
    if abs(h0) <= ANGLE_TOL and abs(h1 - 90) <= ANGLE_TOL:          # quadrant symmetry
        h, T = _mirror(h, T, 90.0)
        h, T = _mirror(*_merge(h, T), 180.0)
    elif abs(h0) <= ANGLE_TOL and abs(h1 - 180) <= ANGLE_TOL:       # about the C0-C180 plane
        h, T = _mirror(h, T, 180.0)
    elif abs(h0 - 90) <= ANGLE_TOL and abs(h1 - 270) <= ANGLE_TOL:  # about the C90-C270 plane
        h, T = _mirror(h, T, 90.0)
        h = h % 360.0
    elif abs(h0) <= ANGLE_TOL and 180 < h1 <= 360 + ANGLE_TOL:      # no symmetry
        pass
    else:
        raise PhotometryError(f"{where}: type C horizontal angles {h0:g} .. {h1:g} are none of "
                              "0, 0-90, 0-180, 90-270, 0-360")
    h, T = _merge(h, T)
    if h[-1] < 360 - ANGLE_TOL:
        h, T = np.append(h, 360.0), np.concatenate([T, T[:1]])
    return h, T


def unfold_ab(h: np.ndarray, T: np.ndarray, where: str, kind: str):
    """Type A or B horizontal angles unfolded to -90 .. 90 (0 .. 90: laterally symmetric)."""
    if len(h) == 1 or abs(h[0]) <= ANGLE_TOL:
        if len(h) == 1:
            h, T = np.array([0.0, 90.0]), np.concatenate([T, T])
        h, T = _merge(*_mirror(h, T, 0.0))
    if h[0] < -90 - ANGLE_TOL or h[-1] > 90 + ANGLE_TOL:
        raise PhotometryError(f"{where}: type {kind} horizontal angles {h[0]:g} .. {h[-1]:g} are "
                              "outside -90 .. 90")
    return h, T


def _check_angles(a: np.ndarray, what: str, where: str, lo: float, hi: float):
    if np.any(np.diff(a) <= 0):
        raise PhotometryError(f"{where}: {what} must increase, got {a.tolist()}")
    if a[0] < lo - ANGLE_TOL or a[-1] > hi + ANGLE_TOL:
        raise PhotometryError(f"{where}: {what} {a[0]:g} .. {a[-1]:g} are outside {lo:g} .. {hi:g}")


def build(kind: str, h: np.ndarray, v: np.ndarray, T: np.ndarray, where: str) -> Photometry:
    """A Photometry from the file's angles and table (nh, nv) cd, checked and unfolded."""
    if kind == "C":
        _check_angles(v, "vertical angles", where, 0.0, 180.0)
        _check_angles(h, "horizontal angles", where, 0.0, 360.0)
        h, T = unfold_c(h, T, where)
    else:
        _check_angles(v, "vertical angles", where, -90.0, 90.0)
        _check_angles(h, "horizontal angles", where, -90.0, 90.0)
        h, T = unfold_ab(h, T, where, kind)
    if np.any(T < 0) or not np.all(np.isfinite(T)):
        raise PhotometryError(f"{where}: a candela value is negative or not finite")
    return Photometry(kind, np.ascontiguousarray(h, np.float64), np.ascontiguousarray(v, np.float64),
                      np.ascontiguousarray(T, np.float64), where)


# ----------------------------------------------------------------------------- IES LM-63

def _read_text(path: str) -> str:
    try:
        with open(path, "rb") as f:
            return f.read().decode("latin-1")
    except OSError as e:
        raise PhotometryError(f"cannot read photometric file {path}: {e.strerror or e}") from None


def read_ies(path: str) -> Photometry:
    """An IES LM-63 file (1986: no header line; 1991, 1995, 2002: keywords before TILT=).
    TILT=NONE only. Candela = value x multiplier x ballast factor x the ballast-lamp factor."""
    lines = _read_text(path).splitlines()
    tilt = next((i for i, ln in enumerate(lines) if ln.strip().upper().startswith("TILT")), None)
    if tilt is None:
        raise PhotometryError(f"{path}: no TILT= line: not an IES LM-63 file")
    value = lines[tilt].split("=", 1)[1].strip() if "=" in lines[tilt] else ""
    if value.upper() != "NONE":
        raise PhotometryError(f"{path}: line {tilt + 1}: TILT={value} is not supported (only "
                              "TILT=NONE: lamp tilt factors are not modelled)")
    toks = [(t, i + 1) for i, ln in enumerate(lines[tilt + 1:], start=tilt + 1)
            for t in ln.replace(",", " ").split()]
    pos = 0

    def take(n: int, what: str) -> np.ndarray:
        nonlocal pos
        if pos + n > len(toks):
            got = len(toks) - pos
            raise PhotometryError(f"{path}: the file ends after {max(got, 0)} of the {n} "
                                  f"{what}")
        out = np.empty(n)
        for k in range(n):
            t, ln = toks[pos + k]
            try:
                out[k] = float(t)
            except ValueError:
                raise PhotometryError(f"{path}: line {ln}: {what}: {t!r} is not a number") from None
            if not math.isfinite(out[k]):
                raise PhotometryError(f"{path}: line {ln}: {what}: {t!r} is not finite")
        pos += n
        return out

    head = take(10, "fields of the line after TILT (lamps, lumens, multiplier, angle counts, "
                    "type, units, width, length, height)")
    _, _, mult, nv, nh, ptype = head[:6]
    bf = take(3, "fields of the ballast line (ballast factor, ballast-lamp factor, watts)")
    for val, what in ((nv, "number of vertical angles"), (nh, "number of horizontal angles")):
        if val != int(val) or val < 1:
            raise PhotometryError(f"{path}: line {toks[0][1]}: {what} {val:g} must be a whole "
                                  "number >= 1")
    if int(ptype) not in TYPES or ptype != int(ptype):
        raise PhotometryError(f"{path}: line {toks[0][1]}: photometric type {ptype:g} must be "
                              "1 (C), 2 (B) or 3 (A)")
    nv, nh = int(nv), int(nh)
    if nv < 2:
        raise PhotometryError(f"{path}: line {toks[0][1]}: {nv} vertical angle: need 2 or more")
    v = take(nv, "vertical angles")
    h = take(nh, "horizontal angles")
    T = take(nv * nh, "candela values").reshape(nh, nv)
    scale = mult * bf[0] * (bf[1] if bf[1] > 0 else 1.0)
    if not scale > 0:
        raise PhotometryError(f"{path}: line {toks[0][1]}: candela multiplier x ballast factors "
                              f"= {scale:g} must be > 0")
    return build(TYPES[int(ptype)], h, v, T * scale, path)


# ----------------------------------------------------------------------------- EULUMDAT

#: Values of the intensity table per symmetry Isym: (first C-plane index, planes) of Mc.
def _ldt_planes(isym: int, mc: int) -> tuple[int, int]:
    return {0: (0, mc), 1: (0, 1), 2: (0, mc // 2 + 1), 3: (mc // 4, mc // 2 + 1),
            4: (0, mc // 4 + 1)}[isym]


def read_ldt(path: str) -> Photometry:
    """An EULUMDAT file: type C, symmetry Isym 0-4, intensities in cd/klm of the lamps' flux
    (set 1: its number of lamps times the luminous flux field; a negative number of lamps:
    absolute photometry, cd as given), times the conversion factor."""
    lines = [ln.strip() for ln in _read_text(path).splitlines()]

    def num(i: int, what: str, integer: bool = False) -> float:
        if i >= len(lines):
            raise PhotometryError(f"{path}: the file ends before line {i + 1} ({what})")
        try:
            x = float(lines[i].replace(",", ".")) if lines[i] else float("nan")
        except ValueError:
            raise PhotometryError(f"{path}: line {i + 1}: {what}: {lines[i]!r} is not a "
                                  "number") from None
        if not math.isfinite(x) or (integer and x != int(x)):
            raise PhotometryError(f"{path}: line {i + 1}: {what}: {lines[i]!r} is not a "
                                  + ("whole number" if integer else "finite number"))
        return x

    isym = int(num(2, "symmetry indicator Isym", True))
    mc = int(num(3, "number of C-planes Mc", True))
    ng = int(num(5, "number of intensities per C-plane Ng", True))
    if isym not in range(5):
        raise PhotometryError(f"{path}: line 3: symmetry indicator Isym {isym} must be 0 .. 4")
    if mc < 1 or ng < 2:
        raise PhotometryError(f"{path}: lines 4 / 6: Mc = {mc} C-planes and Ng = {ng} angles "
                              "(need Mc >= 1, Ng >= 2)")
    cf = num(23, "conversion factor for luminous intensities")
    n = int(num(25, "number of standard sets of lamps n", True))
    if n < 1:
        raise PhotometryError(f"{path}: line 26: number of standard sets of lamps {n} must be >= 1")
    lamps = num(26, "number of lamps", True)
    flux = num(26 + 2 * n, "total luminous flux of lamps")
    at = 26 + 6 * n + 10                    # after the sets and the 10 direct ratios
    C = np.array([num(at + k, f"C-angle {k + 1}") for k in range(mc)])
    G = np.array([num(at + mc + k, f"gamma angle {k + 1}") for k in range(ng)])
    first, planes = _ldt_planes(isym, mc)
    start = at + mc + ng
    I = np.array([num(start + k, f"luminous intensity {k + 1}") for k in range(planes * ng)])
    I = I.reshape(planes, ng)
    per_klm = (abs(flux) / 1000.0) if lamps >= 0 else 1.0
    if not per_klm * cf > 0:
        raise PhotometryError(f"{path}: lines 24 / {28 + n}: the lamps' flux x conversion "
                              f"factor = {per_klm * cf * 1000:g} must be > 0")
    if isym == 1:
        h = np.array([0.0])
    else:
        h = C[first:first + planes]
        if len(h) != planes:
            raise PhotometryError(f"{path}: Isym {isym} needs C-planes {first + 1} .. "
                                  f"{first + planes} of the Mc = {mc} given")
    return build("C", h, G, I * per_klm * cf, path)


#: Readers by file extension.
READERS = {".ies": read_ies, ".ldt": read_ldt}


def read_photometry(path: str) -> Photometry:
    """The photometric file at `path`, by its extension (.ies or .ldt, any case)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in READERS:
        raise PhotometryError(f"{path}: unknown photometric file type {ext or '(none)'!r}: "
                              f"use {', '.join(READERS)}")
    if not os.path.isfile(path):
        raise PhotometryError(f"photometric file not found: {path}")
    return READERS[ext](path)
