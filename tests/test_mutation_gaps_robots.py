"""Checks that close gaps a mutation test of the cable-robot, plant, controller and
compensation code found: each test pins one documented behaviour against an independent
reference (hand-computed values, the paper's published numbers, finite differences)."""

import math

import numpy as np
import pytest

from msarm.cdpr.force_estimation import WinchParameters, force_from_motor_torque
from msarm.cdpr.forward_kinematics import rotation_matrix
from msarm.cdpr.robot_model import load_cable_robot
from msarm.cdpr.sensitivity import sensitivity_index, sensitivity_matrix
from msarm.cdpr.switching import HALF_PI, SwitchingFactor, switching_cycles
from msarm.cdpr.winch_friction import (
    PAPER_000_WINCH_FRICTION,
    WinchFrictionModel,
    m_per_min_to_m_per_s,
)
from msarm.control.cdpr_controllers import (
    CdprMeasurement,
    SensitivityPairSelector,
    cable_motion,
    make_cdpr_controller,
)
from msarm.control.kernels import muscle_speed
from msarm.control.pid import DiscretePID, PIDGains
from msarm.errors import InputError


@pytest.fixture(scope="module")
def model():
    return load_cable_robot()


def _centre(model):
    return np.array(model.workspace_center, dtype=float)


# ------------------------------------------------------------------ msarm.cdpr


def test_rotation_matrix_of_a_tiny_rotation_vector_is_rodrigues():
    """Below 1e-4 rad the Taylor branch must keep sin(t)/t = 1 - t^2/6 (not 1)."""
    t = 8e-5
    R = rotation_matrix([t, 0.0, 0.0])
    # the exact rotation about x; sin(t) carries t^3/6 = 8.5e-14, far above round-off
    np.testing.assert_allclose(R[2, 1], math.sin(t), rtol=1e-14, atol=0)
    np.testing.assert_allclose(R[1, 2], -math.sin(t), rtol=1e-14, atol=0)
    np.testing.assert_allclose(R[1, 1], math.cos(t), rtol=0, atol=2e-16)


# Table 1 of paper 000 as printed: (c1, c2, c3, c4), f in N and v in m/min.
_TABLE_1 = {
    ("torque", "p"): (-3.64e-3, -5.85e-6, -4.66e-4, -2.45e-2),
    ("torque", "n"): (-5.97e-3, -2.31e-4, 3.10e-3, 2.52e-2),
    ("force", "p"): (-1.73e-1, 1.62e-2, -2.51e-2, 2.93e-1),
    ("force", "n"): (-1.60e-1, -1.40e-2, 1.25e-1, 1.81e-1),
}


@pytest.mark.parametrize("quantity", ["torque", "force"])
@pytest.mark.parametrize("v_min", [-4.0, -1.0, 1.5, 5.0])
def test_friction_outer_branches_are_table_1_of_paper_000(quantity, v_min):
    """Eq. 5 / eq. 7 outside +-v_L evaluated by hand with the coefficients of Table 1."""
    f = 17.0
    c1, c2, c3, c4 = _TABLE_1[(quantity, "p" if v_min > 0 else "n")]
    expected = c1 * v_min + c2 * v_min**2 + c3 * f + c4
    v = float(m_per_min_to_m_per_s(v_min))
    got = getattr(PAPER_000_WINCH_FRICTION, quantity)(f, v)
    assert float(got) == pytest.approx(expected, rel=1e-12, abs=1e-15)


def test_torque_estimate_refuses_a_friction_that_falls_faster_than_the_drum_radius():
    """Eq. 3 is only invertible when r_D + d tau_F / d f > 0 (documented InputError)."""
    steep = WinchFrictionModel.from_paper_units(
        torque_negative=(-5.97e-3, -2.31e-4, -0.05, 2.52e-2),
        torque_positive=(-3.64e-3, -5.85e-6, -0.05, -2.45e-2),
    )
    winch = WinchParameters(drum_radius=0.02, friction=steep)  # 0.02 - 0.05 < 0
    with pytest.raises(InputError, match="cannot be inverted"):
        force_from_motor_torque(np.full(8, 0.2), np.full(8, 0.05), winch=winch)


