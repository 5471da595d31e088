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
    # joint: 1 - sqrt((16 - 9) / (25 - 9)); drive: no gap above the floor; length: no floor,
    # counted noise-free (as the ceiling counts it): 1 - 1 / 2; no 'elbow' group: left out
    got = _excess_shrink(before, after, ("joint", "drive", "length", "elbow"), floor)
    assert got == pytest.approx((1 - math.sqrt(7 / 16) + 0.5) / 2)
    # a diagnosis that goes below the floor has removed all of the excess: 1, not more
    assert _excess_shrink({"joint": 5.0}, {"joint": 2.0}, ("joint",), floor) == 1.0
    assert math.isnan(_excess_shrink(before, after, ("drive", "elbow"), floor))


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
    # excess: elasticity's length has no floor, counted noise-free: 1 - 0.25 / 0.5 for both;
    # msarm's drive gap is not above the floor (no value); PySINDy's 0.2 after is under the
    # 0.3 floor: all of the excess removed
    assert ours["mean_excess_shrink"] == pytest.approx(0.5)
    assert theirs["mean_excess_shrink"] == pytest.approx((0.5 + 1.0) / 2)
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


def _plant_answer(effect: str, truth: dict, named: dict) -> dict:
    return {"effects": [effect], "parameters": {effect: truth}, "msarm": {"parameters": named}}


def test_parameters_are_compared_with_the_plants_by_hand():
    from msarm.diagnose.bench_parameters import parameter_errors, summarise_parameter_errors

    sheath = _plant_answer("sheath_friction", {"mu": 0.1}, {"capstan": {"mu": 0.11, "eps": 0.002}})
    assert parameter_errors(sheath) == {"mu": pytest.approx(0.1)}
    winch = _plant_answer(
        "winch_friction",
        {"coulomb": 0.02, "viscous": 0.0002},
        {"winch_friction": {"coulomb[all]": 0.019, "viscous[all]": 0.0003}},
    )
    assert parameter_errors(winch) == {
        "coulomb": pytest.approx(0.05),
        "viscous": pytest.approx(0.5),
    }
    elastic = _plant_answer(
        "elasticity", {"stiffness": 4e4}, {"elasticity": {"compliance[all]": 2.4e-5}}
    )
    assert parameter_errors(elastic) == {"compliance": pytest.approx(0.04)}  # 1/k = 2.5e-5
    cogging = _plant_answer(
        "cogging",
        {"amplitude": 0.01},
        {"motor_cogging": {"cogging_a[all]": 0.006, "cogging_b[all]": -0.008}},
    )
    assert parameter_errors(cogging) == {"amplitude": pytest.approx(0.0)}  # hypot = 0.01
    bias = _plant_answer("sensor_bias", {"tension_bias": -2.0}, {"sensor": {"bias[all]": -1.9}})
    assert parameter_errors(bias) == {"bias": pytest.approx(0.05)}
    delay = _plant_answer(
        "delay",
        {"sensing_periods": 1, "actuation_periods": 1},
        {"command_delay": {"w[1]": 0.2, "w[2]": 0.9, "w[3]": 0.0, "w[4]": 0.0}},
    )
    assert parameter_errors(delay) == {"delay": pytest.approx(0.0)}  # 0.2 + 1.8 = 2 samples
    # joint friction: the steady curve c + b v at 0.05, 0.2, 0.5 rad/s; a Coulomb + viscous
    # answer of the plant's law is exact, a Dahl level on top adds 0.1 N m at every speed
    truth = {"coulomb": 0.2, "viscous": 0.1}
    exact = {"coulomb": {f"coulomb[{j}]": 0.2 for j in range(4)}}
    exact["viscous"] = {f"viscous[{j}]": 0.1 for j in range(4)}
    assert parameter_errors(_plant_answer("joint_friction", truth, exact))["friction_curve"] == (
        pytest.approx(0.0, abs=1e-15)
    )
    biased = {**exact, "dahl": {f"coulomb[{j}]": 0.1 for j in range(4)}}
    curve = [0.2 + 0.1 * v for v in (0.05, 0.2, 0.5)]
    expected = 0.1 / math.sqrt(sum(c * c for c in curve) / 3)
    got = parameter_errors(_plant_answer("joint_friction", truth, biased))["friction_curve"]
    assert got == pytest.approx(expected)
    # the Stribeck law at its own speeds: s at rest falling to c, plus its viscous part
    stribeck = {
        "stribeck": {
            k: v
            for j in range(4)
            for k, v in {
                f"coulomb[{j}]": 0.2,
                f"static[{j}]": 0.2,
                f"stribeck_velocity[{j}]": 0.1,
                f"viscous[{j}]": 0.1,
            }.items()
        }
    }
    assert parameter_errors(_plant_answer("joint_friction", truth, stribeck))["friction_curve"] == (
        pytest.approx(0.0, abs=1e-15)
    )
    # not named: None, counted in the summary as not compared
    missed = _plant_answer(
        "sheath_friction", {"mu": 0.1}, {"capstan_hysteresis": {"a[mu=0.03]": 1.0}}
    )
    assert parameter_errors(missed) == {"mu": None}
    assert parameter_errors({"effects": [], "parameters": {}, "msarm": {"parameters": {}}}) == {}
    # the baseline's answer is read from its own entry
    sindy = {**winch, "sindy": {"parameters": {"winch_friction": {"coulomb[all]": 0.03}}}}
    assert parameter_errors(sindy, "sindy") == {"coulomb": pytest.approx(0.5), "viscous": None}
    summary = summarise_parameter_errors([sheath, missed, winch])
    assert summary["sheath_friction"]["mu"] == {
        "median": pytest.approx(0.1),
        "max": pytest.approx(0.1),
        "compared": 1,
        "scenarios": 2,
    }
    assert summary["winch_friction"]["viscous"]["median"] == pytest.approx(0.5)


