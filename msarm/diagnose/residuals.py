"""Per-sample residuals of a log against the nominal model (issue 7, the "where" step's input).

Three residuals say, sample by sample, how far the logged robot is from the nominal model:

- ``joint_torque`` [N m], shape ``(T, n)``: ``T_f = -J_c^T F - ID(q, qd, qdd)``
  (:func:`msarm.compensation.target.torque_error`): the torque the motor-side load cells
  would deliver through ideal cables minus what the nominal inverse dynamics needs for the
  logged motion (Savitzky-Golay derivatives of the joint encoders). The delivered torque is
  filtered as the joint angles are (integrated twice, at the load cells' timing, then
  differentiated twice by the same filter: parallel filtering), so that the two sides of the
  balance have one bandwidth and one timing. The whole measured tension counts: a log with
  the compensator's ``tension_ff`` columns keeps them in (the compensator's target takes them
  off), so that the joint and drive residuals describe the same plant.
- ``cable_length`` [m], shape ``(T, m)``: ``l_hat - l(q)``, the cable length the motor
  encoders say (``l_hat = l(q_0) - r (theta - theta_0)``, drum radius ``r``, from the log's
  first diagnosed sample: the motor angles are absolute, so a time gap does not restart the
  estimate) minus the path length of the logged posture. Zero for rigid cables; stretch, slack
  and drum slip make it differ.
- ``drive`` [N], shape ``(T, m)``: ``F - F_cmd``, the load-cell tension minus the tension the
  controller commanded one sample earlier (the nominal drive renders each command exactly by
  the next sample: on the ideal plant this residual is zero). Winch friction, cogging, a drive
  delay and load-cell errors show here; None when the log has no ``tension_cmd`` channels.
- ``replay`` [rad], shape ``(T, n)`` (optional): the nominal dynamics (Pinocchio ``aba``)
  driven by the logged tension commands (or, per ``ResidualSpec.replay_source``, the measured
  load-cell tensions) through ideal cables (``tau = -J_c(q)^T F``, tension held over each
  sample period: from ``t_k`` to ``t_k+1`` the command sent at ``t_k``, which the load-cell
  sample at ``t_k+1`` answers), integrated (explicit midpoint rule, second order) over short
  windows that restart from the logged (filtered) state, minus the logged ``q``. It shows the
  gap as motion, the way a simulator would miss it. A replay that drifts beyond pi rad is clipped
  there and starts again from the next sample's logged state (the other windows are not
  touched).

Only the log is read -- never its ground-truth sidecar. A log whose ``model_sha256`` is not
the nominal model's is refused. Time gaps (a step longer than 1.5 sample periods) split the
log into contiguous segments that are processed separately; segments shorter than the filter
window are dropped (their samples are marked invalid, with a warning naming the file).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio
from numpy.typing import NDArray
from scipy.signal import savgol_filter

from msarm.compensation.target import TargetSpec, filtered_motion, torque_error
from msarm.diagnose.missing_values import read_log_for_diagnosis
from msarm.errors import InputError, LogError, MsarmWarning
from msarm.io.logs import TIME, RunLog, check_standard_units, nominal_step, split_channel
from msarm.model import RobotModel
from msarm.muscle.batch_kinematics import JacobianAt, cable_kinematics_batch

__all__ = [
    "FILTER_SPAN_S",
    "GAP_FACTOR",
    "JOINT_RANGE_MARGIN",
    "LENGTH_SLOPE",
    "MIN_CHECKED_TRAVEL",
    "MIN_MEDIAN_TENSION",
    "RESIDUAL_UNITS",
    "TENSION_RATIO",
    "gap_starts",
    "replay_runs",
    "DiagnosisWarning",
    "ResidualSpec",
    "Residuals",
    "residuals_from_log",
]

FloatArray = NDArray[np.float64]

#: Unit of each residual kind.
RESIDUAL_UNITS = {"joint_torque": "N m", "cable_length": "m", "drive": "N", "replay": "rad"}

#: The log quantities the residuals read (their units must be msarm's SI ones).
_QUANTITIES_READ = ("q", "q_ref", "tension_motor", "tension_cmd", "motor_angle")
#: Range of the commanded tensions' median over the load cells' outside which a log is
#: warned about (a unit slip: kN logged as N gives 0.001).
TENSION_RATIO = (0.5, 2.0)
#: Range of one cable's commanded median over its load cell's outside which a log is warned
#: about (one cable's unit slip: mN or kN gives 1000 or 0.001, kgf 9.81, lbf 4.45). Over the
#: 454 logs of the benchmark's two seeds and the compensator's runs (2026-11-29) the cables
#: ranged 0.58-2.06, the ends on plants with a load-cell bias (a cable near 1 N reads a
#: bias of 1 N as half or twice its tension).
CABLE_TENSION_RATIO = (0.25, 4.0)
#: Median tension [N] of the load cells (or commands) over a log below which it is warned
#: about: every sample would be slack (tensions in kN read as N; msarm's arm runs at medians of
#: 7-19 N, 12 N on most of 280 logs).
MIN_MEDIAN_TENSION = 1.0
#: Range of the slope of the encoder cable lengths over the path lengths (least squares,
#: cable by cable) outside which a log is warned about: degrees read as radians give 57, a
#: mirrored winch -1, a gearbox left out of the drum radius its ratio.
LENGTH_SLOPE = (0.5, 2.0)
#: Least travel of a cable's path (RMS over a log) [m] for that check: below it, the cable's
#: stretch under changing tension can be as large as its travel.
MIN_CHECKED_TRAVEL = 2e-3
#: How far [rad] a logged joint angle may lie outside the model's joint range before the log
#: is warned about (a unit slip: degrees read as radians put a 90 deg posture at 90 rad).
JOINT_RANGE_MARGIN = 0.5
#: Time spans [s] of the derivative filter's window outside which a log is warned about
#: (msarm's default: 25 samples at 250 Hz, 0.1 s). Above 0.15 s the residual takes a bias of
#: the filter itself: the inverse dynamics of the smoothed motion are not the smoothed
#: inverse dynamics (the dynamics are nonlinear in the motion), and on a plant with sensor
#: noise alone windows of 0.18, 0.2 and 0.3 s named a mass error (0.14 s and less: nothing).
FILTER_SPAN_S = (0.01, 0.15)
#: A step of ``t`` longer than this many nominal sample periods is a gap.
GAP_FACTOR = 1.5
#: The mean step of ``t`` (gaps left out, :func:`~msarm.io.logs.nominal_step`) may differ
#: from the nominal period by this fraction at most.
_RATE_TOLERANCE = 0.05
#: Beyond this fraction (but within :data:`_RATE_TOLERANCE`) the difference is warned about:
#: the filtered derivatives use the metadata's period, so velocities are off by as much.
_RATE_WARNING = 0.002
#: A replay error beyond this [rad] counts as diverged: it is clipped and the window starts
#: again from the next sample's logged state.
_REPLAY_LIMIT = np.pi


class DiagnosisWarning(MsarmWarning):
    """Something in a log limits the diagnosis (a time gap, a dropped segment)."""


@dataclass(frozen=True)
class ResidualSpec:
    """How the residuals are computed.

    Attributes:
        target: Savitzky-Golay filter of the joint encoders (window [samples], order).
        drum_radius: Winch drum radius ``r`` [m] (motor angle to cable length).
        drive_gain: Gain ``K`` of the drives' tension loop [-] (winch torque to tension error,
            for the drive-side terms' parameters in N m).
        length_resolution: Smallest cable length gap worth diagnosing [m]: a diagnosis
            leaves the cable-length group out when its RMS on the training or held-out runs
            is below this. The encoders and the joint-angle noise alone make about 30 µm on
            the simulated arm (measured on noise-only plants), so the default is 50 µm.
        replay: Also compute the replay residual.
        replay_source: What drives the replay: ``"command"``, the logged tension commands
            (each aligned with the tension that answers it; the measured tensions when a log
            has no commands), or ``"tension"``, the measured tensions.
        replay_window: Length of one replay window [s]; each restarts from the logged state.
        replay_substeps: Integration steps per sample period in the replay (explicit midpoint
            rule: two evaluations of the dynamics a step). One step a sample was within 0.6 %
            of a fine fourth-order reference (RMS of the replay residual on five scenarios of
            the withheld-effect benchmark, 250 Hz logs); semi-implicit Euler, used before, was
            up to 7 % off with four steps a sample, at twice the cost.
    """

    target: TargetSpec = TargetSpec()
    drum_radius: float = 0.003
    drive_gain: float = 4.0
    length_resolution: float = 5e-5
    replay: bool = True
    replay_source: str = "command"
    replay_window: float = 0.2
    replay_substeps: int = 1

    def __post_init__(self) -> None:
        if not self.drum_radius > 0:
            raise InputError(f"drum_radius must be > 0 [m], got {self.drum_radius}")
        if self.replay_source not in ("command", "tension"):
            raise InputError(
                f"replay_source must be 'command' or 'tension', got {self.replay_source!r}"
            )
        if not self.length_resolution >= 0:
            raise InputError(f"length_resolution must be >= 0 [m], got {self.length_resolution}")
        if not self.drive_gain >= 0:
            raise InputError(f"drive_gain must be >= 0, got {self.drive_gain}")
        if not self.replay_window > 0:
            raise InputError(f"replay_window must be > 0 [s], got {self.replay_window}")
        if self.replay_substeps < 1:
            raise InputError(f"replay_substeps must be >= 1, got {self.replay_substeps}")


@dataclass(frozen=True, eq=False)
class Residuals:
    """Residuals of one log against the nominal model, with per-sample context.

    Arrays of invalid samples (in a dropped segment, see ``valid``) hold NaN.

    Attributes:
        source: Name of the log (its file, usually).
        joint_names: Joint names, shape ``(n,)``.
        cable_names: Cable names, shape ``(m,)``.
        sample_rate_hz: Nominal sample rate [Hz].
        t: Sample times [s], shape ``(T,)``.
        valid: Whether each sample has residuals, shape ``(T,)``.
        joint_torque: Joint-torque residual ``T_f`` [N m], shape ``(T, n)``.
        cable_length: Cable length error ``l_hat - l`` [m], shape ``(T, m)``; None when the
            log has no ``motor_angle`` channels.
        drive: Drive residual ``F - F_cmd`` [N], shape ``(T, m)``; None when the log has no
            ``tension_cmd`` channels.
        replay: Replay residual ``q_replay - q`` [rad], shape ``(T, n)``; None if not computed.
        q: Logged joint angles [rad], shape ``(T, n)``.
        qd: Filtered joint velocities [rad/s], shape ``(T, n)``.
        qdd: Filtered joint accelerations [rad/s^2], shape ``(T, n)``.
        cable_velocity: Cable velocities ``J_c(q) qd`` [m/s], shape ``(T, m)``.
        tension: Motor-side load-cell tensions [N], shape ``(T, m)``.
        tension_cmd: The command each tension answers (the previous sample's; the first of a
            segment takes its own) [N], shape ``(T, m)``; None without ``tension_cmd``.
        motor_speed: Filtered motor speeds [rad/s], shape ``(T, m)``; None without
            ``motor_angle``.
        qdd_ref: Filtered accelerations of the logged reference [rad/s^2], shape ``(T, n)``;
            None without ``q_ref`` channels.
        lengths: Nominal cable path lengths ``l(q)`` [m], shape ``(T, m)``; None unless
            asked for (``with_geometry``).
        jacobian: Nominal cable Jacobians ``J_c(q)`` [m/rad], shape ``(T, m, n)``; likewise.
        wrap: Wrap angles ``Theta(q)`` of the cables' paths [rad], shape ``(T, m)``;
            likewise.
        target: The filter the residuals were made with (``ResidualSpec.target``), for the
            noise floor (:mod:`msarm.diagnose.noise_floor`); None: the default
            :class:`~msarm.compensation.target.TargetSpec`.
    """

    source: str
    joint_names: tuple[str, ...]
    cable_names: tuple[str, ...]
    sample_rate_hz: float
    t: FloatArray
    valid: NDArray[np.bool_]
    joint_torque: FloatArray
    cable_length: FloatArray | None
    drive: FloatArray | None
    replay: FloatArray | None
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    cable_velocity: FloatArray
    tension: FloatArray
    tension_cmd: FloatArray | None = None
    motor_speed: FloatArray | None = None
    qdd_ref: FloatArray | None = None
    lengths: FloatArray | None = None
    jacobian: FloatArray | None = None
    wrap: FloatArray | None = None
    target: TargetSpec | None = None

    def __len__(self) -> int:
        """Number of samples ``T``."""
        return len(self.t)

    def kinds(self) -> list[str]:
        """The residual kinds present (keys of :data:`RESIDUAL_UNITS`)."""
        return [k for k in RESIDUAL_UNITS if getattr(self, k) is not None]

    def get(self, kind: str) -> FloatArray:
        """One residual by kind, shape ``(T, n)`` or ``(T, m)``.

        Args:
            kind: ``"joint_torque"``, ``"cable_length"``, ``"drive"`` or ``"replay"``.

        Raises:
            InputError: Unknown kind, or a kind this log has none of.
        """
        if kind not in RESIDUAL_UNITS:
            raise InputError(f"unknown residual kind {kind!r}; kinds: {', '.join(RESIDUAL_UNITS)}")
        value = getattr(self, kind)
        if value is None:
            raise InputError(
                f"{self.source}: no {kind} residual (kinds: {', '.join(self.kinds())})"
            )
        return value

    def scored(self, kind: str) -> FloatArray:
        """One residual on the valid samples as the diagnosis scores it, ``(T_valid, k)``.

        ``cable_length`` is taken about its mean over them: the motor encoders give lengths up
        to the log's offset (their zero at its start), so the level carries no gap.

        Raises:
            InputError: As :meth:`get`.
        """
        values = self.get(kind)[self.valid]
        return values - values.mean(axis=0) if kind == "cable_length" else values

    def channel_names(self, kind: str) -> tuple[str, ...]:
        """Channel names of a residual kind: the joints or the cables."""
        return self.cable_names if kind in ("cable_length", "drive") else self.joint_names


def residuals_from_log(
    model: RobotModel,
    log: RunLog | str | Path,
    source: str | None = None,
    spec: ResidualSpec | None = None,
    with_geometry: bool = False,
) -> Residuals:
    """Compute the residuals of one log against the nominal model.

    Args:
        model: The nominal robot model.
        log: The log, or its Parquet file (read with
            :func:`msarm.diagnose.missing_values.read_log_for_diagnosis`, which leaves out
            missing values with a warning; the sidecar is never opened).
        source: Name of the log in messages; default the file name, or ``"log"``.
        spec: Filter, drum radius and replay settings.
        with_geometry: Also keep the nominal cable lengths, Jacobians and wrap angles at each
            logged posture (``lengths``, ``jacobian``, ``wrap``), computed in the same pass
            as the cable velocities.

    Returns:
        The residuals and context of every sample.

    Raises:
        LogError: The log is of another model (file and both hashes named); a needed channel
            is missing (file and column named); a quantity read is not in msarm's SI unit;
            the sample times disagree with the nominal rate; no segment is long enough for
            the filter.
    """
    spec = spec or ResidualSpec()
    if not isinstance(log, RunLog):
        source = source or str(log)
        log = read_log_for_diagnosis(model, log, source)
    source = source or "log"
    if log.metadata.model_sha256.lower() != model.sha256.lower():
        raise LogError(
            f"{source}: the log is of another robot model: its model_sha256 is "
            f"{log.metadata.model_sha256!r} (model {log.metadata.robot_model!r}), the nominal "
            f"model {model.path} has {model.sha256!r}; diagnose it against the arm model it "
            "was recorded with (--model). The diagnosis reads logs of cable-driven arms "
            "(joint angles and cables, as msarm track writes); a cable-driven parallel robot's "
            "logs are not diagnosed yet"
        )
    _warn_channels_of_no_joint_or_cable(log, model, source)
    check_standard_units(log, _QUANTITIES_READ, source)
    joints, cables = list(model.joint_names), list(model.cable_names)
    for quantity, names in (("q", joints), ("tension_motor", cables)):
        for name in names:
            if f"{quantity}.{name}" not in log.columns:
                raise LogError(
                    f"{source}: column '{quantity}.{name}' is missing; the diagnosis needs "
                    f"q.<joint> for every joint and tension_motor.<cable> for every cable"
                )
    has_motor = _has_channels(
        log,
        "motor_angle",
        cables,
        source,
        "no cable-length residual and no motor speed, so the length terms, winch friction, "
        "encoder skew and motor cogging are left out (for every log diagnosed with this one); "
        "the joint-torque and replay residuals are still computed",
    )
    has_reference = _has_channels(
        log,
        "q_ref",
        joints,
        source,
        "the mass-error term uses the measured accelerations, whose encoder noise is also in "
        "the residual (it may be named on noise alone; its confidence tells)",
    )
    has_command = _has_channels(
        log,
        "tension_cmd",
        cables,
        source,
        "no drive residual (the winch-friction, motor-cogging and command-delay terms cannot "
        "be fitted) and no commanded tensions for the sheath-stiction term "
        "(capstan_hysteresis); the joint-torque "
        + ("and cable-length residuals are" if has_motor else "residual is")
        + " still computed",
    )
    segments = _segments(log, source, spec.target.window)
    _warn_filter_span(source, spec.target.window, log.metadata.sample_rate_hz)

    n_samples, n, m = len(log), len(joints), len(cables)
    out = {
        "joint_torque": np.full((n_samples, n), np.nan),
        "cable_length": np.full((n_samples, m), np.nan) if has_motor else None,
        "drive": np.full((n_samples, m), np.nan) if has_command else None,
        "tension_cmd": np.full((n_samples, m), np.nan) if has_command else None,
        "motor_speed": np.full((n_samples, m), np.nan) if has_motor else None,
        "qdd_ref": np.full((n_samples, n), np.nan) if has_reference else None,
        "lengths": np.full((n_samples, m), np.nan) if with_geometry else None,
        "jacobian": np.full((n_samples, m, n), np.nan) if with_geometry else None,
        "wrap": np.full((n_samples, m), np.nan) if with_geometry else None,
        "replay": np.full((n_samples, n), np.nan) if spec.replay else None,
        "qd": np.full((n_samples, n), np.nan),
        "qdd": np.full((n_samples, n), np.nan),
        "cable_velocity": np.full((n_samples, m), np.nan),
    }
    valid = np.zeros(n_samples, dtype=bool)
    q_all = log.matrix("q", joints)
    tension_all = log.matrix("tension_motor", cables)
    motor_all = log.matrix("motor_angle", cables) if has_motor else None
    command_all = log.matrix("tension_cmd", cables) if has_command else None
    reference_all = log.matrix("q_ref", joints) if has_reference else None
    _warn_outside_joint_range(
        source,
        [("q", q_all)] + ([("q_ref", reference_all)] if reference_all is not None else []),
        model,
        joints,
    )
    _warn_constant_sensors(
        source,
        [("q", joints, q_all), ("tension_motor", cables, tension_all)]
        + ([("motor_angle", cables, motor_all)] if motor_all is not None else []),
    )
    dt = 1.0 / log.metadata.sample_rate_hz
    work = _Work(model)
    anchor: tuple[FloatArray, FloatArray] | None = None
    for start, stop in segments:
        part = slice(start, stop)
        sub = RunLog({k: v[part] for k, v in log.columns.items()}, log.metadata)
        q = q_all[part]
        kinematics = cable_kinematics_batch(model, q, with_wrap_angles=with_geometry)
        motion = filtered_motion(q, spec.target, dt)
        out["joint_torque"][part] = torque_error(
            model, sub, spec.target, source, kinematics.jacobian, motion, remove_feedforward=False
        )
        q_f, qd, qdd = motion
        window, order = spec.target.window, spec.target.polyorder
        out["qd"][part] = qd
        out["qdd"][part] = qdd
        lengths = kinematics.lengths
        out["cable_velocity"][part] = np.matmul(kinematics.jacobian, qd[:, :, None])[:, :, 0]
        if with_geometry:
            out["lengths"][part] = lengths
            out["jacobian"][part] = kinematics.jacobian
            out["wrap"][part] = kinematics.wrap_angles
        if motor_all is not None:
            motor = motor_all[part]
            if anchor is None:  # the run's first diagnosed sample: motor angles are absolute,
                anchor = (lengths[0], motor[0])  # so one anchor carries across time gaps
            estimate = anchor[0] - spec.drum_radius * (motor - anchor[1])
            out["cable_length"][part] = estimate - lengths
            out["motor_speed"][part] = savgol_filter(
                motor, window, order, deriv=1, delta=dt, axis=0
            )
        if reference_all is not None:
            out["qdd_ref"][part] = savgol_filter(
                reference_all[part], window, order, deriv=2, delta=dt, axis=0
            )
        if command_all is not None:
            command = command_all[part]
            aligned = np.concatenate([command[:1], command[:-1]])
            out["tension_cmd"][part] = aligned
            out["drive"][part] = tension_all[part] - aligned
        if spec.replay:
            use_command = spec.replay_source == "command" and out["tension_cmd"] is not None
            driving = out["tension_cmd"][part] if use_command else tension_all[part]
            ending = use_command or spec.target.tension_timing == "period"
            out["replay"][part] = _replay(work, q, q_f, qd, driving, dt, spec, ending)
        valid[part] = True
    imported = "imported_from" in log.metadata.extra  # msarm log import wrote it
    _warn_implausible_scales(source, out, tension_all, motor_all, valid, spec, cables, imported)
    return Residuals(
        source=source,
        joint_names=tuple(joints),
        cable_names=tuple(cables),
        sample_rate_hz=log.metadata.sample_rate_hz,
        t=np.asarray(log.t, dtype=float).copy(),
        valid=valid,
        joint_torque=out["joint_torque"],
        cable_length=out["cable_length"],
        drive=out["drive"],
        replay=out["replay"],
        q=q_all,
        qd=out["qd"],
        qdd=out["qdd"],
        cable_velocity=out["cable_velocity"],
        tension=tension_all,
        tension_cmd=out["tension_cmd"],
        motor_speed=out["motor_speed"],
        qdd_ref=out["qdd_ref"],
        lengths=out["lengths"],
        jacobian=out["jacobian"],
        wrap=out["wrap"],
        target=spec.target,
    )


def _warn_implausible_scales(
    source: str,
    out: dict[str, FloatArray | None],
    tension: FloatArray,
    motor: FloatArray | None,
    valid: NDArray[np.bool_],
    spec: ResidualSpec,
    cable_names: list[str],
    imported: bool = False,
) -> None:
    """Warn when a channel's scale disagrees with what it should match (a unit or sign slip).

    - The load cells' tensions against a cable that pulls: a median below
      :data:`MIN_MEDIAN_TENSION` over the log would make every sample slack, as tensions
      logged in kN and read as N do (the commands are named too when theirs is as low: both
      in kN pass the next check). The message suggests ``msarm log import --unit`` when
      ``imported`` (the log's ``msarm.extra`` has ``imported_from``).
    - The commanded tensions against the load cells: the drives render each command at the
      load cell, so their medians agree within :data:`TENSION_RATIO` unless one is logged in
      another unit (kN as N). The drive residual ``F - F_cmd`` would then be mostly that.
    - The cable lengths the motor encoders give against the cables' path lengths: the
      first change as the second (a slope of 1 in :data:`LENGTH_SLOPE`) unless the motor
      angles are in another unit or sign, or the drum radius is wrong (a gearbox). Checked
      cable by cable (one winch may be mirrored), where the path's travel is above
      :data:`MIN_CHECKED_TRAVEL` (RMS over the log).
    """
    if not valid.any():
        return
    command = out["tension_cmd"]
    slack = [
        (quantity, median)
        for quantity, matrix in (("tension_motor", tension), ("tension_cmd", command))
        if matrix is not None
        and (median := float(np.median(np.abs(matrix[valid])))) < MIN_MEDIAN_TENSION
    ]
    if slack and slack[0][0] == "tension_motor":  # commands alone: the ratio check below
        named = ", ".join(f"{quantity}.* (median {median:.3g} N)" for quantity, median in slack)
        fix = (
            "import it again with "
            + " ".join(f"--unit {quantity}=kN" for quantity, _ in slack)
            + " if they are in kN"
            if imported
            else "convert them to N if they are in another unit"
        )
        warnings.warn(
            f"{source}: the tensions {named} are below {MIN_MEDIAN_TENSION:g} N in most "
            "samples, where a cable that pulls the arm carries several N: are they in kN (or "
            f"another unit) read as N? The diagnosis would take the cables as slack and the "
            f"tensions as far too small to carry the arm; {fix}",
            DiagnosisWarning,
            stacklevel=3,
        )
    if command is not None:
        measured = float(np.median(np.abs(tension[valid])))
        commanded = float(np.median(np.abs(command[valid])))
        low, high = TENSION_RATIO
        if measured > 0 and commanded > 0 and not low <= commanded / measured <= high:
            warnings.warn(
                f"{source}: the commanded tensions (tension_cmd.*, median {commanded:.4g} N) "
                f"are {commanded / measured:.3g} times the load cells' (tension_motor.*, median "
                f"{measured:.4g} N), where drives that render their commands give about 1: is "
                "one of them in another unit (kN logged as N)? The drive residual F - F_cmd "
                "is then mostly this, and the drive terms are fitted to it",
                DiagnosisWarning,
                stacklevel=3,
            )
        else:
            _warn_cable_tension_scale(source, tension[valid], command[valid], cable_names)
    length = out["cable_length"]
    if length is not None and motor is not None:
        # the encoders' length change against the path's, cable by cable: a slope of 1
        # (stretch and slack scatter about it), 57 for degrees, -1 for a mirrored winch
        encoder = -spec.drum_radius * (motor[valid] - motor[valid].mean(axis=0))
        path = encoder - (length[valid] - length[valid].mean(axis=0))
        spread = np.sqrt(np.mean(path**2, axis=0))
        slope = np.sum(encoder * path, axis=0) / np.maximum(np.sum(path**2, axis=0), 1e-300)
        low, high = LENGTH_SLOPE
        off = np.flatnonzero((spread > MIN_CHECKED_TRAVEL) & ((slope < low) | (slope > high)))
        if off.size:
            named = ", ".join(
                f"'motor_angle.{cable_names[k]}' ({float(slope[k]):.3g})" for k in off[:3]
            )
            more = f" and {off.size - 3} more" if off.size > 3 else ""
            warnings.warn(
                f"{source}: the cable lengths the motor encoders give (drum radius "
                f"{spec.drum_radius:g} m) do not follow the cables' path lengths for "
                f"{named}{more} (in brackets: how many times the path's change the encoders' "
                "is, where 1 is expected). Are the motor angles in rad and reel-in positive, "
                "and is the drum radius right "
                "(--drum-radius; a gearbox between encoder and drum divides it by its ratio)? "
                "The length terms would be fitted to this mismatch",
                DiagnosisWarning,
                stacklevel=3,
            )


def _warn_cable_tension_scale(
    source: str, tension: FloatArray, command: FloatArray, cable_names: list[str]
) -> None:
    """Warn about cables whose load cell and command disagree in scale (one cable's unit slip).

    The pooled medians of :func:`_warn_implausible_scales` hide one cable logged in another unit
    among nine; here each cable's commanded median over its load cell's must lie within
    :data:`CABLE_TENSION_RATIO`, for cables whose command or load cell reads
    :data:`MIN_MEDIAN_TENSION` or more in most samples (a cable held slack has no scale).

    Args:
        source: The log's name, for the message.
        tension: Load-cell tensions of the valid samples [N], ``(T, m)``.
        command: Commanded tensions of the same samples [N], ``(T, m)``.
        cable_names: The cables' names, ``(m,)``.
    """
    measured = np.median(np.abs(tension), axis=0)
    commanded = np.median(np.abs(command), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(measured > 0, commanded / measured, np.inf)  # inf: a dead load cell
    low, high = CABLE_TENSION_RATIO
    carries = np.maximum(measured, commanded) >= MIN_MEDIAN_TENSION
    off = np.flatnonzero(carries & ((ratio < low) | (ratio > high)))
    if not off.size:
        return
    named = ", ".join(
        f"'{cable_names[k]}' ({float(ratio[k]):.3g}: command {float(commanded[k]):.4g} N, load "
        f"cell {float(measured[k]):.4g} N)"
        for k in off[:3]
    )
    more = f" and {off.size - 3} more" if off.size > 3 else ""
    one = off.size == 1
    cables = "tension of cable" if one else "tensions of cables"
    are, reads = ("is", "its load cell reads") if one else ("are", "their load cells read")
    each = "that cable's" if one else "each such cable's"
    warnings.warn(
        f"{source}: the commanded {cables} {named}{more} {are} far from what {reads} "
        "(medians; in parentheses their ratio, where drives that render their commands give "
        f"about 1, 0.58-2.06 on msarm's simulated plants): is {each} tension_motor or "
        "tension_cmd column in another unit (mN, kN), or its load cell dead? Its drive "
        "residual F - F_cmd is then mostly this",
        DiagnosisWarning,
        stacklevel=4,
    )


def _warn_outside_joint_range(
    source: str, angles: list[tuple[str, FloatArray]], model: RobotModel, joints: list[str]
) -> None:
    """Warn when joint angles lie far outside the model's joint range (a unit slip).

    ``angles`` holds ``(quantity, matrix)``: the measured ``q`` and the reference ``q_ref``,
    each ``(T, n)`` [rad] in the order of ``joints`` (degrees read as radians in either: the
    reference's give the mass-error term its accelerations). A joint with no finite limit is
    not checked. "Far": more than :data:`JOINT_RANGE_MARGIN` beyond a limit.
    """
    lower = np.asarray(model.joint_lower, dtype=float)
    upper = np.asarray(model.joint_upper, dtype=float)
    named, quantities = [], []
    for quantity, q in angles:
        with np.errstate(invalid="ignore"):
            below = np.where(np.isfinite(lower), lower - np.nanmin(q, axis=0), -np.inf)
            above = np.where(np.isfinite(upper), np.nanmax(q, axis=0) - upper, -np.inf)
        off = np.flatnonzero(np.maximum(below, above) > JOINT_RANGE_MARGIN)
        if off.size:
            quantities.append(quantity)
        named += [
            f"'{quantity}.{joints[k]}' spans [{np.nanmin(q[:, k]):.3g}, "
            f"{np.nanmax(q[:, k]):.3g}] (range [{lower[k]:.3g}, {upper[k]:.3g}])"
            for k in off
        ]
    if not named:
        return
    more = f" and {len(named) - 3} more" if len(named) > 3 else ""
    convert = " ".join(f"--unit {quantity}=deg" for quantity in quantities)
    warnings.warn(
        f"{source}: joint angles far outside the model's joint range: "
        f"{', '.join(named[:3])}{more}, in rad. "
        "Are the joint angles in rad (degrees read as radians are 57 times too large; "
        f"msarm log import {convert} converts them), and is this the robot's model? The "
        "cable geometry and the inverse dynamics would be evaluated at postures the robot "
        "cannot take",
        DiagnosisWarning,
        stacklevel=3,
    )


def _warn_channels_of_no_joint_or_cable(log: RunLog, model: RobotModel, source: str) -> None:
    """Warn of channels of a joint or cable quantity that name none of the model's.

    The quantities are those ``msarm log import`` checks the names of
    (:data:`~msarm.io.table_import.JOINT_QUANTITIES`, :data:`~msarm.io.table_import.
    CABLE_QUANTITIES`). The diagnosis reads each quantity by the model's names, so such a
    column is not read: a misspelt ``q_ref.Elbow`` would otherwise leave ``q_ref.elbow``
    missing with no word on why. One warning for the joints' channels, one for the cables'.
    """
    from msarm.io.table_import import CABLE_QUANTITIES, JOINT_QUANTITIES

    for kind, quantities, known in (
        ("joint", JOINT_QUANTITIES, list(model.joint_names)),
        ("cable", CABLE_QUANTITIES, list(model.cable_names)),
    ):
        strangers = [
            column
            for column in log.columns
            if column != TIME
            and split_channel(column)[0] in quantities
            and split_channel(column)[1] not in known
        ]
        if not strangers:
            continue
        one = len(strangers) == 1
        listed = ", ".join(repr(column) for column in strangers[:4])
        more = f" and {len(strangers) - 4} more" if len(strangers) > 4 else ""
        warnings.warn(
            f"{source}: column{'' if one else 's'} {listed}{more} name{'s' if one else ''} no "
            f"{kind} of the model {model.name!r} (its {kind}s: {', '.join(known)}); the "
            f"diagnosis does not read {'it' if one else 'them'} (a misspelt name, or a "
            f"{kind} the model lacks? rename the column to one of the model's {kind}s, or "
            "leave it out)",
            DiagnosisWarning,
            stacklevel=3,
        )


def _has_channels(log: RunLog, quantity: str, names: list[str], source: str, without: str) -> bool:
    """Whether the log has ``quantity.<name>`` for every name; if not, warn what is lost."""
    missing = [name for name in names if f"{quantity}.{name}" not in log.columns]
    if missing:
        if len(missing) == len(names):
            what = f"columns '{quantity}.*' are missing (all {len(names)})"
        else:
            listed = ", ".join(f"'{quantity}.{name}'" for name in missing[:3])
            more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
            what = (
                f"column{'s' if len(missing) > 1 else ''} {listed}{more} "
                f"{'are' if len(missing) > 1 else 'is'} missing ({len(missing)} of "
                f"{len(names)} '{quantity}.*' columns)"
            )
        warnings.warn(f"{source}: {what}: {without}", DiagnosisWarning, stacklevel=3)
    return not missing


def _warn_constant_sensors(source: str, channels: list[tuple[str, list[str], FloatArray]]) -> None:
    """Warn (one line) about sensor columns that hold exactly one value over the whole log.

    ``channels`` holds ``(quantity, names, matrix)`` with ``matrix[:, k]`` the column
    ``quantity.names[k]``. A joint held still may be legitimate, so this is not refused.
    Commands (``tension_cmd``) are not checked: a cable kept at its least tension is commanded
    one value over a whole run (so msarm's own allocation does for an unused cable).
    """
    constant = [
        f"'{quantity}.{name}'"
        for quantity, names, matrix in channels
        if len(matrix)
        for name, spread in zip(names, np.ptp(matrix, axis=0), strict=True)
        if spread == 0.0
    ]
    if constant:
        warnings.warn(
            f"{source}: column(s) {', '.join(constant)} hold one value over the whole log: a "
            "dead or disconnected sensor? (a real sensor's noise moves its reading; a joint "
            "held still or a noise-free simulation may not) The diagnosis uses them as "
            "logged; leave the log out if a sensor is dead",
            DiagnosisWarning,
            stacklevel=3,
        )


def _warn_filter_span(source: str, window: int, sample_rate_hz: float) -> None:
    """Warn when the derivative filter spans a time no arm's motion is measured over.

    The window is in samples; its span in time is what smooths the velocities and
    accelerations. Outside :data:`FILTER_SPAN_S`, either the sample rate (or the time unit of
    the log) is wrong, or the window was not scaled with the rate.
    """
    span = window / sample_rate_hz
    low, high = FILTER_SPAN_S
    if low <= span <= high:
        return
    suggested = max(2 * round(0.05 * sample_rate_hz) + 1, 5)  # about 0.1 s, odd
    if span > high:
        beyond = f"more than {high:g} s"
        effect = (
            "smoothed over much of a motion, and the joint-torque residual takes a bias from "
            "the filter itself (on a plant with sensor noise alone a 0.2 s window named a mass "
            "error)"
        )
    else:
        beyond, effect = f"less than {low:g} s", "mostly the encoders' noise"
    warnings.warn(
        f"{source}: the derivative filter's {window} samples span {span:.3g} s at the log's "
        f"{sample_rate_hz:g} Hz ({beyond}): the velocities and accelerations are {effect}. "
        "Is the log's time in seconds and its sample_rate_hz right? Else scale the window "
        f"with the rate (--filter-window; about 0.1 s is {suggested} samples here)",
        DiagnosisWarning,
        stacklevel=3,
    )


def gap_starts(t: FloatArray, sample_rate_hz: float) -> NDArray[np.intp]:
    """The rows that start a new stretch after a time gap.

    Args:
        t: Sample times [s], shape ``(T,)``.
        sample_rate_hz: Nominal sample rate [Hz].

    Returns:
        Row indices ``k`` (ascending) with ``t[k] - t[k - 1]`` longer than
        :data:`GAP_FACTOR` nominal sample periods, shape ``(G,)``.
    """
    period = 1.0 / sample_rate_hz
    return np.flatnonzero(np.diff(t) > GAP_FACTOR * period) + 1


def _segments(log: RunLog, source: str, window: int) -> list[tuple[int, int]]:
    """Contiguous, uniformly sampled stretches ``[start, stop)`` of a log; warns about gaps.

    Raises:
        LogError: The mean step (gaps left out) disagrees with the nominal rate, or no
            stretch is long enough for the filter.
    """
    t = log.t
    period = 1.0 / log.metadata.sample_rate_hz
    # the mean step between gaps: stamps rounded to whole ms at 300 Hz step 3, 3, 4 ms
    step = nominal_step(t) if len(t) > 1 else period
    if abs(step - period) > _RATE_TOLERANCE * period:
        raise LogError(
            f"{source}: column '{TIME}' has a mean step of {step:.6g} s (gaps left out), but "
            f"the metadata's sample_rate_hz {log.metadata.sample_rate_hz:g} means {period:.6g} "
            "s; resample the log or fix its sample rate"
        )
    if abs(step - period) > _RATE_WARNING * period:
        off = 100.0 * (step / period - 1.0)
        warnings.warn(
            f"{source}: column '{TIME}' has a mean step of {step:.6g} s (gaps left out), "
            f"{off:+.2g} % off the {period:.6g} s of the metadata's sample_rate_hz "
            f"{log.metadata.sample_rate_hz:g}; the filtered velocities and accelerations use "
            "the metadata's period, so they are off by about as much (fix sample_rate_hz if "
            "it is wrong)",
            DiagnosisWarning,
            stacklevel=3,
        )
    gaps = gap_starts(t, log.metadata.sample_rate_hz)
    bounds = [0, *gaps.tolist(), len(t)]
    segments = list(zip(bounds[:-1], bounds[1:], strict=True))
    if len(gaps):
        row = int(gaps[0])
        warnings.warn(
            f"{source}: column '{TIME}' has {len(gaps)} gap(s) longer than {GAP_FACTOR:g} "
            f"sample periods, the first at row {row} "
            f"(t = {float(t[row - 1]):.6g} -> {float(t[row]):.6g} s); "
            "the log is diagnosed as separate segments",
            DiagnosisWarning,
            stacklevel=3,
        )
    kept = [(a, b) for a, b in segments if b - a >= window]
    dropped = len(segments) - len(kept)
    if not kept:
        raise LogError(
            f"{source}: no contiguous stretch of column '{TIME}' has the filter's {window} "
            "samples; nothing can be diagnosed (record longer stretches or use a shorter "
            "filter window: msarm diagnose --filter-window, or "
            "ResidualSpec(target=TargetSpec(window=...)) in Python)"
        )
    if dropped:
        warnings.warn(
            f"{source}: {dropped} segment(s) shorter than the filter's {window} samples are "
            "left out (marked invalid); the rest is diagnosed",
            DiagnosisWarning,
            stacklevel=3,
        )
    return kept


class _Work:
    """Work space: MuJoCo data for the cable kinematics, Pinocchio's for the forward dynamics.

    The forward dynamics of many states at once is Pinocchio's ``abaInParallel`` on one
    thread (a C++ loop over the states: half the time of calling ``aba`` state by state from
    Python, with the same bits as ``aba`` in the WORLD convention, and each state's bits
    whatever the batch).
    """

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        self.data = model.create_data()
        self.jacobian_at = JacobianAt(model, self.data)
        self.index = np.asarray(model.pin_q_index)
        self.inverse = np.argsort(self.index)
        self.identity = bool(np.array_equal(self.index, np.arange(self.index.size)))
        self.pool = pinocchio.ModelPool(model.pin_model, 1)

    def acceleration(
        self, q: FloatArray, qd: FloatArray, tension: FloatArray, lost: FloatArray | None = None
    ) -> FloatArray:
        """Nominal ``qdd`` [rad/s^2] under ``tau = -J_c(q)^T F - lost`` (ideal cables).

        ``lost`` [N m], ``(n,)``: torque lost on the way (a fitted residual), if any.
        """
        tau = -self.jacobian_at(q).T @ tension
        return self._forward(q, qd, tau if lost is None else tau - lost)

    def accelerations(
        self, q: FloatArray, qd: FloatArray, tension: FloatArray, lost: FloatArray | None = None
    ) -> FloatArray:
        """:meth:`acceleration` of ``W`` states at once (the same bits), ``(W, n)``.

        Args:
            q: Joint angles [rad], ``(W, n)``.
            qd: Joint velocities [rad/s], ``(W, n)``.
            tension: Cable tensions [N], ``(W, m)``.
            lost: Torque lost [N m], ``(W, n)``, or None.
        """
        jacobians = self.jacobian_at.many(q)
        # one batched product: the bits of -J^T F row by row (the same summation)
        tau = np.matmul(-jacobians.transpose(0, 2, 1), tension[:, :, None])[:, :, 0]
        if lost is not None:
            tau = tau - lost
        return self._forward_many(q, qd, tau)

    def _forward(self, q: FloatArray, qd: FloatArray, tau: FloatArray) -> FloatArray:
        """Pinocchio's forward dynamics in msarm's joint order [rad/s^2], ``(n,)``."""
        return self._forward_many(q[None, :], qd[None, :], tau[None, :])[0]

    def _forward_many(self, q: FloatArray, qd: FloatArray, tau: FloatArray) -> FloatArray:
        """:meth:`_forward` of ``W`` states, ``(W, n)`` each, in one ``abaInParallel``."""
        if not self.identity:  # msarm's joint order to Pinocchio's
            q, qd, tau = q[:, self.index], qd[:, self.index], tau[:, self.index]
        qdd = pinocchio.abaInParallel(1, self.pool, q.T, qd.T, tau.T)
        qdd = np.asarray(qdd).reshape(q.shape[1], q.shape[0]).T  # one state comes back (n,)
        return qdd if self.identity else qdd[:, self.inverse]


def _replay(
    work: _Work,
    q_log: FloatArray,
    q_start: FloatArray,
    qd_start: FloatArray,
    tension: FloatArray,
    dt: float,
    spec: ResidualSpec,
    period_ending: bool,
    lost: FloatArray | None = None,
    stretches: Sequence[slice] | None = None,
) -> FloatArray:
    """Replay residual of one segment [rad], shape ``(T, n)``.

    The segment is cut into windows of ``spec.replay_window``; each starts at the filtered
    state ``(q_start, qd_start)`` of its first sample and runs the nominal dynamics under the
    logged tensions (held over each sample period), less the torque ``lost`` [N m], ``(T, n)``,
    when given (the nominal model with fitted effects). With ``period_ending`` each
    ``tension[k]`` is the tension over the period ending at ``t_k`` (msarm's load cells, and
    the commands aligned with them), so the step from ``t_k`` is driven by ``tension[k + 1]``;
    otherwise (tensions read at their instant) by ``tension[k]``. Driving it by
    ``tension[k]`` always, as before 2026-11-29, put the tensions a period late: on the ideal
    plant the replay residual was 0.45 mrad RMS where it is 0.05 mrad. The windows are
    independent, so they are integrated side by side, sample by sample (each window's numbers
    are those of integrating it alone). An error beyond pi rad (a diverging replay) is
    clipped to +-pi and the window starts again from the logged state of the next sample.

    ``stretches``: the rows of several segments set end to end (each cut into windows from
    its first row; all of them integrated side by side), or None: the whole arrays, one
    segment.
    """
    per_window = max(1, round(spec.replay_window / dt))
    h = dt / spec.replay_substeps
    out = np.empty_like(q_log)
    starts, stops = _windows([slice(0, len(q_log))] if stretches is None else stretches, per_window)
    q = q_start[starts].copy()
    v = qd_start[starts].copy()
    with np.errstate(over="ignore", invalid="ignore"):
        for j in range(per_window):
            live = starts + j < stops  # a segment's last window may be shorter
            rows = starts[live] + j
            error = q[live] - q_log[rows]
            bad = ~np.all(np.abs(error) < _REPLAY_LIMIT, axis=1)  # diverged (or NaN)
            error[bad] = np.clip(
                np.nan_to_num(error[bad], nan=_REPLAY_LIMIT), -_REPLAY_LIMIT, _REPLAY_LIMIT
            )
            out[rows] = error
            if j + 1 == per_window:
                break
            more = rows + 1 < stops[live]
            go = np.flatnonzero(live)[~bad & more]
            restart = np.flatnonzero(live)[bad & more]
            q[restart] = q_start[starts[restart] + j + 1]
            v[restart] = qd_start[starts[restart] + j + 1]
            if go.size:
                k = starts[go] + j
                qs, vs = q[go], v[go]
                extra = None if lost is None else lost[k]
                acting = tension[k + 1] if period_ending else tension[k]
                for _ in range(spec.replay_substeps):  # explicit midpoint rule
                    a_start = work.accelerations(qs, vs, acting, extra)
                    q_mid, v_mid = qs + 0.5 * h * vs, vs + 0.5 * h * a_start
                    a_mid = work.accelerations(q_mid, v_mid, acting, extra)
                    qs, vs = qs + h * v_mid, vs + h * a_mid
                q[go], v[go] = qs, vs
    return out


def _windows(
    stretches: Sequence[slice], per_window: int
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """First rows of the replay windows and the end of each one's segment (exclusive)."""
    starts = [np.arange(part.start, part.stop, per_window) for part in stretches]
    stops = [np.full(len(first), part.stop) for first, part in zip(starts, stretches, strict=True)]
    return np.concatenate(starts), np.concatenate(stops)


def replay_runs(
    model: RobotModel,
    q: FloatArray,
    qd: FloatArray,
    tension: FloatArray,
    run: NDArray[np.int64],
    dt: float,
    lost: FloatArray | None = None,
    spec: ResidualSpec | None = None,
    *,
    period_ending: bool | None = None,
) -> FloatArray:
    """Replay residual of concatenated runs, optionally with a fitted torque loss.

    The nominal dynamics driven by the logged tensions over short windows (see the module
    docstring), less ``lost`` when given: how far the nominal model, or the nominal model with
    fitted effects, drifts from the logged motion. Several replays of the same motion
    (``tension`` of shape ``(V, T, m)``, ``lost`` ``(V, T, n)``) are integrated side by side:
    the bits of each replayed alone, in a fraction of the time.

    Args:
        model: The nominal robot model.
        q: Logged joint angles [rad], ``(T, n)``.
        qd: Filtered joint velocities [rad/s], ``(T, n)`` (the windows' start states).
        tension: Load-cell tensions [N], ``(T, m)``, or ``(V, T, m)`` for ``V`` replays.
        run: Label of each sample's stretch without a time gap (:attr:`Signals.segment`),
            ``(T,)``; each contiguous.
        dt: Sample period [s].
        lost: Torque lost between the cables and the joints [N m], ``(T, n)`` (the fitted
            joint-torque residual), or ``(V, T, n)`` with ``V`` tensions, or None for the
            nominal model.
        spec: Window and substeps.
        period_ending: Whether ``tension[k]`` is the tension over the sample period ending
            at ``t_k`` (msarm's load cells with ``tension_timing="period"``, and commands
            aligned with the tension that answers them): the step from ``t_k`` to
            ``t_k+1`` is then driven by ``tension[k + 1]``; else (tensions read at their
            instant) by ``tension[k]``. None: as ``spec.target.tension_timing`` says of
            load-cell tensions (pass True for aligned commands).

    Returns:
        ``q_replay - q`` [rad], ``(T, n)``, or ``(V, T, n)`` for ``V`` tensions.
    """
    spec = spec or ResidualSpec()
    if period_ending is None:
        period_ending = spec.target.tension_timing == "period"
    tensions = np.asarray(tension, dtype=float)
    single = tensions.ndim == 2
    if single:
        tensions = tensions[None]
    V, T = len(tensions), len(q)
    losses = None if lost is None else np.asarray(lost, dtype=float).reshape(V * T, -1)
    parts = []
    for label in np.unique(run):
        index = np.flatnonzero(run == label)
        parts.append((int(index[0]), int(index[-1]) + 1))
    # the replays end to end, each cut into its runs: one integration of all their windows
    stretches = [slice(a + k * T, b + k * T) for k in range(V) for a, b in parts]
    q_all, qd_all = np.tile(q, (V, 1)), np.tile(qd, (V, 1))
    out = _replay(
        _Work(model), q_all, q_all, qd_all, tensions.reshape(V * T, -1), dt, spec,
        period_ending, losses, stretches,
    ).reshape(V, T, -1)  # fmt: skip
    return out[0] if single else out
