"""Check the diagnosis's friction terms on a real cable transmission (da Vinci tool data).

Data: the input spindle of a da Vinci Maryland tool is driven along a sine, the jaw is loaded
by a second motor with a constant resistive torque; both angles and both torques are measured
at 1 kHz (subset of ``MRDLab/mis-tool-characterization``, O'Neill et al., RA-L 2018; ODbL 1.0,
Medical Robotics and Devices Lab, University of Minnesota). Three wrist pitches (+60, +30,
0 degrees) change how the cables wrap over the wrist pulleys.

Model: the jaw is the one joint ``q`` [rad] (front-end encoder, positive in the direction the
input drives it), one cable runs from the input spindle (effective radius ``R_IN``) to the
jaw. The nominal transmission is ideal: ``q = k q_in`` with the ratio ``k`` fitted on the
training files' angles only, and lossless, so the torque it delivers to the jaw is
``tau_MS = tau_in / |k|`` (power in = power out). The jaw is slow and light, so its nominal
inverse dynamics is the load: ``ID = -tau_out`` (the front-end torque, negative: it resists).
The residual ``r = tau_MS - ID`` [N m] is the torque lost in the transmission.

Candidates (msarm's own classes where the mapping fits): Coulomb, viscous, Stribeck, Dahl
friction of the jaw; msarm's capstan friction ``F_out = F_in exp(-mu Theta s)`` with a unit
wrap (pitch-blind: ``mu`` is the loss exponent ``mu Theta``); the same with the wrap
``Theta = Theta_0 + |pitch|`` (``mu``, ``Theta_0`` fitted on training data); and a load-cell
bias and scale error (msarm's ``sensor`` term, the rival explanation of a loss that grows with
the load). Every score is the explained variance on files the term was not fitted on:
(a) leave one torque level, one frequency or one yaw stop out; (b) leave one pitch out.

    python examples/real_cable_transmission.py [--data DIR] [--out runs/mis-tool] [--seed 0]

The data folder defaults to ``$MSARM_MIS_TOOL_DATA`` or ``../shared/data/mis-tool`` (next to
the repository); the data are never copied into the repository. Every file needs a whole cycle
of its sine after the first :data:`SETTLE_S` s, each pitch at least 2 files and each family of
files (torque level, frequency, yaw stop) at least 2 levels, as every fold leaves one level
out; data that do not are refused (exit code 2) before the analysis.

Output: ``held_out.png``, ``loops_per_pitch.png`` and ``results.json`` in ``--out`` (created
if missing). A previous run's ``results.json`` there is removed first, and the new one is
written last (atomically), after the plots: a folder holding ``results.json`` holds one whole
run; one without it, a run that was cut off (SIGTERM ends the script with exit code 143 and
no temporary file left behind).
"""

from __future__ import annotations

import argparse
import gzip
import math
import os
import sys
import time
import warnings
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import butter, sosfiltfilt

from msarm.cli.common import output_folder, run_script
from msarm.diagnose.effects import (
    NUMPY_OPS,
    CableCapstanFriction,
    CandidateEffect,
    CoulombFriction,
    DahlFriction,
    NumpyOps,
    Ops,
    SensorBiasScale,
    StribeckFriction,
    ViscousFriction,
    parameter_kind,
)
from msarm.diagnose.fitting import FitResult, bootstrap, fit, stacked_constraints
from msarm.diagnose.signals import Signals
from msarm.errors import InputError
from msarm.io.atomic import atomic_path, write_json_atomic

FloatArray = NDArray[np.float64]

#: Factor on the RGB of a load's colour for its predicted loop (a darker shade of it).
PREDICTION_SHADE = 0.55
#: Environment variable that points at the data folder.
DATA_ENV = "MSARM_MIS_TOOL_DATA"
#: Default data folder: ``../shared/data/mis-tool`` relative to the repository root.
DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mis-tool"
#: Wrist pitch of each folder [deg] (the data README's table).
PITCH_DEG = {
    "Tool_4_Maryland_L_Pitch_1": 60.0,
    "Tool_4_Maryland_L_Pitch_2": 30.0,
    "Tool_4_Maryland_L_Pitch_3": 0.0,
}
#: Input (back-end CUI) encoder resolution [counts/rev].
INPUT_COUNTS_PER_REV = 8192.0
#: Output (front-end Maxon) encoder resolution [counts/rev].
OUTPUT_COUNTS_PER_REV = 4000.0
#: Futek torque sensors' scale, both ends [N m/count].
TORQUE_PER_COUNT = 0.000039811
#: Raw sample period: the time column holds seconds (the header says ms) [s].
RAW_PERIOD = 1e-3
#: Rate the runs are thinned to after low-pass filtering [Hz].
RATE_HZ = 100.0
#: Cut-off of the zero-phase low-pass filter applied before thinning and differentiating [Hz].
CUTOFF_HZ = 10.0
#: Start of every file that is dropped (the load motor and the sine start up) [s].
SETTLE_S = 1.0
#: Effective input-spindle radius [m]: an assumed value. It cancels in every torque (the
#: tension is ``tau_in / R_IN``, the Jacobian ``-R_IN / |k|``); it only scales the cable speed
#: and hence the capstan term's smoothing speed, which is set as ``R_IN`` times ``EPS``.
R_IN = 0.005
#: Speed scale of every smoothed sign, in joint (jaw) units [rad/s].
EPS = 0.05
#: Dahl rates tried on the training files [1/rad] (the one of least training error is kept).
DAHL_RATES = (40.0, 80.0, 160.0, 320.0, 640.0, 1280.0)
#: Largest wrap at zero pitch ``Theta_0`` a fit may choose [rad].
MAX_THETA0 = 4.0 * np.pi


