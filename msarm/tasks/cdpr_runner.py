"""Run a cable-robot controller on the simulated IPAnema 3 Mini along a trajectory.

Every 1 ms cycle (the PLC cycle of paper 000): read the sensors, let the controller compute
the cable set lengths, feed-forward velocities and drive modes, send them, advance the plant
one cycle (``round(dt / timestep)`` plant steps: a plant time step that does not divide the
cycle is refused). Before it runs (:func:`check_cdpr_run`), the trajectory is checked: its
sample time must be the controller's cycle, it must stay in the wrench-feasible workspace of
the bounds the controller's force distribution uses (the platform's weight and inertia with
8-35 N; refused with the first infeasible sample named), and, for a controller with the
winch friction model, its cable speeds must stay within the range the model was fitted over.
The plant starts at rest at the trajectory's first pose, its drives in the controller's
modes and, for a hybrid controller, its cables holding the force distribution the
controller commands there (what a real robot holds before a motion starts); IKC and NC,
which track no distribution, start at the plant's default pretension (see :func:`run_cdpr`).

Metrics (paper 000 section 4): the position error of the marker (the laser tracker measures
the platform position: here the simulated platform position) against the reference,
maximum and mean over the whole motion (Table 4); the share of time every cable force stays
within ``[f_min, f_max]`` (platform-side forces, Fig. 11); the RMS force-tracking error of the
force-controlled cables against the force distribution (not for IKC, which controls no force,
nor NC, which keeps forces near its own mean force rather than at the distribution); and how
many samples found a drive at its torque limit (``drive_saturated_samples``, msarm's addition).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from msarm.cdpr.forward_kinematics import platform_wrench
from msarm.cdpr.robot_model import CableRobotModel
from msarm.cdpr.winch_friction import BranchCoefficients
from msarm.control.cdpr_controllers import CdprController, make_cdpr_controller
from msarm.errors import InputError, MsarmWarning
from msarm.io.logs import columns_from_quantities
from msarm.plant.arm_plant import SimulationDivergedError
from msarm.plant.cdpr_config import CdprPlantConfig
from msarm.plant.cdpr_plant import CdprPlant
from msarm.tasks.cdpr_trajectories import CdprTrajectory

__all__ = ["CdprMetrics", "CdprRun", "check_cdpr_run", "check_feasible", "run_cdpr"]

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
            distribution [N] (NaN for a controller without force control, IKC, or one that
            does not track the distribution, NC: see ``CdprController.tracks_distribution``).
        completed: Whether the run reached the end of the trajectory.
        drive_saturated_samples: Samples at which at least one drive was at the plant's
            ``winch.torque_limit`` (in the plant step just before the sample, whose forces
            it logs); None where not recorded (the metrics of a hand-made run).
    """

    max_position_error_mm: float
    mean_position_error_mm: float
    time_in_bounds_percent: float
    min_force: float
    max_force: float
    force_rms_error: float
    completed: bool
    drive_saturated_samples: int | None = None

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
        truth: Ground-truth columns: the platform-side cable forces ``tension.<cable>`` [N]
            (what only a simulation knows; the marker position is in ``columns``).
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


def check_feasible(
    model: CableRobotModel,
    trajectory: CdprTrajectory,
    f_min: float | None = None,
    f_max: float | None = None,
) -> None:
    """Refuse a trajectory outside the wrench-feasible workspace (first bad sample named).

    Args:
        model: The cable robot.
        trajectory: The trajectory.
        f_min: Lower force bound [N] (the model file's if None).
        f_max: Upper force bound [N] (the model file's if None).

    Raises:
        InputError: A sample's weight-and-inertia wrench cannot be balanced within the force
            bounds.
    """
    rotations = np.broadcast_to(trajectory.rotation, (len(trajectory), 3, 3))
    model.check_trajectory(
        trajectory.position,
        rotations,
        _wrenches(model, trajectory),
        f_min=f_min,
        f_max=f_max,
    )


def _substeps(plant_config: CdprPlantConfig, cycle: float) -> int:
    """Plant steps per control cycle; refuses a time step that does not divide the cycle."""
    ratio = cycle / plant_config.timestep
    n = int(round(ratio))
    if n < 1 or abs(ratio - n) > 1e-9 * max(1.0, ratio):
        raise InputError(
            f"plant timestep {plant_config.timestep:g} s does not divide the controller's "
            f"cycle of {cycle:g} s: expected {cycle:g} s / k for a whole number k "
            "(e.g. 0.001 or 0.0005)"
        )
    return n


def _paper_units(branch: BranchCoefficients) -> tuple[float, float, float, float]:
    """Eq. 4 coefficients back in Table 1's units (v in m/min), as a plant file gives them."""
    return (branch.c1 / 60.0, branch.c2 / 3600.0, branch.c3, branch.c4)


