"""A second reference: illuminance at points computed by Radiance (`rtrace -I`), the program
lighting engineers trust, from the binaries the `pyradiance` wheel ships.

The conversion (`radiance_scene`) starts from the project's own loaded Scene, as the Mitsuba one
does (reference.py: the same material groups, the same triangles), so both see the same
elements, reflectances, emission and sides. Units: Radiance's RGB radiance is taken as ours
(W sr^-1 m^-2 per channel) and its irradiance comes back per channel in W m^-2; lux is then
computed here with the project's own conversion (683 lm per W of Rec. 709 Y, stages/tables.py),
never with Radiance's 179 lm/W and its RGB weights, which would differ by a constant factor.
The standard error comes from K independent estimates per point (the points repeated K times
in one rtrace process with uncorrelated sampling and no ambient cache): std (ddof 1) / sqrt K.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import tempfile
import time
from dataclasses import asdict, dataclass

import numpy as np

from radiosity.core.bundles import Scene
from radiosity.core.colour import EFFICACY, LUMA
from radiosity.validation.reference import ReferenceError, _mesh_arrays, shape_groups

INSTALL = "pip install pyradiance (or pip install -e '.[reference]')"
#: The side function of one-sided and two-coloured surfaces: 1 on the front (Rdot > 0: the
#: ray arrives against the surface normal), 0 on the back.
SIDE_CAL = ("side = if(Rdot, 1, 0);\n"
            # the skies of `sky_text`: A1 the zenith's radiance, A2 the ground's
            "radiosity_overcast = if(Dz, A1 * (1 + 2 * Dz) / 3, A2);\n"
            "radiosity_uniform = if(Dz, A1, A2);\n")
#: Distance of an emitter's light source in front of its surface, in scene diagonals (above
#: Radiance's own ray epsilon for scenes of a millimetre or more).
SOURCE_OFFSET = 1e-5


@dataclass(frozen=True)
class Quality:
    """rtrace settings of one accuracy level (docs/src/how-to/ground-truth.md, measured in
    docs/src/measurements/radiance.md).

    truncation : ambient bounces -ab = the smallest D with rho_max^D <= truncation (the light
        of more bounces is dropped, at most rho_max^D of the scene's largest radiance)
    ad, as_ : ambient divisions and super-samples of the first bounce (Radiance lowers them by
        ray weight deeper down); aa = 0: no irradiance cache, so estimates are independent
    lw : ray weight below which Russian roulette (unbiased) decides whether a ray goes on
    ds, dj : source subdivision ratio and jitter (dj > 0: stratified, unbiased area sampling)
    source_size : emitting elements are cut into pieces no longer than this fraction of the
        scene's diagonal before Radiance sees them (its own subdivision of a source stops at
        a fixed count: a 10 x 10 m panel 1 m above a point read 6.9 % low whole, 0.002 %
        when cut into 20 x 20)
    repeats : K independent estimates per point, averaged; their spread gives the error
    """

    name: str
    truncation: float
    ad: int
    as_: int
    lw: float
    ds: float
    dj: float
    source_size: float
    repeats: int

    def options(self, bounces: int) -> list[str]:
        return ["-ab", str(bounces), "-ad", str(self.ad), "-as", str(self.as_), "-aa", "0",
                "-lr", "-10", "-lw", f"{self.lw:g}", "-ds", f"{self.ds:g}", "-dj", f"{self.dj:g}",
                "-dt", "0", "-dc", "1", "-dr", "0", "-u+"]


#: Accuracy levels by name (`radiosity reference --engine radiance --quality`).
QUALITIES = {q.name: q for q in (
    Quality("draft", 1e-2, 128, 64, 1e-3, 0.2, 0.9, 0.1, 4),
    Quality("medium", 1e-3, 512, 256, 1e-4, 0.1, 0.9, 0.05, 8),
    Quality("high", 1e-4, 2048, 1024, 1e-4, 0.05, 0.9, 0.02, 16),
    Quality("reference", 1e-6, 4096, 2048, 1e-5, 0.05, 0.9, 0.02, 32),
)}


def named_quality(name: str) -> Quality:
    """The Quality called `name`; ReferenceError listing the known ones otherwise."""
    try:
        return QUALITIES[name]
    except KeyError:
        raise ReferenceError(f"Radiance quality {name!r}: one of {', '.join(QUALITIES)}") from None


# ----------------------------------------------------------------------------- the binaries

def radiance_env() -> dict:
    """Environment in which pyradiance's rtrace and oconv run (PATH and RAYPATH set to the
    wheel's bin and lib folders); ReferenceError naming the install when pyradiance is missing."""
    try:
        import pyradiance
    except ImportError:
        raise ReferenceError(f"Radiance (pyradiance) is not installed: {INSTALL}") from None
    base = os.path.dirname(pyradiance.__file__)
    env = dict(os.environ)
    env["PATH"] = os.path.join(base, "bin") + os.pathsep + env.get("PATH", "")
    env["RAYPATH"] = os.pathsep.join([".", os.path.join(base, "lib")])
    if not os.path.isfile(os.path.join(base, "bin", "rtrace")):
        raise ReferenceError(f"pyradiance at {base} has no bin/rtrace: {INSTALL}")
    return env


