"""Bounded least squares: the answer every solver gives when it cannot meet ``M f = b``.

When no force within the bounds meets ``M f = b`` (or a method fails to find one), a control
loop still needs forces. The fallback returns the bounded f that comes closest::

    minimise  1/2 ||M f - b||^2  over  f_min <= f <= f_max

Its minimisers are not unique (M has a null space); ties are broken towards the allocation's
own objective by the regularised problem::

    minimise  1/2 ||M f - b||^2 + eps/2 ||W (f - f_ref)||^2,   eps = EPS_REL tr(M^T M)/tr(W^2)

solved exactly by DAQP, then *polished*: with the bounds that are active there held fixed,
the remaining forces are the minimum-W-norm least-squares solution (no regularisation); a
force that then leaves its bounds is held at the bound it crosses and the rest solved again.
With the right bounds held this is the exact lexicographic optimum (closest to ``M f = b``
first, then smallest objective). The polished point is kept only if it lies within the bounds
and is no farther from ``M f = b``; else the regularised one, whose squared residual exceeds
the optimum by at most ``eps ||W (f* - f_ref)||^2``.

``Allocator.solve`` calls this after a method found no f and, for methods other than DAQP,
after DAQP's exact QP found none either; so a feasible problem gets the QP optimum, an
infeasible one the closest bounded f.
"""

from __future__ import annotations

import daqp
import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dgelsy

FloatArray = NDArray[np.float64]

__all__ = ["EPS_REL", "bounded_least_squares", "min_norm_lstsq", "polish_least_squares"]

EPS_REL = 1e-8
"""Relative weight of the tie-breaking objective in the regularised least squares."""

_EMPTY_ROWS: dict[int, FloatArray] = {}


def min_norm_lstsq(A: FloatArray, rhs: FloatArray) -> FloatArray:
    """Minimum-norm least-squares solution of ``A y = rhs`` for a small dense A (n, k).

    LAPACK's ``dgelsy`` (complete orthogonal factorisation with column pivoting, rank
    cut-off 1e-13), called directly: a quarter of the overhead of ``np.linalg.lstsq``.

    Args:
        A: Shape (n, k).
        rhs: Shape (n,).

    Returns:
        y of least norm among the minimisers of ``|A y - rhs|``, shape (k,).
    """
    n, k = A.shape
    pad = np.zeros(max(n, k))
    pad[:n] = rhs
    _, x, _, _, info = dgelsy(A, pad, np.zeros(k, dtype=np.int32), 1e-13, 32 * (n + k + 1))
    if info != 0:  # pragma: no cover - dgelsy fails only on malformed input
        return np.linalg.lstsq(A, rhs, rcond=None)[0]
    return x[:k]


def polish_least_squares(
    M: FloatArray,
    b: FloatArray,
    f_min: FloatArray,
    f_max: FloatArray,
    weights: FloatArray,
    f_ref: FloatArray,
    f: FloatArray,
    active: NDArray[np.int8],
) -> FloatArray:
    """Re-solve the free forces of a bounded least-squares point exactly.

    With the forces of ``active`` held at their bounds, the free ones become the minimum
    W-norm least-squares solution. A free force that then leaves its bounds (the one that
    leaves them most, each round) is held at the bound it crosses and the rest solved again.

    Args:
        M: Shape (n, m).
        b: Shape (n,).
        f_min: Lower bounds [N], shape (m,).
        f_max: Upper bounds [N], shape (m,).
        weights: Diagonal of W, shape (m,).
        f_ref: Reference force [N], shape (m,).
        f: The point to polish [N], shape (m,), within the bounds.
        active: -1/0/+1 per force: held at f_min, free, held at f_max.

    Returns:
        The polished forces [N], shape (m,), when they are within the bounds and no farther
        from ``M f = b`` than ``f``; else ``f`` with its active entries set to their bounds.
    """
    out = np.where(active < 0, f_min, np.where(active > 0, f_max, f))
    r_out = M @ out - b
    best = float(r_out @ r_out)
    held = active.copy()
    slack = 1e-12 * (1.0 + np.abs(f_min) + np.abs(f_max))
    for _ in range(M.shape[1]):
        free = held == 0
        if not free.any():
            break
        cand = np.where(held < 0, f_min, np.where(held > 0, f_max, f_ref))
        wf = weights[free]
        cand[free] += min_norm_lstsq(M[:, free] / wf, b - M @ cand) / wf
        violation = np.maximum(f_min - cand, cand - f_max) - slack
        worst = int(violation.argmax())
        if violation[worst] > 0.0:
            held[worst] = -1 if cand[worst] < f_min[worst] else 1
            continue
        cand = np.clip(cand, f_min, f_max)  # round-off only: within 1e-12 relative
        r_c = M @ cand - b
        if float(r_c @ r_c) <= best * (1.0 + 1e-9) + 1e-300:
            return cand
        break
    return out


def bounded_least_squares(
    M: FloatArray,
    b: FloatArray,
    f_min: FloatArray,
    f_max: FloatArray,
    weights: FloatArray,
    f_ref: FloatArray,
) -> tuple[FloatArray, int]:
    """The bounded f closest to ``M f = b``, ties broken towards f_ref (see module doc).

    Args:
        M: Shape (n, m).
        b: Shape (n,), units of the rows of M times N.
        f_min: Lower bounds [N], shape (m,), finite.
        f_max: Upper bounds [N], shape (m,), finite, >= f_min.
        weights: Diagonal of W [1/N], shape (m,), > 0.
        f_ref: Reference force [N], shape (m,).

    Returns:
        ``(f, iterations)``: forces [N] of shape (m,) within the bounds, and DAQP's
        iteration count.
    """
    m = M.shape[1]
    f_min = np.array(f_min, dtype=np.float64)  # DAQP needs writable, contiguous buffers
    f_max = np.array(f_max, dtype=np.float64)
    ew2 = weights * weights
    H = M.T @ M
    ew2 *= EPS_REL * max(float(H.trace()), 1e-300) / float(ew2.sum())
    H.flat[:: m + 1] += ew2
    g = -(b @ M) - ew2 * f_ref
    rows = _EMPTY_ROWS.get(m)
    if rows is None:
        rows = _EMPTY_ROWS.setdefault(m, np.zeros((0, m)))
    x, _, exitflag, info = daqp.solve(H, g, rows, f_max, f_min, primal_tol=1e-12)
    iterations = int(info["iterations"])
    if exitflag < 1:  # not expected for a positive-definite H and a box; stay robust
        from scipy.optimize import lsq_linear

        sw = np.sqrt(ew2)
        A = np.vstack([M, np.diag(sw)])
        sol = lsq_linear(
            A, np.concatenate([b, sw * f_ref]), bounds=(f_min, f_max), method="bvls", tol=1e-14
        )
        x = np.clip(sol.x, f_min, f_max)
        span = 1e-12 * (1.0 + np.abs(f_min) + np.abs(f_max))
        active = (x >= f_max - span).astype(np.int8) - (x <= f_min + span).astype(np.int8)
        iterations += int(sol.nit)
    else:
        x = np.clip(x, f_min, f_max)  # DAQP holds bounds to 1e-12; remove that round-off
        active = np.sign(info["lam"]).astype(np.int8)
    return polish_least_squares(M, b, f_min, f_max, weights, f_ref, x, active), iterations
