"""The training target of the compensator: the joint-torque error T_f of paper 003 eq. 5.

``D(q) qdd + C(q, qd) qd + G(q) = tau_MS - T_f``, so

``T_f = tau_MS - ID(q, qd, qdd)``

with ``tau_MS = -J_c(q)^T F_sensor`` the torque the logged motor-side tensions would deliver
through ideal cables, and ``ID`` Pinocchio's inverse dynamics (RNEA) of the logged motion.
In a run with the compensator's sheath stage on, the drives were asked on purpose for more
(or less) than the tension meant for the insertions; what the stage added is logged
(``tension_ff``) and taken off: ``F_sensor - F_ff`` is the tension the stage meant to arrive,
so ``T_f`` is the torque error the stage leaves, which is what a network on top of it has to
learn. Logs without ``tension_ff`` columns (runs without the stage) count it as zero.
The derivatives come from the joint encoders through a Savitzky-Golay filter (zero phase:
this is offline, for training only). On a plant without unmodelled effects ``T_f`` is zero up
to filtering error; friction, slack and cable elasticity make it differ.

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
from msarm.io.logs import RunLog
from msarm.model import RobotModel
from msarm.muscle.batch_kinematics import cable_kinematics_batch

__all__ = ["TargetSpec", "torque_error"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class TargetSpec:
    """How the target is computed from a log.

    Attributes:
        window: Savitzky-Golay window [samples], odd (25 samples = 0.1 s at 250 Hz).
        polyorder: Savitzky-Golay polynomial order.
    """

    window: int = 25
    polyorder: int = 3

    def __post_init__(self) -> None:
        if self.window % 2 == 0 or self.window <= self.polyorder:
            raise ValueError(
                f"window must be odd and > polyorder, got {self.window}, {self.polyorder}"
            )


def torque_error(
    model: RobotModel,
    log: RunLog,
    spec: TargetSpec | None = None,
    source: str = "log",
    jacobians: FloatArray | None = None,
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

    Raises:
        InputError: Too few samples for the filter, or a needed channel is missing.
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
    q = savgol_filter(q_raw, spec.window, spec.polyorder, axis=0)
    qd = savgol_filter(q_raw, spec.window, spec.polyorder, deriv=1, delta=dt, axis=0)
    qdd = savgol_filter(q_raw, spec.window, spec.polyorder, deriv=2, delta=dt, axis=0)
    tension = log.matrix("tension_motor", cables)
    if all(f"tension_ff.{c}" in log.columns for c in cables):
        tension = tension - log.matrix("tension_ff", cables)
    data = model.create_data()
    out = np.empty_like(q)
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
        delivered = -jacobians[k].T @ tension[k]
        needed = pinocchio.rnea(
            model.pin_model, data.pin, q[k][index], qd[k][index], qdd[k][index]
        )[inverse]
        out[k] = delivered - needed
    return out
