"""Tracking metrics of paper 003 and tension-bound counts (pure numpy).

Paper 003 (the musculoskeletal arm with feedforward compensation) scores a run by the final
end-effector error and its share of the commanded displacement (eq. 10-11) and by the RMSE of
the cable ("muscle") lengths as a share of each cable's travel (eq. 12-13); its results section
(3.2) reports the cable lengths otherwise, as their difference at the end of the movement in %
of the theoretical length (:func:`cable_length_error_at_end`). The joint RMSE and the tension
counts (slack events, time outside the tension bounds) complete them.

Shapes: ``T`` samples, ``n`` joints, ``m`` cables, ``d`` Cartesian dimensions. Every function
refuses NaN, infinite values (bounds excepted: an infinite bound is no bound), values that
are not numbers and shape mismatches with an :class:`~msarm.errors.InputError` naming the
argument.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

__all__ = [
    "cable_length_error",
    "cable_length_error_at_end",
    "final_position_error",
    "settle_sample",
    "joint_rmse",
    "slack_events",
    "time_outside_bounds",
]

FloatArray = NDArray[np.float64]


def _array(value: ArrayLike, name: str, ndim: int) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numeric: {exc}") from None
    if arr.ndim != ndim:
        shape = {0: "a scalar", 1: "of shape (k,)", 2: "of shape (T, k)"}[ndim]
        raise InputError(f"{name} must be {shape}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        where = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        label = "NaN" if np.isnan(arr[where]) else f"{arr[where]} (not finite)"
        raise InputError(f"{name} has {label} at index {where}")
    return arr


def _scalar(value: float, name: str) -> float:
    """A number, or an InputError naming ``name`` and what it got."""
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None


def _same_shape(a: FloatArray, b: FloatArray, name_a: str, name_b: str) -> None:
    if a.shape != b.shape:
        raise InputError(f"{name_a} has shape {a.shape} but {name_b} has shape {b.shape}")


def _per_cable(value: ArrayLike, name: str, m: int) -> FloatArray:
    """A scalar or ``(m,)`` bound, broadcast to ``(m,)`` (infinite: no bound)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number or of shape ({m},), got {value!r}") from None
    if arr.ndim == 0:
        arr = np.full(m, float(arr))
    if arr.shape != (m,):
        raise InputError(f"{name} must be a scalar or of shape ({m},), got shape {arr.shape}")
    if np.isnan(arr).any():
        raise InputError(f"{name} has NaN")
    return arr


def settle_sample(t: ArrayLike, q_ref: ArrayLike, delay: float) -> int | None:
    """The sample ``delay`` seconds after the reference last changes (its move has ended).

    Args:
        t: Sample times [s], shape ``(T,)``, increasing.
        q_ref: Reference joint angles [rad], shape ``(T, n)``.
        delay: Time after the reference comes to rest [s], >= 0.

    Returns:
        The first sample at or after that time, or None when the run ends sooner or the
        reference never comes to rest (it changes between its last two samples).

    Raises:
        InputError: Shapes differ, NaN or infinite values, times that do not increase, or a
            bad delay.
    """
    times = _array(t, "t", 1)
    ref = _array(q_ref, "q_ref", 2)
    if ref.shape[0] != times.shape[0]:
        raise InputError(f"q_ref has {ref.shape[0]} samples but t has {times.shape[0]}")
    steps = np.diff(times)
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0))
        raise InputError(
            f"t must increase, got {times[k]:g} then {times[k + 1]:g} s at samples {k}, {k + 1}"
        )
    delay = _scalar(delay, "delay")
    if not delay >= 0.0:
        raise InputError(f"delay must be >= 0 [s], got {delay}")
    moving = np.flatnonzero(np.any(np.diff(ref, axis=0) != 0.0, axis=1))
    rest = 0 if moving.size == 0 else int(moving[-1]) + 1
    if rest >= times.shape[0] - 1 and moving.size:
        return None
    k = int(np.searchsorted(times, times[rest] + delay - 1e-9))
    return k if k < times.shape[0] else None


