"""Calculation grids (issue 52): illuminance at points anywhere, checked against exact answers
(Howell's B-3 and quadrature for an area source in a black room; the furnace, where every point
in mid-air receives pi Le / (1 - rho); the energy balance of a closed room of uniform
reflectance), in both direct-light modes, and the scene keys' errors."""

from __future__ import annotations

import math
import os
import shutil

import numpy as np
import pytest

from helpers import SCENES, scene_path
from radiosity.core.exact import differential_to_rectangle
from radiosity.errors import SceneError
from radiosity.scene.grids import grid_points, parse_grids

CIE = os.path.join(SCENES, "cie171")
EFF = 683.0


def _rect_ff(px, py, c, x0, x1, y0, y1):
    """F from a point (facing up) to the parallel rectangle [x0, x1] x [y0, y1] at height c
    above it: Howell B-3 by superposition of corner rectangles."""
    def g(a, b):
        return np.sign(a) * np.sign(b) * differential_to_rectangle(abs(a), abs(b), c)
    return g(x1 - px, y1 - py) - g(x0 - px, y1 - py) - g(x1 - px, y0 - py) + g(x0 - px, y0 - py)


def _quadrature_ff(p, n, x0, x1, y0, y1, z, k=400):
    """F from point p (unit normal n) to the horizontal rectangle at height z facing down:
    midpoint rule on k x k cells (independent of the contour integral)."""
    t = (np.arange(k) + 0.5) / k
    X, Y = np.meshgrid(x0 + (x1 - x0) * t, y0 + (y1 - y0) * t, indexing="ij")
    d = np.stack([X - p[0], Y - p[1], np.full_like(X, z - p[2])], -1)
    r2 = np.sum(d * d, -1)
    ci = np.clip(d @ n, 0, None) / np.sqrt(r2)
    cj = d[..., 2] / np.sqrt(r2)
    return float(np.sum(ci * cj / (math.pi * r2)) * (x1 - x0) * (y1 - y0) / k ** 2)


# ----------------------------------------------------------------------------- scene keys

def test_grid_points_at_cell_centres_with_the_normal_along_u_cross_v():
    P, N = grid_points({"origin": [0, 0, 1], "u": [2, 0, 0], "v": [0, 1, 0], "spacing": [1, 0.5]})
    assert P.shape == (4, 3)
    assert np.allclose(P, [[0.5, 0.25, 1], [0.5, 0.75, 1], [1.5, 0.25, 1], [1.5, 0.75, 1]])
    assert np.allclose(N, [0, 0, 1])
    P, N = grid_points({"origin": [0, 0, 0], "u": [0, 3, 0], "v": [1, 0, 0], "spacing": 1})
    assert P.shape == (3, 3) and np.allclose(N, [0, 0, -1])


def test_grid_points_from_a_file(tmp_path):
    (tmp_path / "p.csv").write_text("x,y,z,nx,ny,nz\n1,2,3,0,0,2\n4,5,6,1,0,0\n")
    P, N = grid_points({"points": "p.csv"}, str(tmp_path))
    assert np.allclose(P, [[1, 2, 3], [4, 5, 6]]) and np.allclose(N, [[0, 0, 1], [1, 0, 0]])


@pytest.mark.parametrize("table, match", [
    ({"name": "a", "origin": [0, 0, 0], "u": [1, 0, 0], "v": [2, 0, 0], "spacing": 1},
     "'a'.*not parallel"),
    ({"name": "b", "origin": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0]}, "'b'.*missing spacing"),
    ({"name": "c", "origin": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0], "spacing": -1},
     "'c'.*spacing must be a positive"),
    ({"name": "d", "points": "nope.csv"}, "'d'.*cannot read points file"),
    ({"name": "e", "origin": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0], "spacing": 1,
      "height": 1}, "'e'.*unknown key"),
    ({"name": "f", "origin": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0], "spacing": 1,
      "maintenance_factor": 1.5}, "'f'.*maintenance_factor"),
])
def test_bad_grids_are_one_line_naming_the_grid(tmp_path, table, match):
    with pytest.raises(SceneError, match=match):
        parse_grids({"grid": [table]}, str(tmp_path / "scene.toml"))


def test_the_scene_maintenance_factor_is_the_default(tmp_path):
    t = {"origin": [0, 0, 0], "u": [1, 0, 0], "v": [0, 1, 0], "spacing": 1}
    g = parse_grids({"maintenance_factor": 0.8, "grid": [t, {**t, "name": "x",
                                                             "maintenance_factor": 0.5}]},
                    str(tmp_path / "s.toml"))
    assert [x.maintenance_factor for x in g] == [0.8, 0.5]


