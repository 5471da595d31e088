"""Gaps found by a hand-made mutation round over msarm.cdpr: kinematics, following error,
switching (eq. 10), sensitivity index, force estimation and forward kinematics.

Every test compares with an independent reference: hand-computed values, a brute-force
search (switching cycles, corners of the error box), the equilibrium A^T f + w = 0,
Rodrigues' closed form, a known pose, or a promise of the module's docstring.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

# sensitivity_map imports msarm.allocation (and cvxpy, several seconds) on its first call;
# importing it here puts that one-off cost into collection, not into a test's duration.
import msarm.allocation  # noqa: F401
from msarm.cdpr import CableRobot, WinchParameters, force_from_motor_torque
from msarm.cdpr.following_error import FollowingErrorModel
from msarm.cdpr.forward_kinematics import (
    ForwardKinematicsError,
    forward_kinematics,
    platform_wrench,
    rotation_matrix,
    rotation_vector,
)
from msarm.cdpr.sensitivity import (
    pair_sensitivities,
    sensitivity_index,
    sensitivity_map,
    sensitivity_matrix,
)
from msarm.cdpr.switching import HALF_PI, SwitchingFactor, switching_cycles, switching_time
from msarm.errors import InputError


def _box_robot() -> CableRobot:
    top = np.array([[-2.0, 1.5, 2.0], [2.0, 1.5, 2.0], [2.0, -1.5, 2.0], [-2.0, -1.5, 2.0]])
    bottom = top * [1.0, 1.0, 0.0]
    plate = np.array([[-0.1, 0.1, 0.07], [0.1, 0.1, 0.07], [0.1, -0.1, 0.07], [-0.1, -0.1, 0.07]])
    return CableRobot(np.vstack([top, bottom]), np.vstack([plate, plate * [1.0, 1.0, -1.0]]))


# --- kinematics -----------------------------------------------------------------------------


def test_anchors_with_four_columns_are_refused_by_their_shape():
    """Both anchor arrays (m, 4): same shape, so only the (m, 3) check can refuse them."""
    with pytest.raises(InputError, match=r"frame_anchors must have shape \(m, 3\)"):
        CableRobot(np.ones((8, 4)), np.ones((8, 4)))


def test_a_slightly_non_orthonormal_rotation_is_refused():
    """|R R^T - I| = 0.0201 for R = 1.01 I: not a rotation; 1e-9 of round-off is accepted."""
    robot = _box_robot()
    r = np.array([0.0, 0.0, 1.0])
    with pytest.raises(InputError, match="rotation matrix"):
        robot.structure_matrix(r, 1.01 * np.eye(3))
    c, s = math.cos(0.3), math.sin(0.3)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) * (1.0 + 1e-9)
    assert robot.structure_matrix(r, R).shape == (6, 8)


def test_one_position_with_a_batch_of_rotations_is_refused():
    """r of shape (3,) is one pose: R must then be (3, 3), not a batch (1, 3, 3)."""
    robot = _box_robot()
    with pytest.raises(InputError, match=r"R must have shape \(3, 3\)"):
        robot.inverse_kinematics(np.array([0.0, 0.0, 1.0]), np.eye(3)[None])


# --- following error (eq. 8-9) --------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [({"k_p": 0.0}, "k_p"), ({"c_v": math.nan}, "c_v"), ({"c_v": math.inf}, "c_v")],
)
def test_following_error_model_refuses_a_zero_gain_and_a_non_finite_c_v(kwargs, name):
    with pytest.raises(InputError, match=name):
        FollowingErrorModel(**kwargs)


# --- switching (eq. 10) ---------------------------------------------------------------------


def _brute_force_cycles(delta: float) -> int:
    """Smallest n with n * delta >= pi/2 in floating point, by counting up."""
    n = 0
    while n * delta < HALF_PI:
        n += 1
    return n


def test_switching_cycles_equal_the_brute_force_count_for_pi_half_over_n():
    """delta = (pi/2) / n sits on the rounding edge of ceil((pi/2) / delta): for some n the
    quotient rounds above n although n * delta >= pi/2 already (n = 61 is one)."""
    for n in range(1, 400):
        delta = HALF_PI / n
        expected = _brute_force_cycles(delta)
        assert switching_cycles(delta) == expected, n
    s = SwitchingFactor(HALF_PI / 61)
    s.activate()
    assert s.cycles_left == _brute_force_cycles(HALF_PI / 61)
    steps = 0
    while s.switching:
        s.step()
        steps += 1
    assert steps == _brute_force_cycles(HALF_PI / 61) and s.h == 1.0


def test_switching_off_steps_alpha_down_by_delta():
    """From h = 1, switching off gives alpha = pi/2 - k delta, h = cos^2(k delta)."""
    delta = 0.02
    s = SwitchingFactor(delta, active=True)
    s.deactivate()
    for k in range(1, 6):
        s.step()
        assert s.alpha == pytest.approx(HALF_PI - k * delta, abs=1e-15)
        assert 0.0 <= s.alpha <= HALF_PI
        assert s.h == pytest.approx(math.cos(k * delta) ** 2, abs=1e-15)


def test_calling_activate_every_cycle_does_not_turn_alpha_into_a_running_sum():
    """Module docstring: alpha is the start plus k delta after k steps, so it does not
    drift; a controller that calls activate() every cycle must not restart the count."""
    delta = 0.0005
    s = SwitchingFactor(delta)
    for k in range(1, 3143):
        s.activate()
        s.step()
        if k < 3142:
            assert s.alpha == k * delta, k
    assert not s.switching and s.h == 1.0


def test_switching_time_refuses_a_zero_cycle_time():
    with pytest.raises(InputError, match="cycle_time"):
        switching_time(0.02, 0.0)
    assert switching_time(0.02, 2e-3) == pytest.approx(79 * 2e-3)


# --- sensitivity index ----------------------------------------------------------------------


def test_sensitivity_matrix_sign_and_order_keep_the_equilibrium():
    """Docstring: Delta f_P = -S Delta f_C keeps A^T f + w = 0, rows in ascending P and
    columns in ascending C, whatever the order in which C is given."""
    robot = _box_robot()
    At = robot.structure_matrix(np.array([0.3, -0.2, 0.8]), np.eye(3))
    c, p = [1, 5], [0, 2, 3, 4, 6, 7]
    S = sensitivity_matrix(At, [5, 1])
    delta_c = np.array([0.7, -1.3])  # cables 1 and 5
    delta_f = np.zeros(8)
    delta_f[c] = delta_c
    delta_f[p] = -S @ delta_c
    np.testing.assert_allclose(At @ delta_f, 0.0, atol=1e-12)
    assert np.abs(S).max() > 0.1  # a real test: the controlled cables do move the others


def _worst_corner(At, pair, e, f, w):
    """Brute force over the corners of the error box +-e on the pair: the largest change of a
    position-controlled tension, and the smallest distance of any tension to its bounds
    (as a function of the bounds), with the pose held by the other cables."""
    others = [k for k in range(At.shape[1]) if k not in pair]
    worst_change, tensions = 0.0, []
    for d in [(-1, -1), (-1, 1), (1, -1), (1, 1)]:
        g = f.copy()
        g[list(pair)] += e * np.array(d, dtype=float)
        g[others] = np.linalg.solve(At[:, others], -w - At[:, list(pair)] @ g[list(pair)])
        worst_change = max(worst_change, np.abs(g[others] - f[others]).max())
        tensions.append(g)
    return worst_change, np.array(tensions)


# 8 cables at arbitrary anchors: at (0, 0, 1) the pair (1, 3) moves every other tension by
# less than the error bound itself (sigma = 0.80 N for e = 1 N).
_SKEW_FRAME = [
    [1.4, -1.4, 0.3], [1.7, 0.9, 0.5], [-0.6, -1.4, 0.3], [-2.0, 0.3, 1.2],
    [-1.4, 1.0, 1.0], [0.4, 0.5, 0.4], [1.2, -0.3, 1.0], [-1.5, -0.7, 0.9],
]  # fmt: skip
_SKEW_PLATE = [
    [0.04, -0.01, 0.01], [0.05, -0.02, -0.1], [0.01, 0.09, -0.09], [-0.01, 0.03, -0.0],
    [-0.08, 0.0, -0.08], [-0.09, -0.03, -0.06], [0.0, 0.09, -0.06], [0.1, -0.03, 0.07],
]  # fmt: skip


def test_map_sigma_below_the_error_bound_counts_only_the_position_controlled_cables():
    """sigma is the largest change of a *position-controlled* tension; the controlled cables'
    own error e does not enter it, which shows where sigma < e."""
    robot = CableRobot(_SKEW_FRAME, _SKEW_PLATE)
    r = np.array([0.0, 0.0, 1.0])
    At = robot.structure_matrix(r, np.eye(3))
    worst, _ = _worst_corner(At, (1, 3), 1.0, np.zeros(8), np.zeros(6))
    assert 0.5 < worst < 0.95
    assert float(sensitivity_index(At, (1, 3))) == pytest.approx(worst, rel=1e-12)
    m = sensitivity_map(
        robot, (1, 3), [0.0], [0.0], [1.0], wrench=np.zeros(6), f_min=0.0, f_max=50.0
    )
    assert float(m.sigma[0, 0, 0]) == pytest.approx(worst, rel=1e-12)


def test_map_margin_is_the_worst_corner_distance_to_either_bound():
    """margin = min over the error-box corners of the distance of every tension to its bounds.

    The minimum-norm tensions sit on f_min = 0 N at every feasible pose here, but at the
    grid's edge the largest reach 119.1 N, within the error of f_max = 120 N, so there the
    upper bound is the one that binds."""
    robot = _box_robot()
    w = np.array([0.0, 0.0, -2.0 * 9.81, 0.0, 0.0, 0.0])
    x, y, z = [-0.6, -0.2, 0.2, 0.6], [-0.4, 0.0, 0.4], [0.6, 1.0, 1.4]
    lo, hi = 0.0, 120.0
    m = sensitivity_map(robot, (0, 3), x, y, z, wrench=w, f_min=lo, f_max=hi)
    At = robot.structure_matrix(m.positions.reshape(-1, 3), np.eye(3))
    forces, feasible, margin = m.forces.reshape(-1, 8), m.feasible.ravel(), m.margin.ravel()
    upper_binds = 0
    for k in np.flatnonzero(feasible):
        _, g = _worst_corner(At[k], (0, 3), 1.0, forces[k], w)
        assert margin[k] == pytest.approx(min((g - lo).min(), (hi - g).min()), abs=1e-9)
        upper_binds += (hi - g).min() < (g - lo).min()
    assert upper_binds > 0
    # Share of the *feasible* points with sigma < 1.5 N; some points are infeasible.
    assert 0 < feasible.sum() < feasible.size
    expected = np.mean(m.sigma.ravel()[feasible] < 1.5)
    assert 0.0 < expected < 1.0
    assert m.fraction_acceptable(1.5) == pytest.approx(expected, rel=1e-15)
    # "sigma < threshold" is strict: a threshold equal to a point's sigma leaves it out.
    k = int(np.flatnonzero(feasible)[0])
    t = float(m.sigma.ravel()[k])
    assert not m.acceptable(t).ravel()[k]
    assert m.acceptable(float(np.nextafter(t, np.inf))).ravel()[k]


def test_sensitivity_map_refuses_pushing_cables_and_bounds_of_another_length():
    """Bounds are checked as CableRobotModel's: f_min = -5 N gave a feasible map with forces
    down to -1.3 N (cables pushing), bounds of 3 entries a bare numpy broadcast error."""
    robot = _box_robot()
    kwargs = {"wrench": np.array([0.0, 0.0, -2.0 * 9.81, 0.0, 0.0, 0.0])}
    grid = ([0.0], [0.0], [1.0])
    with pytest.raises(InputError, match=r"f_min must be finite and >= 0 N .*got -5"):
        sensitivity_map(robot, (0, 3), *grid, f_min=-5.0, f_max=35.0, **kwargs)
    with pytest.raises(InputError, match=r"f_max must be a number or of shape \(8,\) \[N\]"):
        sensitivity_map(robot, (0, 3), *grid, f_min=5.0, f_max=np.full(3, 35.0), **kwargs)
    with pytest.raises(InputError, match=r"f_min must be <= f_max, got f_min = 40.0"):
        sensitivity_map(robot, (0, 3), *grid, f_min=40.0, f_max=35.0, **kwargs)
    ok = sensitivity_map(robot, (0, 3), *grid, f_min=np.full(8, 5.0), f_max=35.0, **kwargs)
    assert ok.forces.min() >= 5.0 - 1e-9


def test_sensitivity_refuses_fractional_indices_and_pair_table_refuses_a_batch():
    robot = _box_robot()
    At = robot.structure_matrix(np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]]), np.eye(3))
    with pytest.raises(InputError, match="cable indices"):
        sensitivity_index(At[0], [0.0, 1.5])
    with pytest.raises(InputError, match="one pose"):
        pair_sensitivities(At)


# --- forward kinematics and rotations -------------------------------------------------------


def test_rotation_matrix_below_the_taylor_switch_matches_rodrigues():
    """Rodrigues: (R - R^T) / 2 = sin(theta)/theta [v]x; at theta = 8.4e-5 rad (Taylor branch)
    a wrong theta^2 coefficient in a or b shows as a relative error of about 1e-9."""
    v = np.array([3e-5, -5e-5, 6e-5])
    theta = float(np.linalg.norm(v))
    assert theta < 1e-4
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    R = rotation_matrix(v)
    np.testing.assert_allclose((R - R.T) / 2.0, math.sin(theta) / theta * K, rtol=1e-13, atol=0)
    # Symmetric part: (1 - cos theta)/theta^2 v v^T off the diagonal, written without the
    # cancellation as 2 sin^2(theta/2)/theta^2; the entries are ~5e-9 next to a K ~ 6e-5, so
    # round-off leaves them about 1e-11 relative, below the 1.2e-9 of a wrong theta^2 term.
    off = ~np.eye(3, dtype=bool)
    b = 2.0 * math.sin(theta / 2.0) ** 2 / theta**2
    np.testing.assert_allclose(((R + R.T) / 2.0)[off], (b * np.outer(v, v))[off], rtol=1e-10)


def test_a_reflection_is_not_a_rotation():
    """-I is orthonormal with det -1: refused wherever a rotation matrix is read."""
    with pytest.raises(InputError, match="rotation matrix"):
        rotation_vector(-np.eye(3))
    robot = _box_robot()
    lengths = robot.cable_lengths(np.array([0.0, 0.0, 1.0]), np.eye(3))
    with pytest.raises(InputError, match="R0 must be a rotation matrix"):
        forward_kinematics(robot, lengths, R0=-np.eye(3))


def test_platform_wrench_refuses_an_asymmetric_inertia():
    inertia = np.diag([1e-3, 2e-3, 3e-3])
    inertia[0, 1] = 1e-4
    with pytest.raises(InputError, match="symmetric"):
        platform_wrench(np.zeros(3), np.eye(3), mass=0.25, inertia=inertia)


def test_forward_kinematics_starts_at_the_frame_anchor_centroid():
    """Default start: the centroid of the frame anchors, here (0, 0, 1); lengths of that
    pose converge in one (zero) Newton step."""
    robot = _box_robot()
    centroid = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(robot.frame_anchors.mean(axis=0), centroid, atol=1e-15)
    result = forward_kinematics(robot, robot.cable_lengths(centroid, np.eye(3)))
    assert result.iterations == 1
    np.testing.assert_allclose(result.r, centroid, atol=1e-15)


def test_forward_kinematics_takes_exactly_max_iter_steps_and_wants_an_integer():
    robot = _box_robot()
    r = np.array([0.3, -0.2, 1.2])
    R = rotation_matrix([0.1, -0.05, 0.2])
    lengths = robot.cable_lengths(r, R)
    n = forward_kinematics(robot, lengths).iterations
    assert n >= 3
    exact = forward_kinematics(robot, lengths, max_iter=n)  # n steps are allowed
    assert exact.iterations == n and np.abs(exact.r - r).max() < 1e-12
    with pytest.raises(ForwardKinematicsError, match=f"in {n - 1} iterations"):
        forward_kinematics(robot, lengths, max_iter=n - 1)
    with pytest.raises(InputError, match="max_iter"):
        forward_kinematics(robot, lengths, max_iter=2.5)
    with pytest.raises(InputError, match="> 0"):
        forward_kinematics(robot, np.r_[lengths[:7], 0.0])


def test_forward_kinematics_from_a_far_start_needs_the_step_halving():
    """From near a frame corner the full Newton step overshoots: the line search has to halve
    it many times (about ten) before the residual falls, and still finds the pose."""
    robot = _box_robot()
    r = np.array([-0.5, 0.5, 0.8])
    lengths = robot.cable_lengths(r, np.eye(3))
    result = forward_kinematics(robot, lengths, r0=np.array([-1.5, 1.2, 1.8]))
    assert np.abs(result.r - r).max() < 1e-9
    assert np.abs(rotation_vector(result.R)).max() < 1e-9


def test_forward_kinematics_refuses_lengths_that_do_not_determine_the_pose():
    """Where the length Jacobian A has rank < 6 the least-squares steps are minimum-norm ones
    and ended at an arbitrary pose with a zero residual: 4 cables gave r off by 2 mm and a
    rotation of 0.0017 rad; 8 cables on one platform point leave the rotation free."""
    top = np.array([[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [1.0, 1.0, 2.0], [-1.0, 1.0, 2.0]])
    four = CableRobot(top, 0.1 * top * [1.0, 1.0, 0.0])
    r = np.array([0.2, 0.1, 1.0])
    with pytest.raises(
        ForwardKinematicsError, match=r"4 cables do not determine .* rank at most 4"
    ):
        forward_kinematics(four, four.cable_lengths(r, np.eye(3)), r0=[0.2, 0.1, 0.9])
    point = CableRobot(_box_robot().frame_anchors, np.zeros((8, 3)))
    lengths = point.cable_lengths(np.array([0.1, 0.0, 1.0]), np.eye(3))
    with pytest.raises(ForwardKinematicsError, match=r"do not determine the pose .*rank 3 < 6"):
        forward_kinematics(point, lengths)
    # the same frame with a real platform: rank 6, the pose is found
    robot = _box_robot()
    result = forward_kinematics(robot, robot.cable_lengths(np.array([0.1, 0.0, 1.0]), np.eye(3)))
    np.testing.assert_allclose(result.r, [0.1, 0.0, 1.0], atol=1e-12)


def test_forward_kinematics_of_unreachable_lengths_says_they_may_be():
    """Lengths no pose has (all 100 times too short) do not converge; the message names that
    cause beside a far start."""
    robot = _box_robot()
    lengths = 0.01 * robot.cable_lengths(np.array([0.2, 0.1, 1.0]), np.eye(3))
    with pytest.raises(ForwardKinematicsError, match="may be unreachable or inconsistent"):
        forward_kinematics(robot, lengths)


# --- force estimation (eq. 3) ---------------------------------------------------------------


def test_default_drum_inertia_gives_0_075_kg_times_a():
    """Module docstring: tau_In is J_D a / r_D^2 = 0.075 kg times a for the defaults; with
    no torque, no friction and a = 2 m/s^2 the estimate is 0.15 N."""
    f = force_from_motor_torque(0.0, 0.0, 2.0, friction_model=False)
    assert float(f) == pytest.approx(0.15, rel=1e-12)


def test_winch_with_no_inertia_is_allowed_and_a_zero_drum_radius_is_not():
    """J_D >= 0: a massless drum leaves f = tau / r_D whatever a (0.2 N m / 0.02 m = 10 N)."""
    winch = WinchParameters(drum_inertia=0.0)
    f = force_from_motor_torque(0.2, 0.0, 5.0, winch=winch, friction_model=False)
    assert float(f) == pytest.approx(10.0, rel=1e-12)
    with pytest.raises(InputError, match="drum_radius"):
        WinchParameters(drum_radius=0.0)


def test_following_error_for_force_without_friction_is_eq_8_of_f_r_d():
    """No tau_F, no inertia term (a = 0), feed-forward: FE = (c_f / K_p) f r_D, by hand
    -0.511 / 200 * (10 N * 0.02 m) = -5.11e-4 m, also at 3 m/min where tau_F would add."""
    winch = WinchParameters()
    fe = winch.following_error_for_force(10.0, 0.05, 0.0, friction_model=False)
    assert float(fe) == pytest.approx(-5.11e-4, rel=1e-12)
    # Without feed-forward eq. 9 adds c_v v = 8.893e-5 min * 3 m/min.
    fe = winch.following_error_for_force(
        10.0, 0.05, 0.0, friction_model=False, velocity_feedforward=False
    )
    assert float(fe) == pytest.approx(-5.11e-4 + 8.893e-5 * 3.0, rel=1e-12)
