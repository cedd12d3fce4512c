"""Solvers of the radiosity equation L = Le + rho (F L) (SPEC §2, §6), pure iterations over an
`Operator` (operator.py): they never see a cluster, a store or the configuration.

Design notes and measurements: docs/src/design/core-solvers.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.core.kernels import get_kernel


@dataclass
class SolveResult:
    radiance: np.ndarray           # (2, 3, m) float64
    iterations: int
    residuals: list = field(default_factory=list)   # relative residual (or bound) per pass
    converged: bool = False
    ambient: np.ndarray | None = None   # (3,) progressive refinement's ambient term (last pass)


def anorm(x: np.ndarray, area: np.ndarray) -> float:
    """Area-weighted 2-norm of a (2, 3, m) vector."""
    return float(np.sqrt(np.sum(area * x * x)))


# ----------------------------------------------------------------------------- solvers

def _fixed_point(step, Le, area, tol, max_iter, callback, x0=None) -> SolveResult:
    """Iterate L <- step(L) from L = Le (or the warm start x0) until the update is at most
    tol ||Le||_A."""
    L = Le.copy() if x0 is None else np.array(x0, dtype=float)
    nb = anorm(Le, area) or 1.0
    res = []
    for k in range(1, max_iter + 1):
        new = step(L)
        res.append(anorm(new - L, area) / nb)
        L = new
        if callback:
            callback(k, res[-1], L)
        if res[-1] <= tol:
            return SolveResult(L, k, res, True)
    return SolveResult(L, max_iter, res, False)


def jacobi(op, Le, rho, area, tol, max_iter, callback=None, x0=None) -> SolveResult:
    """The seed's iteration of eq. 4: L <- Le + rho F L. Its update is the residual of the
    previous iterate, Le + rho F L - L. x0: a warm start (None: Le)."""
    return _fixed_point(lambda L: Le + rho * op.apply(L), Le, area, tol, max_iter, callback, x0)


def gauss_seidel(op, Le, rho, area, tol, max_iter, callback=None, x0=None) -> SolveResult:
    """Block Gauss-Seidel by original element (rows in order, latest values), one Dask task per
    sweep. Stops on the size of the last update, a bound on the residual's decrease. x0: a
    warm start (None: Le)."""
    return _fixed_point(lambda L: op.gs_sweep(L, Le, rho), Le, area, tol, max_iter, callback,
                        x0)


def progressive(op, Le, rho, area, tol, max_iter, callback=None,
                shoot_fraction: float = 0.25, x0=None) -> SolveResult:
    """Progressive refinement (2nd seed; Cohen et al. 1988): shoot the unshot radiance of the
    sub-elements with the largest unshot power A dL (all within `shoot-fraction` of the largest
    shoot together, one pass). The ambient term (unshot power spread uniformly and reflected
    with the mean reflectance) makes early previews plausible; it is not added to the answer.
    Stops when the unshot radiance ||dL||_A <= tol ||Le||_A. x0: a warm start; what it has
    not shot yet is its residual r = Le + rho F x0 - x0 (one pass), and L starts at x0 + r."""
    if x0 is None:
        L = Le.copy()
        dL = Le.copy()
    else:
        dL = Le + rho * op.apply(x0) - x0  # L includes what it has not shot, as from Le
        L = x0 + dL
    nb = anorm(Le, area) or 1.0
    total_area = area.sum()
    nch = Le.shape[1]
    rho_mean = np.array([(area * rho[0, c]).sum() / total_area for c in range(nch)])
    res = []
    ambient = np.zeros(nch)
    for k in range(1, max_iter + 1):
        power = area * np.abs(dL).sum(axis=(0, 1))
        top = power.max(initial=0.0)
        if top <= 0:
            return SolveResult(L, k - 1, res, True, ambient=ambient)
        shoot = power >= shoot_fraction * top
        x = np.where(shoot, dL, 0.0)
        y = op.apply(x, live=shoot)
        recv = rho * y
        L += recv
        dL = np.where(shoot, 0.0, dL) + recv
        res.append(anorm(dL, area) / nb)
        unshot = np.array([(area * dL[:, c]).sum() for c in range(nch)]) / total_area
        ambient = unshot / np.maximum(1.0 - rho_mean, 1e-12)
        if callback:
            callback(k, res[-1], L + rho * ambient[None, :, None])
        if res[-1] <= tol:
            return SolveResult(L, k, res, True, ambient=ambient)
    return SolveResult(L, max_iter, res, False, ambient=ambient)


def cg(op, Le, rho, area, tol, max_iter, callback=None, x0=None) -> SolveResult:
    """Conjugate gradients on the symmetric form (SPEC §6): with D = diag(A / rho),
    D (I - rho F) = D - diag(A) F is symmetric by reciprocity (A_a F_ab = A_b F_ba), and positive
    definite when rho < 1 and row sums <= 1. D itself is the preconditioner (it is the diagonal,
    F_aa = 0), which removes the spread of element areas from the conditioning. Entries with
    rho = 0 are known (L = Le) and move to the right-hand side. One product per iteration; the
    three channels are three systems solved in the same passes. x0: a warm start (None: Le;
    its entries with rho = 0 are Le whatever x0 says)."""
    if not get_kernel(op.kernel).reciprocal:
        raise RadiosityError(f"the cg solver needs a reciprocal kernel (A_a F_ab = A_b F_ba); "
                             f"'{op.kernel}' is not: use --kernel point, or --solver jacobi, "
                             "gauss-seidel or progressive")
    U = rho > 0
    D = np.where(U, area / np.where(U, rho, 1.0), 0.0)
    Dinv = np.where(U, rho / np.where(U, area, 1.0), 0.0)
    known = np.where(U, 0.0, Le)
    b = np.where(U, D * Le + area * op.apply(known), 0.0)

    def M(x):
        return np.where(U, D * x - area * op.apply(x), 0.0)

    def dot(u, v):  # per channel
        return (u * v).sum(axis=(0, 2))

    x = np.where(U, Le if x0 is None else x0, 0.0)
    r = b - M(x)
    z = Dinv * r
    p = z.copy()
    rz = dot(r, z)
    nb = anorm(Le, area) or 1.0
    res = []
    for k in range(1, max_iter + 1):
        Mp = M(p)
        pMp = dot(p, Mp)
        alpha = np.where(pMp > 0, rz / np.where(pMp > 0, pMp, 1.0), 0.0)
        x = x + alpha[None, :, None] * p
        r = r - alpha[None, :, None] * Mp
        z = Dinv * r  # also the true residual Le + rho F L - L on U
        res.append(anorm(z, area) / nb)
        L = x + known
        if callback:
            callback(k, res[-1], L)
        if res[-1] <= tol:
            return SolveResult(L, k, res, True)
        rz_new = dot(r, z)
        beta = np.where(rz > 0, rz_new / np.where(rz > 0, rz, 1.0), 0.0)
        p = z + beta[None, :, None] * p
        rz = rz_new
    return SolveResult(x + known, max_iter, res, False)


SOLVERS = {"jacobi": jacobi, "gauss-seidel": gauss_seidel, "progressive": progressive, "cg": cg}


def choose_solver(name: str, kernel: str) -> str:
    """The solver to run: `name`, or for "auto" CG when the kernel is reciprocal (symmetric
    form, fewest passes) and Gauss-Seidel otherwise."""
    if name == "auto":
        return "cg" if get_kernel(kernel).reciprocal else "gauss-seidel"
    get_solver(name)
    return name


def get_solver(name: str):
    try:
        return SOLVERS[name]
    except KeyError:
        raise RadiosityError(f"unknown solver {name!r}: use one of {', '.join(SOLVERS)}") from None
