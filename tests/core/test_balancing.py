"""core/balancing.balance_rows, the one row balancing of the solve and the view factors: rows
in `balance` reach their target, the others are capped at 1, dead rows and columns are 0, and
D K D keeps reciprocity (A K symmetric) and the sparsity pattern."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from radiosity.core.balancing import D_MAX, RowTargets, balance_rows


def _reciprocal(rng, n, density=0.3):
    """A random K (n, n) with A K symmetric and rows within about 10 % of 1, and the areas A."""
    S = sp.random(n, n, density=density, random_state=np.random.RandomState(1)).toarray()
    S = S + S.T
    np.fill_diagonal(S, 0.0)
    A = S.sum(axis=1)
    E = rng.random((n, n)) * 0.2 - 0.1
    K = S * (1 + E + E.T) / A[:, None]
    return K, A


def test_balanced_rows_reach_targets_capped_rows_stay_below_one_dead_are_zero(rng):
    n = 40
    K, A = _reciprocal(rng, n)
    target = np.ones(n)
    target[:5] = 0.9
    balance = np.ones(n, bool)
    balance[30:35] = False       # capped
    dead = np.zeros(n, bool)
    dead[35:] = True
    sums = K.sum(axis=1)[None, :]

    def apply(d):
        y = K @ d
        return y, y

    d, passes, err, stuck = balance_rows(apply, sums, target, balance, dead)
    F = d[:, None] * K * d[None, :]
    rows = F.sum(axis=1)
    bal = balance & ~dead
    assert stuck == 0 and err < 1e-12 and passes < 100
    assert np.abs(rows[bal] - target[bal]).max() < 1e-11
    assert rows[30:35].max() <= 1 + 1e-12
    assert not F[dead].any() and not F[:, dead].any()
    S = A[:, None] * F
    assert np.abs(S - S.T).max() < 1e-14 and ((F != 0) == ((K != 0) & ~dead[:, None] & ~dead)).all()
    assert (d[~dead] >= 1 / D_MAX).all() and (d[~dead] <= D_MAX).all()


def test_row_targets_of_a_closure_one_sided():
    """RowTargets.of: contact fronts of one-sided elements are dead; the snapped targets are
    balanced, the measured (not exact) ones are not."""
    from types import SimpleNamespace

    n = 4
    cl = SimpleNamespace(closed=True, contact=np.array([[True, False]] + [[False, False]] * 3),
                         target=np.array([[0.0, 0], [1, 0], [0.7, 0], [1, 0]]),
                         exact=np.array([[True, True], [True, True], [False, True], [True, True]]))
    rt = RowTargets.of(cl, np.arange(n), np.zeros(n, bool))
    assert rt.dead.tolist() == [True, False, False, False]
    assert rt.balance.tolist() == [False, True, False, True]
    assert rt.target.tolist() == [0.0, 1.0, 0.7, 1.0]
