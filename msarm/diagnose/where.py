"""Where the sim-to-real gap lies: the residual energy broken down by channel, phase, posture.

The residual energy of a set of samples is the sum of squares of one residual kind
(:mod:`msarm.diagnose.residuals`: ``joint_torque`` [N m], ``drive`` [N], ``cable_length`` [m] or
``replay`` [rad]) over those samples and the kind's channels; ``cable_length`` about each log's
mean, as the diagnosis scores it (the encoders give lengths up to an offset: measured from the log's
first sample, the breakdown would depend on where the log starts). Several logs combine by summing
over all their valid samples. The breakdown has four groups of rows; each group partitions the
energy, so that its shares sum to 100 %:

``channel``
    Each joint (or each cable, for ``drive`` and ``cable_length``): the channel's own sum of
    squares. Its
    "time share" is an even split between the channels (100 % / number of channels).
``motion``
    Each sample is counted in exactly one motion phase, the first that matches in this
    priority order (thresholds in :class:`PhaseSettings`; ``qd``, ``qdd`` are the filtered
    joint velocities and accelerations):

    1. ``reversal``: some joint's ``qd`` is above ``+reversal_speed`` and below
       ``-reversal_speed`` within ``+-reversal_window`` of the sample, in the same
       stretch of the log (a sign change across a time gap is no reversal);
    2. ``acceleration``: some joint has ``|qdd| >= acceleration``;
    3. ``hold``: every joint has ``|qd| < hold_speed``;
    4. ``constant_velocity``: the rest (some ``|qd| >= hold_speed``, every
       ``|qdd| < acceleration``).
``load``
    Likewise one load phase per sample, first match of:

    1. ``low_tension``: some load cell reads below ``low_tension`` (slack or nearly);
    2. ``high_load``: the largest tension of the sample is above the
       ``high_load_percentile``-th percentile of that largest tension over all samples;
    3. ``normal_load``: the rest.
``posture``
    The cells of a grid over two joints (default: the two that move most, i.e. with the
    largest standard deviation of ``q``), ``bins`` equal bins over each joint's range in the
    model (postures outside the range go into the edge bins). Only cells with samples are
    rows. A model with one joint has a grid of that joint against itself: only its diagonal
    has samples, and each row is named by the one joint's bin (``jaw [-0.48, -0.16]``).

Each row has the share of the energy [%], the share of time (samples) [%] and the energy
density: share of energy / share of time. A density above 1 means the gap concentrates there
(for channels: above an even split between channels).

The sensors' noise alone makes a residual, and for the joint torque it does not spread evenly:
the encoders' noise reaches it through the filtered accelerations times the mass matrix, which
is several times larger with the arm nearly straight than flexed, so on plants with sensor
noise alone the posture cells about the home posture (where the tasks start with a hold) had
densities of 1.4-3.0 and were named hot spots (22 of 22 logs of msarm's arm). With the model
given, :func:`break_down` estimates each sensor's white-noise level from the logs and the
energy it alone is expected to put in each row (:mod:`msarm.diagnose.noise_floor`;
``joint_torque`` only: :data:`~msarm.diagnose.noise_floor.NOISE_FLOOR_KINDS` says why not the
others). Rows then also have that ``noise_energy``, the ``excess_energy`` beyond it and the
*excess density*: the row's share of the total excess over its share of the samples. The
excess is taken away from the filter's edges (the half window at each end of each stretch of
log, about 1 % of the samples), where the noise alone makes a residual up to 34 times larger
than elsewhere, decided by a handful of noise values: one such edge made a cell of 431
samples 2.3 times its expected noise energy on a noise-level plant. A phase or posture cell
is a hot spot only with margins (:class:`PhaseSettings`): an excess density of
``hot_spot_density`` (1.2) or more; an excess of ``hot_spot_noise_ratio - 1`` (0.5) times
the row's expected noise energy or more (the floor's own error: measured over expected noise
energy was 0.51-1.37 per cell on noise-only logs; the excess is counted away from the
filter's edges, the noise energy over all the row's samples, edges included: a stricter
margin for a row that holds a log's ends, where the noise energy is largest) and of
``hot_spot_noise_sigmas`` (3) standard deviations of that noise energy or more (its scatter
over few samples); and ``hot_spot_samples`` (100) samples or more. On 22 noise-only logs of
msarm's arm, alone and pooled (300 candidate rows), the largest excess was 0.34 times the
expected noise energy and 2.1 standard deviations of it; on 56 logs of plants whose effects
leave the joint torque nearly alone (elasticity, winch friction, a command delay; 778 rows),
0.42 and 2.5.
Without a noise floor (other kinds, or no model) the noise energy is 0, the excess energy
and density are the energy and density, and the rule is the one before: on a plant with
sensor noise alone the drive residual's densities scatter about 1 (1.01 and the like),
which is no concentration.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.noise_floor import (
    NOISE_FLOOR_KINDS,
    SensorNoise,
    joint_torque_noise,
    sensor_noise,
)
from msarm.diagnose.residuals import (
    RESIDUAL_UNITS,
    Residuals,
    ResidualSpec,
    gap_starts,
    residuals_from_log,
)
from msarm.errors import InputError
from msarm.model import RobotModel

__all__ = [
    "GROUPS",
    "HOT_SPOT_DENSITY",
    "HOT_SPOT_NOISE_RATIO",
    "HOT_SPOT_NOISE_SIGMAS",
    "HOT_SPOT_SAMPLES",
    "LOAD_PHASES",
    "MOTION_PHASES",
    "PLOT_UNITS",
    "BreakdownRow",
    "GapBreakdown",
    "PhaseSettings",
    "break_down",
    "diagnose_where",
    "load_phases",
    "motion_phases",
    "plot_heatmap",
]

FloatArray = NDArray[np.float64]

#: Motion phases, in priority order (a sample is counted in the first that matches).
MOTION_PHASES = ("reversal", "acceleration", "hold", "constant_velocity")
#: Load phases, in priority order.
LOAD_PHASES = ("low_tension", "high_load", "normal_load")
#: Groups of rows of a breakdown, in display order.
GROUPS = ("channel", "motion", "load", "posture")
#: Least energy density of a hot spot (:attr:`PhaseSettings.hot_spot_density`) [-].
HOT_SPOT_DENSITY = 1.2
#: Least number of samples of a hot spot (:attr:`PhaseSettings.hot_spot_samples`): 0.4 s at
#: 250 Hz.
HOT_SPOT_SAMPLES = 100
#: A hot spot's excess energy is at least this minus 1 times the energy the sensors' noise
#: alone would put there (its energy about this many times that;
#: :attr:`PhaseSettings.hot_spot_noise_ratio`) [-]. On 22 noise-only logs of msarm's arm the
#: measured energy of the phases and posture cells of 100 samples or more was 0.51-1.37 times
#: the expected one (150 cells; 10th-90th percentile 0.75-1.15).
HOT_SPOT_NOISE_RATIO = 1.5
#: Least excess of a hot spot's energy over its expected noise energy, in standard deviations
#: of that noise energy (:attr:`PhaseSettings.hot_spot_noise_sigmas`) [-].
HOT_SPOT_NOISE_SIGMAS = 3.0


@dataclass(frozen=True)
class PhaseSettings:
    """Thresholds of the phases of motion and load.

    Attributes:
        hold_speed: Below this joint speed (every joint) the arm holds [rad/s].
        reversal_speed: A joint reverses when its velocity passes from above this to below
            its negative (or back) [rad/s], straight through or after a stop.
        reversal_window: Half width of the window in which a reversal counts [s] (see
            :func:`motion_phases`), rounded to whole samples (at least one).
        reversal_pause: Longest stop between the two ways that still makes a reversal [s]
            (a reach-and-hold task's joint goes out and back through a hold).
        acceleration: Joint acceleration from which a sample is in the acceleration phase
            [rad/s^2].
        low_tension: Load-cell tension below which a cable is slack or nearly [N].
        high_load_percentile: Percentile of the per-sample largest tension above which a
            sample is under high load [%].
        hot_spot_density: Least energy density of a hot spot [-] (:meth:`GapBreakdown.hot_spots`):
            a margin above 1, which noise alone scatters about; with a noise floor, the
            density of the energy beyond the sensors' noise (``excess_density``).
        hot_spot_samples: Least number of samples of a hot spot.
        hot_spot_noise_ratio: A hot spot's excess energy is at least ``hot_spot_noise_ratio -
            1`` times its expected noise energy [-] (its energy about ``hot_spot_noise_ratio``
            times it; rows with a noise floor: a margin for the floor's own error). The excess
            is counted away from the filter's edges, the noise energy over all the row's
            samples: for a row holding a log's ends, whose edges have the largest noise
            energy, the margin is stricter.
        hot_spot_noise_sigmas: Least excess of a hot spot's energy over its expected noise
            energy, in standard deviations of that noise energy [-] (rows with a noise floor:
            a noise energy over few samples, or over the filter's edges at a log's ends,
            scatters widely).
    """

    hold_speed: float = 0.05
    reversal_speed: float = 0.05
    reversal_window: float = 0.05
    reversal_pause: float = 1.0
    acceleration: float = 0.5
    low_tension: float = 2.0
    high_load_percentile: float = 90.0
    hot_spot_density: float = HOT_SPOT_DENSITY
    hot_spot_samples: int = HOT_SPOT_SAMPLES
    hot_spot_noise_ratio: float = HOT_SPOT_NOISE_RATIO
    hot_spot_noise_sigmas: float = HOT_SPOT_NOISE_SIGMAS

    def __post_init__(self) -> None:
        for name in (
            "hold_speed",
            "reversal_speed",
            "reversal_window",
            "reversal_pause",
            "acceleration",
        ):
            if not getattr(self, name) > 0:
                raise InputError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0 < self.high_load_percentile < 100:
            raise InputError(
                f"high_load_percentile must be in (0, 100), got {self.high_load_percentile}"
            )
        if not self.hot_spot_density >= 1:
            raise InputError(f"hot_spot_density must be >= 1, got {self.hot_spot_density}")
        if not self.hot_spot_samples >= 1:
            raise InputError(f"hot_spot_samples must be >= 1, got {self.hot_spot_samples}")
        if not self.hot_spot_noise_ratio >= 1:
            raise InputError(f"hot_spot_noise_ratio must be >= 1, got {self.hot_spot_noise_ratio}")
        if not self.hot_spot_noise_sigmas >= 0:
            raise InputError(
                f"hot_spot_noise_sigmas must be >= 0, got {self.hot_spot_noise_sigmas}"
            )


@dataclass(frozen=True)
class BreakdownRow:
    """One row of a breakdown.

    Attributes:
        group: ``"channel"``, ``"motion"``, ``"load"`` or ``"posture"``.
        where: The channel, phase or posture cell.
        energy: Residual energy (sum of squares) [unit^2].
        share: Share of the total residual energy [%].
        time_share: Share of the samples [%] (channels: an even split).
        density: ``share / time_share`` (1: as much as the average).
        samples: Number of samples (channels: all of them).
        noise_energy: Energy the sensors' white noise alone is expected to put in the row
            [unit^2] (:mod:`msarm.diagnose.noise_floor`); 0 without a noise floor.
        excess_energy: The row's energy beyond its expected noise energy [unit^2], over its
            samples away from the filter's edges (the half window at each end of a stretch
            of log, where the noise alone makes a residual up to 34 times larger and too
            scattered to be taken off: those samples count at their expected noise); below
            0 where the row has less than the noise would make. By default (None) the
            energy: no noise floor.
        excess_density: Density of the energy beyond the noise: the row's share of the total
            ``excess_energy`` over its share of the samples away from the filter's edges
            (channels: an even split) [-]; NaN when the total is within the noise (no
            excess). By default (None) the density: no noise floor.
        noise_std: Standard deviation of the row's noise energy over its samples away from
            the filter's edges [unit^2] (an upper bound for a row of scattered samples,
            :class:`~msarm.diagnose.noise_floor.NoiseFloor`); 0 without a noise floor.
    """

    group: str
    where: str
    energy: float
    share: float
    time_share: float
    density: float
    samples: int
    noise_energy: float = 0.0
    excess_energy: float | None = None
    excess_density: float | None = None
    noise_std: float = 0.0

    def __post_init__(self) -> None:
        if self.excess_energy is None:  # no noise floor
            object.__setattr__(self, "excess_energy", self.energy)
        if self.excess_density is None:
            object.__setattr__(self, "excess_density", self.density)


@dataclass(frozen=True, eq=False)
class GapBreakdown:
    """Where the residual energy of one residual kind lies, over one or more logs.

    Attributes:
        kind: The residual kind (``joint_torque``, ``drive``, ``cable_length``, ``replay``).
        unit: Its unit.
        sources: The logs.
        samples: Number of valid samples, all logs together.
        total_energy: Sum of squares over all samples and channels [unit^2].
        rms: Root mean square over samples and channels [unit].
        rows: The rows, group by group (:data:`GROUPS` order), each group by share, largest
            first.
        posture_joints: The two joints of the posture grid (the same joint twice for a model
            with one joint).
        posture_edges: Bin edges of the grid over each of the two joints [rad].
        posture_rms: Residual RMS of each grid cell [unit], shape ``(bins, bins)``; NaN
            where the cell has no samples. Axis 0 is the first joint.
        posture_samples: Samples in each grid cell, shape ``(bins, bins)``.
        settings: The phase thresholds used.
        noise_energy: Energy the sensors' white noise alone is expected to make over all
            samples and channels [unit^2]; 0 without a noise floor (a kind not in
            :data:`~msarm.diagnose.noise_floor.NOISE_FLOOR_KINDS`, or no model given).
        sensor_noise: The white-noise levels estimated from the logs, by log column
            (``q.<joint>`` [rad], ``tension_motor.<cable>`` [N]; over several logs the RMS
            weighted by their samples); empty without a noise floor.
    """

    kind: str
    unit: str
    sources: tuple[str, ...]
    samples: int
    total_energy: float
    rms: float
    rows: tuple[BreakdownRow, ...]
    posture_joints: tuple[str, str]
    posture_edges: tuple[FloatArray, FloatArray]
    posture_rms: FloatArray
    posture_samples: NDArray[np.int64]
    settings: PhaseSettings = field(default_factory=PhaseSettings)
    noise_energy: float = 0.0
    sensor_noise: dict[str, float] = field(default_factory=dict)

    def group(self, name: str) -> list[BreakdownRow]:
        """The rows of one group, largest share first.

        Args:
            name: One of :data:`GROUPS`.
        """
        if name not in GROUPS:
            raise InputError(f"unknown group {name!r}; groups: {', '.join(GROUPS)}")
        return [row for row in self.rows if row.group == name]

    def share(self, group: str, where: str) -> float:
        """Share of the energy [%] of one row (0 when the row does not exist)."""
        return next((r.share for r in self.group(group) if r.where == where), 0.0)

    def density(self, group: str, where: str) -> float:
        """Energy density of one row (NaN when the row does not exist)."""
        return next((r.density for r in self.group(group) if r.where == where), float("nan"))

    def hot_spots(self, count: int = 5, min_time_share: float = 5.0) -> list[BreakdownRow]:
        """Phases and posture cells where the gap concentrates most beyond the sensors' noise.

        Args:
            count: Number of rows at most.
            min_time_share: Rows with less time share [%] are left out (too few samples).

        Returns:
            Rows of the ``motion``, ``load`` and ``posture`` groups with an excess density of
            at least ``settings.hot_spot_density``, an ``excess_energy`` of at least
            ``settings.hot_spot_noise_ratio - 1`` times their expected noise energy and of at
            least ``settings.hot_spot_noise_sigmas`` standard deviations of it, and at least
            ``settings.hot_spot_samples`` samples, largest excess density first (without a
            noise floor: the density, and no noise condition); none where the gap does not
            concentrate beyond what the sensors' noise explains (a plant with sensor noise
            alone).
        """
        s = self.settings
        rows = [
            r
            for r in self.rows
            if r.group != "channel"
            and r.time_share >= min_time_share
            and r.samples >= s.hot_spot_samples
            and r.excess_density >= s.hot_spot_density
            and r.excess_energy
            >= max(
                (s.hot_spot_noise_ratio - 1.0) * r.noise_energy,
                s.hot_spot_noise_sigmas * r.noise_std,
            )
        ]
        return sorted(rows, key=lambda r: r.excess_density, reverse=True)[:count]

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of the breakdown (``None`` for an empty cell, never NaN).

        Returns:
            ``kind``, ``unit``, ``sources``, ``samples``, ``total_energy`` [unit^2], ``rms``
            [unit], ``settings`` (the phase thresholds, :class:`PhaseSettings`), ``rows``
            (each row's ``group``, ``where``, ``energy`` [unit^2], ``share`` and
            ``time_share`` [%], ``density``, ``samples``, ``rms`` [unit]: a channel's RMS
            over its samples, a phase's or cell's over its samples and all channels,
            ``noise_energy``, ``excess_energy`` and ``noise_std`` [unit^2] and
            ``excess_density``), ``hot_spots`` (``group`` and ``where`` of each, largest
            excess density first), ``noise_energy`` [unit^2] (all samples; 0 without a noise
            floor), ``sensor_noise`` (the estimated white-noise std by log column,
            ``q.<joint>`` [rad] and ``tension_motor.<cable>`` [N]; empty without a noise
            floor) and ``posture`` (the grid's ``joints``, bin ``edges`` [rad], ``rms``
            [unit] and ``samples`` per cell, ``None`` for a cell without samples).
        """
        n_channels = max(1, len(self.group("channel")))

        def number(value: float) -> float | None:
            return float(value) if np.isfinite(value) else None

        def rms(row: BreakdownRow) -> float | None:
            count = row.samples * (1 if row.group == "channel" else n_channels)
            return number(np.sqrt(row.energy / count)) if count else None

        return {
            "kind": self.kind,
            "unit": self.unit,
            "sources": list(self.sources),
            "samples": int(self.samples),
            "total_energy": number(self.total_energy),
            "rms": number(self.rms),
            "settings": asdict(self.settings),
            "rows": [
                {
                    "group": r.group,
                    "where": r.where,
                    "energy": number(r.energy),
                    "share": number(r.share),
                    "time_share": number(r.time_share),
                    "density": number(r.density),
                    "samples": int(r.samples),
                    "rms": rms(r),
                    "noise_energy": number(r.noise_energy),
                    "excess_energy": number(r.excess_energy),
                    "noise_std": number(r.noise_std),
                    "excess_density": number(r.excess_density),
                }
                for r in self.rows
            ],
            "hot_spots": [{"group": r.group, "where": r.where} for r in self.hot_spots()],
            "noise_energy": number(self.noise_energy),
            "sensor_noise": {name: number(value) for name, value in self.sensor_noise.items()},
            "posture": {
                "joints": list(self.posture_joints),
                "edges": [[float(e) for e in edges] for edges in self.posture_edges],
                "rms": [[number(v) for v in row] for row in np.asarray(self.posture_rms)],
                "samples": np.asarray(self.posture_samples).astype(int).tolist(),
            },
        }

    def to_markdown(self) -> str:
        """The breakdown as Markdown: a summary, the hot spots, one table per group."""
        s = self.settings
        floor = self.noise_energy > 0
        squared = f"{f'({self.unit})' if ' ' in self.unit else self.unit}^2"
        lines = [
            f"## Where the gap lies: {self.kind} residual [{self.unit}]",
            "",
            f"{len(self.sources)} log(s), {self.samples} samples; residual RMS "
            f"{self.rms:.4g} {self.unit}, energy {self.total_energy:.4g} {squared}.",
            "",
            "Density = share of energy / share of time (> 1: the gap concentrates there). "
            "Each sample is counted in one motion phase and one load phase (first match of "
            "reversal, acceleration, hold, constant velocity; low tension, high load, normal). "
            f"Thresholds: hold |qd| < {s.hold_speed:g} rad/s, reversal |qd| > "
            f"{s.reversal_speed:g} rad/s both ways within +-{s.reversal_window:g} s, "
            f"acceleration |qdd| >= {s.acceleration:g} rad/s^2, low tension < "
            f"{s.low_tension:g} N, high load > p{s.high_load_percentile:g} of the largest "
            f"tension; a hot spot has a density >= {s.hot_spot_density:g} over >= "
            f"{s.hot_spot_samples} samples"
            + (
                " (the excess density: that of the energy beyond the sensors' noise, away from "
                "the filter's edges) and an excess of >= "
                f"{s.hot_spot_noise_ratio - 1.0:g} times its expected noise energy and >= "
                f"{s.hot_spot_noise_sigmas:g} standard deviations of it."
                if floor
                else "."
            ),
            "",
        ]
        if floor:
            levels = {"q.": ("encoders", "rad"), "tension_motor.": ("load cells", "N")}
            said = []
            for prefix, (what, unit) in levels.items():
                values = [v for k, v in self.sensor_noise.items() if k.startswith(prefix)]
                if values:
                    said.append(f"{what} {min(values):.3g} to {max(values):.3g} {unit}")
            lines += [
                f"Noise floor: the sensors' white noise (estimated from the logs: "
                f"{', '.join(said)} std) alone is expected to make an energy of "
                f"{self.noise_energy:.4g} {squared}, "
                f"{100.0 * self.noise_energy / self.total_energy:.0f} % of the residual's; "
                "it is taken off each row before hot spots are named.",
                "",
            ]
        hot = self.hot_spots()
        if hot:
            lines.append(
                "Hot spots: "
                + "; ".join(
                    (
                        f"{r.group} {r.where} (x{r.excess_density:.2f} beyond the sensors' "
                        f"noise, {r.share:.1f} % of the energy, "
                        f"{r.energy / r.noise_energy:.1f} times its expected noise)"
                    )
                    if floor and r.noise_energy > 0
                    else f"{r.group} {r.where} (x{r.density:.2f}, {r.share:.1f} % of the energy)"
                    for r in hot
                )
                + "."
            )
        elif floor and self.total_energy < s.hot_spot_noise_ratio * self.noise_energy:
            lines.append(
                f"Hot spots: none, no concentration beyond the sensors' noise (the residual's "
                f"energy is {self.total_energy / self.noise_energy:.2f} times what the noise "
                "alone is expected to make)."
            )
        else:
            lines.append(
                f"Hot spots: none, no concentration (no phase or posture cell has a density "
                f"of {s.hot_spot_density:g} or more over {s.hot_spot_samples} samples or more"
                + (
                    " beyond the sensors' noise, with an excess of "
                    f"{s.hot_spot_noise_ratio - 1.0:g} times its expected noise energy and "
                    f"{s.hot_spot_noise_sigmas:g} standard deviations of it)."
                    if floor
                    else ")."
                )
            )
        lines.append("")
        header = ["where", "energy share [%]", "time share [%]", "density", "samples"]
        if floor:
            header += ["noise [% of energy]", "excess density"]
        for name in GROUPS:
            lines += [
                f"### By {name}",
                "",
                "| " + " | ".join(header) + " |",
                "|---" + "|---:" * (len(header) - 1) + "|",
            ]
            for r in self.group(name):
                cells = [r.where, f"{r.share:.1f}", f"{r.time_share:.1f}", f"{r.density:.2f}"]
                cells.append(str(r.samples))
                if floor:
                    cells += [_percent(r.noise_energy, r.energy), _number(r.excess_density)]
                lines.append("| " + " | ".join(cells) + " |")
            lines.append("")
        return "\n".join(lines)


