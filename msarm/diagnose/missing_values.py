"""Missing values in a log the diagnosis reads: left out as a dropout, with a warning.

A real robot's log may hold missing samples: a sensor that dropped out for a few samples
(written as NaN, as a null by pandas, or as an infinity by a driver that saturates). The log
schema has no missing values, so :func:`msarm.io.logs.read_log` refuses such a log; the
diagnosis reads it with :func:`msarm.io.logs.read_log_with_missing_values` and decides, column
by column, what it can still do (each case warned, naming the file and the columns):

- a column the diagnosis does not read (``activation.<muscle>``, ``motor_torque.<cable>``,
  a joint or cable of no model, ...) is left out of the log: nothing changes;
- a column of an optional channel (``motor_angle``, ``tension_cmd``, ``q_ref``) with no
  value in any row is left out, so the channel counts as not logged (the terms that need it
  are skipped, as for a log without it);
- an optional channel whose missing values fall in more than
  :data:`OPTIONAL_MISSING_LIMIT` of the rows (a channel logged at a lower rate, say) is left
  out too, rather than cut the log into pieces;
- otherwise the rows with a missing value in a column the diagnosis reads (those above and
  ``q``, ``tension_motor``) are left out: the log is diagnosed around them as around a time
  gap (:func:`msarm.diagnose.residuals.gap_starts`), in contiguous segments, and a segment
  shorter than the derivative filter is left out with them;
- a ``q`` or ``tension_motor`` column with no value in any row is refused: every residual
  needs it.

A missing value in ``t`` is refused by the reader: no sample can be placed without its time.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from msarm.errors import LogError
from msarm.io.logs import TIME, RunLog, read_log_with_missing_values
from msarm.model import RobotModel

__all__ = [
    "OPTIONAL_CHANNELS",
    "OPTIONAL_MISSING_LIMIT",
    "REQUIRED_CHANNELS",
    "read_log_for_diagnosis",
]

FloatArray = NDArray[np.float64]

#: Quantities the diagnosis cannot do without, each over the model's joints or cables.
REQUIRED_CHANNELS = ("q", "tension_motor")
#: Quantities the diagnosis reads when every one of their columns is logged.
OPTIONAL_CHANNELS = ("motor_angle", "tension_cmd", "q_ref")
#: Share of a log's rows above which the missing values of an optional channel leave the
#: channel out (as not logged) instead of their rows.
OPTIONAL_MISSING_LIMIT = 0.1
#: Quantities whose channels run over the joints (the others run over the cables).
_JOINT_QUANTITIES = ("q", "q_ref")
#: Columns listed by name in a warning before the rest are counted.
_NAMED = 3


def read_log_for_diagnosis(
    model: RobotModel, path: str | Path, source: str | None = None
) -> RunLog:
    """Read a log for the diagnosis, leaving out its missing values (see the module docstring).

    Args:
        model: The nominal robot model (its joint and cable names say which columns are read).
        path: The log's Parquet file (the sidecar is never opened).
        source: Name of the log in messages; default the path.

    Returns:
        The log without the columns and rows left out; the same log as
        :func:`msarm.io.logs.read_log` gives when nothing is missing.

    Raises:
        LogError: As :func:`msarm.io.logs.read_log` (a missing time included), and when a
            ``q`` or ``tension_motor`` column of the model has no value in any row, or no row
            is left.

    Warns:
        DiagnosisWarning: For each case of the module docstring, naming the file and columns.
    """
    from msarm.diagnose.residuals import DiagnosisWarning

    source = source or str(path)
    columns, metadata = read_log_with_missing_values(path)
    missing = {name: ~np.isfinite(values) for name, values in columns.items() if name != TIME}
    missing = {name: rows for name, rows in missing.items() if rows.any()}
    if not missing:
        return RunLog(columns, metadata)
    read = _columns_read(model, columns, missing)
    unread = [name for name in missing if name not in read]
    empty = [name for name in missing if name in read and missing[name].all()]
    for name in empty:
        if _quantity(name) in REQUIRED_CHANNELS:
            raise LogError(
                f"{source}: column {name!r} has no value in any row (NaN, null or infinite "
                "throughout); the diagnosis needs q.<joint> for every joint and "
                "tension_motor.<cable> for every cable"
            )
    if unread:
        warnings.warn(
            f"{source}: {_named(unread)} {_have(unread)} missing values (NaN, null or "
            f"infinite; {_first(unread, missing, columns)}); the diagnosis does not read "
            f"{_them(unread)} and leaves {_them(unread)} out",
            DiagnosisWarning,
            stacklevel=2,
        )
    if empty:
        warnings.warn(
            f"{source}: {_named(empty)} {_have(empty)} no value in any row (NaN, null or "
            f"infinite throughout); the diagnosis leaves {_them(empty)} out, as if not "
            "logged (the warning about the missing channel says what that costs)",
            DiagnosisWarning,
            stacklevel=2,
        )
    sparse = _sparse_optional_columns(model, missing, read, empty)
    if sparse:
        share = np.logical_or.reduce([missing[name] for name in sparse]).mean()
        warnings.warn(
            f"{source}: {_named(sparse)} {_have(sparse)} missing values in "
            f"{100.0 * share:.2g} % of the rows ({_first(sparse, missing, columns)}; a channel "
            "logged at a lower rate?); leaving those rows out would cost more than "
            f"{100.0 * OPTIONAL_MISSING_LIMIT:g} % of the log, so the diagnosis leaves "
            f"{_them(sparse)} out instead, as if not logged (the warning about the missing "
            "channel says what that costs)",
            DiagnosisWarning,
            stacklevel=2,
        )
    partial = [name for name in missing if name in read and name not in empty + sparse]
    kept = {name: values for name, values in columns.items() if name not in unread + empty + sparse}
    if not partial:
        return RunLog(kept, metadata)
    drop = np.logical_or.reduce([missing[name] for name in partial])
    if drop.all():
        raise LogError(
            f"{source}: every row has a missing value (NaN, null or infinite) in a column the "
            f"diagnosis reads ({_named(partial)}); nothing is left to diagnose"
        )
    warnings.warn(
        f"{source}: {_named(partial)} {_have(partial)} missing values (NaN, null or "
        f"infinite; {_first(partial, missing, columns)}); the {int(drop.sum())} row(s) with "
        f"a missing value in a column the diagnosis reads ({100.0 * drop.mean():.2g} % of "
        "the log) are left out, and the log is diagnosed around them as around a time gap",
        DiagnosisWarning,
        stacklevel=2,
    )
    keep = ~drop
    return RunLog({name: values[keep] for name, values in kept.items()}, metadata)


def _sparse_optional_columns(
    model: RobotModel,
    missing: dict[str, NDArray[np.bool_]],
    read: set[str],
    empty: list[str],
) -> list[str]:
    """The read columns of the optional channels with too many rows missing.

    A channel qualifies when its missing rows (over its columns) are more than
    :data:`OPTIONAL_MISSING_LIMIT` of the log. Such a channel (a sensor logged at a lower
    rate, say) is better left out than have its gaps cut the log: rows dropped every other
    sample would double the time step.
    """
    sparse: list[str] = []
    for quantity in OPTIONAL_CHANNELS:
        holed = [
            column
            for column in _channel_columns(model, quantity)
            if column in missing and column in read and column not in empty
        ]
        if holed and np.logical_or.reduce([missing[c] for c in holed]).mean() > (
            OPTIONAL_MISSING_LIMIT
        ):
            sparse.extend(holed)
    return sparse


def _columns_read(
    model: RobotModel, columns: dict[str, FloatArray], missing: dict[str, NDArray[np.bool_]]
) -> set[str]:
    """The columns the diagnosis reads, and the empty columns of the optional channels.

    Every column of a required channel is read; an optional channel is read when it has a
    column for each of the model's joints or cables and each of them has a value somewhere.
    """
    read: set[str] = set()
    for quantity in REQUIRED_CHANNELS + OPTIONAL_CHANNELS:
        wanted = _channel_columns(model, quantity)
        if quantity in REQUIRED_CHANNELS:
            read.update(name for name in wanted if name in columns)
            continue
        complete = all(
            name in columns and not (name in missing and missing[name].all()) for name in wanted
        )
        # a channel with a column absent or empty is not read; its empty columns are
        # counted with the read ones so that they are reported as left out, not logged
        read.update(
            name
            for name in wanted
            if name in columns and (complete or (name in missing and missing[name].all()))
        )
    return read


def _channel_columns(model: RobotModel, quantity: str) -> list[str]:
    """The columns ``quantity.<name>`` of every joint (or cable) of the model, in its order."""
    names = model.joint_names if quantity in _JOINT_QUANTITIES else model.cable_names
    return [f"{quantity}.{name}" for name in names]


def _quantity(column: str) -> str:
    return column.split(".", 1)[0]


def _named(names: list[str]) -> str:
    shown = ", ".join(repr(name) for name in names[:_NAMED])
    more = f" and {len(names) - _NAMED} more" if len(names) > _NAMED else ""
    return f"column{'s' if len(names) > 1 else ''} {shown}{more}"


def _have(names: list[str]) -> str:
    return "have" if len(names) > 1 else "has"


def _them(names: list[str]) -> str:
    return "them" if len(names) > 1 else "it"


def _first(
    names: list[str], missing: dict[str, NDArray[np.bool_]], columns: dict[str, FloatArray]
) -> str:
    """Where the first missing value of the first column named is, and how many it has."""
    rows = missing[names[0]]
    row = int(np.argmax(rows))
    return (
        f"{int(rows.sum())} in {names[0]!r}, the first at row {row}, "
        f"t = {float(columns[TIME][row]):.6g} s"
    )
