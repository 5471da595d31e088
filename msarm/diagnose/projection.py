"""The joint fit of a coupled set of terms: IPOPT on the nonlinear parameters, linear eliminated.

A set of candidate terms whose predictions share residual columns (a Stribeck friction beside a
Dahl friction on the same joints) has to be fitted jointly: fitting one block after the other
(backfitting) converges slowly when the blocks are correlated and stops short of the optimum.
Variable projection (Golub and Pereyra, 1973) finds the joint optimum in one solve: for fixed
nonlinear parameters ``theta_N`` the best linear parameters are a weighted least squares, so the
objective of ``theta_N`` alone is what that least squares leaves,

``J(theta_N) = sum w e^2 - b^T G^+ b``,  ``e = r - f(theta_N)``,  ``b = A^T W e``,
``G = A^T W A``,

with ``A`` the linear terms' stacked design (columns normalised), ``W`` the per-sample weights
and ``G^+`` the pseudo-inverse from :class:`~msarm.diagnose.fitting.LinearSolver`'s thin SVD
of ``W^(1/2) A`` (its cut, its zero rows left out). IPOPT (exact Hessian, within the
nonlinear terms' bounds) minimises ``J / sum w r^2``; the linear parameters are then the least
squares at the optimum, ``G^+ b``. The problem is built once for a set of terms and samples and
solved for any residual, weights and start (the weights, residual and ``G^+`` are NLP
parameters), so a bootstrap reuses it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import casadi
import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.effects import CandidateEffect
from msarm.diagnose.fitting import LinearSolver, bounds_of, column_scale, stacked_constraints
from msarm.diagnose.nlp import DataOps, shared_solver
from msarm.diagnose.signals import Signals
from msarm.errors import InputError
from msarm.interrupts import raise_if_terminated

__all__ = ["ProjectedProblem"]

FloatArray = NDArray[np.float64]


class ProjectedProblem:
    """Variable projection of one coupled set on fixed training samples (see the module).

    Args:
        nonlinear: The nonlinear terms, each predicting the residual columns ``columns_of[k]``
            (``term.torque(signals, theta, ops)`` gives those columns, ``(T, k)``).
        columns_of: The residual columns of each nonlinear term, in its output's order.
        columns: Every residual column of the set (the union of the nonlinear terms' and the
            linear design's), ``(C,)``.
        design: The linear terms' stacked design on ``columns``, ``(T, C, p)``, or None.
        signals: The training samples' signals, ``T`` of them.
    """

    def __init__(
        self,
        nonlinear: Sequence[CandidateEffect],
        columns_of: Sequence[NDArray[np.intp]],
        columns: NDArray[np.intp],
        design: FloatArray | None,
        signals: Signals,
    ) -> None:
        if not nonlinear:
            raise InputError("ProjectedProblem: the set has no nonlinear term")
        self.nonlinear = tuple(nonlinear)
        self.columns = np.asarray(columns, dtype=np.intp)
        T, C = signals.n_samples, len(self.columns)
        self.shape = (T, C)
        self.sizes = [t.n_parameters for t in self.nonlinear]
        p = 0 if design is None else design.shape[2]
        if design is not None:
            if design.shape[:2] != (T, C):
                raise InputError(f"design: expected shape ({T}, {C}, p), got {design.shape}")
            self.scale = column_scale(design.reshape(-1, p))
            #: The normalised design, column after column (casadi's ``vec`` order), ``(C T, p)``.
            self.flat = np.ascontiguousarray(design.transpose(1, 0, 2)).reshape(-1, p) / self.scale
        position = {int(c): k for k, c in enumerate(self.columns)}
        #: Where each nonlinear term's columns sit among ``columns``.
        self._own = [np.array([position[int(c)] for c in own], dtype=np.intp) for own in columns_of]
        ops = DataOps()
        thetas = [casadi.MX.sym(f"theta{k}", n) for k, n in enumerate(self.sizes)]
        parts: list[list[Any]] = [[] for _ in range(C)]
        for term, own, theta in zip(self.nonlinear, columns_of, thetas, strict=True):
            out = term.torque(signals, theta, ops)
            for j, c in enumerate(own):
                parts[position[int(c)]].append(out[:, j])
        zero = casadi.DM.zeros(T, 1)
        predicted = casadi.horzcat(*[sum(ps[1:], ps[0]) if ps else zero for ps in parts])
        target = casadi.MX.sym("r", T, C)
        weights = casadi.MX.sym("w", T)
        inverse = casadi.MX.sym("g", p, p)
        x = casadi.vertcat(*thetas)
        flat = ops.const(self.flat) if p else None
        self.solver, self.data, self.constraint_bounds = shared_solver(
            "fit_projected", x, [weights, target, inverse],
            _objective(predicted, target, weights, inverse, flat), ops,
            stacked_constraints(self.nonlinear),
        )  # fmt: skip
        bounds = [bounds_of(t) for t in self.nonlinear]
        self.lower = np.concatenate([low for low, _ in bounds])
        self.upper = np.concatenate([high for _, high in bounds])
        self.p = p
        self._unweighted: LinearSolver | None = None

    def _solver(self, root: FloatArray | None) -> LinearSolver:
        """The least squares of the normalised design weighted by rows ``root`` (``sqrt w``)."""
        if root is None and self._unweighted is not None:
            return self._unweighted
        flat = self.flat if root is None else self.flat * root[:, None]
        solver = LinearSolver(flat[:, None, :])
        if root is None:
            self._unweighted = solver
        return solver

    def solve(
        self,
        residual: FloatArray,
        predict: Sequence[Any],
        initial: Sequence[FloatArray],
        weights: FloatArray | None = None,
    ) -> tuple[list[FloatArray], FloatArray, str]:
        """The joint optimum for ``residual`` on the set's columns.

        Args:
            residual: The residual on ``columns``, ``(T, C)``.
            predict: For each nonlinear term, a function of its parameters giving its
                prediction on its columns ``(T, k)`` (numpy), to compute the linear part.
            initial: Start of each nonlinear term's parameters.
            weights: Per-sample weights ``(T,)``; all 1 when None.

        Returns:
            ``(nonlinear, linear, status)``: each nonlinear term's parameters, the linear
            terms' stacked parameters ``(p,)`` (in the design's units) and IPOPT's status.
        """
        residual = np.asarray(residual, dtype=float)
        if residual.shape != self.shape:
            raise InputError(f"residual: expected shape {self.shape}, got {residual.shape}")
        T, C = self.shape
        w = np.ones(T) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != (T,) or not np.all(w >= 0):
            raise InputError(f"weights: expected {T} values >= 0, got shape {w.shape}")
        root = None if weights is None else np.tile(np.sqrt(w), C)  # by row of the flat design
        inverse = np.zeros((0, 0))
        if self.p:  # G^+ = M M^T of the factored weighted design, M = V S^-1 / its scale
            solver = self._solver(root)
            factor = solver.v_over_s / solver.scale[:, None]
            inverse = factor @ factor.T
        start = np.concatenate([np.asarray(x, dtype=float) for x in initial])
        x0 = np.clip(start, self.lower, self.upper)
        values = np.concatenate(
            [w, residual.reshape(-1, order="F"), inverse.reshape(-1, order="F"), self.data]
        )
        solution = self.solver(
            x0=x0, p=values, lbx=self.lower, ubx=self.upper, **self.constraint_bounds
        )
        raise_if_terminated()  # IPOPT stops early on a SIGTERM and swallows its exception
        status = str(self.solver.stats()["return_status"])
        x = np.clip(np.asarray(solution["x"], dtype=float).reshape(-1), self.lower, self.upper)
        thetas = np.split(x, np.cumsum(self.sizes)[:-1])
        linear = np.zeros(0)
        if self.p:
            left = residual.copy()
            for k, theta in enumerate(thetas):
                left[:, self._own[k]] -= predict[k](theta)
            b = left.reshape(-1, 1, order="F")
            linear = solver.solve(b if root is None else b * root[:, None]) / self.scale
        return thetas, linear, status


def _objective(
    predicted: casadi.MX,
    target: casadi.MX,
    weights: casadi.MX,
    inverse: casadi.MX,
    flat: casadi.MX | None,
) -> casadi.MX:
    """The projected objective ``J / sum w r^2`` of the module's docstring.

    Args:
        predicted: The nonlinear terms' prediction ``f(x)``, ``(T, C)``.
        target: The residual ``r``, ``(T, C)``.
        weights: The per-sample weights, ``(T, 1)``.
        inverse: ``G^+``, ``(p, p)``.
        flat: The normalised design ``A`` column after column, ``(C T, p)``; None without.
    """
    error = casadi.vec(target - predicted)  # column by column: the design's row order
    w = casadi.repmat(weights, target.size2(), 1)
    objective = casadi.dot(w, error * error)
    if flat is not None:
        b = casadi.mtimes(flat.T, w * error)
        objective = objective - casadi.dot(b, casadi.mtimes(inverse, b))
    return objective / _reference(target, w)


def _reference(target: casadi.MX, w: casadi.MX) -> casadi.MX:
    """The objective's scale: the residual's weighted energy (at least 1e-300)."""
    return casadi.fmax(casadi.dot(w, casadi.vec(target) ** 2), 1e-300)