def final_position_error(
    p_final: ArrayLike, p_target: ArrayLike, p_start: ArrayLike
) -> tuple[float, float]:
    """Final end-effector position error and its share of the displacement (eq. 10-11).

    ``z = |p - p_d|`` (eq. 10) and ``r_p = z / |p_d - p_0| * 100`` (eq. 11), where ``p`` is the
    final position, ``p_d`` the desired one and ``p_0`` the start.

    Args:
        p_final: Final position p [m], shape ``(d,)``.
        p_target: Desired position p_d [m], shape ``(d,)``.
        p_start: Start position p_0 [m], shape ``(d,)``.

    Returns:
        ``(error, percent)``: the distance ``z`` [m] and ``r_p`` [%].

    Raises:
        InputError: Shapes differ, NaN or infinite values, or ``p_target == p_start`` (no
            displacement).
    """
    p = _array(p_final, "p_final", 1)
    p_d = _array(p_target, "p_target", 1)
    p_0 = _array(p_start, "p_start", 1)
    _same_shape(p, p_d, "p_final", "p_target")
    _same_shape(p_0, p_d, "p_start", "p_target")
    error = float(np.linalg.norm(p - p_d))
    displacement = float(np.linalg.norm(p_d - p_0))
    if displacement == 0.0:
        raise InputError(
            "p_target equals p_start: zero displacement, the percentage (eq. 11) is undefined"
        )
    return error, 100.0 * error / displacement


def joint_rmse(q: ArrayLike, q_ref: ArrayLike) -> FloatArray:
    """Root mean square joint tracking error, per joint.

    Args:
        q: Measured joint angles [rad], shape ``(T, n)``.
        q_ref: Reference joint angles [rad], shape ``(T, n)``.

    Returns:
        ``sqrt(mean_t (q - q_ref)^2)`` [rad], shape ``(n,)``.

    Raises:
        InputError: Shapes differ, no samples, or NaN or infinite values.
    """
    q = _array(q, "q", 2)
    q_ref = _array(q_ref, "q_ref", 2)
    _same_shape(q, q_ref, "q", "q_ref")
    if q.shape[0] == 0:
        raise InputError("q has no samples")
    return np.sqrt(np.mean((q - q_ref) ** 2, axis=0))


