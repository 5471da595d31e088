"""The runner: steps a plant and a controller at their own fixed rates through a task.

Each control period (``1 / rate_hz``, a whole number of plant steps): read the sensors,
evaluate the task's reference, let the controller (and an optional feedforward
compensator) compute the tension commands, send them, and advance the plant. Everything the
controller saw and did is logged at the control rate in the log's channel naming
(``<quantity>.<name>``); the plant's ground truth goes to separate columns for the sidecar.

A run that diverges stops with :class:`msarm.plant.SimulationDivergedError`; the partial log up
to that point is kept in :attr:`TrackingRun.error`'s run (see :func:`run_tracking`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from msarm.control.arm_controller import ControlOutput, MuscleSpaceController
from msarm.errors import InputError
from msarm.io.logs import STANDARD_TRUTH_UNITS, STANDARD_UNITS, columns_from_quantities
from msarm.plant.arm_plant import ArmPlant, SimulationDivergedError
from msarm.plant.effects import SensorReadings
from msarm.tasks.compiled_loop import compiled_loop_supported, run_compiled
from msarm.tasks.registry import check_task_against

__all__ = [
    "LOG_UNITS",
    "TRUTH_UNITS",
    "Feedforward",
    "TrackingRun",
    "plant_steps_per_tick",
    "run_tracking",
]

FloatArray = NDArray[np.float64]

#: Units of the log's quantities (the runner's channels, in the log's order), taken from
#: :data:`msarm.io.logs.STANDARD_UNITS` (one source of the units).
LOG_UNITS = {
    key: STANDARD_UNITS[key]
    for key in (
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
        "tension_ff",
    )
}
#: Units of the ground-truth (sidecar) quantities, from
#: :data:`msarm.io.logs.STANDARD_TRUTH_UNITS`.
TRUTH_UNITS = dict(STANDARD_TRUTH_UNITS)

#: Wrap angles change slowly with posture: refresh them every this many control periods.
_WRAP_REFRESH_PERIODS = 10


class Feedforward(Protocol):
    """A joint-torque feedforward compensation ``dtau`` (e.g. the learned compensator).

    The controller calls it every tick after estimating the joint velocities. One that also
    has a ``tension_command(tension, q_ref)`` method reshapes the wanted tensions [N],
    ``(m,)``, into the drives' command (a tension-space feedforward, e.g. the compensator's
    sheath stage; what it adds is logged as ``tension_ff``). One with an
    ``observe_command(tension_command)`` method is told each tick's tension command [N],
    ``(m,)``, once the controller has computed it (a feedforward with memory of the commands,
    e.g. the ``sheath_stiction`` features). One with a ``precompute(q_ref, qd_ref)`` method
    may run in the compiled loop: it returns ``(dtau, stage)`` for the whole run, ``dtau``
    ``(T, n)`` [N m] and a sheath stage or None, or None when it cannot (see
    :meth:`msarm.compensation.feedforward.LearnedFeedforward.precompute`). One with a
    ``run_at(period)`` method is told the control period [s] before the run (a feedforward
    with its own clock, e.g. the sheath stage's low-pass).
    """

    def reset(self) -> None:
        """Forget the previous run (called before a run starts)."""
        ...

    def __call__(
        self,
        readings: SensorReadings,
        qdot_estimate: FloatArray,
        q_ref: FloatArray,
        qd_ref: FloatArray,
    ) -> FloatArray:
        """Return ``dtau`` [N m], shape ``(n,)``, from this tick's readings and reference."""
        ...


class _Reference(Protocol):
    name: str
    duration: float
    home: FloatArray

    def reference(self, t: float | FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]: ...


@dataclass
class TrackingRun:
    """The result of one run.

    Attributes:
        task_name: Name of the task.
        columns: Log columns at the control rate (``t`` and ``<quantity>.<name>``).
        truth: Ground-truth columns at the control rate (for the sidecar only).
        effects: The plant's effects and their parameters (for the sidecar only).
        control_rate_hz: Control (and log) rate [Hz].
        error: The divergence that stopped the run, or None if it completed.
    """

    task_name: str
    columns: dict[str, FloatArray]
    truth: dict[str, FloatArray]
    effects: dict
    control_rate_hz: float
    error: SimulationDivergedError | None = field(default=None)

    @property
    def completed(self) -> bool:
        """Whether the run reached the end of its task."""
        return self.error is None


def _names(prefix: str, names: tuple[str, ...]) -> list[str]:
    return [f"{prefix}.{name}" for name in names]


def plant_steps_per_tick(period: float, timestep: float) -> int | None:
    """Plant steps in one control period, or None when it is not a whole number of them.

    Args:
        period: The control period [s].
        timestep: The plant's step [s].

    Returns:
        The number of plant steps (>= 1), or None.
    """
    steps = int(round(period / timestep))
    if steps < 1 or abs(steps * timestep - period) > 1e-12:
        return None
    return steps


def run_tracking(
    plant: ArmPlant,
    controller: MuscleSpaceController,
    task: _Reference,
    feedforward: Feedforward | None = None,
    progress: Callable[[float], None] | None = None,
    compiled: bool | None = None,
) -> TrackingRun:
    """Run ``task`` on ``plant`` with ``controller`` (and ``feedforward``) from the task's home.

    The plant starts at rest at the task's home posture with every cable at the tension the
    controller asks for there, so the run starts in equilibrium.

    Args:
        plant: The plant (it is reset).
        controller: The controller (it is reset).
        task: The task: ``name``, ``duration`` [s], ``home`` (n,), ``reference(t)``.
        feedforward: Optional joint-torque compensation, called every control period.
        progress: Optional callback with the fraction done, called about 50 times.
        compiled: Run the ticks in the compiled loop of :mod:`msarm.tasks.compiled_loop`
            (the same bits as the Python loop, several times faster); None (the default) takes
            it wherever the run qualifies (see ``compiled_loop_supported``), False never.

    Returns:
        The run, with ``error`` set if the simulation diverged (the log then ends there).

    Raises:
        InputError: The control period is not a whole number of plant steps, ``compiled``
            is True for a run the compiled loop cannot do, the task is shorter than two
            control periods, or its postures leave the joint range.
    """
    model = plant.model
    period = controller.period
    substeps = plant_steps_per_tick(period, plant.config.timestep)
    if substeps is None:
        raise InputError(
            f"the control period {period} s is not a whole number of plant steps of "
            f"{plant.config.timestep} s"
        )
    supported = compiled_loop_supported(plant, controller, feedforward)
    if compiled and not supported:
        raise InputError(
            "this run cannot take the compiled loop (it needs no feedforward or one whose "
            "torques follow from the task's reference, a plant with a "
            "compiled step and no sensor or actuation effect but the built-in noise and delay, "
            "and the controller with the "
            "'newton' solver and no activation dynamics): pass compiled=None or False"
        )
    n_ticks = int(round(task.duration / period))
    if n_ticks < 2:
        raise InputError(
            f"task {task.name!r} lasts {task.duration} s: expected at least two control periods "
            f"({2 * period} s) to have a start and an end to measure"
        )
    delay = plant.config.effects.delay
    longest = max(delay.sensing_periods, delay.actuation_periods) if delay.enabled else 0
    if longest >= n_ticks:
        raise InputError(
            f"effects.delay: a delay of {longest} control periods is as long as task "
            f"{task.name!r} ({n_ticks} periods of {period:g} s): the controller would never "
            "see a reading or the drives a command; expected fewer periods than the task has"
        )
    check_task_against(task, model)  # a target outside the joint range: refused, not run
    home = np.asarray(task.home, dtype=float)
    zeros = np.zeros(model.n_joints)

    plant.reset(home)
    controller.reset(home)
    start = controller.update(plant.sense(), home, zeros, zeros)
    # the drives start where they can: a weak drive holds at most its torque limit's tension
    # (the plant refuses more at rest); its first step would saturate there anyway
    plant.reset(home, tensions=np.minimum(start.tension_command, plant.holding_tension))
    controller.reset(home)
    if feedforward is not None:
        run_at = getattr(feedforward, "run_at", None)
        if callable(run_at):  # a feedforward with its own clock ticks at this period
            run_at(period)
        feedforward.reset()

    times = np.arange(n_ticks) * period
    q_ref_all, qd_ref_all, qdd_ref_all = task.reference(times)
    n, m = model.n_joints, model.n_cables
    log = {
        key: np.full((n_ticks, size), np.nan)
        for key, size in [
            ("q_ref", n),
            ("qd_ref", n),
            ("q", n),
            ("qdot_est", n),
            ("tau_cmd", n),
            ("tau_ff", n),
            ("motor_angle", m),
            ("motor_torque", m),
            ("tension_motor", m),
            ("tension_cmd", m),
            ("activation", m),
            ("tension_ff", m),
        ]
    }
    truth = {
        key: np.full((n_ticks, size), np.nan)
        for key, size in [
            ("q", n),
            ("qdot", n),
            ("tension_insertion", m),
            ("tension_motor", m),
            ("stretch", m),
            ("wrap_angle", m),
        ]
    }
    references = (q_ref_all, qd_ref_all, qdd_ref_all)
    planned = None  # the feedforward of the whole run, for the compiled loop
    if supported and compiled is not False and feedforward is not None:
        planned = feedforward.precompute(q_ref_all, qd_ref_all)
        if planned is None:
            if compiled:
                raise InputError(
                    "this run cannot take the compiled loop: its feedforward's torques need "
                    "the robot's sensors (or are not finite): pass compiled=None or False"
                )
            supported = False
    if supported and compiled is not False:
        error, done = run_compiled(
            plant,
            controller,
            references,
            tuple(log[key] for key in LOG_UNITS),
            tuple(truth[key] for key in TRUTH_UNITS),
            substeps,
            _WRAP_REFRESH_PERIODS,
            progress,
            planned,
        )
    else:
        error, done = _python_loop(
            plant, controller, references, feedforward, log, truth, substeps, progress
        )
    if progress is not None:
        progress(1.0)

    joint_quantities = {"q_ref", "qd_ref", "q", "qdot_est", "tau_cmd", "tau_ff", "qdot"}

    def named(arrays: dict[str, FloatArray]) -> dict[str, FloatArray]:
        channels = {
            key: (
                model.joint_names if key in joint_quantities else model.cable_names,
                values[:done],
            )
            for key, values in arrays.items()
        }
        return columns_from_quantities(times[:done], channels)

    columns, truth_columns = named(log), named(truth)
    return TrackingRun(
        task_name=task.name,
        columns=columns,
        truth=truth_columns,
        effects=plant.effect_parameters(),
        control_rate_hz=1.0 / period,
        error=error,
    )


def _python_loop(
    plant: ArmPlant,
    controller: MuscleSpaceController,
    references: tuple[FloatArray, FloatArray, FloatArray],
    feedforward: Feedforward | None,
    log: dict[str, FloatArray],
    truth: dict[str, FloatArray],
    substeps: int,
    progress: Callable[[float], None] | None,
) -> tuple[SimulationDivergedError | None, int]:
    """The ticks of :func:`run_tracking` in Python: ``(divergence or None, ticks logged)``."""
    q_ref_all, qd_ref_all, qdd_ref_all = references
    n_ticks = q_ref_all.shape[0]
    report_every = max(1, n_ticks // 50)
    for k in range(n_ticks):
        readings = plant.sense()
        q_ref, qd_ref, qdd_ref = q_ref_all[k], qd_ref_all[k], qdd_ref_all[k]
        out: ControlOutput = controller.update(readings, q_ref, qd_ref, qdd_ref, feedforward)
        plant.command(out.tension_command)
        _record(log, k, readings, out, q_ref, qd_ref)
        _record_truth(truth, k, plant)
        try:
            plant.step(substeps)
        except SimulationDivergedError as exc:
            return exc, k + 1
        if k % _WRAP_REFRESH_PERIODS == 0:
            plant.update_wrap_angles()
        if progress is not None and k % report_every == 0:
            progress(k / n_ticks)
    return None, n_ticks


def _record(
    log: dict[str, FloatArray],
    k: int,
    readings: SensorReadings,
    out: ControlOutput,
    q_ref: FloatArray,
    qd_ref: FloatArray,
) -> None:
    log["q_ref"][k] = q_ref
    log["qd_ref"][k] = qd_ref
    log["q"][k] = readings.q
    log["qdot_est"][k] = out.qdot_estimate
    log["tau_cmd"][k] = out.joint_torque
    log["tau_ff"][k] = out.feedforward
    log["motor_angle"][k] = readings.motor_angle
    log["motor_torque"][k] = readings.motor_torque
    log["tension_motor"][k] = readings.tension_motor
    log["tension_cmd"][k] = out.tension_command
    log["activation"][k] = out.activation
    log["tension_ff"][k] = out.tension_feedforward


def _record_truth(truth: dict[str, FloatArray], k: int, plant: ArmPlant) -> None:
    plant.record_ground_truth({key: values[k] for key, values in truth.items()})
