"""Which unmodelled effect explains the gap: forward selection scored on held-out runs.

The residuals of the logs come in channel groups (:data:`msarm.diagnose.builder.GROUPS`): the
joint-torque residual [N m], the drive residual (load cell minus command) [N] and the cable
length error [m]. Each candidate predicts the columns of one or more groups. So that the groups
weigh alike whatever their units, each group is divided by its training residual's spread
(the root of its summed column mean squares) before fitting.

:func:`diagnose` starts from the nominal model (no term: every residual is unexplained) and,
step by step, tries each remaining candidate together with the terms already selected:

- **Joint fit.** All linear terms (the selected ones and the candidate, if linear) are fitted
  together by one least-squares problem on their stacked, group-normalised design matrices.
  Nonlinear terms are then fitted one after another (in the order they were selected, the
  candidate last) by IPOPT, each on the residual left by the linear block and the nonlinear
  terms before it (one pass). Fits use the training runs only.
- **Score.** The held-out explained share of the residual: per group, ``1 - sum (r -
  pred)^2 / sum r^2`` over the held-out samples and the group's columns (energy about zero,
  so that a constant offset such as a load-cell bias counts as gap), then the mean over the
  groups. A term earns its place by predicting runs it was not fitted on.
- **Rule.** A candidate's gain is the rise of the explained share averaged over the groups
  it acts on (so that a term is not diluted by groups it cannot touch). The candidate with the
  largest gain is added when that gain exceeds ``threshold`` (:data:`DEFAULT_THRESHOLD` =
  0.02); otherwise the selection stops. A null plant (only
  sensor noise) leaves nothing a term can predict on held-out runs, so nothing is selected.

**Confidence.** The final model is refitted on ``n_boot`` bootstrap draws of the training runs
(the parameters' standard deviation comes from the same draws). An effect's confidence is the
share of (draw, held-out run) pairs in which leaving that effect out of the refitted model
lowers the run's explained share on the effect's groups by more than the threshold: 1 when
every resample of the training runs and every held-out run needs it, near 0 for a term that
only helps by chance.

The result, a :class:`Diagnosis`, names the selected effects in order with their parameters,
bootstrap standard deviations and confidence, the held-out explained variance after each step,
and the gap per channel: the held-out RMSE of the residual before and after subtracting the
selected terms' prediction, and the share it shrank, group by group and effect by effect (the
waterfall of :mod:`msarm.diagnose.report`).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.builder import GROUP_UNITS, GROUPS, channels_from_logs
from msarm.diagnose.cable_effects import (
    CableBacklash,
    CableElasticity,
    CommandDelay,
    DriveCogging,
    WinchFriction,
)
from msarm.diagnose.effects import (
    NUMPY_OPS,
    CableCapstanFriction,
    CandidateEffect,
    CoulombFriction,
    DahlFriction,
    InertiaError,
    MotorCogging,
    NumpyOps,
    Ops,
    SensorBiasScale,
    StribeckFriction,
    TensionDelay,
    ViscousFriction,
)
from msarm.diagnose.fitting import _NonlinearProblem, _solve_linear
from msarm.diagnose.residuals import DiagnosisWarning, ResidualSpec, replay_runs
from msarm.diagnose.signals import Signals
from msarm.errors import InputError
from msarm.model import RobotModel

__all__ = [
    "CONFOUNDING_LIMIT",
    "DEFAULT_CANDIDATES",
    "DEFAULT_COGGING_PERIODS",
    "DEFAULT_THRESHOLD",
    "MAX_FIT_SAMPLES",
    "Diagnosis",
    "DiagnosisData",
    "SelectedEffect",
    "available_candidates",
    "default_candidates",
    "diagnose",
    "load_data",
    "select_effects",
]

FloatArray = NDArray[np.float64]

#: A candidate is added when it raises the held-out explained variance by more than this [-].
DEFAULT_THRESHOLD = 0.02
#: Largest canonical correlation between a candidate's regressor and those of the terms
#: already selected (training runs) for the candidate to be tried: above it, the data cannot
#: tell the two apart (e.g. a load-cell scale error, whose regressor is the measured cable
#: torque, against the links' mass error, whose regressor spans the inverse dynamics that
#: torque balances), and their joint fit would trade one for the other [-].
CONFOUNDING_LIMIT = 0.99
#: The selection fits and scores on at most this many training (and held-out) samples,
#: evenly thinned: 20 runs of 20 s at 250 Hz are 100,000 samples, and the residuals' content
#: lies far below the thinned rate (12.5 Hz or more).
MAX_FIT_SAMPLES = 20_000
#: Of the fitting samples, every this many enter the confounding test.
_CONFOUNDING_STRIDE = 8
#: Cogging periods per motor revolution of the default cogging candidates (motor datasheet).
DEFAULT_COGGING_PERIODS = 24
#: The candidates tried by default, by name (see :func:`available_candidates`).
DEFAULT_CANDIDATES = (
    "coulomb",
    "viscous",
    "stribeck",
    "dahl",
    "capstan",
    "sensor",
    "inertia",
    "winch_friction",
    "motor_cogging",
    "command_delay",
    "elasticity",
    "backlash",
)


def available_candidates(
    model: RobotModel, spec: ResidualSpec | None = None
) -> dict[str, CandidateEffect]:
    """Every built-in candidate, configured for ``model``, by name.

    Joint-torque terms: Coulomb and viscous joint friction, Stribeck friction (nonlinear),
    Dahl friction (pre-sliding hysteresis, 100 1/rad),
    capstan sheath friction (one shared ``mu``, nonlinear), the links' mass error (base set of
    masses and first moments), and two terms that act on the joints through the load cells'
    reading: ``cogging`` (a cogging force behind the load cell) and ``delay`` (tensions logged
    late against the encoders, first order). Joint and drive: ``sensor`` (load-cell bias and
    scale shared by all cables). Drive terms: ``winch_friction``, ``motor_cogging``
    (:data:`DEFAULT_COGGING_PERIODS` periods per revolution) and ``command_delay``. Cable
    length: ``elasticity`` and ``backlash``. Drive terms use ``spec.drum_radius`` and
    ``spec.drive_gain``.

    Args:
        model: The nominal robot model.
        spec: Residual settings (drum radius, drive gain).
    """
    spec = spec or ResidualSpec()
    n, m = model.n_joints, model.n_cables
    effects: list[CandidateEffect] = [
        CoulombFriction(n_joints=n),
        ViscousFriction(n_joints=n),
        StribeckFriction(n_joints=n),
        DahlFriction(n_joints=n),
        CableCapstanFriction(n_cables=m, n_joints=n),
        SensorBiasScale(n_cables=m, n_joints=n, shared=True, drive=True),
        InertiaError(model, subset="mass"),
        WinchFriction(spec.drum_radius, spec.drive_gain, n_cables=m),
        DriveCogging(DEFAULT_COGGING_PERIODS, spec.drum_radius, spec.drive_gain, n_cables=m),
        CommandDelay(n_cables=m),
        CableElasticity(n_cables=m),
        CableBacklash(spec.drum_radius, n_cables=m),
        MotorCogging(DEFAULT_COGGING_PERIODS, spec.drum_radius, n_cables=m, n_joints=n),
        TensionDelay(n_cables=m, n_joints=n),
    ]
    return {e.name: e for e in effects}


def default_candidates(
    model: RobotModel, spec: ResidualSpec | None = None
) -> dict[str, CandidateEffect]:
    """The candidates tried by default (:data:`DEFAULT_CANDIDATES`), by name.

    Args:
        model: The nominal robot model.
        spec: Residual settings (drum radius, drive gain).
    """
    every = available_candidates(model, spec)
    return {name: every[name] for name in DEFAULT_CANDIDATES}


class _Layout:
    """Where each group's columns sit in the stacked residual, and its normalising spread."""

    def __init__(self, groups: dict[str, FloatArray]) -> None:
        self.groups = tuple(g for g in GROUPS if g in groups)
        self.slices: dict[str, slice] = {}
        self.spread: dict[str, float] = {}
        start = 0
        for g in self.groups:
            r = groups[g]
            self.slices[g] = slice(start, start + r.shape[1])
            start += r.shape[1]
            spread = float(np.sqrt(np.sum(r**2) / max(len(r), 1)))
            self.spread[g] = spread if spread > 0 else 1.0
        self.width = start

    def stack(self, groups: dict[str, FloatArray]) -> FloatArray:
        """Group residuals ``{g: (T, k_g)}`` -> the normalised stack ``(T, W)``."""
        return np.concatenate([groups[g] / self.spread[g] for g in self.groups], axis=1)

    def unstack(self, stacked: FloatArray) -> dict[str, FloatArray]:
        """The normalised stack ``(T, W)`` -> group residuals in their units."""
        return {g: stacked[:, self.slices[g]] * self.spread[g] for g in self.groups}


