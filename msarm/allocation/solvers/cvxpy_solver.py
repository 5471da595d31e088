"""The reference: the allocation QP written in cvxpy, built once with ``cp.Parameter``s.

Two problems are compiled at construction (DPP, so each tick only sets parameter values):
the allocation QP, and the bounded least squares used when the QP is infeasible (solved in
two stages, the least squares then the QP on its ``M f``). Both are solved by Clarabel, an
interior-point solver independent of the fast paths, with tolerances tightened to 1e-14, in
scaled variables::

    x = W (f - f_ref) / s,   s = max |W (f_bound - f_ref)|   (the tick's farthest bound)

so that x lies in [-1, 1] and the objective ``1/2 ||x||^2`` is of order one whatever the
units of forces and weights (the rows of ``M f = b`` are scaled too). Solved in forces [N],
with forces and bounds 30 times the arm's and weights 30 times smaller, Clarabel stopped short
(InsufficientProgress) and answers 0.1 % to 94 times above the optimum were kept, on 23 and
53 of 100 arm problems in two draws. Clarabel's point is then polished
(``polish_least_squares``: the forces at a bound held there, the rest solved exactly), since
an interior point meets a bound whose multiplier is zero only to the square root of its
tolerance. A tick on which Clarabel fails, or whose answer misses the bounds beyond the spec's
tolerance, goes to DAQP's exact QP, then (none found) to the two-stage bounded least squares,
rather than keep Clarabel's last point: with weights spanning 1e5-1e6 Clarabel failed on 3-17 of
60 feasible problems, and the least squares alone had called them infeasible.

Accuracy, measured against DAQP's optimum: within 1e-12 of the force scale
``max |f_bound|`` (9e-13 at worst over 1,000 arm problems at 1 and 30 times the arm's
forces, 8e-13 over 600 random 4 x 9 and 6 x 8 problems, feasible and not), the objective to
about 1e-14 relative; ``tests/test_allocation_edge_cases.py`` holds it to 1e-10. With weights
spanning 1e6 (an extreme), Clarabel's "optimal" answer was 30 N off the optimum (objective
1.8e-4 above it) on 1 of 120 random problems. About 1-2 ms a solve.
"""

from __future__ import annotations

import warnings
from typing import ClassVar

import cvxpy as cp
import numpy as np

from msarm.allocation.fallback import bounded_least_squares, polish_least_squares
from msarm.allocation.problem import OPTIMAL, AllocationSpec, snap_to_bounds
from msarm.allocation.solvers.base import Allocator, FloatArray, MethodOutput

__all__ = ["CLARABEL_SETTINGS", "CvxpyAllocator"]

