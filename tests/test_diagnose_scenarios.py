"""Scenarios of the withheld-effect benchmark: plants, tasks and the resumable log cache."""

from __future__ import annotations

import json
import math
from dataclasses import fields, replace

import numpy as np
import pytest

import msarm.diagnose.scenarios as scenarios_module
from msarm.diagnose.scenarios import (
    DEFAULT_PAIRS,
    EFFECT_CLASSES,
    PARAMETER_RANGES,
    Scenario,
    ScenarioRunError,
    build_scenarios,
    generate_logs,
    noisy_base_plant,
    run_seed,
    scenario_tasks,
)
from msarm.errors import InputError
from msarm.io.atomic import write_json_atomic
from msarm.io.code_version import code_fingerprint
from msarm.io.logs import read_log
from msarm.plant.config import SensorNoiseConfig
from msarm.tasks.track import track as real_track

NOISE = SensorNoiseConfig()


def _blocks(effects: tuple[str, ...]) -> list[str]:
    """The EffectsConfig blocks a scenario with ``effects`` must switch on (noise always)."""
    names = {"sensor_noise"} | {e for e in effects if e != "sensor_bias"}
    return sorted(names)


def _in_range(value: float, effect: str, key: str) -> bool:
    low, high = PARAMETER_RANGES[effect][key]
    return low <= value <= high


def test_scenarios_are_deterministic_for_a_seed_and_differ_across_seeds():
    first, again, other = build_scenarios(0), build_scenarios(0), build_scenarios(1)
    assert len(first) == 3 * len(EFFECT_CLASSES) + len(DEFAULT_PAIRS) + 3
    assert first == again
    names = [s.name for s in first]
    assert len(set(names)) == len(names)
    assert "joint_friction-0" in names and "null-2" in names
    assert "joint_friction+winch_friction-0" in names
    assert [s.name for s in other] == names
    for a, b in zip(first, other, strict=True):
        assert a.seed != b.seed
        if a.effects and a.effects != ("delay",):  # the delay has only two variants
            assert a.parameters != b.parameters
    # a scenario's draw depends on its identity, not on how many others are built
    small = {s.name: s for s in build_scenarios(0, draws=1, pairs=[], n_null=1)}
    for scenario in first:
        if scenario.name in small:
            assert small[scenario.name] == scenario
    assert len({s.seed for s in first}) == len(first)


def test_each_single_effect_scenario_switches_on_only_its_effect_within_range():
    singles = build_scenarios(3, draws=4, pairs=[], n_null=0)
    assert {s.effects for s in singles} == {(e,) for e in EFFECT_CLASSES}
    for s in singles:
        (effect,) = s.effects
        fx = s.plant.effects
        assert sorted(fx.enabled()) == _blocks(s.effects), s.name
        assert s.plant.name == s.name
        assert set(s.parameters) == {effect}
        values = s.parameters[effect]
        noise = fx.sensor_noise
        # the noise is the default's, the bias is zero but for the sensor_bias class
        assert (noise.joint_noise, noise.tension_noise, noise.torque_noise) == (
            NOISE.joint_noise,
            NOISE.tension_noise,
            NOISE.torque_noise,
        )
        if effect == "sensor_bias":
            assert noise.tension_bias == values["tension_bias"] != 0.0
            assert _in_range(abs(values["tension_bias"]), effect, "tension_bias")
        else:
            assert noise.tension_bias == 0.0
        if effect == "sheath_friction":
            assert fx.sheath_friction.mu == values["mu"]
            assert _in_range(values["mu"], effect, "mu")
        elif effect in ("winch_friction", "joint_friction"):
            block = getattr(fx, effect)
            assert (block.coulomb, block.viscous) == (values["coulomb"], values["viscous"])
            assert _in_range(values["coulomb"], effect, "coulomb")
            assert _in_range(values["viscous"], effect, "viscous")
        elif effect == "elasticity":
            assert fx.elasticity.stiffness == values["stiffness"]
            assert _in_range(values["stiffness"], effect, "stiffness")
        elif effect == "cogging":
            assert fx.cogging.amplitude == values["amplitude"]
            assert fx.cogging.periods_per_revolution == 24
            assert _in_range(values["amplitude"], effect, "amplitude")
            assert fx.cogging.phase == values["phase"]
            assert 0.0 <= values["phase"] < 2 * math.pi
        elif effect == "delay":
            sensing, actuation = fx.delay.sensing_periods, fx.delay.actuation_periods
            assert (sensing, actuation) == (values["sensing_periods"], values["actuation_periods"])
            low, high = PARAMETER_RANGES["delay"]["total_periods"]
            assert low <= sensing + actuation <= high
            assert min(sensing, actuation) >= 0


