"""``msarm cdpr …``: the cable-driven parallel robot of paper 000."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from msarm.cli.common import (
    console,
    output_folder,
    progress_bar,
    progress_lines,
    resolve_plant_of,
    seed_suffix,
)

cdpr_app = typer.Typer(
    help="The IPAnema 3 Mini cable robot: hybrid position-force controllers (paper 000).",
    no_args_is_help=True,
)

CDPR_UNITS = {
    "r_ref": "m",
    "marker": "m",
    "cable_length": "m",
    "motor_torque": "N m",
    "following_error": "m",
    "load_cell": "N",
    "l_set": "m",
    "f_desired": "N",
    "h": "1",
}


def _plant(name: str):
    """The cable-robot plant from a preset name (``default``, ``ideal``) or a YAML file.

    Raises:
        InputError: Not a preset nor a readable plant file; or the file's plant is named
            like a preset (its runs would overwrite the preset's), or, without a ``name``
            key, the file's stem is not a simple identifier.
        ConfigError: The file is not a valid plant file (with a hint when it looks like an
            arm plant).
    """
    from msarm.plant.cdpr_config import DEFAULT_CDPR_PLANT, IDEAL_CDPR_PLANT, CdprPlantConfig
    from msarm.plant.config import PlantConfig

    presets = {"default": DEFAULT_CDPR_PLANT, "ideal": IDEAL_CDPR_PLANT}
    return resolve_plant_of(name, presets, CdprPlantConfig, PlantConfig)


def _plant_suffix(config) -> str:
    """``-<plant name>`` for a plant other than the default, else ``""`` (folder names)."""
    return "" if config.name == "default" else f"-{config.name}"


def _share_inside(percent: float) -> str:
    """A time share in % to 0.1, or to 0.01 near 100: 99.96 % is not printed as 100.0."""
    if np.isnan(percent):
        return "-"
    if percent >= 100.0:
        return "100"
    if percent >= 99.95:
        return f"{np.floor(percent * 100.0) / 100.0:.2f}"
    return f"{percent:.1f}"


def _metric_cells(m) -> list[str]:
    rms = "-" if np.isnan(m.force_rms_error) else f"{m.force_rms_error:.2f}"
    return [
        f"{m.max_position_error_mm:.2f}",
        f"{m.mean_position_error_mm:.2f}",
        _share_inside(m.time_in_bounds_percent),
        f"{m.min_force:.1f}-{m.max_force:.1f}",
        rms,
    ]


#: The files ``msarm cdpr run`` writes to its folder, ``metrics.json`` (written last) first:
#: a run removes an older run's, in this order, before it writes its own.
RUN_FILES = ("metrics.json", "forces.png", "config.yaml", "log.truth.parquet", "log.parquet")

_METRIC_COLUMNS = (
    "max error [mm]",
    "mean error [mm]",
    "time in [5, 35] N [%]",
    "forces [N]",
    "force RMS error [N]",
)


def controller_options(items: list[str], controller: str | None = None) -> dict[str, object]:
    """``KEY=VALUE`` texts as controller keyword options (values read as YAML scalars).

    Values are read as in a config file: ``1e-3`` (an exponent without a dot) is a float.

    Args:
        items: The ``KEY=VALUE`` texts.
        controller: The controller they are for: each option is then checked against it
            (:func:`msarm.control.cdpr_controllers.check_plain_options`); None: not checked.

    Raises:
        InputError: An item without ``=``, a key that is not an identifier, a key given
            twice, a value that is not valid YAML or not a YAML number, boolean, null or
            string; with ``controller``, an option it does not take, one that takes an object
            (Python API only) or a value not of the option's type.
    """
    import yaml

    from msarm.control.cdpr_controllers import check_plain_options
    from msarm.errors import InputError
    from msarm.io.config import _load_yaml, yaml_problem

    options: dict[str, object] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key.isidentifier():
            raise InputError(f"--option: expected KEY=VALUE with KEY an identifier, got {item!r}")
        if key in options:
            raise InputError(f"--option: {key} given twice")
        try:  # config files' loader: 1e-3 is a float, not YAML 1.1's string
            value = _load_yaml(text, f"--option {key}")
        except yaml.YAMLError as exc:
            problem = yaml_problem(exc).removeprefix("line 1, ")
            raise InputError(f"--option {key}: {text!r} is not a YAML value: {problem}") from None
        if controller is None and not isinstance(value, (bool, int, float, str)):
            raise InputError(
                f"--option {key}: expected a number, true/false or a word, got {text!r}"
            )
        options[key] = value
    if controller is not None:
        check_plain_options(controller, options)
    return options


def default_run_folder(
    controller: str, trajectory: str, plant_config, seed: int, options: dict[str, object]
) -> Path:
    """``runs/cdpr-<controller>-<trajectory>[-<plant>][-s<seed>][-KEY=VALUE...]``.

    The plant is named when it is not the default, the seed when it is not 0, and each
    controller option: runs that differ in any of them get folders of their own.
    """
    on = _plant_suffix(plant_config) + seed_suffix(seed)
    on += "".join(f"-{k}={_option_text(v)}" for k, v in options.items())
    return Path("runs") / f"cdpr-{controller}-{trajectory}{on}"


def _option_text(value: object) -> str:
    """An option's value as written on the command line (YAML): ``true``, not ``True``."""
    if value is None:
        return "null"
    return str(value).lower() if isinstance(value, bool) else str(value)


@cdpr_app.command("run")
def run_command(
    controller: Annotated[
        str, typer.Option(help="ikc, hc-f, hc-tau, hc-e, hc-e-all, nc.")
    ] = "hc-e",
    trajectory: Annotated[
        str, typer.Option(help="triangle-12, circle-12, triangle-34, circle-34, rectangle-switch.")
    ] = "triangle-12",
    plant: Annotated[
        str,
        typer.Option(help="default, ideal, a plant YAML file, or a run's config.yaml (its plant)."),
    ] = "default",
    seed: Annotated[int, typer.Option(min=0, help="Seed of the sensor noise.")] = 0,
    out: Annotated[
        Path | None,
        typer.Option(
            help="Output folder (default runs/cdpr-<controller>-<trajectory>, with "
            "-<plant> after it for a plant other than the default, -s<seed> for a --seed "
            "other than 0 and -KEY=VALUE for each --option)."
        ),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print the metrics as JSON.")] = False,
    option: Annotated[
        list[str] | None,
        typer.Option(
            "--option",
            metavar="KEY=VALUE",
            help="A keyword option of the controller (repeat for several), e.g. "
            "fe_feedforward=true (HC-e) or friction_model=false; values are read as YAML "
            "and checked against the option's type (gains and winch: Python only).",
        ),
    ] = None,
) -> None:
    """Run one controller along one trajectory; print its metrics; write log, config, plots."""
    from msarm.cdpr.robot_model import load_cable_robot
    from msarm.io.atomic import write_json_atomic
    from msarm.io.config import config_to_dict, write_config
    from msarm.io.logs import LogMetadata, RunLog, write_log, write_sidecar
    from msarm.tasks.cdpr_compare import plot_forces
    from msarm.tasks.cdpr_runner import check_cdpr_run, run_cdpr
    from msarm.tasks.cdpr_trajectories import get_cdpr_trajectory

    model = load_cable_robot()
    path = get_cdpr_trajectory(trajectory)
    plant_config = _plant(plant)
    options = controller_options(option or [], controller)
    # before any folder is created
    check_cdpr_run(model, plant_config, controller, path, options)
    # the log's metadata too (standard JSON: an option of .inf is refused now, not after)
    metadata = LogMetadata(
        robot_model=model.name,
        model_sha256=model.sha256,
        sample_rate_hz=1000.0,
        units=CDPR_UNITS,
        controller_config={"name": controller, **options},
        extra={"trajectory": trajectory, "seed": seed, "plant": plant_config.name},
    )
    folder = output_folder(
        out or default_run_folder(controller, trajectory, plant_config, seed, options)
    )
    with progress_bar() as bar:  # on stderr, with --json too
        job = bar.add_task(f"{controller} on {trajectory}", total=1.0)
        run = run_cdpr(
            model,
            plant_config,
            controller,
            path,
            seed,
            options,
            progress=lambda done: bar.update(job, completed=done),
        )
    # metrics.json is written last and marks a whole run: an older run's goes first, then its
    # other files, so that a run cut off between two writes leaves no mix of the two runs
    for name in RUN_FILES:
        (folder / name).unlink(missing_ok=True)
    files = {"log": write_log(folder / "log.parquet", RunLog(run.columns, metadata))}
    files["sidecar"] = write_sidecar(
        files["log"], run.truth, {"plant": plant_config.name}, {"tension": "N"}
    )
    payload = {"controller": controller, "trajectory": trajectory, **run.metrics.as_dict()}
    if run.error is not None:
        payload["diverged"] = str(run.error)
    files["config"] = write_config(
        {
            "controller": controller,
            "controller_options": options,
            "trajectory": trajectory,
            "seed": seed,
            "plant": config_to_dict(plant_config),
        },
        folder / "config.yaml",
    )
    files["forces_plot"] = plot_forces(
        run, model, folder / "forces.png", plant=plant_config.name, seed=seed, options=options
    )
    files["metrics"] = write_json_atomic(folder / "metrics.json", payload)
    payload["files"] = {k: str(v) for k, v in files.items()}
    if json_output:
        typer.echo(json.dumps(payload, indent=2))
    else:
        title = f"{controller} on {trajectory} ({plant_config.name} plant, seed {seed})"
        if run.error is not None:
            title = (
                f"DIVERGED at t = {run.error.time:.3f} s of {path.duration:.3f} s: "
                f"{title}, metrics of the partial run"
            )
        table = Table(title=escape(title), title_style="bold red" if run.error else None)
        for column in _METRIC_COLUMNS:
            table.add_column(escape(column), justify="right")
        table.add_row(*_metric_cells(run.metrics))
        out_console = console()
        out_console.print(table)
        for kind, file in files.items():
            out_console.print(f"{kind}: {file}")
    if run.error is not None:
        typer.echo(f"msarm: error: {run.error}", err=True)
        raise typer.Exit(code=1)


@cdpr_app.command("compare")
def compare_command(
    plant: Annotated[
        str,
        typer.Option(help="default, ideal, a plant YAML file, or a run's config.yaml (its plant)."),
    ] = "default",
    repeats: Annotated[
        int,
        typer.Option(
            min=0,
            help="Runs per repeatability test (paper: 15); 0 or 1: no Table 5 (a spread "
            "needs two runs or more).",
        ),
    ] = 15,
    out: Annotated[
        Path | None,
        typer.Option(
            help="Output folder (default runs/cdpr-compare, with -<plant> after it for a "
            "plant other than the default)."
        ),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print the results as JSON.")] = False,
    fresh: Annotated[
        bool,
        typer.Option(
            "--fresh",
            help="Simulate every run again (by default the runs kept in OUT/runs with the same "
            "plant, model and settings are reused: an interrupted grid goes on where it "
            "stopped).",
        ),
    ] = False,
) -> None:
    """Run the Table 3 test grid: Table 4 (accuracy), Table 5 (repeatability), force bounds."""
    from msarm.cdpr.robot_model import load_cable_robot
    from msarm.tasks.cdpr_compare import _grid, compare_cdpr, progress_steps
    from msarm.tasks.cdpr_runner import check_cdpr_run
    from msarm.tasks.cdpr_trajectories import get_cdpr_trajectory

    model = load_cable_robot()
    plant_config = _plant(plant)
    for _, controller, trajectory, options in _grid():  # before any folder is created
        check_cdpr_run(model, plant_config, controller, get_cdpr_trajectory(trajectory), options)
    folder = output_folder(out or Path("runs") / f"cdpr-compare{_plant_suffix(plant_config)}")
    total = progress_steps(repeats)  # the runs compare_cdpr reports, one a step
    line = progress_lines("cdpr compare", total)
    with progress_bar() as bar:  # on stderr, with --json too (a line a step off a terminal)
        job = bar.add_task("cdpr compare", total=total)

        def step(label: str) -> None:
            bar.update(job, advance=1, description=label)
            line(label)

        result = compare_cdpr(
            model, plant_config, folder, repeats=repeats, progress=step, resume=not fresh
        )
    if json_output:
        typer.echo(json.dumps(result.as_dict(), indent=2))
        return
    out_console = console()
    table = Table(
        title="Table 4: accuracy, forces and force tracking per test (paper 000 Table 3 ids)"
        f", {plant_config.name} plant"
    )
    for column in ("test", "controller", "trajectory"):
        table.add_column(column, no_wrap=True, min_width=len(column))
    for column in _METRIC_COLUMNS:
        table.add_column(escape(column), justify="right", overflow="fold")
    for test, (controller, trajectory, metrics) in result.tests.items():
        table.add_row(escape(test), controller, trajectory, *_metric_cells(metrics))
    out_console.print(table)
    if result.repeatability:
        rep = Table(title=f"Table 5: repeatability over {result.repeats} runs [mm]")
        for column in ("test", "rho_max", "rho_mean"):
            rep.add_column(column, justify="right", no_wrap=True)
        for test, (rho_max, rho_mean) in result.repeatability.items():
            rep.add_row(test, f"{rho_max:.3f}", f"{rho_mean:.3f}")
        out_console.print(rep)
    for kind, file in result.files.items():
        out_console.print(f"{kind}: {file}")