# --------------------------------------------------------------------------- reading
@dataclass(frozen=True)
class Run:
    """One file, filtered and thinned to :data:`RATE_HZ`; angles and torques in SI units.

    Attributes:
        folder: Data folder name (one pitch).
        name: File stem, ``ZXY`` (yaw stop, frequency, torque level indices).
        pitch: Wrist pitch [rad].
        yaw: Jaw (yaw) stop from the header [rad].
        freq: Sine frequency from the header [Hz].
        torque_pct: Resistive torque level from the header [%].
        t: Time [s], shape ``(T,)``.
        q_in: Input spindle angle from its start [rad], ``(T,)``.
        q_out: Jaw angle from its start [rad], ``(T,)``.
        qd_in: Input speed [rad/s], ``(T,)``.
        qd_out: Jaw speed [rad/s], ``(T,)``.
        qdd_out: Jaw acceleration [rad/s^2], ``(T,)``.
        tau_in: Input torque in the input encoder's frame [N m], ``(T,)``: the back-end
            Futek reads the opposite sign (its large readings come while ``q_in`` falls, and
            a driven spindle takes power in), so its reading is negated; over whole cycles
            ``tau_in * qd_in`` then averages to the (positive) power the transmission
            dissipates.
        tau_out: Output (front-end) torque as measured [N m], ``(T,)`` (negative: the load
            resists the jaw's positive motion).
        amplitude_deg: Sine amplitude the header states [deg].
    """

    folder: str
    name: str
    pitch: float
    yaw: float
    freq: float
    torque_pct: float
    t: FloatArray
    q_in: FloatArray
    q_out: FloatArray
    qd_in: FloatArray
    qd_out: FloatArray
    qdd_out: FloatArray
    tau_in: FloatArray
    tau_out: FloatArray
    amplitude_deg: float

    @property
    def label(self) -> str:
        """A short label, e.g. ``p60/103``."""
        return f"p{np.degrees(self.pitch):.0f}/{self.name}"


def read_header(path: Path) -> dict[str, str]:
    """The ``%key=value`` lines of a data file's header (and the sine amplitude).

    Args:
        path: A ``.TXT`` file, gzipped (``.TXT.gz``) or not.

    Returns:
        Keys and values as text; ``amplitude_deg`` parsed from the description line.
    """
    out: dict[str, str] = {}
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as handle:
        for line in handle:
            if not line.startswith("%"):
                break
            body = line[1:].strip()
            if "=" in body and "," not in body:
                key, value = body.split("=", 1)
                out[key.strip()] = value.strip()
            elif "amplitude of" in body:
                out["amplitude_deg"] = body.split("amplitude of", 1)[1].split("degrees")[0].strip()
    return out


def read_raw(path: Path) -> FloatArray:
    """The 10 data columns of a file as they are stored, shape ``(N, 10)``.

    Raises:
        ValueError: The file has no data rows, or not 10 columns.
    """
    with warnings.catch_warnings():  # numpy's warning about an empty file: the error below
        warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
        data = np.loadtxt(path, comments="%", delimiter=",", ndmin=2)
    if data.size == 0:
        raise ValueError(f"{path}: no data rows; expected 10 comma-separated columns at 1 kHz")
    if data.shape[1] != 10:
        raise ValueError(f"{path}: expected 10 comma-separated columns, got {data.shape[1]}")
    return data


def to_si(raw: FloatArray) -> dict[str, FloatArray]:
    """Convert the raw columns to SI units (no filtering), each ``(N,)``.

    Returns:
        ``t`` [s] (column 1 holds seconds despite its ``[ms]`` label), ``q_in``, ``q_out``
        [rad] from the first sample, ``tau_in_raw``, ``tau_out`` [N m] as the sensors read.
    """
    return {
        "t": raw[:, 0].copy(),
        "q_in": (raw[:, 1] - raw[0, 1]) * (2.0 * np.pi / INPUT_COUNTS_PER_REV),
        "q_out": (raw[:, 4] - raw[0, 4]) * (2.0 * np.pi / OUTPUT_COUNTS_PER_REV),
        "tau_in_raw": raw[:, 2] * TORQUE_PER_COUNT,
        "tau_out": raw[:, 5] * TORQUE_PER_COUNT,
    }


def min_samples(freq: float) -> int:
    """The fewest 1 kHz samples a file of a ``freq`` [Hz] sine needs.

    The first :data:`SETTLE_S` s are dropped, and a whole cycle of the sine must be left
    after them (the loss is a loop over a cycle; the Dahl state takes a cycle to settle).
    """
    return int(round(SETTLE_S / RAW_PERIOD)) + math.ceil(1.0 / (freq * RAW_PERIOD) - 1e-9)


