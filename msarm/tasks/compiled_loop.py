"""The closed loop compiled: sensors, controller, log and plant of every tick in one numba loop.

:func:`msarm.tasks.runner.run_tracking` steps a plant and a controller through a task. From
Python each control tick crosses the interpreter some twenty times (the sensors, the
controller's kernels, MuJoCo, the allocation QP, the log), which costs several times what the
physics does. Where the run needs nothing that lives only in Python, this module runs the
same ticks in one compiled function, :func:`run_ticks`, that calls the very kernels the Python
path calls:

- sensors: the plant's state plus the sensor noise, whose samples are drawn beforehand from the
  plant's generator in one call (the same stream as one draw per tick);
- controller: the reference's inverse-dynamics torques come from Pinocchio before the loop
  (:meth:`MuscleSpaceController.reference_torques`, the same call as every tick's), then
  ``filter_and_pid``, the cable kinematics by MuJoCo's own functions
  (:mod:`msarm.mujoco_c`), ``muscle_speed``, the Hill kernel, ``force_bounds``, the allocation
  by :func:`msarm.allocation.solvers.newton.dual_newton_tick` and ``activation_and_reach``;
- plant: :func:`msarm.plant.cable_kernel.step_plant` and the wrap-angle refresh;
- log and ground truth: written row by row into the runner's arrays.

The result is the same bits as the Python loop (tested). What the compiled loop cannot
finish it hands back for one tick: an allocation the Newton method does not settle goes to
the controller's allocator (DAQP, then the bounded least squares) and the loop goes on from
there; a bad muscle length, a non-finite command or a diverged simulation are raised by the
Python functions that raise them on the Python path, with the same messages.

:func:`compiled_loop_supported` says when a run qualifies: no feedforward, a plant whose step
is compiled and whose only sensor effect is the built-in noise (no delay, no user hooks), and
the controller itself (not a subclass) with the ``"newton"`` solver and no activation dynamics.
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np
from numpy.typing import NDArray

from msarm.allocation.batched import MAX_ITER
from msarm.allocation.solvers.newton import dual_newton_tick
from msarm.control.arm_controller import MuscleSpaceController
from msarm.control.kernels import activation_and_reach, filter_and_pid, force_bounds, muscle_speed
from msarm.mujoco_c import function_addresses
from msarm.muscle.batch_kinematics import KINEMATICS_FUNCTIONS, jacobian_at, wrap_angles_into
from msarm.muscle.fast import hill_parts
from msarm.plant.arm_plant import ArmPlant, SimulationDivergedError
from msarm.plant.cable_kernel import step_plant
from msarm.plant.effects import SensorNoise

__all__ = ["compiled_loop_supported", "run_compiled", "run_ticks"]

FloatArray = NDArray[np.float64]

DONE = 0
"""Status of :func:`run_ticks`: every tick asked for ran."""
ALLOCATE = 1
"""Status: the Newton method did not settle this tick's allocation (Python solves it)."""
BAD_MUSCLE_LENGTH = 2
"""Status: an MTU length at or below its tendon slack length (the Hill model raises)."""
BAD_COMMAND = 3
"""Status: a non-finite tension command (the plant refuses it)."""
DIVERGED = 4
"""Status: the plant diverged during this tick's step."""


def compiled_loop_supported(
    plant: ArmPlant, controller: MuscleSpaceController, feedforward: object | None
) -> bool:
    """Whether :func:`run_compiled` can run this plant and controller (see the module doc)."""
    return (
        feedforward is None
        and plant.compiled
        and all(type(effect) is SensorNoise for effect in plant._sensors)
        and len(plant._sensors) <= 1
        and not plant._actuators
        and type(controller) is MuscleSpaceController
        and controller.config.solver == "newton"
        and not controller.config.activation_dynamics
        and function_addresses(*KINEMATICS_FUNCTIONS) is not None
    )


