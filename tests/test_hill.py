"""Hill muscle-tendon units: eq. 14 forward model, inverse model, eq. 15, bad input."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from msarm.errors import InputError
from msarm.muscle import (
    HillMuscles,
    MuscleParameters,
    active_force_length,
    force_velocity,
    passive_force_length,
)

PARAMS = [
    MuscleParameters("biceps", 600.0, 0.12, 0.25, 10.0, 0.0),
    MuscleParameters("triceps", 800.0, 0.10, 0.20, 10.0, 0.2),
    MuscleParameters("deltoid", 1000.0, 0.08, 0.05, 8.0, 0.35),
]


@pytest.fixture
def muscles():
    return HillMuscles(PARAMS)


def mtu_state(l_norm, v_norm):
    """MTU length and velocity [m, m/s] that give the wanted normalised fibre state."""
    l_norm = np.broadcast_to(np.asarray(l_norm, dtype=float), (3,))
    v_norm = np.broadcast_to(np.asarray(v_norm, dtype=float), (3,))
    l_opt = np.array([p.optimal_fiber_length for p in PARAMS])
    slack = np.array([p.tendon_slack_length for p in PARAMS])
    alpha0 = np.array([p.pennation_at_optimal for p in PARAMS])
    v_max = np.array([p.max_contraction_velocity for p in PARAMS])
    fiber = l_norm * l_opt
    thickness = l_opt * np.sin(alpha0)
    along = np.sqrt(fiber**2 - thickness**2)
    cos_alpha = along / fiber
    return slack + along, v_norm * v_max * l_opt / cos_alpha


# ---------------------------------------------------------------- parameters


def test_parameters_are_validated():
    with pytest.raises(InputError, match="muscle 'm': max_isometric_force must be a finite"):
        MuscleParameters("m", -1.0, 0.1, 0.2)
    with pytest.raises(InputError, match="optimal_fiber_length must be a finite number > 0"):
        MuscleParameters("m", 100.0, math.nan, 0.2)
    with pytest.raises(InputError, match="tendon_slack_length"):
        MuscleParameters("m", 100.0, 0.1, 0.0)
    with pytest.raises(InputError, match="max_contraction_velocity"):
        MuscleParameters("m", 100.0, 0.1, 0.2, math.inf)
    with pytest.raises(InputError, match=r"pennation_at_optimal must be in \[0, pi/2\)"):
        MuscleParameters("m", 100.0, 0.1, 0.2, 10.0, math.pi / 2)
    with pytest.raises(InputError, match="pennation_at_optimal"):
        MuscleParameters("m", 100.0, 0.1, 0.2, 10.0, -0.1)
    with pytest.raises(InputError, match="name must be a non-empty str"):
        MuscleParameters("", 100.0, 0.1, 0.2)
    with pytest.raises(InputError, match="must be a real number"):
        MuscleParameters("m", True, 0.1, 0.2)
    params = MuscleParameters("m", 100, 0.1, 0.2)
    assert isinstance(params.max_isometric_force, float)
    assert params.max_contraction_velocity == 10.0
    assert params.pennation_at_optimal == 0.0


def test_collection_conveniences(muscles):
    assert len(muscles) == 3
    assert muscles.names == ("biceps", "triceps", "deltoid")
    assert muscles.params == tuple(PARAMS)
    np.testing.assert_array_equal(muscles.max_isometric_force, [600.0, 800.0, 1000.0])
    with pytest.raises(ValueError):
        muscles.max_isometric_force[0] = 1.0
    again = HillMuscles.from_arrays(
        ["biceps", "triceps", "deltoid"],
        [600.0, 800.0, 1000.0],
        [0.12, 0.10, 0.08],
        [0.25, 0.20, 0.05],
        [10.0, 10.0, 8.0],
        [0.0, 0.2, 0.35],
    )
    assert again.params == muscles.params
    assert len(HillMuscles.from_arrays(["a", "b"], 100.0, 0.1, 0.2)) == 2


def test_collection_is_validated():
    with pytest.raises(InputError, match="at least one"):
        HillMuscles([])
    with pytest.raises(InputError, match=r"repeated: \['biceps'\]"):
        HillMuscles([PARAMS[0], PARAMS[0]])
    with pytest.raises(InputError, match=r"params\[0\] must be a MuscleParameters"):
        HillMuscles([{"name": "x"}])
    with pytest.raises(InputError, match=r"optimal_fiber_length must be a scalar or have shape"):
        HillMuscles.from_arrays(["a", "b"], 100.0, [0.1, 0.1, 0.1], 0.2)


# ---------------------------------------------------------------- geometry


def test_fiber_state_recovers_normalised_state(muscles):
    l_norm = np.array([0.7, 1.0, 1.3])
    v_norm = np.array([-0.5, 0.0, 0.8])
    state = muscles.fiber_state(*mtu_state(l_norm, v_norm))
    np.testing.assert_allclose(state.length_norm, l_norm, rtol=1e-12)
    np.testing.assert_allclose(state.velocity_norm, v_norm, rtol=1e-12, atol=1e-15)
    assert state.cos_pennation[1] == pytest.approx(math.cos(0.2), rel=1e-12)
    assert state.cos_pennation[0] == 1.0


def test_constant_thickness_pennation(muscles):
    length, _ = mtu_state([0.6, 0.9, 1.5], 0.0)
    state = muscles.fiber_state(length, np.zeros(3))
    l_opt = np.array([0.12, 0.10, 0.08])
    fiber = state.length_norm * l_opt
    sin_alpha = np.sqrt(1.0 - state.cos_pennation**2)
    np.testing.assert_allclose(fiber * sin_alpha, l_opt * np.sin([0.0, 0.2, 0.35]), atol=1e-15)
    np.testing.assert_allclose(fiber * state.cos_pennation, length - [0.25, 0.20, 0.05])


def test_fiber_velocity_is_time_derivative_of_fiber_length(muscles):
    length, _ = mtu_state([0.8, 1.1, 1.2], 0.0)
    mtu_velocity = np.array([0.3, -0.2, 0.1])
    h = 1e-6
    ahead = muscles.fiber_state(length + h * mtu_velocity, np.zeros(3)).length_norm
    behind = muscles.fiber_state(length - h * mtu_velocity, np.zeros(3)).length_norm
    l_opt, v_max = np.array([0.12, 0.10, 0.08]), np.array([10.0, 10.0, 8.0])
    finite_difference = (ahead - behind) / (2 * h) / v_max  # normalised fibre velocity
    state = muscles.fiber_state(length, mtu_velocity)
    np.testing.assert_allclose(state.velocity_norm, finite_difference, rtol=1e-7)
    np.testing.assert_allclose(state.length_norm * l_opt > 0, True)


# ---------------------------------------------------------------- forward model (eq. 14)


def test_force_hand_value_at_optimal_length_isometric(muscles):
    length, velocity = mtu_state(1.0, 0.0)
    force = muscles.force(np.ones(3), length, velocity)
    # F_max f_l(1) f_v(0) cos(alpha_0), with f_l(1) = 0.9993335 and f_v(0) = 1.0023206.
    expected = np.array([600.0, 800.0, 1000.0]) * 0.9993334763 * 1.0023206225
    expected *= np.cos([0.0, 0.2, 0.35])
    np.testing.assert_allclose(force, expected, rtol=1e-9)
    assert force[0] == pytest.approx(600.99, abs=0.01)


def test_force_matches_equation_14(muscles):
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = rng.uniform(0, 1, 3)
        l_norm = rng.uniform(0.5, 1.6, 3)
        v_norm = rng.uniform(-1, 1, 3)
        length, velocity = mtu_state(l_norm, v_norm)
        cos_alpha = muscles.fiber_state(length, velocity).cos_pennation
        expected = (
            muscles.max_isometric_force
            * (
                a * active_force_length(l_norm) * force_velocity(v_norm)
                + passive_force_length(l_norm)
            )
            * cos_alpha
        )
        np.testing.assert_allclose(muscles.force(a, length, velocity), expected, rtol=1e-9)


def test_force_capacity_equals_force_at_zero_and_full_activation(muscles):
    length, velocity = mtu_state([0.9, 1.2, 1.45], [-0.3, 0.0, 0.4])
    f_min, f_max = muscles.force_capacity(length, velocity)
    np.testing.assert_array_equal(f_min, muscles.force(np.zeros(3), length, velocity))
    np.testing.assert_array_equal(f_max, muscles.force(np.ones(3), length, velocity))
    assert np.all(f_min >= 0) and np.all(f_max > f_min)
    assert f_min[0] == 0.0  # below the passive slack length
    assert f_min[2] > 0.0  # stretched beyond it


# ---------------------------------------------------------------- inverse model


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3),
    st.lists(st.floats(0.5, 1.6), min_size=3, max_size=3),
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
)
def test_activation_for_force_inverts_force(a, l_norm, v_norm):
    muscles = HillMuscles(PARAMS)
    length, velocity = mtu_state(l_norm, v_norm)
    # Round-off of mtu_state may push v_norm a hair below -1; the model accepts that.
    force = muscles.force(np.array(a), length, velocity)
    activation, reachable = muscles.activation_for_force(force, length, velocity)
    np.testing.assert_allclose(activation, a, rtol=0, atol=1e-9)
    assert reachable.all()


def test_activation_for_force_boundaries_are_reachable(muscles):
    length, velocity = mtu_state([1.0, 1.3, 1.5], [-1.0, 0.0, 1.0])
    for a in (0.0, 1.0):
        force = muscles.force(np.full(3, a), length, velocity)
        activation, reachable = muscles.activation_for_force(force, length, velocity)
        assert reachable.all()
        np.testing.assert_allclose(activation, a, atol=1e-12)


def test_unreachable_forces_are_flagged_and_clipped(muscles):
    length, velocity = mtu_state(1.4, [0.0, -0.2, 0.3])
    f_min, f_max = muscles.force_capacity(length, velocity)
    assert np.all(f_min > 0)
    wanted = np.array([0.5 * f_min[0], 1.5 * f_max[1], -10.0])
    activation, reachable = muscles.activation_for_force(wanted, length, velocity)
    np.testing.assert_array_equal(reachable, [False, False, False])
    np.testing.assert_array_equal(activation, [0.0, 1.0, 0.0])
    mid = 0.5 * (f_min + f_max)
    activation, reachable = muscles.activation_for_force(mid, length, velocity)
    assert reachable.all()
    np.testing.assert_allclose(activation, 0.5, atol=1e-12)
    assert reachable.dtype == bool


# ---------------------------------------------------------------- eq. 15


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.floats(0.05, 1.0), min_size=3, max_size=3),
    st.lists(st.floats(0.5, 1.6), min_size=3, max_size=3),
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
)
def test_fiber_velocity_for_force_inverts_force(a, l_norm, v_norm):
    muscles = HillMuscles(PARAMS)
    length, velocity = mtu_state(l_norm, v_norm)
    state = muscles.fiber_state(length, velocity)
    force = muscles.force(np.array(a), length, velocity)
    fiber_velocity = muscles.fiber_velocity_for_force(np.array(a), force, length)
    expected = velocity * state.cos_pennation  # v_M = v_MT cos(alpha)
    np.testing.assert_allclose(fiber_velocity, expected, rtol=0, atol=1e-9)


def test_equation_15_rejects_zero_activation_and_too_small_force(muscles):
    length, velocity = mtu_state(1.0, 0.0)
    force = muscles.force(np.full(3, 0.5), length, velocity)
    with pytest.raises(InputError, match=r"activation\[1\] \(muscle 'triceps'\) = 0.0"):
        muscles.fiber_velocity_for_force(np.array([0.5, 0.0, 0.5]), force, length)
    with pytest.raises(InputError, match=r"force\[2\] \(muscle 'deltoid'\).*no solution"):
        muscles.fiber_velocity_for_force(np.full(3, 0.5), force * [1, 1, 0.001], length)


def test_equation_15_inverts_force_at_the_top_of_its_range(muscles):
    """At exactly 10 v_max lengthening the force is inverted, not refused for round-off."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        a = rng.uniform(0.01, 1.0, 3)
        length, velocity = mtu_state(rng.uniform(0.5, 1.6, 3), 10.0)
        force = muscles.force(a, length, velocity)
        fiber = muscles.fiber_velocity_for_force(a, force, length)
        expected = velocity * muscles.fiber_state(length, velocity).cos_pennation
        np.testing.assert_allclose(fiber, expected, rtol=1e-12)


