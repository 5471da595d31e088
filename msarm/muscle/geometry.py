"""Muscle geometry: cable lengths l(q), the muscle Jacobian J_c(q) and cable wrap angles.

Conventions (used throughout msarm):

- ``l(q)`` [m], shape ``(m,)``: the length of each cable's path as MuJoCo's spatial tendon
  computes it, from the motor's exit in the chest through the sheath waypoints to the
  insertion (wrapping included).
- ``J_c(q) = dl/dq``, shape ``(m, n)``: the muscle Jacobian of paper 003 eq. 2-3, so that the
  cable velocities are ``ldot = J_c qdot`` (eq. 3).
- Cable tension ``f >= 0`` pulls. The joint torque of cable forces is ``tau = -J_c^T f``: a
  cable that shortens as a joint turns (``dl/dq < 0``) pulls that joint forwards. (Paper 003
  eq. 2 writes ``tau = J_c f`` with the paper's own sign of ``dl``; the virtual work of a
  pulling cable, ``tau . dq = -f . dl``, fixes the sign used here.)
- Wrap angle ``Theta(q)`` [rad], shape ``(m,)``: the total angle through which each cable's
  path turns, the sum of the turning angles at its waypoints (and around wrapping geoms),
  which is what the capstan friction ``exp(-mu Theta)`` of a sheath depends on.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from itertools import product
from typing import TYPE_CHECKING

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linprog

from msarm.errors import InputError

if TYPE_CHECKING:
    from msarm.model import RobotData, RobotModel

__all__ = [
    "CableGeometry",
    "cable_geometry",
    "cable_kinematics",
    "joint_grid",
    "path_points",
    "positive_spanning_margin",
    "wrap_angles",
]

#: The MuJoCo wrap object id that marks a pulley (a split of the path into branches).
_PULLEY = -2


@dataclass(frozen=True)
class CableGeometry:
    """Cable geometry at one state.

    Attributes:
        q: Joint coordinates [rad], shape ``(n,)``.
        lengths: Cable path lengths l(q) [m], shape ``(m,)``.
        velocities: Cable velocities ``J_c qdot`` [m/s], shape ``(m,)``.
        jacobian: Muscle Jacobian ``J_c = dl/dq`` [m/rad], shape ``(m, n)``.
        wrap_angles: Total turning angle of each cable's path [rad], shape ``(m,)``.
    """

    q: NDArray[np.float64]
    lengths: NDArray[np.float64]
    velocities: NDArray[np.float64]
    jacobian: NDArray[np.float64]
    wrap_angles: NDArray[np.float64]

    @property
    def moment_arms(self) -> NDArray[np.float64]:
        """Joint torque per newton of each cable, ``-J_c`` [m], shape ``(m, n)``."""
        return -self.jacobian

    def joint_torque(self, forces: ArrayLike) -> NDArray[np.float64]:
        """Joint torque ``tau = -J_c^T f`` [N m] of cable forces ``f`` [N], shape ``(m,)``.

        Raises:
            InputError: ``forces`` is not a finite ``(m,)`` array.
        """
        return -self.jacobian.T @ _checked_vector(forces, self.jacobian.shape[0], "forces", "N")


def _checked_vector(
    value: ArrayLike | None, size: int, name: str, unit: str
) -> NDArray[np.float64]:
    if value is None:
        return np.zeros(size)
    if np.iscomplexobj(value):  # numpy would drop the imaginary part with a mere warning
        raise InputError(
            f"{name} must be real numbers; got complex values, whose imaginary part would be lost"
        )
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(
            f"{name} must be an array of real numbers [{unit}], got {value!r}"
        ) from None
    if array.shape != (size,):
        raise InputError(f"{name} must have shape ({size},), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise InputError(f"{name} must be finite, got {array}")
    return array


def cable_geometry(
    model: RobotModel,
    data: RobotData,
    q: ArrayLike,
    qdot: ArrayLike | None = None,
    with_wrap_angles: bool = True,
) -> CableGeometry:
    """Compute l(q), J_c(q), the cable velocities and the wrap angles with MuJoCo.

    Runs MuJoCo's kinematics, ``mj_comPos`` and ``mj_tendon`` on ``data`` (it overwrites the
    position and velocity there).

    Args:
        model: The robot.
        data: A work space of ``model``.
        q: Joint coordinates [rad], shape ``(n,)``; not checked against the joint range (the
            full-rank and positive-spanning guarantees hold only inside it: see
            :meth:`msarm.model.RobotModel.geometry`).
        qdot: Joint velocities [rad/s], shape ``(n,)``; zero if omitted.
        with_wrap_angles: Compute the wrap angles (NaN if False: a controller needs none).

    Returns:
        The cable geometry at ``(q, qdot)``.
    """
    n = model.n_joints
    if q is None:
        raise InputError(f"q must be joint coordinates of shape ({n},), got None")
    q = _checked_vector(q, n, "q", "rad")
    qdot = _checked_vector(qdot, n, "qdot", "rad/s")
    m_model, m_data = model.mj_model, data.mj
    m_data.qvel[:] = qdot
    jacobian = np.zeros((m_model.ntendon, m_model.nv))
    lengths = cable_kinematics(m_model, m_data, q, jacobian)
    return CableGeometry(
        q=q.copy(),
        lengths=lengths,
        velocities=jacobian @ qdot,
        jacobian=jacobian,
        wrap_angles=(
            wrap_angles(m_model, m_data) if with_wrap_angles else np.full(m_model.ntendon, np.nan)
        ),
    )


def cable_kinematics(
    m_model: mujoco.MjModel,
    m_data: mujoco.MjData,
    q: NDArray[np.float64],
    jacobian: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Cable lengths and dense muscle Jacobian at posture ``q``, without validation.

    The hot path shared by :func:`cable_geometry`, the controller and the compensator's
    features: MuJoCo's ``mj_kinematics``, ``mj_comPos`` and ``mj_tendon`` on ``m_data``, then
    the sparse tendon Jacobian densified into ``jacobian``.

    Args:
        m_model: MuJoCo model.
        m_data: MuJoCo data (its ``qpos`` is overwritten).
        q: Joint coordinates [rad], shape ``(n,)``.
        jacobian: Output ``J_c = dl/dq`` [m/rad], shape ``(m, n)``, written in place.

    Returns:
        The cable lengths l(q) [m], shape ``(m,)`` (a copy).
    """
    m_data.qpos[:] = q
    mujoco.mj_kinematics(m_model, m_data)
    mujoco.mj_comPos(m_model, m_data)
    mujoco.mj_tendon(m_model, m_data)
    mujoco.mju_sparse2dense(
        jacobian, m_data.ten_J, m_model.ten_J_rownnz, m_model.ten_J_rowadr, m_model.ten_J_colind
    )
    return m_data.ten_length.copy()


