"""Build the fitting input of the gap diagnosis from log files.

:func:`channels_from_logs` reads each log with :func:`msarm.diagnose.residuals.residuals_from_log`
(which never opens the ground-truth sidecar), keeps its valid samples, adds what the candidate
effects need (cable lengths, Jacobian and wrap angles of the nominal model at each logged
posture, the logged motor angles and speeds, the aligned tension commands) and concatenates the
runs, each labelled by its index. It returns the residual of each channel group
(:data:`GROUPS`): ``"joint"`` the joint-torque residual [N m], ``"drive"`` the load-cell
tension minus its command [N], ``"length"`` the cable length error [m] minus its mean over each
run (the motor encoders give lengths up to an unknown offset per run).
:func:`signals_from_logs` is the joint group alone.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.missing_values import read_log_for_diagnosis
from msarm.diagnose.residuals import (
    DiagnosisWarning,
    ResidualSpec,
    gap_starts,
    residuals_from_log,
)
from msarm.diagnose.signals import Signals
from msarm.errors import InputError, LogError
from msarm.model import RobotModel

__all__ = [
    "GROUPS",
    "GROUP_UNITS",
    "MIN_TRAVEL",
    "SAME_PERIOD",
    "channels_from_logs",
    "check_distinct_files",
    "check_log_file",
    "check_same_rate",
    "little_motion",
    "signals_from_logs",
]

FloatArray = NDArray[np.float64]

#: The channel groups of the diagnosis, in the order they are stacked.
GROUPS = ("joint", "drive", "length")
#: Least joint travel [rad] (the largest joint's range over a log) below which a log is
#: said to hold too little motion to diagnose (10 mrad, 0.57 degrees).
MIN_TRAVEL = 0.01
#: Relative difference of two logs' sample periods up to which they are of one rate: a rate
#: taken from a time column is rounded to six digits (1/0.004 s in floats is 250 within 1e-15).
SAME_PERIOD = 1e-6
#: Unit of each group's residual.
GROUP_UNITS = {"joint": "N m", "drive": "N", "length": "m"}


def check_log_file(path: Path) -> None:
    """Refuse a log path that is not a file: missing, or a run's folder.

    Raises:
        InputError: ``path`` does not exist, is a folder (named with the log file it holds),
            or is a CSV file (``msarm log import`` named).
    """
    if path.is_dir():
        inside = (
            " (it holds log.parquet: give that file)" if (path / "log.parquet").is_file() else ""
        )
        raise InputError(f"{path}: a folder, expected a log file (Parquet){inside}")
    if not path.is_file():
        raise InputError(f"{path}: no such log file")
    if path.suffix.lower() in (".csv", ".tsv", ".txt") or path.name.lower().endswith(".csv.gz"):
        raise InputError(
            f"{path}: a CSV file, expected a log (Parquet); msarm log import turns CSV "
            "recordings into logs"
        )


def little_motion(q: FloatArray, source: str) -> tuple[float, str | None]:
    """The largest joint's travel in a log, and what to say when it is below MIN_TRAVEL.

    Args:
        q: Joint angles of the log's diagnosed samples [rad], shape ``(T, n)``.
        source: The log, named in the message.

    Returns:
        ``(travel, message)``: the largest joint's range [rad], and the warning's text when
        it is below :data:`MIN_TRAVEL` (friction and inertia cannot be told from noise), else
        None.
    """
    travel = float(np.max(np.ptp(q, axis=0))) if len(q) else 0.0
    if travel >= MIN_TRAVEL:
        return travel, None
    return travel, (
        f"{source}: no joint moves more than {1e3 * travel:.2g} mrad in this log (less than "
        f"{1e3 * MIN_TRAVEL:g} mrad): the friction and inertia terms cannot be told from "
        "the noise on it; diagnose logs with motion"
    )


def _segment_labels(t: FloatArray, sample_rate_hz: float) -> NDArray[np.int64]:
    """Label of each row's stretch between time gaps (0 for the first), shape ``(T,)``."""
    starts = np.zeros(len(t), dtype=np.int64)
    starts[gap_starts(t, sample_rate_hz)] = 1
    return np.cumsum(starts)


def _one_run(
    model: RobotModel, path: Path, spec: ResidualSpec
) -> tuple[dict[str, FloatArray], dict[str, FloatArray], float]:
    """Signal arrays and group residuals (valid samples only) and sample period of one log."""
    source = str(path)
    check_log_file(path)
    log = read_log_for_diagnosis(model, path, source)
    residuals = residuals_from_log(model, log, source=source, spec=spec, with_geometry=True)
    valid = residuals.valid
    if not valid.any():
        raise LogError(f"{source}: no valid sample to diagnose")
    cables = list(model.cable_names)
    missing = [c for c in cables if f"motor_angle.{c}" not in log.columns]
    if missing:  # residuals_from_log has warned about it
        motor = np.zeros((len(log), len(cables)))
    else:
        motor = log.matrix("motor_angle", cables)
    q = residuals.q[valid]
    _, little = little_motion(q, source)
    if little is not None:
        warnings.warn(little, DiagnosisWarning, stacklevel=3)
    arrays = {
        "t": residuals.t[valid],
        "q": q,
        "qd": residuals.qd[valid],
        "qdd": residuals.qdd[valid],
        "tension": residuals.tension[valid],
        "lengths": residuals.lengths[valid],
        "cable_velocity": residuals.cable_velocity[valid],
        "jacobian": residuals.jacobian[valid],
        "wrap": residuals.wrap[valid],
        "motor_angle": motor[valid],
        # the stretches between time gaps, as the residuals were computed (0, 1, ... in each
        # log: Signals relabels them to refine the runs)
        "segment": _segment_labels(residuals.t, residuals.sample_rate_hz)[valid],
    }
    if residuals.tension_cmd is not None:
        arrays["tension_cmd"] = residuals.tension_cmd[valid]
    if residuals.motor_speed is not None:
        arrays["motor_speed"] = residuals.motor_speed[valid]
    if residuals.qdd_ref is not None:
        arrays["qdd_ref"] = residuals.qdd_ref[valid]
    for name, value in arrays.items():
        if not np.all(np.isfinite(value)):
            row = int(np.argwhere(~np.isfinite(value))[0][0])
            raise LogError(f"{source}: non-finite {name} at valid sample {row}")
    groups = {"joint": residuals.scored("joint_torque")}
    if residuals.drive is not None:
        groups["drive"] = residuals.scored("drive")
    if residuals.cable_length is not None:
        groups["length"] = residuals.scored("cable_length")
    for group, residual in groups.items():
        if not np.all(np.isfinite(residual)):
            row = int(np.argwhere(~np.isfinite(residual))[0][0])
            raise LogError(f"{source}: non-finite {group} residual at valid sample {row}")
    return arrays, groups, 1.0 / residuals.sample_rate_hz


