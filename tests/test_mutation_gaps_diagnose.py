"""Gaps found by a hand-made mutation round over msarm.diagnose: signals, candidate terms,
fitting and bootstrap, the selection's scores, the "where" phases and the residuals' checks.

Every test compares with an independent reference: a value worked out by hand from the
documented formula or rule, a tiny synthetic signal whose answer is known exactly, or a
promise of the module's docstring (a bound, a boundary that is inclusive or strict).
"""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import hand_breakdown

import msarm.diagnose.select as select
from msarm.diagnose.cable_effects import WinchFriction
from msarm.diagnose.effects import (
    CableCapstanFriction,
    CableCapstanHysteresis,
    CoulombFriction,
    DahlFriction,
    InertiaError,
    MotorCogging,
    StribeckFriction,
    ViscousFriction,
    parameter_index,
)
from msarm.diagnose.fitting import LinearSolver, bootstrap, fit
from msarm.diagnose.residuals import (
    DiagnosisWarning,
    Residuals,
    ResidualSpec,
    _warn_filter_span,
    _warn_implausible_scales,
    _warn_outside_joint_range,
    gap_starts,
)
from msarm.diagnose.signals import Signals
from msarm.diagnose.stack import Layout, own_gain
from msarm.diagnose.where import (
    BreakdownRow,
    PhaseSettings,
    break_down,
    motion_phases,
)
from msarm.errors import InputError


def _signals(T: int, n: int = 1, m: int = 1, **fields) -> Signals:
    """Signals of ``T`` samples at 100 Hz: zeros, unit wraps, and the given fields."""
    base = dict(
        t=np.arange(T) * 0.01,
        q=np.zeros((T, n)),
        qd=np.zeros((T, n)),
        qdd=np.zeros((T, n)),
        tension=np.zeros((T, m)),
        lengths=np.ones((T, m)),
        cable_velocity=np.zeros((T, m)),
        jacobian=np.zeros((T, m, n)),
        wrap=np.ones((T, m)),
        motor_angle=np.zeros((T, m)),
        dt=0.01,
    )
    base.update(fields)
    return Signals(**base)


# --- signals ----------------------------------------------------------------------------------


def test_the_tension_rate_restarts_in_each_segment_and_a_two_sample_one_is_one_sided():
    """``dF/dt`` by central differences within each segment, one-sided at its ends, zero for a
    segment of one sample: one run with two time gaps (segments of 2, 3 and 1 samples)."""
    t = np.array([0.0, 0.01, 0.05, 0.06, 0.07, 0.2])
    F = np.array([1.0, 3.0, 10.0, 14.0, 20.0, 50.0])[:, None]
    signals = _signals(6, t=t, tension=F, segment=np.array([0, 0, 1, 1, 1, 2]))
    assert signals.run.tolist() == [0] * 6  # one run: the segments alone split it
    # by hand: (3 - 1) / 0.01 on both samples of the first segment; (14 - 10) / 0.01,
    # (20 - 10) / 0.02 and (20 - 14) / 0.01 in the second; 0 for the lone sample
    expected = [200.0, 200.0, 400.0, 500.0, 600.0, 0.0]
    np.testing.assert_allclose(signals.tension_rate()[:, 0], expected, rtol=1e-9)


# --- candidate terms --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "build",
    [
        lambda: CoulombFriction(eps=0.0),
        lambda: DahlFriction(rate=0.0),
        lambda: StribeckFriction(eps=0.0),
        lambda: StribeckFriction(max_stribeck_velocity=0.0),
        lambda: CableCapstanFriction(eps=0.0),
        lambda: CableCapstanFriction(max_mu=0.0),
        lambda: CableCapstanHysteresis(mus=(0.03, 0.0)),
    ],
    ids=[
        "coulomb eps",
        "dahl rate",
        "stribeck eps",
        "stribeck v max",
        "capstan eps",
        "max mu",
        "mus",
    ],
)
def test_a_zero_smoothing_scale_rate_or_bound_is_refused(build):
    """These constants must be > 0 (a zero eps divides by zero in tanh(qd / eps))."""
    with pytest.raises(InputError, match="expected a finite value > 0"):
        build()


def test_the_stiction_weights_are_bounded_at_zero_and_a_negative_one_is_not_fitted():
    """``a_k >= 0`` (and <= max_weight), kept by IPOPT: a residual that only a negative
    weight explains is fitted with the weight on its lower bound, 0."""
    effect = CableCapstanHysteresis(n_cables=1, n_joints=1, mus=(0.1,), max_weight=5.0)
    lower, upper = effect.bounds()
    np.testing.assert_array_equal(lower, [0.0])
    np.testing.assert_array_equal(upper, [5.0])
    T = 60
    command = (20.0 + 10.0 * np.sin(np.linspace(0.0, 6.0, T)))[:, None]
    signals = _signals(
        T,
        tension=command,
        tension_cmd=command,
        jacobian=np.full((T, 1, 1), -0.03),
        wrap=np.full((T, 1), 2.0),
    )
    column = np.asarray(effect.torque(signals, np.array([1.0])))
    assert np.abs(column).max() > 0.1
    assert fit(effect, signals, -column).parameters[0] == 0.0


