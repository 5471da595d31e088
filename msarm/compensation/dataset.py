"""Training data of the compensator: seeded random runs on a plant, split by runs.

Paper 003 recorded 14 runs of 20 s at 250 Hz and split its data into training, validation and test
(its text reads "70% ... 70% for validation, and 15% for testing", a typo we read as 70 / 15 / 15 %;
msarm splits runs, not samples). :func:`collect_runs` records such runs on a simulated plant: each
run is the task ``random-<seed>`` written as a log (with its sidecar and config) into
``<folder>/run-<seed>/``; a run whose log already exists with the same settings is reused, so an
interrupted collection resumes. :func:`split_runs` splits runs (never samples), and
:func:`build_arrays` turns logs into feature and target arrays, naming the run file and the column
of any NaN.
"""

from __future__ import annotations

import json
import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from msarm.compensation.features import FeatureExtractor, FeatureSpec
from msarm.compensation.target import TargetSpec, torque_error
from msarm.control import ArmControllerConfig
from msarm.errors import InputError, MsarmError
from msarm.io.atomic import remove_stale_temps_in
from msarm.io.code_version import code_fingerprint
from msarm.io.config import load_config
from msarm.io.logs import STANDARD_UNITS, check_standard_units, read_log, read_model_sha256
from msarm.model import RobotModel
from msarm.plant import PlantConfig
from msarm.tasks.registry import get_task
from msarm.tasks.runner import Feedforward
from msarm.tasks.track import TrackSettings, track

