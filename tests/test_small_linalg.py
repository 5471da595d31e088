"""The compiled Cholesky solve against numpy's, and its refusal of indefinite matrices."""

from __future__ import annotations

import numpy as np

from msarm.small_linalg import cholesky_solve


def test_cholesky_solve_matches_numpy_on_random_spd_systems():
    rng = np.random.default_rng(0)
    for n in (1, 2, 4, 6, 9):
        for _ in range(5):
            G = rng.normal(size=(n, n))
            a = G @ G.T + 0.1 * np.eye(n)
            b = rng.normal(size=n)
            x = np.empty(n)
            factor = a.copy()
            assert cholesky_solve(factor, b, x)
            np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(
                np.tril(factor), np.linalg.cholesky(a), rtol=1e-12, atol=1e-12
            )


def test_cholesky_solve_refuses_an_indefinite_matrix_with_nan():
    a = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and -1
    x = np.zeros(2)
    assert not cholesky_solve(a.copy(), np.ones(2), x)
    assert np.isnan(x).all()
    x = np.zeros(2)
    assert not cholesky_solve(np.zeros((2, 2)), np.ones(2), x)  # a zero pivot
    assert np.isnan(x).all()
