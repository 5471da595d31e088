"""The cable-robot controllers of paper 000: IKC, HC-f, HC-tau, HC-e, HC-e on all cables, NC.

Every controller is built once for a robot (geometry :class:`~msarm.cdpr.CableRobot` and the
platform's mass properties) and stepped every control cycle (1 ms) with the platform's
reference (position ``r``, velocity ``v``, acceleration ``a``; rotation, angular velocity and
angular acceleration optional, R = I by default) and the robot's sensor readings; it returns
a :class:`CdprCommand`: per cable a set length ``l_set`` [m], a feed-forward velocity
``v_ff`` [m/s] and a drive mode (``"pi"``: the drive's usual PI velocity controller, ``"p"``:
pure proportional drive, needed by HC-e). A controller reads only what a real robot's
sensors give (:class:`CdprMeasurement`, or ``msarm.plant.cdpr_plant.CdprPlant.sense()``'s
readings: encoder cable length, motor torque, following error, load cell force), never the
plant's internals.

Nominal model (common to all): inverse kinematics gives the cable lengths ``l_i`` (eq. 1),
their velocities ``v_i = dl_i/dt`` and accelerations ``a_i`` (analytic, from the platform
twist and its derivative); the platform wrench ``w`` is its weight and inertia (Newton-Euler,
the formulas of :func:`msarm.cdpr.forward_kinematics.platform_wrench`, in a single-pose
helper :meth:`PlatformParameters.wrench`); the desired forces ``f_i`` are the
minimum-2-norm distribution of ``A^T f + w = 0`` within ``[8, 35] N`` (allocation core,
``f_ref=None``; paper 000 Sec. 4 computes the distribution with 8 N instead of the robot's
5 N limit as a margin). The feed-forward velocity of every cable is ``v_i`` (or zero with
``velocity_feedforward=False``, as the paper's PLC; see HC-e below).

Controllers (``CDPR_CONTROLLERS``):

- ``"ikc"`` :class:`InverseKinematicsController`: ``l_set = l_i``, all drives PI.
- ``"hc-f"`` :class:`HybridForceController` (Fig. 8a): the force-controlled pair compares
  ``f_set = f_i + f_F(f_i, v_i)`` (eq. 7; the load cell sits before the last pulley and reads
  the tension plus the friction force f_F) with the load cell, low-passed with 5 ms by
  default (:data:`HC_F_FILTER_TIME`, msarm's choice). Drives PI.
- ``"hc-tau"`` :class:`HybridTorqueController` (Fig. 8b): compares the motor torque of eq. 3,
  ``tau_i = f_i r_D + tau_F(f_i, v_i) + tau_In``, with the measured motor torque;
  ``friction_model=False`` sets ``tau_F = 0`` (Fig. 10, last column). The torque is
  low-passed with 20 ms by default (:data:`HC_TAU_FILTER_TIME`; the paper smooths it with an
  unspecified filter). Drives PI.
- ``"hc-e"`` :class:`HybridFollowingErrorController` (Fig. 8c): turns ``tau_i`` into the
  wanted following error with eq. 9, ``FE_set = c_f tau_i / K_p + c_v v_i``, and compares it
  with the measured FE. The velocity term ``c_v v_i`` is the lag of the PLC's P position loop
  on a ramp when no velocity feedforward is sent (the paper's PLC); with the feedforward
  ``v_ff = v_i`` (msarm's default, ``velocity_feedforward=True``) that lag is gone and
  ``FE_set = c_f tau_i / K_p`` (eq. 8). The switchable cables (both candidate pairs) use
  pure-P drives, the others PI (Sec. 3: the drive's controller is not changed online).
- ``"hc-e-all"`` :class:`AllCablesFollowingErrorController`: HC-e on all eight cables, all
  pure-P drives (paper 000's test 51).
- ``"nc"`` :class:`NullspaceController`: load-cell forces kept near 12 N and raised when
  below 7 N by length corrections in the nullspace of ``A^T`` (see its docstring).

Hybrid law (Sec. 3, eq. 10-11): for a switchable cable ``i``,
``l_set,i = l_i + h_i Delta l_i`` with ``Delta l_i`` from the high-level PID (eq. 11,
:mod:`msarm.control.pid`, gains of Table 2) and ``h_i`` the scaling factor of eq. 10
(:class:`~msarm.cdpr.switching.SwitchingFactor`, step ``delta`` per cycle). The other cables
are position-controlled, ``l_set,i = l_i``.

Sign conventions (derived, not printed in the paper; the tests check them; they are also
those of ``msarm.plant.cdpr_plant``):

- Lengths and velocities: ``l_set`` is the commanded cable length; ``Delta l > 0`` pays cable
  out (longer cable, lower tension), ``v > 0`` pays out (as ``msarm.cdpr.winch_friction``).
- Motor torque (HC-tau): positive in the sense that holds the cable's tension, as in eq. 3
  (``tau = f r_D`` at rest without friction).
- Following error (HC-e): the convention of eq. 9 with the published ``c_f < 0``: more
  tension gives a more negative FE (FE = commanded minus actual cable length, the cable
  stretched out by its tension).
- The PID's input is the *tension excess* expressed in the feedback's unit,
  ``e = s (y_measured - y_set)`` with ``s = +1`` for force and torque and
  ``s = sign(c_f / K_p)`` (``-1``) for the following error; with the positive gains of Table 2
  ``Delta l = PID(e)`` is negative (reel in) when the tension is too low and positive (pay
  out) when it is too high.
- Inertial torque of eq. 3: ``tau_In = -J_D a_i / r_D`` with ``a_i > 0`` accelerating the
  pay-out (the cable's tension accelerates the drum outwards, so the motor needs less
  holding torque; the paper writes ``tau_In(a_i)`` without a formula).

Cable numbering: msarm numbers cables from 0, paper 000 from 1. The paper's force-controlled
pairs "1, 2" and "3, 4" are msarm's ``(0, 1)`` and ``(2, 3)``: the upper cables whose frame
anchors lie at y > 0 and y < 0 (``models/ipanema_mini.xml``). The default pair choice is by
region (:class:`RegionPairSelector`: ``(0, 1)`` where ``y > 0``, ``(2, 3)`` where
``y <= 0``), which matches Fig. 7 for msarm's robot: with ``msarm.cdpr.sensitivity``,
sigma_01 < 1.5 N for y >= -0.05 m and sigma_23 < 1.5 N for y <= 0.10 m at the workspace's mid
height over |x| <~ 0.25 m (sigma_01 reaches 1.5-1.7 N at |x| = 0.35-0.40 m).
:class:`SensitivityPairSelector` picks the candidate with the smaller sigma instead.

Winch parameters: the drum radius ``r_D`` and the inertia ``J_D`` of the winch's moving parts
are not given in paper 000; :class:`WinchParameters` defaults to ``r_D = 0.02 m`` (35 N then
needs 0.70 N m, the nominal torque of the paper's motors, 0.69 N m) and
``J_D = 3e-5 kg m^2``. Give the controller the values of the robot it drives.
:class:`WinchParameters` lives in :mod:`msarm.cdpr.force_estimation` (re-exported here): its
eq. 3 and eq. 9 are the single copy that HC-tau and HC-e use for their set values and that
the load-cell-free force estimates of that module invert.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.allocation import make_allocator
from msarm.cdpr.force_estimation import WinchParameters
from msarm.cdpr.forward_kinematics import STANDARD_GRAVITY
from msarm.cdpr.kinematics import CableRobot
from msarm.cdpr.sensitivity import sensitivity_index
from msarm.cdpr.switching import SwitchingFactor
from msarm.control.pid import (
    CYCLE_TIME,
    HC_E_GAINS,
    HC_F_GAINS,
    HC_TAU_GAINS,
    DiscretePID,
    PIDGains,
)
from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = [
    "CDPR_CONTROLLERS",
    "DISTRIBUTION_F_MAX",
    "DISTRIBUTION_F_MIN",
    "DRIVE_P",
    "DRIVE_PI",
    "HC_F_FILTER_TIME",
    "HC_TAU_FILTER_TIME",
    "NC_LOW_FORCE",
    "NC_MEAN_FORCE",
    "PAIR_12",
    "PAIR_34",
    "AllCablesFollowingErrorController",
    "CdprCommand",
    "CdprController",
    "CdprMeasurement",
    "CdprReadingsLike",
    "FixedPair",
    "HybridController",
    "HybridFollowingErrorController",
    "HybridForceController",
    "HybridTorqueController",
    "InverseKinematicsController",
    "NominalState",
    "NullspaceController",
    "PairSelector",
    "PlatformParameters",
    "RegionPairSelector",
    "SensitivityPairSelector",
    "WinchParameters",
    "cable_motion",
    "check_plain_options",
    "list_cdpr_controllers",
    "make_cdpr_controller",
]

DRIVE_PI = "pi"
"""Drive mode: the drive's PI velocity controller (position loop closed in the PLC)."""
DRIVE_P = "p"
"""Drive mode: pure proportional drive (K_p = 200 in paper 000), needed by HC-e."""
DriveMode = Literal["pi", "p"]

