"""Refinement by the solved radiance (hierarchy.rounds, methods/hierarchical/views/rounds.py; issue
26): warm starts of the solvers, the oracle's per-node weights, rounds off unchanged, rounds on
the indirectly lit Cornell box, exact answers kept, and views of a run with rounds."""

from __future__ import annotations

import os

import dask.config
import numpy as np
import pytest

from radiosity.core.solvers import cg, jacobi, progressive
from radiosity.methods.hierarchical.links.master import refine_pairs
from radiosity.runtime.store import RunStore
from helpers import link_power_balance, prepared, radiance, scene_path

from test_hierarchy import in_process  # noqa: E402  (tests/methods/hierarchical on sys.path)
from radiosity.settings import options as settings_of


class _Dense:
    """A reciprocal operator over a dense symmetric F (unit areas): what the solvers see."""

    kernel = "point"

    def __init__(self, F):
        self.F = F
        self.calls = 0

    def apply(self, L, live=None, use_need=True):
        self.calls += 1
        return np.einsum("ab,scb->sca", self.F, L)


def _system(rng, m=12):
    F = rng.uniform(0, 1, (m, m))
    F = (F + F.T) / 2
    np.fill_diagonal(F, 0)
    F /= 1.2 * F.sum(axis=1).max()
    Le = np.zeros((2, 3, m))
    Le[0, :, 0] = 5.0
    rho = np.full((2, 3, m), 0.7)
    return _Dense(F), Le, rho, np.ones(m)


@pytest.mark.parametrize("solver", [cg, jacobi, progressive])
def test_a_warm_start_at_the_answer_converges_at_once_to_the_same_answer(rng, solver):
    op, Le, rho, area = _system(rng)
    cold = solver(op, Le, rho, area, 1e-12, 2000)
    warm = solver(op, Le, rho, area, 1e-10, 2000, x0=cold.radiance)
    assert cold.converged and warm.converged
    assert warm.iterations <= 2 < cold.iterations
    np.testing.assert_allclose(warm.radiance, cold.radiance, rtol=1e-8, atol=1e-12)
    # and from a perturbed start, the same answer
    near = solver(op, Le, rho, area, 1e-12, 2000, x0=cold.radiance * 1.1)
    np.testing.assert_allclose(near.radiance, cold.radiance, rtol=1e-9, atol=1e-12)


def test_per_node_weights_equal_to_the_a_priori_ones_give_the_same_links():
    """The oracle's per-node path (nhat, used by rounds) with each node at its original's
    a-priori weight makes exactly the links of the per-original path (nhat empty: rounds
    off); raising one original's nodes makes more links between it and the others."""
    sc, part, tree, inp = in_process(scene_path("cornell-box-indirect"), res=12)
    from radiosity.tracing.rays import RayCaster

    caster = RayCaster(sc.elements.verts, sc.elements.nverts, 1e-6)
    pairs = np.array([[0, 1], [0, 3], [6, 3], [0, 20], [1, 20]], np.int64)
    a, _, ca = refine_pairs(inp, pairs, caster)
    inp.nhat = np.ascontiguousarray(inp.lhat[tree.orig.astype(np.int64)])
    b, _, cb = refine_pairs(inp, pairs, caster)
    assert len(a) == len(b) and a.tobytes() == b.tobytes() and np.array_equal(ca, cb)
    inp.nhat = inp.nhat.copy()
    inp.nhat[tree.orig == 3] *= 20.0  # a bright piece of ceiling
    c, _, _ = refine_pairs(inp, pairs, caster)
    with3 = lambda l: int(((l["po"] == 3) | (l["qo"] == 3)).sum())  # noqa: E731
    assert with3(c) > with3(a)


