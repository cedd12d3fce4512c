"""Luminaires: point sources and goniometric (IES / EULUMDAT) luminaires of a scene's
`[[luminaire]]` tables, as one frozen `Luminaires` bundle that travels with the scene's
Elements (`Elements.luminaires`), so every user of the elements (the first bounce, new views,
grids) sees them; `emitters.PointEmitters` puts them behind the Emitter protocol and
`direct.DirectLight` gives their exact direct light at points.

Units: positions in the scene's unit, taken as metres for photometry (cd / m^2 = lx);
intensities in cd, turned into W sr^-1 per RGB channel by the colour (normalised to a Y of 1,
Rec. 709 weights) over 683 lm/W, the efficacy stages/tables.py reads lux back with, so that
photometric values are exact end to end. Design note: docs/src/design/scene-emitters.md.
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass

import numpy as np

from radiosity.core.colour import EFFICACY, LUMA
from radiosity.errors import SceneError
from radiosity.formats.photometry import Photometry, read_photometry

#: Keys of a [[luminaire]] table.
KEYS = {"name", "ies", "position", "aim", "rotation", "multiplier", "flux_lm", "colour",
        "intensity_cd", "distribution"}
#: Distributions of a luminaire without a photometric file (I0: intensity_cd).
DISTRIBUTIONS = ("isotropic", "lambertian")
#: Directions probed from a luminaire for the inside-a-wall check (axes and diagonals).
_PROBES = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                    if (x, y, z) != (0, 0, 0)], np.float64)
_PROBES /= np.linalg.norm(_PROBES, axis=1, keepdims=True)


@dataclass(frozen=True)
class Luminaire:
    """One luminaire: where, which way, how bright.

    frame : (3, 3) rows p (the C0 axis), q (the C90 axis), f (the aim, photometric nadir);
        p x q = -f
    distribution : "isotropic" | "lambertian" (intensity_cd about the aim) | "table"
    cd : intensity_cd of a point source, or the table's scale (multiplier, or flux_lm over the
        table's own flux)
    colour : (3,) RGB with 0.2126 R + 0.7152 G + 0.0722 B = 1
    """

    name: str
    position: np.ndarray
    frame: np.ndarray
    distribution: str
    cd: float
    colour: np.ndarray
    photometry: Photometry | None = None

    def candela(self, directions: np.ndarray) -> np.ndarray:
        """(k,) cd toward unit world directions (k, 3) leaving the luminaire."""
        local = np.asarray(directions, np.float64) @ self.frame.T
        if self.distribution == "isotropic":
            return np.full(len(local), self.cd)
        if self.distribution == "lambertian":
            return self.cd * np.maximum(local[:, 2], 0.0)
        return self.cd * self.photometry.intensity(local)

    def flux_lm(self) -> float:
        """Total luminous flux, lm."""
        if self.distribution == "isotropic":
            return 4.0 * math.pi * self.cd
        if self.distribution == "lambertian":
            return math.pi * self.cd
        return self.cd * self.photometry.flux()

    def peak_cd(self) -> float:
        return self.cd if self.distribution != "table" else self.cd * self.photometry.peak()

    def describe(self) -> str:
        what = (f"{self.photometry.kind}-type table of {os.path.basename(self.photometry.source)}"
                if self.photometry is not None else f"{self.distribution} {self.cd:.4g} cd")
        return (f"luminaire '{self.name}' at ({', '.join(f'{x:.4g}' for x in self.position)}): "
                f"{what}, {self.flux_lm():.4g} lm")

    def to_dict(self) -> dict:
        return {"name": self.name, "position": self.position.tolist(),
                "frame": self.frame.tolist(), "distribution": self.distribution, "cd": self.cd,
                "colour": self.colour.tolist(),
                "photometry": None if self.photometry is None else self.photometry.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> "Luminaire":
        ph = d.get("photometry")
        return cls(d["name"], np.asarray(d["position"], np.float64),
                   np.asarray(d["frame"], np.float64), d["distribution"], float(d["cd"]),
                   np.asarray(d["colour"], np.float64),
                   None if ph is None else Photometry.from_dict(ph))


@dataclass(frozen=True)
class Luminaires:
    """The scene's luminaires (possibly none), in the order of its [[luminaire]] tables."""

    items: tuple = ()

    def __len__(self) -> int:
        return len(self.items)

    def __bool__(self) -> bool:
        return bool(self.items)

    @property
    def positions(self) -> np.ndarray:
        return np.array([lum.position for lum in self.items], np.float64).reshape(-1, 3)

    def intensity_w(self, k: int, directions: np.ndarray) -> np.ndarray:
        """(m, 3) W sr^-1 per channel that luminaire k sends along unit `directions` (m, 3)."""
        lum = self.items[k]
        return lum.candela(directions)[:, None] * (lum.colour / EFFICACY)[None]

    def power(self) -> np.ndarray:
        """(3,) W: the luminaires' flux per channel."""
        return sum((lum.flux_lm() * lum.colour / EFFICACY for lum in self.items), np.zeros(3))

    def flux_lm(self) -> float:
        return float(sum(lum.flux_lm() for lum in self.items))

    def describe(self) -> str:
        return f"{len(self)} luminaire(s), {self.flux_lm():.5g} lm"

    def to_dict(self) -> list:
        return [lum.to_dict() for lum in self.items]

    @classmethod
    def from_dict(cls, d) -> "Luminaires":
        return cls(tuple(Luminaire.from_dict(x) for x in (d or [])))

    def digest(self) -> str:
        """sha256 of everything that sets their light (run digests, cache keys)."""
        h = hashlib.sha256()
        for lum in self.items:
            h.update(repr((lum.name, lum.distribution, lum.cd)).encode())
            for a in (lum.position, lum.frame, lum.colour):
                h.update(np.ascontiguousarray(a, np.float64).tobytes())
            if lum.photometry is not None:
                for a in (lum.photometry.horizontal, lum.photometry.vertical,
                          lum.photometry.candela):
                    h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()

    def __dask_tokenize__(self):
        return ("Luminaires", self.digest())


