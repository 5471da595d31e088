"""The withheld-effect benchmark and its PySINDy baseline, on a tiny scenario set."""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import replace

import pytest

import msarm.diagnose.bench as bench_module
from msarm.diagnose.baseline import sindy_baseline
from msarm.diagnose.bench import (
    EFFECT_CANDIDATES,
    BenchSettings,
    run_diagnosis_benchmark,
    summarise,
)
from msarm.errors import InputError
from msarm.io.code_version import code_fingerprint

TINY = BenchSettings(
    draws=1,
    n_null=1,
    n_train=2,
    n_holdout=1,
    duration=4.0,
    n_boot=0,
    effects=("winch_friction", "sensor_bias"),
    pairs=False,
)


@pytest.fixture(scope="module")
def report(arm, tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    return out, run_diagnosis_benchmark(arm, out, TINY)


def test_tiny_benchmark_names_the_withheld_effects(report):
    out, result = report
    names = [row["scenario"] for row in result["scenarios"]]
    assert names[0].startswith("null-")  # null plants first: they give the noise floor
    assert sorted(names[1:]) == ["sensor_bias-0", "winch_friction-0"]
    summary = result["summary"]
    for method in ("msarm", "sindy"):
        assert summary[method]["single_scenarios"] == 2
        assert summary[method]["null_scenarios"] == 1
        assert summary[method]["pair_scenarios"] == 0 and summary[method]["both_found"] is None
    ours = summary["msarm"]
    assert ours["top1_accuracy"] == 1.0
    assert ours["false_alarms"] == 0
    assert ours["mean_shrink"] > 0.3
    assert ours["mean_excess_shrink"] > ours["mean_shrink"]
    assert set(ours["shrink_by_effect"]) == {"winch_friction", "sensor_bias"}
    assert set(summary["noise_floor"]) >= {"joint", "drive"}
    # the ceiling is what a perfect diagnosis would reach: the diagnosis comes close to it,
    # not past it by more than the noise floor's own scatter between plants
    assert ours["mean_shrink"] - 0.02 < summary["shrink_ceiling"] < 1.0
    assert set(summary["shrink_ceiling_by_effect"]) == {"winch_friction", "sensor_bias"}
    # both methods' parameters against the plant's (bench_parameters): found near them
    for method in ("msarm", "sindy"):
        errors = summary[method]["parameter_error_by_effect"]
        assert set(errors) == {"winch_friction", "sensor_bias"}
        assert errors["winch_friction"]["coulomb"]["median"] < 0.1
        assert errors["sensor_bias"]["bias"]["median"] < 0.1
    # the timings are recorded (their definitions are checked on a fake clock in
    # test_the_timings_are_taken_at_the_marks_they_are_named_for); each includes reading the
    # logs, so they are marks of one monotonic clock in order: no comparison of two
    # separately measured durations, which a loaded machine could reorder
    for row in result["scenarios"]:
        times = [row["load_seconds"], row["msarm"]["selection_seconds"], row["msarm"]["seconds"]]
        assert all(math.isfinite(t) for t in times) and times[0] > 0
        assert times == sorted(times)
        assert row["sindy"]["seconds"] >= row["load_seconds"]
    assert 0 < ours["selection_seconds_per_scenario"] <= ours["seconds_per_scenario"]
    assert summary["sindy"]["selection_seconds_per_scenario"] is None
    assert (out / "confusion.png").read_bytes().startswith(b"\x89PNG")
    saved = json.loads((out / "results.json").read_text())
    assert saved["summary"] == json.loads(json.dumps(summary))


def test_the_timings_are_taken_at_the_marks_they_are_named_for(monkeypatch):
    """On a fake clock: ``load_seconds`` is reading the logs; the diagnosis's
    ``selection_seconds`` runs from the start (reading included) to the bootstrap's first
    progress line, its ``seconds`` to the end of the diagnosis; PySINDy's ``seconds`` is its
    own fit plus the same reading of the logs."""
    from types import SimpleNamespace

    now = [0.0]

    def advance(seconds):
        now[0] += seconds

    def load_data(model, train, held):
        advance(1.0)  # reading the logs: 1 s
        return "data"

    def select_effects(data, threshold, n_boot, seed, progress):
        advance(2.0)
        progress("step 1: screening")
        advance(3.0)
        progress("bootstrap of the chosen effects")  # the selection ends here: 1 + 2 + 3 s
        advance(4.0)
        progress("replaying the held-out runs")
        advance(5.0)
        return SimpleNamespace(names=(), selected=(), waterfall=[{}], groups=())

    def baseline(data, threshold, alpha):
        advance(7.0)
        return SimpleNamespace(
            names=(), contributions={}, gap_before={}, gap_after={}, parameters={}
        )

    monkeypatch.setattr(bench_module, "time", SimpleNamespace(perf_counter=lambda: now[0]))
    monkeypatch.setattr(bench_module, "load_data", load_data)
    monkeypatch.setattr(bench_module, "select_effects", select_effects)
    monkeypatch.setattr(bench_module, "sindy_baseline", baseline)
    row = bench_module._diagnose_scenario(None, [], [], TINY)
    assert row["load_seconds"] == 1.0
    assert row["msarm"]["selection_seconds"] == 6.0
    assert row["msarm"]["seconds"] == 15.0
    assert row["sindy"]["seconds"] == 8.0


def test_a_rerun_reuses_the_scores_and_rescore_recomputes(arm, report, monkeypatch):
    out, first = report

    def refuse(*args, **kwargs):
        raise AssertionError("diagnosed again")

    monkeypatch.setattr(bench_module, "_diagnose_scenario", refuse)
    again = run_diagnosis_benchmark(arm, out, TINY)
    assert again["summary"] == first["summary"]
    assert json.loads((out / "results.json").read_text())["code"] == code_fingerprint("diagnosis")
    with pytest.raises(AssertionError, match="diagnosed again"):
        run_diagnosis_benchmark(arm, out, TINY, rescore=True)
    # scores of another msarm version (or library version) are not reused
    monkeypatch.setattr(bench_module, "code_fingerprint", lambda scope: "f" * 64)
    with pytest.raises(AssertionError, match="diagnosed again"):
        run_diagnosis_benchmark(arm, out, TINY)


def test_scores_are_computed_from_the_names():
    rows = [
        {
            "effects": [],
            "msarm": {"names": [], "gap_before": {"drive": 0.3}, "seconds": 1.0},
            "sindy": {"names": ["inertia"], "gap_before": {"drive": 0.3}, "seconds": 1.0},
        },
        {
            "effects": ["winch_friction"],
            "msarm": {
                "names": ["winch_friction"],
                "gap_before": {"drive": 1.0},
                "gap_after": {"drive": 0.5},
                "seconds": 1.0,
            },
            "sindy": {
                "names": ["inertia", "winch_friction"],
                "gap_before": {"drive": 1.0},
                "gap_after": {"drive": 0.5},
                "seconds": 1.0,
            },
        },
    ]
    for row in rows:
        scenario = bench_module.Scenario(
            name="x", effects=tuple(row["effects"]), plant=None, draw=0
        )
        for method in ("msarm", "sindy"):
            row[method]["score"] = bench_module._score_one(scenario, tuple(row[method]["names"]))
    summary = summarise(rows)
    assert summary["msarm"]["top1_accuracy"] == 1.0 and summary["sindy"]["top1_accuracy"] == 0.0
    assert summary["msarm"]["false_alarms"] == 0 and summary["sindy"]["false_alarms"] == 1
    assert summary["msarm"]["mean_shrink"] == pytest.approx(0.5)
    # floor 0.3: 1 - sqrt((0.25 - 0.09) / (1 - 0.09))
    assert summary["msarm"]["mean_excess_shrink"] == pytest.approx(1 - (0.16 / 0.91) ** 0.5)
    assert summary["sindy"]["mean_extra_terms"] == 1.0
    # a perfect diagnosis leaves the 0.3 of noise out of 1.0: 70 %, whatever the method
    assert summary["shrink_ceiling"] == pytest.approx(0.7)
    assert summary["shrink_ceiling_by_effect"] == {"winch_friction": pytest.approx(0.7)}


def test_baseline_runs_on_the_same_data(arm, report):
    out, _ = report
    from msarm.diagnose.select import load_data

    logs = sorted((out / "logs" / "winch_friction-0").glob("*/log.parquet"))
    train = [p for p in logs if p.parent.name.startswith("train")]
    held = [p for p in logs if p.parent.name.startswith("holdout")]
    data = load_data(arm, train, held)
    result = sindy_baseline(data)
    # the library regression names the true effect; with no held-out check it ranks terms
    # fitted to the joint group's noise before it on these 4 s runs (the stick-slip capstan's
    # four correlated elements and a mass error: 0.55 and 0.32 of its model's energy, 0.09 for
    # winch friction)
    assert "winch_friction" in result.names
    assert "stribeck" in result.excluded and "capstan" in result.library
    # its coefficients, by term and parameter, in the parameters' units: the winch's Coulomb
    # friction near the plant's (what the benchmark compares, bench_parameters)
    assert list(result.parameters) == list(result.names)
    truth = json.loads((out / "logs" / "winch_friction-0" / "scenario.json").read_text())
    coulomb = result.parameters["winch_friction"]["coulomb[all]"]
    assert coulomb == pytest.approx(truth["parameters"]["winch_friction"]["coulomb"], rel=0.1)
    assert result.as_dict()["parameters"] == result.parameters
    assert result.group_shrink("drive") > 0.3
    with pytest.raises(InputError, match="threshold"):
        sindy_baseline(data, threshold=-1.0)


def test_bad_settings_are_refused(arm, tmp_path):
    with pytest.raises(InputError, match="effects"):
        run_diagnosis_benchmark(arm, tmp_path, BenchSettings(effects=("gremlins",)))
    with pytest.raises(InputError, match="draws"):
        run_diagnosis_benchmark(arm, tmp_path, BenchSettings(draws=0))
    with pytest.raises(InputError, match="sindy_threshold"):
        run_diagnosis_benchmark(arm, tmp_path, BenchSettings(sindy_threshold=float("nan")))
    with pytest.raises(InputError, match="sindy_alpha"):
        run_diagnosis_benchmark(arm, tmp_path, BenchSettings(sindy_alpha=-1.0))
    with pytest.raises(InputError, match=r"threshold: expected a value in \[0, 1\)"):
        run_diagnosis_benchmark(arm, tmp_path, BenchSettings(threshold=1.0))
    assert not any(tmp_path.iterdir())  # refused before anything was simulated


def test_the_baseline_s_threshold_reaches_it(arm, report, monkeypatch, tmp_path):
    out, first = report
    shutil.copytree(out / "logs", tmp_path / "logs")  # the same logs, scored anew
    seen = []

    def spy(data, threshold, alpha):
        seen.append((threshold, alpha))
        return sindy_baseline(data, threshold=threshold, alpha=alpha)

    monkeypatch.setattr(bench_module, "sindy_baseline", spy)
    settings = replace(TINY, sindy_threshold=1e6, sindy_alpha=0.2)
    strict = run_diagnosis_benchmark(arm, tmp_path, settings)
    assert len(seen) == len(strict["scenarios"]) and set(seen) == {(1e6, 0.2)}
    # a threshold no coefficient passes: the baseline names nothing, the diagnosis is as before
    assert all(not row["sindy"]["names"] for row in strict["scenarios"])
    assert strict["summary"]["msarm"]["top1_accuracy"] == first["summary"]["msarm"]["top1_accuracy"]


def test_a_diverged_scenario_is_reported_not_scored(arm, report, monkeypatch, tmp_path):
    out, _ = report
    real = bench_module.generate_logs

    def diverge_winch(model, scenario, train, held, root, *args, **kwargs):
        if scenario.name.startswith("winch_friction"):
            raise bench_module.ScenarioRunError(
                "diverged at 1.2 s", scenario.name, "train-0", root, 1.2
            )
        return real(model, scenario, train, held, root, *args, **kwargs)

    monkeypatch.setattr(bench_module, "generate_logs", diverge_winch)
    result = run_diagnosis_benchmark(arm, out, TINY, rescore=True)
    assert [f["scenario"] for f in result["failed"]] == ["winch_friction-0"]
    assert "winch_friction-0" not in [r["scenario"] for r in result["scenarios"]]
    assert result["summary"]["msarm"]["single_scenarios"] == 1


def test_the_cli_lists_every_effect_class_of_the_benchmark():
    from msarm.cli.bench import BENCH_EFFECTS

    assert BENCH_EFFECTS == tuple(EFFECT_CANDIDATES)


def test_a_rerun_says_what_it_reused_and_the_effects_order_does_not_matter(arm, report, tmp_path):
    """The same set of effects, in another order and repeated, is the same benchmark: reused
    (each order re-scored before), and the progress says so (a rerun printed old timings
    as if just measured)."""
    out, _ = report
    shutil.copytree(out, tmp_path / "b")  # other tests rescore the module's folder
    first = run_diagnosis_benchmark(arm, tmp_path / "b", TINY)
    lines = []
    shuffled = replace(TINY, effects=("sensor_bias", "winch_friction", "sensor_bias"))
    again = run_diagnosis_benchmark(arm, tmp_path / "b", shuffled, progress=lines.append)
    assert again["summary"] == first["summary"]
    assert lines == [
        f"3 of 3 scenarios reused from {tmp_path / 'b' / 'results.json'} (their times are "
        "those of the run that scored them; --rescore scores them again)"
    ]


def test_the_plot_of_replaced_results_goes_before_new_scores(arm, report, monkeypatch, tmp_path):
    """Killed after its first new scenario, a run with other settings left the old run's plot
    beside its own partial results."""
    out, _ = report
    shutil.copytree(out, tmp_path / "b")
    # the old run's plot (other tests may have rescored the module's folder and left none)
    (tmp_path / "b" / "confusion.png").write_bytes(b"the plot of the results replaced")

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(bench_module, "_diagnose_scenario", stop)
    with pytest.raises(KeyboardInterrupt), pytest.warns(bench_module.BenchCacheWarning):
        run_diagnosis_benchmark(arm, tmp_path / "b", replace(TINY, sindy_alpha=0.1))
    assert not (tmp_path / "b" / "confusion.png").exists()


def test_out_paths_that_cannot_be_written_are_refused_before_any_simulation(arm, tmp_path):
    (tmp_path / "a" / "results.json").mkdir(parents=True)
    with pytest.raises(InputError, match=r"results.json: it is a folder"):
        run_diagnosis_benchmark(arm, tmp_path / "a", TINY)
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "logs").write_text("not a folder")
    with pytest.raises(InputError, match=r"logs is a file; expected the folder"):
        run_diagnosis_benchmark(arm, tmp_path / "b", TINY)
    (tmp_path / "c" / "logs").mkdir(parents=True)
    (tmp_path / "c" / "logs" / "null-0").write_text("not a folder")
    with pytest.raises(InputError, match=r"null-0 is a file; expected the folder of null-0"):
        run_diagnosis_benchmark(arm, tmp_path / "c", TINY)