def _text(value: float | tuple[float, ...]) -> str:
    if isinstance(value, tuple):
        return "[" + ", ".join(f"{v:.4g}" for v in value) + "]"
    return f"{value:.4g}"


def _same(own: float | tuple[float, ...], theirs: float | tuple[float, ...]) -> bool:
    pairs = zip(own, theirs, strict=True) if isinstance(own, tuple) else [(own, theirs)]
    return all(math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-15) for a, b in pairs)


def _winch_model_differences(ctrl: CdprController, plant_config: CdprPlantConfig) -> list[str]:
    """What of the plant's winches, drives and friction the controller models otherwise.

    Only what the controller's set values use: r_D and J_D (eq. 3: HC-tau, HC-e), c_f / K_p
    (eq. 8-9: HC-e), c_v (eq. 9: HC-e without velocity feed-forward), the friction torque's
    coefficients (eq. 5: HC-tau, HC-e) or the friction force's (eq. 7: HC-f, NC, which read
    load cells), with v_L and v_H, when the controller uses its friction model.
    """
    feedback = getattr(ctrl, "feedback", None)
    torque = feedback in ("torque", "following_error")
    force = feedback == "force" or ctrl.name == "nc"
    mine, plant = ctrl.winch, plant_config
    pairs: list[tuple[str, str, float | tuple[float, ...], float | tuple[float, ...]]] = []
    if torque:
        pairs += [
            ("drum radius r_D [m]", "winch.drum_radius", mine.drum_radius, plant.winch.drum_radius),
            ("inertia J_D [kg m^2]", "winch.inertia", mine.drum_inertia, plant.winch.inertia),
        ]
    if feedback == "following_error":
        fe = mine.following_error
        pairs.append(
            ("c_f / K_p [m/(N m)]", "drive.fe_compliance", fe.compliance, plant.drive.fe_compliance)
        )
        if not ctrl.velocity_feedforward:  # with v_ff the position loop does not lag: no c_v
            pairs.append(
                ("c_v [s]", "1 / drive.position_gain", fe.c_v, 1.0 / plant.drive.position_gain)
            )
    if getattr(ctrl, "friction_model", False) and (torque or force):
        if not plant.friction.enabled:
            return [
                *_differences(pairs),
                "a winch friction model (the plant has none: friction.enabled false)",
            ]
        kind = "torque" if torque else "force"
        branches = mine.friction.torque_branches if torque else mine.friction.force_branches
        for sign in ("negative", "positive"):
            key = f"{kind}_{sign}"
            pairs.append(
                (
                    f"{kind} friction c1..c4 (Table 1 units)",
                    f"friction.{key}",
                    _paper_units(getattr(branches, sign)),
                    tuple(getattr(plant.friction, key)),
                )
            )
        pairs += [
            ("v_L [m/min]", "friction.v_low", 60.0 * mine.friction.v_low, plant.friction.v_low),
            ("v_H [m/min]", "friction.v_high", 60.0 * mine.friction.v_high, plant.friction.v_high),
        ]
    return _differences(pairs)


def _differences(pairs: list) -> list[str]:
    """``<what> <own> (the plant's <key>: <theirs>)`` for each pair whose values differ."""
    return [
        f"{what} {_text(own)} (the plant's {key}: {_text(theirs)})"
        for what, key, own, theirs in pairs
        if not _same(own, theirs)
    ]


def _warn_other_winch(ctrl: CdprController, name: str, plant_config: CdprPlantConfig) -> None:
    """Warn when a controller models other winches, drives or friction than the plant's.

    HC-tau and HC-e turn force set values into motor torques and following errors through
    their own :class:`~msarm.control.cdpr_controllers.WinchParameters` (eq. 3: drum radius,
    inertia, friction torque; eq. 8-9: c_f / K_p, and c_v without velocity feed-forward);
    HC-f and NC take the load cell's friction force (eq. 7) out of its reading. A plant file
    with other winches, drives or friction would otherwise leave them mis-modelled without a
    word (a deliberate mismatch, to study it, is a use too: hence a warning). The command
    line cannot give a controller another winch model (``winch`` is an object option).
    """
    differ = _winch_model_differences(ctrl, plant_config)
    if differ:
        friction_only = all("friction" in d for d in differ)
        warnings.warn(
            f"controller {name!r} models the winches with {'; '.join(differ)} on plant "
            f"{plant_config.name!r}: its set values (paper 000 eq. 3, 7, 9) use its own model; "
            "give it the robot's (Python only, the command line has no option for it: "
            "make_cdpr_controller(..., winch=WinchParameters(drum_radius=..., drum_inertia=..., "
            "friction=WinchFrictionModel.from_paper_units(...), "
            "following_error=FollowingErrorModel(c_f=..., c_v=..., k_p=...))))"
            + (
                ", or leave its friction model out (--option friction_model=false)"
                if friction_only
                else ""
            )
            + " unless the mismatch is what you study",
            MsarmWarning,
            stacklevel=3,
        )


