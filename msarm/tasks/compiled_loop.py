"""The closed loop compiled: sensors, controller, log and plant of every tick in one numba loop.

:func:`msarm.tasks.runner.run_tracking` steps a plant and a controller through a task. From
Python each control tick crosses the interpreter some twenty times (the sensors, the
controller's kernels, MuJoCo, the allocation QP, the log), which costs several times what the
physics does. Where the run needs nothing that lives only in Python, this module runs the
same ticks in one compiled function, :func:`run_ticks`, that calls the very kernels the Python
path calls:

- sensors: the plant's state plus the sensor noise, whose samples are drawn beforehand from the
  plant's generator in one call (the same stream as one draw per tick), through the delay
  effect's ring of readings;
- controller: the reference's inverse-dynamics torques come from Pinocchio before the loop
  (:meth:`MuscleSpaceController.reference_torques`, the same call as every tick's), then
  ``filter_and_pid``, the cable kinematics by MuJoCo's own functions
  (:mod:`msarm.mujoco_c`), ``muscle_speed``, the Hill kernel, ``force_bounds``, the allocation
  by :func:`msarm.allocation.solvers.newton.dual_newton_tick` and ``activation_and_reach``;
- plant: the delay effect's ring of commands, :func:`msarm.plant.cable_kernel.step_plant` and
  the wrap-angle refresh;
- log and ground truth: written row by row into the runner's arrays.

- feedforward: a feedforward whose joint torques ``dtau`` follow from the task's reference
  alone (:meth:`msarm.compensation.feedforward.LearnedFeedforward.precompute`: the learned
  network on the reference's features) has them computed before the loop, by the calls the
  Python loop makes each tick; its sheath stage runs in the loop, by the kernel the Python
  path calls (:func:`msarm.compensation.sheath_kernel.sheath_tick`).

The result is the same bits as the Python loop (tested). What the compiled loop cannot
finish it hands back for one tick: an allocation the Newton method does not settle goes to
the controller's allocator (DAQP, then the bounded least squares) and the loop goes on from
there; a bad muscle length, a non-finite or negative command or a diverged simulation are
raised by the Python functions that raise them on the Python path, with the same messages.

:func:`compiled_loop_supported` says when a run qualifies: no feedforward or one with a
``precompute`` method (see above; the runner takes the Python loop when that method gives
None), a plant whose step is compiled and whose only sensor and actuation effects are the
built-in noise and delay (no user hooks), and the controller itself (not a subclass) with
the ``"newton"`` solver and no activation dynamics.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from msarm.allocation.batched import MAX_ITER
from msarm.allocation.solution_check import residual_limit
from msarm.allocation.solvers.newton import dual_newton_tick
from msarm.compensation.sheath_kernel import sheath_tick
from msarm.control.arm_controller import MuscleSpaceController, check_tension_command
from msarm.control.kernels import activation_and_reach, filter_and_pid, force_bounds, muscle_speed
from msarm.errors import InputError
from msarm.mujoco_c import function_addresses
from msarm.muscle.batch_kinematics import KINEMATICS_FUNCTIONS, jacobian_at, wrap_angles_into
from msarm.muscle.fast import hill_parts
from msarm.numba_cache import compiled_or_cached, drop_stale_kernels
from msarm.plant.arm_plant import ArmPlant, SimulationDivergedError
from msarm.plant.cable_kernel import step_plant
from msarm.plant.effects import Delay, SensorNoise

if TYPE_CHECKING:
    from msarm.compensation.sheath import SheathInverse

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = [
    "Allocation",
    "Control",
    "FeedforwardArrays",
    "PlantArrays",
    "Sensing",
    "compiled_loop_ready",
    "compiled_loop_supported",
    "run_compiled",
    "run_ticks",
]

FloatArray = NDArray[np.float64]

DONE = 0
"""Status of :func:`run_ticks`: every tick asked for ran."""
ALLOCATE = 1
"""Status: the Newton method did not settle this tick's allocation (Python solves it)."""
BAD_MUSCLE_LENGTH = 2
"""Status: a non-finite MTU length or speed, or a length at or below its tendon slack length
(the Hill model raises)."""
BAD_COMMAND = 3
"""Status: a non-finite or negative tension command (the plant refuses it)."""
DIVERGED = 4
"""Status: the plant diverged during this tick's step."""
BAD_STAGE_COMMAND = 5
"""Status: a non-finite or negative command from the feedforward's sheath stage."""


