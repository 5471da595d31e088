"""The reference: the allocation QP written in cvxpy, built once with ``cp.Parameter``s.

Two problems are compiled at construction (DPP, so each tick only sets parameter values):
the allocation QP, and the bounded least squares used when the QP is infeasible (solved in
two stages, the least squares then the QP on its ``M f``, then the exact polish of
``msarm.allocation.fallback``). Both are
solved by Clarabel, an interior-point solver independent of the fast paths, with tolerances
tightened to 1e-12 so the reference is accurate to about 1e-12 relative. About 1 ms a solve.
"""

from __future__ import annotations

import warnings
from typing import ClassVar

import cvxpy as cp
import numpy as np

from msarm.allocation.fallback import polish_least_squares
from msarm.allocation.problem import OPTIMAL, AllocationSpec
from msarm.allocation.solvers.base import Allocator, FloatArray, MethodOutput

__all__ = ["CLARABEL_SETTINGS", "CvxpyAllocator"]

CLARABEL_SETTINGS = {
    "tol_gap_abs": 1e-12,
    "tol_gap_rel": 1e-12,
    "tol_feas": 1e-12,
    "tol_ktratio": 1e-10,
    "max_iter": 200,
}
"""Clarabel settings of the reference (defaults are 1e-8)."""

_SOLVED = (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)


class CvxpyAllocator(Allocator):
    """The cvxpy reference of the allocation QP (slow; for tests and benchmarks).

    Args:
        spec: Sizes, weights, reference force and tolerance.
    """

    name: ClassVar[str] = "cvxpy"
    exact: ClassVar[bool] = True

    def __init__(self, spec: AllocationSpec) -> None:
        super().__init__(spec)
        m, n = spec.n_actuators, spec.n_dof
        w = spec.weights
        self._f = cp.Variable(m, name="f")
        self._M = cp.Parameter((n, m), name="M")
        self._b = cp.Parameter(n, name="b")
        self._lo = cp.Parameter(m, name="f_min")
        self._hi = cp.Parameter(m, name="f_max")
        self._wref = cp.Parameter(m, name="W_f_ref")
        f = self._f
        bounds = [f >= self._lo, f <= self._hi]
        self._qp = cp.Problem(
            cp.Minimize(0.5 * cp.sum_squares(cp.multiply(w, f) - self._wref)),
            [self._M @ f == self._b, *bounds],
        )
        # the bounded least squares, the first stage of the fallback
        self._ls = cp.Problem(cp.Minimize(0.5 * cp.sum_squares(self._M @ f - self._b)), bounds)

    def _solve(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> MethodOutput:
        w = self._weights
        self._M.value = M
        self._b.value = b
        self._lo.value = f_min
        self._hi.value = f_max
        self._wref.value = w * f_ref
        try:
            self._qp.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
        except cp.SolverError:
            return None, OPTIMAL, 0, None
        iterations = int(self._qp.solver_stats.num_iters or 0)
        if self._qp.status not in _SOLVED or self._f.value is None:
            return None, OPTIMAL, iterations, None
        return np.array(self._f.value, dtype=np.float64), OPTIMAL, iterations, None

    def _fallback(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> tuple[FloatArray, int]:
        """The QP is infeasible: the lexicographic bounded least squares, in two stages.

        First the bounded f closest to ``M f = b`` (the least squares alone: its ``M f`` is
        unique, its f is not); then, among the bounded f with that same ``M f``, the one of
        least objective (the allocation QP with ``b`` replaced by it); then the exact polish of
        ``msarm.allocation.fallback``. The fast paths reach the same point through a
        regularised problem; Clarabel, an interior-point method, resolves the regularisation's
        1e-8 only to its tolerance, and then picked another of the tied points (up to 48 N off
        on an arm problem, with the same residual and a larger objective).

        Args:
            M: Shape (n, m).
            b: Shape (n,).
            f_min: Lower bounds [N], shape (m,).
            f_max: Upper bounds [N], shape (m,).
            f_ref: Reference force [N], shape (m,).

        Returns:
            ``(f, iterations)``: f [N] of shape (m,) within the bounds, Clarabel's iterations
            over both stages.
        """
        w = self._weights
        self._M.value = M
        self._b.value = b
        self._lo.value = f_min
        self._hi.value = f_max
        self._ls.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
        iterations = int(self._ls.solver_stats.num_iters or 0)
        x = np.clip(np.asarray(self._f.value, dtype=np.float64), f_min, f_max)
        closest = M @ x  # the stage's unique M f
        self._b.value = closest
        self._wref.value = w * f_ref
        try:
            with warnings.catch_warnings():  # "may be inaccurate": the polish below settles it
                warnings.simplefilter("ignore", UserWarning)
                self._qp.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
            if self._qp.status in _SOLVED and self._f.value is not None:
                x = np.clip(np.asarray(self._f.value, dtype=np.float64), f_min, f_max)
                iterations += int(self._qp.solver_stats.num_iters or 0)
        except cp.SolverError:
            pass  # keep the first stage's point: as close to M f = b, a larger objective
        span = 1e-9 * (1.0 + np.abs(f_min) + np.abs(f_max))
        active = (x >= f_max - span).astype(np.int8) - (x <= f_min + span).astype(np.int8)
        f = polish_least_squares(M, b, f_min, f_max, w, f_ref, x, active)
        return f, iterations
