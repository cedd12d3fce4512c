"""Row balancing: the one symmetric scaling that makes rows of a reciprocal form-factor matrix
sum to their targets (the render's solve, stages/solve.normalise_rows, and the view factors,
viewfactors/outputs.py, both call `balance_rows`), and the targets a closure decision asks of
the rows (`RowTargets`). Pure numpy.

The scaling K -> D K D (F_ij <- d_i F_ij d_j) keeps reciprocity (A_i F_ij = A_j F_ji) and the
sparsity pattern; d comes from the symmetric iteration d <- sqrt(d t / (F d)) (Knight 2008).
Why, and its bounds: docs/src/design/scene-closure.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BALANCE_MIN = 0.5  # rows below this fraction of their target are capped, not balanced
D_MAX = 4.0        # the balancing scales a row by at most this factor either way


@dataclass(frozen=True)
class RowTargets:
    """What the closure decision asks of the rows of the unknowns (m,): target, the row sum
    over the sides that transport (closure.Closure.target summed); balance, rows that may be
    balanced to it (every side's target exact); dead, unknowns whose every
    transporting side is a contact side (their rows and columns are zeroed); sided, the
    two-sided flags with contact backs made one-sided."""

    target: np.ndarray
    balance: np.ndarray
    dead: np.ndarray
    sided: np.ndarray

    @classmethod
    def of(cls, closure, orig: np.ndarray, sided: np.ndarray) -> "RowTargets | None":
        """The targets of unknowns on the original elements `orig` (m,) of a
        scene/closure.Closure; sided (m,) their two-sided flags. None without contact sides
        decided (no closure)."""
        if closure is None or closure.contact is None:
            return None
        c = closure.contact[orig]
        sided = np.asarray(sided, bool) & ~c[:, 1]
        dead = c[:, 0] & ~sided
        if closure.target is None:  # stated: every row's target is 1
            return cls(np.ones(len(orig)), np.full(len(orig), bool(closure.closed)) & ~dead,
                       dead, sided)
        t, x = closure.target[orig], closure.exact[orig]
        target = t[:, 0] + np.where(sided, t[:, 1], 0.0)
        # (used in the closed mode only: auto chooses it for a closed scene; a stated
        # normalise-rows=closed on an open one balances the sides that see no way out)
        balance = x[:, 0] & (~sided | x[:, 1]) & ~dead & (target > 0)
        return cls(target, balance, dead, sided)

    @classmethod
    def burying(cls, targets: "RowTargets | None", buried: np.ndarray,
                sided: np.ndarray) -> "RowTargets":
        """`targets` with the unknowns `buried` (M,) dead as well: sub-elements inside a solid
        (the methods' Opened.state["live"] at 0) take no part, as contact sides."""
        if targets is None:
            return cls(np.ones(len(buried)), ~buried, buried.copy(), np.asarray(sided, bool))
        return cls(targets.target, targets.balance & ~buried, targets.dead | buried,
                   targets.sided)


def balance_rows(apply, sums, target, balance, dead, tol: float = 1e-12,
                 max_iterations: int = 100):
    """Symmetric scaling d (m,) of K -> D K D: rows in `balance` sum (over their sides) to
    `target`, the others are capped (each side at most 1), the dead rows and columns are 0.

    apply(d) -> (Fd, Fm): (m,) each, the rows of K scaled by d on the columns, summed over the
    sides and their largest side; sums (sides, m): K's row sums per side; target (m,) float64;
    balance, dead (m,) bool. Stops when the error is below tol or after max_iterations passes.
    Returns d, the passes, the final error and the number of rows stopped at D_MAX."""
    total = sums.sum(axis=0)
    live = (total > 0) & ~dead
    # a row far below its target is a partly covered sub-element (under a block's edge, a
    # table top's underside where a leg stands): it is capped, not balanced (balancing it
    # would multiply its form factors many times over)
    bal = balance & live & (total >= BALANCE_MIN * target)
    cap = live & ~bal
    d = np.where(bal, np.sqrt(np.where(bal, target, 1.0) / np.where(live, total, 1.0)), 1.0)
    d[dead] = 0.0
    err = 0.0
    for it in range(max_iterations):
        Fd, Fm = apply(d)
        err = max(np.abs(d * Fd - target)[bal].max(initial=0.0),
                  np.maximum(d * Fm - 1.0, 0.0)[cap].max(initial=0.0))
        if err < tol:
            break
        d = np.where(bal, np.sqrt(d * np.where(bal, target, 1.0) / np.where(bal & (Fd > 0), Fd, 1.0)), d)
        d = np.where(cap & (Fm > 0), np.minimum(1.0, np.sqrt(d / np.where(Fm > 0, Fm, 1.0))), d)
        # a scaling beyond D_MAX either way is not a kernel error balanced away but a pair of
        # surfaces in a thin gap whose kernel rows cannot be balanced together (a cushion 1 mm
        # over a seat: d ran to 0.002 in room-2400): those rows stop at the bound
        d = np.where(bal, np.clip(d, 1.0 / D_MAX, D_MAX), d)
    stuck = bal & ((d <= 1.0 / D_MAX) | (d >= D_MAX))
    if stuck.any():  # the error of the rows that could be balanced
        Fd, Fm = apply(d)
        err = max(np.abs(d * Fd - target)[bal & ~stuck].max(initial=0.0),
                  np.maximum(d * Fm - 1.0, 0.0)[cap].max(initial=0.0))
    return d, it + 1, float(err), int(stuck.sum())
