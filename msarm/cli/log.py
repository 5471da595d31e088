"""``msarm log``: a robot's own recordings as msarm logs, and what the diagnosis can make of them.

- ``msarm log import``: each CSV file (a header of column names, one row per sample) becomes
  a Parquet log of the schema of :mod:`msarm.io.logs` (:func:`msarm.io.table_import.read_csv_log`:
  units converted to SI, channels checked against the model and put in its order, the sample
  rate given or taken from the time column), then checked as ``msarm log check`` does.
- ``msarm log check``: each log read and its residuals computed as the diagnosis does
  (:func:`msarm.diagnose.log_check.check_log`): which residuals it supports, what the
  diagnosis would warn about, and why it would refuse a log, for every log at once.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape
from rich.table import Table

from msarm.cli.common import (
    RepeatedWarnings,
    check_drum_radius,
    check_filter_window,
    console,
    output_folder,
)
from msarm.errors import InputError, MsarmError

if TYPE_CHECKING:
    from msarm.diagnose.log_check import LogCheck
    from msarm.diagnose.residuals import ResidualSpec
    from msarm.model import RobotModel

log_app = typer.Typer(
    help="Bring a robot's own recordings into msarm's log format, and check logs.",
    no_args_is_help=True,
    add_completion=False,
)

#: The ``--drum-radius`` option of both commands: the drums the diagnosis would read the
#: motor angles with.
DrumRadius = Annotated[
    float,
    typer.Option(
        metavar="METRES",
        help=r"Radius of the winch drums the diagnosis would use \[m] (msarm diagnose "
        "--drum-radius): the motor angles' cable lengths are checked with it.",
    ),
]

#: Short column names of the residuals in the check table
#: (:data:`msarm.diagnose.log_check.RESIDUALS_CHECKED`).
RESIDUAL_COLUMNS = {
    "joint_torque": "joint",
    "drive": "drive",
    "cable_length": "length",
    "clean_accelerations": "q_ref",
}


def parse_units(pairs: list[str]) -> dict[str, str]:
    """``["q=deg", "tension_motor=kN"]`` as ``{"q": "deg", "tension_motor": "kN"}``.

    Args:
        pairs: The ``--unit`` values, ``QUANTITY=UNIT`` each.

    Returns:
        Quantity -> unit.

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

    Args:
        files: The CSV files.
        out: The folder for the logs, or None for each file's own folder.

    Returns:
        The log path of each file, in order.

    Raises:
        InputError: Two files would write one log, a log would replace one of the CSV files
            (a log given to import, a Parquet file, is named as such), a log's path is a
            folder, or a file that is not a log imported before (a simulated run's
            ``log.parquet``, another tool's file); all before anything is written.
    """
    from msarm.io.table_import import check_not_parquet

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
            check_not_parquet(path)  # a log given to import: said as such
            raise InputError(
                f"{path}: its log {target} would replace a CSV file given; rename the file "
                "(a CSV file ends in .csv) or give --out"
            )
        if target.is_dir():
            raise InputError(f"{path}: its log {target} is a folder; expected a file path")
    others = [str(target) for target in targets if target.exists() and not _imported_log(target)]
    if others:
        raise InputError(
            f"{', '.join(others)}: already there and not a log that msarm log import wrote (a "
            "simulated run's log or another file), which a log would replace; move "
            f"{'them' if len(others) > 1 else 'it'}, or import to another folder (--out)"
        )
    return targets


def _imported_log(path: Path) -> bool:
    """Whether ``path`` is a log that ``msarm log import`` wrote, which it may replace.

    Such a log's ``msarm.extra`` names the CSV file it was imported from (``imported_from``);
    a file that cannot be read as Parquet, or a log without it, is not one.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        metadata = pq.read_schema(path).metadata or {}
        extra = json.loads(metadata.get(b"msarm.extra", b"{}"))
    except (OSError, ValueError, pa.ArrowException):  # not a Parquet file of ours
        return False
    return isinstance(extra, dict) and "imported_from" in extra


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
            help=r"Nominal sample rate \[Hz]; default: 1 / mean step of the time column "
            "(its gaps left out).",
        ),
    ] = None,
    time_column: Annotated[
        str, typer.Option(metavar="NAME", help="Name of the time column.")
    ] = "t",
    time_unit: Annotated[
        str, typer.Option(metavar="s|ms|us|ns", help="Unit of the time column.")
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
    drum_radius: DrumRadius = 0.003,
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
    check_drum_radius(drum_radius)
    if time_unit not in TIME_UNITS:
        raise InputError(f"--time-unit: expected one of {', '.join(TIME_UNITS)}, got {time_unit!r}")
    if rate is not None and not (0 < rate < float("inf")):
        raise InputError(f"--rate: expected a sample rate > 0 in Hz, got {rate}")
    if out is not None:
        out = output_folder(out)
    targets = log_paths(files, out)
    model = load_robot(model_path or ARM_MODEL_PATH)
    # every file is read and checked before any log is written; every error is said
    logs, errors = [], []
    for path in files:
        try:
            logs.append(
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
            )
        except MsarmError as exc:
            errors.append(str(exc))
            continue
        lacking = _required_columns_missing(logs[-1].columns, model)
        if lacking:
            errors.append(
                f"{path}: {lacking}; the diagnosis needs q.<joint> for every joint and "
                "tension_motor.<cable> for every cable"
            )
    if len(errors) == 1:
        raise InputError(errors[0] + " (nothing written)")
    if errors:
        raise InputError(
            f"{len(errors)} of {len(files)} CSV files cannot be imported (nothing written): "
            + "; ".join(errors)
        )
    for log, target in zip(logs, targets, strict=True):
        write_log(target, log)
    from msarm.diagnose.residuals import ResidualSpec

    spec = ResidualSpec(drum_radius=drum_radius)
    _report_checks(model, targets, spec, json_output, "logs written", sources=files)


def _required_columns_missing(columns: Mapping[str, object], model: RobotModel) -> str:
    """What a log lacks of the columns every diagnosis reads, in words; empty if nothing."""
    from msarm.diagnose.missing_values import REQUIRED_CHANNELS

    names = {"q": model.joint_names, "tension_motor": model.cable_names}
    missing = [
        f"{quantity}.{name}"
        for quantity in REQUIRED_CHANNELS
        for name in names[quantity]
        if f"{quantity}.{name}" not in columns
    ]
    if not missing:
        return ""
    listed = ", ".join(repr(name) for name in missing[:4])
    more = f" and {len(missing) - 4} more" if len(missing) > 4 else ""
    return f"column{'s' if len(missing) > 1 else ''} {listed}{more} missing"


@log_app.command("check")
def check_command(
    logs: Annotated[
        list[Path], typer.Argument(metavar="LOG", help="Log files (Parquet) to check.")
    ],
    filter_window: Annotated[
        int,
        typer.Option(
            metavar="SAMPLES",
            help=r"The derivative filter's window the diagnosis would use \[samples] (msarm "
            "diagnose --filter-window).",
        ),
    ] = 25,
    drum_radius: DrumRadius = 0.003,
    model_path: Annotated[
        Path | None,
        typer.Option(
            "--model",
            help="The nominal model (MJCF) the diagnosis would use; default msarm's arm "
            "(models/msarm_arm.xml).",
        ),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print the checks as JSON.")] = False,
) -> None:
    """Say what msarm diagnose can make of each log: its residuals, warnings and errors."""
    from msarm.model import ARM_MODEL_PATH, load_robot

    check_filter_window(filter_window)
    check_drum_radius(drum_radius)
    model = load_robot(model_path or ARM_MODEL_PATH)
    from msarm.compensation.target import TargetSpec
    from msarm.diagnose.residuals import ResidualSpec

    spec = ResidualSpec(target=TargetSpec(window=filter_window), drum_radius=drum_radius)
    _report_checks(model, logs, spec, json_output, "logs checked")


def _report_checks(
    model: RobotModel,
    logs: list[Path],
    spec: ResidualSpec,
    json_output: bool,
    title: str,
    sources: list[Path] | None = None,
) -> None:
    """Check the logs (:func:`msarm.diagnose.log_check.check_logs`) and print the result.

    ``spec`` holds the filter window and drum radius the diagnosis would use.

    Raises:
        InputError: Some log cannot be diagnosed, or the logs not together (after all is
            printed), naming how many or why.
    """
    from msarm.diagnose.log_check import check_logs

    checks, together = check_logs(model, list(logs), spec)
    if json_output:
        rows = [check.as_dict() for check in checks]
        for row, source in zip(rows, sources or [], strict=False):
            row["csv"] = str(source)
        report = {"model": str(model.path), "logs": rows, "together": together}
        print(json.dumps(report, indent=2))
    else:
        _print_checks(checks, title, sources)
        for text in together:
            console().print(escape(f"error (the logs together): {text}"), soft_wrap=True)
    where = "the JSON" if json_output else "above"
    bad = [check.path for check in checks if not check.ok]
    if bad:
        raise InputError(
            f"{len(bad)} of {len(checks)} log(s) cannot be diagnosed: {', '.join(bad)} (see "
            f"{where})"
        )
    if together:
        more = f" (and {len(together) - 1} more, see {where})" if len(together) > 1 else ""
        raise InputError(f"the logs cannot be diagnosed together: {together[0]}{more}")


def _print_checks(checks: list[LogCheck], title: str, sources: list[Path] | None) -> None:
    from msarm.diagnose.log_check import RESIDUALS_CHECKED

    screen = console()
    table = Table(title=f"{title}: what msarm diagnose can make of them")
    if sources:
        table.add_column("CSV")
    table.add_column("log")
    table.add_column("samples", justify="right")
    table.add_column("rate [Hz]", justify="right")
    for name in RESIDUALS_CHECKED:
        table.add_column(RESIDUAL_COLUMNS[name])
    table.add_column("warnings", justify="right")
    for k, check in enumerate(checks):
        first = [escape(str(sources[k]))] if sources else []
        if not check.ok:
            table.add_row(
                *first,
                escape(check.path),
                "error",
                "",
                *[""] * len(RESIDUALS_CHECKED),
                str(len(check.warnings)),
            )
            continue
        table.add_row(
            *first,
            escape(check.path),
            f"{check.samples} ({check.duration_s:.3g} s)",
            f"{check.sample_rate_hz:g}",
            *("yes" if check.residuals[name] else "no" for name in RESIDUALS_CHECKED),
            str(len(check.warnings)),
        )
    screen.print(table)
    for name, use in RESIDUALS_CHECKED.items():
        screen.print(escape(f"{RESIDUAL_COLUMNS[name]}: {use}"))
    repeats = RepeatedWarnings()  # the same warning about several logs: shown once
    for check in checks:
        for text in check.warnings:
            if repeats.first(text):
                screen.print(escape(f"warning: {text}"), soft_wrap=True)
        if check.error:
            screen.print(escape(f"error: {check.error}"), soft_wrap=True)
    for text in repeats.summary():  # each one line, also piped (grep, a CI log)
        screen.print(escape(f"warning: {text}"), soft_wrap=True)
