"""Forward kinematics of a cable robot from cable lengths, and the platform's own wrench.

Forward kinematics (paper 001, Sec. 4.2): given measured cable lengths ``l`` [m], shape
(m,), find the pose (r, R) whose inverse kinematics gives them. With ``m > 6`` cables the
lengths over-determine the pose, so the pose minimises the length residual
``e(r, R) = l(r, R) - l_measured`` in the least-squares sense, by Newton-Raphson (Gauss-Newton)
steps from a known start pose. Rotation increments are rotation vectors in K_0, ``R <-
exp([dtheta]x) R``, so the six unknowns of a step are ``(dr, dtheta)``; the length Jacobian
with respect to them is ``-A`` (``A^T`` is ``CableRobot.structure_matrix``: a platform twist
(v, omega) changes the lengths at the rate ``-A (v, omega)``). A step solves
``A (dr, dtheta) = e`` in the least-squares sense and is halved while it does not lower
``||e||``. Near the pose, for consistent lengths, the iteration converges quadratically;
from a start far from it (a rotated platform started at R = I) it can stop at a local
minimum of ``||e||`` whose residual, a few micrometres or more, looks like measurement
noise (on a robot of a user's own: 5 of 200 random poses about 0.05 rad from the start, up
to 0.17 rad off). Start from the last known pose, and pass ``max_residual`` (what the
lengths' accuracy allows) to have such an end refused.

The lengths determine the pose only where ``A`` (m x 6) has rank 6: at least six cables
whose lines are independent there. Where it has not (fewer than six cables, or a degenerate
geometry such as all platform anchors at one point, which leaves the rotation free), the
least-squares steps are minimum-norm ones and would end at an arbitrary pose with a zero
residual; :func:`forward_kinematics` refuses such a pose instead. ``A``'s rank counts its
singular values above :data:`RANK_RTOL` times the largest.

Platform wrench: the external wrench ``w`` of ``A^T f + w = 0`` produced by the platform's
own weight and inertia (Newton-Euler), force [N] and moment about the platform reference
point r [N m], both in K_0.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.cdpr.kinematics import CableRobot
from msarm.errors import InputError, MsarmError

FloatArray = NDArray[np.float64]

__all__ = [
    "RANK_RTOL",
    "STANDARD_GRAVITY",
    "ForwardKinematicsError",
    "ForwardKinematicsResult",
    "forward_kinematics",
    "matrix_from_quaternion",
    "platform_wrench",
    "quaternion_from_matrix",
    "rotation_angle_between",
    "rotation_matrix",
    "rotation_vector",
]

#: Gravity vector in K_0 [m/s^2] (z up), the default of MuJoCo and Pinocchio.
STANDARD_GRAVITY = np.array([0.0, 0.0, -9.81])
_MAX_HALVINGS = 30
#: Singular values of the length Jacobian A below this times its largest count as zero in
#: its rank [-]: there a length error of 1e-12 m would move the pose by about 1e-3 (m or rad).
RANK_RTOL = 1e-9


class ForwardKinematicsError(MsarmError, RuntimeError):
    """Forward kinematics failed: no convergence, or lengths that do not determine the pose.

    The message names the iterations, step and residual, or the rank of the length Jacobian.
    """


@dataclass(frozen=True)
class ForwardKinematicsResult:
    """A pose found by :func:`forward_kinematics`.

    Attributes:
        r: Platform position in K_0 [m], shape (3,).
        R: Platform rotation matrix (K_p in K_0), shape (3, 3).
        iterations: Newton-Raphson steps taken.
        residual: Largest length residual ``max_i |l_i(r, R) - l_i|`` at the pose [m]; about
            round-off for consistent lengths at the right pose, the measurement inconsistency
            otherwise, or a local minimum's residual (module docstring).
    """

    r: FloatArray
    R: FloatArray
    iterations: int
    residual: float


def _skew(v: FloatArray) -> FloatArray:
    """Cross-product matrices [v]x, shape (..., 3, 3), of vectors of shape (..., 3)."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rotation_matrix(rotvec: ArrayLike) -> FloatArray:
    """Rotation matrix of a rotation vector (Rodrigues' formula, the exponential map).

    Args:
        rotvec: Rotation vector theta * axis [rad], shape (3,) or (N, 3).

    Returns:
        ``exp([rotvec]x)``, shape (3, 3) or (N, 3, 3).

    Raises:
        InputError: On a wrong shape or non-finite values.
    """
    v = np.asarray(rotvec, dtype=np.float64)
    if v.shape[-1:] != (3,) or v.ndim > 2:
        raise InputError(f"rotvec must have shape (3,) or (N, 3) [rad], got {v.shape}")
    if not np.isfinite(v).all():
        raise InputError("rotvec must be finite [rad]")
    theta = np.linalg.norm(v, axis=-1)[..., None, None]
    K = _skew(v)
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    # Taylor series below 1e-4 rad: error below 1e-18, no 0/0.
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * K + b * (K @ K)


