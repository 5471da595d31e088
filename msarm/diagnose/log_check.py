"""What the diagnosis can make of one log, said before a diagnosis is run (``msarm log check``).

:func:`check_log` reads a log as the diagnosis does and computes its residuals
(:func:`msarm.diagnose.residuals.residuals_from_log`, without the replay), so every check the
diagnosis makes of a log is made here too, by the same code: the model's hash, the units,
missing channels and values, time gaps and the sample rate, the derivative filter's span, dead
sensors, channels whose scales disagree, too little motion, channels that name no joint or
cable of the model (not read). What it finds is kept, not raised: an error that would stop
the diagnosis, the warnings it would give, and which residuals the log supports.
:func:`check_logs` adds what the diagnosis refuses of logs together: one run under two names,
and logs of different sample rates.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from msarm.errors import MsarmError
from msarm.model import RobotModel

if TYPE_CHECKING:
    from msarm.diagnose.residuals import ResidualSpec

__all__ = ["RESIDUALS_CHECKED", "LogCheck", "check_log", "check_logs"]

#: The residuals a log may support -> what each gives the diagnosis.
RESIDUALS_CHECKED: dict[str, str] = {
    "joint_torque": "friction, capstan, mass error and sensor terms (needs q, tension_motor)",
    "drive": "winch friction, cogging, command delay, sheath stiction (needs tension_cmd)",
    "cable_length": "elasticity, slack, backlash, sheath stretch, encoder skew (needs motor_angle)",
    "clean_accelerations": "the mass-error term without the encoders' noise (needs q_ref)",
}


@dataclass(frozen=True)
class LogCheck:
    """What the diagnosis can make of one log.

    Attributes:
        path: The log file.
        error: Why the diagnosis would refuse the log, or None.
        warnings: What it would warn about (each message once, in order).
        samples: Rows read (after any left out for missing values); None on an error.
        duration_s: Time from the first to the last sample [s]; None on an error.
        sample_rate_hz: The metadata's sample rate [Hz]; None on an error.
        diagnosed_share: Share of the samples that get residuals (the rest are in stretches
            between time gaps too short for the filter) [-]; None on an error.
        joint_travel_rad: The largest joint's range of motion [rad]; None on an error.
        residuals: Each of :data:`RESIDUALS_CHECKED` -> whether the log supports it (all
            False on an error).
    """

    path: str
    error: str | None
    warnings: tuple[str, ...] = ()
    samples: int | None = None
    duration_s: float | None = None
    sample_rate_hz: float | None = None
    diagnosed_share: float | None = None
    joint_travel_rad: float | None = None
    residuals: dict[str, bool] = field(
        default_factory=lambda: dict.fromkeys(RESIDUALS_CHECKED, False)
    )

    @property
    def ok(self) -> bool:
        """Whether the diagnosis can use the log (it may still warn)."""
        return self.error is None

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON data."""
        out = asdict(self)
        out["warnings"] = list(self.warnings)
        return out


def check_log(model: RobotModel, path: str | Path, spec: ResidualSpec | None = None) -> LogCheck:
    """Check a log as the diagnosis reads it (see the module docstring).

    Args:
        model: The nominal robot model the diagnosis would use.
        path: The log's Parquet file (the sidecar is never opened).
        spec: The :class:`~msarm.diagnose.residuals.ResidualSpec` the diagnosis would use
            (filter window, drum radius, ...); the defaults when None. Its replay is not run.

    Returns:
        What was found; nothing is raised for a bad log (its error is kept).
    """
    from dataclasses import replace

    from msarm.diagnose.builder import check_log_file, little_motion
    from msarm.diagnose.residuals import DiagnosisWarning, ResidualSpec, residuals_from_log

    spec = replace(spec or ResidualSpec(), replay=False)
    source = str(path)
    error: str | None = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DiagnosisWarning)
        try:
            check_log_file(Path(path))
            residuals = residuals_from_log(model, path, source=source, spec=spec)
        except MsarmError as exc:
            error = str(exc)
    # outside the recording: other warnings are passed on, not recorded again
    said = list(_messages(caught, DiagnosisWarning))
    if error is not None:
        return LogCheck(source, error, tuple(said))
    valid = residuals.valid
    travel, little = little_motion(residuals.q[valid], source)
    if little is not None:  # what the diagnosis warns of each log it reads
        said.append(little)
    return LogCheck(
        path=source,
        error=None,
        warnings=tuple(said),
        samples=len(residuals),
        duration_s=float(residuals.t[-1] - residuals.t[0]),
        sample_rate_hz=residuals.sample_rate_hz,
        diagnosed_share=float(valid.mean()),
        joint_travel_rad=travel,
        residuals={
            "joint_torque": True,
            "drive": residuals.drive is not None,
            "cable_length": residuals.cable_length is not None,
            "clean_accelerations": residuals.qdd_ref is not None,
        },
    )


def check_logs(
    model: RobotModel, paths: Sequence[str | Path], spec: ResidualSpec | None = None
) -> tuple[list[LogCheck], list[str]]:
    """Check several logs (:func:`check_log`), and what the diagnosis refuses of them together.

    Args:
        model: The nominal robot model the diagnosis would use.
        paths: The log files.
        spec: The :class:`~msarm.diagnose.residuals.ResidualSpec` (see :func:`check_log`).

    Returns:
        ``(checks, together)``: each log's check, and why the diagnosis would refuse these
        logs together (one run given twice or under two names; logs of different sample
        rates), empty when it would not.
    """
    from msarm.diagnose.builder import SAME_PERIOD, check_distinct_files

    checks = [check_log(model, path, spec) for path in paths]
    together: list[str] = []
    try:
        check_distinct_files(paths)
    except MsarmError as exc:
        together.append(str(exc))
    rates: dict[float, list[str]] = {}
    for check in checks:
        if check.ok and check.sample_rate_hz is not None:
            # one rate as the diagnosis takes it: periods within SAME_PERIOD of each other
            rate = check.sample_rate_hz
            same = [r for r in rates if abs(r / rate - 1.0) <= SAME_PERIOD]
            rates.setdefault(same[0] if same else rate, []).append(check.path)
    if len(rates) > 1:
        groups = "; ".join(
            f"{rate:.9g} Hz: {', '.join(logs)}" for rate, logs in sorted(rates.items())
        )
        together.append(
            f"logs of {len(rates)} sample rates ({groups}); the diagnosis takes logs of one "
            "sample rate together"
        )
    return checks, together


def _messages(caught: list[warnings.WarningMessage], category: type) -> tuple[str, ...]:
    """The messages of ``category`` among ``caught``, each once, in order; others re-warned."""
    out: list[str] = []
    for item in caught:
        if issubclass(item.category, category):
            text = str(item.message)
            if text not in out:
                out.append(text)
        else:
            warnings.warn_explicit(item.message, item.category, item.filename, item.lineno)
    return tuple(out)
