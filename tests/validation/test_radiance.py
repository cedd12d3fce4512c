"""Radiance as a second reference (validation/radiance.py): the conversion, then rtrace -I
against exact answers (a panel over points: pi L F by the contour integral; the furnace:
L = Le / (1 - rho)) and against the engine's own lux on the Cornell box floor."""

from __future__ import annotations

import math
import sys
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

from helpers import scene_path, write_scene
from radiosity.settings import options as settings_of

PANEL = """
v -0.5 -0.5 1
v -0.5 0.5 1
v 0.5 0.5 1
v 0.5 -0.5 1
v -3 -3 0
v 3 -3 0
v 3 3 0
v -3 3 0
usemtl light
f 1 2 3 4
usemtl floor
f 5 6 7 8
"""
PANEL_MATERIALS = """
[material.light]
reflectance = [0.0, 0.0, 0.0]
emission = [1.0, 0.5, 0.25]
[material.floor]
reflectance = [0.0, 0.0, 0.0]
"""
PANEL_CAMERA = """
[camera]
position = [0.0, -4.0, 0.5]
look_at = [0.0, 0.0, 0.5]
up = [0.0, 0.0, 1.0]
fov_y = 60.0
resolution = [16, 16]
"""
LUMA = np.array([0.2126, 0.7152, 0.0722])


def _load(path):
    from radiosity.scene.load import load_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_scene(path, settings=settings_of())


def _panel(tmp_path):
    return _load(write_scene(tmp_path, PANEL, PANEL_MATERIALS, camera=PANEL_CAMERA))


def _panel_points():
    P = np.array([[0, 0, 0], [0.3, 0.1, 0], [1.5, 0.2, 0], [0, 0, 0.5], [0.7, -0.6, 0.3]], float)
    N = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [1, 0, 1], [-0.2, 0.3, 1]], float)
    return P, N / np.linalg.norm(N, axis=1)[:, None]


# ----------------------------------------------------------------------------- the conversion

def test_split_triangles_keeps_the_area_and_the_winding(rng):
    from radiosity.validation.radiance import split_triangles

    tri = rng.random((5, 3, 3))
    parts = split_triangles(tri, 0.1)
    def normals(t):
        return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert len(parts) > 5 * 4
    assert np.linalg.norm(normals(parts), axis=1).sum() == pytest.approx(
        np.linalg.norm(normals(tri), axis=1).sum(), rel=1e-9)
    edges = np.linalg.norm(parts - np.roll(parts, 1, axis=1), axis=2)
    assert edges.max() <= 0.1 + 1e-12
    n0 = normals(tri) / np.linalg.norm(normals(tri), axis=1)[:, None]
    n1 = normals(parts) / np.linalg.norm(normals(parts), axis=1)[:, None]
    assert min(np.max(n1 @ n) for n in n0) > 1 - 1e-9  # every part faces as its triangle does


def test_scene_text_sides_sources_and_refusals(tmp_path):
    from radiosity.validation.radiance import radiance_scene
    from radiosity.validation.reference import ReferenceError

    sc = _panel(tmp_path)
    text, cal = radiance_scene(sc, source_size=0.05)
    assert "mixfunc" in text and "side = if(Rdot, 1, 0);" in cal  # one-sided: the back is black
    assert text.count(" illum ") == 1 and "0 0 3 1 0.5 0.25" in text
    n_sources = sum(1 for line in text.splitlines()
                    if line.split()[0].endswith(".e") and line.split()[1] == "polygon")
    k = math.ceil(math.sqrt(2) / (0.05 * math.sqrt(6 ** 2 + 6 ** 2 + 1)))  # 5 % of the diagonal
    assert n_sources == 2 * k * k == 32
    glow, gcal = radiance_scene(sc, emitters="glow")
    assert " glow " in glow and " illum " not in glow and "= if(Rdot, 0.5, 0);" in gcal
    two = write_scene(tmp_path, PANEL, PANEL_MATERIALS.replace(
        "emission = [1.0, 0.5, 0.25]", "emission = [1.0, 0.5, 0.25]\ntwo_sided = true\n"
        "back_emission = [1, 1, 1]"), camera=PANEL_CAMERA, name="two.toml")
    with pytest.raises(ReferenceError, match="emits from its back"):
        radiance_scene(_load(two))
    with pytest.raises(ReferenceError, match="one of sources, glow"):
        radiance_scene(sc, emitters="lamp")


