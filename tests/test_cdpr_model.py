"""IPAnema-3-Mini-like cable robot: model file, two engines, forward kinematics, statics."""

import dataclasses

import mujoco
import numpy as np
import pinocchio
import pytest

from msarm.allocation import make_allocator
from msarm.cdpr import CableRobot
from msarm.cdpr.forward_kinematics import (
    ForwardKinematicsError,
    forward_kinematics,
    matrix_from_quaternion,
    platform_wrench,
    quaternion_from_matrix,
    rotation_angle_between,
    rotation_matrix,
    rotation_vector,
)
from msarm.cdpr.robot_model import (
    IPANEMA_MINI_PATH,
    _check_engines_agree,
    load_cable_robot,
    pin_q_from_qpos,
    pin_v_from_qvel,
    pose_from_qpos,
    qpos_from_pin_q,
    qpos_from_pose,
    qvel_from_pin_v,
    qvel_from_twist,
    twist_from_qvel,
    velocity_map,
)
from msarm.errors import InputError, ModelError

SCALE = 0.1
FULL_A = np.array(
    [
        (-8.544, 5.463, 3.202),
        (8.184, 5.692, 3.236),
        (8.224, -5.492, 3.25),
        (-8.491, -5.322, 3.221),
        (-8.192, 5.648, -0.589),
        (7.208, 6.463, -0.548),
        (7.869, -5.557, -0.527),
        (-8.27, -5.545, -0.582),
    ]
)
FULL_B = np.array(
    [
        (-0.085, 0.748, 0.261),
        (0.095, 0.749, 0.26),
        (0.095, -0.745, 0.26),
        (-0.085, -0.746, 0.261),
        (-0.07, 0.648, -0.26),
        (0.06, 0.648, -0.262),
        (0.06, -0.651, -0.262),
        (-0.07, -0.651, -0.26),
    ]
)
G = 9.81


@pytest.fixture(scope="module")
def model():
    return load_cable_robot()


def random_poses(model, rng, count, max_angle=0.3):
    lo, hi = model.workspace_lower, model.workspace_upper
    r = rng.uniform(lo, hi, size=(count, 3))
    R = rotation_matrix(rng.uniform(-max_angle, max_angle, size=(count, 3)))
    return r, R


def mj_state(model, r, R, qvel=None):
    data = mujoco.MjData(model.mj_model)
    data.qpos[:] = qpos_from_pose(r, R)
    if qvel is not None:
        data.qvel[:] = qvel
    mujoco.mj_forward(model.mj_model, data)
    return data


# ------------------------------------------------------------------- the file


