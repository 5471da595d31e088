"""Compare tracking without and with the learned feedforward (paper 003 section 3).

The same controller, the same gains, the same plant and the same seed run every task twice:
once without and once with the feedforward, which is the only difference. Tasks: the four
Table I tasks and held-out random tasks (the test runs of the compensator's split, never used
for training or early stopping). Writes, into one folder:

- ``comparison.json``: every metric of every run;
- ``trajectories_<task>.png``: joint angles without and with feedforward against the
  reference (paper 003 Fig. 7 and 8), each joint with a panel of its tracking error
  ``q - q_ref`` [mrad] under it;
- ``error_statistics.png`` (:func:`plot_error_statistics`): per task the end-effector error
  0.5 s after the move, the final error (the encoders' and the true joint angles', with the
  encoders' noise floor) and the time outside the tension bounds; per cable the cable length
  error of every task; without and with feedforward (paper 003 Fig. 9).

Besides, every run's final error from the plant's true joint angles (the ground truth of the
simulation, which a real robot does not have) is kept next to the encoders' one: it tells how
much of a small final error is the encoders' noise. ``parts`` runs more variants of the
feedforward on the same tasks (the sheath stage alone, say) to show what each part does.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter
from matplotlib.transforms import blended_transform_factory

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
    encoder_noise_floor,
    evaluate_run,
    hand_position,
)
from msarm.tasks.registry import get_task
from msarm.tasks.runner import Feedforward
from msarm.tasks.track import TrackSettings, track

__all__ = ["SHEATH_ONLY", "Comparison", "compare_feedforward", "plot_error_statistics"]

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
        encoder_noise_floor_mm: ``[task]``: the final error [mm] that the joint encoders'
            noise alone reads on average at the task's target
            (:func:`~msarm.tasks.evaluate.encoder_noise_floor`); empty when the plant's
            encoders have no noise.
    """

    tasks: tuple[str, ...]
    held_out: tuple[str, ...]
    metrics: dict[str, dict[str, TrackingMetrics]]
    true_final_error_mm: dict[str, dict[str, float]]
    files: dict[str, Path]
    true_min_insertion_tension: dict[str, dict[str, float]]
    encoder_noise_floor_mm: dict[str, float] = field(default_factory=dict)

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
            "encoder_noise_floor_mm": self.encoder_noise_floor_mm,
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
    noise = plant.effects.sensor_noise
    floor: dict[str, float] = {}
    if noise.enabled and noise.joint_noise > 0:
        for name in tasks:
            posture = get_task(name, model).target
            floor[name] = 1000.0 * encoder_noise_floor(model, posture, noise.joint_noise)
    files: dict[str, Path] = {}
    comparison = Comparison(tuple(tasks), held_out, metrics, true_final, files, lowest, floor)
    # the results go last and the old ones first: a folder with comparison.json holds one
    # whole comparison, not new plots beside an old run's results (a review's kill during
    # the plots left such a mix)
    (out_dir / "comparison.json").unlink(missing_ok=True)
    for name in tasks[:4] + list(held_out[:2]):
        kind = " (held out)" if name in held_out else ""
        files[f"trajectories_{name}"] = plots.plot_joint_tracking(
            columns[name][WITHOUT],
            model.joint_names,
            out_dir / f"trajectories_{name}.png",
            title=f"{name}{kind} on the {plant.name} plant: without and with feedforward",
            others={label: columns[name][label] for label, _, _ in variants[1:]},
            label=WITHOUT,
            error_panels=True,
        )
    files["error_statistics"] = plot_error_statistics(
        comparison, model.cable_names, out_dir / "error_statistics.png", plant.name
    )
    files["json"] = out_dir / "comparison.json"
    write_json_atomic(files["json"], comparison.as_dict())
    return comparison


#: Hatch of the bars of the true joint angles' final error in ``error_statistics.png``.
TRUE_HATCH = "////"


def _log_if_decades(ax: plt.Axes, values: Sequence[float]) -> None:
    """A log y-axis where the positive values span more than a decade (and none is <= 0)."""
    finite = np.array([v for v in values if np.isfinite(v)], dtype=float)
    if len(finite) and np.all(finite > 0) and finite.max() > 10.0 * finite.min():
        ax.set_yscale("log")
        ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.yaxis.set_minor_formatter(NullFormatter())


def _task_axis(ax: plt.Axes, tasks: Sequence[str], held_out: Sequence[str]) -> None:
    """Task names on the x axis; the held-out tasks set apart by a line and named above."""
    x = np.arange(len(tasks))
    ax.set_xticks(x, tasks, rotation=30, ha="right")
    table1 = [k for k, t in enumerate(tasks) if t not in held_out]
    out = [k for k, t in enumerate(tasks) if t in held_out]
    for label in ax.get_xticklabels():
        if label.get_text() in held_out:
            label.set_fontstyle("italic")
    top = blended_transform_factory(ax.transData, ax.transAxes)
    if table1 and out:
        ax.axvline(max(table1) + 0.5, color="0.5", ls=":", lw=1.0)
    for group, name in ((table1, "Table I"), (out, "held out")):
        if group:
            ax.text(
                np.mean(group),
                0.98,
                name,
                transform=top,
                ha="center",
                va="top",
                fontsize=9,
                color="0.3",
            )


