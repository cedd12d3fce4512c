"""Luminaires (scene/luminaires.py, emitters.PointEmitters, their light in direct.DirectLight):
the scene keys and their one-line errors, the frame (aim, rotation, the scene's up), colour and
flux scaling, the exact inverse-square and cosine law at points (with shadows), a candela
table's direction through a whole scene, flux conservation in a closed box, a luminaire inside
a wall, and the run store's round trip."""

from __future__ import annotations

import math
import os
import shutil

import numpy as np
import pytest

from radiosity.core.colour import EFFICACY, LUMA
from radiosity.errors import SceneError
from radiosity.scene.direct import DirectLight
from radiosity.scene.emitters import EMITTER_TYPES, Emitter, PointEmitters, emits, irradiance
from radiosity.scene.load import load_scene
from radiosity.scene.luminaires import frame_of, luminaires_of
from radiosity.settings import options

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data",
                    "photometry")
PLANE = "v -5 -5 0\nv 5 -5 0\nv 5 5 0\nv -5 5 0\nf 1 2 3 4\n"
CAMERA = """
[camera]
position = [0, -4, 6]
look_at = [0, 0, 0]
up = [0, 0, 1]
fov_y = 60
resolution = [16, 16]
"""


def scene(tmp_path, lum: str, obj: str = PLANE, camera: str = CAMERA, extra: str = ""):
    (tmp_path / "mesh.obj").write_text(obj)
    (tmp_path / "scene.toml").write_text('[[mesh]]\npath = "mesh.obj"\n' + extra + camera + lum)
    return load_scene(str(tmp_path / "scene.toml"), settings=options())


def lux(E):
    """Illuminance (lx) of irradiances E (p, 3) W m^-2, as stages/tables reads it."""
    return np.asarray(E) @ LUMA * EFFICACY


def test_isotropic_1000_cd_3_m_above_gives_111_11_lx(tmp_path):
    sc = scene(tmp_path, '[[luminaire]]\nposition = [0, 0, 3]\nintensity_cd = 1000\n')
    dl = DirectLight(sc.elements, 1e-6)
    assert dl
    x = np.array([0.0, 1.0, 2.5, 4.0])
    P = np.stack([x, 0.5 * x, np.zeros(4)], axis=1)
    E = lux(dl.irradiance(P, np.tile([0.0, 0.0, 1.0], (4, 1)), np.zeros(4, np.int64)))
    r2 = (P[:, :2] ** 2).sum(1) + 9.0
    assert E[0] == pytest.approx(1000 / 9, rel=1e-12)            # 111.11 lx straight below
    assert np.allclose(E, 1000 * 3 / r2 ** 1.5, rtol=1e-12)       # cos / r^2 everywhere
    # a tilted receiver: the cosine of its normal; facing away: nothing
    n = np.array([[math.sin(0.3), 0.0, math.cos(0.3)], [0.0, 0.0, -1.0]])
    E2 = lux(dl.irradiance(P[:2], n, np.array([-1, -1])))
    d = np.array([0.0, 0.0, 3.0]) - P[0]
    assert E2[0] == pytest.approx(1000 * (d @ n[0]) / 27, rel=1e-12)
    assert E2[1] == 0.0
    assert np.allclose(dl.unoccluded(P, np.tile([0.0, 0.0, 1.0], (4, 1))) @ LUMA * EFFICACY, E)


def test_shadow_ray_per_point(tmp_path):
    """A small plate at z = 1.5 over the origin, facing up: points under it are dark, beside
    it lit; the plate's own top gets the light at its distance."""
    plate = "v -0.5 -0.5 1.5\nv 0.5 -0.5 1.5\nv 0.5 0.5 1.5\nv -0.5 0.5 1.5\nf 5 6 7 8\n"
    sc = scene(tmp_path, '[[luminaire]]\nposition = [0, 0, 3]\nintensity_cd = 1000\n',
               obj=PLANE + plate)
    dl = DirectLight(sc.elements, 1e-6)
    P = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, 0.0], [3.0, 0.0, 0.0], [0.1, 0.0, 1.5]])
    E = lux(dl.irradiance(P, np.tile([0.0, 0.0, 1.0], (4, 1)), np.array([0, 0, 0, 1])))
    assert E[0] == 0.0 and E[1] == 0.0
    assert E[2] == pytest.approx(1000 * 3 / 18 ** 1.5, rel=1e-12)
    assert E[3] == pytest.approx(1000 * 1.5 / (1.5 ** 2 + 0.01) ** 1.5, rel=1e-12)
    assert dl.rays >= 3


