"""The muscle-space controller of paper 003 (Fig. 3 and 5), for the cable-driven arm.

At every control tick (250 Hz by default), from sensor readings only:

1. joint velocity estimate: finite difference of the encoders through a first-order low-pass;
2. wanted joint torque: inverse-dynamics feedforward of the reference (Pinocchio RNEA,
   gravity included) plus a joint PID, plus an optional feedforward compensation ``dtau``
   (the learned compensator of paper 003 section 3.1):
   ``tau = ID(q_r, qd_r, qdd_r) + Kp e + Ki int(e) + Kd de/dt + dtau`` with ``e = q_r - q``;
3. muscle forces from the allocation core: ``-J_c(q)^T f = tau`` with each force within the
   muscle's capacity at its current length and velocity (``[max(passive, T_min),
   full activation]``), minimising the sum of squared normalised forces
   ``sum (f_i / F_max,i)^2`` (a stand-in for squared activations: paper 003 names no
   objective);
4. activations from the inverse Hill model (clipped to [0, 1], flagged when out of reach),
   optionally filtered by the activation dynamics;
5. the muscle force at that activation (forward Hill model) is the tension wanted at the
   insertions, and the tension command that the motor drives render at the motor side;
6. optionally a feedforward reshapes that command in tension space (the compensator's sheath
   stage, :mod:`msarm.compensation.sheath`, asks the drives for what the sheaths will let
   through): ``T_cmd = shape(F, q_r)``.

The controller's model is the nominal one: rigid, frictionless cables through
``msarm.muscle.geometry``; it never reads the plant's internals.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pinocchio
from numpy.typing import ArrayLike, NDArray

from msarm.allocation import make_allocator
from msarm.control.kernels import (
    activation_and_reach,
    filter_and_pid,
    force_bounds,
    muscle_speed,
)
from msarm.errors import InputError
from msarm.io.config import check_field_types, check_numbers
from msarm.model import RobotModel
from msarm.muscle.activation import step_activation
from msarm.muscle.fast import FastHill
from msarm.muscle.geometry import cable_kinematics
from msarm.plant.effects import SensorReadings

__all__ = ["ArmControllerConfig", "ControlOutput", "MuscleSpaceController"]

FloatArray = NDArray[np.float64]


def _vector(value: ArrayLike, size: int, name: str) -> FloatArray:
    """``value`` as a float64 array of shape ``(size,)`` (itself when it already is one).

    Raises:
        InputError: The shape is not ``(size,)`` (the compiled kernels index it blindly), or
            a value is NaN or infinite (it would stay in the filter and integral states).
    """
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be {size} numbers, got {value!r}") from None
    if array.shape != (size,):
        raise InputError(f"{name} must have shape ({size},), got {array.shape}")
    if not np.isfinite(array).all():
        k = int(np.argmax(~np.isfinite(array)))
        raise InputError(f"{name} must be finite, got {array[k]} at index {k}")
    return array


@dataclass(frozen=True)
class ArmControllerConfig:
    """Gains and settings of :class:`MuscleSpaceController`.

    Attributes:
        rate_hz: Control rate [Hz] (paper 003: 250 Hz).
        kp: Proportional gains [N m/rad], one per joint.
        ki: Integral gains [N m/(rad s)], one per joint.
        kd: Derivative gains [N m s/rad], one per joint.
        integral_limit: Bound on each joint's integral term ``Ki int(e)`` [N m] (anti-windup).
        min_tension: Lowest cable force the allocation may ask for [N] (keeps cables taut).
        velocity_cutoff_hz: Cut-off of the low-pass on the encoder velocity estimate [Hz].
        activation_dynamics: Filter activations by the first-order activation dynamics.
        solver: Allocation solver name (see ``msarm.allocation.SOLVERS``). The default,
            ``"newton"``, is the exact solver that the compiled closed loop
            (:mod:`msarm.tasks.compiled_loop`) calls without the interpreter; with another one
            every run takes the Python loop.
    """

    rate_hz: float = 250.0
    kp: tuple[float, ...] = (60.0, 60.0, 30.0, 30.0)
    ki: tuple[float, ...] = (40.0, 40.0, 20.0, 20.0)
    kd: tuple[float, ...] = (4.0, 4.0, 1.5, 1.5)
    integral_limit: float = 3.0
    min_tension: float = 5.0
    velocity_cutoff_hz: float = 30.0
    activation_dynamics: bool = False
    solver: str = "newton"

    def __post_init__(self) -> None:
        # a config file's loader names the key; the controller checks the gain count
        check_field_types(self)
        check_numbers(
            self,
            positive=("rate_hz", "velocity_cutoff_hz"),
            non_negative=("integral_limit", "min_tension"),
        )
        if not self.velocity_cutoff_hz < 0.5 * self.rate_hz:
            raise ValueError(
                f"velocity_cutoff_hz must be below the Nyquist frequency rate_hz / 2 = "
                f"{0.5 * self.rate_hz:g} Hz (above it the low-pass filters nothing), got "
                f"{self.velocity_cutoff_hz:g}"
            )
        for name in ("kp", "ki", "kd"):
            try:
                gains = np.asarray(getattr(self, name), dtype=float)
            except (TypeError, ValueError):
                gains = np.full(1, np.nan)  # named below, with what was given
            if gains.ndim != 1 or not np.all(np.isfinite(gains) & (gains >= 0)):
                raise InputError(
                    f"{name} must be a list of finite gains >= 0 (one per joint), got "
                    f"{getattr(self, name)!r}"
                )


@dataclass(frozen=True)
class ControlOutput:
    """What the controller computed at one tick.

    Attributes:
        tension_command: Tension for each motor drive [N], shape ``(m,)``.
        joint_torque: Wanted joint torque (feedforward compensation included) [N m], ``(n,)``.
        feedforward: The feedforward compensation ``dtau`` added [N m], ``(n,)`` (zeros if none).
        tension_feedforward: What a tension-space feedforward added to the wanted tensions,
            ``tension_command - F`` [N], ``(m,)`` (zeros if none).
        muscle_force: Allocated muscle forces [N], shape ``(m,)``.
        activation: Muscle activations [-], shape ``(m,)``.
        qdot_estimate: Estimated joint velocities [rad/s], shape ``(n,)``.
        feasible: Whether the allocation met the wanted torque within the muscles' capacity.
        reachable: Per muscle, whether the inverse Hill model reached the force, ``(m,)``.
    """

    tension_command: FloatArray
    joint_torque: FloatArray
    feedforward: FloatArray
    tension_feedforward: FloatArray
    muscle_force: FloatArray
    activation: FloatArray
    qdot_estimate: FloatArray
    feasible: bool
    reachable: NDArray[np.bool_]


@dataclass
class _ControllerState:
    q_prev: FloatArray
    qdot: FloatArray
    integral: FloatArray
    activation: FloatArray
    started: bool = field(default=False)


def check_tension_command(command: FloatArray, shape: tuple[int, ...]) -> None:
    """Refuse a tension-space feedforward's command that is not ``shape`` finite tensions.

    Args:
        command: What ``feedforward.tension_command`` gave [N].
        shape: The shape it must have, ``(m,)``.

    Raises:
        InputError: Another shape or a non-finite value (the command named).
    """
    if command.shape != shape or not np.all(np.isfinite(command)):
        raise InputError(f"feedforward.tension_command must give {shape} finite N, got {command}")


class MuscleSpaceController:
    """Joint PID + inverse dynamics + allocation + inverse Hill model (paper 003).

    Args:
        model: The nominal arm model (Pinocchio dynamics, MuJoCo cable geometry, Hill muscles).
        config: Gains and settings.
    """

    def __init__(self, model: RobotModel, config: ArmControllerConfig | None = None) -> None:
        if model.muscles is None:
            raise InputError("the muscle-space controller needs a model with Hill parameters")
        self.model = model
        self.config = config or ArmControllerConfig()
        n, m = model.n_joints, model.n_cables
        for name in ("kp", "ki", "kd"):
            if len(getattr(self.config, name)) != n:
                raise InputError(
                    f"controller {name} needs {n} gains, got {getattr(self.config, name)}"
                )
        strongest = np.asarray(model.muscles.max_isometric_force, dtype=float)
        if self.config.min_tension > strongest.min():
            weak = int(np.argmin(strongest))
            raise InputError(
                f"controller min_tension {self.config.min_tension} N is above the strength of "
                f"{model.cable_names[weak]} ({strongest[weak]} N, its max isometric force): "
                "expected a floor every muscle can pull"
            )
        self.period = 1.0 / self.config.rate_hz
        self._kp = np.asarray(self.config.kp, dtype=float)
        self._ki = np.asarray(self.config.ki, dtype=float)
        self._kd = np.asarray(self.config.kd, dtype=float)
        # the integral state is bounded so that Ki * integral stays within the integral limit
        self._integral_bound = self.config.integral_limit / np.maximum(self._ki, 1e-12)
        self._from_pinocchio = np.argsort(model.pin_q_index)
        identity = np.array_equal(model.pin_q_index, np.arange(n))
        self._pin_order = None if identity else np.asarray(model.pin_q_index)
        self._data = model.create_data()
        self._muscles = model.muscles
        self._hill = FastHill(model.muscles)
        self._jacobian = np.zeros((m, n))
        self._allocator = make_allocator(
            m, n, self.config.solver, weights=1.0 / model.muscles.max_isometric_force
        )
        # highest MTU shortening speed the Hill model is evaluated at, with a margin
        self._max_shortening = 0.95 * self._hill.max_shortening_speed
        cutoff = 2 * np.pi * self.config.velocity_cutoff_hz * self.period
        self._alpha = cutoff / (1.0 + cutoff)
        self._state = _ControllerState(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(m))

    def _cable_geometry(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Nominal cable lengths l(q) [m] and muscle Jacobian J_c(q) [m/rad] (MuJoCo)."""
        lengths = cable_kinematics(self.model.mj_model, self._data.mj, q, self._jacobian)
        return lengths, self._jacobian

    def _inverse_dynamics(
        self, q_ref: FloatArray, qd_ref: FloatArray, qdd_ref: FloatArray
    ) -> FloatArray:
        """Inverse-dynamics torque of the reference (Pinocchio RNEA) [N m], ``(n,)``, new."""
        model = self.model
        if self._pin_order is None:  # the two orders agree: no permutation
            return pinocchio.rnea(model.pin_model, self._data.pin, q_ref, qd_ref, qdd_ref)
        order = self._pin_order
        return pinocchio.rnea(
            model.pin_model, self._data.pin, q_ref[order], qd_ref[order], qdd_ref[order]
        )[self._from_pinocchio]

    def reference_torques(
        self, q_ref: FloatArray, qd_ref: FloatArray, qdd_ref: FloatArray
    ) -> FloatArray:
        """Inverse-dynamics torques of a whole reference [N m], ``(T, n)``.

        Row ``k`` is the torque :meth:`update` starts from at the reference's sample ``k``
        (the same call, so the same bits): the compiled loop takes them from here.

        Args:
            q_ref: Reference joint angles [rad], ``(T, n)``.
            qd_ref: Reference joint velocities [rad/s], ``(T, n)``.
            qdd_ref: Reference joint accelerations [rad/s^2], ``(T, n)``.

        Returns:
            The inverse-dynamics torque (Pinocchio RNEA of the nominal model) at every
            sample [N m], ``(T, n)``, a new array.
        """
        out = np.empty(np.shape(q_ref))
        for k in range(out.shape[0]):
            out[k] = self._inverse_dynamics(q_ref[k], qd_ref[k], qdd_ref[k])
        return out

    @property
    def qdot_estimate(self) -> FloatArray:
        """The current joint velocity estimate [rad/s], shape ``(n,)``."""
        return self._state.qdot.copy()

    def reset(self, q: ArrayLike) -> None:
        """Start from rest at the measured posture ``q`` [rad], shape ``(n,)``.

        Clears the velocity estimate, the PID integral and the muscle activations.

        Args:
            q: Measured joint angles [rad], shape ``(n,)``.

        Raises:
            InputError: ``q`` is not ``n`` finite numbers.
        """
        n, m = self.model.n_joints, self.model.n_cables
        self._state = _ControllerState(
            _vector(q, n, "q").copy(), np.zeros(n), np.zeros(n), np.zeros(m)
        )

    def update(
        self,
        readings: SensorReadings,
        q_ref: ArrayLike,
        qd_ref: ArrayLike,
        qdd_ref: ArrayLike,
        feedforward: ArrayLike | Callable[..., ArrayLike] | None = None,
    ) -> ControlOutput:
        """One control tick.

        Args:
            readings: The robot's sensor readings.
            q_ref: Reference joint angles [rad], shape ``(n,)``.
            qd_ref: Reference joint velocities [rad/s], shape ``(n,)``.
            qdd_ref: Reference joint accelerations [rad/s^2], shape ``(n,)``.
            feedforward: Joint-torque compensation ``dtau`` [N m], shape ``(n,)``; or a callable
                ``(readings, qdot_estimate, q_ref, qd_ref) -> dtau`` called after this tick's
                velocity estimate; or None. A callable with a ``tension_command(tension,
                q_ref)`` method turns the wanted tensions [N], ``(m,)``, into the drives'
                command (a tension-space feedforward); one with an
                ``observe_command(tension_command)`` method is then told the tick's command.

        Returns:
            The commands and what led to them.

        Raises:
            InputError: A reading or reference of the wrong shape or not finite, or a
                feedforward that gives one; the controller's state is then as before the call.
        """
        state = self._state
        n = state.qdot.shape[0]
        q = _vector(readings.q, n, "readings.q")
        q_ref, qd_ref = _vector(q_ref, n, "q_ref"), _vector(qd_ref, n, "qd_ref")
        tau = self._inverse_dynamics(q_ref, qd_ref, _vector(qdd_ref, n, "qdd_ref"))
        kept = [state.q_prev.copy(), state.qdot.copy(), state.integral.copy()]
        activation, started = state.activation, state.started
        try:
            return self._tick(readings, q, q_ref, qd_ref, tau, feedforward)
        except Exception:
            for now, then in zip((state.q_prev, state.qdot, state.integral), kept, strict=True):
                now[:] = then
            state.activation, state.started = activation, started
            raise

    def _tick(
        self,
        readings: SensorReadings,
        q: FloatArray,
        q_ref: FloatArray,
        qd_ref: FloatArray,
        tau: FloatArray,
        feedforward: ArrayLike | Callable[..., ArrayLike] | None,
    ) -> ControlOutput:
        """The tick of :meth:`update` after its input checks (it changes the state)."""
        state, cfg = self._state, self.config
        filter_and_pid(
            q,
            q_ref,
            qd_ref,
            self.period,
            self._alpha,
            self._kp,
            self._ki,
            self._kd,
            self._integral_bound,
            state.q_prev,
            state.qdot,
            state.integral,
            tau,
        )
        qdot = state.qdot
        observe = getattr(feedforward, "observe_command", None)
        shape = getattr(feedforward, "tension_command", None)
        if callable(feedforward):
            feedforward = feedforward(readings, qdot, q_ref, qd_ref)
        if feedforward is not None:
            dtau = np.asarray(feedforward, dtype=float)
            if dtau.shape != tau.shape or not np.all(np.isfinite(dtau)):
                raise InputError(f"feedforward must be {tau.shape} finite N m, got {dtau}")
            tau = tau + dtau

        lengths, jacobian = self._cable_geometry(q)
        m = lengths.shape[0]
        speed = np.empty(m)
        muscle_speed(jacobian, qdot, self._max_shortening, speed)
        active, passive = self._hill.parts(lengths, speed)
        f_min, f_max = np.empty(m), np.empty(m)
        force_bounds(active, passive, cfg.min_tension, f_min, f_max)
        result = self._allocator.solve(-jacobian.T, tau, f_min, f_max)
        activation, reachable = np.empty(m), np.empty(m, dtype=np.bool_)
        activation_and_reach(result.f, active, passive, activation, reachable)
        if cfg.activation_dynamics:
            state.activation = step_activation(state.activation, activation, self.period)
        else:
            state.activation = activation
        force = state.activation * active + passive
        command = force
        if shape is not None:  # a feedforward in tension space
            command = np.asarray(shape(force, q_ref), dtype=float)
            check_tension_command(command, force.shape)
        if observe is not None:  # a feedforward with memory of the commands
            observe(command)
        return ControlOutput(
            tension_command=command,
            joint_torque=tau,
            feedforward=np.zeros(tau.shape) if feedforward is None else dtau,
            tension_feedforward=command - force,
            muscle_force=result.f,
            activation=state.activation.copy(),
            qdot_estimate=qdot.copy(),
            feasible=result.feasible,
            reachable=reachable,
        )
