"""core/arrays.py against numpy's own unique and argsort."""

import numpy as np
import pytest

from radiosity.core.arrays import unique, unique_rows


def test_unique_and_unique_rows_equal_numpy():
    rng = np.random.default_rng(5)
    for n in (0, 1, 2, 1000):
        a = rng.integers(-50, 50, n)
        np.testing.assert_array_equal(unique(a), np.unique(a))
        rows = rng.integers(0, 4, (n, 3))
        got = unique_rows(rows)
        want = np.unique(rows, axis=0, return_index=True, return_inverse=True)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, np.asarray(w).reshape(g.shape))
        assert np.array_equal(got[0][got[2]], rows)
    np.testing.assert_array_equal(unique(np.array([[3, 1], [1, 2]])), [1, 2, 3])


@pytest.mark.parametrize("bits", [1, 11, 12, 33, 62])
def test_radix_order_is_the_stable_argsort(bits):
    """radix_order(key, bits) is np.argsort(key, kind="stable") for keys below 2**bits, with
    repeats (stability), one digit or several, and no keys."""
    from radiosity.core.arrays import radix_order

    rng = np.random.default_rng(bits)
    for n in (0, 1, 1000, 50_000):
        key = rng.integers(0, 2 ** bits, n, dtype=np.int64)
        key[: n // 3] = key[n // 3: 2 * (n // 3)]  # repeats
        assert np.array_equal(radix_order(key, bits), np.argsort(key, kind="stable"))