def test_null_and_pair_scenarios():
    built = build_scenarios(0, draws=1, n_null=3)
    nulls = [s for s in built if not s.effects]
    assert [s.name for s in nulls] == ["null-0", "null-1", "null-2"]
    for s in nulls:
        assert s.plant == noisy_base_plant(s.name)
        assert s.plant.effects.enabled() == ["sensor_noise"]
        assert s.plant.effects.sensor_noise.tension_bias == 0.0
        assert s.parameters == {}
    # the null plants differ by their noise seeds
    assert len({run_seed(s, "train", 0) for s in nulls}) == 3
    pairs = [s for s in built if len(s.effects) == 2]
    assert [s.effects for s in pairs] == [tuple(p) for p in DEFAULT_PAIRS]
    for s in pairs:
        assert sorted(s.plant.effects.enabled()) == _blocks(s.effects)
        assert set(s.parameters) == set(s.effects)
        assert s.plant.effects.elasticity.enabled == ("elasticity" in s.effects)
    payload = json.loads(json.dumps(pairs[0].as_dict()))
    assert payload["name"] == pairs[0].name
    assert payload["effects"] == list(pairs[0].effects)
    assert payload["plant"]["effects"]["joint_friction"]["enabled"] is True


def test_tasks_are_deterministic_and_training_differs_from_held_out(arm):
    train, holdout = scenario_tasks(arm, n_train=4, n_holdout=2, duration=10.0, seed=0)
    train2, holdout2 = scenario_tasks(arm, n_train=4, n_holdout=2, duration=10.0, seed=0)
    assert train == train2 and holdout == holdout2
    assert (len(train), len(holdout)) == (4, 2)
    for task in holdout:
        assert all(task != other for other in train)
        assert all(not np.allclose(task.postures()[1:2], o.postures()[1:2]) for o in train)
    names = [t.name for t in train + holdout]
    assert len(set(names)) == len(names)
    other_train, _ = scenario_tasks(arm, seed=1)
    assert all(a != b for a, b in zip(train, other_train, strict=True))
    lower, upper = np.asarray(arm.joint_lower), np.asarray(arm.joint_upper)
    for task in train + holdout:
        assert task.duration == 10.0
        assert len(task.moves) >= 3
        postures = task.postures()
        assert np.all(postures[1:] > lower) and np.all(postures[1:] < upper)
        # every joint reverses its velocity at every move
        steps = np.diff(postures[1:], axis=0)
        assert np.all(steps[1:] * steps[:-1] < 0)