@numba.njit(cache=True)
def run_ticks(
    k_start,
    k_end,
    resume,
    substeps,
    timestep,
    clock,
    reference,
    sensing,
    control,
    allocation,
    plant,
    log,
    truth,
):  # pragma: no cover - compiled
    """Ticks ``k_start`` .. ``k_end - 1`` of a run; stops early at a tick Python must handle.

    Args:
        k_start: First tick.
        k_end: One past the last tick.
        resume: Tick ``k_start`` was stopped with :data:`ALLOCATE` and Python has written its
            forces into the allocation's ``f``: go on from there.
        substeps: Plant steps per control period.
        timestep: Plant time step [s].
        clock: ``[time before the next step, end of the diverged period]`` [s], updated: the
            plant's time as MuJoCo counts it (one addition of the time step per step).
        reference: ``(q_ref, qd_ref, tau_id)``, each ``(T, n)``.
        sensing: ``(noisy, noise, bias, q, motor_angle, motor_torque, tension_motor)``: whether
            the noise effect is on, its samples ``(T, 2n + 3m)`` and load-cell bias [N], and
            the readings of the current tick (written).
        control: The controller's gains, state and work arrays (see :func:`run_compiled`).
        allocation: ``(M, weights, f_ref, f_min, f_max, f, active, tol)``.
        plant: The plant's step arguments, state views and work arrays.
        log: The log's arrays, in :data:`msarm.tasks.runner.LOG_UNITS` order, ``(T, .)``.
        truth: The ground truth's arrays, in :data:`msarm.tasks.runner.TRUTH_UNITS` order.

    Returns:
        ``(status, k)``: :data:`DONE` with ``k = k_end``, or the status that stopped tick k.
    """
    q_ref_all, qd_ref_all, tau_id = reference
    noisy, noise, bias, read_q, read_angle, read_torque, read_tension = sensing
    (
        period,
        alpha,
        kp,
        ki,
        kd,
        bound,
        q_prev,
        qdot,
        integral,
        activation,
        tau,
        reach,
        functions,
        c_model,
        c_data,
        c_qpos,
        c_length,
        c_ten_j,
        rownnz,
        rowadr,
        colind,
        jacobian,
        lengths,
        max_shortening,
        speed,
        hill,
        active,
        passive,
        min_tension,
    ) = control
    f_max_muscle, l_opt, l_slack, thickness, v_max, coefficients, curve = hill
    M, weights, f_ref, f_min, f_max, force, active_set, tol = allocation
    (
        step_args,
        command,
        theta,
        motor_torque,
        tension_motor,
        tension_insertion,
        ten_length,
        length_ref,
        stretch_motor0,
        stretch_insertion0,
        drum_radius,
        wrap_xpos,
        wrap_obj,
        wrapadr,
        wrapnum,
        wrap,
        start_q,
        start_qdot,
        start_theta,
        wrap_every,
    ) = plant
    step1, step2, m_model, m_data, cable_args, qpos, qvel, winch_speed, warnings, unstable = (
        step_args
    )
    (
        log_q_ref,
        log_qd_ref,
        log_q,
        log_qdot,
        log_tau,
        log_ff,
        log_angle,
        log_torque,
        log_tension,
        log_command,
        log_activation,
    ) = log
    true_q, true_qdot, true_insertion, true_motor, true_stretch, true_wrap = truth
    n, m = q_prev.shape[0], command.shape[0]
    for k in range(k_start, k_end):
        if not (resume and k == k_start):
            # the sensors (plant.sense(): the state, plus the noise effect's reading)
            for i in range(n):
                read_q[i] = qpos[i] + noise[k, i] if noisy else qpos[i]
            for i in range(m):
                if noisy:
                    read_angle[i] = theta[i] + noise[k, n + i]
                    read_torque[i] = motor_torque[i] + noise[k, n + m + i]
                    read_tension[i] = (tension_motor[i] + bias) + noise[k, n + 2 * m + i]
                else:
                    read_angle[i] = theta[i]
                    read_torque[i] = motor_torque[i]
                    read_tension[i] = tension_motor[i]
            # the controller (MuscleSpaceController.update) up to the allocation
            for i in range(n):
                tau[i] = tau_id[k, i]
            filter_and_pid(
                read_q,
                q_ref_all[k],
                qd_ref_all[k],
                period,
                alpha,
                kp,
                ki,
                kd,
                bound,
                q_prev,
                qdot,
                integral,
                tau,
            )
            jacobian_at(
                functions,
                c_model,
                c_data,
                read_q,
                c_qpos,
                c_ten_j,
                rownnz,
                rowadr,
                colind,
                jacobian,
            )
            for i in range(m):
                lengths[i] = c_length[i]
            muscle_speed(jacobian, qdot, max_shortening, speed)
            bad = hill_parts(
                lengths,
                speed,
                f_max_muscle,
                l_opt,
                l_slack,
                thickness,
                v_max,
                coefficients,
                curve,
                active,
                passive,
            )
            if bad >= 0:
                return BAD_MUSCLE_LENGTH, k
            force_bounds(active, passive, min_tension, f_min, f_max)
            for i in range(m):
                for j in range(n):
                    M[j, i] = -jacobian[i, j]
            code = dual_newton_tick(
                M, tau, weights, f_ref, f_min, f_max, force, active_set, MAX_ITER
            )
            if code < 0:
                return ALLOCATE, k
            # Allocator.solve's acceptance: ||M f - b|| <= tol (1 + ||b||)
            rr, bb = 0.0, 0.0
            for j in range(n):
                r = -tau[j]
                for i in range(m):
                    r += M[j, i] * force[i]
                rr += r * r
                bb += tau[j] * tau[j]
            if not np.sqrt(rr) <= tol * (1.0 + np.sqrt(bb)):
                return ALLOCATE, k
        activation_and_reach(force, active, passive, activation, reach)
        for i in range(m):
            command[i] = activation[i] * active[i] + passive[i]
            if not np.isfinite(command[i]):
                return BAD_COMMAND, k
        # the log, then the ground truth, as the Python loop records them
        for i in range(n):
            log_q_ref[k, i] = q_ref_all[k, i]
            log_qd_ref[k, i] = qd_ref_all[k, i]
            log_q[k, i] = read_q[i]
            log_qdot[k, i] = qdot[i]
            log_tau[k, i] = tau[i]
            log_ff[k, i] = 0.0
            true_q[k, i] = qpos[i]
            true_qdot[k, i] = qvel[i]
        for i in range(m):
            log_angle[k, i] = read_angle[i]
            log_torque[k, i] = read_torque[i]
            log_tension[k, i] = read_tension[i]
            log_command[k, i] = command[i]
            log_activation[k, i] = activation[i]
            true_insertion[k, i] = tension_insertion[i]
            true_motor[k, i] = tension_motor[i]
            unstretched = ((length_ref[i] - stretch_motor0[i]) - stretch_insertion0[i]) - (
                drum_radius * theta[i]
            )
            true_stretch[k, i] = ten_length[i] - unstretched
            true_wrap[k, i] = wrap[i]
        # the plant's period (ArmPlant.step)
        for i in range(n):
            start_q[i] = qpos[i]
            start_qdot[i] = qvel[i]
        for i in range(m):
            start_theta[i] = theta[i]
        end = clock[0] + substeps * timestep
        diverged = step_plant(
            substeps,
            step1,
            step2,
            m_model,
            m_data,
            cable_args,
            qpos,
            qvel,
            winch_speed,
            warnings,
            unstable,
        )
        for _ in range(substeps):
            clock[0] += timestep
        if diverged:
            clock[1] = end
            return DIVERGED, k
        if k % wrap_every == 0:
            wrap_angles_into(wrap_xpos, wrap_obj, wrapadr, wrapnum, wrap)
    return DONE, k_end