def test_file_geometry_is_scaled_ipanema3(model):
    assert model.n_cables == 8
    assert model.cable_names == tuple(f"cable_{i}" for i in range(8))
    np.testing.assert_allclose(model.robot.frame_anchors, SCALE * FULL_A, atol=1e-12)
    cross = [(i + 4) % 8 for i in range(8)]  # cable i runs from a_i to b_(i+4 mod 8)
    np.testing.assert_allclose(model.robot.platform_anchors, SCALE * FULL_B[cross], atol=1e-12)
    assert model.platform_site_names == tuple(f"b{j}" for j in cross)
    assert model.mass == pytest.approx(0.25)
    np.testing.assert_allclose(model.com, 0.0)
    np.testing.assert_array_equal(model.f_min, 5.0)
    np.testing.assert_array_equal(model.f_max, 35.0)
    np.testing.assert_allclose(model.gravity, [0.0, 0.0, -G])
    np.testing.assert_allclose(model.pin_model.gravity.linear, model.gravity)
    # Solid box 18 x 150 x 52 mm.
    lx, ly, lz = 0.018, 0.15, 0.052
    expected = 0.25 / 12 * np.diag([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
    np.testing.assert_allclose(model.inertia, expected, rtol=1e-8)
    np.testing.assert_allclose(model.home_qpos[:3], model.workspace_center)
    assert (model.pin_model.nq, model.pin_model.nv) == (7, 6)


# ------------------------------------------------------------------- coordinates


def test_quaternion_conventions(model):
    rng = np.random.default_rng(0)
    r, R = random_poses(model, rng, 20, max_angle=3.0)
    qpos = qpos_from_pose(r, R)
    assert qpos.shape == (20, 7)
    np.testing.assert_allclose(qpos_from_pose(r, R[0])[:, 3:], np.tile(qpos[0, 3:], (20, 1)))
    for k in range(20):  # MuJoCo's own conversion agrees (wxyz)
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, qpos[k, 3:])
        np.testing.assert_allclose(mat.reshape(3, 3), R[k], atol=1e-14)
    r2, R2 = pose_from_qpos(qpos)
    np.testing.assert_allclose(r2, r, atol=0)
    np.testing.assert_allclose(R2, R, atol=1e-14)
    q = pin_q_from_qpos(qpos)
    np.testing.assert_array_equal(q[:, 3:], qpos[:, [4, 5, 6, 3]])  # xyzw
    np.testing.assert_array_equal(qpos_from_pin_q(q), qpos)
    data = model.pin_model.createData()
    for k in range(5):  # Pinocchio's own conversion agrees (xyzw)
        pinocchio.forwardKinematics(model.pin_model, data, q[k])
        np.testing.assert_allclose(data.oMi[1].rotation, R[k], atol=1e-14)
        np.testing.assert_allclose(data.oMi[1].translation, r[k], atol=1e-15)
    np.testing.assert_allclose(quaternion_from_matrix(R[0]), qpos[0, 3:], atol=1e-15)
    np.testing.assert_allclose(matrix_from_quaternion(qpos[0, 3:]), R[0], atol=1e-15)
    with pytest.raises(InputError, match="unit quaternion"):
        pose_from_qpos(np.r_[r[0], 2.0, 0.0, 0.0, 0.0])


def test_velocity_conventions_match_both_integrators(model):
    rng = np.random.default_rng(1)
    r, R = random_poses(model, rng, 1)
    qpos = qpos_from_pose(r[0], R[0])
    qvel = rng.normal(size=6)
    v = pin_v_from_qvel(qpos, qvel)
    np.testing.assert_allclose(qvel_from_pin_v(pin_q_from_qpos(qpos), v), qvel, atol=1e-15)
    np.testing.assert_allclose(velocity_map(R[0]) @ v, qvel, atol=1e-15)
    # Pinocchio integrates along a screw, MuJoCo translation and rotation apart: the two
    # agree to O(dt^2), so a small step checks that both read the same velocity.
    dt = 1e-6
    q_next = pinocchio.integrate(model.pin_model, pin_q_from_qpos(qpos), v * dt)
    qpos_next = qpos.copy()
    mujoco.mj_integratePos(model.mj_model, qpos_next, qvel, dt)
    np.testing.assert_allclose(qpos_from_pin_q(q_next), qpos_next, rtol=0, atol=1e-11)
    vel, omega = twist_from_qvel(qpos, qvel)
    np.testing.assert_allclose(omega, R[0] @ qvel[3:], atol=1e-15)
    np.testing.assert_allclose(qvel_from_twist(qpos, vel, omega), qvel, atol=1e-15)


def test_rotation_vector_round_trip():
    rng = np.random.default_rng(2)
    for rotvec in rng.uniform(-1.5, 1.5, size=(20, 3)):
        np.testing.assert_allclose(rotation_vector(rotation_matrix(rotvec)), rotvec, atol=1e-13)
    tiny = np.array([1e-9, -2e-9, 3e-10])
    np.testing.assert_allclose(rotation_vector(rotation_matrix(tiny)), tiny, atol=1e-20)
    near_pi = np.array([0.0, 0.0, np.pi - 1e-9])
    assert rotation_angle_between(rotation_matrix(near_pi), np.eye(3)) == pytest.approx(
        np.pi - 1e-9, abs=1e-12
    )


def test_rotation_maps_agree_with_pinocchio():
    """exp and log of SO(3) against Pinocchio's exp3 / log3, small angles and near pi too."""
    rng = np.random.default_rng(3)
    rotvecs = np.vstack(
        [
            rng.uniform(-1.8, 1.8, size=(30, 3)),
            [[1e-7, -3e-8, 2e-7], [0.0, 0.0, 0.0]],
            [[0.0, np.pi - 1e-6, 0.0], [2.0, -1.0, 1.5]],
        ]
    )
    for rotvec in rotvecs:
        R = pinocchio.exp3(rotvec)
        np.testing.assert_allclose(rotation_matrix(rotvec), R, rtol=0, atol=1e-14)
        np.testing.assert_allclose(rotation_vector(R), pinocchio.log3(R), rtol=0, atol=1e-9)
    batch = rotation_matrix(rotvecs)
    for R, rotvec in zip(batch, rotvecs, strict=True):
        np.testing.assert_allclose(R, pinocchio.exp3(rotvec), rtol=0, atol=1e-14)


# ------------------------------------------------------------------- two engines


def test_tendon_lengths_and_jacobian_equal_cable_robot(model):
    rng = np.random.default_rng(3)
    r, R = random_poses(model, rng, 30)
    for k in range(30):
        data = mj_state(model, r[k], R[k])
        np.testing.assert_allclose(
            data.ten_length, model.cable_lengths(r[k], R[k]), rtol=0, atol=1e-9
        )
        # dl/dt = -A (v, omega) with qvel = (v, R^T omega): ten_J = -A diag(I, R).
        At = model.robot.structure_matrix(r[k], R[k])
        expected = -At.T @ np.block([[np.eye(3), np.zeros((3, 3))], [np.zeros((3, 3)), R[k]]])
        np.testing.assert_allclose(data.ten_J.reshape(8, 6), expected, atol=1e-9)


def test_pinocchio_mass_matrix_and_bias_equal_mujoco(model):
    rng = np.random.default_rng(4)
    r, R = random_poses(model, rng, 25, max_angle=np.pi)
    pdata = model.pin_model.createData()
    for k in range(25):
        qvel = rng.normal(scale=2.0, size=6)
        data = mj_state(model, r[k], R[k], qvel)
        qpos = data.qpos.copy()
        q, v = pin_q_from_qpos(qpos), pin_v_from_qvel(qpos, qvel)
        M_mj = np.zeros((6, 6))
        mujoco.mj_fullM(model.mj_model, data, M_mj)
        T = velocity_map(R[k])
        M_pin = pinocchio.crba(model.pin_model, pdata, q)
        M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
        np.testing.assert_allclose(M_pin, T.T @ M_mj @ T, rtol=0, atol=1e-9)
        dT_v = np.r_[R[k] @ np.cross(qvel[3:], v[:3]), np.zeros(3)]
        nle = pinocchio.nonLinearEffects(model.pin_model, pdata, q, v)
        np.testing.assert_allclose(nle, T.T @ (data.qfrc_bias + M_mj @ dT_v), rtol=0, atol=1e-9)
        # The same through accelerations: MuJoCo's forward dynamics, Pinocchio's ABA.
        tau = rng.normal(size=6)
        data.qfrc_applied[:] = tau
        mujoco.mj_forward(model.mj_model, data)
        a_pin = pinocchio.aba(model.pin_model, pdata, q, v, T.T @ tau)
        np.testing.assert_allclose(T @ a_pin + np.r_[dT_v[:3], 0, 0, 0], data.qacc, atol=1e-9)


def test_wrong_quaternion_order_is_caught(model):
    """Feeding MuJoCo's wxyz straight into Pinocchio gives a different gravity force."""
    r, R = model.robot.frame_anchors.mean(axis=0), rotation_matrix([0.4, -0.3, 0.2])
    data = mj_state(model, r, R)
    wrong = data.qpos.copy()
    nle = pinocchio.nonLinearEffects(
        model.pin_model, model.pin_model.createData(), wrong, np.zeros(6)
    )
    assert np.abs(nle - velocity_map(R).T @ data.qfrc_bias).max() > 0.1


def test_load_check_names_the_mismatched_cable(model):
    a = model.robot.frame_anchors.copy()
    a[3, 0] += 1e-6
    broken = dataclasses.replace(model, robot=CableRobot(a, model.robot.platform_anchors))
    with pytest.raises(ModelError, match="cable 'cable_3'"):
        _check_engines_agree(broken)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('<numeric name="cable_force_bounds" data="5 35"/>', "", "cable_force_bounds"),
        ('data="5 35"', 'data="35 5"', "0 <= f_min < f_max"),
        ('<site site="a2"/><site site="b6"/>', '<site site="a2"/><site site="a3"/>', "cable_2"),
        ('<site site="a1"/>', '<site site="a1"/><site site="a0"/>', "exactly two sites"),
        ('<frame name="frame">', '<body name="frame">', "exactly one body"),
        # forces MuJoCo would add on top of the plant's cables (the nominal model has none)
        (
            '<spatial name="cable_0">',
            '<spatial name="cable_0" stiffness="2000" springlength="0.5">',
            r"tendon stiffness is set \(2000 on tendon 'cable_0'\).*--plant",
        ),
        (
            '<spatial name="cable_1">',
            '<spatial name="cable_1" limited="true" range="0 0.9">',
            r"cable 'cable_1' has a length range",
        ),
        (
            '<freejoint name="platform_free"/>',
            '<joint type="free" name="platform_free" damping="0.1"/>',
            r"joint damping is set",
        ),
    ],
)
def test_bad_model_files(tmp_path, old, new, message):
    text = IPANEMA_MINI_PATH.read_text()
    assert old in text
    text = text.replace(old, new, 1)
    if new == '<body name="frame">':
        text = text.replace("</frame>", "</body>")
    path = tmp_path / "bad.xml"
    path.write_text(text)
    with pytest.raises(ModelError, match=message):
        load_cable_robot(path)