class _Embedded(CandidateEffect):
    """A term's prediction placed in its groups' columns of the normalised stack."""

    def __init__(self, term: CandidateEffect, layout: _Layout) -> None:
        self.term, self.layout = term, layout
        self.name = term.name  # type: ignore[misc]
        self.description = term.description  # type: ignore[misc]
        self.linear = term.linear  # type: ignore[misc]
        self.parameter_names = term.parameter_names
        self.channels = tuple(range(layout.width))
        self.groups = layout.groups

    def width(self, signals: Signals) -> int:  # noqa: D102
        return self.layout.width

    def check(self, signals: Signals) -> None:  # noqa: D102
        self.term.check(signals)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        inner = self.term.design(signals)
        out = np.zeros((inner.shape[0], self.layout.width, inner.shape[2]))
        start = 0
        for g in self.term.groups:
            cols = self.layout.slices[g]
            size = cols.stop - cols.start
            out[:, cols, :] = inner[:, start : start + size, :] / self.layout.spread[g]
            start += size
        return out

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:  # noqa: D102
        if self.linear and isinstance(ops, NumpyOps):
            return np.einsum("tnp,p->tn", self.design(signals), np.asarray(theta, dtype=float))
        inner = self.term.torque(signals, theta, ops)
        T = signals.n_samples
        blocks, start = [], 0
        placed = {}
        for g in self.term.groups:
            cols = self.layout.slices[g]
            size = cols.stop - cols.start
            placed[g] = inner[:, start : start + size] * (1.0 / self.layout.spread[g])
            start += size
        for g in self.layout.groups:
            if g in placed:
                blocks.append(placed[g])
            else:
                cols = self.layout.slices[g]
                blocks.append(ops.const(np.zeros((T, cols.stop - cols.start))))
        return ops.hcat(blocks)

    def initial_guess(  # noqa: D102
        self, signals: Signals, residual: FloatArray | None = None
    ) -> FloatArray:
        if residual is None:
            return self.term.initial_guess(signals)
        parts = self.layout.unstack(residual)
        own = np.concatenate([parts[g] for g in self.term.groups], axis=1)
        return self.term.initial_guess(signals, own)

    def bounds(self) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        return self.term.bounds()

    def own_columns(self) -> NDArray[np.intp]:
        """Columns of the stack the term's groups occupy, in the term's group order."""
        return np.concatenate(
            [np.arange(self.layout.width)[self.layout.slices[g]] for g in self.term.groups]
        )


class _OwnColumns(CandidateEffect):
    """An embedded nonlinear term restricted to its own columns (smaller IPOPT problems).

    The columns it does not touch add a constant to the fit's objective, so the optimum on
    its own columns is the optimum on the whole stack.
    """

    def __init__(self, embedded: _Embedded) -> None:
        self.embedded = embedded
        self.name = embedded.name  # type: ignore[misc]
        self.linear = False  # type: ignore[misc]
        self.parameter_names = embedded.parameter_names
        self.columns = embedded.own_columns()
        self.channels = tuple(range(len(self.columns)))
        layout = embedded.layout
        self.factors = [1.0 / layout.spread[g] for g in embedded.term.groups]
        self.sizes = [layout.slices[g].stop - layout.slices[g].start for g in embedded.term.groups]

    def width(self, signals: Signals) -> int:  # noqa: D102
        return len(self.columns)

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:  # noqa: D102
        inner = self.embedded.term.torque(signals, theta, ops)
        blocks, start = [], 0
        for factor, size in zip(self.factors, self.sizes, strict=True):
            blocks.append(inner[:, start : start + size] * factor)
            start += size
        return ops.hcat(blocks)

    def initial_guess(  # noqa: D102
        self, signals: Signals, residual: FloatArray | None = None
    ) -> FloatArray:
        if residual is None:
            return self.embedded.term.initial_guess(signals)
        scale = np.repeat(1.0 / np.asarray(self.factors), self.sizes)
        return self.embedded.term.initial_guess(signals, residual * scale)

    def bounds(self) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        return self.embedded.term.bounds()