def radiance_version(env: dict | None = None) -> str:
    env = env or radiance_env()
    r = subprocess.run(["rtrace", "-version"], env=env, capture_output=True, text=True)
    return (r.stdout or r.stderr).strip().splitlines()[0] if (r.stdout or r.stderr) else "?"


def _run(cmd: list[str], env: dict, stdin: bytes | None = None, cwd: str | None = None) -> bytes:
    r = subprocess.run(cmd, input=stdin, env=env, cwd=cwd, capture_output=True)
    if r.returncode != 0:
        msg = " ".join(r.stderr.decode(errors="replace").split())[:300]
        raise ReferenceError(f"Radiance {cmd[0]} failed (exit {r.returncode}): {msg}")
    return r.stdout


# ----------------------------------------------------------------------------- the conversion

def bounces(scene: Scene, truncation: float) -> tuple[int, float]:
    """(ab, rho_max): ambient bounces, the smallest D >= 1 with rho_max^D <= truncation (as
    reference.path_depth), and the scene's largest reflectance."""
    rho = float(np.max(scene.elements.reflectance)) if len(scene.elements) else 0.0
    if rho <= 0.0:
        return 1, rho
    return max(1, math.ceil(math.log(float(truncation)) / math.log(rho) - 1e-12)), rho


def diagonal(scene: Scene) -> float:
    v = scene.elements.verts.reshape(-1, 3)
    return float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) or 1.0


def split_triangles(tri: np.ndarray, max_edge: float) -> np.ndarray:
    """Triangles (t, 3, 3) cut into k^2 similar ones each (k = ceil(longest edge / max_edge)),
    with their winding. Returns (t', 3, 3) float64."""
    out = []
    for a, b, c in np.asarray(tri, np.float64):
        longest = max(np.linalg.norm(b - a), np.linalg.norm(c - b), np.linalg.norm(a - c))
        k = max(1, int(math.ceil(longest / max_edge - 1e-9)))
        u, v = (b - a) / k, (c - a) / k
        for i in range(k):
            for j in range(k - i):
                p = a + i * u + j * v
                out.append((p, p + u, p + v))
                if j < k - i - 1:
                    out.append((p + u, p + u + v, p + v))
    return np.array(out, np.float64).reshape(-1, 3, 3)


