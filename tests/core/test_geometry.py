"""core/geometry.py against numpy."""

import numpy as np


def test_polygon_diameters_are_numpys_pairwise_norms_to_the_bit():
    """core.geometry.diameter (numba, no (n, 4, 4, 3) temporaries) against numpy's norms of
    every vertex difference, on quads and on triangles (fourth slot repeating a vertex)."""
    from radiosity.core.geometry import diameter

    rng = np.random.default_rng(5)
    v = rng.normal(size=(20000, 4, 3)) * rng.random((20000, 1, 1)) * 1e3
    v[::3, 3] = v[::3, 2]
    ref = np.linalg.norm(v[:, :, None, :] - v[:, None, :, :], axis=-1).reshape(len(v), -1)
    np.testing.assert_array_equal(diameter(v), ref.max(axis=1))
    assert diameter(np.zeros((0, 4, 3))).shape == (0,)