def signals_from_logs(
    model: RobotModel,
    paths: Sequence[str | Path],
    spec: ResidualSpec | None = None,
) -> tuple[Signals, FloatArray, tuple[str, ...]]:
    """Signals and joint-torque residual of several logs (see :func:`channels_from_logs`).

    Returns:
        ``(signals, residual, runs)`` with ``residual`` the joint group ``(T, n)`` [N m].
    """
    signals, groups, names = channels_from_logs(model, paths, spec)
    return signals, groups["joint"], names


def channels_from_logs(
    model: RobotModel,
    paths: Sequence[str | Path],
    spec: ResidualSpec | None = None,
) -> tuple[Signals, dict[str, FloatArray], tuple[str, ...]]:
    """Signals and group residuals of several logs, concatenated with run labels.

    Args:
        model: The nominal robot model the logs were recorded with.
        paths: Log files (Parquet), at least one. Their ground-truth sidecars are never read.
        spec: Residual settings (filter, drum radius); the replay is never computed here.

    Returns:
        ``(signals, groups, runs)``: the :class:`Signals` of all valid samples (``T`` in
        total, ``signals.run[k]`` the index in ``paths`` of sample ``k``'s log), the residual of
        each group present in every log (``groups["joint"]`` ``(T, n)`` always; ``"drive"`` and
        ``"length"`` ``(T, m)`` when every log has the channels they need), and the log names
        (``str`` of each path), indexed by run label.

    Raises:
        InputError: No paths, or a file that does not exist (named).
        LogError: A log that cannot be diagnosed (file and reason named; see
            :func:`~msarm.diagnose.residuals.residuals_from_log`), or logs of different sample
            rates.
    """
    if not paths:
        raise InputError("paths: no log files given")
    base = spec or ResidualSpec()
    if base.replay:
        base = replace(base, replay=False)
    parts, residuals, names = [], [], []
    dt = None
    for label, path in enumerate(paths):
        path = Path(path)
        arrays, residual, period = _one_run(model, path, base)
        if dt is None:
            dt = period
        elif abs(period - dt) > SAME_PERIOD * dt:
            raise LogError(
                f"{path}: sample period {period:.9g} s differs from {dt:.9g} s of {paths[0]}; "
                "diagnose logs of one sample rate together"
            )
        arrays["run"] = np.full(arrays["t"].shape[0], label, dtype=np.int64)
        parts.append(arrays)
        residuals.append(residual)
        names.append(str(path))
    keys = set.intersection(*(set(p) for p in parts))
    joined = {key: np.concatenate([p[key] for p in parts]) for key in parts[0] if key in keys}
    signals = Signals(dt=float(dt), **joined)
    present = [g for g in GROUPS if all(g in r for r in residuals)]
    groups = {g: np.concatenate([r[g] for r in residuals]) for g in present}
    return signals, groups, tuple(names)


def check_distinct_files(paths: Sequence[str | Path]) -> None:
    """Refuse two log files with the same bytes: one run under two names.

    A copy of a training log held out would score the terms on the data they were fitted
    on; two copies in training would weigh that run twice. Files that cannot be read are
    left to the log reader, which names what is wrong with them.

    Args:
        paths: The log files.

    Raises:
        InputError: Two files have the same bytes (both named).
    """
    seen: dict[str, str] = {}
    for path in paths:
        try:
            digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
        except OSError:
            continue
        if digest in seen:
            first = seen[digest]
            same = Path(first).resolve() == Path(path).resolve()
            how = (
                "is given twice"
                if same
                else f"has the same contents as {first}: one run under two names"
            )
            raise InputError(
                f"logs: {path} {how}; expected each run once (a copy held out would score "
                "the terms on the data they were fitted on)"
            )
        seen[digest] = str(path)


def check_same_rate(
    first: Signals, first_name: str, second: Signals, second_name: str, roles: tuple[str, str]
) -> None:
    """Refuse two sets of logs of different sample periods (each read by its own call).

    Args:
        first: Signals of the first set (e.g. the training logs).
        first_name: A log of the first set, for the message.
        second: Signals of the second set (e.g. the held-out logs).
        second_name: A log of the second set, for the message.
        roles: What the two sets are, e.g. ``("training", "held-out")``.

    Raises:
        LogError: The periods differ (by more than :data:`SAME_PERIOD` relative), both named.
    """
    if abs(second.dt - first.dt) > SAME_PERIOD * first.dt:
        raise LogError(
            f"{second_name}: sample period {second.dt:.9g} s ({roles[1]}) differs from "
            f"{first.dt:.9g} s of {first_name} ({roles[0]}); diagnose logs of one sample rate "
            "together"
        )
