"""The answer of a gap diagnosis: the selected effects and the gap before and after."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.builder import GROUP_UNITS
from msarm.diagnose.effects import parameter_index
from msarm.model import HAND_SITE

if TYPE_CHECKING:
    from msarm.diagnose.where import GapBreakdown

__all__ = ["Diagnosis", "SelectedEffect", "label_parameters"]

FloatArray = NDArray[np.float64]


def label_parameters(
    names: Sequence[str],
    indexed_by: str | None,
    joint_names: Sequence[str],
    cable_names: Sequence[str],
) -> tuple[str, ...]:
    """Parameter names with the joint or cable their bracketed index counts.

    Args:
        names: The parameters' names, e.g. ``("coulomb[0]", "coulomb[3]")``.
        indexed_by: What a whole number in brackets counts: ``"joint"``, ``"cable"`` (see
            ``CandidateEffect.indexed_by``) or None (the names are kept).
        joint_names: The model's joints, in order.
        cable_names: The model's cables, in order.

    Returns:
        The labels, e.g. ``("coulomb[shoulder_abduction]", "coulomb[elbow]")``; a name
        without such an index, or with one outside the model's count, is kept.
    """
    channels = {"joint": joint_names, "cable": cable_names}.get(indexed_by or "", ())
    labels = []
    for name in names:
        index = parameter_index(name)
        if index is not None and index < len(channels):
            name = f"{name.rsplit('[', 1)[0]}[{channels[index]}]"
        labels.append(name)
    return tuple(labels)


def _number(value: Any) -> str:
    """A value as shown: ``0.003``, ``4``, ``true``, or ``[0.003, 0.004]`` for one per channel."""
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_number(v) for v in value) + "]"
    if isinstance(value, bool):
        return str(value).lower()
    return f"{value:.4g}" if isinstance(value, float | int) else str(value)


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
        parameter_units: Unit of each parameter (``"-"``: dimensionless, ``""``: not stated),
            ``(p,)`` strings; empty when not recorded.
        notes: What the reader should know about this result: a parameter below zero that no
            physical effect of the kind has, an effect the logs cannot tell from another.
        parameter_labels: Each parameter's name as shown to a reader, with the joint or cable
            its bracketed index counts (``coulomb[elbow]`` for ``coulomb[3]``; see
            :func:`label_parameters`), ``(p,)`` strings; empty: the names themselves.
        constants: The fixed (not fitted) constants of its equation by their symbol in
            :attr:`description` (``{"rho": 0.003, "K": 4.0, "omega_s": 0.5}``; see
            ``CandidateEffect.constants``); empty when the term states none.
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
    parameter_units: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    parameter_labels: tuple[str, ...] = ()
    constants: dict[str, Any] = field(default_factory=dict)

    @property
    def labels(self) -> tuple[str, ...]:
        """The parameters' names as shown: :attr:`parameter_labels`, or the names."""
        return self.parameter_labels or self.parameter_names

    def parameter_rows(self) -> list[tuple[str, float, float, str]]:
        """``(label, value, bootstrap std, unit)`` of each parameter.

        The unit is ``""`` when the term states none or the parameter is dimensionless.
        """
        units = self.parameter_units or ("",) * len(self.parameter_names)
        return [
            (label, float(value), float(std), "" if unit == "-" else unit)
            for label, value, std, unit in zip(
                self.labels, self.parameters, self.std, units, strict=True
            )
        ]

    def parameter_texts(self, limit: int | None = 6, equals: str = " = ") -> list[str]:
        """``label = value ± std unit`` of the first ``limit`` parameters, and how many more.

        ``limit=None`` gives every parameter.
        """
        parts = []
        for label, value, std, unit in self.parameter_rows():
            text = f"{label}{equals}{value:.4g}"
            if np.isfinite(std):
                text += f" ± {std:.2g}"
            if unit:
                text += f" {unit}"
            parts.append(text)
        if limit is not None and len(parts) > limit:
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
            "units": dict(zip(self.parameter_names, self.parameter_units, strict=True))
            if self.parameter_units
            else {},
            "notes": list(self.notes),
            "labels": dict(zip(self.parameter_names, self.labels, strict=True)),
            "constants": dict(self.constants),
        }

    def equation(self) -> str:
        """Its equation (:attr:`description`) with the fixed constants' values after it."""
        if not self.constants:
            return self.description
        values = ", ".join(f"{k} = {_number(v)}" for k, v in self.constants.items())
        return f"{self.description} (fixed, not fitted: {values})"


@dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`.

    Attributes:
        selected: The selected effects, in the order they were added.
        explained_variance: Held-out score after each step [-], starting with the nominal
            model's 0.0; length ``len(selected) + 1``.
        step_scores: Per step, the gain (on its own groups) of every candidate tried with the
            terms selected before, by name: from the joint fit for the shortlisted
            candidates (every candidate at the first step), from the screening fit for the
            others; NaN for a candidate not tried, confounded (see ``confounded``).
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
            dynamics driven by the logged commands over windows (0.2 s by default), without
            and with the selected drive and joint terms; None when not computed. Its hand
            errors are None for a model without the hand site (the joint RMSE alone).
        search: The selection's settings besides the threshold: ``shortlist`` (None: every
            candidate fitted jointly), ``screen_samples``, ``max_samples`` (training samples
            the fits use), ``max_score_samples`` (held-out samples the scores use), ``n_boot``,
            ``seed`` and ``final_fit`` (``"projection"``: the named effects' final fit and the
            bootstrap's at their joint optimum; ``"blocks"``: that optimum was not kept, and
            the parameters are the selection's last step-wise fit by blocks, the bootstrap's
            refits by blocks too, ``final_fit_rejected`` saying why; absent from answers made
            before 2026-11-28), ``bootstrap_refits_by_blocks`` (draws whose joint optimum was
            unsound, refitted by blocks) (empty when not recorded).
        log_warnings: What the logs lacked or held that the diagnosis worked around (a
            missing channel, a time gap, a sensor that holds one value), as the
            :class:`~msarm.diagnose.residuals.DiagnosisWarning` messages said it, each once
            (the candidates not tried are in ``skipped``).
        shortlisted: Per step (as ``step_scores``), the candidates whose score is a joint fit
            with the terms selected before (the shortlist; every candidate tried when the
            first step's screening was already that fit); the others' scores are screening
            scores (each alone on thinned samples, the selected terms held fixed). Empty when
            not recorded.
        residual_spec: The residual settings the logs were read with
            (:class:`~msarm.diagnose.residuals.ResidualSpec` as a dict: ``target`` (filter
            ``window`` [samples], ``polyorder``, ``smooth_tension``, ``tension_timing``),
            ``drum_radius`` [m], ``drive_gain`` [-], ``length_resolution`` [m], ``replay``,
            ``replay_source``, ``replay_window`` [s], ``replay_substeps``); they set the
            parameters (the drive terms' in N m through the drum radius and the drive gain).
            Empty when not recorded.
        model: The nominal model: ``name``, ``sha256`` (of its MJCF, as the logs carry it) and
            ``path`` (absolute). Empty when not recorded.
        code_fingerprint: :func:`msarm.io.code_version.code_fingerprint` of scope
            ``"diagnosis"`` of the code that made the answer (msarm's sources and the fitting
            libraries' versions); ``""`` when not recorded.
        log_paths: The logs' absolute paths, ``{"train": (...), "holdout": (...)}`` in the
            order of ``train_runs`` and ``holdout_runs`` (which keep the paths as given).
        where: The "where" breakdown of the training runs by residual kind (``joint_torque``,
            ``drive``, ``cable_length``): each :meth:`~msarm.diagnose.where.GapBreakdown.as_dict`,
            or ``{"skipped": why}`` for a kind not broken down; empty when not computed (see
            :meth:`with_where`).
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
    search: dict[str, Any] = field(default_factory=dict)
    log_warnings: tuple[str, ...] = ()
    shortlisted: tuple[tuple[str, ...], ...] = ()
    residual_spec: dict[str, Any] = field(default_factory=dict)
    model: dict[str, str] = field(default_factory=dict)
    code_fingerprint: str = ""
    log_paths: dict[str, tuple[str, ...]] = field(default_factory=dict)
    where: dict[str, Any] = field(default_factory=dict)

    def with_where(
        self, breakdowns: Mapping[str, GapBreakdown], skipped: Mapping[str, str] | None = None
    ) -> Diagnosis:
        """The same diagnosis with its "where" section (:attr:`where`) filled in.

        Args:
            breakdowns: The breakdowns of the training runs by residual kind
                (:func:`msarm.cli.diagnose.where_breakdowns`).
            skipped: Why each kind not broken down was skipped.

        Returns:
            A new :class:`Diagnosis`; its :attr:`where` holds the kinds in the order given,
            the breakdowns first.
        """
        where = {kind: breakdown.as_dict() for kind, breakdown in breakdowns.items()}
        where.update({kind: {"skipped": why} for kind, why in (skipped or {}).items()})
        return replace(self, where=where)

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the selected effects, in order."""
        return tuple(s.name for s in self.selected)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint names, ``(n,)``."""
        return self.channel_names["joint"]

    def shrink(self, group: str = "joint") -> FloatArray:
        """Share of each channel's held-out gap removed, ``1 - after / before`` [-].

        Args:
            group: A diagnosed channel group (``"joint"``, ``"drive"`` or ``"length"``).

        Returns:
            The shrink of each channel of the group [-], shape ``(k,)`` with ``k`` its number
            of channels (``n`` joints or ``m`` cables); 0 where the gap before is 0.

        Raises:
            KeyError: ``group`` was not diagnosed.
        """
        before, after = self.gap_before[group], self.gap_after[group]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(before > 0, 1.0 - after / before, 0.0)

    def gap_rows(self, group: str) -> list[tuple[str, float, float, float]]:
        """``(channel, before, after, shrink)`` of each channel of a group.

        Args:
            group: A diagnosed channel group (``"joint"``, ``"drive"`` or ``"length"``).

        Returns:
            One tuple per channel, in channel order: its name, the held-out RMSE before and
            after (in the group's unit, :data:`~msarm.diagnose.builder.GROUP_UNITS`) and the
            shrink [-].

        Raises:
            KeyError: ``group`` was not diagnosed.
        """
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
        """``1 - RMSE_after / RMSE_before`` of one group, pooled over its channels [-].

        Args:
            group: A diagnosed channel group (``"joint"``, ``"drive"`` or ``"length"``).

        Returns:
            The pooled shrink [-] (1: gap removed, negative: gap grown); 0 when the gap
            before is 0.

        Raises:
            KeyError: ``group`` was not diagnosed.
        """
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
        """A JSON-ready dict of the whole diagnosis.

        Returns:
            Plain data keyed like the attributes (``selected`` as :meth:`SelectedEffect.as_dict`
            dicts), with ``gap`` (per group: unit, shrink and each channel's before, after and
            shrink) in place of ``gap_before`` / ``gap_after`` and with ``total_shrink``;
            non-finite step scores are ``None``. The keys are documented in the README
            ("Sim-to-real gap diagnosis", the keys of ``diagnosis.json``).
        """
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
            "search": dict(self.search),
            "log_warnings": list(self.log_warnings),
            "shortlisted": [list(names) for names in self.shortlisted],
            "residual_spec": dict(self.residual_spec),
            "model": dict(self.model),
            "code_fingerprint": self.code_fingerprint,
            "log_paths": {k: list(v) for k, v in self.log_paths.items()},
            "where": dict(self.where),
        }

    def _parameter_table(self) -> list[str]:
        """Markdown lines: every parameter of the selected effects, one row each."""
        lines = [
            "Every parameter of the named effects (an index that counts joints or cables is "
            "shown by the joint's or cable's name):",
            "",
            "| effect | parameter | value | bootstrap std | unit |",
            "|---|---|---:|---:|---|",
        ]
        for s in self.selected:
            for label, value, std, unit in s.parameter_rows():
                spread = f"{std:.2g}" if np.isfinite(std) else "n/a"
                lines.append(f"| {s.name} | {label} | {value:.4g} | {spread} | {unit} |")
        return lines

    def settings_markdown(self) -> list[str]:
        """Markdown lines: what the answer was made from (model, code, logs, residual settings).

        Returns:
            A ``## Made from`` section (without a blank line at its end); only the items
            recorded (an answer made before they were recorded has the logs' names alone).
        """
        lines = ["## Made from", ""]
        if self.model:
            lines.append(
                f"- model: {self.model.get('name', '')} (`{self.model.get('path', '')}`), "
                f"SHA-256 `{self.model.get('sha256', '')}`"
            )
        if self.code_fingerprint:
            lines.append(
                f"- code fingerprint (msarm.io.code_version, scope diagnosis): "
                f"`{self.code_fingerprint}`"
            )
        paths = self.log_paths or {"train": self.train_runs, "holdout": self.holdout_runs}
        for key, label in (("train", "training logs"), ("holdout", "held-out logs")):
            lines.append(f"- {label}: " + ", ".join(f"`{p}`" for p in paths.get(key, ())))
        if self.residual_spec:
            units = {
                "window": "samples",
                "drum_radius": "m",
                "length_resolution": "m",
                "replay_window": "s",
            }
            flat: list[tuple[str, Any]] = []
            for key, value in self.residual_spec.items():
                pairs = value.items() if isinstance(value, dict) else [(key, value)]
                flat += list(pairs)
            lines.append(
                "- residual settings: "
                + ", ".join(
                    f"{key} {_number(value)}" + (f" {units[key]}" if key in units else "")
                    for key, value in flat
                )
            )
        return lines

    def glossary_markdown(self) -> list[str]:
        """Markdown lines: the terms the report uses, each in a sentence or two.

        Returns:
            A ``## Terms used`` section (without a blank line at its end).
        """
        return [
            "## Terms used",
            "",
            "- **Residuals.** What the nominal model and the logs disagree on, in three "
            "residuals named twice: the diagnosis's channel groups `joint` [N m], `drive` [N] "
            "and `length` [m] are the where breakdown's residual kinds `joint_torque`, "
            "`drive` and `cable_length` (the same residuals; cable lengths about each log's "
            "mean).",
            "- **Explained share** (the held-out score): per group, `1 - sum (r - pred)^2 / "
            "sum r^2` over the held-out samples, an energy share; the score is its mean over "
            "the groups. An explained share `e` shrinks the group's RMSE by `1 - sqrt(1 - e)`: "
            "0.869 is a shrink of 63.8 %, 0.5 one of 29.3 %.",
            "- **Gain when selected**: the rise of the explained share, averaged over the "
            "groups the term acts on, that the term brought when it was selected (its fit at "
            "that step, with the terms selected before it).",
            "- **Screening / joint fit** (candidates tried): a screening score fits each "
            "candidate alone, on thinned samples, the selected terms held fixed; the "
            "shortlist is then fitted jointly with them, and only a shortlisted candidate can "
            "be selected.",
            "- **Shrink** and the effect-by-effect table / waterfall: `1 - RMSE_after / "
            "RMSE_nominal` of the held-out residual (RMSE, not energy), from the final model: "
            "the terms fitted together, then added one by one in selection order; a step's "
            "drop is a share of the nominal RMSE. It need not match the gain when selected, "
            "which is an energy share from the fit at that step.",
            "- **Confidence**: the share of (bootstrap draw of the training runs, held-out "
            "run) pairs in which leaving the term out of the refitted final model loses a "
            "gain that would earn it its place (1: every draw and run needs it); n/a without "
            "a bootstrap.",
            "- **Density** (where): share of the residual energy / share of the time; a hot "
            "spot is a phase or posture cell well above 1.",
        ]

    def to_markdown(self, preamble: bool = True) -> str:
        """The diagnosis as Markdown (tables only; :mod:`msarm.diagnose.report` adds plots).

        Args:
            preamble: Open with what the answer was made from (:meth:`settings_markdown`) and
                the terms it uses (:meth:`glossary_markdown`); the report puts them in its
                own header instead.

        Returns:
            The Markdown text: the selected effects, the held-out gap before and after per
            channel and step by step, the replay (if computed) and the candidates tried,
            confounded and skipped; ends with a newline.
        """
        from msarm.diagnose.select import RELATIVE_GAIN, RELATIVE_GAIN_FLOOR

        lines = ["# Sim-to-real gap diagnosis", ""]
        if preamble:
            lines += [*self.settings_markdown(), "", *self.glossary_markdown(), ""]
        lines.append(
            f"Training runs: {len(self.train_runs)} ({self.n_train} samples); held-out runs: "
            f"{len(self.holdout_runs)} ({self.n_holdout} samples); channel groups: "
            f"{', '.join(self.groups)}. A term is added when it raises the held-out explained "
            "share of the groups it acts on (its gain, the mean over those groups) by more than "
            f"{self.threshold:.3g}, or by more than {RELATIVE_GAIN_FLOOR * self.threshold:.3g} "
            f"and by at least {RELATIVE_GAIN:.3g} of the share those groups leave unexplained; "
            "the held-out score is the explained share averaged over all the groups."
        )
        if self.search:
            short = self.search.get("shortlist")
            lines[-1] += (
                " Each step screens every candidate on at most "
                f"{self.search.get('screen_samples')} samples and fits "
                + ("every one" if short is None else f"the best {short}")
                + " jointly with the effects already named"
                + (
                    f" on at most {self.search['max_samples']} training samples"
                    if "max_samples" in self.search
                    else ""
                )
                + (
                    f", scored on at most {self.search['max_score_samples']} held-out ones"
                    if "max_score_samples" in self.search
                    else ""
                )
                + (
                    " (by blocks); the named effects' parameters, and each bootstrap draw's, are "
                    "their joint optimum (variable projection)"
                    if self.search.get("final_fit") == "projection"
                    else ""
                )
                + (
                    " (by blocks); the named effects' parameters, and each bootstrap draw's, are "
                    "the last step's fit by blocks: their joint optimum (variable projection) "
                    f"was not kept ({self.search.get('final_fit_rejected')})"
                    if self.search.get("final_fit") == "blocks"
                    else ""
                )
                + f"; {self.search.get('n_boot')} bootstrap draws (seed {self.search.get('seed')})."
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
                "gain when selected (fit at that step) | confidence |",
                "|---|---|---|---|---|---|---|",
            ]
            for k, s in enumerate(self.selected, start=1):
                confidence = f"{s.confidence:.2f}" if np.isfinite(s.confidence) else "n/a"
                parameters = ", ".join(s.parameter_texts(equals="="))
                lines.append(
                    f"| {k} | {s.name} | {', '.join(s.groups)} | {parameters} | "
                    f"{s.explained_variance:.3f} | {s.gain:+.3f} | {confidence} |"
                )
            lines += ["", "What each named effect is (its equation):", ""]
            lines += [f"- {s.name}: {s.equation()}" for s in self.selected]
            notes = [f"- {s.name}: {note}" for s in self.selected for note in s.notes]
            if notes:
                lines += ["", "Notes:", "", *notes]
            lines += ["", *self._parameter_table()]
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
            lines += [
                "",
                "Effect by effect: the final model, its terms added in selection order (pooled "
                "held-out RMSE of each group; the waterfall plot shows each drop as a share of "
                "the nominal RMSE):",
                "",
            ]
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
                if b is None or a is None:  # a model without the hand site
                    continue
                share = 100 * (1 - a / b) if b > 0 else 0.0
                lines.append(
                    f"| {label} | {scale * b:.3g} {unit} | {scale * a:.3g} {unit} | {share:.1f} % |"
                )
            if r.get("hand_error_end_before") is None:
                lines += [
                    "",
                    f"No hand error: the model has no `{HAND_SITE}` site (the hand position "
                    "is that site's); the replay is scored by its joint RMSE alone.",
                ]
        lines += ["", "## Candidates tried at each step (held-out gain on their groups)", ""]
        if self.shortlisted:
            lines += [
                "Scores marked (screening) fit the candidate alone on thinned samples, the "
                "effects already named held fixed; the others are joint fits with those effects "
                "(the shortlist, from which a step selects).",
                "",
            ]
        for k, scores in enumerate(self.step_scores, start=1):
            tried = sorted(
                ((n, v) for n, v in scores.items() if np.isfinite(v)), key=lambda kv: -kv[1]
            )
            held_back = [n for n, v in scores.items() if not np.isfinite(v)]
            joint = set(self.shortlisted[k - 1]) if k <= len(self.shortlisted) else None
            text = ", ".join(
                f"{n} {v:+.3f}" + ("" if joint is None or n in joint else " (screening)")
                for n, v in tried
            )
            if held_back:
                text += f" (not tried, confounded: {', '.join(held_back)})"
            lines.append(f"{k}. {text}")
        if self.confounded:
            lines += ["", "## Candidates the data cannot tell apart from a selected one", ""]
            lines += [f"- {name}: {why}" for name, why in self.confounded.items()]
        if self.skipped:
            lines += ["", "## Candidates not tried", ""]
            lines += [f"- {name}: {why}" for name, why in self.skipped.items()]
        if self.log_warnings:
            lines += ["", "## What the logs lacked (warnings)", ""]
            lines += [f"- {text}" for text in self.log_warnings]
        return "\n".join(lines) + "\n"
