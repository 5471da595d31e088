"""The muscle-space controller of paper 003 (Fig. 3 and 5), for the cable-driven arm.

At every control tick (250 Hz by default), from sensor readings only:

1. joint velocity estimate: finite difference of the encoders through a first-order low-pass;
2. wanted joint torque: inverse-dynamics feedforward of the reference (Pinocchio RNEA,
   gravity included) plus a joint PID, plus an optional feedforward compensation ``dtau``
   (the learned compensator of paper 003 section 3.1):
   ``tau = ID(q_r, qd_r, qdd_r) + Kp e + Ki int(e) + Kd de/dt + dtau`` with ``e = q_r - q``;
3. muscle forces from the allocation core: ``-J_c(q)^T f = tau`` with each force within the
   muscle's capacity at its current length and velocity (``[max(passive, T_min),
   full activation]``), minimising the sum of squared activations ``sum (f_i / F_max,i)^2``;
4. activations from the inverse Hill model (clipped to [0, 1], flagged when out of reach),
   optionally filtered by the activation dynamics;
5. the muscle force at that activation (forward Hill model) is the tension command that the
   motor drives render at the motor side.

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
from msarm.errors import InputError
from msarm.model import RobotModel
from msarm.muscle.activation import step_activation
from msarm.muscle.fast import FastHill
from msarm.muscle.geometry import cable_kinematics
from msarm.plant.effects import SensorReadings

__all__ = ["ArmControllerConfig", "ControlOutput", "MuscleSpaceController"]

FloatArray = NDArray[np.float64]


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
        solver: Allocation solver name (see ``msarm.allocation.SOLVERS``).
    """

    rate_hz: float = 250.0
    kp: tuple[float, ...] = (60.0, 60.0, 30.0, 30.0)
    ki: tuple[float, ...] = (40.0, 40.0, 20.0, 20.0)
    kd: tuple[float, ...] = (4.0, 4.0, 1.5, 1.5)
    integral_limit: float = 3.0
    min_tension: float = 5.0
    velocity_cutoff_hz: float = 30.0
    activation_dynamics: bool = False
    solver: str = "fast"


@dataclass(frozen=True)
class ControlOutput:
    """What the controller computed at one tick.

    Attributes:
        tension_command: Tension for each motor drive [N], shape ``(m,)``.
        joint_torque: Wanted joint torque (feedforward compensation included) [N m], ``(n,)``.
        feedforward: The feedforward compensation ``dtau`` added [N m], ``(n,)`` (zeros if none).
        muscle_force: Allocated muscle forces [N], shape ``(m,)``.
        activation: Muscle activations [-], shape ``(m,)``.
        qdot_estimate: Estimated joint velocities [rad/s], shape ``(n,)``.
        feasible: Whether the allocation met the wanted torque within the muscles' capacity.
        reachable: Per muscle, whether the inverse Hill model reached the force, ``(m,)``.
    """

    tension_command: FloatArray
    joint_torque: FloatArray
    feedforward: FloatArray
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
        self.period = 1.0 / self.config.rate_hz
        self._kp = np.asarray(self.config.kp, dtype=float)
        self._ki = np.asarray(self.config.ki, dtype=float)
        self._kd = np.asarray(self.config.kd, dtype=float)
        # the integral state is bounded so that Ki * integral stays within the integral limit
        self._integral_bound = self.config.integral_limit / np.maximum(self._ki, 1e-12)
        self._from_pinocchio = np.argsort(model.pin_q_index)
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

    @property
    def qdot_estimate(self) -> FloatArray:
        """The current joint velocity estimate [rad/s], shape ``(n,)``."""
        return self._state.qdot.copy()

    def reset(self, q: ArrayLike) -> None:
        """Start from rest at the measured posture ``q`` [rad], shape ``(n,)``."""
        n, m = self.model.n_joints, self.model.n_cables
        self._state = _ControllerState(
            np.asarray(q, dtype=float).copy(), np.zeros(n), np.zeros(n), np.zeros(m)
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
                velocity estimate; or None.

        Returns:
            The commands and what led to them.
        """
        state, cfg, model = self._state, self.config, self.model
        q = readings.q
        raw_velocity = (q - state.q_prev) / self.period
        state.qdot += self._alpha * (raw_velocity - state.qdot)
        state.q_prev = q.copy()
        qdot = state.qdot

        error = np.asarray(q_ref, dtype=float) - q
        state.integral = np.clip(
            state.integral + error * self.period, -self._integral_bound, self._integral_bound
        )
        tau = pinocchio.rnea(
            model.pin_model,
            self._data.pin,
            model.to_pinocchio(np.asarray(q_ref, dtype=float)),
            model.to_pinocchio(np.asarray(qd_ref, dtype=float)),
            model.to_pinocchio(np.asarray(qdd_ref, dtype=float)),
        )[self._from_pinocchio]
        tau = tau + self._kp * error + self._ki * state.integral
        tau += self._kd * (np.asarray(qd_ref, dtype=float) - qdot)
        if callable(feedforward):
            feedforward = feedforward(readings, qdot, q_ref, qd_ref)
        if feedforward is not None:
            dtau = np.asarray(feedforward, dtype=float)
            if dtau.shape != tau.shape or not np.all(np.isfinite(dtau)):
                raise InputError(f"feedforward must be {tau.shape} finite N m, got {dtau}")
            tau = tau + dtau

        lengths, jacobian = self._cable_geometry(q)
        speed = np.maximum(jacobian @ qdot, -self._max_shortening)
        active, passive = self._hill.parts(lengths, speed)
        f_min = np.maximum(passive, cfg.min_tension)
        f_max = np.maximum(passive + active, f_min)
        result = self._allocator.solve(-jacobian.T, tau, f_min, f_max)
        activation = np.clip((result.f - passive) / active, 0.0, 1.0)
        reachable = (result.f >= passive - 1e-9) & (result.f <= passive + active + 1e-9)
        if cfg.activation_dynamics:
            state.activation = step_activation(state.activation, activation, self.period)
        else:
            state.activation = activation
        force = state.activation * active + passive
        return ControlOutput(
            tension_command=force,
            joint_torque=tau,
            feedforward=np.zeros_like(tau) if feedforward is None else dtau,
            muscle_force=result.f,
            activation=state.activation.copy(),
            qdot_estimate=qdot.copy(),
            feasible=result.feasible,
            reachable=reachable,
        )