def read_run(path: Path, pitch_deg: float) -> Run:
    """Read, convert, low-pass filter, differentiate and thin one file.

    Filtering is zero phase (2nd-order Butterworth at :data:`CUTOFF_HZ`, forwards and
    backwards) at 1 kHz; derivatives are central differences of the filtered angles; the
    first :data:`SETTLE_S` are dropped and every ``1 kHz / RATE_HZ``-th sample is kept.

    Args:
        path: A ``.TXT`` file, gzipped (``.TXT.gz``) or not.
        pitch_deg: The folder's wrist pitch [deg].

    Raises:
        ValueError: The header lacks a key or states no positive frequency, the file has no
            data rows or fewer than :func:`min_samples`, or the sample period is not 1 ms.
    """
    header = read_header(path)
    lacking = [k for k in ("Yaw_rad", "Freq_Hz", "Torque_Pct") if k not in header]
    if lacking:
        raise ValueError(f"{path}: the header has no %{', %'.join(k + '=' for k in lacking)}")
    freq = float(header["Freq_Hz"])
    if not 0.0 < freq < math.inf:
        raise ValueError(f"{path}: %Freq_Hz={header['Freq_Hz']}; expected a frequency > 0 Hz")
    raw = read_raw(path)
    need = min_samples(freq)
    if raw.shape[0] < need:
        raise ValueError(
            f"{path}: {raw.shape[0]} samples ({raw.shape[0] * RAW_PERIOD:g} s); expected at "
            f"least {need}: the first {SETTLE_S:g} s are dropped (settling), then a whole "
            f"cycle of the {freq:g} Hz sine is needed"
        )
    si = to_si(raw)
    period = float(np.median(np.diff(si["t"])))
    if abs(period - RAW_PERIOD) > 1e-6:
        raise ValueError(f"{path}: sample period {period} s, expected {RAW_PERIOD} s")
    sos = butter(2, CUTOFF_HZ, fs=1.0 / RAW_PERIOD, output="sos")
    smooth = {k: sosfiltfilt(sos, si[k]) for k in ("q_in", "q_out", "tau_in_raw", "tau_out")}
    qd_in = np.gradient(smooth["q_in"], RAW_PERIOD)
    qd_out = np.gradient(smooth["q_out"], RAW_PERIOD)
    qdd_out = np.gradient(qd_out, RAW_PERIOD)
    step = int(round(1.0 / (RATE_HZ * RAW_PERIOD)))
    keep = np.arange(int(round(SETTLE_S / RAW_PERIOD)), si["t"].size, step)
    return Run(
        folder=path.parent.name,
        name=path.name.split(".")[0],
        pitch=float(np.radians(pitch_deg)),
        yaw=float(header["Yaw_rad"]),
        freq=freq,
        torque_pct=float(header["Torque_Pct"]),
        t=si["t"][keep],
        q_in=smooth["q_in"][keep],
        q_out=smooth["q_out"][keep],
        qd_in=qd_in[keep],
        qd_out=qd_out[keep],
        qdd_out=qdd_out[keep],
        tau_in=-smooth["tau_in_raw"][keep],
        tau_out=smooth["tau_out"][keep],
        amplitude_deg=float(header.get("amplitude_deg", "nan")),
    )


def data_folder(arg: str | None) -> Path:
    """The data folder: ``--data``, else ``$MSARM_MIS_TOOL_DATA``, else the default."""
    if arg is not None:
        return Path(arg)
    return Path(os.environ.get(DATA_ENV, DEFAULT_DATA))


def data_files(root: Path) -> list[tuple[Path, float]]:
    """Every data file under ``root`` with its pitch [deg], sorted (empty when absent)."""
    out = []
    for folder, pitch in PITCH_DEG.items():
        # the upstream files are plain .TXT; a gzipped copy is taken where both are there
        files = {p.name: p for p in (root / folder).glob("*.TXT")}
        files.update({p.name.removesuffix(".gz"): p for p in (root / folder).glob("*.TXT.gz")})
        out += [(files[name], pitch) for name in sorted(files)]
    return out


def load_runs(root: Path) -> list[Run]:
    """Read every file of the three pitch folders (48 runs).

    Raises:
        ValueError: A file that cannot be read as a data file (named, with the reason).
    """
    runs = []
    for path, pitch in data_files(root):
        try:
            runs.append(read_run(path, pitch))
        except (OSError, ValueError, EOFError, zlib.error) as exc:
            text = str(exc)
            raise ValueError(text if str(path) in text else f"{path}: {text}") from exc
    return runs


def missing_pitches(files: Sequence[tuple[Path, float]]) -> list[str]:
    """The pitch folders without a file among ``files`` (each pitch is held out once)."""
    present = {path.parent.name for path, _ in files}
    return [f for f in PITCH_DEG if f not in present]


# --------------------------------------------------------------------------- nominal model
def fit_ratio(runs: Sequence[Run]) -> float:
    """The kinematic ratio ``k = dq_out / dq_in`` [-], least squares with an offset per run."""
    x = np.concatenate([r.q_in - r.q_in.mean() for r in runs])
    y = np.concatenate([r.q_out - r.q_out.mean() for r in runs])
    return float(x @ y / (x @ x))


@dataclass(frozen=True)
class TransmissionSignals(Signals):
    """msarm's :class:`Signals` plus what the transmission's extra terms read.

    Attributes:
        pitch: Wrist pitch of each sample [rad], shape ``(T,)``.
        output_tension: Tension at the jaw's end of the cable, ``load / R_out`` [N],
            ``(T, 1)``.
    """

    pitch: FloatArray | None = None
    output_tension: FloatArray | None = None


def build_signals(runs: Sequence[Run], ratio: float) -> tuple[TransmissionSignals, FloatArray]:
    """The runs as one :class:`Signals` of 1 joint and 1 cable, and the residual.

    Args:
        runs: The runs (each one label of ``Signals.run``, in order).
        ratio: Kinematic ratio ``k`` (fitted on training runs only).

    Returns:
        The signals (``T`` samples) and the residual ``r = tau_in / k + tau_out`` [N m]
        (``tau_in / k`` is what a lossless transmission delivers to the jaw), shape
        ``(T, 1)``.
    """
    r_out = R_IN / abs(ratio)
    tau_ms = [r.tau_in / ratio for r in runs]
    cat = np.concatenate
    t = cat([r.t + 100.0 * i for i, r in enumerate(runs)])  # runs apart in time
    q, qd, qdd = (
        cat([getattr(r, f) for r in runs])[:, None] for f in ("q_out", "qd_out", "qdd_out")
    )
    tension = cat(tau_ms)[:, None] / r_out
    T = t.size
    signals = TransmissionSignals(
        t=t,
        q=q,
        qd=qd,
        qdd=qdd,
        tension=tension,
        lengths=-r_out * q,
        cable_velocity=cat([-np.sign(ratio) * R_IN * r.qd_in for r in runs])[:, None],
        jacobian=np.full((T, 1, 1), -r_out),
        wrap=np.ones((T, 1)),
        motor_angle=cat([r.q_in for r in runs])[:, None],
        dt=1.0 / RATE_HZ,
        run=cat([np.full(r.t.size, i) for i, r in enumerate(runs)]),
        pitch=cat([np.full(r.t.size, r.pitch) for r in runs]),
        output_tension=cat([-r.tau_out for r in runs])[:, None] / r_out,
    )
    residual = cat([m + r.tau_out for m, r in zip(tau_ms, runs, strict=True)])[:, None]
    return signals, residual


