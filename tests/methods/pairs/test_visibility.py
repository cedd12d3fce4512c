"""The visibility matrix: bit for bit the brute force, symmetric, resilient, resumable."""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import naive
from radiosity.errors import StoreError
from radiosity.stages.preprocess import preprocess
from radiosity.methods.pairs.plan import END, FIRST, NBYTES, START, TBYTES, TSTART, choose_chunk, make_plan
from radiosity.scene.load import load_scene
from radiosity.runtime.store import RunStore
from radiosity.methods.pairs.store import VisibilityStore
from radiosity.tracing.shafts import shaft_excludes
from radiosity.methods.pairs.visibility import compute_visibility, dense_visibility
from helpers import scene_path
from radiosity.settings import options as settings_of


def _run(client, tmp_path, name, res, **kw):
    out = str(tmp_path / name.replace("/", "_"))
    sc = load_scene(scene_path(name), resolution=res, settings=settings_of())
    preprocess(sc, out, client, settings_of(), progress=False)
    fig = compute_visibility(out, client, settings_of(), progress=False, **kw)  # kw: unit
    return out, fig


@pytest.mark.parametrize("name, res", [("cornell-box", 12), ("three-rectangles", 16),
                                       ("construction-in-wood", 12), ("furnace-cube", 8)])
def test_matrix_equals_brute_force_bit_for_bit(client, tmp_path, name, res):
    out, fig = _run(client, tmp_path, name, res)
    rs = RunStore(out)
    V = dense_visibility(rs)
    ref = naive.visibility(rs.load_partition(), rs.load_elements())
    assert np.array_equal(V, V.T)
    diff = np.argwhere(V != ref)
    assert len(diff) == 0, f"{len(diff)} pairs differ, e.g. {diff[:5].tolist()}"
    assert fig["pairs_visible"] == np.triu(ref, 1).sum()
    # counts add up
    assert fig["pairs_facing"] + fig["pairs_culled_by_orientation"] == fig["pairs_total"]
    assert fig["rays"] + fig["pairs_shaft_visible"] <= fig["pairs_facing"]


def test_stripe_and_block_give_the_same_matrix(client, tmp_path):
    a, fa = _run(client, tmp_path / "a", "cornell-box", 10, unit="block")
    b, fb = _run(client, tmp_path / "b", "cornell-box", 10, unit="stripe")
    assert fa["task_unit"] == "block" and fb["task_unit"] == "stripe"
    assert fb["tasks"] < fa["tasks"]
    assert np.array_equal(dense_visibility(RunStore(a)), dense_visibility(RunStore(b)))


def test_three_rectangles_shadow_is_where_the_geometry_puts_it(client, tmp_path):
    """Light y=2 (|x|,|z| <= 0.5), occluder y=1 (|x|,|z| <= 0.4), screen y=0 (|x|,|z| <= 2.5):
    a screen point sees the centre of a light sub-element iff the segment misses the occluder."""
    out, _ = _run(client, tmp_path, "three-rectangles", 24)
    rs = RunStore(out)
    part, el = rs.load_partition(), rs.load_elements()
    V = dense_visibility(rs)
    light = [i for i, e in enumerate(el.emission[:, 0].max(1)) if e > 0][0]
    screen = int(np.argmin(el.center[:, 1]))
    L = np.arange(part.offsets[light], part.offsets[light + 1])
    S = np.arange(part.offsets[screen], part.offsets[screen + 1])
    p, q = part.center[S][:, None, :], part.center[L][None, :, :]
    mid = p + (q - p) * ((1.0 - p[..., 1:2]) / (q[..., 1:2] - p[..., 1:2]))  # crossing at y = 1
    blocked = (np.abs(mid[..., 0]) <= 0.4) & (np.abs(mid[..., 2]) <= 0.4)
    margin = np.minimum(np.abs(np.abs(mid[..., 0]) - 0.4), np.abs(np.abs(mid[..., 2]) - 0.4))
    clear = margin > 1e-6
    got = V[np.ix_(S, L)]
    assert np.array_equal(got[clear], ~blocked[clear])
    # the umbra (|x|, |z| <= 0.3 under the occluder's centre) sees no light at all
    umbra = (np.abs(part.center[S, 0]) < 0.29) & (np.abs(part.center[S, 2]) < 0.29)
    assert umbra.any() and not got[umbra].any()
    assert got[~umbra].any()


