"""Array helpers where numpy is slow on large arrays: `unique` by one sort (numpy 2's np.unique
of plain values hashes them: 34 s against 2.7 s for sorting 3e7 scattered int64 keys on this
machine) and `unique_rows` by one lexsort (np.unique(axis=0) sorts structured records: 3.1 s
against 0.7 s for 1e6 rows of 4 int64)."""

from __future__ import annotations

import numpy as np


def unique(a: np.ndarray) -> np.ndarray:
    """np.unique(a) (sorted distinct values of a flattened) by one sort."""
    s = np.sort(np.asarray(a).ravel())
    if len(s) < 2:
        return s
    return s[np.concatenate([[True], s[1:] != s[:-1]])]


def unique_rows(keys: np.ndarray):
    """np.unique(keys, axis=0, return_index=True, return_inverse=True) of an (N, k) integer
    array: the distinct rows in lexicographic order, the first index of each, the inverse."""
    keys = np.asarray(keys)
    order = np.lexsort(keys.T[::-1])
    k = keys[order]
    new = np.r_[True, np.any(k[1:] != k[:-1], axis=1)] if len(k) else np.zeros(0, bool)
    inv = np.empty(len(keys), np.int64)
    inv[order] = np.cumsum(new) - 1
    return k[new], order[new], inv
