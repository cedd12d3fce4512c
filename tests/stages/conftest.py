"""A small lamp over a floor, rendered once per session by the whole pipeline: the scene of
the light-table (test_tables.py) and smooth-export (test_export.py) tests.

A square lamp of side LAMP_SIDE at height LAMP_HEIGHT faces down over a 2 x 2 floor; the lamp
reflects nothing (rho = 0) and the floor is flat, so the floor receives the lamp's direct
light only (no interreflection can reach it): its irradiance is the lamp's form factor times
pi Le, known exactly."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from helpers import write_scene
from radiosity.settings import options as settings_of

LAMP_SIDE = 0.1
LAMP_HEIGHT = 1.0
LAMP_LE = (12.0, 10.0, 6.0)          # W sr^-1 m^-2
FLOOR_RHO = (0.5, 0.4, 0.3)
_a = LAMP_SIDE / 2
LAMP_OBJ = f"""
v -1 0 -1
v -1 0 1
v 1 0 1
v 1 0 -1
v {-_a} {LAMP_HEIGHT} {-_a}
v {_a} {LAMP_HEIGHT} {-_a}
v {_a} {LAMP_HEIGHT} {_a}
v {-_a} {LAMP_HEIGHT} {_a}
usemtl floor
f 1 2 3 4
usemtl lamp
f 5 6 7 8
"""
LAMP_TOML = f"""
[material.floor]
reflectance = {list(FLOOR_RHO)}
[material.lamp]
reflectance = [0.0, 0.0, 0.0]
emission = {list(LAMP_LE)}
"""
# under the lamp, looking down: the whole floor in view, the lamp behind the camera
LAMP_CAMERA = """
[camera]
position = [0.0, 0.8, 0.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov_y = 106.0
resolution = [32, 32]
"""


@dataclass(frozen=True)
class Lamp:
    """The lamp scene's figures: side and height (m), Le (W sr^-1 m^-2), the floor's rho,
    and the lamp's corners (4, 3), counter-clockwise about its normal (-y)."""

    side: float = LAMP_SIDE
    height: float = LAMP_HEIGHT
    le: tuple = LAMP_LE
    floor_rho: tuple = FLOOR_RHO

    @property
    def polygon(self) -> np.ndarray:
        return np.array([[-_a, LAMP_HEIGHT, -_a], [_a, LAMP_HEIGHT, -_a],
                         [_a, LAMP_HEIGHT, _a], [-_a, LAMP_HEIGHT, _a]])


@pytest.fixture(scope="session")
def lamp():
    return Lamp()


@pytest.fixture(scope="session")
def lamp_render(client, tmp_path_factory):
    """render(method) -> the run directory of the lamp scene rendered by render_scene at 32^2
    with that transport method (the default kernel), once per session and method."""
    from radiosity.pipeline import render_scene
    from radiosity.scene.load import load_scene

    runs = {}

    def render(method: str) -> str:
        if method not in runs:
            d = tmp_path_factory.mktemp(f"lamp-{method}")
            path = write_scene(d, LAMP_OBJ, LAMP_TOML, camera=LAMP_CAMERA)
            out = str(d / "run")
            render_scene(load_scene(path, settings=settings_of()), out, client,
                         settings_of(method=method), preview=False, progress=False,
                         echo=lambda s: None)
            runs[method] = out
        return runs[method]

    return render


@pytest.fixture(scope="session")
def lamp_run(lamp_render):
    """The lamp scene rendered with the pairs method (the seed's visibility matrix)."""
    return lamp_render("pairs")
