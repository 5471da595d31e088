"""The allocation problem, its validated specification, and the results every solver returns.

The problem (one tick)::

    find f in R^m   minimising   1/2 || W (f - f_ref) ||^2
    subject to      M f = b,    f_min <= f <= f_max

with ``m`` actuators (cables, muscles) and ``n`` degrees of freedom. For the arm ``M = -J_c^T``
(n = 4 joints, m = 9 muscles) and ``b = tau`` [N m]; for a cable robot ``M = A^T`` (paper 000,
eq. 2) and ``b = -w`` (w the external wrench [N, N m]). ``W = diag(weights)`` with
``weights > 0`` and ``f_ref`` a reference force [N]: ``f_ref = 0`` gives the minimum 2-norm
force distribution, the midpoint of the bounds Pott's choice, ``weights = 1/F_max`` the sum of
squared normalised forces ``(f_i / F_max,i)^2`` of a muscle model (not quite its squared
activations, which would subtract the passive force and divide by the length- and
velocity-dependent active capacity).

An ``AllocationSpec`` is built once per robot; each tick only ``M``, ``b`` and the bounds
change. ``validate_tick`` checks one tick's data cheaply enough for a 1 kHz loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

FloatArray = NDArray[np.float64]
_F64 = np.dtype(np.float64)

__all__ = [
    "CLOSED_FORM",
    "FALLBACK",
    "INFEASIBLE",
    "OPTIMAL",
    "STATUSES",
    "AllocationResult",
    "AllocationSpec",
    "BatchAllocationResult",
    "ReferenceMode",
    "active_set",
    "check_bound_order",
    "check_tick",
    "snap_to_bounds",
    "tension_bounds",
    "validate_batch",
    "validate_tick",
]

OPTIMAL = "optimal"
"""Status: f is the exact optimum of the quadratic program."""
CLOSED_FORM = "closed_form"
"""Status: a closed form (Pott) found f within the bounds; not the QP optimum in general."""
FALLBACK = "fallback"
"""Status: the method found no f; the bounded least-squares fallback found one meeting M f = b."""
INFEASIBLE = "infeasible"
"""Status: no f within the bounds meets M f = b; f is the bounded least-squares solution."""
STATUSES = (OPTIMAL, CLOSED_FORM, FALLBACK, INFEASIBLE)

ReferenceMode = Literal["zero", "midpoint", "fixed"]


@dataclass(frozen=True)
class AllocationSpec:
    """What is fixed for a robot: sizes, weights, reference force and tolerance.

    Attributes:
        n_actuators: m, number of cables or muscles.
        n_dof: n, number of rows of M (joints, or 6 for a platform wrench).
        weights: Diagonal of W [1/N], shape (m,), all > 0 (read-only).
        f_ref_mode: ``"zero"`` (minimum weighted 2-norm), ``"midpoint"`` (f_ref is the
            midpoint of each tick's bounds, Pott's choice) or ``"fixed"``.
        f_ref: The fixed reference force [N], shape (m,); zeros unless mode is "fixed".
        tol: Feasibility tolerance: f is feasible when
            ``||M f - b|| <= tol (1 + ||b|| + || |M| |f| ||)`` (the round-off of ``M f = b``'s
            terms, at any force scale) and
            ``f_min - tol (1 + |f_min|) <= f <= f_max + tol (1 + |f_max|)``.
    """

    n_actuators: int
    n_dof: int
    weights: FloatArray
    f_ref_mode: ReferenceMode
    f_ref: FloatArray
    tol: float

    @classmethod
    def build(
        cls,
        n_actuators: int,
        n_dof: int,
        *,
        weights: ArrayLike | None = None,
        f_ref: ArrayLike | str | None = None,
        tol: float = 1e-9,
    ) -> AllocationSpec:
        """Validate and build a specification.

        Args:
            n_actuators: m >= n_dof.
            n_dof: n >= 1.
            weights: Diagonal of W [1/N], shape (m,), finite and > 0; ``None`` for ones.
                Zero weights are rejected: they make the optimum non-unique.
            f_ref: ``None`` (f_ref = 0), ``"midpoint"`` or a fixed array [N] of shape (m,).
            tol: Feasibility tolerance (relative to 1 + magnitude), in (0, 1e-3].

        Returns:
            The frozen specification.

        Raises:
            InputError: On any invalid argument, naming it.
        """
        if isinstance(n_actuators, bool) or not isinstance(n_actuators, int | np.integer):
            raise InputError(f"n_actuators must be an int, got {n_actuators!r}")
        if isinstance(n_dof, bool) or not isinstance(n_dof, int | np.integer):
            raise InputError(f"n_dof must be an int, got {n_dof!r}")
        m, n = int(n_actuators), int(n_dof)
        if n < 1:
            raise InputError(f"n_dof must be >= 1, got {n}")
        if m < n:
            raise InputError(
                f"n_actuators must be >= n_dof = {n} (a redundantly actuated robot), got {m}"
            )
        if weights is None:
            w = np.ones(m)
        else:
            w = np.array(_as_float_array(weights, "weights"))
            if w.shape != (m,):
                raise InputError(f"weights must have shape ({m},) [1/N], got {w.shape}")
            if not np.all(np.isfinite(w)) or np.any(w <= 0.0):
                raise InputError(f"weights must be finite and > 0 [1/N], got {w}")
        w.setflags(write=False)
        mode: ReferenceMode
        if f_ref is None:
            mode, ref = "zero", np.zeros(m)
        elif isinstance(f_ref, str):
            if f_ref != "midpoint":
                raise InputError(f"f_ref must be None, 'midpoint' or an array, got {f_ref!r}")
            mode, ref = "midpoint", np.zeros(m)
        else:
            ref = np.array(_as_float_array(f_ref, "f_ref"))
            if ref.shape != (m,):
                raise InputError(f"f_ref must have shape ({m},) [N], got {ref.shape}")
            if not np.all(np.isfinite(ref)):
                raise InputError(f"f_ref must be finite [N], got {ref}")
            mode = "fixed"
        ref.setflags(write=False)
        try:
            tol = float(tol)
        except (TypeError, ValueError):
            raise InputError(f"tol must be a number in (0, 1e-3], got {tol!r}") from None
        if not (0.0 < tol <= 1e-3):
            raise InputError(f"tol must be in (0, 1e-3], got {tol}")
        return cls(m, n, w, mode, ref, tol)

    def reference(self, f_min: FloatArray, f_max: FloatArray) -> FloatArray:
        """The reference force f_ref [N] of one tick, shape (m,) (or (N, m) for batches).

        Args:
            f_min: Lower force bounds [N], shape (m,) or (N, m) (used in "midpoint" mode only).
            f_max: Upper force bounds [N], shape of ``f_min``.

        Returns:
            The midpoint ``(f_min + f_max) / 2`` [N], shape of the bounds, in "midpoint" mode;
            else the spec's (read-only) :attr:`f_ref` [N], shape (m,).
        """
        if self.f_ref_mode == "midpoint":
            return 0.5 * (f_min + f_max)
        return self.f_ref

    def objective(self, f: ArrayLike, f_min: ArrayLike, f_max: ArrayLike) -> float:
        """The objective 1/2 ||W (f - f_ref)||^2 of a solution f [N] of one tick.

        Args:
            f: Actuator forces [N], shape (m,).
            f_min: Lower force bounds [N], shape (m,) or scalar (they set f_ref in
                "midpoint" mode only).
            f_max: Upper force bounds [N], shape (m,) or scalar.

        Returns:
            The objective value [-] (W is in 1/N).
        """
        f = np.asarray(f, dtype=np.float64)
        ref = self.reference(np.asarray(f_min, np.float64), np.asarray(f_max, np.float64))
        e = self.weights * (f - ref)
        return 0.5 * float(e @ e)


@dataclass(frozen=True, slots=True)
class AllocationResult:
    """The answer of one allocation.

    Attributes:
        f: Actuator forces [N], shape (m,), always within the bounds.
        feasible: True when f meets ``M f = b`` to the spec's tolerance (and the bounds).
        status: How f was found: ``"optimal"`` (exact QP optimum), ``"closed_form"``
            (a closed form within the bounds), ``"fallback"`` (the method found none; the
            bounded least-squares fallback met ``M f = b``) or ``"infeasible"`` (no f
            within the bounds meets ``M f = b``; f is the bounded least-squares solution).
        residual: ||M f - b||_2, in the units of b (N m for the arm, N/N m for a CDPR).
        active: Active set, shape (m,) int8: -1 where f is at f_min, +1 at f_max, else 0.
        iterations: Iterations of the method (active-set changes, Newton steps, closed-form
            solves), plus those of the fallback when it ran.
        solve_time: Wall time of the call [s], validation included.
        solver: Name of the solver that produced it.
    """

    f: FloatArray
    feasible: bool
    status: str
    residual: float
    active: NDArray[np.int8]
    iterations: int
    solve_time: float
    solver: str


@dataclass(frozen=True, slots=True)
class BatchAllocationResult:
    """The answers of N allocations solved in one call.

    Attributes:
        f: Forces [N], shape (N, m).
        feasible: Shape (N,) bool, as in ``AllocationResult``.
        status: Shape (N,) str, as in ``AllocationResult``.
        residual: ||M f - b||_2 per problem, shape (N,).
        active: Shape (N, m) int8, -1 at f_min, +1 at f_max, else 0.
        iterations: Shape (N,) int.
        solve_time: Wall time of the whole call [s].
        solver: Name of the solver.
    """

    f: FloatArray
    feasible: NDArray[np.bool_]
    status: NDArray[np.str_]
    residual: FloatArray
    active: NDArray[np.int8]
    iterations: NDArray[np.int64]
    solve_time: float
    solver: str

    def __len__(self) -> int:
        return self.f.shape[0]

    def __getitem__(self, i: int) -> AllocationResult:
        """The i-th problem's answer (its solve_time is the batch's time divided by N)."""
        return AllocationResult(
            f=self.f[i],
            feasible=bool(self.feasible[i]),
            status=str(self.status[i]),
            residual=float(self.residual[i]),
            active=self.active[i],
            iterations=int(self.iterations[i]),
            solve_time=self.solve_time / max(len(self), 1),
            solver=self.solver,
        )


def active_set(f: FloatArray, f_min: FloatArray, f_max: FloatArray, tol: float) -> NDArray[np.int8]:
    """-1 where f is at f_min, +1 at f_max, 0 between (to ``tol (1 + |bound|)``); any shape."""
    at_max = f >= f_max - tol * (1.0 + np.abs(f_max))
    at_min = f <= f_min + tol * (1.0 + np.abs(f_min))
    return at_max.astype(np.int8) - at_min.astype(np.int8)


def snap_to_bounds(
    f: FloatArray, f_min: FloatArray, f_max: FloatArray, tol: float
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Forces within round-off of a bound set onto it; and which rows were within that.

    A solver's forces may step past a bound by round-off (DAQP holds its bounds to 1e-12, an
    interior-point method to its tolerance). Such excursions, up to ``tol (1 + |bound|)``,
    are removed; a row with a force farther out, or a NaN, is flagged, never clipped into a
    plausible-looking answer: its solve failed.

    Args:
        f: Forces [N], shape (..., m).
        f_min: Lower bounds [N], broadcastable to f.
        f_max: Upper bounds [N], broadcastable to f.
        tol: Allowed excursion, relative to ``1 + |bound|``.

    Returns:
        ``(f, ok)``: f clipped to the bounds, shape of f (to be used only where ok), and ok,
        shape (...,) bool: every force of the row is finite and within the tolerance.
    """
    excess = np.maximum(
        f_min - f - tol * (1.0 + np.abs(f_min)), f - f_max - tol * (1.0 + np.abs(f_max))
    )
    ok = (excess <= 0.0).all(axis=-1)  # False for NaN
    return np.clip(f, f_min, f_max), ok


