"""Scenarios of the withheld-effect benchmark (issue 7): plants with hidden effects, and logs.

A :class:`Scenario` is a simulated plant that differs from the nominal model by one benchmark
effect class (:data:`EFFECT_CLASSES`), by a pair of them, or by nothing at all (a *null*
plant). Every scenario plant is :data:`~msarm.plant.IDEAL_PLANT` with sensor noise switched on
at its default standard deviations (and no load-cell bias), so every scenario, null ones
included, has realistic noise; then its effect(s) are switched on with parameters drawn
uniformly over :data:`PARAMETER_RANGES` (plausible ranges around the default plant's values).

Effect classes and what each switches on (everything else stays as in the ideal plant: rigid
cables, perfect drives):

- ``sheath_friction``: capstan friction in the sheaths. With rigid cables the plant uses the
  smooth capstan law ``T_i = T_m exp(-mu Theta tanh(v_in / v_s))``.
- ``winch_friction``: Coulomb + viscous friction on the winches. With rigid cables the drive
  renders ``T_m = T_cmd + tau_w / (r (1 + K))``: the friction torque ``tau_w`` changes the
  motor-side tension and shows between the motor torque and ``r`` times the load cell.
- ``elasticity``: elastic, slackening cables (this also brings in the winch dynamics, the
  rotor inertia and the rope's damping, which are part of the plant's elastic cable model).
  Stiffness 3.5e4-8e4 N/m, damping at its default (40 N s/m): on its own (without the
  stiction of sheath friction, which damps the default plant) the elastic plant under the
  default controller is unstable below about 2.7e4 N/m (the winch-cable mode, about
  25-30 Hz with a damping ratio of a few percent, oscillates with joint errors of 2 rad and
  tensions of thousands of newtons), the default plant's 2e4 N/m included.
- ``joint_friction``: Coulomb + viscous friction at every joint (MuJoCo).
- ``cogging``: cogging torque on each winch, ``A sin(N theta + phi)`` (rigid cables: through
  the drive as for winch friction).
- ``sensor_bias``: a constant load-cell bias (``sensor_noise.tension_bias``), drawn non-zero.
  It changes no motion: the drives close their loop on the true tension inside the plant and
  the controller does not read the load cells, so it shows only in the logged
  ``tension_motor`` readings (and against ``motor_torque / r``).
- ``delay``: sensing or actuation late by one control period (4 ms at 250 Hz), which of the
  two drawn. With 2 periods in total (sensing, actuation or one each) the default controller
  falls into a limit cycle on the scenario tasks (joint errors near 0.9 rad, tensions near
  890 N), with 3 already on a single slow move, so the range stops at 1.

Each single effect acts on its own (checked against the ideal plant with the default
controller; see :mod:`msarm.plant.cable_kernel` for the rigid-cable branch).

Seeding: a scenario's parameters come from a ``numpy.random.Generator`` seeded with the
benchmark seed and the scenario's *identity* (its kind, its effect classes and its draw
index), not with its position in the list, so that ``joint_friction-1`` is the same plant
whatever ``draws``, ``pairs`` or ``n_null`` are: a cache written with fewer draws stays valid.

Tasks (:func:`scenario_tasks`): seeded random reaches of several minimum-jerk moves; each move
crosses the middle of every joint's range, so every joint's velocity reverses at every move.
Training and held-out tasks come from disjoint seeds and are the same for every scenario.

Logs (:func:`generate_logs`): ``root/<scenario>/<train|holdout>-<k>/`` holds what
:func:`msarm.tasks.track.track` writes (``log.parquet``, its sidecar, ``config.yaml``,
``metrics.json``) and ``task.json``, the task's definition, written last as the mark of a
complete run; ``root/<scenario>/scenario.json`` holds :meth:`Scenario.as_dict`. The cache is
resumable: a run whose files are all there and whose ``config.yaml`` and ``task.json`` match
is not run again.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from msarm.control import ArmControllerConfig
from msarm.diagnose.effect_classes import EFFECT_CLASSES
from msarm.errors import InputError, MsarmError
from msarm.io.atomic import remove_stale_temps_in, write_json_atomic
from msarm.io.code_version import code_fingerprint
from msarm.io.config import config_to_dict, dump_config
from msarm.io.logs import read_model_sha256
from msarm.model import RobotModel
from msarm.plant import IDEAL_PLANT, EffectsConfig, PlantConfig
from msarm.plant.config import (
    CoggingConfig,
    DelayConfig,
    ElasticityConfig,
    JointFrictionConfig,
    SensorNoiseConfig,
    SheathFrictionConfig,
    WinchFrictionConfig,
)
from msarm.tasks.track import TrackSettings, track
from msarm.tasks.trajectories import HOME_POSTURE, Move, Task

__all__ = [
    "DEFAULT_PAIRS",
    "EFFECT_CLASSES",
    "PARAMETER_RANGES",
    "SPLITS",
    "Scenario",
    "ScenarioRunError",
    "build_scenarios",
    "generate_logs",
    "noisy_base_plant",
    "run_seed",
    "scenario_tasks",
]

FloatArray = NDArray[np.float64]


#: The pairs of effect classes of the default benchmark, one scenario each: two frictions at
#: different places (joints, winches), a transmission loss with a motor-periodic torque, the
#: elastic cable model with a joint-side effect, and a sensing error with a physical effect.
DEFAULT_PAIRS: tuple[tuple[str, str], ...] = (
    ("joint_friction", "winch_friction"),
    ("sheath_friction", "cogging"),
    ("elasticity", "joint_friction"),
    ("sensor_bias", "joint_friction"),
    # elastic cables give the sheath its stiction (a capstan law that sticks in between)
    ("sheath_friction", "elasticity"),
)

#: Ranges of the drawn parameters, per effect class: ``(low, high)``, drawn uniformly.
#: Units: ``mu`` [1/rad]; ``coulomb`` [N m]; ``viscous`` [N m s/rad]; ``stiffness`` [N/m];
#: ``amplitude`` [N m]; ``phase`` [rad]; ``tension_bias`` [N] is the *magnitude* of the bias
#: (its sign is drawn too); ``total_periods`` [control periods] is the sensing plus actuation
#: delay (integers, both ends included). Cogging has 24 periods per revolution.
PARAMETER_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "sheath_friction": {"mu": (0.05, 0.2)},
    "winch_friction": {"coulomb": (0.01, 0.04), "viscous": (1e-4, 4e-4)},
    "elasticity": {"stiffness": (3.5e4, 8.0e4)},
    "joint_friction": {"coulomb": (0.05, 0.3), "viscous": (0.02, 0.1)},
    "cogging": {"amplitude": (0.005, 0.02), "phase": (0.0, 2.0 * math.pi)},
    "sensor_bias": {"tension_bias": (1.0, 3.0)},
    "delay": {"total_periods": (1, 1)},
}

#: Cogging periods per motor revolution of every cogging scenario.
COGGING_PERIODS = 24

#: The two kinds of runs of a scenario, and their code in the run seeds.
SPLITS: tuple[str, ...] = ("train", "holdout")

#: Move durations of the scenario tasks [s].
_MOVE_TIME = (1.2, 2.2)
#: Holds before each move [s].
_HOLD_TIME = (0.3, 0.7)
#: Shortest final hold of a scenario task [s].
_FINAL_HOLD = 0.5
#: Shortest scenario task [s]: one hold, one (possibly shortened) move, the final hold.
_MIN_TASK_DURATION = 2.0
#: Fraction of each joint's range kept free at each end by the task targets.
_MARGIN = 0.15

#: Kind codes in the scenario seeds.
_NULL, _SINGLE, _PAIR = 0, 1, 2


class ScenarioRunError(MsarmError):
    """A run of a scenario diverged (its partial log is kept on disk).

    Attributes:
        scenario: Name of the scenario.
        run: The run, ``"<split>-<k>"``.
        run_dir: The run's folder.
        time: Simulated time of the divergence [s] (NaN if unknown).
    """

    def __init__(self, message: str, scenario: str, run: str, run_dir: Path, time: float) -> None:
        super().__init__(message)
        self.scenario = scenario
        self.run = run
        self.run_dir = run_dir
        self.time = time


@dataclass(frozen=True)
class Scenario:
    """One plant of the benchmark.

    Attributes:
        name: ``"<class>-<draw>"``, ``"<class>+<class>-<draw>"`` or ``"null-<draw>"``.
        effects: The effect classes switched on beyond sensor noise (names from
            :data:`EFFECT_CLASSES`; all are :class:`~msarm.plant.EffectsConfig` blocks but
            ``sensor_bias``, which is the ``tension_bias`` of ``sensor_noise``); empty for a
            null plant.
        plant: The plant (named after the scenario).
        draw: Index of the draw among the scenarios of the same effect(s).
        parameters: The drawn values, ``{class: {parameter: value}}`` (plain Python numbers;
            units as in :data:`PARAMETER_RANGES`, the delay as ``sensing_periods`` and
            ``actuation_periods``); empty for a null plant.
        seed: The scenario's seed (from the benchmark seed and the scenario's identity); the
            plant seeds of its runs derive from it (:func:`run_seed`).
    """

    name: str
    effects: tuple[str, ...]
    plant: PlantConfig
    draw: int
    parameters: dict[str, dict[str, Any]] = field(default_factory=dict)
    seed: int = 0

    def as_dict(self) -> dict[str, Any]:
        """The scenario as plain data (JSON-safe), the plant resolved field by field.

        Returns:
            ``name``, ``effects`` (list), ``draw``, ``seed``, ``parameters`` and ``plant``.
        """
        return {
            "name": self.name,
            "effects": list(self.effects),
            "draw": self.draw,
            "seed": self.seed,
            "parameters": json.loads(json.dumps(self.parameters)),
            "plant": config_to_dict(self.plant),
        }


# --- plants ---------------------------------------------------------------------------------


def noisy_base_plant(name: str = "noisy") -> PlantConfig:
    """The plant every scenario starts from: ideal, plus sensor noise at its defaults.

    Args:
        name: Name of the plant.

    Returns:
        :data:`~msarm.plant.IDEAL_PLANT` with sensor noise on (default standard deviations,
        ``tension_bias = 0``).
    """
    noise = SensorNoiseConfig(enabled=True, tension_bias=0.0)
    return replace(IDEAL_PLANT, name=name, effects=replace(IDEAL_PLANT.effects, sensor_noise=noise))


def _uniform(rng: np.random.Generator, effect: str, key: str) -> float:
    low, high = PARAMETER_RANGES[effect][key]
    return float(rng.uniform(low, high))


#: Effect classes that are one config block, drawn parameter by parameter from
#: :data:`PARAMETER_RANGES` (in its order), with these fixed values besides.
_PLAIN_BLOCKS: dict[str, tuple[type, dict[str, Any]]] = {
    "sheath_friction": (SheathFrictionConfig, {}),
    "winch_friction": (WinchFrictionConfig, {}),
    "elasticity": (ElasticityConfig, {}),
    "joint_friction": (JointFrictionConfig, {}),
    "cogging": (CoggingConfig, {"periods_per_revolution": COGGING_PERIODS}),
}


def _draw_effect(
    effect: str, rng: np.random.Generator, effects: EffectsConfig
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Switch ``effect`` on with drawn parameters.

    Args:
        effect: An effect class of :data:`EFFECT_CLASSES`.
        rng: The scenario's generator.
        effects: The :class:`~msarm.plant.EffectsConfig` so far.

    Returns:
        The config blocks to replace (``{block: config}``) and the drawn values.
    """
    if effect in _PLAIN_BLOCKS:
        config_class, fixed = _PLAIN_BLOCKS[effect]
        drawn = {key: _uniform(rng, effect, key) for key in PARAMETER_RANGES[effect]}
        values = {**drawn, **fixed}
        return {effect: config_class(enabled=True, **values)}, values
    if effect == "sensor_bias":
        sign = 1.0 if rng.random() < 0.5 else -1.0
        bias = sign * _uniform(rng, effect, "tension_bias")
        block = replace(effects.sensor_noise, enabled=True, tension_bias=bias)
        return {"sensor_noise": block}, {"tension_bias": bias}
    if effect == "delay":
        low, high = PARAMETER_RANGES[effect]["total_periods"]
        totals = range(int(low), int(high) + 1)
        splits = [(s, total - s) for total in totals for s in range(total + 1)]
        sensing, actuation = splits[int(rng.integers(len(splits)))]
        block = DelayConfig(enabled=True, sensing_periods=sensing, actuation_periods=actuation)
        return {effect: block}, {"sensing_periods": sensing, "actuation_periods": actuation}
    raise InputError(f"effect must be one of {', '.join(EFFECT_CLASSES)}, got {effect!r}")


