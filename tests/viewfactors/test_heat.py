"""radiosity heat (issue 53) on view factors computed from meshes: concentric tessellated
spheres against the two-surface formula, isothermal and black enclosures, the conductances'
symmetry and rows, the CLI end to end with a scene TOML, and a network solver reading the
ESATAN conductor list that reproduces the heat flows. The solver on exact matrices:
tests/core/test_netradiation.py."""

from __future__ import annotations

import csv
import dataclasses
import json
import os

import numpy as np
import pytest
import scipy.sparse as sp
from click.testing import CliRunner

from radiosity.cli.commands import main
from radiosity.core.netradiation import SIGMA, network_heat
from radiosity.errors import SceneError
from radiosity.settings import options as settings_of
from radiosity.viewfactors.heat import (ESATAN_SPACE_NODE, compute_heat, read_esatan,
                                        solve_facets)
from radiosity.viewfactors.facets import load_facets
from radiosity.viewfactors.thermal import ThermalDefaults, heat_inputs

from test_viewfactors import box  # noqa: E402


def spheres(k=2):
    """(vertices, faces, n1): an icosphere of radius 0.5 facing out inside one of radius 1
    facing in, k subdivisions each (20 x 4^k triangles); n1 inner facets first."""
    import trimesh

    a = trimesh.creation.icosphere(subdivisions=k, radius=0.5)
    b = trimesh.creation.icosphere(subdivisions=k, radius=1.0)
    V = np.vstack([a.vertices, b.vertices])
    F = np.vstack([a.faces, b.faces[:, ::-1] + len(a.vertices)])
    return V, F, len(a.faces)


@pytest.fixture(scope="module")
def sphere_run(client, tmp_path_factory):
    """The heat run of the concentric spheres (every facet e = 0.5 at 300 K, conductances on)
    and its inner facet count."""
    V, F, n1 = spheres()
    out = str(tmp_path_factory.mktemp("spheres"))
    st = settings_of(conductances="on")
    res = compute_heat((V, F), out, client, st, ThermalDefaults(0.5, 300.0), progress=False)
    return res, n1


def with_inputs(res, **kw):
    return dataclasses.replace(res.inputs, **kw)


def test_concentric_spheres_match_the_two_surface_formula(sphere_run):
    """Inner sphere (e1 = 0.3, 500 K) in the outer (e2 = 0.6, 300 K), 320 + 320 triangles: the
    net heat within 1e-4 of q = sigma A1 (T1^4 - T2^4) / (1/e1 + (A1/A2)(1/e2 - 1)) with the
    facets' own areas (7e-8 measured: the view factors' error and the solver's), within 0.5 %
    asked by the issue; with the spheres' areas the formula differs by the tessellation's own
    error (the polyhedra are 1.9 % smaller than the spheres), said here, not tested against."""
    res, n1 = sphere_run
    n = len(res.area_m2)
    inner = np.arange(n) < n1
    e = np.where(inner, 0.3, 0.6)
    T = np.where(inner, 500.0, 300.0)
    r = solve_facets(res.facets, with_inputs(res, emissivity=e, temperature_K=T),
                     res.viewfactors, res.live, settings_of().heat, covered=res.covered)
    A1, A2 = res.area_m2[inner].sum(), res.area_m2[~inner].sum()
    q = SIGMA * A1 * (500.0 ** 4 - 300.0 ** 4) / (1 / 0.3 + A1 / A2 * (1 / 0.6 - 1))
    Q = r.solution.net_flux * res.area_m2
    assert abs(Q[inner].sum() / q - 1) < 1e-4
    assert abs(Q[~inner].sum() / q + 1) < 1e-4
    assert abs(r.figures.energy_balance_W) < 1e-9 * q
    assert 0.015 < 1 - A1 / (np.pi * 0.5 ** 2 * 4) < 0.025   # the tessellation's own error


def test_isothermal_spheres_of_any_emissivities_have_no_net_flux(sphere_run, rng):
    """Every facet at 300 K with its own emissivity in (0.02, 1]: every net flux 0 within
    1e-9 of sigma T^4; the run's own (e = 0.5) too."""
    res, _ = sphere_run
    n = len(res.area_m2)
    E = SIGMA * 300.0 ** 4
    assert np.abs(res.solution.net_flux).max() < 1e-9 * E
    r = solve_facets(res.facets, with_inputs(res, emissivity=rng.uniform(0.02, 1.0, n)),
                     res.viewfactors, res.live, settings_of(conductances="off").heat,
                     covered=res.covered)
    assert np.abs(r.solution.net_flux).max() < 1e-9 * E
    assert r.conductances is None


