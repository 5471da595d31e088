"""msarm.tasks.evaluate.evaluate_run: every metric of a hand-made run against hand values."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from msarm.tasks.evaluate import cable_travel, evaluate_run

DT = 0.004  # s
N_SAMPLES = 250  # 1 s
HOME = np.array([0.0, 0.0, 0.0, -0.2])
TARGET = np.array([0.1, 0.3, -0.2, -0.8])
#: The reference rests at HOME until sample 10, moves until sample 60 and rests at TARGET
#: from there (0.24 s): the settle error is taken 0.5 s later, at sample 185 (0.74 s).
SETTLE = 185
SETTLE_POSTURE = TARGET + [0.0, 0.0, 0.0, 0.05]
FINAL_POSTURE = TARGET + [0.002, 0.0, 0.0, 0.0]
DRUM_RADIUS = 0.004  # m (not the plant's default, so that it must be the one passed)
THETA_0 = 1.5  # rad: the motor encoders do not start at 0
MIN_TENSION = 5.0  # N: lower bound 4 N with the 1 N tolerance


def _hand(arm, q) -> np.ndarray:
    """The hand site's position [m] from a fresh MjData (not the library's scratch data)."""
    data = mujoco.MjData(arm.mj_model)
    data.qpos[:] = q
    mujoco.mj_kinematics(arm.mj_model, data)
    return data.site("hand_center").xpos.copy()


def _reference() -> np.ndarray:
    s = np.clip((np.arange(N_SAMPLES) - 10) / 50.0, 0.0, 1.0)[:, None]
    return HOME + s * (TARGET - HOME)


def _tensions(arm) -> np.ndarray:
    """20 N everywhere but for dips below 1 N (slack) and excursions beyond [4 N, F_max + 1 N].

    Per cable: (slack events, samples outside the bounds)
    - cable 0: (2, 10) - 0.5 N x3 (slack), 1.0 N x1 (exactly the threshold: taut, but below
      4 N), 0 N x2 (slack again), 4.5 N x5 (inside: within the tolerance), 3.9 N x2,
      F_max + 0.5 N x3 (inside), F_max + 1.5 N x2;
    - cable 1: (1, 25) - 0.2 N for its first 5 samples (slack from the start: no event),
      0.9 N for its last 20 (an event);
    - cable 7: (0, 3) - F_max + 1.5 N x3, F_max + 0.9 N x1;
    - cable 8: (0, 0) - exactly 4.0 N (the lower bound less the tolerance) x10;
    - the others: (0, 0).
    """
    f_max = np.asarray(arm.muscles.max_isometric_force, dtype=float)
    tension = np.full((N_SAMPLES, arm.n_cables), 20.0)
    tension[20:23, 0] = 0.5
    tension[40, 0] = 1.0
    tension[100:102, 0] = 0.0
    tension[150:155, 0] = 4.5
    tension[160:162, 0] = 3.9
    tension[200:203, 0] = f_max[0] + 0.5
    tension[203:205, 0] = f_max[0] + 1.5
    tension[0:5, 1] = 0.2
    tension[230:, 1] = 0.9
    tension[50:53, 7] = f_max[7] + 1.5
    tension[53, 7] = f_max[7] + 0.9
    tension[120:130, 8] = 4.0
    return tension


def _columns(arm) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """A run's log columns, with the per-sample joint and cable-length offsets built in."""
    t = np.arange(N_SAMPLES) * DT
    q_ref = _reference()
    alternating = np.where(np.arange(N_SAMPLES) % 2 == 0, 1.0, -1.0)
    joint_offset = np.outer(alternating, [0.001, 0.002, 0.003, 0.004])
    q = q_ref + joint_offset
    q[SETTLE] = SETTLE_POSTURE
    q[-1] = FINAL_POSTURE
    # the reeled length l(q_0) - r (theta - theta_0) is l(q_k) + e_k: e_k = +-b_c, e_0 = 0
    # (the reeled length starts at l(q_0) by definition)
    lengths = np.array([arm.geometry(posture, with_wrap_angles=False).lengths for posture in q])
    b = 0.001 * np.arange(1, arm.n_cables + 1)
    length_offset = np.outer(alternating, b)
    length_offset[0] = 0.0
    motor = THETA_0 - (lengths - lengths[0] + length_offset) / DRUM_RADIUS
    columns = {"t": t}
    for j, name in enumerate(arm.joint_names):
        columns[f"q.{name}"] = q[:, j]
        columns[f"q_ref.{name}"] = q_ref[:, j]
    tension = _tensions(arm)
    for c, name in enumerate(arm.cable_names):
        columns[f"motor_angle.{name}"] = motor[:, c]
        columns[f"tension_motor.{name}"] = tension[:, c]
    return columns, q, q_ref