def test_forced_nodes_and_source_spreads_split_only_their_own_links():
    """The kernel's two inputs from rounds besides the weights: nodes forced to split (where a
    leaf's row of F passed 1) split while the link's shaft holds occluders, and a source node
    whose solved radiance spreads over it splits while rho F dL is above epsilon. Set on the
    floor, each makes more links with it; the pairs without it keep their links to the byte;
    all zero (no node forced, no spread) is the plain per-node path."""
    sc, part, tree, inp = in_process(scene_path("cornell-box-indirect"), res=12)
    from radiosity.tracing.rays import RayCaster

    caster = RayCaster(sc.elements.verts, sc.elements.nverts, 1e-6)
    pairs = np.array([[0, 3], [6, 3], [0, 20], [7, 20], [0, 6]], np.int64)
    inp.nhat = np.ascontiguousarray(inp.lhat[tree.orig.astype(np.int64)])
    base, _, _ = refine_pairs(inp, pairs, caster)
    inp.nvar = np.zeros_like(inp.nhat)
    inp.force = np.zeros(inp.nhat.shape, np.bool_)
    same, _, _ = refine_pairs(inp, pairs, caster)
    assert same.tobytes() == base.tobytes()
    def split(o):  # the links with original o, and the others' bytes
        return (lambda l: int(((l["po"] == o) | (l["qo"] == o)).sum()),
                lambda l: l[(l["po"] != o) & (l["qo"] != o)].tobytes())

    with0, without0 = split(0)
    inp.force = inp.force.copy()
    inp.force[tree.orig == 0, 0] = True  # the floor's lit side
    forced, _, _ = refine_pairs(inp, pairs, caster)
    assert with0(forced) > with0(base) and without0(forced) == without0(base)
    inp.force[tree.orig == 0, :] = False
    inp.force[tree.orig == 0, 1] = True  # its back sees nothing: nothing changes
    back, _, _ = refine_pairs(inp, pairs, caster)
    assert back.tobytes() == base.tobytes()
    inp.force = np.zeros(inp.nhat.shape, np.bool_)
    inp.nvar = inp.nvar.copy()
    on0 = tree.orig == 0
    inp.nvar[on0, 0] = 50.0 * inp.nhat[on0, 0]
    spread, _, _ = refine_pairs(inp, pairs, caster)
    assert with0(spread) > with0(base) and without0(spread) == without0(base)


def test_a_round_refines_the_links_of_rows_past_one(client, tmp_path):
    """The Cornell box lit only indirectly at 24^2, one round: without row flags
    (rounds-row-excess 1e9) leaves by the lamp, whose coarse links' rays pass the lamp's edge,
    keep rows of F v up to 1.16 (capped at 1 in the solve, which loses light); with them
    (0.03, the default) their nodes are forced to split where a link would be kept with
    occluders in its shaft, and the rows come down (measured: 203 -> 105 leaves past 1.03, the
    largest 1.163 -> 1.065)."""
    got = {}
    for name, ex in (("off", 1e9), ("on", 0.03)):
        out = str(tmp_path / name)
        fig = _render(client, scene_path("cornell-box-indirect"), out, 24, rounds=1,
                      **{"rounds-row-excess": ex})
        rows = RunStore(out).read_arrays("solution")["leaf_rows"]
        got[name] = (fig.report["rounds"]["rounds"][0]["forced_nodes"], rows.max(),
                     int((rows > 1.03).sum()))
    print(got)
    assert got["off"][0] == 0 and got["on"][0] > 0
    assert got["off"][1] > 1.1 and got["on"][1] < 1.09
    assert got["on"][2] < 0.6 * got["off"][2]


def _render(client, path, out, res, **cfg):
    from radiosity.pipeline import render_scene
    from radiosity.scene.load import load_scene

    with dask.config.set({f"radiosity.hierarchy.{k}": v for k, v in cfg.items()}):
        return render_scene(load_scene(path, resolution=res, settings=settings_of()), out, client,
                            settings_of(method="hierarchical"), preview=False, progress=False,
                            echo=lambda *a: None)


def _surface_means(out):
    from radiosity.stages.image import read_exr

    img = read_exr(os.path.join(out, "image.exr")).astype(np.float64).sum(-1)
    orig = RunStore(out).read_arrays("raster")["orig"]
    return {int(e): img[orig == e].mean() for e in np.unique(orig[orig >= 0])}