__all__ = ["DataConfig", "RunSplit", "build_arrays", "collect_runs", "split_runs"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class DataConfig:
    """Which runs to collect and how to split them.

    Attributes:
        plant: Plant preset (``default``, ``ideal``) or a plant YAML file.
        n_runs: Number of runs (paper 003: 14).
        first_seed: Seed of the first run's task and noise; run i uses ``first_seed + i``.
        split: Shares of runs for training, validation and test (paper 003's typo read as
            0.7/0.15/0.15).
        folder: Where the runs' logs are written.
        rounds: Rounds of iterative training after the first: each collects the training
            and validation runs again with the current feedforward on and trains on all runs
            so far, so that the network sees the states its own compensation leads to.
    """

    plant: str = "default"
    n_runs: int = 14
    first_seed: int = 1000
    split: tuple[float, float, float] = (0.7, 0.15, 0.15)
    folder: str = "runs/compensator/data"
    rounds: int = 2

    def __post_init__(self) -> None:
        """Check the settings before any run is collected.

        Raises:
            InputError: ``n_runs``, ``first_seed`` or ``rounds`` is not an integer (a bool is
                refused), ``rounds < 0`` or ``n_runs < 3``; ``split`` is not three finite
                positive shares adding to 1; ``folder`` is empty; or the split leaves a set
                without runs.
        """
        for name in ("n_runs", "first_seed", "rounds"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise InputError(
                    f"{name} must be an integer (a whole number), got "
                    f"{type(value).__name__} {value!r}"
                )
        if self.rounds < 0:
            raise InputError(f"rounds must be >= 0, got {self.rounds}")
        if self.n_runs < 3:
            raise InputError(f"n_runs must be >= 3 (training, validation, test), got {self.n_runs}")
        shares = self.split
        try:
            valid = (
                not isinstance(shares, str | bytes)
                and len(shares) == 3
                and all(
                    not isinstance(share, bool)
                    and isinstance(share, numbers.Real)
                    and math.isfinite(share)
                    and share > 0
                    for share in shares
                )
                and abs(sum(shares) - 1) <= 1e-9
            )
        except TypeError:  # no length: not a sequence of shares
            valid = False
        if not valid:
            raise InputError(
                f"split must be three finite positive shares adding to 1, got {self.split!r}"
            )
        if not str(self.folder).strip():
            # Path("") is the working directory: the runs would be written all over it
            raise InputError("folder must name a folder for the runs' logs, got an empty string")
        try:
            split_runs(self.seeds, self.split)
        except InputError as exc:
            raise InputError(f"n_runs and split: {exc}") from None

    @property
    def seeds(self) -> list[int]:
        """The runs' seeds."""
        return [self.first_seed + i for i in range(self.n_runs)]


@dataclass(frozen=True)
class RunSplit:
    """Seeds of the runs in each set."""

    train: tuple[int, ...]
    validation: tuple[int, ...]
    test: tuple[int, ...]


def split_runs(seeds: Sequence[int], shares: tuple[float, float, float]) -> RunSplit:
    """Split runs (not samples) into training, validation and test, in seed order.

    At least one run goes to each set; 14 runs at 0.7/0.15/0.15 give 10/2/2.
    """
    seeds = list(seeds)
    n = len(seeds)
    if n < 3:
        raise InputError(f"need at least 3 runs to hold any out, got {n}")
    n_val = max(1, round(shares[1] * n))
    n_test = max(1, round(shares[2] * n))
    n_train = n - n_val - n_test
    if n_train < 1:
        raise InputError(
            f"{n} runs leave none for training with shares {shares} (each set gets at least "
            "one run): expected more runs or a larger training share"
        )
    return RunSplit(
        tuple(seeds[:n_train]),
        tuple(seeds[n_train : n_train + n_val]),
        tuple(seeds[n_train + n_val :]),
    )


def run_folder(folder: str | Path, seed: int) -> Path:
    """Folder of the run with ``seed``."""
    return Path(folder) / f"run-{seed}"


def collect_runs(
    model: RobotModel,
    data: DataConfig,
    plant: PlantConfig,
    controller: ArmControllerConfig,
    progress: Callable[[int, int, bool], None] | None = None,
    feedforward: Feedforward | None = None,
    feedforward_name: str = "",
    seeds: Sequence[int] | None = None,
    folder: str | Path | None = None,
) -> list[Path]:
    """Run (or reuse) the random tasks of ``data`` on ``plant``; return their log paths.

    Args:
        model: The arm.
        data: Which runs.
        plant: The plant to run them on.
        controller: The controller's gains.
        progress: Called after each run with ``(done, total, reused)``.
        feedforward: A feedforward to run with (later rounds of an iterative training).
        feedforward_name: Its name, recorded in each run's config (decides reuse).
        seeds: The runs' seeds (default ``data.seeds``).
        folder: Where the runs go (default ``data.folder``).

    Raises:
        MsarmError: A run diverged (its partial log is kept; the message names it).
    """
    paths = []
    seeds = list(data.seeds if seeds is None else seeds)
    for i, seed in enumerate(seeds):
        run_dir = run_folder(data.folder if folder is None else folder, seed)
        settings = TrackSettings(f"random-{seed}", seed, plant, controller, feedforward_name)
        log_path = run_dir / "log.parquet"
        reused = reusable_run(run_dir, settings, model.sha256)
        if not reused:
            task = get_task(settings.task, model)
            result = track(model, task, settings, run_dir, feedforward=feedforward, plots_too=False)
            if result.run.error is not None:
                raise MsarmError(f"{log_path}: run random-{seed} diverged: {result.run.error}")
        paths.append(log_path)
        if progress is not None:
            progress(i + 1, len(seeds), reused)
    return paths


def reusable_run(folder: Path, settings: TrackSettings, model_sha256: str) -> bool:
    """Whether the run in ``folder`` is the one ``settings`` ask for, whole, on this model.

    A run is reused when its config is ``settings``, its metrics were written (they are
    written last), say it did not diverge and were made by the code in use (their ``code``,
    :func:`~msarm.io.code_version.code_fingerprint`: the same msarm sources and library
    versions), and its log was recorded with the model of ``model_sha256``; any other run is
    simulated again. A reused run's folder loses the temporary files a killed writer left
    there (:func:`~msarm.io.atomic.remove_stale_temps_in`): its files are not written again.
    """
    config_path, log_path = folder / "config.yaml", folder / "log.parquet"
    metrics_path = folder / "metrics.json"
    if not (config_path.is_file() and log_path.is_file() and metrics_path.is_file()):
        return False
    try:
        if load_config(config_path, TrackSettings) != settings:
            return False
        metrics = json.loads(metrics_path.read_text(encoding="utf-8"))
        if not isinstance(metrics, dict) or "diverged" in metrics:
            return False
        if metrics.get("code") != code_fingerprint("simulation"):
            return False  # made by another version of msarm or of its libraries
        if read_model_sha256(log_path).lower() != model_sha256.lower():
            return False
    except (MsarmError, OSError, ValueError):
        return False
    remove_stale_temps_in(folder)
    return True


def build_arrays(
    model: RobotModel,
    log_paths: Sequence[Path],
    features: FeatureSpec,
    target: TargetSpec,
    cache: dict[Path, tuple[FloatArray, FloatArray]] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Features ``(N, d)`` and targets ``(N, n)`` of the logs, stacked in order.

    Args:
        model: The robot model the logs were recorded with.
        log_paths: The run logs, in the order their samples are stacked.
        features: The feature spec.
        target: The target spec.
        cache: Arrays already built, by log path, for the same model and specs (one
            training's rounds stack the same runs again); the logs built here are added.
            The caller keeps it only while the files cannot change.

    Returns:
        ``(x, y)``: the features ``(N, d)`` and the targets [N m] ``(N, n)``.

    Raises:
        InputError: ``log_paths`` is a single path (str or Path) or empty, not a sequence of
            log paths; or a log holds NaN (file, column and row named) or lacks a channel.
    """
    if isinstance(log_paths, str | bytes | PathLike):
        raise InputError(
            f"log_paths must be a sequence of log paths, got a single path {log_paths!r}; "
            f"expected e.g. [{str(log_paths)!r}]"
        )
    log_paths = list(log_paths)
    if not log_paths:
        raise InputError("log_paths must be a non-empty sequence of log paths, got none ([])")
    extractor = FeatureExtractor(model, features)
    xs, ys = [], []
    for path in log_paths:
        if cache is not None and Path(path) in cache:
            x, y = cache[Path(path)]
            xs.append(x)
            ys.append(y)
            continue
        log = read_log(path)  # refuses NaN, naming the file, column and row
        if log.metadata.model_sha256.lower() != model.sha256.lower():
            raise InputError(
                f"{path}: the log was recorded with model {log.metadata.model_sha256[:12]}…, "
                f"not {model.name} ({model.sha256[:12]}…)"
            )
        check_standard_units(log, tuple(STANDARD_UNITS), str(path))
        xs.append(extractor.from_log(log, source=str(path)))
        ys.append(torque_error(model, log, target, source=str(path)))
        if cache is not None:
            cache[Path(path)] = (xs[-1], ys[-1])
    return np.concatenate(xs), np.concatenate(ys)
