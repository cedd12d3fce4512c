"""New views of a solved run (stages/views.py, methods/hierarchical/views/points.py): another camera's
image from the stored solution, no re-solve. Against a fresh render from that camera (the
Cornell box seen from above, where the run's camera saw the floor at a grazing angle and not
at all behind the blocks), and from the run's own camera against its own image."""

from __future__ import annotations

import hashlib
import os

import numpy as np
import pytest
from click.testing import CliRunner

from helpers import per_surface, scene_path
from radiosity.settings import options as settings_of

pytestmark = pytest.mark.cluster

R = 48
ABOVE = dict(position=[278.0, 540.0, 280.0], look_at=[278.0, 0.0, 280.0], up=[0.0, 0.0, 1.0],
             fov_y=80.0)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The Cornell box at R^2 from its own camera (A), and a fresh render from above (B)."""
    import radiosity

    d = tmp_path_factory.mktemp("views")
    src = open(scene_path("cornell-box")).read()
    i = src.index("[camera]")
    j = src.find("\n[", i + 1)
    above = ("[camera]\n" + "\n".join(f"{k} = {v}" for k, v in ABOVE.items())
             + f"\nresolution = {R}\n")
    mesh_dir = os.path.dirname(scene_path("cornell-box"))
    (d / "above.toml").write_text((src[:i] + above + (src[j:] if j >= 0 else ""))
                                  .replace('path = "', f'path = "{mesh_dir}/'))
    a = radiosity.render(scene_path("cornell-box"), out=str(d / "A"), resolution=R)
    b = radiosity.render(str(d / "above.toml"), out=str(d / "B"))
    return d, a, b


def test_a_view_from_above_equals_a_fresh_render_from_there(runs):
    from radiosity.runtime.store import RunStore
    from radiosity.stages.views import render_view

    d, a, b = runs
    cam = RunStore(str(d / "B")).load_camera()
    v = render_view(str(d / "A"), cam, name="above", settings=settings_of())
    assert v.figures["gather"]["gathered_points"] > 0  # the floor behind the blocks was unseen
    assert abs(v.image.mean() / b.image.mean() - 1) < 0.01
    orig = RunStore(str(d / "B")).read_arrays("raster")["orig"]
    diffs = per_surface(v.image, b.image, orig)
    assert len(diffs) >= 5 and max(abs(x) for x in diffs.values()) < 0.03, diffs


def test_a_view_from_the_runs_own_camera_shows_its_solution(runs):
    """A view from the run's own camera, one ray through each pixel's centre, shows the
    solution's sub-elements those rays hit (the run's point-sampled image): every surface
    within 0.5 % (points in leaves the run never saw are gathered afresh)."""
    from radiosity.runtime.store import RunStore
    from radiosity.stages.views import render_view

    d, a, _ = runs
    rs = RunStore(str(d / "A"))
    cam = rs.load_camera()
    v = render_view(str(d / "A"), cam, name="same", samples=1, settings=settings_of())
    raster = rs.read_arrays("raster")
    sub, orig = raster["sub"], raster["orig"]
    part, el = rs.load_partition(), rs.load_elements()
    rad = rs.read_arrays("solution")["radiance"]
    side = (np.einsum("ij,j->i", part.normal, cam.center) - np.einsum("ij,ij->i", part.normal, part.center)
            <= 0).astype(int)
    point = np.where((sub >= 0)[..., None], rad[np.maximum(sub, 0), side[np.maximum(sub, 0)]], 0.0)
    assert abs(v.image.mean() / point.mean() - 1) < 0.002
    diffs = per_surface(v.image, point, orig)
    assert max(abs(x) for x in diffs.values()) < 0.005, diffs


def test_the_cli_writes_a_view_and_leaves_the_run_alone(runs):
    from radiosity.cli.commands import main

    d, _, _ = runs
    run = d / "A"
    before = hashlib.sha256((run / "image.exr").read_bytes()).hexdigest()
    cam = d / "cam.toml"
    cam.write_text("[camera]\n" + "\n".join(f"{k} = {v}" for k, v in ABOVE.items()) + "\n")
    r = CliRunner().invoke(main, ["image", str(run), "--camera", str(cam), "--name", "top",
                                  "--resolution", "24"])
    assert r.exit_code == 0, r.output
    assert (run / "views" / "top" / "image.png").stat().st_size > 0
    assert hashlib.sha256((run / "image.exr").read_bytes()).hexdigest() == before
    r = CliRunner().invoke(main, ["image", str(run), "--position", "278,273,-800",
                                  "--look-at", "278,273,0", "--resolution", "16"])
    assert r.exit_code == 0, r.output
    assert (run / "views" / "view-1" / "image.exr").exists()
    r = CliRunner().invoke(main, ["image", str(run), "--look-at", "1,2,3"])
    assert r.exit_code == 2 and "--position" in r.output