def _with_grid(tmp_path, scene: str, grid: str) -> str:
    d = tmp_path / "scene"
    shutil.copytree(os.path.dirname(scene_path(scene)), d)
    with open(d / "scene.toml", "a") as f:
        f.write("\n" + grid)
    return str(d)


@pytest.mark.parametrize("origin, match", [([0.2, 0.2, 2.0], "outside the model"),
                                           ([0.2, 0.2, -0.5], "outside the model")])
def test_a_grid_outside_the_model_is_one_line(tmp_path, origin, match):
    from radiosity.scene.load import load_scene
    from radiosity.settings import options

    grid = (f'[[grid]]\nname = "out"\norigin = {origin}\nu = [0.5, 0, 0]\nv = [0, 0.5, 0]\n'
            'spacing = 0.25\n')
    with pytest.raises(SceneError, match=f"grid.*'out'.*{match}"):
        load_scene(_with_grid(tmp_path, "furnace-cube", grid), settings=options(None))


def test_a_grid_inside_a_closed_solid_is_one_line(tmp_path):
    """The furnace cube seen from outside: its faces point inwards, so a point inside a cube
    whose faces point outwards is in a solid. Turn the cube inside out by its orientation."""
    from radiosity.scene.grids import check_grids, parse_grids
    from radiosity.scene.load import load_scene
    from radiosity.settings import options
    from radiosity.tracing.rays import caster_of
    import dataclasses

    sc = load_scene(scene_path("furnace-cube"), settings=options(None))
    el = dataclasses.replace(sc.elements, normal=-sc.elements.normal)  # faces out: a solid
    g = parse_grids({"grid": [{"name": "in", "origin": [0.2, 0.2, 0.5], "u": [0.5, 0, 0],
                               "v": [0, 0.5, 0], "spacing": 0.25}]}, "x.toml")
    with pytest.raises(SceneError, match="'in'.*inside a solid"):
        check_grids(g, el, caster_of(el.verts, el.nverts, 1e-6))
    check_grids(g, sc.elements, caster_of(el.verts, el.nverts, 1e-6))  # inside the room: fine


# ----------------------------------------------------------------------------- exact answers

@pytest.mark.slow
def test_area_source_in_a_black_room_is_exact_at_every_point(tmp_path):
    """CIE 171 5.3-style (scenes/cie171/area-source): black surfaces, so the illuminance is the
    source's direct light alone, at points on the floor (Howell B-3) and on a wall facing the
    room (quadrature): within 1e-4 at every point (the shadow rays see nothing to block)."""
    import radiosity

    r = radiosity.render(os.path.join(CIE, "area-source"), str(tmp_path / "run"), resolution=16)
    f = r.grids["floor"]
    ref = EFF * math.pi * 10 * np.array([_rect_ff(x, y, 3.0, 1.5, 2.5, 1.5, 2.5)
                                         for x, y in zip(f["x"], f["y"])])
    assert np.abs(f["illuminance_lux"] / ref - 1).max() < 1e-4
    assert np.all(f["indirect_lux"] == 0)
    w = r.grids["wall"]
    ref = EFF * math.pi * 10 * np.array([_quadrature_ff((x, y, z), np.array([0, 1.0, 0]), 1.5, 2.5,
                                                        1.5, 2.5, 3.0)
                                         for x, y, z in zip(w["x"], w["y"], w["z"])])
    assert np.abs(w["illuminance_lux"] / ref - 1).max() < 1e-3
    rep = r.report["grids"]["grids"]
    assert {g["name"] for g in rep} == {"floor", "wall"}
    fl = next(g for g in rep if g["name"] == "floor")
    assert fl["min_lux"] == pytest.approx(f["illuminance_lux"].min())
    assert fl["uniformity_u0"] == pytest.approx(f["illuminance_lux"].min()
                                                / f["illuminance_lux"].mean())
    assert os.path.isfile(tmp_path / "run" / "grids" / "floor.png")
    # the tables on the black floor: no NaN, the light that arrives at each element's centre
    e = np.genfromtxt(tmp_path / "run" / "elements.csv", delimiter=",", names=True, dtype=None,
                      encoding="utf-8")
    fl = e[e["material"] == "floor"]
    ref = EFF * math.pi * 10 * np.array([_rect_ff(x, y, 3.0, 1.5, 2.5, 1.5, 2.5)
                                         for x, y in zip(fl["center_x"], fl["center_y"])])
    assert np.abs(fl["illuminance"] / ref - 1).max() < 1e-4
    assert np.all(np.isfinite(e["illuminance"]))
    # `radiosity grid RUN --grid FILE` adds a grid to the solved run, no solve: a work plane
    # at 0.85 m with a maintenance factor, and one clear line for a grid outside the model
    from click.testing import CliRunner

    from radiosity.cli.commands import main

    (tmp_path / "g.toml").write_text('maintenance_factor = 0.8\n[[grid]]\nname = "wp"\n'
                                     'origin = [0.5, 0.5, 0.85]\nu = [3, 0, 0]\nv = [0, 3, 0]\n'
                                     'spacing = [1.0, 0.5]\n')
    res = CliRunner().invoke(main, ["grid", str(tmp_path / "run"), "--grid", str(tmp_path / "g.toml")])
    assert res.exit_code == 0, res.output
    assert "grid wp" in res.output and "MF 0.8" in res.output
    wp = np.genfromtxt(tmp_path / "run" / "grids" / "wp.csv", delimiter=",", names=True)
    assert len(wp) == 18
    ref = 0.8 * EFF * math.pi * 10 * np.array([_rect_ff(x, y, 3.0 - 0.85, 1.5, 2.5, 1.5, 2.5)
                                               for x, y in zip(wp["x"], wp["y"])])
    assert np.abs(wp["illuminance_lux"] / ref - 1).max() < 1e-4
    import json

    rep = json.load(open(tmp_path / "run" / "report.json"))["grids"]["grids"]
    assert [g["name"] for g in rep] == ["floor", "wall", "wp"]
    (tmp_path / "bad.toml").write_text('[[grid]]\nname = "roof"\norigin = [0, 0, 3.5]\n'
                                       'u = [1, 0, 0]\nv = [0, 1, 0]\nspacing = 0.5\n')
    res = CliRunner().invoke(main, ["grid", str(tmp_path / "run"), "--grid",
                                    str(tmp_path / "bad.toml")])
    assert res.exit_code == 2 and "'roof'" in res.output and "outside the model" in res.output
    assert "Traceback" not in res.output


