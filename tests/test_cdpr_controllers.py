"""CDPR controllers of paper 000 (IKC, HC-f, HC-tau, HC-e, HC-e-all, NC), the high-level PID
(eq. 11, Table 2) and the Fig. 9 trajectories: pure signal tests, no plant."""

import math

import numpy as np
import pytest

from msarm.allocation.workspace import feasibility_batch
from msarm.cdpr.forward_kinematics import platform_wrench, rotation_matrix
from msarm.cdpr.robot_model import load_cable_robot
from msarm.cdpr.sensitivity import sensitivity_index
from msarm.cdpr.switching import switching_cycles
from msarm.control.cdpr_controllers import (
    CDPR_CONTROLLERS,
    DRIVE_P,
    DRIVE_PI,
    CdprMeasurement,
    NullspaceController,
    PlatformParameters,
    RegionPairSelector,
    SensitivityPairSelector,
    cable_motion,
    list_cdpr_controllers,
    make_cdpr_controller,
)
from msarm.control.pid import (
    HC_E_GAINS,
    HC_F_GAINS,
    HC_TAU_GAINS,
    TABLE_2,
    DiscretePID,
    PIDGains,
)
from msarm.errors import InputError
from msarm.tasks.cdpr_trajectories import (
    CDPR_TRAJECTORIES,
    SPEED,
    get_cdpr_trajectory,
    list_cdpr_trajectories,
)

DT = 1e-3


@pytest.fixture(scope="module")
def model():
    return load_cable_robot()


@pytest.fixture(scope="module")
def trajectories():
    return {name: get_cdpr_trajectory(name) for name in list_cdpr_trajectories()}


def _centre(model):
    return np.array(model.workspace_center, dtype=float)


# --------------------------------------------------------------------------- PID (eq. 11)


def test_table_2_gains():
    assert (HC_F_GAINS.k, HC_F_GAINS.t_i, HC_F_GAINS.t_v, HC_F_GAINS.t_d) == pytest.approx(
        (3.0e-4, 0.070, 0.015, 0.005), rel=1e-15
    )
    assert (HC_TAU_GAINS.k, HC_TAU_GAINS.t_i, HC_TAU_GAINS.t_v, HC_TAU_GAINS.t_d) == pytest.approx(
        (2.0e-2, 0.200, 0.0, 0.0), rel=1e-15
    )
    assert (HC_E_GAINS.k, HC_E_GAINS.t_i, HC_E_GAINS.t_v, HC_E_GAINS.t_d) == pytest.approx(
        (0.45, 0.007, 0.0, 0.0), rel=1e-15
    )
    assert HC_TAU_GAINS.is_pi and HC_E_GAINS.is_pi and not HC_F_GAINS.is_pi
    assert set(TABLE_2) == {"hc-f", "hc-tau", "hc-e"}


def test_pid_step_response_is_the_backward_euler_image_of_eq_11():
    g = HC_F_GAINS
    pid = DiscretePID(g, n=1, dt=DT)
    n = 400
    u = np.array([pid.step(1.0)[0] for _ in range(n)])
    k = np.arange(n)
    rho = g.t_d / (g.t_d + DT)
    # Hand-computed: P + backward-Euler integral + filtered derivative of a unit step.
    expected = g.k + g.k * DT * (k + 1) / g.t_i + g.k * g.t_v / (g.t_d + DT) * rho**k
    np.testing.assert_allclose(u, expected, rtol=1e-9, atol=0.0)
    # Continuous eq. 11: integral ramp slope K/T_i per second once the derivative has died.
    slope = (u[-1] - u[-2]) / DT
    assert slope == pytest.approx(g.k / g.t_i, rel=1e-9)
    # Derivative filter: decay per cycle 1/(1 + T/T_d) (time constant T_d), and the area
    # under the derivative impulse equals the continuous one, K T_v.
    pid = DiscretePID(g, n=1, dt=DT)
    d = []
    for _ in range(2000):
        pid.step(1.0)
        d.append(pid.derivative[0])
    d = np.array(d)
    np.testing.assert_allclose(d[1:50] / d[:49], 1.0 / (1.0 + DT / g.t_d), rtol=1e-12)
    assert d.sum() * DT == pytest.approx(g.k * g.t_v, rel=1e-9)