#: The sensor effects the compiled loop renders, in the plant's order (noise, then delay).
_SENSOR_EFFECTS = ([], [SensorNoise], [Delay], [SensorNoise, Delay])


def compiled_loop_ready() -> bool:
    """False when the next compiled run will first compile :func:`run_ticks` (10-20 s).

    That happens once after an install or an update of msarm (numba then caches it on
    disk, see :mod:`msarm.numba_cache`); the commands say so before their first run, so that
    a progress bar that does not move is explained. True when numba does not tell.
    """
    return compiled_or_cached(run_ticks) is not False


def compiled_loop_supported(
    plant: ArmPlant, controller: MuscleSpaceController, feedforward: object | None
) -> bool:
    """Whether :func:`run_compiled` can run this plant and controller (see the module doc)."""
    return (
        (feedforward is None or callable(getattr(feedforward, "precompute", None)))
        and plant.compiled
        and [type(effect) for effect in plant._sensors] in _SENSOR_EFFECTS
        and [type(effect) for effect in plant._actuators] in ([], [Delay])
        and type(controller) is MuscleSpaceController
        and controller.config.solver == "newton"
        and not controller.config.activation_dynamics
        and function_addresses(*KINEMATICS_FUNCTIONS) is not None
    )


# The tick's parts are functions of their own, inlined into run_ticks (numba passes named
# tuples by value: called, each part would copy the arrays' descriptors every tick).


class Sensing(NamedTuple):
    """What :func:`run_ticks` needs to read the sensors, and this tick's readings."""

    noisy: bool  # the noise effect is on
    noise: FloatArray  # its samples, (T, 2n + 3m): q, motor angle, motor torque, tension
    bias: float  # its load-cell bias [N]
    delay: int  # the delay effect's sensing delay [control periods] (0 without it)
    history: FloatArray  # the last delay + 1 readings, (delay + 1, 2n + 3m), a ring
    q: FloatArray  # this tick's readings (as the controller gets them), written
    motor_angle: FloatArray
    motor_torque: FloatArray
    tension_motor: FloatArray


class Control(NamedTuple):
    """The controller's gains, state (views, updated) and work arrays, for :func:`run_ticks`."""

    period: float
    alpha: float
    kp: FloatArray
    ki: FloatArray
    kd: FloatArray
    bound: FloatArray
    q_prev: FloatArray
    qdot: FloatArray
    integral: FloatArray
    activation: FloatArray
    tau: FloatArray
    command: FloatArray  # the tension command the controller sends [N]
    reach: NDArray[np.bool_]
    functions: NDArray[np.intp]  # MuJoCo's kinematics functions (addresses)
    model: int  # the controller's mjModel and mjData (addresses) and views of the latter
    data: int
    qpos: FloatArray
    ten_length: FloatArray
    ten_j: FloatArray
    rownnz: NDArray[np.int32]
    rowadr: NDArray[np.int32]
    colind: NDArray[np.int32]
    jacobian: FloatArray
    lengths: FloatArray
    max_shortening: FloatArray
    speed: FloatArray
    hill: tuple  # FastHill.parameters
    active: FloatArray
    passive: FloatArray
    min_tension: float


class Allocation(NamedTuple):
    """The allocation's data and work arrays, for :func:`run_ticks`."""

    M: FloatArray
    weights: FloatArray
    f_ref: FloatArray
    f_min: FloatArray
    f_max: FloatArray
    force: FloatArray
    active: NDArray[np.int8]
    tol: float


