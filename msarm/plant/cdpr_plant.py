"""The simulated IPAnema 3 Mini: MuJoCo platform, direct-drive winches, elastic cables, drives.

MuJoCo simulates the platform (one free body, ``models/ipanema_mini.xml``) at 1 kHz. Each of
the ``m`` cables is wound on a winch (drum radius ``r_D``, rotor plus drum inertia ``J_D``)
driven through a PLC position loop and a drive velocity loop, as in paper 000, Sec. 2.3.

Sign conventions (paper 000): the winch angle ``theta`` and the cable speed ``v = r_D dtheta/dt``
are positive when cable is **paid out** (as ``msarm.cdpr.winch_friction``); the motor torque
``tau`` is positive when it **hauls in** (holds the load), so that at constant speed eq. 3
reads ``tau = f r_D + tau_F(f, v)``. The following error is ``FE = l_set - l_motor`` (set
minus actual, Sec. 2.3), so a holding torque gives ``FE < 0``, the sign of ``c_f < 0`` in eq. 8
(``msarm.cdpr.following_error``), and paying out gives ``FE > 0``, the sign of ``c_v > 0``.

Per cable, every step ``h`` (the PLC cycle):

- PLC: ``v_cmd = v_ff + K_pos (l_set - l_motor)`` with the encoder's cable length
  ``l_motor = l_cal + r_D theta`` (sampled at the start of the cycle);
- drive (its loop is much faster than the PLC and is simulated as continuous, implicitly):
  ``tau = K_v (v - v_cmd) + (K_v / T_n) I``, ``dI/dt = v - v_cmd`` (PI), or ``I = 0`` (pure
  P), limited to ``+-tau_max`` (the integral is held while the torque saturates);
- winch: ``J_D / r_D dv/dt = f r_D - tau + tau_F(f, v)`` with the friction torque of eq. 5
  (it opposes the motion: negative while paying out, positive while hauling in);
- cable: unstretched length ``L0 = L0_ref + r_D theta``, stretch ``e = l(q) - L0`` with
  ``l(q)`` MuJoCo's tendon length, stiffness ``k = EA / (L0 + l_chain)``, tension
  ``f = max(0, k e + k tau_d de/dt)`` while taut, 0 when slack;
- platform: ``qfrc_applied = -J^T f`` with ``J = dl/dq`` MuJoCo's tendon Jacobian (a cable
  pulls the platform towards its frame anchor; the same convention as the arm plant).

Integration: the platform and the winches are advanced together by one linearly implicit
(backward) Euler step in their velocities: the cable force at the end of the step,
``f' = k e + (h k + c)(J v' - y)``, the drive torque and the friction slope enter the
equations of motion of the platform velocity ``v'`` and of the cable speeds ``y``. The winch
rows are diagonal, so a Schur complement leaves one ``nv x nv`` SPD system. Slack cables and
saturated drives are found by an active-set iteration (a cable that would push is slack, a
drive whose linear law exceeds its limit is saturated). The force so found is given to MuJoCo
as ``qfrc_applied`` and its (semi-implicit) Euler step reproduces ``v'``. Stiff cables
(``EA = 2e6 N``, about 1.4e6 N/m) stay stable at 1 ms.

Friction beyond the fitted range: the friction model of paper 000 was fitted for
``|v| <= v_H = 6 m/min`` and refuses faster speeds. Fast transients (vibrations, steps of the
set-point, fast trajectories) do exceed it; the plant then evaluates the model at ``+-v_H``
(``beyond_v_high="clamp"``, the default: a friction plateau, without the slope term) or
evaluates eq. 4 beyond it (``"extrapolate"``). Every step that ran beyond ``v_H`` is counted
per cable in :meth:`CdprPlant.ground_truth` (``friction_beyond_v_high``).

Load cell (pulley 3): it reads the platform-side force plus the friction of eq. 7,
``f + f_F(f, v)`` at the new tension and speed, while the cable is taut (paying out it reads
less than the platform feels, hauling in more); 0 when the cable is slack (no tension, so no
friction is transmitted); never negative.

Sensors: the motor encoder (angle, and the cable length ``l_motor`` it implies), the drive's
speed, the motor torque (from the current), the following error as the PLC computed it in the
last cycle (``l_set`` minus the ``l_motor`` sampled at the start of that cycle, the error its
position loop acted on), and the load cells; Gaussian noise from the plant's seeded generator.

Encoder calibration (homing): at :meth:`CdprPlant.reset` the encoder's cable length is set to
the kinematic length of the reset pose, ``l_motor = l_i(pose)``, under the reset tensions, as a
robot is homed at a known pose. Commanding the inverse-kinematics lengths of that pose with the
PI drive then holds the reset state exactly.

The physics of a step runs compiled (numba) in :func:`_step_kernel`, between MuJoCo's
``mj_step1`` and ``mj_step2``. Sensors (:meth:`CdprPlant.sense`) are what a controller may
read; ground truth (:meth:`CdprPlant.ground_truth`) never goes through them.
"""

from __future__ import annotations

import copy
import math
import numbers
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import mujoco
import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.cdpr.robot_model import (
    CableRobotModel,
    load_cable_robot,
    pose_from_qpos,
    qpos_from_pose,
    twist_from_qvel,
)
from msarm.errors import InputError, MsarmWarning
from msarm.numba_cache import drop_stale_kernels
from msarm.plant.arm_plant import SimulationDivergedError
from msarm.plant.cdpr_config import DEFAULT_CDPR_PLANT, DRIVE_MODES, CdprPlantConfig
from msarm.plant.instability import instability_found
from msarm.plant.seeding import seed_generator
from msarm.small_linalg import cholesky_solve

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = ["CdprPlant", "CdprSensorReadings", "SimulationDivergedError"]