def test_switching_counts_a_step_that_lands_exactly_on_pi_half():
    """``n delta >= pi/2`` (docstring): with delta = pi/4 two steps reach h = 1 exactly."""
    delta = math.pi / 4.0
    assert 2.0 * delta == HALF_PI
    assert switching_cycles(delta) == 2
    assert switching_cycles(HALF_PI) == 1
    s = SwitchingFactor(delta)
    s.activate()
    assert s.step() == pytest.approx(0.5)  # sin^2(pi/4)
    assert s.step() == 1.0
    assert not s.switching and s.cycles_left == 0


def test_sensitivity_is_inf_where_the_position_cables_cannot_hold_the_pose():
    """Docstring: sigma is inf where A_P^T is singular (two identical P columns)."""
    rng = np.random.default_rng(3)
    At = rng.normal(size=(6, 8))
    At[:, 5] = At[:, 4]  # cables 4 and 5 (both position-controlled) pull alike
    S = sensitivity_matrix(At, [0, 1])
    assert np.all(np.isinf(S))
    assert np.isinf(sensitivity_index(At, [0, 1]))
    # the same matrix with a force-controlled duplicate is regular
    assert np.isfinite(sensitivity_index(At, [0, 5]))


# ------------------------------------------------------------------ msarm.control


def test_pid_limits_clip_the_output_and_never_push_the_integral_back():
    """Module docstring of pid: output limited to [u_min, u_max]; the integrator moves
    towards a limit only until the output reaches it and is never pushed back by it."""
    pid = DiscretePID(PIDGains(k=1.0, t_i=1.0), n=1, dt=0.1, output_min=-1.0, output_max=1.0)
    u = pid.step(0.5)  # P = 0.5, I = 0.05
    assert u[0] == pytest.approx(0.55)
    assert pid.integral[0] == pytest.approx(0.05)
    u = pid.step(2.0)  # P = 2 alone passes the limit: I stays at 0.05, u = 1
    assert u[0] == 1.0
    assert pid.integral[0] == pytest.approx(0.05)
    u = pid.step(-0.2)  # the error turns: the output leaves the limit at once
    assert u[0] == pytest.approx(-0.2 + 0.05 - 0.02)


def test_cable_acceleration_of_a_spinning_platform_matches_finite_differences(model):
    """l'' with omega != 0 (the centripetal term omega x (omega x R b)) against central
    differences of the inverse-kinematics lengths along R(t) = exp([omega t]x) R0."""
    r0 = _centre(model)
    R0 = rotation_matrix([0.1, -0.2, 0.05])
    v = np.array([0.03, -0.02, 0.01])
    omega = np.array([1.5, -2.0, 2.5])
    zero = np.zeros(3)
    _, l_dot, l_ddot, _ = cable_motion(model.robot, r0, R0, v, omega, zero, zero)
    h = 1e-4

    def lengths(t):
        return model.robot.cable_lengths(r0 + v * t, rotation_matrix(omega * t) @ R0)

    lp, l0, lm = lengths(h), lengths(0.0), lengths(-h)
    np.testing.assert_allclose(l_dot, (lp - lm) / (2 * h), atol=1e-8)
    np.testing.assert_allclose(l_ddot, (lp - 2 * l0 + lm) / h**2, atol=2e-5)


def test_sensitivity_selector_keeps_its_set_within_the_hysteresis(model):
    """Switch only when another candidate's sigma is lower by more than the hysteresis."""
    At = model.robot.structure_matrix(_centre(model) + [0.05, 0.04, 0.0], np.eye(3))
    probe = SensitivityPairSelector(hysteresis=0.0)
    sig = probe.sigmas(At)
    best, worst = int(np.argmin(sig)), int(np.argmax(sig))
    gap = float(sig[worst] - sig[best])
    assert gap > 1e-3
    r = np.zeros(3)
    wide = SensitivityPairSelector(hysteresis=gap * 1.5)
    assert wide.select(r, At, wide.candidates[worst]) == wide.candidates[worst]
    narrow = SensitivityPairSelector(hysteresis=gap * 0.5)
    assert narrow.select(r, At, narrow.candidates[worst]) == narrow.candidates[best]


