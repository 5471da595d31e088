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

import copy
import math
from collections.abc import Mapping, Sequence

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError, MsarmError
from msarm.model import RobotModel
from msarm.mujoco_c import step_functions
from msarm.muscle.batch_kinematics import current_wrap_angles
from msarm.plant.cable_kernel import PARAMS, step_cables, step_plant
from msarm.plant.config import PlantConfig
from msarm.plant.effects import (
    EFFECT_DESCRIPTIONS,
    CableState,
    Delay,
    Effect,
    SensorReadings,
    build_effects,
)
from msarm.plant.instability import UNSTABLE_INDEX, instability_found
from msarm.plant.seeding import seed_generator

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


def _check_effects(user: Sequence[Effect], built_in: Sequence[Effect]) -> None:
    """Refuse user effects that are not effects or whose names clash.

    Every effect's name keys its parameters in :meth:`ArmPlant.effect_parameters` (and so in
    the ground-truth sidecar): two effects of one name would overwrite each other there.

    Raises:
        InputError: An entry is not an :class:`Effect`, its ``name`` is not a non-empty
            string, two user effects share a name, or a user effect takes the name of a
            built-in effect (both named).
    """
    reserved = set(EFFECT_DESCRIPTIONS) | {effect.name for effect in built_in}
    seen: dict[str, int] = {}
    for i, effect in enumerate(user):
        if not isinstance(effect, Effect):
            raise InputError(
                f"extra_effects[{i}] must be an msarm.plant.Effect, got {type(effect).__name__}"
            )
        name = effect.name
        label = f"extra_effects[{i}] ({type(effect).__name__})"
        if not isinstance(name, str) or not name:
            raise InputError(f"{label}: name must be a non-empty string, got {name!r}")
        if name in reserved:
            raise InputError(
                f"{label} is named {name!r}, the name of msarm's built-in effect {name!r}; "
                "give it a name of its own (effect names key the ground-truth parameters)"
            )
        if name in seen:
            j = seen[name]
            raise InputError(
                f"extra_effects[{j}] ({type(user[j]).__name__}) and {label} are both named "
                f"{name!r}; effect names must be unique (they key the ground-truth parameters)"
            )
        seen[name] = i


def _hook_array(
    effect: Effect, hook: str, value: object, size: int, low: float | None = None
) -> FloatArray:
    """A user hook's output as a float array of shape ``(size,)``, checked.

    Args:
        effect: The effect whose hook returned ``value``.
        hook: The hook and output (for the message), e.g. ``"transmission()"``.
        value: What the hook returned.
        size: The expected length.
        low: The smallest value allowed, or ``None``.

    Raises:
        InputError: Wrong shape, a non-finite value, or a value below ``low`` (effect, hook
            and index named).
    """
    where = f"effect {effect.name!r} ({type(effect).__name__}): {hook}"
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise InputError(
            f"{where} must return an array of {size} floats, got {type(value).__name__}"
        ) from error
    if array.shape != (size,):
        raise InputError(f"{where} must return shape ({size},), got shape {array.shape}")
    bad = ~np.isfinite(array)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"{where} must return finite values, got {float(array[i])} at index {i}")
    if low is not None and (array < low).any():
        i = int(np.argmax(array < low))
        raise InputError(f"{where} must return values >= {low}, got {float(array[i])} at index {i}")
    return array


