"""Array helpers where numpy is slow on large arrays: `unique` by one sort (numpy 2's np.unique
of plain values hashes them) and `unique_rows` by one lexsort (np.unique(axis=0) sorts
structured records), each several times faster (docs/src/measurements/choices.md); `radix_order`, the stable order of non-negative int64
keys of few bits in a few linear passes (faster than np.argsort, in the same memory)."""

from __future__ import annotations

import numba
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


@numba.njit(cache=True, nogil=True)
def radix_order(key: np.ndarray, bits: int) -> np.ndarray:
    """The stable sorting order of key (n,) int64 with 0 <= key < 2**bits and n < 2**31
    (np.argsort(key, kind="stable")) as int32: least significant digit first, 11 bits a pass,
    the keys read through the order (two int32 arrays: the memory of np.argsort's result;
    its speed against np.argsort: docs/src/design/methods-hierarchical-clusters.md)."""
    n = key.shape[0]
    if n >= 2 ** 31:
        raise ValueError("radix_order: more than 2**31 keys")
    idx = np.arange(n).astype(np.int32)
    idx2 = np.empty(n, np.int32)
    mask = (1 << 11) - 1
    cnt = np.empty(mask + 1, np.int64)
    shift = 0
    while shift < bits:
        cnt[:] = 0
        for i in range(n):
            cnt[(key[idx[i]] >> shift) & mask] += 1
        at = 0
        for d in range(mask + 1):
            c = cnt[d]
            cnt[d] = at
            at += c
        for i in range(n):
            j = idx[i]
            d = (key[j] >> shift) & mask
            idx2[cnt[d]] = j
            cnt[d] += 1
        idx, idx2 = idx2, idx
        shift += 11
    return idx
