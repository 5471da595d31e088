"""The batched path: N allocation problems solved at once, vectorised over the batch in NumPy.

For workspace maps and data generation, where thousands of problems arrive together. Each
problem is first scaled to an identity Hessian, ``x = W (f - f_ref)``::

    minimise 1/2 ||x||^2   subject to   A x = c,   lo <= x <= hi
    A = M W^-1,  c = b - M f_ref,  lo = W (f_min - f_ref),  hi = W (f_max - f_ref)

Its dual is unconstrained: for multipliers lambda (n,) the minimising x is
``x(lambda) = clip(A^T lambda, lo, hi)`` and the concave, piecewise-quadratic dual function has
gradient ``c - A x(lambda)``. A semismooth Newton method (a "dual Newton" method, as in
qpDUNES) maximises it, all problems in lockstep: the generalised Hessian is ``A D A^T`` with D
the free (unclipped) entries, regularised by 1e-14 tr(A A^T), at least 1e-300 (it is singular
while fewer than n entries are free). A step is taken in full where the dual still rises at its
end (or ends higher), else after an *exact* line search over the breakpoints of the
piecewise-linear directional derivative (sorted, prefix sums). It starts from the
unconstrained minimum-norm solution, so a problem with no active bound ends after 0
iterations.

Exactness: at every iterate ``x = clip(A^T lambda)`` meets the bounds exactly, and the sign
conditions of the bound multipliers hold by construction; so once ``A x = c`` holds (to
1e-13 relative) x is the optimum: the last Newton step, taken with the right active set,
solves the KKT system to round-off. Forces at a bound are then set to the bound exactly.

Infeasibility: where the dual grows without bound, the Newton direction z soon proves it,
``z^T c > max over the box of z^T A x`` (Farkas, tested with a margin each iteration); such
problems get the bounded least-squares fallback.

Hand-off: the lockstep loop stops once an iteration converges too few problems to pay for
the next one (cost model ``HANDOFF_COST``, ``ITER_OVERHEAD``: a DAQP solve costs about six
problem-iterations); the rest, and those still unconverged after ``MAX_ITER``, go through
DAQP in a tight loop (``DaqpAllocator.solve_many``), so every answer is exact either way.
"""

from __future__ import annotations

import math
from time import perf_counter
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.allocation.fallback import bounded_least_squares
from msarm.allocation.problem import (
    FALLBACK,
    INFEASIBLE,
    OPTIMAL,
    AllocationResult,
    AllocationSpec,
    BatchAllocationResult,
    active_set,
    validate_batch,
    validate_tick,
)
from msarm.allocation.solution_check import residual_limit, residual_limits
from msarm.allocation.solvers.base import Allocator, FloatArray, MethodOutput
from msarm.allocation.solvers.daqp_solver import DaqpAllocator

__all__ = [
    "CONV_TOL",
    "HANDOFF_COST",
    "ITER_OVERHEAD",
    "MAX_ITER",
    "REG",
    "REG_FLOOR",
    "BatchedAllocator",
    "dual_newton",
]

MAX_ITER = 15
"""Newton iterations after which a problem goes to the DAQP path."""
REG = 1e-14
"""Regularisation of the generalised Hessian, relative to tr(A A^T)."""
REG_FLOOR = 1e-300
"""Least regularisation (a normal number: ``REG tr(A A^T)`` underflows for ``M ~ 0``)."""
HANDOFF_COST = 6.0
"""Cost of one DAQP solve, in units of one problem's share of a Newton iteration."""
ITER_OVERHEAD = 100.0
"""Fixed cost of one vectorised Newton iteration, in the same units."""
CONV_TOL = 1e-13
"""Convergence: ||A x - c||_inf <= CONV_TOL (1 + ||c||_inf)."""