# --------------------------------------------------------------------------- extra terms
class WrapCapstan(CableCapstanFriction):
    """msarm's capstan term with the wrap from the pitch, or referred to the jaw's tension.

    ``reference="input"``: msarm's form, ``F_out = F_in exp(-mu Theta s)`` with the motor-side
    tension ``F_in`` (``Signals.tension``), ``r = J_c^T F_in (exp(-mu Theta s) - 1)``.
    ``reference="output"``: the same law solved for the input, ``F_in = F_out exp(mu Theta s)``
    with the tension at the jaw ``F_out`` (the load, always pulling:
    ``TransmissionSignals.output_tension``), ``r = -J_c^T F_out (exp(mu Theta s) - 1)``.
    With ``pitch_wrap`` the wrap is ``Theta = Theta_0 + |pitch|`` and ``Theta_0`` [rad] is a
    second parameter; without it ``Theta = 1`` and ``mu`` is the loss exponent ``mu Theta``.
    """

    name = "wrap_capstan"

    def __init__(self, reference: str = "input", pitch_wrap: bool = True, eps: float = 1e-3):
        """Build the term.

        Args:
            reference: ``"input"`` or ``"output"``: which end's tension the law starts from.
            pitch_wrap: Wrap ``Theta_0 + |pitch|`` (else a unit wrap).
            eps: Cable-velocity scale of the smoothed sign [m/s].
        """
        super().__init__(n_cables=1, n_joints=1, eps=eps, max_mu=5.0)
        if reference not in ("input", "output"):
            raise ValueError(f"reference: expected 'input' or 'output', got {reference!r}")
        self.reference, self.pitch_wrap = reference, bool(pitch_wrap)
        self.parameter_names = ("mu", "theta0") if pitch_wrap else ("mu",)
        self.linear = False  # type: ignore[misc]

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:
        """Predicted residual [N m], ``(T, 1)``."""
        if isinstance(ops, NumpyOps):
            theta = self._check_theta(theta)
        s = ops.const(self._direction(signals))
        if self.pitch_wrap:
            pitch = ops.const(np.abs(np.asarray(signals.pitch))[:, None])
            exponent = theta[0] * (theta[1] + pitch) * s
        else:
            exponent = theta[0] * s
        if self.reference == "input":
            g = ops.const(signals.tension) * (ops.exp(-exponent) - 1.0)
        else:
            g = ops.const(-np.asarray(signals.output_tension)) * (ops.exp(exponent) - 1.0)
        return ops.cable_to_joint(signals.jacobian, g)

    def initial_guess(self, signals: Signals, residual: FloatArray | None = None) -> FloatArray:
        """Start: ``mu = 0.1`` (and ``Theta_0 = 1`` rad)."""
        return np.array([0.1, 1.0] if self.pitch_wrap else [0.1])

    def bounds(self) -> tuple[FloatArray, FloatArray]:
        """``0 <= mu <= 5``, ``0 <= Theta_0 <= MAX_THETA0``."""
        if self.pitch_wrap:
            return np.zeros(2), np.array([self.max_mu, MAX_THETA0])
        return np.zeros(1), np.array([self.max_mu])


class SumOfTerms(CandidateEffect):
    """Several candidates fitted jointly: the sum of their predictions, parameters in order."""

    name = "sum"

    def __init__(self, terms: Sequence[CandidateEffect]) -> None:
        """Build the sum of ``terms`` (all of 1 joint)."""
        self.terms = tuple(terms)
        self.channels = (0,)
        self.parameter_names = tuple(f"{t.name}:{p}" for t in terms for p in t.parameter_names)
        self.sizes = np.cumsum([0] + [t.n_parameters for t in terms])
        self.linear = all(t.linear for t in terms)  # type: ignore[misc]

    def split(self, theta: Any) -> list[Any]:
        """Each term's slice of ``theta``."""
        return [theta[a:b] for a, b in zip(self.sizes[:-1], self.sizes[1:], strict=True)]

    def check(self, signals: Signals) -> None:
        """Check every term."""
        for t in self.terms:
            t.check(signals)

    def design(self, signals: Signals) -> FloatArray:
        """Designs side by side (all terms linear), ``(T, 1, p)``."""
        return np.concatenate([t.design(signals) for t in self.terms], axis=2)

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:
        """Sum of the terms' predictions, ``(T, 1)``."""
        if self.linear:
            return super().torque(signals, theta, ops)
        parts = self.split(theta)
        total = None
        for term, part in zip(self.terms, parts, strict=True):
            value = term.torque(signals, part, ops)
            total = value if total is None else total + value
        return total

    def initial_guess(self, signals: Signals, residual: FloatArray | None = None) -> FloatArray:
        """The terms' own starts, in order."""
        return np.concatenate([t.initial_guess(signals, residual) for t in self.terms])

    def bounds(self) -> tuple[FloatArray, FloatArray]:
        """The terms' bounds (none for linear terms)."""
        low, high = zip(*(t.bounds() for t in self.terms), strict=True)
        return np.concatenate(low), np.concatenate(high)

    def constraints(self) -> FloatArray:
        """The terms' constraints (a Stribeck term's ``s >= c``), block diagonal."""
        return stacked_constraints(self.terms)


# --------------------------------------------------------------------------- candidates
Factory = Callable[[Signals, FloatArray, NDArray[np.bool_]], CandidateEffect]


