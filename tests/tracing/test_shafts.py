"""The occluder tree finds exactly the shaft candidates the linear scan finds (the same ids in
the same order), on a scene of large quads and on a terrain of many small triangles."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from helpers import ROOT, scene_path


@pytest.mark.parametrize("which", ["cornell-box", "terrain"])
def test_tree_candidates_equal_the_linear_scan(tmp_path, which, rng):
    from radiosity.methods.hierarchical.links import occluder_tree
    from radiosity.scene.load import load_scene
    from radiosity.tracing.shafts import block_candidates, occluders, tree_candidates

    if which == "terrain":
        sys.path.insert(0, f"{ROOT}/benchmarks")
        import scenes_generated

        path = scenes_generated.terrain(str(tmp_path / "t"), 3000, 8)
    else:
        path = scene_path(which)
    el = load_scene(path).elements
    elo, ehi, en, eo, pad = occluders(el)
    tree = occluder_tree(el, elo, ehi)
    n = len(el)
    for _ in range(300):
        a, b = rng.integers(0, n, 2)
        A = np.stack([el.verts[a].min(0), el.verts[a].max(0)])
        B = np.stack([el.verts[b].min(0), el.verts[b].max(0)])
        want = block_candidates(A, B, elo, ehi, en, eo, pad, a, b)
        got = tree_candidates(A, B, tree, elo, ehi, en, eo, pad, a, b)
        assert np.array_equal(got, want)
