"""msarm.tasks.metrics: the paper 003 metrics on tiny hand-computed arrays."""

from __future__ import annotations

import numpy as np
import pytest

from msarm.errors import InputError
from msarm.tasks import metrics
from msarm.tasks.metrics import (
    cable_length_error,
    cable_length_error_at_end,
    final_position_error,
    joint_rmse,
    settle_sample,
    slack_events,
    time_outside_bounds,
)


def test_final_position_error_eq_10_11():
    # Start at the origin, target 0.5 m away along x; the arm stops 3-4-5 cm off.
    error, percent = final_position_error([0.53, 0.04, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert error == pytest.approx(0.05, rel=1e-12)
    assert percent == pytest.approx(10.0, rel=1e-12)
    # Paper 003's numbers: 147.1 mm is 31.49 % of a 467.1 mm displacement.
    error, percent = final_position_error([0.1471, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.4671, 0.0])
    assert error == pytest.approx(0.1471) and percent == pytest.approx(31.49, abs=0.01)


def test_final_position_error_bad_input():
    with pytest.raises(InputError, match="zero displacement"):
        final_position_error([1.0, 0.0], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(InputError, match="p_start has shape"):
        final_position_error([1.0, 0.0], [0.0, 0.0], [0.0, 0.0, 0.0])
    with pytest.raises(InputError, match="p_final has NaN"):
        final_position_error([np.nan, 0.0], [0.0, 0.0], [1.0, 0.0])


def test_joint_rmse_per_joint():
    q = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 4.0]])
    q_ref = np.zeros((4, 2))
    np.testing.assert_allclose(joint_rmse(q, q_ref), [1.0, 2.0])
    with pytest.raises(InputError, match="q_ref has shape"):
        joint_rmse(q, q_ref[:3])
    with pytest.raises(InputError, match=r"q must be of shape \(T, k\)"):
        joint_rmse(q[0], q_ref[0])
    q[2, 1] = np.nan
    with pytest.raises(InputError, match=r"q has NaN at index \(2, 1\)"):
        joint_rmse(q, q_ref)


def test_cable_length_error_eq_12_13():
    l_theory = np.array([[0.30, 0.20], [0.31, 0.21], [0.32, 0.22], [0.33, 0.23]])
    offsets = np.array([[0.003, 0.0], [-0.003, 0.0], [0.003, 0.001], [-0.003, -0.001]])
    rmse, percent = cable_length_error(l_theory + offsets, l_theory, [0.06, 0.01])
    # Cable 0: |e| = 3 mm everywhere; cable 1: sqrt((0 + 0 + 1 + 1) / 4) mm.
    np.testing.assert_allclose(rmse, [0.003, np.sqrt(0.5) * 1e-3], rtol=1e-10)
    np.testing.assert_allclose(percent, [5.0, np.sqrt(0.5) * 10.0], rtol=1e-10)


def test_cable_length_error_at_the_end_as_paper_003_reports_it():
    l_theory = np.array([[0.30, 0.20], [0.31, 0.21], [0.32, 0.22], [0.33, 0.25]])
    offsets = np.array([[0.003, 0.0], [-0.003, 0.0], [0.003, 0.001], [-0.0033, 0.001]])
    # the last sample only: 3.3 mm of 0.33 m, 1 mm of 0.25 m; the sign does not count
    np.testing.assert_allclose(
        cable_length_error_at_end(l_theory + offsets, l_theory), [1.0, 0.4], rtol=1e-10
    )
    with pytest.raises(InputError, match=r"l_theory must be > 0 at the last sample.*cable 1"):
        cable_length_error_at_end(l_theory, l_theory * [1.0, 0.0])
    with pytest.raises(InputError, match="no samples"):
        cable_length_error_at_end(np.zeros((0, 2)), np.zeros((0, 2)))


def test_cable_length_error_bad_input():
    l_theory = np.zeros((3, 2))
    with pytest.raises(InputError, match="max_travel must have shape"):
        cable_length_error(l_theory, l_theory, [0.1])
    with pytest.raises(InputError, match=r"max_travel must be > 0.*cable 1"):
        cable_length_error(l_theory, l_theory, [0.1, 0.0])
    with pytest.raises(InputError, match="l_theory has shape"):
        cable_length_error(l_theory, l_theory[:, :1], [0.1, 0.1])


def test_slack_events_count_entries_into_slack():
    tension = np.array(
        [
            [10.0, 0.0, 5.0],
            [0.5, 0.0, 5.0],  # cable 0 goes slack
            [10.0, 2.0, 5.0],  # cable 1 taut for the first time
            [0.0, 0.5, 0.9],  # cables 0, 1, 2 go slack
            [0.0, 0.0, 1.0],  # staying slack is not a new event; exactly 1 N is taut
            [3.0, 0.0, 0.99],  # cable 2 slack again
        ]
    )
    np.testing.assert_array_equal(slack_events(tension, 1.0), [2, 1, 2])
    np.testing.assert_array_equal(slack_events(tension, [1.0, 3.0, 0.95]), [2, 0, 1])
    assert slack_events(tension, 1.0).dtype.kind == "i"
    with pytest.raises(InputError, match=r"threshold must be a scalar or of shape \(3,\)"):
        slack_events(tension, [1.0, 2.0])


