"""Cable force without a load cell: paper 000, eq. 3 and eq. 8-9, and their inverses.

The winch of cable ``i`` obeys the torque balance of eq. 3::

    tau_i = f_i r_D + tau_F(f_i, v_i) + tau_In(a_i),    tau_In = -J_D a_i / r_D

with the friction torque ``tau_F`` of eq. 4-6 (:mod:`msarm.cdpr.winch_friction`). A drive with
a pure proportional velocity loop turns that torque into a following error (eq. 9,
:mod:`msarm.cdpr.following_error`)::

    FE_i = (c_f / K_p) tau_i + c_v v_lag,i

where ``v_lag = v`` when the PLC sends no velocity feed-forward (its P position loop lags a
ramp by ``c_v v``) and ``v_lag = 0`` when it does (msarm's default, as HC-e assumes).

:class:`WinchParameters` holds ``r_D``, ``J_D`` and the two models; its methods
:meth:`~WinchParameters.motor_torque` and :meth:`~WinchParameters.following_error_for_force`
are the forward direction (force to torque, force to FE) and are what the controllers HC-tau
and HC-e of :mod:`msarm.control.cdpr_controllers` use for their set values: there is one copy
of each formula. The functions :func:`force_from_motor_torque`,
:func:`force_from_motor_current` and :func:`force_from_following_error` invert them, so
that a robot without load cells, or a log of one, gives its cable forces.

The inversion is exact: for a fixed cable speed ``v`` every term of eq. 3 is affine in ``f``
(eq. 4 has ``c3 f``; the eq. 6 polynomial blends values of eq. 4, so it is affine in ``f``
too), hence with ``g(f) = tau(f, v, a)`` evaluated by the forward formula,
``f = (tau - g(0)) / (g(1) - g(0))``. ``g(1) - g(0) = r_D + d tau_F / d f`` must be > 0
(it is 0.0193-0.0231 m for Table 1 and ``r_D = 20 mm``).

Which force: ``f`` of eq. 3 is the tension the force distribution ``A^T f + w = 0`` refers
to, the platform-side tension (``tau_F`` covers the drum and every pulley up to the platform).
In the simulated robot (:mod:`msarm.plant.cdpr_plant`) that is the ground truth
``tension.<cable>`` of a run (``CdprRun.truth``, ``CdprPlant.true_cable_tension``); the load
cell reads it plus ``f_F`` of eq. 7.

Sign conventions (those of paper 000 as msarm reads it, and of the plant): ``v > 0`` pays
cable out, ``a > 0`` accelerates the pay-out, the motor torque is positive when it hauls in
(holds the tension), ``FE`` is set minus actual length (a holding torque gives ``FE < 0``,
with ``c_f < 0``).

Limits: the estimates are not clipped; a negative value means the reading implies no tension
(a slack cable, or noise near zero). The friction model refuses speeds beyond the
``v_H = 6 m/min`` it was fitted over unless built with ``extrapolate=True``. The FE estimate
holds only for cables whose drive runs the pure P velocity loop (a PI drive integrates the
torque's following error away).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.cdpr.following_error import PAPER_000_FOLLOWING_ERROR, FollowingErrorModel
from msarm.cdpr.winch_friction import PAPER_000_WINCH_FRICTION, WinchFrictionModel
from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = [
    "WinchParameters",
    "force_from_following_error",
    "force_from_motor_current",
    "force_from_motor_torque",
]


@dataclass(frozen=True)
class WinchParameters:
    """Winch data for eq. 3 and eq. 9 (one model for all winches, as in paper 000).

    The defaults are those of msarm's simulated IPAnema 3 Mini (paper 000 gives neither
    ``r_D`` nor ``J_D``; see :mod:`msarm.plant.cdpr_config`): give the values of your robot.

    Attributes:
        drum_radius: r_D [m], > 0.
        drum_inertia: J_D, inertia of all parts turning with the motor shaft [kg m^2], >= 0.
        friction: Friction torque (eq. 5) and force (eq. 7) model (Table 1 by default).
        following_error: FE model of eq. 9 (c_f, c_v, K_p of the paper by default).
    """

    drum_radius: float = 0.02
    drum_inertia: float = 3e-5
    friction: WinchFrictionModel = PAPER_000_WINCH_FRICTION
    following_error: FollowingErrorModel = PAPER_000_FOLLOWING_ERROR

    def __post_init__(self) -> None:
        for name in ("drum_radius", "drum_inertia"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise InputError(f"{name} must be a number, got {value!r}")
        if not (math.isfinite(self.drum_radius) and self.drum_radius > 0.0):
            raise InputError(f"drum_radius must be finite and > 0 m, got {self.drum_radius}")
        if not (math.isfinite(self.drum_inertia) and self.drum_inertia >= 0.0):
            raise InputError(
                f"drum_inertia must be finite and >= 0 kg m^2, got {self.drum_inertia}"
            )

    def motor_torque(
        self, f: FloatArray, v: FloatArray, a: FloatArray, *, friction_model: bool = True
    ) -> FloatArray:
        """Motor torque that gives the tension f, eq. 3: ``f r_D + tau_F(f, v) + tau_In`` [N m].

        Args:
            f: Cable tension [N], >= 0, any shape broadcastable with ``v`` and ``a``.
            v: Cable velocity [m/s] (> 0: paid out).
            a: Cable acceleration [m/s^2] (> 0: pay-out accelerating).
            friction_model: False sets tau_F = 0.

        Returns:
            tau [N m], the broadcast shape; ``tau_In = -J_D a / r_D``.
        """
        # lists as well as arrays, as the docstring says (a list times a float was a TypeError)
        f, v, a = (np.asarray(x, dtype=np.float64) for x in (f, v, a))
        tau = f * self.drum_radius - self.drum_inertia * a / self.drum_radius
        if friction_model:
            tau = tau + self.friction.torque(f, v)
        return tau

    def following_error_for_force(
        self,
        f: FloatArray,
        v: FloatArray,
        a: FloatArray,
        *,
        friction_model: bool = True,
        velocity_feedforward: bool = True,
    ) -> FloatArray:
        """Following error of a pure-P drive holding the tension f: eq. 9 of eq. 3's torque [m].

        Args:
            f: Cable tension [N], >= 0, any shape broadcastable with ``v`` and ``a``.
            v: Cable velocity [m/s] (> 0: paid out).
            a: Cable acceleration [m/s^2] (> 0: pay-out accelerating).
            friction_model: False sets tau_F = 0.
            velocity_feedforward: True (the PLC sends ``v_ff = v``): the position loop does
                not lag and FE is eq. 8's torque term alone; False: eq. 9's ``c_v v`` is
                added.

        Returns:
            FE [m], the broadcast shape.
        """
        tau = self.motor_torque(f, v, a, friction_model=friction_model)
        v = np.asarray(v, dtype=np.float64)
        return self.following_error.following_error(tau, _lag_speed(v, velocity_feedforward))


def _lag_speed(v: FloatArray, velocity_feedforward: bool) -> FloatArray:
    """The speed of eq. 9's ``c_v v`` term [m/s]: 0 with velocity feed-forward, else v."""
    # Eq. 9's c_v v is the lag of the P position loop without velocity feedforward; with
    # v_ff = v the loop does not lag and the FE is eq. 8's torque term alone.
    return np.zeros_like(v) if velocity_feedforward else v