class _Stacked(CandidateEffect):
    """Several linear terms as one: their design matrices side by side."""

    name = "stacked"
    description = "sum of linear terms, fitted together"
    linear = True

    def __init__(self, terms: Sequence[CandidateEffect]) -> None:
        self.terms = tuple(terms)
        self.parameter_names = tuple(f"{t.name}:{p}" for t in self.terms for p in t.parameter_names)
        self.channels = tuple(sorted({c for t in self.terms for c in t.channels}))
        self.sizes = [t.n_parameters for t in self.terms]

    def width(self, signals: Signals) -> int:  # noqa: D102
        return self.terms[0].width(signals)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        return np.concatenate([t.design(signals) for t in self.terms], axis=2)

    def check(self, signals: Signals) -> None:  # noqa: D102
        for t in self.terms:
            t.check(signals)

    def split(self, theta: FloatArray) -> list[FloatArray]:
        """The parameters of each term, in order."""
        return np.split(np.asarray(theta, dtype=float), np.cumsum(self.sizes)[:-1])


class _Sampled:
    """The samples the selection fits and scores on, with the linear terms' designs cached.

    Long logs are thinned evenly to at most ``max_samples`` training and held-out samples
    (designs are computed on the whole runs first, so terms with memory, such as the Dahl
    state or the delay taps, see every sample; nonlinear terms are evaluated on the thinned
    samples and must be per-sample).
    """

    def __init__(self, data: DiagnosisData, max_samples: int) -> None:
        self.full = {"train": data.train, "hold": data.hold}
        self.rows = {
            split: _even_rows(sig.n_samples, max_samples) for split, sig in self.full.items()
        }
        self.signals = {split: sig.take(self.rows[split]) for split, sig in self.full.items()}
        self.residual = {
            "train": data.r_train[self.rows["train"]],
            "hold": data.r_hold[self.rows["hold"]],
        }
        self._designs: dict[tuple[int, str], FloatArray] = {}
        self._problems: dict[int, _NonlinearProblem] = {}

    def fit_nonlinear(
        self,
        term: _Embedded,
        residual: FloatArray,
        initial: FloatArray | None = None,
        weights: FloatArray | None = None,
    ) -> tuple[FloatArray, str]:
        """Fit a nonlinear term to the training ``residual`` (stack columns) by IPOPT.

        The problem (on the term's own columns) is built once per term and reused.
        """
        if id(term) not in self._problems:
            own = _OwnColumns(term)
            self._problems[id(term)] = _NonlinearProblem(
                own, self.signals["train"], self.residual["train"][:, own.columns]
            )
        problem = self._problems[id(term)]
        columns = problem.effect.columns
        theta, _, message = problem.solve(initial, weights, residual[:, columns])
        return theta, message

    def design(self, term: CandidateEffect, split: str) -> FloatArray:
        key = (id(term), split)
        if key not in self._designs:
            self._designs[key] = term.design(self.full[split])[self.rows[split]]
        return self._designs[key]

    def predict(self, term: CandidateEffect, theta: FloatArray, split: str) -> FloatArray:
        if term.linear:
            return np.einsum("tnp,p->tn", self.design(term, split), theta)
        return np.asarray(term.torque(self.signals[split], theta), dtype=float)


def _even_rows(n: int, limit: int) -> NDArray[np.intp]:
    if n <= limit:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, limit).round().astype(np.intp))


@dataclass(frozen=True)
class _Model:
    """A fitted combination of terms: parameters by term, in the given order."""

    terms: tuple[CandidateEffect, ...]
    parameters: tuple[FloatArray, ...]
    messages: tuple[str, ...]

    def predict(self, sampled: _Sampled, split: str) -> FloatArray:
        out = np.zeros_like(sampled.residual[split])
        for term, theta in zip(self.terms, self.parameters, strict=True):
            out += sampled.predict(term, theta, split)
        return out


def _fit_together(terms: Sequence[CandidateEffect], sampled: _Sampled) -> _Model:
    """Joint fit: linear terms by one stacked least squares, then nonlinear ones in turn."""
    linear = [t for t in terms if t.linear]
    nonlinear = [t for t in terms if not t.linear]
    parameters: dict[int, FloatArray] = {}
    messages: dict[int, str] = {}
    left = sampled.residual["train"]
    if linear:
        design = np.concatenate([sampled.design(t, "train") for t in linear], axis=2)
        theta = _solve_linear(design, left)
        for term, part in zip(linear, _Stacked(linear).split(theta), strict=True):
            parameters[id(term)], messages[id(term)] = part, "least squares (joint)"
        left = left - np.einsum("tnp,p->tn", design, theta)
    for term in nonlinear:
        theta, message = sampled.fit_nonlinear(term, left)
        parameters[id(term)], messages[id(term)] = theta, message
        left = left - sampled.predict(term, theta, "train")
    return _Model(
        terms=tuple(terms),
        parameters=tuple(parameters[id(t)] for t in terms),
        messages=tuple(messages[id(t)] for t in terms),
    )