def test_pid_derivative_tends_to_continuous_filter_for_small_steps():
    g = HC_F_GAINS
    dt = 1e-6
    pid = DiscretePID(g, n=1, dt=dt)
    n = 20000  # 20 ms = 4 T_d
    d = np.empty(n)
    for i in range(n):
        pid.step(1.0)
        d[i] = pid.derivative[0]
    t = np.arange(n) * dt
    continuous = g.k * g.t_v / g.t_d * np.exp(-t / g.t_d)
    assert np.max(np.abs(d - continuous)) < 1e-3 * continuous[0]


def test_pid_is_pi_when_t_v_is_zero():
    for gains in (HC_E_GAINS, HC_TAU_GAINS, PIDGains(0.3, 0.05, 0.0, 0.004)):
        pid = DiscretePID(gains, n=2, dt=DT)
        e = np.array([1.0, -2.0])
        for k in range(50):
            u = pid.step(e)
            expected = gains.k * e * (1.0 + (k + 1) * DT / gains.t_i)
            np.testing.assert_allclose(u, expected, rtol=1e-12)
        assert np.all(pid.derivative == 0.0)


def test_pid_anti_windup_and_reset():
    g = PIDGains(1.0, 0.01)
    pid = DiscretePID(g, n=2, dt=DT, output_min=-0.05, output_max=0.05)
    for _ in range(5000):
        u = pid.step(np.array([0.02, -0.02]))
    np.testing.assert_allclose(u, [0.05, -0.05])
    # The integrator did not wind up beyond what the limit allows ...
    np.testing.assert_allclose(pid.integral, [0.05 - 0.02, -0.05 + 0.02], rtol=1e-12)
    # ... so the output leaves the limit as soon as the error changes sign.
    u = pid.step(np.array([-0.02, 0.02]))
    assert u[0] < 0.05 and u[1] > -0.05
    pid.reset(np.array([True, False]))
    assert pid.integral[0] == 0.0 and pid.integral[1] != 0.0
    with pytest.raises(InputError):
        DiscretePID(g, output_min=1.0, output_max=0.0)
    with pytest.raises(InputError):
        PIDGains(1.0, 0.0)


# --------------------------------------------------------------------------- nominal model


def test_platform_wrench_helper_matches_forward_kinematics(model):
    rng = np.random.default_rng(3)
    params = PlatformParameters(
        mass=model.mass,
        inertia=np.diag([1e-3, 2e-3, 3e-3]) + 1e-4,
        com=np.array([0.01, -0.02, 0.005]),
        gravity=model.gravity,
    )
    for _ in range(5):
        r, v, w, a, al = rng.normal(size=(5, 3))
        R = rotation_matrix(0.3 * rng.normal(size=3))
        ours = params.wrench(r, R, v, w, a, al)
        ref = platform_wrench(
            r, R, v, w, a, al, mass=params.mass, inertia=params.inertia, com=params.com,
            gravity=params.gravity,
        )  # fmt: skip
        np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-14)