def test_a_mass_corrected_to_exactly_zero_is_impossible(arm):
    """impossible_masses lists each mass whose corrected value is <= 0: zero is no body."""
    inertia = InertiaError(arm, n_probe=40)
    k = next(i for i, p in enumerate(inertia.parameter_names) if p.endswith(".m"))
    nominal = float(inertia.nominal[k])
    assert nominal > 0
    theta = np.zeros(inertia.n_parameters)
    theta[k] = -nominal  # nominal + error == 0.0 exactly
    assert inertia.impossible_masses(theta) == [(inertia.parameter_names[k], nominal, 0.0)]
    theta[k] = -0.999 * nominal
    assert inertia.impossible_masses(theta) == []


def test_constants_collapse_a_per_channel_value_only_when_every_channel_has_it():
    """One value for every channel is that value; different values stay a list."""
    same = MotorCogging(n_periods=6, drum_radius=0.012, n_cables=3, n_joints=2)
    assert same.constants() == {"N": 6.0, "rho": 0.012}
    each = MotorCogging(n_periods=6, drum_radius=[0.01, 0.02, 0.03], n_cables=3, n_joints=2)
    assert each.constants() == {"N": 6.0, "rho": [0.01, 0.02, 0.03]}


def test_a_parameter_index_is_a_whole_number_in_closing_brackets():
    assert parameter_index("coulomb[3]") == 3
    assert parameter_index("mu[12]") == 12
    assert parameter_index("x[12") is None  # no closing bracket: no index
    assert parameter_index("bias[all]") is None
    assert parameter_index("a[mu=0.03]") is None


def test_winch_friction_of_a_drive_without_tension_feedback():
    """A drive gain K = 0 is allowed (>= 0): ``e = -(tau_c tanh(omega / omega_s) + b omega)
    / rho``, the winch torque over the drum radius alone."""
    omega = np.array([[-2.0], [-0.1], [0.0], [0.3], [4.0]])
    signals = _signals(5, motor_speed=omega)
    effect = WinchFriction(drum_radius=0.01, drive_gain=0.0, n_cables=1, smoothing_speed=0.5)
    expected = -(0.02 * np.tanh(omega / 0.5) + 0.003 * omega) / 0.01
    np.testing.assert_allclose(
        effect.torque(signals, np.array([0.02, 0.003])), expected, rtol=1e-12
    )


# --- fitting and the bootstrap ----------------------------------------------------------------


def _three_runs(levels=(0.0, 3.0, 6.0)):
    """Three runs with one joint of the same speeds each; run k's residual is levels[k] qd."""
    qd = np.array([1.0, -2.0, 3.0, 0.5])
    T = 4 * len(levels)
    signals = _signals(
        T, qd=np.tile(qd, len(levels))[:, None], run=np.repeat(np.arange(len(levels)), 4)
    )
    residual = np.repeat(np.asarray(levels, dtype=float), 4)[:, None] * signals.qd
    return signals, residual


def test_each_bootstrap_refit_draws_as_many_runs_as_there_are_and_counts_repeats():
    """Each refit draws 3 runs of 3 with replacement, a run drawn twice counting twice: the
    viscous level is then the mean of 3 drawn levels (0, 3, 6), a whole number. Two draws,
    or a repeat counted once, give halves (1.5, 4.5); resampled samples, anything."""
    signals, residual = _three_runs()
    result = bootstrap(ViscousFriction(n_joints=1), signals, residual, n_boot=200, seed=1)
    values = result.samples[:, 0]
    np.testing.assert_allclose(values, np.round(values), atol=1e-9)
    assert set(np.round(values).astype(int)) <= set(range(7))
    # means that need a run twice (1 = (0 + 0 + 3) / 3, 2, 4, 5) do come up
    assert set(np.round(values).astype(int)) & {1, 2, 4, 5}
    with pytest.raises(InputError, match="n_boot"):
        bootstrap(ViscousFriction(n_joints=1), signals, residual, n_boot=1)


def test_a_fit_on_as_many_training_samples_as_parameters_is_allowed():
    """Only *fewer* training samples than parameters are refused: one sample of one joint
    fits one Coulomb level exactly, c = r / tanh(qd / eps)."""
    qd = np.array([[0.05], [0.3], [-0.4]])
    signals = _signals(3, qd=qd)
    residual = np.array([[0.7], [1.0], [2.0]])
    mask = np.array([True, False, False])
    result = fit(CoulombFriction(n_joints=1, eps=0.1), signals, residual, train_mask=mask)
    np.testing.assert_allclose(result.parameters, 0.7 / np.tanh(0.5), rtol=1e-12)
    with pytest.raises(
        InputError, match=r"train_mask: 0 samples of 1 channel.* 0 residual values for 1"
    ):
        fit(CoulombFriction(n_joints=1), signals, residual, train_mask=np.zeros(3, bool))