def test_fibre_stretched_past_its_range_is_refused(muscles):
    """Lengths in centimetres (say) give an error, not inf or 1e289 N of passive force."""
    length, velocity = mtu_state(1.0, 0.0)
    with pytest.raises(InputError, match=r"mtu_length\[0\] \(muscle 'biceps'\).* are the"):
        muscles.force(np.ones(3), length * 100, velocity)
    at_limit, _ = mtu_state(2.5, 0.0)
    assert np.all(np.isfinite(muscles.force(np.ones(3), at_limit * (1 - 1e-12), velocity)))
    with pytest.raises(InputError, match=r"mtu_length\[1\] \(muscle 'triceps'\).*at most 2.5"):
        muscles.force_capacity(at_limit * [0.99, 1.01, 0.99], velocity)


@pytest.mark.parametrize("activation", [0.01, 1e-6])
def test_equation_15_rejects_a_force_above_the_eccentric_range(muscles, activation):
    """A force no plausible lengthening speed gives: refused, not 1e115 m/s or inf."""
    length, velocity = mtu_state(1.0, 10.0)
    top = muscles.force(np.full(3, activation), length, velocity)
    fiber = muscles.fiber_velocity_for_force(np.full(3, activation), top * (1 - 1e-12), length)
    assert np.all(np.isfinite(fiber))
    force = top * [1.0, 1.0, 1.01]
    with pytest.raises(InputError, match=r"force\[2\] \(muscle 'deltoid'\) = .* N is above "):
        muscles.fiber_velocity_for_force(np.full(3, activation), force, length)
    with pytest.raises(InputError, match=r"force\[0\].* above .* lengthening at 10 times"):
        muscles.fiber_velocity_for_force(np.full(3, activation), np.full(3, 400.0), length)


