"""The net radiation solver and the Gebhart conductances (core/netradiation.py) on view-factor
matrices whose answers are known exactly: two-node concentric spheres, the textbook
three-surface enclosure with a reradiating surface, black and isothermal enclosures, and a dense
Gebhart solve (np.linalg) for the conductances. The same checks on view factors computed from
meshes: tests/viewfactors/test_heat.py."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from radiosity.core.exact import parallel_rectangles
from radiosity.core.netradiation import (SIGMA, block_cg, conductances, network_heat,
                                         solve_heat)


def closed_enclosure(rng, n, density=0.6):
    """(F CSR, A): a random enclosure whose rows sum to 1 and A F is symmetric, both exactly
    up to rounding (A_i = the row sums of a random symmetric S >= 0, F = S / A)."""
    S = rng.random((n, n)) * (rng.random((n, n)) < density)
    S = np.triu(S, 1)
    S = S + S.T + np.diag(np.full(n, 1e-3))   # no empty row
    A = S.sum(axis=1)
    return sp.csr_matrix(S / A[:, None]), A


def open_enclosure(rng, n):
    """(F, A): as closed_enclosure but every row below 1 (0.5 .. 1): the rest sees the
    environment."""
    F, A = closed_enclosure(rng, n)
    # scale A F by one symmetric factor per pair: keep reciprocity, lose row sums
    S = (sp.diags(A) @ F).toarray()
    d = rng.uniform(0.7, 1.0, n)
    S = S * np.outer(d, d)
    return sp.csr_matrix(S / A[:, None]), A


def dense_gebhart(F, A, e):
    """GR ((n+1) x (n+1), the environment last) by np.linalg: B = (I - F rho)^-1 F E with
    the environment a black column, GR = diag(e A) B."""
    F = F.toarray()
    n = len(A)
    fe = 1 - F.sum(axis=1)
    rho = 1 - e
    M = np.eye(n) - F * rho[None, :]
    B = np.linalg.solve(M, F * e[None, :])
    Benv = np.linalg.solve(M, fe)
    GR = np.zeros((n + 1, n + 1))
    GR[:n, :n] = (e * A)[:, None] * B
    GR[:n, n] = e * A * Benv
    GR[n, :n] = GR[:n, n]
    return GR


def test_two_node_concentric_spheres_match_the_formula():
    """Exact two-node view factors of concentric spheres (F12 = 1, F21 = A1/A2): the net heat
    q = sigma A1 (T1^4 - T2^4) / (1/e1 + (A1/A2)(1/e2 - 1)) to 1e-12, the conductance GR12 =
    q / sigma (T1^4 - T2^4), and the inner sphere reradiating reaches the outer's temperature."""
    for A1, A2, e1, e2 in ((1.0, 4.0, 0.3, 0.6), (2.0, 2.5, 0.05, 0.9), (1.0, 9.0, 1.0, 0.2)):
        F = sp.csr_matrix(np.array([[0, 1.0], [A1 / A2, 1 - A1 / A2]]))
        A, e, T = np.array([A1, A2]), np.array([e1, e2]), np.array([500.0, 300.0])
        live = np.ones(2, bool)
        s = solve_heat(F, A, e, live, SIGMA * T ** 4, np.zeros(2), 0.0, live)
        q = SIGMA * A1 * (T[0] ** 4 - T[1] ** 4) / (1 / e1 + A1 / A2 * (1 / e2 - 1))
        assert s.net_flux * A == pytest.approx([q, -q], rel=1e-12)
        c = conductances(F, A, e, live)
        assert c.GR[0, 1] == pytest.approx(q / (SIGMA * (T[0] ** 4 - T[1] ** 4)), rel=1e-12)
        r = solve_heat(F, A, e, np.array([False, True]), SIGMA * T ** 4, np.zeros(2), 0.0, live)
        assert r.temperature[0] == pytest.approx(T[1], rel=1e-12)
        assert abs(r.net_flux[0]) < 1e-9 * SIGMA * T[1] ** 4


