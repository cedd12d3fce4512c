"""Nothing n x n in the original elements (issue 15): the hierarchy's facing pairs and
"anything behind" flags equal the dense relations exactly; the sparse plan equals the dense
one; many originals plan in bounded memory; beyond the budget, one line up front."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import scene_path
from radiosity.scene.effects import _behind
from radiosity.scene.originals import (TOL, FacingPairsError, behind_any, build_tree,
                                       check_budget, estimate_facing_pairs, facing_pairs, tree_of)
from radiosity.methods.pairs.plan import facing_blocks, make_plan
from radiosity.scene.load import load_scene
from radiosity.settings import options as settings_of


def dense_pairs(v, nv, nrm, c, ts):
    f = facing_blocks(v, nv, nrm, c, ts)
    both = f & f.T
    iu, ju = np.triu_indices(len(v), 1)
    k = both[iu, ju]
    return iu[k], ju[k]


def soup(rng, n, two_frac=0.3, coplanar=False):
    """n random triangles (some two-sided; optionally all in one plane, some facing down)."""
    c = rng.random((n, 3)) * 10
    if coplanar:
        c[:, 1] = 0.0
    e1 = rng.normal(size=(n, 3))
    e2 = rng.normal(size=(n, 3))
    if coplanar:
        e1[:, 1] = e2[:, 1] = 0.0
    v = np.stack([c, c + e1, c + e2, c + e2], 1)
    nrm = np.cross(e1, e2)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return v, np.full(n, 3, np.int8), nrm, v[:, :3].mean(1), rng.random(n) < two_frac


SCENES = ["cornell-box", "room-2400", "furnace-sphere", "construction-in-wood", "coaxial-discs",
          "perpendicular-squares"]


@pytest.mark.parametrize("name", SCENES)
def test_facing_pairs_and_behind_equal_the_dense_relations_on_builtin_scenes(name):
    el = load_scene(scene_path(name), settings=settings_of()).elements
    bi, bj, _ = facing_pairs(tree_of(el))
    di, dj = dense_pairs(el.verts, el.nverts, el.normal, el.center, el.two_sided)
    np.testing.assert_array_equal(bi, di)
    np.testing.assert_array_equal(bj, dj)
    np.testing.assert_array_equal(behind_any(tree_of(el)), _behind(el).any(axis=1))


@pytest.mark.parametrize("seed,n,coplanar,leaf", [(1, 300, False, 16), (2, 500, True, 4),
                                                  (3, 257, False, 1), (4, 40, False, 64)])
def test_facing_pairs_equal_the_dense_relation_on_random_soups(rng, seed, n, coplanar, leaf):
    v, nv, nrm, c, ts = soup(np.random.default_rng(seed), n, coplanar=coplanar)
    if coplanar:  # half of them facing down: coplanar pairs never face each other
        flip = np.arange(n) % 2 == 0
        nrm[flip] *= -1
    t = build_tree(v, nv, nrm, c, ts, leaf=leaf)
    bi, bj, _ = facing_pairs(t)
    di, dj = dense_pairs(v, nv, nrm, c, ts)
    np.testing.assert_array_equal(bi, di)
    np.testing.assert_array_equal(bj, dj)
    behind = (np.einsum("ic,jkc->ijk", nrm, v) - np.einsum("ic,ic->i", nrm, c)[:, None, None]
              < -TOL * np.linalg.norm(v.reshape(-1, 3).max(0) - v.reshape(-1, 3).min(0))).any(2)
    np.testing.assert_array_equal(behind_any(t), behind.any(axis=1))
    wanted = np.arange(n) % 3 == 1  # only some elements asked: the same answer for them
    np.testing.assert_array_equal(behind_any(t, wanted=wanted), behind.any(axis=1) & wanted)
    assert behind_any(t, first=True).any() == behind.any()
    est = estimate_facing_pairs(t)  # counted on the hierarchy: exact
    assert est["exact"] and est["estimate"] == len(bi)
    rough = estimate_facing_pairs(t, max_node_pairs=20)  # mostly sampled
    assert abs(rough["estimate"] - len(bi)) < 0.25 * len(bi) + 50


def test_sparse_plan_equals_the_dense_plan(rng):
    el = load_scene(scene_path("room-2400"), settings=settings_of()).elements
    bi, bj, _ = facing_pairs(tree_of(el))
    f = facing_blocks(el.verts, el.nverts, el.normal, el.center, el.two_sided)
    off = np.concatenate([[0], np.cumsum(rng.integers(1, 30, len(el)))])
    for unit, mtb, mn in (("block", 1 << 10, 0), ("stripe", 1 << 12, 1 << 10), ("stripe", 1 << 26, 1 << 14)):
        a = make_plan(off, f, unit, max_task_bits=mtb, min_task_bits=mn)
        b = make_plan(off, (bi, bj), unit, max_task_bits=mtb, min_task_bits=mn)
        np.testing.assert_array_equal(a.tiles, b.tiles)
        np.testing.assert_array_equal(a.tasks, b.tasks)
        assert (a.chunk, a.total, a.blocks_culled) == (b.chunk, b.total, b.blocks_culled)
        assert a.blocks_culled == len(el) * (len(el) - 1) // 2 - len(bi)


def floor_and_light(n_side: int, rng):
    """2 n_side^2 jittered coplanar floor triangles (facing up) and one light quad above."""
    g = np.stack(np.meshgrid(np.arange(n_side + 1.0), np.arange(n_side + 1.0), indexing="ij"), -1)
    g = g + rng.uniform(-0.3, 0.3, g.shape)
    p = np.zeros((n_side + 1, n_side + 1, 3))
    p[..., 0], p[..., 2] = g[..., 0], g[..., 1]
    a, b, c, d = p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]
    t1 = np.stack([a, c, b, b], -2).reshape(-1, 4, 3)  # (a, c, b): normal +y
    t2 = np.stack([a, d, c, c], -2).reshape(-1, 4, 3)
    s = float(n_side)
    light = np.array([[[0.3 * s, 0.5 * s, 0.3 * s], [0.7 * s, 0.5 * s, 0.3 * s],
                       [0.7 * s, 0.5 * s, 0.7 * s], [0.3 * s, 0.5 * s, 0.7 * s]]])
    v = np.concatenate([t1, t2, light])
    nv = np.concatenate([np.full(len(t1) + len(t2), 3, np.int8), [4]]).astype(np.int8)
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    nrm = np.cross(e1, e2)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    cen = np.where(nv[:, None] == 3, v[:, :3].mean(1), v.mean(1))
    return v, nv, nrm, cen, np.zeros(len(v), bool)


def test_many_originals_plan_in_bounded_memory():
    """80 001 originals: the dense relation would take 80 001^2 x 4 x 8 bytes (191 GiB); the
    hierarchy lists the 80 000 facing pairs within a small, stated bound."""
    import tracemalloc

    v, nv, nrm, c, ts = floor_and_light(200, np.random.default_rng(5))
    n = len(v)
    assert n == 80_001
    tracemalloc.start()
    t = build_tree(v, nv, nrm, c, ts)
    bi, bj, stats = facing_pairs(t, cap=10 ** 6)
    back = behind_any(t)
    est = estimate_facing_pairs(t)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    up = nrm[:-1, 1] > 0  # the jitter folds a few triangles over
    assert len(bi) == up.sum() > 0.99 * (n - 1) and (bj == n - 1).all()  # each against the light
    assert back.sum() == (~up).sum()
    assert est["exact"] and est["estimate"] == len(bi)
    assert peak < 400 * 2 ** 20, f"peak {peak / 2 ** 20:.0f} MiB"  # about 60 bytes per original x 100


def test_a_scene_beyond_the_pair_budget_is_refused_for_pairs_and_clustered_otherwise(tmp_path):
    """Beyond plan.max-facing-pairs the pairs method is refused up front in one line when it is
    stated; with method auto the plan takes the hierarchical method, which clusters the
    originals (SPEC §9) and is not limited by the budget."""
    import dask.config
    from click.testing import CliRunner

    from radiosity.cli.commands import main

    el = load_scene(scene_path("furnace-sphere"), settings=settings_of()).elements  # 320 elements, 51 040 facing pairs
    with pytest.raises(FacingPairsError, match=r"about 5.1e\+04 pairs of its 320 original elements"):
        check_budget(tree_of(el), 10_000, "furnace-sphere")
    with dask.config.set({"radiosity.plan.max-facing-pairs": 10_000}):
        for cmd in (["plan", scene_path("furnace-sphere"), "--method", "pairs"],
                    ["render", scene_path("furnace-sphere"), "--out", str(tmp_path / "r"),
                     "--method", "pairs"]):
            r = CliRunner().invoke(main, cmd)
            assert r.exit_code == 2, r.output
            [line] = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
            assert "radiosity.plan.max-facing-pairs = 10000" in line and "DASK_RADIOSITY__PLAN__" in line
            assert "--method hierarchical" in line
            assert "dashboard" not in r.output and not (tmp_path / "r").exists()
        r = CliRunner().invoke(main, ["plan", scene_path("furnace-sphere")])
        assert r.exit_code == 0, r.output
        assert "method: hierarchical: auto, about 5.1e+04 facing pairs of originals > " \
               "plan.max-facing-pairs 10000 (clustered)" in r.output