def _rgb(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


def _polygons(mod: str, name: str, tri: np.ndarray) -> list[str]:
    return [f"{mod} polygon {name}.{k} 0 0 9 " + " ".join(f"{x:.17g}" for x in t.ravel())
            for k, t in enumerate(tri)]


EMITTER_MODES = ("sources", "glow")


def _reflector(lines: list, mat: str, front, back, two: bool, scale: float = 1.0) -> None:
    """Material `mat`: Lambertian `plastic` (no specular part) where both sides reflect alike,
    else a `mixfunc` of a front and a back plastic by the side a ray arrives on (a one-sided
    element's back is black, as the engine has it). `scale` divides the front reflectance."""
    f = np.asarray(front, np.float64) / scale
    if two and np.array_equal(front, back) and scale == 1.0:
        lines.append(f"void plastic {mat} 0 0 5 {_rgb(f)} 0 0")
        return
    lines.append(f"void plastic {mat}.f 0 0 5 {_rgb(f)} 0 0")
    lines.append(f"void plastic {mat}.b 0 0 5 {_rgb(back)} 0 0")
    lines.append(f"void mixfunc {mat} 4 {mat}.f {mat}.b side side.cal 0 0")


def radiance_scene(scene: Scene, source_size: float = 0.02,
                   emitters: str = "sources") -> tuple[str, str]:
    """The loaded scene as Radiance scene text and the function file it reads as side.cal.
    Per material group (reference.shape_groups: one per material, side and emission), with
    the engine's triangles (a quad as v0 v1 v2, v0 v2 v3; reference._mesh_arrays), so the
    front normals are the engine's (Radiance orients by the right-hand rule too):

    - reflection: `_reflector` (Lambertian plastic, the back black where one-sided);
    - emission, `emitters="sources"`: a copy of the emitting triangles `SOURCE_OFFSET` x the
      scene diagonal in front of them, cut into triangles no longer than `source_size` x the
      diagonal, as `illum` with no alternate material: light sources for Radiance's direct
      sampling (front side only, as in the engine) that shadow rays aimed elsewhere and rays
      arriving from behind pass through. Radiance gives an ambient ray that meets a source's
      front nothing (its light is in the direct part), so the light an emitting surface
      reflects is lost to ambient rays: fine for small lamps, wrong for emitters that are much
      of the scene;
    - `emitters="glow"`: the emitting surface itself is a `mixfunc` (a weighted sum per ray)
      of a `glow` of Le / F and its reflector with the front reflectance / (1 - F), F = (1 -
      rho_max) / 2 on the front, 0 on the back: no source sampling, its light reaches points
      through ambient rays only (exact for large emitters such as a furnace, noisy for small
      ones).

    An element whose back emits has no Radiance equivalent (sources emit from the front):
    ReferenceError naming it.
    """
    if emitters not in EMITTER_MODES:
        raise ReferenceError(f"Radiance emitters {emitters!r}: one of {', '.join(EMITTER_MODES)}")
    el = scene.elements
    diag = diagonal(scene)
    max_edge = float(source_size) * diag
    lines = ["# converted by radiosity.validation.radiance from " + str(scene.path)]
    cal = [SIDE_CAL]
    for j, idx in enumerate(shape_groups(scene)):
        i = int(idx[0])
        two = bool(el.two_sided[i])
        front = el.reflectance[i, 0]
        back = el.reflectance[i, 1] if two else np.zeros(3)
        Le, Lb = el.emission[i, 0], el.emission[i, 1] if two else np.zeros(3)
        if np.any(Lb > 0):
            raise ReferenceError(f"{scene.path}: {el.describe(i)} emits from its back: Radiance's "
                                 "sources emit from the front only (make it one-sided, facing "
                                 "the way it emits, for the Radiance reference)")
        mat = f"m{j}"
        verts, faces = _mesh_arrays(el, idx)
        tri = verts.astype(np.float64)[faces.astype(np.int64)]
        if np.any(Le > 0) and emitters == "glow":
            share = 0.5 * (1.0 - float(np.max(front)))
            _reflector(lines, f"{mat}.r", front, back, two, 1.0 - share)
            lines.append(f"void glow {mat}.g 0 0 4 {_rgb(np.asarray(Le) / share)} 0")
            lines.append(f"void mixfunc {mat} 4 {mat}.g {mat}.r w{j} side.cal 0 0")
            cal.append(f"w{j} = if(Rdot, {share:.17g}, 0);\n")
            lines += _polygons(mat, f"s{j}", tri)
            continue
        _reflector(lines, mat, front, back, two)
        lines += _polygons(mat, f"s{j}", tri)
        if np.any(Le > 0):
            lines.append(f"void illum {mat}.e 0 0 3 {_rgb(Le)}")
            n = el.normal[idx]
            lift = SOURCE_OFFSET * diag * np.concatenate([n, n[el.nverts[idx] == 4]])  # faces' order
            lines += _polygons(f"{mat}.e", f"e{j}", split_triangles(tri + lift[:, None, :], max_edge))
    return "\n".join(lines) + "\n", "".join(cal)


def point_source(name: str, position, intensity, radius: float) -> str:
    """Radiance text of an isotropic point source: a `light` sphere of `radius` (scene units)
    at `position` whose radiance I / (pi r^2) gives the intensity `intensity` (3,) W sr^-1 per
    channel (cd / 683 for a grey source) in every direction: a sphere of radiance L shows
    pi r^2 L to any point outside it, so E = I / d^2 at normal incidence, exactly. The hook for
    the luminaires of issue 52 (point sources; IES ones through ies2rad), once scenes have
    them: `radiance_scene`'s text plus one of these per source."""
    L = np.asarray(intensity, np.float64) / (math.pi * float(radius) ** 2)
    x, y, z = (float(c) for c in position)
    return (f"void light {name}.m 0 0 3 {_rgb(L)}\n"
            f"{name}.m sphere {name} 0 0 4 {x:.17g} {y:.17g} {z:.17g} {float(radius):.17g}\n")


def sky_text(kind: str, horizontal_lux: float, ground_reflectance: float) -> str:
    """Radiance text of a sky (core/sky.py: "cie-overcast" or "uniform") that gives
    `horizontal_lux` on an unobstructed horizontal plane, over a ground of
    `ground_reflectance`, +z up: a `glow` over the whole sphere of directions (a `source` of
    360 degrees) whose `brightfunc` is the exact distribution (side.cal's radiosity_overcast),
    found by ambient rays (-ab >= 1). Not gensky's own sky: its skybright.cal blends sky and
    ground near the horizon (weights (Dz + 1.01)^+-10), which moves a vertical plane's light.
    Grey, in our units: lux / 683 per channel."""
    from radiosity.core.sky import SKY_TYPES, zenith_luminance

    if kind not in SKY_TYPES:
        raise ReferenceError(f"sky type {kind!r}: one of {', '.join(SKY_TYPES)}")
    eh = float(horizontal_lux) / EFFICACY
    fn = "radiosity_overcast" if kind == "cie-overcast" else "radiosity_uniform"
    return (f"void brightfunc radiosity_sky 2 {fn} side.cal 0 2 "
            f"{zenith_luminance(kind, eh):.17g} {float(ground_reflectance) * eh / math.pi:.17g}\n"
            "radiosity_sky glow radiosity_sky_glow 0 0 4 1 1 1 0\n"
            "radiosity_sky_glow source radiosity_sky_dome 0 0 4 0 0 1 360\n")


def write_octree(scene: Scene, workdir: str, source_size: float, env: dict,
                 emitters: str = "sources", extra: str = "") -> str:
    """scene.rad (plus `extra` Radiance text: `point_source`s), side.cal and scene.oct in
    `workdir`; returns the octree's path."""
    text, cal = radiance_scene(scene, source_size, emitters)
    text += extra
    with open(os.path.join(workdir, "side.cal"), "w") as f:
        f.write(cal)
    with open(os.path.join(workdir, "scene.rad"), "w") as f:
        f.write(text)
    oct_ = os.path.join(workdir, "scene.oct")
    with open(oct_, "wb") as f:
        f.write(_run(["oconv", "-f", "scene.rad"], env, cwd=workdir))
    return oct_


# ----------------------------------------------------------------------------- illuminance

@dataclass(frozen=True)
class PointIlluminance:
    """Radiance's answer at p points.

    lux : (p,) float64, illuminance (683 lm per W of Rec. 709 Y of the irradiance)
    stderr_lux : (p,) float64, its standard error (spread of the K repeats / sqrt K)
    irradiance : (p, 3) float64, W m^-2 per RGB channel (mean of the repeats)
    figures : dict, settings, times and versions (JSON-ready)
    """

    lux: np.ndarray
    stderr_lux: np.ndarray
    irradiance: np.ndarray
    figures: dict


def _check_points(points, normals) -> tuple[np.ndarray, np.ndarray]:
    P = np.asarray(points, np.float64).reshape(-1, 3)
    N = np.asarray(normals, np.float64).reshape(-1, 3)
    if len(P) != len(N):
        raise ReferenceError(f"{len(P)} points but {len(N)} normals")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(N))):
        raise ReferenceError("a point or normal is not a finite number")
    length = np.linalg.norm(N, axis=1)
    bad = np.flatnonzero(length < 1e-12)
    if len(bad):
        raise ReferenceError(f"point {bad[0] + 1} has a zero normal")
    return P, N / length[:, None]