def test_reradiating_surface_between_two_plates_matches_the_three_surface_network():
    """Two directly opposed squares (Howell's F12) closed by their four sides as one
    reradiating surface R: Q1 = (Eb1 - Eb2) / (R1 + 1 / (A1 F12 + 1 / (1/(A1 F1R) +
    1/(A2 F2R))) + R2), R_i = (1 - e_i) / (e_i A_i) (Incropera eq. 13.30), and J_R between
    J1 and J2 as the network divides it; R's net flux 0 and its temperature (E_R = J_R)."""
    a, c = 1.0, 0.5
    F12 = float(parallel_rectangles(a, a, c))
    A1 = A2 = a * a
    AR = 4 * a * c
    F1R = 1 - F12
    FR1 = A1 * F1R / AR
    F = sp.csr_matrix(np.array([[0, F12, F1R], [F12, 0, F1R], [FR1, FR1, 1 - 2 * FR1]]))
    A = np.array([A1, A2, AR])
    e = np.array([0.4, 0.7, 0.5])  # R's emissivity does not matter
    T = np.array([1000.0, 500.0, 0.0])
    fixed = np.array([True, True, False])
    E = SIGMA * T ** 4
    s = solve_heat(F, A, e, fixed, E, np.zeros(3), 0.0, np.ones(3, bool))
    R1, R2 = (1 - e[0]) / (e[0] * A1), (1 - e[1]) / (e[1] * A2)
    Q1 = (E[0] - E[1]) / (R1 + 1 / (A1 * F12 + 1 / (1 / (A1 * F1R) + 1 / (A2 * F1R))) + R2)
    Q = s.net_flux * A
    assert Q[0] == pytest.approx(Q1, rel=1e-12) and Q[1] == pytest.approx(-Q1, rel=1e-12)
    assert abs(Q[2]) < 1e-9 * Q1
    J1, J2 = E[0] - Q1 * R1, E[1] + Q1 * R2
    assert s.radiosity[2] == pytest.approx((J1 + J2) / 2, rel=1e-12)   # equal resistances
    assert s.emissive_power[2] == pytest.approx(s.radiosity[2], rel=1e-12)
    # the same with R's emissivity changed: nothing moves
    s2 = solve_heat(F, A, np.array([0.4, 0.7, 0.05]), fixed, E, np.zeros(3), 0.0, np.ones(3, bool))
    assert s2.net_flux == pytest.approx(s.net_flux, rel=1e-10, abs=1e-9)


def test_black_enclosure_net_flux_is_the_view_factor_sum(rng):
    """Every facet black: q_i = sum_j F_ij sigma (T_i^4 - T_j^4) in a closed enclosure, and
    q_i = E_i - sum_j F_ij E_j - F_i,env E_env in an open one, to 1e-12."""
    n = 40
    T = rng.uniform(200, 900, n)
    E = SIGMA * T ** 4
    F, A = closed_enclosure(rng, n)
    live = np.ones(n, bool)
    s = solve_heat(F, A, np.ones(n), live, E, np.zeros(n), 0.0, live)
    Fd = F.toarray()
    q = (Fd * (E[:, None] - E[None, :])).sum(axis=1)
    assert np.abs(s.net_flux - q).max() < 1e-12 * E.max()
    F, A = open_enclosure(rng, n)
    Fd = F.toarray()
    Eenv = SIGMA * 250.0 ** 4
    s = solve_heat(F, A, np.ones(n), live, E, np.zeros(n), Eenv, live)
    q = E - Fd @ E - (1 - Fd.sum(axis=1)) * Eenv
    assert np.abs(s.net_flux - q).max() < 1e-12 * E.max()
    assert s.env_W == pytest.approx(float((s.net_flux * A).sum()), rel=1e-10)


def test_isothermal_enclosure_of_any_emissivities_has_no_net_flux(rng):
    """A closed enclosure at one temperature, emissivities anywhere in (0, 1] (some black,
    some reradiating): every net flux 0 within 1e-9 of sigma T^4, every radiosity sigma T^4,
    the reradiating facets at T."""
    n = 60
    F, A = closed_enclosure(rng, n)
    e = rng.uniform(0.02, 1.0, n)
    e[:5] = 1.0
    fixed = rng.random(n) < 0.8
    fixed[0] = True
    T = 321.0
    E = np.full(n, SIGMA * T ** 4)
    live = np.ones(n, bool)
    s = solve_heat(F, A, e, fixed, E, np.zeros(n), 0.0, live, tol=1e-12)
    assert np.abs(s.net_flux).max() < 1e-9 * E[0]
    assert np.abs(s.radiosity / E[0] - 1).max() < 1e-9
    assert np.abs(s.temperature / T - 1).max() < 1e-9