#: Dahl rate chosen per training set, by ``(id(signals), training sample count)``; the
#: signals are kept beside the rate so that a recycled ``id`` is not mistaken for them.
_DAHL_RATE: dict[tuple[int, int], tuple[Signals, float]] = {}


def _dahl(signals: Signals, residual: FloatArray, train: NDArray[np.bool_]) -> CandidateEffect:
    """Dahl friction with the rate of :data:`DAHL_RATES` of least training error."""
    key = (id(signals), int(train.sum()))
    if key not in _DAHL_RATE or _DAHL_RATE[key][0] is not signals:
        rate = min(
            DAHL_RATES,
            key=lambda a: fit(DahlFriction(1, rate=a), signals, residual, train).rms_after,
        )
        _DAHL_RATE[key] = (signals, rate)
    return DahlFriction(1, rate=_DAHL_RATE[key][1])


#: Candidate name -> factory (given the training samples, since Dahl picks its rate there).
CANDIDATES: dict[str, Factory] = {
    "coulomb": lambda s, r, m: CoulombFriction(1, eps=EPS),
    "viscous": lambda s, r, m: ViscousFriction(1),
    "stribeck": lambda s, r, m: StribeckFriction(1, eps=EPS, max_stribeck_velocity=2.0),
    "dahl": _dahl,
    "capstan": lambda s, r, m: CableCapstanFriction(1, 1, eps=R_IN * EPS, max_mu=5.0),
    "capstan_pitch": lambda s, r, m: WrapCapstan("input", True, eps=R_IN * EPS),
    "capstan_load": lambda s, r, m: WrapCapstan("output", False, eps=R_IN * EPS),
    "capstan_load_pitch": lambda s, r, m: WrapCapstan("output", True, eps=R_IN * EPS),
    "sensor": lambda s, r, m: SensorBiasScale(1, 1, shared=True),
}


# --------------------------------------------------------------------------- splits and scores
@dataclass(frozen=True)
class Fold:
    """One train/held-out split of the runs.

    Attributes:
        family: ``"torque"``, ``"frequency"``, ``"yaw"`` (files held out) or ``"pitch"``.
        held_out: What is held out, e.g. ``"80%"`` or ``"pitch 30 deg"``.
        test: Run indices held out.
    """

    family: str
    held_out: str
    test: tuple[int, ...]


#: What each fold family holds out, one level at a time: the level of a run.
FOLD_KEYS: dict[str, Callable[[Run], float]] = {
    "torque": lambda r: r.torque_pct,
    "frequency": lambda r: r.freq,
    "yaw": lambda r: r.yaw,
    "pitch": lambda r: round(float(np.degrees(r.pitch))),
}
#: Each family's levels in words.
FOLD_NAMES = {
    "torque": "torque level",
    "frequency": "frequency",
    "yaw": "yaw stop",
    "pitch": "pitch",
}
#: Unit of each family's levels, as the fold names show them.
FOLD_UNITS = {"torque": "%", "frequency": " Hz", "yaw": " rad", "pitch": " deg"}


def make_folds(runs: Sequence[Run]) -> list[Fold]:
    """Leave-one-level-out folds: torque level, frequency, yaw stop (files) and pitch."""
    folds = []
    for family, key in FOLD_KEYS.items():
        for value in sorted({key(r) for r in runs}):
            test = tuple(i for i, r in enumerate(runs) if key(r) == value)
            folds.append(Fold(family, f"{family} {value:g}{FOLD_UNITS[family]}", test))
    return folds


def too_few_levels(runs: Sequence[Run]) -> list[str]:
    """What the runs lack for the folds and the per-pitch fits, in words (empty: nothing).

    Every family of folds needs 2 levels or more (a fold trains on the others), and every
    pitch 2 files or more (its parameters are bootstrapped over its files).
    """
    single = []
    for family, key in FOLD_KEYS.items():
        levels = sorted({key(r) for r in runs})
        if len(levels) == 1:
            single.append(f"{FOLD_NAMES[family]} ({levels[0]:g}{FOLD_UNITS[family]})")
    lone = sorted(f for f in {r.folder for r in runs} if sum(r.folder == f for r in runs) < 2)
    problems = []
    if single:
        problems.append(
            f"one level only of: {', '.join(single)}; each fold leaves one level out and "
            "trains on the others, so at least 2 levels of each are needed"
        )
    if lone:
        problems.append(
            f"one file only in: {', '.join(lone)}; each pitch's parameters are bootstrapped "
            "over its files, so at least 2 files a pitch are needed"
        )
    return problems


@dataclass
class FoldData:
    """A fold's signals (ratio fitted on its training runs), residual and masks."""

    fold: Fold
    ratio: float
    signals: TransmissionSignals
    residual: FloatArray
    train: NDArray[np.bool_]
    test: NDArray[np.bool_]


def prepare_fold(runs: Sequence[Run], fold: Fold) -> FoldData:
    """Fit the nominal ratio on the fold's training runs and build its signals."""
    train_runs = [r for i, r in enumerate(runs) if i not in fold.test]
    ratio = fit_ratio(train_runs)
    signals, residual = build_signals(runs, ratio)
    test = np.isin(signals.run, fold.test)
    return FoldData(fold, ratio, signals, residual, ~test, test)


def build_model(names: Sequence[str], data: FoldData) -> CandidateEffect:
    """The candidates ``names`` (one, or their sum), built on the fold's training samples."""
    terms = [CANDIDATES[n](data.signals, data.residual, data.train) for n in names]
    return terms[0] if len(terms) == 1 else SumOfTerms(terms)


def held_out_score(names: Sequence[str], data: FoldData) -> tuple[float, FitResult]:
    """Fit ``names`` on the fold's training runs; explained variance on its held-out runs."""
    result = fit(build_model(names, data), data.signals, data.residual, data.train)
    score = result.explained_variance(data.signals, data.residual, data.test)
    return float(score), result