# ---------------------------------------------------------------- bad input


def test_nan_is_rejected_with_muscle_name(muscles):
    length, velocity = mtu_state(1.0, 0.0)
    length[1] = math.nan
    with pytest.raises(InputError, match=r"mtu_length\[1\] \(muscle 'triceps'\) = nan m"):
        muscles.force(np.ones(3), length, velocity)
    with pytest.raises(InputError, match=r"activation\[0\] \(muscle 'biceps'\) = nan"):
        muscles.force([math.nan, 1.0, 1.0], *mtu_state(1.0, 0.0))
    with pytest.raises(InputError, match=r"force\[2\] \(muscle 'deltoid'\) = nan N"):
        muscles.activation_for_force([1.0, 1.0, math.nan], *mtu_state(1.0, 0.0))


def test_negative_length_is_rejected(muscles):
    length, velocity = mtu_state(1.0, 0.0)
    length[0] = -0.3
    with pytest.raises(InputError, match=r"mtu_length\[0\] \(muscle 'biceps'\) = -0.3 m; expected"):
        muscles.fiber_state(length, velocity)


def test_length_not_longer_than_tendon_slack_is_rejected(muscles):
    length, velocity = mtu_state(1.0, 0.0)
    length[2] = 0.05  # exactly the deltoid's tendon slack length
    with pytest.raises(
        InputError,
        match=r"mtu_length\[2\] \(muscle 'deltoid'\) = 0.05 m is not longer than its "
        r"tendon_slack_length 0.05 m",
    ):
        muscles.force_capacity(length, velocity)


