"""Run a tracking task and write everything a user looks at afterwards.

:func:`track` runs one task on one plant with the paper 003 controller (and an optional
feedforward compensator) and writes, into one folder (atomically, file by file):

- ``log.parquet``: the log in the documented schema (sensors, references, commands);
- ``log.truth.parquet``: the sim-only ground truth sidecar (never read by a diagnosis);
- ``config.yaml``: the resolved plant, controller and task settings and the seed;
- ``metrics.json``: the metrics of paper 003 (see :mod:`msarm.tasks.evaluate`) and the
  fingerprint of the code that made the run (``code``,
  :func:`msarm.io.code_version.code_fingerprint`), by which the caches of ``msarm train``,
  ``msarm compare`` and ``msarm bench diagnose`` tell their runs from another version's;
- ``joints.png`` and ``tensions.png``: joint angles against the reference, cable tensions.

A run that diverges keeps its partial log and reports the divergence in ``metrics.json``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msarm import plots
from msarm.control import ArmControllerConfig, MuscleSpaceController
from msarm.io.atomic import folder_for_writing, write_json_atomic
from msarm.io.code_version import code_fingerprint
from msarm.io.config import config_to_dict, write_config
from msarm.io.logs import LogMetadata, RunLog, write_log, write_sidecar
from msarm.model import RobotModel
from msarm.plant import ArmPlant, PlantConfig
from msarm.tasks.evaluate import TrackingMetrics, evaluate_run
from msarm.tasks.runner import LOG_UNITS, TRUTH_UNITS, Feedforward, TrackingRun, run_tracking
from msarm.tasks.trajectories import Task

__all__ = ["TrackResult", "TrackSettings", "run_title", "track"]


@dataclass(frozen=True)
class TrackSettings:
    """Everything that defines a tracking run (written as ``config.yaml``).

    Attributes:
        task: Task name.
        seed: Seed of the plant (sensor noise).
        plant: The plant.
        controller: The controller's gains and settings.
        feedforward: Path of the feedforward checkpoint, or "" for none.
    """

    task: str
    seed: int
    plant: PlantConfig
    controller: ArmControllerConfig
    feedforward: str = ""


@dataclass(frozen=True)
class TrackResult:
    """What :func:`track` produced.

    Attributes:
        run: The run (log and truth columns).
        metrics: Its metrics.
        files: The files written, by kind (``log``, ``sidecar``, ``config``, ``metrics``,
            ``joints_plot``, ``tensions_plot``); empty when nothing was written.
    """

    run: TrackingRun
    metrics: TrackingMetrics
    files: dict[str, Path]


#: The plots a run writes (and a new run in its folder removes first).
PLOT_FILES = ("joints.png", "tensions.png")


def run_title(task: str, settings: TrackSettings, with_feedforward: bool) -> str:
    """The title of a run's plots: task, plant, the feedforward if any, the seed if not 0.

    ``"<task> on the <plant> plant[, with feedforward (<checkpoint file name>)][, seed <s>]"``;
    the checkpoint is named by its file name (``settings.feedforward``), if given.
    """
    title = f"{task} on the {settings.plant.name} plant"
    if with_feedforward:
        name = Path(settings.feedforward).name if settings.feedforward else ""
        title += f", with feedforward ({name})" if name else ", with feedforward"
    if settings.seed != 0:
        title += f", seed {settings.seed}"
    return title


def track(
    model: RobotModel,
    task: Task,
    settings: TrackSettings,
    out_dir: Path | None = None,
    feedforward: Feedforward | None = None,
    progress: Callable[[float], None] | None = None,
    plots_too: bool = True,
) -> TrackResult:
    """Run ``task`` and, if ``out_dir`` is given, write its log, sidecar, config, metrics, plots.

    Args:
        model: The arm.
        task: The task (``msarm.tasks.registry.get_task``).
        settings: Plant, controller, seed (and the feedforward's name, for the record).
        out_dir: Folder for the outputs, created if needed; nothing is written if None.
        feedforward: The feedforward compensation, if any.
        progress: Progress callback (fraction done).
        plots_too: Also write the PNG plots.

    Returns:
        The run, its metrics and the files written.
    """
    plant = ArmPlant(model, settings.plant, seed=settings.seed)
    controller = MuscleSpaceController(model, settings.controller)
    run = run_tracking(plant, controller, task, feedforward=feedforward, progress=progress)
    metrics = evaluate_run(
        model,
        run.columns,
        home=task.home,
        target=task.target,
        drum_radius=settings.plant.winch.drum_radius,
        min_tension=settings.controller.min_tension,
        completed=run.completed,
    )
    files: dict[str, Path] = {}
    if out_dir is None:
        return TrackResult(run, metrics, files)
    # an interrupted write leaves no empty run folder of its own
    with folder_for_writing(out_dir) as out_dir:
        # metrics.json is written last and marks a whole run (msarm compare and msarm train reuse
        # such runs): an older run's must go before this run's files replace the others, or a run
        # cut off between them would pair this log with that run's metrics; so must its plots,
        # which a run too short to plot would otherwise leave beside this one's log
        for name in ("metrics.json", *PLOT_FILES):
            (out_dir / name).unlink(missing_ok=True)
        metadata = LogMetadata.for_model(
            model,
            sample_rate_hz=run.control_rate_hz,
            units=LOG_UNITS,
            controller_config=config_to_dict(settings.controller),
            extra={"task": task.name, "seed": settings.seed},
        )
        files["log"] = write_log(out_dir / "log.parquet", RunLog(run.columns, metadata))
        files["sidecar"] = write_sidecar(files["log"], run.truth, run.effects, TRUTH_UNITS)
        files["config"] = out_dir / "config.yaml"
        write_config(settings, files["config"])
        payload = {"task": task.name, "plant": settings.plant.name, **metrics.as_dict()}
        # the code that made the run: a cache reuses it only under the same code
        payload["code"] = code_fingerprint("simulation")
        if run.error is not None:
            payload["diverged"] = {"time": run.error.time, "message": str(run.error)}
        if plots_too and len(run.columns["t"]) > 1:
            title = run_title(task.name, settings, feedforward is not None)
            files["joints_plot"] = plots.plot_joint_tracking(
                run.columns, model.joint_names, out_dir / "joints.png", title=title
            )
            files["tensions_plot"] = plots.plot_cable_tensions(
                run.columns,
                model.cable_names,
                out_dir / "tensions.png",
                lower=settings.controller.min_tension,
                upper=np.asarray(model.muscles.max_isometric_force),
                title=title,
            )
        files["metrics"] = write_json_atomic(out_dir / "metrics.json", payload)
    return TrackResult(run, metrics, files)
