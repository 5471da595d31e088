"""First-order muscle activation dynamics (De Groote et al. 2016, smooth form).

The neural excitation ``e`` in [0, 1] drives the activation ``a`` in [0, 1]:

``da/dt = (e - a) / tau(e, a)`` with

``1 / tau(e, a) = (0.5 + f) / (tau_act * (0.5 + 1.5 a)) + (0.5 - f) * (0.5 + 1.5 a) / tau_deact``

and the smooth switch ``f = 0.5 * tanh(b * (e - a))`` (De Groote, Kinney, Rao, Fregly 2016,
Ann. Biomed. Eng. 44(10), eq. 1-2, after Raasch et al. 1997 and Thelen 2003).

Time constants: ``tau_act = 15 ms`` and ``tau_deact = 60 ms`` by default. As ``b`` grows, ``f``
tends to ``+0.5`` while activating (``e > a``) and to ``-0.5`` while deactivating, so the
effective time constant is ``tau_act * (0.5 + 1.5 a)`` when rising and
``tau_deact / (0.5 + 1.5 a)`` when falling: it equals ``tau_act`` or ``tau_deact`` exactly at
``a = 1/3`` and depends on ``a`` elsewhere. Integrating the sharp-switch form in closed form:

- a step of excitation 0 -> 1 from ``a = 0`` reaches ``1 - 1/e`` (63.2 %) after
  ``(2 - 1.5 (1 - 1/e)) tau_act`` ≈ 1.052 ``tau_act`` (15.8 ms by default);
- a step 1 -> 0 from ``a = 1`` decays to ``1/e`` (36.8 %) after
  ``(2 + 2 ln(0.25 + 0.75/e)) tau_deact`` ≈ 0.715 ``tau_deact`` (42.9 ms by default).

Smoothing: the default ``b = 10`` makes the switch complete to within 0.2 % once
``|e - a| >= 0.35``, and the step responses above hold to better than 0.1 %. De Groote et al.
(2016) used ``b = 0.1``, for which ``|tanh(b (e - a))| < 0.1``: rise and fall then use
nearly the same blend of both constants, so a 0 -> 1 step reaches 63 % only after about
1.54 ``tau_act`` and a 1 -> 0 step decays to 37 % after about 0.47 ``tau_deact``, and the two
constants no longer mean what their names say. Pass ``smoothing=0.1`` to reproduce the
paper.

Arrays: ``excitation`` and ``activation`` may be scalars or arrays of any (broadcastable)
shape, typically ``(m,)`` for ``m`` muscles; the result has the broadcast shape (a numpy
float for scalars). Time is in seconds.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import ArrayLike

from msarm.errors import InputError
from msarm.muscle.curves import FloatArray, _checked_array, _raise_where

__all__ = [
    "DEFAULT_ACTIVATION_SMOOTHING",
    "DEFAULT_TAU_ACT",
    "DEFAULT_TAU_DEACT",
    "activation_derivative",
    "activation_time_constant",
    "step_activation",
]

#: Activation time constant tau_act [s] (De Groote et al. 2016).
DEFAULT_TAU_ACT: Final[float] = 0.015
#: Deactivation time constant tau_deact [s] (De Groote et al. 2016).
DEFAULT_TAU_DEACT: Final[float] = 0.060
#: Smoothness ``b`` of the tanh switch between activation and deactivation [-].
DEFAULT_ACTIVATION_SMOOTHING: Final[float] = 10.0


def _checked_positive_scalar(value: float, name: str, unit: str) -> float:
    """Validate a finite, strictly positive scalar parameter.

    Args:
        value: The parameter.
        name: Its name, used in error messages.
        unit: Its unit, used in error messages (e.g. ``"s"``).

    Returns:
        ``value`` as a float.

    Raises:
        InputError: If ``value`` is not a finite number > 0.
    """
    array = _checked_array(value, name)
    if array.ndim != 0:
        raise InputError(f"{name} must be a scalar [{unit}]; got an array of shape {array.shape}")
    _raise_where(array <= 0.0, array, name, f"> 0 [{unit}]")
    return float(array)


def _checked_unit_interval(value: ArrayLike, name: str) -> FloatArray:
    """Validate an excitation or activation: finite and within [0, 1]."""
    array = _checked_array(value, name)
    _raise_where((array < 0.0) | (array > 1.0), array, name, "in [0, 1]")
    return array


def _broadcast(excitation: FloatArray, activation: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Broadcast excitation and activation to one shape, with a clear error if impossible."""
    try:
        e, a = np.broadcast_arrays(excitation, activation)
    except ValueError as exc:
        raise InputError(
            f"excitation (shape {excitation.shape}) and activation (shape {activation.shape}) "
            "must have broadcastable shapes"
        ) from exc
    return e, a


def _inverse_time_constant(
    e: FloatArray, a: FloatArray, tau_act: float, tau_deact: float, smoothing: float
) -> FloatArray:
    """``1 / tau(e, a)`` [1/s] of the smooth De Groote form, for validated inputs."""
    switch = 0.5 * np.tanh(smoothing * (e - a))
    gain = 0.5 + 1.5 * a
    return (0.5 + switch) / (tau_act * gain) + (0.5 - switch) * gain / tau_deact