def _exact_line_search(
    y: FloatArray, s: FloatArray, lo: FloatArray, hi: FloatArray, g0: FloatArray
) -> FloatArray:
    """Maximiser t > 0 of the dual along a direction, for each problem of the batch.

    The dual's derivative along the direction is ``phi'(t) = g0 - sum_i s_i (clip(y_i +
    t s_i, l_i, u_i) - clip(y_i, l_i, u_i))``: continuous, piecewise linear, non-increasing,
    with slope ``-sum s_i^2`` over the entries free in each piece. Its root is found from the
    sorted breakpoints where entries enter or leave their bounds.

    Args:
        y: A^T lambda, shape (N, m).
        s: A^T delta (delta the Newton direction), shape (N, m).
        lo: Lower bounds of x, shape (N, m).
        hi: Upper bounds of x, shape (N, m).
        g0: phi'(0) = delta . (c - A x) > 0, shape (N,).

    Returns:
        Step lengths, shape (N,); ``inf`` where phi' stays positive for ever (the dual is
        unbounded: the problem is infeasible).
    """
    count = y.shape[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - y) / s
        tb = (hi - y) / s
    t_enter = np.minimum(ta, tb)
    t_leave = np.maximum(ta, tb)
    moving = s != 0.0
    s2 = s * s
    free0 = moving & (t_enter <= 0.0) & (t_leave > 0.0)
    slope0 = -(s2 * free0).sum(axis=1)
    events = np.concatenate(
        [
            np.where(moving & (t_enter > 0.0), t_enter, np.inf),
            np.where(moving & (t_leave > 0.0), t_leave, np.inf),
        ],
        axis=1,
    )
    deltas = np.concatenate([-s2, s2], axis=1)
    order = np.argsort(events, axis=1)
    ts = np.take_along_axis(events, order, axis=1)
    ds = np.take_along_axis(deltas, order, axis=1)
    finite = np.isfinite(ts)
    ds = np.where(finite, ds, 0.0)
    t_last = np.where(finite, ts, 0.0).max(axis=1)
    ts = np.where(finite, ts, t_last[:, None])
    slope_after = slope0[:, None] + np.cumsum(ds, axis=1)
    slope_before = np.concatenate([slope0[:, None], slope_after[:, :-1]], axis=1)
    t_before = np.concatenate([np.zeros((count, 1)), ts[:, :-1]], axis=1)
    g = g0[:, None] + np.cumsum(slope_before * (ts - t_before), axis=1)
    hit = g <= 0.0
    any_hit = hit.any(axis=1)
    k = np.argmax(hit, axis=1)
    rows = np.arange(count)
    g_prev = np.where(k > 0, g[rows, np.maximum(k - 1, 0)], g0)
    sl = slope_before[rows, k]
    t_hit = t_before[rows, k] - g_prev / np.where(sl < 0.0, sl, -1.0)
    s_end, g_end = slope_after[:, -1], g[:, -1]
    t_end = np.where(s_end < 0.0, ts[:, -1] - g_end / np.where(s_end < 0.0, s_end, -1.0), np.inf)
    return np.where(any_hit, t_hit, t_end)


def _farkas(
    z: FloatArray, Atz: FloatArray, c: FloatArray, lo: FloatArray, hi: FloatArray
) -> NDArray[np.bool_]:
    """Farkas test: ``z^T c > max over lo <= x <= hi of z^T A x`` proves ``A x = c`` infeasible.

    Args:
        z: Candidate multipliers, shape (N, n).
        Atz: ``A^T z``, shape (N, m).
        c: Shape (N, n).
        lo: Shape (N, m).
        hi: Shape (N, m).

    Returns:
        Shape (N,) bool: True where the test proves infeasibility (with a margin of 1e-10
        times the sums of the absolute terms, far above round-off).
    """
    terms = np.maximum(lo * Atz, hi * Atz)
    zc_terms = z * c
    # Margin: far above the round-off of both sums (relative to their absolute terms).
    margin = 1e-10 * (np.abs(terms).sum(axis=1) + np.abs(zc_terms).sum(axis=1)) + 1e-300
    return zc_terms.sum(axis=1) - terms.sum(axis=1) > margin