def test_black_spheres_net_flux_is_the_view_factor_sum(sphere_run, rng):
    """Every facet black at its own temperature: q_i = sum_j F_ij sigma (T_i^4 - T_j^4)."""
    res, _ = sphere_run
    n = len(res.area_m2)
    T = rng.uniform(250, 600, n)
    r = solve_facets(res.facets, with_inputs(res, emissivity=np.ones(n), temperature_K=T),
                     res.viewfactors, res.live, settings_of(conductances="off").heat,
                     covered=res.covered)
    E = SIGMA * T ** 4
    F = res.viewfactors
    q = np.asarray(F.sum(axis=1)).ravel() * E - F @ E
    assert np.abs(r.solution.net_flux - q).max() < 1e-9 * E.max()


def test_sphere_conductances_are_symmetric_and_rows_are_e_a(sphere_run):
    """GR of the closed spheres: symmetric to 1e-12, each row's sum e_i A_i to 1e-12 (the
    environment's conductances 0), and they give the solve's heat."""
    res, _ = sphere_run
    GR = res.conductances.GR
    n = len(res.area_m2)
    ea = res.inputs.emissivity * res.area_m2
    assert abs(GR - GR.T).max() <= 1e-12 * GR.max()
    rows = np.asarray(GR.sum(axis=1)).ravel()[:n]
    assert np.abs(rows / ea - 1).max() < 1e-12
    assert GR[n].sum() < 1e-12 * ea.sum()
    fig = res.figures["conductances"]
    assert fig["row_sum_relative_error_max"] < 1e-12 and fig["heat_relative_error_max"] < 1e-9


# ----------------------------------------------------------------------------- CLI and inputs

def _open_box_scene(tmp_path, env_K=250.0):
    """A 1 m box of 2 x 2 tiles a face, the top missing (open to an environment at env_K):
    floor 'hot' (e 0.9, 400 K), walls 'wall' (e 0.5, reradiating). Returns the TOML path."""
    V, F = box([0, 0, 0], [1, 1, 1], 2)
    c = V[np.array(F)].mean(axis=1)
    F = [f for f, z in zip(F, c[:, 2]) if z < 1 - 1e-9]           # no lid
    c = V[np.array(F)].mean(axis=1)
    with open(tmp_path / "box.obj", "w") as f:
        for v in V:
            f.write("v " + " ".join(repr(float(x)) for x in v) + "\n")
        for name, sel in (("hot", c[:, 2] < 1e-9), ("wall", c[:, 2] > 1e-9)):
            f.write(f"usemtl {name}\n")
            for face, s in zip(F, sel):
                if s:
                    f.write("f " + " ".join(str(k + 1) for k in face) + "\n")
    toml = tmp_path / "scene.toml"
    toml.write_text('[[mesh]]\npath = "box.obj"\n\n'
                    '[material.hot]\nemissivity = 0.9\ntemperature_K = 400\n\n'
                    '[material.wall]\nemissivity = 0.5\nheat_flux_W_m2 = 0\n\n'
                    f'[environment]\ntemperature_K = {env_K}\n')
    return str(toml)


def _rows(fn):
    with open(fn, newline="") as f:
        return list(csv.DictReader(f))