CLARABEL_SETTINGS = {
    "tol_gap_abs": 1e-14,
    "tol_gap_rel": 1e-14,
    "tol_feas": 1e-14,
    "tol_ktratio": 1e-10,
    "max_iter": 200,
}
"""Clarabel settings of the reference (defaults are 1e-8), for the scaled variables.

With 1e-12, the bounds Clarabel reached were too loose to polish on some infeasible arm
problems (1e-8 of the force scale off); 1e-15 made it stop short or end inaccurate.
"""

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
        self._x = cp.Variable(m, name="x")  # W (f - f_ref) / s
        self._A = cp.Parameter((n, m), name="A")  # s M W^-1
        self._c = cp.Parameter(n, name="c")  # b - M f_ref
        self._lo = cp.Parameter(m, name="x_min")
        self._hi = cp.Parameter(m, name="x_max")
        x = self._x
        bounds = [x >= self._lo, x <= self._hi]
        self._qp = cp.Problem(
            cp.Minimize(0.5 * cp.sum_squares(x)), [self._A @ x == self._c, *bounds]
        )
        # the bounded least squares, the first stage of the fallback
        self._ls = cp.Problem(cp.Minimize(0.5 * cp.sum_squares(self._A @ x - self._c)), bounds)

    def _scale(self, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray) -> float:
        """Set the bounds of x = W (f - f_ref) / s; returns s [-] (W is in 1/N)."""
        w = self._weights
        lo, hi = w * (f_min - f_ref), w * (f_max - f_ref)
        s = float(max(np.abs(lo).max(), np.abs(hi).max()))
        if not s > 0.0:  # f_min = f_max = f_ref: any scale does
            s = 1.0
        self._lo.value = lo / s
        self._hi.value = hi / s
        return s

    def _set_rows(self, A: FloatArray, c: FloatArray, rows: bool) -> None:
        """Set ``A x = c`` with each row (``rows``) or the whole (else) scaled to max |A| = 1.

        Scaling each row leaves the QP's solution alone; the least squares' minimisers are
        left alone only by one scale for all rows.
        """
        if rows:
            d = np.abs(A).max(axis=1)
        else:
            d = np.full(A.shape[0], np.abs(A).max())
        d[~(d > 0.0)] = 1.0  # a zero row (no actuator acts there) stays as it is
        self._A.value = A / d[:, None]
        self._c.value = c / d

    def _run(self, problem: cp.Problem, *, inaccurate: bool = False) -> int | None:
        """Solve with Clarabel; its iterations, or ``None`` when it found no solution.

        Args:
            problem: ``self._qp`` or ``self._ls``, its parameters set.
            inaccurate: Accept an "optimal_inaccurate" answer (one the caller polishes).
        """
        try:
            with warnings.catch_warnings():  # "may be inaccurate": see ``inaccurate``
                warnings.simplefilter("ignore", UserWarning)
                problem.solve(solver=cp.CLARABEL, **CLARABEL_SETTINGS)
        except cp.SolverError:  # e.g. InsufficientProgress: no answer, not an answer
            return None
        solved = _SOLVED if inaccurate else (cp.OPTIMAL,)
        if problem.status not in solved or self._x.value is None:
            return None
        return int(problem.solver_stats.num_iters or 0)

    def _solve(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> MethodOutput:
        s = self._scale(f_min, f_max, f_ref)
        self._set_rows(M * (s / self._weights), b - M @ f_ref, rows=True)
        iterations = self._run(self._qp)
        if iterations is None:
            return None, OPTIMAL, 0, None
        f = f_ref + np.asarray(self._x.value, dtype=np.float64) * (s / self._weights)
        f, within = snap_to_bounds(f, f_min, f_max, self._tol)
        if not within:  # not an answer: Allocator.solve's fallback takes the tick
            return None, OPTIMAL, iterations, None
        return self._polish(M, b, f_min, f_max, f_ref, f), OPTIMAL, iterations, None

    def _polish(
        self,
        M: FloatArray,
        b: FloatArray,
        f_min: FloatArray,
        f_max: FloatArray,
        f_ref: FloatArray,
        f: FloatArray,
    ) -> FloatArray:
        """Clarabel's point made exact: ``polish_least_squares`` on the bounds it reached.

        With the forces within 1e-9 (relative) of a bound held there, the others are solved
        again exactly (the KKT system of that face). An interior-point method meets a bound
        only to about the square root of its tolerance where the bound's multiplier is zero
        (an optimum on a bound with no pull from it): 5.8e-7 N off, bounds up to 18 N.

        Args:
            M: Shape (n, m).
            b: Shape (n,).
            f_min: Lower bounds [N], shape (m,).
            f_max: Upper bounds [N], shape (m,).
            f_ref: Reference force [N], shape (m,).
            f: Clarabel's forces [N], shape (m,), within the bounds.

        Returns:
            The polished forces [N], shape (m,), within the bounds (``f`` itself when the
            polish does not lie within them or is farther from ``M f = b``).
        """
        span = 1e-9 * (1.0 + np.abs(f_min) + np.abs(f_max))
        active = (f >= f_max - span).astype(np.int8) - (f <= f_min + span).astype(np.int8)
        return polish_least_squares(M, b, f_min, f_max, self._weights, f_ref, f, active)

    def _fallback(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> tuple[FloatArray, int]:
        """The QP failed: DAQP's exact QP, else the lexicographic bounded least squares.

        Clarabel fails on some feasible problems (weights spanning 1e5 or more: one scale
        for every x cannot suit them all); DAQP's optimum, when it is a solution
        (:meth:`Allocator._exact_qp`), is the answer then. Otherwise, in two stages: first
        the bounded f closest to ``M f = b`` (the least squares alone: its ``M f`` is
        unique, its f is not); then, among the bounded f with that same ``M f``, the one of
        least objective (the allocation QP with ``b`` replaced by it); then the exact polish of
        ``msarm.allocation.fallback``. The fast paths reach the same point through a
        regularised problem; Clarabel, an interior-point method, resolves the regularisation's
        1e-8 only to its tolerance, and then picked another of the tied points (up to 48 N off
        on an arm problem, with the same residual and a larger objective). If Clarabel fails
        at either stage, the bounded least squares of ``msarm.allocation.fallback`` rather
        than a point of unknown quality.

        Args:
            M: Shape (n, m).
            b: Shape (n,).
            f_min: Lower bounds [N], shape (m,).
            f_max: Upper bounds [N], shape (m,).
            f_ref: Reference force [N], shape (m,).

        Returns:
            ``(f, iterations)``: f [N] of shape (m,) within the bounds; DAQP's iterations
            and Clarabel's over both stages.
        """
        f, iterations = self._exact_qp(M, b, f_min, f_max, f_ref)
        if f is not None:
            return f, iterations
        w = self._weights
        s = self._scale(f_min, f_max, f_ref)
        A = M * (s / w)
        self._set_rows(A, b - M @ f_ref, rows=False)
        first = self._run(self._ls, inaccurate=True)
        if first is None:
            f, extra = bounded_least_squares(M, b, f_min, f_max, w, f_ref)
            return f, iterations + extra
        iterations += first
        x = np.clip(np.asarray(self._x.value, dtype=np.float64), self._lo.value, self._hi.value)
        self._set_rows(A, A @ x, rows=True)  # the stage's unique M f (less M f_ref)
        extra = self._run(self._qp, inaccurate=True)  # on a face: often degenerate
        if extra is None:
            f, more = bounded_least_squares(M, b, f_min, f_max, w, f_ref)
            return f, iterations + more
        f = np.clip(f_ref + np.asarray(self._x.value, dtype=np.float64) * (s / w), f_min, f_max)
        return self._polish(M, b, f_min, f_max, f_ref, f), iterations + extra
