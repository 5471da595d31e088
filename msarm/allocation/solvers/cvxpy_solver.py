"""The reference: the allocation QP written in cvxpy, built once with ``cp.Parameter``s.

Two problems are compiled at construction (DPP, so each tick only sets parameter values):
the allocation QP, and the regularised bounded least squares used when the QP is infeasible
(same regularisation as ``msarm.allocation.fallback``, then the same exact polish). Both are
solved by Clarabel, an interior-point solver independent of the fast paths, with tolerances
tightened to 1e-12 so the reference is accurate to about 1e-12 relative. About 1 ms a solve.
"""

from __future__ import annotations

import math
from typing import ClassVar

import cvxpy as cp
import numpy as np

from msarm.allocation.fallback import EPS_REL, polish_least_squares
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
        # Least squares: 1/2 ||M f - b||^2 + eps/2 ||W (f - f_ref)||^2, with sqrt(eps) W and
        # sqrt(eps) W f_ref as parameters to stay DPP.
        self._sw = cp.Parameter(m, nonneg=True, name="sqrt_eps_W")
        self._swref = cp.Parameter(m, name="sqrt_eps_W_f_ref")
        self._ls = cp.Problem(
            cp.Minimize(
                0.5 * cp.sum_squares(self._M @ f - self._b)
                + 0.5 * cp.sum_squares(cp.multiply(self._sw, f) - self._swref)
            ),
            bounds,
        )

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
        """The QP is infeasible: the bounded least squares, solved by cvxpy (the reference).

        Args:
            M: Shape (n, m).
            b: Shape (n,).
            f_min: Lower bounds [N], shape (m,).
            f_max: Upper bounds [N], shape (m,).
            f_ref: Reference force [N], shape (m,).

        Returns:
            ``(f, iterations)``: f [N] of shape (m,) within the bounds, Clarabel's iterations.
        """
        w = self._weights
        w2 = w * w
        eps = EPS_REL * max(float(np.sum(M * M)), 1e-300) / float(w2.sum())
        self._M.value = M
        self._b.value = b
        self._lo.value = f_min
        self._hi.value = f_max
        self._sw.value = math.sqrt(eps) * w
        self._swref.value = math.sqrt(eps) * w * f_ref
        self._ls.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
        x = np.clip(np.asarray(self._f.value, dtype=np.float64), f_min, f_max)
        span = 1e-9 * (1.0 + np.abs(f_min) + np.abs(f_max))
        active = (x >= f_max - span).astype(np.int8) - (x <= f_min + span).astype(np.int8)
        f = polish_least_squares(M, b, f_min, f_max, w, f_ref, x, active)
        return f, int(self._ls.solver_stats.num_iters or 0)
