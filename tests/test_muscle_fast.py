"""The compiled Hill fast path equals the validated reference (HillMuscles)."""

from __future__ import annotations

import numpy as np
import pytest

from msarm.errors import InputError
from msarm.muscle.fast import FastHill


def test_fast_parts_equal_reference_over_random_states(arm):
    muscles = arm.muscles
    fast = FastHill(muscles)
    rng = np.random.default_rng(3)
    for _ in range(200):
        q = rng.uniform(arm.joint_lower, arm.joint_upper)
        qdot = rng.normal(scale=1.0, size=arm.n_joints)
        geometry = arm.geometry(q, qdot)
        speed = np.maximum(geometry.velocities, -0.9 * fast.max_shortening_speed)
        f_min, f_max = muscles.force_capacity(geometry.lengths, speed)
        active, passive = fast.parts(geometry.lengths, speed)
        np.testing.assert_allclose(passive, f_min, rtol=1e-12, atol=1e-10)
        np.testing.assert_allclose(passive + active, f_max, rtol=1e-12, atol=1e-10)
        activation = rng.uniform(0, 1, arm.n_cables)
        np.testing.assert_allclose(
            activation * active + passive,
            muscles.force(activation, geometry.lengths, speed),
            rtol=1e-12,
            atol=1e-10,
        )


def test_fast_path_refuses_a_length_below_slack(arm):
    fast = FastHill(arm.muscles)
    lengths = np.array(arm.muscles.tendon_slack_length) + 0.1
    lengths[3] = arm.muscles.tendon_slack_length[3]
    with pytest.raises(InputError, match="pectoralis_major"):
        fast.parts(lengths, np.zeros(arm.n_cables))


def test_fast_path_names_a_nan_before_the_slack_length(arm):
    """NaN is reported as NaN, for the argument that holds it, in plain floats."""
    fast = FastHill(arm.muscles)
    lengths = np.array(arm.muscles.tendon_slack_length) + 0.1
    speeds = np.zeros(arm.n_cables)
    slack = float(arm.muscles.tendon_slack_length[3])
    lengths[3] = slack
    with pytest.raises(InputError, match=rf"mtu_length\[3\] .* = {slack} m is not longer") as e:
        fast.parts(lengths, speeds)
    assert "np.float64" not in str(e.value)
    lengths[3] = np.nan
    with pytest.raises(InputError, match=r"mtu_length\[3\] .* must be finite, got nan m$"):
        fast.parts(lengths, speeds)
    lengths[3] = slack + 0.1
    speeds[5] = np.nan
    with pytest.raises(InputError, match=r"mtu_velocity\[5\] .* must be finite, got nan m/s"):
        fast.parts(lengths, speeds)


def test_fast_path_refuses_arrays_of_another_length(arm):
    """Fewer values kept the last call's results; more read past the parameters."""
    fast = FastHill(arm.muscles)
    lengths = np.array(arm.muscles.tendon_slack_length) + 0.1
    with pytest.raises(InputError, match=r"mtu_length has shape \(1,\); expected \(9,\)"):
        fast.parts(lengths[:1], np.zeros(1))
    with pytest.raises(InputError, match=r"mtu_velocity has shape \(11,\); expected \(9,\)"):
        fast.parts(lengths, np.zeros(11))


def test_fast_path_refuses_a_fibre_past_the_longest_length_as_the_reference_does(arm):
    """Lengths in centimetres gave inf or 6.7e6 N of passive force with no error."""
    fast = FastHill(arm.muscles)
    lengths = list(np.array(arm.muscles.tendon_slack_length) + 0.1)  # a list is taken too
    active, _ = fast.parts(lengths, [0.0] * arm.n_cables)
    assert np.all(np.isfinite(active))
    lengths[2] *= 100.0
    with pytest.raises(InputError, match=r"mtu_length\[2\] .* past 2.5 optimal lengths"):
        fast.parts(lengths, [0.0] * arm.n_cables)
    with pytest.raises(InputError, match=r"mtu_length\[2\] .* at most 2.5"):
        arm.muscles.force_capacity(lengths, np.zeros(arm.n_cables))