def test_points_file_errors_name_the_file_and_line(tmp_path):
    from radiosity.validation.radiance import read_points
    from radiosity.validation.reference import ReferenceError

    f = tmp_path / "p.csv"
    f.write_text("x,y,z,nx,ny,nz,name\n0,0,0,0,0,2,a\n1,2,3,1,0,0,b\n")
    P, N = read_points(str(f))
    assert P.shape == (2, 3) and np.allclose(N, [[0, 0, 1], [1, 0, 0]])
    for text, msg in (("x,y,z\n1,2,3\n", "first line must name the columns"),
                      ("x,y,z,nx,ny,nz\n1,2,3,0,0,x\n", r"p.csv:2: expected numbers"),
                      ("x,y,z,nx,ny,nz\n", "no points"),
                      ("x,y,z,nx,ny,nz\n1,2,3,0,0,0\n", "point 1 has a zero normal")):
        f.write_text(text)
        with pytest.raises(ReferenceError, match=msg):
            read_points(str(f))


# ----------------------------------------------------------------------------- exact answers

@pytest.mark.needs("radiance")
def test_panel_over_points_is_exact_within_one_percent(tmp_path):
    """pi Le F (point to polygon, contour integral) per channel, in lux at 683 lm/W of Y."""
    from radiosity.core.exact import polygon_point_form_factor
    from radiosity.validation.radiance import illuminance

    sc = _panel(tmp_path)
    P, N = _panel_points()
    light = int(np.flatnonzero(sc.elements.emission[:, 0, 0] > 0)[0])
    F = np.array([polygon_point_form_factor(p, n, sc.elements.verts[light]) for p, n in zip(P, N)])
    exact = 683.0 * math.pi * F * float(sc.elements.emission[light, 0] @ LUMA)
    r = illuminance(sc, P, N, "high")
    assert np.all(np.abs(r.lux / exact - 1) <= 0.01), r.lux / exact - 1
    assert np.allclose(r.irradiance[:, 1] / r.irradiance[:, 0], 0.5, rtol=1e-6)  # per channel
    assert np.all(r.stderr_lux > 0) and np.all(r.stderr_lux < 0.01 * exact)


@pytest.mark.needs("radiance")
def test_closed_grey_box_is_le_over_one_minus_rho_within_two_percent():
    """The furnace (closed cube, Le = 1, rho = 0.5): E = pi Le / (1 - rho) at every point, every
    normal. The emitters are the whole scene, so they go in as `glow` (ambient rays); as light
    sources Radiance's ambient rays get nothing from them, the reflection included: only the
    direct pi Le is left (what `radiance_scene` says)."""
    from radiosity.validation.radiance import illuminance

    sc = _load(scene_path("furnace-cube"))
    P = np.array([[0.5, 0.5, 0.5], [0.2, 0.3, 0.7], [0.5, 0.0, 0.5], [0.9, 0.9, 0.99]])
    N = np.array([[0, 1, 0], [1, 0, 0], [0, 1, 0], [0, 0, -1.0]])
    exact = 683.0 * math.pi * 1.0 / (1 - 0.5)
    r = illuminance(sc, P, N, "medium", emitters="glow")
    assert np.all(np.abs(r.lux / exact - 1) <= 0.02), r.lux / exact - 1
    direct = illuminance(sc, P, N, "draft", emitters="sources")
    assert np.all(np.abs(direct.lux / (exact / 2) - 1) <= 0.03), direct.lux / exact


@pytest.mark.needs("radiance")
def test_isotropic_point_source_1000_cd_at_3_m_gives_111_lux(tmp_path):
    """The hook for point luminaires: 1 000 cd (1000 / 683 W sr^-1 grey) 3 m above a black
    floor: 111.11 lx straight below, I cos / d^2 beside it. Within 0.5 %: Radiance's sampling of
    the small source sphere varied by more than its own standard error from run to run (one
    full-suite run read -0.22 % straight below, its standard error 0.04 %)."""
    from radiosity.validation.radiance import illuminance, point_source

    sc = _panel(tmp_path)  # its panel is 1 m up: the points below look away from it
    src = point_source("lamp", [0.0, 0.0, -3.0], np.full(3, 1000.0 / 683.0), 0.01)
    P = np.array([[0.0, 0.0, -6.0], [1.0, 0.0, -6.0]])
    N = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    r = illuminance(sc, P, N, "medium", extra=src)
    exact = np.array([1000.0 / 9.0, 1000.0 * 3.0 / 10.0 ** 1.5])
    assert np.all(np.abs(r.lux / exact - 1) <= 0.005), r.lux / exact - 1