def test_fe_feedforward_adds_the_following_error_in_the_share_1_minus_h(model):
    """HC-e with fe_feedforward: l_set = l_IK + h Delta l + (1 - h) FE_set (docstring)."""
    ctrl = make_cdpr_controller(
        "hc-e", model, pair_selector=(0, 1), start_active=True, fe_feedforward=True
    )
    r = _centre(model)
    nom = ctrl.nominal(r)
    fe = ctrl.targets(nom, np.arange(8))
    cmd = ctrl.step(r, measurement=CdprMeasurement(following_error=fe + 1e-5))
    assert cmd.h[0] == 1.0 and cmd.h[1] == 1.0
    expected = cmd.l_ik + cmd.h * cmd.delta_l
    expected[:2] += (1.0 - cmd.h[:2]) * cmd.target[:2]
    np.testing.assert_allclose(cmd.l_set, expected, rtol=0, atol=1e-15)
    assert np.any(cmd.target[:2] != 0.0)


def test_hybrid_pid_restarts_from_zero_when_a_cable_is_switched_back_on(model):
    """A cable whose h fell to 0 has its PID reset: when it is force-controlled again, its
    first Delta l is eq. 11's first-cycle answer (PI: K e + K T / T_i e), no old integral."""
    ctrl = make_cdpr_controller("hc-e", model, delta=0.5)  # region pairs (0, 1) / (2, 3)
    c = _centre(model)
    up, down = c + [0.0, 0.05, 0.0], c + [0.0, -0.05, 0.0]
    nom = ctrl.nominal(up)
    fe_set = ctrl.targets(nom, np.arange(8))
    offset = 2e-6  # [m] of FE: a steady error on the controlled cables
    for _ in range(30):  # (0, 1) on, integral builds up
        cmd = ctrl.step(up, measurement=CdprMeasurement(following_error=fe_set + offset))
    assert cmd.h[0] == 1.0
    for _ in range(10):  # (0, 1) off (4 cycles at delta = 0.5)
        cmd = ctrl.step(down, measurement=CdprMeasurement(following_error=np.zeros(8)))
    assert cmd.h[0] == 0.0
    cmd = ctrl.step(up, measurement=CdprMeasurement(following_error=fe_set + offset))
    g, T = ctrl.gains, ctrl.dt
    e = ctrl.sign * offset
    np.testing.assert_allclose(cmd.delta_l[:2], g.k * e + g.k * T / g.t_i * e, rtol=1e-6)


def test_nullspace_limit_scales_the_integral_with_the_output(model):
    """NC: |dl| is limited by scaling the whole vector and the integral with it (no windup),
    so once the force error reverses the correction reverses within a few cycles."""
    ctrl = make_cdpr_controller("nc", model, delta_l_limit=1e-4, friction_model=False)
    r = _centre(model)
    low = np.full(8, 2.0)  # every cable far below the 12 N mean for a long time
    for _ in range(300):
        cmd = ctrl.step(r, measurement=CdprMeasurement(load_cell=low))
    assert np.abs(cmd.delta_l).max() == pytest.approx(1e-4)
    # the integral is the limited output: k_p = 0, so dl_k = I_k
    high = np.full(8, 25.0)
    before = cmd.delta_l.copy()
    P = ctrl.nullspace_projector(ctrl.nominal(r).structure_matrix)
    e = ctrl.force_error(high)
    expected = P @ (before + ctrl.k_i * ctrl.dt * e)
    cmd = ctrl.step(r, measurement=CdprMeasurement(load_cell=high))
    peak = np.abs(expected).max()
    if peak > 1e-4:
        expected *= 1e-4 / peak
    np.testing.assert_allclose(cmd.delta_l, expected, rtol=1e-9, atol=1e-15)


def test_muscle_speed_is_clamped_at_the_highest_shortening_speed():
    """muscle_speed = max(J_c qdot, -max_shortening), hand-computed."""
    jacobian = np.array([[1.0, 2.0], [0.5, -1.0], [0.0, 3.0]])
    qdot = np.array([-3.0, -1.0])
    out = np.empty(3)
    muscle_speed(jacobian, qdot, np.array([2.0, 2.0, 5.0]), out)
    np.testing.assert_array_equal(out, [-2.0, -0.5, -3.0])


