"""The "where" breakdown on small hand-made residuals: thresholds, grid, ordering, hot spots.

No simulation: every input is laid out by hand and every expected value is worked out by hand
(or, for the posture grid, by ``np.histogram2d`` as a brute-force reference).
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import hand_breakdown

from msarm.diagnose.residuals import Residuals
from msarm.diagnose.where import (
    BreakdownRow,
    PhaseSettings,
    break_down,
    load_phases,
    motion_phases,
)


def _residuals(
    qd: np.ndarray,
    qdd: np.ndarray | None = None,
    torque: np.ndarray | None = None,
    q: np.ndarray | None = None,
    tension: np.ndarray | None = None,
    joints: tuple[str, ...] | None = None,
    cables: tuple[str, ...] = ("c1", "c2"),
    rate: float = 100.0,
) -> Residuals:
    n_samples, n = qd.shape
    joints = joints or tuple(f"j{k}" for k in range(n))
    return Residuals(
        source="hand",
        joint_names=joints,
        cable_names=cables,
        sample_rate_hz=rate,
        t=np.arange(n_samples) / rate,
        valid=np.ones(n_samples, dtype=bool),
        joint_torque=np.ones((n_samples, n)) if torque is None else torque,
        cable_length=None,
        drive=None,
        replay=None,
        q=np.zeros((n_samples, n)) if q is None else q,
        qd=qd,
        qdd=np.zeros_like(qd) if qdd is None else qdd,
        cable_velocity=np.zeros((n_samples, len(cables))),
        tension=np.full((n_samples, len(cables)), 10.0) if tension is None else tension,
    )


# thresholds that are exact binary fractions, so that "at the threshold" is exact
EXACT = PhaseSettings(
    hold_speed=0.5,
    reversal_speed=0.25,
    reversal_window=0.02,
    reversal_pause=0.02,  # straight through zero only (the through-a-stop case: below)
    acceleration=2.0,
)


def test_motion_thresholds_are_strict_or_inclusive_as_documented():
    """hold: |qd| < hold_speed (strict); acceleration: |qdd| >= acceleration (inclusive);
    reversal: qd above +reversal_speed and below -reversal_speed (both strict) within
    +-reversal_window (here +-2 samples at 100 Hz); an invalid (NaN) sample is ``hold``."""
    qd = np.zeros((40, 2))
    qdd = np.zeros((40, 2))
    qd[5, 0] = 0.5  # exactly hold_speed: not holding -> constant velocity
    qdd[10, 1] = -2.0  # exactly the acceleration threshold -> acceleration
    qd[15, 0] = 0.25  # exactly +reversal_speed: not above it, so no reversal with ...
    qd[16, 0] = -0.3  # ... this one (both are below hold_speed: hold)
    qd[30, 1] = 0.3  # a real reversal two samples apart: samples 30..32 see both signs
    qd[32, 1] = -0.3
    qd[20, 1] = 0.3  # straight through, three samples apart (more than the 2-sample
    qd[23, 1] = -0.3  # reversal_pause, within the window): samples 21..22 see both signs
    qd[37] = np.nan  # an invalid sample
    qdd[37] = np.nan
    expected = np.full(40, 2)  # hold
    expected[5] = 3  # constant_velocity
    expected[10] = 1  # acceleration
    expected[30:33] = 0  # reversal
    expected[21:23] = 0
    got = motion_phases(_residuals(qd, qdd), EXACT)
    np.testing.assert_array_equal(got, expected)


def test_a_joint_that_stops_and_goes_back_reverses_at_its_restart():
    """Out, a 0.4 s hold, back (a reach-and-hold task's joint): the 0.05 s either side of the
    first sample moving back is a reversal; before, only a pass straight through zero was,
    and no sample of the benchmark's tasks ever was. A hold longer than reversal_pause is
    none."""
    qd = np.zeros((80, 1))
    qd[:20, 0] = 0.3
    qd[60:, 0] = -0.3
    expected = np.full(80, 3)  # constant velocity (|qd| >= hold_speed 0.25) ...
    expected[20:60] = 2  # ... around the hold
    expected[55:66] = 0  # +-5 samples of 10 ms about sample 60, the first moving back
    settings = PhaseSettings(hold_speed=0.25, reversal_speed=0.25, reversal_window=0.05)
    np.testing.assert_array_equal(motion_phases(_residuals(qd), settings), expected)
    expected[55:66] = np.where(np.arange(55, 66) < 60, 2, 3)
    short = replace(settings, reversal_pause=0.3)  # the 0.4 s hold is longer
    np.testing.assert_array_equal(motion_phases(_residuals(qd), short), expected)


def test_a_sign_change_across_a_time_gap_is_no_reversal():
    """The reversal window is +-reversal_window in time within one stretch of the log: qd of
    +0.3 rad/s, then a 1 s gap (the log's rows go on), then -0.3 rad/s is no reversal; the
    same rows without the gap reverse at the two samples either side of the change."""
    qd = np.zeros((20, 1))
    qd[:10, 0] = 0.3
    qd[10:, 0] = -0.3
    joined = _residuals(qd)
    expected = np.full(20, 3)  # constant velocity (|qd| >= hold_speed 0.25)
    expected[8:12] = 0  # +-2 samples of 10 ms around the change see both signs
    settings = PhaseSettings(hold_speed=0.25, reversal_speed=0.25, reversal_window=0.02)
    np.testing.assert_array_equal(motion_phases(joined, settings), expected)
    t = joined.t.copy()
    t[10:] += 1.0  # rows 0..9, then rows 10..19 a second later
    gapped = replace(joined, t=t)
    np.testing.assert_array_equal(motion_phases(gapped, settings), np.full(20, 3))


def test_load_thresholds_and_the_high_load_percentile():
    """low: some tension < low_tension (strict); high: largest tension > the percentile of the
    per-sample largest tension (strict), by the largest and not the total tension."""
    tension = np.array(
        [
            [10.0, 5.0],  # largest 10
            [20.0, 3.0],  # 20
            [30.0, 25.0],  # 30
            [40.0, 45.0],  # 45 (largest total, 85, after the slack sample's 91)
            [1.0, 90.0],  # slack cable: low, though the largest tension
            [60.0, 3.0],  # 60
            [2.0, 8.0],  # exactly low_tension: not low
            [70.0, 3.0],  # 70: exactly the 75th percentile, not above it
            [80.0, 3.0],  # 80: high
        ]
    )
    # largest, sorted: 8 10 20 30 45 60 70 80 90; p75 at index 0.75 * 8 = 6: 70
    got = load_phases(tension, PhaseSettings(low_tension=2.0, high_load_percentile=75.0))
    np.testing.assert_array_equal(got, [2, 2, 2, 2, 0, 2, 2, 2, 1])


def test_channel_rows_rms_and_row_order():
    """Channel rows: own sum of squares, time share an even split (100 / 3 channels);
    rms over samples and channels; each group's rows by share, largest first; a phase
    without samples has no row (share 0, density NaN) and no NaN reaches the Markdown."""
    n_samples = 10
    torque = np.zeros((n_samples, 3))
    torque[:, 0] = 1.0  # energy 10
    torque[:, 1] = 3.0  # energy 90
    torque[:, 2] = 2.0  # energy 40
    qd = np.zeros((n_samples, 3))
    qd[6:, 0] = 0.3  # 4 samples constant velocity, 6 holding; no reversal, no acceleration
    breakdown = break_down(_residuals(qd, torque=torque, cables=("c",)), bins=1)
    assert breakdown.total_energy == pytest.approx(140.0)
    assert breakdown.rms == pytest.approx(np.sqrt(140.0 / 30))
    channel = breakdown.group("channel")
    assert [r.where for r in channel] == ["j1", "j2", "j0"]
    assert [r.energy for r in channel] == pytest.approx([90.0, 40.0, 10.0])
    for row in channel:
        assert row.time_share == pytest.approx(100.0 / 3)
        assert row.density == pytest.approx(row.share / (100.0 / 3))
        assert row.samples == n_samples
    motion = breakdown.group("motion")
    # every sample holds 14 of energy: hold 6 samples (60 %), constant velocity 4 (40 %)
    assert [(r.where, r.samples) for r in motion] == [("hold", 6), ("constant_velocity", 4)]
    assert [r.share for r in motion] == pytest.approx([60.0, 40.0])
    assert breakdown.share("motion", "reversal") == 0.0
    assert np.isnan(breakdown.density("motion", "reversal"))
    assert "nan" not in breakdown.to_markdown()


def test_the_posture_grid_defaults_to_the_two_joints_that_move_most():
    rng = np.random.default_rng(3)
    q = np.column_stack([rng.normal(0, 0.2, 50), rng.normal(0, 0.05, 50), rng.normal(0, 0.9, 50)])
    breakdown = break_down(_residuals(np.zeros((50, 3)), q=q, joints=("a", "b", "c")))
    assert breakdown.posture_joints == ("c", "a")


def _grid_reference(q_a, q_b, per_sample, edges_a, edges_b):
    """Counts and energies of the cells by np.histogram2d (bins [e_i, e_i+1), last closed),
    the samples outside the range moved onto its ends."""
    q_a = np.clip(q_a, edges_a[0], edges_a[-1])
    q_b = np.clip(q_b, edges_b[0], edges_b[-1])
    counts, _, _ = np.histogram2d(q_a, q_b, bins=[edges_a, edges_b])
    energy, _, _ = np.histogram2d(q_a, q_b, bins=[edges_a, edges_b], weights=per_sample)
    return counts, energy


def test_the_posture_grid_bins_as_a_2d_histogram():
    """Samples on an interior edge go into the upper bin; outside the model's range into the
    edge bins; the cell RMS is over its samples and the channels."""
    q_a = np.array([0.0, 0.5, 0.5, 1.0, 0.25, -3.0, 0.75, 0.5])
    q_b = np.array([-1.0, -0.5, 0.0, 1.0, 5.0, 0.5, -0.5, 1.0])
    q = np.column_stack([q_a, q_b])
    torque = np.arange(1.0, 17.0).reshape(8, 2)
    model = SimpleNamespace(joint_lower=np.array([0.0, -1.0]), joint_upper=np.array([1.0, 1.0]))
    breakdown = break_down(
        _residuals(np.zeros((8, 2)), torque=torque, q=q, joints=("a", "b")),
        posture_joints=("a", "b"),
        bins=4,
        model=model,
    )
    edges_a, edges_b = breakdown.posture_edges
    np.testing.assert_allclose(edges_a, [0.0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(edges_b, [-1.0, -0.5, 0.0, 0.5, 1.0])
    per_sample = (torque**2).sum(axis=1)
    counts, energy = _grid_reference(q_a, q_b, per_sample, edges_a, edges_b)
    np.testing.assert_array_equal(breakdown.posture_samples, counts)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(energy / (2 * counts))
    np.testing.assert_allclose(breakdown.posture_rms, rms)  # NaN where no samples, alike
    # by hand: each sample in a cell of its own, named by the cell's ranges
    rows = {r.where: (r.samples, r.energy) for r in breakdown.group("posture")}
    assert rows == {
        "a [0.00, 0.25] x b [-1.00, -0.50]": (1, 5.0),
        "a [0.50, 0.75] x b [-0.50, 0.00]": (1, 25.0),
        "a [0.50, 0.75] x b [0.00, 0.50]": (1, 61.0),
        "a [0.75, 1.00] x b [0.50, 1.00]": (1, 113.0),
        "a [0.25, 0.50] x b [0.50, 1.00]": (1, 181.0),
        "a [0.00, 0.25] x b [0.50, 1.00]": (1, 265.0),
        "a [0.75, 1.00] x b [-0.50, 0.00]": (1, 365.0),
        "a [0.50, 0.75] x b [0.50, 1.00]": (1, 481.0),
    }


def test_a_posture_joint_that_never_moves_still_gets_a_grid_of_increasing_edges():
    q = np.column_stack([np.linspace(0.0, 1.0, 6), np.full(6, 0.3)])
    breakdown = break_down(
        _residuals(np.zeros((6, 2)), q=q, joints=("a", "b")), posture_joints=("a", "b"), bins=3
    )
    assert np.all(np.diff(breakdown.posture_edges[1]) > 0)
    assert breakdown.posture_edges[1][0] == 0.3
    # every sample lies at the bottom of the constant joint's range: its first bin
    assert breakdown.posture_samples[:, 0].sum() == 6


def _row(group: str, where: str, share: float, time_share: float) -> BreakdownRow:
    return BreakdownRow(group, where, share, share, time_share, share / time_share, 1)


def test_hot_spots_are_the_densest_non_channel_rows_with_enough_time():
    rows = (
        _row("channel", "j0", 90.0, 50.0),  # density 1.8, but a channel: never a hot spot
        _row("motion", "hold", 10.0, 5.0),  # density 2, time share exactly the minimum
        _row("motion", "reversal", 6.0, 6.0),  # density 1, not above 1
        _row("load", "high_load", 40.0, 25.0),  # density 1.6, the largest share
        _row("posture", "cell", 9.8, 4.9),  # density 2, but under 5 % of the time
        _row("load", "low_tension", 12.0, 4.0),  # density 3, too little time
    )
    # the rows have one sample each
    breakdown = hand_breakdown(rows, PhaseSettings(hot_spot_samples=1))
    hot = breakdown.hot_spots(min_time_share=5.0)
    assert [(r.group, r.where) for r in hot] == [("motion", "hold"), ("load", "high_load")]
    assert [r.where for r in breakdown.hot_spots(count=1)] == ["hold"]


def test_logs_of_different_robots_and_a_grid_without_bins_are_refused():
    one = _residuals(np.zeros((5, 2)))
    other_cables = _residuals(np.zeros((5, 2)), cables=("c1", "c3"))
    with pytest.raises(ValueError, match=r"different robots"):
        break_down([one, other_cables])
    with pytest.raises(ValueError, match=r"bins must be >= 1"):
        break_down(one, bins=0)
    with pytest.raises(ValueError, match=r"unknown joint 'elbow'"):
        break_down(one, posture_joints=("j0", "elbow"))
    with pytest.raises(ValueError, match=r"unknown group 'joints'"):
        break_down(one).group("joints")


def test_hot_spots_need_a_margin_above_one_and_enough_samples():
    """Densities that scatter about 1 (a plant with sensor noise alone) are no hot spot."""
    rows = (
        BreakdownRow("motion", "hold", 71.0, 71.0 * 1.01, 71.0, 1.01, 710),
        BreakdownRow("load", "high_load", 11.5, 11.5, 10.0, 1.15, 100),
        BreakdownRow("posture", "cell", 15.0, 15.0, 10.0, 1.5, 99),
    )
    settings = PhaseSettings()
    noise = hand_breakdown(rows, settings)
    assert noise.hot_spots() == []
    assert "Hot spots: none, no concentration" in noise.to_markdown()
    assert f"density >= {settings.hot_spot_density:g}" in noise.to_markdown()
    # the margins are the settings' (named, recorded with the breakdown)
    looser = hand_breakdown(rows, replace(settings, hot_spot_density=1.1))
    assert [r.where for r in looser.hot_spots()] == ["high_load"]
    assert "Hot spots: load high_load (x1.15" in looser.to_markdown()
    fewer = hand_breakdown(rows, replace(settings, hot_spot_samples=99))
    assert [r.where for r in fewer.hot_spots()] == ["cell"]
    for bad in ({"hot_spot_density": 0.9}, {"hot_spot_samples": 0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            PhaseSettings(**bad)


def test_the_breakdown_as_json_has_every_row_and_null_for_empty_cells():
    n_samples = 200
    qd = np.zeros((n_samples, 2))
    qd[: n_samples // 2, 0] = 1.0  # half the samples move: constant velocity
    torque = np.tile([1.0, 2.0], (n_samples, 1))  # channel RMS 1 and 2 N m
    q = np.zeros((n_samples, 2))
    q[n_samples // 2 :] = 1.0  # two corners of the posture grid: the other cells are empty
    settings = PhaseSettings(hot_spot_samples=10)
    breakdown = break_down(_residuals(qd, torque=torque, q=q), settings=settings, bins=3)
    payload = breakdown.as_dict()
    text = json.dumps(payload, allow_nan=False)  # strict JSON: no NaN token
    assert json.loads(text) == payload
    assert payload["settings"] == asdict(settings)
    assert payload["samples"] == n_samples and payload["unit"] == "N m"
    assert [(r["group"], r["where"]) for r in payload["rows"]] == [
        (r.group, r.where) for r in breakdown.rows
    ]
    channel = {r["where"]: r for r in payload["rows"] if r["group"] == "channel"}
    assert channel["j0"]["rms"] == pytest.approx(1.0) and channel["j1"]["rms"] == pytest.approx(2.0)
    phases = {r["where"]: r for r in payload["rows"] if r["group"] == "motion"}
    assert phases["hold"]["samples"] == n_samples // 2
    assert phases["hold"]["rms"] == pytest.approx(np.sqrt((1.0 + 4.0) / 2))
    grid = payload["posture"]
    cells = np.asarray(breakdown.posture_samples)
    assert grid["samples"] == cells.tolist()
    assert (cells == 0).any()
    for i, k in np.ndindex(cells.shape):
        assert (grid["rms"][i][k] is None) == (cells[i, k] == 0)
    assert payload["hot_spots"] == [
        {"group": r.group, "where": r.where} for r in breakdown.hot_spots()
    ]