def plot_error_statistics(
    comparison: Comparison,
    cable_names: Sequence[str],
    path: Path,
    plant_name: str = "",
) -> Path:
    """``error_statistics.png``: the comparison's errors, without and with feedforward.

    Four panels, one colour per variant (:attr:`Comparison.labels`), the held-out tasks set
    apart from the Table I tasks:

    - end-effector error :data:`~msarm.tasks.evaluate.SETTLE_DELAY` after the move, per task;
    - final end-effector error per task: the encoders' (plain bars, the metric) and the true
      joint angles' (hatched bars, simulation ground truth), with the mean error that the
      encoders' noise alone reads at each task's target as a black line (where
      :attr:`Comparison.encoder_noise_floor_mm` has it);
    - time outside the tension bounds per task (load cells, summed over the cables);
    - cable length error per cable, one point per task (circles Table I, triangles held
      out), no mean ± std of a positive quantity.

    The end-effector panels have a log y-axis where their values span more than a decade.

    Args:
        comparison: The comparison.
        cable_names: Cable names, in the order of the metrics' per-cable values.
        path: PNG file to write.
        plant_name: The plant, named in the title if given.

    Returns:
        The path written.
    """
    tasks, held_out, metrics = comparison.tasks, comparison.held_out, comparison.metrics
    labels = comparison.labels
    colors = {label: f"C{k}" for k, label in enumerate(labels)}
    fig, axes = plt.subplots(2, 2, figsize=(16, 9.5), layout="constrained")
    (ax_settle, ax_final), (ax_bounds, ax_cable) = axes
    x = np.arange(len(tasks))
    width = 0.8 / len(labels)
    offsets = [(k - (len(labels) - 1) / 2) * width for k in range(len(labels))]

    settle = []
    for offset, label in zip(offsets, labels, strict=True):
        values = [metrics[t][label].settle_error_mm for t in tasks]
        settle += values
        ax_settle.bar(x + offset, values, width, color=colors[label], label=label)
    ax_settle.set_ylabel(f"end-effector error {SETTLE_DELAY:g} s after the move [mm]")
    _log_if_decades(ax_settle, settle)

    half = width / 2
    final = []
    for offset, label in zip(offsets, labels, strict=True):
        encoders = [metrics[t][label].final_error_mm for t in tasks]
        true = [comparison.true_final_error_mm[t][label] for t in tasks]
        final += encoders + true
        ax_final.bar(x + offset - half / 2, encoders, half, color=colors[label], label=label)
        ax_final.bar(
            x + offset + half / 2,
            true,
            half,
            color=colors[label],
            alpha=0.55,
            hatch=TRUE_HATCH,
            edgecolor="white",
            lw=0,
        )
    handles = [
        Patch(color="0.45", label="encoders (the metric)"),
        Patch(
            facecolor="0.45",
            alpha=0.55,
            hatch=TRUE_HATCH,
            edgecolor="white",
            lw=0,
            label="true joint angles (simulation)",
        ),
    ]
    floor = comparison.encoder_noise_floor_mm
    if floor:
        drawn = False
        for k, task in enumerate(tasks):
            if floor.get(task, 0.0) > 0:
                ax_final.hlines(floor[task], k - 0.45, k + 0.45, color="k", lw=1.5)
                final.append(floor[task])
                drawn = True
        if drawn:
            handles.append(Line2D([], [], color="k", lw=1.5, label="encoder noise floor"))
    ax_final.set_ylabel("final end-effector error [mm]")
    _log_if_decades(ax_final, final)
    ax_final.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(0.0, 0.93))

    for offset, label in zip(offsets, labels, strict=True):
        values = [sum(metrics[t][label].time_outside_bounds) for t in tasks]
        ax_bounds.bar(x + offset, values, width, color=colors[label], label=label)
    ax_bounds.set_ylabel("time outside tension bounds [s]")
    ax_bounds.set_title("load cells, summed over the cables", fontsize=9)

    for ax in (ax_settle, ax_final, ax_bounds):
        _task_axis(ax, tasks, held_out)
        ax.margins(y=0.12)

    c = np.arange(len(cable_names))
    spread = np.linspace(-0.3, 0.3, len(tasks)) * width if len(tasks) > 1 else np.zeros(1)
    for offset, label in zip(offsets, labels, strict=True):
        for k, task in enumerate(tasks):
            ax_cable.plot(
                c + offset + spread[k],
                metrics[task][label].cable_length_error_percent,
                "^" if task in held_out else "o",
                color=colors[label],
                ms=4,
                alpha=0.8,
                ls="none",
            )
    ax_cable.set_xticks(c, cable_names, rotation=30, ha="right")
    ax_cable.set_ylabel("cable length error [% of travel]")
    ax_cable.set_ylim(bottom=0)
    ax_cable.set_title("one point per task", fontsize=9)
    ax_cable.legend(
        handles=[
            Line2D([], [], marker="o", color="0.45", ls="none", label="Table I task"),
            Line2D([], [], marker="^", color="0.45", ls="none", label="held-out task"),
        ],
        fontsize=8,
    )
    fig.legend(
        handles=[Patch(color=colors[label], label=label) for label in labels],
        loc="outside lower center",
        ncol=len(labels),
        frameon=False,
    )
    where = f" on the {plant_name} plant" if plant_name else ""
    fig.suptitle(f"error statistics without and with feedforward{where} (paper 003 Fig. 9)")
    return plots.save_figure(fig, path)