DEFAULT_WINCH = WinchParameters()


def _reading(value: ArrayLike, name: str, unit: str) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} [{unit}] must be an array of numbers: {err}") from None
    bad = ~np.isfinite(arr)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0]) if arr.ndim else ()
        raise InputError(
            f"{name} [{unit}] must be finite, got {arr[bad].flat[0]} at index {where} "
            f"(shape {arr.shape}); drop or fill the bad samples first"
        )
    return arr


def _like(value: ArrayLike, name: str, unit: str, shape: tuple[int, ...], of: str) -> FloatArray:
    arr = _reading(value, name, unit)
    try:
        out_shape = np.broadcast_shapes(arr.shape, shape)
    except ValueError:
        out_shape = None
    if out_shape != shape:
        raise InputError(
            f"{name} [{unit}] has shape {arr.shape}, expected a shape that broadcasts to the "
            f"{of}'s {shape} (e.g. {shape}, the number of cables {shape[-1:]} or a scalar)"
        )
    return np.broadcast_to(arr, shape)


def _winch(winch: WinchParameters | None) -> WinchParameters:
    if winch is None:
        return DEFAULT_WINCH
    if not isinstance(winch, WinchParameters):
        raise InputError(f"winch must be a WinchParameters, got {type(winch).__name__}")
    return winch


def _invert_torque(
    tau: FloatArray, v: FloatArray, a: FloatArray, winch: WinchParameters, friction_model: bool
) -> FloatArray:
    """The tension f with ``winch.motor_torque(f, v, a) = tau`` (eq. 3 is affine in f)."""
    g0 = winch.motor_torque(np.zeros_like(tau), v, a, friction_model=friction_model)
    slope = winch.motor_torque(np.ones_like(tau), v, a, friction_model=friction_model) - g0
    if not np.all(slope > 0.0):
        raise InputError(
            f"eq. 3 cannot be inverted: r_D + d tau_F/d f = {float(np.min(slope)):.4g} m at "
            f"some speed; expected > 0 (check the friction model's c3 against r_D)"
        )
    return (tau - g0) / slope