def test_rounds_off_is_the_plain_solve(client, tmp_path):
    """hierarchy.rounds 0 (the default): solve_with_rounds is run_solve, bit for bit, and the
    report has no rounds."""
    from radiosity.methods.hierarchical.links.master import compute_links
    from radiosity.stages.rounds import solve_with_rounds
    from radiosity.settings import resolve
    from radiosity.stages.solve import run_solve

    out = prepared(client, tmp_path, scene_path("cornell-box-indirect"), 12, visibility=False)
    compute_links(out, client, settings_of(), progress=False)
    run_solve(out, client, settings_of(), progress=False, method="hierarchical")
    a = radiance(out).copy()
    solve_with_rounds(out, client, resolve({"hierarchy.rounds": 0}), progress=False,
                      method="hierarchical")
    assert np.array_equal(a, radiance(out))
    import json

    assert "rounds" not in json.load(open(os.path.join(out, "report.json")))


def test_rounds_auto_runs_one_round_where_the_a_priori_weights_were_wrong(client, tmp_path):
    """hierarchy.rounds auto (the default), at 24^2: on the Cornell box lit only indirectly
    most of the reflected light leaves surfaces over 8 times brighter than the a-priori
    estimate, so one round runs and the summary says why; on the Cornell box almost none does,
    no round runs, and the answer is that of rounds 0 to the bit (the first solve is the
    plain one); a stricter share turns the indirect box's round off."""
    from radiosity.methods.hierarchical.views.rounds import hot_share

    runs = {}
    for name, scene, cfg in (("indirect", "cornell-box-indirect", {}),
                             ("box", "cornell-box", {}), ("box0", "cornell-box", {"rounds": 0}),
                             ("strict", "cornell-box-indirect", {"rounds-auto-share": 0.95})):
        out = str(tmp_path / name)
        runs[name] = (out, _render(client, scene_path(scene), out, 24, **cfg))
    share = {k: hot_share(RunStore(runs[k][0]), "bf", 8.0) for k in ("indirect", "box")}
    assert share["indirect"] > 0.5 and share["box"] < 0.02
    ind = runs["indirect"][1].report["rounds"]
    assert ind["why"].startswith("auto: one round") and ind["rounds"][0]["tasks"] > 0
    assert dict(runs["indirect"][1].rows())["rounds"] == ind["why"]
    box = runs["box"][1].report["rounds"]
    assert box["why"].startswith("auto: none") and box["rounds"] == [] and box["solves"] == 1
    assert np.array_equal(radiance(runs["box"][0]), radiance(runs["box0"][0]))
    strict = runs["strict"][1].report["rounds"]
    assert strict["why"].startswith("auto: none") and strict["solves"] == 1


def test_rounds_bring_the_indirect_box_toward_a_tight_epsilon(client, tmp_path):
    """The Cornell box lit only indirectly at 24^2: against an --epsilon 1e-4 render, epsilon
    5e-4 with the a-priori weights (the default base this was measured with) is off by more
    than 8 % on some surface (the red wall), with two rounds every surface is within 6 % and
    the mean error is lower; the rounds' links are in the store (a solve from scratch on them
    gives the rounds' answer). The emitters' light through the links, as measured then (at
    points, measured 2026-12-07: 8.2 % and 7.1 % worst, the mean 1.19 % and 1.46 %: the
    rounds do not help there yet)."""
    with dask.config.set({"radiosity.direct.mode": "links"}):
        path = scene_path("cornell-box-indirect")
        _render(client, path, str(tmp_path / "ref"), 24, rounds=0, epsilon=1e-4)
        ref = _surface_means(str(tmp_path / "ref"))
        errs = {}
        for name, n in (("default", 0), ("rounds", 2)):
            out = str(tmp_path / name)
            fig = _render(client, path, out, 24, rounds=n, epsilon=5e-4)
            got = _surface_means(out)
            errs[name] = {e: got[e] / ref[e] - 1 for e in ref if ref[e] > 0}
        worst = {k: max(abs(x) for x in v.values()) for k, v in errs.items()}
        mean = {k: np.mean([abs(x) for x in v.values()]) for k, v in errs.items()}
        print(f"worst surface {worst}, mean {mean}")
        assert worst["default"] > 0.08 and worst["rounds"] < 0.06
        # 0.88 (2026-12-05; 0.8 held until rows past one were capped leaf by leaf, which took a
        # part of what the rounds gave the mean)
        assert mean["rounds"] < 0.92 * mean["default"]
        rep = fig.report["rounds"]
        made = [r for r in rep["rounds"] if r["tasks"]]
        assert rep["rounds"][0]["tasks"] > 0 and made[-1]["links"] == fig["links"]["links"]
        # the stored links are the rounds' own: a cold solve on them gives the same answer
        from radiosity.stages.solve import run_solve

        warm = radiance(out).copy()
        run_solve(out, client, settings_of(), progress=False, method="hierarchical", closure=None)
        np.testing.assert_allclose(radiance(out), warm, rtol=2e-3, atol=1e-6)