def illuminance(scene: Scene, points, normals, quality: Quality | str = "reference",
                emitters: str = "sources", processes: int = 1, echo=None,
                workdir: str | None = None, extra: str = "") -> PointIlluminance:
    """Illuminance at `points` (p, 3) on surfaces facing `normals` (p, 3) (scene units;
    normalised here), by Radiance: `rtrace -I` with `quality`'s settings, each point traced
    `repeats` times in one process (independent estimates: uncorrelated sampling, no cache).
    The points need not lie on a surface; a point on one should be on its lit side. They are
    moved 1e-6 of the scene's diagonal along their normal, off a surface they lie on.
    emitters: "sources" or "glow" (`radiance_scene`). extra: more Radiance text (sources
    the scene file cannot say yet: `point_source`). processes: rtrace -n. workdir: keep scene.rad / scene.oct there (None: a temporary one)."""
    q = named_quality(quality) if isinstance(quality, str) else quality
    P, N = _check_points(points, normals)
    env = radiance_env()
    ab, rho = bounces(scene, q.truncation)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="radiance-") as tmp:
        wd = os.path.abspath(workdir or tmp)
        os.makedirs(wd, exist_ok=True)
        oct_ = write_octree(scene, wd, q.source_size, env, emitters, extra)
        t_oct = time.perf_counter() - t0
        if echo:
            echo(f"Radiance ({radiance_version(env)}): {len(P)} points x {q.repeats} repeats, "
                 f"quality {q.name}: -ab {ab} (max reflectance {rho:.3g}), -ad {q.ad}")
        rays = np.concatenate([P + 1e-6 * diagonal(scene) * N, N], axis=1)
        stdin = np.tile(rays, (q.repeats, 1)).astype("<f8").tobytes()
        cmd = ["rtrace", "-I+", "-h-", "-fdd", "-ov", "-n", str(int(processes)), *q.options(ab), oct_]
        t1 = time.perf_counter()
        out = _run(cmd, env, stdin=stdin, cwd=wd)
        t_trace = time.perf_counter() - t1
    E = np.frombuffer(out, "<f8").reshape(q.repeats, len(P), 3)
    lux = EFFICACY * (E @ LUMA)                                    # (K, p)
    se = lux.std(axis=0, ddof=1) / math.sqrt(q.repeats) if q.repeats > 1 else np.zeros(len(P))
    fig = {"engine": "radiance", "scene": scene.path, "points": int(len(P)), "quality": asdict(q),
           "emitters": emitters, "ambient_bounces": ab, "max_reflectance": rho,
           "truncation_bound": rho ** ab if rho > 0 else 0.0, "processes": int(processes),
           "rtrace": " ".join(cmd[:-1]), "radiance_version": radiance_version(env),
           "time_s": time.perf_counter() - t0, "time_octree_s": t_oct, "time_rtrace_s": t_trace,
           "efficacy_lm_per_w": EFFICACY, "luma": LUMA.tolist()}
    return PointIlluminance(lux.mean(axis=0), se, E.mean(axis=0), fig)


