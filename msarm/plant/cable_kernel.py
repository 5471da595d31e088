"""The compiled per-step physics of the cables and winches (numba).

One call per plant step advances every winch and computes every cable's motor-side and
insertion-side tension and the joint forces they produce. Equations, per cable:

Drive (tension loop on the motor-side load cell), limited to +-tau_max:
    ``tau_m = r (T_cmd + K (T_cmd - T_m))``

Winch (implicit Euler in the speed omega; theta reels in):
    ``J domega/dt = tau_m - r T_m + tau_f(omega) + tau_cog(theta) + tau_user``
    ``tau_f = -tau_c tanh(omega / omega_s) - b omega``,  ``tau_cog = A sin(N theta + phi)``

Elastic cable in two segments joined at the sheath by a massless node that slides ``x``
towards the motor (capstan friction with true stiction, a quasi-static Coulomb law):
    motor-side stretch ``e_m = e_m0 + r theta - x``, ``T_m = 2k max(e_m, 0)``;
    insertion-side stretch ``e_i = e_i0 + (l(q) - l_ref) + x``, ``T_i = 2k max(e_i, 0)``;
    a dashpot in parallel with the whole rope adds ``c (dl/dt + r omega)`` (the rate of the
    total stretch) to both while the cable is taut, each tension staying >= 0;
    the node sticks while ``T_i / beta <= T_m <= beta T_i`` with ``beta = exp(mu Theta(q))``
    and otherwise slides until ``T_m = beta T_i`` (cable pulled in) or ``T_m = T_i / beta``
    (paid out); the winch's implicit step sees the node where this step's path has put it
    (in its stick band; a cable the path has made slack, no tension).
    Without sheath friction (``mu = 0``) the node balances and the cable is one
    spring of stiffness k. A cable whose total stretch ``e_m + e_i`` is not positive is
    slack: no tension on either side.

Rigid cable (elasticity off): the drive renders ``T_m = max(0, T_cmd + tau_w / (r (1 + K)))``
quasi-statically, the winch follows the path, and sheath friction is the smooth capstan law
``T_i = T_m exp(-mu Theta tanh(v_in / v_s))`` with ``v_in = -dl/dt``.

Joint forces: ``qfrc = -J_c^T T_i`` from MuJoCo's sparse tendon Jacobian.
"""

from __future__ import annotations

import math

import numba

from msarm.mujoco_c import call_model_data
from msarm.numba_cache import drop_stale_kernels

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = ["PARAMS", "step_cables", "step_plant"]

#: Layout of the scalar parameter vector of :func:`step_cables`.
PARAMS = (
    "timestep",
    "drum_radius",
    "rotor_inertia",
    "drive_gain",
    "stiffness",
    "mu",
    "smoothing_velocity",
    "coulomb",
    "viscous",
    "smoothing_speed",
    "cog_amplitude",
    "cog_periods",
    "cog_phase",
    "elastic",
    "damping",
)


