"""The check of a solver's answer, compiled: within the bounds, and how far from ``M f = b``.

Every tick's answer is checked (:meth:`msarm.allocation.solvers.base.Allocator.solve`); done
with numpy on a 9 x 4 problem the bound test and the residual took about 5 µs, a quarter of
a DAQP solve, against 0.6 µs here.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from msarm.numba_cache import drop_stale_kernels

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = ["PAST_A_BOUND", "bounded_residual", "residual_limit", "residual_limits"]

#: What :func:`bounded_residual` returns when a force lies past a bound by round-off only.
PAST_A_BOUND = -1.0


@numba.njit(cache=True)
def bounded_residual(f, f_min, f_max, tol, M, b):  # pragma: no cover - compiled
    """``||M f - b||`` of forces within their bounds; what is wrong with them otherwise.

    Args:
        f: Forces [N], shape ``(m,)``.
        f_min: Lower bounds [N], shape ``(m,)``.
        f_max: Upper bounds [N], shape ``(m,)``.
        tol: Round-off allowed past a bound, relative to ``1 + |bound|``.
        M: Structure matrix, shape ``(n, m)``.
        b: Wanted wrench, shape ``(n,)``.

    Returns:
        ``||M f - b||`` when every force is within its bounds; :data:`PAST_A_BOUND` when
        some lie past a bound by no more than ``tol (1 + |bound|)`` (to be set onto it, then
        checked again); NaN when a force is NaN or farther past a bound.
    """
    past = False
    for i in range(f.shape[0]):
        x = f[i]
        if x < f_min[i]:
            if not f_min[i] - x <= tol * (1.0 + abs(f_min[i])):
                return math.nan
            past = True
        elif x > f_max[i]:
            if not x - f_max[i] <= tol * (1.0 + abs(f_max[i])):
                return math.nan
            past = True
        elif x != x:
            return math.nan
    if past:
        return PAST_A_BOUND
    total = 0.0
    for j in range(M.shape[0]):
        r = -b[j]
        for i in range(M.shape[1]):
            r += M[j, i] * f[i]
        total += r * r
    return math.sqrt(total)


@numba.njit(cache=True)
def residual_limit(M, b, f, tol):  # pragma: no cover - compiled
    """The largest ``||M f - b||`` that counts as meeting ``M f = b``: round-off of its terms.

    ``tol (1 + ||b|| + || |M| |f| ||)``: with the size of ``M f``'s products in it, the test
    holds at any force scale (with bounds of 1e7 N and a small ``b``, the rounding of ``M f``
    alone exceeded ``tol (1 + ||b||)`` and feasible problems were called infeasible).

    Args:
        M: Structure matrix, shape ``(n, m)``.
        b: Wanted wrench, shape ``(n,)``.
        f: Forces [N], shape ``(m,)``.
        tol: The spec's tolerance.
    """
    bb = 0.0
    tt = 0.0
    for j in range(M.shape[0]):
        bb += b[j] * b[j]
        t = 0.0
        for i in range(M.shape[1]):
            t += abs(M[j, i]) * abs(f[i])
        tt += t * t
    return tol * (1.0 + math.sqrt(bb) + math.sqrt(tt))


def residual_limits(
    M: NDArray[np.float64], b: NDArray[np.float64], f: NDArray[np.float64], tol: float
) -> NDArray[np.float64]:
    """:func:`residual_limit` of N problems: ``M`` (N, n, m), ``b`` (N, n), ``f`` (N, m); (N,)."""
    terms = (np.abs(M) @ np.abs(f)[..., None])[..., 0]
    return tol * (1.0 + np.sqrt((b * b).sum(axis=1)) + np.sqrt((terms * terms).sum(axis=1)))