class ArmPlant:
    """The simulated musculoskeletal arm: the "real robot" of msarm.

    Args:
        model: The arm (its file is loaded again into a private MuJoCo model, so effects may
            change that model without touching ``model``).
        config: Plant parameters and effect switches.
        seed: Seed of the plant's random generator (sensor noise): a non-negative integer or a
            ``numpy.random.Generator`` (copied: every :meth:`reset` starts again from the state
            it had here); same seed, same run.
        extra_effects: User effects added after the built-in ones. Each must have a name of its
            own (not a built-in effect's, not another user effect's): the names key
            :meth:`effect_parameters`. Their hooks' outputs are checked at every call (shape,
            finite values, range; see :mod:`msarm.plant.effects`).

    Raises:
        InputError: ``config`` is not a :class:`PlantConfig`, ``seed`` is neither a
            non-negative integer nor a generator, the model has no Hill parameters, or an
            effect's name clashes (both effects named).
    """

    def __init__(
        self,
        model: RobotModel,
        config: PlantConfig,
        seed: int | np.random.Generator = 0,
        extra_effects: Sequence[Effect] | None = None,
    ) -> None:
        if not isinstance(config, PlantConfig):
            raise InputError(
                f"config must be an msarm.plant.PlantConfig, got {type(config).__name__}"
            )
        if getattr(model, "muscles", None) is None:
            raise InputError(
                "model: the arm plant needs a robot model with Hill parameters (F_max per "
                f"cable), got {type(model).__name__} without them"
            )
        self._seed_rng = seed_generator(seed)
        self.model = model
        self.config = config
        self.seed = seed
        user = list(extra_effects or [])
        built_in = build_effects(config.effects)
        _check_effects(user, built_in)
        self.mj_model = mujoco.MjModel.from_xml_path(str(model.path))
        self.mj_model.opt.timestep = config.timestep
        self.mj_data = mujoco.MjData(self.mj_model)
        self.effects: list[Effect] = built_in + user
        for effect in self.effects:
            effect.configure(self)
        # user effects' hook outputs are checked; the built-in ones are trusted (fast path)
        self._user_ids = {id(effect) for effect in user}
        self._transmitters = [e for e in self.effects if _overrides(e, "transmission")]
        self._winch_loads = [e for e in self.effects if _overrides(e, "winch_torque")]
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
        self._rng = copy.deepcopy(self._seed_rng)
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

    @property
    def holding_tension(self) -> FloatArray:
        """The most tension each drive holds [N], shape ``(m,)``: torque limit / drum radius."""
        return self.torque_limit / self.drum_radius

    def reset(
        self, q: ArrayLike, tensions: ArrayLike | None = None, qdot: ArrayLike | None = None
    ) -> None:
        """Put the arm at rest at ``q`` with the cables pre-tensioned to ``tensions``.

        Args:
            q: Joint angles [rad], shape ``(n,)``, inside the model's joint range
                ``[joint_lower, joint_upper]`` (edges included).
            tensions: Motor-side tensions [N], shape ``(m,)``, each >= 0; zero if omitted. The
                drives are commanded the same until the first :meth:`command` reaches them
                (with the delay effect, ``actuation_periods`` control periods after it).
            qdot: Joint velocities [rad/s], shape ``(n,)``; zero if omitted.

        Raises:
            InputError: A wrong shape, a non-finite value, a joint of ``q`` outside its range
                (joint, value and range named), or a tension that is negative or more than the
                cable's drive holds (torque limit / drum radius; cable named).
        """
        n, m = self.model.n_joints, self.n_cables
        q = self._vector(q, n, "q")
        lower = np.asarray(self.model.joint_lower, dtype=float)
        upper = np.asarray(self.model.joint_upper, dtype=float)
        outside = (q < lower) | (q > upper)
        if outside.any():
            j = int(np.argmax(outside))
            raise InputError(
                f"q: joint {j} ({self.model.joint_names[j]!r}) at {float(q[j])} rad is outside "
                f"the model's joint range [{float(lower[j])}, {float(upper[j])}] rad"
            )
        tensions = self._vector(np.zeros(m) if tensions is None else tensions, m, "tensions")
        self._check_tensions(tensions, "tensions")
        held = self.holding_tension
        beyond = tensions > held * (1.0 + 1e-12)
        if beyond.any():
            i = int(np.argmax(beyond))
            raise InputError(
                f"tensions: {float(tensions[i])} N on cable {i} ({self.model.cable_names[i]!r}) "
                f"is more than its drive holds at rest ({float(held[i]):g} N: the torque limit "
                f"{float(self.torque_limit[i]):g} N m on a {self.drum_radius:g} m drum)"
            )
        mujoco.mj_resetData(self.mj_model, self.mj_data)
        self.mj_data.qpos[:] = q
        self.mj_data.qvel[:] = 0.0 if qdot is None else self._vector(qdot, n, "qdot")
        self._rng = copy.deepcopy(self._seed_rng)
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
        for effect in self._actuators:
            if isinstance(effect, Delay):  # the drives hold this until the first command
                effect.hold(tensions)
        self.tension_insertion[:] = tensions
        self.motor_torque[:] = tensions * self.drum_radius

    def command(self, tension: ArrayLike) -> None:
        """Set the tension command of the drives; held until the next.

        Args:
            tension: Motor-side tension command [N], shape ``(m,)``, finite and >= 0 (a cable
                only pulls; the command is not clipped). As a real drive, a motor asked for
                more than it can hold (:attr:`holding_tension`, its torque limit over the
                drum radius) saturates at its torque limit: the tension it reaches is then
                below the command (the ground truth's ``tension_motor`` shows it).

        Raises:
            InputError: A wrong shape, a non-finite or negative value (cable named), or a
                user effect's ``actuate`` hook returned a bad command (effect named).
        """
        m = self.n_cables
        tension = self._vector(tension, m, "tension")
        self._check_tensions(tension, "tension")
        for effect in self._actuators:
            tension = effect.actuate(tension)
            if id(effect) in self._user_ids:
                tension = _hook_array(effect, "actuate()", tension, m, low=0.0)
        self._command[:] = tension

    def sense(self) -> SensorReadings:
        """Read the robot's sensors (encoders, motor torques, motor-side load cells).

        Returns:
            The readings at the current time after every effect's ``sense`` hook (noise,
            bias, delay): ``t`` [s], ``q`` [rad] ``(n,)``, ``motor_angle`` [rad],
            ``motor_torque`` [N m] and ``tension_motor`` [N] ``(m,)`` (copies).

        Raises:
            InputError: A user effect's ``sense`` hook returned bad readings (effect named).
        """
        readings = SensorReadings(
            t=float(self.mj_data.time),
            q=self._state.q.copy(),
            motor_angle=self._state.winch_angle.copy(),
            motor_torque=self.motor_torque.copy(),
            tension_motor=self._state.tension_motor.copy(),
        )
        for effect in self._sensors:
            readings = effect.sense(readings, self._rng)
            if id(effect) in self._user_ids:
                readings = self._checked_readings(effect, readings)
        return readings

    def _checked_readings(self, effect: Effect, readings: object) -> SensorReadings:
        """A user ``sense`` hook's output, checked (type, shapes, finite values).

        Raises:
            InputError: Not a :class:`SensorReadings`, or a channel of the wrong shape or with
                a non-finite value (effect, hook and channel named).
        """
        if not isinstance(readings, SensorReadings):
            raise InputError(
                f"effect {effect.name!r} ({type(effect).__name__}): sense() must return "
                f"SensorReadings, got {type(readings).__name__}"
            )
        n, m = self.model.n_joints, self.n_cables
        channels = {
            "t": np.array([readings.t]) if np.isscalar(readings.t) else readings.t,
            "q": readings.q,
            "motor_angle": readings.motor_angle,
            "motor_torque": readings.motor_torque,
            "tension_motor": readings.tension_motor,
        }
        sizes = {"t": 1, "q": n, "motor_angle": m, "motor_torque": m, "tension_motor": m}
        for key, value in channels.items():
            _hook_array(effect, f"sense().{key}", value, sizes[key])
        return readings

    def ground_truth(self) -> dict[str, FloatArray]:
        """Simulation-only truth at the current step (never available to a controller).

        Returns:
            Copies keyed ``q``, ``qdot`` [rad, rad/s], shape ``(n,)``; ``tension_motor``,
            ``tension_insertion`` [N]; ``stretch`` [m] (negative: slack); ``wrap_angle``
            [rad]; ``winch_angle`` [rad], each of shape ``(m,)``.
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
        """Unstretched cable lengths [m], shape ``(m,)``: the path length minus the stretch.

        Returns:
            The reference path length at the reset posture minus the initial stretch and the
            cable reeled in since (``r * theta``) [m], shape ``(m,)``, a new array.
        """
        return (
            self._length_ref
            - self._stretch_motor0
            - self._stretch_insertion0
            - self.drum_radius * self._state.winch_angle
        )

    def effect_parameters(self) -> dict[str, dict]:
        """Ground truth of the plant: every effect switched on, with its parameters.

        Returns:
            Effect name to its :meth:`Effect.parameters`, for every effect of the plant
            (built-in and user), plus ``elasticity`` (``stiffness`` [N/m], ``damping``
            [N s/m]) when the cables are elastic.
        """
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

        The sheath friction's wrap angles stay as they are: call :meth:`update_wrap_angles`
        as the posture changes (the tracking runner does every 10 control periods).

        Args:
            n_steps: Number of plant time steps, an integer >= 0 (0: nothing happens).

        Raises:
            InputError: ``n_steps`` is not an integer or is negative; a user effect's hook
                returned a bad value (effect and hook named).
            SimulationDivergedError: NaN in the state or a MuJoCo instability warning.
        """
        if not isinstance(n_steps, (int, np.integer)) or isinstance(n_steps, (bool, np.bool_)):
            raise InputError(
                f"n_steps must be an integer >= 0, got {n_steps!r} of type {type(n_steps).__name__}"
            )
        if n_steps < 0:
            raise InputError(f"n_steps must be an integer >= 0, got {int(n_steps)}")
        n_steps = int(n_steps)
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
            output = effect.winch_torque(state)
            if id(effect) in self._user_ids:
                if not isinstance(output, tuple) or len(output) != 2:
                    raise InputError(
                        f"effect {effect.name!r} ({type(effect).__name__}): winch_torque() must "
                        f"return a pair (torque, slope), got {type(output).__name__}"
                    )
                output = (
                    _hook_array(effect, "winch_torque() torque", output[0], m),
                    _hook_array(effect, "winch_torque() slope", output[1], m),
                )
            torque, slope = output
            self._user_torque += torque
            self._user_slope += slope
        for effect in self._transmitters:
            factor = effect.transmission(state)
            if id(effect) in self._user_ids:
                factor = _hook_array(effect, "transmission()", factor, m, low=0.0)
            self._user_factor *= factor

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

    def _check_tensions(self, tensions: FloatArray, name: str) -> None:
        """Refuse a negative tension (cables only pull), naming the first such cable."""
        negative = tensions < 0
        if negative.any():
            i = int(np.argmax(negative))
            raise InputError(
                f"{name} must be >= 0 N (a cable only pulls), got {float(tensions[i])} N for "
                f"cable {i} ({self.model.cable_names[i]!r})"
            )

    @staticmethod
    def _vector(value: ArrayLike, size: int, name: str) -> FloatArray:
        if value is None:
            raise InputError(f"{name} must be an array of shape ({size},), got None")
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as error:
            raise InputError(
                f"{name} must be an array of {size} real numbers, got {type(value).__name__}"
            ) from error
        if array.shape != (size,):
            raise InputError(f"{name} must have shape ({size},), got {array.shape}")
        bad = ~np.isfinite(array)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"{name} must be finite, got {float(array[i])} at index {i}")
        return array.copy()