NONE = Luminaires()


def luminaires_of(elements) -> Luminaires:
    """The luminaires that travel with `elements` (none for elements built without them)."""
    return getattr(elements, "luminaires", None) or NONE


# ----------------------------------------------------------------------------- scene tables

def scene_up(doc: dict) -> np.ndarray:
    """The scene's up axis: its (first) camera's `up` (look-at form) or `y` (the seed's form),
    +y when it gives neither (the camera's own default)."""
    cam = doc.get("camera", {})
    if isinstance(cam, list):
        cam = cam[0] if cam and isinstance(cam[0], dict) else {}
    up = cam.get("up", cam.get("y", [0.0, 1.0, 0.0])) if isinstance(cam, dict) else [0, 1, 0]
    try:
        u = np.asarray(up, np.float64).reshape(3)
    except (TypeError, ValueError):
        return np.array([0.0, 1.0, 0.0])
    n = float(np.linalg.norm(u))
    return u / n if n > 0 and np.isfinite(n) else np.array([0.0, 1.0, 0.0])


def frame_of(aim: np.ndarray, up: np.ndarray, rotation_deg: float) -> np.ndarray:
    """(3, 3) rows p, q, f: f the unit aim; p the C0 axis: the scene's up made perpendicular to
    the aim (a luminaire aimed sideways: C0 points up), or, for an aim along the up axis, the
    world axis least along the aim (x first); then turned by `rotation_deg` about -f
    (counter-clockwise seen from above a downlight, C0 toward C90); q = -f x p."""
    f = aim / np.linalg.norm(aim)
    p = up - (up @ f) * f
    if np.linalg.norm(p) < 1e-6:
        axis = np.eye(3)[int(np.argmin(np.abs(f)))]
        p = axis - (axis @ f) * f
    p = p / np.linalg.norm(p)
    q = np.cross(-f, p)
    t = math.radians(rotation_deg)
    p, q = math.cos(t) * p + math.sin(t) * q, -math.sin(t) * p + math.cos(t) * q
    return np.array([p, q, f])


def _number(val, what: str, where: str, positive: bool = False) -> float:
    if isinstance(val, bool):
        raise SceneError(f"{where}: {what} must be a number, got {val!r}")
    try:
        x = float(val)
    except (TypeError, ValueError):
        raise SceneError(f"{where}: {what} must be a number, got {val!r}") from None
    if not math.isfinite(x) or (positive and not x > 0):
        raise SceneError(f"{where}: {what} must be a finite number{' > 0' if positive else ''}, "
                         f"got {val!r}")
    return x


