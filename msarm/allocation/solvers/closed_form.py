"""Pott's closed-form force distributions (paper 001).

Closed form (Pott, Bruckmann, Mikelsons 2009): the unbounded optimum of the allocation
objective (``f_ref = 0`` gives the unbounded minimum 2-norm forces, which may be negative;
paper 000's distribution is the *bounded* minimum 2-norm one, the QP solvers' answer)::

    f = f_ref + W^-2 M^T (M W^-2 M^T)^-1 (b - M f_ref)

With ``W = I`` and ``f_ref`` the midpoint of the bounds this is ``f = f_m + A^+T (...)``,
Pott's choice. It meets ``M f = b`` exactly, but not the bounds: it succeeds only when the
result lies within them, and then equals the QP optimum when no bound is active.

Improved closed form (Pott 2014, used in paper 001): when a force leaves its bounds, the one
with the largest violation [N] is fixed at the bound it violates, its contribution moved to
the right-hand side, and the closed form solved again for the remaining forces; at most
``m - n`` times. If the last solve (n forces left) still violates a bound, or the remaining
columns lose rank, the method reports failure.

When a closed form fails, ``Allocator.solve`` returns the bounded least-squares fallback:
status ``"fallback"`` if that meets ``M f = b`` (the problem was feasible, the closed form
missed it) or ``"infeasible"``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from msarm.allocation.problem import CLOSED_FORM, AllocationSpec
from msarm.allocation.solvers.base import Allocator, FloatArray, MethodOutput

__all__ = ["ClosedFormAllocator", "ImprovedClosedFormAllocator", "weighted_closed_form"]


def weighted_closed_form(
    M: FloatArray, b: FloatArray, inv_w2: FloatArray, f_ref: FloatArray
) -> FloatArray | None:
    """The unbounded minimiser of 1/2 ||W (f - f_ref)||^2 subject to M f = b.

    Args:
        M: Shape (n, k) with k >= n.
        b: Shape (n,).
        inv_w2: 1 / weights^2, shape (k,).
        f_ref: Shape (k,) [N].

    Returns:
        f [N], shape (k,), or ``None`` when ``M W^-2 M^T`` is singular (M loses rank).
    """
    MW = M * inv_w2
    K = MW @ M.T
    try:
        y = np.linalg.solve(K, b - M @ f_ref)
    except np.linalg.LinAlgError:
        return None
    with np.errstate(over="ignore", invalid="ignore"):  # a non-finite f is refused below
        f = f_ref + MW.T @ y
    # np.linalg.solve does not flag near-singular systems: check that M f = b holds.
    r = M @ f - b
    if not np.isfinite(r).all() or np.abs(r).max() > 1e-9 * (1.0 + np.abs(b).max()):
        return None
    return f


class ClosedFormAllocator(Allocator):
    """Pott's closed-form force distribution: one linear solve, no bound handling.

    Args:
        spec: Sizes, weights, reference force (Pott: ``f_ref="midpoint"``) and tolerance.
    """

    name: ClassVar[str] = "closed_form"
    exact: ClassVar[bool] = False

    def __init__(self, spec: AllocationSpec) -> None:
        super().__init__(spec)
        self._inv_w2 = 1.0 / (spec.weights * spec.weights)

    def _within(self, f: FloatArray, f_min: FloatArray, f_max: FloatArray) -> bool:
        tol = self._tol
        return bool(
            np.all(f >= f_min - tol * (1.0 + np.abs(f_min)))
            and np.all(f <= f_max + tol * (1.0 + np.abs(f_max)))
        )

    def _solve(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> MethodOutput:
        f = weighted_closed_form(M, b, self._inv_w2, f_ref)
        if f is None or not self._within(f, f_min, f_max):
            return None, CLOSED_FORM, 1, None
        return f, CLOSED_FORM, 1, None


class ImprovedClosedFormAllocator(ClosedFormAllocator):
    """Pott's improved closed form: fix the worst violation at its bound, solve again.

    Args:
        spec: Sizes, weights, reference force (Pott: ``f_ref="midpoint"``) and tolerance.
    """

    name: ClassVar[str] = "improved_closed_form"
    exact: ClassVar[bool] = False

    def _solve(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> MethodOutput:
        m, n = self.spec.n_actuators, self.spec.n_dof
        tol = self._tol
        f = np.empty(m)
        free = np.ones(m, dtype=bool)
        active = np.zeros(m, dtype=np.int8)
        rhs = b
        for solves in range(1, m - n + 2):
            idx = np.flatnonzero(free)
            f_free = weighted_closed_form(M[:, idx], rhs, self._inv_w2[idx], f_ref[idx])
            if f_free is None:
                return None, CLOSED_FORM, solves, None
            lo, hi = f_min[idx], f_max[idx]
            below = lo - f_free
            above = f_free - hi
            violation = np.maximum(below, above)
            worst = int(np.argmax(violation))
            slack = tol * (1.0 + np.maximum(np.abs(lo), np.abs(hi)))
            if violation[worst] <= slack[worst] and np.all(violation <= slack):
                f[idx] = f_free
                return f, CLOSED_FORM, solves, active
            if solves == m - n + 1:  # n forces left and still out of bounds
                return None, CLOSED_FORM, solves, None
            i = idx[worst]
            if below[worst] > above[worst]:
                f[i], active[i] = f_min[i], -1
            else:
                f[i], active[i] = f_max[i], 1
            free[i] = False
            rhs = rhs - M[:, i] * f[i]
        return None, CLOSED_FORM, m - n + 1, None  # pragma: no cover - loop always returns
