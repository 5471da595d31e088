"""Effects: what makes the simulated arm differ from its nominal model.

An effect is a small class with named parameters and a documented equation. The built-in
effects of the cables and winches (sheath friction, winch friction, cogging, elasticity) run
inside the compiled step of :mod:`msarm.plant.cable_kernel`; the others, and every effect a
user adds, work through hooks that the plant calls. An effect overrides only the hooks it
needs (the plant looks up, once, which hooks each effect overrides, so unused hooks cost
nothing per step):

- ``configure(plant)``: once, when the plant is built (may edit the plant's private
  ``mj_model``, e.g. joint friction);
- ``reset(rng)``: at every plant reset, with the plant's seeded generator;
- ``transmission(state) -> (m,)``: factor from motor-side to insertion-side tension,
  ``T_insertion = factor * T_motor`` (several multiply); finite and ``>= 0`` (a cable only
  pulls; above 1 is allowed, as a cable paid out through its sheath delivers more);
- ``winch_torque(state) -> ((m,), (m,))``: torque added on each winch [N m] and its
  derivative with respect to the winch speed [N m s/rad], both finite (the plant integrates
  the winch implicitly, so steep friction laws stay stable);
- ``sense(readings, rng) -> readings``: change what the sensors report (noise, bias, delay);
  a :class:`SensorReadings` of the same shapes, finite;
- ``actuate(command) -> command``: change the tension command on its way to the drives;
  shape ``(m,)``, finite and ``>= 0`` [N];
- ``parameters() -> dict``: the ground truth written to the sidecar file, under the
  effect's ``name``.

Each effect of a plant has its own ``name`` (a user effect may not take a built-in effect's
name, nor another's): the plant refuses a clash when it is built. The plant checks what a
user effect's hooks return at every call (shape, finite values, the ranges above) and raises
:class:`msarm.errors.InputError` naming the effect and the hook; the built-in effects' hooks
are not checked (the compiled step runs them).

Winch angle ``theta`` is positive when the winch reels cable in; the cable slides through
its sheath towards the motor at ``v_in = r * omega``. Users add their own effect by
subclassing :class:`Effect` and passing an instance to ``ArmPlant(..., extra_effects=[...])``
(see ``examples/custom_effect.py``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import NDArray

from msarm.plant.config import (
    CoggingConfig,
    DelayConfig,
    EffectsConfig,
    JointFrictionConfig,
    SensorNoiseConfig,
    SheathFrictionConfig,
    WinchFrictionConfig,
)

if TYPE_CHECKING:
    from msarm.plant.arm_plant import ArmPlant

__all__ = [
    "CableState",
    "Cogging",
    "EFFECT_DESCRIPTIONS",
    "Delay",
    "Effect",
    "JointFriction",
    "SensorNoise",
    "SensorReadings",
    "SheathFriction",
    "WinchFriction",
    "build_effects",
]

FloatArray = NDArray[np.float64]


@dataclass
class CableState:
    """The state the effects see at a plant step (views; do not modify).

    Attributes:
        q: Joint angles [rad], shape ``(n,)``.
        qdot: Joint velocities [rad/s], shape ``(n,)``.
        lengths: Cable path lengths l(q) [m], shape ``(m,)``.
        wrap_angles: Cable wrap angles Theta(q) [rad], shape ``(m,)``.
        winch_angle: Winch angles theta (reel-in positive) [rad], shape ``(m,)``.
        winch_speed: Winch speeds omega [rad/s], shape ``(m,)``.
        tension_motor: Motor-side tensions of the last step [N], shape ``(m,)``.
        drum_radius: Winch drum radius r [m].
    """

    q: FloatArray
    qdot: FloatArray
    lengths: FloatArray
    wrap_angles: FloatArray
    winch_angle: FloatArray
    winch_speed: FloatArray
    tension_motor: FloatArray
    drum_radius: float


@dataclass(frozen=True)
class SensorReadings:
    """What the robot's sensors report (the only thing a controller may read).

    Attributes:
        t: Time [s].
        q: Joint encoders [rad], shape ``(n,)``.
        motor_angle: Motor (winch) encoders, reel-in positive [rad], shape ``(m,)``.
        motor_torque: Motor torque from the current [N m], shape ``(m,)``.
        tension_motor: Load cell on each cable at the motor side [N], shape ``(m,)``.
    """

    t: float
    q: FloatArray
    motor_angle: FloatArray
    motor_torque: FloatArray
    tension_motor: FloatArray


class Effect:
    """Base class of the effects; override the hooks you need (see the module docstring)."""

    name: ClassVar[str] = "effect"

    def configure(self, plant: ArmPlant) -> None:
        """Prepare for ``plant`` (called once).

        Args:
            plant: The plant being built; its private ``mj_model`` may be edited here.
        """

    def reset(self, rng: np.random.Generator) -> None:
        """Reset internal state (called at every plant reset).

        Args:
            rng: The plant's generator, re-seeded at every reset (draw from it, not from a
                generator of your own, to keep runs reproducible).
        """

    def transmission(self, state: CableState) -> FloatArray:
        """Factor ``T_insertion / T_motor`` of each cable [-], shape ``(m,)``, finite, ``>= 0``.

        Called at every plant step; the insertion-side tension after sheath friction is
        multiplied by the factor (the factors of several effects multiply).

        Args:
            state: The plant's state at this step (read-only views).

        Returns:
            The factor of each cable [-], shape ``(m,)``, finite and ``>= 0`` (1: no change;
            above 1 is allowed).
        """
        raise NotImplementedError

    def winch_torque(self, state: CableState) -> tuple[FloatArray, FloatArray]:
        """Torque on each winch [N m] and its derivative wrt the winch speed [N m s/rad].

        Called at every plant step; the torques of several effects add to the winch friction
        and cogging. Sign as the winch angle: a positive torque acts in the reel-in direction
        (friction is ``-b * omega``, its slope ``-b``).

        Args:
            state: The plant's state at this step (read-only views).

        Returns:
            ``(torque, slope)``, each of shape ``(m,)`` and finite: the torque added on each
            winch [N m] and its derivative ``d torque / d omega`` [N m s/rad], which the plant
            uses to integrate the winch implicitly.
        """
        raise NotImplementedError

    def sense(self, readings: SensorReadings, rng: np.random.Generator) -> SensorReadings:
        """Return the readings as this effect changes them (same shapes, finite values).

        Args:
            readings: The readings so far (true values, or as earlier effects changed them):
                ``t`` [s] a float, ``q`` [rad] ``(n,)``, ``motor_angle`` [rad],
                ``motor_torque`` [N m] and ``tension_motor`` [N] ``(m,)``. Do not modify them
                in place.
            rng: The plant's seeded generator (for noise).

        Returns:
            A new :class:`SensorReadings` with the same shapes, finite values.
        """
        raise NotImplementedError

    def actuate(self, command: FloatArray) -> FloatArray:
        """Return the tension command [N] as it reaches the drives, ``(m,)``, finite, ``>= 0``.

        Args:
            command: Motor-side tension command [N], shape ``(m,)``, finite and ``>= 0`` (as
                the controller sent it, or as earlier effects changed it).

        Returns:
            The command passed on to the drives [N], shape ``(m,)``, finite and ``>= 0``.
        """
        raise NotImplementedError

    def parameters(self) -> dict:
        """The effect's parameters (ground truth for the sidecar file).

        Returns:
            Parameter names to values (YAML-serialisable), stored under the effect's
            ``name``; empty by default.
        """
        return {}


class SheathFriction(Effect):
    """Capstan friction of each cable in its sheath, posture dependent, with stiction.

    The cable carries ``T_m`` on the motor side and ``T_i`` at the insertion. While the cable
    slides through its sheath the two obey the capstan law

    ``T_i = T_m * exp(-mu * Theta(q) * sgn(v_in))``

    with ``Theta(q)`` the total wrap angle of the cable's path [rad] and ``v_in`` the speed at
    which the cable slides towards the motor: pulled in, the insertion sees less than the motor
    side pulls; paid out, more. While it sticks, ``T_i`` stays anywhere in
    ``[T_m e^(-mu Theta), T_m e^(mu Theta)]`` (hysteresis). With elastic cables this holds
    exactly for the springs' tensions (a two-segment cable with a quasi-static sliding node);
    the rope's internal damping adds ``c (dl/dt + r omega)`` at both ends, outside the law, so
    while tensions change fast the ratio leaves it by a few percent (up to 7.7 % at a 5 Hz,
    30 +- 20 N command; within 0.4 % on a tracking run). With rigid cables the sign is
    smoothed, ``tanh(v_in / v_s)``. Runs in :mod:`msarm.plant.cable_kernel`.
    """

    name = "sheath_friction"

    def __init__(self, config: SheathFrictionConfig) -> None:
        self.config = config

    def parameters(self) -> dict:  # noqa: D102
        return asdict(self.config)


class WinchFriction(Effect):
    """Coulomb + viscous friction in winch and motor (a simplification of paper 000 eq. 4-5).

    ``tau_f = -tau_c * tanh(omega / omega_s) - b * omega`` on the winch speed ``omega``:
    paper 000's model without its load term ``c3 f`` and its ``v^2`` term.
    Runs in :mod:`msarm.plant.cable_kernel`.
    """

    name = "winch_friction"

    def __init__(self, config: WinchFrictionConfig) -> None:
        self.config = config

    def parameters(self) -> dict:  # noqa: D102
        return asdict(self.config)


class Cogging(Effect):
    """Motor cogging torque, periodic in the motor angle (paper 001 eq. 2-3, one harmonic).

    ``tau_cog = A * sin(N * theta + phi)``. Runs in :mod:`msarm.plant.cable_kernel`.
    """

    name = "cogging"

    def __init__(self, config: CoggingConfig) -> None:
        self.config = config

    def parameters(self) -> dict:  # noqa: D102
        return asdict(self.config)


class JointFriction(Effect):
    """Coulomb + viscous friction at every joint.

    ``tau_f = -tau_c sgn(qdot) - b qdot``, rendered by MuJoCo's dry-friction constraint
    (``dof_frictionloss``, true stiction) and joint damping (``dof_damping``).
    """

    name = "joint_friction"

    def __init__(self, config: JointFrictionConfig) -> None:
        self.config = config

    def configure(self, plant: ArmPlant) -> None:  # noqa: D102
        plant.mj_model.dof_frictionloss[:] = self.config.coulomb
        plant.mj_model.dof_damping[:] = self.config.viscous

    def parameters(self) -> dict:  # noqa: D102
        return asdict(self.config)


class SensorNoise(Effect):
    """Gaussian noise (std per channel) and a constant load-cell bias on every reading."""

    name = "sensor_noise"

    def __init__(self, config: SensorNoiseConfig) -> None:
        self.config = config
        self._sizes: tuple[int, ...] = ()
        self._std = np.zeros(0)

    def _noise_std(self, sizes: tuple[int, ...]) -> FloatArray:
        """The noise std of every sample of one reading, channel after channel, ``(sum(sizes),)``.

        Args:
            sizes: Sizes of ``q``, ``motor_angle``, ``motor_torque`` and ``tension_motor``.
        """
        if sizes != self._sizes:  # built once per plant size
            c = self.config
            stds = (c.joint_noise, c.motor_angle_noise, c.torque_noise, c.tension_noise)
            self._std = np.repeat(np.array(stds, dtype=float), sizes)
            self._sizes = sizes
        return self._std

    def draw(
        self, sizes: tuple[int, ...], rng: np.random.Generator, readings: int | None = None
    ) -> FloatArray:
        """Noise samples of one reading, ``(d,)``, or of ``readings`` readings, ``(readings, d)``.

        ``d = sum(sizes)``: the channels ``q``, ``motor_angle``, ``motor_torque``,
        ``tension_motor`` side by side. Drawn in one call: the generator's stream is the same
        as with one draw per channel in that order, or per reading (the compiled closed loop
        draws a whole run's at once).
        """
        std = self._noise_std(sizes)
        shape = std.shape if readings is None else (readings, std.shape[0])
        return std * rng.standard_normal(shape)

    def sense(self, readings: SensorReadings, rng: np.random.Generator) -> SensorReadings:
        """Add the noise (and the load-cell bias) to every channel (each of shape ``(k,)``).

        The samples come from :meth:`draw`.
        """
        channels = (readings.q, readings.motor_angle, readings.motor_torque)
        sizes = (*(x.size for x in channels), readings.tension_motor.size)
        noise = self.draw(sizes, rng)
        a = sizes[0]
        b = a + sizes[1]
        c = b + sizes[2]
        return SensorReadings(
            t=readings.t,
            q=readings.q + noise[:a],
            motor_angle=readings.motor_angle + noise[a:b],
            motor_torque=readings.motor_torque + noise[b:c],
            tension_motor=readings.tension_motor + self.config.tension_bias + noise[c:],
        )

    def parameters(self) -> dict:  # noqa: D102
        return asdict(self.config)


class Delay(Effect):
    """Readings and commands arrive a whole number of control periods late.

    ``y_controller(k) = y(k - d_s)`` and ``u_drive(k) = u_controller(k - d_a)``. Before enough
    history exists the controller gets the first reading, and the drives hold the tension the
    plant was reset to (:meth:`hold`) until the first command reaches them, ``d_a`` periods
    after it was sent.
    """

    name = "delay"

    def __init__(self, config: DelayConfig) -> None:
        self.config = config
        self._readings: deque[SensorReadings] = deque(maxlen=config.sensing_periods + 1)
        self._commands: deque[FloatArray] = deque(maxlen=config.actuation_periods + 1)

    def reset(self, rng: np.random.Generator) -> None:  # noqa: D102
        self._readings.clear()
        self._commands.clear()

    def sense(self, readings: SensorReadings, rng: np.random.Generator) -> SensorReadings:  # noqa: D102
        self._readings.append(readings)
        return self._readings[0]

    def hold(self, command: FloatArray) -> None:
        """Start the command history with the drives' command at reset.

        Args:
            command: The tension the drives hold at reset [N], shape ``(m,)``: what they
                get in the first ``d_a`` periods, before the first command arrives.
        """
        self._commands.clear()
        for _ in range(self.config.actuation_periods):
            self._commands.append(np.array(command, dtype=float))

    def actuate(self, command: FloatArray) -> FloatArray:  # noqa: D102
        self._commands.append(np.array(command, dtype=float))
        return self._commands[0]

    def parameters(self) -> dict:  # noqa: D102
        return asdict(self.config)


#: One line per built-in effect: its equation, for ``msarm track --list``.
EFFECT_DESCRIPTIONS = {
    "sheath_friction": "T_insertion = T_motor exp(-mu Theta(q) sgn(v)); sticks in between",
    "winch_friction": "tau_f = -tau_c tanh(omega/omega_s) - b omega on each winch",
    "elasticity": "T = max(k s + c ds/dt, 0), s = stretch (0 when slack): elastic, damped "
    "cables that go slack",
    "joint_friction": "tau_f = -tau_c sgn(qdot) - b qdot at each joint (MuJoCo dry friction)",
    "cogging": "tau_cog = A sin(N theta + phi) on each motor",
    "sensor_noise": "reading = truth + N(0, sigma^2) on every sensor, + bias on the load cells",
    "delay": "readings / commands late by whole control periods",
}

_BUILT_IN = {
    "sheath_friction": SheathFriction,
    "winch_friction": WinchFriction,
    "cogging": Cogging,
    "joint_friction": JointFriction,
    "sensor_noise": SensorNoise,
    "delay": Delay,
}


def build_effects(config: EffectsConfig) -> list[Effect]:
    """Instantiate the built-in effects that ``config`` switches on.

    Elasticity is not among them: it is the plant's cable model itself.

    Args:
        config: Switches and parameters of the built-in effects.

    Returns:
        One effect per enabled built-in effect (elasticity excepted), in the order sheath
        friction, winch friction, cogging, joint friction, sensor noise, delay.
    """
    return [
        cls(getattr(config, name))
        for name, cls in _BUILT_IN.items()
        if getattr(config, name).enabled
    ]
