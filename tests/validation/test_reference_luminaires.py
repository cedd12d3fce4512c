"""The Mitsuba reference of scenes with [[luminaire]] tables (validation/reference.luminaire_dicts):
isotropic luminaires become Mitsuba point emitters whose floor radiance is the inverse-square
law's; Lambertian and IES luminaires are refused in one line."""

from __future__ import annotations

import math
import os
import shutil

import numpy as np
import pytest

from radiosity.scene.load import load_scene
from radiosity.settings import options

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data",
                    "photometry")
SCENE = """[[mesh]]
path = "mesh.obj"
[material.default]
reflectance = [0.5, 0.5, 0.5]
[camera]
position = [0, -4, 6]
look_at = [0, 0, 0]
up = [0, 0, 1]
fov_y = 60
resolution = [16, 16]
"""


def _scene(tmp_path, lum):
    (tmp_path / "mesh.obj").write_text("v -5 -5 0\nv 5 -5 0\nv 5 5 0\nv -5 5 0\nf 1 2 3 4\n")
    (tmp_path / "scene.toml").write_text(SCENE + lum)
    return load_scene(str(tmp_path / "scene.toml"), settings=options())


@pytest.mark.parametrize("lum, what", [
    ('intensity_cd = 10\ndistribution = "lambertian"\n', "is Lambertian"),
    ('ies = "lamp.ies"\n', "is an IES table"),
])
def test_non_isotropic_luminaires_are_refused(tmp_path, lum, what):
    from radiosity.validation.reference import ReferenceError, luminaire_dicts

    shutil.copy(os.path.join(DATA, "cosine.ies"), tmp_path / "lamp.ies")
    sc = _scene(tmp_path, '[[luminaire]]\nname = "L1"\nposition = [0, 0, 3]\n' + lum)
    with pytest.raises(ReferenceError, match=rf"\[\[luminaire\]\] 'L1' {what}: the Mitsuba"):
        luminaire_dicts(sc)


@pytest.mark.needs("mitsuba")
def test_isotropic_luminaire_as_a_mitsuba_point_light(tmp_path):
    """Pixels of the floor under an isotropic 1000 cd source 3 m up, colour (1, 0.5, 0.25):
    L = rho / pi I cos / r^2 per channel, I = cd colour / 683 (the pixel's centre ray's hit
    point; the pixel's footprint averages a curved function: 2 %)."""
    from radiosity.core.colour import LUMA
    from radiosity.validation.reference import load_mitsuba, mitsuba_scene, render_passes

    sc = _scene(tmp_path, '[[luminaire]]\nposition = [0, 0, 3]\nintensity_cd = 1000\n'
                          'colour = [1, 0.5, 0.25]\n')
    s = options()
    mi, _ = load_mitsuba(s.reference.variant)
    msc, _ = mitsuba_scene(sc, 2, spp=1, mi=mi)
    img, _, _ = render_passes(mi, msc, 128, 2, max_samples=s.reference.max_samples_per_call)
    img = np.asarray(img)
    cam = sc.camera
    colour = np.array([1.0, 0.5, 0.25]) / (np.array([1.0, 0.5, 0.25]) @ LUMA)
    for r, c in ((7, 7), (3, 10), (12, 4)):
        u = cam.half_w * (2 * (c + 0.5) / cam.width - 1)
        v = cam.half_h * (1 - 2 * (r + 0.5) / cam.height)
        d = u * cam.x + v * cam.y + cam.focal * cam.z
        P = cam.center - cam.center[2] / d[2] * d
        L = 0.5 / math.pi * 1000 * 3 / (P[0] ** 2 + P[1] ** 2 + 9) ** 1.5 / 683 * colour
        assert np.allclose(img[r, c], L, rtol=2e-2), (r, c)
