"""`radiosity render room.glb`: a mesh file is a scene (issue 27). The render runs, the printed
[camera] table is the camera of the run, and a mesh without an emitter is refused in one line
before anything starts."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest
from click.testing import CliRunner

from radiosity.cli.commands import main

from helpers import glb_room


@pytest.mark.cluster
def test_render_a_glb_room_and_copy_its_camera(tmp_path):
    from radiosity.runtime.store import RunStore
    from radiosity.scene.load import parse_camera

    glb = tmp_path / "room.glb"
    glb.write_bytes(glb_room())
    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["render", str(glb), "--out", str(out), "--resolution", "16",
                                  "--workers", "1", "--no-preview"])
    assert r.exit_code == 0, r.output
    assert "camera: room.glb has none, so inside: a closed room" in r.output
    text = r.output[r.output.index("[camera]"):r.output.index("scene room:")]
    table = tomllib.loads(text)["camera"]
    assert table["resolution"] == [16, 16]
    cam, used = parse_camera(table, "printed"), RunStore(str(out)).load_camera()
    for k in ("center", "x", "y", "z"):
        np.testing.assert_array_equal(getattr(cam, k), getattr(used, k))
    assert (cam.half_w, cam.half_h, cam.width, cam.height) == \
        (used.half_w, used.half_h, used.width, used.height)
    rep = json.loads((out / "report.json").read_text())
    assert rep["run"]["scene"] == "room" and rep["solve"]["converged"]
    img = RunStore(str(out)).read_arrays("solution")["radiance"]
    assert np.all(np.isfinite(img)) and img.max() > 0


def test_a_glb_without_an_emitter_is_refused_in_one_line(tmp_path):
    glb = tmp_path / "dark.glb"
    glb.write_bytes(glb_room(emissive=(0.0, 0.0, 0.0)))
    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["render", str(glb), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert lines == ["error: dark.glb has no emissive material (lamp, red, white): give one "
                     "material an emissiveFactor (with KHR_materials_emissive_strength for "
                     "radiance above 1), or write a scene.toml with [[mesh]] path = \"dark.glb\" "
                     "and [material.NAME] emission = [r, g, b] (see "
                     "docs/src/how-to/meshes-as-scenes.md)"], r.output
    assert not out.exists()