def test_goniometric_table_points_the_right_way(tmp_path):
    """asymmetric.ies aimed down at 2 m, rotated 30 degrees: at a floor point in direction C
    (from C0 toward C90, counter-clockwise seen from above) and gamma, E = I(C - 30, gamma)
    cos(gamma) / r^2, I from the file itself."""
    from radiosity.formats.photometry import read_photometry

    fn = shutil.copy(os.path.join(DATA, "asymmetric.ies"), tmp_path / "lamp.ies")
    sc = scene(tmp_path, '[[luminaire]]\nname = "a"\nies = "lamp.ies"\nposition = [0, 0, 2]\n'
                         'rotation = 30\nmultiplier = 3\n')
    ph = read_photometry(str(fn))
    dl = DirectLight(sc.elements, 1e-6)
    for C, g in ((0.0, 20.0), (75.0, 40.0), (200.0, 55.0), (333.0, 10.0)):
        r_xy = 2 * math.tan(math.radians(g))
        P = np.array([[r_xy * math.cos(math.radians(C)), r_xy * math.sin(math.radians(C)), 0]])
        E = lux(dl.irradiance(P, np.array([[0.0, 0, 1]]), np.array([0])))[0]
        want = 3 * ph.at(np.array([(C - 30) % 360]), np.array([g]))[0]
        r2 = 4 + r_xy ** 2
        assert E == pytest.approx(want * math.cos(math.radians(g)) / r2, rel=1e-9), (C, g)


def test_frame_default_aim_follows_the_scene_up_and_rotation_turns_c0_toward_c90():
    f = frame_of(np.array([0.0, 0, -1]), np.array([0.0, 0, 1]), 0.0)
    assert np.allclose(f, [[1, 0, 0], [0, 1, 0], [0, 0, -1]])
    f = frame_of(np.array([0.0, 0, -1]), np.array([0.0, 0, 1]), 90.0)
    assert np.allclose(f[0], [0, 1, 0]) and np.allclose(f[1], [-1, 0, 0])
    f = frame_of(np.array([0.0, -1, 0]), np.array([0.0, 1, 0]), 0.0)     # y up
    assert np.allclose(np.cross(f[0], f[1]), -f[2]) and np.allclose(f[2], [0, -1, 0])
    f = frame_of(np.array([1.0, 0, 0]), np.array([0.0, 0, 1]), 0.0)      # aimed sideways
    assert np.allclose(f[0], [0, 0, 1])                                 # C0 up


def test_default_aim_is_minus_the_camera_up(tmp_path):
    cam = CAMERA.replace("up = [0, 0, 1]", "up = [0, 1, 0]").replace(
        "position = [0, -4, 6]", "position = [0, 6, -4]")
    obj = "v -5 0 -5\nv -5 0 5\nv 5 0 5\nv 5 0 -5\nf 1 2 3 4\n"        # floor y = 0, facing +y
    sc = scene(tmp_path, '[[luminaire]]\nposition = [0, 3, 0]\nintensity_cd = 100\n'
                         'distribution = "lambertian"\n', obj=obj, camera=cam)
    lum = luminaires_of(sc.elements).items[0]
    assert np.allclose(lum.frame[2], [0, -1, 0])
    dl = DirectLight(sc.elements, 1e-6)
    P = np.array([[0.0, 0, 0], [3.0, 0, 0]])
    E = lux(dl.irradiance(P, np.array([[0.0, 1, 0]] * 2), np.array([0, 0])))
    c = 3 / math.sqrt(18)
    assert E[0] == pytest.approx(100 / 9, rel=1e-12)
    assert E[1] == pytest.approx(100 * c * c / 18, rel=1e-12)          # cos at both ends


