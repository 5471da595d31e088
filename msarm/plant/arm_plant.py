"""The tendon-in-sheath arm plant: MuJoCo arm, motor winches, elastic cables, effects.

Each cable is wound on a winch (drum radius ``r``, rotor inertia ``J``) driven by a motor
whose drive closes a tension loop on the motor-side load cell. The cable runs through its
sheath to the arm; its path length ``l(q)`` is MuJoCo's spatial tendon length. The cable is
elastic and goes slack (no tension) when its path is shorter than what was paid out; sheath
friction makes the insertion-side tension differ from the motor-side one, with stiction.
The joints feel ``tau = -J_c(q)^T T_insertion`` (see ``msarm.muscle.geometry``). The
equations are in :mod:`msarm.plant.cable_kernel`, which runs them compiled, once per plant
step, between MuJoCo's ``mj_step1`` and ``mj_step2``.

The plant steps at its own time step (1 kHz by default). The sensors (:meth:`ArmPlant.sense`)
are what a controller may read; ground truth (insertion tensions, stretch, the effects'
parameters) is available separately and never through :meth:`ArmPlant.sense`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError, MsarmError
from msarm.model import RobotModel
from msarm.mujoco_c import step_functions
from msarm.muscle.batch_kinematics import current_wrap_angles
from msarm.plant.cable_kernel import PARAMS, step_cables, step_plant
from msarm.plant.config import PlantConfig
from msarm.plant.effects import CableState, Effect, SensorReadings, build_effects
from msarm.plant.instability import UNSTABLE_INDEX, instability_found

__all__ = ["ArmPlant", "SimulationDivergedError"]

FloatArray = NDArray[np.float64]


class SimulationDivergedError(MsarmError):
    """The simulation produced NaN or MuJoCo reported an instability.

    Attributes:
        time: Simulated time at which it was detected [s].
        state: The plant state then (joint angles and velocities, winch angles).
    """

    def __init__(self, message: str, time: float, state: dict) -> None:
        super().__init__(message)
        self.time = time
        self.state = state


def _overrides(effect: Effect, hook: str) -> bool:
    return getattr(type(effect), hook) is not getattr(Effect, hook)


class ArmPlant:
    """The simulated musculoskeletal arm: the "real robot" of msarm.

    Args:
        model: The arm (its file is loaded again into a private MuJoCo model, so effects may
            change that model without touching ``model``).
        config: Plant parameters and effect switches.
        seed: Seed of the plant's random generator (sensor noise); same seed, same run.
        extra_effects: User effects added after the built-in ones.
    """

    def __init__(
        self,
        model: RobotModel,
        config: PlantConfig,
        seed: int = 0,
        extra_effects: list[Effect] | None = None,
    ) -> None:
        if model.muscles is None:
            raise InputError("the arm plant needs a model with Hill parameters (F_max per cable)")
        self.model = model
        self.config = config
        self.seed = seed
        self.mj_model = mujoco.MjModel.from_xml_path(str(model.path))
        self.mj_model.opt.timestep = config.timestep
        self.mj_data = mujoco.MjData(self.mj_model)
        self.effects: list[Effect] = build_effects(config.effects) + list(extra_effects or [])
        for effect in self.effects:
            effect.configure(self)
        self._transmitters = [e for e in self.effects if _overrides(e, "transmission")]
        self._winch_loads = [e for e in self.effects if _overrides(e, "winch_torque")]
        if extra_effects is None:
            extra_effects = []
        self._sensors = [e for e in self.effects if _overrides(e, "sense")]
        self._actuators = [e for e in self.effects if _overrides(e, "actuate")]
        m = model.n_cables
        winch = config.winch
        self.drum_radius = winch.drum_radius
        self.torque_limit = (
            winch.torque_limit_factor * model.muscles.max_isometric_force * winch.drum_radius
        )
        effects = config.effects
        self.elastic = effects.elasticity.enabled
        self._k = effects.elasticity.stiffness
        sheath, friction, cogging = effects.sheath_friction, effects.winch_friction, effects.cogging
        values = {
            "timestep": config.timestep,
            "drum_radius": winch.drum_radius,
            "rotor_inertia": winch.rotor_inertia,
            "drive_gain": winch.drive_gain,
            "stiffness": self._k,
            "mu": sheath.mu if sheath.enabled else 0.0,
            "smoothing_velocity": sheath.smoothing_velocity,
            "coulomb": friction.coulomb if friction.enabled else 0.0,
            "viscous": friction.viscous if friction.enabled else 0.0,
            "smoothing_speed": friction.smoothing_speed,
            "cog_amplitude": cogging.amplitude if cogging.enabled else 0.0,
            "cog_periods": float(cogging.periods_per_revolution),
            "cog_phase": cogging.phase,
            "elastic": 1.0 if self.elastic else 0.0,
            "damping": effects.elasticity.damping,
        }
        self._params = np.array([values[name] for name in PARAMS])
        self._slide = np.zeros(m)
        self._stretch_motor0 = np.zeros(m)
        self._stretch_insertion0 = np.zeros(m)
        self._user_torque = np.zeros(m)
        self._user_slope = np.zeros(m)
        self._user_factor = np.ones(m)
        self._has_user_hooks = bool(self._winch_loads or self._transmitters)
        self._state = CableState(
            q=self.mj_data.qpos,
            qdot=self.mj_data.qvel,
            lengths=self.mj_data.ten_length,
            wrap_angles=np.zeros(m),
            winch_angle=np.zeros(m),
            winch_speed=np.zeros(m),
            tension_motor=np.zeros(m),
            drum_radius=winch.drum_radius,
        )
        self._rng = np.random.default_rng(seed)
        self._period_start = {
            "q": np.zeros(self.mj_model.nq),
            "qdot": np.zeros(self.mj_model.nv),
            "winch_angle": np.zeros(m),
        }
        self._command = np.zeros(m)
        self._length_ref = np.zeros(m)
        self.tension_insertion = np.zeros(m)
        self.motor_torque = np.zeros(m)
        self._kernel_args = self._cable_kernel_args()
        # live view of MuJoCo's warning counters (read after every period)
        self._warnings = self.mj_data.warning.number
        # the whole step loop compiled (MuJoCo called through its C addresses) when MuJoCo's
        # library is found and no user hook must run in Python between the two halves
        functions = step_functions()
        self._compiled_args = (
            None
            if functions is None or self._has_user_hooks
            else (
                functions.step1,
                functions.step2,
                self.mj_model._address,
                self.mj_data._address,
                self._kernel_args,
                self.mj_data.qpos,
                self.mj_data.qvel,
                self._state.winch_speed,
                self._warnings,
                UNSTABLE_INDEX,
            )
        )

    # ----------------------------------------------------------------------------- state
    @property
    def time(self) -> float:
        """Simulated time [s]."""
        return float(self.mj_data.time)

    @property
    def compiled(self) -> bool:
        """Whether :meth:`step` runs its whole loop compiled (see :mod:`msarm.mujoco_c`).

        False where MuJoCo's library was not found or a user effect hooks into the step.
        """
        return self._compiled_args is not None

    @property
    def n_cables(self) -> int:
        """Number of cables ``m``."""
        return self.model.n_cables

    def reset(
        self, q: ArrayLike, tensions: ArrayLike | None = None, qdot: ArrayLike | None = None
    ) -> None:
        """Put the arm at rest at ``q`` with the cables pre-tensioned to ``tensions``.

        Args:
            q: Joint angles [rad], shape ``(n,)``.
            tensions: Motor-side tensions [N], shape ``(m,)``; zero if omitted. The drives are
                commanded the same until the first :meth:`command`.
            qdot: Joint velocities [rad/s], shape ``(n,)``; zero if omitted.
        """
        n, m = self.model.n_joints, self.n_cables
        q = self._vector(q, n, "q")
        tensions = self._vector(np.zeros(m) if tensions is None else tensions, m, "tensions")
        if np.any(tensions < 0):
            raise InputError(f"tensions must be >= 0 N, got {tensions}")
        mujoco.mj_resetData(self.mj_model, self.mj_data)
        self.mj_data.qpos[:] = q
        self.mj_data.qvel[:] = 0.0 if qdot is None else self._vector(qdot, n, "qdot")
        self._rng = np.random.default_rng(self.seed)
        for effect in self.effects:
            effect.reset(self._rng)
        mujoco.mj_forward(self.mj_model, self.mj_data)
        state = self._state
        state.wrap_angles[:] = current_wrap_angles(self.mj_model, self.mj_data)
        # theta = 0 at the reset posture; each cable segment carries half the initial stretch.
        half = tensions / (2.0 * self._k) if self.elastic else np.zeros(m)
        self._length_ref[:] = self.mj_data.ten_length
        self._stretch_motor0[:] = half
        self._stretch_insertion0[:] = half
        self._slide[:] = 0.0
        state.winch_angle[:] = 0.0
        state.winch_speed[:] = 0.0
        state.tension_motor[:] = tensions
        self._command[:] = tensions
        self.tension_insertion[:] = tensions
        self.motor_torque[:] = tensions * self.drum_radius

    def command(self, tension: ArrayLike) -> None:
        """Set the tension command of the drives [N], shape ``(m,)``; held until the next."""
        tension = self._vector(tension, self.n_cables, "tension command")
        for effect in self._actuators:
            tension = effect.actuate(tension)
        self._command[:] = tension

    def sense(self) -> SensorReadings:
        """Read the robot's sensors (encoders, motor torques, motor-side load cells)."""
        readings = SensorReadings(
            t=float(self.mj_data.time),
            q=self._state.q.copy(),
            motor_angle=self._state.winch_angle.copy(),
            motor_torque=self.motor_torque.copy(),
            tension_motor=self._state.tension_motor.copy(),
        )
        for effect in self._sensors:
            readings = effect.sense(readings, self._rng)
        return readings

    def ground_truth(self) -> dict[str, FloatArray]:
        """Simulation-only truth at the current step (never available to a controller).

        Returns:
            ``q``, ``qdot`` [rad, rad/s]; ``tension_motor``, ``tension_insertion`` [N];
            ``stretch`` [m] (negative: slack); ``wrap_angle`` [rad]; ``winch_angle`` [rad].
        """
        truth = {key: value.copy() for key, value in self._truth_views().items()}
        truth["stretch"] = self._state.lengths - self.unstretched_length()
        return truth

    def record_ground_truth(self, out: Mapping[str, FloatArray]) -> None:
        """Write the ground truth of :meth:`ground_truth` into ``out``, without copies.

        The runner's fast path: each array of ``out`` (one row of a log, say) receives the
        same values as the entry of :meth:`ground_truth` of the same key.

        Args:
            out: Destination arrays keyed like :meth:`ground_truth`'s (any subset of its keys),
                shape ``(n,)`` for ``q``/``qdot`` and ``(m,)`` for the others, written in place.
        """
        views = self._truth_views()
        for key, target in out.items():
            if key == "stretch":
                np.subtract(self._state.lengths, self.unstretched_length(), out=target)
            else:
                target[...] = views[key]

    def _truth_views(self) -> dict[str, FloatArray]:
        """Live views of the ground truth's arrays, all but the stretch (which is computed)."""
        state = self._state
        return {
            "q": state.q,
            "qdot": state.qdot,
            "tension_motor": state.tension_motor,
            "tension_insertion": self.tension_insertion,
            "wrap_angle": state.wrap_angles,
            "winch_angle": state.winch_angle,
        }

    def unstretched_length(self) -> FloatArray:
        """Unstretched cable lengths [m], shape ``(m,)``: the path length minus the stretch."""
        return (
            self._length_ref
            - self._stretch_motor0
            - self._stretch_insertion0
            - self.drum_radius * self._state.winch_angle
        )

    def effect_parameters(self) -> dict[str, dict]:
        """Ground truth of the plant: every effect switched on, with its parameters."""
        truth = {effect.name: effect.parameters() for effect in self.effects}
        if self.elastic:
            truth["elasticity"] = {
                "stiffness": self._k,
                "damping": self.config.effects.elasticity.damping,
            }
        return truth

    # ------------------------------------------------------------------------------ step
    def step(self, n_steps: int = 1) -> None:
        """Advance the plant by ``n_steps`` time steps with the current command.

        Raises:
            SimulationDivergedError: NaN in the state or a MuJoCo instability warning.
        """
        # MuJoCo resets its state (time included) when it finds a bad one: take the time and
        # the state first, to name them if the period fails
        end = float(self.mj_data.time) + n_steps * self.config.timestep
        start = self._period_start
        np.copyto(start["q"], self.mj_data.qpos)
        np.copyto(start["qdot"], self.mj_data.qvel)
        np.copyto(start["winch_angle"], self._state.winch_angle)
        if self._compiled_args is not None:
            if step_plant(n_steps, *self._compiled_args):
                self._raise_diverged(end)
            return
        model, data = self.mj_model, self.mj_data
        step1, step2, args = mujoco.mj_step1, mujoco.mj_step2, self._kernel_args
        hooks = self._user_hooks if self._has_user_hooks else None
        for _ in range(n_steps):
            # one plant step: MuJoCo up to the forces, the cables and winches, MuJoCo's rest
            step1(model, data)
            if hooks is not None:
                hooks()
            step_cables(*args)
            step2(model, data)
        self._check_finite(end)

    def update_wrap_angles(self) -> None:
        """Recompute the cables' wrap angles at the current posture.

        The runner calls this every few control periods: they change slowly with posture.
        """
        self._state.wrap_angles[:] = current_wrap_angles(self.mj_model, self.mj_data)

    def _user_hooks(self) -> None:
        state, m = self._state, self.n_cables
        self._user_torque[:] = 0.0
        self._user_slope[:] = 0.0
        self._user_factor[:] = 1.0
        for effect in self._winch_loads:
            torque, slope = effect.winch_torque(state)
            self._user_torque += torque
            self._user_slope += slope
        for effect in self._transmitters:
            self._user_factor *= effect.transmission(state)
        if self._user_factor.shape != (m,):
            raise InputError(f"user effects must return arrays of shape ({m},)")

    def _cable_kernel_args(self) -> tuple:
        """The arguments of :func:`step_cables`, in its order (views, built once).

        Every array is updated in place (by the kernel, :meth:`reset` and :meth:`command`) or is
        a live view of MuJoCo's model or data, so one tuple serves every step.
        """
        model, data, state = self.mj_model, self.mj_data, self._state
        return (
            self._params,
            data.ten_length,
            data.ten_velocity,
            state.wrap_angles,
            self._command,
            self.torque_limit,
            self._length_ref,
            self._stretch_motor0,
            self._stretch_insertion0,
            self._user_torque,
            self._user_slope,
            self._user_factor,
            state.winch_angle,
            state.winch_speed,
            self._slide,
            state.tension_motor,
            self.tension_insertion,
            self.motor_torque,
            data.ten_J,
            model.ten_J_rownnz,
            model.ten_J_rowadr,
            model.ten_J_colind,
            data.qfrc_applied,
        )

    def _check_finite(self, end: float) -> None:
        state = self._state
        # one sum is NaN or inf exactly when some element is (a cheap check every period)
        total = float(state.q.sum() + state.qdot.sum() + state.winch_speed.sum())
        if self._warnings[UNSTABLE_INDEX].any() or not math.isfinite(total):
            self._raise_diverged(end)

    def _raise_diverged(self, end: float) -> None:
        """Raise :class:`SimulationDivergedError`: the period that ended at ``end`` [s], the state.

        Where MuJoCo found a bad joint state it has reset its own (time and state), so the time
        named is the end of the period, the state is the one the period started from (the last
        one MuJoCo accepted), and the message says what MuJoCo found. Otherwise (a NaN in the
        winches) the state is the one the period ended in.
        """
        data = self.mj_data
        found = instability_found(data)
        if found:
            start = self._period_start
            state = {key: values.tolist() for key, values in start.items()}
            where = "at the start of that period"
        else:
            state = {
                "q": data.qpos.tolist(),
                "qdot": data.qvel.tolist(),
                "winch_angle": self._state.winch_angle.tolist(),
            }
            where = "at its end"
        raise SimulationDivergedError(
            f"simulation diverged at t = {end:.4f} s ({where}: q = {state['q']}, "
            f"qdot = {state['qdot']})" + "".join(f"; {text}" for text in found),
            end,
            state,
        )

    @staticmethod
    def _vector(value: ArrayLike, size: int, name: str) -> FloatArray:
        array = np.asarray(value, dtype=float)
        if array.shape != (size,):
            raise InputError(f"{name} must have shape ({size},), got {array.shape}")
        if not np.isfinite(array).all():
            raise InputError(f"{name} must be finite, got {array}")
        return array.copy()
