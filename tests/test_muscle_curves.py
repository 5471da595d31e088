"""De Groote et al. (2016) curves against independently written formulas and hand values."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from msarm.errors import InputError
from msarm.muscle.curves import (
    FORCE_VELOCITY_AT_MAX_SHORTENING,
    active_force_length,
    force_velocity,
    force_velocity_inverse,
    passive_force_length,
)

# Published constants, typed in again here on purpose (not imported from the module).
B = [
    (0.815, 1.055, 0.162, 0.063),
    (0.433, 0.717, -0.030, 0.200),
    (0.100, 1.000, 0.354, 0.000),
]
D1, D2, D3, D4 = -0.318, -8.149, -0.374, 0.886


def ref_fl(x: float) -> float:
    return sum(b1 * math.exp(-0.5 * (x - b2) ** 2 / (b3 + b4 * x) ** 2) for b1, b2, b3, b4 in B)


def ref_fv(v: float) -> float:
    x = D2 * v + D3
    return D1 * math.log(x + math.sqrt(x * x + 1.0)) + D4


def ref_fpe(x: float) -> float:
    if x <= 1.0:
        return 0.0
    return (math.exp(4.0 * (x - 1.0) / 0.6) - 1.0) / (math.exp(4.0) - 1.0)


# ---------------------------------------------------------------- defining points


def test_active_force_length_at_optimal_length_is_published_value():
    # Hand computation: 0.815 exp(-0.5 (0.055/0.225)^2) + 0.433 exp(-0.5 (0.283/0.170)^2) + 0.1
    #                 = 0.791011 + 0.108322 + 0.100000 = 0.999333 (not exactly 1).
    assert active_force_length(1.0) == pytest.approx(0.999333, abs=1e-6)
    assert abs(active_force_length(1.0) - 1.0) < 1e-3


def test_active_force_length_peaks_near_one():
    lengths = np.linspace(0.5, 1.5, 100_001)
    values = active_force_length(lengths)
    peak = lengths[np.argmax(values)]
    assert 1.0 <= peak <= 1.03
    assert values.max() == pytest.approx(1.0, abs=1e-3)
    assert np.all(np.diff(values[lengths < 1.0]) > 0)
    assert np.all(np.diff(values[lengths > 1.02]) < 0)


def test_force_velocity_defining_points():
    # f_v(0) = 0.318 asinh(0.374) + 0.886 = 1.00232 with the published constants.
    assert force_velocity(0.0) == pytest.approx(1.00232, abs=1e-5)
    assert abs(force_velocity(0.0) - 1.0) < 3e-3
    # f_v(-1) = -0.318 asinh(7.775) + 0.886 = 0.01208: about 0 at maximum shortening.
    assert force_velocity(-1.0) == pytest.approx(0.012082, abs=1e-6)
    assert 0.0 < force_velocity(-1.0) < 0.015
    assert FORCE_VELOCITY_AT_MAX_SHORTENING == force_velocity(-1.0)
    # Eccentric plateau about 1.8 at v_max.
    assert force_velocity(1.0) == pytest.approx(1.78891, abs=1e-5)


def test_force_velocity_is_increasing():
    v = np.linspace(-1.0, 3.0, 4001)
    assert np.all(np.diff(force_velocity(v)) > 0)


def test_passive_force_is_zero_at_and_below_slack_and_increasing_above():
    below = np.array([1e-3, 0.2, 0.5, 0.9, 0.999999, 1.0])
    assert np.all(passive_force_length(below) == 0.0)
    above = np.linspace(1.0, 2.0, 1001)
    values = passive_force_length(above)
    assert np.all(np.diff(values) > 0)
    assert np.all(values[1:] > 0)


def test_passive_force_hand_values():
    # f_PE(1.3) = (e^2 - 1) / (e^4 - 1) = 1 / (e^2 + 1); f_PE(1 + e0) = 1.
    assert passive_force_length(1.3) == pytest.approx(1.0 / (math.e**2 + 1.0), rel=1e-12)
    assert passive_force_length(1.6) == pytest.approx(1.0, rel=1e-12)
    assert passive_force_length(1.1) == pytest.approx(0.01768221553, rel=1e-9)


@pytest.mark.parametrize(
    ("l_norm", "expected"),
    [(0.5, 0.0537543541), (0.8, 0.8348429133), (1.2, 0.7925220379), (1.5, 0.2242989227)],
)
def test_active_force_length_hand_values(l_norm, expected):
    assert active_force_length(l_norm) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize(
    ("v_norm", "expected"),
    [(-0.5, 0.2438336294), (0.5, 1.5850003903)],
)
def test_force_velocity_hand_values(v_norm, expected):
    assert force_velocity(v_norm) == pytest.approx(expected, rel=1e-9)


def test_curves_match_independent_formulas_on_a_grid():
    lengths = np.linspace(0.2, 2.0, 181)
    velocities = np.linspace(-1.0, 1.0, 201)
    np.testing.assert_allclose(
        active_force_length(lengths), [ref_fl(x) for x in lengths], rtol=1e-12, atol=0
    )
    np.testing.assert_allclose(
        passive_force_length(lengths), [ref_fpe(x) for x in lengths], rtol=1e-12, atol=1e-15
    )
    np.testing.assert_allclose(
        force_velocity(velocities), [ref_fv(x) for x in velocities], rtol=1e-12, atol=1e-14
    )


def test_active_force_length_handles_zero_width_of_second_term():
    # b32 + b42 l = 0 at l = 0.15: the second term's limit is 0.
    value = active_force_length(0.15)
    expected = 0.815 * math.exp(-0.5 * (0.15 - 1.055) ** 2 / (0.162 + 0.063 * 0.15) ** 2)
    expected += 0.1 * math.exp(-0.5 * (0.85 / 0.354) ** 2)
    assert value == pytest.approx(expected, rel=1e-12)


# ---------------------------------------------------------------- shapes and types


def test_scalars_give_floats_and_arrays_keep_their_shape():
    for function in (active_force_length, passive_force_length):
        assert isinstance(function(1.1), float)
        assert function(np.full((2, 3), 1.1)).shape == (2, 3)
    assert isinstance(force_velocity(0.1), float)
    assert isinstance(force_velocity_inverse(1.0), float)
    assert force_velocity(np.zeros((4, 1))).shape == (4, 1)
    assert force_velocity_inverse(np.ones(5)).shape == (5,)


# ---------------------------------------------------------------- inverse


def test_force_velocity_inverse_roundtrip_on_valid_range():
    v = np.linspace(-1.0, 1.0, 20_001)
    np.testing.assert_allclose(force_velocity_inverse(force_velocity(v)), v, rtol=0, atol=1e-9)
    f = np.linspace(FORCE_VELOCITY_AT_MAX_SHORTENING, 1.8, 2001)
    np.testing.assert_allclose(force_velocity(force_velocity_inverse(f)), f, rtol=0, atol=1e-9)


def test_force_velocity_inverse_hand_values():
    assert force_velocity_inverse(force_velocity(0.0)) == pytest.approx(0.0, abs=1e-12)
    # f_v = d4 makes the asinh argument 0, so v = -d3/d2 = -0.374/8.149.
    assert force_velocity_inverse(0.886) == pytest.approx(-0.374 / 8.149, rel=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.floats(min_value=-1.0, max_value=3.0, allow_nan=False))
def test_force_velocity_inverse_roundtrip_property(v):
    assert force_velocity_inverse(force_velocity(v)) == pytest.approx(v, abs=1e-9)


@pytest.mark.parametrize("value", [0.0, 0.012, -0.5])
def test_force_velocity_inverse_rejects_values_below_curve_range(value):
    with pytest.raises(InputError, match=r"f_v must be >= force_velocity\(-1\)"):
        force_velocity_inverse(value)


@pytest.mark.parametrize("value", [2.6, 40.0, 1000.0, np.array([1.0, 1e6])])
def test_force_velocity_inverse_rejects_values_above_the_eccentric_range(value):
    """Past force_velocity(10) the analytic inverse grows to 1e115 or overflows: refused."""
    with pytest.raises(InputError, match=r"f_v must be <= force_velocity\(10\) = 2.50724"):
        force_velocity_inverse(value)


def test_force_velocity_inverse_reaches_ten_times_vmax_lengthening():
    top = force_velocity(10.0)
    assert force_velocity_inverse(top) == pytest.approx(10.0, abs=1e-9)


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize("function", [active_force_length, passive_force_length])
@pytest.mark.parametrize("bad", [0.0, -0.3, np.array([1.0, -1.0])])
def test_lengths_must_be_positive(function, bad):
    with pytest.raises(InputError, match="l_norm must be > 0"):
        function(bad)


@pytest.mark.parametrize(
    "function",
    [active_force_length, passive_force_length, force_velocity, force_velocity_inverse],
)
@pytest.mark.parametrize("bad", [math.nan, np.array([1.0, np.nan]), math.inf])
def test_nan_and_inf_are_rejected(function, bad):
    with pytest.raises(InputError, match="must be finite"):
        function(bad)


def test_nan_error_names_the_index():
    with pytest.raises(InputError, match=r"l_norm must be finite; got nan at index \(1,\)"):
        active_force_length([1.0, math.nan, 1.0])


def test_force_velocity_rejects_shortening_faster_than_vmax():
    with pytest.raises(InputError, match="v_norm must be >= -1"):
        force_velocity(-1.01)


def test_non_numeric_input_is_rejected():
    with pytest.raises(InputError, match="l_norm must be a real number"):
        active_force_length("long")
    with pytest.raises(ValueError):  # InputError is a ValueError
        force_velocity([0.1, "x"])


def test_none_and_complex_are_named_as_such():
    """None read as NaN ("must be finite; got nan"), complex lost its imaginary part."""
    with pytest.raises(InputError, match="l_norm must be a real number or array of them; got None"):
        active_force_length(None)
    with pytest.raises(InputError, match=r"must be a real number or array of them; got \(1\+1j\)"):
        active_force_length(1 + 1j)