def _take(keep: NDArray[np.bool_], arrays: tuple) -> tuple:
    """Keep the rows ``keep`` of every array of the iteration state."""
    return tuple(a[keep] for a in arrays)


def dual_newton(
    A: FloatArray,
    c: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    *,
    max_iter: int = MAX_ITER,
    handoff_cost: float | None = HANDOFF_COST,
) -> tuple[FloatArray, NDArray[np.bool_], NDArray[np.int64], FloatArray, NDArray[np.bool_]]:
    """Solve N problems ``min 1/2 ||x||^2  s.t.  A x = c, lo <= x <= hi`` at once.

    Each iteration takes the full Newton step where it does not overshoot the maximum of
    the dual along the direction (the directional derivative there is still >= 0), and the
    exact line search elsewhere.

    Args:
        A: Shape (N, n, m), each of full row rank for a guaranteed answer.
        c: Shape (N, n).
        lo: Shape (N, m).
        hi: Shape (N, m), >= lo.
        max_iter: Newton iterations before giving up on a problem.
        handoff_cost: Stop early, leaving the remaining problems unconverged, once an
            iteration converges too few of them to pay for the next one: when
            ``handoff_cost * newly_converged < remaining + ITER_OVERHEAD`` (costs in units of
            one problem's share of an iteration; ``handoff_cost`` is what solving one
            problem elsewhere costs). ``None`` iterates up to ``max_iter``.

    Returns:
        ``(x, converged, iterations, y, infeasible)``: x of shape (N, m) (zero where not
        converged), converged (N,) bool, iterations (N,), ``y = A^T lambda`` (N, m) whose
        entries outside [lo, hi] mark the active bounds, and infeasible (N,) bool: problems
        proven infeasible (the dual grows without bound along a direction z for which
        ``z^T c > max_box z^T A x``, a Farkas certificate).
    """
    count, n, m = A.shape
    x_out = np.zeros((count, m))
    y_out = np.zeros((count, m))
    converged = np.zeros(count, dtype=bool)
    infeasible = np.zeros(count, dtype=bool)
    iterations = np.full(count, max_iter, dtype=np.int64)
    if count == 0:
        return x_out, converged, iterations, y_out, infeasible
    eye = np.eye(n)
    At = A.transpose(0, 2, 1)
    G = A @ At
    reg = np.maximum(REG * np.einsum("kii->k", G), REG_FLOOR)[:, None, None] * eye
    lam = np.linalg.solve(G + reg, c[..., None])[..., 0]
    tol = CONV_TOL * (1.0 + np.abs(c).max(axis=1))
    idx = np.arange(count)
    y = (At @ lam[..., None])[..., 0]
    x = np.clip(y, lo, hi)
    r = c - (A @ x[..., None])[..., 0]
    state = (idx, A, At, c, lo, hi, reg, tol, lam, y, x, r)
    for it in range(max_iter + 1):
        idx, A, At, c, lo, hi, reg, tol, lam, y, x, r = state
        done = np.abs(r).max(axis=1) <= tol
        n_done = int(done.sum())
        if (
            handoff_cost is not None
            and it >= 1
            and handoff_cost * n_done < idx.size - n_done + ITER_OVERHEAD
        ):
            max_iter = it  # the rest is cheaper elsewhere
        if n_done:
            hit = idx[done]
            x_out[hit], y_out[hit] = x[done], y[done]
            converged[hit], iterations[hit] = True, it
            state = _take(~done, state)
            idx, A, At, c, lo, hi, reg, tol, lam, y, x, r = state
        if idx.size == 0 or it == max_iter:
            iterations[idx] = it
            break
        free = ((y > lo) & (y < hi)).astype(np.float64)
        K = (A * free[:, None, :]) @ At + reg
        delta = np.linalg.solve(K, r[..., None])[..., 0]
        s = (At @ delta[..., None])[..., 0]
        # Farkas test along the Newton direction: where the dual grows without bound (an
        # infeasible problem) the direction is, or soon becomes, a certificate.
        proven = _farkas(delta, s, c, lo, hi)
        if proven.any():
            infeasible[idx[proven]] = True
            iterations[idx[proven]] = it
            keep = ~proven
            state, delta, s = _take(keep, state), delta[keep], s[keep]
            idx, A, At, c, lo, hi, reg, tol, lam, y, x, r = state
            if idx.size == 0:
                break
        y1 = y + s
        x1 = np.clip(y1, lo, hi)
        r1 = c - (A @ x1[..., None])[..., 0]
        # Full step where the dual still rises at t = 1 or ends higher than it started (a
        # primal-dual active-set step); the exact line search elsewhere.
        d0 = (lam * c).sum(axis=1) - (y * x - 0.5 * x * x).sum(axis=1)
        d1 = ((lam + delta) * c).sum(axis=1) - (y1 * x1 - 0.5 * x1 * x1).sum(axis=1)
        full = ((delta * r1).sum(axis=1) >= 0.0) | (d1 > d0 + 1e-12 * np.abs(d0))
        lam1 = lam + delta
        if not full.all():
            part = ~full
            g0 = (r[part] * delta[part]).sum(axis=1)
            t = _exact_line_search(y[part], s[part], lo[part], hi[part], g0)
            # t = inf without a certificate (round-off) or t = 0 (a stall): leave the
            # problem to the DAQP path, marked by a zero step and dropped below.
            stalled = ~(np.isfinite(t) & (t > 0.0))
            tp = np.where(stalled, 0.0, t)[:, None]
            lam1[part] = lam[part] + tp * delta[part]
            y1[part] = y[part] + tp * s[part]
            x1[part] = np.clip(y1[part], lo[part], hi[part])
            r1[part] = c[part] - (A[part] @ x1[part][..., None])[..., 0]
            state = (idx, A, At, c, lo, hi, reg, tol, lam1, y1, x1, r1)
            if stalled.any():
                keep = np.ones(idx.size, dtype=bool)
                keep[np.flatnonzero(part)[stalled]] = False
                iterations[idx[~keep]] = it
                state = _take(keep, state)
                if state[0].size == 0:
                    break
        else:
            state = (idx, A, At, c, lo, hi, reg, tol, lam1, y1, x1, r1)
    return x_out, converged, iterations, y_out, infeasible


