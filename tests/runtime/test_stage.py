"""The one stage master (runtime/stage.py) and typed figures (runtime/store.StageFigures): a toy
stage with an in-memory ledger runs, resumes only what is missing, recomputes a corrupted task;
a stage without a ledger hands every result to on_result and keeps nothing; figures write the
report section's keys and only those."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

import numpy as np
import pytest

from radiosity.runtime.stage import StageMaster, StagePlan
from radiosity.runtime.store import StageFigures


def _square(x: int) -> dict:
    """A toy task: its result as every ledger stage's task gives it."""
    t = time.time()
    return {"value": x * x, "counts": np.array([1, x]), "worker": "w", "start": t, "stop": t}


class _MemoryLedger:
    def __init__(self, token=None, entries=None, bad=()):
        self._token, self.entries, self.bad = token, dict(entries or {}), set(bad)

    def token(self):
        return self._token

    def finished(self, token):
        return dict(self.entries)

    def verify(self, task, entry):
        return task not in self.bad

    def rewrite_manifest(self, token, entries):
        self.entries = dict(entries)

    def record(self, task, result):
        self.entries[task] = result


@dataclass(frozen=True)
class _ToyFigures(StageFigures):
    SECTION = "toy"
    OPTIONAL = ("note",)
    FLAT = ("counters",)
    tasks: int
    counters: dict
    values: list
    computed: int
    reused: int
    note: str | None = None


class _Toy(StageMaster):
    task = staticmethod(_square)
    counters = ("tasks_done", "sum")

    def __init__(self, client, n, ledger, **kw):
        super().__init__(client, **kw)
        self.n, self._ledger, self.created = n, ledger, 0

    def plan(self):
        return StagePlan("toy", "tok", "", self.n, np.arange(self.n), "rerun")

    def args(self, task, shared):
        return (task,)

    def ledger(self):
        return self._ledger

    def create(self):
        self.created += 1
        self._ledger.entries, self._ledger._token = {}, "tok"

    def figures(self, run):
        return _ToyFigures(tasks=self.n, counters=dict(zip(self.counters, run.counts.tolist())),
                           values=[run.done[t]["value"] for t in range(self.n)],
                           computed=run.computed, reused=run.reused)


def test_figures_write_their_section_with_optional_and_flat_fields(tmp_path):
    f = _ToyFigures(tasks=3, counters={"a": 1, "b": 2}, values=[1], computed=1, reused=2)
    assert f.to_dict() == {"tasks": 3, "a": 1, "b": 2, "values": [1], "computed": 1, "reused": 2}
    assert list(f.to_dict()) == ["tasks", "a", "b", "values", "computed", "reused"]
    assert f["a"] == 1 and "b" in f and "counters" not in f and "note" not in f
    with pytest.raises(KeyError):
        f["note"]
    g = _ToyFigures(tasks=3, counters={}, values=[], computed=0, reused=0, note="x")
    assert g["note"] == "x" and g.get("nothing", 7) == 7
    f.write(str(tmp_path))
    g.write(str(tmp_path))  # merged into the same section
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["toy"] == {"tasks": 3, "a": 1, "b": 2, "values": [], "computed": 0, "reused": 0,
                          "note": "x"}


def test_nested_figures_are_written_as_their_sections(tmp_path):
    from radiosity.methods.hierarchical.clusters.tasks import ClusterFigures
    from radiosity.runtime.store import update_report

    off = ClusterFigures(why="off: 12 originals")
    assert off.to_dict() == {"why": "off: 12 originals"} and off.row() == "off: 12 originals"
    on = ClusterFigures(nodes=5, links=9, pairs_to_elements=2, evaluated=10,
                        culled_orientation=1, rays=4, visible_mean=0.5, tasks=0,
                        time_refine_s=0.1, time_s=0.2, why="on", epsilon=1e-3)
    assert "9 cluster links over 5 nodes" in on.row() and "epsilon 0.001" in on.row()
    update_report(str(tmp_path), "links", {"rounds": [on, off]})
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["links"]["rounds"][1] == {"why": "off: 12 originals"}
    assert rep["links"]["rounds"][0]["links"] == 9 and "unseen" not in rep["links"]["rounds"][0]


def test_the_stage_master_runs_resumes_and_recomputes_corrupted_tasks(client, tmp_path):
    ledger = _MemoryLedger()
    toy = _Toy(client, 6, ledger, progress=False, report_dir=str(tmp_path))
    fig = toy.run()
    assert toy.created == 1 and fig.values == [t * t for t in range(6)]
    assert fig["tasks_done"] == 6 and fig["sum"] == 15 and fig.computed == 6
    assert json.loads((tmp_path / "report.json").read_text())["toy"]["sum"] == 15
    # resume: tasks 0-3 kept (2 corrupted), 4 and 5 missing
    kept = {t: ledger.entries[t] for t in range(4)}
    again = _Toy(client, 6, _MemoryLedger("tok", kept, bad={2}), resume=True, progress=False)
    fig = again.run()
    assert again.created == 0 and fig.computed == 3 and fig.reused == 3
    assert fig.values == [t * t for t in range(6)] and fig["sum"] == 15
    # a ledger of another plan starts afresh
    other = _Toy(client, 6, _MemoryLedger("other", kept), resume=True, progress=False)
    assert other.run().computed == 6 and other.created == 1


class _Keep(StageMaster):
    task = staticmethod(_square)

    def __init__(self, client, n):
        super().__init__(client, progress=False)
        self.n, self.got = n, {}

    def plan(self):
        return StagePlan("keep", "tok", "", self.n, None, "again", window_per_worker=2)

    def inputs(self):
        return None

    def args(self, task, shared):
        return (task + 1,)

    def on_result(self, task, result, done):
        self.got[task] = result["value"]

    def figures(self, run):
        return run


def test_a_stage_without_a_ledger_gives_every_result_to_on_result_and_keeps_none(client):
    stage = _Keep(client, 5)
    run = stage.run()
    assert stage.got == {t: (t + 1) ** 2 for t in range(5)}
    assert run.computed == 5 and set(run.done) == set(range(5))
    assert all(v is None for v in run.done.values()) and not run.counts.size
    assert _Keep(None, 0).run().computed == 0  # nothing to run needs no cluster