DISTRIBUTION_F_MIN = 8.0
"""Lower bound of the force distribution [N] (paper 000 Sec. 4: 5 N limit plus margin)."""
DISTRIBUTION_F_MAX = 35.0
"""Upper bound of the force distribution [N] (paper 000 Sec. 4)."""
NC_MEAN_FORCE = 12.0
"""Force the nullspace controller keeps the cables near [N] (paper 000 Sec. 4.2)."""
NC_LOW_FORCE = 7.0
"""Force below which the nullspace controller corrects a cable more strongly [N]."""
PAIR_12: tuple[int, int] = (0, 1)
"""The paper's force-controlled pair "1, 2" in msarm's 0-based numbering."""
PAIR_34: tuple[int, int] = (2, 3)
"""The paper's force-controlled pair "3, 4" in msarm's 0-based numbering."""
DEFAULT_DELTA = 0.02
"""Default step of alpha per cycle of eq. 10 [rad]: a switch takes 79 cycles (79 ms)."""
DEFAULT_DELTA_L_LIMIT = 0.02
"""Default bound on the high-level PID output |Delta l| [m] (anti-windup limit)."""
HC_F_FILTER_TIME = 0.005
"""Default low-pass time constant on HC-f's load-cell reading [s] (msarm's choice)."""
HC_TAU_FILTER_TIME = 0.02
"""Default low-pass time constant on HC-tau's motor torque [s] (the paper's unspecified
filter; msarm's choice)."""
N_DOF = 6


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class PlatformParameters:
    """Mass properties of the platform for its Newton-Euler wrench.

    Attributes:
        mass: Platform mass [kg], > 0 (paper 000: 0.25 kg).
        inertia: Inertia tensor about the centre of mass in K_p [kg m^2], shape (3, 3).
        com: Centre of mass in K_p [m], shape (3,).
        gravity: Gravity in K_0 [m/s^2], shape (3,).
    """

    mass: float
    inertia: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    com: FloatArray = field(default_factory=lambda: np.zeros(3))
    gravity: FloatArray = field(default_factory=lambda: STANDARD_GRAVITY.copy())

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mass) and self.mass > 0.0):
            raise InputError(f"platform mass must be finite and > 0 kg, got {self.mass}")
        for name, shape in (("inertia", (3, 3)), ("com", (3,)), ("gravity", (3,))):
            value = np.array(getattr(self, name), dtype=np.float64)
            if value.shape != shape or not np.isfinite(value).all():
                raise InputError(f"platform {name} must be finite with shape {shape}")
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    def wrench(
        self,
        r: FloatArray,
        R: FloatArray,
        v: FloatArray,
        omega: FloatArray,
        a: FloatArray,
        alpha: FloatArray,
    ) -> FloatArray:
        """External wrench of weight and inertia (force [N], moment about r [N m]), (6,).

        Newton-Euler at one pose, as :func:`msarm.cdpr.forward_kinematics.platform_wrench`
        (same formulas, without its batch handling; a test keeps the two equal): with
        ``c = R com``, ``a_c = a + alpha x c + omega x (omega x c)`` and ``I = R I_c R^T``,
        ``force = mass (gravity - a_c)``, ``moment = c x force - I alpha - omega x I omega``.

        Args:
            r: Platform position in K_0 [m], shape (3,) (the moment is taken about it).
            R: Rotation matrix, shape (3, 3).
            v: Velocity [m/s], shape (3,) (does not enter the wrench).
            omega: Angular velocity in K_0 [rad/s], shape (3,).
            a: Acceleration of r [m/s^2], shape (3,).
            alpha: Angular acceleration in K_0 [rad/s^2], shape (3,).

        Returns:
            w, shape (6,), such that the cables must give ``A^T f = -w``.
        """
        if not (self.com.any() or omega.any() or alpha.any()):
            return np.concatenate([self.mass * (self.gravity - a), np.zeros(3)])
        c = R @ self.com
        a_c = a + _cross(alpha, c) + _cross(omega, _cross(omega, c))
        force = self.mass * (self.gravity - a_c)
        inertia = R @ self.inertia @ R.T
        moment = _cross(c, force) - inertia @ alpha - _cross(omega, inertia @ omega)
        return np.concatenate([force, moment])


class CdprReadingsLike(Protocol):
    """What the controllers read: any object with these attributes, arrays of shape (m,).

    ``msarm.plant.cdpr_plant.CdprSensorReadings`` (what ``CdprPlant.sense()`` returns) is one;
    :class:`CdprMeasurement` is another. A controller reads only the attributes it needs.
    """

    cable_length: FloatArray | None
    motor_torque: FloatArray | None
    following_error: FloatArray | None
    load_cell: FloatArray | None


@dataclass(frozen=True)
class CdprMeasurement:
    """The robot's sensor readings at one cycle, per cable (any may be None if not needed).

    Attributes:
        cable_length: Motor position as the cable length paid out (encoder) [m], shape (m,).
        motor_torque: Motor torque [N m], shape (m,), positive holding the tension (eq. 3).
        following_error: Following error [m], shape (m,), eq. 9's convention (more tension,
            more negative).
        load_cell: Load-cell force [N], shape (m,) (the tension plus the friction force f_F
            of eq. 7).
    """

    cable_length: FloatArray | None = None
    motor_torque: FloatArray | None = None
    following_error: FloatArray | None = None
    load_cell: FloatArray | None = None


def _reading(measurement: Any, name: str, unit: str, m: int, controller: str) -> FloatArray:
    value = None if measurement is None else getattr(measurement, name, None)
    if value is None:
        raise InputError(f"controller {controller!r} needs the sensor reading {name!r} [{unit}]")
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (m,):
        raise InputError(
            f"sensor reading {name!r} must have shape ({m},) [{unit}], got {arr.shape}"
        )
    if not np.isfinite(arr).all():
        raise InputError(f"sensor reading {name!r} must be finite [{unit}], got {arr}")
    return arr


# --------------------------------------------------------------------------- outputs


@dataclass(frozen=True)
class NominalState:
    """The nominal model at one reference sample.

    Attributes:
        lengths: IK cable lengths l_i [m], shape (m,).
        velocities: Cable velocities dl_i/dt [m/s] (> 0: paid out), shape (m,).
        accelerations: Cable accelerations d^2l_i/dt^2 [m/s^2], shape (m,).
        structure_matrix: A^T [-, m], shape (6, m).
        wrench: Platform wrench w (weight and inertia) [N, N m], shape (6,).
        forces: Desired forces f_i, the minimum-2-norm distribution in the bounds [N], (m,).
        feasible: Whether ``A^T f + w = 0`` holds within the bounds (else f is the bounded
            least-squares answer of the allocation core).
    """

    lengths: FloatArray
    velocities: FloatArray
    accelerations: FloatArray
    structure_matrix: FloatArray
    wrench: FloatArray
    forces: FloatArray
    feasible: bool