@pytest.mark.needs("radiance")
@pytest.mark.slow
def test_cornell_floor_agrees_with_the_engine_within_two_percent(client, tmp_path):
    """The engine's lux per floor sub-element (elements.csv's illuminance) against Radiance at
    their centres, over the lit floor: the median ratio within 2 % (the median, because at the
    blocks' shadow edges a sub-element's mean and its centre's value differ by up to 35 %,
    which is the discretisation, not the light)."""
    from radiosity.pipeline import render_scene
    from radiosity.scene.load import load_scene
    from radiosity.validation.radiance import illuminance

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc = load_scene(scene_path("cornell-box"), resolution=32, settings=settings_of())
        render_scene(sc, str(tmp_path / "run"), client, settings_of(), preview=False,
                     progress=False, echo=lambda *a: None)
    t = np.genfromtxt(tmp_path / "run" / "elements.csv", delimiter=",", names=True, dtype=None,
                      encoding="utf-8")
    floor = (t["normal_y"] > 0.99) & (np.abs(t["center_y"]) < 1e-6) & (t["side"] == "front")
    ours = t["illuminance"][floor]
    lit = np.flatnonzero(ours > 0.2 * np.median(ours))[::6]  # not under the blocks
    P = np.stack([t["center_x"], t["center_y"], t["center_z"]], axis=1)[floor][lit]
    r = illuminance(sc, P, np.tile([0.0, 1.0, 0.0], (len(P), 1)), "draft")
    rel = ours[lit] / r.lux - 1.0
    assert len(lit) >= 30 and abs(np.median(rel)) <= 0.02, (np.median(rel), rel)


# ----------------------------------------------------------------------------- the command

@pytest.mark.needs("radiance")
def test_reference_command_with_radiance(tmp_path, monkeypatch):
    from radiosity.cli.commands import main

    path = write_scene(tmp_path, PANEL, PANEL_MATERIALS, camera=PANEL_CAMERA)
    pts = tmp_path / "pts.csv"
    P, N = _panel_points()
    pts.write_text("x,y,z,nx,ny,nz\n" + "".join(",".join(f"{v:.17g}" for v in [*p, *n]) + "\n"
                                                for p, n in zip(P, N)))
    out = tmp_path / "runs" / "ref"
    monkeypatch.chdir(tmp_path)  # relative paths, as people type them
    r = CliRunner().invoke(main, ["reference", "scene.toml", "--engine", "radiance", "--points",
                                  "pts.csv", "--out", "runs/ref", "--quality", "draft"])
    assert r.exit_code == 0, r.output
    t = np.genfromtxt(out / "points.csv", delimiter=",", names=True)
    assert list(t.dtype.names[:8]) == ["x", "y", "z", "nx", "ny", "nz", "illuminance_lux",
                                       "stderr_lux"]
    assert len(t) == 5 and np.all(t["illuminance_lux"] > 0) and (out / "radiance.json").is_file()
    for args, msg in ((["--spp", "4"], "--spp is for --engine mitsuba"),
                      ([], "--engine radiance needs --points")):
        extra = ["--points", str(pts)] if args else []
        r = CliRunner().invoke(main, ["reference", path, "--engine", "radiance", "--out",
                                      str(tmp_path / "x"), *extra, *args])
        assert r.exit_code == 2 and f"error: {msg}" in r.output, r.output