def test_cable_velocity_and_acceleration_match_finite_differences(model, trajectories):
    tr = trajectories["circle-12"]
    R = np.eye(3)
    zero = np.zeros(3)
    k = np.arange(2000, 2100)
    out = [cable_motion(model.robot, tr.position[i], R, tr.velocity[i], zero,
                        tr.acceleration[i], zero) for i in k]  # fmt: skip
    lengths = np.array([o[0] for o in out])
    l_dot = np.array([o[1] for o in out])
    l_ddot = np.array([o[2] for o in out])
    fd_v = (lengths[2:] - lengths[:-2]) / (2 * DT)
    fd_a = (l_dot[2:] - l_dot[:-2]) / (2 * DT)
    np.testing.assert_allclose(l_dot[1:-1], fd_v, atol=1e-7)
    np.testing.assert_allclose(l_ddot[1:-1], fd_a, atol=1e-6)
    np.testing.assert_allclose(out[0][3], model.robot.structure_matrix(tr.position[k[0]], R))
    # Rotating platform: l_dot = -A twist, checked by finite differences of a rotation.
    omega = np.array([0.2, -0.1, 0.3])
    r0 = _centre(model)
    l0, ld, _, At = cable_motion(model.robot, r0, R, zero, omega, zero, zero)
    h = 1e-6
    lp = model.robot.cable_lengths(r0, rotation_matrix(omega * h))
    lm = model.robot.cable_lengths(r0, rotation_matrix(-omega * h))
    np.testing.assert_allclose(ld, (lp - lm) / (2 * h), atol=1e-8)
    np.testing.assert_allclose(ld, -At.T @ np.concatenate([zero, omega]), atol=1e-12)


def test_desired_forces_at_centre_at_rest_balance_the_weight_within_8_35(model):
    for name in list_cdpr_controllers():
        ctrl = make_cdpr_controller(name, model)
        nom = ctrl.nominal(_centre(model))
        assert nom.feasible
        np.testing.assert_allclose(nom.wrench, [0, 0, -model.mass * 9.81, 0, 0, 0], atol=1e-12)
        np.testing.assert_allclose(nom.structure_matrix @ nom.forces + nom.wrench, 0, atol=1e-9)
        assert nom.forces.min() >= 8.0 - 1e-9 and nom.forces.max() <= 35.0 + 1e-9
    # The lower bound is active somewhere: without it the minimum-norm forces go below 8 N.
    assert nom.forces.min() == pytest.approx(8.0, abs=1e-7)


# --------------------------------------------------------------------------- signs


def _hybrid(model, name, **options):
    return make_cdpr_controller(name, model, pair_selector=(0, 1), start_active=True, **options)


def _reading_for(ctrl, name, nom, target, cable, tension_offset):
    """A reading equal to the target except on ``cable``: the reading of a tension offset."""
    m = ctrl.m
    if name == "hc-f":
        value = target.copy()
        value[cable] += tension_offset
        return CdprMeasurement(load_cell=np.where(np.isnan(value), nom.forces, value))
    r_d = ctrl.winch.drum_radius
    tau = ctrl.targets(nom, np.arange(m)) if name == "hc-tau" else None
    if name == "hc-tau":
        tau[cable] += tension_offset * r_d
        return CdprMeasurement(motor_torque=tau)
    # HC-e: the FE the drive shows at the torque of the offset tension (eq. 9).
    tau = ctrl.winch.motor_torque(nom.forces, nom.velocities, nom.accelerations)
    tau[cable] += tension_offset * r_d
    return CdprMeasurement(following_error=ctrl.winch.following_error.following_error(tau, 0.0))


@pytest.mark.parametrize("name", ["hc-f", "hc-tau", "hc-e"])
@pytest.mark.parametrize("offset", [-1.0, 1.0])
def test_hybrid_reels_in_when_tension_reads_low_and_pays_out_when_high(model, name, offset):
    ctrl = _hybrid(model, name)
    r = _centre(model)
    nom = ctrl.nominal(r)
    target = np.full(ctrl.m, np.nan)
    target[list(ctrl.switchable)] = ctrl.targets(nom, list(ctrl.switchable))
    meas = _reading_for(ctrl, name, nom, target, 0, offset)
    cmd = ctrl.step(r, measurement=meas)
    assert cmd.h[0] == 1.0 and cmd.h[1] == 1.0
    change = cmd.l_set - cmd.l_ik
    # Tension too low (offset < 0): shorter set length (reel in); too high: pay out.
    assert np.sign(change[0]) == np.sign(offset) and abs(change[0]) > 1e-7
    np.testing.assert_allclose(change[1:], 0.0, atol=1e-15)
    np.testing.assert_allclose(cmd.l_ik, model.robot.cable_lengths(r, np.eye(3)), atol=1e-15)
    if name == "hc-e":
        # In eq. 9's convention less tension reads as a larger (less negative) FE.
        fe = meas.following_error
        assert (fe[0] > cmd.target[0]) == (offset < 0)