def force_from_motor_torque(
    motor_torque: ArrayLike,
    v: ArrayLike,
    a: ArrayLike = 0.0,
    *,
    winch: WinchParameters | None = None,
    friction_model: bool = True,
) -> FloatArray:
    """Cable tension from the motor torque: eq. 3 solved for f [N] (HC-tau's model).

    ``f = (tau - tau_F(0, v) - tau_In(a)) / (r_D + tau_F(1, v) - tau_F(0, v))``, evaluated
    through :meth:`WinchParameters.motor_torque`, the formula HC-tau uses for its set values.

    Args:
        motor_torque: Motor torque [N m], haul-in positive, any shape, e.g. (n_samples, m).
        v: Cable velocity [m/s] (> 0: paid out), broadcastable to ``motor_torque``'s shape;
            within the friction model's ``+-v_H`` (0.1 m/s) unless it extrapolates.
        a: Cable acceleration [m/s^2] (> 0: pay-out accelerating), broadcastable; 0 (default)
            leaves out the inertial torque ``-J_D a / r_D`` (1.5e-3 kg m times ``a`` for the
            defaults: an error of ``J_D a / r_D^2`` = 0.075 kg times ``a`` in the force).
        winch: r_D, J_D and the friction model; :class:`WinchParameters` defaults if None.
        friction_model: False sets tau_F = 0 (``f = (tau - tau_In) / r_D``), the baseline
            the paper shows to be much worse.

    Returns:
        Estimated platform-side tension f [N], ``motor_torque``'s shape; not clipped
        (negative: the reading implies no tension).

    Raises:
        InputError: A NaN or inf in any input, a shape that does not broadcast to
            ``motor_torque``'s, ``|v| > v_H`` for a friction model that does not extrapolate,
            or a friction model whose torque falls with f faster than ``r_D``.
    """
    tau = _reading(motor_torque, "motor_torque", "N m")
    v_arr = _like(v, "v", "m/s", tau.shape, "motor torque")
    a_arr = _like(a, "a", "m/s^2", tau.shape, "motor torque")
    return _invert_torque(tau, v_arr, a_arr, _winch(winch), friction_model)


def force_from_motor_current(
    current: ArrayLike,
    torque_constant: ArrayLike,
    v: ArrayLike,
    a: ArrayLike = 0.0,
    *,
    winch: WinchParameters | None = None,
    friction_model: bool = True,
) -> FloatArray:
    """Cable tension from the motor current: ``tau = k_t i``, then :func:`force_from_motor_torque`.

    Args:
        current: Motor (torque-forming, q-axis) current [A], haul-in positive, any shape.
        torque_constant: k_t [N m/A], > 0, a scalar or broadcastable to ``current``'s shape
            (e.g. one per cable, shape (m,)).
        v: Cable velocity [m/s], as :func:`force_from_motor_torque`.
        a: Cable acceleration [m/s^2], as :func:`force_from_motor_torque`.
        winch: As :func:`force_from_motor_torque`.
        friction_model: As :func:`force_from_motor_torque`.

    Returns:
        Estimated platform-side tension f [N], ``current``'s shape.

    Raises:
        InputError: As :func:`force_from_motor_torque`, or a ``torque_constant`` that is not
            finite and > 0.
    """
    i = _reading(current, "current", "A")
    k_t = _like(torque_constant, "torque_constant", "N m/A", i.shape, "current")
    if not np.all(k_t > 0.0):
        raise InputError(
            f"torque_constant [N m/A] must be > 0, got {float(np.min(k_t)):.6g} (the current "
            "is taken haul-in positive, like the torque)"
        )
    return force_from_motor_torque(k_t * i, v, a, winch=winch, friction_model=friction_model)


def force_from_following_error(
    following_error: ArrayLike,
    v: ArrayLike,
    a: ArrayLike = 0.0,
    *,
    winch: WinchParameters | None = None,
    friction_model: bool = True,
    velocity_feedforward: bool,
) -> FloatArray:
    """Cable tension from a pure-P drive's following error: eq. 9 then eq. 3 inverted [N].

    ``tau = K_p (FE - c_v v_lag) / c_f`` (:meth:`FollowingErrorModel.torque`, ``v_lag`` as
    in :meth:`WinchParameters.following_error_for_force`, HC-e's set value), then
    :func:`force_from_motor_torque`'s inversion of eq. 3.

    Args:
        following_error: FE = set minus actual cable length [m] (more tension, more
            negative), any shape, e.g. (n_samples, m); only meaningful for cables whose
            drive runs the pure P velocity loop.
        v: Cable velocity [m/s] (> 0: paid out), broadcastable to the FE's shape.
        a: Cable acceleration [m/s^2], broadcastable; 0 (default) leaves out tau_In.
        winch: r_D, J_D, friction and FE models; :class:`WinchParameters` defaults if None.
        friction_model: False sets tau_F = 0.
        velocity_feedforward: Whether the PLC sent ``v_ff = v`` (msarm's controllers do by
            default; FE is then eq. 8's torque term alone) or not, as paper 000's PLC
            (eq. 9's ``c_v v`` lag is removed first). No default: the wrong one is far off
            (a true 10 N at 4 m/min read as 2.9 N), so say which your drives do.

    Returns:
        Estimated platform-side tension f [N], the FE's shape; not clipped.

    Raises:
        InputError: As :func:`force_from_motor_torque`.
    """
    fe = _reading(following_error, "following_error", "m")
    v_arr = _like(v, "v", "m/s", fe.shape, "following error")
    a_arr = _like(a, "a", "m/s^2", fe.shape, "following error")
    w = _winch(winch)
    tau = w.following_error.torque(fe, _lag_speed(v_arr, velocity_feedforward))
    return _invert_torque(tau, v_arr, a_arr, w, friction_model)
