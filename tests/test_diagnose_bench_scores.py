"""The benchmark's scoring on hand-made answers: shrinks, the noise floor, top-1, pairs,
false alarms, extra terms, the ceiling. Every expected number is worked out by hand."""

from __future__ import annotations

import math

import pytest

from msarm.diagnose.bench import Scenario, _excess_shrink, _score_one, _shrink, summarise


def test_shrink_is_the_mean_over_the_groups_that_have_a_gap():
    before = {"joint": 2.0, "drive": 4.0, "length": 0.0}
    after = {"joint": 1.0, "drive": 1.0, "length": 0.0}
    # joint 1 - 1/2, drive 1 - 1/4; no gap on length, no 'elbow' group: both left out
    got = _shrink(before, after, ("joint", "drive", "length", "elbow"))
    assert got == pytest.approx((0.5 + 0.75) / 2)
    assert math.isnan(_shrink(before, after, ("length", "elbow")))


def test_excess_shrink_removes_the_noise_floor():
    before = {"joint": 5.0, "drive": 3.0, "length": 2.0}
    after = {"joint": 4.0, "drive": 1.0, "length": 1.0}
    floor = {"joint": 3.0, "drive": 3.0}
    # joint: 1 - sqrt((16 - 9) / (25 - 9)); drive: no gap above the floor; length: no floor
    got = _excess_shrink(before, after, ("joint", "drive", "length", "elbow"), floor)
    assert got == pytest.approx(1 - math.sqrt(7 / 16))
    # a diagnosis that goes below the floor has removed all of the excess: 1, not more
    assert _excess_shrink({"joint": 5.0}, {"joint": 2.0}, ("joint",), floor) == 1.0
    assert math.isnan(_excess_shrink(before, after, ("drive", "length"), floor))


def _scenario(*effects: str) -> Scenario:
    return Scenario(name="x", effects=tuple(effects), plant=None, draw=0)


def test_a_pair_is_found_only_when_both_effects_are_named():
    pair = _scenario("winch_friction", "cogging")
    assert _score_one(pair, ("winch_friction", "coulomb")) == {"kind": "pair", "both": False}
    assert _score_one(pair, ("coulomb", "motor_cogging", "winch_friction")) == {
        "kind": "pair",
        "both": True,
    }
    assert _score_one(pair, ()) == {"kind": "pair", "both": False}


def _answer(names, before, after, seconds, **score):
    return {
        "names": names,
        "gap_before": before,
        "gap_after": after,
        "seconds": seconds,
        "score": score,
    }


def _rows():
    nulls = [
        {
            "effects": [],
            "msarm": _answer(
                [], {"joint": 0.2, "drive": 0.4, "length": 0.1}, {}, 1.0, false_alarm=False
            ),
            "sindy": _answer(["inertia"], {"joint": 0.2, "drive": 0.4}, {}, 2.0, false_alarm=True),
        },
        {
            "effects": [],
            "msarm": _answer([], {"joint": 0.4, "drive": 0.2}, {}, 3.0, false_alarm=False),
            "sindy": _answer([], {"joint": 0.4, "drive": 0.2}, {}, 4.0, false_alarm=False),
        },
    ]
    singles = [
        {
            "effects": ["elasticity"],  # shows in 'length', which the null plants lack
            "msarm": _answer(
                ["elasticity"],
                {"joint": 1.0, "length": 0.5},
                {"joint": 1.0, "length": 0.25},
                5.0,
                top1=True,
            ),
            "sindy": _answer(
                ["coulomb", "elasticity"],
                {"joint": 1.0, "length": 0.5},
                {"joint": 1.0, "length": 0.25},
                6.0,
                top1=False,
            ),
        },
        {
            "effects": ["winch_friction"],  # msarm's gap is below the floor before the fit
            "msarm": _answer(["winch_friction"], {"drive": 0.2}, {"drive": 0.1}, 7.0, top1=True),
            "sindy": _answer([], {"drive": 0.5}, {"drive": 0.2}, 8.0, top1=False),
        },
        {
            "effects": ["winch_friction"],  # no gap at all: no shrink
            "msarm": _answer(["coulomb"], {"drive": 0.0}, {"drive": 0.0}, 9.0, top1=False),
            "sindy": _answer(
                ["winch_friction", "viscous"], {"drive": 0.0}, {"drive": 0.0}, 10.0, top1=True
            ),
        },
    ]
    pair = {
        "effects": ["winch_friction", "cogging"],
        "msarm": _answer(
            ["winch_friction", "coulomb"], {"drive": 1.0}, {"drive": 0.5}, 11.0, both=False
        ),
        "sindy": _answer(
            ["motor_cogging", "winch_friction"], {"drive": 1.0}, {"drive": 0.5}, 12.0, both=True
        ),
    }
    return [*nulls, *singles, pair]