def _as_float_array(value: ArrayLike, name: str) -> FloatArray:
    if np.iscomplexobj(value):  # numpy would drop the imaginary part with a mere warning
        raise InputError(
            f"{name} must be real numbers; got complex values, whose imaginary part would be lost"
        )
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be an array of real numbers: {err}") from None


def _where(bad: NDArray[np.bool_]) -> str:
    return str(tuple(int(i) for i in np.argwhere(bad)[0]))


def _diagnose(
    M: FloatArray, b: FloatArray, f_min: FloatArray, f_max: FloatArray, unit_b: str
) -> None:
    """Raise the precise error for data that failed the cheap combined checks."""
    for name, value, unit in (
        ("M", M, ""),
        ("b", b, unit_b),
        ("f_min", f_min, " [N]"),
        ("f_max", f_max, " [N]"),
    ):
        bad = ~np.isfinite(value)
        if np.any(bad):
            raise InputError(
                f"{name}{unit} must be finite, got {value[tuple(np.argwhere(bad)[0])]} "
                f"at index {_where(bad)}"
            )
    check_bound_order(f_min, f_max)


def validate_tick(
    spec: AllocationSpec, M: ArrayLike, b: ArrayLike, f_min: ArrayLike, f_max: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Check one tick's data and return it as float64 arrays (no copies when possible).

    Args:
        spec: The allocator's specification.
        M: Shape (n, m).
        b: Shape (n,).
        f_min: Lower force bounds [N], shape (m,) or a scalar, finite.
        f_max: Upper force bounds [N], shape (m,) or a scalar, finite, >= f_min.

    Returns:
        ``(M, b, f_min, f_max)`` as float64 arrays of shapes (n, m), (n,), (m,), (m,).

    Raises:
        InputError: On a wrong shape, a NaN or infinity, or f_min > f_max, naming it.
    """
    M, b, f_min, f_max = check_tick(spec, M, b, f_min, f_max)
    check_bound_order(f_min, f_max)
    return M, b, f_min, f_max


def check_bound_order(f_min: FloatArray, f_max: FloatArray) -> None:
    """Raise ``InputError`` naming the first index where f_min > f_max [N] (any shape)."""
    if not (f_min <= f_max).all():
        bad = f_min > f_max
        idx = tuple(np.argwhere(bad)[0])
        raise InputError(
            f"f_min must be <= f_max, got f_min = {f_min[idx]} > f_max = {f_max[idx]} N at "
            f"index {_where(bad)}"
        )


def tension_bounds(
    f_min: float | ArrayLike, f_max: float | ArrayLike, m: int
) -> tuple[FloatArray, FloatArray]:
    """Validated force bounds of ``m`` cables, which only pull [N], shape (m,) each.

    Args:
        f_min: Lower force bound [N], a number or shape (m,), finite and >= 0.
        f_max: Upper force bound [N], a number or shape (m,), finite and >= f_min.
        m: Number of cables.

    Returns:
        ``(f_min, f_max)`` as new float64 arrays of shape (m,).

    Raises:
        InputError: Naming the bound: not a number or of another length than m, not finite
            or negative (a cable cannot push), or f_min > f_max (the first index named).
    """
    out = []
    for name, value in (("f_min", f_min), ("f_max", f_max)):
        try:
            arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (m,))
        except (TypeError, ValueError):
            raise InputError(
                f"{name} must be a number or of shape ({m},) [N], got {value!r}"
            ) from None
        if not np.isfinite(arr).all() or np.any(arr < 0.0):
            raise InputError(f"{name} must be finite and >= 0 N (cables only pull), got {value!r}")
        out.append(arr.astype(np.float64))
    check_bound_order(out[0], out[1])
    return out[0], out[1]


def check_tick(
    spec: AllocationSpec, M: ArrayLike, b: ArrayLike, f_min: ArrayLike, f_max: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The hot path of ``validate_tick``: shapes and finiteness.

    It does not check ``f_min <= f_max``: ``Allocator.solve`` calls ``check_bound_order``
    after it (a solver's answer does not prove the order).

    Args:
        spec: The problem's sizes (n_dof, n_actuators).
        M: Structure matrix, shape (n_dof, n_actuators).
        b: Right-hand side (wrench or joint torque), shape (n_dof,).
        f_min: Lower force bounds [N], shape (n_actuators,) or a scalar.
        f_max: Upper force bounds [N], shape (n_actuators,) or a scalar.

    Returns:
        ``(M, b, f_min, f_max)`` as float64 arrays of those shapes (bounds broadcast to
        (n_actuators,)).

    Raises:
        InputError: A wrong shape or a non-finite value, named.
    """
    n, m = spec.n_dof, spec.n_actuators
    if type(M) is not np.ndarray or M.dtype is not _F64:
        M = _as_float_array(M, "M")
    if M.shape != (n, m):
        raise InputError(f"M must have shape ({n}, {m}) (n_dof, n_actuators), got {M.shape}")
    if type(b) is not np.ndarray or b.dtype is not _F64:
        b = _as_float_array(b, "b")
    if b.shape != (n,):
        raise InputError(f"b must have shape ({n},) (n_dof,), got {b.shape}")
    if type(f_min) is not np.ndarray or f_min.dtype is not _F64:
        f_min = _as_float_array(f_min, "f_min")
    if f_min.shape != (m,):
        if f_min.ndim != 0:
            raise InputError(f"f_min must have shape ({m},) or be a scalar [N], got {f_min.shape}")
        f_min = np.full(m, float(f_min))
    if type(f_max) is not np.ndarray or f_max.dtype is not _F64:
        f_max = _as_float_array(f_max, "f_max")
    if f_max.shape != (m,):
        if f_max.ndim != 0:
            raise InputError(f"f_max must have shape ({m},) or be a scalar [N], got {f_max.shape}")
        f_max = np.full(m, float(f_max))
    # Three dot products catch every NaN and infinity at once (inf * 0, inf - inf and NaN
    # all end non-finite); an overflow of the sum alone goes to the exact check, which passes.
    flat = M.reshape(-1)
    with np.errstate(invalid="ignore", over="ignore"):  # 0 * inf: the check's own NaN
        total = float(flat @ flat) + float(b @ b) + float(f_min @ f_max)
    if not math.isfinite(total):
        _diagnose(M, b, f_min, f_max, "")
    return M, b, f_min, f_max


def validate_batch(
    spec: AllocationSpec, M: ArrayLike, b: ArrayLike, f_min: ArrayLike, f_max: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Check a batch of N problems; bounds may be shared (shape (m,)) or per problem.

    Args:
        spec: The allocator's specification.
        M: Shape (N, n, m).
        b: Shape (N, n).
        f_min: Lower bounds [N], shape (m,), (N, m) or a scalar.
        f_max: Upper bounds [N], shape (m,), (N, m) or a scalar.

    Returns:
        ``(M, b, f_min, f_max)`` as float64 arrays of shapes (N, n, m), (N, n), (N, m), (N, m).

    Raises:
        InputError: On a wrong shape, a NaN or infinity, or f_min > f_max, naming it.
    """
    n, m = spec.n_dof, spec.n_actuators
    M = _as_float_array(M, "M")
    if M.ndim != 3 or M.shape[1:] != (n, m):
        raise InputError(f"M must have shape (N, {n}, {m}) for a batch, got {M.shape}")
    count = M.shape[0]
    b = _as_float_array(b, "b")
    if b.shape != (count, n):
        raise InputError(f"b must have shape ({count}, {n}) for a batch, got {b.shape}")
    bounds = []
    for name, value in (("f_min", f_min), ("f_max", f_max)):
        arr = _as_float_array(value, name)
        if arr.ndim == 0 or arr.shape == (m,):
            arr = np.broadcast_to(arr, (count, m))
        elif arr.shape != (count, m):
            raise InputError(
                f"{name} must have shape ({m},) or ({count}, {m}) [N] for a batch, got {arr.shape}"
            )
        bounds.append(arr)
    lo, hi = bounds
    if (
        not np.isfinite(M).all()
        or not np.isfinite(b).all()
        or not np.isfinite(lo).all()
        or not np.isfinite(hi).all()
        or not (lo <= hi).all()
    ):
        _diagnose(M, b, lo, hi, "")
    return M, b, lo, hi