def test_the_confusion_columns_put_the_right_answers_on_the_diagonal():
    from msarm.diagnose.bench import confusion_columns

    truths = ["sheath_friction", "winch_friction", "elasticity", "null"]
    named = ["sheath_stretch", "capstan", "winch_friction", "coulomb", "none", "dahl"]
    # each row's candidates named, in the registry's order; elasticity was never named
    # first: its column is there, empty; then the wrong answers, alphabetically
    assert confusion_columns(truths, named) == [
        "capstan",
        "sheath_stretch",
        "winch_friction",
        "elasticity",
        "none",
        "coulomb",
        "dahl",
    ]
    # "none" named in an effect's row only: a wrong answer, after the others
    assert confusion_columns(["cogging"], ["none", "viscous"]) == [
        "motor_cogging",
        "viscous",
        "none",
    ]


def test_the_confusion_plot_orders_its_columns_and_names_its_scenarios(tmp_path, monkeypatch):
    import msarm.plots
    from msarm.diagnose.bench import plot_benchmark

    def scenario(effects, ours, theirs):
        return {"effects": effects, "msarm": {"names": ours}, "sindy": {"names": theirs}}

    report = {
        "scenarios": [
            scenario(["delay"], ["command_delay"], ["viscous"]),
            scenario(["cogging"], ["motor_cogging"], []),
            scenario([], [], ["coulomb"]),
            scenario(["delay", "cogging"], ["command_delay"], []),
        ],
        "summary": {
            m: {"top1_accuracy": 0.5, "false_alarms": 0, "null_scenarios": 1}
            for m in ("msarm", "sindy")
        },
    }
    figures = []
    save = msarm.plots.save_figure
    monkeypatch.setattr(
        msarm.plots, "save_figure", lambda fig, path: figures.append(fig) or save(fig, path)
    )
    plot_benchmark(report, tmp_path / "confusion.png")
    (fig,) = figures
    rows = [t.get_text() for t in fig.axes[0].get_yticklabels()]
    assert rows == ["cogging", "delay", "null"]
    for ax in fig.axes[:2]:
        columns = [t.get_text() for t in ax.get_xticklabels()]
        assert columns[:3] == ["motor_cogging", "command_delay", "none"]
    assert "3 single-effect and null scenarios" in fig._suptitle.get_text()
    assert "two-effect scenarios left out: 1" in fig._suptitle.get_text()