# ----------------------------------------------------------------------------- files

POINT_COLUMNS = ("x", "y", "z", "nx", "ny", "nz")


def read_points(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Points and normals from a CSV file with the header x,y,z,nx,ny,nz (extra columns are
    ignored) and one point a line. Returns ((p, 3), (p, 3)) float64; ReferenceError naming the
    file and line when it cannot be read."""
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except OSError as e:
        raise ReferenceError(f"{path}: cannot read the points ({e.strerror})") from None
    head = [c.strip().lower() for c in (lines[0].split(",") if lines else [])]
    if not set(POINT_COLUMNS) <= set(head):
        raise ReferenceError(f"{path}: the first line must name the columns "
                             f"{','.join(POINT_COLUMNS)} (got {lines[0][:80] if lines else 'nothing'!r})")
    cols = [head.index(c) for c in POINT_COLUMNS]
    rows = []
    for k, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        try:
            rows.append([float(cells[c]) for c in cols])
        except (ValueError, IndexError):
            raise ReferenceError(f"{path}:{k}: expected numbers in the columns "
                                 f"{','.join(POINT_COLUMNS)}: {line[:80]!r}") from None
    if not rows:
        raise ReferenceError(f"{path}: no points after the header")
    a = np.array(rows, np.float64)
    try:
        return _check_points(a[:, :3], a[:, 3:])
    except ReferenceError as e:
        raise ReferenceError(f"{path}: {e}") from None


def make_radiance_reference(scene: Scene, points, normals, out: str, quality: str = "reference",
                            emitters: str = "sources", processes: int = 1, echo=print,
                            grids: tuple = ()) -> dict:
    """Radiance's illuminance at `points` with `normals` into `out`: points.csv (x, y, z, nx,
    ny, nz, illuminance_lux, stderr_lux, irradiance_r/g/b in W m^-2), radiance.json (the
    figures, returned) and the converted scene (scene.rad, side.cal, scene.oct) to rerun by
    hand. grids: (name, count) pairs when the points are the scene's [[grid]] tables one
    after another: each grid's rows also go to grids/NAME.csv."""
    from radiosity.formats.csvtext import write_csv

    q = named_quality(quality)
    os.makedirs(out, exist_ok=True)
    res = illuminance(scene, points, normals, q, emitters=emitters, processes=processes,
                      echo=echo, workdir=out)
    P, N = _check_points(points, normals)
    table = {c: v for c, v in zip(POINT_COLUMNS, np.concatenate([P, N], axis=1).T)}
    table.update(illuminance_lux=res.lux, stderr_lux=res.stderr_lux,
                 irradiance_r=res.irradiance[:, 0], irradiance_g=res.irradiance[:, 1],
                 irradiance_b=res.irradiance[:, 2])
    write_csv(os.path.join(out, "points.csv"), table)
    start = 0
    for name, count in grids:
        os.makedirs(os.path.join(out, "grids"), exist_ok=True)
        write_csv(os.path.join(out, "grids", f"{name}.csv"),
                  {c: v[start:start + count] for c, v in table.items()})
        start += count
    ok = res.lux > 0
    fig = dict(res.figures)
    fig.update(lux_min=float(res.lux.min()), lux_mean=float(res.lux.mean()),
               lux_max=float(res.lux.max()),
               rel_stderr_median=float(np.median(res.stderr_lux[ok] / res.lux[ok])) if ok.any() else None,
               rel_stderr_max=float(np.max(res.stderr_lux[ok] / res.lux[ok])) if ok.any() else None)
    with open(os.path.join(out, "radiance.json"), "w") as f:
        json.dump(fig, f, indent=1)
    return fig
