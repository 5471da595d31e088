"""Small dense linear algebra for compiled loops (numba).

Where a few unknowns are solved thousands of times a second, a LAPACK call would cost more
than the arithmetic.
"""

from __future__ import annotations

import math

import numba

from msarm.numba_cache import drop_stale_kernels

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = ["cholesky_solve"]


@numba.njit(cache=True)
def cholesky_solve(a, b, x):  # pragma: no cover - compiled
    """Solve ``a x = b`` for a small symmetric positive definite ``a`` by Cholesky.

    Args:
        a: Shape ``(n, n)``; its lower triangle is overwritten by the Cholesky factor.
        b: Shape ``(n,)``.
        x: Shape ``(n,)``, written: the solution, or NaN where ``a`` is not positive
            definite.

    Returns:
        Whether ``a`` was positive definite (a pivot was not positive: ``x`` is NaN).
    """
    n = b.shape[0]
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= a[j, k] * a[j, k]
        if not s > 0.0:
            for i in range(n):
                x[i] = math.nan
            return False
        d = math.sqrt(s)
        a[j, j] = d
        for i in range(j + 1, n):
            s = a[i, j]
            for k in range(j):
                s -= a[i, k] * a[j, k]
            a[i, j] = s / d
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= a[i, k] * x[k]
        x[i] = s / a[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= a[k, i] * x[k]
        x[i] = s / a[i, i]
    return True
