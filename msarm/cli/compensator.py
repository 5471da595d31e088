"""``msarm train`` and ``msarm compare``: the feedforward compensator's main job."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from msarm.cli.common import (
    PLANTS,
    check_control_period,
    check_controller_file,
    console,
    note_first_compile,
    output_folder,
    progress_bar,
    progress_lines,
    resolve_plant,
)
from msarm.errors import InputError

DEFAULT_RECIPE = Path("training/compensator.yaml")
DEFAULT_CHECKPOINT = Path("runs/compensator/compensator.pt")
#: First seed of the extra held-out random tasks of ``msarm compare --extra``.
EXTRA_FIRST_SEED = 5000
#: Columns of ``msarm compare``'s output when it is not a terminal: its table of nine columns
#: is wider than the 120 of the other commands, and was cut there (no right border).
COMPARE_WIDTH = 200


def train_command(
    config: Annotated[
        Path,
        typer.Option(
            help="Training recipe (YAML of CompensatorRecipe). Without the default file (outside "
            "the repository) the recipe's default values run: the same values."
        ),
    ] = DEFAULT_RECIPE,
    fresh: Annotated[
        bool,
        typer.Option(
            "--fresh",
            help="Ignore an interrupted training; start the training over (runs already "
            "collected with the same settings are still reused).",
        ),
    ] = False,
    json_output: Annotated[bool, typer.Option("--json", help="Print the report as JSON.")] = False,
) -> None:
    """Collect (or reuse) seeded runs on the plant and train the feedforward compensator."""
    from rich.progress import BarColumn, TextColumn, TimeRemainingColumn

    from msarm.compensation.dataset import split_runs
    from msarm.compensation.pipeline import (
        CompensatorRecipe,
        check_recipe_paths,
        check_recipe_plant,
        train_compensator,
    )
    from msarm.io.config import folder_instead_of_file, load_config
    from msarm.model import load_arm

    folder = folder_instead_of_file(config, "a training recipe file (YAML of CompensatorRecipe)")
    if folder is not None:
        raise InputError(f"--config: {folder}")
    recipe = load_config(config, CompensatorRecipe) if config.is_file() else None
    source = str(config)
    if recipe is None:
        if config != DEFAULT_RECIPE:
            raise InputError(f"{config}: recipe file not found")
        recipe = CompensatorRecipe()
        source = "the default recipe"
        typer.echo(
            f"msarm train: no {config} here: the recipe's default values (the same as the "
            "repository's file)",
            err=True,
        )
    arm = load_arm()
    plant_spec = recipe.data.plant
    beside = config.parent / plant_spec
    if plant_spec not in PLANTS and not Path(plant_spec).is_file() and beside.is_file():
        plant_spec = str(beside)  # a plant file next to the recipe, named relative to it
    try:
        plant = resolve_plant(plant_spec)
    except InputError as exc:
        raise InputError(f"{config}: data.plant: {exc}") from None
    # up front: found after collecting, these would lose the runs' minutes
    check_recipe_paths(recipe, source)
    check_recipe_plant(recipe, plant, source)
    check_controller_file(arm, recipe.controller, f"{source}: key 'controller'")
    check_control_period(
        recipe.controller,
        plant,
        f"{source}: controller.rate_hz",
        None if plant_spec in PLANTS else plant_spec,
    )
    split = split_runs(recipe.data.seeds, recipe.data.split)
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.fields[info]}"),
        TimeRemainingColumn(),
    )
    # progress on stderr (a bar on a terminal, else a line a step), with --json too
    note_first_compile("train")
    with progress_bar(*columns, transient=False) as bar:
        runs = bar.add_task("collect runs", total=recipe.data.n_runs, info="")
        epochs = bar.add_task("train", total=recipe.network.max_epochs, info="", visible=False)

        line = progress_lines("train")

        def on_run(done: int, total: int, reused: bool) -> None:
            bar.update(runs, completed=done, info=f"{done}/{total}{' (reused)' if reused else ''}")
            line(f"run {done}/{total} collected{' (reused)' if reused else ''}")

        def on_epoch(epoch: int, total: int, train_loss: float, val_loss: float) -> None:
            # every epoch (about a second each): early stopping ends a round after a few
            line(f"epoch {epoch}: train {train_loss:.4f}, validation {val_loss:.4f}")
            bar.update(
                epochs,
                visible=True,
                completed=epoch,
                info=f"epoch {epoch}: train {train_loss:.4f}, validation {val_loss:.4f}",
            )

        rerun = len(split.train) + len(split.validation)  # runs collected again per round

        def on_round(round_: int, rounds: int) -> None:
            label = f"round {round_}/{rounds}"
            line(label)
            if round_ > 0:  # round 0 trains on the runs already collected
                bar.update(runs, completed=0, total=rerun, description=f"collect runs, {label}")
            bar.update(epochs, completed=0, description=f"train, {label}")

        def on_sheath(parameters, total: int) -> None:
            line(f"sheath stage identified (mu {parameters.mu:.4f}); collecting with it")
            bar.update(
                runs,
                completed=0,
                total=total,
                description=f"collect runs with the sheath stage (mu {parameters.mu:.4f})",
            )

        report = train_compensator(
            arm,
            recipe,
            plant,
            resume=not fresh,
            on_run=on_run,
            on_epoch=on_epoch,
            on_round=on_round,
            on_sheath=on_sheath,
        )
        bar.update(epochs, completed=recipe.network.max_epochs)
    payload = {
        "checkpoint": str(report.checkpoint),
        "split": report.split,
        "samples": report.samples,
        "collect_time_s": report.collect_time_s,
        "train_time_s": report.train_time_s,
        "epochs_run": report.epochs[0],
        "best_epoch": report.epochs[1],
        "test_rmse_Nm": report.test_rmse,
        "test_baseline_rmse_Nm": report.test_baseline_rmse,
        "test_r2": report.test_r2,
        "sheath": None if report.sheath is None else report.sheath.as_dict(),
    }
    if json_output:
        typer.echo(json.dumps(payload, indent=2))
        return
    out = console()
    table = Table(title=escape("T_f prediction on the held-out test runs [N m]"))
    for column in ("joint", "RMSE", "RMS of T_f (predict 0)", "R²"):
        table.add_column(column, justify="left" if column == "joint" else "right")
    for k, joint in enumerate(arm.joint_names):
        table.add_row(
            joint,
            f"{report.test_rmse[k]:.3f}",
            f"{report.test_baseline_rmse[k]:.3f}",
            f"{report.test_r2[k]:.3f}",
        )
    out.print(table)
    if report.sheath is not None:
        p = report.sheath
        out.print(
            f"sheath stage: mu {p.mu:.4f} (held-out share of the joint residual "
            f"{p.mu_share:.2f}), cable compliance {p.compliance:.3g} m/N (of the length "
            f"residual {p.compliance_share:.2f}); the network learns what the stage leaves"
        )
    out.print(
        f"runs: train {report.split['train']}, validation {report.split['validation']}, "
        f"test {report.split['test']}; samples {report.samples}"
    )
    out.print(
        f"collected in {report.collect_time_s:.1f} s, trained in {report.train_time_s:.1f} s "
        f"(summed over the sessions that trained it; the last network: {report.epochs[0]} "
        f"epochs, the best at epoch {report.epochs[1]})"
    )
    out.print(f"checkpoint: {report.checkpoint}")


def compare_command(
    ff: Annotated[
        Path, typer.Option("--ff", help="Compensator checkpoint (from msarm train).")
    ] = DEFAULT_CHECKPOINT,
    plant: Annotated[
        str,
        typer.Option(help="default, ideal, a plant YAML file, or a run's config.yaml (its plant)."),
    ] = "default",
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("runs/compare"),
    seed: Annotated[int, typer.Option(min=0, help="Noise seed of the Table I runs.")] = 0,
    extra: Annotated[
        int,
        typer.Option(
            min=0,
            help=f"More held-out random tasks, random-{EXTRA_FIRST_SEED} on (never trained on): "
            "a steadier mean than the two test runs alone. They are in the table, the means and "
            "error_statistics.png; trajectory plots are drawn for Table I and the first two "
            "held-out tasks (the test runs, then these).",
        ),
    ] = 0,
    parts: Annotated[
        bool,
        typer.Option(
            "--parts",
            help="Also run the compensator's sheath stage alone (without the network), to see "
            "what each part does.",
        ),
    ] = False,
    json_output: Annotated[bool, typer.Option("--json", help="Print the results as JSON.")] = False,
    fresh: Annotated[
        bool,
        typer.Option(
            "--fresh",
            help="Simulate every run again (by default a run already in --out with the same "
            "task, plant, gains, seed, checkpoint, model and msarm code is reused: an interrupted "
            "comparison goes on where it stopped).",
        ),
    ] = False,
) -> None:
    """Table I tasks and held-out random tasks, without and with feedforward: table and plots."""
    # the summary also gives the final error of the plant's true joint angles (simulation
    # only): the table's comes from the encoders, whose noise is a good part of a final error
    # of a tenth of a millimetre
    from msarm.compensation.checkpoint import CheckpointError
    from msarm.compensation.compare import SHEATH_ONLY, compare_feedforward
    from msarm.compensation.feedforward import (
        LearnedFeedforward,
        load_feedforward,
        trained_controller,
        warn_if_other_plant,
    )
    from msarm.io.config import folder_instead_of_file
    from msarm.model import load_arm

    folder = folder_instead_of_file(
        ff,
        f"a compensator checkpoint file (what msarm train writes, by default {DEFAULT_CHECKPOINT})",
    )
    if folder is not None:
        raise CheckpointError(f"--ff: {folder}")
    if not ff.is_file():
        raise CheckpointError(f"--ff: no checkpoint at {ff}; run `msarm train` first, or give --ff")
    arm = load_arm()
    feedforward = load_feedforward(ff, arm)
    variants = {}
    if parts:
        if feedforward.sheath is None:
            raise typer.BadParameter(
                f"--parts: the compensator {ff} has no sheath stage (trained with "
                "sheath.enabled: false); nothing to run apart"
            )
        variants[SHEATH_ONLY] = LearnedFeedforward(arm, None, feedforward.sheath)
    split = feedforward.compensator.metadata.get("split")
    if not isinstance(split, dict) or not all(
        isinstance(split.get(k), list) for k in ("train", "validation", "test")
    ):
        raise CheckpointError(
            f"{ff}: records no run split (metadata 'split' with train, validation and test "
            "seeds), so its held-out tasks are unknown; expected a compensator written by "
            "msarm train"
        )
    held_out = list(split["test"])
    seen = set(split["train"]) | set(split["validation"])
    more = [EXTRA_FIRST_SEED + k for k in range(extra)]
    if seen & set(more):
        raise typer.BadParameter(
            f"--extra {extra}: the tasks random-{sorted(seen & set(more))} were trained on; "
            f"expected fewer extra tasks (the compensator's runs are {sorted(seen)})"
        )
    held_out += [s for s in more if s not in held_out]
    gains = trained_controller(feedforward.compensator)
    plant_config = resolve_plant(plant)
    warn_if_other_plant(feedforward.compensator, plant_config, str(ff))
    # before the output folder is made: the runner would refuse it at the start of a run
    check_control_period(
        gains,
        plant_config,
        f"the gains recorded in {ff}: rate_hz",
        None if plant in PLANTS else plant,
    )
    out_dir = output_folder(out)
    n_runs = (2 + len(variants)) * (4 + len(held_out))
    line = progress_lines("compare", n_runs)
    note_first_compile("compare")
    with progress_bar() as bar:
        job = bar.add_task("compare", total=n_runs)

        def step(label: str) -> None:
            bar.update(job, advance=1, description=label)
            line(label)

        result = compare_feedforward(
            arm,
            feedforward,
            plant_config,
            gains,
            held_out,
            out_dir,
            seed=seed,
            progress=step,
            parts=variants,
            # what the compensator does, not its file's bytes (a retraining to the same
            # network writes other times in the file: its runs are still reused)
            feedforward_id=feedforward.compensator.behaviour_sha256(),
            resume=not fresh,
        )
    if json_output:
        typer.echo(json.dumps(result.as_dict(), indent=2))
        return
    out_console = console(width=COMPARE_WIDTH)
    out_console.print(comparison_table(result, arm.joint_names))
    for group, tasks in (
        ("held-out random tasks", list(result.held_out)),
        ("Table I tasks", [t for t in result.tasks if t.startswith("table1")]),
    ):
        if tasks:
            for line in summary_lines(result, group, tasks):
                out_console.print(line)
    for kind, path in result.files.items():
        out_console.print(f"{kind}: {path}")


def summary_lines(result, group: str, tasks: list[str]) -> list[str]:
    """Means over ``tasks``: the feedforward against none, then each part against none."""
    from msarm.compensation.compare import WITH, WITHOUT
    from msarm.tasks.evaluate import SETTLE_DELAY

    def mean(label: str, key: str) -> float:
        return float(np.mean([np.mean(getattr(result.metrics[t][label], key)) for t in tasks]))

    def final(label: str, true: bool = False) -> float:
        return result.mean_final_error(tasks, label, true)

    def outside(label: str) -> float:
        return float(np.mean([sum(result.metrics[t][label].time_outside_bounds) for t in tasks]))

    def lowest(label: str) -> float:
        return min(result.true_min_insertion_tension[t][label] for t in tasks)

    def largest(label: str, key: str) -> float:
        return max(max(getattr(result.metrics[t][label], key)) for t in tasks)

    lines = []
    for label in result.labels[1:]:
        name = "feedforward" if label == WITH else label
        lines.append(
            f"{group}, {name}: mean final error {final(WITHOUT):.2f} mm "
            f"without, {final(label):.2f} mm with (ratio "
            f"{result.ratio(tasks, label):.2f}; of the true joint angles "
            f"{final(WITHOUT, True):.2f} -> {final(label, True):.2f} mm, ratio "
            f"{result.ratio(tasks, label, true=True):.2f}); mean joint RMSE "
            f"{1000 * mean(WITHOUT, 'joint_rmse'):.1f} -> {1000 * mean(label, 'joint_rmse'):.1f} "
            f"mrad; mean error {SETTLE_DELAY:g} s after the move "
            f"{mean(WITHOUT, 'settle_error_mm'):.2f} -> {mean(label, 'settle_error_mm'):.2f} mm; "
            f"time outside the tension bounds (load cells, all cables) "
            f"{outside(WITHOUT):.1f} -> {outside(label):.1f} s a task; lowest tension at an "
            f"insertion (simulation) {lowest(WITHOUT):.2f} -> {lowest(label):.2f} N; largest "
            f"cable length error {largest(WITHOUT, 'cable_length_error_percent'):.2f} -> "
            f"{largest(label, 'cable_length_error_percent'):.2f} % of the travel (eq. 12-13), "
            f"at the end {largest(WITHOUT, 'cable_length_end_percent'):.2f} -> "
            f"{largest(label, 'cable_length_end_percent'):.2f} % of the length (as paper 003 "
            "section 3.2 reports it)"
        )
    return lines


def comparison_table(result, joint_names) -> Table:
    """The table of paper 003 section 3: each task without and with feedforward."""
    from msarm.compensation.compare import WITH, WITHOUT
    from msarm.tasks.evaluate import SETTLE_DELAY

    table = Table(title="tracking without / with feedforward (same controller, same plant)")
    for column in (
        "task",
        "final error [mm]",
        "final error [%]",
        f"error {SETTLE_DELAY:g} s after the move [mm]",
        "joint RMSE [mrad] (mean)",
        "cable length error [% travel]",
        "cable length at the end [% of length]",
        "slack events",
        "time outside tension bounds [s]",
    ):
        if column == "task":  # the name whole (random-1013 was cut to "random-10…")
            longest = max((len(task) for task in result.tasks), default=4)
            table.add_column(column, justify="left", min_width=longest)
        else:
            table.add_column(escape(column), justify="right")
    for task in result.tasks:
        a, b = result.metrics[task][WITHOUT], result.metrics[task][WITH]
        label = f"{task}{' (held out)' if task in result.held_out else ''}"
        table.add_row(
            label,
            f"{a.final_error_mm:.2f} / {b.final_error_mm:.2f}",
            f"{a.final_error_percent:.2f} / {b.final_error_percent:.2f}",
            f"{a.settle_error_mm:.2f} / {b.settle_error_mm:.2f}",
            f"{1000 * np.mean(a.joint_rmse):.1f} / {1000 * np.mean(b.joint_rmse):.1f}",
            f"{min(a.cable_length_error_percent):.2f}-{max(a.cable_length_error_percent):.2f} / "
            f"{min(b.cable_length_error_percent):.2f}-{max(b.cable_length_error_percent):.2f}",
            f"{min(a.cable_length_end_percent):.2f}-{max(a.cable_length_end_percent):.2f} / "
            f"{min(b.cable_length_end_percent):.2f}-{max(b.cable_length_end_percent):.2f}",
            f"{sum(a.slack_events)} / {sum(b.slack_events)}",
            f"{sum(a.time_outside_bounds):.1f} / {sum(b.time_outside_bounds):.1f}",
        )
    return table