@numba.njit(cache=True, fastmath=False)
def step_cables(
    params,
    lengths,
    velocities,
    wrap,
    command,
    torque_limit,
    length_ref,
    stretch_motor0,
    stretch_insertion0,
    user_torque,
    user_slope,
    user_factor,
    theta,
    omega,
    slide,
    tension_motor,
    tension_insertion,
    motor_torque,
    jac_data,
    jac_rownnz,
    jac_rowadr,
    jac_colind,
    qfrc,
):
    """Advance the winches one step and write the cable tensions and joint forces.

    Args:
        params: Scalars in the order of :data:`PARAMS`, shape ``(15,)``.
        lengths: Cable path lengths l(q) [m], ``(m,)``.
        velocities: Cable path velocities dl/dt [m/s], ``(m,)``.
        wrap: Wrap angles Theta(q) [rad], ``(m,)``.
        command: Tension commands T_cmd [N], ``(m,)``.
        torque_limit: Peak motor torques [N m], ``(m,)``.
        length_ref: Path lengths at the reset posture [m], ``(m,)``.
        stretch_motor0: Initial motor-side stretch e_m0 [m], ``(m,)``.
        stretch_insertion0: Initial insertion-side stretch e_i0 [m], ``(m,)``.
        user_torque: Winch torque of user effects [N m], ``(m,)``.
        user_slope: Its derivative wrt the winch speed [N m s/rad], ``(m,)``.
        user_factor: Transmission factor of user effects [-], ``(m,)``.
        theta: Winch angles [rad], ``(m,)``, updated in place.
        omega: Winch speeds [rad/s], ``(m,)``, updated in place.
        slide: Node slides x [m], ``(m,)``, updated in place.
        tension_motor: Motor-side tensions [N], ``(m,)``, in: last step, out: this step.
        tension_insertion: Insertion-side tensions [N], ``(m,)``, written.
        motor_torque: Motor torques [N m], ``(m,)``, written.
        jac_data: MuJoCo ``ten_J`` (sparse values).
        jac_rownnz: MuJoCo ``ten_J_rownnz``.
        jac_rowadr: MuJoCo ``ten_J_rowadr``.
        jac_colind: MuJoCo ``ten_J_colind``.
        qfrc: Joint forces [N m], ``(n,)``, written (``qfrc_applied``).
    """
    h = params[0]
    r = params[1]
    inertia = params[2]
    gain = params[3]
    k2 = 2.0 * params[4]
    mu = params[5]
    v_s = params[6]
    t_c = params[7]
    b = params[8]
    w_s = params[9]
    cog_a = params[10]
    cog_n = params[11]
    cog_p = params[12]
    elastic = params[13] > 0.5
    c_damp = params[14]
    m = lengths.shape[0]
    for i in range(m):
        tau_m = r * (command[i] + gain * (command[i] - tension_motor[i]))
        if tau_m > torque_limit[i]:
            tau_m = torque_limit[i]
        elif tau_m < -torque_limit[i]:
            tau_m = -torque_limit[i]
        if not elastic:
            # rigid cable: the winch follows the path; its torques act at the new state
            new_theta = (length_ref[i] - lengths[i]) / r
            omega[i] = (new_theta - theta[i]) / h
            theta[i] = new_theta
        w = omega[i]
        x = w / w_s
        tau_w = -t_c * math.tanh(x) - b * w + cog_a * math.sin(cog_n * theta[i] + cog_p)
        tau_w += user_torque[i]
        slope = -t_c / w_s / math.cosh(x) ** 2 - b + user_slope[i]
        beta = math.exp(mu * wrap[i])
        if elastic:
            a = stretch_motor0[i] + r * theta[i]
            bb = stretch_insertion0[i] + lengths[i] - length_ref[i]
            # effective stiffness seen by the winch at the current node state
            if a + bb <= 0.0:
                k_eff = 0.0
            else:
                t_m = k2 * max(a - slide[i], 0.0)
                t_i = k2 * max(bb + slide[i], 0.0)
                if t_m > beta * t_i:
                    k_eff = k2 * beta * k2 / (k2 + beta * k2)
                elif t_m * beta < t_i:
                    k_eff = k2 * (k2 / beta) / (k2 + k2 / beta)
                else:
                    k_eff = k2 if a - slide[i] > 0.0 else 0.0
            # the winch feels the motor-side tension with the node already where the path
            # has put it this step (quasi-static: it sticks, or slides to the capstan bound);
            # the node of the last step would lag the path by one step, a drag r^2 k h omega
            x_now = slide[i]
            if a + bb > 0.0:
                x_now = min(
                    max(x_now, (a - beta * bb) / (1.0 + beta)), (beta * a - bb) / (1.0 + beta)
                )
            else:  # slack: the node within [a, -bb], no tension on either side
                x_now = min(max(x_now, a), -bb)
            t_m_now = k2 * max(a - x_now, 0.0)
            # the rope's dashpot on the total stretch rate (taut cables), implicit in omega
            c_eff = c_damp if a + bb > 0.0 else 0.0
            lhs = inertia / h + r * r * (k_eff * h + c_eff) - slope
            rhs = (
                inertia * w / h + tau_m - r * (t_m_now + c_eff * velocities[i]) + tau_w - slope * w
            )
            w_new = rhs / lhs
            omega[i] = w_new
            theta[i] += h * w_new
            a = stretch_motor0[i] + r * theta[i]
            # quasi-static node: stick, or slide to the capstan bound
            if a + bb <= 0.0:
                lo, hi = a, -bb
                if slide[i] < lo:
                    slide[i] = lo
                elif slide[i] > hi:
                    slide[i] = hi
                t_m = 0.0
                t_i = 0.0
            else:
                t_m = k2 * max(a - slide[i], 0.0)
                t_i = k2 * max(bb + slide[i], 0.0)
                if t_m > beta * t_i:
                    slide[i] = (k2 * a - beta * k2 * bb) / (k2 + beta * k2)
                elif t_m * beta < t_i:
                    slide[i] = (k2 * a - (k2 / beta) * bb) / (k2 + k2 / beta)
                t_m = k2 * max(a - slide[i], 0.0)
                t_i = k2 * max(bb + slide[i], 0.0)
                damping = c_eff * (velocities[i] + r * w_new)
                t_m = max(t_m + damping, 0.0)
                t_i = max(t_i + damping, 0.0)
            tension_motor[i] = t_m
            tension_insertion[i] = t_i * user_factor[i]
        else:
            t_m = command[i] + tau_w / (r * (1.0 + gain))
            if t_m < 0.0:
                t_m = 0.0
            tau_m = r * t_m - tau_w
            if tau_m > torque_limit[i] or tau_m < -torque_limit[i]:
                # a saturated motor holds what its torque limit balances (r T = tau_m + tau_w)
                tau_m = torque_limit[i] if tau_m > 0.0 else -torque_limit[i]
                t_m = max((tau_m + tau_w) / r, 0.0)
            sign = math.tanh(-velocities[i] / v_s)
            tension_motor[i] = t_m
            tension_insertion[i] = t_m * math.exp(-mu * wrap[i] * sign) * user_factor[i]
        motor_torque[i] = tau_m
    for j in range(qfrc.shape[0]):
        qfrc[j] = 0.0
    for i in range(m):
        start = jac_rowadr[i]
        for p in range(jac_rownnz[i]):
            qfrc[jac_colind[start + p]] -= jac_data[start + p] * tension_insertion[i]