@pytest.mark.cluster  # its own LocalCluster of worker processes, one of them killed
def test_worker_killed_mid_run_gives_the_same_matrix(tmp_path):
    from distributed import Client, LocalCluster

    sc = load_scene(scene_path("cornell-box"), resolution=12, settings=settings_of())
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=50) as cluster, Client(cluster) as c:
        ref_dir = str(tmp_path / "ref")
        preprocess(sc, ref_dir, c, settings_of(), progress=False)
        compute_visibility(ref_dir, c, settings_of(), progress=False, unit="block")
        out = str(tmp_path / "run")
        preprocess(sc, out, c, settings_of(), progress=False)
        pids = list(c.run(os.getpid).values())
        killed = []

        def kill(n):
            if n == 5 and not killed:
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])

        fig = compute_visibility(out, c, settings_of(), progress=False, unit="block", on_done=kill)
        assert killed and fig["tasks_computed"] == fig["tasks"]
        assert np.array_equal(dense_visibility(RunStore(out)), dense_visibility(RunStore(ref_dir)))


class _Stop(Exception):
    pass


def test_interrupted_run_resumes_with_only_the_missing_tasks(client, tmp_path):
    sc = load_scene(scene_path("cornell-box"), resolution=12, settings=settings_of())
    ref = str(tmp_path / "ref")
    preprocess(sc, ref, client, settings_of(), progress=False)
    full = compute_visibility(ref, client, settings_of(), progress=False, unit="block")
    out = str(tmp_path / "run")
    preprocess(sc, out, client, settings_of(), progress=False)

    def stop(n):
        if n == 7:
            raise _Stop

    with pytest.raises(_Stop):
        compute_visibility(out, client, settings_of(), progress=False, unit="block", on_done=stop)
    rs = RunStore(out)
    with pytest.raises(StoreError, match="is missing: run radiosity visibility .* --resume"):
        dense_visibility(rs)
    fig = compute_visibility(out, client, settings_of(), progress=False, unit="block", resume=True)
    assert fig["tasks_reused"] == 7
    assert fig["tasks_computed"] == full["tasks"] - 7
    assert np.array_equal(dense_visibility(RunStore(out)), dense_visibility(RunStore(ref)))
    # nothing left to do: a second resume computes nothing
    again = compute_visibility(out, client, settings_of(), progress=False, unit="block",
                               resume=True)
    assert again["tasks_computed"] == 0


def test_corrupted_chunk_is_detected_and_recomputed(client, tmp_path):
    out, full = _run(client, tmp_path, "cornell-box", 12, unit="block")
    rs = RunStore(out, "r+")
    ref = dense_visibility(rs)
    vs = VisibilityStore(rs)
    plan = vs.plan()
    # flip bits inside the biggest task's first chunk, written through zarr (valid compression)
    task = int(plan.cost_order()[0])
    arr = rs.root["visibility"]["bits"]
    s = int(plan.tasks[task, TSTART])
    data = arr[s:s + 16]
    arr[s:s + 16] = data ^ 0xFF
    with pytest.raises(StoreError, match="corrupted"):
        dense_visibility(RunStore(out))
    # and a chunk file overwritten with garbage (unreadable)
    chunk_dir = os.path.join(rs.path, "visibility", "bits", "c")
    files = sorted(os.listdir(chunk_dir), key=int)
    with open(os.path.join(chunk_dir, files[-1]), "wb") as f:
        f.write(b"garbage")
    fig = compute_visibility(out, client, settings_of(), progress=False, unit="block", resume=True)
    assert fig["tasks_corrupted_recomputed"] == 2
    assert fig["tasks_computed"] == 2
    assert np.array_equal(dense_visibility(RunStore(out)), ref)