def test_conductances_match_a_dense_gebhart_solve_and_reproduce_the_heat(rng):
    """GR from column blocks (3 columns a block, some facets black, an open enclosure with the
    environment node) equals diag(e A) (I - F rho)^-1 F E by np.linalg to 1e-10; it is
    symmetric to 1e-12 (exactly: symmetrised) and each row sums to e_i A_i (environment
    included) to 1e-12; sum_j GR_ij (E_i - E_j) gives the net radiation solve's heat for any
    temperatures, and solving that network for the reradiating facets gives their
    temperatures."""
    n = 25
    F, A = open_enclosure(rng, n)
    e = rng.uniform(0.1, 1.0, n)
    e[[2, 7]] = 1.0
    live = np.ones(n, bool)
    c = conductances(F, A, e, live, block=3, tol=1e-13)
    assert c.blocks == 9
    GR = c.GR.toarray()
    ref = dense_gebhart(F, A, e)
    assert np.abs(GR - ref).max() < 1e-10 * ref.max()
    assert np.abs(GR - GR.T).max() <= 1e-12 * GR.max()
    assert np.abs(GR[:n].sum(axis=1) / (e * A) - 1).max() < 1e-12
    B = c.gebhart(e, A).toarray()
    assert np.abs(B.sum(axis=1) - 1).max() < 1e-12
    # heat flows for given temperatures
    E = SIGMA * rng.uniform(250, 800, n) ** 4
    Eenv = SIGMA * 100.0 ** 4
    s = solve_heat(F, A, e, live, E, np.zeros(n), Eenv, live, tol=1e-13)
    Q = network_heat(c.GR, E, Eenv)
    assert np.abs(Q - s.net_flux * A).max() < 1e-9 * np.abs(s.net_flux * A).max()
    # reradiating facets: the network's own solve for their E
    fixed = rng.random(n) < 0.6
    s = solve_heat(F, A, e, fixed, E, np.zeros(n), Eenv, live, tol=1e-13)
    free = np.nonzero(~fixed)[0]
    G = GR.copy()
    np.fill_diagonal(G, 0)
    Eall = np.append(np.where(fixed, E, 0.0), Eenv)
    # sum_j G_ij (E_i - E_j) = 0 for i free: (sum_j G_ij) E_i - sum_{j free} G_ij E_j = sum_{j fixed} G_ij E_j
    K = np.diag(G[free].sum(axis=1)) - G[np.ix_(free, free)]
    rhs = G[free] @ np.where(np.isin(np.arange(n + 1), free), 0.0, Eall)
    Efree = np.linalg.solve(K, rhs)
    assert np.abs(Efree / s.emissive_power[free] - 1).max() < 1e-9


def test_conductance_cutoff_drops_small_conductors_and_says_how_much(rng):
    """With a cutoff, conductors below cutoff x sqrt(e_i A_i e_j A_j) are gone, the rest
    unchanged, and each row's sum plus what it dropped is e_i A_i."""
    n = 30
    F, A = closed_enclosure(rng, n, density=0.3)
    e = rng.uniform(0.2, 0.9, n)
    live = np.ones(n, bool)
    full = conductances(F, A, e, live, tol=1e-13).GR.toarray()
    cut = 0.05
    c = conductances(F, A, e, live, cutoff=cut, tol=1e-13)
    GR = c.GR.toarray()
    ea = np.append(e * A, 1.0)
    small = full < cut * np.sqrt(np.outer(ea, ea))
    assert small[:n, :n].any() and (GR[small[:n + 1, :n + 1]] == 0).all()
    assert np.allclose(GR[~small], full[~small], rtol=1e-10, atol=0)
    assert c.dropped.max() > 0
    assert np.abs((GR[:n].sum(axis=1) + c.dropped) / (e * A) - 1).max() < 1e-10


def test_block_cg_solves_every_column(rng):
    """block_cg against np.linalg.solve on a random symmetric positive definite system with
    five right-hand sides (one of them zero)."""
    m = 50
    M = rng.random((m, m))
    K = M @ M.T + m * np.eye(m)
    B = rng.random((m, 5))
    B[:, 3] = 0
    X, steps, res = block_cg(lambda P: K @ P, np.diag(K).copy(), B, 1e-13, 500)
    assert res < 1e-12 and steps < 500
    assert np.abs(X - np.linalg.solve(K, B)).max() < 1e-10 * np.abs(X).max()
    assert not X[:, 3].any()


def test_dense_factorisation_gives_the_conjugate_gradients_conductances(rng):
    """The dense Cholesky path (dense_max) and the block conjugate gradients agree to 1e-10 on
    an open enclosure with black facets, in blocks of 4 columns."""
    n = 30
    F, A = open_enclosure(rng, n)
    e = rng.uniform(0.1, 1.0, n)
    e[[0, 9]] = 1.0
    live = np.ones(n, bool)
    cg = conductances(F, A, e, live, block=4, tol=1e-13).GR.toarray()
    d = conductances(F, A, e, live, block=4, tol=1e-13, dense_max=n)
    assert d.steps == 0 and d.residual < 1e-12
    assert np.abs(d.GR.toarray() - cg).max() < 1e-10 * cg.max()
    assert np.abs(d.GR.toarray() - dense_gebhart(F, A, e)).max() < 1e-10 * cg.max()