def test_hc_f_closes_the_loop_on_a_spring_cable(model):
    """A toy cable with stiffness k: tension rises when the set length shortens. The loop
    converges to the set force only if the sign is right."""
    ctrl = _hybrid(model, "hc-f")
    r = _centre(model)
    nom = ctrl.nominal(r)
    f_set = ctrl.targets(nom, [0, 1])
    k = 800.0  # N/m (with a one-cycle delay, Table 2's HC-f gains are stable up to ~900 N/m)
    offset = np.array([-3.0, 2.0])  # the cables start 3 N low and 2 N high
    l_set = nom.lengths.copy()
    for _ in range(4000):
        tension = f_set + offset + k * (nom.lengths[:2] - l_set[:2])
        load = nom.forces.copy()
        load[:2] = tension
        l_set = ctrl.step(r, measurement=CdprMeasurement(load_cell=load)).l_set
    tension = f_set + offset + k * (nom.lengths[:2] - l_set[:2])
    np.testing.assert_allclose(tension, f_set, atol=1e-3)
    assert l_set[0] < nom.lengths[0] and l_set[1] > nom.lengths[1]


def test_hc_tau_without_friction_model_drops_tau_f(model, trajectories):
    tr = trajectories["triangle-12"]
    i = 4000  # cruising
    with_f = _hybrid(model, "hc-tau")
    without = _hybrid(model, "hc-tau", friction_model=False)
    nom = with_f.nominal(tr.position[i], tr.velocity[i], tr.acceleration[i])
    cables = np.array([0, 1])
    v = nom.velocities[cables]
    assert np.all(np.abs(v) > 0.004)  # beyond v_L: friction is on its outer branch
    winch = with_f.winch
    base = nom.forces[cables] * winch.drum_radius - (
        winch.drum_inertia * nom.accelerations[cables] / winch.drum_radius
    )
    np.testing.assert_allclose(without.targets(nom, cables), base, rtol=1e-14)
    np.testing.assert_allclose(
        with_f.targets(nom, cables), base + winch.friction.torque(nom.forces[cables], v),
        rtol=1e-14,
    )  # fmt: skip


def test_set_values_follow_eq_3_7_9_on_a_moving_sample(model, trajectories):
    tr = trajectories["circle-12"]
    i = 5000  # cruising: cable velocities beyond v_L, non-zero accelerations
    cables = np.array([0, 1])
    ctrls = {name: _hybrid(model, name) for name in ("hc-f", "hc-tau", "hc-e")}
    nom = ctrls["hc-f"].nominal(tr.position[i], tr.velocity[i], tr.acceleration[i])
    f, v, a = nom.forces[cables], nom.velocities[cables], nom.accelerations[cables]
    assert np.all(np.abs(v) > 0.004) and np.all(np.abs(a) > 0)
    winch = ctrls["hc-f"].winch
    f_set = f + winch.friction.force(f, v)  # eq. 7: the load cell reads f + f_F
    tau = (
        f * winch.drum_radius
        + winch.friction.torque(f, v)
        - (winch.drum_inertia * a / winch.drum_radius)
    )  # eq. 3
    fe_model = winch.following_error
    fe = fe_model.c_f * tau / fe_model.k_p + fe_model.c_v * v  # eq. 9
    np.testing.assert_allclose(ctrls["hc-f"].targets(nom, cables), f_set, rtol=1e-14)
    np.testing.assert_allclose(ctrls["hc-tau"].targets(nom, cables), tau, rtol=1e-14)
    # Without velocity feedforward (the paper's PLC) the P position loop lags by c_v v: eq. 9.
    no_ff = _hybrid(model, "hc-e", velocity_feedforward=False)
    np.testing.assert_allclose(no_ff.targets(nom, cables), fe, rtol=1e-12)
    cmd = no_ff.step(tr.position[i], tr.velocity[i], tr.acceleration[i],
                     CdprMeasurement(following_error=np.zeros(8)))  # fmt: skip
    np.testing.assert_array_equal(cmd.v_ff, 0.0)
    # With v_ff = v_i (default) the lag is gone: eq. 8's torque term alone.
    np.testing.assert_allclose(ctrls["hc-e"].targets(nom, cables), fe - fe_model.c_v * v,
                               rtol=1e-12)  # fmt: skip
    assert np.all(np.abs(f_set - f) > 1e-3)  # friction matters here