# --- selection and stack ----------------------------------------------------------------------


@pytest.mark.parametrize(("spread", "resolved"), [(0.18, False), (0.16, True)])
def test_a_parameter_is_resolved_at_ten_jackknife_errors(spread, resolved):
    """Runs k = 0, 1, 2 with residual b_k x (the same x): the fit is mean(b) = 1, each
    leave-one-out fit the mean of the two others, and the jackknife error
    ``sqrt((n - 1) / n sum (theta_i - mean)^2)`` is ``spread / sqrt(3)``: 10.8 errors from
    zero is resolved, 9.6 is not (the error of the mean, ``sqrt(sum / (n - 1))``, would give
    11.1)."""
    x = np.array([1.0, -2.0, 0.5, 3.0])
    b = np.array([1.0 - spread, 1.0, 1.0 + spread])
    design = np.tile(x, 3)[:, None, None]
    left = np.repeat(b, 4)[:, None] * design[:, :, 0]
    sampled = SimpleNamespace(
        signals={"train": SimpleNamespace(run=np.repeat(np.arange(3), 4))},
        design=lambda term, split: design,
        solver=lambda terms: LinearSolver(design),
    )
    term = SimpleNamespace(n_parameters=1)
    assert select._resolved_by_runs(term, left, sampled).tolist() == [resolved]


def test_unexplained_and_gain_are_means_over_the_groups():
    scores = {"joint": 0.9, "drive": 0.5, "length": 0.0}
    assert select._unexplained(("joint", "drive"), scores) == pytest.approx(0.3)
    before = {"joint": 0.1, "drive": 0.2}
    after = {"joint": 0.5, "drive": 0.3}
    assert own_gain(("joint", "drive"), before, after) == pytest.approx(0.25)


def test_a_group_is_divided_by_the_root_of_its_summed_column_mean_squares():
    joint = np.array([[1.0, 2.0], [3.0, 0.0], [-1.0, 4.0], [1.0, -2.0]])  # T = 4, 2 columns
    drive = np.array([[3.0], [-3.0], [3.0], [-3.0]])
    layout = Layout({"joint": joint, "drive": drive})
    # mean squares 3 and 6 of the joint columns: sqrt(9) = 3; the drive's: 3
    assert layout.spread == pytest.approx({"joint": 3.0, "drive": 3.0})
    np.testing.assert_allclose(layout.stack({"joint": joint, "drive": drive})[:, :2], joint / 3.0)


# --- where the gap lies -----------------------------------------------------------------------


def _residuals(qd, q=None, rate=100.0):
    T, n = qd.shape
    return Residuals(
        source="hand",
        joint_names=tuple(f"j{k}" for k in range(n)),
        cable_names=("c1",),
        sample_rate_hz=rate,
        t=np.arange(T) / rate,
        valid=np.ones(T, dtype=bool),
        joint_torque=np.ones((T, n)),
        cable_length=None,
        drive=None,
        replay=None,
        q=np.zeros((T, n)) if q is None else q,
        qd=qd,
        qdd=np.zeros_like(qd),
        cable_velocity=np.zeros((T, 1)),
        tension=np.full((T, 1), 10.0),
    )


def test_a_straight_reversal_spanning_the_whole_window_marks_its_middle_sample():
    """+-2 samples of window at 100 Hz; +0.3 at sample 10 and -0.3 at 14: only sample 12 has
    both within +-2 samples (the documented rule, straight through zero)."""
    qd = np.zeros((30, 1))
    qd[10, 0], qd[14, 0] = 0.3, -0.3
    settings = PhaseSettings(
        hold_speed=0.5, reversal_speed=0.25, reversal_window=0.02, reversal_pause=0.02
    )
    expected = np.full(30, 2)  # hold
    expected[12] = 0
    np.testing.assert_array_equal(motion_phases(_residuals(qd), settings), expected)


def test_a_stop_of_exactly_reversal_pause_is_still_a_reversal():
    """0.1 s from the last sample moving out to the first moving back (a pause of 10 samples
    at 100 Hz): "at most reversal_pause", so the window about the first moving back
    reverses; one sample more of rest and it does not."""
    settings = PhaseSettings(
        hold_speed=0.25, reversal_speed=0.25, reversal_window=0.02, reversal_pause=0.1
    )
    qd = np.zeros((40, 1))
    qd[:10, 0] = 0.3  # last moving out: sample 9
    qd[19:, 0] = -0.3  # first moving back: sample 19
    expected = np.full(40, 3)  # constant velocity
    expected[10:19] = 2  # hold
    expected[17:22] = 0  # +-2 samples about sample 19
    np.testing.assert_array_equal(motion_phases(_residuals(qd), settings), expected)
    qd[19, 0] = 0.0  # first moving back: sample 20, 0.11 s after the last moving out
    expected[10:20] = 2
    expected[20:] = 3
    np.testing.assert_array_equal(motion_phases(_residuals(qd), settings), expected)


