"""Which unmodelled effect explains the gap: forward selection scored on held-out runs.

:func:`diagnose` starts from the nominal model (no term: the whole joint-torque residual
``r = tau_MS - ID`` is unexplained) and, step by step, tries each remaining candidate together
with the terms already selected:

- **Joint fit.** All linear terms (the selected ones and the candidate, if linear) are fitted
  together by one least-squares problem on their stacked design matrices. Nonlinear terms are
  then fitted one after another (in the order they were selected, the candidate last) by IPOPT,
  each on the residual left by the linear block and the nonlinear terms before it (one pass; the
  linear block is not refitted afterwards). Fits use the training runs only.
- **Score.** The share of the held-out residual's variance the fitted model explains,
  ``1 - sum_j var(r_j - pred_j) / sum_j var(r_j)`` over the held-out samples (variances about
  each joint's mean, pooled over joints): a term earns its place by predicting runs it was not
  fitted on, not by fitting noise.
- **Rule.** The best candidate is added when it raises the held-out explained variance by more
  than ``threshold`` (:data:`DEFAULT_THRESHOLD` = 0.02, two percentage points of the residual's
  variance); otherwise the selection stops. A null plant (only sensor noise) leaves nothing a
  term can predict on held-out runs, so nothing is selected.

The result, a :class:`Diagnosis`, names the selected effects in order with their parameters
(and their bootstrap standard deviation over the training runs), the held-out explained
variance after each step, and the gap per joint: the held-out RMSE of the residual before and
after subtracting the selected terms' prediction, and the share it shrank.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.builder import signals_from_logs
from msarm.diagnose.effects import (
    CableCapstanFriction,
    CandidateEffect,
    CoulombFriction,
    InertiaError,
    MotorCogging,
    SensorBiasScale,
    StribeckFriction,
    TensionDelay,
    ViscousFriction,
)
from msarm.diagnose.fitting import bootstrap, fit
from msarm.diagnose.residuals import ResidualSpec
from msarm.diagnose.signals import Signals
from msarm.errors import InputError
from msarm.model import RobotModel

__all__ = [
    "DEFAULT_COGGING_PERIODS",
    "DEFAULT_THRESHOLD",
    "Diagnosis",
    "SelectedEffect",
    "default_candidates",
    "diagnose",
]

FloatArray = NDArray[np.float64]

#: A candidate is added when it raises the held-out explained variance by more than this [-].
DEFAULT_THRESHOLD = 0.02
#: Cogging periods per motor revolution of the default cogging candidate (motor datasheet).
DEFAULT_COGGING_PERIODS = 24


def default_candidates(
    model: RobotModel, spec: ResidualSpec | None = None
) -> dict[str, CandidateEffect]:
    """The candidate effects tried by default, by name.

    Coulomb and viscous joint friction, Stribeck friction (nonlinear), capstan sheath friction
    (one shared ``mu``, nonlinear), motor cogging (:data:`DEFAULT_COGGING_PERIODS` periods per
    revolution, the drum radius of ``spec``), load-cell bias and scale (shared by all cables),
    a tension delay and the links' mass error (base set of masses and first moments).

    Args:
        model: The nominal robot model.
        spec: Residual settings; its ``drum_radius`` [m] is the cogging term's.
    """
    spec = spec or ResidualSpec()
    n, m = model.n_joints, model.n_cables
    effects: list[CandidateEffect] = [
        CoulombFriction(n_joints=n),
        ViscousFriction(n_joints=n),
        StribeckFriction(n_joints=n),
        CableCapstanFriction(n_cables=m, n_joints=n),
        MotorCogging(DEFAULT_COGGING_PERIODS, spec.drum_radius, n_cables=m, n_joints=n),
        SensorBiasScale(n_cables=m, n_joints=n, shared=True),
        TensionDelay(n_cables=m, n_joints=n),
        InertiaError(model, subset="mass"),
    ]
    return {e.name: e for e in effects}


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

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        return np.concatenate([t.design(signals) for t in self.terms], axis=2)

    def check(self, signals: Signals) -> None:  # noqa: D102
        for t in self.terms:
            t.check(signals)

    def split(self, theta: FloatArray) -> list[FloatArray]:
        """The parameters of each term, in order."""
        return np.split(np.asarray(theta, dtype=float), np.cumsum(self.sizes)[:-1])


@dataclass(frozen=True)
class _Model:
    """A fitted combination of terms: parameters by term, in the given order."""

    terms: tuple[CandidateEffect, ...]
    parameters: tuple[FloatArray, ...]
    messages: tuple[str, ...]

    def predict(self, signals: Signals) -> FloatArray:
        out = np.zeros((signals.n_samples, signals.n_joints))
        for term, theta in zip(self.terms, self.parameters, strict=True):
            out += np.asarray(term.torque(signals, theta), dtype=float)
        return out


def _fit_together(
    terms: Sequence[CandidateEffect], signals: Signals, residual: FloatArray
) -> _Model:
    """Joint fit: linear terms by one stacked least squares, then nonlinear ones in turn."""
    linear = [t for t in terms if t.linear]
    nonlinear = [t for t in terms if not t.linear]
    parameters: dict[int, FloatArray] = {}
    messages: dict[int, str] = {}
    left = residual
    if linear:
        stacked = _Stacked(linear)
        result = fit(stacked, signals, residual)
        for term, theta in zip(linear, stacked.split(result.parameters), strict=True):
            parameters[id(term)], messages[id(term)] = theta, "least squares (joint)"
        left = residual - result.predict(signals)
    for term in nonlinear:
        result = fit(term, signals, left)
        parameters[id(term)] = result.parameters
        messages[id(term)] = result.message
        left = left - result.predict(signals)
    return _Model(
        terms=tuple(terms),
        parameters=tuple(parameters[id(t)] for t in terms),
        messages=tuple(messages[id(t)] for t in terms),
    )


def _explained(residual: FloatArray, prediction: FloatArray) -> float:
    """Pooled explained variance ``1 - sum var(r - pred) / sum var(r)`` [-]."""
    error = residual - prediction
    var_r = np.sum((residual - residual.mean(axis=0)) ** 2)
    var_e = np.sum((error - error.mean(axis=0)) ** 2)
    return float(1.0 - var_e / var_r)


def _rmse(values: FloatArray) -> FloatArray:
    return np.sqrt(np.mean(values**2, axis=0))


@dataclass(frozen=True)
class SelectedEffect:
    """One selected term of a :class:`Diagnosis`.

    Attributes:
        name: Candidate name (registry name, see :mod:`msarm.diagnose.effects`).
        description: The term's equation.
        parameter_names: Names of its ``p`` parameters.
        parameters: Fitted parameters (training runs, joint fit of the final model), ``(p,)``.
        std: Bootstrap standard deviation over training runs, ``(p,)``; NaN when not computed
            (fewer than 2 training runs, or ``n_boot = 0``).
        explained_variance: Held-out explained variance after adding this term [-].
        gain: Increase of the held-out explained variance this term brought [-].
        message: Solver status of its fit.
    """

    name: str
    description: str
    parameter_names: tuple[str, ...]
    parameters: FloatArray
    std: FloatArray
    explained_variance: float
    gain: float
    message: str

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        return {
            "name": self.name,
            "description": self.description,
            "parameters": dict(zip(self.parameter_names, map(float, self.parameters), strict=True)),
            "std": {
                k: (None if not np.isfinite(v) else float(v))
                for k, v in zip(self.parameter_names, self.std, strict=True)
            },
            "explained_variance": self.explained_variance,
            "gain": self.gain,
            "message": self.message,
        }


@dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`.

    Attributes:
        selected: The selected effects, in the order they were added.
        explained_variance: Held-out explained variance after each step [-], starting with the
            nominal model's 0.0; length ``len(selected) + 1``.
        step_scores: Per step, the held-out explained variance of every candidate tried
            (with the terms selected before), by name.
        joint_names: Joint names, ``(n,)``.
        gap_before: Held-out RMSE of the residual per joint, nominal model [N m], ``(n,)``.
        gap_after: Held-out RMSE of the residual minus the selected terms' prediction [N m],
            ``(n,)``.
        threshold: The selection threshold [-].
        train_runs: The training logs.
        holdout_runs: The held-out logs.
        n_train: Training samples.
        n_holdout: Held-out samples.
    """

    selected: tuple[SelectedEffect, ...]
    explained_variance: tuple[float, ...]
    step_scores: tuple[dict[str, float], ...]
    joint_names: tuple[str, ...]
    gap_before: FloatArray
    gap_after: FloatArray
    threshold: float
    train_runs: tuple[str, ...]
    holdout_runs: tuple[str, ...]
    n_train: int
    n_holdout: int

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the selected effects, in order."""
        return tuple(s.name for s in self.selected)

    @property
    def shrink(self) -> FloatArray:
        """Share of each joint's held-out gap removed, ``1 - after / before`` [-], ``(n,)``."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.gap_before > 0, 1.0 - self.gap_after / self.gap_before, 0.0)

    @property
    def total_shrink(self) -> float:
        """``1 - RMSE_after / RMSE_before`` pooled over joints [-]."""
        before = float(np.sqrt(np.mean(self.gap_before**2)))
        after = float(np.sqrt(np.mean(self.gap_after**2)))
        return 0.0 if before == 0.0 else 1.0 - after / before

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of the whole diagnosis."""
        return {
            "selected": [s.as_dict() for s in self.selected],
            "explained_variance": list(self.explained_variance),
            "step_scores": [dict(s) for s in self.step_scores],
            "gap": {
                name: {
                    "before_Nm": float(b),
                    "after_Nm": float(a),
                    "shrink": float(s),
                }
                for name, b, a, s in zip(
                    self.joint_names, self.gap_before, self.gap_after, self.shrink, strict=True
                )
            },
            "total_shrink": self.total_shrink,
            "threshold": self.threshold,
            "train_runs": list(self.train_runs),
            "holdout_runs": list(self.holdout_runs),
            "n_train": self.n_train,
            "n_holdout": self.n_holdout,
        }

    def to_markdown(self) -> str:
        """The diagnosis as a Markdown report."""
        lines = ["# Sim-to-real gap diagnosis", ""]
        lines.append(
            f"Training runs: {len(self.train_runs)} ({self.n_train} samples); held-out runs: "
            f"{len(self.holdout_runs)} ({self.n_holdout} samples). A term is added when it "
            f"raises the held-out explained variance by more than {self.threshold:.3g}."
        )
        lines += ["", "## Selected effects", ""]
        if not self.selected:
            lines.append(
                "None: no candidate explains the held-out residual better than the nominal "
                "model by more than the threshold."
            )
        else:
            lines += [
                "| step | effect | parameters | held-out explained variance | gain |",
                "|---|---|---|---|---|",
            ]
            for k, s in enumerate(self.selected, start=1):
                lines.append(
                    f"| {k} | {s.name} | {_format_parameters(s)} | "
                    f"{s.explained_variance:.3f} | {s.gain:+.3f} |"
                )
        lines += ["", "## Gap per joint (held-out RMSE of the joint-torque residual)", ""]
        lines += ["| joint | before [N m] | after [N m] | shrink |", "|---|---|---|---|"]
        for name, b, a, s in zip(
            self.joint_names, self.gap_before, self.gap_after, self.shrink, strict=True
        ):
            lines.append(f"| {name} | {b:.4g} | {a:.4g} | {100 * s:.1f} % |")
        lines.append(f"| all | | | {100 * self.total_shrink:.1f} % |")
        lines += ["", "## Candidates tried at each step (held-out explained variance)", ""]
        for k, scores in enumerate(self.step_scores, start=1):
            ranked = sorted(scores.items(), key=lambda kv: -kv[1])
            lines.append(f"{k}. " + ", ".join(f"{n} {v:.3f}" for n, v in ranked))
        return "\n".join(lines) + "\n"


def _format_parameters(effect: SelectedEffect, limit: int = 6) -> str:
    parts = []
    for name, value, std in zip(effect.parameter_names, effect.parameters, effect.std, strict=True):
        text = f"{name}={value:.4g}"
        if np.isfinite(std):
            text += f"±{std:.2g}"
        parts.append(text)
    if len(parts) > limit:
        parts = [*parts[:limit], f"... ({len(parts) - limit} more)"]
    return ", ".join(parts)


def _resolve(
    model: RobotModel,
    candidates: Sequence[CandidateEffect | str] | None,
    spec: ResidualSpec | None,
) -> list[CandidateEffect]:
    defaults = default_candidates(model, spec)
    if candidates is None:
        return list(defaults.values())
    out: list[CandidateEffect] = []
    for c in candidates:
        if isinstance(c, str):
            if c not in defaults:
                raise InputError(
                    f"candidates: unknown name {c!r}; known: {', '.join(defaults)} "
                    "(or pass a CandidateEffect instance)"
                )
            c = defaults[c]
        if not isinstance(c, CandidateEffect):
            raise InputError(f"candidates: expected a name or a CandidateEffect, got {c!r}")
        out.append(c)
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise InputError(f"candidates: names must be unique, got {names}")
    return out


def _bootstrap_std(
    model: _Model, signals: Signals, residual: FloatArray, n_boot: int, seed: int
) -> list[FloatArray]:
    """Bootstrap std over runs: the linear block jointly, nonlinear terms on what is left."""
    stds = {id(t): np.full(t.n_parameters, np.nan) for t in model.terms}
    if n_boot < 2 or np.unique(signals.run).size < 2:
        return [stds[id(t)] for t in model.terms]
    linear = [t for t in model.terms if t.linear]
    left = residual
    if linear:
        stacked = _Stacked(linear)
        result = bootstrap(stacked, signals, residual, n_boot=n_boot, seed=seed)
        for term, std in zip(linear, stacked.split(result.std), strict=True):
            stds[id(term)] = std
        for term, theta in zip(model.terms, model.parameters, strict=True):
            if term.linear:
                left = left - np.asarray(term.torque(signals, theta), dtype=float)
    for term, theta in zip(model.terms, model.parameters, strict=True):
        if not term.linear:
            result = bootstrap(term, signals, left, n_boot=n_boot, seed=seed)
            stds[id(term)] = result.std
            left = left - np.asarray(term.torque(signals, theta), dtype=float)
    return [stds[id(t)] for t in model.terms]


def diagnose(
    model: RobotModel,
    train_paths: Sequence[str | Path],
    holdout_paths: Sequence[str | Path],
    candidates: Sequence[CandidateEffect | str] | None = None,
    threshold: float = DEFAULT_THRESHOLD,
    spec: ResidualSpec | None = None,
    n_boot: int = 30,
    seed: int = 0,
) -> Diagnosis:
    """Find which candidate effects explain the gap, by forward selection on held-out runs.

    See the module docstring for the joint fit, the score and the stopping rule. Only the logs
    are read, never their ground-truth sidecars.

    Args:
        model: The nominal robot model the logs were recorded with.
        train_paths: Logs the terms are fitted on (at least one).
        holdout_paths: Logs the terms are scored on (at least one, none of the training ones).
        candidates: Candidate effects (instances, or names of :func:`default_candidates`);
            all defaults when ``None``.
        threshold: Least gain of held-out explained variance for a term to be added [-].
        spec: Residual settings (filter, drum radius).
        n_boot: Bootstrap refits over training runs for the parameters' std (0: none).
        seed: Seed of the bootstrap draws.

    Returns:
        The :class:`Diagnosis`.

    Raises:
        InputError: No training or held-out logs, a log in both, a bad candidate or
            threshold, or a held-out residual without variance.
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
    threshold = float(threshold)
    if not np.isfinite(threshold) or threshold < 0:
        raise InputError(f"threshold: expected a finite value >= 0, got {threshold}")
    pool = _resolve(model, candidates, spec)
    train, r_train, train_names = signals_from_logs(model, train_paths, spec)
    hold, r_hold, hold_names = signals_from_logs(model, holdout_paths, spec)
    if np.sum((r_hold - r_hold.mean(axis=0)) ** 2) <= 0:
        raise InputError("holdout_paths: the held-out residual has no variance")

    chosen: list[CandidateEffect] = []
    scores_per_step: list[dict[str, float]] = []
    explained = [0.0]
    gains: list[float] = []
    remaining = list(pool)
    while remaining:
        scores: dict[str, float] = {}
        for candidate in remaining:
            fitted = _fit_together([*chosen, candidate], train, r_train)
            scores[candidate.name] = _explained(r_hold, fitted.predict(hold))
        scores_per_step.append(scores)
        best = max(remaining, key=lambda c: scores[c.name])
        gain = scores[best.name] - explained[-1]
        if not gain > threshold:
            break
        chosen.append(best)
        remaining.remove(best)
        explained.append(scores[best.name])
        gains.append(gain)

    final = _fit_together(chosen, train, r_train)
    stds = _bootstrap_std(final, train, r_train, int(n_boot), seed)
    prediction = final.predict(hold)
    selected = tuple(
        SelectedEffect(
            name=term.name,
            description=term.description,
            parameter_names=term.parameter_names,
            parameters=theta,
            std=std,
            explained_variance=explained[k + 1],
            gain=gains[k],
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
        joint_names=tuple(model.joint_names),
        gap_before=_rmse(r_hold),
        gap_after=_rmse(r_hold - prediction),
        threshold=threshold,
        train_runs=train_names,
        holdout_runs=hold_names,
        n_train=train.n_samples,
        n_holdout=hold.n_samples,
    )