def test_cli_heat_end_to_end_and_an_esatan_network_reproduces_it(client, tmp_path):
    """radiosity heat on an open box (hot floor, reradiating walls, environment 250 K):
    facets.csv with the issue's columns, energy balance (what leaves the facets reaches the
    environment), per-material sums in report.json; a network solver that reads
    conductances_esatan.txt (GR(a, b) = value; heat GR sigma (T_a^4 - T_b^4)) and solves for the
    reradiating walls' temperatures, with the floor and the environment fixed, reproduces the
    walls' temperatures and the floor's net heat; radiosity.heat gives the same numbers."""
    scene = _open_box_scene(tmp_path)
    out = tmp_path / "run"
    r = CliRunner().invoke(main, ["heat", scene, "--out", str(out), "--scheduler",
                                  client.scheduler.address])
    assert r.exit_code == 0, r.output
    assert "material hot" in r.output and "conductances" in r.output
    rows = _rows(out / "facets.csv")
    assert list(rows[0]) == ["facet", "mesh", "material", "area_m2", "emissivity", "temperature_K",
                             "radiosity_W_m2", "net_heat_flux_W_m2", "net_heat_W",
                             "view_to_environment", "boundary", "covered_fraction"]
    n = len(rows)
    assert n == 20
    hot = np.array([x["material"] == "hot" for x in rows])
    T = np.array([float(x["temperature_K"]) for x in rows])
    Q = np.array([float(x["net_heat_W"]) for x in rows])
    fenv = np.array([float(x["view_to_environment"]) for x in rows])
    assert (T[hot] == 400).all() and (250 < T[~hot]).all() and (T[~hot] < 400).all()
    assert np.abs(Q[~hot]).max() < 1e-9 * Q[hot].sum() and Q[hot].min() > 0
    assert (fenv > 0).all()
    rep = json.load(open(out / "report.json"))["heat"]
    assert rep["materials"]["hot"]["net_heat_W"] == pytest.approx(Q[hot].sum(), rel=1e-12)
    assert rep["environment_absorbed_W"] == pytest.approx(Q.sum(), rel=1e-9)
    assert rep["conductances"]["row_sum_relative_error_max"] < 1e-12
    # the network solver: ESATAN's conductors, nodes a = facet + 1, the environment 99999
    G = np.zeros((n + 1, n + 1))
    for a, b, v in read_esatan(out / "conductances_esatan.txt"):
        ia = n if a == ESATAN_SPACE_NODE else a - 1
        ib = n if b == ESATAN_SPACE_NODE else b - 1
        G[ia, ib] += v
        G[ib, ia] += v
    E = np.append(np.where(hot, SIGMA * 400.0 ** 4, 0.0), SIGMA * 250.0 ** 4)
    free = np.nonzero(~hot)[0]
    K = np.diag(G[free].sum(axis=1)) - G[np.ix_(free, free)]
    E[free] = np.linalg.solve(K, G[free] @ E)
    assert np.abs((E[free] / SIGMA) ** 0.25 / T[free] - 1).max() < 1e-9
    Qnet = (G.sum(axis=1) * E - G @ E)[:n]
    assert np.abs(Qnet[hot] / Q[hot] - 1).max() < 1e-9
    GR = sp.load_npz(out / "conductances.npz")
    assert GR.shape == (n + 1, n + 1)
    assert np.allclose(network_heat(GR, E[:n], E[n]), Qnet, rtol=1e-12, atol=1e-9)
    # the Python API
    import radiosity

    res = radiosity.heat(scene, client=client)
    assert np.allclose(res.table()["net_heat_W"], Q, rtol=1e-9, atol=1e-9)


def test_heat_inputs_materials_meshes_and_options(tmp_path):
    """Each facet's values: [material.NAME] over its [[mesh]] entry over the options, the
    temperature and the flux as one pair; a plain mesh takes the options."""
    scene = _open_box_scene(tmp_path)
    with open(scene, "a") as f:
        f.write('\n[[mesh]]\npath = "box.obj"\nmaterial = "x"\nemissivity = 0.2\n')
    # the second entry's faces are 'hot' and 'wall' again (OBJ usemtl): the materials win
    st = settings_of()
    fac = load_facets(scene, st)
    inp = heat_inputs(scene, fac, ThermalDefaults(heat_flux_W_m2=5.0))
    names = np.array(inp.material_names)[inp.material]
    assert len(fac) == 40 and set(names) == {"hot", "wall"}
    assert (inp.emissivity[names == "hot"] == 0.9).all()
    assert (inp.fixed_t == (names == "hot")).all() and (inp.heat_flux[names == "wall"] == 0).all()
    assert inp.environment_K == 250.0
    # a material with no heat keys takes its [[mesh]] entry's, then the options'
    text = open(scene).read().replace("emissivity = 0.5\nheat_flux_W_m2 = 0\n", "")
    open(scene, "w").write(text)
    inp = heat_inputs(scene, fac, ThermalDefaults(emissivity=0.7, temperature_K=300.0))
    wall = names == "wall"
    assert (inp.emissivity[wall & (fac.source == 0)] == 0.7).all()
    assert (inp.emissivity[wall & (fac.source == 1)] == 0.2).all()
    assert (inp.temperature_K[wall] == 300.0).all()
    obj = str(tmp_path / "box.obj")
    inp = heat_inputs(obj, load_facets(obj, st), ThermalDefaults(0.4, None, 0.0, 3.0))
    assert (inp.emissivity == 0.4).all() and not inp.fixed_t.any() and inp.environment_K == 3.0