@pytest.mark.slow
@pytest.mark.parametrize("direct", ["links", "points"])
def test_furnace_points_in_mid_air_receive_pi_le_over_one_minus_rho(tmp_path, direct):
    """The furnace (closed cube, rho = 0.5, Le = 1 everywhere: L = 2): a point anywhere inside,
    facing any way, receives pi Le directly and pi (L - Le) indirectly. With links the
    solution carries the first bounce through the links, with points it adds it at leaf
    points: either way the emitters' own light is counted once."""
    import radiosity

    grid = ('[[grid]]\nname = "air"\norigin = [0.1, 0.2, 0.3]\nu = [0.7, 0.1, 0]\n'
            'v = [0, 0.3, 0.5]\nspacing = 0.25\n\n[[grid]]\nname = "floor"\n'
            'origin = [0, 0, 0]\nu = [1, 0, 0]\nv = [0, 1, 0]\nspacing = 0.25\n'
            'maintenance_factor = 0.8\n')
    r = radiosity.render(_with_grid(tmp_path, "furnace-cube", grid), str(tmp_path / "run"),
                         resolution=16, method="hierarchical", direct=direct)
    assert r.report["plan"]["direct"] == direct
    a = r.grids["air"]
    assert np.allclose(a["direct_lux"], EFF * math.pi, rtol=1e-6)
    assert np.allclose(a["indirect_lux"], EFF * math.pi, rtol=0.01)
    f = r.grids["floor"]
    assert np.allclose(f["illuminance_lux"], 0.8 * EFF * 2 * math.pi, rtol=0.01)


def _closed_room_mean_indirect(r, rho):
    """The mean indirect illuminance over the six face grids of a 4 m cube, against the exact
    energy balance rho Phi / (S (1 - rho))."""
    ind = np.concatenate([g["indirect_lux"] for g in r.grids.values()])
    phi = math.pi * 10.0 * 1.0 * EFF
    return float(ind.mean()) / (rho * phi / (96.0 * (1 - rho))) - 1


@pytest.mark.slow
@pytest.mark.parametrize("rho", [0.2, 0.8])
def test_closed_room_interreflection_meets_the_energy_balance(tmp_path, rho):
    """CIE 171 5.8-style (scenes/cie171/interreflection-NN): the light reflected in a closed
    room of uniform reflectance arrives on average at rho Phi / (S (1 - rho)): within 1 %."""
    import radiosity

    r = radiosity.render(os.path.join(CIE, f"interreflection-{round(rho * 100):02d}"),
                         str(tmp_path / "run"), resolution=16)
    assert abs(_closed_room_mean_indirect(r, rho)) < 0.01


# ----------------------------------------------------------------------------- the oracle

