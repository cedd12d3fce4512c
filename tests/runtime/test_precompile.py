"""A first run's compile on two processes (runtime/precompile.py): the recorded kernel order reads
back, still covers what a render compiles, and the helper fills an empty cache from the end."""

from __future__ import annotations

import os
import subprocess
import sys
from collections import namedtuple

import numba
import numpy as np
import pytest

from radiosity.runtime import precompile as P

from helpers import scene_path


def _run(code: str, env: dict | None = None, timeout: int = 600) -> str:
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env={**os.environ, **(env or {})}, timeout=timeout)
    assert r.returncode == 0, r.stderr[-3000:]
    return r.stdout


def test_every_recorded_signature_reads_back_to_the_same_text():
    entries = P.read_entries()
    assert len(entries) > 30
    for mod, fn, args in entries:
        disp, sig = P.resolve((mod, fn, args))
        assert isinstance(disp, numba.core.registry.CPUDispatcher), (mod, fn)
        assert ", ".join(P.typestr(t) for t in sig) == args
        assert tuple(P.parse_type(P.typestr(t)) for t in sig) == sig


Pair = namedtuple("Pair", "a b")  # at module level: typestr names its class by import path


def test_typestr_round_trips_the_kinds_of_argument_kernels_take():
    from numba.core import types

    values = [np.zeros((2, 3)), np.zeros(3, np.int32)[::2], np.zeros(3, np.uint8), 1.5, 3, True,
              (1, 2), (1, 2.0), np.zeros(2, dtype=[("x", "f8"), ("n", "i4")]),
              Pair(np.zeros(2), np.zeros(2)), Pair(np.zeros(2), 1)]
    for v in values:
        t = numba.typeof(v)
        assert P.parse_type(P.typestr(t)) == t, t
    ro = types.Array(types.float64, 2, "C", readonly=True)
    assert P.parse_type(P.typestr(ro)) == ro
    with pytest.raises(TypeError, match="no text form"):
        P.typestr(types.literal(3))


@pytest.mark.cluster
def test_the_record_covers_every_kernel_a_quick_start_render_uses(tmp_path):
    """In a fresh process (the cache warm), the Quick start render and a pairs render, then
    every signature of every radiosity kernel that process holds: each must be in kernels.txt (else regenerate it:
    the helper would not compile that kernel, and a first run would compile it alone)."""
    code = f"""
import sys, numba
from radiosity.pipeline import render
from radiosity.runtime.precompile import typestr
render({scene_path('cornell-box')!r}, {str(tmp_path / 'run')!r}, resolution=32, method="hierarchical")
render({scene_path('cornell-box')!r}, {str(tmp_path / 'pairs')!r}, resolution=16, method="pairs")
for name, mod in list(sys.modules.items()):
    if not name.startswith("radiosity."):
        continue
    for k, v in list(vars(mod).items()):
        if isinstance(v, numba.core.registry.CPUDispatcher) and v.py_func.__module__ == name:
            for sig in v.signatures:
                try:
                    print(name + "\\t" + v.py_func.__qualname__ + "\\t" + ", ".join(typestr(t) for t in sig))
                except TypeError:
                    pass
"""
    used = {tuple(line.split("\t")) for line in _run(code, {"RADIOSITY_NO_PRECOMPILE": "1"}).splitlines()
            if line.startswith("radiosity.")}
    recorded = set(P.read_entries())
    assert used, "the render used no kernel?"
    missing = sorted(used - recorded)
    assert not missing, (f"{len(missing)} kernel signature(s) a render compiles are not in "
                         f"kernels.txt, e.g. {missing[:3]}; regenerate it with "
                         "NUMBA_CACHE_DIR=$(mktemp -d) radiosity warmup --record")


@pytest.mark.cluster
def test_the_helper_fills_an_empty_cache_from_the_end_and_skips_what_is_there(tmp_path):
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    check = ("from radiosity.runtime.precompile import cache_is_warm, cold_entries; "
             "print(cache_is_warm(), len(cold_entries()))")
    warm, cold = _run(check, env).split()
    assert warm == "False" and int(cold) == len(P.read_entries())  # a fresh cache: all cold
    code = "from radiosity.runtime.precompile import main; main(['--last', '3', '-v'])"
    first = _run(code, env)
    assert first.count("compiled ") >= 1, first
    assert int(_run(check, env).split()[1]) <= int(cold) - 3
    # a later helper (a first pairs render after a Quick start) takes the next cold kernels,
    # none of those compiled before
    again = _run(code, env)
    done = {line.split()[1] for line in first.splitlines() if line.startswith("compiled ")}
    redone = {line.split()[1] for line in again.splitlines() if line.startswith("compiled ")}
    assert redone and not done & redone, (first, again)


def test_no_helper_when_the_cache_is_warm_or_when_turned_off(monkeypatch):
    monkeypatch.setattr(P, "cache_is_warm", lambda entries=None: True)
    assert P.start_helper() is None
    monkeypatch.setattr(P, "cache_is_warm", lambda entries=None: False)
    monkeypatch.setenv("RADIOSITY_NO_PRECOMPILE", "1")
    assert P.start_helper() is None