@pytest.mark.parametrize("table, needle", [
    ("[material.hot]\nemissivity = 1.5\ntemperature_K = 400\n", "[material.hot] emissivity = 1.5 must be in (0, 1]"),
    ("[material.hot]\nemissivity = 0\ntemperature_K = 400\n", "emissivity = 0 must be in (0, 1]"),
    ("[material.hot]\nemissivity = 0.9\ntemperature_K = 400\nheat_flux_W_m2 = 3\n",
     "[material.hot] temperature_K and heat_flux_W_m2 are both set"),
    ("[material.hot]\nemissivity = 0.9\n", "material 'hot' has neither temperature_K nor heat_flux_W_m2"),
    ("[material.hot]\ntemperature_K = 400\n", "material 'hot' has no emissivity"),
    ("[material.hot]\nemissivity = 0.9\ntemperature_K = -4\n", "[material.hot] temperature_K = -4 is negative"),
    ("[material.hot]\nemissivity = 0.9\ntemperature_K = 'warm'\n", "temperature_K = 'warm' must be a finite number"),
])
def test_bad_thermal_inputs_are_one_line(tmp_path, table, needle):
    """Bad values: exit 2 and one line naming the file, the table and the key, before any
    view factor is computed."""
    scene = _open_box_scene(tmp_path)
    text = open(scene).read()
    text = text.replace("[material.hot]\nemissivity = 0.9\ntemperature_K = 400\n", table)
    open(scene, "w").write(text)
    r = CliRunner().invoke(main, ["heat", scene, "--out", str(tmp_path / "o")])
    assert r.exit_code == 2, r.output
    assert r.output.count("\n") == 1 and needle in r.output and "scene.toml" in r.output, r.output
    assert not (tmp_path / "o").exists()


def test_bad_environment_and_options_are_one_line(tmp_path):
    scene = _open_box_scene(tmp_path, env_K=-1.0)
    r = CliRunner().invoke(main, ["heat", scene, "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "[environment] temperature_K = -1 is negative" in r.output
    obj = str(tmp_path / "box.obj")
    for args, needle in ((["--emissivity", "0.5"], "has neither temperature_K nor"),
                         (["--temperature", "300"], "has no emissivity"),
                         (["--emissivity", "2", "--temperature", "300"], "--emissivity"),
                         (["--emissivity", "0.5", "--heat-flux", "nan"], "--heat-flux (heat_flux_W_m2=) = nan must be a finite number"),
                         (["--emissivity", "0.5", "--temperature", "300", "--heat-flux", "0"],
                          "are both set")):
        r = CliRunner().invoke(main, ["heat", obj, "--out", str(tmp_path / "o"), *args])
        assert r.exit_code == 2 and r.output.count("\n") == 1 and needle in r.output, r.output
    with pytest.raises(SceneError, match="environment_K"):
        heat_inputs(obj, load_facets(obj, settings_of()), ThermalDefaults(0.5, 300.0, None, -3.0))


def test_furnished_room_with_contact_is_isothermal_to_1e_9(client, tmp_path, rng):
    """The built-in furnished room (304 quads modelled with contact: a shelf on the floor,
    table legs under its top): the facets covered by a touching surface take no part, the
    partly covered ones radiate from their uncovered part only (their rows lack what is
    covered; nothing of a closed room sees the environment), so at one temperature every net
    flux is 0 within 1e-9 of sigma T^4 whatever the emissivities, and with other temperatures
    the net heat sums to 0 (a closed room loses nothing)."""
    from helpers import scene_path

    res = compute_heat(scene_path("furnished-room"), str(tmp_path / "room"), client,
                       settings_of(conductances="off"), ThermalDefaults(0.9, 300.0),
                       progress=False)
    t = res.table()
    assert (t["boundary"] == "contact").sum() == 16
    assert (t["covered_fraction"] > 1e-6).sum() >= 4
    assert np.abs(t["view_to_environment"]).max() < 1e-12
    E = SIGMA * 300.0 ** 4
    assert np.abs(t["net_heat_flux_W_m2"]).max() < 1e-9 * E
    n = len(res.area_m2)
    inp = with_inputs(res, emissivity=rng.uniform(0.05, 1.0, n),
                      temperature_K=rng.uniform(280.0, 320.0, n))
    r = solve_facets(res.facets, inp, res.viewfactors, res.live, settings_of(conductances="off").heat,
                     covered=res.covered)
    Q = r.table()["net_heat_W"]
    assert abs(Q.sum()) < 1e-9 * np.abs(Q).sum() and abs(r.figures.environment_absorbed_W) < 1e-9


def test_a_heat_scene_still_renders(tmp_path):
    """The scene loader of renders accepts the heat keys (and ignores them): one scene file
    serves `radiosity render`, `viewfactors` and `heat`."""
    from radiosity.scene.load import load_scene

    scene = _open_box_scene(tmp_path)
    with open(scene, "a") as f:
        f.write('\n[camera]\nposition = [0.5, 0.5, 3.0]\nlook_at = [0.5, 0.5, 0.0]\n'
                'up = [0.0, 1.0, 0.0]\nfov_y = 40.0\nresolution = [8, 8]\n')
    text = open(scene).read().replace("[material.hot]\n", "[material.hot]\nemission = [1, 1, 1]\n")
    open(scene, "w").write(text.replace('path = "box.obj"\n', 'path = "box.obj"\nemissivity = 0.5\n', 1))
    sc = load_scene(scene, settings=settings_of())
    assert len(sc.elements.area) == 20 and sc.elements.emission.max() > 0
