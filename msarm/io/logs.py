"""Run logs: the Parquet interchange format, and the sim-only ground-truth sidecar.

Log schema, version 1
---------------------
One Parquet file per run, one row per sample.

Columns (every one ``double``, i.e. float64, without nulls, NaN or infinities):

- ``t`` -- time [s], strictly increasing (msarm writes it first; readers accept it anywhere).
- Channels named ``<quantity>.<name>``: ``quantity`` is an identifier (letters, digits and
  ``_``, not starting with a digit), ``name`` is the joint or cable name from the robot's model
  file (anything non-empty after the first dot), e.g. ``q.elbow``, ``tension_motor.biceps``.
  The channels of one quantity are in the model file's joint or cable order. Column names are
  unique.

File key-value metadata (Parquet footer), each value a JSON text, every key prefixed
``msarm.``:

================================  ========================================================
key                               value
================================  ========================================================
``msarm.schema_version``          ``1`` (integer)
``msarm.robot_model``             robot model name (string), e.g. ``"msarm_arm"``
``msarm.model_sha256``            SHA-256 of the model's MJCF file (hex string)
``msarm.sample_rate_hz``          nominal sample rate [Hz] (number > 0)
``msarm.units``                   object: quantity -> unit (``{"q": "rad", ...}``); every
                                  quantity of the columns has one (SI: ``rad``, ``N``, ``m``)
``msarm.controller_config``       object: the controller's resolved config (may be ``{}``)
``msarm.extra``                   object: anything else (task name, seed, ...; may be ``{}``)
================================  ========================================================

Every value is standard JSON (RFC 8259): a NaN or an infinity anywhere in the metadata is
refused when the metadata is built (the key named), never written as the non-standard
``NaN``/``Infinity`` nor turned into ``null``.

Other metadata keys (those of pandas or Arrow, say) are ignored; unknown ``msarm.`` keys are
refused. A log from another robot is valid when it follows this schema; ``read_log`` checks
all of it and names the file, the column or key, and what was expected.

Ground-truth sidecar
--------------------
What only a simulation knows -- the plant's effects and their parameters, and hidden signals
such as the tension at the insertion -- goes to ``<stem>.truth.parquet`` next to the log
``<stem>.parquet`` (:func:`sidecar_path`), never into the log, so that a diagnosis reading the
log cannot read what it must find. Its columns follow the same rules (``t`` and
``<quantity>.<name>``, float64); its metadata keys are prefixed ``msarm_truth.``:
``schema_version`` (1), ``ground_truth`` (object: the plant's effects and their parameters) and
``units``. :func:`read_log` never opens the sidecar and refuses a sidecar given as a log.

Writes are atomic (a temporary file in the same folder, then ``os.replace``); a write then read
gives back the same columns bit for bit and the same metadata.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError, LogError
from msarm.io.atomic import atomic_path

__all__ = [
    "SCHEMA_VERSION",
    "NOMINAL_STEP_GAP",
    "SIDECAR_SCHEMA_VERSION",
    "STANDARD_TRUTH_UNITS",
    "STANDARD_UNITS",
    "LogMetadata",
    "columns_from_quantities",
    "RunLog",
    "TruthSidecar",
    "check_increasing_time",
    "check_standard_units",
    "nominal_step",
    "regular_steps",
    "read_log",
    "read_log_with_missing_values",
    "read_model_sha256",
    "read_sidecar",
    "same_unit",
    "sidecar_path",
    "split_channel",
    "write_log",
    "write_sidecar",
]

FloatArray = NDArray[np.float64]

#: Version of the log schema this module writes and reads.
SCHEMA_VERSION = 1
#: Version of the ground-truth sidecar schema.
SIDECAR_SCHEMA_VERSION = 1
#: Prefix of the log's metadata keys.
_PREFIX = "msarm."
#: Prefix of the sidecar's metadata keys.
_TRUTH_PREFIX = "msarm_truth."
#: Suffix of a sidecar file name (replaces the log's ``.parquet``).
_SIDECAR_SUFFIX = ".truth.parquet"
#: Name of the time column.
TIME = "t"
#: A time step longer than this many nominal steps is a gap, left out of the nominal step.
NOMINAL_STEP_GAP = 1.5
_QUANTITY_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

#: Units of the quantities msarm logs (SI), for :attr:`LogMetadata.units`: every quantity of
#: the arm runner's logs (``msarm.tasks.runner.LOG_UNITS`` is taken from here) and the common
#: names a user's own log may use (``qd``, ``tau``, ...).
STANDARD_UNITS: Mapping[str, str] = {
    "q": "rad",
    "qd": "rad/s",
    "qdd": "rad/s^2",
    "qdot_est": "rad/s",
    "q_ref": "rad",
    "qd_ref": "rad/s",
    "qdd_ref": "rad/s^2",
    "tau": "N m",
    "tau_cmd": "N m",
    "tau_ff": "N m",
    "tension_cmd": "N",
    "tension_ff": "N",
    "tension_motor": "N",
    "motor_angle": "rad",
    "motor_torque": "N m",
    "cable_length": "m",
    "activation": "1",
    "excitation": "1",
}

#: Units of the ground-truth quantities msarm writes to the sidecar (SI);
#: ``msarm.tasks.runner.TRUTH_UNITS`` is taken from here.
STANDARD_TRUTH_UNITS: Mapping[str, str] = {
    "q": "rad",
    "qdot": "rad/s",
    "tension_insertion": "N",
    "tension_motor": "N",
    "stretch": "m",
    "wrap_angle": "rad",
}


class _HasNameAndHash(Protocol):
    @property
    def name(self) -> str: ...

    @property
    def sha256(self) -> str: ...


def split_channel(column: str) -> tuple[str, str]:
    """Split a channel column name ``<quantity>.<name>`` at its first dot.

    Args:
        column: Column name, e.g. ``"tension_motor.biceps"``.

    Returns:
        ``(quantity, name)``, e.g. ``("tension_motor", "biceps")``.

    Raises:
        InputError: The name has no dot, an empty part, or a quantity that is no identifier.
    """
    quantity, dot, name = column.partition(".")
    if not dot or not name or not _QUANTITY_RE.match(quantity):
        raise InputError(
            f"channel column {column!r} is not named '<quantity>.<name>' (quantity: letters, "
            "digits and '_', not starting with a digit; name: non-empty)"
        )
    return quantity, name


def _non_finite_key(value: Any, where: str) -> str | None:
    """The path (``extra['a'][2]``) of the first NaN or infinity in ``value``, or None."""
    if isinstance(value, float | np.floating) and not math.isfinite(value):
        return where
    if isinstance(value, Mapping):
        items: Any = ((f"{where}[{key!r}]", item) for key, item in value.items())
    elif isinstance(value, list | tuple):
        items = ((f"{where}[{i}]", item) for i, item in enumerate(value))
    else:
        return None
    for path, item in items:
        found = _non_finite_key(item, path)
        if found is not None:
            return found
    return None


def _json_roundtrip(value: Any, what: str) -> Any:
    """``value`` as it comes back from JSON (tuples become lists).

    Raises:
        InputError: ``value`` is not JSON-serialisable, or holds a NaN or an infinity
            (standard JSON has none; the key is named).
    """
    bad = _non_finite_key(value, what)
    if bad is not None:
        raise InputError(
            f"{bad} is not finite; metadata is standard JSON, which has no NaN or infinity "
            "(store a finite number, or null/a string for 'no value')"
        )
    try:
        return json.loads(json.dumps(value, allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise InputError(f"{what} must be JSON-serialisable: {exc}") from None


@dataclass(frozen=True)
class LogMetadata:
    """What a log says about its run (the ``msarm.*`` key-value metadata of the file).

    Mappings are stored as they come back from JSON (tuples become lists), so that a
    written and read log compares equal.

    Attributes:
        robot_model: Name of the robot model.
        model_sha256: SHA-256 of the robot's MJCF file (hex).
        sample_rate_hz: Nominal sample rate [Hz], finite and > 0 (a Python or numpy number;
            stored as a float).
        units: Unit of every quantity of the log's channels (quantity -> unit string).
        controller_config: The controller's resolved config (plain data, see
            :func:`msarm.io.config.config_to_dict`), without NaN or infinities.
        extra: Anything else worth keeping with the run (plain JSON data), without NaN or
            infinities.

    Raises:
        InputError: A field of the wrong type, a sample rate that is not finite and > 0, or
            a value that is not standard JSON (a NaN or infinity anywhere is refused, its key
            named).
        schema_version: Log schema version (only :data:`SCHEMA_VERSION` exists).
    """

    robot_model: str
    model_sha256: str
    sample_rate_hz: float
    units: Mapping[str, str] = field(default_factory=dict)
    controller_config: Mapping[str, Any] = field(default_factory=dict)
    extra: Mapping[str, Any] = field(default_factory=dict)
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        if not isinstance(self.robot_model, str) or not self.robot_model:
            raise InputError(f"robot_model must be a non-empty string, got {self.robot_model!r}")
        if not isinstance(self.model_sha256, str):
            raise InputError(f"model_sha256 must be a string, got {self.model_sha256!r}")
        if not re.fullmatch(r"[0-9a-fA-F]{64}", self.model_sha256):
            raise InputError(
                "model_sha256 must be the SHA-256 of the model's MJCF file, 64 hex digits "
                f"(msarm.model.RobotModel.sha256), got {self.model_sha256!r}"
            )
        rate = self.sample_rate_hz
        if isinstance(rate, bool | np.bool_) or not isinstance(
            rate, int | float | np.integer | np.floating
        ):
            raise InputError(
                f"sample_rate_hz must be a real number [Hz], got {rate!r} of type "
                f"{type(rate).__name__}"
            )
        if not (math.isfinite(rate) and rate > 0):
            raise InputError(f"sample_rate_hz must be finite and > 0 [Hz], got {float(rate)}")
        object.__setattr__(self, "sample_rate_hz", float(rate))
        if not isinstance(self.units, Mapping) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in self.units.items()
        ):
            raise InputError(f"units must map quantity names to unit strings, got {self.units!r}")
        object.__setattr__(self, "units", dict(self.units))
        for name in ("controller_config", "extra"):
            value = getattr(self, name)
            if not isinstance(value, Mapping):
                raise InputError(f"{name} must be a mapping, got {type(value).__name__}")
            object.__setattr__(self, name, _json_roundtrip(dict(value), name))
        if self.schema_version != SCHEMA_VERSION:
            raise InputError(
                f"schema_version must be {SCHEMA_VERSION}, got {self.schema_version!r}"
            )

    @classmethod
    def for_model(
        cls,
        model: _HasNameAndHash,
        sample_rate_hz: float,
        units: Mapping[str, str] | None = None,
        controller_config: Mapping[str, Any] | None = None,
        extra: Mapping[str, Any] | None = None,
    ) -> LogMetadata:
        """Metadata of a run of ``model`` (a :class:`msarm.model.RobotModel`).

        Args:
            model: Anything with ``.name`` and ``.sha256``.
            sample_rate_hz: Nominal sample rate [Hz].
            units: Units of the logged quantities; default :data:`STANDARD_UNITS` (which
                covers every quantity of msarm's own arm runs).
            controller_config: The controller's resolved config (plain data).
            extra: Anything else.

        Returns:
            The metadata.
        """
        return cls(
            robot_model=model.name,
            model_sha256=model.sha256,
            sample_rate_hz=sample_rate_hz,
            units=dict(STANDARD_UNITS if units is None else units),
            controller_config=dict(controller_config or {}),
            extra=dict(extra or {}),
        )

    def to_kv(self) -> dict[str, str]:
        """The Parquet key-value metadata: ``msarm.<field>`` -> JSON text.

        Returns:
            One entry per field (``schema_version``, ``robot_model``, ``model_sha256``,
            ``sample_rate_hz``, ``units``, ``controller_config``, ``extra``), keyed
            ``msarm.<field>``, each value the field's JSON text.
        """
        return {
            _PREFIX + "schema_version": json.dumps(self.schema_version),
            _PREFIX + "robot_model": json.dumps(self.robot_model),
            _PREFIX + "model_sha256": json.dumps(self.model_sha256),
            _PREFIX + "sample_rate_hz": json.dumps(self.sample_rate_hz),
            _PREFIX + "units": json.dumps(self.units),
            _PREFIX + "controller_config": json.dumps(self.controller_config),
            _PREFIX + "extra": json.dumps(self.extra),
        }


class _Channels:
    """Column access shared by :class:`RunLog` and :class:`TruthSidecar`."""

    columns: Mapping[str, FloatArray]

    @property
    def t(self) -> FloatArray:
        """Sample times [s], shape ``(T,)``."""
        return self.columns[TIME]

    def __len__(self) -> int:
        """Number of samples ``T``."""
        return len(self.columns[TIME])

    @property
    def duration(self) -> float:
        """Time from the first to the last sample [s] (0 for a single sample)."""
        t = self.t
        return float(t[-1] - t[0])

    def quantities(self) -> list[str]:
        """The quantities of the channels, in order of first appearance (``t`` excluded)."""
        seen: dict[str, None] = {}
        for column in self.columns:
            if column != TIME:
                seen.setdefault(split_channel(column)[0], None)
        return list(seen)

    def names(self, quantity: str) -> list[str]:
        """Channel names of one quantity, in column order.

        Args:
            quantity: E.g. ``"q"`` for the columns ``q.<joint>``.

        Returns:
            The names after the dot, e.g. the joint names.

        Raises:
            InputError: No channel of that quantity.
        """
        prefix = quantity + "."
        out = [c[len(prefix) :] for c in self.columns if c.startswith(prefix)]
        if not out:
            raise InputError(
                f"no channel of quantity {quantity!r}; quantities: {', '.join(self.quantities())}"
            )
        return out

    def matrix(self, quantity: str, names: Sequence[str] | None = None) -> FloatArray:
        """The channels of one quantity stacked as columns.

        Args:
            quantity: E.g. ``"tension_motor"``.
            names: Channel names, in the order wanted; default all, in column order.

        Returns:
            Array of shape ``(T, k)`` (a copy), ``k`` the number of names.

        Raises:
            InputError: Unknown quantity or name.
        """
        available = self.names(quantity)
        if names is None:
            names = available
        else:
            missing = [n for n in names if n not in available]
            if missing:
                raise InputError(
                    f"no channel {quantity}.{missing[0]}; names of {quantity!r}: "
                    f"{', '.join(available)}"
                )
        if len(names) == 0:
            return np.empty((len(self), 0))
        return np.column_stack([self.columns[f"{quantity}.{n}"] for n in names])

    def _columns_equal(self, other: _Channels) -> bool:
        return list(self.columns) == list(other.columns) and all(
            a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
            for a, b in zip(self.columns.values(), other.columns.values(), strict=True)
        )


@dataclass(frozen=True, eq=False)
class RunLog(_Channels):
    """One run: columns and metadata (the in-memory form of a log file).

    ``t`` is moved to the front; every column is checked (see the module docstring).
    Equality is bit for bit on the columns (names and order included) and on the metadata.

    Attributes:
        columns: Column name -> samples, each float64 of shape ``(T,)``: ``t`` [s] and the
            channels ``<quantity>.<name>``.
        metadata: What the log says about its run.
    """

    columns: Mapping[str, FloatArray]
    metadata: LogMetadata

    def __post_init__(self) -> None:
        object.__setattr__(self, "columns", _checked_columns(self.columns, "RunLog"))
        if not isinstance(self.metadata, LogMetadata):
            raise InputError(f"metadata must be a LogMetadata, got {type(self.metadata).__name__}")
        _check_units(self.columns, self.metadata.units, "RunLog")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RunLog):
            return NotImplemented
        return self.metadata == other.metadata and self._columns_equal(other)

    __hash__ = None  # type: ignore[assignment]

    @classmethod
    def from_quantities(
        cls,
        t: ArrayLike,
        channels: Mapping[str, tuple[Sequence[str], ArrayLike]],
        metadata: LogMetadata,
    ) -> RunLog:
        """Build a log from one matrix per quantity.

        Args:
            t: Sample times [s], shape ``(T,)``.
            channels: quantity -> (names, values of shape ``(T, k)``), e.g.
                ``{"q": (model.joint_names, Q)}``.
            metadata: The run's metadata.

        Returns:
            The log, columns ``t`` then each quantity's channels in the order given.
        """
        return cls(columns_from_quantities(t, channels), metadata)


@dataclass(frozen=True, eq=False)
class TruthSidecar(_Channels):
    """Sim-only ground truth of a run (the in-memory form of a sidecar file).

    Attributes:
        columns: Column name -> samples, float64 of shape ``(T,)``: ``t`` [s] and channels
            such as ``tension_insertion.<cable>``.
        ground_truth: The plant's effects and their parameters (plain JSON data).
        units: Unit of each quantity of the channels.
    """

    columns: Mapping[str, FloatArray]
    ground_truth: Mapping[str, Any]
    units: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "columns", _checked_columns(self.columns, "TruthSidecar"))
        if not isinstance(self.ground_truth, Mapping):
            raise InputError(f"ground_truth must be a mapping, got {type(self.ground_truth)}")
        object.__setattr__(
            self, "ground_truth", _json_roundtrip(dict(self.ground_truth), "ground_truth")
        )
        object.__setattr__(self, "units", _json_roundtrip(dict(self.units), "units"))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TruthSidecar):
            return NotImplemented
        return (
            self.ground_truth == other.ground_truth
            and self.units == other.units
            and self._columns_equal(other)
        )

    __hash__ = None  # type: ignore[assignment]


# --- checks ---------------------------------------------------------------------------------


def columns_from_quantities(
    t: ArrayLike, channels: Mapping[str, tuple[Sequence[str], ArrayLike]]
) -> dict[str, FloatArray]:
    """Log columns from one matrix per quantity.

    Args:
        t: Sample times [s], shape ``(T,)``.
        channels: quantity -> (names, values of shape ``(T, k)``), e.g.
            ``{"q": (model.joint_names, Q)}``.

    Returns:
        ``t`` then ``<quantity>.<name>`` for each quantity's channels in the order given, each
        a contiguous float64 array of shape ``(T,)``.

    Raises:
        InputError: Values of the wrong shape, or a channel name given twice.
    """
    columns: dict[str, FloatArray] = {TIME: np.array(t, dtype=np.float64)}
    for quantity, (names, values) in channels.items():
        values = np.asarray(values, dtype=np.float64)
        if values.ndim != 2 or values.shape[1] != len(names):
            raise InputError(
                f"channels[{quantity!r}]: values must have shape (T, {len(names)}) for the "
                f"{len(names)} names, got {values.shape}"
            )
        twice = sorted({str(n) for n in names if list(names).count(n) > 1})
        if twice:  # the second column would replace the first
            raise InputError(
                f"channels[{quantity!r}]: channel names must be unique; "
                f"{', '.join(map(repr, twice))} given more than once"
            )
        for j, name in enumerate(names):
            columns[f"{quantity}.{name}"] = np.ascontiguousarray(values[:, j])
    return columns


def _checked_columns(
    columns: Mapping[str, ArrayLike], source: str, missing_values: bool = False
) -> dict[str, FloatArray]:
    """Check columns against the schema; returns them as float64 arrays, ``t`` first.

    With ``missing_values``, a channel column may hold NaN or infinities (``t`` may not).

    Raises:
        LogError: Naming ``source`` and the column.
    """
    if not isinstance(columns, Mapping):
        raise LogError(f"{source}: columns must be a mapping name -> array")
    if TIME not in columns:
        raise LogError(
            f"{source}: no time column '{TIME}'; columns: {', '.join(map(str, columns)) or '-'}"
        )
    out: dict[str, FloatArray] = {}
    n_rows = None
    for name in [TIME, *(c for c in columns if c != TIME)]:
        if not isinstance(name, str):
            raise LogError(f"{source}: column names must be strings, got {name!r}")
        if name != TIME:
            try:
                split_channel(name)
            except InputError as exc:
                raise LogError(f"{source}: {exc}") from None
        raw = columns[name]
        arr = np.asarray(raw)
        if arr.dtype.kind not in "fiu":
            raise LogError(f"{source}: column {name!r} has dtype {arr.dtype}, expected float64")
        arr = arr.astype(np.float64, copy=False)
        if arr.ndim != 1:
            raise LogError(f"{source}: column {name!r} must be 1-D, got shape {arr.shape}")
        if n_rows is None:
            n_rows = len(arr)
            if n_rows == 0:
                raise LogError(f"{source}: the log has no samples (column '{TIME}' is empty)")
        elif len(arr) != n_rows:
            raise LogError(
                f"{source}: column {name!r} has {len(arr)} rows, column '{TIME}' has {n_rows}"
            )
        bad = ~np.isfinite(arr)
        if bad.any() and (name == TIME or not missing_values):
            row = int(np.argmax(bad))
            raise LogError(f"{source}: column {name!r} has {arr[row]} (not finite) at row {row}")
        out[name] = arr
    check_increasing_time(out[TIME], source)
    return out


def check_increasing_time(
    t: FloatArray, source: str, rows: str = "", name: str = TIME, unit: str = "s"
) -> None:
    """Refuse sample times that are not strictly increasing, naming the first such row.

    Args:
        t: Sample times, shape ``(T,)``, in ``unit``.
        source: The log or file, named first in the message.
        rows: How the rows are counted, added to the message (e.g. ``"rows count from 0"``).
        name: The time column's name in the source (a CSV file's own, say).
        unit: The times' unit, as the source has them.

    Raises:
        LogError: ``t[k] <= t[k - 1]`` for some ``k``; the first such ``k`` and both times
            named.
    """
    steps = np.diff(t)
    if (steps <= 0).any():
        row = int(np.argmax(steps <= 0)) + 1
        counted = f"; {rows}" if rows else ""
        # every digit (an epoch time's step is in its last ones) and the step itself
        raise LogError(
            f"{source}: column '{name}' is not strictly increasing at row {row} "
            f"({name}[{row - 1}] = {float(t[row - 1])!r} {unit}, {name}[{row}] = "
            f"{float(t[row])!r} {unit}: a step of {float(steps[row - 1]):.6g} {unit}{counted})"
        )


def regular_steps(t: FloatArray) -> FloatArray:
    """The steps of sample times that are not gaps, in the unit of ``t``.

    A first estimate of the step is the mean of the steps up to twice the median (so that
    time stamps rounded to a coarser unit than the step keep both of their roundings: at
    700 Hz in whole milliseconds the steps are 1 and 2 ms, the median 1 ms); then the steps
    shorter than :data:`NOMINAL_STEP_GAP` times the estimate are kept and averaged again,
    until that settles (a dropped sample, a step of twice the estimate, is left out).

    Args:
        t: Sample times, shape ``(T,)`` with ``T >= 2``, strictly increasing.

    Returns:
        The regular steps, shape ``(k,)``, ``k >= 1``.
    """
    steps = np.diff(np.asarray(t, dtype=float))
    regular = steps[steps <= 2.0 * np.median(steps)]
    for _ in range(20):
        kept = steps[steps < NOMINAL_STEP_GAP * float(np.mean(regular))]
        if kept.size == regular.size:
            break
        regular = kept
    return regular


def nominal_step(t: FloatArray) -> float:
    """The nominal time step of sample times: the mean of the steps between gaps.

    The mean of :func:`regular_steps`: time stamps rounded to a coarser unit than the step
    (300 Hz in whole milliseconds: steps of 3, 3, 4 ms; 700 Hz: 1 and 2 ms) have the median
    of one rounding, but their mean is the step.

    Args:
        t: Sample times, shape ``(T,)`` with ``T >= 2``, strictly increasing.

    Returns:
        The nominal step, in the unit of ``t``.
    """
    return float(np.mean(regular_steps(t)))


def same_unit(a: str, b: str) -> bool:
    """Whether two spellings name one unit: they differ only by spaces, ``·``, ``*`` and ``^``.

    Args:
        a: A unit, e.g. ``"N m"``.
        b: Another, e.g. ``"N·m"``.

    Returns:
        True when they are the same unit spelt two ways.
    """
    return re.sub(r"[\s·*^]", "", a) == re.sub(r"[\s·*^]", "", b)


def check_standard_units(log: RunLog, quantities: Sequence[str], source: str) -> None:
    """Refuse a log whose units of ``quantities`` are not msarm's (:data:`STANDARD_UNITS`).

    A log may declare any unit (the schema asks for one per quantity); what reads it as
    numbers in SI must refuse another unit rather than misread it (degrees taken as radians,
    kN as N). Spellings that differ only by spaces, ``·``, ``*`` or ``^`` are the same unit.
    Quantities the log does not have are not checked.

    Args:
        log: The log.
        quantities: The quantities the caller reads, each a key of :data:`STANDARD_UNITS`.
        source: Name of the log in messages (its file).

    Raises:
        LogError: A quantity in another unit (file, quantity, its unit and the expected one
            named).
    """
    present = {split_channel(c)[0] for c in log.columns if c != TIME}
    for quantity in quantities:
        if quantity not in present:
            continue
        unit, expected = log.metadata.units.get(quantity, ""), STANDARD_UNITS[quantity]
        if not same_unit(unit, expected):
            raise LogError(
                f"{source}: quantity {quantity!r} is in {unit!r}, expected {expected!r} (SI, "
                f"as msarm.io.logs.STANDARD_UNITS); convert the columns {quantity}.* to "
                f"{expected} and set the metadata's units to match"
            )


def _check_units(columns: Mapping[str, Any], units: Mapping[str, str], source: str) -> None:
    for column in columns:
        if column == TIME:
            continue
        quantity = split_channel(column)[0]
        if quantity not in units:
            raise LogError(
                f"{source}: no unit for quantity {quantity!r} (column {column!r}); add it to the "
                "metadata's units (msarm.io.logs.STANDARD_UNITS has msarm's)"
            )


# --- files ----------------------------------------------------------------------------------


def _table(columns: Mapping[str, FloatArray], kv: Mapping[str, str]) -> pa.Table:
    arrays = [pa.array(v, type=pa.float64()) for v in columns.values()]
    schema = pa.schema([pa.field(name, pa.float64(), nullable=False) for name in columns])
    return pa.Table.from_arrays(arrays, schema=schema.with_metadata(dict(kv)))


def _write_parquet_atomic(path: Path, table: pa.Table) -> None:
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)


def _read_parquet(
    path: Path, missing_values: bool = False
) -> tuple[dict[str, FloatArray], dict[str, str]]:
    """Columns (float64 arrays) and string key-value metadata of a Parquet file.

    With ``missing_values``, nulls are read as NaN instead of refused (not in ``t``).
    """
    label = str(path)
    if not path.is_file():
        raise LogError(f"{label}: file not found" if not path.exists() else f"{label}: not a file")
    try:
        # Arrow's own file, not a Python one: a read through a Python file leaves Arrow's
        # worker threads releasing Python buffers after it returns, and one still doing so
        # when the interpreter exits aborts the process (seen as exit code 134 after an error)
        with pa.OSFile(str(path), "rb") as fh:
            table = pq.ParquetFile(fh).read()
    except (pa.ArrowException, OSError) as exc:
        raise LogError(f"{label}: not a readable Parquet file: {exc}") from None
    raw_meta = table.schema.metadata or {}
    kv = {k.decode("utf-8", "replace"): v.decode("utf-8", "replace") for k, v in raw_meta.items()}
    names = table.column_names
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise LogError(f"{label}: column {dup!r} appears more than once")
    columns: dict[str, FloatArray] = {}
    for name, col in zip(names, table.columns, strict=True):
        if col.type != pa.float64():
            raise LogError(
                f"{label}: column {name!r} has type {col.type}, expected double (float64); "
                "write every column as float64"
            )
        if col.null_count and (name == TIME or not missing_values):
            row = int(np.argmax(col.is_null().to_numpy(zero_copy_only=False)))
            raise LogError(f"{label}: column {name!r} has a null at row {row}")
        columns[name] = col.to_numpy()  # a null becomes NaN
    return columns, kv


def _decode(kv: Mapping[str, str], key: str, label: str, required: bool = True) -> Any:
    if key not in kv:
        if required:
            raise LogError(f"{label}: metadata key {key!r} is missing")
        return None
    try:
        return json.loads(kv[key])
    except json.JSONDecodeError as exc:
        raise LogError(f"{label}: metadata key {key!r} is not valid JSON: {exc}") from None


def write_log(path: str | Path, log: RunLog) -> Path:
    """Write a run log as Parquet, atomically. Never writes the sidecar.

    Args:
        path: Destination, conventionally ``runs/<name>/<log>.parquet``; the folder is created.
        log: The log.

    Returns:
        The path written.

    Raises:
        LogError: ``path`` is a sidecar name (``*.truth.parquet``).
    """
    path = Path(path)
    if path.name.endswith(_SIDECAR_SUFFIX):
        raise LogError(f"{path}: a log must not be named '*{_SIDECAR_SUFFIX}' (the sidecar's)")
    if not isinstance(log, RunLog):
        raise InputError(f"write_log needs a RunLog, got {type(log).__name__}")
    _write_parquet_atomic(path, _table(log.columns, log.metadata.to_kv()))
    return path


def _check_version(version: Any, expected: int, what: str) -> None:
    """Refuse a schema version other than the JSON integer ``expected``.

    ``"1"`` (a string), ``1.0`` and ``true`` compare equal to 1 or look like it; they are
    named as what they are.
    """
    if type(version) is int and version == expected:
        return
    if isinstance(version, str) and version.strip() == str(expected):
        got = f"the string {version!r}"
    elif isinstance(version, bool):
        got = f"the boolean {json.dumps(version)}"
    elif isinstance(version, float) and version == expected:
        got = f"the number {version!r}"
    else:
        raise LogError(f"{what} {version!r} is not supported (expected {expected})")
    raise LogError(f"{what}: expected the JSON integer {expected}, got {got}")


def read_log(path: str | Path) -> RunLog:
    """Read and check a run log (never its sidecar).

    Args:
        path: The log's Parquet file.

    Returns:
        The log; its column arrays may be read-only.

    Raises:
        LogError: The file is missing or not Parquet; it is a sidecar; a metadata key is
            missing, malformed or unknown; the schema version is not 1; ``t`` is missing or
            not strictly increasing; a column is not float64, has a null, NaN or infinity
            (column and first row named); a quantity has no unit. Each names the file.
    """
    columns, metadata = _read_log_file(Path(path), missing_values=False)
    return RunLog(columns, metadata)


def read_log_with_missing_values(path: str | Path) -> tuple[dict[str, FloatArray], LogMetadata]:
    """Read a run log whose channels may have missing values (never its sidecar).

    A reader that can work around missing samples (the diagnosis treats them as a dropout)
    uses this, then builds a :class:`RunLog` from what it keeps: a ``RunLog`` holds no
    missing value.

    Args:
        path: The log's Parquet file.

    Returns:
        ``(columns, metadata)``: column name -> float64 samples of shape ``(T,)``, ``t``
        first, with a null read as NaN and NaN and infinities as they are.

    Raises:
        LogError: As :func:`read_log`, except for a null, NaN or infinity in a channel
            column; ``t`` must still be finite.
    """
    return _read_log_file(Path(path), missing_values=True)


def _read_log_file(path: Path, missing_values: bool) -> tuple[dict[str, FloatArray], LogMetadata]:
    """Columns and metadata of a log file, checked (see :func:`read_log`)."""
    label = str(path)
    columns, kv = _read_parquet(path, missing_values)
    if _TRUTH_PREFIX + "schema_version" in kv:
        raise LogError(f"{label}: this is a ground-truth sidecar, not a log; read_sidecar reads it")
    version = _decode(kv, _PREFIX + "schema_version", label)
    _check_version(version, SCHEMA_VERSION, f"{label}: log schema version")
    known = {_PREFIX + f for f in _META_FIELDS}
    unknown = sorted(k for k in kv if k.startswith(_PREFIX) and k not in known)
    if unknown:
        raise LogError(
            f"{label}: unknown metadata key {unknown[0]!r}; known keys: {', '.join(sorted(known))}"
            " (put free data under 'msarm.extra')"
        )
    fields: dict[str, Any] = {}
    for name, required in _META_FIELDS.items():
        value = _decode(kv, _PREFIX + name, label, required)
        if value is not None:
            fields[name] = value
    try:
        metadata = LogMetadata(**fields)
    except InputError as exc:
        raise LogError(f"{label}: metadata: {exc}") from None
    checked = _checked_columns(columns, label, missing_values)
    _check_units(checked, metadata.units, label)
    return checked, metadata


#: Metadata fields of a log -> whether the file must have them.
_META_FIELDS: dict[str, bool] = {
    "schema_version": True,
    "robot_model": True,
    "model_sha256": True,
    "sample_rate_hz": True,
    "units": True,
    "controller_config": False,
    "extra": False,
}


def read_model_sha256(path: str | Path) -> str:
    """The SHA-256 of the robot model a log was recorded with, from its metadata alone.

    Reads the Parquet footer only (not the columns): a cheap check of whether a cached log
    still matches the model.

    Args:
        path: The log's Parquet file.

    Returns:
        The hexadecimal SHA-256 as the log stores it.

    Raises:
        LogError: The file is missing, not Parquet, or has no (valid) ``model_sha256``.
    """
    path = Path(path)
    label = str(path)
    if not path.is_file():
        raise LogError(f"{label}: file not found" if not path.exists() else f"{label}: not a file")
    try:
        raw_meta = pq.read_schema(path).metadata or {}
    except (pa.ArrowException, OSError) as exc:
        raise LogError(f"{label}: not a readable Parquet file: {exc}") from None
    kv = {k.decode("utf-8", "replace"): v.decode("utf-8", "replace") for k, v in raw_meta.items()}
    value = _decode(kv, _PREFIX + "model_sha256", label)
    if not isinstance(value, str):
        raise LogError(f"{label}: metadata 'model_sha256' is not a string: {value!r}")
    return value


def sidecar_path(log_path: str | Path) -> Path:
    """The ground-truth sidecar of a log: ``<stem>.truth.parquet`` in the log's folder.

    Args:
        log_path: The log file, e.g. ``runs/a/log.parquet``.

    Returns:
        E.g. ``runs/a/log.truth.parquet``.

    Raises:
        InputError: ``log_path`` already ends in ``.truth.parquet`` (it is a sidecar).
    """
    log_path = Path(log_path)
    if log_path.name.endswith(_SIDECAR_SUFFIX):
        raise InputError(f"{log_path} is already a sidecar path")
    return log_path.with_name(log_path.stem + _SIDECAR_SUFFIX)


def write_sidecar(
    log_path: str | Path,
    columns: Mapping[str, ArrayLike],
    ground_truth: Mapping[str, Any],
    units: Mapping[str, str] | None = None,
) -> Path:
    """Write the sim-only ground truth of a run next to its log, atomically.

    Args:
        log_path: The log the sidecar belongs to (it need not exist yet).
        columns: ``t`` [s] and channels ``<quantity>.<name>`` (e.g.
            ``tension_insertion.biceps``), each of shape ``(T,)``.
        ground_truth: The plant's effects and their parameters (JSON-serialisable).
        units: Unit of each quantity of the channels.

    Returns:
        The sidecar's path (:func:`sidecar_path`).
    """
    sidecar = TruthSidecar(columns=columns, ground_truth=ground_truth, units=dict(units or {}))
    path = sidecar_path(log_path)
    kv = {
        _TRUTH_PREFIX + "schema_version": json.dumps(SIDECAR_SCHEMA_VERSION),
        _TRUTH_PREFIX + "ground_truth": json.dumps(sidecar.ground_truth),
        _TRUTH_PREFIX + "units": json.dumps(sidecar.units),
    }
    _write_parquet_atomic(path, _table(sidecar.columns, kv))
    return path


def read_sidecar(log_path: str | Path) -> TruthSidecar:
    """Read the ground-truth sidecar of a log (for tests and scoring, never for a diagnosis).

    Args:
        log_path: The log whose sidecar to read (the log itself is not opened).

    Returns:
        The sidecar.

    Raises:
        LogError: The sidecar is missing or malformed (file and column or key named).
    """
    path = sidecar_path(log_path)
    label = str(path)
    columns, kv = _read_parquet(path)
    version = _decode(kv, _TRUTH_PREFIX + "schema_version", label)
    _check_version(version, SIDECAR_SCHEMA_VERSION, f"{label}: sidecar schema version")
    ground_truth = _decode(kv, _TRUTH_PREFIX + "ground_truth", label)
    units = _decode(kv, _TRUTH_PREFIX + "units", label, required=False) or {}
    if not isinstance(ground_truth, dict) or not isinstance(units, dict):
        raise LogError(f"{label}: ground_truth and units must be JSON objects")
    return TruthSidecar(_checked_columns(columns, label), ground_truth, units)
