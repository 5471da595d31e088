"""Residuals of a hand-made log (no simulation): drive, cable length, segments, derivatives.

The log moves every joint at a constant speed, every motor at a constant speed and the
reference along a parabola, so that the Savitzky-Golay derivatives (order 3) are exact and
the expected values follow by hand; the cable paths of the logged postures come from the
batch kinematics (not part of the residuals module).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from msarm.diagnose.residuals import DiagnosisWarning, ResidualSpec, residuals_from_log
from msarm.errors import LogError
from msarm.io.logs import LogMetadata, RunLog
from msarm.muscle.batch_kinematics import cable_kinematics_batch

RATE = 250.0
# three stretches: 60 samples, exactly the filter's 25, then 24 (too short: left out);
# each gap skips one sample (a step of 2 periods)
LENGTHS = (60, 25, 24)
HOME = np.array([0.1, 0.2, -0.1, -0.5])
SPEED = np.array([0.3, -0.2, 0.25, 0.4])  # [rad/s]


def _index() -> np.ndarray:
    starts = np.cumsum([0, *[n + 1 for n in LENGTHS[:-1]]])
    return np.concatenate([s + np.arange(n) for s, n in zip(starts, LENGTHS, strict=True)])


def _log(arm, tension=None, seed=0):
    rng = np.random.default_rng(seed)
    t = _index() / RATE
    m = len(arm.cable_names)
    q = HOME + SPEED * t[:, None]
    motor_speed = np.linspace(-2.0, 3.0, m)  # [rad/s]
    motor = 5.0 + motor_speed * t[:, None]
    ref_acceleration = np.array([1.0, -2.0, 0.5, 3.0])  # q_ref = HOME + a t^2 / 2
    q_ref = HOME + 0.5 * ref_acceleration * t[:, None] ** 2
    if tension is None:
        tension = rng.uniform(10.0, 30.0, size=(len(t), m))
    command = rng.uniform(10.0, 30.0, size=(len(t), m))
    log = RunLog.from_quantities(
        t,
        {
            "q": (arm.joint_names, q),
            "q_ref": (arm.joint_names, q_ref),
            "tension_motor": (arm.cable_names, tension),
            "tension_cmd": (arm.cable_names, command),
            "motor_angle": (arm.cable_names, motor),
        },
        LogMetadata.for_model(arm, RATE),
    )
    return log, {
        "q": q,
        "motor": motor,
        "motor_speed": motor_speed,
        "ref_acceleration": ref_acceleration,
        "tension": tension,
        "command": command,
    }


def _diagnose(arm, log, spec):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = residuals_from_log(arm, log, source="hand", spec=spec)
    return result, [str(w.message) for w in caught if issubclass(w.category, DiagnosisWarning)]


def _aligned_commands(command: np.ndarray) -> np.ndarray:
    """Each tension answers the previous sample's command; a stretch's first takes its own."""
    out = np.empty_like(command)
    start = 0
    for n in LENGTHS:
        stop = start + n
        out[start] = command[start]
        out[start + 1 : stop] = command[start : stop - 1]
        start = stop
    return out


def test_residuals_of_a_hand_made_log(arm):
    log, made = _log(arm)
    result, messages = _diagnose(arm, log, ResidualSpec(replay=False))
    assert any("gap" in m for m in messages)
    assert any("1 segment(s) shorter" in m for m in messages)
    # the 60- and 25-sample stretches are diagnosed; the 24-sample one is not
    expected_valid = np.r_[np.ones(85, dtype=bool), np.zeros(24, dtype=bool)]
    np.testing.assert_array_equal(result.valid, expected_valid)
    ok = result.valid
    assert np.isnan(result.drive[~ok]).all() and np.isnan(result.joint_torque[~ok]).all()
    # drive: F[k] - F_cmd[k - 1], a stretch's first sample against its own command
    aligned = _aligned_commands(made["command"])
    np.testing.assert_allclose(result.drive[ok], (made["tension"] - aligned)[ok], atol=1e-12)
    np.testing.assert_allclose(result.tension_cmd[ok], aligned[ok], atol=1e-12)
    # cable length: l(q_0) - r (theta - theta_0) - l(q), anchored at the first sample
    lengths = cable_kinematics_batch(arm, made["q"], with_wrap_angles=False).lengths
    motor = made["motor"]
    expected = lengths[0] - 0.003 * (motor - motor[0]) - lengths
    np.testing.assert_allclose(result.cable_length[ok], expected[ok], rtol=0, atol=1e-12)
    # exact derivatives of the straight lines and the parabola
    np.testing.assert_allclose(result.qd[ok], np.broadcast_to(SPEED, (85, 4)), atol=1e-9)
    np.testing.assert_allclose(result.qdd[ok], 0.0, atol=1e-6)
    np.testing.assert_allclose(
        result.motor_speed[ok], np.broadcast_to(made["motor_speed"], (85, 9)), atol=1e-9
    )
    np.testing.assert_allclose(
        result.qdd_ref[ok], np.broadcast_to(made["ref_acceleration"], (85, 4)), atol=1e-6
    )
    # cable velocities J_c(q) qd
    jacobian = cable_kinematics_batch(arm, made["q"], with_wrap_angles=False).jacobian
    np.testing.assert_allclose(
        result.cable_velocity[ok], (jacobian @ SPEED)[ok], rtol=1e-9, atol=1e-12
    )


def test_the_replay_is_driven_by_the_commands_each_tension_answers(arm):
    """replay_source='command' on a log equals replay_source='tension' on the same log whose
    load cells read exactly those (aligned) commands; and it differs from the tension-driven
    replay of the log itself."""
    log, made = _log(arm)
    spec = ResidualSpec(replay=True, replay_window=0.04)
    by_command, _ = _diagnose(arm, log, spec)
    swapped, _ = _log(arm, tension=_aligned_commands(made["command"]))
    by_swapped_tension, _ = _diagnose(
        arm, swapped, ResidualSpec(replay=True, replay_window=0.04, replay_source="tension")
    )
    by_tension, _ = _diagnose(
        arm, log, ResidualSpec(replay=True, replay_window=0.04, replay_source="tension")
    )
    ok = by_command.valid
    np.testing.assert_array_equal(by_command.replay[ok], by_swapped_tension.replay[ok])
    assert np.abs(by_command.replay[ok] - by_tension.replay[ok]).max() > 1e-6


@pytest.mark.parametrize("step", [1.4, 1.6])
def test_a_step_beyond_one_and_a_half_periods_is_a_gap(arm, step):
    log, made = _log(arm)
    t = np.arange(60.0)
    t[30:] += step - 1.0  # one longer step between samples 29 and 30
    columns = {k: v[:60] for k, v in log.columns.items()}
    columns["t"] = t / RATE
    result, messages = _diagnose(arm, RunLog(columns, log.metadata), ResidualSpec(replay=False))
    split = step > 1.5
    # (the 1.4-period step also makes the mean step of these 60 samples 0.7 % long: warned)
    assert any("gap(s) longer than" in m for m in messages) == split
    expected = made["tension"][30] - made["command"][30 if split else 29]
    np.testing.assert_allclose(result.drive[30], expected, atol=1e-12)


def test_a_log_without_a_stretch_as_long_as_the_filter_is_refused(arm):
    log, _ = _log(arm)
    short = RunLog({k: v[:24] for k, v in log.columns.items()}, log.metadata)
    with pytest.raises(LogError, match=r"^hand: no contiguous stretch .* filter's 25 samples"):
        residuals_from_log(arm, short, source="hand", spec=ResidualSpec(replay=False))


def test_the_joint_residual_keeps_a_compensators_feedforward_tension(arm):
    """The diagnosis describes the plant: the whole measured tension counts, as in the drive
    residual. The compensator's target takes the sheath stage's ``tension_ff`` off (what the
    stage leaves); the diagnosis took it off too, and its joint and drive groups disagreed."""
    from msarm.compensation.target import torque_error

    log, _ = _log(arm)
    columns = dict(log.columns)
    for cable in arm.cable_names:
        columns[f"tension_ff.{cable}"] = np.full(len(log), 2.0)
    with_ff = RunLog(columns, log.metadata)
    spec = ResidualSpec(replay=False)
    plain, _ = _diagnose(arm, log, spec)
    kept, _ = _diagnose(arm, with_ff, spec)
    ok = plain.valid
    np.testing.assert_array_equal(kept.joint_torque[ok], plain.joint_torque[ok])
    np.testing.assert_array_equal(kept.drive[ok], plain.drive[ok])
    # the compensator's target does take it off: 2 N on every cable is a torque
    first = slice(0, LENGTHS[0])
    target = torque_error(arm, RunLog({k: v[first] for k, v in columns.items()}, log.metadata))
    assert np.abs(target - plain.joint_torque[first]).max() > 1e-3
