"""``msarm track``: run a tracking task on a plant, print its metrics, write log and plots."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

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
    read_config_section,
    resolve_plant,
    seed_suffix,
)

if TYPE_CHECKING:
    from msarm.control import ArmControllerConfig

ListOption = Annotated[
    bool,
    typer.Option(
        "--list", help="List the tasks, plants and effects (with --json: as JSON), and exit."
    ),
]


def list_choices(as_json: bool = False) -> None:
    """Print the tasks, plants and effects a user can choose from (tables, or JSON)."""
    from msarm.plant.config import DEFAULT_PLANT, EFFECT_NAMES
    from msarm.plant.effects import EFFECT_DESCRIPTIONS
    from msarm.tasks.registry import list_tasks

    if as_json:
        import json

        choices = {
            "tasks": list_tasks(),
            "plants": {name: list(config.effects.enabled()) for name, config in PLANTS.items()},
            "effects": {
                name: {
                    "default_plant": getattr(DEFAULT_PLANT.effects, name).enabled,
                    "equation": EFFECT_DESCRIPTIONS[name],
                }
                for name in EFFECT_NAMES
            },
        }
        print(json.dumps(choices, indent=2))
        return
    out = console()
    tasks = Table(title="tasks (--task)")
    tasks.add_column("name")
    tasks.add_column("what")
    for name, text in list_tasks().items():
        tasks.add_row(name, text)
    out.print(tasks)
    plants = Table(title="plants (--plant): a preset or a YAML file of msarm.plant.PlantConfig")
    plants.add_column("name")
    plants.add_column("effects on")
    for name, config in PLANTS.items():
        plants.add_row(name, ", ".join(config.effects.enabled()) or "none")
    out.print(plants)
    effects = Table(title="effects (switches in a plant YAML under effects.<name>.enabled)")
    for column in ("effect", "default plant", "equation"):
        effects.add_column(column)
    for name in EFFECT_NAMES:
        on = getattr(DEFAULT_PLANT.effects, name).enabled
        effects.add_row(name, "on" if on else "off", EFFECT_DESCRIPTIONS[name])
    out.print(effects)


def metrics_table(title: str, rows: dict[str, object], joint_names, cable_names) -> Table:
    """A table of one or more runs' metrics side by side (``rows``: label -> metrics)."""
    from msarm.tasks.evaluate import SETTLE_DELAY

    table = Table(title=title)
    table.add_column("metric")
    for label in rows:
        table.add_column(label, justify="right")

    def add(name: str, values) -> None:
        table.add_row(escape(name), *values)

    metrics = list(rows.values())
    add("final error [mm]", [f"{m.final_error_mm:.2f}" for m in metrics])
    add("final error [% displacement]", [f"{m.final_error_percent:.2f}" for m in metrics])
    add(
        f"error {SETTLE_DELAY:g} s after the move [mm]",
        [f"{m.settle_error_mm:.2f}" for m in metrics],
    )
    for k, joint in enumerate(joint_names):
        add(f"RMSE {joint} [mrad]", [f"{1000 * m.joint_rmse[k]:.1f}" for m in metrics])
    add(
        "cable length error [% travel]",
        [
            f"{min(m.cable_length_error_percent):.2f}-{max(m.cable_length_error_percent):.2f}"
            for m in metrics
        ],
    )
    add(
        "cable length at the end [% of length]",
        [
            f"{min(m.cable_length_end_percent):.2f}-{max(m.cable_length_end_percent):.2f}"
            for m in metrics
        ],
    )
    add("slack events (all cables)", [str(sum(m.slack_events)) for m in metrics])
    add(
        "time outside bounds [s] (sum)",
        [f"{sum(m.time_outside_bounds):.2f}" for m in metrics],
    )
    add("completed", ["yes" if m.completed else "DIVERGED" for m in metrics])
    return table


def default_folder(task: str, plant: str, seed: int, ff: bool) -> Path:
    """``runs/track-<task>-<plant>[-s<seed>][-ff]``: the default output folder of a run.

    The seed is named when it is not 0 (seed 0 keeps the plain name), so that runs of other
    seeds are not written over each other; ``-ff`` keeps a run with feedforward from
    overwriting one without.
    """
    return Path("runs") / f"track-{task}-{plant}{seed_suffix(seed)}{'-ff' if ff else ''}"


def _over_trained_gains(
    gains: ArmControllerConfig,
    given_keys: set[str],
    trained: ArmControllerConfig,
    controller: Path,
    ff: Path,
) -> ArmControllerConfig:
    """The trained gains with those a ``--controller`` file gives, and a warning if they differ.

    A file that gives only some gains (``kp`` alone, say) keeps the compensator's others,
    not :class:`ArmControllerConfig`'s defaults (which are the ideal plant's).
    """
    import dataclasses
    import warnings

    from msarm.control import ArmControllerConfig
    from msarm.errors import MsarmWarning

    fields = {f.name for f in dataclasses.fields(ArmControllerConfig)}
    chosen = dataclasses.replace(
        trained, **{key: getattr(gains, key) for key in given_keys & fields}
    )
    differ = [key for key in sorted(fields) if getattr(chosen, key) != getattr(trained, key)]
    if differ:
        warnings.warn(
            f"--controller {controller}: {', '.join(differ)} differ from the gains the "
            f"compensator {ff} was trained with (its feedforward was learned under them); "
            "the others are the trained ones",
            MsarmWarning,
            stacklevel=2,
        )
    return chosen