class _Work:
    """The arrays one compiled run works on, and the tuples :func:`run_ticks` takes.

    Args:
        plant: The plant (reset for the run).
        controller: The controller (reset for the run).
        n_ticks: Number of control ticks.
        wrap_every: Wrap-angle refresh period, in control periods.
    """

    def __init__(
        self, plant: ArmPlant, controller: MuscleSpaceController, n_ticks: int, wrap_every: int
    ) -> None:
        n, m = plant.model.n_joints, plant.n_cables
        # the sensors: the noise effect's samples, drawn now in one call from the plant's
        # generator (the same stream as one draw of 2n + 3m samples per tick)
        noise_effects = plant._sensors
        if noise_effects:
            effect = noise_effects[0]
            std = effect._noise_std((n, m, m, m))
            self.noise = std * plant._rng.standard_normal((n_ticks, std.shape[0]))
            bias = float(effect.config.tension_bias)
        else:
            self.noise, bias = np.zeros((0, 0)), 0.0
        self.read_q, self.read_tension = np.empty(n), np.empty(m)
        self.sensing = (
            bool(noise_effects),
            self.noise,
            bias,
            self.read_q,
            np.empty(m),
            np.empty(m),
            self.read_tension,
        )
        # the controller
        c, state = controller, controller._state
        data = c._data.mj
        mj_model = c.model.mj_model
        self.tau, self.lengths, self.speed = np.empty(n), np.empty(m), np.empty(m)
        self.jacobian = np.zeros((m, n))
        self.control = (
            c.period, c._alpha, c._kp, c._ki, c._kd, c._integral_bound, state.q_prev,
            state.qdot, state.integral, state.activation, self.tau, np.empty(m, dtype=np.bool_),
            np.array(function_addresses(*KINEMATICS_FUNCTIONS), dtype=np.intp),
            mj_model._address, data._address, data.qpos, data.ten_length, data.ten_J,
            mj_model.ten_J_rownnz, mj_model.ten_J_rowadr, mj_model.ten_J_colind,
            self.jacobian, self.lengths, c._max_shortening, self.speed, c._hill.parameters,
            c._hill.active, c._hill.passive, float(c.config.min_tension),
        )  # fmt: skip
        spec = c._allocator.spec
        self.M, self.f_min, self.f_max, self.force = (
            np.empty((n, m)),
            np.empty(m),
            np.empty(m),
            np.empty(m),
        )
        self.allocation = (
            self.M,
            np.asarray(spec.weights, dtype=float),
            np.asarray(spec.f_ref, dtype=float),
            self.f_min,
            self.f_max,
            self.force,
            np.empty(m, dtype=np.int8),
            float(spec.tol),
        )
        # the plant
        p, pstate, data = plant, plant._state, plant.mj_data
        start = p._period_start
        self.command = p._command
        self.plant = (
            p._compiled_args, p._command, pstate.winch_angle, p.motor_torque,
            pstate.tension_motor, p.tension_insertion, data.ten_length, p._length_ref,
            p._stretch_motor0, p._stretch_insertion0, float(p.drum_radius),
            data.wrap_xpos.reshape(-1, 3), data.wrap_obj.reshape(-1), data.ten_wrapadr,
            data.ten_wrapnum, pstate.wrap_angles, start["q"], start["qdot"],
            start["winch_angle"], int(wrap_every),
        )  # fmt: skip


