"""Load a cable-driven parallel robot (CDPR): one MJCF file, two engines, one geometry.

:func:`load_cable_robot` reads an MJCF file (``models/ipanema_mini.xml`` by default) into
MuJoCo (the plant) and Pinocchio (the nominal model), builds the :class:`CableRobot` geometry
from the file's sites, reads the platform's mass and inertia and the cable force bounds, and
checks that all of them describe one mechanism.

The file's layout: the platform is the only root body of ``<worldbody>`` and has one free
joint (MuJoCo allows free joints only in children of the world, Pinocchio's parser reads only
the first root body); each cable is a ``<spatial>`` tendon between a site fixed in the world
(the frame anchor a_i, K_0) and a site of the platform body (the platform anchor b_i, K_p);
``<custom>`` holds ``cable_force_bounds`` (f_min f_max [N]) and optionally ``workspace_box``
(x_min y_min z_min x_max y_max z_max [m]).

Coordinates of the free joint (both engines have nq = 7, nv = 6)::

    MuJoCo     qpos = [r, qw, qx, qy, qz]    qvel = [v (in K_0), omega_p (in K_p)]
    Pinocchio  q    = [r, qx, qy, qz, qw]    v    = [R^T v (in K_p), omega_p (in K_p)]

with r the platform origin in K_0, v its velocity and omega_p the angular velocity in K_p
(``omega = R omega_p`` in K_0). So ``qvel = T v_pin`` with ``T = diag(R, I_3)``, and the
engines' dynamics relate by ``M_pin = T^T M_mj T`` and
``nle_pin = T^T (qfrc_bias_mj + M_mj dT/dt v_pin)``, ``dT/dt v_pin = (R (omega_p x R^T v), 0)``
(the mass matrices coincide when the centre of mass is the body origin, the bias forces do
not: Pinocchio's linear rows are in K_p). Pinocchio's parser ignores ``<option gravity>``;
the loader copies MuJoCo's gravity into the Pinocchio model.

Wrench feasibility: a pose is feasible when cable forces within the file's bounds hold the
platform, ``A^T f + w = 0`` (``msarm.allocation.is_wrench_feasible``), where ``w`` is by
default the platform's own wrench (weight, and inertia when the motion is given).
:meth:`CableRobotModel.first_infeasible` finds the first infeasible sample of a trajectory and
:meth:`CableRobotModel.check_trajectory` refuses one, naming it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pinocchio
from numpy.typing import ArrayLike, NDArray

from msarm.allocation.problem import tension_bounds
from msarm.allocation.workspace import feasibility_batch, is_wrench_feasible
from msarm.cdpr.forward_kinematics import (
    ForwardKinematicsResult,
    forward_kinematics,
    matrix_from_quaternion,
    platform_wrench,
    quaternion_from_matrix,
    rotation_matrix,
)
from msarm.cdpr.kinematics import CableRobot
from msarm.errors import InputError, ModelError
from msarm.model import (
    MODELS_DIR,
    RobotData,
    check_no_passive_forces,
    model_gravity,
    model_sha256,
    mujoco_model_name,
)

FloatArray = NDArray[np.float64]

__all__ = [
    "IPANEMA_MINI_PATH",
    "CableRobotModel",
    "load_cable_robot",
    "pin_q_from_qpos",
    "pin_v_from_qvel",
    "pose_from_qpos",
    "qpos_from_pin_q",
    "qpos_from_pose",
    "qvel_from_pin_v",
    "qvel_from_twist",
    "twist_from_qvel",
    "velocity_map",
]

#: The IPAnema-3-Mini-like 8-cable robot shipped with msarm.
IPANEMA_MINI_PATH = MODELS_DIR / "ipanema_mini.xml"
#: Largest allowed disagreement between engines or geometry at load [m, kg, N, N m].
_ENGINE_TOLERANCE = 1e-9
#: Offset of the load-time test pose from the home pose [m] and its rotation vector [rad].
_TEST_OFFSET = np.array([0.021, -0.013, 0.017])
_TEST_ROTVEC = np.array([0.11, -0.23, 0.17])
_TEST_TWIST = np.array([0.3, -0.2, 0.1, 0.7, -0.4, 0.9])  # qvel: v in K_0, omega_p in K_p


# --------------------------------------------------------------------------- coordinates


def _qpos_array(qpos: ArrayLike, name: str = "qpos") -> FloatArray:
    x = np.asarray(qpos, dtype=np.float64)
    if x.ndim not in (1, 2) or x.shape[-1] != 7:
        raise InputError(f"{name} must have shape (7,) or (N, 7), got {x.shape}")
    if not np.isfinite(x).all():
        raise InputError(f"{name} must be finite")
    return x


def _vec_array(value: ArrayLike, name: str, size: int, unit: str) -> FloatArray:
    x = np.asarray(value, dtype=np.float64)
    if x.ndim not in (1, 2) or x.shape[-1] != size:
        raise InputError(f"{name} must have shape ({size},) or (N, {size}) [{unit}], got {x.shape}")
    if not np.isfinite(x).all():
        raise InputError(f"{name} must be finite [{unit}]")
    return x


def qpos_from_pose(r: ArrayLike, R: ArrayLike) -> FloatArray:
    """MuJoCo free-joint coordinates of a pose.

    Args:
        r: Platform position in K_0 [m], shape (3,) or (N, 3).
        R: Platform rotation matrix, shape (3, 3) (shared by N positions) or (N, 3, 3).

    Returns:
        qpos = [r, qw, qx, qy, qz] (quaternion with qw >= 0), shape (7,) or (N, 7).

    Raises:
        InputError: On wrong shapes, non-finite values or a non-rotation ``R``.
    """
    r_arr = _vec_array(r, "r", 3, "m")
    quat = quaternion_from_matrix(R)
    if r_arr.ndim == 2 and quat.ndim == 1:
        quat = np.broadcast_to(quat, (len(r_arr), 4))
    if quat.shape[:-1] != r_arr.shape[:-1]:
        raise InputError(f"r {r_arr.shape} and R {np.shape(R)} must be one pose or N poses")
    return np.concatenate([r_arr, quat], axis=-1)


def pose_from_qpos(qpos: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Pose (r [m], R) of MuJoCo free-joint coordinates, shapes (3,), (3, 3) or batched."""
    x = _qpos_array(qpos)
    return x[..., :3].copy(), matrix_from_quaternion(x[..., 3:], name="qpos[3:7]")