def test_generate_logs_writes_the_runs_and_resumes(arm, tmp_path, monkeypatch):
    scenario = next(s for s in build_scenarios(0, draws=1) if s.name == "joint_friction-0")
    train, holdout = scenario_tasks(arm, n_train=1, n_holdout=1, duration=2.0)
    messages = []
    train_logs, holdout_logs = generate_logs(
        arm, scenario, train, holdout, tmp_path, progress=lambda *a: messages.append(a)
    )
    folder = tmp_path / scenario.name
    assert train_logs == [folder / "train-0" / "log.parquet"]
    assert holdout_logs == [folder / "holdout-0" / "log.parquet"]
    assert [m[:2] for m in messages] == [(1, 2), (2, 2)]
    assert "ran" in messages[0][2] and scenario.name in messages[0][2]
    log = read_log(train_logs[0])
    assert log.columns["t"][-1] == pytest.approx(2.0, abs=0.01)
    assert log.metadata.extra["seed"] == run_seed(scenario, "train", 0)
    assert json.loads((folder / "scenario.json").read_text()) == scenario.as_dict()
    assert "joint_friction" in (folder / "train-0" / "config.yaml").read_text()
    mtimes = {p: p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}

    def refuse(*args, **kwargs):
        raise AssertionError("track must not run again")

    monkeypatch.setattr(scenarios_module, "track", refuse)
    messages.clear()
    again = generate_logs(
        arm, scenario, train, holdout, tmp_path, progress=lambda *a: messages.append(a)
    )
    assert again == (train_logs, holdout_logs)
    assert all("cached" in m[2] for m in messages)
    assert {p: p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()} == mtimes

    # a run whose config no longer matches is run again, and only that one
    calls = []

    def counting(model, task, settings, out_dir, **kwargs):
        calls.append(out_dir.name)
        return real_track(model, task, settings, out_dir, **kwargs)

    monkeypatch.setattr(scenarios_module, "track", counting)
    config = folder / "holdout-0" / "config.yaml"
    config.write_text(config.read_text().replace("seed:", "seed: 1 #"))
    generate_logs(arm, scenario, train, holdout, tmp_path)
    assert calls == ["holdout-0"]
    # runs made by other code (another msarm version or library version) are all run again
    calls.clear()
    monkeypatch.setattr(scenarios_module, "code_fingerprint", lambda scope: "f" * 64)
    generate_logs(arm, scenario, train, holdout, tmp_path)
    assert calls == ["train-0", "holdout-0"]
    monkeypatch.setattr(scenarios_module, "code_fingerprint", code_fingerprint)
    calls.clear()
    generate_logs(arm, scenario, train, holdout, tmp_path)
    assert calls == []  # the runs just made carry the fingerprint in use
    # logs recorded with another model file (its hash differs) are all run again
    generate_logs(replace(arm, sha256="0" * 64), scenario, train, holdout, tmp_path)
    assert calls == ["train-0", "holdout-0"]


def test_a_diverged_run_raises_naming_scenario_and_run(arm, tmp_path, monkeypatch):
    scenario = build_scenarios(0, draws=1, pairs=[], n_null=1)[-1]
    train, holdout = scenario_tasks(arm, n_train=1, n_holdout=1, duration=2.0)

    def diverging(model, task, settings, out_dir, **kwargs):
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "log.parquet").write_bytes(b"partial")
        (out_dir / "config.yaml").write_text("stub\n")
        write_json_atomic(out_dir / "metrics.json", {"diverged": {"time": 1.25, "message": "NaN"}})

    monkeypatch.setattr(scenarios_module, "track", diverging)
    with pytest.raises(ScenarioRunError, match=r"'null-0', run train-0.*1\.250") as info:
        generate_logs(arm, scenario, train, holdout, tmp_path)
    assert (info.value.scenario, info.value.run, info.value.time) == ("null-0", "train-0", 1.25)


def test_bad_input_is_refused_with_the_argument_named(arm, tmp_path):
    with pytest.raises(InputError, match="draws"):
        build_scenarios(draws=0)
    with pytest.raises(InputError, match="n_null"):
        build_scenarios(n_null=-1)
    with pytest.raises(InputError, match="seed"):
        build_scenarios(seed=-1)
    with pytest.raises(InputError, match=r"pairs\[1\].*'no_such_effect'"):
        build_scenarios(pairs=[("cogging", "delay"), ("cogging", "no_such_effect")])
    with pytest.raises(InputError, match=r"pairs\[0\].*two different"):
        build_scenarios(pairs=[("cogging", "cogging")])
    with pytest.raises(InputError, match=r"pairs\[1\].*repeats"):
        build_scenarios(pairs=[("cogging", "delay"), ("delay", "cogging")])
    with pytest.raises(InputError, match="n_train"):
        scenario_tasks(arm, n_train=0)
    with pytest.raises(InputError, match="duration"):
        scenario_tasks(arm, duration=1.0)
    scenario = build_scenarios(0, draws=1, pairs=[], n_null=1)[-1]
    train, _ = scenario_tasks(arm, n_train=1, n_holdout=1, duration=2.0)
    with pytest.raises(InputError, match="holdout_tasks"):
        generate_logs(arm, scenario, train, train, tmp_path)
    with pytest.raises(InputError, match="holdout_tasks"):
        generate_logs(arm, scenario, train, [], tmp_path)
    assert not any(tmp_path.iterdir())


def test_scenario_fields():
    assert [f.name for f in fields(Scenario)][:5] == [
        "name",
        "effects",
        "plant",
        "draw",
        "parameters",
    ]
