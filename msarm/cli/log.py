"""``msarm log import``: a robot's own CSV recordings as msarm logs, ready for the diagnosis.

Each CSV file (a header of column names, one row per sample) becomes a Parquet log of the
schema of :mod:`msarm.io.logs` (:func:`msarm.io.table_import.read_csv_log`: units converted
to SI, channels checked against the model and put in its order, the sample rate given or
taken from the time column). The command then says, per log, which of the diagnosis'
residuals the log supports (:data:`DIAGNOSIS_CHANNELS`), so that a missing channel shows
before a diagnosis is run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from msarm.cli.common import console, output_folder
from msarm.errors import InputError

if TYPE_CHECKING:
    from msarm.io.logs import RunLog
    from msarm.model import RobotModel

log_app = typer.Typer(
    help="Bring a robot's own recordings into msarm's log format.",
    no_args_is_help=True,
    add_completion=False,
)

#: What the diagnosis computes from a log (a short name) -> the quantities it needs (each for
#: every joint or cable of the model).
DIAGNOSIS_CHANNELS: dict[str, tuple[str, ...]] = {
    "joint": ("q", "tension_motor"),
    "drive": ("tension_cmd", "tension_motor"),
    "length": ("motor_angle", "q"),
    "q_ref": ("q_ref",),
}
#: What each of :data:`DIAGNOSIS_CHANNELS` gives the diagnosis.
DIAGNOSIS_USES: dict[str, str] = {
    "joint": "the joint-torque residual (friction, capstan, mass error, sensor terms)",
    "drive": "the drive residual (winch friction, cogging, command delay, sheath stiction)",
    "length": "the cable-length residual (elasticity, slack, backlash, stretch)",
    "q_ref": "clean accelerations for the mass-error term",
}


def parse_units(pairs: list[str]) -> dict[str, str]:
    """``["q=deg", "tension_motor=kN"]`` as ``{"q": "deg", "tension_motor": "kN"}``.

    Raises:
        InputError: A pair without ``=``, with an empty side, or a quantity given twice.
    """
    units: dict[str, str] = {}
    for pair in pairs:
        quantity, sep, unit = pair.partition("=")
        quantity, unit = quantity.strip(), unit.strip()
        if not sep or not quantity or not unit:
            raise InputError(f"--unit: expected QUANTITY=UNIT (e.g. q=deg), got {pair!r}")
        if quantity in units and units[quantity] != unit:
            raise InputError(
                f"--unit: quantity {quantity!r} given twice ({units[quantity]!r} and {unit!r})"
            )
        units[quantity] = unit
    return units


#: Compression endings of a CSV file's name, dropped with the ending before them
#: (``run.csv.gz`` -> ``run``).
COMPRESSION_SUFFIXES = (".gz", ".bz2")


def log_paths(files: list[Path], out: Path | None) -> list[Path]:
    """Where the log of each CSV file goes: ``<name>.parquet`` in ``out`` or beside the file.

    The name is the file's without its ending (``run.csv`` -> ``run.parquet``), and without
    a compression ending before that (``run.csv.gz`` -> ``run.parquet``).

    Raises:
        InputError: Two files would write one log, a log would replace one of the CSV files,
            or a log's path is a folder; all before anything is written.
    """
    targets = []
    for path in files:
        bare = path.with_suffix("") if path.suffix.lower() in COMPRESSION_SUFFIXES else path
        targets.append((out or path.parent) / f"{bare.stem}.parquet")
    resolved = [target.resolve() for target in targets]
    for k, target in enumerate(resolved):
        if resolved.count(target) > 1:
            others = [str(files[j]) for j, t in enumerate(resolved) if t == target]
            raise InputError(
                f"CSV: {', '.join(others)} would all write the log {targets[k]}; give files of "
                "different names (or import them to different --out folders)"
            )
    inputs = {path.resolve() for path in files}
    for path, target in zip(files, targets, strict=True):
        if target.resolve() in inputs:
            raise InputError(
                f"{path}: its log {target} would replace a CSV file given; rename the file "
                "(a CSV file ends in .csv) or give --out"
            )
        if target.is_dir():
            raise InputError(f"{path}: its log {target} is a folder; expected a file path")
    return targets


def diagnosis_support(log: RunLog, model: RobotModel) -> dict[str, bool]:
    """Which residuals of the diagnosis a log supports (:data:`DIAGNOSIS_CHANNELS`).

    Args:
        log: The log.
        model: Its robot model (the joints and cables each quantity needs).

    Returns:
        What the diagnosis computes -> whether the log has every column it needs.
    """
    from msarm.io.table_import import JOINT_QUANTITIES

    def complete(quantity: str) -> bool:
        names = model.joint_names if quantity in JOINT_QUANTITIES else model.cable_names
        return all(f"{quantity}.{name}" in log.columns for name in names)

    return {what: all(map(complete, needs)) for what, needs in DIAGNOSIS_CHANNELS.items()}


@log_app.command("import")
def import_command(
    files: Annotated[
        list[Path],
        typer.Argument(
            metavar="CSV",
            help="CSV files, one a run: a header row of column names (the time column and "
            "channels <quantity>.<name>, e.g. q.elbow, tension_motor.biceps), then one row a "
            "sample; an empty field is a missing value.",
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option(
            help="Folder for the logs (<csv name>.parquet); default: next to each CSV file."
        ),
    ] = None,
    unit: Annotated[
        list[str] | None,
        typer.Option(
            "--unit",
            metavar="QUANTITY=UNIT",
            help="The unit a quantity's columns are in, converted to msarm's SI unit (e.g. "
            "q=deg, tension_motor=kN, motor_angle=deg, cable_length=mm); repeat the option for "
            "each quantity. Quantities not given are taken to be in SI (rad, N, m, N m).",
        ),
    ] = None,
    rate: Annotated[
        float | None,
        typer.Option(
            metavar="HZ",
            help=r"Nominal sample rate \[Hz]; default: 1 / median step of the time column.",
        ),
    ] = None,
    time_column: Annotated[
        str, typer.Option(metavar="NAME", help="Name of the time column.")
    ] = "t",
    time_unit: Annotated[
        str, typer.Option(metavar="s|ms|us", help="Unit of the time column.")
    ] = "s",
    drop_missing: Annotated[
        bool,
        typer.Option(
            "--drop-missing",
            help="Leave out the rows with a missing value (with a warning) instead of "
            "refusing the file; the diagnosis then sees a time gap there.",
        ),
    ] = False,
    skip_column: Annotated[
        list[str] | None,
        typer.Option(
            "--skip-column",
            metavar="NAME",
            help="A column to leave out (e.g. a sensor logged at a lower rate, empty in most "
            "rows); repeat the option for each.",
        ),
    ] = None,
    model_path: Annotated[
        Path | None,
        typer.Option(
            "--model",
            help="The robot model (MJCF) the recordings are of; default msarm's arm "
            "(models/msarm_arm.xml). Its joint and cable names are the channel names.",
        ),
    ] = None,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print what was written as JSON.")
    ] = False,
) -> None:
    """Turn CSV recordings of a robot into msarm logs (Parquet) for msarm diagnose."""
    from msarm.io.logs import write_log
    from msarm.io.table_import import TIME_UNITS, read_csv_log
    from msarm.model import ARM_MODEL_PATH, load_robot

    units = parse_units(list(unit or []))
    if time_unit not in TIME_UNITS:
        raise InputError(f"--time-unit: expected one of {', '.join(TIME_UNITS)}, got {time_unit!r}")
    if rate is not None and not (0 < rate < float("inf")):
        raise InputError(f"--rate: expected a sample rate > 0 in Hz, got {rate}")
    if out is not None:
        out = output_folder(out)
    targets = log_paths(files, out)
    model = load_robot(model_path or ARM_MODEL_PATH)
    # every file is read and checked before any log is written
    logs = [
        read_csv_log(
            path,
            model,
            sample_rate_hz=rate,
            units=units,
            time_column=time_column,
            time_unit=time_unit,
            drop_missing=drop_missing,
            skip_columns=list(skip_column or []),
        )
        for path in files
    ]
    written: list[dict[str, Any]] = []
    for path, log, target in zip(files, logs, targets, strict=True):
        write_log(target, log)
        written.append(
            {
                "csv": str(path),
                "log": str(target),
                "samples": len(log),
                "duration_s": float(log.t[-1] - log.t[0]),
                "sample_rate_hz": log.metadata.sample_rate_hz,
                "units": dict(log.metadata.units),
                "diagnosis": diagnosis_support(log, model),
            }
        )
    if json_output:
        print(json.dumps({"model": str(model.path), "logs": written}, indent=2))
        return
    _print_written(written)


def _print_written(written: list[dict[str, Any]]) -> None:
    screen = console()
    table = Table(title="logs written (msarm diagnose reads them)")
    table.add_column("CSV")
    table.add_column("log")
    table.add_column("samples", justify="right")
    table.add_column("rate [Hz]", justify="right")
    for what in DIAGNOSIS_CHANNELS:
        table.add_column(what)
    for row in written:
        table.add_row(
            escape(row["csv"]),
            escape(row["log"]),
            f"{row['samples']} ({row['duration_s']:.3g} s)",
            f"{row['sample_rate_hz']:g}",
            *("yes" if ok else "no" for ok in row["diagnosis"].values()),
        )
    screen.print(table)
    for what, needs in DIAGNOSIS_CHANNELS.items():
        columns = ", ".join(f"{quantity}.*" for quantity in needs)
        screen.print(escape(f"{what}: {DIAGNOSIS_USES[what]}; needs {columns}"))
