"""Compiled element-wise steps of :class:`msarm.control.MuscleSpaceController`'s tick (numba).

A control tick runs a dozen short vector formulas between its library calls (Pinocchio,
MuJoCo, the allocation QP); as NumPy expressions each costs a call of about a microsecond.
These kernels run them in one compiled loop each. They evaluate every formula in the order
and with the operations of the NumPy expressions they replace (no fused multiply-add, no
reassociation: ``fastmath`` is off), so the results are the same to the bit; ``clip`` follows
NumPy's (a NaN stays NaN).
"""

from __future__ import annotations

import numba

from msarm.numba_cache import drop_stale_kernels

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = ["activation_and_reach", "filter_and_pid", "force_bounds", "muscle_speed"]


@numba.njit(cache=True)
def _clip(x: float, lower: float, upper: float) -> float:
    """``np.clip`` of one value: ``min(max(x, lower), upper)``, NaN propagated."""
    if not (x != x or x > lower):
        x = lower
    if not (x != x or x < upper):
        x = upper
    return x


@numba.njit(cache=True)
def _maximum(a: float, b: float) -> float:
    """``np.maximum`` of two values (a NaN in either is returned)."""
    return a if (a >= b or a != a) else b


@numba.njit(cache=True, error_model="numpy")
def filter_and_pid(q, q_ref, qd_ref, period, alpha, kp, ki, kd, bound, q_prev, qdot, integral, tau):
    """Velocity estimate, integral and PID torque of one tick, in place.

    Per joint ``i`` (shapes ``(n,)``)::

        qdot += alpha * ((q - q_prev) / period - qdot);  q_prev = q
        e = q_ref - q;  integral = clip(integral + e * period, -bound, bound)
        tau = tau + kp * e + ki * integral;  tau += kd * (qd_ref - qdot)

    Args:
        q: Measured joint angles [rad].
        q_ref: Reference joint angles [rad].
        qd_ref: Reference joint velocities [rad/s].
        period: Control period [s].
        alpha: Low-pass factor of the velocity estimate [-].
        kp: Proportional gains [N m/rad].
        ki: Integral gains [N m/(rad s)].
        kd: Derivative gains [N m s/rad].
        bound: Bound on the integral state [rad s].
        q_prev: Previous joint angles [rad], updated.
        qdot: Joint velocity estimate [rad/s], updated.
        integral: Integral of the error [rad s], updated.
        tau: In: inverse-dynamics torque [N m]; out: with the PID terms added.
    """
    for i in range(q.shape[0]):
        raw_velocity = (q[i] - q_prev[i]) / period
        qdot[i] += alpha * (raw_velocity - qdot[i])
        q_prev[i] = q[i]
        error = q_ref[i] - q[i]
        integral[i] = _clip(integral[i] + error * period, -bound[i], bound[i])
        tau[i] = tau[i] + kp[i] * error + ki[i] * integral[i]
        tau[i] += kd[i] * (qd_ref[i] - qdot[i])


@numba.njit(cache=True, error_model="numpy")
def force_bounds(active, passive, min_tension, f_min, f_max):
    """Allocation bounds from the muscles' capacity, shapes ``(m,)`` [N], written.

    ``f_min = max(passive, min_tension)`` and ``f_max = max(passive + active, f_min)``.
    """
    for i in range(active.shape[0]):
        f_min[i] = _maximum(passive[i], min_tension)
        f_max[i] = _maximum(passive[i] + active[i], f_min[i])


@numba.njit(cache=True, error_model="numpy")
def activation_and_reach(force, active, passive, activation, reachable):
    """Inverse Hill model of allocated forces, shapes ``(m,)``, written.

    ``activation = clip((force - passive) / active, 0, 1)`` [-] and ``reachable`` (bool):
    ``passive - 1e-9 <= force <= passive + active + 1e-9`` [N].
    """
    for i in range(force.shape[0]):
        activation[i] = _clip((force[i] - passive[i]) / active[i], 0.0, 1.0)
        reachable[i] = (force[i] >= passive[i] - 1e-9) and (
            force[i] <= passive[i] + active[i] + 1e-9
        )


@numba.njit(cache=True, error_model="numpy")
def muscle_speed(jacobian, qdot, max_shortening, speed):
    """MTU speeds ``max(J_c qdot, -max_shortening)`` [m/s], shape ``(m,)``, written.

    Each row's product is summed joint after joint (the compiled loop and the controller's
    Python path share this kernel, so the two agree to the bit).

    Args:
        jacobian: Muscle Jacobian ``J_c`` [m/rad], ``(m, n)``.
        qdot: Joint velocity estimate [rad/s], ``(n,)``.
        max_shortening: Highest shortening speed the Hill model is evaluated at [m/s], ``(m,)``.
        speed: Output [m/s], ``(m,)``.
    """
    for i in range(jacobian.shape[0]):
        total = 0.0
        for j in range(jacobian.shape[1]):
            total += jacobian[i, j] * qdot[j]
        speed[i] = _maximum(total, -max_shortening[i])