# --------------------------------------------------------------------------- all controllers


def test_registry_and_drive_modes(model):
    assert set(CDPR_CONTROLLERS) == {"ikc", "hc-f", "hc-tau", "hc-e", "hc-e-all", "nc"}
    with pytest.raises(InputError, match="valid names: ikc, hc-f, hc-tau, hc-e, hc-e-all, nc"):
        make_cdpr_controller("hc-x", model)
    r = _centre(model)
    m = 8
    nom_forces = make_cdpr_controller("ikc", model).nominal(r).forces
    meas = CdprMeasurement(
        cable_length=np.zeros(m),
        motor_torque=0.02 * nom_forces,
        following_error=np.zeros(m),
        load_cell=nom_forces,
    )
    modes = {}
    for name in list_cdpr_controllers():
        cmd = make_cdpr_controller(name, model).step(r, measurement=meas)
        modes[name] = cmd.drive_mode
        assert cmd.l_set.shape == cmd.v_ff.shape == (m,)
        np.testing.assert_allclose(cmd.v_ff, 0.0, atol=1e-15)  # at rest
    assert modes["ikc"] == modes["hc-f"] == modes["hc-tau"] == modes["nc"] == (DRIVE_PI,) * m
    assert modes["hc-e"] == (DRIVE_P,) * 4 + (DRIVE_PI,) * 4  # both switchable pairs P
    assert modes["hc-e-all"] == (DRIVE_P,) * m
    with pytest.raises(InputError, match="valid options"):
        make_cdpr_controller("hc-e", model, gain=1.0)
    with pytest.raises(InputError, match="load_cell"):
        make_cdpr_controller("hc-f", model).step(r, measurement=CdprMeasurement())


def test_ikc_is_pure_inverse_kinematics(model, trajectories):
    tr = trajectories["circle-34"]
    ctrl = make_cdpr_controller("ikc", model)
    for i in (0, 3000, 6000):
        cmd = ctrl.step(tr.position[i], tr.velocity[i], tr.acceleration[i])
        l_ik, l_dot, _, _ = cable_motion(
            model.robot, tr.position[i], np.eye(3), tr.velocity[i], np.zeros(3),
            tr.acceleration[i], np.zeros(3),
        )  # fmt: skip
        np.testing.assert_array_equal(cmd.l_set, l_ik)
        np.testing.assert_array_equal(cmd.v_ff, l_dot)


def test_hc_e_all_controls_every_cable(model):
    ctrl = make_cdpr_controller("hc-e-all", model, start_active=True)
    r = _centre(model)
    nom = ctrl.nominal(r)
    fe = ctrl.targets(nom, np.arange(8))
    fe_low = fe + 1e-4  # every FE reads a lower tension
    cmd = ctrl.step(r, measurement=CdprMeasurement(following_error=fe_low))
    assert cmd.force_controlled == tuple(range(8))
    assert np.all(cmd.l_set < cmd.l_ik)