def test_colour_is_normalised_and_flux_lm_scales(tmp_path):
    sc = scene(tmp_path, '[[luminaire]]\nposition = [0, 0, 3]\nflux_lm = 2000\n'
                         'intensity_cd = 1\ncolour = [1.0, 0.5, 0.25]\n'
                         '[[luminaire]]\nname = "t"\nies = "cos.ies"\nposition = [1, 0, 3]\n'
                         'flux_lm = 500\n'.replace("cos.ies", os.path.join(DATA, "cosine.ies")))
    a, b = luminaires_of(sc.elements).items
    assert a.colour @ LUMA == pytest.approx(1.0, rel=1e-12)
    assert np.allclose(a.colour / a.colour[0], [1.0, 0.5, 0.25])
    assert a.flux_lm() == pytest.approx(2000.0, rel=1e-12)
    assert a.cd == pytest.approx(2000 / (4 * math.pi), rel=1e-12)
    assert b.flux_lm() == pytest.approx(500.0, rel=1e-12)
    pe = PointEmitters.of_scene(sc.elements)
    assert isinstance(pe, Emitter) and EMITTER_TYPES["point"] is PointEmitters
    assert pe.power() @ LUMA * EFFICACY == pytest.approx(2500.0, rel=1e-12)
    # the protocol's sum gives the same as DirectLight, unoccluded
    P = np.array([[0.3, -0.2, 0.0], [2.0, 1.0, 0.0]])
    N = np.array([[0.0, 0.0, 1.0]] * 2)
    s = pe.sample(1)
    assert np.allclose(irradiance(pe, s, P, N), DirectLight(sc.elements, 1e-6).unoccluded(P, N))
    bound = pe.irradiance_bound(P[0] - 0.1, P[0] + 0.1)
    assert np.all(irradiance(pe, s, P[:1], N[:1])[0] <= bound)
    assert emits(sc.elements)


@pytest.mark.parametrize("lum, words", [
    ('[[luminaire]]\nintensity_cd = 1\n', "has no 'position'"),
    ('[[luminaire]]\nposition = [0, 0, 1]\n', "needs 'ies'"),
    ('[[luminaire]]\nposition = [0, 0, 1]\nintensity_cd = 1\nflux = 3\n', "unknown key(s) ['flux']"),
    ('[[luminaire]]\nposition = [0, 0, 1]\nintensity_cd = 1\nmultiplier = 2\nflux_lm = 3\n',
     "not both"),
    ('[[luminaire]]\nposition = [0, 0, 1]\nintensity_cd = -1\n', "intensity_cd must be"),
    ('[[luminaire]]\nposition = [0, 0, 1]\nintensity_cd = 1\ndistribution = "spot"\n',
     "distribution 'spot'"),
    ('[[luminaire]]\nposition = [0, 0, 1]\nies = "none.ies"\n', "photometric file not found"),
    ('[[luminaire]]\nposition = [0, 0, 1]\nies = "x.ies"\nintensity_cd = 3\n',
     "'intensity_cd' is for a luminaire without 'ies'"),
    ('[[luminaire]]\nname = "a"\nposition = [0, 0, 1]\nintensity_cd = 1\n'
     '[[luminaire]]\nname = "a"\nposition = [0, 0, 2]\nintensity_cd = 1\n', "used twice"),
    ('[[luminaire]]\nposition = [0, 0, 1]\nintensity_cd = 1\naim = [0, 0, 0]\n', "non-zero"),
])
def test_bad_luminaire_tables_one_line(tmp_path, lum, words):
    with pytest.raises(SceneError) as e:
        scene(tmp_path, lum)
    assert words in str(e.value) and "scene.toml" in str(e.value) and "\n" not in str(e.value)


CUBE_IN = """v 0 0 0
v 4 0 0
v 4 4 0
v 0 4 0
v 0 0 4
v 4 0 4
v 4 4 4
v 0 4 4
f 1 2 3 4
f 5 8 7 6
f 1 5 6 2
f 2 6 7 3
f 3 7 8 4
f 4 8 5 1
"""


def test_inside_a_closed_solid_is_refused_inside_a_room_is_not(tmp_path):
    """The cube as a room (faces inward, CUBE_IN) holds a luminaire; the same cube as a solid
    (orient = "outward") refuses it with one line; so does a point behind a wall's back."""
    cam = CAMERA.replace("position = [0, -4, 6]", "position = [2, 0.5, 2]").replace(
        "look_at = [0, 0, 0]", "look_at = [2, 4, 2]")
    lum = '[[luminaire]]\nname = "bulb"\nposition = [2, 2, 2]\nintensity_cd = 10\n'
    sc = scene(tmp_path, lum, obj=CUBE_IN, camera=cam)
    assert len(luminaires_of(sc.elements)) == 1
    (tmp_path / "mesh.obj").write_text(CUBE_IN)
    (tmp_path / "scene.toml").write_text('[[mesh]]\npath = "mesh.obj"\norient = "outward"\n'
                                         + cam + lum)
    with pytest.raises(SceneError, match=r"\[\[luminaire\]\] 'bulb' at \[2.0, 2.0, 2.0\] is "
                                         r"inside a wall or a closed solid"):
        load_scene(str(tmp_path / "scene.toml"), settings=options())


