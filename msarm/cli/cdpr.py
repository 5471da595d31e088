"""``msarm cdpr …``: the cable-driven parallel robot of paper 000."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from msarm.cli.common import console, output_folder, progress_lines, resolve_config

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
    """The cable-robot plant from a preset name (``default``, ``ideal``) or a YAML file."""
    from msarm.plant.cdpr_config import DEFAULT_CDPR_PLANT, IDEAL_CDPR_PLANT, CdprPlantConfig

    presets = {"default": DEFAULT_CDPR_PLANT, "ideal": IDEAL_CDPR_PLANT}
    return resolve_config(name, presets, CdprPlantConfig, "plant")


def _metric_cells(m) -> list[str]:
    rms = "-" if np.isnan(m.force_rms_error) else f"{m.force_rms_error:.2f}"
    return [
        f"{m.max_position_error_mm:.2f}",
        f"{m.mean_position_error_mm:.2f}",
        f"{m.time_in_bounds_percent:.1f}",
        f"{m.min_force:.1f}-{m.max_force:.1f}",
        rms,
    ]


_METRIC_COLUMNS = (
    "max error [mm]",
    "mean error [mm]",
    "time in [5, 35] N [%]",
    "forces [N]",
    "force RMS error [N]",
)


@cdpr_app.command("run")
def run_command(
    controller: Annotated[
        str, typer.Option(help="ikc, hc-f, hc-tau, hc-e, hc-e-all, nc.")
    ] = "hc-e",
    trajectory: Annotated[
        str, typer.Option(help="triangle-12, circle-12, triangle-34, circle-34, rectangle-switch.")
    ] = "triangle-12",
    plant: Annotated[str, typer.Option(help="default, ideal or a plant YAML file.")] = "default",
    seed: Annotated[int, typer.Option(min=0, help="Seed of the sensor noise.")] = 0,
    out: Annotated[
        Path | None,
        typer.Option(
            help="Output folder (default runs/cdpr-<controller>-<trajectory>, with "
            "-<plant> after it for a plant other than the default)."
        ),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print the metrics as JSON.")] = False,
) -> None:
    """Run one controller along one trajectory; print its metrics; write log and force plot."""
    from rich.progress import Progress

    from msarm.cdpr.robot_model import load_cable_robot
    from msarm.io.atomic import write_json_atomic
    from msarm.io.config import config_to_dict, write_config
    from msarm.io.logs import LogMetadata, RunLog, write_log, write_sidecar
    from msarm.tasks.cdpr_compare import plot_forces
    from msarm.tasks.cdpr_runner import run_cdpr
    from msarm.tasks.cdpr_trajectories import get_cdpr_trajectory

    model = load_cable_robot()
    path = get_cdpr_trajectory(trajectory)
    plant_config = _plant(plant)
    on = "" if plant_config.name == "default" else f"-{plant_config.name}"
    folder = output_folder(out or Path("runs") / f"cdpr-{controller}-{trajectory}{on}")
    with Progress(transient=True, disable=json_output) as bar:
        job = bar.add_task(f"{controller} on {trajectory}", total=1.0)
        run = run_cdpr(
            model,
            plant_config,
            controller,
            path,
            seed,
            progress=lambda done: bar.update(job, completed=done),
        )
    metadata = LogMetadata(
        robot_model=model.name,
        model_sha256=model.sha256,
        sample_rate_hz=1000.0,
        units=CDPR_UNITS,
        controller_config={"name": controller},
        extra={"trajectory": trajectory, "seed": seed, "plant": plant_config.name},
    )
    files = {"log": write_log(folder / "log.parquet", RunLog(run.columns, metadata))}
    files["sidecar"] = write_sidecar(
        files["log"], run.truth, {"plant": plant_config.name}, {"tension": "N"}
    )
    payload = {"controller": controller, "trajectory": trajectory, **run.metrics.as_dict()}
    if run.error is not None:
        payload["diverged"] = str(run.error)
    files["metrics"] = write_json_atomic(folder / "metrics.json", payload)
    files["config"] = write_config(
        {
            "controller": controller,
            "trajectory": trajectory,
            "seed": seed,
            "plant": config_to_dict(plant_config),
        },
        folder / "config.yaml",
    )
    files["forces_plot"] = plot_forces(
        run, model, folder / "forces.png", title=f"{controller}, {trajectory}"
    )
    payload["files"] = {k: str(v) for k, v in files.items()}
    if json_output:
        typer.echo(json.dumps(payload, indent=2))
    else:
        table = Table(
            title=f"{controller} on {trajectory} ({plant_config.name} plant, seed {seed})"
        )
        for column in _METRIC_COLUMNS:
            table.add_column(escape(column), justify="right")
        table.add_row(*_metric_cells(run.metrics))
        out_console = console()
        out_console.print(table)
        for kind, file in files.items():
            out_console.print(f"{kind}: {file}")
    if run.error is not None:
        raise typer.Exit(code=1)


@cdpr_app.command("compare")
def compare_command(
    plant: Annotated[str, typer.Option(help="default, ideal or a plant YAML file.")] = "default",
    repeats: Annotated[
        int,
        typer.Option(
            min=0,
            help="Runs per repeatability test (paper: 15); 0 or 1: no Table 5 (a spread "
            "needs two runs or more).",
        ),
    ] = 15,
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("runs/cdpr-compare"),
    json_output: Annotated[bool, typer.Option("--json", help="Print the results as JSON.")] = False,
) -> None:
    """Run the Table 3 test grid: Table 4 (accuracy), Table 5 (repeatability), force bounds."""
    from rich.progress import Progress

    from msarm.cdpr.robot_model import load_cable_robot
    from msarm.tasks.cdpr_compare import _grid, compare_cdpr

    model = load_cable_robot()
    total = len(_grid()) + (4 * (repeats - 1) if repeats >= 2 else 0)
    line = progress_lines("cdpr compare", total, enabled=not json_output)
    with Progress(transient=True, disable=json_output) as bar:
        job = bar.add_task("cdpr compare", total=total)

        def step(label: str) -> None:
            bar.update(job, advance=1, description=label)
            line(label)

        result = compare_cdpr(
            model, _plant(plant), output_folder(out), repeats=repeats, progress=step
        )
    if json_output:
        typer.echo(json.dumps(result.as_dict(), indent=2))
        return
    out_console = console()
    table = Table(
        title="Table 4: accuracy, forces and force tracking per test (paper 000 Table 3 ids)"
    )
    table.add_column("test")
    table.add_column("controller")
    table.add_column("trajectory")
    for column in _METRIC_COLUMNS:
        table.add_column(escape(column), justify="right")
    for test, (controller, trajectory, metrics) in result.tests.items():
        table.add_row(test, controller, trajectory, *_metric_cells(metrics))
    out_console.print(table)
    if result.repeatability:
        rep = Table(title=f"Table 5: repeatability over {result.repeats} runs [mm]")
        for column in ("test", "rho_max", "rho_mean"):
            rep.add_column(column, justify="right")
        for test, (rho_max, rho_mean) in result.repeatability.items():
            rep.add_row(test, f"{rho_max:.3f}", f"{rho_mean:.3f}")
        out_console.print(rep)
    for kind, file in result.files.items():
        out_console.print(f"{kind}: {file}")
