"""The arm's Hill parameters fit its geometry: fibres in range, gravity can be held."""

from __future__ import annotations

import numpy as np
import pinocchio
import pytest
from scipy.optimize import linprog

from msarm.errors import InputError
from msarm.muscle.geometry import joint_grid
from msarm.muscle.sizing import size_fibres


def _grid_lengths(arm, points=5):
    return np.array(
        [arm.geometry(q).lengths for q in joint_grid(arm.joint_lower, arm.joint_upper, points)]
    )


def test_fibres_work_between_0_8_and_1_2_optimal_lengths_over_the_range(arm):
    lengths = _grid_lengths(arm)
    muscles = arm.muscles
    normalised = np.array(
        [muscles.fiber_state(row, np.zeros(arm.n_cables)).length_norm for row in lengths]
    )
    assert normalised.min() > 0.78
    assert normalised.max() < 1.22


def test_model_parameters_are_what_size_fibres_gives_for_the_model(arm):
    """The numbers in the file come from the documented sizing rule, not by hand."""
    lengths = _grid_lengths(arm, points=9)
    optimal, slack = size_fibres(lengths, arm.muscles.pennation_at_optimal)
    np.testing.assert_allclose(arm.muscles.optimal_fiber_length, optimal, rtol=0.02)
    np.testing.assert_allclose(arm.muscles.tendon_slack_length, slack, atol=0.002)


def test_size_fibres_maps_the_travel_onto_the_span():
    lengths = np.array([[0.50, 0.70], [0.60, 0.75], [0.55, 0.72]])
    pennation = np.array([0.0, 0.3])
    optimal, slack = size_fibres(lengths, pennation, span=(0.8, 1.2))
    for column, (lo, hi) in enumerate([(0.50, 0.60), (0.70, 0.75)]):
        width = optimal[column] * np.sin(pennation[column])
        fibre = np.sqrt((np.array([lo, hi]) - slack[column]) ** 2 + width**2)
        np.testing.assert_allclose(fibre / optimal[column], [0.8, 1.2], rtol=1e-12)
    with pytest.raises(InputError, match="change length"):
        size_fibres(np.ones((3, 2)), pennation)


@pytest.mark.parametrize(
    ("pennation", "span", "message"),
    [
        ([0.0, np.nan], (0.8, 1.2), r"pennation_at_optimal\[1\] = nan rad"),
        ([-0.3, 0.0], (0.8, 1.2), r"pennation_at_optimal\[0\] = -0.3 rad; expected .*\[0, pi/2\)"),
        ([0.0, np.pi - 0.3], (0.8, 1.2), r"pennation_at_optimal\[1\]"),
        ([0.0, 2.0], (0.8, 1.2), r"pennation_at_optimal\[1\] = 2.0 rad"),
        ([0.0, 0.3], (0.8, 1.0, 1.2), r"span must be two numbers"),
        ([0.0, 0.3], (0.8, np.inf), r"span must satisfy"),
        ([0.0, 0.3], (0.8, 2.6), r"s_hi <= 2.5 \(the longest fibre"),
    ],
)
def test_size_fibres_names_a_bad_pennation_or_span(pennation, span, message):
    lengths = np.array([[0.50, 0.70], [0.60, 0.75]])
    with pytest.raises(InputError, match=message):
        size_fibres(lengths, pennation, span=span)


@pytest.mark.parametrize(
    ("lower", "upper", "points", "message"),
    [
        ([0, 0], [1, 1], 2.9, "whole numbers >= 1"),
        ([0, 0], [1, 1], 0, "whole numbers >= 1"),
        ([0, 0], [1, 1], [2, 2, 2], "one count or one per joint"),
        ([0, np.nan], [1, 1], 2, "must be finite"),
        ([0, 0], [1, 1, 1], 2, "one shape"),
        ([0, 2], [1, 1], 2, "lower limit must be <= its upper"),
    ],
)
def test_joint_grid_refuses_bad_limits_and_counts_when_called(lower, upper, points, message):
    with pytest.raises(InputError, match=message):
        joint_grid(lower, upper, points)  # before the first posture is asked for


def test_joint_grid_takes_whole_float_counts():
    assert len(list(joint_grid([0.0, 0.0], [1.0, 2.0], [2.0, 3]))) == 6


def test_muscles_can_hold_the_arm_against_gravity_everywhere(arm):
    """At every grid posture some forces within [passive, full activation] give g(q)."""
    data = arm.pin_model.createData()
    for q in joint_grid(arm.joint_lower, arm.joint_upper, 4):
        gravity = pinocchio.computeGeneralizedGravity(arm.pin_model, data, arm.to_pinocchio(q))
        # hold gravity plus a margin of 2 N m on every joint, in either direction
        geometry = arm.geometry(q)
        f_min, f_max = arm.muscles.force_capacity(geometry.lengths, np.zeros(arm.n_cables))
        for extra in (+2.0, -2.0):
            result = linprog(
                np.zeros(arm.n_cables),
                A_eq=-geometry.jacobian.T,
                b_eq=gravity + extra,
                bounds=list(zip(f_min, f_max, strict=True)),
                method="highs",
            )
            assert result.status == 0, f"cannot hold q={q} with {extra:+} N m margin"