def test_a_platform_that_can_touch_the_world_is_refused(tmp_path):
    """A floor and a platform geom with contacts on loaded, and the run was 10.9 mm off."""
    text = IPANEMA_MINI_PATH.read_text()
    text = text.replace('contype="0" conaffinity="0"', 'contype="1" conaffinity="1"', 1)
    text = text.replace(
        '<body name="platform"',
        '<geom name="floor" type="plane" size="1 1 0.1"/>\n    <body name="platform"',
        1,
    )
    path = tmp_path / "floor.xml"
    path.write_text(text)
    with pytest.raises(ModelError, match=r"geom 'platform' can collide with geom 'floor'"):
        load_cable_robot(path)


def test_a_contact_pair_is_refused_and_contacts_switched_off_are_not(tmp_path):
    """A <contact><pair> collides whatever the masks; <flag contact="disable"/> none at all."""
    text = IPANEMA_MINI_PATH.read_text()
    floor = text.replace(
        '<body name="platform"',
        '<geom name="floor" type="plane" size="1 1 0.1"/>\n    <body name="platform"',
        1,
    )
    paired = floor.replace(
        "</worldbody>",
        '</worldbody>\n  <contact><pair geom1="platform" geom2="floor"/></contact>',
        1,
    )
    (tmp_path / "pair.xml").write_text(paired)
    with pytest.raises(ModelError, match=r"<contact><pair> of geoms '(platform|floor)' and"):
        load_cable_robot(tmp_path / "pair.xml")
    touching = floor.replace('contype="0" conaffinity="0"', 'contype="1" conaffinity="1"', 1)
    off = touching.replace("<option ", '<option><flag contact="disable"/></option>\n  <option ', 1)
    (tmp_path / "off.xml").write_text(off)
    load_cable_robot(tmp_path / "off.xml")


