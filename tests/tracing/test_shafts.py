"""The occluder tree finds exactly the shaft candidates the linear scan finds (the same ids in
the same order, less the occluders whose plane holds both polygons on one closed side, which
no segment between them crosses), on a scene of large quads and on a terrain of many small
triangles."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from helpers import ROOT, scene_path
from radiosity.settings import options as settings_of


@pytest.mark.parametrize("which", ["cornell-box", "terrain"])
def test_tree_candidates_equal_the_linear_scan(tmp_path, which, rng):
    from radiosity.methods.hierarchical.links.master import occluder_tree
    from radiosity.scene.load import load_scene
    from radiosity.tracing.shafts import (block_candidates, occluders, same_side_polys,
                                          tree_candidates)

    if which == "terrain":
        sys.path.insert(0, f"{ROOT}/benchmarks")
        import scenes_generated

        path = scenes_generated.terrain(str(tmp_path / "t"), 3000, 8)
    else:
        path = scene_path(which)
    el = load_scene(path, settings=settings_of()).elements
    elo, ehi, en, eo, pad = occluders(el)
    tree = occluder_tree(el, elo, ehi)
    n = len(el)
    V, nv = el.verts, el.nverts.astype(np.int64)
    dropped = 0
    for _ in range(300):
        a, b = rng.integers(0, n, 2)
        A = np.stack([el.verts[a].min(0), el.verts[a].max(0)])
        B = np.stack([el.verts[b].min(0), el.verts[b].max(0)])
        box = block_candidates(A, B, elo, ehi, en, eo, pad, a, b)
        poly = np.array([not same_side_polys(V, a, nv[a], b, nv[b], en, eo, o, pad) for o in box],
                        bool)
        got = tree_candidates(A, B, V, a, nv[a], b, nv[b], tree, elo, ehi, en, eo, pad, a, b, 0)
        assert np.array_equal(got, box[poly])
        for o in box[~poly]:  # no segment between the two polygons crosses a dropped one
            dropped += 1
            x, y = _points(V, nv, a, rng), _points(V, nv, b, rng)
            assert not _crosses(x, y, V, nv, o).any(), (a, b, o)
        few = tree_candidates(A, B, V, a, nv[a], b, nv[b], tree, elo, ehi, en, eo, pad, a, b, 4)
        assert len(few) == min(len(got), 5) and np.isin(few, got).all()
    assert dropped > 0  # coplanar neighbours of tilted triangles: their boxes straddle


@pytest.mark.parametrize("which", ["cornell-box", "terrain"])
def test_the_tight_shaft_drops_only_occluders_no_segment_crosses(tmp_path, which, rng):
    """The polygons' tight shaft (hull_axes, outside_hull) drops, of the boxes' shaft
    candidates, only occluders that no segment between the two polygons crosses, and drops
    some (it is tighter); first_in_hull finds one of the rest, or -1 exactly when none is left,
    or -2 when its budget of tree nodes runs out."""
    from radiosity.methods.hierarchical.links.master import occluder_tree
    from radiosity.scene.load import load_scene
    from radiosity.tracing.shafts import (HULL_AXES, first_in_hull, hull_axes, occluders,
                                          outside_hull, tree_candidates)

    if which == "terrain":
        sys.path.insert(0, f"{ROOT}/benchmarks")
        import scenes_generated

        path = scenes_generated.terrain(str(tmp_path / "t"), 3000, 8)
    else:
        path = scene_path(which)
    el = load_scene(path, settings=settings_of()).elements
    elo, ehi, en, eo, pad = occluders(el)
    tree = occluder_tree(el, elo, ehi)
    V, nv = el.verts, el.nverts.astype(np.int64)
    axes, lo, hi = np.empty((HULL_AXES, 3)), np.empty(HULL_AXES), np.empty(HULL_AXES)
    stack = np.empty(256, np.int64)
    dropped = kept = 0
    for _ in range(300 if which == "terrain" else 2000):
        a, b = rng.integers(0, len(el), 2)
        if a == b:
            continue
        A = np.stack([V[a, :nv[a]].min(0), V[a, :nv[a]].max(0)])
        B = np.stack([V[b, :nv[b]].min(0), V[b, :nv[b]].max(0)])
        got = tree_candidates(A, B, V, a, nv[a], b, nv[b], tree, elo, ehi, en, eo, pad, a, b, 0)
        m = hull_axes(V, a, nv[a], b, nv[b], axes, lo, hi, True)
        out = np.array([outside_hull(V, nv, o, axes, lo, hi, m, pad) for o in got], bool)
        x, y = _points(V, nv, a, rng, 256), _points(V, nv, b, rng, 256)
        for o in got[out]:
            dropped += 1
            assert not _crosses(x, y, V, nv, o).any(), (a, b, o)
        kept += int((~out).sum())
        first = first_in_hull(A, B, V, a, nv[a], b, nv[b], tree, elo, ehi, V, nv, en, eo, pad,
                              a, b, axes, lo, hi, m, 10 ** 9, stack)
        assert (first == -1) == (not (~out).any()) and (first < 0 or first in got[~out])
        if len(tree.left) > 1:
            assert first_in_hull(A, B, V, a, nv[a], b, nv[b], tree, elo, ehi, V, nv, en, eo,
                                 pad, a, b, axes, lo, hi, m, 1, stack) in (-2, -1)
    assert dropped > 0 and kept > 0


def _points(V, nv, i, rng, k=64):
    """k random points inside polygon i (a fan of triangles)."""
    t = rng.integers(0, nv[i] - 2, k)
    u, v = rng.random(k), rng.random(k)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    p0, p1, p2 = V[i, 0], V[i, 1 + t], V[i, 2 + t]
    return p0 + u[:, None] * (p1 - p0) + v[:, None] * (p2 - p0)


def _crosses(x, y, V, nv, o):
    """Which segments x[k] - y[k] pass through polygon o's interior (Moeller-Trumbore on its
    fan, ends excluded)."""
    hit = np.zeros(len(x), bool)
    d = y - x
    for t in range(nv[o] - 2):
        p0, e1, e2 = V[o, 0], V[o, 1 + t] - V[o, 0], V[o, 2 + t] - V[o, 0]
        h = np.cross(d, e2)
        det = h @ e1
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = x - p0
        u = inv * np.einsum("kc,kc->k", s, h)
        q = np.cross(s, e1)
        v = inv * np.einsum("kc,kc->k", d, q)
        w = inv * (q @ e2)
        hit |= ok & (u > 1e-9) & (v > 1e-9) & (u + v < 1 - 1e-9) & (w > 1e-9) & (w < 1 - 1e-9)
    return hit


def test_crossing_check_sees_a_crossing():
    """The check above can fail: segments through a triangle's middle cross it, beside it not."""
    V = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0]]])
    x = np.array([[0.2, 0.2, 1.0], [2.0, 2.0, 1.0]])
    y = np.array([[0.2, 0.2, -1.0], [2.0, 2.0, -1.0]])
    assert _crosses(x, y, V, np.array([3]), 0).tolist() == [True, False]
