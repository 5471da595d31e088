"""msarm.io.config: YAML into frozen dataclasses, with every mistake named."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pytest
import yaml

from msarm.errors import ConfigError, MsarmError
from msarm.io.config import (
    MISSING,
    config_to_dict,
    dump_config,
    join_differences,
    load_config,
    value_differences,
    write_config,
)


@dataclass(frozen=True)
class Gains:
    kp: float
    kd: float = 0.5
    per_joint: tuple[float, ...] = (1.0, 2.0)


@dataclass(frozen=True)
class Limits:
    low: float = 0.0
    high: float = 10.0

    def __post_init__(self) -> None:
        if self.low > self.high:
            raise ValueError(f"low {self.low} > high {self.high}")


@dataclass(frozen=True)
class Experiment:
    name: str
    gains: Gains
    repeats: int = 3
    verbose: bool = False
    note: str | None = None
    pair: tuple[int, float] = (1, 2.0)
    mode: Literal["fast", "exact"] = "fast"
    cables: dict[str, Limits] = field(default_factory=dict)
    limits: Limits = field(default_factory=Limits)


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "exp.yaml"
    path.write_text(text)
    return path


def test_nested_and_dict_of_dataclass_config_from_yaml(tmp_path):
    path = _write(
        tmp_path,
        """
name: run-1
gains: {kp: 3, per_joint: [1, 2.5, 3]}
repeats: 5
note: null
pair: [4, 5]
mode: exact
cables:
  biceps: {low: 1.0, high: 2e1}
  triceps: {}
limits: {high: 3.5}
""",
    )
    cfg = load_config(path, Experiment)
    assert cfg == Experiment(
        name="run-1",
        gains=Gains(kp=3.0, per_joint=(1.0, 2.5, 3.0)),
        repeats=5,
        pair=(4, 5.0),
        mode="exact",
        cables={"biceps": Limits(1.0, 20.0), "triceps": Limits()},
        limits=Limits(high=3.5),
    )
    assert isinstance(cfg.gains.kp, float) and isinstance(cfg.gains.per_joint, tuple)


def test_defaults_fill_missing_keys_and_mapping_source_works():
    cfg = load_config({"name": "a", "gains": {"kp": 1.0}}, Experiment)
    assert cfg.repeats == 3 and cfg.limits == Limits() and cfg.cables == {}


def test_unknown_key_names_file_path_and_valid_keys(tmp_path):
    path = _write(tmp_path, "name: a\ngains: {kp: 1.0, kpp: 2.0}\n")
    with pytest.raises(ConfigError) as info:
        load_config(path, Experiment)
    msg = str(info.value)
    assert str(path) in msg and "'gains.kpp'" in msg
    assert "kp, kd, per_joint" in msg and "did you mean 'kp'" in msg


def test_unknown_key_inside_dict_of_dataclass(tmp_path):
    path = _write(tmp_path, "name: a\ngains: {kp: 1}\ncables: {biceps: {lo: 1}}\n")
    with pytest.raises(ConfigError, match=r"'cables\.biceps\.lo'.*low, high"):
        load_config(path, Experiment)


def test_missing_key_is_named(tmp_path):
    path = _write(tmp_path, "name: a\ngains: {kd: 1.0}\n")
    with pytest.raises(ConfigError, match=r"exp\.yaml: missing key 'gains\.kp'"):
        load_config(path, Experiment)
    with pytest.raises(ConfigError, match="missing key 'gains'"):
        load_config({"name": "a"}, Experiment)


@pytest.mark.parametrize(
    ("text", "key", "expected"),
    [
        ("gains: {kp: fast}", "gains.kp", "a number"),
        ("gains: {kp: true}", "gains.kp", "a number"),
        ("gains: {kp: 1}\nrepeats: 2.5", "repeats", "an integer"),
        ("gains: {kp: 1}\nverbose: 1", "verbose", "a boolean"),
        ("gains: {kp: 1, per_joint: 3}", "gains.per_joint", "a list"),
        ("gains: {kp: 1, per_joint: [1, x]}", r"gains.per_joint\[1\]", "a number"),
        ("gains: {kp: 1}\npair: [1]", "pair", "a list of 2 items"),
        ("gains: {kp: 1}\nmode: slow", "mode", "one of 'fast', 'exact'"),
        ("gains: 3", "gains", "a mapping"),
        ("gains: {kp: 1}\ncables: {biceps: 2}", "cables.biceps", "a mapping"),
    ],
)
def test_wrong_type_names_key_expected_type_and_value(tmp_path, text, key, expected):
    path = _write(tmp_path, "name: a\n" + text + "\n")
    with pytest.raises(ConfigError, match=f"'{key}'.*{expected}") as info:
        load_config(path, Experiment)
    assert str(path) in str(info.value)


def test_post_init_error_is_reported_with_its_key(tmp_path):
    path = _write(tmp_path, "name: a\ngains: {kp: 1}\nlimits: {low: 5, high: 1}\n")
    with pytest.raises(ConfigError, match=r"key 'limits'.*low 5.0 > high 1.0"):
        load_config(path, Experiment)


def test_missing_file_bad_yaml_and_non_mapping(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yaml", Experiment)
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(_write(tmp_path, "a: [1, 2\n"), Experiment)
    with pytest.raises(ConfigError, match="expected a mapping"):
        load_config(_write(tmp_path, "- 1\n- 2\n"), Experiment)


@pytest.mark.parametrize(
    ("text", "line", "key"),
    [
        ("name: a\ngains: {kp: 1}\nname: b\n", 3, "name"),
        ("name: a\ngains:\n  kp: 1\n  kd: 0.2\n  kp: 2\n", 5, "gains.kp"),
        (
            "name: a\ngains: {kp: 1}\ncables:\n  biceps: {low: 0.2, low: 0.02}\n",
            4,
            "cables.biceps.low",
        ),
        ("name: a\ngains: {kp: 1}\nx:\n  - {a: 1}\n  - {a: 1, 'a': 2}\n", 5, r"x\[1\]\.a"),
    ],
)
def test_a_key_given_twice_in_one_mapping_is_refused(tmp_path, text, line, key):
    path = _write(tmp_path, text)
    with pytest.raises(
        ConfigError,
        match=rf"exp\.yaml: line {line}: key '{key}' appears twice in one mapping "
        r"\(first at line \d+\); expected each key once",
    ):
        load_config(path, Experiment)


def test_merge_keys_may_be_overridden_and_anchors_still_work(tmp_path):
    path = _write(
        tmp_path,
        """