FloatArray = NDArray[np.float64]

# ------------------------------------------------------------------ kernel layouts
# Scalar parameters of the kernel (``par``).
_P_H, _P_R, _P_JW, _P_EA, _P_LC, _P_TD, _P_KPOS, _P_KV, _P_TN = range(9)
_P_TAUMAX, _P_FRIC, _P_VL, _P_VH, _P_EXTRAP = range(9, 14)
_N_PAR = 14
# Rows of the per-cable state (``st``, shape (_N_STATE, m)).
_S_THETA = 0  # winch angle, paid out positive [rad]
_S_SPEED = 1  # cable speed at the drum, paid out positive [m/s]
_S_INTEG = 2  # PI integral of (v - v_cmd) [m]
_S_TENSION = 3  # platform-side tension [N]
_S_L0REF = 4  # unstretched length at theta = 0 [m]
_S_LCAL = 5  # encoder cable length at theta = 0 [m]
_S_LSET = 6  # commanded cable length [m]
_S_VFF = 7  # velocity feedforward [m/s]
_S_PI = 8  # 1: PI drive, 0: pure P
_S_TORQUE = 9  # motor torque, haul-in positive [N m]
_S_FRIC_TORQUE = 10  # friction torque tau_F that acted (eq. 5 sign) [N m]
_S_FRIC_FORCE = 11  # friction force f_F at the load cell (eq. 7) [N]
_S_LOAD_CELL = 12  # noise-free load-cell reading [N]
_S_STRETCH = 13  # stretch at the end of the step (linearised) [m]
_S_SAT = 14  # drive saturation: 0, +1 (at +tau_max) or -1
_S_BEYOND = 15  # number of steps with |v| > v_H
_S_VCMD = 16  # PLC velocity command [m/s]
_S_ACTIVE = 17  # 1: taut, 0: slack
_S_FE = 18  # following error of the last PLC cycle, l_set - l_motor [m]
_N_STATE = 19
_MAX_ACTIVE_SET_ITERATIONS = 30


@numba.njit(cache=True)
def _friction_eval(fric, row, f, v, v_low):  # pragma: no cover - compiled
    """Eq. 5/7 of paper 000 and its slope d/dv at (f [N], v [m/s]), SI coefficients.

    ``fric[row]`` holds the negative branch (c1, c2, c3, c4) and ``fric[row + 1]`` the positive
    one; inside ``|v| < v_low`` the quartic of eq. 6 joins them.
    """
    n1, n2, n3, n4 = fric[row, 0], fric[row, 1], fric[row, 2], fric[row, 3]
    p1, p2, p3, p4 = fric[row + 1, 0], fric[row + 1, 1], fric[row + 1, 2], fric[row + 1, 3]
    if v <= -v_low:
        return n1 * v + n2 * v * v + n3 * f + n4, n1 + 2.0 * n2 * v
    if v >= v_low:
        return p1 * v + p2 * v * v + p3 * f + p4, p1 + 2.0 * p2 * v
    L = v_low
    yn = -n1 * L + n2 * L * L + n3 * f + n4
    yp = p1 * L + p2 * L * L + p3 * f + p4
    dn = n1 - 2.0 * n2 * L
    dp = p1 + 2.0 * p2 * L
    b1 = -(3.0 * (yn - yp) + L * (dn + dp)) / (4.0 * L)
    b2 = (4.0 * (yn + yp) + L * (dn - dp)) / (4.0 * L**2)
    b3 = (yn - yp + L * (dn + dp)) / (4.0 * L**3)
    b4 = -(2.0 * (yn + yp) + L * (dn - dp)) / (4.0 * L**4)
    value = v * (b1 + v * (b2 + v * (b3 + v * b4)))
    slope = b1 + v * (2.0 * b2 + v * (3.0 * b3 + v * 4.0 * b4))
    return value, slope