def track_command(
    task: Annotated[
        str, typer.Option(help="Task name: table1-1 ... table1-4, random-<seed>.")
    ] = "table1-1",
    plant: Annotated[
        str,
        typer.Option(help="default, ideal, a plant YAML file, or a run's config.yaml (its plant)."),
    ] = "default",
    seed: Annotated[int, typer.Option(min=0, help="Seed of the plant's sensor noise.")] = 0,
    controller: Annotated[
        Path | None,
        typer.Option(
            help="YAML file of controller gains (ArmControllerConfig), or a file with a "
            "controller: section (a training recipe, a run's config.yaml); default: the "
            "defaults, or with --ff the gains the compensator was trained with (with --ff, "
            "the file's gains replace those they name, with a warning)."
        ),
    ] = None,
    ff: Annotated[
        Path | None,
        typer.Option(
            "--ff",
            help="Feedforward compensator checkpoint (from msarm train); none if omitted.",
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            help="Output folder (default runs/track-<task>-<plant>, with -s<seed> after it "
            "for a --seed other than 0, then -ff with --ff)."
        ),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print the metrics as JSON.")] = False,
    list_: ListOption = False,
) -> None:
    """Run a tracking task on a plant; print its metrics; write log, sidecar, config, plots."""
    if list_:
        list_choices(as_json=json_output)
        return
    from msarm.control import ArmControllerConfig
    from msarm.errors import InputError
    from msarm.io.config import folder_instead_of_file
    from msarm.model import load_arm
    from msarm.tasks.registry import get_task
    from msarm.tasks.track import TrackSettings, track

    arm = load_arm()
    task_obj = get_task(task, arm)
    plant_config = resolve_plant(plant)
    gains, given_keys = None, set()
    if controller is not None:
        folder = folder_instead_of_file(
            controller, "a YAML file of controller gains, or one with a controller: section"
        )
        if folder is not None:
            raise InputError(f"--controller: {folder}")
        gains, given = read_config_section(controller, ArmControllerConfig, "controller")
        given_keys = set(given) if isinstance(given, dict) else set()
        check_controller_file(arm, gains, controller)
    feedforward = None
    if ff is not None:
        from msarm.compensation.feedforward import (
            load_feedforward,
            trained_controller,
            warn_if_other_plant,
        )

        feedforward = load_feedforward(ff, arm)
        warn_if_other_plant(feedforward.compensator, plant_config, str(ff))
        trained = trained_controller(feedforward.compensator)
        if gains is None:
            gains = trained
        else:
            gains = _over_trained_gains(gains, given_keys, trained, controller, ff)
    if controller is not None:
        gains_from = f"gains from {controller}"
    elif feedforward is not None:
        gains_from = "the gains the compensator was trained with"
    else:
        from msarm.cli.compensator import DEFAULT_RECIPE

        where = (
            f"--controller {DEFAULT_RECIPE}, its controller: block"
            if DEFAULT_RECIPE.is_file()
            else "--controller with a recipe's or a run's config.yaml, e.g. "
            "runs/compensator/data/run-1000/config.yaml after msarm train"
        )
        gains_from = (
            "ArmControllerConfig's default gains, tuned for the ideal plant (the default "
            f"plant's tuned gains: {where})"
        )
    gains = gains or ArmControllerConfig()
    if controller is not None:
        rate_source = f"{controller}: rate_hz"
    elif feedforward is not None:
        rate_source = f"the gains recorded in {ff}: rate_hz"
    else:
        rate_source = "ArmControllerConfig's default rate_hz"
    # before the output folder is made: the runner would refuse it at the start of the run
    check_control_period(gains, plant_config, rate_source, None if plant in PLANTS else plant)
    settings = TrackSettings(task_obj.name, seed, plant_config, gains, str(ff or ""))
    out_dir = output_folder(
        out or default_folder(task_obj.name, plant_config.name, seed, feedforward is not None)
    )
    note_first_compile("track")
    with progress_bar() as bar:  # on stderr, with --json too
        job = bar.add_task(f"{task_obj.name} on {plant_config.name}", total=1.0)
        result = track(
            arm,
            task_obj,
            settings,
            out_dir,
            feedforward=feedforward,
            progress=lambda done: bar.update(job, completed=done),
        )
    payload = {"task": task_obj.name, "plant": plant_config.name, **result.metrics.as_dict()}
    payload["files"] = {kind: str(path) for kind, path in result.files.items()}
    if result.run.error is not None:
        payload["diverged"] = str(result.run.error)
    if json_output:
        typer.echo(json.dumps(payload, indent=2))
    else:
        out_console = console()
        out_console.print(
            metrics_table(
                f"{task_obj.name} on the {plant_config.name} plant (seed {seed})",
                {plant_config.name: result.metrics},
                arm.joint_names,
                arm.cable_names,
            )
        )
        out_console.print(f"controller: {gains_from}")
        for kind, path in result.files.items():
            out_console.print(f"{kind}: {path}")
    if result.run.error is not None:  # on stderr, one line, with --json too
        log = result.files.get("log")
        kept = f" (partial log kept: {log})" if log is not None else ""
        typer.echo(f"msarm: error: {result.run.error}{kept}", err=True)
        raise typer.Exit(code=1)