def path_points(m_model: mujoco.MjModel, m_data: mujoco.MjData, cable: int) -> list[NDArray]:
    """Return the branches of a cable's current path as arrays of points [m].

    The path is what ``mj_tendon`` last computed: site positions and the tangent points on
    wrapping geoms, split into separate branches at pulleys.

    Args:
        m_model: MuJoCo model.
        m_data: MuJoCo data after ``mj_tendon``.
        cable: Tendon index.

    Returns:
        A list of arrays of shape ``(k, 3)``, one per branch.
    """
    start, count = int(m_data.ten_wrapadr[cable]), int(m_data.ten_wrapnum[cable])
    points = m_data.wrap_xpos.reshape(-1, 3)[start : start + count]
    objects = m_data.wrap_obj.reshape(-1)[start : start + count]
    branches, current = [], []
    for point, obj in zip(points, objects, strict=True):
        if obj == _PULLEY:
            if current:
                branches.append(np.array(current))
            current = []
            continue
        current.append(point.copy())
    if current:
        branches.append(np.array(current))
    return branches


def wrap_angles(m_model: mujoco.MjModel, m_data: mujoco.MjData) -> NDArray[np.float64]:
    """Total turning angle of every cable's path [rad], shape ``(m,)``.

    The sum over the interior points of each path of the angle between the incoming and the
    outgoing segment (a segment of zero length, two sites at one point, is passed over).
    Around a wrapping geom the path holds the two tangent points, joined here by their
    chord: the two turns at the tangent points add up to the arc angle exactly for a
    circular arc (a cylinder wrapped square to its axis) and approximately otherwise.
    Pulleys split a path into branches; no turn is counted across a pulley.

    Args:
        m_model: MuJoCo model.
        m_data: MuJoCo data after ``mj_tendon``.
    """
    count = int(m_data.ten_wrapadr[-1] + m_data.ten_wrapnum[-1])
    points = m_data.wrap_xpos.reshape(-1, 3)[:count]
    objects = m_data.wrap_obj.reshape(-1)[:count]
    owner = np.repeat(np.arange(m_model.ntendon), m_data.ten_wrapnum)
    segments = np.diff(points, axis=0)
    # a segment joins two points of the same branch: same tendon, neither end a pulley
    in_branch = (owner[1:] == owner[:-1]) & (objects[1:] != _PULLEY) & (objects[:-1] != _PULLEY)
    norms = np.linalg.norm(segments, axis=1)
    # a segment of zero length (two sites at one point) has no direction: the turn there is
    # taken between the segments before and after it
    kept = np.flatnonzero(in_branch & (norms > 1e-12))
    unit = segments[kept] / norms[kept, None]
    breaks = np.cumsum(~in_branch)  # segments up to each one that leave a branch
    same_branch = breaks[kept[1:]] == breaks[kept[:-1]]
    cosines = np.clip(np.einsum("ij,ij->i", unit[:-1], unit[1:]), -1.0, 1.0)
    turns = np.where(same_branch, np.arccos(cosines), 0.0)
    return np.bincount(owner[kept[:-1]], weights=turns, minlength=m_model.ntendon)


