"""The sky emitter (scene/emitters.py) against the analytic sky component: an unobstructed point
gets Eh on a horizontal plane and (0.3962 + rho_g / 2) Eh on a vertical one (CIE overcast;
0.5 + rho_g / 2 uniform), through the emitters' own direct-light sum."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from helpers import ROOT
from radiosity.errors import SceneError
from radiosity.scene.emitters import Emitter, emitter_type, irradiance
from radiosity.scene.emitters import SkyEmitter

OVERCAST_VERTICAL = (math.pi / 6 + 4 / 9) / (7 * math.pi / 9)


@pytest.mark.parametrize("kind, vertical", [("cie-overcast", OVERCAST_VERTICAL), ("uniform", 0.5)])
@pytest.mark.parametrize("up", [(0.0, 0.0, 1.0), (0.0, 1.0, 0.0)])
def test_sky_component_of_an_unobstructed_point(kind, vertical, up, rng):
    sky = SkyEmitter(kind, 10_000.0, 0.2, up=up, centre=(1.0, 2.0, 3.0), diagonal=5.0)
    assert isinstance(sky, Emitter) and emitter_type("sky") is SkyEmitter
    up = np.asarray(up)
    side = np.array([1.0, 0.0, 0.0])
    P = np.array([[0.5, 1.0, 2.0], [3.0, 2.0, 1.0], [0.0, 0.0, 0.0]])
    N = np.stack([up, side, -up])
    for r in (None, rng):
        E = irradiance(sky, sky.sample(48, r), P, N)
        lux = 683.0 * E.mean(axis=1)
        exact = 10_000.0 * np.array([1.0, vertical + 0.1, 0.2])
        assert np.allclose(lux, exact, rtol=2e-3), lux / exact - 1
    bound = sky.irradiance_bound(P.min(axis=0), P.max(axis=0))
    assert np.all(bound * 683.0 >= lux.max())


def test_sky_settings_are_checked():
    for args, msg in ((("clear", 1.0), "one of cie-overcast, uniform"),
                      (("uniform", -1.0), "horizontal_illuminance_lux"),
                      (("uniform", 1.0, 1.5), "ground_reflectance"),
                      (("uniform", 1.0, 0.1, (0, 0, 0)), "up")):
        with pytest.raises(SceneError, match=msg):
            SkyEmitter(*args)


def test_sky_through_shadow_rays_open_floor_and_closed_box(tmp_path):
    """daylight.sky_irradiance: on an open floor the horizontal point gets Eh and a vertical one
    0.3962 Eh (black ground: the floor hides nothing of the sky); inside a closed box, nothing."""
    from helpers import write_scene
    from radiosity.scene.daylight import sky_irradiance
    from radiosity.scene.load import load_scene
    from radiosity.settings import options
    from radiosity.tracing.rays import caster_of

    floor = "v -50 -50 0\nv 50 -50 0\nv 50 50 0\nv -50 50 0\nf 1 2 3 4\n"
    cam = ("[camera]\nposition = [0.0, -4.0, 2.0]\nlook_at = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 1.0]\n"
           "fov_y = 60.0\nresolution = [8, 8]\n")
    sc = load_scene(write_scene(tmp_path, floor, camera=cam), settings=options())
    el = sc.elements
    caster = caster_of(el.verts, el.nverts, 1e-6)
    sky = SkyEmitter("cie-overcast", 10_000.0, 0.0, up=(0, 0, 1), centre=(0, 0, 0), diagonal=141.0)
    P = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]])
    N = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    lux = 683.0 * sky_irradiance(caster, sky, P, N, n=32).mean(axis=1)
    assert np.allclose(lux, 10_000.0 * np.array([1.0, OVERCAST_VERTICAL]), rtol=5e-3), lux

    bel = load_scene(os.path.join(ROOT, "scenes", "furnace-cube", "scene.toml"),
                     settings=options()).elements
    inside = sky_irradiance(caster_of(bel.verts, bel.nverts, 1e-6), sky, np.array([[0.5, 0.5, 0.5]]),
                            np.array([[0.0, 0.0, 1.0]]))
    assert np.all(inside == 0.0)