@numba.njit(cache=True)
def _step_kernel(
    par,
    fric,
    st,
    lengths,
    jac_data,
    jac_rownnz,
    jac_rowadr,
    jac_colind,
    mass,
    qvel,
    qfrc_smooth,
    qfrc_out,
):  # pragma: no cover - compiled
    """One implicit step of winches, drives and cables; writes the cable forces on the platform.

    Args:
        par: Scalars, layout ``_P_*``, shape (14,).
        fric: SI friction coefficients (c1..c4) of tau_F negative, tau_F positive, f_F
            negative, f_F positive, shape (4, 4).
        st: Per-cable state, layout ``_S_*``, shape (19, m), updated in place.
        lengths: Tendon lengths l(q) [m], (m,).
        jac_data: MuJoCo ``ten_J`` (sparse values).
        jac_rownnz: MuJoCo ``ten_J_rownnz``.
        jac_rowadr: MuJoCo ``ten_J_rowadr``.
        jac_colind: MuJoCo ``ten_J_colind``.
        mass: Dense mass matrix [kg, kg m^2], (nv, nv).
        qvel: Platform velocity (MuJoCo qvel), (nv,).
        qfrc_smooth: All generalised forces but the cables' (passive - bias + external), (nv,).
        qfrc_out: Written: the cables' generalised force ``-J^T f``, (nv,).

    Returns:
        Number of active-set iterations.
    """
    h = par[_P_H]
    r = par[_P_R]
    mw = par[_P_JW] / (r * r)
    ea = par[_P_EA]
    lc = par[_P_LC]
    td = par[_P_TD]
    kpos = par[_P_KPOS]
    kvf = par[_P_KV] / r
    tn = par[_P_TN]
    fmax = par[_P_TAUMAX] / r
    fric_on = par[_P_FRIC] > 0.5
    v_low = par[_P_VL]
    v_high = par[_P_VH]
    extrap = par[_P_EXTRAP] > 0.5
    m = lengths.shape[0]
    nv = qvel.shape[0]

    jac = np.zeros((m, nv))
    for i in range(m):
        start = jac_rowadr[i]
        for p in range(jac_rownnz[i]):
            jac[i, jac_colind[start + p]] = jac_data[start + p]
    ldot = np.zeros(m)
    k = np.empty(m)
    g = np.empty(m)
    e = np.empty(m)
    beta = np.empty(m)
    gamma = np.empty(m)
    ff0 = np.empty(m)
    s = np.empty(m)
    u = np.empty(m)
    active = np.zeros(m, dtype=np.bool_)
    sat = np.zeros(m)
    for i in range(m):
        for j in range(nv):
            ldot[i] += jac[i, j] * qvel[j]
        theta = st[_S_THETA, i]
        u[i] = st[_S_SPEED, i]
        l0 = st[_S_L0REF, i] + r * theta
        k[i] = ea / (l0 + lc)
        g[i] = h * k[i] + k[i] * td
        e[i] = lengths[i] - l0
        l_motor = st[_S_LCAL, i] + r * theta
        st[_S_FE, i] = st[_S_LSET, i] - l_motor
        vcmd = st[_S_VFF, i] + kpos * st[_S_FE, i]
        st[_S_VCMD, i] = vcmd
        ki = kvf / tn if st[_S_PI, i] > 0.5 else 0.0
        beta[i] = kvf + h * ki
        gamma[i] = -beta[i] * vcmd + ki * st[_S_INTEG, i]
        ff0[i] = 0.0
        s[i] = 0.0
        if fric_on:
            v_eval = u[i]
            clamped = False
            if not extrap:
                if v_eval > v_high:
                    v_eval = v_high
                    clamped = True
                elif v_eval < -v_high:
                    v_eval = -v_high
                    clamped = True
            value, slope = _friction_eval(fric, 0, st[_S_TENSION, i], v_eval, v_low)
            ff0[i] = value / r
            if not clamped and slope < 0.0:
                s[i] = slope / r
        active[i] = k[i] * e[i] + g[i] * (ldot[i] - u[i]) > 0.0
        sat[i] = st[_S_SAT, i]

    y = np.zeros(m)
    f = np.zeros(m)
    jv = np.zeros(m)
    vnew = np.zeros(nv)
    iterations = 0
    for it in range(_MAX_ACTIVE_SET_ITERATIONS):
        iterations = it + 1
        a = mass.copy()
        b = np.zeros(nv)
        for j in range(nv):
            acc = h * qfrc_smooth[j]
            for c in range(nv):
                acc += mass[j, c] * qvel[c]
            b[j] = acc
        for i in range(m):
            if not active[i]:
                continue
            be = beta[i] if sat[i] == 0.0 else 0.0
            ga = gamma[i] if sat[i] == 0.0 else sat[i] * fmax
            d = mw + h * (g[i] + be - s[i])
            rhs = mw * u[i] + h * (k[i] * e[i] - ga + ff0[i] - s[i] * u[i])
            w = h * (g[i] - h * g[i] * g[i] / d)
            cb = -h * k[i] * e[i] + h * g[i] * rhs / d
            for j in range(nv):
                b[j] += cb * jac[i, j]
                for c in range(nv):
                    a[j, c] += w * jac[i, j] * jac[i, c]
        vnew = np.empty(nv)
        cholesky_solve(a, b, vnew)
        changed = False
        for i in range(m):
            acc = 0.0
            for j in range(nv):
                acc += jac[i, j] * vnew[j]
            jv[i] = acc
            be = beta[i] if sat[i] == 0.0 else 0.0
            ga = gamma[i] if sat[i] == 0.0 else sat[i] * fmax
            if active[i]:
                d = mw + h * (g[i] + be - s[i])
                rhs = mw * u[i] + h * (k[i] * e[i] - ga + ff0[i] - s[i] * u[i])
                y[i] = (rhs + h * g[i] * jv[i]) / d
                f[i] = k[i] * e[i] + g[i] * (jv[i] - y[i])
                if f[i] < 0.0:
                    active[i] = False
                    changed = True
            else:
                d = mw + h * (be - s[i])
                y[i] = (mw * u[i] + h * (-ga + ff0[i] - s[i] * u[i])) / d
                f[i] = 0.0
                if k[i] * e[i] + g[i] * (jv[i] - y[i]) > 0.0:
                    active[i] = True
                    changed = True
            linear = beta[i] * y[i] + gamma[i]
            if sat[i] == 0.0:
                if linear > fmax:
                    sat[i] = 1.0
                    changed = True
                elif linear < -fmax:
                    sat[i] = -1.0
                    changed = True
            elif sat[i] * linear < fmax:
                sat[i] = 0.0
                changed = True
        if not changed:
            break

    for j in range(nv):
        qfrc_out[j] = 0.0
    for i in range(m):
        fi = f[i] if f[i] > 0.0 else 0.0
        for j in range(nv):
            qfrc_out[j] -= jac[i, j] * fi
        yi = y[i]
        fm = beta[i] * yi + gamma[i] if sat[i] == 0.0 else sat[i] * fmax
        st[_S_TORQUE, i] = r * fm
        st[_S_FRIC_TORQUE, i] = r * (ff0[i] + s[i] * (yi - u[i]))
        if st[_S_PI, i] > 0.5:
            if sat[i] == 0.0:
                st[_S_INTEG, i] += h * (yi - st[_S_VCMD, i])
        else:
            st[_S_INTEG, i] = 0.0
        st[_S_SPEED, i] = yi
        st[_S_THETA, i] += h * yi / r
        st[_S_TENSION, i] = fi
        st[_S_STRETCH, i] = e[i] + h * (jv[i] - yi)
        st[_S_SAT, i] = sat[i]
        st[_S_ACTIVE, i] = 1.0 if active[i] else 0.0
        friction_force = 0.0
        reading = fi
        if fric_on and fi > 0.0:
            v_eval = yi
            if not extrap:
                v_eval = min(max(v_eval, -v_high), v_high)
            friction_force, _ = _friction_eval(fric, 2, fi, v_eval, v_low)
            reading = fi + friction_force
            if reading < 0.0:
                reading = 0.0
        st[_S_FRIC_FORCE, i] = friction_force
        st[_S_LOAD_CELL, i] = reading
        if abs(yi) > v_high:
            st[_S_BEYOND, i] += 1.0
    return iterations