class BatchedAllocator(Allocator):
    """Exact allocation of many problems at once (dual Newton, vectorised over the batch).

    ``solve_batch`` is the point of this class; ``solve`` works (a batch of one) but the
    fast path is quicker for a single tick.

    Args:
        spec: Sizes, weights, reference force and tolerance.
    """

    name: ClassVar[str] = "batched"
    exact: ClassVar[bool] = True

    def __init__(self, spec: AllocationSpec) -> None:
        super().__init__(spec)
        self._single = DaqpAllocator(spec)

    def _solve(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> MethodOutput:  # pragma: no cover - solve() is overridden
        return self._single._solve(M, b, f_min, f_max, f_ref)

    def solve(
        self,
        M: ArrayLike,
        b: ArrayLike,
        f_min: ArrayLike,
        f_max: ArrayLike,
        *,
        f_ref: ArrayLike | str | None = None,
    ) -> AllocationResult:
        """One tick through the batched path (a batch of one); see ``Allocator.solve``.

        Args:
            M: Shape (n, m): ``-J_c^T`` for the arm, ``A^T`` for a cable robot.
            b: Shape (n,): joint torques [N m] for the arm, ``-w`` for a cable robot.
            f_min: Lower force bounds [N], shape (m,) or scalar, finite.
            f_max: Upper force bounds [N], shape (m,) or scalar, finite, >= f_min.
            f_ref: Overrides the spec's reference force for this tick: forces [N], shape
                (m,), or ``"midpoint"`` (of this tick's bounds).

        Returns:
            The forces and how they were found (the batch's single answer, with the time of
            this whole call).

        Raises:
            InputError: On wrong shapes, NaN or infinite values, or f_min > f_max.
        """
        t0 = perf_counter()
        M, b, lo, hi = validate_tick(self.spec, M, b, f_min, f_max)
        ref = None if f_ref is None else self._reference(lo, hi, f_ref)
        batch = self.solve_batch(M[None], b[None], lo, hi, f_ref=None if ref is None else ref[None])
        res = batch[0]
        return AllocationResult(
            res.f,
            res.feasible,
            res.status,
            res.residual,
            res.active,
            res.iterations,
            perf_counter() - t0,
            self.name,
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
        """Allocate forces for N problems at once.

        Args:
            M: Shape (N, n, m).
            b: Shape (N, n).
            f_min: Lower bounds [N], shape (m,), (N, m) or scalar.
            f_max: Upper bounds [N], shape (m,), (N, m) or scalar.
            f_ref: Reference forces [N], shape (m,) or (N, m), or ``"midpoint"`` (of each
                problem's bounds), overriding the spec's.

        Returns:
            The N answers; each equal to what the fast path gives for that problem, to
            round-off (about 1e-12 relative: another order of the same arithmetic).

        Raises:
            InputError: On wrong shapes, NaN or infinite values, or f_min > f_max.
        """
        t0 = perf_counter()
        M, b, lo, hi = validate_batch(self.spec, M, b, f_min, f_max)
        count, m = M.shape[0], self.n_actuators
        ref = np.broadcast_to(
            self.spec.reference(lo, hi) if f_ref is None else self._reference(lo, hi, f_ref),
            (count, m),
        )
        w = self._weights
        A = M / w
        c = b - (M @ ref[..., None])[..., 0]
        x, converged, iterations, y, infeasible = dual_newton(A, c, w * (lo - ref), w * (hi - ref))
        active = (y >= w * (hi - ref)).astype(np.int8) - (y <= w * (lo - ref)).astype(np.int8)
        # Forces at a bound are the bound exactly (x / w + ref would round); the others, x
        # within its bounds, are clipped only of the rounding of ref + x / w.
        f = np.where(active < 0, lo, np.where(active > 0, hi, np.clip(ref + x / w, lo, hi)))
        r = (M @ f[..., None])[..., 0] - b
        residual = np.sqrt((r * r).sum(axis=1))
        converged &= residual <= residual_limits(M, b, f, self._tol)
        status = np.full(count, OPTIMAL, dtype="<U11")
        feasible = np.ones(count, dtype=bool)
        rest = np.flatnonzero(~converged & ~infeasible)
        if rest.size:
            f_r, solved, active_r, it_r = self._single.solve_many(
                M[rest], b[rest], lo[rest], hi[rest], ref[rest]
            )
            iterations[rest] += it_r
            good = rest[solved]
            f[good], active[good] = f_r[solved], active_r[solved]
            r = (M[good] @ f[good][..., None])[..., 0] - b[good]
            residual[good] = np.sqrt((r * r).sum(axis=1))
            ok = residual[good] <= residual_limits(M[good], b[good], f[good], self._tol)
            infeasible[rest[~solved]] = True  # DAQP found none: least squares
            infeasible[good[~ok]] = True
        for i in np.flatnonzero(infeasible):
            fi, extra = bounded_least_squares(M[i], b[i], lo[i], hi[i], w, ref[i])
            e = M[i] @ fi - b[i]
            f[i], residual[i] = fi, math.sqrt(e @ e)
            feasible[i] = residual[i] <= residual_limit(M[i], b[i], fi, self._tol)
            status[i] = FALLBACK if feasible[i] else INFEASIBLE
            active[i] = active_set(fi, lo[i], hi[i], self._tol)
            iterations[i] += extra
        return BatchAllocationResult(
            f, feasible, status, residual, active, iterations, perf_counter() - t0, self.name
        )