def _warn_weak_drives(ctrl: CdprController, name: str, plant_config: CdprPlantConfig) -> None:
    """Warn when the drives cannot hold the controller's least desired force at the drum.

    Every force of the controller's distribution is at least ``f_min`` (8 N): with
    ``torque_limit / r_D`` below it the drives saturate whenever a cable is to hold its least
    force (friction and inertia need more still), and the run's forces and positions are
    not what the controller commands (``drive_saturated_samples`` of the metrics counts the
    cycles). The plant itself warns only below the model file's lower bound (5 N).
    """
    winch = plant_config.winch
    most = winch.torque_limit / winch.drum_radius
    if most < ctrl.f_min:
        warnings.warn(
            f"plant {plant_config.name!r}: winch.torque_limit {winch.torque_limit:g} N m gives "
            f"at most {most:.4g} N at the drum (drum_radius {winch.drum_radius:g} m), below "
            f"the {ctrl.f_min:g} N lower bound of the force distribution of controller {name!r}: "
            "the drives saturate and the cables do not get the forces the controller commands "
            "(metrics: drive_saturated_samples); expected a torque_limit of at least "
            f"{ctrl.f_min * winch.drum_radius:g} N m",
            MsarmWarning,
            stacklevel=3,
        )


def _warn_bounds_beyond_the_robots(ctrl: CdprController, name: str, model: CableRobotModel) -> None:
    """Warn when the controller distributes forces outside the model file's cable bounds.

    The trajectory is checked against the controller's bounds only (the forces it plans): with
    ``f_min=0`` a path whose distribution needs slack cables passed, and its run left the
    file's [5, 35] N all the time with no message.
    """
    lower = np.broadcast_to(np.asarray(ctrl.f_min, dtype=float), model.f_min.shape)
    upper = np.broadcast_to(np.asarray(ctrl.f_max, dtype=float), model.f_max.shape)
    if np.any(lower < model.f_min) or np.any(upper > model.f_max):
        warnings.warn(
            f"controller {name!r} distributes forces within [{lower.min():g}, {upper.max():g}] "
            f"N, beyond the model file's cable bounds [{model.f_min.min():g}, "
            f"{model.f_max.max():g}] N ({model.path.name}): the forces it plans may leave the "
            "range the cables are made for (metrics: time in bounds counts the file's)",
            MsarmWarning,
            stacklevel=3,
        )


def _check_cable_speeds(
    model: CableRobotModel, ctrl: CdprController, name: str, trajectory: CdprTrajectory
) -> None:
    """Refuse a trajectory whose cable speeds leave the controller's friction-model range."""
    friction = ctrl.winch.friction
    if not getattr(ctrl, "friction_model", False) or friction.extrapolate:
        return
    rotations = np.broadcast_to(trajectory.rotation, (len(trajectory), 3, 3))
    At = model.robot.structure_matrix(trajectory.position, rotations)  # (N, 6, m)
    # the rotation is constant: dl_i/dt = -u_i . v
    speeds = np.abs(np.einsum("nji,nj->ni", At[:, :3, :], trajectory.velocity))
    k, i = np.unravel_index(int(np.argmax(speeds)), speeds.shape)
    fastest = float(speeds[k, i])
    limit = friction.v_high * (1.0 + 1e-12)
    if fastest > limit:
        raise InputError(
            f"trajectory {trajectory.name!r} moves {model.cable_names[i]} at "
            f"{fastest:.4g} m/s ({60.0 * fastest:.3g} m/min, t = {trajectory.t[k]:.3f} s), "
            f"beyond the {friction.v_high:.4g} m/s ({60.0 * friction.v_high:.3g} m/min) over "
            f"which the winch friction model of controller {name!r} was fitted (paper 000 "
            "Table 1): expected a slower trajectory (a lower speed), or a controller without "
            "the friction model (ikc, or the option friction_model=False)"
        )