def test_nullspace_controller_keeps_pose_and_raises_low_forces(model):
    ctrl = make_cdpr_controller("nc", model)
    assert isinstance(ctrl, NullspaceController)
    r = _centre(model)
    load = np.full(8, 12.0)
    load[5] = 5.0  # one cable below 7 N
    cmd = ctrl.step(r, measurement=CdprMeasurement(load_cell=load))
    At = model.robot.structure_matrix(r, np.eye(3))
    dl = cmd.l_set - cmd.l_ik
    assert np.abs(dl).max() > 0
    np.testing.assert_allclose(At @ dl, 0.0, atol=1e-15)  # no pose change to first order
    assert dl[5] < 0  # the slack cable is reeled in
    # A pure mean error: forces above 12 N are paid out along the nullspace.
    ctrl.reset()
    f_hat = ctrl.estimate_forces(load, np.zeros(8))
    np.testing.assert_array_equal(f_hat, load)  # at rest eq. 7 gives f_F = 0
    v = np.full(8, 0.05)
    f_hat = ctrl.estimate_forces(load, v)
    np.testing.assert_allclose(f_hat + ctrl.winch.friction.force(f_hat, v), load, atol=1e-12)
    err = ctrl.force_error(np.array([12.0, 6.0, 20.0, 12, 12, 12, 12, 12]))
    np.testing.assert_allclose(err[:3], [0.0, -6.0 - 4.0, 8.0])


def test_nullspace_controller_refuses_inconsistent_force_levels(model):
    """low_force = 50 > mean_force = 12 N was accepted: every cable would count as low."""
    with pytest.raises(InputError, match=r"low_force <= mean_force <= f_max.*low_force=50, mean"):
        make_cdpr_controller("nc", model, low_force=50.0, mean_force=12.0)
    with pytest.raises(InputError, match=r"mean_force=40, f_max=35 N"):
        make_cdpr_controller("nc", model, mean_force=40.0)
    equal = make_cdpr_controller("nc", model, low_force=12.0, mean_force=12.0)
    assert (equal.low_force, equal.mean_force) == (12.0, 12.0)


# --------------------------------------------------------------------------- switching


def test_region_selector_matches_the_sensitivity_index(model, trajectories):
    region = RegionPairSelector()
    sens = SensitivityPairSelector(hysteresis=0.0)
    for y in (-0.15, -0.08, 0.08, 0.15):
        r = np.array([-0.025, y, 0.115])
        At = model.robot.structure_matrix(r, np.eye(3))
        assert region.select(r, At, None) == sens.select(r, At, None)
    assert region.select(np.array([0.0, 0.0, 0.1]), None, None) == (2, 3)  # y <= 0


@pytest.mark.parametrize("delta", [0.02, 0.5])
def test_rectangle_switches_the_pair_in_the_eq_10_number_of_cycles(model, trajectories, delta):
    tr = trajectories["rectangle-switch"]
    y = tr.position[:, 1]
    up = int(np.flatnonzero((y[:-1] <= 0.0) & (y[1:] > 0.0))[0]) + 1  # first sample y > 0
    down = int(np.flatnonzero((y[:-1] > 0.0) & (y[1:] <= 0.0))[0]) + 1
    assert up < down
    ctrl = make_cdpr_controller("hc-e", model, delta=delta, start_active=True)
    fe = CdprMeasurement(following_error=np.full(8, -0.03))
    n = switching_cycles(delta)
    start = up - 200
    hs, pairs, cmds = [], [], []
    for i in range(start, up + n + 50):
        cmd = ctrl.step(tr.position[i], tr.velocity[i], tr.acceleration[i], fe)
        hs.append(cmd.h)
        pairs.append(ctrl.pair)
        cmds.append(cmd)
    hs = np.array(hs)
    k0 = up - start
    assert pairs[k0 - 1] == (2, 3) and pairs[k0] == (0, 1)
    np.testing.assert_array_equal(hs[:k0, 2:4], 1.0)
    np.testing.assert_array_equal(hs[:k0, 0:2], 0.0)
    first_on = k0 + int(np.flatnonzero(hs[k0:, 0] == 1.0)[0])
    first_off = k0 + int(np.flatnonzero(hs[k0:, 2] == 0.0)[0])
    assert first_on - k0 + 1 == n and first_off - k0 + 1 == n
    ramp = np.sin(np.arange(1, n) * delta) ** 2
    np.testing.assert_allclose(hs[k0 : k0 + n - 1, 0], ramp, rtol=1e-12)
    ramp_down = np.sin(math.pi / 2 - np.arange(1, n) * delta) ** 2
    np.testing.assert_allclose(hs[k0 : k0 + n - 1, 2], ramp_down, rtol=1e-12)
    np.testing.assert_array_equal(hs[:, 4:], 0.0)
    for cmd in cmds:  # l_set = l_IK + h Delta l on every cable
        np.testing.assert_allclose(cmd.l_set, cmd.l_ik + cmd.h * cmd.delta_l, atol=1e-15)
    assert cmds[-1].force_controlled == (0, 1)
    # The deactivated pair's PID is reset: no correction left on it.
    np.testing.assert_array_equal(cmds[-1].delta_l[2:4], 0.0)


