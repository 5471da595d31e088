"""The training target of the compensator: the joint-torque error T_f of paper 003 eq. 5.

``D(q) qdd + C(q, qd) qd + G(q) = tau_MS - T_f``, so

``T_f = tau_MS - ID(q, qd, qdd)``

with ``tau_MS = -J_c(q)^T F_sensor`` the torque the logged motor-side tensions would deliver
through ideal cables, and ``ID`` Pinocchio's inverse dynamics (RNEA) of the logged motion.
In a run with the compensator's sheath stage on, the drives were asked on purpose for more
(or less) than the tension meant for the insertions; what the stage added is logged
(``tension_ff``) and taken off: ``F_sensor - F_ff`` is the tension the stage meant to arrive,
so ``T_f`` is the torque error the stage leaves, which is what a network on top of it has to
learn. Logs without ``tension_ff`` columns (runs without the stage) count it as zero. The two
are taken off row by row, although with ``tension_timing="period"`` the load-cell sample of a
row is the tension the previous row's command made: ``tension_ff`` of row ``k - 1`` would be
the exact pair. A review measured the difference (2026-11-29, the demo's runs with the stage):
0.006-0.016 N m RMS of a ``T_f`` of 0.21-0.30 N m, and a compensator trained on the shifted
target did no better on the fourteen held-out tasks (0.111 mm mean final error against
0.097 mm, within what a retraining moves); it is left as it is.
The derivatives come from the joint encoders through a Savitzky-Golay filter (zero phase:
this is offline, for training only). On a plant without unmodelled effects ``T_f`` is zero up
to filtering error; friction, slack and cable elasticity make it differ.

Both sides of the balance go through the same filter (parallel filtering, as in the
identification of robot dynamics): the delivered torque ``-J_c^T F`` is integrated twice over
time, as the joints integrate it, and the result differentiated twice by the Savitzky-Golay
filter that gives the joint angles their accelerations, so that it keeps exactly the part of
the torque that the smoothed accelerations can show. Without it, ``T_f`` carries the load
cells' noise and the tension's fast part (the controller's answer to the encoders' noise).
The integration follows the load cells' timing (``TargetSpec.tension_timing``): msarm's
drives hold each command over a control period, so a load-cell sample is the tension of the
period that ends at its time stamp (``"period"``); a load cell read at its instant gives a
tension taken as linear between samples (``"instant"``). On msarm's rigid-cable plants the
first fits (noise-free, 0.0019 N m RMS left against 0.0039 N m); on its elastic plants,
whose logged tension is one plant step (a quarter period) late, the two come out alike
(0.0025 and 0.0019 N m), both far below the sensor noise's share. On the diagnosis
benchmark's plants with sensor noise alone, whose ``T_f`` should be zero, its held-out RMS is
0.057 N m without parallel filtering and 0.017 N m with it; from one run's noise-free signals
(the sidecar's), 0.042 and 0.002 N m.

The feedforward compensation is ``dtau = T_f_hat``: asking the muscles for ``tau + T_f``
makes the joints receive ``tau``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio
from numpy.typing import NDArray
from scipy.signal import savgol_filter

from msarm.errors import InputError
from msarm.io.config import check_field_types
from msarm.io.logs import RunLog
from msarm.model import RobotModel
from msarm.muscle.batch_kinematics import cable_kinematics_batch

__all__ = [
    "TENSION_TIMINGS",
    "TargetSpec",
    "delivered_torque",
    "filtered_motion",
    "torque_error",
]

FloatArray = NDArray[np.float64]

#: What a load-cell sample can be (:attr:`TargetSpec.tension_timing`).
TENSION_TIMINGS = ("period", "instant")


@dataclass(frozen=True)
class TargetSpec:
    """How the target is computed from a log.

    Attributes:
        window: Savitzky-Golay window [samples], odd (25 samples = 0.1 s at 250 Hz).
        polyorder: Savitzky-Golay polynomial order.
        smooth_tension: Filter the delivered torque as the joint angles are (parallel
            filtering; see the module docstring); False: the torque of each sample as it is.
        tension_timing: What a load-cell sample is: ``"period"``, the tension held over the
            sample period that ends at its time stamp (msarm's drives); ``"instant"``, the
            tension at its time stamp, linear between samples.
    """

    window: int = 25
    polyorder: int = 3
    smooth_tension: bool = True
    tension_timing: str = "period"

    def __post_init__(self) -> None:
        check_field_types(self)
        if self.window % 2 == 0 or self.window <= self.polyorder:
            raise ValueError(
                f"window must be odd and > polyorder, got {self.window}, {self.polyorder}"
            )
        if self.tension_timing not in TENSION_TIMINGS:
            raise ValueError(
                f"tension_timing must be one of {', '.join(TENSION_TIMINGS)}, "
                f"got {self.tension_timing!r}"
            )


def filtered_motion(
    q_raw: FloatArray, spec: TargetSpec, dt: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The logged joint angles through the target's Savitzky-Golay filter.

    Args:
        q_raw: Joint angles as logged [rad], ``(T, n)``, ``T >= spec.window``.
        spec: The filter.
        dt: Sample period [s].

    Returns:
        Smoothed angles [rad], velocities [rad/s] and accelerations [rad/s^2], each ``(T, n)``.
    """
    window, order = spec.window, spec.polyorder
    return (
        savgol_filter(q_raw, window, order, axis=0),
        savgol_filter(q_raw, window, order, deriv=1, delta=dt, axis=0),
        savgol_filter(q_raw, window, order, deriv=2, delta=dt, axis=0),
    )


def torque_error(
    model: RobotModel,
    log: RunLog,
    spec: TargetSpec | None = None,
    source: str = "log",
    jacobians: FloatArray | None = None,
    motion: tuple[FloatArray, FloatArray, FloatArray] | None = None,
    *,
    remove_feedforward: bool = True,
) -> FloatArray:
    """``T_f`` of every sample of a log [N m], shape ``(T, n)``.

    Args:
        model: The nominal robot model.
        log: A run's log (``q`` and ``tension_motor`` channels, uniform sampling).
        spec: Filter settings.
        source: Name of the log for error messages.
        jacobians: The muscle Jacobians at the logged postures, ``(T, m, n)``, if the caller
            has them already (:func:`msarm.muscle.batch_kinematics.cable_kinematics_batch`);
            computed here otherwise.
        motion: :func:`filtered_motion` of the log's joint angles with ``spec``, if the caller
            has it already; computed here otherwise.
        remove_feedforward: Take the sheath stage's logged ``tension_ff`` off the load-cell
            tensions (the compensator's target: what the stage leaves). ``False`` keeps the
            whole measured tension (the diagnosis: the gap between the plant and the nominal
            model, whatever the drives were asked for).

    Raises:
        InputError: Too few samples for the filter, a needed channel is missing, or
            ``jacobians`` or ``motion`` of the wrong shape.
    """
    spec = spec or TargetSpec()
    joints, cables = list(model.joint_names), list(model.cable_names)
    for quantity, names in (("q", joints), ("tension_motor", cables)):
        missing = [n for n in names if f"{quantity}.{n}" not in log.columns]
        if missing:
            raise InputError(f"{source}: columns {quantity}.{missing[0]} ... are missing")
    q_raw = log.matrix("q", joints)
    if len(q_raw) < spec.window:
        raise InputError(f"{source}: {len(q_raw)} samples, fewer than the filter's {spec.window}")
    dt = 1.0 / log.metadata.sample_rate_hz
    if motion is None:
        motion = filtered_motion(q_raw, spec, dt)
    elif any(np.shape(part) != q_raw.shape for part in motion):
        raise InputError(f"{source}: motion must be three arrays of shape {q_raw.shape}")
    q, qd, qdd = motion
    tension = log.matrix("tension_motor", cables)
    if remove_feedforward and all(f"tension_ff.{c}" in log.columns for c in cables):
        tension = tension - log.matrix("tension_ff", cables)
    data = model.create_data()
    needed = np.empty_like(q)
    index = model.pin_q_index
    inverse = np.argsort(index)
    if jacobians is None:
        jacobians = cable_kinematics_batch(model, q_raw, with_wrap_angles=False).jacobian
    elif jacobians.shape != (len(q_raw), model.n_cables, model.n_joints):
        raise InputError(
            f"{source}: jacobians must have shape {(len(q_raw), model.n_cables, model.n_joints)}"
            f", got {jacobians.shape}"
        )
    for k in range(len(q)):
        needed[k] = pinocchio.rnea(
            model.pin_model, data.pin, q[k][index], qd[k][index], qdd[k][index]
        )[inverse]
    return delivered_torque(jacobians, tension, spec, dt) - needed


def delivered_torque(
    jacobians: FloatArray, tension: FloatArray, spec: TargetSpec, dt: float
) -> FloatArray:
    """``-J_c^T F`` of every sample, filtered as the joint angles are [N m], ``(T, n)``.

    With ``spec.smooth_tension`` the torque is integrated twice over time (exactly, for a
    torque held over each period or linear between samples, as ``spec.tension_timing`` says;
    from zero at the first sample) and differentiated twice by the Savitzky-Golay filter of
    ``spec``: the filter the joint accelerations come from, so that both sides of the torque
    balance have one bandwidth and one timing.

    Args:
        jacobians: Muscle Jacobians at the logged postures, ``(T, m, n)``.
        tension: Load-cell tensions (less a tension-space feedforward) [N], ``(T, m)``.
        spec: The filter and the load cells' timing.
        dt: Sample period [s].
    """
    delivered = -np.einsum("tmn,tm->tn", jacobians, tension)
    if not spec.smooth_tension:
        return delivered
    before, after = delivered[:-1], delivered[1:]
    if spec.tension_timing == "period":  # held over [t_k, t_k+1): the sample at t_k+1
        rise, bend = after, 0.5 * after
    else:  # linear from one sample to the next
        rise, bend = 0.5 * (before + after), before / 3.0 + after / 6.0
    zero = np.zeros((1, delivered.shape[1]))
    speed = np.concatenate([zero, dt * np.cumsum(rise, axis=0)])
    travel = np.concatenate([zero, np.cumsum(dt * speed[:-1] + dt * dt * bend, axis=0)])
    return savgol_filter(travel, spec.window, spec.polyorder, deriv=2, delta=dt, axis=0)