def _scenario(seed: int, kind: int, classes: tuple[str, ...], draw: int) -> Scenario:
    """Draw one scenario from its identity (kind, classes, draw) and the benchmark seed."""
    codes = [EFFECT_CLASSES.index(c) + 1 for c in classes] + [0, 0]
    # a fixed-length key: SeedSequence pads short keys with zeros, so lengths must not vary
    sequence = np.random.SeedSequence([seed, kind, codes[0], codes[1], draw])
    draw_sequence, noise_sequence = sequence.spawn(2)
    rng = np.random.default_rng(draw_sequence)
    scenario_seed = int(noise_sequence.generate_state(1)[0])
    name = f"{'+'.join(classes) if classes else 'null'}-{draw}"
    plant = noisy_base_plant(name)
    parameters: dict[str, dict[str, Any]] = {}
    for effect in classes:
        blocks, values = _draw_effect(effect, rng, plant.effects)
        plant = replace(plant, effects=replace(plant.effects, **blocks))
        parameters[effect] = values
    return Scenario(
        name=name,
        effects=tuple(classes),
        plant=plant,
        draw=draw,
        parameters=parameters,
        seed=scenario_seed,
    )


def _check_count(value: Any, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise InputError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _check_pairs(pairs: Any) -> list[tuple[str, str]]:
    if isinstance(pairs, str) or not isinstance(pairs, Sequence):
        raise InputError(f"pairs must be a sequence of pairs of effect classes, got {pairs!r}")
    out: list[tuple[str, str]] = []
    valid = ", ".join(EFFECT_CLASSES)
    for k, pair in enumerate(pairs):
        if isinstance(pair, str) or not isinstance(pair, Sequence) or len(pair) != 2:
            raise InputError(f"pairs[{k}] must be a pair of effect classes, got {pair!r}")
        for name in pair:
            if name not in EFFECT_CLASSES:
                raise InputError(
                    f"pairs[{k}] names an unknown effect class {name!r}; valid: {valid}"
                )
        if pair[0] == pair[1]:
            raise InputError(f"pairs[{k}] must name two different effect classes, got {pair!r}")
        key = (str(pair[0]), str(pair[1]))
        if key in out or key[::-1] in out:
            raise InputError(f"pairs[{k}] repeats the pair {pair!r}")
        out.append(key)
    return out


def build_scenarios(
    seed: int = 0,
    draws: int = 3,
    pairs: Sequence[Sequence[str]] = DEFAULT_PAIRS,
    n_null: int = 3,
) -> list[Scenario]:
    """The scenarios of the benchmark, deterministic for a seed.

    Args:
        seed: Benchmark seed, a non-negative integer.
        draws: Scenarios per effect class of :data:`EFFECT_CLASSES`, >= 1.
        pairs: Pairs of effect classes, one scenario each (draw 0).
        n_null: Null plants (sensor noise only; each has its own noise seeds), >= 0.

    Returns:
        ``draws`` scenarios per effect class (in :data:`EFFECT_CLASSES` order), then one per
        pair, then the null plants: ``7 draws + len(pairs) + n_null`` scenarios.

    Raises:
        InputError: A negative or non-integer seed, ``draws < 1``, ``n_null < 0``, or a pair
            that is not two different known effect classes (or repeats another pair).
    """
    seed = _check_count(seed, "seed", 0)
    draws = _check_count(draws, "draws", 1)
    n_null = _check_count(n_null, "n_null", 0)
    checked = _check_pairs(pairs)
    scenarios = [
        _scenario(seed, _SINGLE, (effect,), draw)
        for effect in EFFECT_CLASSES
        for draw in range(draws)
    ]
    scenarios += [_scenario(seed, _PAIR, pair, 0) for pair in checked]
    scenarios += [_scenario(seed, _NULL, (), draw) for draw in range(n_null)]
    return scenarios


# --- tasks ----------------------------------------------------------------------------------


def _reach_task(
    name: str, entropy: list[int], lower: FloatArray, upper: FloatArray, duration: float
) -> Task:
    """A random reach whose every move crosses the middle of every joint's range."""
    rng = np.random.default_rng(entropy)
    lo = lower + _MARGIN * (upper - lower)
    hi = upper - _MARGIN * (upper - lower)
    mid = 0.5 * (lo + hi)
    side = rng.random(lower.shape[0]) < 0.5  # True: the next target is in the upper half
    moves: list[Move] = []
    clock = 0.0
    while True:
        hold = float(rng.uniform(*_HOLD_TIME))
        move_time = float(rng.uniform(*_MOVE_TIME))
        u = rng.random(lower.shape[0])
        if clock + hold + move_time + _FINAL_HOLD > duration:
            if moves:
                break
            # the first move always fits: shortened if it must be (duration >= 2 s)
            hold = min(hold, _HOLD_TIME[0])
            move_time = duration - hold - _FINAL_HOLD
        target = np.where(side, mid + u * (hi - mid), lo + u * (mid - lo))
        moves.append(Move(start=clock + hold, duration=move_time, target=target))
        clock += hold + move_time
        side = ~side
    return Task(name=name, duration=duration, home=HOME_POSTURE, moves=tuple(moves))


def scenario_tasks(
    model: RobotModel,
    n_train: int = 4,
    n_holdout: int = 2,
    duration: float = 10.0,
    seed: int = 0,
) -> tuple[list[Task], list[Task]]:
    """The training and held-out tasks, the same for every scenario.

    Each task starts at :data:`~msarm.tasks.trajectories.HOME_POSTURE` and makes as many
    minimum-jerk moves as fit (moves of 1.2-2.2 s after holds of 0.3-0.7 s, then a final hold
    of at least 0.5 s: about four moves in 10 s). The targets lie in the joint range shrunk by
    15 % at each end and alternate, per joint, between the halves above and below its middle,
    so every joint's velocity reverses at every move. Task ``k`` of a split draws from
    ``numpy.random.default_rng([seed, split, k])`` (split 0: training, 1: held-out): the two
    lists come from disjoint seeds.

    Args:
        model: The arm (its joint limits).
        n_train: Number of training tasks, >= 1.
        n_holdout: Number of held-out tasks, >= 1.
        duration: Length of each task [s], >= 2.
        seed: Task seed, a non-negative integer.

    Returns:
        ``(train_tasks, holdout_tasks)``, named ``reach-<split>-<k>-s<seed>``.

    Raises:
        InputError: A count below 1, a duration below 2 s or not finite, or a bad seed.
    """
    n_train = _check_count(n_train, "n_train", 1)
    n_holdout = _check_count(n_holdout, "n_holdout", 1)
    seed = _check_count(seed, "seed", 0)
    if isinstance(duration, bool) or not isinstance(duration, int | float | np.floating):
        raise InputError(f"duration must be a number of seconds, got {duration!r}")
    duration = float(duration)
    if not (math.isfinite(duration) and duration >= _MIN_TASK_DURATION):
        raise InputError(f"duration must be >= {_MIN_TASK_DURATION} s and finite, got {duration}")
    lower = np.asarray(model.joint_lower, dtype=float)
    upper = np.asarray(model.joint_upper, dtype=float)
    lists: list[list[Task]] = []
    for code, (split, count) in enumerate(zip(SPLITS, (n_train, n_holdout), strict=True)):
        lists.append(
            [
                _reach_task(f"reach-{split}-{k}-s{seed}", [seed, code, k], lower, upper, duration)
                for k in range(count)
            ]
        )
    return lists[0], lists[1]


def _task_dict(task: Task) -> dict[str, Any]:
    """The task's definition as plain data (what ``task.json`` holds)."""
    return {
        "name": task.name,
        "duration": task.duration,
        "home": task.home.tolist(),
        "moves": [
            {"start": m.start, "duration": m.duration, "target": m.target.tolist()}
            for m in task.moves
        ],
    }


# --- logs -----------------------------------------------------------------------------------


def run_seed(scenario: Scenario, split: str, k: int) -> int:
    """The plant seed of run ``k`` of ``split`` of ``scenario`` (sensor noise).

    Args:
        scenario: The scenario.
        split: ``"train"`` or ``"holdout"``.
        k: Index of the run in its split, >= 0.

    Returns:
        A non-negative integer below 2**32, from ``(scenario.seed, split, k)``.
    """
    if split not in SPLITS:
        raise InputError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    k = _check_count(k, "k", 0)
    sequence = np.random.SeedSequence([scenario.seed, SPLITS.index(split), k])
    return int(sequence.generate_state(1)[0])


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _is_done(
    run_dir: Path, settings: TrackSettings, task_data: dict[str, Any], model_sha256: str
) -> bool:
    """Whether ``run_dir`` holds this exact run, complete, made with this model file and code.

    The code is the fingerprint in the run's ``metrics.json``
    (:func:`~msarm.io.code_version.code_fingerprint`): a run of another msarm version is
    simulated again.
    """
    needed = ("log.parquet", "config.yaml", "metrics.json", "task.json")
    if not all((run_dir / name).is_file() for name in needed):
        return False
    try:
        config_text = (run_dir / "config.yaml").read_text(encoding="utf-8")
        recorded_with = read_model_sha256(run_dir / "log.parquet")
    except (OSError, MsarmError):
        return False
    metrics = _read_json(run_dir / "metrics.json")
    done = (
        config_text == dump_config(settings)
        and _read_json(run_dir / "task.json") == task_data
        and recorded_with.lower() == model_sha256.lower()
        and isinstance(metrics, dict)
        and metrics.get("code") == code_fingerprint("simulation")
    )
    if done:  # reused, never written again: a killed writer's temporary files go now
        remove_stale_temps_in(run_dir)
    return done


def _check_diverged(scenario: Scenario, run: str, run_dir: Path) -> None:
    metrics = _read_json(run_dir / "metrics.json")
    diverged = metrics.get("diverged") if isinstance(metrics, dict) else None
    if diverged is None:
        return
    when = float(diverged.get("time", math.nan))
    raise ScenarioRunError(
        f"scenario {scenario.name!r}, run {run}: the simulation diverged at t = {when:.3f} s "
        f"({diverged.get('message', '')}); partial log in {run_dir}",
        scenario=scenario.name,
        run=run,
        run_dir=run_dir,
        time=when,
    )


def generate_logs(
    model: RobotModel,
    scenario: Scenario,
    train_tasks: Sequence[Task],
    holdout_tasks: Sequence[Task],
    root: Path,
    progress: Callable[[int, int, str], None] | None = None,
) -> tuple[list[Path], list[Path]]:
    """Run every task on the scenario's plant and write the logs (resumable).

    Run ``k`` of split ``s`` (``train`` or ``holdout``) runs ``tasks[k]`` with the default
    controller (:class:`~msarm.control.ArmControllerConfig`) on ``scenario.plant`` with plant
    seed :func:`run_seed` ``(scenario, s, k)`` and writes into ``root/<scenario.name>/<s>-<k>/``
    through :func:`msarm.tasks.track.track` (no plots), then ``task.json``. A run whose
    ``log.parquet``, ``config.yaml``, ``metrics.json`` and ``task.json`` are there, with the
    same config and task, is not run again (every file is written atomically, ``task.json``
    last, so a present set is complete). ``root/<scenario.name>/scenario.json`` holds
    :meth:`Scenario.as_dict` (rewritten only when it changed).

    A run that diverges: ``track`` keeps the partial log and records the divergence in
    ``metrics.json``; this function then raises :class:`ScenarioRunError` naming the scenario
    and the run (also when it finds such a run in the cache), and runs nothing more of the
    scenario. A caller that benchmarks many scenarios can catch it and mark the scenario
    failed.

    Args:
        model: The arm.
        scenario: The scenario.
        train_tasks: Training tasks (:func:`scenario_tasks`), at least one.
        holdout_tasks: Held-out tasks, at least one, none also a training task.
        root: The cache folder (created if needed).
        progress: Called after each run with ``(runs done, runs in all, message)``, the
            message naming the scenario and run, and whether it ran (and in how many seconds)
            or was cached.

    Returns:
        ``(train_logs, holdout_logs)``: the ``log.parquet`` paths, in task order.

    Raises:
        InputError: No training or no held-out task, or a task in both lists.
        ScenarioRunError: A run diverged.
    """
    train_tasks, holdout_tasks = list(train_tasks), list(holdout_tasks)
    if not train_tasks:
        raise InputError("train_tasks must hold at least one task, got none")
    if not holdout_tasks:
        raise InputError("holdout_tasks must hold at least one task, got none")
    for task in holdout_tasks:
        if any(task == other for other in train_tasks):
            raise InputError(
                f"holdout_tasks must differ from the training tasks; {task.name!r} is in both"
            )
    folder = Path(root) / scenario.name
    for place in (Path(root), folder):
        if place.exists() and not place.is_dir():
            raise InputError(f"{place} is a file; expected the folder of {scenario.name}'s logs")
    folder.mkdir(parents=True, exist_ok=True)
    description = scenario.as_dict()
    if _read_json(folder / "scenario.json") != description:
        write_json_atomic(folder / "scenario.json", description)
    controller = ArmControllerConfig()
    total = len(train_tasks) + len(holdout_tasks)
    done = 0
    out: dict[str, list[Path]] = {split: [] for split in SPLITS}
    for split, tasks in zip(SPLITS, (train_tasks, holdout_tasks), strict=True):
        for k, task in enumerate(tasks):
            run = f"{split}-{k}"
            run_dir = folder / run
            seed = run_seed(scenario, split, k)
            settings = TrackSettings(task.name, seed, scenario.plant, controller)
            task_data = _task_dict(task)
            if _is_done(run_dir, settings, task_data, model.sha256):
                message = f"{scenario.name} {run}: cached"
            else:
                start = time.perf_counter()
                track(model, task, settings, run_dir, plots_too=False)
                write_json_atomic(run_dir / "task.json", task_data)
                message = f"{scenario.name} {run}: ran in {time.perf_counter() - start:.1f} s"
            _check_diverged(scenario, run, run_dir)
            out[split].append(run_dir / "log.parquet")
            done += 1
            if progress is not None:
                progress(done, total, message)
    return out["train"], out["holdout"]