def test_arm_controller_caps_the_integral_torque_at_the_integral_limit(arm):
    """Ki int(e) is bounded by ``integral_limit`` [N m] (ArmControllerConfig): with a steady
    error the wanted torque settles at RNEA(q_r) + Kp e + integral_limit (the rest at rest)."""
    import pinocchio

    from msarm.control import ArmControllerConfig, MuscleSpaceController
    from msarm.plant.effects import SensorReadings

    config = ArmControllerConfig()
    ctrl = MuscleSpaceController(arm, config)
    lower, upper = np.asarray(arm.joint_lower), np.asarray(arm.joint_upper)
    q = lower + 0.4 * (upper - lower)
    q_ref = q + 0.2
    ctrl.reset(q)
    m, n = arm.n_cables, arm.n_joints
    readings = SensorReadings(0.0, q, np.zeros(m), np.zeros(m), np.zeros(m))
    zero = np.zeros(n)
    for _ in range(250):  # 1 s: Ki e t >= 20 * 0.2 * 1.0 = 4 > 3 N m
        out = ctrl.update(readings, q_ref, zero, zero)
    index = np.asarray(arm.pin_q_index)
    rnea = pinocchio.rnea(arm.pin_model, arm.pin_model.createData(), q_ref[index], zero, zero)
    inverse_dynamics = np.asarray(rnea)[np.argsort(index)]
    integral = out.joint_torque - inverse_dynamics - np.asarray(config.kp) * 0.2
    np.testing.assert_allclose(integral, np.full(n, config.integral_limit), rtol=1e-9)


# ------------------------------------------------------------------ msarm.plant


def _one_cable_step(params, *, command, tension_motor, velocity=0.0, stretch=0.0):
    """One step of the compiled cable kernel for a single cable that touches no joint."""
    from msarm.plant.cable_kernel import PARAMS, step_cables

    par = np.array([params[name] for name in PARAMS], dtype=float)
    one = lambda value: np.array([value], dtype=float)  # noqa: E731
    state = {"theta": one(0.0), "omega": one(0.0), "slide": one(0.0)}
    out = {"tension_motor": one(tension_motor), "insertion": one(0.0), "torque": one(0.0)}
    empty = np.zeros(0, dtype=np.int32)
    step_cables(
        par, one(0.3), one(velocity), one(1.0), one(command), one(1.0), one(0.3),
        one(stretch), one(stretch), one(0.0), one(0.0), one(1.0),
        state["theta"], state["omega"], state["slide"],
        out["tension_motor"], out["insertion"], out["torque"],
        np.zeros(0), np.zeros(1, dtype=np.int32), np.zeros(1, dtype=np.int32), empty,
        np.zeros(2),
    )  # fmt: skip
    return out


_KERNEL = {
    "timestep": 1e-3,
    "drum_radius": 0.01,
    "rotor_inertia": 1e-5,
    "drive_gain": 2.0,
    "stiffness": 1000.0,
    "mu": 0.0,
    "smoothing_velocity": 0.01,
    "coulomb": 0.0,
    "viscous": 0.0,
    "smoothing_speed": 1.0,
    "cog_amplitude": 0.0,
    "cog_periods": 6.0,
    "cog_phase": 0.0,
    "elastic": 1.0,
    "damping": 0.0,
}


def test_cable_kernel_cogging_is_a_sin_n_theta_plus_phi():
    """Rigid cable at rest (theta = 0): T_m = T_cmd + tau_cog / (r (1 + K)) with
    tau_cog = A sin(N * 0 + phi), and the motor gives r T_m - tau_cog (module docstring)."""
    params = dict(_KERNEL, elastic=0.0, cog_amplitude=0.02, cog_phase=0.5)
    out = _one_cable_step(params, command=10.0, tension_motor=10.0)
    tau_cog = 0.02 * math.sin(0.5)
    t_m = 10.0 + tau_cog / (0.01 * 3.0)
    assert out["tension_motor"][0] == pytest.approx(t_m, rel=1e-14)
    assert out["insertion"][0] == pytest.approx(t_m, rel=1e-14)
    assert out["torque"][0] == pytest.approx(0.01 * t_m - tau_cog, rel=1e-14)


def test_cable_kernel_limits_a_negative_drive_torque_too():
    """tau_m = r (T_cmd + K (T_cmd - T_m)) is limited to +-tau_max: here r K T_m = 5 N m
    against a 1 N m limit, paying out."""
    params = dict(_KERNEL, drive_gain=50.0)
    out = _one_cable_step(params, command=0.0, tension_motor=10.0, stretch=0.005)
    assert out["torque"][0] == -1.0