@dataclass(frozen=True)
class CdprCommand:
    """What a controller sends to the drives for one cycle, and why.

    Attributes:
        l_set: Set cable lengths [m], shape (m,).
        v_ff: Feed-forward cable velocities [m/s] (> 0: pay out), shape (m,).
        drive_mode: Drive mode per cable, ``"pi"`` or ``"p"``, length m.
        l_ik: Inverse-kinematics lengths [m], shape (m,).
        delta_l: High-level correction before scaling (hybrid: PID output Delta l; NC: its
            nullspace correction) [m], shape (m,); zero where not applied.
        h: Scaling factor of eq. 10 per cable [-], shape (m,) (1 where NC corrects, 0 for
            position-controlled cables).
        f_desired: Desired forces of the distribution [N], shape (m,).
        target: Set value of the feedback per cable, in its unit (N, N m or m; NC: the
            estimated tension [N]), shape (m,); NaN for cables that are never force-controlled
            (and for IKC).
        force_controlled: Cables whose force control is on or switching on (ascending).
        feasible: Whether the force distribution met the equilibrium within the bounds.
    """

    l_set: FloatArray
    v_ff: FloatArray
    drive_mode: tuple[str, ...]
    l_ik: FloatArray
    delta_l: FloatArray
    h: FloatArray
    f_desired: FloatArray
    target: FloatArray
    force_controlled: tuple[int, ...]
    feasible: bool


