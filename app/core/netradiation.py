"""Radiative heat exchange between gray diffuse facets on a sparse view-factor matrix: the net
radiation (radiosity) equations for given temperatures or heat fluxes, and the radiative
conductances GR_ij = e_i A_i B_ij (B: Gebhart's absorption factors, script-F). Pure: arrays in,
arrays out. What is solved and why this form: docs/src/design/heat-method.md.

Units: W, m, K; E = sigma T^4 (W m^-2) is a facet's blackbody emissive power. Facets radiate
from their front side only; the environment is one black node at E_env that receives every
facet's view out of the mesh (1 - its row sum).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Stefan-Boltzmann constant, W m^-2 K^-4 (exact in the SI since 2019, CODATA 2018).
SIGMA = 5.670374419e-8


def environment_view(F, live: np.ndarray) -> np.ndarray:
    """(n,) float64: each live facet's view to the environment, 1 - its row sum of F (CSR,
    n x n), clipped at 0 (a balanced row is 1 within rounding); 0 for a facet that is not live
    (covered by a touching surface: it takes no part)."""
    rows = np.asarray(F.sum(axis=1)).ravel()
    return np.where(live, np.clip(1.0 - rows, 0.0, None), 0.0)


def block_cg(matvec, diag: np.ndarray, B: np.ndarray, tol: float, max_iterations: int,
             X0: np.ndarray | None = None):
    """Jacobi-preconditioned conjugate gradients on a symmetric positive definite system
    K X = B, every column of B (m, b) at once (one sparse product per step serves them all).
    matvec(P (m, b)) -> K P; diag (m,): K's diagonal. A column stops when its residual is at
    most tol x its right-hand side's norm. Returns (X (m, b), steps, the worst relative
    residual b - K X recomputed at the end)."""
    B = np.asarray(B, float)
    X = np.zeros_like(B) if X0 is None else np.array(X0, float)
    if B.size == 0:
        return X, 0, 0.0
    bnorm = np.linalg.norm(B, axis=0)
    bnorm = np.where(bnorm > 0, bnorm, 1.0)
    minv = (1.0 / diag)[:, None]
    R = B - matvec(X)
    Z = R * minv
    P = Z.copy()
    rz = np.einsum("ij,ij->j", R, Z)
    steps = 0
    for steps in range(1, int(max_iterations) + 1):
        active = np.linalg.norm(R, axis=0) > tol * bnorm
        if not active.any():
            steps -= 1
            break
        KP = matvec(P)
        den = np.einsum("ij,ij->j", P, KP)
        alpha = np.where(active & (den > 0), rz / np.where(den > 0, den, 1.0), 0.0)
        X += alpha * P
        R -= alpha * KP
        Z = R * minv
        rz_new = np.einsum("ij,ij->j", R, Z)
        beta = np.where(active & (rz > 0), rz_new / np.where(rz > 0, rz, 1.0), 0.0)
        P = Z + beta * P
        rz = rz_new
    res = float((np.linalg.norm(B - matvec(X), axis=0) / bnorm).max())
    return X, steps, res


def _system(F, area: np.ndarray, rho: np.ndarray, unknown: np.ndarray):
    """The symmetric system of the unknown radiosities: K = diag(A/rho) - (A F)[U, U] over
    the facets U = unknown (rho > 0 there: 1 - e for a fixed temperature, 1 for a fixed flux).
    Returns (S = A F (CSR n x n, symmetric by reciprocity), K (CSR), its diagonal, U's
    indices)."""
    import scipy.sparse as sp

    S = sp.csr_matrix(sp.diags(area) @ F)
    u = np.nonzero(unknown)[0]
    Suu = S[u][:, u]
    K = sp.csr_matrix(sp.diags(area[u] / rho[u]) - Suu)
    return S, K, K.diagonal(), u


@dataclass(frozen=True)
class HeatSolution:
    """The net radiation solution, per facet (n,) float64 (W, m, K):
    radiosity J and irradiation H (W m^-2: leaving, arriving), net flux q = J - H (W m^-2,
    positive leaving), emissive power E = sigma T^4 (W m^-2; given for a fixed temperature,
    solved for a fixed flux), environment view (1 - row sum); the environment's absorbed power
    env_W (W, = sum A q); steps and residual of the solve."""

    radiosity: np.ndarray
    irradiation: np.ndarray
    net_flux: np.ndarray
    emissive_power: np.ndarray
    environment_view: np.ndarray
    env_W: float
    steps: int
    residual: float

    @property
    def temperature(self) -> np.ndarray:
        """(n,) K: (E / sigma)^(1/4)."""
        return (np.clip(self.emissive_power, 0.0, None) / SIGMA) ** 0.25


def solve_heat(F, area: np.ndarray, emissivity: np.ndarray, fixed_t: np.ndarray,
               emissive_power: np.ndarray, flux: np.ndarray, env_power: float,
               live: np.ndarray, tol: float = 1e-12, max_iterations: int = 10000) -> HeatSolution:
    """Net radiation between facets: F (CSR n x n, A F symmetric, rows <= 1), area (n,) m^2,
    emissivity (n,) in (0, 1], fixed_t (n,) bool (else the flux is fixed), emissive_power (n,)
    sigma T^4 of the fixed-temperature facets, flux (n,) W m^-2 of the fixed-flux ones (0:
    reradiating), env_power sigma T_env^4, live (n,) bool (False: covered, takes no part).

    Solves J_i = e_i E_i + (1 - e_i) H_i (fixed T) or J_i - H_i = q_i (fixed q), with
    H_i = sum_j F_ij J_j + F_i,env E_env, multiplied by A_i / rho_i so that the system is
    symmetric (reciprocity) and positive definite: conjugate gradients. Black fixed-T facets
    are known (J = E) and move to the right-hand side."""
    n = len(area)
    e = np.asarray(emissivity, float)
    fixed_t = np.asarray(fixed_t, bool)
    live = np.asarray(live, bool)
    fe = environment_view(F, live)
    rho = np.where(fixed_t, 1.0 - e, 1.0)
    known = live & (rho <= 0)
    unknown = live & ~known
    S, K, kd, u = _system(F, area, rho, unknown)
    J = np.zeros(n)
    J[known] = emissive_power[known]
    src = np.where(fixed_t, e * emissive_power / np.where(rho > 0, rho, 1.0), flux)
    b = area[u] * (src[u] + fe[u] * env_power) + (S @ J)[u]
    x, steps, res = block_cg(lambda P: K @ P, kd, b[:, None], tol, max_iterations,
                             X0=np.where(fixed_t, emissive_power, env_power)[u][:, None])
    J[u] = x[:, 0]
    H = np.where(live, F @ J + fe * env_power, 0.0)
    q = np.where(live, J - H, 0.0)
    # a fixed flux's temperature: J = e E + (1 - e) H, i.e. E = J + q (1 - e) / e
    E = np.where(fixed_t, emissive_power, np.where(live, J + flux * (1.0 - e) / e, 0.0))
    env_W = float(np.sum(area * fe * (J - env_power)))
    return HeatSolution(J, H, q, E, fe, env_W, steps, res)


@dataclass(frozen=True)
class Conductances:
    """GR: CSR (n + 1, n + 1) float64 m^2, symmetric, the last row and column the environment
    node; GR_ij = e_i A_i B_ij (B_ij: the fraction of facet i's emission absorbed by j after
    any number of diffuse reflections); the net heat i -> j is GR_ij sigma (T_i^4 - T_j^4).
    Conductors below cutoff x sqrt(e_i A_i e_j A_j) are dropped: dropped (n,) m^2 is what each
    facet's row lost (its row sum is e_i A_i less that, within the solve's residual).
    steps: conjugate-gradient steps summed over the column blocks; residual: the worst."""

    GR: object
    dropped: np.ndarray
    blocks: int
    steps: int
    residual: float

    def gebhart(self, emissivity: np.ndarray, area: np.ndarray):
        """B (CSR n x (n + 1)): GR's facet rows divided by e_i A_i (the environment last)."""
        import scipy.sparse as sp

        n = len(area)
        ea = np.asarray(emissivity, float) * np.asarray(area, float)
        return sp.csr_matrix(sp.diags(np.where(ea > 0, 1.0 / np.where(ea > 0, ea, 1.0), 0.0))
                             @ self.GR[:n])


