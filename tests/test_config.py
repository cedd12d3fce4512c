"""Configuration (docs/src/how-to/configuration.md): radiosity.yaml in dask.config, overridden by
DASK_RADIOSITY__SECTION__KEY environment variables, which CLI flags override in turn. Checked in
fresh processes: dask reads the environment when it is imported."""

from __future__ import annotations

import os
import subprocess
import sys

from helpers import scene_path


def _run(args, **env) -> str:
    e = {k: v for k, v in os.environ.items() if not k.startswith("DASK_RADIOSITY__")}
    e.update(env)
    r = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=e, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout


def test_environment_variables_override_the_yaml():
    code = ("from radiosity.settings import resolve; s = resolve(); print(s.subdivide.max_depth, "
            "s.solve.tol, s.solve.kernel, resolve({'solve.tol': 1e-9}).solve.tol)")
    assert _run(["-c", code]).split() == ["48", "1e-05", "point-nf", "1e-09"]  # the YAML's
    out = _run(["-c", code], DASK_RADIOSITY__SUBDIVIDE__MAX_DEPTH="30",
               DASK_RADIOSITY__SOLVE__TOL="1e-3", DASK_RADIOSITY__SOLVE__KERNEL="disc")
    assert out.split() == ["30", "0.001", "disc", "1e-09"]  # an explicit value (a flag) wins


def test_environment_reaches_the_command_and_a_flag_wins():
    """`radiosity plan` with closure and tolerance from the environment: the furnace cube (closed
    by its geometry) is planned open because the environment says so, and the Jacobi bound
    follows the environment's tolerance (ceil(log 1e-3 / log 0.5) = 10 passes) until --tol
    gives another (1e-6: 20 passes)."""
    cube = scene_path("furnace-cube")
    out = _run(["-m", "radiosity.cli", "plan", cube])  # the YAML's tol 1e-5: 17 passes
    assert "closure            on" in out and "passes to tolerance (Jacobi bound): 17" in out
    env = {"DASK_RADIOSITY__SOLVE__CLOSURE": "off", "DASK_RADIOSITY__SOLVE__TOL": "1e-3"}
    out = _run(["-m", "radiosity.cli", "plan", cube], **env)
    assert "closure            OFF     stated (closure: off)" in out
    assert "passes to tolerance (Jacobi bound): 10" in out
    out = _run(["-m", "radiosity.cli", "plan", cube, "--tol", "1e-6"], **env)
    assert "passes to tolerance (Jacobi bound): 20" in out


def test_the_ray_module_default_offset_is_the_shipped_setting():
    """tracing/rays.py may not read the configuration (worker side): its fallback offset must
    equal radiosity.yaml's rays.epsilon as shipped."""
    import yaml

    import radiosity
    from radiosity.tracing.rays import DEFAULT_RAY_OFFSET

    with open(os.path.join(os.path.dirname(radiosity.__file__), "radiosity.yaml")) as f:
        shipped = yaml.safe_load(f)["radiosity"]["rays"]["epsilon"]
    assert DEFAULT_RAY_OFFSET == shipped


# ----------------------------------------------------------------------------- one validation

BAD = [({"tol": 2}, "tol (--tol, radiosity.solve.tol) must be a number in (0, 1), got 2.0"),
       ({"tol": -1}, "tol (--tol, radiosity.solve.tol) must be a number in (0, 1), got -1.0"),
       ({"max_iterations": 0}, "max_iterations (--max-iterations, radiosity.solve.max-iterations) "
                               "must be 1 or more, got 0"),
       ({"subpixel": 0}, "subpixel (--subpixel, radiosity.subdivide.subpixel) must be 1 or more, "
                         "got 0"),
       ({"epsilon": -1.0}, "epsilon (--epsilon, radiosity.hierarchy.epsilon) must be a number "
                           ">= 0 or auto, got -1.0"),
       ({"solver": "sor"}, "solver (--solver, radiosity.solve.solver): unknown solver 'sor': use "
                           "one of jacobi, gauss-seidel, progressive, cg"),
       ({"sigma": float("inf")}, "sigma (--sigma, radiosity.render.sigma) must be a number above 0, "
                                 "got inf: not a finite number")]


def test_the_api_checks_options_as_the_cli_does_with_the_same_line():
    """radiosity.render(tol=2) rendered silently with one pass, tol=-1 ended in a ValueError
    traceback: both are now the CLI's check, one RadiosityError before anything starts, and
    `radiosity render --tol 2` prints the very same line (exit 2)."""
    import pytest

    import radiosity
    from radiosity.errors import RadiosityError

    for given, line in BAD:
        with pytest.raises(RadiosityError) as e:
            radiosity.render(scene_path("cornell-box"), **given)
        assert str(e.value) == line, given
    flag, value = "--tol", "2"
    r = subprocess.run([sys.executable, "-m", "radiosity.cli", "render", scene_path("cornell-box"),
                        "--out", "unused-run", flag, value], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 2 and BAD[0][1] in r.stderr + r.stdout, r.stderr
    assert "Traceback" not in r.stderr


def test_settings_check_names_every_bad_value_and_passes_the_shipped_yaml():
    import pytest

    from radiosity.errors import RadiosityError
    from radiosity.settings import CHECKS, check, options, resolve

    s = resolve()  # the shipped YAML passes its own checks
    assert check(s) is s
    for key in CHECKS:  # and every check can fail
        with pytest.raises(RadiosityError, match=key.replace(".", r"\.")):
            check(s.replace({key: float("nan")}) if key not in ("render.exposure",) else
                  s.replace({key: -1.0}))
    with pytest.raises(RadiosityError, match="unknown option.*resolutoin"):
        options(resolutoin=16)
    assert options(unit="block").hierarchy.task_unit == "block" == options(
        unit="block").visibility.task_unit


def test_a_trimesh_scene_renders_as_its_glb_would():
    """radiosity.render takes trimesh objects (a Scene gave AttributeError): they are read as a
    GLB with their materials, and one without an emitter is the mesh loader's one line."""
    import numpy as np
    import pytest
    import trimesh

    from radiosity.errors import SceneError
    from radiosity.pipeline import scene_of
    from radiosity.settings import options

    st = options()
    with pytest.raises(SceneError, match="no emissive material"):
        scene_of(trimesh.creation.box(), 16, st)
    lamp = trimesh.creation.box(extents=[0.2, 0.2, 0.05])
    lamp.apply_translation([0, 0, 2])
    lamp.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        name="lamp", baseColorFactor=[0, 0, 0, 255], emissiveFactor=[1, 1, 1]))
    room = trimesh.creation.box(extents=[6, 6, 6])
    room.invert()
    sc = scene_of(trimesh.Scene([room, lamp]), 16, st)
    assert len(sc.elements) == 12 and np.isclose(sc.elements.emission.max(), 1.0)
    assert (sc.camera.width, sc.camera.height) == (16, 16)
    with pytest.raises(Exception, match="cannot render a dict"):
        scene_of({}, 16, st)
    # view factors take a trimesh.Scene too: its meshes placed by their transforms
    from radiosity.viewfactors.facets import load_facets

    far = trimesh.creation.box()
    far.apply_translation([3, 0, 0])
    one = load_facets(trimesh.creation.box(), st)
    two = load_facets(trimesh.Scene([trimesh.creation.box(), far]), st)
    assert len(two) == 2 * len(one) and two.center[:, 0].max() > 2.5