# --------------------------------------------------------------------------- trajectories


def test_trajectory_registry():
    assert list_cdpr_trajectories() == [
        "triangle-12", "circle-12", "triangle-34", "circle-34", "rectangle-switch",
    ]  # fmt: skip
    assert set(CDPR_TRAJECTORIES) == set(list_cdpr_trajectories())
    with pytest.raises(InputError, match="valid names: triangle-12"):
        get_cdpr_trajectory("square")
    with pytest.raises(InputError, match="unknown option"):
        get_cdpr_trajectory("circle-12", radius=1.0)


def test_trajectories_speed_continuity_and_rest(trajectories):
    for name, tr in trajectories.items():
        assert tr.name == name
        assert SPEED == pytest.approx(4.0 / 60.0, rel=1e-15)
        speed = np.linalg.norm(tr.velocity, axis=1)
        cruise = tr.cruise_mask
        assert cruise.sum() > 0.7 * len(tr)
        np.testing.assert_allclose(speed[cruise], 4.0 / 60.0, rtol=0.0, atol=1e-9)
        assert speed.max() <= 4.0 / 60.0 + 1e-12
        np.testing.assert_allclose(np.diff(tr.t), DT, rtol=1e-9)
        steps = np.linalg.norm(np.diff(tr.position, axis=0), axis=1)
        assert steps.max() <= SPEED * DT * (1 + 1e-9)  # continuous, no jumps
        np.testing.assert_allclose(tr.position[0], tr.position[-1], atol=1e-12)  # closed
        assert np.all(speed[:400] == 0.0) and np.all(speed[-400:] == 0.0)  # holds
        np.testing.assert_allclose(tr.position[:, 2], 0.115)
        np.testing.assert_array_equal(tr.rotation, np.eye(3))
        # Velocity and acceleration are the derivatives of the position.
        fd_v = np.gradient(tr.position, DT, axis=0)
        np.testing.assert_allclose(fd_v[1:-1], tr.velocity[1:-1], atol=6e-5)
        fd_a = np.gradient(tr.velocity, DT, axis=0)
        smooth = np.linalg.norm(fd_a - tr.acceleration, axis=1) < 1e-3
        assert smooth.mean() > 0.99  # except next to the arc joins of the rounded corners
        assert np.abs(tr.acceleration).max() <= 0.26


def test_trajectories_inside_the_workspace_and_their_pairs_region(model, trajectories):
    lower, upper = model.workspace_lower, model.workspace_upper
    rel = model.robot
    for name, tr in trajectories.items():
        assert np.all(tr.position >= lower) and np.all(tr.position <= upper), name
        sub = slice(None, None, 25)
        pos, acc = tr.position[sub], tr.acceleration[sub]
        At = rel.structure_matrix(pos, np.eye(3))
        w = platform_wrench(pos, np.eye(3), a=acc, mass=model.mass, inertia=model.inertia,
                            gravity=model.gravity)  # fmt: skip
        # The 8-35 N distribution of the controllers exists along the whole motion.
        assert feasibility_batch(At, -w, 8.0, 35.0).all(), name
        pair = tr.force_controlled_pair
        if pair is None:  # rectangle: the region rule's pair at every sample
            y = pos[:, 1]
            assert y.min() < -0.1 and y.max() > 0.1
            sigma = np.where(y > 0, sensitivity_index(At, [0, 1]), sensitivity_index(At, [2, 3]))
        else:
            sigma = sensitivity_index(At, list(pair))
            expected = (0, 1) if tr.position[:, 1].min() > 0 else (2, 3)
            assert pair == expected
        assert sigma.max() < 1.5, name  # Fig. 7: sigma_ij < 1.5 N