def test_flux_conservation_in_a_closed_box(tmp_path):
    """An isotropic source inside a closed cube: the direct flux on its six faces (E at a fine
    midpoint grid times the cells' areas) is the source's flux 4 pi I, to the grid's error."""
    cam = CAMERA.replace("position = [0, -4, 6]", "position = [2, 0.5, 2]").replace(
        "look_at = [0, 0, 0]", "look_at = [2, 4, 2]")
    sc = scene(tmp_path, '[[luminaire]]\nposition = [1.3, 2.2, 2.9]\nintensity_cd = 1000\n',
               obj=CUBE_IN, camera=cam)
    el = sc.elements
    dl = DirectLight(el, 1e-6)
    k = 120
    g = (np.arange(k) + 0.5) / k
    u, v = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    total = 0.0
    for e in range(len(el)):
        V = el.verts[e]
        P = V[0] + u[:, None] * (V[1] - V[0]) + v[:, None] * (V[3] - V[0])
        E = lux(dl.irradiance(P, np.tile(el.normal[e], (len(P), 1)), np.full(len(P), e)))
        total += E.sum() * el.area[e] / len(P)
    assert total == pytest.approx(4 * math.pi * 1000, rel=2e-4)


def test_run_store_keeps_the_luminaires(tmp_path):
    from radiosity.runtime.store import RunStore

    fn = shutil.copy(os.path.join(DATA, "asymmetric.ies"), tmp_path / "lamp.ies")
    sc = scene(tmp_path, f'[[luminaire]]\nies = "{os.path.basename(fn)}"\nposition = [0, 0, 2]\n'
                         'rotation = 10\ncolour = [1, 0.8, 0.6]\n'
                         '[[luminaire]]\nposition = [1, 1, 2]\nintensity_cd = 5\n')
    rs = RunStore(str(tmp_path / "run"), "w")
    rs.save_elements(sc.elements)
    back = RunStore(str(tmp_path / "run")).load_elements()
    a, b = luminaires_of(sc.elements), luminaires_of(back)
    assert a.digest() == b.digest() and len(b) == 2
    P = np.array([[0.5, -0.3, 0.0]])
    N = np.array([[0.0, 0.0, 1.0]])
    assert np.array_equal(DirectLight(back, 1e-6).unoccluded(P, N),
                          DirectLight(sc.elements, 1e-6).unoccluded(P, N))


def test_a_leaf_near_a_luminaire_takes_more_points_and_gets_closer(tmp_path):
    """One 1 m leaf (a floor) 0.3 m under an isotropic luminaire over its centre: leaf_strata
    gives it more than 2 x 2 points, and its first bounce rho / pi mean(H1) is closer to the
    exact mean (a 600 x 600 midpoint grid of I h / r^3) than with 4 points."""
    from radiosity.methods.hierarchical.solve.direct import first_bounce, leaf_strata

    obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"
    sc = scene(tmp_path, '[[luminaire]]\nposition = [0.5, 0.5, 0.3]\nintensity_cd = 1000\n',
               obj=obj, extra="[material.default]\nreflectance = [0.5, 0.5, 0.5]\n")
    el = sc.elements
    table = {"verts": el.verts, "nverts": el.nverts, "orig": np.arange(1),
             "leaf_node": np.arange(1)}
    assert leaf_strata(table, el, 4)[0] > 2
    assert leaf_strata(table, el, 4, adaptive=False)[0] == 2
    g = (np.arange(600) + 0.5) / 600 - 0.5
    x, y = np.meshgrid(g, g)
    exact = 0.5 / math.pi * (1000 * 0.3 / (x * x + y * y + 0.09) ** 1.5).mean() / EFFICACY
    s = options()
    fixed = first_bounce(table, el, s, adaptive=False)[0, 1, 0]
    more = first_bounce(table, el, s)[0, 1, 0]
    assert abs(more / exact - 1) < 0.1 * abs(fixed / exact - 1)    # measured: -8.9 % -> 0.34 %
    assert abs(more / exact - 1) < 0.01