@pytest.mark.needs("radiance")
def test_reference_command_traces_the_scenes_grids(tmp_path):
    """Without --points the scene's [[grid]] tables are the points: grids/NAME.csv per grid,
    each point within 1 % of pi Le F (the panel, exact by the contour integral)."""
    from radiosity.cli.commands import main
    from radiosity.core.exact import polygon_point_form_factor

    grid = """
    [[grid]]
    name = "floor"
    origin = [-1.0, -1.0, 0.0]
    u = [2.0, 0.0, 0.0]
    v = [0.0, 2.0, 0.0]
    spacing = 1.0
    """
    path = write_scene(tmp_path, PANEL, PANEL_MATERIALS + grid, camera=PANEL_CAMERA)
    out = tmp_path / "ref"
    r = CliRunner().invoke(main, ["reference", path, "--engine", "radiance", "--out", str(out),
                                  "--quality", "high"])
    assert r.exit_code == 0, r.output
    assert "grids/floor.csv" in r.output
    t = np.genfromtxt(out / "grids" / "floor.csv", delimiter=",", names=True)
    assert len(t) == 4  # 2 x 2 cell centres
    sc = _load(path)
    light = int(np.flatnonzero(sc.elements.emission[:, 0, 0] > 0)[0])
    P = np.stack([t["x"], t["y"], t["z"]], axis=1)
    F = np.array([polygon_point_form_factor(p, np.array([0.0, 0.0, 1.0]), sc.elements.verts[light])
                  for p in P])
    exact = 683.0 * math.pi * F * float(sc.elements.emission[light, 0] @ LUMA)
    assert np.all(np.abs(t["illuminance_lux"] / exact - 1) <= 0.01), t["illuminance_lux"] / exact


def test_the_command_offers_every_quality():
    from radiosity.cli.radiance import QUALITIES as offered
    from radiosity.validation.radiance import QUALITIES

    assert tuple(QUALITIES) == offered


def test_without_pyradiance_the_command_says_how_to_install(monkeypatch, tmp_path):
    from radiosity.cli.commands import main

    monkeypatch.setitem(sys.modules, "pyradiance", None)  # import pyradiance raises ImportError
    pts = tmp_path / "p.csv"
    pts.write_text("x,y,z,nx,ny,nz\n0,0,0,0,0,1\n")
    r = CliRunner().invoke(main, ["reference", scene_path("furnace-cube"), "--engine", "radiance",
                                  "--points", str(pts), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2
    assert r.output.strip().splitlines()[-1].startswith("error: Radiance (pyradiance) is not installed")


# ----------------------------------------------------------------------------- daylight

def test_overcast_sky_on_a_vertical_plane_is_0_396_of_the_horizontal():
    """The analytic sky component, by integration over the hemisphere a vertical plane faces:
    CIE overcast pi/6 + 4/9 over 7 pi / 9 = 0.3962 of Eh, uniform 1/2; the ground half adds
    rho_g Eh / 2."""
    from radiosity.core.sky import luminance

    n = 400
    theta = (np.arange(n) + 0.5) / n * math.pi  # from the zenith, the whole sphere
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * math.pi
    T, F = np.meshgrid(theta, phi, indexing="ij")
    dw = np.sin(T) * (math.pi / n) * (math.pi / n)
    for kind, ratio in (("cie-overcast", (math.pi / 6 + 4 / 9) / (7 * math.pi / 9)),
                        ("uniform", 0.5)):
        L = luminance(kind, 10_000.0, 0.2, np.cos(T))
        horizontal = (L * np.maximum(np.cos(T), 0) * dw).sum()
        vertical = (L * np.maximum(np.sin(T) * np.cos(F), 0) * dw).sum()
        assert horizontal == pytest.approx(10_000.0, rel=1e-4)
        assert vertical == pytest.approx(10_000.0 * (ratio + 0.2 / 2), rel=1e-4)
    assert (math.pi / 6 + 4 / 9) / (7 * math.pi / 9) == pytest.approx(0.3962, abs=1e-4)


SPECK = """
v 0 0 -100
v 0.001 0 -100
v 0 0.001 -100
f 1 2 3
"""


@pytest.mark.needs("radiance")
@pytest.mark.parametrize("kind, vertical", [("cie-overcast", (math.pi / 6 + 4 / 9) / (7 * math.pi / 9)),
                                            ("uniform", 0.5)])
def test_radiance_sky_gives_eh_on_the_horizontal_and_the_analytic_vertical(tmp_path, kind, vertical):
    from radiosity.validation.radiance import illuminance, sky_text

    sc = _load(write_scene(tmp_path, SPECK, "[material.default]\nreflectance = [0, 0, 0]\n",
                           camera=PANEL_CAMERA))
    P = np.zeros((3, 3))
    N = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]])
    r = illuminance(sc, P, N, "medium", extra=sky_text(kind, 10_000.0, 0.2))
    exact = 10_000.0 * np.array([1.0, vertical + 0.1, vertical + 0.1])
    assert np.all(np.abs(r.lux / exact - 1) <= 0.01), r.lux / exact - 1