class FeedforwardArrays(NamedTuple):
    """The feedforward of a run, for :func:`run_ticks` (see the module docstring)."""

    on: bool  # a feedforward is given: its dtau is added (zeros for a stage alone)
    dtau: FloatArray  # its joint torques of every tick [N m], (T, n)
    stage: bool  # a sheath stage turns the wanted tensions into the drives' command
    lengths: FloatArray  # the stage's cable lengths at every reference posture [m], (T, m)
    wrap: FloatArray  # its wrap angles there [rad], (T, m)
    constants: tuple  # sheath_tick's (alpha, c_s, w, g mu, floor)
    state: FloatArray  # the stage's state (4, m), updated (the stage's own array)
    force: FloatArray  # the tension the controller wants this tick [N], (m,), work


class PlantArrays(NamedTuple):
    """The plant's compiled step arguments and state views, for :func:`run_ticks`."""

    step_args: tuple  # ArmPlant's arguments of step_plant after n_steps
    qpos: FloatArray  # views of the plant's MuJoCo state
    qvel: FloatArray
    command: FloatArray  # the command the drives get (after the delay effect)
    command_delay: int  # the delay effect's actuation delay [control periods] (0 without it)
    command_history: FloatArray  # the last command_delay + 1 commands, a ring (reset: the
    # reset tension in every slot)
    theta: FloatArray
    motor_torque: FloatArray
    tension_motor: FloatArray
    tension_insertion: FloatArray
    ten_length: FloatArray
    length_ref: FloatArray
    stretch_motor0: FloatArray
    stretch_insertion0: FloatArray
    drum_radius: float
    wrap_xpos: FloatArray
    wrap_obj: NDArray[np.int32]
    wrapadr: NDArray[np.int32]
    wrapnum: NDArray[np.int32]
    wrap: FloatArray
    start_q: FloatArray  # the state a period starts from (for a divergence report)
    start_qdot: FloatArray
    start_theta: FloatArray
    wrap_every: int


@numba.njit(cache=True, inline="always")
def _sense(k, sensing, plant):  # pragma: no cover - compiled
    """``ArmPlant.sense``: the state plus the noise effect's tick-``k`` samples and bias.

    The controller gets the reading of tick ``max(k - delay, 0)`` (the delay effect).
    """
    qpos = plant.qpos
    n, m = qpos.shape[0], plant.theta.shape[0]
    noise, fresh = sensing.noise, sensing.history[k % sensing.history.shape[0]]
    for i in range(n):
        fresh[i] = qpos[i] + noise[k, i] if sensing.noisy else qpos[i]
    for i in range(m):
        if sensing.noisy:
            fresh[n + i] = plant.theta[i] + noise[k, n + i]
            fresh[n + m + i] = plant.motor_torque[i] + noise[k, n + m + i]
            tension = plant.tension_motor[i] + sensing.bias
            fresh[n + 2 * m + i] = tension + noise[k, n + 2 * m + i]
        else:
            fresh[n + i] = plant.theta[i]
            fresh[n + m + i] = plant.motor_torque[i]
            fresh[n + 2 * m + i] = plant.tension_motor[i]
    seen = sensing.history[max(k - sensing.delay, 0) % sensing.history.shape[0]]
    for i in range(n):
        sensing.q[i] = seen[i]
    for i in range(m):
        sensing.motor_angle[i] = seen[n + i]
        sensing.motor_torque[i] = seen[n + m + i]
        sensing.tension_motor[i] = seen[n + 2 * m + i]


