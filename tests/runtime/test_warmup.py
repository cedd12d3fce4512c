"""Where numba's compile time goes (runtime/warmup.py) and `radiosity warmup`."""

from __future__ import annotations

import json

import numba
import numpy as np
import pytest
from click.testing import CliRunner


def test_recording_names_each_compile_and_its_signatures():
    from radiosity.runtime.warmup import recording

    @numba.njit  # no cache: a compile every time the test runs
    def inner(x):
        return x * 2.0

    @numba.njit
    def outer(a):
        s = 0.0
        for v in a:
            s += inner(v)
        return s

    lines = []
    with recording(echo=lines.append) as log:
        outer(np.arange(3.0))
        outer(np.arange(3))  # a second signature
    names = {k.rsplit(".", 1)[-1]: k for k in log.seconds}
    assert "outer" in names and "inner" in names
    assert log.signatures[names["outer"]] == 2
    assert all(v >= 0 for v in log.seconds.values()) and log.total_s > 0
    assert any("outer" in line for line in lines)  # progress: one line per top-level compile
    d = log.to_dict()
    assert d["kernels"] == len(log.seconds) and set(d["per_kernel_s"]) == set(log.seconds)
    with recording() as quiet:  # compiled already: nothing recorded
        outer(np.arange(3.0))
    assert quiet.total_s == 0 and not quiet.seconds


def test_recording_throttles_its_progress_lines():
    from radiosity.runtime.warmup import recording

    lines = []
    with recording(echo=lines.append, every_s=3600) as log:
        numba.njit(lambda x: x + 1)(1)
    assert log.seconds and not lines  # within the hour: no line yet


@pytest.mark.cluster
def test_warmup_command_writes_the_compile_table(tmp_path):
    from radiosity.cli.commands import main

    out = tmp_path / "compile.json"
    r = CliRunner().invoke(main, ["warmup", "--methods", "pairs", "--json", str(out)])
    assert r.exit_code == 0, r.output
    assert "warmup: pairs" in r.output and "compiled" in r.output
    d = json.loads(out.read_text())
    assert set(d) >= {"total_s", "kernels", "per_kernel_s", "signatures"}