def test_missing_model_file(tmp_path):
    with pytest.raises(ModelError, match="not found"):
        load_cable_robot(tmp_path / "none.xml")


# ------------------------------------------------------------------- forward kinematics


def test_forward_kinematics_inverts_inverse_kinematics(model):
    rng = np.random.default_rng(5)
    r, R = random_poses(model, rng, 60)
    lengths = model.cable_lengths(r, R)
    for k in range(60):
        result = model.forward_kinematics(lengths[k])  # from the home pose
        assert np.abs(result.r - r[k]).max() < 1e-9
        assert rotation_angle_between(result.R, R[k]) < 1e-9
        assert result.residual < 1e-12
        assert result.iterations <= 10


def test_forward_kinematics_tracks_from_previous_pose(model):
    rng = np.random.default_rng(6)
    r, R = random_poses(model, rng, 1)
    r_prev, R_prev = r[0] - 0.002, rotation_matrix([0.004, 0.0, -0.003]) @ R[0]
    result = forward_kinematics(model.robot, model.cable_lengths(r[0], R[0]), r_prev, R_prev)
    assert np.abs(result.r - r[0]).max() < 1e-12
    assert result.iterations <= 4
    default_start = forward_kinematics(model.robot, model.cable_lengths(r[0], R[0]))
    assert np.abs(default_start.r - r[0]).max() < 1e-9  # from the frame anchors' centroid