@numba.njit(cache=True, inline="always")
def _control_and_allocate(k, reference, sensing, c, a, ff):  # pragma: no cover - compiled
    """``MuscleSpaceController.update`` up to the allocation's forces; returns a status."""
    q_ref, qd_ref, tau_id = reference
    for i in range(c.tau.shape[0]):
        c.tau[i] = tau_id[k, i]
    filter_and_pid(
        sensing.q, q_ref[k], qd_ref[k], c.period, c.alpha, c.kp, c.ki, c.kd, c.bound,
        c.q_prev, c.qdot, c.integral, c.tau,
    )  # fmt: skip
    if ff.on:
        for i in range(c.tau.shape[0]):
            c.tau[i] = c.tau[i] + ff.dtau[k, i]
    jacobian_at(
        c.functions, c.model, c.data, sensing.q, c.qpos, c.ten_j, c.rownnz, c.rowadr,
        c.colind, c.jacobian,
    )  # fmt: skip
    m, n = c.jacobian.shape
    for i in range(m):
        c.lengths[i] = c.ten_length[i]
    muscle_speed(c.jacobian, c.qdot, c.max_shortening, c.speed)
    f_max, l_opt, l_slack, thickness, v_max, coefficients, curve = c.hill
    bad = hill_parts(
        c.lengths, c.speed, f_max, l_opt, l_slack, thickness, v_max, coefficients, curve,
        c.active, c.passive,
    )  # fmt: skip
    if bad >= 0:
        return BAD_MUSCLE_LENGTH
    force_bounds(c.active, c.passive, c.min_tension, a.f_min, a.f_max)
    for i in range(m):
        for j in range(n):
            a.M[j, i] = -c.jacobian[i, j]
    code = dual_newton_tick(
        a.M, c.tau, a.weights, a.f_ref, a.f_min, a.f_max, a.force, a.active, MAX_ITER
    )
    if code < 0:
        return ALLOCATE
    # Allocator.solve's acceptance: ||M f - b|| <= tol (1 + ||b|| + || |M| |f| ||)
    rr = 0.0
    for j in range(n):
        r = -c.tau[j]
        for i in range(m):
            r += a.M[j, i] * a.force[i]
        rr += r * r
    if not np.sqrt(rr) <= residual_limit(a.M, c.tau, a.force, a.tol):
        return ALLOCATE
    return DONE


@numba.njit(cache=True, inline="always")
def _record(k, reference, sensing, c, ff, plant, log, truth):  # pragma: no cover - compiled
    """The tick's row of the log, then of the ground truth, as the Python loop writes them.

    ``log`` and ``truth`` are in the order of the runner's ``LOG_UNITS`` and ``TRUTH_UNITS``.
    """
    q_ref, qd_ref, _ = reference
    qpos, qvel = plant.qpos, plant.qvel
    for i in range(qpos.shape[0]):
        log[0][k, i] = q_ref[k, i]
        log[1][k, i] = qd_ref[k, i]
        log[2][k, i] = sensing.q[i]
        log[3][k, i] = c.qdot[i]
        log[4][k, i] = c.tau[i]
        log[5][k, i] = ff.dtau[k, i] if ff.on else 0.0
        truth[0][k, i] = qpos[i]
        truth[1][k, i] = qvel[i]
    for i in range(plant.theta.shape[0]):
        log[6][k, i] = sensing.motor_angle[i]
        log[7][k, i] = sensing.motor_torque[i]
        log[8][k, i] = sensing.tension_motor[i]
        log[9][k, i] = c.command[i]
        log[10][k, i] = c.activation[i]
        log[11][k, i] = c.command[i] - ff.force[i] if ff.stage else 0.0
        truth[2][k, i] = plant.tension_insertion[i]
        truth[3][k, i] = plant.tension_motor[i]
        unstretched = (
            (plant.length_ref[i] - plant.stretch_motor0[i]) - plant.stretch_insertion0[i]
        ) - plant.drum_radius * plant.theta[i]
        truth[4][k, i] = plant.ten_length[i] - unstretched
        truth[5][k, i] = plant.wrap[i]


@numba.njit(cache=True, inline="always")
def _step(substeps, timestep, clock, plant):  # pragma: no cover - compiled
    """``ArmPlant.step`` of one control period; returns whether the plant diverged."""
    step1, step2, model, data, cable_args, qpos, qvel, winch_speed, warnings, unstable = (
        plant.step_args
    )
    for i in range(qpos.shape[0]):
        plant.start_q[i] = qpos[i]
        plant.start_qdot[i] = qvel[i]
    for i in range(plant.theta.shape[0]):
        plant.start_theta[i] = plant.theta[i]
    end = clock[0] + substeps * timestep
    diverged = step_plant(
        substeps, step1, step2, model, data, cable_args, qpos, qvel, winch_speed, warnings,
        unstable,
    )  # fmt: skip
    for _ in range(substeps):
        clock[0] += timestep
    if diverged:
        clock[1] = end
    return diverged


