"""The test harness itself: a test that needs an external component (marker `needs`, conftest.py)
skips outside CI and fails under CI=true when the component is missing, so that a CI without
Chromium, Slurm or Mitsuba cannot pass green."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

from helpers import ROOT


def _run(tmp_path, env_extra: dict) -> subprocess.CompletedProcess:
    """pytest on a one-test file that needs Chromium, with the suite's conftest."""
    for f in ("conftest.py", "helpers.py"):
        shutil.copy(os.path.join(ROOT, "tests", f), tmp_path / f)
    (tmp_path / "test_one.py").write_text(
        "import pytest\n\n@pytest.mark.needs('chromium')\ndef test_one():\n    pass\n")
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    env.update(env_extra, RADIOSITY_CHROMIUM=str(tmp_path / "no-such-chromium"))
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rsf", "-p", "no:cacheprovider",
                           str(tmp_path / "test_one.py")], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)


def test_missing_component_skips_outside_ci_and_fails_under_ci(tmp_path):
    r = _run(tmp_path, {})
    assert r.returncode == 0 and "1 skipped" in r.stdout, r.stdout
    assert "no-such-chromium" in r.stdout and "RADIOSITY_CHROMIUM" in r.stdout  # says why
    r = _run(tmp_path, {"CI": "true"})
    # failed in the fixture: pytest counts it as an error, and the run exits 1 (red)
    assert r.returncode == 1 and "1 error" in r.stdout and "passed" not in r.stdout, r.stdout
    assert "CI=true and chromium is missing" in r.stdout