def joint_grid(
    lower: ArrayLike, upper: ArrayLike, points_per_joint: int | ArrayLike
) -> Iterator[NDArray[np.float64]]:
    """Iterate over the postures of a regular grid over the joint range, limits included.

    The arguments are checked when this is called, before the first posture.

    Args:
        lower: Lower joint limits, shape ``(n,)``, finite.
        upper: Upper joint limits, shape ``(n,)``, finite, each >= its lower limit.
        points_per_joint: Grid points along each joint, whole numbers >= 1 (one number or
            one per joint).

    Returns:
        An iterator over postures of shape ``(n,)``, ``prod(points_per_joint)`` of them.

    Raises:
        InputError: On limits that are not finite ``(n,)`` arrays of the same shape, a lower
            limit above its upper one, or a count that is not a whole number >= 1.
    """
    low = np.asarray(lower, dtype=float)
    high = np.asarray(upper, dtype=float)
    if low.ndim != 1 or high.shape != low.shape:
        raise InputError(
            f"lower and upper must be joint limits of one shape (n,); got {low.shape} and "
            f"{high.shape}"
        )
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        raise InputError(f"joint limits must be finite; got lower={low}, upper={high}")
    if np.any(low > high):
        raise InputError(f"every lower limit must be <= its upper limit; got {low} and {high}")
    given = np.asarray(points_per_joint)
    try:
        counts = np.broadcast_to(given, low.shape)
    except ValueError as exc:
        raise InputError(
            f"points_per_joint must be one count or one per joint ({low.shape[0]}); got "
            f"{points_per_joint!r}"
        ) from exc
    whole = counts.dtype.kind in "iu" or (
        counts.dtype.kind == "f"
        and np.all(np.isfinite(counts))
        and np.all(counts == np.round(counts))
    )
    if not whole or np.any(counts < 1):
        raise InputError(f"points_per_joint must be whole numbers >= 1; got {points_per_joint!r}")
    axes = [np.linspace(lo, hi, int(c)) for lo, hi, c in zip(low, high, counts, strict=True)]
    return (np.array(posture) for posture in product(*axes))


def positive_spanning_margin(jacobian: ArrayLike) -> float:
    """How well non-negative cable forces span every joint-torque direction.

    Solves the linear programme ``max t`` subject to ``J_c^T f = 0``, ``sum f = 1``,
    ``f_i >= t``. The torques ``-J_c^T f`` with ``f >= 0`` cover all of R^n exactly when
    ``J_c`` has full column rank and a strictly positive ``f`` balances (``t > 0``): then any
    torque can be produced while every cable stays taut. Returns ``t`` (the smallest share of
    the cable forces in the most even balancing force set), or ``-inf`` when no balancing
    non-negative force set exists; zero or less means some direction cannot be produced.

    Args:
        jacobian: Muscle Jacobian ``J_c``, shape ``(m, n)``.
    """
    jacobian = np.asarray(jacobian, dtype=float)
    if jacobian.ndim != 2 or not np.all(np.isfinite(jacobian)):
        raise InputError(f"jacobian must be a finite (m, n) matrix, got shape {jacobian.shape}")
    m, n = jacobian.shape
    if np.linalg.matrix_rank(jacobian) < n:
        return -np.inf
    cost = np.zeros(m + 1)
    cost[-1] = -1.0
    a_eq = np.zeros((n + 1, m + 1))
    a_eq[:n, :m] = jacobian.T
    a_eq[n, :m] = 1.0
    b_eq = np.zeros(n + 1)
    b_eq[n] = 1.0
    a_ub = np.hstack([-np.eye(m), np.ones((m, 1))])
    result = linprog(
        cost,
        A_ub=a_ub,
        b_ub=np.zeros(m),
        A_eq=a_eq,
        b_eq=b_eq,
        bounds=[(0, None)] * m + [(None, None)],
        method="highs",
    )
    return float(result.x[-1]) if result.status == 0 else -np.inf
