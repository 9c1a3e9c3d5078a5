"""The canonical Poisson matrix ``J = [[0, I], [-I, 0]]``, defined once (sympredict.symplectic.metrics) and used everywhere."""

import numpy as np
import pytest

from sympredict.symplectic.metrics import canonical_J, j_times


@pytest.mark.parametrize("dim", [2, 4, 10])
def test_canonical_J_is_skew_and_squares_to_minus_identity(dim):
    J = canonical_J(dim)
    n = dim // 2
    assert J.shape == (dim, dim)
    np.testing.assert_array_equal(J.T, -J)
    np.testing.assert_array_equal(J @ J, -np.eye(dim))
    np.testing.assert_array_equal(J[:n, n:], np.eye(n))  # (q, p) ordering: q' = dH/dp


@pytest.mark.parametrize("dim", [2, 6])
def test_j_times_applies_J_without_forming_it(dim):
    rng = np.random.default_rng(0)
    J = canonical_J(dim)
    v = rng.normal(size=(3, 5, dim))
    np.testing.assert_array_equal(j_times(v), v @ J.T)  # last axis of a batch of states
    A = rng.normal(size=(dim, 7))
    np.testing.assert_array_equal(j_times(A, axis=0), J @ A)  # columns of a (2N, k) basis
    S = rng.normal(size=(4, dim, dim))
    np.testing.assert_array_equal(j_times(S, axis=-2), J @ S)  # J A for a stack of matrices
    np.testing.assert_array_equal(j_times(j_times(v)), -v)  # J^2 = -I