def _vector(val, what: str, where: str) -> np.ndarray:
    try:
        a = np.asarray(val, np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{where}: {what} must be a list of 3 numbers, got {val!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise SceneError(f"{where}: {what} must be a list of 3 finite numbers, got {val!r}")
    return a


def parse_luminaires(entries, path: str, up: np.ndarray) -> Luminaires:
    """The scene file's [[luminaire]] tables (`entries`, a list; `path` the scene file, photometric
    files relative to it; `up` the scene's up axis: the default aim is -up)."""
    if entries is None:
        return NONE
    if not isinstance(entries, list):
        raise SceneError(f"{path}: 'luminaire' must be [[luminaire]] tables")
    out, names = [], set()
    for i, t in enumerate(entries):
        where = f"{path}: [[luminaire]] {i + 1}"
        if not isinstance(t, dict):
            raise SceneError(f"{where} must be a table")
        unknown = set(t) - KEYS
        if unknown:
            raise SceneError(f"{where} has unknown key(s) {sorted(unknown)}; allowed: "
                             f"{sorted(KEYS)}")
        name = str(t.get("name", f"luminaire-{i + 1}"))
        if name in names:
            raise SceneError(f"{where}: the name {name!r} is used twice")
        names.add(name)
        where = f"{path}: [[luminaire]] {name!r}"
        if "position" not in t:
            raise SceneError(f"{where} has no 'position'")
        pos = _vector(t["position"], "position", where)
        aim = _vector(t.get("aim", -up), "aim", where)
        if not np.linalg.norm(aim) > 0:
            raise SceneError(f"{where}: aim must be a non-zero vector")
        frame = frame_of(aim, up, _number(t.get("rotation", 0.0), "rotation", where))
        colour = _vector(t.get("colour", [1.0, 1.0, 1.0]), "colour", where)
        if np.any(colour < 0) or not float(colour @ LUMA) > 0:
            raise SceneError(f"{where}: colour {colour.tolist()} must be >= 0 with some luminance")
        colour = colour / float(colour @ LUMA)
        if "multiplier" in t and "flux_lm" in t:
            raise SceneError(f"{where}: give 'multiplier' or 'flux_lm', not both")
        mult = _number(t.get("multiplier", 1.0), "multiplier", where, positive=True)
        if "ies" in t:
            for k in ("intensity_cd", "distribution"):
                if k in t:
                    raise SceneError(f"{where}: '{k}' is for a luminaire without 'ies' (the "
                                     "photometric file gives the distribution)")
            fn = os.path.join(os.path.dirname(path), str(t["ies"]))
            if not os.path.isfile(fn):
                raise SceneError(f"{where}: ies = {t['ies']!r}: photometric file not found: {fn}")
            ph = read_photometry(fn)
            lum = Luminaire(name, pos, frame, "table", mult, colour, ph)
        else:
            if "intensity_cd" not in t:
                raise SceneError(f"{where} needs 'ies' (a photometric file) or 'intensity_cd'")
            dist = t.get("distribution", "isotropic")
            if dist not in DISTRIBUTIONS:
                raise SceneError(f"{where}: distribution {dist!r} must be one of "
                                 f"{', '.join(DISTRIBUTIONS)}")
            cd = _number(t["intensity_cd"], "intensity_cd", where, positive=True)
            lum = Luminaire(name, pos, frame, dist, cd * mult, colour)
        if "flux_lm" in t:
            want = _number(t["flux_lm"], "flux_lm", where, positive=True)
            have = lum.flux_lm()
            if not have > 0:
                raise SceneError(f"{where}: its distribution emits no flux to scale to {want:g} lm")
            lum = Luminaire(name, pos, frame, lum.distribution, lum.cd * want / have, colour,
                            lum.photometry)
        out.append(lum)
    return Luminaires(tuple(out))


def check_placement(luminaires: Luminaires, elements, caster, path: str) -> None:
    """One SceneError for a luminaire inside a wall or a closed solid: most rays from it (26
    axes and diagonals) meet the back of a one-sided element first, so its light could not
    leave. A luminaire whose every ray escapes (an open scene) passes."""
    if not luminaires:
        return
    n = np.asarray(elements.normal, np.float64)
    two = np.asarray(elements.two_sided, bool)
    for lum in luminaires.items:
        e = np.asarray(caster.first_hit(np.repeat(lum.position[None], len(_PROBES), axis=0),
                                        _PROBES), np.int64)
        hit = e >= 0
        back = hit & ~two[np.maximum(e, 0)] & (np.einsum("kc,kc->k", _PROBES,
                                                         n[np.maximum(e, 0)]) > 0)
        if back.sum() * 2 > len(_PROBES):
            k = int(np.flatnonzero(back)[0])
            raise SceneError(f"{path}: [[luminaire]] {lum.name!r} at {lum.position.tolist()} is "
                             f"inside a wall or a closed solid: {int(back.sum())} of "
                             f"{len(_PROBES)} rays from it meet the back of a one-sided "
                             f"surface first, e.g. {elements.describe(int(e[k]))}; move it "
                             "into the room")