def is_physical(result: FitResult) -> bool:
    """Whether no fitted parameter of a kind its term declares nonnegative is below zero."""
    model = result.effect
    terms = model.terms if isinstance(model, SumOfTerms) else (model,)
    parts = model.split(result.parameters) if isinstance(model, SumOfTerms) else [result.parameters]
    for term, theta in zip(terms, parts, strict=True):
        for name, value in zip(term.parameter_names, theta, strict=True):
            if parameter_kind(name) in term.nonnegative and value < -1e-9:
                return False
    return True


def score_models(
    models: Sequence[tuple[str, ...]], folds: Sequence[FoldData]
) -> tuple[dict[tuple[str, ...], list[float]], dict[tuple[str, ...], bool]]:
    """Held-out explained variance of every model on every fold, ``{model: [per fold]}``.

    Returns:
        The scores and, per model, whether its fits were physical on every fold
        (:func:`is_physical`).
    """
    scores: dict[tuple[str, ...], list[float]] = {}
    physical: dict[tuple[str, ...], bool] = {}
    for m in models:
        pairs = [held_out_score(m, f) for f in folds]
        scores[m] = [p[0] for p in pairs]
        physical[m] = all(is_physical(p[1]) for p in pairs)
    return scores, physical


def forward_selection(
    folds: Sequence[FoldData], candidates: Sequence[str], rounds: int = 3, min_gain: float = 0.01
) -> list[dict[str, Any]]:
    """Greedy selection on the held-out files: add the term that raises the mean score most.

    Only models whose fits are physical on every fold (:func:`is_physical`: no negative
    friction level) may be chosen. Stops when the best addition raises the mean held-out
    explained variance by less than ``min_gain`` or fails to raise it on every fold.

    Returns:
        One entry per round: the scores of every tried model and the one chosen (or None).
    """
    chosen: tuple[str, ...] = ()
    base = [0.0] * len(folds)
    history = []
    for _ in range(rounds):
        tried = [chosen + (c,) for c in candidates if c not in chosen]
        if not tried:
            break
        scores, physical = score_models(tried, folds)
        allowed = [m for m in tried if physical[m]] or tried
        best = max(allowed, key=lambda m: float(np.mean(scores[m])))
        gain = np.asarray(scores[best]) - np.asarray(base)
        accept = bool(gain.mean() >= min_gain and np.all(gain > 0))
        history.append(
            {
                "scores": {"+".join(m): [round(v, 4) for v in s] for m, s in scores.items()},
                "unphysical": ["+".join(m) for m in tried if not physical[m]],
                "best": "+".join(best),
                "gain": round(float(gain.mean()), 4),
                "accepted": accept and physical[best],
            }
        )
        if not history[-1]["accepted"]:
            break
        chosen, base = best, scores[best]
    return history


#: Terms predicting the loss from the motion and the load only: the selection's pool. The
#: wrap's pitch dependence (``capstan_load_pitch``) is not in it: with every pitch in the
#: training files it cannot be judged there; it is judged on the withheld pitch instead.
PHYSICAL = ("coulomb", "viscous", "stribeck", "dahl", "capstan_load")
#: Terms whose regressor is the measured input torque, which is itself in the residual
#: (``r = tau_in / k + tau_out`` with a load held constant in every file): scored and shown,
#: not selected (see the module's README text: they "explain" the loss by restating it).
INPUT_TORQUE_TERMS = ("capstan", "capstan_pitch", "sensor")


# --------------------------------------------------------------------------- parameters
def bootstrap_model(
    names: Sequence[str], runs: Sequence[Run], n_boot: int, seed: int
) -> dict[str, Any]:
    """Fit ``names`` on all runs and bootstrap the parameters over whole files.

    Returns:
        Fitted parameters, their bootstrap mean and standard deviation, by name.
    """
    everything = Fold("all", "nothing", ())
    data = prepare_fold(runs, everything)
    model = build_model(names, data)
    result = fit(model, data.signals, data.residual)
    spread = bootstrap(model, data.signals, data.residual, n_boot=n_boot, seed=seed)
    out: dict[str, Any] = {"ratio": data.ratio, "train_reduction": result.reduction}
    for i, p in enumerate(model.parameter_names):
        out[p] = {"value": float(result.parameters[i]), "std": float(spread.std[i])}
    if isinstance(model, SumOfTerms):
        for term in model.terms:
            if isinstance(term, DahlFriction):
                out["dahl_rate"] = term.rate
    elif isinstance(model, DahlFriction):
        out["dahl_rate"] = model.rate
    return out


def per_pitch_exponent(
    names: Sequence[str], runs: Sequence[Run], n_boot: int, seed: int
) -> dict[str, dict[str, float]]:
    """The capstan exponent ``mu Theta`` fitted on each pitch's files alone (descriptive)."""
    out = {}
    for pitch in sorted({r.pitch for r in runs}):
        subset = [r for r in runs if r.pitch == pitch]
        fitted = bootstrap_model(names, subset, n_boot, seed)
        key = next(k for k in fitted if k.endswith("mu"))
        out[f"{np.degrees(pitch):.0f} deg"] = fitted[key]
    return out