def _number(value: float) -> str:
    """A density with two decimals; "-" for NaN (nothing beyond the noise)."""
    return f"{value:.2f}" if np.isfinite(value) else "-"


def _percent(part: float, whole: float) -> str:
    """``part`` as a percentage of ``whole``, no decimals; "-" when ``whole`` is not > 0."""
    return f"{100.0 * part / whole:.0f}" if whole > 0 else "-"


def motion_phases(residuals: Residuals, settings: PhaseSettings | None = None) -> NDArray:
    """The motion phase of every sample of one log (index into :data:`MOTION_PHASES`).

    A joint reverses when it moves one way (faster than ``reversal_speed``) and then the other,
    straight through zero speed or after a stop of at most ``reversal_pause``. Straight
    through, the reversal is the samples that have both ways within ``reversal_window``;
    through a stop, the samples within ``reversal_window`` of the first one moving the other
    way (where the friction turns). Before 2026-11-29 only a pass straight through zero
    counted, and no sample of a reach-and-hold task (the benchmark's, 0.3-0.7 s holds between
    moves) was a reversal.

    Args:
        residuals: One log's residuals (its filtered ``qd`` and ``qdd``).
        settings: Thresholds.

    Returns:
        Phase index of each sample, shape ``(T,)`` (invalid samples: ``hold``).
    """
    s = settings or PhaseSettings()
    qd = np.nan_to_num(residuals.qd)
    qdd = np.nan_to_num(residuals.qdd)
    rate = residuals.sample_rate_hz
    half = max(1, round(s.reversal_window * rate))
    pause = max(1, round(s.reversal_pause * rate))
    reversal = np.zeros(len(qd), dtype=bool)
    # within each stretch: a sign change across a time gap is no reversal (the residuals are
    # computed stretch by stretch too)
    bounds = [0, *gap_starts(residuals.t, rate).tolist(), len(qd)]
    for start, stop in zip(bounds[:-1], bounds[1:], strict=True):
        way = np.sign(qd[start:stop]) * (np.abs(qd[start:stop]) > s.reversal_speed)
        for joint in range(qd.shape[1]):
            moving = np.flatnonzero(way[:, joint])
            turns = np.flatnonzero(np.diff(way[moving, joint]) != 0)
            for last, first in zip(moving[turns], moving[turns + 1], strict=True):
                # straight through zero: the samples whose window holds both ways; through a
                # stop: the window about the start the other way (where friction turns)
                straight = first - last <= 2 * half
                if not straight and first - last > pause:
                    continue
                low, high = first - half, (last if straight else first) + half
                reversal[start + max(low, 0) : start + min(high + 1, stop - start)] = True
    accelerating = (np.abs(qdd) >= s.acceleration).any(axis=1)
    holding = (np.abs(qd) < s.hold_speed).all(axis=1)
    return np.select(
        [reversal, accelerating, holding],
        [0, 1, 2],
        default=3,
    )