def test_summary_of_hand_made_answers():
    summary = summarise(_rows())
    # the floor: mean over the null plants, of the groups every null plant has
    assert summary["noise_floor"] == pytest.approx({"joint": 0.3, "drive": 0.3})
    # ceiling: elasticity's length has no floor (noise-free): 1 - 0 / 0.5; winch friction's
    # 0.2 is under the floor: a perfect diagnosis leaves it, 0 (the no-gap draw: no value)
    assert summary["shrink_ceiling_by_effect"] == pytest.approx(
        {"elasticity": 1.0, "winch_friction": 0.0}
    )
    assert summary["shrink_ceiling"] == pytest.approx(0.5)
    ours, theirs = summary["msarm"], summary["sindy"]
    assert ours["single_scenarios"] == 3 and ours["pair_scenarios"] == 1
    assert ours["null_scenarios"] == 2
    assert ours["top1_accuracy"] == pytest.approx(2 / 3)
    assert theirs["top1_accuracy"] == pytest.approx(1 / 3)
    assert ours["top1_by_effect"] == pytest.approx({"elasticity": 1.0, "winch_friction": 0.5})
    assert ours["both_found"] == 0.0 and theirs["both_found"] == 1.0
    assert ours["false_alarms"] == 0 and theirs["false_alarms"] == 1
    # shrinks: msarm 0.5, 0.5, none; PySINDy 0.5, 1 - 0.2 / 0.5, none
    assert ours["mean_shrink"] == pytest.approx(0.5)
    assert theirs["mean_shrink"] == pytest.approx(0.55)
    assert ours["shrink_by_effect"] == pytest.approx({"elasticity": 0.5, "winch_friction": 0.5})
    assert theirs["shrink_by_effect"] == pytest.approx({"elasticity": 0.5, "winch_friction": 0.6})
    # excess: length has no floor, msarm's drive gap is not above it: none at all for msarm;
    # PySINDy's 0.2 after is under the 0.3 floor: all of the excess removed
    assert ours["mean_excess_shrink"] is None
    assert theirs["mean_excess_shrink"] == pytest.approx(1.0)
    # extra terms per scenario with effects (pairs included): msarm 0, 0, 1, 1; PySINDy 1, 0,
    # 1, 0
    assert ours["mean_extra_terms"] == pytest.approx(0.5)
    assert theirs["mean_extra_terms"] == pytest.approx(0.5)
    # time: over every scenario, the null plants included
    assert ours["seconds_per_scenario"] == pytest.approx(6.0)
    assert theirs["seconds_per_scenario"] == pytest.approx(7.0)
    assert ours["selection_seconds_per_scenario"] is None


def test_without_null_plants_there_is_no_floor_and_no_ceiling():
    rows = [r for r in _rows() if len(r["effects"]) == 1]
    summary = summarise(rows)
    assert summary["noise_floor"] == {}
    assert summary["shrink_ceiling"] is None
    assert summary["shrink_ceiling_by_effect"] == {}
    for method in ("msarm", "sindy"):
        assert summary[method]["null_scenarios"] == 0
        assert summary[method]["false_alarms"] == 0
        assert summary[method]["both_found"] is None and summary[method]["pair_scenarios"] == 0
        assert summary[method]["mean_excess_shrink"] is None  # no floor: no excess
