"""Compare tracking without and with the learned feedforward (paper 003 section 3).

The same controller, the same gains, the same plant and the same seed run every task twice:
once without and once with the feedforward, which is the only difference. Tasks: the four
Table I tasks and held-out random tasks (the test runs of the compensator's split, never used
for training or early stopping). Writes, into one folder:

- ``comparison.json``: every metric of every run;
- ``trajectories_<task>.png``: joint angles without and with feedforward against the
  reference (paper 003 Fig. 7 and 8);
- ``error_statistics.png``: final end-effector error per task and cable length error per
  cable (mean and standard deviation over the tasks) without and with feedforward
  (paper 003 Fig. 9).

Besides, every run's final error from the plant's true joint angles (the ground truth of the
simulation, which a real robot does not have) is kept next to the encoders' one: it tells how
much of a small final error is the encoders' noise. ``parts`` runs more variants of the
feedforward on the same tasks (the sheath stage alone, say) to show what each part does.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from msarm import plots
from msarm.compensation.dataset import reusable_run
from msarm.control import ArmControllerConfig
from msarm.errors import InputError
from msarm.io.atomic import write_json_atomic
from msarm.io.logs import read_log, read_sidecar
from msarm.model import RobotModel
from msarm.plant import PlantConfig
from msarm.tasks.evaluate import (
    SETTLE_DELAY,
    TrackingMetrics,
    evaluate_run,
    hand_position,
)
from msarm.tasks.registry import get_task
from msarm.tasks.runner import Feedforward
from msarm.tasks.track import TrackSettings, track

__all__ = ["SHEATH_ONLY", "Comparison", "compare_feedforward"]

WITHOUT, WITH = "without feedforward", "with feedforward"
#: Label of the sheath stage run alone (``msarm compare --parts``).
SHEATH_ONLY = "sheath stage alone"


@dataclass(frozen=True)
class Comparison:
    """Metrics of every task without and with feedforward.

    Attributes:
        tasks: Task names, in order.
        held_out: The subset of ``tasks`` that are held-out random tasks.
        metrics: ``metrics[task][label]``, labels :data:`WITHOUT`, :data:`WITH` and those of
            the parts.
        true_final_error_mm: ``[task][label]``: the final error of the plant's true joint
            angles [mm] (simulation ground truth; the metrics' is the encoders').
        files: Files written (plots, JSON).
        true_min_insertion_tension: ``[task][label]``: the lowest tension any cable had at
            its insertion over the run [N] (simulation ground truth). The metrics' tension
            bounds are read from the load cells at the motors; a sheath stage asks a motor
            for less than the allocation's floor while its cable pays out, because the
            sheath then delivers more at the insertion.
    """

    tasks: tuple[str, ...]
    held_out: tuple[str, ...]
    metrics: dict[str, dict[str, TrackingMetrics]]
    true_final_error_mm: dict[str, dict[str, float]]
    files: dict[str, Path]
    true_min_insertion_tension: dict[str, dict[str, float]]

    @property
    def labels(self) -> tuple[str, ...]:
        """The variants run: :data:`WITHOUT`, :data:`WITH`, then the parts."""
        return tuple(self.metrics[self.tasks[0]])

    def mean_final_error(self, tasks: Sequence[str], label: str, true: bool = False) -> float:
        """Mean final error of ``label`` over ``tasks`` [mm].

        The encoders' final errors, or with ``true`` those of the true joint angles.
        """
        if true:
            return float(np.mean([self.true_final_error_mm[t][label] for t in tasks]))
        return float(np.mean([self.metrics[t][label].final_error_mm for t in tasks]))

    def ratio(self, tasks: Sequence[str], label: str = WITH, true: bool = False) -> float:
        """Mean final error without over mean final error of ``label``, over ``tasks``.

        With ``true``, of the final errors of the true joint angles.
        """
        with_ff = self.mean_final_error(tasks, label, true)
        without = self.mean_final_error(tasks, WITHOUT, true)
        return without / with_ff if with_ff > 0 else float("inf")

    def as_dict(self) -> dict:
        """JSON-ready form."""
        table1 = [t for t in self.tasks if t.startswith("table1")]
        return {
            "tasks": list(self.tasks),
            "held_out": list(self.held_out),
            "metrics": {
                task: {label: m.as_dict() for label, m in runs.items()}
                for task, runs in self.metrics.items()
            },
            "true_final_error_mm": self.true_final_error_mm,
            "true_min_insertion_tension_N": self.true_min_insertion_tension,
            "final_error_ratio_held_out": self.ratio(self.held_out) if self.held_out else None,
            "final_error_ratio_table1": self.ratio(table1),
            "true_final_error_ratio_held_out": (
                self.ratio(self.held_out, true=True) if self.held_out else None
            ),
            "true_final_error_ratio_table1": self.ratio(table1, true=True),
            "files": {kind: str(path) for kind, path in self.files.items()},
        }


def compare_feedforward(
    model: RobotModel,
    feedforward: Feedforward,
    plant: PlantConfig,
    controller: ArmControllerConfig,
    held_out_seeds: Sequence[int],
    out_dir: Path,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
    parts: Mapping[str, Feedforward] | None = None,
    feedforward_id: str = "",
    resume: bool = True,
) -> Comparison:
    """Run the Table I tasks and the held-out random tasks without and with feedforward.

    Args:
        model: The arm.
        feedforward: The learned feedforward.
        plant: The plant (the same for both).
        controller: The controller's gains (the same for both).
        held_out_seeds: Seeds of the held-out random tasks (the compensator's test runs).
        out_dir: Folder for the runs, plots and JSON.
        seed: Seed of the plant's noise for the Table I tasks (a random task uses its own).
        progress: Called with a label before each run.
        parts: More feedforwards to run on the same tasks, by label (e.g. :data:`SHEATH_ONLY`).
        feedforward_id: What identifies the feedforward and its parts (``msarm compare``
            gives :meth:`~msarm.compensation.checkpoint.Compensator.behaviour_sha256`),
            recorded in each run's config; runs with feedforward are reused only when it is
            given and the same.
        resume: Reuse a run already in ``out_dir`` when it is this one, whole, undiverged
            and of this model file (:func:`~msarm.compensation.dataset.reusable_run`): an
            interrupted comparison goes on where it stopped, with the same numbers (the
            metrics are computed again from the kept log; its label ends in ``(cached)``).

    Returns:
        The comparison.
    """
    out_dir = Path(out_dir)
    tasks = [f"table1-{k}" for k in range(1, 5)] + [f"random-{s}" for s in held_out_seeds]
    held_out = tuple(f"random-{s}" for s in held_out_seeds)
    variants: list[tuple[str, Feedforward | None, str]] = [
        (WITHOUT, None, "without_ff"),
        (WITH, feedforward, "with_ff"),
    ]
    for label, part in (parts or {}).items():
        if label in (WITHOUT, WITH):
            raise InputError(f"parts: the label {label!r} is taken; expected another name")
        variants.append((label, part, label.replace(" ", "_")))
    metrics: dict[str, dict[str, TrackingMetrics]] = {}
    true_final: dict[str, dict[str, float]] = {}
    lowest: dict[str, dict[str, float]] = {}
    columns: dict[str, dict[str, dict]] = {}
    for name in tasks:
        task = get_task(name, model)
        run_seed = int(name.split("-")[1]) if name.startswith("random-") else seed
        metrics[name], columns[name], true_final[name], lowest[name] = {}, {}, {}, {}
        target = hand_position(model, task.target)[0]
        for label, ff, folder_name in variants:
            ff_name = f"{folder_name}@{feedforward_id}" if ff and feedforward_id else folder_name
            settings = TrackSettings(name, run_seed, plant, controller, ff_name if ff else "")
            folder = out_dir / name / folder_name
            kept = (
                resume
                and (ff is None or bool(feedforward_id))
                and reusable_run(folder, settings, model.sha256)
            )
            if progress is not None:
                progress(f"{name}, {label}" + (" (cached)" if kept else ""))
            if kept:
                run_columns = dict(read_log(folder / "log.parquet").columns)
                truth = read_sidecar(folder / "log.parquet").columns
                metrics[name][label] = evaluate_run(
                    model,
                    run_columns,
                    home=task.home,
                    target=task.target,
                    drum_radius=plant.winch.drum_radius,
                    min_tension=controller.min_tension,
                )
            else:
                result = track(model, task, settings, folder, feedforward=ff, plots_too=False)
                metrics[name][label] = result.metrics
                run_columns, truth = result.run.columns, result.run.truth
            columns[name][label] = run_columns
            q_true = np.array([truth[f"q.{j}"][-1] for j in model.joint_names])
            true_final[name][label] = 1000.0 * float(
                np.linalg.norm(hand_position(model, q_true)[0] - target)
            )
            lowest[name][label] = float(
                min(np.min(truth[f"tension_insertion.{c}"]) for c in model.cable_names)
            )
    files: dict[str, Path] = {}
    for name in tasks[:4] + list(held_out[:2]):
        files[f"trajectories_{name}"] = plots.plot_joint_tracking(
            columns[name][WITHOUT],
            model.joint_names,
            out_dir / f"trajectories_{name}.png",
            title=f"{name}: without (measured) and with feedforward",
            others={label: columns[name][label] for label, _, _ in variants[1:]},
        )
    files["error_statistics"] = _plot_error_statistics(
        metrics, tasks, model.cable_names, out_dir / "error_statistics.png"
    )
    comparison = Comparison(tuple(tasks), held_out, metrics, true_final, files, lowest)
    files["json"] = out_dir / "comparison.json"
    write_json_atomic(files["json"], comparison.as_dict())
    return comparison


def _legend_above(ax: plt.Axes, columns: int) -> None:
    """The legend in one row above the axes, where it hides no bar."""
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=columns, frameon=False)


def _plot_error_statistics(
    metrics: dict[str, dict[str, TrackingMetrics]],
    tasks: Sequence[str],
    cable_names: Sequence[str],
    path: Path,
) -> Path:
    fig, (ax_settle, ax_final, ax_cable) = plt.subplots(
        1, 3, figsize=(18, 4.5), layout="constrained"
    )
    x = np.arange(len(tasks))
    labels = list(metrics[tasks[0]])
    width = 0.8 / len(labels)
    offsets = [(k - (len(labels) - 1) / 2) * width for k in range(len(labels))]
    for ax, key, ylabel in (
        (
            ax_settle,
            "settle_error_mm",
            f"end-effector error {SETTLE_DELAY:g} s after the move [mm]",
        ),
        (ax_final, "final_error_mm", "final end-effector error [mm]"),
    ):
        for offset, label in zip(offsets, labels, strict=True):
            values = [getattr(metrics[t][label], key) for t in tasks]
            ax.bar(x + offset, values, width, label=label)
        ax.set_xticks(x, tasks, rotation=30, ha="right")
        ax.set_ylabel(ylabel)
        _legend_above(ax, len(labels))
    c = np.arange(len(cable_names))
    for offset, label in zip(offsets, labels, strict=True):
        values = np.array([metrics[t][label].cable_length_error_percent for t in tasks])
        ax_cable.bar(
            c + offset, values.mean(axis=0), width, yerr=values.std(axis=0), capsize=3, label=label
        )
    ax_cable.set_xticks(c, cable_names, rotation=30, ha="right")
    ax_cable.set_ylabel("cable length error [% of travel]")
    ax_cable.set_xlabel("mean ± std over the tasks", fontsize=9)
    _legend_above(ax_cable, len(labels))
    fig.suptitle("error statistics without and with feedforward (paper 003 Fig. 9)")
    return plots.save_figure(fig, path)