def cable_motion(
    robot: CableRobot,
    r: FloatArray,
    R: FloatArray,
    v: FloatArray,
    omega: FloatArray,
    a: FloatArray,
    alpha: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Cable lengths, velocities, accelerations and structure matrix at one platform state.

    With ``d_i = a_i - r - R b_i`` (eq. 1), ``rb_i = R b_i``::

        d'_i  = -v - omega x rb_i
        d''_i = -a - alpha x rb_i - omega x (omega x rb_i)
        l'_i  = u_i . d'_i
        l''_i = u_i . d''_i + (|d'_i|^2 - l'_i^2) / l_i

    Args:
        robot: The cable robot.
        r: Platform position in K_0 [m], shape (3,).
        R: Rotation matrix, shape (3, 3).
        v: Velocity of r [m/s], shape (3,).
        omega: Angular velocity in K_0 [rad/s], shape (3,).
        a: Acceleration of r [m/s^2], shape (3,).
        alpha: Angular acceleration in K_0 [rad/s^2], shape (3,).

    Returns:
        ``(l [m], dl/dt [m/s], d^2l/dt^2 [m/s^2], A^T)``, shapes (m,), (m,), (m,), (6, m).
    """
    kin = robot.inverse_kinematics(r, R)
    u, rb, lengths = kin.unit_vectors, kin.platform_anchors_world, kin.lengths
    if omega.any() or alpha.any():
        d_dot = -v - _cross(omega, rb)
        d_ddot = -a - _cross(alpha, rb) - _cross(omega, _cross(omega, rb))
    else:  # translation only: the rotational terms vanish
        d_dot = _rows(-v, rb.shape[0])
        d_ddot = _rows(-a, rb.shape[0])
    l_dot = np.einsum("ij,ij->i", u, d_dot)
    l_ddot = (
        np.einsum("ij,ij->i", u, d_ddot)
        + (np.einsum("ij,ij->i", d_dot, d_dot) - l_dot**2) / lengths
    )
    At = np.empty((6, len(lengths)))  # [u; rb x u] per column, as concatenate(...).T.copy()
    At[:3] = u.T
    At[3:] = _cross(rb, u).T
    return lengths, l_dot, l_ddot, At


_IDENTITY = np.eye(3)
_IDENTITY.setflags(write=False)


def _rows(x: FloatArray, n: int) -> FloatArray:
    """``np.broadcast_to(x, (n, 3))`` for a contiguous x of shape (3,), without its overhead.

    The same view (row stride 0), so einsum over it runs the same loops.
    """
    out = np.ndarray((n, 3), np.float64, buffer=x, strides=(0, x.strides[0]))
    return out


def _cross(x: FloatArray, y: FloatArray) -> FloatArray:
    """Cross product along the last axis, broadcast (numpy's ``cross`` costs ~30 us a call)."""
    x0, x1, x2 = x[..., 0], x[..., 1], x[..., 2]
    y0, y1, y2 = y[..., 0], y[..., 1], y[..., 2]
    c0 = x1 * y2 - x2 * y1
    out = np.empty((*c0.shape, 3))
    out[..., 0] = c0
    out[..., 1] = x2 * y0 - x0 * y2
    out[..., 2] = x0 * y1 - x1 * y0
    return out


def _vector3(value: ArrayLike | None, name: str, unit: str) -> FloatArray:
    if value is None:
        return np.zeros(3)
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise InputError(f"{name} must be finite with shape (3,) [{unit}], got {arr.shape}")
    return arr


# --------------------------------------------------------------------------- base class


class CdprController(ABC):
    """Common part of the CDPR controllers: nominal model and force distribution.

    Args:
        robot: Cable geometry (m cables, m > 6 for the hybrid controllers).
        platform: Platform mass properties for the wrench.
        winch: Winch data for eq. 3, 7 and 9; :class:`WinchParameters` defaults if None.
        f_min: Lower bound of the force distribution [N] (8 N, paper 000 Sec. 4).
        f_max: Upper bound of the force distribution [N] (35 N).
        dt: Control cycle [s] (1 ms).
        solver: Allocation solver name (an exact one gives the minimum-2-norm distribution).
        velocity_feedforward: Send the IK cable velocities as ``v_ff`` (True, default) or
            zeros (False, as the paper's PLC, whose P position loop then lags a ramp by
            ``c_v v``, the velocity term of eq. 9).

    Raises:
        InputError: On invalid bounds or cycle time, or a winch that is no WinchParameters.
    """

    name: ClassVar[str] = "base"
    #: Whether the controller's force control tracks the desired forces of the distribution
    #: (the hybrid controllers: the force-tracking metric applies, and a run starts holding
    #: them). IKC controls no force; NC keeps forces near its own mean force instead.
    tracks_distribution: ClassVar[bool] = False

    def __init__(
        self,
        robot: CableRobot,
        platform: PlatformParameters,
        *,
        winch: WinchParameters | None = None,
        f_min: float = DISTRIBUTION_F_MIN,
        f_max: float = DISTRIBUTION_F_MAX,
        dt: float = CYCLE_TIME,
        solver: str = "fast",
        velocity_feedforward: bool = True,
    ) -> None:
        if not (math.isfinite(f_min) and math.isfinite(f_max) and 0.0 <= f_min < f_max):
            raise InputError(f"need finite 0 <= f_min < f_max [N], got {f_min}, {f_max}")
        if not (math.isfinite(dt) and dt > 0.0):
            raise InputError(f"dt must be finite and > 0 s, got {dt}")
        if winch is not None and not isinstance(winch, WinchParameters):
            raise InputError(
                f"winch must be a WinchParameters (or None), got {type(winch).__name__} {winch!r}"
            )
        self.robot = robot
        self.platform = platform
        self.winch = winch if winch is not None else WinchParameters()
        self.m = robot.n_cables
        self.dt = float(dt)
        self.f_min = float(f_min)
        self.f_max = float(f_max)
        self._lo = np.full(self.m, self.f_min)
        self._hi = np.full(self.m, self.f_max)
        self._allocator = make_allocator(self.m, N_DOF, solver, f_ref=None)
        self.velocity_feedforward = bool(velocity_feedforward)
        # one tuple for every command (the plant recognises the same object cycle to cycle)
        self._all_pi: tuple[str, ...] = (DRIVE_PI,) * self.m

    def _feedforward(self, nominal: NominalState) -> FloatArray:
        """The v_ff of the command [m/s], shape (m,): IK velocities, or zeros without FF."""
        if self.velocity_feedforward:
            return nominal.velocities.copy()
        return np.zeros(self.m)

    @classmethod
    def from_model(cls, model: Any, **options: Any) -> CdprController:
        """Build from a loaded robot (``msarm.cdpr.robot_model.CableRobotModel`` or alike).

        Reads ``model.robot``, ``mass``, ``inertia``, ``com`` and ``gravity``.

        Args:
            model: The robot model.
            **options: Keyword arguments of the controller class.

        Returns:
            The controller.
        """
        platform = PlatformParameters(
            mass=float(model.mass),
            inertia=np.asarray(model.inertia, dtype=np.float64),
            com=np.asarray(model.com, dtype=np.float64),
            gravity=np.asarray(model.gravity, dtype=np.float64),
        )
        return cls(model.robot, platform, **options)

    def nominal(
        self,
        r: ArrayLike,
        v: ArrayLike | None = None,
        a: ArrayLike | None = None,
        *,
        R: ArrayLike | None = None,
        omega: ArrayLike | None = None,
        alpha: ArrayLike | None = None,
    ) -> NominalState:
        """Inverse kinematics, platform wrench and desired forces at a reference sample.

        Args:
            r: Platform position in K_0 [m], shape (3,).
            v: Velocity [m/s], shape (3,); zero if None.
            a: Acceleration [m/s^2], shape (3,); zero if None.
            R: Rotation matrix, shape (3, 3); identity if None.
            omega: Angular velocity in K_0 [rad/s], shape (3,); zero if None.
            alpha: Angular acceleration in K_0 [rad/s^2], shape (3,); zero if None.

        Returns:
            The nominal state (see :class:`NominalState`).

        Raises:
            InputError: On invalid shapes or values.
        """
        r_ = _vector3(r, "r", "m")
        v_ = _vector3(v, "v", "m/s")
        a_ = _vector3(a, "a", "m/s^2")
        w_ = _vector3(omega, "omega", "rad/s")
        al_ = _vector3(alpha, "alpha", "rad/s^2")
        R_ = _IDENTITY if R is None else np.asarray(R, dtype=np.float64)
        lengths, l_dot, l_ddot, At = cable_motion(self.robot, r_, R_, v_, w_, a_, al_)
        wrench = self.platform.wrench(r_, R_, v_, w_, a_, al_)
        result = self._allocator.solve(At, -wrench, self._lo, self._hi)
        return NominalState(
            lengths, l_dot, l_ddot, At, wrench, np.asarray(result.f, dtype=float), result.feasible
        )

    def reset(self) -> None:  # noqa: B027 - stateless controllers keep the no-op
        """Forget the controller's state (start of a run)."""

    def step(
        self,
        r: ArrayLike,
        v: ArrayLike | None = None,
        a: ArrayLike | None = None,
        measurement: CdprReadingsLike | CdprMeasurement | None = None,
        *,
        R: ArrayLike | None = None,
        omega: ArrayLike | None = None,
        alpha: ArrayLike | None = None,
    ) -> CdprCommand:
        """One control cycle.

        Args:
            r: Reference platform position in K_0 [m], shape (3,).
            v: Reference velocity [m/s], shape (3,); zero if None.
            a: Reference acceleration [m/s^2], shape (3,); zero if None.
            measurement: Sensor readings (see :class:`CdprMeasurement`); only the readings
                the controller uses must be present.
            R: Reference rotation, shape (3, 3); identity if None.
            omega: Reference angular velocity in K_0 [rad/s], shape (3,); zero if None.
            alpha: Reference angular acceleration in K_0 [rad/s^2], shape (3,); zero if None.

        Returns:
            The command for the drives.

        Raises:
            InputError: On invalid references or missing/invalid sensor readings.
        """
        nominal = self.nominal(r, v, a, R=R, omega=omega, alpha=alpha)
        return self._command(np.asarray(r, dtype=float), nominal, measurement)

    @abstractmethod
    def _command(self, r: FloatArray, nominal: NominalState, measurement: Any) -> CdprCommand:
        """The controller's law from the nominal state and the readings."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}(m={self.m}, f=[{self.f_min:g}, {self.f_max:g}] N)"


class InverseKinematicsController(CdprController):
    """IKC: set lengths from inverse kinematics only, all drives PI; reads no sensor.

    Args:
        robot: Cable geometry.
        platform: Platform mass properties (the desired forces are still computed and
            reported, as the paper's Fig. 11 plots them).
        **options: ``winch``, ``f_min``, ``f_max``, ``dt``, ``solver`` of
            :class:`CdprController`.
    """

    name: ClassVar[str] = "ikc"

    def __init__(self, robot: CableRobot, platform: PlatformParameters, **options: Any) -> None:
        super().__init__(robot, platform, **options)

    def _command(self, r: FloatArray, nominal: NominalState, measurement: Any) -> CdprCommand:
        zeros = np.zeros(self.m)
        return CdprCommand(
            l_set=nominal.lengths.copy(),
            v_ff=self._feedforward(nominal),
            drive_mode=self._all_pi,
            l_ik=nominal.lengths,
            delta_l=zeros,
            h=zeros.copy(),
            f_desired=nominal.forces,
            target=np.full(self.m, np.nan),
            force_controlled=(),
            feasible=nominal.feasible,
        )


# --------------------------------------------------------------------------- pair choice


class PairSelector(ABC):
    """Chooses the force-controlled cable set along a trajectory."""

    candidates: tuple[tuple[int, ...], ...]

    @abstractmethod
    def select(
        self, r: FloatArray, structure_matrix: FloatArray, current: tuple[int, ...] | None
    ) -> tuple[int, ...]:
        """The set to force-control at position r [m] with structure matrix A^T (6, m).

        Args:
            r: Reference platform position in K_0 [m], shape (3,).
            structure_matrix: A^T at the reference pose, shape (6, m).
            current: The set chosen at the previous cycle (None at the first).

        Returns:
            One of ``candidates`` (0-based cable indices, ascending).
        """

    def reset(self) -> None:  # noqa: B027 - stateless selectors keep the no-op
        """Forget any state."""


def _pair(value: ArrayLike, name: str) -> tuple[int, ...]:
    arr = np.asarray(value)
    if arr.ndim != 1 or arr.size < 1 or not np.issubdtype(arr.dtype, np.integer):
        raise InputError(f"{name} must be a sequence of cable indices, got {value!r}")
    out = tuple(sorted(int(i) for i in arr))
    if len(set(out)) != len(out) or out[0] < 0:
        raise InputError(f"{name} must hold distinct cable indices >= 0, got {value!r}")
    return out


class FixedPair(PairSelector):
    """Always the same force-controlled set.

    Args:
        pair: 0-based cable indices, e.g. ``(0, 1)`` for the paper's cables 1, 2.
    """

    def __init__(self, pair: ArrayLike) -> None:
        self.pair = _pair(pair, "pair")
        self.candidates = (self.pair,)

    def select(
        self, r: FloatArray, structure_matrix: FloatArray, current: tuple[int, ...] | None
    ) -> tuple[int, ...]:
        """Return the fixed set."""
        return self.pair

    def __repr__(self) -> str:
        return f"FixedPair({self.pair})"


class RegionPairSelector(PairSelector):
    """Pair by region of the workspace: ``positive`` where y > y_split, else ``negative``.

    Paper 000 force-controls cables 1, 2 in the region of Fig. 7a and 3, 4 in that of
    Fig. 7b, and switches on the plane y = 0 (Sec. 4, rectangular path). With a hysteresis
    band the pair changes only once y is beyond ``y_split +- hysteresis``.

    Args:
        y_split: The switching plane's y [m].
        positive: Pair used where y > y_split (default ``(0, 1)``, the paper's 1, 2).
        negative: Pair used where y <= y_split (default ``(2, 3)``, the paper's 3, 4).
        hysteresis: Half-width of the band around y_split where the pair is kept [m], >= 0.
    """

    def __init__(
        self,
        y_split: float = 0.0,
        positive: ArrayLike = PAIR_12,
        negative: ArrayLike = PAIR_34,
        hysteresis: float = 0.0,
    ) -> None:
        if not (math.isfinite(y_split) and math.isfinite(hysteresis) and hysteresis >= 0.0):
            raise InputError(
                f"need finite y_split and hysteresis >= 0 m, got {y_split}, {hysteresis}"
            )
        self.y_split = float(y_split)
        self.hysteresis = float(hysteresis)
        self.positive = _pair(positive, "positive")
        self.negative = _pair(negative, "negative")
        self.candidates = (self.positive, self.negative)

    def select(
        self, r: FloatArray, structure_matrix: FloatArray, current: tuple[int, ...] | None
    ) -> tuple[int, ...]:
        """Return the pair of the region of r (kept inside the hysteresis band)."""
        y = float(r[1])
        if current is not None and abs(y - self.y_split) <= self.hysteresis:
            return current
        return self.positive if y > self.y_split else self.negative

    def __repr__(self) -> str:
        return (
            f"RegionPairSelector(y_split={self.y_split:g}, positive={self.positive}, "
            f"negative={self.negative}, hysteresis={self.hysteresis:g})"
        )


class SensitivityPairSelector(PairSelector):
    """Pair with the smallest sensitivity index sigma (``msarm.cdpr.sensitivity``).

    Switches from the current set only when another candidate's sigma is lower by more than
    ``hysteresis``, so the choice does not chatter where two indices are close.

    Args:
        candidates: The sets to choose from (default the paper's ``(0, 1)`` and ``(2, 3)``).
        hysteresis: Required improvement of sigma to switch [N], >= 0.
        error: Force-error bound e of the index [N], > 0.
    """

    def __init__(
        self,
        candidates: tuple[ArrayLike, ...] = (PAIR_12, PAIR_34),
        hysteresis: float = 0.1,
        error: float = 1.0,
    ) -> None:
        if len(candidates) < 1:
            raise InputError("SensitivityPairSelector needs at least one candidate set")
        if not (math.isfinite(hysteresis) and hysteresis >= 0.0):
            raise InputError(f"hysteresis must be finite and >= 0 N, got {hysteresis}")
        self.candidates = tuple(_pair(c, "candidate") for c in candidates)
        self.hysteresis = float(hysteresis)
        self.error = float(error)

    def sigmas(self, structure_matrix: FloatArray) -> FloatArray:
        """The index sigma of every candidate [N], shape (k,)."""
        return np.array(
            [
                float(sensitivity_index(structure_matrix, list(c), self.error))
                for c in self.candidates
            ]
        )

    def select(
        self, r: FloatArray, structure_matrix: FloatArray, current: tuple[int, ...] | None
    ) -> tuple[int, ...]:
        """Return the candidate with the smallest sigma (with hysteresis)."""
        sig = self.sigmas(structure_matrix)
        best = int(np.argmin(sig))
        if current is not None and current in self.candidates:
            k = self.candidates.index(current)
            if not sig[best] < sig[k] - self.hysteresis:
                return current
        return self.candidates[best]

    def __repr__(self) -> str:
        return (
            f"SensitivityPairSelector(candidates={self.candidates}, hysteresis={self.hysteresis:g})"
        )


def _selector(spec: PairSelector | str | ArrayLike) -> PairSelector:
    if isinstance(spec, PairSelector):
        return spec
    if isinstance(spec, str):
        if spec == "region":
            return RegionPairSelector()
        if spec == "sensitivity":
            return SensitivityPairSelector()
        raise InputError(
            f"pair_selector must be 'region', 'sensitivity', a cable pair or a PairSelector, "
            f"got {spec!r}"
        )
    return FixedPair(spec)


# --------------------------------------------------------------------------- hybrid control

Feedback = Literal["force", "torque", "following_error"]
_DEFAULT_GAINS: dict[str, PIDGains] = {
    "force": HC_F_GAINS,
    "torque": HC_TAU_GAINS,
    "following_error": HC_E_GAINS,
}
_READING: dict[str, tuple[str, str]] = {
    "force": ("load_cell", "N"),
    "torque": ("motor_torque", "N m"),
    "following_error": ("following_error", "m"),
}


class HybridController(CdprController):
    """Hybrid joint-space control (paper 000, Sec. 3, Fig. 8): n cables by length, r by force.

    See the module docstring for the law and the sign conventions.

    Args:
        robot: Cable geometry (m > 6 cables).
        platform: Platform mass properties.
        feedback: ``"force"`` (HC-f), ``"torque"`` (HC-tau) or ``"following_error"`` (HC-e).
        gains: High-level PID gains (eq. 11); Table 2's row of the feedback if None.
        pair_selector: ``"region"`` (default), ``"sensitivity"``, a fixed pair such as
            ``(0, 1)``, or a :class:`PairSelector`. Ignored with ``all_cables``.
        all_cables: Force-control every cable (paper 000, test 51).
        delta: Step of alpha per cycle of eq. 10 [rad], > 0.
        start_active: Start with h = 1 on the first pair instead of ramping it in from 0.
        friction_model: Include tau_F (eq. 5) and f_F (eq. 7) in the set values; False sets
            them to 0 (Fig. 10, last column).
        delta_l_limit: Bound on |Delta l| of the PID [m] (anti-windup); None: no bound.
        filter_time: Time constant of a first-order low-pass on the feedback reading [s],
            >= 0; 0 (default) feeds the raw reading. Paper 000 smooths the motor torque of
            HC-tau with a filter (Sec. 3, not specified) and feeds the FE of HC-e raw.
            Discretised by backward Euler: ``y_k = y_{k-1} + T / (T + T_f) (x_k - y_{k-1})``,
            started at the first reading.
        fe_feedforward: HC-e only (msarm's addition, off by default as in paper 000): add
            to the set length of every switchable cable, in the share ``1 - h`` it is
            position-controlled, the following error eq. 9 predicts for its desired force.
            Its drive runs pure P (so that it can be switched to force control), which leaves
            the cable longer than its set length by that following error; the paper reports
            this did not affect its robot's accuracy, on msarm's simulated one it doubles
            HC-e's mean position error (see the README).
        **options: ``winch``, ``f_min``, ``f_max``, ``dt``, ``solver`` of
            :class:`CdprController`.

    Raises:
        InputError: On an unknown feedback, invalid pairs (cable index out of range, not
            m - 6 cables) or invalid parameters.
    """

    name: ClassVar[str] = "hc"
    tracks_distribution: ClassVar[bool] = True

    def __init__(
        self,
        robot: CableRobot,
        platform: PlatformParameters,
        *,
        feedback: Feedback = "following_error",
        gains: PIDGains | None = None,
        pair_selector: PairSelector | str | ArrayLike = "region",
        all_cables: bool = False,
        delta: float = DEFAULT_DELTA,
        start_active: bool = False,
        friction_model: bool = True,
        delta_l_limit: float | None = DEFAULT_DELTA_L_LIMIT,
        filter_time: float = 0.0,
        fe_feedforward: bool = False,
        **options: Any,
    ) -> None:
        super().__init__(robot, platform, **options)
        if fe_feedforward and feedback != "following_error":
            raise InputError(
                "fe_feedforward: only HC-e (feedback='following_error') runs P drives whose "
                f"following error it compensates; got feedback={feedback!r}"
            )
        self.fe_feedforward = bool(fe_feedforward)
        if not (math.isfinite(filter_time) and filter_time >= 0.0):
            raise InputError(f"filter_time must be finite and >= 0 s, got {filter_time}")
        self.filter_time = float(filter_time)
        self._filter_gain = self.dt / (self.dt + self.filter_time)
        self._filtered: FloatArray | None = None
        if feedback not in _DEFAULT_GAINS:
            raise InputError(f"feedback must be one of {sorted(_DEFAULT_GAINS)}, got {feedback!r}")
        self.feedback = feedback
        if gains is not None and not isinstance(gains, PIDGains):
            raise InputError(
                f"gains must be a PIDGains (or None), got {type(gains).__name__} {gains!r}"
            )
        self.gains = gains if gains is not None else _DEFAULT_GAINS[feedback]
        self.all_cables = bool(all_cables)
        self.friction_model = bool(friction_model)
        self.start_active = bool(start_active)
        m = self.m
        if self.all_cables:
            self.selector: PairSelector = FixedPair(range(m))
        else:
            self.selector = _selector(pair_selector)
            for c in self.selector.candidates:
                if c[-1] >= m or len(c) != m - N_DOF:
                    raise InputError(
                        f"force-controlled set {c} must name m - 6 = {m - N_DOF} cables in [0, {m})"
                    )
        switchable = sorted({i for c in self.selector.candidates for i in c})
        self.switchable: tuple[int, ...] = tuple(switchable)
        self._switchable_mask = np.zeros(m, dtype=bool)
        self._switchable_mask[switchable] = True
        if feedback == "following_error":
            self.sign = float(np.sign(self.winch.following_error.compliance))
            modes = [DRIVE_P if self._switchable_mask[i] else DRIVE_PI for i in range(m)]
        else:
            self.sign = 1.0
            modes = [DRIVE_PI] * m
        self.drive_mode: tuple[str, ...] = tuple(modes)
        self.delta = float(delta)
        self._factors = [SwitchingFactor(self.delta) for _ in range(m)]
        limit = None if delta_l_limit is None else float(delta_l_limit)
        if limit is not None and not (math.isfinite(limit) and limit > 0.0):
            raise InputError(f"delta_l_limit must be finite and > 0 m (or None), got {limit}")
        self.delta_l_limit = limit
        self._pid = DiscretePID(
            self.gains,
            m,
            self.dt,
            output_min=None if limit is None else -limit,
            output_max=limit,
        )
        self._pair: tuple[int, ...] | None = None

    @property
    def pair(self) -> tuple[int, ...] | None:
        """The force-controlled set chosen at the last cycle (None before the first)."""
        return self._pair

    @property
    def h(self) -> FloatArray:
        """Current scaling factors h of eq. 10 [-], shape (m,)."""
        return np.array([f.h for f in self._factors])

    def reset(self) -> None:
        """Force control off on all cables (h = 0), PID state zero, no pair chosen."""
        self._factors = [SwitchingFactor(self.delta) for _ in range(self.m)]
        self._pid.reset()
        self._pair = None
        self._filtered = None
        self.selector.reset()

    def targets(self, nominal: NominalState, cables: ArrayLike) -> FloatArray:
        """Set values of the feedback for some cables, in its unit (N, N m or m).

        HC-f: ``f_i + f_F(f_i, v_i)``; HC-tau: eq. 3; HC-e: eq. 9 of eq. 3's torque.

        Args:
            nominal: The nominal state of this cycle.
            cables: Cable indices, shape (k,).

        Returns:
            Shape (k,).
        """
        idx = np.asarray(cables, dtype=np.intp)
        f = nominal.forces[idx]
        v = nominal.velocities[idx]
        if self.feedback == "force":
            if not self.friction_model:
                return f.copy()
            return f + self.winch.friction.force(f, v)
        a = nominal.accelerations[idx]
        # one copy of eq. 3 and eq. 9 (msarm.cdpr.force_estimation inverts the same formulas)
        if self.feedback == "torque":
            return self.winch.motor_torque(f, v, a, friction_model=self.friction_model)
        return self.winch.following_error_for_force(
            f,
            v,
            a,
            friction_model=self.friction_model,
            velocity_feedforward=self.velocity_feedforward,
        )

    def _command(self, r: FloatArray, nominal: NominalState, measurement: Any) -> CdprCommand:
        m = self.m
        pair = self.selector.select(r, nominal.structure_matrix, self._pair)
        if self._pair is None and self.start_active:
            for i in pair:
                self._factors[i] = SwitchingFactor(self.delta, active=True)
        self._pair = pair
        chosen = set(pair)
        for i in self.switchable:
            self._factors[i].set_active(i in chosen)
        steps = [f.step() for f in self._factors]  # each the factor's h after its step
        h = np.array(steps)
        engaged = np.array(
            [f.active or hf > 0.0 for f, hf in zip(self._factors, steps, strict=True)]
        )
        reading, unit = _READING[self.feedback]
        measured = _reading(measurement, reading, unit, m, self.name)
        if self.filter_time > 0.0:
            if self._filtered is None:
                self._filtered = measured.copy()
            else:
                self._filtered += self._filter_gain * (measured - self._filtered)
            measured = self._filtered
        sw = np.flatnonzero(self._switchable_mask)
        target = np.full(m, np.nan)
        target[sw] = self.targets(nominal, sw)
        error = np.zeros(m)
        error[engaged] = self.sign * (measured[engaged] - target[engaged])
        delta_l = self._pid.step(error)
        self._pid.reset(~engaged)
        delta_l[~engaged] = 0.0
        l_set = nominal.lengths + h * delta_l
        if self.fe_feedforward:  # a P drive leaves the cable FE longer than its set length
            l_set[sw] += (1.0 - h[sw]) * target[sw]
        return CdprCommand(
            l_set=l_set,
            v_ff=self._feedforward(nominal),
            drive_mode=self.drive_mode,
            l_ik=nominal.lengths,
            delta_l=delta_l,
            h=h,
            f_desired=nominal.forces,
            target=target,
            force_controlled=tuple(i for i in range(m) if self._factors[i].active),
            feasible=nominal.feasible,
        )

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(feedback={self.feedback!r}, selector={self.selector!r}, "
            f"delta={self.delta:g}, gains={self.gains})"
        )


class HybridForceController(HybridController):
    """HC-f (Fig. 8a): load-cell feedback, ``f_set = f_i + f_F(f_i, v_i)``; drives PI.

    Arguments as :class:`HybridController` without ``feedback`` (Table 2 gains: K_HL =
    3.0e-4 m/N, T_i = 70 ms, T_v = 15 ms, T_d = 5 ms). ``filter_time`` defaults to
    :data:`HC_F_FILTER_TIME` (5 ms, msarm's choice, the paper names no load-cell filter): on
    msarm's simulated robot (``msarm.plant.cdpr_plant``, stiff Dyneema cables, noisy load
    cells) Table 2's PID oscillates on the raw reading (a limit cycle of about 13 Hz) and
    settles with it; pass ``filter_time=0.0`` for the raw reading.
    """

    name: ClassVar[str] = "hc-f"

    def __init__(
        self,
        robot: CableRobot,
        platform: PlatformParameters,
        *,
        filter_time: float = HC_F_FILTER_TIME,
        **options: Any,
    ) -> None:
        super().__init__(robot, platform, feedback="force", filter_time=filter_time, **options)


class HybridTorqueController(HybridController):
    """HC-tau (Fig. 8b): motor-torque feedback, ``tau_i`` of eq. 3; drives PI.

    Arguments as :class:`HybridController` without ``feedback`` (Table 2 gains: K_HL =
    2.0e-2 m/(N m), T_i = 200 ms, PI). ``friction_model=False`` sets tau_F = 0.
    ``filter_time`` defaults to :data:`HC_TAU_FILTER_TIME` (20 ms): paper 000 smooths the
    motor torque with a filter it does not specify; with the raw torque, Table 2's gains make
    the loop unstable (the PI drive turns 1 mm of set-length change into about 0.4 N m at
    once, a loop gain near 8).
    """

    name: ClassVar[str] = "hc-tau"

    def __init__(
        self,
        robot: CableRobot,
        platform: PlatformParameters,
        *,
        filter_time: float = HC_TAU_FILTER_TIME,
        **options: Any,
    ) -> None:
        super().__init__(robot, platform, feedback="torque", filter_time=filter_time, **options)


class HybridFollowingErrorController(HybridController):
    """HC-e (Fig. 8c): FE feedback, ``FE_set`` = eq. 9 of ``tau_i``; switchable cables P drive.

    Arguments as :class:`HybridController` without ``feedback`` (Table 2 gains: K_HL = 0.45,
    T_i = 7 ms, PI).
    """

    name: ClassVar[str] = "hc-e"

    def __init__(self, robot: CableRobot, platform: PlatformParameters, **options: Any) -> None:
        super().__init__(robot, platform, feedback="following_error", **options)


class AllCablesFollowingErrorController(HybridController):
    """HC-e on all cables (paper 000, test 51): every cable FE-controlled, all P drives.

    Arguments as :class:`HybridController` without ``feedback``, ``all_cables`` and
    ``pair_selector``.
    """

    name: ClassVar[str] = "hc-e-all"

    def __init__(self, robot: CableRobot, platform: PlatformParameters, **options: Any) -> None:
        for key in ("pair_selector", "all_cables", "feedback"):
            if key in options:
                raise InputError(f"hc-e-all controls every cable by FE; {key!r} is not an option")
        super().__init__(robot, platform, feedback="following_error", all_cables=True, **options)


# --------------------------------------------------------------------------- nullspace control


class NullspaceController(CdprController):
    """NC: keep the cable forces near 12 N, raise those below 7 N, without moving the platform.

    Paper 000 (Sec. 4.2) uses the nullspace control of its reference [4] (not available
    here) and describes its effect: the forces stay "as close as possible to the mean value
    12 N" and are corrected "when they become lower than 7 N". msarm implements this law
    (its own, with those numbers):

    1. Tension estimate from the load cells, the friction force removed: the load cell reads
       ``f + f_F(f, v_i)`` (eq. 7, linear in f at a given v), solved exactly for f:
       ``f_hat = (y - f_F(0, v)) / (1 + f_F(1, v) - f_F(0, v))`` (``friction_model=False``:
       ``f_hat = y``).
    2. Force error ``e_i = (f_hat_i - 12 N) + k_low min(f_hat_i - 7 N, 0)`` [N]: the distance
       to the mean, plus a stronger pull on cables below 7 N (``k_low = 4``).
    3. Length correction in the nullspace of A^T, with ``P_N = I - A (A^T A)^-1 A^T`` (the
       orthogonal projector onto ``{dl : A^T dl = 0}``, m x m) at the current pose::

           I_k      = P_N (I_{k-1} + k_i T e_k)
           dl_k     = I_k + P_N k_p e_k
           l_set    = l_IK + dl_k

       Cable length changes in that nullspace are not produced by any platform twist
       (``dl = -A twist`` spans the range of A, orthogonal to it), so the pose is unchanged
       to first order; with equally stiff cables the tension change ``-k dl`` is an internal
       force (``A^T df = 0``) and keeps the equilibrium. Shortening a cable raises its
       tension, so ``dl`` follows ``+e`` (pay out when the tension is above target). The
       integral is re-projected every cycle as the pose moves. ``|dl|`` is limited by
       scaling the whole vector (keeping it in the nullspace) to ``delta_l_limit``.

    Steady state: ``P_N e = 0``, i.e. the tensions are the equilibrium forces closest to
    12 N in the 2-norm, pushed up where a cable is below 7 N.

    Args:
        robot: Cable geometry (m > 6).
        platform: Platform mass properties (only for the reported desired forces).
        mean_force: f_bar [N] (12 N), at most ``f_max``.
        low_force: f'_min [N] (7 N), at most ``mean_force``.
        low_weight: k_low, extra weight of the error below ``low_force`` [-], >= 0.
        k_i: Integral gain [m/(N s)], >= 0 (default 4.3e-3, K_HL / T_i of HC-f's Table 2).
        k_p: Proportional gain [m/N], >= 0 (default 0).
        friction_model: Remove the friction force f_F (eq. 7) from the load-cell reading.
        delta_l_limit: Bound on max |dl| [m]; None: no bound.
        **options: ``winch``, ``f_min``, ``f_max``, ``dt``, ``solver`` of
            :class:`CdprController`.

    Raises:
        InputError: As :class:`CdprController`; with 6 cables or fewer; a negative or
            non-finite level, weight or gain; ``low_force > mean_force`` or
            ``mean_force > f_max``; a ``delta_l_limit`` that is not > 0.
    """

    name: ClassVar[str] = "nc"

    def __init__(
        self,
        robot: CableRobot,
        platform: PlatformParameters,
        *,
        mean_force: float = NC_MEAN_FORCE,
        low_force: float = NC_LOW_FORCE,
        low_weight: float = 4.0,
        k_i: float = HC_F_GAINS.k / HC_F_GAINS.t_i,
        k_p: float = 0.0,
        friction_model: bool = True,
        delta_l_limit: float | None = DEFAULT_DELTA_L_LIMIT,
        **options: Any,
    ) -> None:
        super().__init__(robot, platform, **options)
        if self.m <= N_DOF:
            raise InputError(f"nullspace control needs more than 6 cables, got {self.m}")
        values = {
            "mean_force": mean_force,
            "low_force": low_force,
            "low_weight": low_weight,
            "k_i": k_i,
            "k_p": k_p,
        }
        for key, value in values.items():
            if not (math.isfinite(value) and value >= 0.0):
                raise InputError(f"NC {key} must be finite and >= 0, got {value}")
        if not low_force <= mean_force <= self.f_max:
            raise InputError(
                f"NC force levels must meet low_force <= mean_force <= f_max: the cables are "
                f"kept near mean_force and pulled up harder below low_force, within the "
                f"distribution's upper bound; got low_force={low_force:g}, "
                f"mean_force={mean_force:g}, f_max={self.f_max:g} N"
            )
        if delta_l_limit is not None and not (math.isfinite(delta_l_limit) and delta_l_limit > 0.0):
            raise InputError(
                f"delta_l_limit must be finite and > 0 m (or None), got {delta_l_limit}"
            )
        self.mean_force = float(mean_force)
        self.low_force = float(low_force)
        self.low_weight = float(low_weight)
        self.k_i = float(k_i)
        self.k_p = float(k_p)
        self.friction_model = bool(friction_model)
        self.delta_l_limit = delta_l_limit
        self._integral = np.zeros(self.m)

    def reset(self) -> None:
        """Zero the nullspace correction."""
        self._integral = np.zeros(self.m)

    @staticmethod
    def nullspace_projector(structure_matrix: FloatArray) -> FloatArray:
        """P_N, the orthogonal projector onto the nullspace of A^T [-], shape (m, m).

        Args:
            structure_matrix: A^T, shape (6, m), full row rank.

        Returns:
            ``I - A (A^T A)^-1 A^T`` computed from the SVD of A^T.
        """
        _, _, vt = np.linalg.svd(structure_matrix)
        basis = vt[N_DOF:].T  # (m, m - 6), orthonormal
        return basis @ basis.T

    def estimate_forces(self, load_cell: FloatArray, velocities: FloatArray) -> FloatArray:
        """Cable tensions from load-cell readings, the friction force removed [N], shape (m,).

        Args:
            load_cell: Load-cell readings [N], shape (m,).
            velocities: Cable velocities [m/s], shape (m,).

        Returns:
            f_hat with ``f_hat + f_F(f_hat, v) = load_cell`` (eq. 7 is affine in f).
        """
        if not self.friction_model:
            return load_cell.copy()
        f0 = self.winch.friction.force(np.zeros(self.m), velocities)
        f1 = self.winch.friction.force(np.ones(self.m), velocities)
        return (load_cell - f0) / (1.0 + f1 - f0)

    def force_error(self, f_hat: FloatArray) -> FloatArray:
        """``e = (f_hat - mean_force) + low_weight min(f_hat - low_force, 0)`` [N], (m,)."""
        return (f_hat - self.mean_force) + self.low_weight * np.minimum(f_hat - self.low_force, 0.0)

    def _command(self, r: FloatArray, nominal: NominalState, measurement: Any) -> CdprCommand:
        m = self.m
        load = _reading(measurement, "load_cell", "N", m, self.name)
        f_hat = self.estimate_forces(load, nominal.velocities)
        error = self.force_error(f_hat)
        P = self.nullspace_projector(nominal.structure_matrix)
        self._integral = P @ (self._integral + self.k_i * self.dt * error)
        delta_l = self._integral + self.k_p * (P @ error)
        if self.delta_l_limit is not None:
            peak = float(np.abs(delta_l).max())
            if peak > self.delta_l_limit:
                scale = self.delta_l_limit / peak
                delta_l = delta_l * scale
                self._integral = self._integral * scale
        return CdprCommand(
            l_set=nominal.lengths + delta_l,
            v_ff=self._feedforward(nominal),
            drive_mode=self._all_pi,
            l_ik=nominal.lengths,
            delta_l=delta_l,
            h=np.ones(m),
            f_desired=nominal.forces,
            target=f_hat,
            force_controlled=tuple(range(m)),
            feasible=nominal.feasible,
        )


# --------------------------------------------------------------------------- registry

CDPR_CONTROLLERS: dict[str, type[CdprController]] = {
    "ikc": InverseKinematicsController,
    "hc-f": HybridForceController,
    "hc-tau": HybridTorqueController,
    "hc-e": HybridFollowingErrorController,
    "hc-e-all": AllCablesFollowingErrorController,
    "nc": NullspaceController,
}
"""The controllers of paper 000 by name."""


_COMMON_OPTIONS = ("winch", "f_min", "f_max", "dt", "solver", "velocity_feedforward")
_HYBRID_OPTIONS = (
    "gains",
    "pair_selector",
    "delta",
    "start_active",
    "friction_model",
    "delta_l_limit",
    "filter_time",
)
_OPTIONS: dict[str, tuple[str, ...]] = {
    "ikc": _COMMON_OPTIONS,
    "hc-f": _COMMON_OPTIONS + _HYBRID_OPTIONS,
    "hc-tau": _COMMON_OPTIONS + _HYBRID_OPTIONS,
    "hc-e": _COMMON_OPTIONS + _HYBRID_OPTIONS + ("fe_feedforward",),
    "hc-e-all": _COMMON_OPTIONS
    + tuple(o for o in _HYBRID_OPTIONS if o != "pair_selector")
    + ("fe_feedforward",),
    "nc": _COMMON_OPTIONS
    + ("mean_force", "low_force", "low_weight", "k_i", "k_p", "friction_model", "delta_l_limit"),
}


_OPTION_TYPES: dict[str, tuple[type, ...]] = {
    "winch": (),
    "f_min": (float,),
    "f_max": (float,),
    "dt": (float,),
    "solver": (str,),
    "velocity_feedforward": (bool,),
    "gains": (),
    "pair_selector": (str,),
    "delta": (float,),
    "start_active": (bool,),
    "friction_model": (bool,),
    "delta_l_limit": (float, type(None)),
    "filter_time": (float,),
    "fe_feedforward": (bool,),
    "mean_force": (float,),
    "low_force": (float,),
    "low_weight": (float,),
    "k_i": (float,),
    "k_p": (float,),
}
"""Plain value types of every option (what ``KEY=VALUE`` text gives); () for an object only."""
_OPTION_OBJECTS: dict[str, str] = {
    "winch": "a WinchParameters (msarm.cdpr.force_estimation)",
    "gains": "a PIDGains (msarm.control.pid)",
    "pair_selector": "a fixed cable pair such as (0, 1) or a PairSelector",
}
"""What the Python API takes for an option that plain text cannot give (wholly or in part)."""
_TYPE_TEXT = {
    bool: "true or false",
    int: "an integer",
    float: "a number",
    str: "a word",
    type(None): "null",
}


def _plain_type_of(value: object, types: tuple[type, ...]) -> bool:
    """Whether ``value`` is of one of ``types`` (a bool is no number, an int is a float)."""
    if isinstance(value, bool):
        return bool in types
    if isinstance(value, int):
        return int in types or float in types
    return any(isinstance(value, t) for t in types if t not in (bool, int))


def check_plain_options(name: str, options: dict[str, object]) -> None:
    """Check options given as plain values (``msarm cdpr run --option KEY=VALUE``).

    Each option must be one the controller takes, with a plain value (true/false, a number, a
    word, null) of its type: a bool option needs true or false, a float option a number (an
    integer too), an int option an integer. An option whose value is an object (``winch``,
    ``gains``) is refused, with the Python call that sets it.

    Args:
        name: The controller, one of :func:`list_cdpr_controllers`.
        options: Option name to value (as read from YAML text).

    Raises:
        InputError: An unknown controller; an option the controller does not take (the
            options plain values can set listed); an object option; or a value of the wrong
            type (the option, the expected type and the value named).
    """
    if name not in CDPR_CONTROLLERS:
        raise InputError(
            f"unknown CDPR controller {name!r}; valid names: {', '.join(CDPR_CONTROLLERS)}"
        )
    settable = sorted(k for k in _OPTIONS[name] if _OPTION_TYPES[k])
    for key, value in options.items():
        if key not in _OPTIONS[name]:
            raise InputError(
                f"invalid option for CDPR controller {name!r}: {key!r}; valid options: "
                f"{', '.join(settable)}"
            )
        types = _OPTION_TYPES[key]
        if not types:
            raise InputError(
                f"option {key!r} of CDPR controller {name!r} takes {_OPTION_OBJECTS[key]}: it "
                f"cannot be set from the command line (KEY=VALUE); set it in Python, "
                f"make_cdpr_controller({name!r}, model, {key}=...)"
            )
        if not _plain_type_of(value, types):
            expected = " or ".join(_TYPE_TEXT[t] for t in types)
            given = "null" if value is None else repr(value)
            python = ""
            if key in _OPTION_OBJECTS:
                python = (
                    f"; {_OPTION_OBJECTS[key]} can be set in Python only, "
                    f"make_cdpr_controller({name!r}, model, {key}=...)"
                )
            raise InputError(
                f"option {key!r} of CDPR controller {name!r} expects {expected}, got "
                f"{given}{python}"
            )


def list_cdpr_controllers() -> list[str]:
    """Names accepted by :func:`make_cdpr_controller`."""
    return list(CDPR_CONTROLLERS)


def make_cdpr_controller(
    name: str,
    robot: CableRobot | Any,
    platform: PlatformParameters | None = None,
    **options: Any,
) -> CdprController:
    """Build a CDPR controller by name.

    Args:
        name: One of :func:`list_cdpr_controllers`.
        robot: The cable geometry (with ``platform``), or a loaded robot model (with
            ``robot``, ``mass``, ``inertia``, ``com``, ``gravity`` attributes, e.g.
            ``msarm.cdpr.robot_model.CableRobotModel``) when ``platform`` is None.
        platform: Platform mass properties; read from ``robot`` if None.
        **options: Keyword arguments of the controller class.

    Returns:
        The controller.

    Raises:
        InputError: For an unknown name (the valid ones are listed) or invalid options.
    """
    cls = CDPR_CONTROLLERS.get(name)
    if cls is None:
        raise InputError(
            f"unknown CDPR controller {name!r}; valid names: {', '.join(CDPR_CONTROLLERS)}"
        )
    if platform is None and isinstance(robot, CableRobot):
        raise InputError(
            "make_cdpr_controller needs platform= (PlatformParameters) with a CableRobot, "
            "or a loaded robot model instead of the CableRobot"
        )
    try:
        if platform is None:
            return cls.from_model(robot, **options)
        return cls(robot, platform, **options)
    except TypeError as exc:  # an unknown keyword, or a value of the wrong type
        if "keyword argument" not in str(exc):
            raise InputError(
                f"invalid option value for CDPR controller {name!r}: {exc}; options given: "
                f"{options}"
            ) from exc
        valid = sorted(_OPTIONS.get(name, ()))
        raise InputError(
            f"invalid option for CDPR controller {name!r}: {exc}; valid options: {valid}"
        ) from exc