def test_forward_kinematics_least_squares_for_inconsistent_lengths(model):
    """Noisy lengths (m > 6) have no exact pose: the least-squares pose, residual reported."""
    r, R = model.home_pose
    noise = np.random.default_rng(7).normal(scale=1e-4, size=8)
    result = model.forward_kinematics(model.cable_lengths(r, R) + noise)
    assert 1e-6 < result.residual < 1e-3
    e = model.cable_lengths(result.r, result.R) - (model.cable_lengths(r, R) + noise)
    A = model.robot.structure_matrix(result.r, result.R)
    np.testing.assert_allclose(A @ e, 0.0, atol=1e-12)  # normal equations hold
    assert np.abs(result.r - r).max() < 1e-3


def test_forward_kinematics_bad_input(model):
    lengths = model.cable_lengths(*model.home_pose)
    with pytest.raises(InputError, match=r"shape \(8,\)"):
        model.forward_kinematics(lengths[:7])
    with pytest.raises(InputError, match="finite"):
        model.forward_kinematics(np.r_[lengths[:7], np.nan])
    with pytest.raises(InputError, match="> 0"):
        model.forward_kinematics(np.r_[lengths[:7], -1.0])
    with pytest.raises(InputError, match="R0"):
        model.forward_kinematics(lengths, R0=2 * np.eye(3))
    with pytest.raises(InputError, match="max_iter"):
        model.forward_kinematics(lengths, max_iter=0)
    for bad in (0.0, True, "1e-6", float("nan")):
        with pytest.raises(InputError, match="max_residual must be a finite number > 0"):
            model.forward_kinematics(lengths, max_residual=bad)


def test_forward_kinematics_can_refuse_a_local_minimum():
    """A user's robot, a rotated pose started at R = I: the steps end 0.09 rad off the pose
    with a residual of 4e-6 m that looks like noise; max_residual refuses it, and a start
    near the pose recovers the pose exactly."""
    a = [
        [x, y, z]
        for z in (0.55, 0.0)
        for x, y in ((-0.6, 0.5), (0.6, 0.5), (0.6, -0.5), (-0.6, -0.5))
    ]
    b = [
        [x, y, z]
        for z in (0.03, -0.03)
        for x, y in ((-0.05, 0.04), (0.05, 0.04), (0.05, -0.04), (-0.05, -0.04))
    ]
    robot = CableRobot(a, b)
    r, R = np.array([-0.014, 0.092, 0.263]), rotation_matrix([-0.102, 0.027, 0.041])
    lengths = robot.cable_lengths(r, R)
    stuck = forward_kinematics(robot, lengths)
    assert rotation_angle_between(stuck.R, R) > 0.05 and 1e-7 < stuck.residual < 1e-4
    with pytest.raises(ForwardKinematicsError, match="more than max_residual 1e-07 m: a local"):
        forward_kinematics(robot, lengths, max_residual=1e-7)
    near = forward_kinematics(robot, lengths, r + 0.01, R, max_residual=1e-7)
    np.testing.assert_allclose(near.r, r, atol=1e-12)
    assert rotation_angle_between(near.R, R) < 1e-12


def test_forward_kinematics_non_convergence_is_an_error(model):
    r, R = model.home_pose
    lengths = model.cable_lengths(r + [0.3, -0.2, 0.05], rotation_matrix([0.2, 0.1, -0.2]) @ R)
    with pytest.raises(ForwardKinematicsError, match="did not converge in 2 iterations"):
        model.forward_kinematics(lengths, max_iter=2)