def _evaluate(arm, columns, completed=True):
    return evaluate_run(
        arm,
        columns,
        home=HOME,
        target=TARGET,
        drum_radius=DRUM_RADIUS,
        min_tension=MIN_TENSION,
        completed=completed,
    )


def test_slack_events_and_time_outside_bounds_of_a_hand_made_run(arm):
    columns, _, _ = _columns(arm)
    metrics = _evaluate(arm, columns)
    assert metrics.slack_events == (2, 1, 0, 0, 0, 0, 0, 0, 0)
    expected = np.array([10, 25, 0, 0, 0, 0, 0, 3, 0]) * DT
    np.testing.assert_allclose(metrics.time_outside_bounds, expected, rtol=1e-12, atol=0)


def test_position_joint_and_cable_length_metrics_of_a_hand_made_run(arm):
    columns, q, q_ref = _columns(arm)
    metrics = _evaluate(arm, columns, completed=False)
    assert metrics.completed is False
    p_home, p_target = _hand(arm, HOME), _hand(arm, TARGET)
    displacement = math.dist(p_home, p_target)
    final = math.dist(_hand(arm, FINAL_POSTURE), p_target)
    assert 0.0 < final < 0.01 < displacement  # a final error of a few mm on a long move
    assert metrics.final_error_mm == pytest.approx(1000.0 * final, rel=1e-9)
    assert metrics.final_error_percent == pytest.approx(100.0 * final / displacement, rel=1e-9)
    # the settle error: the posture 0.5 s after the reference rests, not the last one
    settle = math.dist(_hand(arm, SETTLE_POSTURE), p_target)
    assert settle > 2 * final
    assert metrics.settle_error_mm == pytest.approx(1000.0 * settle, rel=1e-9)
    # joint RMSE: +-0.001 j rad everywhere but at the settle and final samples
    n = N_SAMPLES
    offsets = np.tile([0.001, 0.002, 0.003, 0.004], (n, 1))
    offsets[SETTLE] = SETTLE_POSTURE - q_ref[SETTLE]
    offsets[-1] = FINAL_POSTURE - q_ref[-1]
    expected = [math.sqrt(sum(offsets[:, j] ** 2) / n) for j in range(4)]
    np.testing.assert_allclose(metrics.joint_rmse, expected, rtol=1e-12)
    # cable length error: |e_k| = b_c on every sample but the first
    b = 0.001 * np.arange(1, arm.n_cables + 1)
    rmse = b * math.sqrt((n - 1) / n)
    np.testing.assert_allclose(
        metrics.cable_length_error_percent, 100.0 * rmse / cable_travel(arm), rtol=1e-9
    )


def test_a_run_that_ends_before_the_settle_time_has_no_settle_error(arm):
    columns, q, _ = _columns(arm)
    short = {name: values[:150] for name, values in columns.items()}  # ends at 0.596 s
    metrics = _evaluate(arm, short)
    assert math.isnan(metrics.settle_error_mm)
    assert metrics.as_dict()["settle_error_mm"] is None
    final = math.dist(_hand(arm, q[149]), _hand(arm, TARGET))
    assert metrics.final_error_mm == pytest.approx(1000.0 * final, rel=1e-9)
    assert metrics.slack_events == (2, 0, 0, 0, 0, 0, 0, 0, 0)  # cable 1's dip comes later


def test_hand_jacobian_is_the_finite_difference_of_the_hand_position(arm):
    from msarm.tasks.evaluate import hand_jacobian

    step = 1e-6
    columns = [(_hand(arm, TARGET + step * e) - _hand(arm, TARGET)) / step for e in np.eye(4)]
    np.testing.assert_allclose(hand_jacobian(arm, TARGET), np.column_stack(columns), atol=1e-6)


def test_encoder_noise_floor_is_the_mean_hand_error_of_the_encoders_noise(arm):
    """The closed form (one quadrature) against seeded Monte Carlo: E|J e|, e ~ N(0, s^2 I)."""
    from msarm.tasks.evaluate import encoder_noise_floor, hand_jacobian

    sigma = 1e-4
    samples = np.random.default_rng(5).standard_normal((400_000, 4)) * sigma
    sampled = np.linalg.norm(samples @ hand_jacobian(arm, TARGET).T, axis=1).mean()
    floor = encoder_noise_floor(arm, TARGET, sigma)
    assert floor == pytest.approx(sampled, rel=3e-3)
    # below the RMS sigma * |J|_F (the mean of a norm is less than its RMS), linear in sigma
    assert floor < sigma * np.linalg.norm(hand_jacobian(arm, TARGET))
    assert encoder_noise_floor(arm, TARGET, 2 * sigma) == pytest.approx(2 * floor, rel=1e-9)
    assert encoder_noise_floor(arm, TARGET, 0.0) == 0.0
    with pytest.raises(ValueError, match="joint_noise"):
        encoder_noise_floor(arm, TARGET, -1e-4)