def _replay_gap(data: DiagnosisData, cumulative: dict[str, FloatArray]) -> dict[str, Any]:
    """Replay the held-out runs' commands with the nominal model, without and with the effects.

    The nominal dynamics start from the logged state every 0.2 s and are driven by the logged
    tension commands (the tension each measured one answers) through ideal cables; "with the
    effects" adds the selected drive terms' prediction to the commands (the tension the drives
    then deliver) and subtracts the selected joint terms' torque. Without commands in the logs
    the measured tensions drive the replay (drive terms then play no part).

    Args:
        data: The diagnosis data.
        cumulative: The selected terms' prediction on the held-out runs, by group, in the
            groups' units.

    Returns:
        ``source`` (``"command"`` or ``"tension"``), the window [s], and before and after:
        the pooled joint RMSE of ``q_replay - q`` [rad] and the mean hand-position error at
        the end of each window [m].
    """
    from msarm.tasks.evaluate import hand_position

    spec = ResidualSpec()
    hold, model = data.hold, data.model
    per_window = max(1, round(spec.replay_window / hold.dt))
    ends = np.zeros(hold.n_samples, dtype=bool)
    for label in np.unique(hold.run):
        index = np.flatnonzero(hold.run == label)
        ends[index[per_window - 1 :: per_window]] = True
    p_log = hand_position(model, hold.q[ends])
    source = "tension" if hold.tension_cmd is None else "command"
    drive = hold.tension if hold.tension_cmd is None else hold.tension_cmd
    lost = cumulative.get("joint")
    delivered = (
        drive + cumulative["drive"] if "drive" in cumulative and source == "command" else drive
    )
    out: dict[str, Any] = {"source": source, "window_s": spec.replay_window}
    for key, tension, extra in (("before", drive, None), ("after", delivered, lost)):
        error = replay_runs(model, hold.q, hold.qd, tension, hold.run, hold.dt, extra, spec)
        p_replay = hand_position(model, hold.q[ends] + error[ends])
        out[f"joint_rmse_{key}"] = _pooled(error)
        out[f"hand_error_end_{key}"] = float(np.mean(np.linalg.norm(p_replay - p_log, axis=1)))
    return out


def _group_scores(
    layout: _Layout, residual: FloatArray, prediction: FloatArray
) -> dict[str, float]:
    """Explained energy of each group, ``1 - sum (r - pred)^2 / sum r^2`` [-].

    About zero, not about the mean: a constant offset (a load-cell bias) is part of the gap.
    """
    out = {}
    for g in layout.groups:
        r = residual[:, layout.slices[g]]
        e = r - prediction[:, layout.slices[g]]
        energy = float(np.sum(r**2))
        out[g] = 1.0 - float(np.sum(e**2)) / energy if energy > 0 else 0.0
    return out


class _Bases:
    """Orthonormal bases of linear terms' training regressors, for the confounding test."""

    def __init__(self, sampled: _Sampled) -> None:
        self.sampled = sampled
        self.cache: dict[int, FloatArray] = {}

    def basis(self, term: CandidateEffect) -> FloatArray:
        if id(term) not in self.cache:
            design = self.sampled.design(term, "train")[::_CONFOUNDING_STRIDE]
            matrix = design.reshape(-1, design.shape[2])
            matrix = matrix / np.maximum(np.linalg.norm(matrix, axis=0), 1e-300)
            u, singular, _ = np.linalg.svd(matrix, full_matrices=False)
            keep = singular > 1e-8 * max(float(singular.max(initial=0.0)), 1e-300)
            self.cache[id(term)] = u[:, keep]
        return self.cache[id(term)]

    def confounder(
        self, candidate: CandidateEffect, chosen: Sequence[CandidateEffect]
    ) -> str | None:
        """Why ``candidate`` cannot be told apart from the chosen terms, or None."""
        linear = [t for t in chosen if t.linear]
        if not candidate.linear or not linear:
            return None
        own = self.basis(candidate)
        if own.shape[1] == 0:
            return None
        together = np.concatenate([self.basis(t) for t in linear], axis=1)
        span, singular, _ = np.linalg.svd(together, full_matrices=False)
        span = span[:, singular > 1e-8 * singular.max(initial=1.0)]
        correlation = float(np.linalg.svd(own.T @ span, compute_uv=False).max(initial=0.0))
        if correlation <= CONFOUNDING_LIMIT:
            return None
        names = ", ".join(t.name for t in linear)
        return (
            f"its regressor lies in the span of {names} (canonical correlation "
            f"{correlation:.4f} > {CONFOUNDING_LIMIT})"
        )


def _own_gain(groups: Sequence[str], before: dict[str, float], after: dict[str, float]) -> float:
    """Gain of the explained share, averaged over the groups a term acts on [-]."""
    return float(np.mean([after[g] - before[g] for g in groups]))


def _score(layout: _Layout, residual: FloatArray, prediction: FloatArray) -> float:
    """The selection score: the mean over groups of their explained variance [-]."""
    return float(np.mean(list(_group_scores(layout, residual, prediction).values())))


def _rmse(values: FloatArray) -> FloatArray:
    return np.sqrt(np.mean(values**2, axis=0))


def _pooled(values: FloatArray) -> float:
    return float(np.sqrt(np.mean(values**2)))


@dataclass(frozen=True)
class SelectedEffect:
    """One selected term of a :class:`Diagnosis`.

    Attributes:
        name: Candidate name (registry name, see :mod:`msarm.diagnose.effects`).
        description: The term's equation.
        groups: The channel groups it acts on (``"joint"``, ``"drive"``, ``"length"``).
        parameter_names: Names of its ``p`` parameters.
        parameters: Fitted parameters (training runs, joint fit of the final model), ``(p,)``.
        std: Bootstrap standard deviation over training runs, ``(p,)``; NaN when not computed
            (fewer than 2 training runs, or ``n_boot < 2``).
        explained_variance: Held-out score (mean over all groups) after adding this term [-].
        gain: Rise of the held-out explained share on its own groups it brought [-].
        confidence: Share of (bootstrap draw, held-out run) pairs that need the term (see the
            module docstring) [-]; NaN when not computed.
        message: Solver status of its fit.
    """

    name: str
    description: str
    groups: tuple[str, ...]
    parameter_names: tuple[str, ...]
    parameters: FloatArray
    std: FloatArray
    explained_variance: float
    gain: float
    confidence: float
    message: str

    def parameter_texts(self, limit: int = 6, equals: str = " = ") -> list[str]:
        """``name = value ± std`` of the first ``limit`` parameters, and a count of the rest."""
        parts = []
        for name, value, std in zip(self.parameter_names, self.parameters, self.std, strict=True):
            text = f"{name}{equals}{value:.4g}"
            if np.isfinite(std):
                text += f" ± {std:.2g}"
            parts.append(text)
        if len(parts) > limit:
            parts = [*parts[:limit], f"... ({len(parts) - limit} more)"]
        return parts

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        return {
            "name": self.name,
            "description": self.description,
            "groups": list(self.groups),
            "parameters": dict(zip(self.parameter_names, map(float, self.parameters), strict=True)),
            "std": {
                k: (None if not np.isfinite(v) else float(v))
                for k, v in zip(self.parameter_names, self.std, strict=True)
            },
            "explained_variance": self.explained_variance,
            "gain": self.gain,
            "confidence": None if not np.isfinite(self.confidence) else self.confidence,
            "message": self.message,
        }


@dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`.

    Attributes:
        selected: The selected effects, in the order they were added.
        explained_variance: Held-out score after each step [-], starting with the nominal
            model's 0.0; length ``len(selected) + 1``.
        step_scores: Per step, the gain (on its own groups) of every candidate tried with the
            terms selected before, by name.
        groups: The channel groups diagnosed, in stack order.
        channel_names: Channel names of each group (joints or cables).
        gap_before: Held-out RMSE per channel of each group, nominal model, in the group's
            unit (:data:`msarm.diagnose.builder.GROUP_UNITS`).
        gap_after: The same after subtracting the selected terms' prediction.
        waterfall: Pooled held-out RMSE of each group after each step (the final model's
            terms added one by one in selection order); ``len(selected) + 1`` entries.
        threshold: The selection threshold [-].
        train_runs: The training logs.
        holdout_runs: The held-out logs.
        n_train: Training samples.
        n_holdout: Held-out samples.
        skipped: Candidates not tried, with the reason (a channel group the logs lack).
        confounded: Candidates left out of a step because the data cannot tell them apart
            from the terms already selected (see :data:`CONFOUNDING_LIMIT`), with the term
            and the canonical correlation.
        replay: The gap as motion on the held-out runs (:func:`_replay_gap`): the nominal
            dynamics driven by the logged commands over 0.2 s windows, without and with the
            selected drive and joint terms; None when not computed.
    """

    selected: tuple[SelectedEffect, ...]
    explained_variance: tuple[float, ...]
    step_scores: tuple[dict[str, float], ...]
    groups: tuple[str, ...]
    channel_names: dict[str, tuple[str, ...]]
    gap_before: dict[str, FloatArray]
    gap_after: dict[str, FloatArray]
    waterfall: tuple[dict[str, float], ...]
    threshold: float
    train_runs: tuple[str, ...]
    holdout_runs: tuple[str, ...]
    n_train: int
    n_holdout: int
    skipped: dict[str, str]
    replay: dict[str, Any] | None = None
    confounded: dict[str, str] = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the selected effects, in order."""
        return tuple(s.name for s in self.selected)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint names, ``(n,)``."""
        return self.channel_names["joint"]

    def shrink(self, group: str = "joint") -> FloatArray:
        """Share of each channel's held-out gap removed, ``1 - after / before`` [-]."""
        before, after = self.gap_before[group], self.gap_after[group]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(before > 0, 1.0 - after / before, 0.0)

    def gap_rows(self, group: str) -> list[tuple[str, float, float, float]]:
        """``(channel, before, after, shrink)`` of each channel of a group."""
        return [
            (name, float(b), float(a), float(s))
            for name, b, a, s in zip(
                self.channel_names[group],
                self.gap_before[group],
                self.gap_after[group],
                self.shrink(group),
                strict=True,
            )
        ]

    def group_shrink(self, group: str) -> float:
        """``1 - RMSE_after / RMSE_before`` of one group, pooled over its channels [-]."""
        before = float(np.sqrt(np.mean(self.gap_before[group] ** 2)))
        after = float(np.sqrt(np.mean(self.gap_after[group] ** 2)))
        return 0.0 if before == 0.0 else 1.0 - after / before

    @property
    def acted_groups(self) -> tuple[str, ...]:
        """The groups at least one selected effect acts on, in stack order."""
        used = {g for s in self.selected for g in s.groups}
        return tuple(g for g in self.groups if g in used)

    @property
    def total_shrink(self) -> float:
        """Mean group shrink over the groups the selected effects act on (0 if none) [-]."""
        acted = self.acted_groups
        return float(np.mean([self.group_shrink(g) for g in acted])) if acted else 0.0

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of the whole diagnosis."""
        gap = {
            g: {
                "unit": GROUP_UNITS[g],
                "shrink": self.group_shrink(g),
                "channels": {
                    name: {"before": b, "after": a, "shrink": sh}
                    for name, b, a, sh in self.gap_rows(g)
                },
            }
            for g in self.groups
        }
        return {
            "selected": [s.as_dict() for s in self.selected],
            "explained_variance": list(self.explained_variance),
            "step_scores": [
                {name: (float(v) if np.isfinite(v) else None) for name, v in scores.items()}
                for scores in self.step_scores
            ],
            "groups": list(self.groups),
            "gap": gap,
            "waterfall": [dict(w) for w in self.waterfall],
            "total_shrink": self.total_shrink,
            "threshold": self.threshold,
            "train_runs": list(self.train_runs),
            "holdout_runs": list(self.holdout_runs),
            "n_train": self.n_train,
            "n_holdout": self.n_holdout,
            "skipped": dict(self.skipped),
            "replay": self.replay,
            "confounded": dict(self.confounded),
        }

    def to_markdown(self) -> str:
        """The diagnosis as Markdown (tables only; :mod:`msarm.diagnose.report` adds plots)."""
        lines = ["# Sim-to-real gap diagnosis", ""]
        lines.append(
            f"Training runs: {len(self.train_runs)} ({self.n_train} samples); held-out runs: "
            f"{len(self.holdout_runs)} ({self.n_holdout} samples); channel groups: "
            f"{', '.join(self.groups)}. A term is added when it raises the held-out score "
            f"(explained variance, mean over groups) by more than {self.threshold:.3g}."
        )
        lines += ["", "## Which: the selected effects", ""]
        if not self.selected:
            lines.append(
                "None: no candidate explains the held-out residual better than the nominal "
                "model by more than the threshold."
            )
        else:
            lines += [
                "| step | effect | acts on | parameters (± bootstrap std) | held-out score | "
                "gain | confidence |",
                "|---|---|---|---|---|---|---|",
            ]
            for k, s in enumerate(self.selected, start=1):
                confidence = f"{s.confidence:.2f}" if np.isfinite(s.confidence) else "n/a"
                parameters = ", ".join(s.parameter_texts(equals="="))
                lines.append(
                    f"| {k} | {s.name} | {', '.join(s.groups)} | {parameters} | "
                    f"{s.explained_variance:.3f} | {s.gain:+.3f} | {confidence} |"
                )
        lines += ["", "## How far: the held-out gap before and after", ""]
        lines += ["| group | channel | before | after | shrink |", "|---|---|---|---|---|"]
        for g in self.groups:
            unit = GROUP_UNITS[g]
            for name, b, a, s in self.gap_rows(g):
                lines.append(
                    f"| {g} | {name} | {b:.4g} {unit} | {a:.4g} {unit} | {100 * s:.1f} % |"
                )
            lines.append(f"| {g} | all | | | {100 * self.group_shrink(g):.1f} % |")
        if self.selected:
            lines += ["", "Effect by effect (pooled held-out RMSE of each group):", ""]
            lines.append("| after | " + " | ".join(self.groups) + " |")
            lines.append("|---|" + "---|" * len(self.groups))
            steps = ["nominal model", *(f"+ {s.name}" for s in self.selected)]
            for step, values in zip(steps, self.waterfall, strict=True):
                cells = " | ".join(f"{values[g]:.4g} {GROUP_UNITS[g]}" for g in self.groups)
                lines.append(f"| {step} | {cells} |")
        if self.replay is not None:
            r = self.replay
            lines += [
                "",
                f"As motion: the nominal dynamics driven by the logged {r['source']}s over "
                f"{r['window_s']:g} s windows from the logged state (held-out runs), without "
                "and with the selected drive and joint terms:",
                "",
                "| | nominal model | with the effects | shrink |",
                "|---|---|---|---|",
            ]
            for key, label, unit, scale in (
                ("joint_rmse", "joint RMSE", "mrad", 1e3),
                ("hand_error_end", "hand error at window end", "mm", 1e3),
            ):
                b, a = r[f"{key}_before"], r[f"{key}_after"]
                share = 100 * (1 - a / b) if b > 0 else 0.0
                lines.append(
                    f"| {label} | {scale * b:.3g} {unit} | {scale * a:.3g} {unit} | {share:.1f} % |"
                )
        lines += ["", "## Candidates tried at each step (held-out gain on their groups)", ""]
        for k, scores in enumerate(self.step_scores, start=1):
            tried = sorted(
                ((n, v) for n, v in scores.items() if np.isfinite(v)), key=lambda kv: -kv[1]
            )
            held_back = [n for n, v in scores.items() if not np.isfinite(v)]
            text = ", ".join(f"{n} {v:+.3f}" for n, v in tried)
            if held_back:
                text += f" (not tried, confounded: {', '.join(held_back)})"
            lines.append(f"{k}. {text}")
        if self.confounded:
            lines += ["", "## Candidates the data cannot tell apart from a selected one", ""]
            lines += [f"- {name}: {why}" for name, why in self.confounded.items()]
        if self.skipped:
            lines += ["", "## Candidates not tried", ""]
            lines += [f"- {name}: {why}" for name, why in self.skipped.items()]
        return "\n".join(lines) + "\n"


def _resolve(
    model: RobotModel,
    candidates: Sequence[CandidateEffect | str] | None,
    spec: ResidualSpec | None,
) -> tuple[list[CandidateEffect], bool]:
    """The candidates to try, and whether the user named them (else the defaults)."""
    if candidates is None:
        return list(default_candidates(model, spec).values()), False
    every = available_candidates(model, spec)
    out: list[CandidateEffect] = []
    for c in candidates:
        if isinstance(c, str):
            if c not in every:
                raise InputError(
                    f"candidates: unknown name {c!r}; known: {', '.join(every)} "
                    "(or pass a CandidateEffect instance)"
                )
            c = every[c]
        if not isinstance(c, CandidateEffect):
            raise InputError(f"candidates: expected a name or a CandidateEffect, got {c!r}")
        out.append(c)
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise InputError(f"candidates: names must be unique, got {names}")
    return out, True


def _usable(
    pool: list[CandidateEffect],
    layout: _Layout,
    signals: Signals,
    required: set[str],
    absent: set[str],
) -> tuple[list[CandidateEffect], dict[str, str]]:
    """Drop candidates whose groups or signals the logs lack (an error if the user named them).

    A warning names those dropped for want of channels (``absent`` groups); those whose group
    is below its resolution are only listed in the result.
    """
    usable, skipped = [], {}
    warn: list[str] = []
    for term in pool:
        missing = [g for g in term.groups if g not in layout.groups]
        if missing:
            smaller = term.restricted([g for g in term.groups if g in layout.groups])
            if smaller is not None:
                term, missing = smaller, []
        reason = ""
        if missing:
            reason = (
                f"needs the {', '.join(missing)} residual, which the logs lack (drive: "
                "tension_cmd.<cable> columns; length: motor_angle.<cable>) or which is zero or "
                "below its resolution (ResidualSpec.length_resolution)"
            )
        else:
            try:
                term.check(signals)
                if term.linear:
                    term.design(signals.take(np.arange(min(signals.n_samples, 8))))
            except InputError as exc:
                reason = str(exc)
        if not reason:
            usable.append(term)
        elif term.name in required:
            raise InputError(f"candidates: {term.name} cannot be fitted to these logs: {reason}")
        else:
            skipped[term.name] = reason
            if not missing or absent & set(missing):
                warn.append(term.name)
    if warn:
        warnings.warn(
            "candidates not tried: " + "; ".join(f"{name} ({skipped[name]})" for name in warn),
            DiagnosisWarning,
            stacklevel=3,
        )
    return usable, skipped


def _bootstrap(
    model: _Model,
    sampled: _Sampled,
    layout: _Layout,
    n_boot: int,
    threshold: float,
    seed: int,
) -> tuple[list[FloatArray], list[float]]:
    """Bootstrap over training runs: each term's parameter std and its confidence."""
    terms = model.terms
    train, hold = sampled.signals["train"], sampled.signals["hold"]
    r_train, r_hold = sampled.residual["train"], sampled.residual["hold"]
    nan_std = [np.full(t.n_parameters, np.nan) for t in terms]
    labels = np.unique(train.run)
    if n_boot < 2 or labels.size < 2 or not terms:
        return nan_std, [float("nan")] * len(terms)
    rng = np.random.default_rng(seed)
    members = [np.flatnonzero(train.run == label) for label in labels]
    linear = [k for k, t in enumerate(terms) if t.linear]
    nonlinear = [k for k, t in enumerate(terms) if not t.linear]
    if linear:
        stacked = _Stacked([terms[k] for k in linear])
        design = np.concatenate([sampled.design(terms[k], "train") for k in linear], axis=2)
    left = r_train
    for k in linear:
        left = left - sampled.predict(terms[k], model.parameters[k], "train")
    lefts = {}
    for k in nonlinear:
        lefts[k] = left
        left = left - sampled.predict(terms[k], model.parameters[k], "train")
    hold_runs = [hold.run == label for label in np.unique(hold.run)]
    samples = [np.empty((n_boot, t.n_parameters)) for t in terms]
    needed = np.zeros(len(terms))
    for b in range(n_boot):
        weights = np.zeros(train.n_samples)
        for k in rng.integers(0, labels.size, size=labels.size):
            weights[members[k]] += 1.0
        if linear:
            root = np.sqrt(weights)
            theta = _solve_linear(design * root[:, None, None], r_train * root[:, None])
            for k, part in zip(linear, stacked.split(theta), strict=True):
                samples[k][b] = part
        for k in nonlinear:
            samples[k][b], _ = sampled.fit_nonlinear(
                terms[k], lefts[k], model.parameters[k], weights
            )
        parts = [sampled.predict(term, samples[k][b], "hold") for k, term in enumerate(terms)]
        full = np.sum(parts, axis=0)
        for mask in hold_runs:
            with_all = _group_scores(layout, r_hold[mask], full[mask])
            for k, term in enumerate(terms):
                without = _group_scores(layout, r_hold[mask], (full - parts[k])[mask])
                needed[k] += _own_gain(term.term.groups, without, with_all) > threshold
    stds = [s.std(axis=0, ddof=1) for s in samples]
    return stds, [float(n / (n_boot * len(hold_runs))) for n in needed]


def diagnose(
    model: RobotModel,
    train_paths: Sequence[str | Path],
    holdout_paths: Sequence[str | Path],
    candidates: Sequence[CandidateEffect | str] | None = None,
    threshold: float = DEFAULT_THRESHOLD,
    spec: ResidualSpec | None = None,
    n_boot: int = 20,
    seed: int = 0,
    groups: Sequence[str] | None = None,
    extra_candidates: Sequence[CandidateEffect] = (),
) -> Diagnosis:
    """Find which candidate effects explain the gap, by forward selection on held-out runs.

    See the module docstring for the groups, the joint fit, the score, the stopping rule and
    the confidence. Only the logs are read, never their ground-truth sidecars.

    Args:
        model: The nominal robot model the logs were recorded with.
        train_paths: Logs the terms are fitted on (at least one).
        holdout_paths: Logs the terms are scored on (at least one, none of the training ones).
        candidates: Candidate effects (instances, or names of :func:`available_candidates`);
            :data:`DEFAULT_CANDIDATES` when ``None`` (those the logs cannot support are
            skipped with a warning; a named one that cannot be fitted is an error).
        threshold: Least gain of the held-out score for a term to be added [-].
        spec: Residual settings (filter, drum radius, drive gain).
        n_boot: Bootstrap refits over training runs for the std and confidence (< 2: none).
        seed: Seed of the bootstrap draws.
        groups: Channel groups to diagnose (default all the logs have).
        extra_candidates: Your own candidates, tried besides ``candidates`` (each must be
            usable on the logs).

    Returns:
        The :class:`Diagnosis`.

    Raises:
        InputError: No training or held-out logs, a log in both, a bad candidate, group or
            threshold, a named candidate the logs cannot support, or no group with
            variance on both training and held-out runs.
        LogError: A log that cannot be diagnosed (file named).
    """
    data = load_data(model, train_paths, holdout_paths, candidates, spec, groups, extra_candidates)
    return select_effects(data, threshold, n_boot, seed)


@dataclass(frozen=True, eq=False)
class DiagnosisData:
    """Everything the selection works on, read once from the logs (see :func:`load_data`).

    Attributes:
        model: The nominal robot model.
        train: Signals of the training runs.
        hold: Signals of the held-out runs.
        layout: The channel groups, their columns and normalising spreads.
        r_train: Normalised, stacked training residual, ``(T_train, W)``.
        r_hold: Normalised, stacked held-out residual, ``(T_hold, W)``.
        candidates: The usable candidates (each embedded in the stack).
        skipped: Candidates not usable on these logs, with the reason.
        train_runs: Training log names.
        holdout_runs: Held-out log names.
        channel_names: Channel names of each group.
    """

    model: RobotModel
    train: Signals
    hold: Signals
    layout: _Layout
    r_train: FloatArray
    r_hold: FloatArray
    candidates: tuple[_Embedded, ...]
    skipped: dict[str, str]
    train_runs: tuple[str, ...]
    holdout_runs: tuple[str, ...]
    channel_names: dict[str, tuple[str, ...]]


def load_data(
    model: RobotModel,
    train_paths: Sequence[str | Path],
    holdout_paths: Sequence[str | Path],
    candidates: Sequence[CandidateEffect | str] | None = None,
    spec: ResidualSpec | None = None,
    groups: Sequence[str] | None = None,
    extra_candidates: Sequence[CandidateEffect] = (),
) -> DiagnosisData:
    """Read the logs and set up the selection's data (arguments as :func:`diagnose`).

    Raises:
        InputError: See :func:`diagnose`.
        LogError: A log that cannot be diagnosed (file named).
    """
    if not train_paths:
        raise InputError("train_paths: no training logs; the terms need runs to be fitted on")
    if not holdout_paths:
        raise InputError("holdout_paths: no held-out logs; the terms need runs to be scored on")
    both = {str(Path(p).resolve()) for p in train_paths} & {
        str(Path(p).resolve()) for p in holdout_paths
    }
    if both:
        raise InputError(f"holdout_paths: logs also used for training: {sorted(both)}")
    wanted = tuple(GROUPS if groups is None else groups)
    unknown = [g for g in wanted if g not in GROUPS]
    if unknown or not wanted:
        raise InputError(f"groups: expected some of {', '.join(GROUPS)}, got {list(wanted)}")
    pool, named = _resolve(model, candidates, spec)
    train, g_train, train_names = channels_from_logs(model, train_paths, spec)
    hold, g_hold, hold_names = channels_from_logs(model, holdout_paths, spec)

    spec = spec or ResidualSpec()
    floor = {"joint": 0.0, "drive": 0.0, "length": spec.length_resolution}

    def above(r: FloatArray, group: str) -> bool:
        rms = float(np.sqrt(np.mean(r**2)))
        return rms > floor[group]

    present = {
        g: g_train[g]
        for g in wanted
        if g in g_train and g in g_hold and above(g_train[g], g) and above(g_hold[g], g)
    }
    if not present:
        raise InputError(
            "holdout_paths: no residual group has variance on both training and held-out runs"
        )
    layout = _Layout(present)
    r_train = layout.stack(g_train)
    r_hold = layout.stack(g_hold)
    absent = {g for g in wanted if g not in g_train or g not in g_hold}
    extras = list(extra_candidates)
    for extra in extras:
        if not isinstance(extra, CandidateEffect):
            raise InputError(f"extra_candidates: expected CandidateEffect instances, got {extra!r}")
    names = [c.name for c in [*pool, *extras]]
    if len(set(names)) != len(names):
        raise InputError(f"extra_candidates: names must be unique, got {names}")
    required = {c.name for c in pool} if named else set()
    required |= {c.name for c in extras}
    usable, skipped = _usable([*pool, *extras], layout, train, required, absent)
    names = {"joint": tuple(model.joint_names)}
    names.update({g: tuple(model.cable_names) for g in ("drive", "length")})
    return DiagnosisData(
        model=model,
        train=train,
        hold=hold,
        layout=layout,
        r_train=r_train,
        r_hold=r_hold,
        candidates=tuple(_Embedded(t, layout) for t in usable),
        skipped=skipped,
        train_runs=train_names,
        holdout_runs=hold_names,
        channel_names={g: names[g] for g in layout.groups},
    )


def select_effects(
    data: DiagnosisData,
    threshold: float = DEFAULT_THRESHOLD,
    n_boot: int = 20,
    seed: int = 0,
    replay: bool = True,
    max_samples: int = MAX_FIT_SAMPLES,
) -> Diagnosis:
    """Forward selection, final fit, bootstrap and gaps on prepared data (see :func:`diagnose`).

    Args:
        data: From :func:`load_data`.
        threshold: Least gain for a term to be added [-].
        n_boot: Bootstrap draws over training runs (< 2: none).
        seed: Seed of the bootstrap.
        replay: Also replay the held-out runs without and with the effects (the gap as motion).
        max_samples: The fits and scores use at most this many training and as many held-out
            samples, evenly thinned (the gaps reported use every held-out sample).

    Raises:
        InputError: A bad threshold or ``max_samples``.
    """
    if int(max_samples) < 100:
        raise InputError(f"max_samples: expected an integer >= 100, got {max_samples}")
    threshold = float(threshold)
    if not np.isfinite(threshold) or threshold < 0:
        raise InputError(f"threshold: expected a finite value >= 0, got {threshold}")
    hold, layout = data.hold, data.layout
    r_hold = data.r_hold
    sampled = _Sampled(data, int(max_samples))
    embedded = list(data.candidates)

    chosen: list[CandidateEffect] = []
    scores_per_step: list[dict[str, float]] = []
    current = dict.fromkeys(layout.groups, 0.0)
    explained = [0.0]
    gains: list[float] = []
    remaining = list(embedded)
    bases = _Bases(sampled)
    confounded: dict[str, str] = {}
    while remaining:
        gain_of: dict[str, float] = {}
        after: dict[str, dict[str, float]] = {}
        for candidate in remaining:
            clash = bases.confounder(candidate, chosen)
            if clash is not None:
                confounded[candidate.name] = clash
                gain_of[candidate.name] = float("nan")
                continue
            fitted = _fit_together([*chosen, candidate], sampled)
            after[candidate.name] = _group_scores(
                layout, sampled.residual["hold"], fitted.predict(sampled, "hold")
            )
            gain_of[candidate.name] = _own_gain(
                candidate.term.groups, current, after[candidate.name]
            )
        scores_per_step.append(gain_of)
        open_ = [c for c in remaining if np.isfinite(gain_of[c.name])]
        if not open_:
            break
        best = max(open_, key=lambda c: gain_of[c.name])
        if not gain_of[best.name] > threshold:
            break
        chosen.append(best)
        remaining.remove(best)
        current = after[best.name]
        explained.append(float(np.mean(list(current.values()))))
        gains.append(gain_of[best.name])

    final = _fit_together(chosen, sampled)
    stds, confidence = _bootstrap(final, sampled, layout, int(n_boot), threshold, seed)
    cumulative = np.zeros_like(r_hold)
    waterfall = [{g: _pooled(v) for g, v in layout.unstack(r_hold).items()}]
    for term, theta in zip(final.terms, final.parameters, strict=True):
        cumulative = cumulative + np.asarray(term.torque(hold, theta), dtype=float)
        waterfall.append({g: _pooled(v) for g, v in layout.unstack(r_hold - cumulative).items()})
    before, after = layout.unstack(r_hold), layout.unstack(r_hold - cumulative)
    motion = _replay_gap(data, layout.unstack(cumulative)) if replay else None
    selected = tuple(
        SelectedEffect(
            name=term.name,
            description=term.description,
            groups=term.term.groups,
            parameter_names=term.parameter_names,
            parameters=theta,
            std=std,
            explained_variance=explained[k + 1],
            gain=gains[k],
            confidence=confidence[k],
            message=message,
        )
        for k, (term, theta, std, message) in enumerate(
            zip(final.terms, final.parameters, stds, final.messages, strict=True)
        )
    )
    return Diagnosis(
        selected=selected,
        explained_variance=tuple(explained),
        step_scores=tuple(scores_per_step),
        groups=layout.groups,
        channel_names=dict(data.channel_names),
        gap_before={g: _rmse(v) for g, v in before.items()},
        gap_after={g: _rmse(v) for g, v in after.items()},
        waterfall=tuple(waterfall),
        threshold=threshold,
        train_runs=data.train_runs,
        holdout_runs=data.holdout_runs,
        n_train=data.train.n_samples,
        n_holdout=hold.n_samples,
        skipped=dict(data.skipped),
        replay=motion,
        confounded={k: v for k, v in confounded.items() if k not in {c.name for c in chosen}},
    )