# ------------------------------------------------------------------- platform wrench


def test_platform_wrench_at_rest_is_the_weight(model):
    r, R = model.home_pose
    np.testing.assert_allclose(
        model.platform_wrench(r, rotation_matrix([0.3, 0.2, -0.1])),
        [0, 0, -0.25 * G, 0, 0, 0],
        atol=1e-15,
    )
    # With the CoM off the reference point the weight has a moment c x m g about r.
    c = np.array([0.01, -0.02, 0.005])
    w = platform_wrench(r, R, mass=0.25, inertia=model.inertia, com=c)
    np.testing.assert_allclose(w[3:], np.cross(c, [0, 0, -0.25 * G]), atol=1e-15)
    batch = model.platform_wrench(np.tile(r, (4, 1)), R)
    assert batch.shape == (4, 6)


def inverse_dynamics_check(mj_model, rng, com, inertia, count=10):
    """-w from platform_wrench equals MuJoCo's inverse dynamics at random states."""
    data = mujoco.MjData(mj_model)
    for _ in range(count):
        r = rng.uniform(-0.2, 0.2, 3)
        R = rotation_matrix(rng.uniform(-np.pi, np.pi, 3) / 2)
        data.qpos[:] = qpos_from_pose(r, R)
        data.qvel[:] = rng.normal(scale=3.0, size=6)
        data.qacc[:] = rng.normal(scale=5.0, size=6)
        mujoco.mj_inverse(mj_model, data)
        v, omega = twist_from_qvel(data.qpos, data.qvel)
        a, alpha = data.qacc[:3], R @ data.qacc[3:]  # d/dt (R omega_p) = R d(omega_p)/dt
        w = platform_wrench(r, R, v, omega, a, alpha, mass=0.25, inertia=inertia, com=com)
        # qfrc_inverse: the cable wrench, force in K_0 and moment about r in K_p.
        np.testing.assert_allclose(data.qfrc_inverse[:3], -w[:3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(data.qfrc_inverse[3:], -R.T @ w[3:], rtol=0, atol=1e-9)


def test_platform_wrench_inertial_part_matches_mujoco(model):
    inverse_dynamics_check(model.mj_model, np.random.default_rng(8), model.com, model.inertia)


def test_platform_wrench_with_offset_com_and_full_inertia_matches_mujoco():
    com = np.array([0.012, -0.007, 0.02])
    inertia = np.array([[4e-4, 2e-5, -1e-5], [2e-5, 1e-4, 3e-5], [-1e-5, 3e-5, 3.5e-4]])
    full = " ".join(str(x) for x in inertia[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]])
    mj_model = mujoco.MjModel.from_xml_string(
        f"""<mujoco><worldbody><body name="p"><freejoint/>
        <inertial pos="{com[0]} {com[1]} {com[2]}" mass="0.25" fullinertia="{full}"/>
        </body></worldbody></mujoco>"""
    )
    inverse_dynamics_check(mj_model, np.random.default_rng(9), com, inertia)


def test_platform_wrench_bad_input(model):
    r, R = model.home_pose
    with pytest.raises(InputError, match="mass"):
        platform_wrench(r, R, mass=0.0, inertia=model.inertia)
    with pytest.raises(InputError, match="omega"):
        platform_wrench(r, R, omega=[np.nan, 0, 0], mass=0.25, inertia=model.inertia)
    with pytest.raises(InputError, match="one length N"):
        platform_wrench(np.zeros((3, 3)), R, a=np.zeros((4, 3)), mass=0.25, inertia=np.eye(3))


# ------------------------------------------------------------------- statics


def test_min_norm_equilibrium_at_workspace_centre(model):
    r, R = model.workspace_center, np.eye(3)
    At = model.robot.structure_matrix(r, R)
    w = model.platform_wrench(r, R)
    result = make_allocator(8, 6, "fast").solve(At, -w, model.f_min, model.f_max)
    assert result.feasible
    np.testing.assert_allclose(At @ result.f + w, 0.0, atol=1e-9)
    assert np.all(result.f >= 5.0 - 1e-9) and np.all(result.f <= 35.0 + 1e-9)
    assert model.is_feasible(r, R)


def test_workspace_box_is_feasible(model):
    lo, hi = model.workspace_lower, model.workspace_upper
    axes = [np.linspace(lo[k], hi[k], 9) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    assert model.feasible_poses(grid).all()
    assert model.first_infeasible(grid) is None
    # bounds of another length or a word are named (a bare numpy error before)
    for bad in (np.ones(3), "a"):
        with pytest.raises(InputError, match=r"f_min must be a number or of shape \(8,\) \[N\]"):
            model.feasible_poses(grid[:2], f_min=bad)


def test_pose_near_frame_corner_is_infeasible(model):
    corner = 0.9 * model.robot.frame_anchors[0]  # 10 % in from the upper corner a_0
    assert not model.is_feasible(corner, np.eye(3))
    At = model.robot.structure_matrix(corner, np.eye(3))
    result = make_allocator(8, 6, "fast").solve(
        At, -model.platform_wrench(corner, np.eye(3)), model.f_min, model.f_max
    )
    assert not result.feasible


def test_first_infeasible_names_the_right_sample(model):
    start, corner = model.workspace_center, 0.9 * model.robot.frame_anchors[0]
    path = start + np.linspace(0.0, 1.0, 41)[:, None] * (corner - start)
    flags = [model.is_feasible(p, np.eye(3)) for p in path]
    expected = flags.index(False)
    assert 0 < expected < 40
    assert model.first_infeasible(path) == expected
    with pytest.raises(InputError, match=f"at sample {expected} "):
        model.check_trajectory(path)
    model.check_trajectory(path[:expected])  # the feasible part passes
    # Per-sample wrenches: a large upward push at sample 3 makes it infeasible there.
    w = model.platform_wrench(path, np.eye(3))
    w[3, 2] += 400.0
    assert model.first_infeasible(path, np.eye(3), w) == 3
    with pytest.raises(InputError, match="wrenches"):
        model.first_infeasible(path, None, np.zeros((5, 6)))


def test_a_transposed_structure_matrix_is_named(model):
    from msarm.allocation import is_wrench_feasible

    r, R = model.home_pose
    At, w = model.robot.structure_matrix(r, R), model.platform_wrench(r, R)
    assert is_wrench_feasible(At, w, model.f_min, model.f_max)
    with pytest.raises(InputError, match=r"structure_matrix has shape \(8, 6\).*transposed"):
        is_wrench_feasible(At.T, w, model.f_min, model.f_max)
    with pytest.raises(InputError, match=r"f_min has 6 entries .* m = 8 columns"):
        is_wrench_feasible(At, w, model.f_min[:6], model.f_max)


def test_feasibility_names_too_few_cables_and_a_wrench_of_the_wrong_size(model):
    """A 4-cable robot got "M must have shape (N, n, m) with 1 <= n <= m, got (1, 6, 4)"; a
    3-vector wrench an error blaming the structure matrix ("expected (n, m) with n = 3")."""
    top = np.array([[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [1.0, 1.0, 2.0], [-1.0, 1.0, 2.0]])
    four = dataclasses.replace(
        model,
        robot=CableRobot(top, 0.1 * top * [1.0, 1.0, 0.0]),
        cable_names=("c0", "c1", "c2", "c3"),
        f_min=np.full(4, 5.0),
        f_max=np.full(4, 35.0),
    )
    r = np.array([0.0, 0.0, 1.0])
    with pytest.raises(InputError, match=r"needs at least 6 cables .* it has 4"):
        four.is_feasible(r, np.eye(3))
    with pytest.raises(InputError, match=r"needs at least 6 cables .* it has 4"):
        four.first_infeasible(r[None, :])
    centre = model.workspace_center
    with pytest.raises(InputError, match=r"wrench must have shape \(6,\) or \(k, 6\) .*got \(3,\)"):
        model.is_feasible(centre, np.eye(3), [0.0, 0.0, -2.45])
    assert model.is_feasible(centre, np.eye(3), model.platform_wrench(centre, np.eye(3)))