# --------------------------------------------------------------------------- plots
def plot_scores(singles: dict[str, dict[str, float]], chosen: Sequence[str], path: Path) -> None:
    """Bar chart of held-out explained variance per candidate, files and pitch held out."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(singles)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(10, 4.2))
    for shift, key, label in ((-0.2, "files", "files held out"), (0.2, "pitch", "pitch held out")):
        ax.bar(x + shift, [singles[n][key] for n in names], 0.4, label=label)
    ax.set_xticks(x, [n.replace("+", "+\n") for n in names], fontsize=8, rotation=25)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylabel("held-out explained variance [-]")
    ax.set_ylim(min(-0.1, min(v["files"] for v in singles.values())), 1.0)
    hatched = [i for i, n in enumerate(names) if set(n.split("+")) & set(INPUT_TORQUE_TERMS)]
    for i in hatched:
        ax.axvspan(i - 0.45, i + 0.45, color="0.9", zorder=-1)
    ax.set_title(
        "mean over folds; grey: regressor is the measured input torque; selected: "
        + " + ".join(chosen),
        fontsize=9,
    )
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def plot_loops(runs: Sequence[Run], chosen: Sequence[str], path: Path) -> None:
    """Per pitch, held out: output vs input torque and the lost torque vs jaw angle.

    The model ``chosen`` is fitted on the two other pitches. Its terms read only the motion
    and the load, so it predicts the input torque the held-out pitch needs at the jaw,
    ``load + r_pred`` (dashed, a darker shade of the load's colour), against the measured
    ``tau_in / k`` (solid). The prediction is drawn from the second cycle of the sine on: a
    state of the model (Dahl's) starts from zero and takes the first cycle to settle.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgb

    pitches = sorted({r.pitch for r in runs}, reverse=True)
    fig, axes = plt.subplots(2, len(pitches), figsize=(4.2 * len(pitches), 7.5), squeeze=False)
    for col, pitch in enumerate(pitches):
        fold = Fold(
            "pitch",
            f"pitch {np.degrees(pitch):.0f} deg",
            tuple(i for i, r in enumerate(runs) if r.pitch == pitch),
        )
        data = prepare_fold(runs, fold)
        result = fit(build_model(chosen, data), data.signals, data.residual, data.train)
        for i, r in enumerate(runs):
            if r.pitch != pitch or r.freq != min(x.freq for x in runs) or r.yaw != 0.0:
                continue
            if r.torque_pct not in (20.0, 80.0):
                continue
            mask = data.signals.run == i
            tau_ms = r.tau_in / data.ratio
            pred = result.predict(data.signals.take(mask))[:, 0]
            lost = data.residual[mask, 0]
            colour = "C0" if r.torque_pct == 20.0 else "C3"
            dark = tuple(PREDICTION_SHADE * c for c in to_rgb(colour))
            settled = r.t >= r.t[0] + 1.0 / r.freq  # after the first cycle
            ax = axes[0, col]
            ax.plot(tau_ms, -r.tau_out, color=colour, lw=0.8, label=f"measured {r.torque_pct:g}%")
            ax.plot(
                (-r.tau_out + pred)[settled],
                -r.tau_out[settled],
                "--",
                color=dark,
                lw=0.8,
                label=f"predicted {r.torque_pct:g}%",
            )
            ax = axes[1, col]
            ax.plot(r.q_out, lost, color=colour, lw=0.8, label=f"measured {r.torque_pct:g}%")
            ax.plot(
                r.q_out[settled],
                pred[settled],
                "--",
                color=dark,
                lw=0.8,
                label=f"predicted {r.torque_pct:g}%",
            )
        axes[0, col].set_title(f"pitch {np.degrees(pitch):.0f} deg (held out)", fontsize=10)
        axes[0, col].set_xlabel("input torque at the jaw, tau_in / k [N m]")
        axes[0, col].set_ylabel("load (output) torque -tau_out [N m]")
        axes[1, col].set_xlabel("jaw angle q [rad]")
        axes[1, col].set_ylabel("lost torque r [N m]")
        axes[0, col].legend(fontsize=7, title="dashed: " + " + ".join(chosen), title_fontsize=7)
    fig.suptitle(
        "0.3 Hz, yaw 0; prediction (dashed, darker) fitted on the two other pitches, "
        "drawn after the first cycle",
        fontsize=10,
    )
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------- main
def analyse(runs: Sequence[Run], n_boot: int = 30, seed: int = 0) -> dict[str, Any]:
    """The whole check: scores per fold, forward selection, parameters with spread.

    Args:
        runs: All runs (the three pitches).
        n_boot: Bootstrap refits over files.
        seed: Seed of the bootstrap draws.

    Returns:
        The results (what ``results.json`` holds).
    """
    folds = [prepare_fold(runs, f) for f in make_folds(runs)]
    files = [f for f in folds if f.fold.family != "pitch"]
    pitch = [f for f in folds if f.fold.family == "pitch"]
    selection = forward_selection(files, PHYSICAL)
    chosen = tuple(h["best"] for h in selection if h["accepted"])
    chosen = tuple(chosen[-1].split("+")) if chosen else ("coulomb",)
    wrap_variant = tuple("capstan_load_pitch" if n == "capstan_load" else n for n in chosen)
    models = [(n,) for n in CANDIDATES] + [chosen[: i + 1] for i in range(1, len(chosen))]
    if wrap_variant != chosen:
        models.append(wrap_variant)
    scores_files, _ = score_models(models, files)
    scores_pitch, _ = score_models(models, pitch)
    table = {
        "+".join(m): {
            "files": float(np.mean(scores_files[m])),
            "files_min": float(np.min(scores_files[m])),
            "pitch": float(np.mean(scores_pitch[m])),
            "pitch_per_fold": dict(
                zip([f.fold.held_out for f in pitch], map(float, scores_pitch[m]), strict=True)
            ),
        }
        for m in models
    }
    capstan_names = [n for n in chosen if n.startswith("capstan")]
    return {
        "n_files": len(runs),
        "folds": [{"family": f.fold.family, "held_out": f.fold.held_out} for f in folds],
        "ratio_per_fold": {f.fold.held_out: f.ratio for f in folds},
        "selection_on_files": selection,
        "chosen": list(chosen),
        "wrap_variant": list(wrap_variant),
        "held_out": table,
        "parameters": bootstrap_model(chosen, runs, n_boot, seed),
        "parameters_wrap_variant": bootstrap_model(wrap_variant, runs, n_boot, seed),
        "exponent_per_pitch": (
            per_pitch_exponent(chosen, runs, max(n_boot // 2, 2), seed) if capstan_names else {}
        ),
    }


def print_report(results: dict[str, Any]) -> None:
    """Print the held-out table, the selection and the answer."""
    head = ("candidate", "files held out", "(worst fold)", "pitch held out")
    print(f"{head[0]:28s} {head[1]:>15s} {head[2]:>12s} {head[3]:>15s}")
    for name, row in results["held_out"].items():
        mark = " *" if set(name.split("+")) & set(INPUT_TORQUE_TERMS) else ""
        print(
            f"{name + mark:28s} {row['files']:15.3f} {row['files_min']:12.3f} {row['pitch']:15.3f}"
        )
    print("* regressor is the measured input torque, which is in the residual: not selected")
    print("forward selection on files held out (mean held-out explained variance):")
    for i, h in enumerate(results["selection_on_files"], 1):
        verdict = "kept" if h["accepted"] else "not kept"
        score = np.mean(h["scores"][h["best"]])
        print(f"  round {i}: {h['best']} -> {score:.3f} (gain {h['gain']:+.3f}, {verdict})")
        for name in h["unphysical"]:
            value = np.mean(h["scores"][name])
            print(f"    ({name}: {value:.3f}, skipped: a friction level fitted below zero)")
    chosen = "+".join(results["chosen"])
    wrap = "+".join(results["wrap_variant"])
    print(f"on the withheld pitch ({chosen} vs wrap Theta_0 + |pitch|: {wrap}):")
    for fold, value in results["held_out"][chosen]["pitch_per_fold"].items():
        other = results["held_out"].get(wrap, {}).get("pitch_per_fold", {}).get(fold, np.nan)
        print(f"  {fold}: {value:.3f} vs {other:.3f}")
    print(f"parameters (all {results['n_files']} files; +- bootstrap std over files):")
    for key, value in results["parameters"].items():
        if isinstance(value, dict):
            print(f"  {key}: {value['value']:.4g} +- {value['std']:.2g}")
        else:
            print(f"  {key}: {value:.4g}")
    theta0 = results["parameters_wrap_variant"].get("wrap_capstan:theta0")
    if theta0 is not None:
        print(f"  wrap variant Theta_0: {theta0['value']:.3g} +- {theta0['std']:.2g} rad")
    for pitch, value in results["exponent_per_pitch"].items():
        mean, std = value["value"], value["std"]
        print(f"  mu Theta fitted on pitch {pitch} alone: {mean:.3f} +- {std:.3f}")


def write_outputs(results: dict[str, Any], runs: Sequence[Run], out: Path) -> None:
    """Write the plots, then ``results.json`` (last, atomically) into ``out``.

    A previous run's ``results.json`` is removed first: a folder holding ``results.json``
    holds one whole run, the plots written just before it included.
    """
    (out / "results.json").unlink(missing_ok=True)
    plot_scores(dict(results["held_out"]), results["chosen"], out / "held_out.png")
    plot_loops(runs, results["chosen"], out / "loops_per_pitch.png")
    write_json_atomic(out / "results.json", results)


def parse_args(argv: Sequence[str] | None) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """The command line, its values checked (an error exits with 2 before any work)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--data", default=None, help=f"data folder (default: ${DATA_ENV} or {DEFAULT_DATA})"
    )
    parser.add_argument("--out", default="runs/mis-tool", help="output folder for plots and JSON")
    parser.add_argument("--seed", type=int, default=0, help="seed of the bootstrap over files")
    parser.add_argument("--n-boot", type=int, default=30, help="bootstrap refits (default 30)")
    args = parser.parse_args(argv)
    if args.data == "":
        parser.error("--data: empty; expected the data folder (or leave --data out)")
    if args.seed < 0:
        parser.error(f"--seed: expected a seed >= 0, got {args.seed}")
    if args.n_boot < 2:
        parser.error(f"--n-boot: expected at least 2 refits, got {args.n_boot}")
    try:
        output_folder(Path(args.out))  # up front: a path under a file is refused before work
    except InputError as exc:
        parser.error(str(exc))
    return parser, args


def main(argv: Sequence[str] | None = None) -> int:
    """Command line entry point; returns the exit status (2: bad data, 143: SIGTERM)."""
    parser, args = parse_args(argv)
    # SIGTERM unwinds: no temporary file left behind
    return run_script(parser.prog, lambda: run(args))


def run(args: argparse.Namespace) -> int:
    """Read the data, analyse them, print the report and write the outputs; the exit status."""
    root = data_folder(args.data)
    layout = f"{', '.join(PITCH_DEG)} with *.TXT or *.TXT.gz files"
    files = data_files(root)
    if not files:
        print(
            f"no data under {root}: expected the mis-tool folders {layout} there (set --data "
            f"or ${DATA_ENV}); nothing done",
            file=sys.stderr,
        )
        return 2
    missing = missing_pitches(files)
    if missing:
        print(
            f"no data in {', '.join(str(root / f) for f in missing)}: every pitch is held out "
            f"once, so all three folders ({layout}) are needed; nothing done",
            file=sys.stderr,
        )
        return 2
    start = time.perf_counter()
    try:
        runs = load_runs(root)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    problems = too_few_levels(runs)
    if problems:
        print(f"error: data under {root}: {'; '.join(problems)}; nothing done", file=sys.stderr)
        return 2
    results = analyse(runs, n_boot=args.n_boot, seed=args.seed)
    results["data"] = str(root)
    results["seconds"] = round(time.perf_counter() - start, 1)
    print_report(results)
    out = Path(args.out)
    write_outputs(results, runs, out)
    print(f"wrote {out}/held_out.png, loops_per_pitch.png, results.json in {results['seconds']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
