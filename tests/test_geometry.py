"""Muscle geometry: J_c against finite differences, sign convention, controllability."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from msarm.errors import InputError
from msarm.muscle.geometry import joint_grid, positive_spanning_margin

SHOULDER_CABLES = slice(0, 7)
ELBOW_CABLES = slice(7, 9)


def test_jacobian_matches_finite_differences(arm):
    rng = np.random.default_rng(7)
    step = 1e-6
    worst = 0.0
    for _ in range(40):
        q = rng.uniform(arm.joint_lower + 2 * step, arm.joint_upper - 2 * step)
        jacobian = arm.geometry(q).jacobian
        numeric = np.empty_like(jacobian)
        for k in range(arm.n_joints):
            dq = np.zeros(arm.n_joints)
            dq[k] = step
            numeric[:, k] = (arm.geometry(q + dq).lengths - arm.geometry(q - dq).lengths) / (
                2 * step
            )
        worst = max(worst, np.abs(jacobian - numeric).max())
    assert worst < 1e-6


def test_cable_velocity_is_jacobian_times_joint_velocity(arm):
    q = np.array([0.2, 0.4, -0.3, -1.0])
    qdot = np.array([0.5, -0.2, 0.3, 1.0])
    geometry = arm.geometry(q, qdot)
    np.testing.assert_allclose(geometry.velocities, geometry.jacobian @ qdot, atol=1e-15)
    h = 1e-6
    numeric = (arm.geometry(q + h * qdot).lengths - arm.geometry(q - h * qdot).lengths) / (2 * h)
    np.testing.assert_allclose(geometry.velocities, numeric, atol=1e-8)


@pytest.mark.parametrize(
    ("cable", "joint", "direction"),
    [
        ("biceps", "elbow", -1.0),  # flexes: the elbow angle decreases
        ("triceps", "elbow", +1.0),
        ("deltoid_lateral", "shoulder_abduction", +1.0),
        ("latissimus_dorsi", "shoulder_flexion", -1.0),
        ("deltoid_anterior", "shoulder_flexion", +1.0),
        ("latissimus_dorsi", "shoulder_rotation", +1.0),
        ("infraspinatus", "shoulder_rotation", -1.0),
        ("teres_minor", "shoulder_rotation", -1.0),
    ],
)
def test_pulling_a_cable_turns_its_joint_the_documented_way(arm, cable, joint, direction):
    """tau = -J_c^T f: simulate the pull in MuJoCo, with gravity off, and watch the joint."""
    m_model = arm.mj_model
    saved_gravity = m_model.opt.gravity.copy()
    m_model.opt.gravity[:] = 0.0
    try:
        data = mujoco.MjData(m_model)
        q0 = np.array([0.3, 0.3, -0.2, -0.8])
        data.qpos[:] = q0
        forces = np.zeros(arm.n_cables)
        forces[arm.cable_names.index(cable)] = 20.0
        for _ in range(20):
            geometry = arm.geometry(data.qpos.copy())
            data.qfrc_applied[:] = geometry.joint_torque(forces)
            mujoco.mj_step(m_model, data)
    finally:
        m_model.opt.gravity[:] = saved_gravity
    k = arm.joint_names.index(joint)
    torque = arm.geometry(q0).joint_torque(forces)
    assert np.sign(torque[k]) == direction
    assert np.sign(data.qpos[k] - q0[k]) == direction
    # The cable that pulls shortens.
    assert arm.geometry(data.qpos.copy()).lengths[forces > 0] < arm.geometry(q0).lengths[forces > 0]


def test_elbow_cables_act_on_the_elbow_only_and_shoulder_cables_on_the_shoulder_only(arm):
    for q in joint_grid(arm.joint_lower, arm.joint_upper, 3):
        jacobian = arm.geometry(q).jacobian
        assert np.abs(jacobian[ELBOW_CABLES, :3]).max() < 1e-12
        assert np.abs(jacobian[SHOULDER_CABLES, 3]).max() < 1e-12


def test_arm_is_controllable_over_a_grid_of_the_joint_range(arm):
    """Full column rank and positive spanning: any torque with every cable taut."""
    worst = np.inf
    for q in joint_grid(arm.joint_lower, arm.joint_upper, 5):
        jacobian = arm.geometry(q).jacobian
        assert np.linalg.matrix_rank(jacobian) == arm.n_joints
        worst = min(worst, positive_spanning_margin(jacobian))
    assert worst > 0.02


def test_shoulder_paths_clear_the_humeral_head(arm):
    """The straight shoulder paths never cut through the joint (a 3 cm humeral head)."""
    head = arm.mj_model.geom("humeral_head")
    radius = float(head.size[0])
    m_data = arm.scratch_data().mj
    from msarm.muscle.geometry import path_points

    for q in joint_grid(arm.joint_lower, arm.joint_upper, [5, 5, 5, 1]):
        arm.geometry(q)
        centre = m_data.xpos[arm.mj_model.body("upper_arm").id]
        for cable in range(7):
            (points,) = path_points(arm.mj_model, m_data, cable)
            start, end = points[-2], points[-1]
            direction = (end - start) / np.linalg.norm(end - start)
            t = np.clip((centre - start) @ direction, 0, np.linalg.norm(end - start))
            assert np.linalg.norm(start + t * direction - centre) > radius


def test_wrap_angles_are_positive_and_change_with_posture(arm):
    straight = arm.geometry(np.zeros(4)).wrap_angles
    bent = arm.geometry(np.array([0.8, 1.0, 0.5, -2.0])).wrap_angles
    assert np.all(straight > 0) and np.all(bent > 0)
    assert np.all(np.abs(bent - straight) > 1e-3)


def test_wrap_angle_of_a_right_angle_path_is_pi_over_two(tmp_path):
    from msarm.model import load_robot

    path = tmp_path / "corner.xml"
    path.write_text(
        """<mujoco><worldbody><body name="b"><joint name="j" type="slide" axis="1 0 0"/>
        <geom type="sphere" size="0.01" mass="1"/>
        <site name="a" pos="0 0 0"/><site name="c" pos="0 1 1"/></body>
        <site name="w" pos="0 0 1"/></worldbody>
        <tendon><spatial name="cable"><site site="a"/><site site="w"/><site site="c"/></spatial>
        </tendon></mujoco>"""
    )
    robot = load_robot(path)
    np.testing.assert_allclose(robot.geometry(np.zeros(1)).wrap_angles, [np.pi / 2], atol=1e-12)


def test_bad_postures_are_refused(arm):
    with pytest.raises(InputError, match=r"q must have shape \(4,\)"):
        arm.geometry(np.zeros(3))
    with pytest.raises(InputError, match="q must be finite"):
        arm.geometry(np.array([0.0, np.nan, 0.0, 0.0]))
    with pytest.raises(InputError, match=r"q must be an array of real numbers \[rad\], got 'abc'"):
        arm.geometry("abc")
    with pytest.raises(InputError, match="q must be real numbers; got complex values"):
        arm.geometry(np.zeros(4) + 0.1j)


def test_positive_spanning_margin_on_known_cases():
    assert positive_spanning_margin(np.array([[1.0], [-1.0]])) == pytest.approx(0.5)
    assert positive_spanning_margin(np.array([[1.0], [2.0]])) == -np.inf
    assert positive_spanning_margin(np.array([[1.0, 0.0], [0.0, 1.0]])) == -np.inf


def test_joint_torque_refuses_forces_of_the_wrong_size_or_not_finite(arm):
    geometry = arm.geometry(np.zeros(4))
    with pytest.raises(InputError, match=r"forces must have shape \(9,\), got \(8,\)"):
        geometry.joint_torque(np.full(8, 50.0))
    with pytest.raises(InputError, match="forces must be finite"):
        geometry.joint_torque(np.full(9, np.nan))
    np.testing.assert_array_equal(
        geometry.joint_torque(np.full(9, 50.0)), -geometry.jacobian.T @ np.full(9, 50.0)
    )