def rotation_vector(R: ArrayLike) -> FloatArray:
    """Rotation vector of a rotation matrix (the logarithm map), angle in [0, pi].

    Args:
        R: Rotation matrix, shape (3, 3).

    Returns:
        theta * axis [rad], shape (3,).

    Raises:
        InputError: If ``R`` is not a finite 3 x 3 rotation matrix.
    """
    # Quaternion (Shepperd's method) first, then the angle from atan2: accurate everywhere.
    q = quaternion_from_matrix(_rotation(R, "R"))
    s = np.linalg.norm(q[1:])
    if s == 0.0:
        return np.zeros(3)
    angle = 2.0 * np.arctan2(s, q[0])
    return q[1:] * (angle / s)


def rotation_angle_between(R1: ArrayLike, R2: ArrayLike) -> float:
    """Angle of the relative rotation ``R1 R2^T`` [rad], in [0, pi]."""
    return float(np.linalg.norm(rotation_vector(_rotation(R1, "R1") @ _rotation(R2, "R2").T)))


def quaternion_from_matrix(R: ArrayLike) -> FloatArray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix (Shepperd's method).

    Args:
        R: Rotation matrix, shape (3, 3) or (N, 3, 3).

    Returns:
        Scalar-first (MuJoCo order) unit quaternion, shape (4,) or (N, 4).

    Raises:
        InputError: If ``R`` is not a finite rotation matrix (or a batch of them).
    """
    R_arr = np.asarray(R, dtype=np.float64)
    if R_arr.ndim == 3:
        return np.array([quaternion_from_matrix(Ri) for Ri in R_arr]).reshape(-1, 4)
    R_arr = _rotation(R_arr, "R")
    trace = np.trace(R_arr)
    k = int(np.argmax([trace, *np.diag(R_arr)]))
    if k == 0:
        w = 0.5 * np.sqrt(1.0 + trace)
        vee = [R_arr[2, 1] - R_arr[1, 2], R_arr[0, 2] - R_arr[2, 0], R_arr[1, 0] - R_arr[0, 1]]
        q = np.array([w, *(np.array(vee) / (4.0 * w))])
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        big = 0.5 * np.sqrt(1.0 + R_arr[i, i] - R_arr[j, j] - R_arr[m, m])
        q = np.empty(4)
        q[0] = (R_arr[m, j] - R_arr[j, m]) / (4.0 * big)
        q[1 + i] = big
        q[1 + j] = (R_arr[j, i] + R_arr[i, j]) / (4.0 * big)
        q[1 + m] = (R_arr[m, i] + R_arr[i, m]) / (4.0 * big)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0.0 else q


def matrix_from_quaternion(quat: ArrayLike, *, name: str = "quat") -> FloatArray:
    """Rotation matrix of a unit quaternion (w, x, y, z) (scalar first, MuJoCo order).

    Args:
        quat: Quaternion(s), shape (4,) or (N, 4); the norm must be 1 to 1e-6 (it is then
            normalised to round-off).
        name: Name of the argument in error messages.

    Returns:
        Rotation matrix, shape (3, 3) or (N, 3, 3).

    Raises:
        InputError: On a wrong shape, non-finite values or a norm other than 1.
    """
    q = np.asarray(quat, dtype=np.float64)
    if q.ndim not in (1, 2) or q.shape[-1] != 4:
        raise InputError(f"{name} must have shape (4,) or (N, 4) (w, x, y, z), got {q.shape}")
    if not np.isfinite(q).all():
        raise InputError(f"{name} must be finite")
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(np.abs(norm - 1.0) > 1e-6):
        raise InputError(f"{name} must be a unit quaternion, got norm {norm.ravel()}")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def _rotation(R: ArrayLike, name: str) -> FloatArray:
    R_arr = np.asarray(R, dtype=np.float64)
    if R_arr.shape != (3, 3):
        raise InputError(f"{name} must have shape (3, 3), got {R_arr.shape}")
    if not np.isfinite(R_arr).all():
        raise InputError(f"{name} must be finite")
    orth = np.abs(R_arr @ R_arr.T - np.eye(3)).max()
    if orth > 1e-6 or np.linalg.det(R_arr) < 0.0:
        raise InputError(
            f"{name} must be a rotation matrix (orthonormal, det +1); |R R^T - I| = {orth:.3g}"
        )
    return R_arr


def _vector(value: ArrayLike, name: str, unit: str) -> FloatArray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,):
        raise InputError(f"{name} must have shape (3,) [{unit}], got {v.shape}")
    if not np.isfinite(v).all():
        raise InputError(f"{name} must be finite [{unit}], got {v}")
    return v


def forward_kinematics(
    robot: CableRobot,
    lengths: ArrayLike,
    r0: ArrayLike | None = None,
    R0: ArrayLike | None = None,
    *,
    tol: float = 1e-10,
    max_iter: int = 50,
    max_residual: float | None = None,
) -> ForwardKinematicsResult:
    """Platform pose from cable lengths by Newton-Raphson (paper 001, Sec. 4.2).

    Minimises ``||l(r, R) - lengths||`` over the pose, starting at (r0, R0); see the module
    docstring for the step. Converged when a full step is at most ``tol`` in every component
    (metres for dr, radians for dtheta); that step is still taken, so the pose error is far
    below ``tol`` for consistent lengths.

    Args:
        robot: The cable robot (anchors a_i in K_0, b_i in K_p).
        lengths: Cable lengths l_i [m], shape (m,), all > 0.
        r0: Start position in K_0 [m], shape (3,); the centroid of the frame anchors if None.
            Use the last known pose when tracking a moving platform.
        R0: Start rotation matrix, shape (3, 3); identity if None.
        tol: Step tolerance [m and rad], > 0.
        max_iter: Largest number of Newton-Raphson steps, >= 1.
        max_residual: Largest length residual [m] a pose is accepted with, > 0 (the
            lengths' accuracy); None: any (check the result's ``residual``).

    Returns:
        The pose, the number of steps and the largest length residual [m].

    Raises:
        InputError: On wrong shapes, NaN or infinite values, non-positive lengths, an invalid
            start pose, ``tol <= 0``, ``max_iter < 1`` or ``max_residual <= 0``.
        ForwardKinematicsError: When the iteration does not converge within ``max_iter``
            steps, stalls (no step length lowers the residual), or runs into a singular pose;
            when the robot has fewer than 6 cables, or the length Jacobian ``A`` has rank
            below 6 at the pose found (singular values below :data:`RANK_RTOL` times the
            largest count as zero): the lengths do not determine the pose there; when the
            pose found leaves a residual above ``max_residual``.
    """
    l_meas = np.asarray(lengths, dtype=np.float64)
    m = robot.n_cables
    if l_meas.shape != (m,):
        raise InputError(f"lengths must have shape ({m},) [m], one per cable, got {l_meas.shape}")
    if not np.isfinite(l_meas).all():
        raise InputError(f"lengths must be finite [m], got {l_meas}")
    if np.any(l_meas <= 0.0):
        raise InputError(f"lengths must be > 0 [m], got {l_meas}")
    if not (np.isfinite(tol) and tol > 0.0):
        raise InputError(f"tol must be a finite number > 0 [m, rad], got {tol}")
    if int(max_iter) != max_iter or max_iter < 1:
        raise InputError(f"max_iter must be an integer >= 1, got {max_iter}")
    if max_residual is not None and (
        isinstance(max_residual, bool)
        or not isinstance(max_residual, numbers.Real)  # as io.config.check_numbers
        or not (math.isfinite(max_residual) and max_residual > 0.0)
    ):
        raise InputError(
            f"max_residual must be a finite number > 0 [m] or None, got {max_residual}"
        )
    r = robot.frame_anchors.mean(axis=0) if r0 is None else _vector(r0, "r0", "m")
    R = np.eye(3) if R0 is None else _rotation(R0, "R0")
    if m < 6:
        raise ForwardKinematicsError(
            f"forward kinematics: the lengths of {m} cables do not determine the 6-DOF pose "
            f"(the length Jacobian has rank at most {m}); it needs at least 6 independent cables"
        )

    def residual(r_: FloatArray, R_: FloatArray) -> tuple[FloatArray, FloatArray]:
        try:
            kin = robot.inverse_kinematics(r_, R_)
        except InputError as exc:  # a cable of zero length: the pose is singular
            raise ForwardKinematicsError(
                f"forward kinematics hit a singular pose r={r_} ({exc})"
            ) from exc
        u = kin.unit_vectors  # A = (A^T)^T, rows [u_i, (R b_i) x u_i], shape (m, 6)
        return kin.lengths - l_meas, np.hstack([u, np.cross(kin.platform_anchors_world, u)])

    e, A = residual(r, R)
    cost = float(e @ e)
    step_norm = np.inf
    for iteration in range(1, int(max_iter) + 1):
        delta, *_ = np.linalg.lstsq(A, e, rcond=None)
        if not np.isfinite(delta).all():
            raise ForwardKinematicsError(
                f"forward kinematics: non-finite Newton step at iteration {iteration} (r={r})"
            )
        step_norm = float(np.abs(delta).max())
        if step_norm <= tol:
            r, R = r + delta[:3], rotation_matrix(delta[3:]) @ R
            e, A = residual(r, R)
            _check_rank(A, r)
            largest = float(np.abs(e).max())
            if max_residual is not None and largest > max_residual:
                raise ForwardKinematicsError(
                    f"forward kinematics converged to r={r} with a largest length residual of "
                    f"{largest:.3g} m, more than max_residual {max_residual:.3g} m: a local "
                    "minimum (start closer to the pose, r0 and R0: the last known pose) or "
                    "lengths no pose has"
                )
            return ForwardKinematicsResult(r, R, iteration, largest)
        t = 1.0
        for _ in range(_MAX_HALVINGS):
            r_try, R_try = r + t * delta[:3], rotation_matrix(t * delta[3:]) @ R
            e_try, A_try = residual(r_try, R_try)
            cost_try = float(e_try @ e_try)
            if cost_try <= cost:
                break
            t *= 0.5
        else:
            raise ForwardKinematicsError(
                f"forward kinematics stalled at iteration {iteration}: no step along the "
                f"Newton direction (|step| = {step_norm:.3g}) lowers the length residual "
                f"{np.sqrt(cost):.3g} m at r={r}; the lengths may be unreachable or inconsistent"
            )
        r, R, e, A, cost = r_try, R_try, e_try, A_try, cost_try
    raise ForwardKinematicsError(
        f"forward kinematics did not converge in {max_iter} iterations: last step "
        f"{step_norm:.3g} (tol {tol:.3g}), largest length residual {np.abs(e).max():.3g} m at "
        f"r={r}; start closer to the pose (r0, R0) or raise max_iter, or the lengths may be "
        "unreachable or inconsistent (no pose has them)"
    )


def _check_rank(A: FloatArray, r: FloatArray) -> None:
    """Refuse a pose where the length Jacobian A (m, 6) has rank below 6 (see RANK_RTOL)."""
    s = np.linalg.svd(A, compute_uv=False)
    rank = int(np.count_nonzero(s > RANK_RTOL * s[0]))
    if rank < 6:
        raise ForwardKinematicsError(
            "forward kinematics: the cable lengths do not determine the pose at "
            f"r={np.array2string(r, precision=4, suppress_small=True)}: the length Jacobian "
            f"has rank {rank} < 6 "
            f"(singular values {np.array2string(s, precision=3)}; below {RANK_RTOL:g} times "
            "the largest count as zero), so fewer than 6 cables are independent there: a "
            "degenerate geometry (e.g. all platform anchors at one point leave the rotation "
            "free)"
        )


def _broadcast_vectors(name: str, value: ArrayLike | None, unit: str) -> FloatArray:
    v = np.zeros(3) if value is None else np.asarray(value, dtype=np.float64)
    if v.ndim not in (1, 2) or v.shape[-1] != 3:
        raise InputError(f"{name} must have shape (3,) or (N, 3) [{unit}], got {v.shape}")
    if not np.isfinite(v).all():
        raise InputError(f"{name} must be finite [{unit}]")
    return v


def platform_wrench(
    r: ArrayLike,
    R: ArrayLike,
    v: ArrayLike | None = None,
    omega: ArrayLike | None = None,
    a: ArrayLike | None = None,
    alpha: ArrayLike | None = None,
    *,
    mass: float,
    inertia: ArrayLike,
    gravity: ArrayLike = STANDARD_GRAVITY,
    com: ArrayLike | None = None,
) -> FloatArray:
    """External wrench of the platform's weight and inertia (Newton-Euler), as in A^T f + w = 0.

    With ``c = R com`` (the centre of mass relative to r, in K_0), the CoM acceleration
    ``a_c = a + alpha x c + omega x (omega x c)`` and ``I = R I_c R^T``::

        force  = mass (gravity - a_c)
        moment = c x force - (I alpha + omega x I omega)      (about r, in K_0)

    so that the cables must supply ``A^T f = -w``. At rest this is the weight (with zero
    moment when r is the centre of mass). The value of r does not enter: the moment is taken
    about r, and the CoM's offset from it is ``c = R com``.

    Args:
        r: Platform reference point (origin of K_p) in K_0 [m], shape (3,) or (N, 3); only its
            shape is used (the moment is taken about it).
        R: Platform rotation matrix, shape (3, 3) or (N, 3, 3).
        v: Velocity of r in K_0 [m/s], shape (3,) or (N, 3); zero if None (it does not enter
            the wrench; accepted for symmetry with the trajectory samples).
        omega: Angular velocity in K_0 [rad/s], shape (3,) or (N, 3); zero if None.
        a: Acceleration of r in K_0 [m/s^2], shape (3,) or (N, 3); zero if None.
        alpha: Angular acceleration in K_0 [rad/s^2], shape (3,) or (N, 3); zero if None.
        mass: Platform mass [kg], > 0.
        inertia: Inertia tensor about the centre of mass in K_p [kg m^2], shape (3, 3),
            symmetric.
        gravity: Gravity in K_0 [m/s^2], shape (3,).
        com: Centre of mass in K_p [m], shape (3,); the origin of K_p (r) if None.

    Returns:
        w = (force [N], moment about r [N m]) in K_0, shape (6,) or (N, 6).

    Raises:
        InputError: On wrong shapes, NaN or infinite values, ``mass <= 0`` or an asymmetric
            inertia tensor.
    """
    r_arr = _broadcast_vectors("r", r, "m")
    R_arr = np.asarray(R, dtype=np.float64)
    if R_arr.shape[-2:] != (3, 3) or R_arr.ndim not in (2, 3) or not np.isfinite(R_arr).all():
        raise InputError(f"R must be finite with shape (3, 3) or (N, 3, 3), got {R_arr.shape}")
    vecs = [
        _broadcast_vectors(name, value, unit)
        for name, value, unit in (
            ("v", v, "m/s"),
            ("omega", omega, "rad/s"),
            ("a", a, "m/s^2"),
            ("alpha", alpha, "rad/s^2"),
        )
    ]
    if not (np.isfinite(mass) and mass > 0.0):
        raise InputError(f"mass must be a finite number > 0 [kg], got {mass}")
    I_c = np.asarray(inertia, dtype=np.float64)
    if I_c.shape != (3, 3) or not np.isfinite(I_c).all():
        raise InputError(f"inertia must be a finite (3, 3) tensor [kg m^2], got {I_c.shape}")
    if np.abs(I_c - I_c.T).max() > 1e-12 * max(1.0, np.abs(I_c).max()):
        raise InputError("inertia must be symmetric [kg m^2]")
    g = _vector(gravity, "gravity", "m/s^2")
    c_p = np.zeros(3) if com is None else _vector(com, "com", "m")
    batch = {x.shape[0] for x in (r_arr, *vecs) if x.ndim == 2}
    if R_arr.ndim == 3:
        batch.add(R_arr.shape[0])
    if len(batch) > 1:
        raise InputError(f"batched inputs must share one length N, got lengths {sorted(batch)}")
    _, omega_w, a_w, alpha_w = vecs
    c = np.einsum("...ij,j->...i", R_arr, c_p)
    I_w = R_arr @ I_c @ np.swapaxes(R_arr, -1, -2)
    a_c = a_w + np.cross(alpha_w, c) + np.cross(omega_w, np.cross(omega_w, c))
    force = mass * (g - a_c)
    I_alpha = np.einsum("...ij,...j->...i", I_w, alpha_w)
    I_omega = np.einsum("...ij,...j->...i", I_w, omega_w)
    moment = np.cross(c, force) - I_alpha - np.cross(omega_w, I_omega)
    force, moment = np.broadcast_arrays(force, moment)
    w = np.concatenate([force, moment], axis=-1)
    if batch and w.ndim == 1:
        w = np.broadcast_to(w, (batch.pop(), 6))
    return np.array(w, dtype=np.float64)