def test_the_oracle_weighs_the_arriving_light_when_the_scene_has_grids(tmp_path):
    """hierarchy.receiver auto: arriving with grids (every receiver weighs 1, the sources'
    weights unchanged), reflected without; resolve_params turns bf into arriving."""
    from radiosity.methods.hierarchical.params import oracle_weights, resolve_params
    from radiosity.pipeline import resolve_receiver
    from radiosity.scene.load import load_scene
    from radiosity.settings import options

    sc = load_scene(os.path.join(CIE, "area-source"), settings=options(None))
    el = sc.elements
    wr, lh, lr = oracle_weights(el, "bf")
    wa, la, la_ref = oracle_weights(el, "arriving")
    assert np.all(wr == el.reflectance.max(axis=2)) and np.all(wa == 1)
    assert np.array_equal(lh, la) and lr == la_ref
    s = options(None)
    assert s.hierarchy.receiver == "auto"
    assert resolve_receiver(s, sc).hierarchy.receiver == "arriving"
    bare = load_scene(scene_path("furnace-cube"), settings=s)
    assert resolve_receiver(s, bare).hierarchy.receiver == "reflected"
    assert resolve_params(el, resolve_receiver(s, sc))[1] == "arriving"
    assert resolve_params(el, resolve_receiver(s, bare))[1] == "bf"


@pytest.mark.slow
@pytest.mark.parametrize("case, worst", [("diffuse-reflection", 0.01), ("obstruction", 0.01)])
def test_cie171_cases_within_one_percent_at_every_point(tmp_path, case, worst):
    """CIE 171 5.6-style (one diffuse reflection off the floor onto the ceiling and a wall) and
    5.7-style (an opaque plate between the source and the floor: umbra, penumbra, full light),
    with no options: every point within 1 % of its exact answer (validation/cie171.py), the
    umbra's points 0."""
    import radiosity
    from radiosity.validation import cie171

    r = radiosity.render(os.path.join(CIE, case), str(tmp_path / "run"))
    for name, g in r.grids.items():
        P = np.column_stack([g["x"], g["y"], g["z"]])
        N = np.column_stack([g["nx"], g["ny"], g["nz"]])
        ref = cie171.reference(case, name, P, N)
        lit = ref > 0
        assert np.abs(g["illuminance_lux"][lit] / ref[lit] - 1).max() < worst, name
        assert np.all(g["illuminance_lux"][~lit] == 0), name
    if case == "obstruction":
        assert (~lit).sum() >= 4  # the umbra has grid points


def test_a_grid_through_the_cornell_boxs_blocks_is_one_line(tmp_path):
    """The blocks stand open side down on the floor: a floor grid 1 mm up runs through them."""
    from radiosity.scene.load import load_scene
    from radiosity.settings import options

    grid = ('[[grid]]\nname = "floor"\norigin = [0.0, 1.0, 0.0]\nu = [0.0, 0.0, 559.0]\n'
            'v = [556.0, 0.0, 0.0]\nspacing = 40.0\n')
    with pytest.raises(SceneError, match="'floor'.*inside a solid"):
        load_scene(_with_grid(tmp_path, "cornell-box", grid), settings=options(None))
    above = grid.replace("1.0, 0.0]", "400.0, 0.0]")
    assert len(load_scene(_with_grid(tmp_path / "b", "cornell-box", above),
                          settings=options(None)).grids[0].points) == 14 * 14


@pytest.mark.slow
def test_black_irradiance_from_the_originals_matches_the_sub_elements(tmp_path, monkeypatch):
    """Above BLACK_PAIRS the tables' gather at black sub-elements takes the originals (their
    mean radiance) as sources: on a solved room with a black floor under reflecting walls it
    stays within a few % of the gather from the sub-elements."""
    import radiosity
    from radiosity.runtime.store import RunStore
    from radiosity.settings import options
    from radiosity.stages import grids as G

    d = tmp_path / "scene"
    shutil.copytree(os.path.join(CIE, "diffuse-reflection"), d)
    toml = (d / "scene.toml").read_text().replace("[material.floor]\nreflectance = [0.5, 0.5, 0.5]",
                                                  "[material.walls]\nreflectance = [0.5, 0.5, 0.5]")
    (d / "scene.toml").write_text(toml)
    radiosity.render(str(d), str(tmp_path / "run"), resolution=8)
    rs = RunStore(str(tmp_path / "run"))
    part, el, L = rs.load_partition(), rs.load_elements(), rs.read_arrays("solution")["radiance"]
    fine = G.black_irradiance(part, el, L, options(None))
    monkeypatch.setattr(G, "BLACK_PAIRS", 0)
    coarse = G.black_irradiance(part, el, L, options(None))
    floor = np.flatnonzero(np.asarray(el.material)[part.orig]
                           == list(el.material_names).index("floor"))
    assert np.all(np.isfinite(fine[floor, 0])) and np.all(np.isnan(fine[:, 1]))
    np.testing.assert_allclose(coarse[floor, 0], fine[floor, 0], rtol=0.05)