def test_time_outside_bounds_seconds_per_cable():
    tension = np.array([[0.0, 5.0], [5.0, 5.0], [12.0, 5.0], [10.0, 2.0]])
    np.testing.assert_allclose(time_outside_bounds(tension, 1.0, 10.0, 0.004), [0.008, 0.0])
    np.testing.assert_allclose(
        time_outside_bounds(tension, [1.0, 3.0], [20.0, 20.0], 0.5), [0.5, 0.5]
    )
    with pytest.raises(InputError, match="lower > upper at cable 0"):
        time_outside_bounds(tension, 11.0, 10.0, 0.004)
    with pytest.raises(InputError, match="dt"):
        time_outside_bounds(tension, 1.0, 10.0, -1.0)
    with pytest.raises(InputError, match="tension has NaN"):
        time_outside_bounds(np.full((2, 2), np.nan), 1.0, 10.0, 0.1)


def test_settle_sample_is_the_delay_after_the_reference_rests():
    t = np.arange(10) * 0.25  # 0, 0.25, ..., 2.25 s
    ref = np.zeros((10, 2))
    ref[1:4, 0] = [0.1, 0.2, 0.3]  # moving until sample 3, at rest from there (0.75 s)
    ref[4:, 0] = 0.3
    assert settle_sample(t, ref, 0.5) == 5  # 1.25 s
    assert settle_sample(t, ref, 0.0) == 3
    assert settle_sample(t, ref, 1.5) == 9  # 2.25 s, the last sample
    assert settle_sample(t, ref, 1.6) is None  # the run ends sooner
    assert settle_sample(t, np.zeros((10, 2)), 0.5) == 2  # never moves: from the start
    still_moving = np.outer(np.arange(10), [1.0, 0.0])
    assert settle_sample(t, still_moving, 0.0) is None
    with pytest.raises(InputError, match="q_ref has 9 samples but t has 10"):
        settle_sample(t, ref[:9], 0.5)
    with pytest.raises(InputError, match="delay must be >= 0"):
        settle_sample(t, ref, -0.1)


def test_cable_travel_finds_each_cable_s_extremes_between_grid_points(arm):
    """Eq. 13's travel: at least what a 21^4 grid sees (7^4 alone fell 0.7 % short), not more."""
    from msarm.muscle.batch_kinematics import cable_kinematics_batch
    from msarm.muscle.geometry import joint_grid
    from msarm.tasks.evaluate import cable_travel

    travel = cable_travel(arm)
    grid = list(joint_grid(arm.joint_lower, arm.joint_upper, 21))
    lengths = cable_kinematics_batch(arm, grid, with_wrap_angles=False).lengths
    dense = lengths.max(axis=0) - lengths.min(axis=0)
    assert np.all(travel >= dense - 1e-12)
    assert np.all(travel <= dense * 1.001)
    coarse = list(joint_grid(arm.joint_lower, arm.joint_upper, 7))
    lengths = cable_kinematics_batch(arm, coarse, with_wrap_angles=False).lengths
    assert np.max(travel / (lengths.max(axis=0) - lengths.min(axis=0))) > 1.005


def test_infinite_values_and_words_are_refused_by_name():
    """Infinity gave inf or NaN back, and a word a bare numpy or Python error; each is now
    an InputError naming the argument (an infinite bound is still no bound)."""
    with pytest.raises(InputError, match=r"p_target has inf \(not finite\) at index \(0,\)"):
        metrics.final_position_error([0, 0, 0], [np.inf, 0, 0], [0, 0, 0])
    q = np.zeros((11, 4))
    with pytest.raises(InputError, match=r"q has -inf \(not finite\) at index \(0, 0\)"):
        metrics.joint_rmse(np.full((11, 4), -np.inf), q)
    with pytest.raises(InputError, match=r"threshold must be a number or of shape \(3,\)"):
        metrics.slack_events(np.ones((5, 3)), "a")
    with pytest.raises(InputError, match=r"dt must be a number, got 'x'"):
        metrics.time_outside_bounds(np.ones((5, 3)), 0.0, 10.0, dt="x")
    with pytest.raises(InputError, match=r"dt must be a number, got None"):
        metrics.time_outside_bounds(np.ones((5, 3)), 0.0, 10.0, dt=None)
    with pytest.raises(InputError, match=r"delay must be a number, got 'x'"):
        metrics.settle_sample(np.arange(4.0), np.zeros((4, 2)), "x")
    outside = metrics.time_outside_bounds(np.full((5, 3), 40.0), -np.inf, np.inf, 0.01)
    np.testing.assert_array_equal(outside, 0.0)


def test_settle_sample_refuses_times_that_do_not_increase():
    q_ref = np.zeros((4, 2))
    with pytest.raises(InputError, match=r"t must increase, got 0.02 then 0.01 s at samples 2, 3"):
        settle_sample([0.0, 0.01, 0.02, 0.01], q_ref, 0.0)