def conductances(F, area: np.ndarray, emissivity: np.ndarray, live: np.ndarray,
                 cutoff: float = 0.0, block: int = 256, tol: float = 1e-12,
                 max_iterations: int = 10000, dense_max: int = 0) -> Conductances:
    """The radiative conductances of facets F (CSR n x n), area (n,) m^2, emissivity (n,),
    live (n,) bool, every live facet a temperature node: column j of GR is what each facet
    absorbs when facet j alone emits with E_j = 1 (the net radiation system with every other
    E = 0, solved for `block` columns at a time: memory about 6 x n x block float64, never
    n x n). GR is symmetrised (A_i e_i B_ij = A_j e_j B_ji holds to the solve's residual).
    With at most dense_max unknown radiosities the system is factored once (dense Cholesky,
    8 x m^2 bytes) instead of conjugate gradients per block."""
    import scipy.sparse as sp

    n = len(area)
    e = np.asarray(emissivity, float)
    live = np.asarray(live, bool)
    fe = environment_view(F, live)
    rho = 1.0 - e
    black = live & (rho <= 0)
    unknown = live & ~black
    S, K, kd, u = _system(F, area, rho, unknown)
    pos = np.full(n, -1, np.int64)
    pos[u] = np.arange(len(u))
    ea = e * area
    afe = area * fe
    cols = np.nonzero(live)[0]
    block = max(1, int(block))
    rows_, cols_, vals = [], [], []
    dropped = np.zeros(n)
    steps_total, worst, blocks = 0, 0.0, 0
    Sc = sp.csc_matrix(S)
    solve = lambda R: block_cg(lambda P: K @ P, kd, R, tol, max_iterations)  # noqa: E731
    if 0 < len(u) <= dense_max:
        from scipy.linalg import LinAlgError, cho_factor, cho_solve

        try:
            cf = cho_factor(K.toarray(), lower=False, check_finite=False)
        except LinAlgError:  # not positive definite: conjugate gradients say how far they get
            cf = None
        if cf is not None:
            def solve(R):
                X = cho_solve(cf, R, check_finite=False)
                bn = np.linalg.norm(R, axis=0)
                res = np.linalg.norm(K @ X - R, axis=0) / np.where(bn > 0, bn, 1.0)
                return X, 0, float(res.max(initial=0.0))
    for start in range(0, len(cols), block):
        c = cols[start:start + block]
        b = len(c)
        R = np.zeros((len(u), b))
        inu = pos[c] >= 0
        R[pos[c[inu]], np.nonzero(inu)[0]] = ea[c[inu]] / rho[c[inu]]
        for k in np.nonzero(~inu)[0]:  # a black emitter: its J = 1 is known
            col = Sc[:, c[k]].toarray().ravel()
            R[:, k] = col[u]
        X, steps, res = solve(R)
        steps_total += steps
        worst = max(worst, res)
        blocks += 1
        Jf = np.zeros((n, b))
        Jf[u] = X
        Jf[c[~inu], np.nonzero(~inu)[0]] = 1.0
        G = e[:, None] * (S @ Jf)      # absorbed by each facet
        genv = afe @ Jf                 # absorbed by the environment
        if cutoff > 0:
            small = G < cutoff * np.sqrt(ea[:, None] * ea[c][None, :])
            dropped[c] += np.where(small, G, 0.0).sum(axis=0)
            G = np.where(small, 0.0, G)
            small_env = genv < cutoff * ea[c]
            dropped[c] += np.where(small_env, genv, 0.0)
            genv = np.where(small_env, 0.0, genv)
        i, k = np.nonzero(G)
        rows_ += [i, np.full(b, n), c]          # the environment's row and column: GR_j,env
        cols_ += [c[k], c, np.full(b, n)]
        vals += [G[i, k], genv, genv]
    if rows_:
        GR = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows_), np.concatenate(cols_))),
                           shape=(n + 1, n + 1))
    else:
        GR = sp.csr_matrix((n + 1, n + 1))
    GR = sp.csr_matrix(0.5 * (GR + GR.T))
    GR.eliminate_zeros()
    GR.sort_indices()
    return Conductances(GR, dropped, blocks, steps_total, worst)


def network_heat(GR, emissive_power: np.ndarray, env_power: float) -> np.ndarray:
    """(n,) W: each facet's net radiated heat from the conductances GR ((n+1) x (n+1), the
    environment last) and the emissive powers E = sigma T^4 (n,): sum_j GR_ij (E_i - E_j)."""
    E = np.append(np.asarray(emissive_power, float), env_power)
    Q = np.asarray(GR.sum(axis=1)).ravel() * E - GR @ E
    return Q[:-1]