def test_cable_kernel_damping_never_makes_a_tension_negative():
    """The rope's dashpot adds c (dl/dt + r omega) while taut, each tension staying >= 0:
    a cable whose path shortens at 1 m/s with c = 1000 N s/m carries no tension."""
    params = dict(_KERNEL, damping=1000.0)
    out = _one_cable_step(params, command=10.0, tension_motor=10.0, velocity=-1.0, stretch=0.005)
    assert out["insertion"][0] == 0.0
    assert out["tension_motor"][0] == 0.0


def test_actuation_delay_holds_a_command_for_its_periods():
    """Delay: u_drive(k) = u_controller(k - d_a), the oldest repeated at the start."""
    from msarm.plant.config import DelayConfig
    from msarm.plant.effects import Delay

    delay = Delay(DelayConfig(enabled=True, actuation_periods=1))
    delay.reset(np.random.default_rng(0))
    first, second, third = np.full(2, 1.0), np.full(2, 2.0), np.full(2, 3.0)
    np.testing.assert_array_equal(delay.actuate(first), first)
    np.testing.assert_array_equal(delay.actuate(second), first)
    np.testing.assert_array_equal(delay.actuate(third), second)
    none = Delay(DelayConfig(enabled=True, actuation_periods=0))
    np.testing.assert_array_equal(none.actuate(third), third)


def _ideal_with(**effects):
    from dataclasses import replace

    from msarm.plant.config import IDEAL_PLANT

    return replace(IDEAL_PLANT, name="test", effects=replace(IDEAL_PLANT.effects, **effects))


def test_arm_plant_stretch_counts_the_cable_the_winch_reeled_in(arm):
    """ground_truth()["stretch"] = l(q) - unstretched length, the cable reeled in since the
    reset (r theta) taken off the unstretched length: one undamped spring without sheath
    friction, so stretch = T / k once the winch has turned."""
    from msarm.plant import ArmPlant
    from msarm.plant.config import ElasticityConfig

    k = 2.0e4
    config = _ideal_with(elasticity=ElasticityConfig(enabled=True, stiffness=k, damping=0.0))
    plant = ArmPlant(arm, config, seed=1)
    plant.reset(np.array([0.2, 0.4, -0.3, -0.9]), tensions=np.full(arm.n_cables, 25.0))
    plant.command(np.full(arm.n_cables, 30.0))
    plant.step(20)
    truth = plant.ground_truth()
    assert np.abs(truth["winch_angle"]).max() > 1e-3  # the winches did turn
    np.testing.assert_allclose(truth["stretch"], truth["tension_insertion"] / k, rtol=1e-9)


def test_arm_plant_reset_accepts_a_posture_on_the_joint_range_edges(arm):
    """ArmPlant.reset: q inside [joint_lower, joint_upper], edges included."""
    from msarm.plant import ArmPlant

    plant = ArmPlant(arm, _ideal_with(), seed=0)
    plant.reset(np.asarray(arm.joint_lower, dtype=float))
    plant.reset(np.asarray(arm.joint_upper, dtype=float))
    np.testing.assert_array_equal(plant.ground_truth()["q"], arm.joint_upper)
    with pytest.raises(InputError, match="outside"):
        plant.reset(np.asarray(arm.joint_lower, dtype=float) - 1e-9)


def test_cdpr_following_error_reading_sees_the_encoder_noise_of_the_cable_length(model):
    """The PLC's FE is l_set minus the encoder's l_motor: encoder noise that lengthens the
    sensed cable shortens the sensed FE by as much, so FE + l_motor is noise-free (= l_set,
    the inverse-kinematics length, right after the reset with PI drives)."""
    from dataclasses import replace

    from msarm.plant.cdpr_config import DEFAULT_CDPR_PLANT, CdprNoiseConfig
    from msarm.plant.cdpr_plant import CdprPlant

    noise = CdprNoiseConfig(enabled=True, encoder=1e-3)
    plant = CdprPlant(model, replace(DEFAULT_CDPR_PLANT, noise=noise), seed=4)
    r = _centre(model)
    plant.reset((r, np.eye(3)), tensions=np.full(model.n_cables, 12.0), drive_mode="pi")
    readings = plant.sense()
    l_ik = model.robot.cable_lengths(r, np.eye(3))
    assert np.abs(readings.cable_length - l_ik).max() > 1e-6  # the noise is there
    np.testing.assert_allclose(readings.following_error + readings.cable_length, l_ik, atol=1e-9)