def test_the_posture_grid_takes_the_joints_with_the_largest_standard_deviation():
    """Joint a has the widest range (one spike) but the smallest spread: b and c are chosen."""
    T = 100
    sign = np.where(np.arange(T) % 2 == 0, 1.0, -1.0)
    a = np.zeros(T)
    a[50] = 5.0  # range 5, std 0.5
    q = np.column_stack([a, sign, 0.8 * sign])  # std 1 and 0.8, ranges 2 and 1.6
    breakdown = break_down(_residuals(np.zeros((T, 3)), q=q))
    assert breakdown.posture_joints == ("j1", "j2")


def test_without_a_model_a_still_joints_grid_spans_its_one_value():
    """The grid spans the logged range: for a joint that never moves, (almost) a point."""
    q = np.column_stack([np.linspace(0.0, 1.0, 6), np.full(6, 0.3)])
    breakdown = break_down(_residuals(np.zeros((6, 2)), q=q), posture_joints=("j0", "j1"), bins=3)
    edges = breakdown.posture_edges[1]
    assert edges[0] == 0.3 and edges[-1] - edges[0] < 1e-6


def test_a_hot_spot_may_have_exactly_the_least_density():
    """hot_spots keeps rows of a density of at least hot_spot_density (1.2 here, exactly)."""
    settings = PhaseSettings()
    rows = (
        BreakdownRow("motion", "hold", 24.0, 24.0, 20.0, settings.hot_spot_density, 500),
        BreakdownRow("load", "high_load", 23.9, 23.9, 20.0, 1.195, 500),
    )
    breakdown = hand_breakdown(rows, settings, samples=2500)
    assert [r.where for r in breakdown.hot_spots()] == ["hold"]


# --- residuals: gaps and the checks of a log's scales -----------------------------------------


def test_a_step_of_exactly_the_gap_factor_is_no_gap():
    """A gap is a step *longer* than 1.5 sample periods (4 Hz: 0.375 s, exact in binary)."""
    assert gap_starts(np.array([0.0, 0.25, 0.625, 0.875]), 4.0).tolist() == []
    assert gap_starts(np.array([0.0, 0.25, 0.6251, 0.8751]), 4.0).tolist() == [2]


def _warnings(function, *args) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        function(*args)
    return [str(w.message) for w in caught if issubclass(w.category, DiagnosisWarning)]


def test_the_filter_span_warns_only_outside_its_range():
    """Spans of exactly 0.01 s and 0.15 s are inside FILTER_SPAN_S = (0.01, 0.15): no warning;
    beyond 0.15 s the warning names the filter's own bias."""
    assert _warnings(_warn_filter_span, "log", 75, 500.0) == []  # 0.15 s
    assert _warnings(_warn_filter_span, "log", 5, 500.0) == []  # 0.01 s
    (message,) = _warnings(_warn_filter_span, "log", 51, 250.0)  # 0.204 s
    assert "bias from the filter itself" in message
    assert len(_warnings(_warn_filter_span, "log", 5, 501.0)) == 1


@pytest.mark.parametrize(("commanded", "warned"), [(20.0, False), (5.0, False), (20.2, True)])
def test_commands_and_load_cells_agree_within_the_tension_ratio(commanded, warned):
    """Median commands of exactly 2 or 0.5 times the load cells' are within TENSION_RATIO."""
    T = 8
    out = {"tension_cmd": np.full((T, 2), commanded), "cable_length": None}
    args = (out, np.full((T, 2), 10.0), None, np.ones(T, bool), ResidualSpec(), ["a", "b"])
    messages = _warnings(_warn_implausible_scales, "log", *args)
    assert bool([m for m in messages if "commanded tensions" in m]) == warned


@pytest.mark.parametrize(("low", "warned"), [(-1.5, False), (-1.5001, True)])
def test_joint_angles_warn_more_than_the_margin_outside_the_range(low, warned):
    """JOINT_RANGE_MARGIN = 0.5 rad: exactly 0.5 beyond the lower limit is not "more than"."""
    model = SimpleNamespace(joint_lower=np.array([-1.0]), joint_upper=np.array([1.0]))
    q = np.array([[0.0], [low], [0.5]])
    messages = _warnings(_warn_outside_joint_range, "log", [("q", q)], model, ["j"])
    assert bool(messages) == warned