def load_phases(tension: FloatArray, settings: PhaseSettings | None = None) -> NDArray:
    """The load phase of every sample (index into :data:`LOAD_PHASES`).

    Args:
        tension: Load-cell tensions [N], shape ``(T, m)`` (all logs together: the high-load
            percentile is over these samples).
        settings: Thresholds.

    Returns:
        Phase index of each sample, shape ``(T,)``.
    """
    s = settings or PhaseSettings()
    largest = tension.max(axis=1)
    high = np.percentile(largest, s.high_load_percentile)
    low = (tension < s.low_tension).any(axis=1)
    return np.select([low, largest > high], [0, 1], default=2)


def break_down(
    residuals: Residuals | Sequence[Residuals],
    kind: str = "joint_torque",
    settings: PhaseSettings | None = None,
    posture_joints: tuple[str, str] | None = None,
    bins: int = 5,
    model: RobotModel | None = None,
    noise_floor: bool = True,
) -> GapBreakdown:
    """Break the residual energy of one or more logs down by channel, phase and posture.

    Args:
        residuals: The residuals of each log (same robot).
        kind: Which residual: ``"joint_torque"``, ``"cable_length"``, ``"drive"`` or
            ``"replay"``.
        settings: Phase thresholds.
        posture_joints: The two joints of the posture grid; default the two with the largest
            standard deviation of ``q`` (a model with one joint: that joint twice, a grid whose
            diagonal alone has samples).
        bins: Bins over each joint of the grid.
        model: The robot, for the joint ranges of the grid (without it the grid spans the
            logged range) and, a :class:`~msarm.model.RobotModel`, for the noise floor of the
            kinds that have one (:data:`~msarm.diagnose.noise_floor.NOISE_FLOOR_KINDS`: the
            sensors' white noise estimated from each log and the energy it alone is expected
            to put in each row, :func:`~msarm.diagnose.noise_floor.joint_torque_noise`);
            without it, no floor.
        noise_floor: Take the noise floor off (with ``model``, for those kinds); False: the
            breakdown without it (``noise_energy`` 0, ``excess_density`` the density).

    Returns:
        The breakdown.

    Raises:
        InputError: No logs, logs of different robots, an unknown kind or joint, no valid
            sample, a residual that is zero everywhere, or (with a noise floor) a model
            whose joints or cables are not the logs'.
    """
    runs = [residuals] if isinstance(residuals, Residuals) else list(residuals)
    if not runs:
        raise InputError("break_down needs at least one log's residuals")
    settings = settings or PhaseSettings()
    if bins < 1:
        raise InputError(f"bins must be >= 1, got {bins}")
    first = runs[0]
    for run in runs[1:]:
        if run.joint_names != first.joint_names or run.cable_names != first.cable_names:
            raise InputError(
                f"{run.source} and {first.source} are logs of different robots (joint or cable "
                "names differ)"
            )
    channels = first.channel_names(kind)
    floor = noise_floor and isinstance(model, RobotModel) and kind in NOISE_FLOOR_KINDS
    parts = []
    levels: list[SensorNoise] = []
    for run in runs:
        keep = run.valid
        scored = run.scored(kind)  # cable lengths about each log's mean, as the diagnosis
        if floor:
            levels.append(sensor_noise(run))
            made = joint_torque_noise(model, run, levels[-1])
            expected = made.energy[keep]
            spread = np.column_stack([made.variance[keep], made.channel_variance[keep]])
            edge = made.edge[keep]
        else:
            expected = np.zeros_like(scored)
            spread = np.zeros((len(scored), scored.shape[1] + 1))
            edge = np.zeros(len(scored), dtype=bool)
        parts.append(
            (
                scored,
                run.q[keep],
                run.tension[keep],
                motion_phases(run, settings)[keep],
                expected,
                spread,
                edge,
            )
        )
    residual = np.concatenate([p[0] for p in parts])
    q = np.concatenate([p[1] for p in parts])
    tension = np.concatenate([p[2] for p in parts])
    motion = np.concatenate([p[3] for p in parts])
    noise = np.concatenate([p[4] for p in parts])
    spread = np.concatenate([p[5] for p in parts])  # total, then each channel [unit^4]
    interior = ~np.concatenate([p[6] for p in parts])
    if len(residual) == 0:
        raise InputError("no valid sample in the logs")
    energy = residual**2
    per_sample = energy.sum(axis=1)
    total = float(per_sample.sum())
    if not total > 0:
        raise InputError(f"the {kind} residual is zero everywhere: nothing to break down")
    n_samples = len(per_sample)
    # the noise floor's statistics of each sample: its expected noise energy; and, away from
    # the filter's edges, its energy beyond that, the variance of its noise energy, and 1
    noise_per_sample = noise.sum(axis=1)
    floor_stats = np.column_stack(
        [
            noise_per_sample,
            np.where(interior, per_sample - noise_per_sample, 0.0),
            np.where(interior, spread[:, 0], 0.0),
            interior.astype(float),
        ]
    )
    channel_beyond = np.where(interior[:, None], energy - noise, 0.0)
    channel_spread = np.where(interior[:, None], spread[:, 1:], 0.0)
    total_noise = float(noise_per_sample.sum())
    total_beyond = float(floor_stats[:, 1].sum())
    n_interior = float(floor_stats[:, 3].sum())

    rows: list[BreakdownRow] = []

    def add(
        group: str,
        where: str,
        value: float,
        count: int,
        time_share: float,
        stats: FloatArray,
    ) -> None:
        """One row: ``stats`` are its sums of ``floor_stats``' columns (channels: alike)."""
        share = 100.0 * value / total
        density = share / time_share if time_share > 0 else float("nan")
        expected, beyond, variance, away = (float(v) for v in stats)
        if not floor:
            rows.append(BreakdownRow(group, where, value, share, time_share, density, count))
            return
        away_share = 100.0 * away / n_interior if n_interior > 0 else 0.0
        if group == "channel":
            away_share = time_share
        if total_beyond > 0 and away_share > 0:
            excess_density = 100.0 * beyond / total_beyond / away_share
        else:
            excess_density = float("nan")  # nothing beyond the noise
        rows.append(
            BreakdownRow(
                group,
                where,
                value,
                share,
                time_share,
                density,
                count,
                noise_energy=expected,
                excess_energy=beyond,
                excess_density=excess_density,
                noise_std=float(np.sqrt(max(variance, 0.0))),
            )
        )

    for j, name in enumerate(channels):
        stats = np.array(
            [noise[:, j].sum(), channel_beyond[:, j].sum(), channel_spread[:, j].sum(), 0.0]
        )
        add("channel", name, float(energy[:, j].sum()), n_samples, 100.0 / len(channels), stats)
    load = load_phases(tension, settings)
    for group, labels, index in (("motion", MOTION_PHASES, motion), ("load", LOAD_PHASES, load)):
        for p, name in enumerate(labels):
            mask = index == p
            count = int(mask.sum())
            if count:
                add(
                    group,
                    name,
                    float(per_sample[mask].sum()),
                    count,
                    100.0 * count / n_samples,
                    floor_stats[mask].sum(axis=0),
                )

    joint_names = list(first.joint_names)
    if posture_joints is None:
        order = np.argsort(-q.std(axis=0), kind="stable")
        pair = (int(order[0]), int(order[min(1, len(order) - 1)]))
    else:
        unknown = [j for j in posture_joints if j not in joint_names]
        if unknown:
            raise InputError(f"unknown joint {unknown[0]!r}; joints: {', '.join(joint_names)}")
        pair = (joint_names.index(posture_joints[0]), joint_names.index(posture_joints[1]))
    edges = []
    cells = []
    for j in pair:
        if model is not None:
            lo, hi = float(model.joint_lower[j]), float(model.joint_upper[j])
        else:
            lo, hi = float(q[:, j].min()), float(q[:, j].max())
            hi = hi if hi > lo else lo + 1e-9
        e = np.linspace(lo, hi, bins + 1)
        edges.append(e)
        cells.append(np.clip(np.searchsorted(e, q[:, j], side="right") - 1, 0, bins - 1))
    grid_energy = np.zeros((bins, bins))
    grid_stats = np.zeros((bins, bins, floor_stats.shape[1]))
    grid_count = np.zeros((bins, bins), dtype=np.int64)
    np.add.at(grid_energy, (cells[0], cells[1]), per_sample)
    np.add.at(grid_stats, (cells[0], cells[1]), floor_stats)
    np.add.at(grid_count, (cells[0], cells[1]), 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        grid_rms = np.sqrt(grid_energy / (grid_count * len(channels)))
    grid_rms[grid_count == 0] = np.nan
    a, b = (joint_names[j] for j in pair)
    for i in range(bins):
        for k in range(bins):
            if grid_count[i, k]:
                where = f"{a} [{edges[0][i]:.2f}, {edges[0][i + 1]:.2f}]"
                if pair[1] != pair[0]:  # a one-joint model's grid is its diagonal: one range
                    where += f" x {b} [{edges[1][k]:.2f}, {edges[1][k + 1]:.2f}]"
                count = int(grid_count[i, k])
                add(
                    "posture",
                    where,
                    float(grid_energy[i, k]),
                    count,
                    100.0 * count / n_samples,
                    grid_stats[i, k],
                )

    ordered = tuple(
        row
        for group in GROUPS
        for row in sorted((r for r in rows if r.group == group), key=lambda r: -r.share)
    )
    return GapBreakdown(
        kind=kind,
        unit=RESIDUAL_UNITS[kind],
        sources=tuple(run.source for run in runs),
        samples=n_samples,
        total_energy=total,
        rms=float(np.sqrt(total / (n_samples * len(channels)))),
        rows=ordered,
        posture_joints=(a, b),
        posture_edges=(edges[0], edges[1]),
        posture_rms=grid_rms,
        posture_samples=grid_count,
        settings=settings,
        noise_energy=total_noise,
        sensor_noise=_pooled_levels(levels, first.joint_names, first.cable_names),
    )


def _pooled_levels(
    levels: Sequence[SensorNoise], joints: Sequence[str], cables: Sequence[str]
) -> dict[str, float]:
    """The logs' noise levels by log column: the RMS over the logs, weighted by samples."""
    weights = np.array([level.samples for level in levels], dtype=float)
    if not weights.sum() > 0:
        return {}
    weights /= weights.sum()
    out = {}
    for prefix, names, values in (
        ("q", joints, [level.joint for level in levels]),
        ("tension_motor", cables, [level.tension for level in levels]),
    ):
        squares = np.nan_to_num(np.asarray(values)) ** 2  # a log without samples: weight 0
        pooled = np.sqrt(np.einsum("l,lk->k", weights, squares))
        out.update({f"{prefix}.{name}": float(v) for name, v in zip(names, pooled, strict=True)})
    return out


def diagnose_where(
    model: RobotModel,
    logs: Sequence[str | Path],
    kind: str = "joint_torque",
    settings: PhaseSettings | None = None,
    spec: ResidualSpec | None = None,
    posture_joints: tuple[str, str] | None = None,
    bins: int = 5,
) -> GapBreakdown:
    """Residuals of log files against the nominal model, broken down (the logs combined).

    Args:
        model: The nominal robot model.
        logs: Log files (their sidecars are never opened).
        kind: Which residual to break down.
        settings: Phase thresholds.
        spec: Residual settings (the replay is computed only for ``kind="replay"``).
        posture_joints: The two joints of the posture grid (default: those that move most).
        bins: Bins over each joint of the grid.

    Returns:
        The breakdown.

    Raises:
        InputError: No logs, an unknown ``kind``, ``bins < 1`` or ``posture_joints`` that
            are not two different joints of the model, all before any log is read; and as
            :func:`break_down`.
    """
    if isinstance(logs, str | Path) or not list(logs):
        raise InputError(f"logs: expected a list of one or more log files, got {logs!r}")
    if kind not in RESIDUAL_UNITS:
        kinds = ", ".join(RESIDUAL_UNITS)
        raise InputError(f"kind: unknown residual kind {kind!r}; kinds: {kinds}")
    if not (isinstance(bins, int | np.integer) and bins >= 1):
        raise InputError(f"bins: expected a whole number >= 1, got {bins!r}")
    if posture_joints is not None:
        names = list(model.joint_names)
        if (
            len(posture_joints) != 2
            or len(set(posture_joints)) != 2
            or any(j not in names for j in posture_joints)
        ):
            raise InputError(
                f"posture_joints: expected two different joints of the model ({', '.join(names)}),"
                f" got {posture_joints!r}"
            )
    spec = spec or ResidualSpec(replay=kind == "replay")
    runs = [residuals_from_log(model, path, spec=spec) for path in logs]
    return break_down(runs, kind, settings, posture_joints, bins, model)


#: Residual unit -> (the unit a plot shows it in, the factor from SI): joint angles in
#: degrees, cable lengths in mm (the breakdown and its JSON stay in SI units).
PLOT_UNITS = {"rad": ("deg", 180.0 / np.pi), "m": ("mm", 1000.0)}


def plot_heatmap(breakdown: GapBreakdown, path: str | Path) -> Path:
    """Plot the residual RMS over the posture grid and the channel and phase shares.

    The posture grid's joints are drawn in degrees and a residual in rad or m in deg or mm
    (:data:`PLOT_UNITS`); the channel panel's dashed line is the even share, 100 % over the
    number of channels.

    Args:
        breakdown: The breakdown.
        path: PNG file to write (atomically).

    Returns:
        The path written.
    """
    from msarm.plots import plt, save_figure

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8), layout="constrained")
    ax = axes[0]
    angle_unit, to_angle = PLOT_UNITS["rad"]  # the grid's joints are hinges (rad)
    ea, eb = (to_angle * np.asarray(e) for e in breakdown.posture_edges)
    unit, scale = PLOT_UNITS.get(breakdown.unit, (breakdown.unit, 1.0))
    rms = scale * np.asarray(breakdown.posture_rms)
    grid = np.ma.masked_invalid(rms)
    mesh = ax.pcolormesh(eb, ea, grid, cmap="magma", shading="flat")
    fig.colorbar(mesh, ax=ax, label=f"{breakdown.kind} RMS [{unit}]")
    for i in range(len(ea) - 1):
        for k in range(len(eb) - 1):
            count = breakdown.posture_samples[i, k]
            if count:
                value = rms[i, k]
                # dark text on magma's light end, light text on its dark end
                light = np.isfinite(value) and mesh.norm(value) > 0.6
                ax.text(
                    (eb[k] + eb[k + 1]) / 2,
                    (ea[i] + ea[i + 1]) / 2,
                    str(count),
                    ha="center",
                    va="center",
                    fontsize=7,
                    color="black" if light else "white",
                )
    ax.set_xlabel(f"{breakdown.posture_joints[1]} [{angle_unit}]")
    ax.set_ylabel(f"{breakdown.posture_joints[0]} [{angle_unit}]")
    first, second = breakdown.posture_joints
    over = first if first == second else "posture"  # one joint: the grid's diagonal
    ax.set_title(f"residual RMS over {over} (numbers: samples)")

    for ax, groups, title in (
        (axes[1], ("channel",), "share of residual energy by channel"),
        (axes[2], ("motion", "load"), "share by phase (bars) vs time (dots)"),
    ):
        rows = [r for g in groups for r in breakdown.group(g)]
        y = np.arange(len(rows))
        colours = ["tab:blue" if r.group in ("channel", "motion") else "tab:orange" for r in rows]
        ax.barh(y, [r.share for r in rows], color=colours)
        if "channel" not in groups:
            ax.plot([r.time_share for r in rows], y, "k.", label="time share")
            ax.legend(loc="lower right")
        else:
            even = 100.0 / max(1, len(rows))
            ax.axvline(even, color="k", lw=0.8, ls="--", label=f"even share (100 % / {len(rows)})")
            ax.legend(loc="lower right")
        ax.set_yticks(y, [f"{r.where} ({r.group})" if len(groups) > 1 else r.where for r in rows])
        ax.invert_yaxis()
        ax.set_xlabel("%")
        ax.set_title(title)
    fig.suptitle(
        f"Where the gap lies: {breakdown.kind} residual, {len(breakdown.sources)} log(s), "
        f"{breakdown.samples} samples, RMS {scale * breakdown.rms:.3g} {unit}"
    )
    return save_figure(fig, path)