def test_closed_cube_with_rounds_stays_exact(client, tmp_path):
    """Furnace cube rho 0.99 (closed, rows balanced): the solved radiance is the a-priori
    one (Le / (1 - rho) everywhere), no round refines anything and the answer is 100 within
    0.1 % as without rounds."""
    cube = scene_path("furnace-cube")
    src = open(cube).read().replace("reflectance = [0.5, 0.5, 0.5]",
                                    "reflectance = [0.99, 0.99, 0.99]")
    src = src.replace('path = "furnace-cube.obj"',
                      f'path = "{os.path.join(os.path.dirname(cube), "furnace-cube.obj")}"')
    path = tmp_path / "furnace.toml"
    path.write_text(src)
    fig = _render(client, str(path), str(tmp_path / "run"), 12, rounds=2)
    assert fig.report["rounds"]["rounds"][0]["tasks"] == 0
    np.testing.assert_allclose(radiance(str(tmp_path / "run"))[:, 0, :], 100.0, rtol=1e-3)


def test_push_pull_conserves_energy_after_rounds(client, tmp_path):
    """three-rectangles (open) with the first round's links: emitted = absorbed + escaped, as
    on the stage's own links (test_hierarchy's energy test, on links made in two rounds)."""
    out = str(tmp_path / "run")
    # the emitters' light through the links: their links are what this round refines (with
    # it at points, test_hierarchy's energy test checks the split's balance)
    with dask.config.set({"radiosity.direct.mode": "links"}):
        fig = _render(client, scene_path("three-rectangles"), out, 16, rounds=1,
                      **{"rounds-epsilon": 0.05})
    assert fig.report["rounds"]["rounds"][0]["tasks"] > 0
    emitted, absorbed, escaped = link_power_balance(out)
    # the final gather changes solution/radiance, not the leaves' fixed point L = Le + rho K L
    assert absorbed + escaped == pytest.approx(emitted, rel=1e-5)


def test_image_of_a_run_with_rounds_from_another_camera(client, tmp_path):
    """A run refined by rounds opens for views like any run (radiosity image --position)."""
    import subprocess

    out = str(tmp_path / "run")
    _render(client, scene_path("cornell-box-indirect"), out, 16, rounds=1)
    res = subprocess.run(["radiosity", "image", out, "--position", "278,300,-500", "--look-at",
                          "278,200,0", "--resolution", "24", "--name", "side"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert os.path.getsize(os.path.join(out, "views", "side", "image.png")) > 0


def test_rounds_make_the_same_links_on_one_worker_and_on_two(client, tmp_path):
    """The links a round makes do not depend on the workers: the session's two worker processes
    and one in-process worker thread store the same links, task by task."""
    from distributed import Client, LocalCluster

    from radiosity.methods.hierarchical.store import LinkStore, read_links

    path = scene_path("cornell-box-indirect")
    a = str(tmp_path / "two")
    _render(client, path, a, 16, rounds=1)
    b = str(tmp_path / "one")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=":0") as cl, Client(cl) as one:
        _render(one, path, b, 16, rounds=1)

    def links(out):
        rs = RunStore(out)
        ls = LinkStore(rs)
        done = ls.finished(ls.token())
        return [read_links(rs.path, t, done[t])[0].tobytes() for t in sorted(done)]

    la, lb = links(a), links(b)
    assert len(la) == len(lb) and la == lb
    np.testing.assert_array_equal(radiance(a), radiance(b))
