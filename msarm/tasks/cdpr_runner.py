"""Run a cable-robot controller on the simulated IPAnema 3 Mini along a trajectory.

Every 1 ms cycle (the PLC cycle of paper 000): read the sensors, let the controller compute
the cable set lengths, feed-forward velocities and drive modes, send them, advance the plant
one step. Before it runs, a trajectory is checked against the wrench-feasible workspace (the
platform's weight and inertia with the 5-35 N bounds) and refused with the first infeasible
sample named.

Metrics (paper 000 section 4): the position error of the marker (the laser tracker measures
the platform position: here the simulated platform position) against the reference,
maximum and mean over the whole motion (Table 4); the share of time every cable force stays
within ``[f_min, f_max]`` (platform-side forces, Fig. 11); the RMS force-tracking error of the
force-controlled cables against the force distribution.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from msarm.cdpr.forward_kinematics import platform_wrench
from msarm.cdpr.robot_model import CableRobotModel
from msarm.control.cdpr_controllers import make_cdpr_controller
from msarm.io.logs import columns_from_quantities
from msarm.plant.arm_plant import SimulationDivergedError
from msarm.plant.cdpr_config import CdprPlantConfig
from msarm.plant.cdpr_plant import CdprPlant
from msarm.tasks.cdpr_trajectories import CdprTrajectory

__all__ = ["CdprMetrics", "CdprRun", "check_feasible", "run_cdpr"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class CdprMetrics:
    """Metrics of one cable-robot run.

    Attributes:
        max_position_error_mm: Largest marker position error [mm] (Table 4, epsilon_max).
        mean_position_error_mm: Mean marker position error [mm] (Table 4, epsilon bar).
        time_in_bounds_percent: Share of the run during which every cable force is within
            the bounds [%].
        min_force: Smallest cable force during the run [N].
        max_force: Largest cable force during the run [N].
        force_rms_error: RMS error of the force-controlled cables' forces against the force
            distribution [N] (NaN for a controller without force control).
        completed: Whether the run reached the end of the trajectory.
    """

    max_position_error_mm: float
    mean_position_error_mm: float
    time_in_bounds_percent: float
    min_force: float
    max_force: float
    force_rms_error: float
    completed: bool

    def as_dict(self) -> dict:
        """A JSON-ready dict (strict JSON: a NaN, a metric that does not apply, is None)."""
        return {
            key: None if isinstance(value, float) and value != value else value
            for key, value in asdict(self).items()
        }


@dataclass
class CdprRun:
    """One run: log columns (sensors, references, commands), truth columns, metrics.

    Attributes:
        controller: Controller name.
        trajectory: Trajectory name.
        columns: Log columns at 1 kHz (``t`` and ``<quantity>.<name>``).
        truth: Ground-truth columns (platform-side forces, position).
        metrics: The run's metrics.
        error: The divergence that stopped it, or None.
    """

    controller: str
    trajectory: str
    columns: dict[str, FloatArray]
    truth: dict[str, FloatArray]
    metrics: CdprMetrics
    error: SimulationDivergedError | None = None


def _wrenches(model: CableRobotModel, trajectory: CdprTrajectory) -> FloatArray:
    rotations = np.broadcast_to(trajectory.rotation, (len(trajectory), 3, 3))
    return platform_wrench(
        trajectory.position,
        rotations,
        trajectory.velocity,
        None,
        trajectory.acceleration,
        None,
        mass=model.mass,
        inertia=model.inertia,
        gravity=model.gravity,
        com=model.com,
    )


def check_feasible(model: CableRobotModel, trajectory: CdprTrajectory) -> None:
    """Refuse a trajectory outside the wrench-feasible workspace (first bad sample named).

    Raises:
        InputError: A sample's weight-and-inertia wrench cannot be balanced within the force
            bounds.
    """
    rotations = np.broadcast_to(trajectory.rotation, (len(trajectory), 3, 3))
    model.check_trajectory(trajectory.position, rotations, _wrenches(model, trajectory))


def run_cdpr(
    model: CableRobotModel,
    plant_config: CdprPlantConfig,
    controller: str,
    trajectory: CdprTrajectory,
    seed: int = 0,
    controller_options: dict | None = None,
    progress: Callable[[float], None] | None = None,
) -> CdprRun:
    """Run ``controller`` along ``trajectory`` on a fresh plant.

    Args:
        model: The cable robot.
        plant_config: The plant.
        controller: Controller name (``msarm.control.cdpr_controllers.CDPR_CONTROLLERS``).
        trajectory: The trajectory (sampled at the 1 ms cycle).
        seed: Seed of the plant's sensor noise.
        controller_options: Keyword options of the controller.
        progress: Called with the fraction done, about 50 times.

    Returns:
        The run.

    Raises:
        InputError: Unknown controller, or the trajectory leaves the feasible workspace.
    """
    check_feasible(model, trajectory)
    ctrl = make_cdpr_controller(controller, model, **(controller_options or {}))
    plant = CdprPlant(model, plant_config, seed=seed)
    start = trajectory.position[0]
    plant.reset((start, trajectory.rotation))
    m, n_samples = model.robot.n_cables, len(trajectory)
    names = model.cable_names
    quantities = (
        "cable_length",
        "motor_torque",
        "following_error",
        "load_cell",
        "l_set",
        "f_desired",
        "h",
    )
    log = {q: np.full((n_samples, m), np.nan) for q in quantities}
    marker = np.full((n_samples, 3), np.nan)
    force = np.full((n_samples, m), np.nan)
    controlled = np.zeros((n_samples, m), dtype=bool)
    error = None
    done = n_samples
    report = max(1, n_samples // 50)
    for k in range(n_samples):
        readings = plant.sense()
        command = ctrl.step(
            trajectory.position[k], trajectory.velocity[k], trajectory.acceleration[k], readings
        )
        plant.command(command.l_set, command.v_ff, command.drive_mode)
        log["cable_length"][k] = readings.cable_length
        log["motor_torque"][k] = readings.motor_torque
        log["following_error"][k] = readings.following_error
        log["load_cell"][k] = readings.load_cell
        log["l_set"][k] = command.l_set
        log["f_desired"][k] = command.f_desired
        log["h"][k] = command.h
        controlled[k] = command.h > 0.5
        marker[k] = plant.true_platform_position
        force[k] = plant.true_cable_tension
        try:
            plant.step(1)
        except SimulationDivergedError as exc:
            error, done = exc, k + 1
            break
        if progress is not None and k % report == 0:
            progress(k / n_samples)
    if progress is not None:
        progress(1.0)

    axes = ("x", "y", "z")
    channels = {
        "r_ref": (axes, trajectory.position[:done]),
        "marker": (axes, marker[:done]),
        **{quantity: (names, values[:done]) for quantity, values in log.items()},
    }
    columns = columns_from_quantities(trajectory.t[:done], channels)
    truth_columns = columns_from_quantities(trajectory.t[:done], {"tension": (names, force[:done])})
    metrics = _metrics(
        model,
        trajectory,
        marker[:done],
        force[:done],
        log["f_desired"][:done],
        controlled[:done],
        error is None,
    )
    return CdprRun(controller, trajectory.name, columns, truth_columns, metrics, error)


def _metrics(
    model: CableRobotModel,
    trajectory: CdprTrajectory,
    marker: FloatArray,
    force: FloatArray,
    desired: FloatArray,
    controlled: NDArray[np.bool_],
    completed: bool,
) -> CdprMetrics:
    error = np.linalg.norm(marker - trajectory.position[: len(marker)], axis=1)
    lower, upper = np.asarray(model.f_min), np.asarray(model.f_max)
    inside = np.all((force >= lower) & (force <= upper), axis=1)
    tracked = force[controlled] - desired[controlled]
    return CdprMetrics(
        max_position_error_mm=1000.0 * float(error.max()),
        mean_position_error_mm=1000.0 * float(error.mean()),
        time_in_bounds_percent=100.0 * float(inside.mean()),
        min_force=float(force.min()),
        max_force=float(force.max()),
        force_rms_error=float(np.sqrt(np.mean(tracked**2))) if tracked.size else float("nan"),
        completed=completed,
    )