def test_culling_on_the_cornell_box_at_48(client, tmp_path):
    out, fig = _run(client, tmp_path, "cornell-box", 48)
    # most facing pairs are proven visible by the hierarchical shafts, not traced
    assert fig["rays"] < 0.5 * fig["pairs_facing"]
    assert fig["pairs_shaft_visible"] > 0 and fig["blocks_culled"] > 0
    rep = json.loads(open(os.path.join(out, "report.json")).read())["visibility"]
    assert rep["idle_fraction"] is not None and 0 <= rep["idle_fraction"] <= 1


# ----------------------------------------------------------------------------- the plan (pure)

@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(1, 40), min_size=2, max_size=9), st.sampled_from(["block", "stripe"]),
       st.integers(8, 400), st.integers(0, 2**31 - 1), st.sampled_from([0, 50, 10**6]))
def test_plan_covers_every_facing_pair_once_with_aligned_tasks(sizes, unit, cap, seed, min_bits):
    r = np.random.default_rng(seed)
    n = len(sizes)
    facing = r.random((n, n)) < 0.7
    off = np.concatenate([[0], np.cumsum(sizes)])
    plan = make_plan(off, facing, unit, max_task_bits=cap, chunk=64, min_task_bits=min_bits)
    cover = np.zeros((off[-1], off[-1]), int)
    for t in plan.tiles:
        i, j, r0, r1 = t[:4]
        cover[off[i] + r0:off[i] + r1, off[j]:off[j + 1]] += 1
    want = np.zeros_like(cover)
    for i in range(n):
        for j in range(i + 1, n):
            if facing[i, j] and facing[j, i]:
                want[off[i]:off[i + 1], off[j]:off[j + 1]] = 1
    assert np.array_equal(cover, want)  # brute-force count: each needed pair exactly once
    # tasks start on chunk boundaries, do not overlap, and hold their tiles' bytes
    assert np.all(plan.tasks[:, TSTART] % plan.chunk == 0)
    ends = plan.tasks[:, TSTART] + plan.tasks[:, TBYTES]
    assert np.all(ends[:-1] <= plan.tasks[1:, TSTART]) and (len(ends) == 0 or ends[-1] == plan.total)
    for t in plan.tasks:
        tl = plan.tiles[t[FIRST]:t[END]]
        assert np.all(tl[:, START] >= t[TSTART]) and np.all(tl[:, START] + tl[:, NBYTES] <= t[TSTART] + t[TBYTES])
        if unit == "stripe":
            assert min_bits > 0 or len(set(tl[:, 0].tolist())) == 1
        else:
            assert len(set(map(tuple, tl[:, :2].tolist()))) == 1
    bits = plan.task_bits()
    assert np.all((bits <= cap) | (np.diff(plan.tasks[:, :2], axis=1)[:, 0] == 1))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-5, 5), min_size=18, max_size=18), st.integers(0, 2**31 - 1))
def test_shaft_never_excludes_a_box_that_a_segment_between_the_boxes_touches(vals, seed):
    v = np.array(vals).reshape(6, 3)
    A = np.sort(v[0:2], axis=0)
    B = np.sort(v[2:4], axis=0)
    C = np.sort(v[4:6], axis=0)
    r = np.random.default_rng(seed)
    p = A[0] + r.random((200, 3)) * (A[1] - A[0])
    q = B[0] + r.random((200, 3)) * (B[1] - B[0])
    s = r.random((200, 1))
    x = p + s * (q - p)
    inside = np.all((x >= C[0]) & (x <= C[1]), axis=1)
    if inside.any():
        assert not shaft_excludes(A, B, C[:1], C[1:], 0)


def test_chunk_size_is_a_bounded_power_of_two():
    assert choose_chunk(np.array([10, 20])) == 4096
    assert choose_chunk(np.array([3_000_000] * 5)) == 1 << 22
    c = choose_chunk(np.array([100_000] * 5))
    assert c & (c - 1) == 0
