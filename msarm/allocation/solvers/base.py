"""The interface every allocation solver implements, and the bookkeeping they share.

A solver implements ``_solve`` for one validated tick; ``Allocator.solve`` adds validation,
the reference force, the check of the method's answer (bounds and ``M f = b``, NaN-safe), the
bounded least-squares fallback, the residual, the feasibility flag, the active set and
timing, identically for all solvers.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from time import perf_counter
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.allocation.fallback import bounded_least_squares
from msarm.allocation.problem import (
    FALLBACK,
    INFEASIBLE,
    AllocationResult,
    AllocationSpec,
    BatchAllocationResult,
    active_set,
    check_bound_order,
    check_tick,
    validate_batch,
)
from msarm.allocation.solution_check import PAST_A_BOUND, bounded_residual, residual_limit
from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = ["Allocator", "MethodOutput"]

MethodOutput = tuple[FloatArray | None, str, int, NDArray[np.int8] | None]
"""What ``_solve`` returns: ``(f or None, status, iterations, active set or None)``.

``f = None`` means the method found no force meeting the constraints; the caller then runs
the fallback. So does an f that misses ``M f = b`` or a bound (beyond the spec's tolerance)
or holds a NaN; an f within that round-off of a bound is set onto it. An active set of
``None`` is computed from f.
"""


class Allocator(ABC):
    """Turns ``M f = b`` with force bounds into forces f, for one robot, every tick.

    Build once (``make_allocator``), then call ``solve`` each tick with the new ``M``, ``b``
    and bounds. See ``msarm.allocation.problem`` for the problem.

    Args:
        spec: Sizes, weights, reference force and tolerance.
    """

    name: ClassVar[str] = "base"
    exact: ClassVar[bool] = True
    """Whether the solver returns the QP optimum (the closed forms do not, in general)."""

    def __init__(self, spec: AllocationSpec) -> None:
        self.spec = spec
        self._weights = spec.weights
        self._tol = spec.tol
        self._exact: Allocator | None = None

    @property
    def n_actuators(self) -> int:
        """m, the number of actuators (length of f)."""
        return self.spec.n_actuators

    @property
    def n_dof(self) -> int:
        """n, the number of rows of M."""
        return self.spec.n_dof

    def __repr__(self) -> str:
        s = self.spec
        return (
            f"{type(self).__name__}(n_actuators={s.n_actuators}, n_dof={s.n_dof}, "
            f"f_ref={s.f_ref_mode!r}, tol={s.tol:g})"
        )

    @abstractmethod
    def _solve(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> MethodOutput:
        """Solve one validated tick; see ``MethodOutput``."""

    def _fallback(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> tuple[FloatArray, int]:
        """Forces when the method found none: ``(f, iterations)``, f within the bounds.

        First the exact QP (DAQP, :meth:`_exact_qp`): the problem may be feasible though the
        method failed, and then the answer is the optimum. If DAQP finds no solution, the
        bounded least squares of ``msarm.allocation.fallback``.
        """
        f, iterations = self._exact_qp(M, b, f_min, f_max, f_ref)
        if f is not None:
            return f, iterations
        f, extra = bounded_least_squares(M, b, f_min, f_max, self._weights, f_ref)
        return f, iterations + extra

    def _exact_qp(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> tuple[FloatArray | None, int]:
        """DAQP's optimum when it is a solution (:meth:`_accept`), else ``None``; its iterations.

        An answer that misses ``M f = b`` or the bounds is not one (DAQP called x = 0 optimal
        for a zero row of M, below f_min).
        """
        if self._exact is None:
            from msarm.allocation.solvers.daqp_solver import DaqpAllocator

            self._exact = DaqpAllocator(self.spec)
        f, _, iterations, _ = self._exact._solve(M, b, f_min, f_max, f_ref)
        f, _ = self._accept(f, M, b, f_min, f_max)
        return f, iterations

    def _accept(
        self,
        f: FloatArray | None,
        M: FloatArray,
        b: FloatArray,
        f_min: FloatArray,
        f_max: FloatArray,
    ) -> tuple[FloatArray | None, float]:
        """A method's f if it is a solution, within the bounds; else ``None``.

        A solution meets ``M f = b`` to the round-off of its terms
        (:func:`~msarm.allocation.solution_check.residual_limit`,
        ``tol (1 + ||b|| + || |M| |f| ||)``) and the bounds to ``tol (1 + |bound|)``
        (the spec's tolerance); a force within that round-off of a bound is set onto it. A
        force farther out, a NaN or a missed ``M f = b`` means that the method failed
        (``None``): it is never clipped into a plausible-looking answer.

        Args:
            f: The method's forces [N], shape (m,), or ``None``.
            M: Shape (n, m).
            b: Shape (n,).
            f_min: Lower bounds [N], shape (m,).
            f_max: Upper bounds [N], shape (m,).

        Returns:
            ``(f, residual)``: f [N] of shape (m,) exactly within the bounds, or ``None``;
            its ``||M f - b||`` (NaN when f is ``None``).
        """
        if f is None:
            return None, math.nan
        residual = bounded_residual(f, f_min, f_max, self._tol, M, b)
        if residual == PAST_A_BOUND:  # by round-off: onto the bound (a new array)
            f = np.clip(f, f_min, f_max)
            residual = bounded_residual(f, f_min, f_max, self._tol, M, b)
        # False for NaN: a NaN or a force farther out
        if not residual <= residual_limit(M, b, f, self._tol):
            return None, math.nan
        return f, residual

    def _reference(
        self, f_min: FloatArray, f_max: FloatArray, f_ref: ArrayLike | str | None
    ) -> FloatArray:
        if f_ref is None:
            return self.spec.reference(f_min, f_max)
        if isinstance(f_ref, str):
            if f_ref != "midpoint":
                raise InputError(
                    f"f_ref must be None, 'midpoint' or an array of forces [N], got {f_ref!r}"
                )
            return 0.5 * (f_min + f_max)
        if np.iscomplexobj(f_ref):
            raise InputError("f_ref must be real forces [N]; got complex values")
        try:
            ref = np.asarray(f_ref, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InputError(
                f"f_ref must be None, 'midpoint' or an array of forces [N], got {f_ref!r}"
            ) from exc
        if ref.shape != f_min.shape[-1:] and ref.shape != f_min.shape:
            raise InputError(
                f"f_ref must have shape ({self.n_actuators},) [N] or match the bounds, got "
                f"{ref.shape}"
            )
        if not np.isfinite(ref).all():
            raise InputError("f_ref must be finite [N]")
        return ref

    def solve(
        self,
        M: ArrayLike,
        b: ArrayLike,
        f_min: ArrayLike,
        f_max: ArrayLike,
        *,
        f_ref: ArrayLike | str | None = None,
    ) -> AllocationResult:
        """Allocate forces for one tick.

        Never raises for an infeasible problem: it then returns the bounded f closest to
        ``M f = b`` with ``feasible=False`` and its residual.

        Args:
            M: Shape (n, m): ``-J_c^T`` for the arm, ``A^T`` for a cable robot.
            b: Shape (n,): joint torques [N m] for the arm, ``-w`` for a cable robot.
            f_min: Lower force bounds [N], shape (m,) or scalar, finite.
            f_max: Upper force bounds [N], shape (m,) or scalar, finite, >= f_min.
            f_ref: Overrides the spec's reference force for this tick: forces [N], shape
                (m,), or ``"midpoint"`` (of this tick's bounds).

        Returns:
            The forces and how they were found.

        Raises:
            InputError: On wrong shapes, NaN or infinite values, or f_min > f_max.
        """
        t0 = perf_counter()
        M, b, f_min, f_max = check_tick(self.spec, M, b, f_min, f_max)
        # checked on every path: a solver's answer does not prove the order (DAQP returns
        # f = 0 as optimal for b = 0 with f_min > f_max; a closed form can overstep f_max)
        check_bound_order(f_min, f_max)
        ref = self._reference(f_min, f_max, f_ref)
        f, status, iterations, active = self._solve(M, b, f_min, f_max, ref)
        tol = self._tol
        # a method that claims success but misses M f = b or the bounds (beyond round-off),
        # or returns NaN, is not trusted: its tick goes to the fallback
        f, residual = self._accept(f, M, b, f_min, f_max)
        if f is None:
            f, extra = self._fallback(M, b, f_min, f_max, ref)
            iterations += extra
            residual = bounded_residual(f, f_min, f_max, 0.0, M, b)  # NaN: past a bound
            if not residual >= 0.0:
                raise RuntimeError(  # pragma: no cover - the fallback clips to finite bounds
                    f"{self.name}: the bounded least-squares fallback returned forces outside "
                    f"[f_min, f_max] or not finite: {f}"
                )
            status = FALLBACK if residual <= residual_limit(M, b, f, tol) else INFEASIBLE
            active = None
        if active is None:
            active = active_set(f, f_min, f_max, tol)
        return AllocationResult(
            f=f,
            feasible=status != INFEASIBLE,
            status=status,
            residual=residual,
            active=active,
            iterations=iterations,
            solve_time=perf_counter() - t0,
            solver=self.name,
        )

    def solve_batch(
        self,
        M: ArrayLike,
        b: ArrayLike,
        f_min: ArrayLike,
        f_max: ArrayLike,
        *,
        f_ref: ArrayLike | str | None = None,
    ) -> BatchAllocationResult:
        """Allocate forces for N problems (this default loops over ``solve``).

        Args:
            M: Shape (N, n, m).
            b: Shape (N, n).
            f_min: Lower bounds [N], shape (m,), (N, m) or scalar.
            f_max: Upper bounds [N], shape (m,), (N, m) or scalar.
            f_ref: Reference forces [N], shape (m,) or (N, m), or ``"midpoint"`` (of each
                problem's bounds), overriding the spec's.

        Returns:
            The N answers as arrays.

        Raises:
            InputError: On wrong shapes, NaN or infinite values, or f_min > f_max.
        """
        t0 = perf_counter()
        M, b, lo, hi = validate_batch(self.spec, M, b, f_min, f_max)
        count, m = M.shape[0], self.n_actuators
        refs = None
        if f_ref is not None:
            refs = np.broadcast_to(self._reference(lo, hi, f_ref), (count, m))
        f = np.empty((count, m))
        feasible = np.empty(count, dtype=bool)
        status = np.empty(count, dtype="<U11")
        residual = np.empty(count)
        active = np.empty((count, m), dtype=np.int8)
        iterations = np.empty(count, dtype=np.int64)
        for i in range(count):
            res = self.solve(M[i], b[i], lo[i], hi[i], f_ref=None if refs is None else refs[i])
            f[i], feasible[i], status[i] = res.f, res.feasible, res.status
            residual[i], active[i], iterations[i] = res.residual, res.active, res.iterations
        return BatchAllocationResult(
            f, feasible, status, residual, active, iterations, perf_counter() - t0, self.name
        )