def check_cdpr_run(
    model: CableRobotModel,
    plant_config: CdprPlantConfig,
    controller: str,
    trajectory: CdprTrajectory,
    controller_options: dict | None = None,
) -> CdprController:
    """Check a run before it starts (and before any output is written); build its controller.

    Args:
        model: The cable robot.
        plant_config: The plant.
        controller: Controller name (``msarm.control.cdpr_controllers.CDPR_CONTROLLERS``).
        trajectory: The trajectory.
        controller_options: Keyword options of the controller.

    Returns:
        The controller, reset.

    Raises:
        InputError: Unknown controller or option; the trajectory's sample time is not the
            controller's cycle; the plant time step does not divide the cycle; the trajectory
            leaves the wrench-feasible workspace of the controller's force bounds; or it
            moves a cable faster than the controller's winch friction model was fitted for.

    Warns:
        MsarmWarning: The controller models other winches, drives or friction than the
            plant's (what its set values use, each named with both values); the plant's
            ``torque_limit / drum_radius`` is below the controller's lower force bound; or
            the controller's force bounds reach beyond the model file's.
    """
    ctrl = make_cdpr_controller(controller, model, **(controller_options or {}))
    if abs(trajectory.dt - ctrl.dt) > 1e-12 * ctrl.dt:
        raise InputError(
            f"trajectory {trajectory.name!r} is sampled every {trajectory.dt:g} s but controller "
            f"{controller!r} runs every {ctrl.dt:g} s: expected a trajectory sampled at the "
            f"controller's cycle (dt={ctrl.dt:g})"
        )
    _substeps(plant_config, ctrl.dt)
    check_feasible(model, trajectory, ctrl.f_min, ctrl.f_max)
    _check_cable_speeds(model, ctrl, controller, trajectory)
    _warn_other_winch(ctrl, controller, plant_config)
    _warn_weak_drives(ctrl, controller, plant_config)
    _warn_bounds_beyond_the_robots(ctrl, controller, model)
    ctrl.reset()
    return ctrl


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

    The plant starts at rest at the trajectory's first pose with its drives in the
    controller's modes and its cables holding, for a hybrid controller, the force
    distribution it commands there (what the robot holds before a motion starts; the plant's
    own minimum-norm pretension within the model file's 5-35 N differs from the 8-35 N
    distribution by 3.2-4.7 N at the start of the paper-000 trajectories), and otherwise
    (IKC, which controls no force; NC, which keeps its own mean force) the plant's default
    pretension. Every control cycle advances the plant ``dt / timestep`` steps.

    Args:
        model: The cable robot.
        plant_config: The plant.
        controller: Controller name (``msarm.control.cdpr_controllers.CDPR_CONTROLLERS``).
        trajectory: The trajectory, sampled at the controller's cycle (1 ms).
        seed: Seed of the plant's sensor noise.
        controller_options: Keyword options of the controller.
        progress: Called with the fraction done, about 50 times.

    Returns:
        The run; a diverged run stops early, with ``error`` set and ``completed`` false.

    Raises:
        InputError: As :func:`check_cdpr_run` (unknown controller or option, the trajectory's
            sample time is not the controller's cycle, the plant time step does not divide
            it, the trajectory leaves the wrench-feasible workspace of the controller's force
            bounds, or it moves a cable beyond the speed range of the controller's friction
            model), all before the run starts.
    """
    ctrl = check_cdpr_run(model, plant_config, controller, trajectory, controller_options)
    substeps = _substeps(plant_config, ctrl.dt)
    plant = CdprPlant(model, plant_config, seed=seed)
    start = trajectory.position[0]
    initial = ctrl.nominal(
        start, trajectory.velocity[0], trajectory.acceleration[0], R=trajectory.rotation
    )
    plant.reset(
        (start, trajectory.rotation),
        tensions=initial.forces if ctrl.tracks_distribution else None,
        drive_mode=getattr(ctrl, "drive_mode", None),
    )
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
    saturated = np.zeros(n_samples, dtype=bool)
    error = None
    done = n_samples
    report = max(1, n_samples // 50)
    for k in range(n_samples):
        readings = plant.sense()
        command = ctrl.step(
            trajectory.position[k],
            trajectory.velocity[k],
            trajectory.acceleration[k],
            readings,
            R=trajectory.rotation,  # ignored before 2026-11-29: a turned pose ran at R = I
        )
        plant.command(command.l_set, command.v_ff, command.drive_mode)
        log["cable_length"][k] = readings.cable_length
        log["motor_torque"][k] = readings.motor_torque
        log["following_error"][k] = readings.following_error
        log["load_cell"][k] = readings.load_cell
        log["l_set"][k] = command.l_set
        log["f_desired"][k] = command.f_desired
        log["h"][k] = command.h
        controlled[k] = (command.h > 0.5) & ctrl.tracks_distribution
        marker[k] = plant.true_platform_position
        force[k] = plant.true_cable_tension
        saturated[k] = plant.drive_saturated.any()
        try:
            plant.step(substeps)
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
        saturated=saturated[:done],
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
    saturated: NDArray[np.bool_] | None = None,
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
        drive_saturated_samples=None if saturated is None else int(saturated.sum()),
    )