def cable_length_error(
    l_valid: ArrayLike, l_theory: ArrayLike, max_travel: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """RMSE of the cable lengths and its share of each cable's travel (eq. 12-13).

    ``RMSE_i = sqrt(sum_t (l_i - l_hat_i)^2 / T)`` (eq. 12) between the valid length (motor
    encoder angle times winch radius) and the theoretical length from the joint angles
    ``l(q)``, and ``r_i = RMSE_i / l_travel_i * 100`` (eq. 13). Both lengths must share one
    zero (e.g. the encoder length set to ``l(q)`` at the start posture).

    Args:
        l_valid: Valid cable lengths [m], shape ``(T, m)``.
        l_theory: Theoretical cable lengths [m], shape ``(T, m)``.
        max_travel: Maximum travel of each cable [m], shape ``(m,)``, > 0.

    Returns:
        ``(rmse, percent)``: [m] and [%], each shape ``(m,)``.

    Raises:
        InputError: Shapes differ, no samples, NaN or infinite values, or a travel that is
            not > 0.
    """
    l_valid = _array(l_valid, "l_valid", 2)
    l_theory = _array(l_theory, "l_theory", 2)
    max_travel = _array(max_travel, "max_travel", 1)
    _same_shape(l_valid, l_theory, "l_valid", "l_theory")
    if l_valid.shape[0] == 0:
        raise InputError("l_valid has no samples")
    if max_travel.shape != (l_valid.shape[1],):
        raise InputError(
            f"max_travel must have shape ({l_valid.shape[1]},) (one per cable), "
            f"got {max_travel.shape}"
        )
    if not (max_travel > 0).all():
        j = int(np.argmax(~(max_travel > 0)))
        raise InputError(f"max_travel must be > 0, got {max_travel[j]} at cable {j}")
    rmse = np.sqrt(np.mean((l_valid - l_theory) ** 2, axis=0))
    return rmse, 100.0 * rmse / max_travel


def cable_length_error_at_end(l_valid: ArrayLike, l_theory: ArrayLike) -> FloatArray:
    """The cable lengths' difference at the end of the run in % of the theoretical length.

    ``100 |l_i(T) - l_hat_i(T)| / l_hat_i(T)``, as paper 003 reports its results (section
    3.2: "the difference between the valid length of the cable and the theoretical length as
    a percentage of the theoretical length", 1.22-11.43 % without feedforward and
    0.03-2.09 % with it), beside the RMSE over the whole run in % of the travel of its
    eq. 12-13 (:func:`cable_length_error`). Both lengths must share one zero.

    Args:
        l_valid: Valid cable lengths [m], shape ``(T, m)``.
        l_theory: Theoretical cable lengths [m], shape ``(T, m)``, > 0 at the last sample.

    Returns:
        The difference at the last sample [%], shape ``(m,)``.

    Raises:
        InputError: Shapes differ, no samples, NaN or infinite values, or a theoretical
            length that is not > 0 at the last sample.
    """
    l_valid = _array(l_valid, "l_valid", 2)
    l_theory = _array(l_theory, "l_theory", 2)
    _same_shape(l_valid, l_theory, "l_valid", "l_theory")
    if l_valid.shape[0] == 0:
        raise InputError("l_valid has no samples")
    last = l_theory[-1]
    if not (last > 0).all():
        j = int(np.argmax(~(last > 0)))
        raise InputError(f"l_theory must be > 0 at the last sample, got {last[j]} at cable {j}")
    return 100.0 * np.abs(l_valid[-1] - last) / last


def slack_events(tension: ArrayLike, threshold: ArrayLike) -> NDArray[np.int64]:
    """Number of times each cable goes slack.

    A cable is taut while its tension is ``>= threshold`` and slack below it; an event is a
    sample where it is slack after being taut at the previous sample (a cable slack from the
    first sample counts only once it has been taut).

    Args:
        tension: Cable tensions [N], shape ``(T, m)``.
        threshold: Slack threshold [N], scalar or shape ``(m,)``.

    Returns:
        Count per cable, shape ``(m,)``, int.

    Raises:
        InputError: Bad shapes, NaN or infinite values.
    """
    tension = _array(tension, "tension", 2)
    threshold = _per_cable(threshold, "threshold", tension.shape[1])
    slack = tension < threshold
    entries = slack[1:] & ~slack[:-1]
    return entries.sum(axis=0).astype(np.int64)


def time_outside_bounds(
    tension: ArrayLike, lower: ArrayLike, upper: ArrayLike, dt: float
) -> FloatArray:
    """Time each cable's tension spends outside ``[lower, upper]``.

    Args:
        tension: Cable tensions [N], shape ``(T, m)``, sampled every ``dt``.
        lower: Lower tension bound [N], scalar or shape ``(m,)``.
        upper: Upper tension bound [N], scalar or shape ``(m,)``, >= ``lower``.
        dt: Sample period [s], >= 0.

    Returns:
        Samples outside the bounds times ``dt`` [s], shape ``(m,)``.

    Raises:
        InputError: Bad shapes, NaN, ``lower > upper`` or a bad ``dt``.
    """
    tension = _array(tension, "tension", 2)
    m = tension.shape[1]
    lower = _per_cable(lower, "lower", m)
    upper = _per_cable(upper, "upper", m)
    if (lower > upper).any():
        j = int(np.argmax(lower > upper))
        raise InputError(f"lower > upper at cable {j}: {lower[j]} > {upper[j]}")
    dt = _scalar(dt, "dt")
    if not (np.isfinite(dt) and dt >= 0):
        raise InputError(f"dt must be finite and >= 0 [s], got {dt}")
    outside = (tension < lower) | (tension > upper)
    return outside.sum(axis=0) * dt