@numba.njit(cache=True)
def step_plant(
    n_steps,
    step1,
    step2,
    model,
    data,
    cable_args,
    qpos,
    qvel,
    winch_speed,
    warning_counts,
    unstable_warnings,
):
    """``n_steps`` whole plant steps, compiled: ``mj_step1``, :func:`step_cables`, ``mj_step2``.

    The same operations in the same order as the plant's Python loop, so the same bits.
    Afterwards it tells whether the simulation diverged, as the plant's check does: a NaN or
    infinity in the joint angles, joint speeds or winch speeds, or one of MuJoCo's instability
    warnings.

    Args:
        n_steps: Number of plant steps.
        step1: Address of MuJoCo's ``mj_step1`` (:func:`msarm.mujoco_c.step_functions`).
        step2: Address of MuJoCo's ``mj_step2``.
        model: Address of the ``mjModel`` (``MjModel._address``).
        data: Address of the ``mjData`` (``MjData._address``) whose arrays the cable
            arguments view (``ten_length``, ``ten_velocity``, ``ten_J``, ``qfrc_applied``).
        cable_args: The arguments of :func:`step_cables`, in its order (a tuple).
        qpos: MuJoCo's joint angles [rad], ``(n,)`` (a view of ``MjData.qpos``).
        qvel: MuJoCo's joint speeds [rad/s], ``(n,)`` (a view of ``MjData.qvel``).
        winch_speed: The winch speeds [rad/s], ``(m,)`` (``omega`` of ``cable_args``).
        warning_counts: MuJoCo's warning counters (a view of ``MjData.warning.number``).
        unstable_warnings: Indices of the instability warnings (``mjWARN_BADQPOS``,
            ``mjWARN_BADQVEL``, ``mjWARN_BADQACC``), int64.

    Returns:
        True if the simulation diverged.
    """
    for _ in range(n_steps):
        call_model_data(step1, model, data)
        step_cables(*cable_args)
        call_model_data(step2, model, data)
    total = 0.0
    for value in qpos:
        total += value
    for value in qvel:
        total += value
    for value in winch_speed:
        total += value
    for index in unstable_warnings:
        if warning_counts[index] > 0:
            return True
    return not math.isfinite(total)
