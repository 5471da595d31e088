"""The metrics of paper 003 computed from a run's log, as a real robot's data allow.

Everything here uses logged sensor channels only (encoders, motor encoders, load cells) and
the nominal model, never the plant's ground truth:

- final end-effector position error ``|p - p_d|`` in mm and in % of the displacement
  ``|p_d - p_0|`` (eq. 10-11), with ``p`` the ``hand_center`` site of the nominal model at the
  last logged encoder reading and ``p_0``, ``p_d`` at the task's home and target postures;
  the same error :data:`SETTLE_DELAY` after the reference comes to rest (the settle error);
- joint RMSE against the reference [rad];
- cable length error (eq. 12-13): the RMSE between the cable length the motor encoders say
  was reeled (``l(q_0) - r (theta - theta_0)``) and the theoretical length ``l(q)`` from the
  joint encoders, in % of each cable's maximum travel over the joint range; and, as paper
  003 reports its results (section 3.2), the two lengths' difference at the end of the run
  in % of the theoretical length;
- slack events (a load cell falling below ``SLACK_THRESHOLD``) and the time each tension
  spends outside its bounds ``[min_tension, F_max]`` by more than ``BOUND_TOLERANCE`` (a
  tension held at its lower bound must not count as outside through round-off or noise).

:func:`encoder_noise_floor` gives the final error that the joint encoders' noise alone puts
on the reading (the floor under the final error metric).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import mujoco
import numpy as np
from numpy.typing import NDArray
from scipy.integrate import quad
from scipy.optimize import minimize

from msarm.model import HAND_SITE, RobotModel, hand_site_id
from msarm.muscle.batch_kinematics import cable_kinematics_batch
from msarm.muscle.geometry import joint_grid
from msarm.tasks import metrics

__all__ = [
    "HAND_SITE",
    "TrackingMetrics",
    "cable_travel",
    "encoder_noise_floor",
    "evaluate_run",
    "hand_jacobian",
    "hand_position",
]

FloatArray = NDArray[np.float64]
#: Load-cell tension below which a cable counts as slack [N].
SLACK_THRESHOLD = 1.0
#: Margin beyond the tension bounds before a tension counts as outside them [N] (more than
#: three standard deviations of the default load-cell noise).
BOUND_TOLERANCE = 1.0
#: Time after the reference comes to rest at which the settle error is taken [s].
SETTLE_DELAY = 0.5


@dataclass(frozen=True)
class TrackingMetrics:
    """Metrics of one tracking run (see the module docstring).

    Attributes:
        final_error_mm: Final end-effector position error [mm].
        final_error_percent: The same in % of the displacement [%].
        settle_error_mm: End-effector error [mm] :data:`SETTLE_DELAY` after the reference
            comes to rest (how close the move itself lands, before the integral action has
            time to help); NaN when the run ends sooner.
        joint_rmse: Joint RMSE against the reference [rad], one per joint.
        cable_length_error_percent: Cable length RMSE in % of the cable's travel, one per
            cable (eq. 12-13).
        cable_length_end_percent: The cable lengths' difference at the end of the run in %
            of the theoretical length, one per cable (how paper 003's section 3.2 reports
            its results).
        slack_events: Entries into slack, one per cable.
        time_outside_bounds: Seconds outside the tension bounds, one per cable.
        completed: Whether the run reached the end of its task.
    """

    final_error_mm: float
    final_error_percent: float
    settle_error_mm: float
    joint_rmse: tuple[float, ...]
    cable_length_error_percent: tuple[float, ...]
    cable_length_end_percent: tuple[float, ...]
    slack_events: tuple[int, ...]
    time_outside_bounds: tuple[float, ...]
    completed: bool

    def as_dict(self) -> dict:
        """A JSON-ready dict (strict JSON: a NaN, a metric that does not apply, is None)."""
        return {
            key: None if isinstance(value, float) and value != value else value
            for key, value in asdict(self).items()
        }


def hand_position(model: RobotModel, q: FloatArray) -> FloatArray:
    """Position of the hand site [m] for postures ``q`` of shape ``(n,)`` or ``(T, n)``.

    Raises:
        ModelError: The model has no hand site :data:`~msarm.model.HAND_SITE`.
    """
    site = hand_site_id(model)
    q = np.atleast_2d(q)
    data = model.scratch_data().mj
    out = np.empty((len(q), 3))
    for k, posture in enumerate(q):
        data.qpos[:] = posture
        mujoco.mj_kinematics(model.mj_model, data)
        out[k] = data.site_xpos[site]
    return out


def hand_jacobian(model: RobotModel, q: FloatArray) -> FloatArray:
    """Jacobian ``dp/dq`` of the hand site's position at posture ``q`` (n,) [m/rad], ``(3, n)``.

    Raises:
        ModelError: The model has no hand site :data:`~msarm.model.HAND_SITE`.
    """
    site = hand_site_id(model)
    data = model.scratch_data().mj
    data.qpos[:] = q
    mujoco.mj_kinematics(model.mj_model, data)
    mujoco.mj_comPos(model.mj_model, data)
    jacobian = np.zeros((3, model.mj_model.nv))
    mujoco.mj_jacSite(model.mj_model, data, jacobian, None, site)
    return jacobian


def encoder_noise_floor(model: RobotModel, q: FloatArray, joint_noise: float) -> float:
    """Mean hand-position error [m] that the joint encoders' noise alone puts on one reading.

    The final error is read from one sample of the encoders, each with Gaussian noise of std
    ``joint_noise``: at posture ``q`` the hand then moves by ``x = J e`` with
    ``J = dp/dq`` (:func:`hand_jacobian`), ``e ~ N(0, sigma^2 I)``. Returns ``E|x|``, the
    final error that a run ending exactly on its target reads on average. With the
    eigenvalues ``l_i`` of ``sigma^2 J J^T``,
    ``E|x| = (1 / sqrt(pi)) int_0^inf (1 - prod_i (1 + 2 l_i u^2)^(-1/2)) / u^2 du``
    (from ``sqrt(s) = (2 sqrt(pi))^-1 int_0^inf (1 - exp(-t s)) t^(-3/2) dt``, ``t = u^2``).

    Args:
        model: The robot.
        q: Posture [rad], shape ``(n,)`` (the target, where a run ends).
        joint_noise: Encoder noise std [rad].

    Returns:
        The mean error [m]; 0 without noise.
    """
    if joint_noise < 0 or not np.isfinite(joint_noise):
        raise ValueError(f"joint_noise must be a finite std >= 0 [rad], got {joint_noise}")
    jacobian = hand_jacobian(model, np.asarray(q, dtype=float))
    eigenvalues = np.clip(np.linalg.eigvalsh(joint_noise**2 * jacobian @ jacobian.T), 0, None)
    scale = float(eigenvalues.max())
    if scale == 0.0:
        return 0.0
    shares = eigenvalues / scale

    def integrand(u: float) -> float:
        return (1.0 - float(np.prod(1.0 + 2.0 * shares * u * u) ** -0.5)) / (u * u) if u else 0.0

    # near u = 0 the integrand tends to sum(shares), not 0; quad never evaluates u = 0 itself
    value, _ = quad(integrand, 0.0, np.inf, epsabs=0.0, epsrel=1e-10, limit=200)
    return float(np.sqrt(scale) * value / np.sqrt(np.pi))


_TRAVEL_CACHE: dict[str, FloatArray] = {}


#: Points of the joint grid per joint that seed the search for each cable's extreme lengths.
TRAVEL_GRID = 7
#: Best grid points from which each extreme length is refined by a bounded local search.
TRAVEL_STARTS = 3


def cable_travel(model: RobotModel) -> FloatArray:
    """Maximum travel of each cable over the joint range [m], shape ``(m,)``.

    ``max l_c(q) - min l_c(q)`` over the joint-range box: a ``TRAVEL_GRID^n`` grid finds the
    neighbourhood of each extreme, then a bounded quasi-Newton search (L-BFGS-B, gradient the
    muscle Jacobian row) from the :data:`TRAVEL_STARTS` best grid points refines it. An
    extreme inside the box or on a face between grid points is found (the 7^n grid alone
    underestimated a travel by up to 0.7 %, which inflates the eq. 13 percentages as much).
    Cached by the model file's SHA-256.
    """
    if model.sha256 not in _TRAVEL_CACHE:
        grid = np.array(list(joint_grid(model.joint_lower, model.joint_upper, TRAVEL_GRID)))
        lengths = cable_kinematics_batch(model, list(grid), with_wrap_angles=False).lengths
        travel = np.empty(model.n_cables)
        for c in range(model.n_cables):
            longest = _extreme_length(model, c, 1.0, grid, lengths[:, c])
            shortest = _extreme_length(model, c, -1.0, grid, lengths[:, c])
            travel[c] = longest - shortest
        _TRAVEL_CACHE[model.sha256] = travel
    return _TRAVEL_CACHE[model.sha256].copy()


def _extreme_length(
    model: RobotModel, cable: int, sign: float, grid: FloatArray, on_grid: FloatArray
) -> float:
    """The longest (``sign = 1``) or shortest (``-1``) length of a cable in the joint range [m].

    ``grid`` ``(G, n)`` postures with the cable's lengths ``on_grid`` ``(G,)``; the best
    :data:`TRAVEL_STARTS` of them start a bounded L-BFGS-B search of ``max sign * l(q)``.
    """
    bounds = list(zip(model.joint_lower, model.joint_upper, strict=True))

    def objective(q: FloatArray) -> tuple[float, FloatArray]:
        geometry = model.geometry(q, with_wrap_angles=False)
        return -sign * float(geometry.lengths[cable]), -sign * geometry.jacobian[cable]

    signed = sign * on_grid
    best = float(signed.max())
    for k in np.argsort(-signed, kind="stable")[:TRAVEL_STARTS]:
        result = minimize(objective, grid[k], jac=True, method="L-BFGS-B", bounds=bounds)
        best = max(best, -float(result.fun))
    return sign * best


def _matrix(columns: dict[str, FloatArray], quantity: str, names: tuple[str, ...]) -> FloatArray:
    return np.stack([columns[f"{quantity}.{name}"] for name in names], axis=1)


def evaluate_run(
    model: RobotModel,
    columns: dict[str, FloatArray],
    home: FloatArray,
    target: FloatArray,
    drum_radius: float,
    min_tension: float,
    completed: bool = True,
) -> TrackingMetrics:
    """Compute the metrics of a run from its log columns.

    Args:
        model: The nominal robot model.
        columns: Log columns (``t``, ``q.*``, ``q_ref.*``, ``motor_angle.*``,
            ``tension_motor.*``).
        home: The task's start posture [rad], shape ``(n,)``.
        target: The task's final target posture [rad], shape ``(n,)``.
        drum_radius: Winch drum radius [m] (to turn motor angles into cable lengths).
        min_tension: Lower tension bound [N].
        completed: Whether the run reached its end.

    Returns:
        The metrics.
    """
    joints, cables = model.joint_names, model.cable_names
    q = _matrix(columns, "q", joints)
    q_ref = _matrix(columns, "q_ref", joints)
    p_final, p_target, p_start = hand_position(model, np.stack([q[-1], target, home]))
    error_m, percent = metrics.final_position_error(p_final, p_target, p_start)
    settle = metrics.settle_sample(columns["t"], q_ref, SETTLE_DELAY)
    settle_mm = (
        float("nan")
        if settle is None
        else 1000.0 * float(np.linalg.norm(hand_position(model, q[settle])[0] - p_target))
    )
    theory = cable_kinematics_batch(model, q, with_wrap_angles=False).lengths
    motor = _matrix(columns, "motor_angle", cables)
    valid = theory[0] - drum_radius * (motor - motor[0])
    _, length_percent = metrics.cable_length_error(valid, theory, cable_travel(model))
    tension = _matrix(columns, "tension_motor", cables)
    dt = float(np.median(np.diff(columns["t"]))) if len(columns["t"]) > 1 else 0.0
    upper = np.asarray(model.muscles.max_isometric_force, dtype=float)
    return TrackingMetrics(
        final_error_mm=1000.0 * float(error_m),
        final_error_percent=float(percent),
        settle_error_mm=settle_mm,
        joint_rmse=tuple(float(v) for v in metrics.joint_rmse(q, q_ref)),
        cable_length_error_percent=tuple(float(v) for v in length_percent),
        cable_length_end_percent=tuple(
            float(v) for v in metrics.cable_length_error_at_end(valid, theory)
        ),
        slack_events=tuple(int(v) for v in metrics.slack_events(tension, SLACK_THRESHOLD)),
        time_outside_bounds=tuple(
            float(v)
            for v in metrics.time_outside_bounds(
                tension,
                np.full(len(cables), min_tension - BOUND_TOLERANCE),
                upper + BOUND_TOLERANCE,
                dt,
            )
        ),
        completed=completed,
    )
