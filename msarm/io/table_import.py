"""A robot's own recordings (CSV or columns) turned into msarm logs.

A real robot logs in its own way: a CSV file a run, a time column in milliseconds, joint
angles in degrees. :func:`log_from_columns` turns such columns into a :class:`RunLog` of the
log schema (:mod:`msarm.io.logs`) for a robot model, and :func:`read_csv_log` reads a CSV file
first; ``msarm log import`` writes the result as Parquet, ready for ``msarm diagnose``.

What it does, and refuses (each error names the file, the column and what was expected):

- the time column (``t`` unless told) becomes ``t`` in seconds from the first sample
  (``time_unit`` ``s``, ``ms``, ``us`` or ``ns``; the first sample's time is kept in the log's
  ``msarm.extra`` as ``time_origin``, in that unit, so that an epoch time keeps its steps'
  digits: a time given as text, as a CSV file's is read, is subtracted in decimals, and its
  first value also kept as that text, ``time_origin_text``, every digit of it); it must
  be strictly increasing and have no missing value;
- every other column is a channel ``<quantity>.<name>``. Its unit is the one given for the
  quantity (``units``), else msarm's (:data:`~msarm.io.logs.STANDARD_UNITS`); a unit other
  than msarm's SI unit is converted to it by the factors of :data:`CONVERSIONS` (``deg`` to
  ``rad``, ``kN`` to ``N``, ``mm`` to ``m``, ...), and one without a known factor is refused.
  A quantity msarm does not know needs a unit, and keeps it;
- a channel of a quantity that runs over the joints (``q``, ``q_ref``, ``tau_cmd``, ...) or
  the cables (``tension_motor``, ``motor_angle``, ...) must name one of the model's joints or
  cables (a misspelt ``q.Elbow`` would otherwise leave ``q.elbow`` missing); the channels of
  a quantity are put in the model's order;
- a missing value (an empty field, NaN, an infinity) is refused with its column, count and
  first row, or with ``drop_missing`` its rows are left out (said in a warning; a column with
  no value at all is left out instead): the log schema has no missing values.
  ``skip_columns`` leaves out columns first (a sensor logged at a lower rate, say);
- the sample rate is the one given, or ``1 / mean step`` of the time column, its gaps left
  out (rounded to six significant digits; steps that spread by more than a few per cent
  are warned about); one outside :data:`RATE_RANGE_HZ` is refused as a likely wrong
  time unit (milliseconds read as seconds), and one given that the time contradicts by more
  than 5 % is refused.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Mapping, Sequence
from decimal import Decimal
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError, LogError, MsarmWarning
from msarm.io.logs import (
    STANDARD_UNITS,
    TIME,
    LogMetadata,
    RunLog,
    check_increasing_time,
    nominal_step,
    regular_steps,
    same_unit,
    split_channel,
)

if TYPE_CHECKING:
    from msarm.model import RobotModel

__all__ = [
    "CABLE_QUANTITIES",
    "CONVERSIONS",
    "JOINT_QUANTITIES",
    "RATE_RANGE_HZ",
    "TIME_UNITS",
    "LogImportWarning",
    "check_not_parquet",
    "log_from_columns",
    "read_csv_log",
]

FloatArray = NDArray[np.float64]

#: Quantities with a channel per joint of the model.
JOINT_QUANTITIES = frozenset(
    ("q", "qd", "qdd", "qdot_est", "q_ref", "qd_ref", "qdd_ref", "tau", "tau_cmd", "tau_ff")
)
#: Quantities with a channel per cable of the model.
CABLE_QUANTITIES = frozenset(
    (
        "tension_cmd",
        "tension_ff",
        "tension_motor",
        "motor_angle",
        "motor_torque",
        "cable_length",
        "activation",
        "excitation",
    )
)
#: SI unit -> {another unit: factor}: a value in the other unit times the factor is in SI.
CONVERSIONS: Mapping[str, Mapping[str, float]] = {
    "rad": {"deg": math.pi / 180.0, "mrad": 1e-3},
    "rad/s": {"deg/s": math.pi / 180.0, "rpm": 2.0 * math.pi / 60.0},
    "rad/s^2": {"deg/s^2": math.pi / 180.0},
    "N": {"kN": 1e3, "mN": 1e-3},
    "N m": {"N mm": 1e-3, "mN m": 1e-3},
    "m": {"mm": 1e-3, "cm": 1e-2, "um": 1e-6},
    "1": {"%": 1e-2},
}
#: Units of the time column -> factor to seconds.
TIME_UNITS: Mapping[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: Significant digits of a sample rate taken from the time column.
_RATE_DIGITS = 6
#: Sample rates [Hz] a robot's log may have; outside, the time unit is likely wrong.
RATE_RANGE_HZ = (1.0, 100_000.0)
#: Largest relative difference between a given rate and the time column's nominal step.
_RATE_TOLERANCE = 0.05
#: Standard deviation of the time steps (gaps left out), as a fraction of their mean,
#: beyond which they are warned about (stamps rounded to whole ms at 300 Hz: 14 %).
_JITTER_WARNING = 0.02
#: Columns with missing values named in a message before the rest are counted.
_NAMED = 5
#: How messages count a file's rows.
_ROWS = "rows count from 0, the header not counted"
#: The first bytes of a Parquet file (a log).
_PARQUET_MAGIC = b"PAR1"
#: The byte order mark a spreadsheet may write at the start of a UTF-8 file.
_UTF8_BOM = b"\xef\xbb\xbf"
#: A line's end in a CSV file: ``\r\n``, ``\n`` or ``\r`` alone (the parser takes each).
_LINE_END = re.compile(rb"\r\n|\n|\r")


class LogImportWarning(MsarmWarning):
    """Something was left out or looks amiss while turning a recording into a log.

    Rows with a gap left out; uneven time steps; degrees given for some angle quantities only.
    """


def log_from_columns(
    columns: Mapping[str, ArrayLike],
    model: RobotModel,
    sample_rate_hz: float | None = None,
    units: Mapping[str, str] | None = None,
    time_column: str = TIME,
    time_unit: str = "s",
    drop_missing: bool = False,
    skip_columns: Sequence[str] = (),
    source: str = "table",
    extra: Mapping[str, Any] | None = None,
) -> RunLog:
    """A log of ``model`` from a robot's own columns (see the module docstring).

    Args:
        columns: Column name -> values, each of shape ``(T,)``: the time column and channels
            ``<quantity>.<name>``. Times given as text or :class:`~decimal.Decimal` are
            counted from the first exactly (floats keep an epoch time's steps to ~2e-7 s).
        model: The robot model the recording is of (its name, hash, joints and cables).
        sample_rate_hz: Nominal sample rate [Hz]; None: ``1 / mean step`` of the time, its
            gaps left out (:func:`~msarm.io.logs.nominal_step`).
        units: Quantity -> the unit its columns are in (e.g. ``{"q": "deg"}``); quantities
            not given are taken to be in msarm's SI units.
        time_column: Name of the time column.
        time_unit: Unit of the time column, one of :data:`TIME_UNITS`.
        drop_missing: Leave out the rows with a missing value (with a
            :class:`LogImportWarning`) instead of refusing them; a column with no value at
            all is left out instead.
        skip_columns: Columns to leave out (each must be there), e.g. a sensor logged at a
            lower rate, whose empty rows would otherwise be missing values.
        source: Name of the recording in messages (its file).
        extra: Anything worth keeping with the log (``msarm.extra``).

    Returns:
        The log: ``t`` [s], then each quantity's channels in the model's order, in SI.

    Raises:
        InputError: A column that is not a channel, names no joint or cable of the model,
            holds a value that is not a number or a missing value (without
            ``drop_missing``); a unit that cannot be converted; a bad time unit; a sample
            rate outside :data:`RATE_RANGE_HZ` (a wrong time unit?) or one given that the
            time column's mean step contradicts by more than 5 %.
        LogError: The time is not strictly increasing (the row named).
    """
    if time_unit not in TIME_UNITS:
        raise InputError(
            f"{source}: time unit {time_unit!r} is not known; expected one of "
            f"{', '.join(TIME_UNITS)}"
        )
    if time_column not in columns:
        raise InputError(
            f"{source}: no time column {time_column!r}; columns: "
            f"{', '.join(map(str, columns)) or '-'} (name the time column, e.g. "
            "--time-column)"
        )
    declared = dict(units or {})
    if time_column in declared:
        raise InputError(
            f"{source}: a unit is given for the time column {time_column!r}; give it as the "
            f"time unit instead (--time-unit, one of {', '.join(TIME_UNITS)})"
        )
    absent = [name for name in skip_columns if name not in columns]
    if absent:
        raise InputError(f"{source}: column {absent[0]!r} to skip is not in the file")
    if time_column in skip_columns:
        raise InputError(f"{source}: the time column {time_column!r} cannot be skipped")
    arrays = {
        name: _numbers(values, name, source)
        for name, values in columns.items()
        if name not in skip_columns
    }
    lengths = {len(values) for values in arrays.values()}
    if len(lengths) > 1:
        raise InputError(f"{source}: the columns have different lengths: {sorted(lengths)}")
    raw_time = arrays.pop(time_column)
    if len(raw_time) == 0:
        raise InputError(f"{source}: no samples (a header without rows?)")
    lost = ~np.isfinite(raw_time)
    if lost.any():
        raise InputError(
            f"{source}: the time column {time_column!r} has {int(lost.sum())} missing value(s), "
            f"the first at row {int(np.argmax(lost))} ({_ROWS}); a sample cannot be placed "
            "without its time (--drop-missing does not leave these out)"
        )
    # in the file's own column and unit first: the row a user looks for
    check_increasing_time(raw_time, source, _ROWS, name=time_column, unit=time_unit)
    # from the first sample: an epoch time (1.7e9 s) scaled whole loses its steps' digits
    origin = float(raw_time[0])
    since, origin_text = _from_origin(columns[time_column], raw_time)
    time = since * TIME_UNITS[time_unit]
    check_increasing_time(time, source, _ROWS)
    by_quantity: dict[str, dict[str, FloatArray]] = {}
    for name, values in arrays.items():
        try:
            quantity, channel = split_channel(name)
        except InputError as exc:
            raise InputError(
                f"{source}: {exc} (the time column is {time_column!r}: --time-column names "
                f"another){_unit_hint(name)}"
            ) from None
        by_quantity.setdefault(quantity, {})[channel] = values
    unknown_units = sorted(set(declared) - set(by_quantity))
    if unknown_units:
        raise InputError(
            f"{source}: a unit is given for {', '.join(map(repr, unknown_units))}, which no "
            f"column has; quantities: {', '.join(by_quantity) or '-'}"
        )
    _warn_some_angles_in_degrees(list(by_quantity), declared, source)
    out: dict[str, FloatArray] = {TIME: time}
    log_units: dict[str, str] = {}
    for quantity, channels in by_quantity.items():
        unit, factor = _si_unit(quantity, declared.get(quantity), source)
        log_units[quantity] = unit
        for channel in _in_model_order(quantity, channels, model, source):
            out[f"{quantity}.{channel}"] = channels[channel] * factor
    rate = _sample_rate(time, sample_rate_hz, time_column, time_unit, source)
    out = _without_missing(out, drop_missing, source)
    _check_step_kept(out[TIME], rate, source)
    extra = {**dict(extra or {}), "time_origin": origin, "time_origin_unit": time_unit}
    if origin_text is not None:  # the first time as given, every digit (a float keeps 16)
        extra["time_origin_text"] = origin_text
    metadata = LogMetadata.for_model(model, rate, units=log_units, extra=extra)
    try:
        return RunLog(out, metadata)
    except LogError as exc:
        raise LogError(str(exc).replace("RunLog", source, 1)) from None


def read_csv_log(path: str | Path, model: RobotModel, **options: Any) -> RunLog:
    """A log of ``model`` from a CSV file with a header row (see :func:`log_from_columns`).

    Args:
        path: The CSV file: a header of column names, then one row per sample; an empty
            field is a missing value, and a row of empty fields only is skipped. The time
            column is read as text (see :func:`log_from_columns`).
        model: The robot model the recording is of.
        **options: Those of :func:`log_from_columns` but ``columns`` and ``source``.

    Returns:
        The log, its ``msarm.extra`` recording the file's name as ``imported_from``.

    Raises:
        InputError: The file is missing or not CSV (a Parquet file, a log already, is said
            to be one; binary data or text not in UTF-8 is named), has no data rows, or what
            :func:`log_from_columns` refuses.
    """
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pacsv

    path = Path(path)
    source = str(path)
    if not path.is_file():
        what = "a folder, expected a CSV file" if path.is_dir() else "no such CSV file"
        raise InputError(f"{source}: {what}")
    # the header first: a file of another separator fails in the parser with a message
    # that names no separator ("Expected 1 columns, got 37")
    header = _header(path, source)
    time_column = options.get("time_column", TIME)
    _refuse_comment_line(header, time_column, source)
    _check_header([name.strip() for name in header], source)
    # the time as text: an epoch time parsed to float64 would lose its steps' digits
    text = {name: pa.string() for name in header if name.strip() == time_column}
    convert = pacsv.ConvertOptions(column_types=text, strings_can_be_null=True)
    try:
        table = pacsv.read_csv(path, convert_options=convert)
    except (pa.ArrowException, OSError) as exc:
        raise InputError(f"{source}: not a readable CSV file: {exc}") from None
    if table.num_columns:  # rows of empty fields only (",,,," as a spreadsheet leaves at
        # the end) hold nothing: skipped, as the parser skips blank lines
        empty = pc.is_null(table.column(0))
        for column in table.columns[1:]:
            empty = pc.and_(empty, pc.is_null(column))
        table = table.filter(pc.invert(empty))
    if table.num_rows == 0:
        raise InputError(
            f"{source}: no samples (a header and no data rows; rows of empty fields only are "
            "skipped); expected a row of values for each sample"
        )
    names = [name.strip() for name in table.column_names]  # "t, q.elbow" as "t,q.elbow"
    columns: dict[str, Any] = {}
    for name, column in zip(names, table.columns, strict=True):
        if name == time_column and pa.types.is_string(column.type):
            values = column.to_pylist()
            row, value = _first_text(values)
            if value is not None and not _is_number(value):
                raise InputError(
                    f"{source}: column {name!r} holds a value that is not a number: {value!r} "
                    f"at row {row} ({_ROWS}); expected numbers (the time of each sample)"
                )
            columns[name] = np.array(values, dtype=object)  # text, counted exactly
            continue
        if pa.types.is_binary(column.type):  # what the parser cannot read as UTF-8 text
            row, value = _first_not_utf8(column.to_pylist())
            raise InputError(
                f"{source}: column {name!r} holds a value that is not UTF-8 text: {value!r} at "
                f"row {row} ({_ROWS}); expected numbers, in a CSV file in UTF-8"
            )
        if not (pa.types.is_integer(column.type) or pa.types.is_floating(column.type)):
            if column.null_count == len(column):  # an empty column: every value missing
                columns[name] = np.full(len(column), np.nan)
                continue
            row, value = _first_text(column.to_pylist())
            raise InputError(
                f"{source}: column {name!r} holds a value that is not a number: {value!r} at "
                f"row {row} ({_ROWS}); expected numbers (an empty field for a missing value)"
            )
        columns[name] = column.to_numpy().astype(np.float64)
    extra = {"imported_from": path.name, **dict(options.pop("extra", None) or {})}
    return log_from_columns(columns, model, source=source, extra=extra, **options)


#: First characters of a comment line, which some loggers write before the header.
_COMMENT_MARKS = ("%", "#")


def _refuse_comment_line(header: list[str], time_column: str, source: str) -> None:
    """Refuse a first line that is a logger's comment, not the header (``%...``, ``#...``).

    A header may start with such a mark itself (``rostopic echo -p`` writes ``%time,...``):
    the line is a comment only when the time column is not one of its fields.

    Raises:
        InputError: The first line starts with ``%`` or ``#`` and does not name the time
            column (how to strip such lines is said).
    """
    text = ",".join(header).lstrip()
    names = [name.strip() for name in header]
    if not text.startswith(_COMMENT_MARKS) or time_column in names:
        return
    mark = text[0]
    raise InputError(
        f"{source}: not a CSV file msarm reads: its first line starts with {mark!r} and names "
        f"no time column {time_column!r}, a comment ({text[:60]!r}); expected a header row "
        f"of column names first. Remove the comment lines (grep -v '^{mark}' FILE > "
        "FILE.csv, if the header does not start with it too) or convert the file with a "
        "script of your own (examples/real_cable_transmission.py reads such files)"
    )


def _header(path: Path, source: str) -> list[str]:
    """The names of a CSV file's first line, as written (``.csv.gz`` decompressed).

    Raises:
        InputError: The file cannot be read or decompressed, is a Parquet file (a log
            already), holds binary data, or its first line is not UTF-8 text or not CSV.
    """
    import csv

    head = _head(path, source)
    if head.startswith(_PARQUET_MAGIC):
        raise _parquet_given(source)
    if b"\0" in head:
        raise InputError(
            f"{source}: not a readable CSV file: it holds binary data (a NUL byte near its "
            "start); expected a CSV file of text (UTF-8; a file saved as UTF-16 has NUL "
            "bytes too: save it as UTF-8)"
        )
    body = head.removeprefix(_UTF8_BOM)
    # a line ends in \r\n, \n or \r alone, as the parser reads it; blank lines are skipped
    first = next((line for line in _LINE_END.split(body) if line), b"")
    try:
        text = first.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{source}: not a readable CSV file: its header is not UTF-8 text (byte "
            f"{first[exc.start]:#04x} at position {exc.start}); expected a CSV file in UTF-8 "
            "(one saved as Latin-1 or Windows-1252? Save it as UTF-8)"
        ) from None
    try:
        return next(csv.reader([text]), [])
    except csv.Error as exc:
        raise InputError(
            f"{source}: not a readable CSV file: its header row cannot be parsed ({exc}); "
            "expected a header row of comma-separated column names"
        ) from None


def check_not_parquet(path: str | Path) -> None:
    """Refuse a Parquet file given as a CSV file: a log already, which needs no import.

    Args:
        path: The file given as a CSV file (one that cannot be read is left to the reader).

    Raises:
        InputError: The file starts with Parquet's magic bytes (``PAR1``).
    """
    try:
        with open(path, "rb") as file:
            start = file.read(len(_PARQUET_MAGIC))
    except OSError:
        return
    if start == _PARQUET_MAGIC:
        raise _parquet_given(str(path))


def _parquet_given(source: str) -> InputError:
    """The error for a Parquet file given as a CSV file."""
    return InputError(
        f"{source}: a Parquet file (it starts with {_PARQUET_MAGIC.decode()}), not a CSV file: "
        "a log already? A log needs no import: msarm log check reads it (and says whether it "
        "follows msarm's log schema); msarm log import reads CSV files"
    )


def _head(path: Path, source: str) -> bytes:
    """The start of a file (decompressed), up to its first line with something on it.

    Reading stops early at what is no text: Parquet's magic bytes or a NUL byte.
    """
    import pyarrow as pa

    text = b""
    try:
        with pa.input_stream(path, compression="detect") as stream:
            # the first line with something on it: pyarrow skips empty lines before the header
            while chunk := stream.read(1 << 16):
                text += chunk
                if text.startswith(_PARQUET_MAGIC) or b"\0" in text:
                    break
                if _LINE_END.search(text.lstrip(_UTF8_BOM + b"\r\n")):
                    break
    except (pa.ArrowException, OSError) as exc:
        raise InputError(f"{source}: not a readable CSV file: {exc}") from None
    return text


def _check_header(names: list[str], source: str) -> None:
    """Refuse a header that is not one: data, another separator, a duplicate or empty name."""
    if len(names) == 1 and any(sep in names[0] for sep in ";\t|"):
        european = (
            " (semicolons, as a spreadsheet set to decimal commas writes: export it with "
            "commas between the fields and decimal points in the numbers)"
            if ";" in names[0]
            else ""
        )
        raise InputError(
            f"{source}: the header is one column ({names[0][:60]!r}...): the file is separated "
            f"by something else than commas{european}; expected a comma-separated file"
        )
    if names and all(_is_number(name) for name in names):
        raise InputError(
            f"{source}: the first row ({', '.join(names[:4])}, ...) holds numbers; expected a "
            "header row of column names (the time column and channels <quantity>.<name>)"
        )
    if "" in names:
        raise InputError(
            f"{source}: column {names.index('') + 1} of the header has no name (a trailing "
            "comma?); expected a name for every column"
        )
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise InputError(f"{source}: column {twice!r} appears more than once in the header")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _first_text(values: list[Any]) -> tuple[int, Any]:
    """The row and value of the first entry that is not a number (nor missing)."""
    for row, value in enumerate(values):
        if value is not None and not _is_number(str(value)):
            return row, value
    return 0, values[0]


def _first_not_utf8(values: list[bytes | None]) -> tuple[int, bytes | None]:
    """The row and value of the first entry that is not UTF-8 text (nor missing)."""
    for row, value in enumerate(values):
        try:
            if value is not None:
                value.decode("utf-8")
        except UnicodeDecodeError:
            return row, value
    return 0, values[0]


def _from_origin(values: ArrayLike, parsed: FloatArray) -> tuple[FloatArray, str | None]:
    """Sample times less the first, in their own unit; exact when given as text.

    ``parsed`` ``(T,)`` are ``values`` as float64, whose 16 digits keep an epoch time's
    steps only to about 2e-7 s (1.7e9 s): a time given as text (``"1700000123.456"``, as
    :func:`read_csv_log` reads it) or as :class:`~decimal.Decimal` is subtracted exactly,
    then turned into floats. Every value is a finite number here.

    Returns:
        ``(times, origin)``: the times from the first, ``(T,)``; and the first time as it
        was given, every digit, when given as text or decimals (else None).
    """
    given = np.asarray(values)
    if given.dtype.kind not in "OU":
        return parsed - parsed[0], None
    exact = [Decimal(str(value).strip()) for value in given]
    return np.array([float(value - exact[0]) for value in exact]), str(given[0]).strip()


def _warn_some_angles_in_degrees(
    quantities: list[str], declared: Mapping[str, str], source: str
) -> None:
    """Warn when some angle quantities are given in degrees and others in no unit (rad).

    A ``--unit q=deg`` without ``--unit q_ref=deg`` leaves a reference in degrees read as
    radians; one in rad indeed is said so with ``--unit q_ref=rad``.
    """
    angles = [q for q in quantities if STANDARD_UNITS.get(q, "").startswith("rad")]
    degrees = [
        q
        for q in angles
        if q in declared and same_unit(declared[q], "deg" + STANDARD_UNITS[q][len("rad") :])
    ]
    untold = [q for q in angles if q not in declared]
    if not degrees or not untold:
        return
    given = " ".join(f"--unit {q}={declared[q]}" for q in degrees)
    suggested = " ".join(f"--unit {q}=deg{STANDARD_UNITS[q][len('rad') :]}" for q in untold)
    said = " ".join(f"--unit {q}={STANDARD_UNITS[q]}" for q in untold)
    taken = ", ".join(dict.fromkeys(STANDARD_UNITS[q] for q in untold))
    warnings.warn(
        f"{source}: {', '.join(degrees)} in degrees ({given}), but no unit is given for "
        f"{', '.join(untold)}, which are taken to be in {taken}: are they in degrees too "
        f"({suggested})? Say so if they are in {taken} ({said})",
        LogImportWarning,
        stacklevel=3,
    )


def _numbers(values: ArrayLike, name: str, source: str) -> FloatArray:
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{source}: column {name!r} holds values that are not numbers") from None
    if array.ndim != 1:
        raise InputError(f"{source}: column {name!r} must be 1-D, got shape {array.shape}")
    return array


def _unit_hint(name: str) -> str:
    """A hint for a column name that holds a unit (``q.elbow [deg]``), else ``""``."""
    if not any(mark in name for mark in "[( "):
        return ""
    return (
        " (the name holds '[', '(' or a space: a unit in the header? Name the columns "
        "<quantity>.<name> alone and give units with --unit QUANTITY=UNIT)"
    )


def _si_unit(quantity: str, given: str | None, source: str) -> tuple[str, float]:
    """The unit a quantity is logged in and the factor from the recording's unit to it."""
    standard = STANDARD_UNITS.get(quantity)
    if standard is None:
        if given is None:
            raise InputError(
                f"{source}: no unit for quantity {quantity!r} (not one of msarm's: "
                f"{', '.join(STANDARD_UNITS)}); give it (--unit {quantity}=UNIT), or leave its "
                f"columns out (--skip-column {quantity}.<name>)"
            )
        return given, 1.0
    if given is None or same_unit(given, standard):
        return standard, 1.0
    for other, factor in CONVERSIONS.get(standard, {}).items():
        if same_unit(given, other):
            return standard, factor
    known = ", ".join([standard, *CONVERSIONS.get(standard, {})])
    raise InputError(
        f"{source}: quantity {quantity!r} in {given!r} cannot be converted to {standard!r} "
        f"(msarm's unit for it); units known for it: {known}"
    )


def _in_model_order(
    quantity: str, channels: Mapping[str, FloatArray], model: RobotModel, source: str
) -> list[str]:
    """The channel names of a quantity, in the model's order.

    Only for a quantity that runs over the joints or cables (each name must then be one of
    them); any other keeps its columns' order.
    """
    if quantity in JOINT_QUANTITIES:
        known, kind = list(model.joint_names), "joint"
    elif quantity in CABLE_QUANTITIES:
        known, kind = list(model.cable_names), "cable"
    else:
        return list(channels)
    strangers = [name for name in channels if name not in known]
    if strangers:
        raise InputError(
            f"{source}: column '{quantity}.{strangers[0]}' names no {kind} of the model "
            f"{model.name!r}; its {kind}s: {', '.join(known)}{_unit_hint(strangers[0])}"
        )
    return [name for name in known if name in channels]


def _without_missing(
    columns: dict[str, FloatArray], drop_missing: bool, source: str
) -> dict[str, FloatArray]:
    """The columns, or (``drop_missing``) without empty columns and rows with a gap."""
    missing = {name: ~np.isfinite(values) for name, values in columns.items()}
    missing = {name: rows for name, rows in missing.items() if rows.any()}
    if not missing:
        return columns
    if not drop_missing:
        sparse = [name for name, rows in missing.items() if rows.mean() >= 0.5]
        hint = (
            f"; a column missing in most rows ({sparse[0]!r}: a sensor logged at a lower "
            "rate?) is better skipped (--skip-column)"
            if sparse
            else ""
        )
        raise InputError(
            f"{source}: {len(missing)} column(s) have missing values (empty, NaN or infinite; "
            f"{_counts(missing)}); the log schema has none: fill them, or leave those rows out "
            f"(--drop-missing; the diagnosis then sees a time gap there){hint}"
        )
    empty = [name for name, rows in missing.items() if rows.all()]
    if empty:
        warnings.warn(
            f"{source}: column(s) {', '.join(map(repr, empty))} have no value in any row and "
            "are left out",
            LogImportWarning,
            stacklevel=3,
        )
        columns = {name: values for name, values in columns.items() if name not in empty}
        missing = {name: rows for name, rows in missing.items() if name not in empty}
        if not missing:
            return columns
    drop = np.logical_or.reduce(list(missing.values()))
    if drop.all():
        raise InputError(
            f"{source}: every row has a missing value ({_counts(missing)}); nothing is left "
            "(skip the columns that are mostly missing: --skip-column)"
        )
    warnings.warn(
        f"{source}: {int(drop.sum())} row(s) with a missing value left out "
        f"({100.0 * drop.mean():.2g} % of the rows; {_counts(missing)})",
        LogImportWarning,
        stacklevel=3,
    )
    return {name: values[~drop] for name, values in columns.items()}


def _counts(missing: Mapping[str, NDArray[np.bool_]]) -> str:
    """``"5 in 'q.elbow' (first at row 3), ..."`` for the first columns of ``missing``."""
    shown = [
        f"{int(rows.sum())} in {name!r} (first at row {int(np.argmax(rows))})"
        for name, rows in list(missing.items())[:_NAMED]
    ]
    more = f", and {len(missing) - _NAMED} more column(s)" if len(missing) > _NAMED else ""
    return ", ".join(shown) + more + f"; {_ROWS}"


def _check_step_kept(t: FloatArray, rate: float, source: str) -> None:
    """Refuse a log whose rows left out (``drop_missing``) changed its time step.

    Every other row dropped (a column logged at half the rate) doubles the nominal step
    (:func:`~msarm.io.logs.nominal_step`): the log would no longer be at its sample rate.
    """
    if len(t) < 2:
        return
    step = nominal_step(t)
    if abs(step * rate - 1.0) > _RATE_TOLERANCE:
        raise InputError(
            f"{source}: leaving out the rows with a missing value changes the time step from "
            f"{1.0 / rate:.6g} s to {step:.6g} s (the mean step between gaps): a column logged "
            "at a lower rate? Leave it out (--skip-column) rather than its rows"
        )


def _roundest_rate(rate: float, regular: FloatArray, n_gaps: int) -> float:
    """The rate [Hz] with the fewest digits that the time stamps cannot tell from ``rate``.

    Time stamps rounded to a unit ``q`` (the spread of the regular steps) give a mean step
    that is off by up to about ``q (1 + n_gaps) / (sum of the regular steps)`` relative (the
    roundings of the ends of the stretches): so two logs of one robot, of other lengths,
    would get rates that differ in their fifth digit (300 and 300.03 Hz) and could not be
    diagnosed together. The rate is rounded to the fewest decimals within that uncertainty,
    and to six significant digits at most (evenly stamped times: no uncertainty to speak of).
    """
    quantum = float(regular.max() - regular.min())
    uncertainty = rate * quantum * (1 + n_gaps) / float(regular.sum())
    for decimals in range(-3, 7):
        candidate = round(rate, decimals)
        if candidate > 0 and abs(candidate - rate) <= uncertainty:
            return float(f"{candidate:.{_RATE_DIGITS}g}")
    return float(f"{rate:.{_RATE_DIGITS}g}")


def _sample_rate(
    t: FloatArray, given: float | None, time_column: str, time_unit: str, source: str
) -> float:
    """The sample rate given, or ``1 / nominal step`` of ``t`` to six significant digits.

    The nominal step is the mean of the steps between gaps
    (:func:`~msarm.io.logs.nominal_step`): time stamps rounded to whole milliseconds at
    300 Hz step 3, 3, 4 ms, whose median would make 333 Hz. Steps that spread by more than
    :data:`_JITTER_WARNING` of it are warned about (:class:`LogImportWarning`).

    Raises:
        InputError: A rate not finite and > 0, outside :data:`RATE_RANGE_HZ`, given and off
            the nominal step by more than 5 %, or not to be had (fewer than two samples).
    """
    if given is not None and not (math.isfinite(given) and given > 0):
        raise InputError(f"{source}: sample rate must be finite and > 0 [Hz], got {given}")
    if len(t) < 2:
        if given is None:
            raise InputError(
                f"{source}: the sample rate cannot be taken from one sample; give it (--rate)"
            )
        return float(given)
    regular = regular_steps(t)
    step = float(np.mean(regular))
    measured = _roundest_rate(1.0 / step, regular, len(t) - 1 - regular.size)
    rate = measured if given is None else float(given)
    low, high = RATE_RANGE_HZ
    if not low <= rate <= high:
        how = "given" if given is not None else f"from the mean step of {step:.6g} s"
        raise InputError(
            f"{source}: a sample rate of {rate:.6g} Hz ({how}) is outside {low:g}-{high:g} Hz: "
            f"is the time column {time_column!r} in {time_unit!r}? (--time-unit: one of "
            f"{', '.join(TIME_UNITS)})"
        )
    if given is not None and abs(given * step - 1.0) > _RATE_TOLERANCE:
        raise InputError(
            f"{source}: the sample rate given, {given:g} Hz, disagrees with the time column's "
            f"mean step of {step:.6g} s ({measured:g} Hz; gaps left out); give the rate the "
            "file was logged at, or leave --rate out to take it from the time"
        )
    spread = float(np.std(regular)) / step
    if spread > _JITTER_WARNING:
        scale = TIME_UNITS[time_unit]
        how = (
            "given"
            if given is not None
            else "their mean; give the rate the robot was logged at with --rate"
        )
        warnings.warn(
            f"{source}: the time column {time_column!r} steps unevenly: from "
            f"{float(regular.min()) / scale:.6g} to {float(regular.max()) / scale:.6g} "
            f"{time_unit} (standard deviation {100.0 * spread:.2g} % of the mean step, "
            f"{step / scale:.6g} {time_unit}; gaps left out): time stamps rounded to a "
            "coarser unit than the step, or a clock that jitters? The diagnosis takes the "
            f"samples as evenly spaced at {rate:g} Hz ({how}): right if only the stamps "
            "are rounded, not if the sampling jitters",
            LogImportWarning,
            stacklevel=3,
        )
    return rate