@numba.njit(cache=True)
def run_ticks(
    k_start, k_end, resume, substeps, timestep, clock, reference, sensing, control,
    allocation, feedforward, plant, log, truth,
):  # fmt: skip  # pragma: no cover - compiled
    """Ticks ``k_start`` .. ``k_end - 1`` of a run; stops early at a tick Python must handle.

    Args:
        k_start: First tick.
        k_end: One past the last tick.
        resume: Tick ``k_start`` was stopped with :data:`ALLOCATE` and Python has written its
            forces into ``allocation.force``: go on from there.
        substeps: Plant steps per control period.
        timestep: Plant time step [s].
        clock: ``[time before the next step, end of the diverged period]`` [s], updated: the
            plant's time as MuJoCo counts it (one addition of the time step per step).
        reference: ``(q_ref, qd_ref, tau_id)``, each ``(T, n)``.
        sensing: :class:`Sensing`.
        control: :class:`Control`.
        allocation: :class:`Allocation`.
        feedforward: :class:`FeedforwardArrays`.
        plant: :class:`PlantArrays`.
        log: The log's arrays ``(T, .)``, in the order of the runner's ``LOG_UNITS``.
        truth: The ground truth's arrays ``(T, .)``, in the order of ``TRUTH_UNITS``.

    Returns:
        ``(status, k)``: :data:`DONE` with ``k = k_end``, or the status that stopped tick k.
    """
    c, a, ff = control, allocation, feedforward
    for k in range(k_start, k_end):
        if not (resume and k == k_start):
            _sense(k, sensing, plant)
            status = _control_and_allocate(k, reference, sensing, c, a, ff)
            if status != DONE:
                return status, k
        activation_and_reach(a.force, c.active, c.passive, c.activation, c.reach)
        for i in range(c.command.shape[0]):
            c.command[i] = c.activation[i] * c.active[i] + c.passive[i]
            if not (np.isfinite(c.command[i]) and c.command[i] >= 0.0):
                return BAD_COMMAND, k
        if ff.stage:  # the sheath stage: the wanted tensions become the drives' command
            ff.force[:] = c.command
            alpha, stretch, width, friction, floor = ff.constants
            sheath_tick(
                ff.force, ff.lengths[k], ff.wrap[k], alpha, stretch, width, friction, floor,
                ff.state, c.command,
            )  # fmt: skip
            for i in range(c.command.shape[0]):
                if not (np.isfinite(c.command[i]) and c.command[i] >= 0.0):
                    return BAD_STAGE_COMMAND, k
        # ArmPlant.command: the drives get the command of tick k - delay (the ring starts
        # full of the reset tension, held until the first command arrives)
        size = plant.command_history.shape[0]
        plant.command_history[k % size] = c.command
        plant.command[:] = plant.command_history[(k + size - plant.command_delay) % size]
        _record(k, reference, sensing, c, ff, plant, log, truth)
        if _step(substeps, timestep, clock, plant):
            return DIVERGED, k
        if k % plant.wrap_every == 0:
            wrap_angles_into(
                plant.wrap_xpos, plant.wrap_obj, plant.wrapadr, plant.wrapnum, plant.wrap
            )
    return DONE, k_end