@dataclass(frozen=True)
class CdprSensorReadings:
    """What the IPAnema's sensors report (the only thing a controller may read).

    Attributes:
        t: Time [s].
        motor_angle: Motor encoders, paid out positive, zero at the reset [rad], shape (m,).
        cable_length: Cable length the encoder says is paid out, ``l_motor`` [m], shape (m,).
        cable_velocity: Cable speed reported by the drive, paid out positive [m/s], (m,).
        motor_torque: Motor torque from the current, haul-in positive (eq. 3) [N m], (m,).
        following_error: ``FE = l_set - l_motor`` (paper 000, Sec. 2.3) [m], shape (m,), as
            the PLC computed it in the last cycle (the error its position loop acted on, with
            ``l_motor`` sampled at the start of that cycle): one cycle older than
            ``cable_length``. With the PI drive and no feedforward it settles to ``v / K_pos``
            on a ramp (the ``c_v v`` of eq. 9), with the pure P drive at rest to
            ``(c_f / K_p) tau`` (eq. 8).
        load_cell: Load cell on pulley 3 [N], shape (m,).
    """

    t: float
    motor_angle: FloatArray
    cable_length: FloatArray
    cable_velocity: FloatArray
    motor_torque: FloatArray
    following_error: FloatArray
    load_cell: FloatArray


def _vector(value: ArrayLike, size: int, name: str, unit: str) -> FloatArray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != (size,):
        raise InputError(f"{name} must have shape ({size},) [{unit}], got {array.shape}")
    if not np.isfinite(array).all():
        raise InputError(f"{name} [{unit}] must be finite, got {array}")
    return array.copy()


def _warn_weak_drives(config: CdprPlantConfig, model: CableRobotModel) -> None:
    """Warn when the drives cannot give the torque the least cable force needs at the drum.

    ``winch.torque_limit < f_min r_D``: every drive saturates at the model's lower force
    bound, so no controller can keep the cables' forces in their bounds.
    """
    needed = float(np.max(model.f_min)) * config.winch.drum_radius
    if config.winch.torque_limit < needed:
        warnings.warn(
            f"plant {config.name!r}: winch.torque_limit {config.winch.torque_limit:g} N m is "
            f"below the {needed:g} N m the model's least cable force needs at the drum "
            f"({float(np.max(model.f_min)):g} N x drum_radius {config.winch.drum_radius:g} m): "
            "the drives saturate and no controller keeps the forces in their bounds",
            MsarmWarning,
            stacklevel=3,
        )