name: a
gains: &g {kp: 1, kd: 0.1}
cables:
  biceps: &wide {low: 1.0, high: 20}
  triceps:
    <<: *wide
    high: 5
  deltoid:
    <<: [*wide, {low: 2.0}]
    low: 3.0
limits: *wide
""",
    )
    cfg = load_config(path, Experiment)
    assert cfg.gains == Gains(kp=1.0, kd=0.1)
    assert cfg.cables == {
        "biceps": Limits(1.0, 20.0),
        "triceps": Limits(1.0, 5.0),
        "deltoid": Limits(3.0, 20.0),
    }
    assert cfg.limits == Limits(1.0, 20.0)


def test_a_plant_file_with_a_repeated_effect_key_is_refused(tmp_path):
    from msarm.plant.config import PlantConfig

    path = tmp_path / "plant.yaml"
    path.write_text("name: p\neffects:\n  sheath_friction:\n    mu: 0.2\n    mu: 0.02\n")
    with pytest.raises(
        ConfigError,
        match=r"plant\.yaml: line 5: key 'effects\.sheath_friction\.mu' appears twice",
    ):
        load_config(path, PlantConfig)


def test_config_error_is_msarm_and_value_error():
    assert issubclass(ConfigError, MsarmError) and issubclass(ConfigError, ValueError)


def test_round_trip_write_then_load_is_equal(tmp_path):
    cfg = Experiment(
        name="x",
        gains=Gains(kp=1e-7, kd=0.1 + 0.2, per_joint=(1.0 / 3.0, 2e300)),
        note="hello",
        cables={"biceps": Limits(0.5, 1.5)},
    )
    path = write_config(cfg, tmp_path / "sub" / "config.yaml")
    assert path.exists() and load_config(path, Experiment) == cfg
    assert [p.name for p in path.parent.iterdir()] == ["config.yaml"]  # no temp file left
    data = yaml.safe_load(path.read_text())
    assert data == config_to_dict(cfg)
    assert data["gains"]["per_joint"] == [1.0 / 3.0, 2e300]


def test_write_is_atomic_when_serialisation_fails(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text("old: 1\n")
    with pytest.raises(TypeError):
        write_config({"bad": object()}, path)
    assert path.read_text() == "old: 1\n"
    assert [p.name for p in tmp_path.iterdir()] == ["config.yaml"]


def test_write_leaves_old_file_when_rename_fails(tmp_path, monkeypatch):
    path = tmp_path / "config.yaml"
    path.write_text("old: 1\n")

    def fail(*args):
        raise OSError("disk full")

    monkeypatch.setattr("msarm.io.atomic.os.replace", fail)
    with pytest.raises(OSError, match="disk full"):
        write_config(Limits(), path)
    assert path.read_text() == "old: 1\n"
    assert [p.name for p in tmp_path.iterdir()] == ["config.yaml"]


def test_plant_and_controller_configs_round_trip(tmp_path):
    from msarm.control.arm_controller import ArmControllerConfig
    from msarm.plant.config import DEFAULT_PLANT, IDEAL_PLANT, PlantConfig

    for cfg in (DEFAULT_PLANT, IDEAL_PLANT):
        assert load_config(write_config(cfg, tmp_path / "p.yaml"), PlantConfig) == cfg
    ctrl = ArmControllerConfig()
    assert load_config(write_config(ctrl, tmp_path / "c.yaml"), ArmControllerConfig) == ctrl
    assert "kp: [" in dump_config(ctrl)


def test_exponent_without_dot_is_a_float(tmp_path):
    cfg = load_config(_write(tmp_path, "name: a\ngains: {kp: 1e-4, kd: -2E+3}\n"), Experiment)
    assert cfg.gains.kp == 1e-4 and cfg.gains.kd == -2000.0


def test_atomic_writes_get_ordinary_permissions(tmp_path):
    import os
    import stat

    from msarm.io.atomic import write_bytes_atomic

    path = write_bytes_atomic(tmp_path / "report.md", b"hello")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask


@pytest.mark.parametrize(
    ("text", "key", "message"),
    [
        ("effects: {sheath_friction: {mu: .nan}}", "effects.sheath_friction", "mu must be"),
        ("winch: {drum_radius: 0}", "winch", "drum_radius must be a finite value > 0"),
        ("winch: {drum_radius: .inf}", "winch", "drum_radius must be a finite value > 0"),
        ("effects: {elasticity: {stiffness: -5}}", "effects.elasticity", "stiffness must be"),
        ("effects: {sensor_noise: {tension_noise: -0.3}}", "effects.sensor_noise", ">= 0"),
        ("effects: {delay: {sensing_periods: -1}}", "effects.delay", "an integer >= 0"),
        ("effects: {winch_friction: {smoothing_speed: 0}}", "effects.winch_friction", "> 0"),
        ("effects: {cogging: {periods_per_revolution: 0}}", "effects.cogging", "integer >= 1"),
        ("name: ''", "top level", "name must be a non-empty string"),
    ],
)
def test_a_plant_value_that_would_make_the_run_wrong_is_refused(tmp_path, text, key, message):
    from msarm.plant import PlantConfig

    path = tmp_path / "plant.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as caught:
        load_config(path, PlantConfig)
    assert f"{path}: " in str(caught.value) and key in str(caught.value)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("rate_hz: 0", "rate_hz must be a finite value > 0"),
        ("velocity_cutoff_hz: -1", "velocity_cutoff_hz must be a finite value > 0"),
        ("velocity_cutoff_hz: 125", r"below the Nyquist frequency rate_hz / 2 = 125 Hz"),
        ("{rate_hz: 100, velocity_cutoff_hz: 60}", r"rate_hz / 2 = 50 Hz.*got 60"),
        ("kp: [.nan, 60, 30, 30]", "kp must be a list of finite gains >= 0"),
        ("ki: [1, 1, -1, 1]", "ki must be a list of finite gains >= 0"),
        ("integral_limit: -3", "integral_limit must be a finite value >= 0"),
    ],
)
def test_a_bad_controller_value_is_refused(tmp_path, text, message):
    from msarm.control import ArmControllerConfig

    path = tmp_path / "controller.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(path, ArmControllerConfig)


def test_a_plant_file_without_a_name_is_named_after_it(tmp_path):
    from msarm.cli.common import resolve_plant
    from msarm.errors import InputError

    path = tmp_path / "cogging_on.yaml"
    path.write_text("effects: {cogging: {enabled: true}}")
    assert resolve_plant(str(path)).name == "cogging_on"  # not "default": not its folder
    path.write_text("name: mine\neffects: {cogging: {enabled: true}}")
    assert resolve_plant(str(path)).name == "mine"
    with pytest.raises(InputError, match="plant file not found"):
        resolve_plant(str(tmp_path / "missing.yaml"))
    with pytest.raises(InputError, match="unknown plant 'nope'"):
        resolve_plant("nope")
    # a name that would misplace or overwrite run folders
    path.write_text("name: ../../elsewhere")
    with pytest.raises(ConfigError, match="name must be a simple identifier"):
        resolve_plant(str(path))
    path.write_text("name: ideal")
    with pytest.raises(InputError, match="named 'ideal', the name of a preset"):
        resolve_plant(str(path))
    spaced = tmp_path / "my plant.yaml"
    spaced.write_text("effects: {cogging: {enabled: true}}")
    with pytest.raises(InputError, match="give the file a 'name' key or rename the file"):
        resolve_plant(str(spaced))
    # '=': cdpr run folders end in -KEY=VALUE per option (lab-delta=0.5 is lab's delta=0.5)
    equals = tmp_path / "lab-delta=0.5.yaml"
    equals.write_text("effects: {cogging: {enabled: true}}")
    with pytest.raises(InputError, match=r"without '=', got 'lab-delta=0.5'.*rename the file"):
        resolve_plant(str(equals))
    path.write_text("name: lab-delta=0.5")
    with pytest.raises(ConfigError, match=r"without '='.*--option delta=0.5"):
        resolve_plant(str(path))


def test_a_runs_config_gives_its_plant_back(tmp_path):
    from dataclasses import replace

    from msarm.cli.cdpr import _plant as resolve_cdpr_plant
    from msarm.cli.common import resolve_plant
    from msarm.errors import InputError
    from msarm.io.config import config_to_dict
    from msarm.plant.cdpr_config import DEFAULT_CDPR_PLANT
    from msarm.plant.config import DEFAULT_PLANT

    def run_config(plant, name="config.yaml"):
        path = tmp_path / name
        record = {"task": "reach", "seed": 3, "plant": config_to_dict(plant), "controller": {}}
        path.write_text(yaml.safe_dump(record))
        return str(path)

    assert resolve_plant(run_config(DEFAULT_PLANT)) is DEFAULT_PLANT  # the preset itself
    assert resolve_cdpr_plant(run_config(DEFAULT_CDPR_PLANT)) is DEFAULT_CDPR_PLANT
    mine = replace(DEFAULT_PLANT, name="mine", timestep=0.0005)
    assert resolve_plant(run_config(mine)) == mine
    # a changed plant that kept a preset's name would overwrite the preset's runs
    with pytest.raises(InputError, match="named 'default', the name of a preset"):
        resolve_plant(run_config(replace(DEFAULT_PLANT, timestep=0.0005)))
    broken = tmp_path / "broken.yaml"
    broken.write_text("task: reach\nplant: {name: mine, timestepp: 0.001}\n")
    with pytest.raises(ConfigError, match=r"broken\.yaml \(its 'plant' section\): unknown key"):
        resolve_plant(str(broken))


def test_an_output_folder_that_is_a_file_is_refused_up_front(tmp_path):
    from msarm.cli.common import output_folder
    from msarm.errors import InputError

    taken = tmp_path / "taken"
    taken.write_text("")
    with pytest.raises(InputError, match="is a file; expected a folder"):
        output_folder(taken)
    with pytest.raises(InputError, match="cannot create the folder"):
        output_folder(taken / "inside")
    assert output_folder(tmp_path / "a" / "b").is_dir()


def test_value_differences_name_each_differing_leaf_by_its_path():
    before = {"a": 1, "b": {"c": True, "d": [1.0, 2.0]}, "e": [{"f": "x"}], "gone": 3}
    after = {"a": 1.0, "b": {"c": 1, "d": [1.0, 2.5]}, "e": [{"f": "y"}], "new": None}
    assert value_differences(before, after) == [
        ("gone", 3, MISSING),  # keys only in before first
        ("b.c", True, 1),  # a bool is not the number 1 here
        ("b.d", [1.0, 2.0], [1.0, 2.5]),  # a list of numbers is one leaf
        ("e[0].f", "x", "y"),  # a list of mappings: item by item
        ("new", MISSING, None),
    ]  # and 1 == 1.0: an int and a float of one value are alike
    assert value_differences(before, before, "spec") == []
    assert value_differences({"k": 1}, {"k": 2}, "spec") == [("spec.k", 1, 2)]
    assert join_differences(["a", "b", "c"], 2) == "a; b; and 1 more"
    assert join_differences(["a", "b"], 2) == "a; b"


def test_configs_built_in_python_name_a_word_given_for_a_number():
    """A bare TypeError or numpy ValueError that did not name the field, before."""
    from msarm.cdpr import WinchParameters
    from msarm.compensation.network import NetworkConfig
    from msarm.control import ArmControllerConfig
    from msarm.errors import InputError

    cases = (
        (lambda: ArmControllerConfig(kp="abc"), r"kp must be a list of finite gains >= 0"),
        (lambda: NetworkConfig(learning_rate="x"), "learning_rate must be a number, got 'x'"),
        (lambda: WinchParameters(drum_radius="0.02"), "drum_radius must be a number, got '0.02'"),
        (lambda: WinchParameters(drum_radius=None), "drum_radius must be a number, got None"),
    )
    for build, message in cases:
        with pytest.raises(InputError, match=message):
            build()


def test_configs_built_in_python_refuse_a_switch_that_is_no_bool_and_a_block_no_dataclass():
    """``enabled="false"`` (a non-empty string: true) switched the effect on, and a dict
    for a block skipped its checks, before 2026-11-29."""
    from dataclasses import replace

    from msarm.compensation.sheath import SheathSpec
    from msarm.control import ArmControllerConfig
    from msarm.errors import InputError
    from msarm.plant import IDEAL_PLANT
    from msarm.plant.config import DelayConfig, EffectsConfig, PlantConfig

    sheath = IDEAL_PLANT.effects.sheath_friction
    cases = (
        (lambda: replace(sheath, enabled="false"), "enabled must be true or false"),
        (lambda: ArmControllerConfig(activation_dynamics="no"), "activation_dynamics must be"),
        (lambda: SheathSpec(enabled=1), "enabled must be true or false .* got 1"),
        (lambda: PlantConfig(winch={"drum_radius": 0.0}), "winch must be a WinchConfig"),
        (lambda: EffectsConfig(delay={}), "delay must be a DelayConfig"),
        (lambda: PlantConfig(timestep="0.001"), "timestep must be a number, got '0.001'"),
        (lambda: DelayConfig(sensing_periods=10**11), "at most 10000 control periods"),
    )
    for build, message in cases:
        with pytest.raises(InputError if "periods" not in message else ValueError, match=message):
            build()
    assert replace(sheath, enabled=np.True_).enabled  # numpy's bool is one


def test_an_integer_too_large_for_a_float_is_named(tmp_path):
    """An OverflowError with a traceback before."""
    from msarm.plant.config import PlantConfig

    path = tmp_path / "plant.yaml"
    path.write_text("name: huge\neffects:\n  elasticity: {stiffness: 1" + "0" * 400 + "}\n")
    with pytest.raises(ConfigError, match=r"key 'effects.elasticity.stiffness' expects a finite"):
        load_config(path, PlantConfig)


@dataclass(frozen=True)
class _Gains:
    kp: float = 1.0
    ki: float = 2.0


@dataclass(frozen=True)
class _Tuned:
    gains: _Gains = field(default_factory=lambda: _Gains(kp=90.0, ki=640.0))


def test_a_block_given_in_part_keeps_the_rest_of_its_enclosing_default(tmp_path):
    """A recipe that set one gain of its controller ran the others at the controller class's
    untuned defaults (kp 60, ki 40) instead of the recipe's (90, 640), without a word."""
    from msarm.compensation.pipeline import TUNED_CONTROLLER, CompensatorRecipe

    path = tmp_path / "c.yaml"
    path.write_text("gains: {kp: 5}\n")
    assert load_config(path, _Tuned) == _Tuned(_Gains(kp=5.0, ki=640.0))
    path.write_text("network: {max_epochs: 100}\ncontroller: {kd: [4.0, 4.0, 1.5, 1.5]}\n")
    recipe = load_config(path, CompensatorRecipe)
    assert recipe.controller.kp == TUNED_CONTROLLER.kp
    assert recipe.controller.ki == TUNED_CONTROLLER.ki
    assert recipe.controller.integral_limit == TUNED_CONTROLLER.integral_limit
    assert recipe.network.patience == CompensatorRecipe().network.patience
    assert recipe.network.max_epochs == 100