def _arrays(
    plant: ArmPlant, controller: MuscleSpaceController, n_ticks: int, wrap_every: int
) -> tuple[Sensing, Control, Allocation, PlantArrays]:
    """What :func:`run_ticks` works on: views of the plant's and controller's state, work arrays.

    Args:
        plant: The plant (reset for the run).
        controller: The controller (reset for the run).
        n_ticks: Number of control ticks.
        wrap_every: Wrap-angle refresh period, in control periods.
    """
    n, m = plant.model.n_joints, plant.n_cables
    noise_effects = [e for e in plant._sensors if type(e) is SensorNoise]
    delays = [e.config for e in plant._sensors + plant._actuators if type(e) is Delay]
    sensing_delay = delays[0].sensing_periods if delays else 0
    command_delay = delays[0].actuation_periods if delays else 0
    # the noise effect's samples of every tick, drawn now from the plant's generator
    if noise_effects:
        noise = noise_effects[0].draw((n, m, m, m), plant._rng, n_ticks)
        bias = float(noise_effects[0].config.tension_bias)
    else:
        noise, bias = np.zeros((0, 0)), 0.0
    sensing = Sensing(
        bool(noise_effects), noise, bias, int(sensing_delay),
        np.empty((sensing_delay + 1, n + 3 * m)), np.empty(n), np.empty(m), np.empty(m),
        np.empty(m),
    )  # fmt: skip
    c, state, data = controller, controller._state, controller._data.mj
    mj_model = c.model.mj_model
    control = Control(
        c.period, c._alpha, c._kp, c._ki, c._kd, c._integral_bound, state.q_prev, state.qdot,
        state.integral, state.activation, np.empty(n), np.empty(m), np.empty(m, dtype=np.bool_),
        np.array(function_addresses(*KINEMATICS_FUNCTIONS), dtype=np.intp), mj_model._address,
        data._address, data.qpos, data.ten_length, data.ten_J, mj_model.ten_J_rownnz,
        mj_model.ten_J_rowadr, mj_model.ten_J_colind, np.zeros((m, n)), np.empty(m),
        c._max_shortening, np.empty(m), c._hill.parameters, c._hill.active, c._hill.passive,
        float(c.config.min_tension),
    )  # fmt: skip
    spec = c._allocator.spec
    allocation = Allocation(
        np.empty((n, m)), np.asarray(spec.weights, dtype=float),
        np.asarray(spec.f_ref, dtype=float), np.empty(m), np.empty(m), np.empty(m),
        np.empty(m, dtype=np.int8), float(spec.tol),
    )  # fmt: skip
    p, pstate, data = plant, plant._state, plant.mj_data
    start = p._period_start
    plant_arrays = PlantArrays(
        p._compiled_args, data.qpos, data.qvel, p._command, int(command_delay),
        np.tile(p._command, (command_delay + 1, 1)), pstate.winch_angle,
        p.motor_torque, pstate.tension_motor, p.tension_insertion, data.ten_length,
        p._length_ref, p._stretch_motor0, p._stretch_insertion0, float(p.drum_radius),
        data.wrap_xpos.reshape(-1, 3), data.wrap_obj.reshape(-1), data.ten_wrapadr,
        data.ten_wrapnum, pstate.wrap_angles, start["q"], start["qdot"],
        start["winch_angle"], int(wrap_every),
    )  # fmt: skip
    return sensing, control, allocation, plant_arrays


def _feedforward_arrays(
    feedforward: tuple[FloatArray, SheathInverse | None] | None, q_ref: FloatArray, m: int
) -> FeedforwardArrays:
    """:class:`FeedforwardArrays` of a precomputed feedforward (or of none)."""
    n_ticks, n = q_ref.shape
    dtau, stage = (np.zeros((0, n)), None) if feedforward is None else feedforward
    dtau = np.ascontiguousarray(dtau, dtype=float)
    if feedforward is not None and dtau.shape != (n_ticks, n):
        raise InputError(f"precomputed dtau must have shape {(n_ticks, n)}, got {dtau.shape}")
    lengths = wrap = np.zeros((0, m))
    constants, state = (0.0,) * 5, np.zeros((4, m))
    if stage is not None:
        lengths, wrap = stage.reference_geometry(q_ref)
        constants = tuple(float(value) for value in stage.constants)
        state = stage.state
    return FeedforwardArrays(
        feedforward is not None, dtau, stage is not None, lengths, wrap, constants, state,
        np.empty(m),
    )  # fmt: skip


