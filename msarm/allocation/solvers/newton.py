"""The compiled path: one problem by the dual Newton method, in numba (the control loop's solver).

The same method as the batched path (:mod:`msarm.allocation.batched`), written for a single
problem as one compiled function, :func:`dual_newton_tick`, that a compiled control loop can
call without the interpreter (:mod:`msarm.tasks.compiled_loop`) and that
:class:`NewtonAllocator` calls for one tick from Python. Scaled to an identity Hessian,
``x = W (f - f_ref)``::

    minimise 1/2 ||x||^2   subject to   A x = c,   lo <= x <= hi
    A = M W^-1,  c = b - M f_ref,  lo = W (f_min - f_ref),  hi = W (f_max - f_ref)

the dual in the multipliers lambda (n,) is maximised by semismooth Newton steps:
``x(lambda) = clip(A^T lambda, lo, hi)``, gradient ``r = c - A x``, generalised Hessian
``A D A^T + reg I`` (D the free entries, ``reg = max(REG tr(A A^T), REG_FLOOR)``), solved by a
Cholesky factorisation. A full step is taken where the dual still rises at its end (or ends
higher), else the exact line search over the breakpoints of the piecewise-linear directional
derivative.
It starts from the unconstrained minimum-norm solution and stops when
``||A x - c||_inf <= CONV_TOL (1 + ||c||_inf)``: with the right active set the last step
solved the KKT system to round-off, so x is the optimum. Forces at a bound are then exactly on
it, and the others within the bounds. A NaN residual never converges: it ends the iterations
with :data:`NOT_CONVERGED` (``M ~ 0`` once made the regulariser underflow to 0, the multipliers
NaN, and NaN forces came back as the optimum).

What it cannot settle it does not guess: a problem proven infeasible (Farkas test along the
Newton direction), a stall of the line search, a failed factorisation or ``MAX_ITER``
iterations without convergence return a negative code, and :class:`NewtonAllocator` (through
``Allocator.solve``) hands the tick to DAQP and then to the bounded least squares, as every
solver does.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numba
import numpy as np

from msarm.allocation.batched import CONV_TOL, MAX_ITER, REG, REG_FLOOR
from msarm.allocation.problem import OPTIMAL, AllocationSpec
from msarm.allocation.solvers.base import Allocator, FloatArray, MethodOutput
from msarm.numba_cache import drop_stale_kernels
from msarm.small_linalg import cholesky_solve

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = ["INFEASIBLE_CODE", "NOT_CONVERGED", "NewtonAllocator", "dual_newton_tick"]

NOT_CONVERGED = -1
"""Return code of :func:`dual_newton_tick`: no answer (stall, factorisation, iterations)."""
INFEASIBLE_CODE = -2
"""Return code of :func:`dual_newton_tick`: the problem is proven infeasible."""


@numba.njit(cache=True)
def _hessian(A, free, reg, K):  # pragma: no cover - compiled
    """``K = A D A^T + reg I``, D the diagonal 0/1 matrix of the ``free`` entries ``(m,)``."""
    n, m = A.shape
    for i in range(n):
        for k in range(i + 1):
            s = 0.0
            for j in range(m):
                if free[j]:
                    s += A[i, j] * A[k, j]
            K[i, k] = s
            K[k, i] = s
        K[i, i] += reg


@numba.njit(cache=True)
def _transposed_product(A, v, out):  # pragma: no cover - compiled
    """``out = A^T v``, shapes ``(n, m)``, ``(n,)`` -> ``(m,)``."""
    n, m = A.shape
    for j in range(m):
        total = 0.0
        for i in range(n):
            total += A[i, j] * v[i]
        out[j] = total


@numba.njit(cache=True)
def _clip_and_residual(A, c, y, lo, hi, x, r):  # pragma: no cover - compiled
    """``x = clip(y, lo, hi)`` and ``r = c - A x``; returns ``||r||_inf`` (NaN if r has one)."""
    n, m = A.shape
    for j in range(m):
        x[j] = min(max(y[j], lo[j]), hi[j])
    worst = 0.0
    for i in range(n):
        s = c[i]
        for j in range(m):
            s -= A[i, j] * x[j]
        r[i] = s
        a = abs(s)
        if a > worst or a != a:  # a NaN stays (max() would drop it and claim convergence)
            worst = a
    return worst


@numba.njit(cache=True)
def _dual_value(lam, c, y, x):  # pragma: no cover - compiled
    """The dual function ``lambda . c - sum(y x - x^2 / 2)`` at ``y = A^T lambda``."""
    value = 0.0
    for i in range(lam.shape[0]):
        value += lam[i] * c[i]
    for j in range(y.shape[0]):
        value -= y[j] * x[j] - 0.5 * x[j] * x[j]
    return value


@numba.njit(cache=True)
def _line_search(y, s, lo, hi, g0, times, deltas):  # pragma: no cover - compiled
    """Maximiser t > 0 of the dual along ``s = A^T delta`` (``inf`` if it rises for ever).

    The derivative along the direction, ``g0 - sum_j s_j (clip(y_j + t s_j) - clip(y_j))``,
    is piecewise linear and non-increasing; its slope changes by ``-s_j^2`` where entry j
    enters the box and by ``+s_j^2`` where it leaves. Its root is found by walking the sorted
    breakpoints.
    """
    count = 0
    slope = 0.0
    for j in range(y.shape[0]):
        if s[j] == 0.0:
            continue
        ta = (lo[j] - y[j]) / s[j]
        tb = (hi[j] - y[j]) / s[j]
        t_enter, t_leave = min(ta, tb), max(ta, tb)
        s2 = s[j] * s[j]
        if t_enter <= 0.0 and t_leave > 0.0:
            slope -= s2
        if t_enter > 0.0:
            times[count], deltas[count] = t_enter, -s2
            count += 1
        if t_leave > 0.0:
            times[count], deltas[count] = t_leave, s2
            count += 1
    for e in range(1, count):  # insertion sort of the breakpoints (a dozen at most)
        t, d = times[e], deltas[e]
        k = e - 1
        while k >= 0 and times[k] > t:
            times[k + 1], deltas[k + 1] = times[k], deltas[k]
            k -= 1
        times[k + 1], deltas[k + 1] = t, d
    g, t_prev = g0, 0.0
    for e in range(count):
        g_next = g + slope * (times[e] - t_prev)
        if g_next <= 0.0:
            return t_prev - g / slope if slope < 0.0 else t_prev
        g, t_prev = g_next, times[e]
        slope += deltas[e]
    return t_prev - g / slope if slope < 0.0 else math.inf


@numba.njit(cache=True)
def _farkas(delta, s, c, lo, hi):  # pragma: no cover - compiled
    """``delta^T c > max over the box of delta^T A x`` (with a margin): A x = c is infeasible."""
    box, box_abs, dc, dc_abs = 0.0, 0.0, 0.0, 0.0
    for j in range(s.shape[0]):
        term = max(lo[j] * s[j], hi[j] * s[j])
        box += term
        box_abs += abs(term)
    for i in range(c.shape[0]):
        dc += delta[i] * c[i]
        dc_abs += abs(delta[i] * c[i])
    return dc - box > 1e-10 * (box_abs + dc_abs) + 1e-300


@numba.njit(cache=True)
def dual_newton_tick(M, b, w, f_ref, f_min, f_max, f, active, max_iter):  # pragma: no cover
    """Solve ``min 1/2 ||W (f - f_ref)||^2 s.t. M f = b, f_min <= f <= f_max`` (compiled).

    Args:
        M: Shape (n, m), of full row rank for a guaranteed answer.
        b: Shape (n,).
        w: Diagonal of W [1/N], shape (m,), > 0.
        f_ref: Reference force [N], shape (m,).
        f_min: Lower bounds [N], shape (m,).
        f_max: Upper bounds [N], shape (m,), >= f_min.
        f: Forces [N], shape (m,), written where the return is >= 0.
        active: Active set, shape (m,) int8, written with f: -1 at f_min, +1 at f_max, else 0.
        max_iter: Newton iterations before giving up.

    Returns:
        The number of Newton iterations (>= 0) at the optimum; :data:`NOT_CONVERGED` or
        :data:`INFEASIBLE_CODE` when there is no answer (f is then not written).
    """
    n, m = M.shape
    A = np.empty((n, m))
    c = np.empty(n)
    lo, hi = np.empty(m), np.empty(m)
    for i in range(n):
        s = b[i]
        for j in range(m):
            A[i, j] = M[i, j] / w[j]
            s -= M[i, j] * f_ref[j]
        c[i] = s
    c_max = 0.0
    for i in range(n):
        c_max = max(c_max, abs(c[i]))
    for j in range(m):
        lo[j] = w[j] * (f_min[j] - f_ref[j])
        hi[j] = w[j] * (f_max[j] - f_ref[j])
    K = np.empty((n, n))
    free = np.ones(m, dtype=np.bool_)
    _hessian(A, free, 0.0, K)  # A A^T
    trace = 0.0
    for i in range(n):
        trace += K[i, i]
    reg = max(REG * trace, REG_FLOOR)  # a normal number: M ~ 0 gave 0 and NaN forces
    for i in range(n):
        K[i, i] += reg
    lam, delta, r, r1 = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    y, x, s, y1, x1 = np.empty(m), np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    times, deltas = np.empty(2 * m), np.empty(2 * m)
    if not cholesky_solve(K, c, lam):
        return NOT_CONVERGED
    _transposed_product(A, lam, y)
    worst = _clip_and_residual(A, c, y, lo, hi, x, r)
    tol = CONV_TOL * (1.0 + c_max)
    for it in range(max_iter + 1):
        if worst <= tol:  # False for NaN
            for j in range(m):
                if y[j] < lo[j]:
                    f[j], active[j] = f_min[j], -1
                elif y[j] > hi[j]:
                    f[j], active[j] = f_max[j], 1
                else:  # y within [lo, hi]: only the round-off of f_ref + y / w can step out
                    f[j], active[j] = min(max(f_ref[j] + y[j] / w[j], f_min[j]), f_max[j]), 0
            return it
        if it == max_iter or not math.isfinite(worst):
            break
        for j in range(m):
            free[j] = y[j] > lo[j] and y[j] < hi[j]
        _hessian(A, free, reg, K)
        if not cholesky_solve(K, r, delta):
            break
        _transposed_product(A, delta, s)
        for j in range(m):
            y1[j] = y[j] + s[j]
        if _farkas(delta, s, c, lo, hi):
            return INFEASIBLE_CODE
        worst1 = _clip_and_residual(A, c, y1, lo, hi, x1, r1)
        rise = 0.0
        for i in range(n):
            rise += delta[i] * r1[i]
        d0 = _dual_value(lam, c, y, x) if rise < 0.0 else 0.0  # only asked when rise < 0
        for i in range(n):
            lam[i] += delta[i]
        if rise >= 0.0 or _dual_value(lam, c, y1, x1) > d0 + 1e-12 * abs(d0):
            for j in range(m):
                y[j], x[j] = y1[j], x1[j]
            for i in range(n):
                r[i] = r1[i]
            worst = worst1
            continue
        g0 = 0.0
        for i in range(n):
            g0 += r[i] * delta[i]
        t = _line_search(y, s, lo, hi, g0, times, deltas)
        if not (math.isfinite(t) and t > 0.0):
            break  # a stall, or an unbounded rise without a certificate (round-off)
        for i in range(n):
            lam[i] += (t - 1.0) * delta[i]
        for j in range(m):
            y[j] += t * s[j]
        worst = _clip_and_residual(A, c, y, lo, hi, x, r)
    return NOT_CONVERGED


class NewtonAllocator(Allocator):
    """Exact allocation by the compiled dual Newton method (the arm controller's solver).

    Falls back to DAQP, then to the bounded least squares, on the ticks it cannot settle.

    Args:
        spec: Sizes, weights, reference force and tolerance.
    """

    name: ClassVar[str] = "newton"
    exact: ClassVar[bool] = True

    def __init__(self, spec: AllocationSpec) -> None:
        super().__init__(spec)
        self._f = np.empty(spec.n_actuators)
        self._active = np.empty(spec.n_actuators, dtype=np.int8)

    def _solve(
        self, M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, f_ref: FloatArray
    ) -> MethodOutput:
        code = dual_newton_tick(
            M, b, self._weights, f_ref, f_min, f_max, self._f, self._active, MAX_ITER
        )
        if code < 0:
            return None, OPTIMAL, 0, None
        return self._f.copy(), OPTIMAL, code, self._active.copy()
