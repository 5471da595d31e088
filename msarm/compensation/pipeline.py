"""The training recipe: collect runs, build features and targets, train, evaluate, save.

``msarm train --config training/compensator.yaml`` runs :func:`train_compensator`. The
checkpoint holds the network, its normalisation, the feature and target specs, the model's
SHA-256, the recipe, the run split, the training metrics and, when the recipe has the sheath
stage on, the stage's settings and identified parameters; it is written atomically and an
interrupted training resumes from it.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from msarm.compensation.checkpoint import CheckpointError, Compensator
from msarm.compensation.dataset import DataConfig, build_arrays, collect_runs, split_runs
from msarm.compensation.features import FeatureExtractor, FeatureSpec
from msarm.compensation.feedforward import LearnedFeedforward
from msarm.compensation.identify import plant_reading, reuse_or_identify_sheath
from msarm.compensation.network import NetworkConfig, train_network
from msarm.compensation.sheath import SheathInverse, SheathParameters, SheathSpec
from msarm.compensation.target import TargetSpec
from msarm.control import ArmControllerConfig
from msarm.errors import ConfigError, MsarmWarning
from msarm.io.config import config_to_dict
from msarm.model import RobotModel
from msarm.plant import PlantConfig
from msarm.tasks.trajectories import RANDOM_TASK_DURATION

__all__ = [
    "RECIPE_NETWORK",
    "TUNED_CONTROLLER",
    "CompensatorRecipe",
    "TrainingReport",
    "check_recipe_paths",
    "check_recipe_plant",
    "train_compensator",
]

#: The controller gains of the shipped recipe, tuned on the default plant without feedforward
#: (tasks ``random-3000`` ... ``random-3011``: the smallest mean final error with no slack
#: event; README "Fairness"). :class:`~msarm.control.ArmControllerConfig`'s own defaults suit
#: the ideal plant and leave 1.4-26 mm on the default one.
TUNED_CONTROLLER = ArmControllerConfig(
    kp=(90.0, 90.0, 45.0, 45.0),
    ki=(640.0, 640.0, 320.0, 320.0),
    kd=(4.0, 4.0, 1.5, 1.5),
    integral_limit=10.0,
)


#: The shipped recipe's network settings: paper 003's network with :class:`NetworkConfig`'s
#: defaults, but early stopping after 5 epochs without a better validation loss, not 20. On
#: the shipped runs every round's best epoch is one of its first three and the next best
#: came within 2 epochs of the last (README), so the weights kept are the same as with 20,
#: for a third of the epochs.
RECIPE_NETWORK = NetworkConfig(patience=5)


@dataclass(frozen=True)
class CompensatorRecipe:
    """Everything that defines a trained compensator (``training/compensator.yaml``).

    Attributes:
        name: Name of the recipe.
        data: Runs to collect and their split.
        features: Network inputs.
        target: How the torque-error target is computed.
        network: Network and training settings.
        controller: The controller's gains while collecting data, and with and without
            the feedforward afterwards (default :data:`TUNED_CONTROLLER`, as the shipped
            recipe: a recipe's defaults are the shipped recipe).
        sheath: The sheath stage (:mod:`msarm.compensation.sheath`).
        checkpoint: Where the trained compensator is written.
    """

    name: str = "compensator"
    data: DataConfig = field(default_factory=DataConfig)
    features: FeatureSpec = field(default_factory=FeatureSpec)
    target: TargetSpec = field(default_factory=TargetSpec)
    network: NetworkConfig = RECIPE_NETWORK
    controller: ArmControllerConfig = TUNED_CONTROLLER
    sheath: SheathSpec = field(default_factory=SheathSpec)
    checkpoint: str = "runs/compensator/compensator.pt"

    def __post_init__(self) -> None:
        # the checks its parts cannot make alone (a config file's loader adds the file)
        seed = self.data.first_seed
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(
                f"key 'data.first_seed' must be an integer >= 0 (run i is the task "
                f"random-<first_seed + i>, whose seed is >= 0), got {seed!r}"
            )
        samples = int(round(RANDOM_TASK_DURATION * self.controller.rate_hz))
        if self.target.window > samples:  # before any run is collected
            raise ValueError(
                f"key 'target.window' is {self.target.window} samples, more than a run has "
                f"({samples}: a {RANDOM_TASK_DURATION:g} s random task at "
                f"controller.rate_hz {self.controller.rate_hz:g} Hz); expected an odd window "
                "of at most that (25 samples, 0.1 s at 250 Hz, by default)"
            )
        order = self.target.polyorder
        if isinstance(order, bool) or not isinstance(order, int) or order < 0:
            raise ValueError(
                f"key 'target.polyorder' must be an integer >= 0 (a Savitzky-Golay "
                f"polynomial order), got {order!r}"
            )


def check_recipe_paths(recipe: CompensatorRecipe, source: str = "the recipe") -> None:
    """Refuse a recipe whose folders cannot be written, before any run is collected.

    ``data.folder`` must be a folder, or a path whose nearest existing part is one (it is
    created); ``checkpoint`` must be a file path, not a folder, in such a folder. Found only
    at the end of a training, either would lose its minutes of work.

    Args:
        recipe: The recipe.
        source: Its file, for the messages (``"the recipe"`` when it has none).

    Raises:
        ConfigError: A path that cannot be written (the file, the key and the path named).
    """

    def blocked(folder: Path) -> Path | None:  # the file in the way of creating ``folder``
        for part in (folder, *folder.parents):
            if part.exists():
                return None if part.is_dir() else part
        return None

    folder = Path(recipe.data.folder)
    block = blocked(folder)
    if block is not None:
        where = "" if block == folder else f"{folder}: "
        raise ConfigError(
            f"{source}: key 'data.folder': {where}{block} is a file; expected a folder "
            "(created if missing) for the runs' logs"
        )
    checkpoint = Path(recipe.checkpoint)
    if checkpoint.is_dir():
        raise ConfigError(
            f"{source}: key 'checkpoint': {checkpoint} is a folder; expected the path of the "
            f"compensator file to write, e.g. {checkpoint / 'compensator.pt'}"
        )
    block = blocked(checkpoint.parent)
    if block is not None:
        raise ConfigError(
            f"{source}: key 'checkpoint': {checkpoint}: {block} is a file; expected a file "
            "path in a folder (created if missing)"
        )
    for key, place in (("data.folder", folder), ("checkpoint", checkpoint.parent)):
        reason = _cannot_create(place)
        if reason:
            raise ConfigError(
                f"{source}: key '{key}': {reason}; expected a folder that can be written "
                "(created if missing)"
            )


def _cannot_create(folder: Path) -> str:
    """Why ``folder`` cannot be created or written, in words; empty if it can.

    The missing part of the path is created to find out, then removed again (a check leaves
    nothing behind).
    """
    missing = [part for part in (folder, *folder.parents) if not part.exists()]
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return f"cannot create the folder {folder} ({exc.strerror or exc})"
    finally:
        for part in missing:  # deepest first
            try:
                part.rmdir()
            except OSError:
                pass
    if folder.exists() and not os.access(folder, os.W_OK | os.X_OK):
        return f"the folder {folder} cannot be written"
    return ""


def check_recipe_plant(
    recipe: CompensatorRecipe, plant: PlantConfig, source: str = "the recipe"
) -> None:
    """Refuse a recipe whose features read the motor angles with another drum than the plant's.

    The cable length error input (``features.drum_radius``) and the sheath identification turn
    motor angles into cable length with the winch drums' radius: with another radius than the
    plant's, the length error would carry a share of each cable's travel that is not there.

    Args:
        recipe: The recipe.
        plant: The plant its runs are collected on.
        source: The recipe's file, for the message (``"the recipe"`` when it has none).

    Raises:
        ConfigError: ``features.drum_radius`` differs from the plant's ``winch.drum_radius``
            (both named).
    """
    drum, plant_drum = recipe.features.drum_radius, plant.winch.drum_radius
    if abs(drum - plant_drum) > 1e-12 * plant_drum:
        raise ConfigError(
            f"{source}: key 'features.drum_radius' is {drum:g} m, the plant {plant.name!r} has "
            f"winch.drum_radius {plant_drum:g} m; expected the same radius (set "
            f"features.drum_radius: {plant_drum:g} in the recipe)"
        )


@dataclass(frozen=True)
class TrainingReport:
    """What :func:`train_compensator` did and measured.

    Attributes:
        checkpoint: Path of the written checkpoint.
        split: Seeds of the training, validation and test runs.
        samples: Samples in each set.
        collect_time_s: Time spent simulating (or reusing) the runs [s], all rounds.
        train_time_s: Time spent training the networks [s], all rounds.
        epochs: Epochs run and best epoch of the last round.
        test_rmse: RMS error of the predicted T_f on the test runs [N m], per joint.
        test_baseline_rmse: RMS of T_f itself on the test runs (predicting 0) [N m].
        test_r2: Share of T_f variance explained on the test runs, per joint.
        sheath: The sheath stage's identified parameters, or None (stage off).
    """

    checkpoint: Path
    split: dict[str, list[int]]
    samples: dict[str, int]
    collect_time_s: float
    train_time_s: float
    epochs: tuple[int, int]
    test_rmse: tuple[float, ...]
    test_baseline_rmse: tuple[float, ...]
    test_r2: tuple[float, ...]
    sheath: SheathParameters | None = None


def _paths_of(by_seed: dict[int, Path], seeds: tuple[int, ...]) -> list[Path]:
    return [by_seed[s] for s in seeds]


def _weights_hash(compensator: Compensator) -> str:
    """12 hex digits of what a round's network feeds forward, which names its runs.

    The weights, and also the normalisers, the activation and the feature spec: the same
    weights with other normalisers (a training whose epochs all failed to improve keeps the
    seeded initial weights, whatever its data) give another ``dtau``, and until 2026-11-29
    their runs were reused under the weights' name. The training settings (``patience``,
    ``max_epochs``) are left out: a training that ends in the same network reuses its runs.
    """
    digest = hashlib.sha256()
    for weight, bias in compensator.layer_weights():
        digest.update(np.ascontiguousarray(weight).tobytes())
        digest.update(np.ascontiguousarray(bias).tobytes())
    for normalizer in (compensator.input_normalizer, compensator.output_normalizer):
        digest.update(normalizer.mean.tobytes())
        digest.update(normalizer.std.tobytes())
    digest.update(compensator.config.activation.encode())
    spec = compensator.metadata.get("feature_spec")
    digest.update(json.dumps(spec, sort_keys=True).encode())
    return digest.hexdigest()[:12]


def train_compensator(
    model: RobotModel,
    recipe: CompensatorRecipe,
    plant: PlantConfig,
    resume: bool = True,
    on_run: Callable[[int, int, bool], None] | None = None,
    on_epoch: Callable[[int, int, float, float], None] | None = None,
    on_round: Callable[[int, int], None] | None = None,
    on_sheath: Callable[[SheathParameters, int], None] | None = None,
) -> TrainingReport:
    """Collect (or reuse) the runs, train on the training runs, test on the test runs.

    Round 0 collects ``recipe.data.n_runs`` runs without feedforward and trains on the
    training runs (early stopping on the validation runs). Each further round (``rounds``)
    runs the training and validation tasks again with the feedforward of the previous round,
    adds those runs to their sets and trains a fresh network on all of them. The test runs
    are collected once and never trained on.

    With the sheath stage on (``recipe.sheath.enabled``), the runs without feedforward are
    for identifying it only (``mu`` and the cable compliance, fitted on the training runs and
    scored on the validation runs, :func:`~msarm.compensation.identify.identify_sheath`; the
    answer is kept in ``data.folder``/``sheath-identification.json`` and reused for the same
    logs, model and code, :func:`~msarm.compensation.identify.reuse_or_identify_sheath`).
    Every run is then collected again with the stage on, and the networks learn what the
    stage leaves (the target takes off what it added, see
    :mod:`msarm.compensation.target`); from round 1 on the stage and the previous round's
    network run together.

    Args:
        model: The arm.
        recipe: The recipe.
        plant: The plant the runs are collected on (resolved from ``recipe.data.plant``).
        resume: Continue an interrupted training from its state file, if one is there (a
            state left by another recipe, other runs or other code cannot be resumed: that round
            starts over, with a warning).
        on_run: Progress of the data collection ``(done, total, reused)``.
        on_epoch: Progress of the training ``(epoch, max_epochs, train_loss, val_loss)``.
        on_round: Called at the start of each round ``(round, rounds)``.
        on_sheath: Called once the sheath stage is identified, with its parameters and the
            number of runs then collected with it on.

    Returns:
        The report; the checkpoint is written to ``recipe.checkpoint``.

    Raises:
        ConfigError: The recipe's ``data.folder`` or ``checkpoint`` cannot be written (see
            :func:`check_recipe_paths`), or its features' drum radius is not the plant's (see
            :func:`check_recipe_plant`), found before any run is collected.
    """
    check_recipe_paths(recipe)
    check_recipe_plant(recipe, plant)
    data = recipe.data
    collect_time = train_time = 0.0
    start = time.perf_counter()
    paths = collect_runs(model, data, plant, recipe.controller, progress=on_run)
    collect_time += time.perf_counter() - start
    by_seed = dict(zip(data.seeds, paths, strict=True))
    split = split_runs(data.seeds, data.split)
    train_paths = _paths_of(by_seed, split.train)
    val_paths = _paths_of(by_seed, split.validation)
    stage: SheathInverse | None = None
    identified: SheathParameters | None = None
    saved_stage: dict | None = None  # the stage as the checkpoint keeps it
    stage_name = ""
    if recipe.sheath.enabled:
        # the logs read with the plant's winch drums and the network target's filter
        identified, _ = reuse_or_identify_sheath(
            model,
            train_paths,
            val_paths,
            Path(data.folder) / "sheath-identification.json",
            plant_reading(plant.winch, recipe.target),
        )
        saved_stage = {"spec": asdict(recipe.sheath), "parameters": identified.as_dict()}
        text = json.dumps(saved_stage, sort_keys=True)
        stage_name = f"-sheath-{hashlib.sha256(text.encode()).hexdigest()[:12]}"
        stage = SheathInverse(model, recipe.sheath, identified, 1.0 / recipe.controller.rate_hz)
        if on_sheath is not None:
            on_sheath(identified, data.n_runs)
        start = time.perf_counter()
        staged = collect_runs(
            model,
            data,
            plant,
            recipe.controller,
            progress=on_run,
            feedforward=LearnedFeedforward(model, None, stage),
            feedforward_name=f"{recipe.name}{stage_name}",
            folder=Path(data.folder) / "sheath",
        )
        collect_time += time.perf_counter() - start
        by_seed = dict(zip(data.seeds, staged, strict=True))
        train_paths = _paths_of(by_seed, split.train)
        val_paths = _paths_of(by_seed, split.validation)
    test_paths = _paths_of(by_seed, split.test)
    # each run's features and target, built once: the rounds stack the same runs again
    built: dict[Path, tuple[np.ndarray, np.ndarray]] = {}
    test_arrays = build_arrays(model, test_paths, recipe.features, recipe.target, built)
    names = FeatureExtractor(model, recipe.features).names
    checkpoint = Path(recipe.checkpoint)
    checkpoint.parent.mkdir(parents=True, exist_ok=True)
    metadata = {
        "model_sha256": model.sha256,
        "model_name": model.name,
        "feature_spec": recipe.features.as_dict(),
        "feature_names": names,
        "target_spec": config_to_dict(recipe.target),
        "recipe": config_to_dict(recipe),
        "split": {
            "train": list(split.train),
            "validation": list(split.validation),
            "test": list(split.test),
        },
    }
    if saved_stage is not None:
        metadata["sheath"] = saved_stage
    compensator: Compensator | None = None
    for round_ in range(data.rounds + 1):
        if on_round is not None:
            on_round(round_, data.rounds)
        if compensator is not None:
            feedforward = LearnedFeedforward(model, compensator, stage)
            seeds = list(split.train) + list(split.validation)
            start = time.perf_counter()
            new = collect_runs(
                model,
                data,
                plant,
                recipe.controller,
                progress=on_run,
                feedforward=feedforward,
                feedforward_name=f"{recipe.name}-round{round_}-{_weights_hash(compensator)}"
                + stage_name,
                seeds=seeds,
                folder=Path(data.folder) / f"round-{round_}",
            )
            collect_time += time.perf_counter() - start
            train_paths += new[: len(split.train)]
            val_paths += new[len(split.train) :]
        x_train, y_train = build_arrays(model, train_paths, recipe.features, recipe.target, built)
        x_val, y_val = build_arrays(model, val_paths, recipe.features, recipe.target, built)
        state_path = checkpoint.with_name(f"{checkpoint.stem}.round{round_}.training.pt")
        metadata["round"] = round_
        resume_round = resume and state_path.is_file()

        train = functools.partial(
            train_network,
            x_train,
            y_train,
            x_val,
            y_val,
            recipe.network,
            checkpoint_path=state_path,
            progress=on_epoch,
            metadata=metadata,
            column_names=names,
        )
        try:
            result = train(resume=resume_round)
        except CheckpointError as exc:
            if not resume_round:
                raise
            # a training state left by a run of another recipe, other runs or a cut-off
            # write: resuming it would train something else, so this round starts over
            warnings.warn(
                f"{exc}; round {round_} of the training starts over (it cannot resume that "
                "state; msarm train --fresh starts every round over)",
                MsarmWarning,
                stacklevel=2,
            )
            result = train(resume=False)
        train_time += result.train_time_s
        compensator = result.compensator
    assert compensator is not None
    x_test, y_test = test_arrays
    error = compensator.predict(x_test) - y_test
    rmse = np.sqrt(np.mean(error**2, axis=0))
    baseline = np.sqrt(np.mean(y_test**2, axis=0))
    r2 = 1.0 - np.sum(error**2, axis=0) / np.sum((y_test - y_test.mean(axis=0)) ** 2, axis=0)
    report = TrainingReport(
        checkpoint=checkpoint,
        split=metadata["split"],
        samples={
            "train": int(len(x_train)),
            "validation": int(len(x_val)),
            "test": int(len(x_test)),
        },
        collect_time_s=collect_time,
        train_time_s=train_time,
        epochs=(result.epochs_run, result.best_epoch),
        test_rmse=tuple(float(v) for v in rmse),
        test_baseline_rmse=tuple(float(v) for v in baseline),
        test_r2=tuple(float(v) for v in r2),
        sheath=identified,
    )
    compensator.metadata["training"] = {
        "plant": config_to_dict(plant),  # what it learned: see trained_plant
        "rounds": data.rounds,
        "samples": report.samples,
        "collect_time_s": collect_time,
        "train_time_s": train_time,
        "epochs_run": result.epochs_run,
        "best_epoch": result.best_epoch,
        "test_rmse": list(report.test_rmse),
        "test_r2": list(report.test_r2),
        "history": [list(map(float, row)) for row in result.history],
    }
    compensator.save(checkpoint)
    return report