class CdprPlant:
    """The simulated IPAnema 3 Mini of paper 000: the "real" cable robot of msarm.

    Args:
        model: The cable robot (its file is loaded again into a private MuJoCo model); the
            ``models/ipanema_mini.xml`` robot if None.
        config: Plant parameters; :data:`~msarm.plant.cdpr_config.DEFAULT_CDPR_PLANT` if None.
        seed: Seed of the plant's random generator (sensor noise): a non-negative integer or
            a ``numpy.random.Generator`` (copied: every :meth:`reset` starts again from the
            state it had here); same seed, same run.

    Call :meth:`reset` before the first :meth:`step`.
    """

    def __init__(
        self,
        model: CableRobotModel | None = None,
        config: CdprPlantConfig | None = None,
        seed: int | np.random.Generator = 0,
    ) -> None:
        self.model = load_cable_robot() if model is None else model
        self.config = DEFAULT_CDPR_PLANT if config is None else config
        self.seed = seed
        self._seed_rng = seed_generator(seed)
        cfg = self.config
        _warn_weak_drives(cfg, self.model)
        self.mj_model = mujoco.MjModel.from_xml_path(str(self.model.path))
        self.mj_model.opt.timestep = cfg.timestep
        # the coupling of cables and platform assumes MuJoCo's semi-implicit Euler step
        self.mj_model.opt.integrator = int(mujoco.mjtIntegrator.mjINT_EULER)
        self.mj_data = mujoco.MjData(self.mj_model)
        self._body = self.mj_model.body(self.model.platform_body).id
        m, nv = self.n_cables, self.mj_model.nv
        self.friction_model = cfg.friction.model()
        fm = self.friction_model
        self._fric = np.array(
            [
                [getattr(branch, c) for c in ("c1", "c2", "c3", "c4")]
                for branch in (
                    fm.torque_branches.negative,
                    fm.torque_branches.positive,
                    fm.force_branches.negative,
                    fm.force_branches.positive,
                )
            ]
        )
        par = np.zeros(_N_PAR)
        par[_P_H] = cfg.timestep
        par[_P_R] = cfg.winch.drum_radius
        par[_P_JW] = cfg.winch.inertia
        par[_P_EA] = cfg.cable.axial_stiffness
        par[_P_LC] = cfg.cable.chain_length
        par[_P_TD] = cfg.cable.damping_time
        par[_P_KPOS] = cfg.drive.position_gain
        par[_P_KV] = cfg.drive.velocity_gain
        par[_P_TN] = cfg.drive.integral_time
        par[_P_TAUMAX] = cfg.winch.torque_limit
        par[_P_FRIC] = 1.0 if cfg.friction.enabled else 0.0
        par[_P_VL] = fm.v_low
        par[_P_VH] = fm.v_high
        par[_P_EXTRAP] = 1.0 if cfg.friction.beyond_v_high == "extrapolate" else 0.0
        self._par = par
        self._st = np.zeros((_N_STATE, m))
        # the state each step() starts from, named if MuJoCo resets its own during it
        self._period_start = {
            "qpos": np.zeros(self.mj_model.nq),
            "qvel": np.zeros(nv),
            "winch_angle": np.zeros(m),
            "tension": np.zeros(m),
        }
        self._mass = np.zeros((nv, nv))
        self._qfrc_smooth = np.zeros(nv)
        self._qfrc_ext = np.zeros(nv)
        self._ext_force = np.zeros(3)
        self._ext_moment = np.zeros(3)
        self._has_ext = False
        self._last_modes: tuple[object, FloatArray | None] = (object(), None)
        self._views: tuple[object, dict[str, FloatArray]] = (None, {})
        self._rng = copy.deepcopy(self._seed_rng)
        self._is_reset = False
        self.last_iterations = 0

    # ----------------------------------------------------------------------- properties
    @property
    def time(self) -> float:
        """Simulated time [s]."""
        return float(self.mj_data.time)

    @property
    def n_cables(self) -> int:
        """Number of cables m."""
        return self.model.n_cables

    @property
    def cable_names(self) -> tuple[str, ...]:
        """Cable names, in the model file's order."""
        return self.model.cable_names

    @property
    def drum_radius(self) -> float:
        """Drum radius r_D [m]."""
        return self.config.winch.drum_radius

    @property
    def velocity_gain(self) -> float:
        """K_v of the drives [N m per m/s of cable speed] (from eq. 8)."""
        return self.config.drive.velocity_gain

    @property
    def position_gain(self) -> float:
        """K_pos of the PLC position loop [1/s]."""
        return self.config.drive.position_gain

    @property
    def drive_modes(self) -> tuple[str, ...]:
        """Velocity-loop mode of every drive, "pi" or "p", shape (m,)."""
        return tuple("pi" if x > 0.5 else "p" for x in self._st[_S_PI])

    # ------------------------------------------------------------------------- control
    def reset(
        self,
        pose: ArrayLike | tuple[ArrayLike, ArrayLike],
        tensions: ArrayLike | None = None,
        drive_mode: str | Sequence[str] | None = None,
    ) -> None:
        """Put the platform at rest at ``pose`` with the cables pre-tensioned to ``tensions``.

        The unstretched lengths are set so that each cable carries its tension at this pose,
        the encoders are homed (``l_motor = l_i(pose)``), and the drives hold the tensions:
        the reset command is ``l_set = l_motor`` (PI, the integrator carries the holding
        torque) or ``l_set = l_motor + (c_f / K_p) f r_D`` (pure P, the following error of
        eq. 8), with ``v_ff = 0``; the first :meth:`command` replaces it. With tensions that
        balance the platform's weight (``A^T f + w = 0``) the run starts in equilibrium.

        Args:
            pose: MuJoCo qpos ``[x, y, z, qw, qx, qy, qz]`` [m, -], shape (7,), or a tuple
                ``(r, R)``: position in K_0 [m], shape (3,), and rotation matrix (3, 3).
            tensions: Cable tensions [N], shape (m,), >= 0; if None, the minimum 2-norm
                distribution within the file's force bounds that holds the platform's weight
                (``msarm.allocation``).
            drive_mode: "pi" or "p" for all drives, or one per cable; the config's default
                if None.

        Raises:
            InputError: On a bad pose, tensions or mode, or when no tensions are given and the
                pose is not wrench-feasible.
        """
        qpos = self._qpos(pose)
        m = self.n_cables
        modes = self._modes(
            drive_mode if drive_mode is not None else self.config.drive.default_mode
        )
        model, data = self.mj_model, self.mj_data
        mujoco.mj_resetData(model, data)
        data.qpos[:] = qpos
        data.qvel[:] = 0.0
        mujoco.mj_forward(model, data)
        if tensions is None:
            tensions = self._default_tensions(qpos)
        f = _vector(tensions, m, "tensions", "N")
        if np.any(f < 0.0):
            raise InputError(f"tensions must be >= 0 N, got {f}")
        cfg = self.config
        lengths = data.ten_length.copy()
        ea, lc, r = cfg.cable.axial_stiffness, cfg.cable.chain_length, cfg.winch.drum_radius
        # f = EA e / (L0 + l_chain) with L0 = l - e
        stretch = f * (lengths + lc) / (ea + f)
        st = self._st
        st[:] = 0.0
        st[_S_L0REF] = lengths - stretch
        st[_S_LCAL] = lengths
        st[_S_TENSION] = f
        st[_S_STRETCH] = stretch
        st[_S_ACTIVE] = (f > 0.0).astype(float)
        st[_S_PI] = modes
        torque = f * r
        st[_S_TORQUE] = torque
        kv = cfg.drive.velocity_gain
        # PI: tau = (K_v / T_n) I at rest; P: tau = -K_v v_cmd = -K_v K_pos FE
        st[_S_INTEG] = np.where(modes > 0.5, torque * cfg.drive.integral_time / kv, 0.0)
        st[_S_LSET] = lengths + np.where(modes > 0.5, 0.0, cfg.drive.fe_compliance * torque)
        st[_S_FE] = st[_S_LSET] - lengths
        st[_S_LOAD_CELL] = f
        self._ext_force[:] = 0.0
        self._ext_moment[:] = 0.0
        self._has_ext = False
        self._rng = copy.deepcopy(self._seed_rng)
        self._is_reset = True

    def command(
        self,
        l_set: ArrayLike,
        v_ff: ArrayLike | None = None,
        drive_mode: str | Sequence[str] | None = None,
    ) -> None:
        """Set the PLC's commands, held until the next call (one call per 1 ms cycle).

        Args:
            l_set: Commanded cable lengths [m], shape (m,) (e.g. inverse kinematics, plus the
                HC corrections).
            v_ff: Velocity feedforward, paid out positive [m/s], shape (m,); zero if None.
            drive_mode: "pi" or "p" for all drives, or one per cable; unchanged if None. A
                drive switched from PI to P drops its integral term (the torque jumps by it);
                one switched to PI starts with an empty integrator (no jump).

        Raises:
            InputError: On wrong shapes, non-finite values or an unknown mode.
        """
        m = self.n_cables
        st = self._st
        st[_S_LSET] = _vector(l_set, m, "l_set", "m")
        st[_S_VFF] = 0.0 if v_ff is None else _vector(v_ff, m, "v_ff", "m/s")
        if drive_mode is not None:
            modes = self._modes(drive_mode)
            switched = modes != st[_S_PI]
            st[_S_INTEG, switched] = 0.0
            st[_S_PI] = modes

    def set_external_wrench(self, force: ArrayLike, moment: ArrayLike | None = None) -> None:
        """Apply a constant external wrench to the platform until changed or reset.

        Args:
            force: Force in K_0 [N], shape (3,), applied at the platform origin r.
            moment: Moment about r in K_0 [N m], shape (3,); zero if None.
        """
        self._ext_force[:] = _vector(force, 3, "force", "N")
        self._ext_moment[:] = 0.0 if moment is None else _vector(moment, 3, "moment", "N m")
        self._has_ext = bool(np.any(self._ext_force) or np.any(self._ext_moment))

    def step(self, n_steps: int = 1) -> None:
        """Advance the plant by ``n_steps`` time steps with the current command.

        Args:
            n_steps: Number of plant time steps (``config.timestep`` each), an integer >= 0.

        Raises:
            InputError: If the plant was not reset, or ``n_steps`` is not an integer >= 0.
            SimulationDivergedError: NaN in the state or a MuJoCo instability warning.
        """
        if isinstance(n_steps, bool | np.bool_) or not isinstance(n_steps, numbers.Integral):
            raise InputError(f"n_steps must be an integer >= 0, got {n_steps!r}")
        if n_steps < 0:
            raise InputError(f"n_steps must be an integer >= 0, got {n_steps}")
        if not self._is_reset:
            raise InputError("call CdprPlant.reset(pose, tensions) before step()")
        # MuJoCo resets its state (time included) when it finds a bad one: take the time and
        # the state first, to name them if the period fails
        end = self.time + int(n_steps) * self.mj_model.opt.timestep
        start = self._period_start
        if self._views[0] is not self.mj_data:  # live views, built once per MjData
            self._views = (self.mj_data, self._state_views())
        for key, value in self._views[1].items():
            np.copyto(start[key], value)
        for _ in range(int(n_steps)):
            self._step_once()
        self._check_finite(end)

    # ------------------------------------------------------------------------- reading
    def sense(self) -> CdprSensorReadings:
        """Read the robot's sensors: encoders, drive speed, motor torques, FE, load cells.

        Noise (if enabled) is drawn in a fixed order from the plant's seeded generator.
        """
        st, m = self._st, self.n_cables
        r = self.config.winch.drum_radius
        angle = st[_S_THETA].copy()
        speed = st[_S_SPEED].copy()
        torque = st[_S_TORQUE].copy()
        fe = st[_S_FE].copy()
        load = st[_S_LOAD_CELL] + self.config.load_cell.bias
        noise = self.config.noise
        if noise.enabled:
            rng = self._rng
            angle_noise = rng.normal(0.0, noise.encoder, m)
            angle += angle_noise
            fe -= r * angle_noise
            speed += rng.normal(0.0, noise.velocity, m)
            torque += rng.normal(0.0, noise.torque, m)
            load += rng.normal(0.0, noise.load_cell, m)
        return CdprSensorReadings(
            t=self.time,
            motor_angle=angle,
            cable_length=st[_S_LCAL] + r * angle,
            cable_velocity=speed,
            motor_torque=torque,
            following_error=fe,
            load_cell=load,
        )

    @property
    def true_platform_position(self) -> FloatArray:
        """Simulation-only truth: the platform position r in K_0 [m], shape (3,).

        The ``position`` of :meth:`ground_truth`, without building the rest.
        """
        return self.mj_data.qpos[:3].copy()

    @property
    def true_cable_tension(self) -> FloatArray:
        """Simulation-only truth: platform-side cable tensions [N], shape (m,).

        The ``tension`` of :meth:`ground_truth`, without building the rest.
        """
        return self._st[_S_TENSION].copy()

    @property
    def drive_saturated(self) -> NDArray[np.bool_]:
        """Simulation-only truth: drives at their torque limit in the last step, shape (m,).

        The ``drive_saturated`` of :meth:`ground_truth`, without building the rest.
        """
        return self._st[_S_SAT] != 0.0

    def ground_truth(self) -> dict[str, Any]:
        """Simulation-only truth at the current step (never available to a controller).

        Returns:
            ``qpos`` (7,), ``qvel`` (6,) (MuJoCo); ``position`` [m] (3,), ``rotation`` (3, 3),
            ``velocity`` [m/s] and ``angular_velocity`` [rad/s] in K_0 (3,); per cable (m,):
            ``tension`` (platform side) [N], ``stretch`` (from the exact geometry, negative:
            slack) [m], ``unstretched_length`` [m], ``slack`` (bool), ``winch_angle`` [rad],
            ``cable_speed`` [m/s], ``motor_torque`` [N m], ``friction_torque`` (tau_F that
            acted) [N m], ``friction_force`` (f_F at the load cell) [N], ``load_cell``
            (noise-free reading) [N], ``following_error`` (of the last PLC cycle, noise-free)
            [m], ``drive_saturated`` (bool),
            ``friction_beyond_v_high`` (steps beyond v_H, int); ``external_force`` [N] and
            ``external_moment`` [N m] (3,).
        """
        st, data = self._st, self.mj_data
        qpos, qvel = data.qpos.copy(), data.qvel.copy()
        position, rotation = pose_from_qpos(qpos)
        velocity, omega = twist_from_qvel(qpos, qvel)
        unstretched = self.unstretched_length()
        lengths = self.model.robot.cable_lengths(position, rotation)
        return {
            "qpos": qpos,
            "qvel": qvel,
            "position": position,
            "rotation": rotation,
            "velocity": velocity,
            "angular_velocity": omega,
            "tension": st[_S_TENSION].copy(),
            "stretch": lengths - unstretched,
            "unstretched_length": unstretched,
            "slack": st[_S_TENSION] <= 0.0,
            "winch_angle": st[_S_THETA].copy(),
            "cable_speed": st[_S_SPEED].copy(),
            "motor_torque": st[_S_TORQUE].copy(),
            "friction_torque": st[_S_FRIC_TORQUE].copy(),
            "friction_force": st[_S_FRIC_FORCE].copy(),
            "load_cell": st[_S_LOAD_CELL].copy(),
            "following_error": st[_S_FE].copy(),
            "drive_saturated": st[_S_SAT] != 0.0,
            "friction_beyond_v_high": st[_S_BEYOND].astype(np.int64),
            "external_force": self._ext_force.copy(),
            "external_moment": self._ext_moment.copy(),
        }

    def unstretched_length(self) -> FloatArray:
        """Unstretched cable lengths L0 (frame exit to platform) [m], shape (m,)."""
        st = self._st
        return st[_S_L0REF] + self.config.winch.drum_radius * st[_S_THETA]

    def cable_stiffness(self) -> FloatArray:
        """Current cable stiffness ``k = EA / (L0 + l_chain)`` [N/m], shape (m,)."""
        cable = self.config.cable
        return cable.axial_stiffness / (self.unstretched_length() + cable.chain_length)

    def effect_parameters(self) -> dict[str, dict]:
        """Ground truth of the plant: every effect switched on, with its parameters (SI)."""
        cfg = self.config
        truth: dict[str, dict] = {
            "elasticity": {
                **asdict(cfg.cable),
                "stiffness_now": self.cable_stiffness().tolist(),
            },
            "drive": {
                "position_gain": cfg.drive.position_gain,
                "velocity_gain": cfg.drive.velocity_gain,
                "integral_time": cfg.drive.integral_time,
                "fe_compliance": cfg.drive.fe_compliance,
                "modes": list(self.drive_modes),
            },
            "winch": asdict(cfg.winch),
        }
        if cfg.friction.enabled:
            fm = self.friction_model
            truth["winch_friction"] = {
                "torque_negative": asdict(fm.torque_branches.negative),
                "torque_positive": asdict(fm.torque_branches.positive),
                "v_low": fm.v_low,
                "v_high": fm.v_high,
                "beyond_v_high": cfg.friction.beyond_v_high,
            }
            truth["load_cell_friction"] = {
                "force_negative": asdict(fm.force_branches.negative),
                "force_positive": asdict(fm.force_branches.positive),
                "v_low": fm.v_low,
                "v_high": fm.v_high,
            }
        if cfg.load_cell.bias != 0.0:
            truth["load_cell_bias"] = asdict(cfg.load_cell)
        if cfg.noise.enabled:
            truth["sensor_noise"] = asdict(cfg.noise)
        return truth

    # ------------------------------------------------------------------------ internals
    def _step_once(self) -> None:
        model, data = self.mj_model, self.mj_data
        mujoco.mj_step1(model, data)
        mujoco.mj_fullM(model, data, self._mass)
        np.subtract(data.qfrc_passive, data.qfrc_bias, out=self._qfrc_smooth)
        if self._has_ext:
            self._qfrc_ext[:] = 0.0
            mujoco.mj_applyFT(
                model,
                data,
                self._ext_force,
                self._ext_moment,
                data.xpos[self._body],
                self._body,
                self._qfrc_ext,
            )
            self._qfrc_smooth += self._qfrc_ext
        self.last_iterations = _step_kernel(
            self._par,
            self._fric,
            self._st,
            data.ten_length,
            data.ten_J,
            model.ten_J_rownnz,
            model.ten_J_rowadr,
            model.ten_J_colind,
            self._mass,
            data.qvel,
            self._qfrc_smooth,
            data.qfrc_applied,
        )
        if self._has_ext:
            data.qfrc_applied += self._qfrc_ext
        mujoco.mj_step2(model, data)

    def _state_views(self) -> dict[str, FloatArray]:
        """Live views of the platform's and the winches' state (for a divergence report)."""
        data, st = self.mj_data, self._st
        return {
            "qpos": data.qpos,
            "qvel": data.qvel,
            "winch_angle": st[_S_THETA],
            "tension": st[_S_TENSION],
        }

    def _check_finite(self, end: float) -> None:
        """Raise :class:`SimulationDivergedError` naming ``end`` [s] if the state went bad.

        Where MuJoCo found a bad state it has reset its own, so the state named is the one
        the period started from; otherwise the one it ended in.
        """
        data, st = self.mj_data, self._st
        total = float(data.qpos.sum() + data.qvel.sum() + st[_S_SPEED].sum())
        found = instability_found(data)
        if found or not math.isfinite(total):
            arrays = self._period_start if found else self._state_views()
            state = {key: value.tolist() for key, value in arrays.items()}
            where = "at the start of that period" if found else "at its end"
            raise SimulationDivergedError(
                f"CDPR simulation diverged at t = {end:.4f} s ({where}: qpos = {state['qpos']}, "
                f"qvel = {state['qvel']})" + "".join(f"; {text}" for text in found),
                end,
                state,
            )

    def _qpos(self, pose: ArrayLike | tuple[ArrayLike, ArrayLike]) -> FloatArray:
        if isinstance(pose, tuple) and len(pose) == 2:
            qpos = qpos_from_pose(pose[0], pose[1])
        else:
            qpos = _vector(pose, 7, "pose (qpos)", "m, -")
            norm = float(np.linalg.norm(qpos[3:]))
            if abs(norm - 1.0) > 1e-6:
                raise InputError(f"pose quaternion qpos[3:7] must have norm 1, got {norm:.9g}")
        if qpos.shape != (7,):
            raise InputError(f"pose must be one pose, got qpos of shape {qpos.shape}")
        return qpos

    def _modes(self, drive_mode: str | Sequence[str]) -> FloatArray:
        """The modes as 1.0 (PI) / 0.0 (P), shape (m,), from a name or one name per cable.

        The same str or tuple object as last time (a controller sends its own every cycle)
        is not parsed again.
        """
        if drive_mode is self._last_modes[0]:
            return self._last_modes[1].copy()
        modes = self._parse_modes(drive_mode)
        if type(drive_mode) is str or (
            type(drive_mode) is tuple and all(type(name) is str for name in drive_mode)
        ):
            self._last_modes = (drive_mode, modes.copy())  # immutable: safe to recognise
        return modes

    def _parse_modes(self, drive_mode: str | Sequence[str]) -> FloatArray:
        m = self.n_cables
        names = [drive_mode] * m if isinstance(drive_mode, str) else list(drive_mode)
        if len(names) != m or any(name not in DRIVE_MODES for name in names):
            raise InputError(
                f"drive_mode must be one of {DRIVE_MODES} or {m} of them, got {drive_mode!r}"
            )
        return np.array([1.0 if name == "pi" else 0.0 for name in names])

    def _default_tensions(self, qpos: FloatArray) -> FloatArray:
        from msarm.allocation import make_allocator

        r, R = pose_from_qpos(qpos)
        robot = self.model
        At = robot.robot.structure_matrix(r, R)
        w = robot.platform_wrench(r, R)
        result = make_allocator(self.n_cables, 6, "fast").solve(At, -w, robot.f_min, robot.f_max)
        if not result.feasible:
            raise InputError(
                f"pose r = {np.array2string(r, precision=4)} m is not wrench-feasible within "
                f"[{robot.f_min.min():g}, {robot.f_max.max():g}] N: give the tensions"
            )
        return np.asarray(result.f, dtype=np.float64)