def pin_q_from_qpos(qpos: ArrayLike) -> FloatArray:
    """Pinocchio q = [r, qx, qy, qz, qw] of MuJoCo qpos = [r, qw, qx, qy, qz], shape (..., 7)."""
    x = _qpos_array(qpos)
    return x[..., [0, 1, 2, 4, 5, 6, 3]].copy()


def qpos_from_pin_q(q: ArrayLike) -> FloatArray:
    """MuJoCo qpos = [r, qw, qx, qy, qz] of Pinocchio q = [r, qx, qy, qz, qw], shape (..., 7)."""
    x = _qpos_array(q, "q")
    return x[..., [0, 1, 2, 6, 3, 4, 5]].copy()


def velocity_map(R: ArrayLike) -> FloatArray:
    """T = diag(R, I_3) with ``qvel_mj = T v_pin`` at rotation R, shape (6, 6) or (N, 6, 6)."""
    R_arr = np.asarray(R, dtype=np.float64)
    T = np.zeros((*R_arr.shape[:-2], 6, 6))
    T[..., :3, :3] = R_arr
    T[..., 3:, 3:] = np.eye(3)
    return T


def pin_v_from_qvel(qpos: ArrayLike, qvel: ArrayLike) -> FloatArray:
    """Pinocchio v = [R^T v, omega_p] of MuJoCo qvel = [v, omega_p], shape (6,) or (N, 6)."""
    _, R = pose_from_qpos(qpos)
    x = _vec_array(qvel, "qvel", 6, "m/s, rad/s")
    lin = np.einsum("...ji,...j->...i", R, x[..., :3])
    return np.concatenate([lin, np.broadcast_to(x[..., 3:], lin.shape)], axis=-1)