def run_compiled(
    plant: ArmPlant,
    controller: MuscleSpaceController,
    references: tuple[FloatArray, FloatArray, FloatArray],
    log: dict[str, FloatArray],
    truth: dict[str, FloatArray],
    substeps: int,
    wrap_every: int,
    progress: Callable[[float], None] | None = None,
) -> tuple[SimulationDivergedError | None, int]:
    """Run a task's ticks compiled, from a plant and a controller reset as the runner does.

    Args:
        plant: The plant, reset at the task's home with the starting tensions.
        controller: The controller, reset at the home posture.
        references: ``(q_ref, qd_ref, qdd_ref)`` of every tick [rad, rad/s, rad/s^2],
            each ``(T, n)``.
        log: The runner's log arrays (the keys of ``LOG_UNITS``), ``(T, .)``, written.
        truth: The runner's ground-truth arrays (the keys of ``TRUTH_UNITS``), written.
        substeps: Plant steps per control period.
        wrap_every: Refresh the plant's wrap angles after every this many periods.
        progress: Optional callback with the fraction done, called at the ticks where the
            Python loop calls it.

    Returns:
        ``(error, done)``: the divergence that stopped the run (or None) and the number of
        ticks logged.

    Raises:
        InputError: Where the Python loop raises it (a bad muscle length, a bad command).
    """
    q_ref, qd_ref, qdd_ref = references
    n_ticks = q_ref.shape[0]
    reference = (q_ref, qd_ref, controller.reference_torques(q_ref, qd_ref, qdd_ref))
    work = _Work(plant, controller, n_ticks, wrap_every)
    log_arrays = tuple(log[key] for key in _LOG_KEYS)
    truth_arrays = tuple(truth[key] for key in _TRUTH_KEYS)
    clock = np.array([float(plant.mj_data.time), np.nan])
    report_every = max(1, n_ticks // 50)
    k, resume = 0, False
    while k < n_ticks:
        report = -(-k // report_every) * report_every  # the next tick after which to report
        stop = n_ticks if progress is None else min(report + 1, n_ticks)
        status, k = run_ticks(
            k, stop, resume, substeps, plant.config.timestep, clock, reference, work.sensing,
            work.control, work.allocation, work.plant, log_arrays, truth_arrays,
        )  # fmt: skip
        resume = status == ALLOCATE
        if status == ALLOCATE:  # the controller's allocator settles it (DAQP, least squares)
            # M as the controller passes it (the same memory layout: the same bits from BLAS)
            M = -work.jacobian.T
            result = controller._allocator.solve(M, work.tau, work.f_min, work.f_max)
            work.force[:] = result.f
        elif status == BAD_MUSCLE_LENGTH:  # the Hill model raises its InputError
            controller._hill.parts(work.lengths, work.speed)
            raise AssertionError("the Hill model accepted what its kernel refused")
        elif status == BAD_COMMAND:  # the plant raises its InputError
            plant.command(work.command)
            raise AssertionError("the plant accepted what the compiled loop refused")
        elif status == DIVERGED:
            try:
                plant._raise_diverged(float(clock[1]))
            except SimulationDivergedError as exc:
                return exc, k + 1
        elif progress is not None and k - 1 == report:
            progress(report / n_ticks)
    return None, n_ticks


_LOG_KEYS = (
    "q_ref",
    "qd_ref",
    "q",
    "qdot_est",
    "tau_cmd",
    "tau_ff",
    "motor_angle",
    "motor_torque",
    "tension_motor",
    "tension_cmd",
    "activation",
)
_TRUTH_KEYS = ("q", "qdot", "tension_insertion", "tension_motor", "stretch", "wrap_angle")
