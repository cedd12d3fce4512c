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
    code = ("from radiosity import config; print(config.get('subdivide.max-depth'), "
            "config.get('solve.tol'), config.get('solve.kernel'), config.get('solve.tol', 1e-9))")
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