def qvel_from_pin_v(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """MuJoCo qvel = [R v_p, omega_p] of Pinocchio q and v = [v_p, omega_p], (6,) or (N, 6)."""
    _, R = pose_from_qpos(qpos_from_pin_q(q))
    x = _vec_array(v, "v", 6, "m/s, rad/s")
    lin = np.einsum("...ij,...j->...i", R, x[..., :3])
    return np.concatenate([lin, np.broadcast_to(x[..., 3:], lin.shape)], axis=-1)


def twist_from_qvel(qpos: ArrayLike, qvel: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Platform twist in K_0: (v [m/s], omega = R omega_p [rad/s]) of MuJoCo qpos and qvel."""
    _, R = pose_from_qpos(qpos)
    x = _vec_array(qvel, "qvel", 6, "m/s, rad/s")
    return x[..., :3].copy(), np.einsum("...ij,...j->...i", R, x[..., 3:])


def qvel_from_twist(qpos: ArrayLike, v: ArrayLike, omega: ArrayLike) -> FloatArray:
    """MuJoCo qvel = [v, R^T omega] of a twist in K_0 (v [m/s], omega [rad/s]) at qpos."""
    _, R = pose_from_qpos(qpos)
    v_arr = _vec_array(v, "v", 3, "m/s")
    w_arr = _vec_array(omega, "omega", 3, "rad/s")
    w_p = np.einsum("...ji,...j->...i", R, w_arr)
    v_arr, w_p = np.broadcast_arrays(v_arr, w_p)
    return np.concatenate([v_arr, w_p], axis=-1)


# --------------------------------------------------------------------------- the model


@dataclass(frozen=True)
class CableRobotModel:
    """A cable robot loaded from one MJCF file into MuJoCo, Pinocchio and a CableRobot.

    Attributes:
        path: The MJCF file.
        sha256: SHA-256 of the file's bytes (hex).
        mj_model: The MuJoCo model (nq 7, nv 6; tendons = cables).
        pin_model: The Pinocchio model of the same file (one free-flyer joint), with MuJoCo's
            gravity.
        robot: Cable geometry: frame anchors a_i in K_0 and platform anchors b_i in K_p [m],
            shape (m, 3) each, in cable order.
        cable_names: Names of the cables (MuJoCo tendons) in file order, shape (m,).
        frame_site_names: Site of a_i of every cable, shape (m,).
        platform_site_names: Site of b_i of every cable, shape (m,).
        platform_body: Name of the platform body (its frame is K_p).
        mass: Platform mass [kg].
        com: Centre of mass in K_p [m], shape (3,).
        inertia: Inertia tensor about the centre of mass in K_p [kg m^2], shape (3, 3).
        gravity: Gravity in K_0 [m/s^2], shape (3,).
        f_min: Lower cable force bound [N], shape (m,).
        f_max: Upper cable force bound [N], shape (m,).
        workspace_lower: Lower corner of the file's ``workspace_box`` [m], shape (3,), or
            None when the file has none.
        workspace_upper: Upper corner of the ``workspace_box`` [m], shape (3,), or None.
        home_qpos: MuJoCo qpos of the platform's pose in the file, shape (7,).
    """

    path: Path
    sha256: str
    mj_model: mujoco.MjModel
    pin_model: pinocchio.Model
    robot: CableRobot
    cable_names: tuple[str, ...]
    frame_site_names: tuple[str, ...]
    platform_site_names: tuple[str, ...]
    platform_body: str
    mass: float
    com: FloatArray
    inertia: FloatArray
    gravity: FloatArray
    f_min: FloatArray
    f_max: FloatArray
    workspace_lower: FloatArray | None
    workspace_upper: FloatArray | None
    home_qpos: FloatArray

    @property
    def name(self) -> str:
        """The model's name (the ``model`` attribute of ``<mujoco>``)."""
        return mujoco_model_name(self.mj_model)

    @property
    def n_cables(self) -> int:
        """Number of cables m."""
        return len(self.cable_names)

    @property
    def home_pose(self) -> tuple[FloatArray, FloatArray]:
        """The platform's pose in the file (r [m], R), shapes (3,), (3, 3)."""
        return pose_from_qpos(self.home_qpos)

    @property
    def workspace_center(self) -> FloatArray:
        """Centre of the workspace box [m], shape (3,) (the home position without a box)."""
        if self.workspace_lower is None or self.workspace_upper is None:
            return self.home_qpos[:3].copy()
        return 0.5 * (self.workspace_lower + self.workspace_upper)

    def create_data(self) -> RobotData:
        """Return a fresh work space (MuJoCo and Pinocchio data) for this model."""
        return RobotData(mj=mujoco.MjData(self.mj_model), pin=self.pin_model.createData())

    def cable_lengths(self, r: ArrayLike, R: ArrayLike) -> FloatArray:
        """Cable lengths [m] at a pose (or N poses), shape (m,) or (N, m)."""
        return self.robot.cable_lengths(r, R)

    def forward_kinematics(
        self,
        lengths: ArrayLike,
        r0: ArrayLike | None = None,
        R0: ArrayLike | None = None,
        *,
        tol: float = 1e-10,
        max_iter: int = 50,
        max_residual: float | None = None,
    ) -> ForwardKinematicsResult:
        """Pose from cable lengths (:func:`msarm.cdpr.forward_kinematics.forward_kinematics`).

        Args:
            lengths: Cable lengths [m], shape (m,).
            r0: Start position in K_0 [m], shape (3,); the home position if None.
            R0: Start rotation matrix, shape (3, 3); the home rotation if None.
            tol: Step tolerance [m and rad].
            max_iter: Largest number of Newton-Raphson steps.
            max_residual: Largest length residual [m] a pose is accepted with; None: any.

        Returns:
            The pose, the number of steps and the largest length residual [m].

        Raises:
            InputError: On invalid input.
            ForwardKinematicsError: When the iteration does not converge, or ends with a
                residual above ``max_residual`` (a local minimum).
        """
        r_home, R_home = self.home_pose
        return forward_kinematics(
            self.robot,
            lengths,
            r_home if r0 is None else r0,
            R_home if R0 is None else R0,
            tol=tol,
            max_iter=max_iter,
            max_residual=max_residual,
        )

    def platform_wrench(
        self,
        r: ArrayLike,
        R: ArrayLike,
        v: ArrayLike | None = None,
        omega: ArrayLike | None = None,
        a: ArrayLike | None = None,
        alpha: ArrayLike | None = None,
    ) -> FloatArray:
        """Wrench of the platform's weight and inertia, (force [N], moment about r [N m]) in K_0.

        :func:`msarm.cdpr.forward_kinematics.platform_wrench` with this file's mass,
        inertia, centre of mass and gravity.

        Args:
            r: Platform position in K_0 [m], shape (3,) or (N, 3).
            R: Platform orientation, K_P to K_0, shape (3, 3) or (N, 3, 3).
            v: Linear velocity in K_0 [m/s], like ``r``; zero if None.
            omega: Angular velocity in K_0 [rad/s], like ``r``; zero if None.
            a: Linear acceleration in K_0 [m/s^2], like ``r``; zero if None.
            alpha: Angular acceleration in K_0 [rad/s^2], like ``r``; zero if None.

        Returns:
            (force [N], moment about r [N m]) in K_0, shape (6,) or (N, 6).
        """
        return platform_wrench(
            r,
            R,
            v,
            omega,
            a,
            alpha,
            mass=self.mass,
            inertia=self.inertia,
            gravity=self.gravity,
            com=self.com,
        )

    def is_feasible(
        self, r: ArrayLike, R: ArrayLike, wrench: ArrayLike | None = None, *, tol: float = 1e-9
    ) -> bool:
        """Is a pose wrench-feasible with the file's cable force bounds?

        Args:
            r: Platform position in K_0 [m], shape (3,).
            R: Platform rotation matrix, shape (3, 3).
            wrench: External wrench(es) on the platform [N, N m], shape (6,) or (k, 6) (the
                vertices of a wrench polytope); the platform's weight at rest if None.
            tol: Equilibrium tolerance, relative to ``1 + ||w||``.

        Returns:
            True when forces within [f_min, f_max] meet ``A^T f + w = 0`` for every wrench.

        Raises:
            InputError: On an invalid pose or wrench, or a robot of fewer than 6 cables.
        """
        self._check_cable_count()
        if wrench is None:
            w = self.platform_wrench(r, R)
        else:
            w = np.asarray(wrench, dtype=np.float64)
            if w.ndim not in (1, 2) or w.shape[-1] != 6 or w.size == 0:
                raise InputError(
                    f"wrench must have shape (6,) or (k, 6) [N, N m] (force, moment about r), "
                    f"got {w.shape}"
                )
        At = self.robot.structure_matrix(r, R)
        return is_wrench_feasible(At, w, self.f_min, self.f_max, tol=tol)

    def _check_cable_count(self) -> None:
        """Refuse wrench feasibility for a robot of fewer cables than the platform's 6 DOF."""
        if self.n_cables < 6:
            raise InputError(
                f"wrench feasibility of {self.name} needs at least 6 cables for the 6-DOF "
                f"platform, it has {self.n_cables}: with fewer, A^T f + w = 0 has more "
                "equations than forces and holds only particular wrenches (an "
                "under-constrained robot), which msarm's feasibility test does not cover"
            )

    def feasible_poses(
        self,
        positions: ArrayLike,
        rotations: ArrayLike | None = None,
        wrenches: ArrayLike | None = None,
        *,
        tol: float = 1e-9,
        f_min: float | ArrayLike | None = None,
        f_max: float | ArrayLike | None = None,
    ) -> NDArray[np.bool_]:
        """Wrench feasibility of every sample of a trajectory.

        Args:
            positions: Platform positions r in K_0 [m], shape (N, 3).
            rotations: Rotation matrices, shape (3, 3) (shared) or (N, 3, 3); identity if
                None.
            wrenches: External wrench on the platform at each sample [N, N m], shape (6,)
                (shared) or (N, 6), e.g. :meth:`platform_wrench` with the trajectory's
                velocities and accelerations; the platform's weight at rest if None.
            tol: Equilibrium tolerance, relative to ``1 + ||w||``.
            f_min: Lower force bound [N], a number or shape (m,): the model file's if None
                (e.g. a controller's distribution bound, which may be tighter).
            f_max: Upper force bound [N], a number or shape (m,): the model file's if None.

        Returns:
            Shape (N,) bool.

        Raises:
            InputError: On invalid poses, wrenches or bounds, or a robot of fewer than 6
                cables.
        """
        self._check_cable_count()
        r = np.asarray(positions, dtype=np.float64)
        if r.ndim != 2 or r.shape[1] != 3 or r.shape[0] < 1:
            raise InputError(f"positions must have shape (N, 3) [m], got {r.shape}")
        R = np.eye(3) if rotations is None else np.asarray(rotations, dtype=np.float64)
        At = self.robot.structure_matrix(r, R)  # validates the poses, (N, 6, m)
        if wrenches is None:
            w = self.platform_wrench(r, np.broadcast_to(R, (len(r), 3, 3)))
        else:
            w = np.asarray(wrenches, dtype=np.float64)
            if w.shape not in ((6,), (len(r), 6)):
                raise InputError(
                    f"wrenches must have shape (6,) or ({len(r)}, 6) [N, N m], got {w.shape}"
                )
            if not np.isfinite(w).all():
                raise InputError("wrenches must be finite [N, N m]")
            w = np.broadcast_to(w, (len(r), 6))
        lower, upper = self._bounds(f_min, f_max)
        return feasibility_batch(At, -w, lower, upper, tol=tol)

    def _bounds(
        self, f_min: float | ArrayLike | None, f_max: float | ArrayLike | None
    ) -> tuple[FloatArray, FloatArray]:
        """The force bounds [N], shape (m,) each: the file's where None.

        Raises:
            InputError: As :func:`msarm.allocation.problem.tension_bounds`.
        """
        return tension_bounds(
            self.f_min if f_min is None else f_min,
            self.f_max if f_max is None else f_max,
            self.n_cables,
        )

    def first_infeasible(
        self,
        positions: ArrayLike,
        rotations: ArrayLike | None = None,
        wrenches: ArrayLike | None = None,
        *,
        tol: float = 1e-9,
        f_min: float | ArrayLike | None = None,
        f_max: float | ArrayLike | None = None,
    ) -> int | None:
        """Index of the first wrench-infeasible sample of a trajectory, None if all feasible.

        Arguments as :meth:`feasible_poses`.
        """
        flags = self.feasible_poses(
            positions, rotations, wrenches, tol=tol, f_min=f_min, f_max=f_max
        )
        bad = np.flatnonzero(~flags)
        return int(bad[0]) if bad.size else None

    def check_trajectory(
        self,
        positions: ArrayLike,
        rotations: ArrayLike | None = None,
        wrenches: ArrayLike | None = None,
        *,
        tol: float = 1e-9,
        f_min: float | ArrayLike | None = None,
        f_max: float | ArrayLike | None = None,
    ) -> None:
        """Refuse a trajectory that leaves the wrench-feasible workspace, before it runs.

        Arguments as :meth:`feasible_poses` (a controller checks with its own force
        distribution's bounds, e.g. 8-35 N, tighter than the file's 5-35 N).

        Raises:
            InputError: Naming the first infeasible sample, its position and the bounds.
        """
        index = self.first_infeasible(
            positions, rotations, wrenches, tol=tol, f_min=f_min, f_max=f_max
        )
        if index is not None:
            lower, upper = self._bounds(f_min, f_max)
            r = np.asarray(positions, dtype=np.float64)[index]
            raise InputError(
                f"trajectory leaves the wrench-feasible workspace of {self.name} at sample "
                f"{index} (r = {np.array2string(r, precision=4)} m): no cable forces within "
                f"[{lower.min():g}, {upper.max():g}] N hold the platform there"
            )


# --------------------------------------------------------------------------- loading


def load_cable_robot(path: str | Path | None = None) -> CableRobotModel:
    """Load a cable robot's MJCF file into MuJoCo, Pinocchio and a CableRobot and check them.

    Args:
        path: The MJCF file; ``models/ipanema_mini.xml`` if None.

    Returns:
        The loaded model.

    Raises:
        ModelError: The file is missing or malformed; it is not one platform body with one
            free joint; a tendon is not a straight cable from a world site to a platform site;
            ``cable_force_bounds`` is missing or invalid; or, at a test pose, a cable length
            of MuJoCo differs from the CableRobot's (the cable is named), or Pinocchio's
            platform pose, mass matrix or bias forces differ from MuJoCo's.
    """
    path = Path(IPANEMA_MINI_PATH if path is None else path)
    if not path.is_file():
        raise ModelError(f"model file not found: {path} (expected an MJCF .xml file)")
    try:
        mj_model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        reason = " ".join(str(exc).split())  # MuJoCo's text spans lines: one line here
        raise ModelError(f"{path}: MuJoCo cannot load the file: {reason}") from exc
    body = _check_platform(mj_model, path)
    cable_names, frame_sites, platform_sites = _read_cables(mj_model, body, path)
    _check_no_forces_of_mujoco(mj_model, body, path)
    f_min, f_max = _read_force_bounds(mj_model, len(cable_names), path)
    lower, upper = _read_workspace(mj_model, path)
    robot = CableRobot(
        mj_model.site_pos[list(frame_sites)], mj_model.site_pos[list(platform_sites)]
    )
    R_inertial = matrix_from_quaternion(mj_model.body_iquat[body])
    inertia = R_inertial @ np.diag(mj_model.body_inertia[body]) @ R_inertial.T
    try:
        pin_model = pinocchio.buildModelFromMJCF(str(path))
    except Exception as exc:  # the parser raises bare RuntimeErrors and ValueErrors
        raise ModelError(f"{path}: Pinocchio cannot load the file: {exc}") from exc
    pin_model.gravity.linear = model_gravity(mj_model)  # the parser ignores <option gravity>
    model = CableRobotModel(
        path=path,
        sha256=model_sha256(path),
        mj_model=mj_model,
        pin_model=pin_model,
        robot=robot,
        cable_names=cable_names,
        frame_site_names=tuple(mj_model.site(s).name for s in frame_sites),
        platform_site_names=tuple(mj_model.site(s).name for s in platform_sites),
        platform_body=mj_model.body(body).name,
        mass=float(mj_model.body_mass[body]),
        com=np.array(mj_model.body_ipos[body], dtype=float),
        inertia=0.5 * (inertia + inertia.T),
        gravity=model_gravity(mj_model),
        f_min=f_min,
        f_max=f_max,
        workspace_lower=lower,
        workspace_upper=upper,
        home_qpos=np.array(mj_model.qpos0, dtype=float),
    )
    _check_engines_agree(model)
    for array in (model.com, model.inertia, model.gravity, model.f_min, model.f_max):
        array.setflags(write=False)
    for array in (model.workspace_lower, model.workspace_upper, model.home_qpos):
        if array is not None:
            array.setflags(write=False)
    return model


def _check_platform(mj_model: mujoco.MjModel, path: Path) -> int:
    """The platform body id; raise unless the file is one free body under the world."""
    if mj_model.nbody != 2:
        names = [mj_model.body(b).name for b in range(1, mj_model.nbody)]
        raise ModelError(
            f"{path}: a cable robot needs exactly one body, the platform, under <worldbody>; "
            f"found {len(names)} ({', '.join(names) or 'none'}). Put the frame anchors as "
            "sites directly in <worldbody> (or a <frame>), not in a body"
        )
    free = int(mujoco.mjtJoint.mjJNT_FREE)
    if mj_model.njnt != 1 or int(mj_model.jnt_type[0]) != free or mj_model.jnt_bodyid[0] != 1:
        raise ModelError(
            f"{path}: the platform '{mj_model.body(1).name}' needs exactly one joint, a free "
            f"joint; the file has {mj_model.njnt} joint(s)"
        )
    if mj_model.ntendon == 0:
        raise ModelError(
            f"{path}: the model has no tendons; msarm needs one <spatial> tendon per cable"
        )
    if mj_model.body_mass[1] <= 0.0:
        raise ModelError(f"{path}: the platform needs a mass > 0 kg (an <inertial> element)")
    return 1


def _read_cables(
    mj_model: mujoco.MjModel, body: int, path: Path
) -> tuple[tuple[str, ...], tuple[int, ...], tuple[int, ...]]:
    """Cable names and the frame and platform site ids of every tendon."""
    site = int(mujoco.mjtWrap.mjWRAP_SITE)
    names, frame_sites, platform_sites = [], [], []
    for t in range(mj_model.ntendon):
        name = mj_model.tendon(t).name
        if not name:
            raise ModelError(f"{path}: tendon {t} has no name; every cable needs one")
        start, count = int(mj_model.tendon_adr[t]), int(mj_model.tendon_num[t])
        types = mj_model.wrap_type[start : start + count]
        if count != 2 or np.any(types != site):
            raise ModelError(
                f"{path}: cable '{name}' must be a <spatial> tendon with exactly two sites "
                f"(frame anchor, platform anchor) and no wrapping; it has {count} path elements"
            )
        ids = [int(i) for i in mj_model.wrap_objid[start : start + 2]]
        bodies = [int(mj_model.site_bodyid[i]) for i in ids]
        if sorted(bodies) != [0, body]:
            raise ModelError(
                f"{path}: cable '{name}' must run from a site fixed in the world (frame anchor) "
                f"to a site of the platform; its sites '{mj_model.site(ids[0]).name}' and "
                f"'{mj_model.site(ids[1]).name}' are on bodies {bodies}"
            )
        if bodies[0] != 0:
            ids.reverse()
        names.append(name)
        frame_sites.append(ids[0])
        platform_sites.append(ids[1])
    return tuple(names), tuple(frame_sites), tuple(platform_sites)


def _check_no_forces_of_mujoco(mj_model: mujoco.MjModel, body: int, path: Path) -> None:
    """Refuse what would make MuJoCo add forces of its own to the plant's cable model.

    Tendon or joint springs, damping or frictionloss, a tendon's length limit and contacts of
    the platform: the plant would apply them on top of its cables, and the nominal model the
    controllers use has none (a spring of 2000 N/m on one cable took a run from 0.09 mm to
    396 mm of error, with no message).
    """
    check_no_passive_forces(
        mj_model,
        path,
        "the plant file (--plant) sets the cables' stiffness and damping and the winches' friction",
    )
    limited = np.flatnonzero(np.asarray(mj_model.tendon_limited).reshape(-1))
    if limited.size:
        name = mj_model.tendon(int(limited[0])).name
        raise ModelError(
            f"{path}: cable '{name}' has a length range (limited); MuJoCo would add a limit "
            "force the nominal model lacks: leave range and limited out of the tendons"
        )
    if mj_model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONTACT):
        return  # <flag contact="disable"/>: no contact at all
    geoms = np.arange(mj_model.ngeom)
    for k in range(mj_model.npair):  # <contact><pair>: collides whatever the geoms' masks
        pair = (int(mj_model.pair_geom1[k]), int(mj_model.pair_geom2[k]))
        if any(mj_model.geom_bodyid[g] == body for g in pair):
            raise ModelError(
                f"{path}: a <contact><pair> of geoms '{mj_model.geom(pair[0]).name}' and "
                f"'{mj_model.geom(pair[1]).name}' makes the platform collide; contacts are not "
                "in the nominal model: leave the pair out"
            )
    contype, conaffinity = mj_model.geom_contype, mj_model.geom_conaffinity
    mine = geoms[mj_model.geom_bodyid == body]
    others = geoms[mj_model.geom_bodyid != body]
    for g in mine:
        touching = (contype[g] & conaffinity[others]) | (contype[others] & conaffinity[g])
        if np.any(touching):
            other = int(others[np.flatnonzero(touching)[0]])
            raise ModelError(
                f"{path}: the platform's geom '{mj_model.geom(int(g)).name or int(g)}' can "
                f"collide with geom '{mj_model.geom(other).name or other}'; contacts are not "
                'in the nominal model: set contype="0" conaffinity="0" on the platform\'s geoms'
            )


def _numeric(mj_model: mujoco.MjModel, key: str) -> FloatArray | None:
    for i in range(mj_model.nnumeric):
        if mj_model.numeric(i).name == key:
            return np.asarray(mj_model.numeric(i).data, dtype=float)
    return None


def _read_force_bounds(
    mj_model: mujoco.MjModel, m: int, path: Path
) -> tuple[FloatArray, FloatArray]:
    values = _numeric(mj_model, "cable_force_bounds")
    if values is None:
        raise ModelError(
            f'{path}: missing <numeric name="cable_force_bounds" data="f_min f_max"/> [N] '
            "in <custom>"
        )
    if values.shape != (2,) or not np.isfinite(values).all() or not 0 <= values[0] < values[1]:
        raise ModelError(
            f"{path}: numeric 'cable_force_bounds' must be two numbers 0 <= f_min < f_max [N], "
            f"got {values}"
        )
    return np.full(m, values[0]), np.full(m, values[1])


def _read_workspace(
    mj_model: mujoco.MjModel, path: Path
) -> tuple[FloatArray | None, FloatArray | None]:
    values = _numeric(mj_model, "workspace_box")
    if values is None:
        return None, None
    if values.shape != (6,) or not np.isfinite(values).all() or np.any(values[:3] >= values[3:]):
        raise ModelError(
            f"{path}: numeric 'workspace_box' must be x_min y_min z_min x_max y_max z_max [m] "
            f"with min < max, got {values}"
        )
    return values[:3].copy(), values[3:].copy()


def _check_engines_agree(model: CableRobotModel) -> None:
    """Compare MuJoCo, Pinocchio and the CableRobot at a test state; raise ModelError."""
    path, mj_model, pin_model = model.path, model.mj_model, model.pin_model
    if (pin_model.nq, pin_model.nv, pin_model.njoints) != (7, 6, 2):
        raise ModelError(
            f"{path}: Pinocchio sees nq={pin_model.nq}, nv={pin_model.nv} and "
            f"{pin_model.njoints - 1} joint(s); expected one free flyer (nq 7, nv 6)"
        )
    r_home, R_home = model.home_pose
    r, R = r_home + _TEST_OFFSET, rotation_matrix(_TEST_ROTVEC) @ R_home
    qpos = qpos_from_pose(r, R)
    data = model.create_data()
    data.mj.qpos[:] = qpos
    data.mj.qvel[:] = _TEST_TWIST
    mujoco.mj_forward(mj_model, data.mj)
    lengths = model.robot.cable_lengths(r, R)
    for i, name in enumerate(model.cable_names):
        if abs(data.mj.ten_length[i] - lengths[i]) > _ENGINE_TOLERANCE:
            raise ModelError(
                f"{path}: cable '{name}' is {data.mj.ten_length[i]:.9f} m long in MuJoCo but "
                f"{lengths[i]:.9f} m from its anchors at the test pose r={np.round(r, 4)}"
            )
    q = pin_q_from_qpos(qpos)
    v = pin_v_from_qvel(qpos, _TEST_TWIST)
    frame = pin_model.getFrameId(model.platform_body, pinocchio.FrameType.BODY)
    if frame >= pin_model.nframes:
        raise ModelError(f"{path}: body '{model.platform_body}' is missing in Pinocchio")
    pinocchio.framesForwardKinematics(pin_model, data.pin, q)
    placement = data.pin.oMf[frame]
    if (
        np.abs(placement.translation - data.mj.xpos[1]).max() > _ENGINE_TOLERANCE
        or np.abs(placement.rotation - data.mj.xmat[1].reshape(3, 3)).max() > _ENGINE_TOLERANCE
    ):
        raise ModelError(
            f"{path}: the platform is at {np.round(data.mj.xpos[1], 6)} in MuJoCo but at "
            f"{np.round(placement.translation, 6)} in Pinocchio (or rotated differently)"
        )
    M_mj = np.zeros((6, 6))
    mujoco.mj_fullM(mj_model, data.mj, M_mj)
    T = velocity_map(R)
    M_pin = pinocchio.crba(pin_model, data.pin, q)
    M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
    err = np.abs(M_pin - T.T @ M_mj @ T).max()
    if err > _ENGINE_TOLERANCE:
        raise ModelError(
            f"{path}: mass matrices of Pinocchio and MuJoCo differ by {err:.3g} at the test pose"
        )
    omega_p = _TEST_TWIST[3:]
    dT_v = np.concatenate([R @ np.cross(omega_p, v[:3]), np.zeros(3)])
    nle_mj = T.T @ (data.mj.qfrc_bias + M_mj @ dT_v)
    nle_pin = pinocchio.nonLinearEffects(pin_model, data.pin, q, v)
    err = np.abs(nle_pin - nle_mj).max()
    if err > _ENGINE_TOLERANCE:
        raise ModelError(
            f"{path}: bias forces of Pinocchio and MuJoCo differ by {err:.3g} at the test state"
        )
