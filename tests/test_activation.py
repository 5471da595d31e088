"""Activation dynamics: documented time constants, integrator accuracy and bounds, bad input."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from msarm.errors import InputError
from msarm.muscle.activation import (
    DEFAULT_ACTIVATION_SMOOTHING,
    DEFAULT_TAU_ACT,
    DEFAULT_TAU_DEACT,
    activation_derivative,
    activation_time_constant,
    step_activation,
)

# Closed-form crossing times of the sharp-switch form (see the module docstring).
RISE_63 = 2.0 - 1.5 * (1.0 - math.exp(-1.0))  # x tau_act, ≈ 1.0518
FALL_37 = 2.0 + 2.0 * math.log(0.25 + 0.75 / math.e)  # x tau_deact, ≈ 0.7147


def reference_derivative(e, a, tau_act=0.015, tau_deact=0.060, b=10.0):
    """De Groote et al. 2016 eq. 1-2, typed in independently."""
    f = 0.5 * math.tanh(b * (e - a))
    return ((f + 0.5) / (tau_act * (0.5 + 1.5 * a)) + (0.5 + 1.5 * a) / tau_deact * (0.5 - f)) * (
        e - a
    )


def crossing_time(a0, excitation, level, duration, dt=1e-5, **kwargs):
    """Integrate with step_activation and interpolate the time the activation crosses level."""
    times = [0.0]
    values = [a0]
    a = a0
    for k in range(1, int(round(duration / dt)) + 1):
        a = step_activation(a, excitation, dt, **kwargs)
        times.append(k * dt)
        values.append(a)
    values = np.array(values)
    sign = np.sign(values - level)
    k = int(np.flatnonzero(sign != sign[0])[0])
    t0, t1, v0, v1 = times[k - 1], times[k], values[k - 1], values[k]
    return t0 + (level - v0) * (t1 - t0) / (v1 - v0)


def test_default_time_constants():
    assert DEFAULT_TAU_ACT == 0.015
    assert DEFAULT_TAU_DEACT == 0.060
    assert DEFAULT_ACTIVATION_SMOOTHING == 10.0


def test_time_constants_hold_exactly_at_one_third():
    # At a = 1/3 the factor 0.5 + 1.5 a is 1: tau = tau_act rising, tau_deact falling.
    third = 1.0 / 3.0
    assert activation_time_constant(1.0, third, smoothing=1e6) == pytest.approx(0.015, rel=1e-12)
    assert activation_time_constant(0.0, third, smoothing=1e6) == pytest.approx(0.060, rel=1e-12)
    # Default smoothing b = 10: tanh(10 * 2/3) leaves a 3e-6 blend when rising; tanh(10/3)
    # leaves 1.3e-3 of the (4x faster) activation rate when falling, i.e. 0.4 %.
    assert activation_derivative(1.0, third) == pytest.approx((2 / 3) / 0.015, rel=1e-5)
    assert activation_derivative(0.0, third) == pytest.approx(-third / 0.060, rel=5e-3)


def test_step_up_reaches_63_percent_at_documented_time():
    t = crossing_time(0.0, 1.0, 1.0 - math.exp(-1.0), duration=0.03)
    assert t == pytest.approx(RISE_63 * DEFAULT_TAU_ACT, rel=2e-3)  # 15.78 ms
    assert t == pytest.approx(DEFAULT_TAU_ACT, rel=0.06)  # i.e. tau_act within 6 %


def test_step_down_decays_to_37_percent_at_documented_time():
    t = crossing_time(1.0, 0.0, math.exp(-1.0), duration=0.06)
    assert t == pytest.approx(FALL_37 * DEFAULT_TAU_DEACT, rel=2e-3)  # 42.9 ms


def test_time_constants_are_configurable():
    slow = crossing_time(0.0, 1.0, 1.0 - math.exp(-1.0), duration=0.06, tau_act=0.03)
    assert slow == pytest.approx(RISE_63 * 0.03, rel=2e-3)
    fast = crossing_time(1.0, 0.0, math.exp(-1.0), duration=0.03, tau_deact=0.03)
    assert fast == pytest.approx(FALL_37 * 0.03, rel=2e-3)


def test_paper_smoothing_blends_the_constants():
    # With b = 0.1 (De Groote et al. 2016) the rise is much slower than tau_act suggests.
    t = crossing_time(0.0, 1.0, 1.0 - math.exp(-1.0), duration=0.04, smoothing=0.1)
    assert t == pytest.approx(1.544 * DEFAULT_TAU_ACT, rel=5e-3)


def test_derivative_matches_independent_formula():
    rng = np.random.default_rng(0)
    e = rng.uniform(0, 1, 200)
    a = rng.uniform(0, 1, 200)
    expected = [reference_derivative(ei, ai) for ei, ai in zip(e, a, strict=True)]
    np.testing.assert_allclose(activation_derivative(e, a), expected, rtol=1e-12, atol=1e-12)
    assert activation_derivative(0.4, 0.4) == 0.0


def test_step_matches_accurate_ode_solution_and_is_second_order():
    e, a0, horizon = 0.8, 0.1, 0.02
    exact = solve_ivp(
        lambda _t, y: [reference_derivative(e, y[0])],
        (0.0, horizon),
        [a0],
        rtol=1e-12,
        atol=1e-14,
    ).y[0, -1]

    def integrate(n):
        a = a0
        for _ in range(n):
            a = step_activation(a, e, horizon / n)
        return a

    coarse, fine = integrate(20), integrate(40)
    assert abs(fine - exact) < 1e-4
    order = math.log2(abs(coarse - exact) / abs(fine - exact))
    assert order > 1.8


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    st.floats(0.0, 1.0),
    st.floats(0.0, 1.0),
    st.floats(1e-6, 10.0),
)
def test_step_stays_between_activation_and_excitation(a, e, dt):
    a_next = step_activation(a, e, dt)
    assert 0.0 <= a_next <= 1.0
    assert min(a, e) <= a_next <= max(a, e)


def test_large_step_converges_to_excitation_and_arrays_broadcast():
    out = step_activation(np.array([0.0, 0.5, 1.0]), 0.3, 10.0)
    np.testing.assert_allclose(out, 0.3, atol=1e-12)
    assert isinstance(step_activation(0.2, 0.7, 1e-3), float)
    assert activation_derivative(np.zeros((2, 3)), 0.5).shape == (2, 3)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"excitation": math.nan}, "excitation must be finite"),
        ({"excitation": 1.2}, r"excitation must be in \[0, 1\]"),
        ({"activation": -0.1}, r"activation must be in \[0, 1\]"),
        ({"activation": np.array([0.1, np.nan])}, "activation must be finite"),
        ({"tau_act": 0.0}, "tau_act must be > 0"),
        ({"tau_deact": -1.0}, "tau_deact must be > 0"),
        ({"smoothing": math.nan}, "smoothing must be finite"),
        ({"excitation": np.zeros(3), "activation": np.zeros(2)}, "broadcastable"),
    ],
)
def test_bad_input_is_rejected(kwargs, match):
    args = {"excitation": 0.5, "activation": 0.5} | kwargs
    with pytest.raises(InputError, match=match):
        activation_derivative(**args)


@pytest.mark.parametrize(("dt", "match"), [(0.0, "dt must be > 0"), (math.nan, "dt must be")])
def test_step_rejects_bad_dt(dt, match):
    with pytest.raises(InputError, match=match):
        step_activation(0.5, 0.5, dt)