# --------------------------------------------------------------------------- options


def test_the_option_table_covers_every_constructor_parameter():
    """Every keyword option of every controller has a plain type (or none: an object)."""
    import inspect

    from msarm.control.cdpr_controllers import _OPTION_TYPES, _OPTIONS

    plain = {"float": (float,), "bool": (bool,), "str": (str,), "float | None": (float, type(None))}
    for name, cls in CDPR_CONTROLLERS.items():
        params = {}
        for klass in cls.__mro__:
            if "__init__" in vars(klass) and klass is not object:
                for p in inspect.signature(klass.__init__).parameters.values():
                    if p.kind is inspect.Parameter.KEYWORD_ONLY:
                        params.setdefault(p.name, p.annotation)
        assert set(_OPTIONS[name]) <= set(params), name
        for key, annotation in params.items():
            if key in ("feedback", "all_cables"):  # fixed by the controller's class
                continue
            types = _OPTION_TYPES[key]
            if annotation in plain:
                assert types == plain[annotation], key
            elif "str" in annotation.split(" | "):  # pair_selector: a word, or an object
                assert types == (str,), key
            else:  # an object only
                assert types == (), key


def test_object_options_of_the_wrong_type_are_refused_by_name(model):
    with pytest.raises(InputError, match=r"gains must be a PIDGains .*got str 'foo'"):
        make_cdpr_controller("hc-e", model, gains="foo")
    with pytest.raises(InputError, match=r"winch must be a WinchParameters .*got int 1"):
        make_cdpr_controller("ikc", model, winch=1)
    with pytest.raises(InputError, match=r"invalid option value .*'f_max': '1e9'"):
        make_cdpr_controller("hc-e", model, f_max="1e9")


def test_plain_options_are_checked_against_their_type():
    from msarm.control.cdpr_controllers import check_plain_options

    check_plain_options("nc", {"f_max": 40, "k_i": 1e-3, "friction_model": False})
    check_plain_options("hc-e", {"delta_l_limit": None, "pair_selector": "sensitivity"})
    for name, options, message in (
        (
            "hc-e",
            {"fe_feedforward": "flase"},
            "'fe_feedforward' .* expects true or false, got 'flase'",
        ),
        ("hc-e", {"start_active": "maybe"}, "'start_active' .* expects true or false, got 'maybe'"),
        ("ikc", {"velocity_feedforward": 2}, "'velocity_feedforward' .* true or false, got 2"),
        ("hc-f", {"f_max": True}, "'f_max' .* expects a number, got True"),
        ("nc", {"delta_l_limit": "none"}, "'delta_l_limit' .* a number or null, got 'none'"),
        ("hc-e", {"pair_selector": [0, 1]}, "expects a word, got \\[0, 1\\]; a fixed cable pair"),
        ("hc-e", {"gains": 1}, "'gains' .* cannot be set from the command line"),
        ("nc", {"winch": "foo"}, "'winch' .* cannot be set from the command line"),
    ):
        with pytest.raises(InputError, match=message):
            check_plain_options(name, options)
    with pytest.raises(InputError, match="valid options: ") as info:
        check_plain_options("hc-e", {"gain": 1.0})
    listed = str(info.value).split("valid options: ")[1].split(", ")
    assert "gains" not in listed and "winch" not in listed and "fe_feedforward" in listed
    with pytest.raises(InputError, match=r"invalid option .*'all_cables'"):
        check_plain_options("hc-f", {"all_cables": True})
