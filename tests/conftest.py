"""Shared fixtures: a real LocalCluster (dashboard on a free loopback port), a seeded rng, a
tiny scene on disk, and the external components some tests drive (Slurm, Chromium, Mitsuba;
shared helpers are in helpers.py): `@pytest.mark.needs("chromium")` skips a test, saying why, when the
component is missing, except under CI (CI=true, as .ci/run sets it), where it fails: .ci/run
provides them, so a missing one there means CI is broken, not that the test may pass."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # helpers, naive

from helpers import FLOOR_AND_TRIANGLE, IN_CI, missing, write_scene  # noqa: E402


# modules whose tests run whole commands (each starts its own cluster) or subprocesses
CLUSTER_MODULES = {"test_cli.py", "test_faults.py", "test_faults_repair.py", "test_cluster.py",
                   "test_dashboard.py", "test_config.py", "test_harness.py", "test_effects.py",
                   "test_viewfactors.py", "test_reference.py", "test_accuracy.py",
                   "test_defaults.py"}


def pytest_collection_modifyitems(config, items):
    """The `cluster` marker (the markers are described in pyproject.toml): on tests that use the
    session's cluster (or one of their own), run whole commands, drive Chromium, Slurm or
    Mitsuba, or are `slow`."""
    for item in items:
        if {"client", "killable"} & set(getattr(item, "fixturenames", ())) \
                or item.get_closest_marker("needs") or item.get_closest_marker("slow") \
                or os.path.basename(str(item.fspath)) in CLUSTER_MODULES:
            item.add_marker(pytest.mark.cluster)


@pytest.fixture(autouse=True)
def _needs(request):
    """The components of the test's `needs` marker: skip (outside CI) or fail (CI=true)."""
    marker = request.node.get_closest_marker("needs")
    for component in (marker.args if marker else ()):
        why = missing(component)
        if why is None:
            continue
        if IN_CI:
            pytest.fail(f"CI=true and {component} is missing: {why}", pytrace=False)
        pytest.skip(why)


@pytest.fixture(scope="session")
def client():
    """Two worker processes on 127.0.0.1 (dashboard on a free loopback port): the real thing,
    shared by the session."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0", silence_logs=40) as cluster, Client(cluster) as c:
        yield c


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


@pytest.fixture
def small_scene(tmp_path):
    """A unit floor quad (facing up) and a tilted triangle above it, seen from above."""
    return write_scene(tmp_path, FLOOR_AND_TRIANGLE, "[material.default]\nreflectance = [0.5, 0.5, 0.5]\n")