def test_wrong_shapes_are_rejected(muscles):
    length, velocity = mtu_state(1.0, 0.0)
    with pytest.raises(InputError, match=r"mtu_length must have shape \(3,\).*got shape \(2,\)"):
        muscles.fiber_state(length[:2], velocity)
    with pytest.raises(InputError, match=r"mtu_velocity must have shape \(3,\)"):
        muscles.fiber_state(length, 0.0)
    with pytest.raises(InputError, match=r"activation must have shape \(3,\)"):
        muscles.force(np.ones((3, 1)), length, velocity)


def test_activation_out_of_range_is_rejected(muscles):
    with pytest.raises(InputError, match=r"activation\[2\] \(muscle 'deltoid'\) = 1.5"):
        muscles.force([0.1, 0.2, 1.5], *mtu_state(1.0, 0.0))


def test_none_and_complex_inputs_are_named(muscles):
    length, velocity = mtu_state(1.0, 0.0)
    with pytest.raises(InputError, match=r"activation must be an array of shape \(3,\).*got None"):
        muscles.force(None, length, velocity)
    with pytest.raises(InputError, match="activation must be real numbers; got complex"):
        muscles.force(np.full(3, 0.5 + 1j), length, velocity)


def test_messages_print_plain_floats(muscles):
    length, velocity = mtu_state(1.0, 0.0)
    length[0] = muscles.tendon_slack_length[0]
    with pytest.raises(InputError) as caught:
        muscles.force(np.ones(3), length, velocity)
    assert "np.float64" not in str(caught.value)
    with pytest.raises(InputError) as caught:
        muscles.force(np.array([0.5, 2.0, 0.5]), *mtu_state(1.0, 0.0))
    assert "activation[1] (muscle 'triceps') = 2.0; expected" in str(caught.value)


def test_shortening_faster_than_vmax_is_rejected(muscles):
    length, velocity = mtu_state(1.0, [0.0, -1.2, 0.0])
    with pytest.raises(InputError, match=r"mtu_velocity\[1\] \(muscle 'triceps'\).*1.2 x"):
        muscles.force(np.ones(3), length, velocity)


def test_equation_15_at_maximum_shortening(muscles):
    length, velocity = mtu_state([1.0, 1.2, 1.5], -1.0)
    force = muscles.force(np.ones(3), length, velocity)
    fiber_velocity = muscles.fiber_velocity_for_force(np.ones(3), force, length)
    np.testing.assert_allclose(fiber_velocity, [-1.2, -1.0, -0.64], rtol=0, atol=1e-9)