def _validated(
    excitation: ArrayLike,
    activation: ArrayLike,
    tau_act: float,
    tau_deact: float,
    smoothing: float,
) -> tuple[FloatArray, FloatArray, float, float, float]:
    """Validate and broadcast the common arguments of the public functions."""
    e = _checked_unit_interval(excitation, "excitation")
    a = _checked_unit_interval(activation, "activation")
    e, a = _broadcast(e, a)
    return (
        e,
        a,
        _checked_positive_scalar(tau_act, "tau_act", "s"),
        _checked_positive_scalar(tau_deact, "tau_deact", "s"),
        _checked_positive_scalar(smoothing, "smoothing", "-"),
    )


def activation_time_constant(
    excitation: ArrayLike,
    activation: ArrayLike,
    tau_act: float = DEFAULT_TAU_ACT,
    tau_deact: float = DEFAULT_TAU_DEACT,
    smoothing: float = DEFAULT_ACTIVATION_SMOOTHING,
) -> FloatArray:
    """Effective time constant ``tau(e, a)`` of the activation dynamics.

    ``da/dt = (e - a) / tau(e, a)``; see the module docstring for ``tau``.

    Args:
        excitation: Neural excitation ``e`` [-] in [0, 1], scalar or array.
        activation: Activation ``a`` [-] in [0, 1], broadcastable with ``excitation``.
        tau_act: Activation time constant [s], > 0.
        tau_deact: Deactivation time constant [s], > 0.
        smoothing: Smoothness ``b`` of the tanh switch [-], > 0.

    Returns:
        ``tau`` [s], broadcast shape of the inputs (a numpy float for scalars).

    Raises:
        InputError: On NaN, values outside [0, 1], unbroadcastable shapes, or a
            non-positive parameter.
    """
    e, a, t_act, t_deact, b = _validated(excitation, activation, tau_act, tau_deact, smoothing)
    return (1.0 / _inverse_time_constant(e, a, t_act, t_deact, b))[()]


def activation_derivative(
    excitation: ArrayLike,
    activation: ArrayLike,
    tau_act: float = DEFAULT_TAU_ACT,
    tau_deact: float = DEFAULT_TAU_DEACT,
    smoothing: float = DEFAULT_ACTIVATION_SMOOTHING,
) -> FloatArray:
    """Time derivative of the activation, ``da/dt = (e - a) / tau(e, a)``.

    Argument order: **excitation first, then activation** (``activation_derivative(e, a)``,
    as in ``da/dt = f(e, a)``); :func:`step_activation` takes them the other way round,
    ``step_activation(a, e, dt)`` (state first). Pass them by keyword where in doubt.

    Args:
        excitation: Neural excitation ``e`` [-] in [0, 1], scalar or array.
        activation: Activation ``a`` [-] in [0, 1], broadcastable with ``excitation``.
        tau_act: Activation time constant [s], > 0.
        tau_deact: Deactivation time constant [s], > 0.
        smoothing: Smoothness ``b`` of the tanh switch [-], > 0.

    Returns:
        ``da/dt`` [1/s], broadcast shape of the inputs (a numpy float for scalars).

    Raises:
        InputError: On NaN, values outside [0, 1], unbroadcastable shapes, or a
            non-positive parameter.
    """
    e, a, t_act, t_deact, b = _validated(excitation, activation, tau_act, tau_deact, smoothing)
    return ((e - a) * _inverse_time_constant(e, a, t_act, t_deact, b))[()]


def step_activation(
    activation: ArrayLike,
    excitation: ArrayLike,
    dt: float,
    tau_act: float = DEFAULT_TAU_ACT,
    tau_deact: float = DEFAULT_TAU_DEACT,
    smoothing: float = DEFAULT_ACTIVATION_SMOOTHING,
) -> FloatArray:
    """Advance the activation by one step ``dt`` with the excitation held constant.

    Argument order: **activation first (the state), then excitation** (``step_activation(a,
    e, dt)``); :func:`activation_derivative` takes them the other way round,
    ``activation_derivative(e, a)``. Pass them by keyword where in doubt.

    Exponential midpoint step: the time constant is frozen at a predicted midpoint,
    ``a_half = e + (a - e) exp(-dt / (2 tau(e, a)))`` and
    ``a_next = e + (a - e) exp(-dt / tau(e, a_half))``. It is exact when ``tau`` is constant,
    second-order accurate in ``dt`` otherwise, stable for any ``dt``, and ``a_next`` always
    lies between ``a`` and ``e`` (so it stays in [0, 1]) and never overshoots ``e``.

    Args:
        activation: Current activation ``a`` [-] in [0, 1], scalar or array.
        excitation: Excitation ``e`` [-] in [0, 1] held over the step, broadcastable with
            ``activation``.
        dt: Step length [s], > 0.
        tau_act: Activation time constant [s], > 0.
        tau_deact: Deactivation time constant [s], > 0.
        smoothing: Smoothness ``b`` of the tanh switch [-], > 0.

    Returns:
        Activation after ``dt`` [-] in [0, 1], broadcast shape of the inputs (a numpy float
        for scalars).

    Raises:
        InputError: On NaN, values outside [0, 1], unbroadcastable shapes, or a
            non-positive ``dt`` or parameter.
    """
    e, a, t_act, t_deact, b = _validated(excitation, activation, tau_act, tau_deact, smoothing)
    step = _checked_positive_scalar(dt, "dt", "s")
    rate = _inverse_time_constant(e, a, t_act, t_deact, b)
    a_half = e + (a - e) * np.exp(-0.5 * step * rate)
    rate_half = _inverse_time_constant(e, a_half, t_act, t_deact, b)
    a_next = e + (a - e) * np.exp(-step * rate_half)
    # Round-off guard only: mathematically a_next already lies between a and e.
    return np.clip(a_next, np.minimum(a, e), np.maximum(a, e))[()]
