"""The Python API (`radiosity.render`) and where a run's workers live: a plain script renders
without a `__main__` guard (local workers are threads in its process), unknown options are one
clear error, and threads and processes give the same answer to the bit."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from helpers import ROOT, radiance, scene_path
from radiosity.settings import options as settings_of

pytestmark = pytest.mark.cluster


def test_a_plain_script_renders_without_a_main_guard(tmp_path):
    """The snippet of the docs, as a user pastes it into a file: no `if __name__ == ...`."""
    script = tmp_path / "render.py"
    script.write_text(textwrap.dedent(f"""
        import radiosity
        r = radiosity.render({scene_path("cornell-box")!r}, out={str(tmp_path / "run")!r},
                             resolution=16)
        print("shape", r.image.shape, r.image_srgb.dtype, float(r.image.mean()))
        print(r.summary())
    """))
    p = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path,
                       timeout=600)
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr and "Nanny" not in p.stderr
    assert "shape (16, 16, 3) uint8" in p.stdout and "sub-elements" in p.stdout
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    workers = rep["render"]["stages"]["peak_rss_mb"]["workers"]
    assert workers and all(k.startswith("inproc://") for k in workers)  # no worker processes


def test_unknown_option_is_one_clear_error(tmp_path):
    import radiosity
    from radiosity.errors import RadiosityError

    with pytest.raises(RadiosityError, match="unknown option.*resolutoin"):
        radiosity.render(scene_path("cornell-box"), resolutoin=16)


def test_threads_and_processes_give_the_same_answer(tmp_path):
    """`--processes false` (threads in the command's process) and `--processes true` (a
    LocalCluster of worker processes): the same partition, links and radiance to the bit."""
    runs = {}
    for mode in ("false", "true"):
        out = tmp_path / mode
        p = subprocess.run([sys.executable, "-m", "radiosity.cli", "render", scene_path("cornell-box"),
                            "--out", str(out), "--resolution", "24", "--processes", mode],
                           capture_output=True, text=True, cwd=ROOT, timeout=600)
        assert p.returncode == 0, p.stderr
        where = "threads in this process" if mode == "false" else "processes"
        assert f"local workers as {where} (stated (processes: {mode}))" in p.stdout
        runs[mode] = radiance(str(out))
    np.testing.assert_array_equal(runs["false"], runs["true"])


def test_auto_takes_threads_for_small_scenes_and_processes_for_large():
    from radiosity.runtime.cluster import local_mode

    assert local_mode("auto", 128 * 128, 65536) == (True, "auto, 16384 camera samples <= 65536")
    assert local_mode("auto", 512 * 512, 65536)[0] is False
    assert local_mode("auto", None, 65536)[0] is False  # a run directory of unknown size
    assert local_mode(True, 16, 65536)[0] is False and local_mode("false", 10 ** 9, 1)[0] is True


def test_render_summary_prints_the_closure_decision_in_one_line():
    """The render's summary says closed or open and why (issue 26): from the solve section,
    else from the plan's."""
    from radiosity.pipeline import RenderFigures

    sol = {"solver": "cg", "kernel": "point-nf", "iterations": 3, "final_residual": 1e-6,
           "channels": 1, "method": "pairs"}
    report = {"preprocess": {"sub_elements": 10, "original_elements": 2},
              "visibility": {"rays": 4, "pairs_total": 8},
              "solve": {**sol, "closure": {"reason": "closed: 0 of 10 hemisphere rays escape"}}}
    stages = {"preprocess_s": 0.1, "visibility_s": 0.1, "solve_s": 0.1, "image_s": 0.1,
              "total_s": 0.4}
    rows = dict(RenderFigures(stages, report).rows())
    assert rows["closure"] == "closed: 0 of 10 hemisphere rays escape"
    report["solve"] = sol
    report["plan"] = {"closure": {"reason": "open: 3 of 10 hemisphere rays escape"}}
    rows = dict(RenderFigures(stages, report).rows())
    assert rows["closure"].startswith("open") and "\n" not in rows["closure"]


def test_the_plan_takes_the_closure_resolved_beside_the_preprocess():
    """render_scene resolves the closure in a thread while the preprocess runs and hands it to
    scene_plan; scene_plan alone resolves the same one (the closed furnace cube: closed)."""
    from radiosity.pipeline import scene_plan
    from radiosity.scene.load import load_scene
    from radiosity.stages.solve import resolve_closure

    sc = load_scene(scene_path("furnace-cube"), settings=settings_of())
    own = scene_plan(sc, settings_of()).closure
    given = resolve_closure("auto", sc.elements, 1e-6)
    assert own.closed and own.reason == given.reason
    assert scene_plan(sc, settings_of(), closure=given).closure is given