def run_compiled(
    plant: ArmPlant,
    controller: MuscleSpaceController,
    references: tuple[FloatArray, FloatArray, FloatArray],
    log: tuple[FloatArray, ...],
    truth: tuple[FloatArray, ...],
    substeps: int,
    wrap_every: int,
    progress: Callable[[float], None] | None = None,
    feedforward: tuple[FloatArray, SheathInverse | None] | None = None,
) -> tuple[SimulationDivergedError | None, int]:
    """Run a task's ticks compiled, from a plant and a controller reset as the runner does.

    Args:
        plant: The plant, reset at the task's home with the starting tensions.
        controller: The controller, reset at the home posture.
        references: ``(q_ref, qd_ref, qdd_ref)`` of every tick [rad, rad/s, rad/s^2],
            each ``(T, n)``.
        log: The runner's log arrays, ``(T, .)``, in the order of its ``LOG_UNITS``, written.
        truth: Its ground-truth arrays, in the order of ``TRUTH_UNITS``, written.
        substeps: Plant steps per control period.
        wrap_every: Refresh the plant's wrap angles after every this many periods.
        progress: Optional callback with the fraction done, called at the ticks where the
            Python loop calls it.
        feedforward: The feedforward of the run, precomputed: ``(dtau, stage)`` as
            :meth:`~msarm.compensation.feedforward.LearnedFeedforward.precompute` gives them
            (the stage reset for the run, and left as the run leaves it); None: none.

    Returns:
        ``(error, done)``: the divergence that stopped the run (or None) and the number of
        ticks logged.

    Raises:
        InputError: Where the Python loop raises it (a bad muscle length, a bad command).
    """
    q_ref, qd_ref, qdd_ref = references
    n_ticks = q_ref.shape[0]
    reference = (q_ref, qd_ref, controller.reference_torques(q_ref, qd_ref, qdd_ref))
    sensing, control, allocation, plant_arrays = _arrays(plant, controller, n_ticks, wrap_every)
    feedforward_arrays = _feedforward_arrays(feedforward, q_ref, plant.n_cables)
    stage = None if feedforward is None else feedforward[1]
    clock = np.array([float(plant.mj_data.time), np.nan])
    report_every = max(1, n_ticks // 50)
    k, resume = 0, False
    while k < n_ticks:
        report = -(-k // report_every) * report_every  # the next tick after which to report
        stop = n_ticks if progress is None else min(report + 1, n_ticks)
        status, k = run_ticks(
            k, stop, resume, substeps, plant.config.timestep, clock, reference, sensing,
            control, allocation, feedforward_arrays, plant_arrays, log, truth,
        )  # fmt: skip
        resume = status == ALLOCATE
        if status == ALLOCATE:  # the controller's allocator settles it (DAQP, least squares)
            # M as the controller passes it (the same memory layout: the same bits from BLAS)
            M = -control.jacobian.T
            result = controller._allocator.solve(M, control.tau, allocation.f_min, allocation.f_max)
            allocation.force[:] = result.f
        elif status == BAD_MUSCLE_LENGTH:  # the Hill model raises its InputError
            controller._hill.parts(control.lengths, control.speed)
            raise AssertionError("the Hill model accepted what its kernel refused")
        elif status == BAD_COMMAND:  # the stage or the plant raises its InputError
            if stage is not None:
                stage.check_inputs(control.command, q_ref[k])
            plant.command(control.command)
            raise AssertionError("the plant accepted what the compiled loop refused")
        elif status == BAD_STAGE_COMMAND:  # the controller's check, else the plant's
            check_tension_command(control.command, control.command.shape)
            plant.command(control.command)
            raise AssertionError("the plant accepted what the compiled loop refused")
        elif status == DIVERGED:
            try:
                plant._raise_diverged(float(clock[1]))
            except SimulationDivergedError as exc:
                return exc, k + 1
        elif progress is not None and k - 1 == report:
            progress(report / n_ticks)
    return None, n_ticks
