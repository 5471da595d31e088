"""The normalised stack of channel groups and the fits on it (used by :mod:`.select`).

The residuals of the diagnosis come in channel groups (joint torque, drive, cable length),
each divided by its training spread and set side by side (:class:`Layout`); every candidate is
placed in its groups' columns (:class:`Embedded`). :class:`Sampled` holds the (thinned)
samples the selection fits and scores on, with the linear terms' designs and the nonlinear
terms' IPOPT problems cached; :func:`fit_together` fits a set of terms jointly;
:class:`Confounding` tells when a candidate cannot be told apart from those chosen. These are
the diagnosis's internals: their interface may change.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.builder import GROUPS
from msarm.diagnose.effects import NUMPY_OPS, CandidateEffect, NumpyOps, Ops
from msarm.diagnose.fitting import BlockSolver, LinearSolver, _NonlinearProblem
from msarm.diagnose.projection import ProjectedProblem
from msarm.diagnose.residuals import ResidualSpec
from msarm.diagnose.signals import Signals
from msarm.errors import InputError
from msarm.model import RobotModel

__all__ = [
    "BACKFIT_ROUNDS",
    "BACKFIT_TOLERANCE",
    "CONFOUNDING_LIMIT",
    "MAX_FIT_SAMPLES",
    "MAX_SCORE_SAMPLES",
    "Confounding",
    "DiagnosisData",
    "Embedded",
    "FittedModel",
    "Layout",
    "OwnColumns",
    "Sampled",
    "Stacked",
    "channel_rmse",
    "fit_together",
    "group_scores",
    "own_gain",
    "pooled_rmse",
]

FloatArray = NDArray[np.float64]

#: Largest canonical correlation between a candidate's regressor and those of the terms
#: already selected (training runs) for the candidate to be tried: above it, the data cannot
#: tell the two apart (e.g. a load-cell scale error, whose regressor is the measured cable
#: torque, against the links' mass error, whose regressor spans the inverse dynamics that
#: torque balances), and their joint fit would trade one for the other [-].
CONFOUNDING_LIMIT = 0.99
#: The selection fits on at most this many training samples, evenly thinned. Thinning
#: drops rows of the regression, not content (designs with memory see whole runs), so it
#: costs only precision, as ``1/sqrt(N)``: on the withheld-effect benchmark (10,000 training
#: samples a scenario) fitting on 5,000 named the same effects in all 29 scenarios, with
#: held-out gaps within 0.25 % and the main parameters within their noise, in two thirds of
#: the time; the fits' IPOPT solves scale with the samples.
MAX_FIT_SAMPLES = 5_000
#: The selection scores on at most this many held-out samples, evenly thinned: the held-out
#: gains decide what is added, and scoring costs only predictions, so it keeps more.
MAX_SCORE_SAMPLES = 20_000
#: Most rounds of a joint fit by blocks (:func:`fit_together`) [-].
BACKFIT_ROUNDS = 10
#: A joint fit by blocks stops once a round lowers the training error by less than this [-].
BACKFIT_TOLERANCE = 1e-4
#: The key of the linear block's prediction in :func:`fit_together` (no term's ``id``).
_LINEAR_BLOCK = 0
#: How many variable-projection problems a :class:`Sampled` keeps (the last built; each holds
#: its set's design on the fitting samples, twice: numpy's and casadi's copy).
_PROJECTIONS_KEPT = 2
#: How many factored designs of blocks of several linear terms a :class:`Sampled` keeps (the
#: last used; see :meth:`Sampled.solver`).
_BLOCKS_KEPT = 8
#: Of the fitting samples, every this many enter the confounding test.
_CONFOUNDING_STRIDE = 8


class Layout:
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

    def size(self, group: str) -> int:
        """Number of columns of a group."""
        return self.slices[group].stop - self.slices[group].start

    def stack(self, groups: dict[str, FloatArray]) -> FloatArray:
        """Group residuals ``{g: (T, k_g)}`` -> the normalised stack ``(T, W)``."""
        return np.concatenate([groups[g] / self.spread[g] for g in self.groups], axis=1)

    def unstack(self, stacked: FloatArray) -> dict[str, FloatArray]:
        """The normalised stack ``(T, W)`` -> group residuals in their units."""
        return {g: stacked[:, self.slices[g]] * self.spread[g] for g in self.groups}


class Embedded(CandidateEffect):
    """A term's prediction placed in its groups' columns of the normalised stack."""

    def __init__(self, term: CandidateEffect, layout: Layout) -> None:
        self.term, self.layout = term, layout
        self.name = term.name  # type: ignore[misc]
        self.description = term.description  # type: ignore[misc]
        self.linear = term.linear  # type: ignore[misc]
        self.memoryless = term.memoryless  # type: ignore[misc]
        self.parameter_names = term.parameter_names
        self.channels = tuple(range(layout.width))
        self.groups = layout.groups

    def width(self, signals: Signals) -> int:  # noqa: D102
        return self.layout.width

    def check(self, signals: Signals) -> None:  # noqa: D102
        self.term.check(signals)

    def own_parts(self, inner: Any, ops: Ops = NUMPY_OPS) -> dict[str, Any]:
        """The term's own output ``(T, W_term, ...)`` split by group, in stack units.

        The groups' spreads enter as ``ops`` data (a solver built with
        :class:`~msarm.diagnose.nlp.DataOps` then serves data of any spreads).
        """
        parts, start = {}, 0
        for g in self.term.groups:
            size = self.layout.size(g)
            parts[g] = inner[:, start : start + size] / ops.const(np.array(self.layout.spread[g]))
            start += size
        return parts

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        parts = self.own_parts(self.term.design(signals))
        first = next(iter(parts.values()))
        out = np.zeros((first.shape[0], self.layout.width, first.shape[2]))
        for g, part in parts.items():
            out[:, self.layout.slices[g], :] = part
        return out

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:  # noqa: D102
        if self.linear and isinstance(ops, NumpyOps):
            return np.einsum("tnp,p->tn", self.design(signals), np.asarray(theta, dtype=float))
        parts = self.own_parts(self.term.torque(signals, theta, ops), ops)
        zeros = {
            g: ops.const(np.zeros((signals.n_samples, self.layout.size(g))))
            for g in self.layout.groups
            if g not in parts
        }
        return ops.hcat([parts[g] if g in parts else zeros[g] for g in self.layout.groups])

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

    def constraints(self) -> FloatArray:  # noqa: D102
        return self.term.constraints()

    def own_columns(self) -> NDArray[np.intp]:
        """Columns of the stack the term's groups occupy, in the term's group order."""
        return np.concatenate(
            [np.arange(self.layout.width)[self.layout.slices[g]] for g in self.term.groups]
        )


class OwnColumns(CandidateEffect):
    """An embedded nonlinear term restricted to its own columns (smaller IPOPT problems).

    The columns it does not touch add a constant to the fit's objective, so the optimum on
    its own columns is the optimum on the whole stack.
    """

    def __init__(self, embedded: Embedded) -> None:
        self.embedded = embedded
        self.name = embedded.name  # type: ignore[misc]
        self.linear = False  # type: ignore[misc]
        self.parameter_names = embedded.parameter_names
        self.columns = embedded.own_columns()
        self.channels = tuple(range(len(self.columns)))

    def width(self, signals: Signals) -> int:  # noqa: D102
        return len(self.columns)

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:  # noqa: D102
        inner = self.embedded.term.torque(signals, theta, ops)
        return ops.hcat(list(self.embedded.own_parts(inner, ops).values()))

    def initial_guess(  # noqa: D102
        self, signals: Signals, residual: FloatArray | None = None
    ) -> FloatArray:
        if residual is None:
            return self.embedded.term.initial_guess(signals)
        layout = self.embedded.layout
        spread = [np.full(layout.size(g), layout.spread[g]) for g in self.embedded.term.groups]
        return self.embedded.term.initial_guess(signals, residual * np.concatenate(spread))

    def bounds(self) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        return self.embedded.term.bounds()

    def constraints(self) -> FloatArray:  # noqa: D102
        return self.embedded.term.constraints()


class Stacked(CandidateEffect):
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


class Sampled:
    """The samples the selection fits and scores on, with the linear terms' designs cached.

    Long logs are thinned evenly to at most ``max_samples`` training and ``max_hold``
    held-out samples (designs are computed on the whole runs first, so terms with memory, such
    as the Dahl state or the delay taps, see every sample; a ``memoryless`` term's design, on
    the thinned samples only; nonlinear terms are evaluated on the thinned samples and must be
    per-sample).
    """

    def __init__(
        self,
        data: DiagnosisData,
        max_samples: int,
        parent: Sampled | None = None,
        max_hold: int | None = None,
    ) -> None:
        """Thin the data to ``max_samples`` training and ``max_hold`` held-out samples.

        ``max_hold`` is ``max_samples`` when None. With a ``parent``, pick among its samples:
        a child's samples are evenly thinned from its parent's, and its linear designs are the
        parent's rows (computed once, by the parent).
        """
        self.full = {"train": data.train, "hold": data.hold}
        self.parent = parent
        limit = {"train": max_samples, "hold": max_samples if max_hold is None else max_hold}
        if parent is None:
            self.rows = {
                split: _even_rows(sig.n_samples, limit[split]) for split, sig in self.full.items()
            }
        else:
            self.within = {
                split: _even_rows(len(rows), limit[split]) for split, rows in parent.rows.items()
            }
            self.rows = {split: parent.rows[split][self.within[split]] for split in parent.rows}
        self.signals = {split: sig.take(self.rows[split]) for split, sig in self.full.items()}
        self.residual = {
            "train": data.r_train[self.rows["train"]],
            "hold": data.r_hold[self.rows["hold"]],
        }
        # the caches are keyed by the terms' ids: each term is held here, so that its id
        # stays its own (a term freed could pass its id, and its cached design, to another)
        self._terms: dict[int, CandidateEffect] = {}
        self._designs: dict[tuple[int, str], FloatArray] = {}
        self._problems: dict[int, _NonlinearProblem] = {}
        self._solutions: dict[tuple[int, bytes], tuple[FloatArray, str]] = {}
        self._joint_design: tuple[tuple[int, ...], FloatArray] | None = None
        self._solvers: dict[tuple[int, ...], LinearSolver | BlockSolver] = {}
        self._set: tuple[int, ...] | None = None  # the key of the last set of several terms
        self._blocks: dict[tuple[int, ...], LinearSolver] = {}
        self._projections: dict[tuple[tuple[int, ...], tuple[int, ...]], ProjectedProblem] = {}
        self._own_designs: dict[tuple[int, str], tuple[NDArray[np.intp], FloatArray]] = {}

    def _key(self, term: CandidateEffect) -> int:
        """The term's id as a cache key, the term held for as long as this object lives."""
        self._terms[id(term)] = term
        return id(term)

    def fit_nonlinear(
        self,
        term: Embedded,
        residual: FloatArray,
        initial: FloatArray | None = None,
        weights: FloatArray | None = None,
    ) -> tuple[FloatArray, str]:
        """Fit a nonlinear term to the training ``residual`` (stack columns) by IPOPT.

        The problem (on the term's own columns) is built once per term and reused. A fit asked
        again with the same residual on those columns, weights and start (the selection and
        the bootstrap do, a fifth of the time) returns the answer of the first: the solver is
        deterministic, so it is the same answer.
        """
        if self._key(term) not in self._problems:
            own = OwnColumns(term)
            self._problems[id(term)] = _NonlinearProblem(
                own, self.signals["train"], self.residual["train"][:, own.columns]
            )
        problem = self._problems[id(term)]
        columns = problem.effect.columns
        own_residual = np.ascontiguousarray(residual[:, columns], dtype=float)
        digest = hashlib.blake2b(own_residual.tobytes(), digest_size=20)
        for extra in (weights, initial):
            digest.update(b"-" if extra is None else np.asarray(extra, dtype=float).tobytes())
        key = (id(term), digest.digest())
        if key not in self._solutions:
            theta, _, message = problem.solve(initial, weights, own_residual)
            self._solutions[key] = (theta, message)
        theta, message = self._solutions[key]
        return theta.copy(), message

    def design(self, term: CandidateEffect, split: str) -> FloatArray:
        """A linear term's design on the ``"train"`` or ``"hold"`` samples (computed once)."""
        key = (self._key(term), split)
        if key not in self._designs:
            if self.parent is not None:
                self._designs[key] = self.parent.design(term, split)[self.within[split]]
            else:
                if term.memoryless:  # no need of the whole runs: only the rows used
                    design = term.design(self.signals[split])
                else:
                    design = term.design(self.full[split])[self.rows[split]]
                if not np.all(np.isfinite(design)):
                    row = int(np.argwhere(~np.isfinite(design))[0][0])
                    raise InputError(
                        f"{term.name}: design() has a non-finite value (NaN or inf) on the "
                        f"{split} samples (sample {row} of those the fits use)"
                    )
                self._designs[key] = design
        return self._designs[key]

    def joint_design(self, terms: Sequence[CandidateEffect]) -> FloatArray:
        """Linear terms' training designs side by side, ``(T, W, sum p)``.

        The last set asked for is kept: a bootstrap refits the same set at every draw.
        """
        key = tuple(self._key(t) for t in terms)
        if self._joint_design is None or self._joint_design[0] != key:
            design = np.concatenate([self.design(t, "train") for t in terms], axis=2)
            self._joint_design = (key, design)
        return self._joint_design[1]

    def solver(self, terms: Sequence[CandidateEffect]) -> LinearSolver | BlockSolver:
        """The least-squares solver of linear terms' joint training design (factored once).

        Terms that share no stack column (:func:`_connected`) are factored apart, by blocks
        (:class:`~msarm.diagnose.fitting.BlockSolver`: the same solution to round-off). Kept
        for each single term (the screening refits each candidate at every step), for the
        last :data:`_BLOCKS_KEPT` blocks of several terms (the chosen terms' blocks serve
        every candidate a step fits with them, and the next steps) and for the last set (a
        joint fit refits the set at every round).
        """
        key = tuple(self._key(t) for t in terms)
        if key in self._solvers:
            return self._solvers[key]
        if len(key) == 1:  # its own design: no copy, the joint set's cache kept
            self._solvers[key] = LinearSolver(self.design(terms[0], "train"))
            return self._solvers[key]

        def factor(block: Sequence[int], cut: float | None) -> LinearSolver:
            members = [terms[k] for k in block]
            return (
                self._block(members) if cut is None else LinearSolver(self._stacked(members), cut)
            )

        solver = self._by_blocks(terms, factor)
        if self._set is not None:
            self._solvers.pop(self._set, None)
        self._set = key
        self._solvers[key] = solver
        return solver

    def _by_blocks(
        self,
        terms: Sequence[CandidateEffect],
        factor: Callable[[Sequence[int], float | None], LinearSolver],
    ) -> LinearSolver | BlockSolver:
        """The solver of linear terms, a block at a time (:func:`_linear_blocks`).

        ``factor(block, cut)`` factors the design of the terms ``block`` (indices into
        ``terms``), with that singular-value cut (None: the block's own).
        """
        blocks = _linear_blocks(terms)
        if len(blocks) == 1:
            return factor(blocks[0], None)
        start = np.concatenate([[0], np.cumsum([t.n_parameters for t in terms])])
        parts = [
            (
                np.concatenate([np.arange(start[k], start[k + 1]) for k in block]),
                factor(block, None),
            )
            for block in blocks
        ]
        shape = (*self.residual["train"].shape, int(start[-1]))
        return BlockSolver(parts, shape, lambda k, cut: factor(blocks[k], cut))

    def _block(self, terms: Sequence[CandidateEffect]) -> LinearSolver:
        """The factored design of terms that share stack columns (kept: see :meth:`solver`)."""
        key = tuple(self._key(t) for t in terms)
        if len(key) == 1:
            return cast(LinearSolver, self.solver(terms))
        if key not in self._blocks:
            if len(self._blocks) >= _BLOCKS_KEPT:
                self._blocks.pop(next(iter(self._blocks)))
            self._blocks[key] = LinearSolver(self._stacked(terms))
        else:  # the most recently used last: the oldest is dropped first
            self._blocks[key] = self._blocks.pop(key)
        return self._blocks[key]

    def _stacked(self, terms: Sequence[CandidateEffect]) -> FloatArray:
        """Terms' training designs side by side (not kept, unlike :meth:`joint_design`)."""
        return np.concatenate([self.design(t, "train") for t in terms], axis=2)

    def weighted_solver(
        self, terms: Sequence[CandidateEffect], weights: FloatArray | None
    ) -> Callable[[FloatArray], FloatArray]:
        """Least squares of linear terms' joint training design with per-sample weights.

        Returns:
            A function of a training residual ``(T, W)`` giving the terms' stacked parameters:
            :meth:`solver`'s (kept) without weights; with them, the weighted design factored
            once for this call's repeated solves (a bootstrap draw), by blocks as in
            :meth:`solver`.
        """
        if weights is None:
            return self.solver(terms).solve
        root = np.sqrt(np.asarray(weights, dtype=float))[:, None]

        def factor(block: Sequence[int], cut: float | None) -> LinearSolver:
            design = self._stacked([terms[k] for k in block]) * root[:, :, None]
            return LinearSolver(design, cut)

        solver = self._by_blocks(terms, factor)
        return lambda residual: solver.solve(residual * root)

    def projection(
        self, linear: Sequence[Embedded], nonlinear: Sequence[Embedded]
    ) -> ProjectedProblem:
        """The variable-projection problem of a coupled set on the training samples.

        Built once per set (IPOPT's problem, the design on the set's columns) and kept for
        the last few sets: a bootstrap refits the chosen set at every draw.
        """
        key = (tuple(self._key(t) for t in linear), tuple(self._key(t) for t in nonlinear))
        if key not in self._projections:
            own = [OwnColumns(t) for t in nonlinear]
            columns = np.array(
                sorted({int(c) for t in [*linear, *nonlinear] for c in t.own_columns()}),
                dtype=np.intp,
            )
            design = self.joint_design(linear)[:, columns, :] if linear else None
            if len(self._projections) >= _PROJECTIONS_KEPT:
                self._projections.pop(next(iter(self._projections)))
            self._projections[key] = ProjectedProblem(
                own, [o.columns for o in own], columns, design, self.signals["train"]
            )
        return self._projections[key]

    def predict(self, term: CandidateEffect, theta: FloatArray, split: str) -> FloatArray:
        """A term's prediction on the ``"train"`` or ``"hold"`` samples, ``(T, W)``.

        A linear term's on its own columns only (its design is zero in the others).
        """
        if not term.linear:
            return np.asarray(term.torque(self.signals[split], theta, NUMPY_OPS), dtype=float)
        if not isinstance(term, Embedded):
            return np.einsum("tnp,p->tn", self.design(term, split), theta)
        columns, design = self._own_design(term, split)
        out = np.zeros(self.residual[split].shape)
        out[:, columns] = np.einsum("tnp,p->tn", design, theta)
        return out

    def _own_design(self, term: Embedded, split: str) -> tuple[NDArray[np.intp], FloatArray]:
        """A linear term's stack columns and its design on them alone (computed once)."""
        key = (self._key(term), split)
        if key not in self._own_designs:
            columns = term.own_columns()
            design = np.ascontiguousarray(self.design(term, split)[:, columns, :])
            self._own_designs[key] = (columns, design)
        return self._own_designs[key]


def _even_rows(n: int, limit: int) -> NDArray[np.intp]:
    if n <= limit:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, limit).round().astype(np.intp))


@dataclass(frozen=True)
class FittedModel:
    """A fitted combination of terms: parameters by term, in the given order."""

    terms: tuple[CandidateEffect, ...]
    parameters: tuple[FloatArray, ...]
    messages: tuple[str, ...]

    def predict(self, sampled: Sampled, split: str) -> FloatArray:
        """The terms' summed prediction on a split of ``sampled``, ``(T, W)``."""
        out = np.zeros_like(sampled.residual[split])
        for term, theta in zip(self.terms, self.parameters, strict=True):
            out += sampled.predict(term, theta, split)
        return out


def fit_together(
    terms: Sequence[CandidateEffect],
    sampled: Sampled,
    weights: FloatArray | None = None,
    initial: Sequence[FloatArray | None] | None = None,
    rounds: int = BACKFIT_ROUNDS,
    method: str = "projection",
) -> FittedModel:
    """Joint fit of ``terms`` to the training residual: the least squares of their sum.

    The terms fall into sets that share stack columns (directly or through one another); sets
    that share none are fitted apart (their objectives add up). In each set:

    - linear terms alone: one stacked least squares;
    - one nonlinear term alone: IPOPT (:meth:`Sampled.fit_nonlinear`);
    - otherwise (``method="projection"``, the default): the joint optimum by variable
      projection (:class:`~msarm.diagnose.projection.ProjectedProblem`): IPOPT on the
      nonlinear parameters with the linear ones eliminated, then the linear ones by least
      squares;
    - with ``method="blocks"``: backfitting, as before 2026-11-28: the linear terms as one
      block and each nonlinear term as a block of its own, refitted in turn to what the others
      leave until a round lowers the training error by less than :data:`BACKFIT_TOLERANCE`
      (relative) or after ``rounds`` rounds. Strongly correlated blocks (a viscous or Dahl
      term beside a Stribeck term) converge slowly and stop short of the optimum: on the
      withheld-effect benchmark's joint-friction scenarios the Stribeck and Dahl parameters
      stopped up to 5 bootstrap standard deviations from it (a test: about 2,000 rounds to
      reach it). The selection's search fits by blocks (faster; the same choices).

    Args:
        terms: The terms, each embedded in the stack (:class:`Embedded`; other terms are
            fitted by blocks, as one set).
        sampled: The samples.
        weights: Per-sample weights of the training samples, ``(T,)`` (a bootstrap's run
            counts); all 1 when ``None``.
        initial: Starting parameters of each term (nonlinear ones start there); a ``None``
            entry starts that term from its own initial guess (a candidate added to fitted
            terms).
        rounds: Most rounds of ``method="blocks"``.
        method: ``"projection"`` or ``"blocks"``.

    Raises:
        InputError: An unknown ``method``.
    """
    if method not in ("projection", "blocks"):
        raise InputError(f"method: expected 'projection' or 'blocks', got {method!r}")
    start: dict[int, FloatArray] = {}
    if initial is not None:
        for term, theta in zip(terms, initial, strict=True):
            if theta is not None:
                start[id(term)] = np.asarray(theta, dtype=float)
    if method == "blocks" or not all(isinstance(t, Embedded) for t in terms):
        return _fit_by_blocks(terms, sampled, weights, start, rounds)
    r = sampled.residual["train"]
    parameters: dict[int, FloatArray] = {}
    messages: dict[int, str] = {}
    alone: list[CandidateEffect] = []  # linear sets: one least squares for all of them
    for members in _connected(terms):
        linear = [t for t in members if t.linear]
        nonlinear = [t for t in members if not t.linear]
        if not nonlinear:
            alone += linear
        elif len(nonlinear) == 1 and not linear:
            term = nonlinear[0]
            parameters[id(term)], messages[id(term)] = sampled.fit_nonlinear(
                term, r, start.get(id(term)), weights
            )
        else:
            problem = sampled.projection(linear, nonlinear)
            own = problem.columns
            first = [
                start[id(t)] if id(t) in start else t.initial_guess(sampled.signals["train"], r)
                for t in nonlinear
            ]
            predict = [
                lambda theta, t=t: sampled.predict(t, theta, "train")[:, t.own_columns()]
                for t in nonlinear
            ]
            thetas, stacked, status = problem.solve(r[:, own], predict, first, weights)
            for term, theta in zip(nonlinear, thetas, strict=True):
                parameters[id(term)], messages[id(term)] = theta, f"{status} (joint)"
            if linear:
                for term, part in zip(linear, Stacked(linear).split(stacked), strict=True):
                    parameters[id(term)], messages[id(term)] = part, "least squares (joint)"
    if alone:
        theta = sampled.weighted_solver(alone, weights)(r)
        for term, part in zip(alone, Stacked(alone).split(theta), strict=True):
            parameters[id(term)], messages[id(term)] = part, "least squares (joint)"
    return FittedModel(
        terms=tuple(terms),
        parameters=tuple(parameters[id(t)] for t in terms),
        messages=tuple(messages[id(t)] for t in terms),
    )


def _connected(terms: Sequence[Embedded]) -> list[list[Embedded]]:
    """The terms in sets that share stack columns, directly or through one another.

    Sets in the order of their first term, each in the terms' order.
    """
    sets: list[tuple[set[int], list[Embedded]]] = []
    for term in terms:
        columns = {int(c) for c in term.own_columns()}
        merged: list[Embedded] = [term]
        kept = []
        for other_columns, members in sets:  # the sets are disjoint: one pass merges
            if other_columns & columns:
                columns |= other_columns
                merged = members + merged
            else:
                kept.append((other_columns, members))
        sets = [*kept, (columns, merged)]
    order = {id(t): k for k, t in enumerate(terms)}
    ordered = [sorted(members, key=lambda t: order[id(t)]) for _, members in sets]
    return sorted(ordered, key=lambda members: order[id(members[0])])


def _linear_blocks(terms: Sequence[CandidateEffect]) -> list[list[int]]:
    """Indices of linear terms in sets whose designs share rows (:func:`_connected`).

    Terms not :class:`Embedded` (whose rows are not known) make one set.
    """
    if not all(isinstance(t, Embedded) for t in terms):
        return [list(range(len(terms)))]
    position = {id(t): k for k, t in enumerate(terms)}
    if len(position) < len(terms):  # a term given twice: one set
        return [list(range(len(terms)))]
    return [[position[id(t)] for t in members] for members in _connected(terms)]


def _fit_by_blocks(
    terms: Sequence[CandidateEffect],
    sampled: Sampled,
    weights: FloatArray | None,
    start: dict[int, FloatArray],
    rounds: int,
) -> FittedModel:
    """Backfitting (``fit_together``'s ``method="blocks"``)."""
    r = sampled.residual["train"]
    w = np.ones(r.shape[0]) if weights is None else np.asarray(weights, dtype=float)
    linear = [t for t in terms if t.linear]
    nonlinear = [t for t in terms if not t.linear]
    parameters: dict[int, FloatArray] = dict(start)
    messages: dict[int, str] = dict.fromkeys(map(id, linear), "least squares (joint)")
    prediction: dict[int, FloatArray] = {
        id(t): sampled.predict(t, parameters[id(t)], "train")
        for t in nonlinear
        if id(t) in parameters
    }
    design = sampled.joint_design(linear) if linear else None
    if design is not None:
        solve = sampled.weighted_solver(linear, weights)  # the weighted design factored once

    def left_by(block: int | None) -> FloatArray:
        """The residual less every block's prediction but ``block``'s (all when None)."""
        return r - sum((v for k, v in prediction.items() if k != block), np.zeros_like(r))

    best = np.inf
    for _ in range(rounds if _coupled(linear, nonlinear) else 1):
        if design is not None:
            left = left_by(_LINEAR_BLOCK)
            theta = solve(left)
            for term, part in zip(linear, Stacked(linear).split(theta), strict=True):
                parameters[id(term)] = part
            prediction[_LINEAR_BLOCK] = np.einsum("tnp,p->tn", design, theta)
        for term in nonlinear:
            theta, messages[id(term)] = sampled.fit_nonlinear(
                term, left_by(id(term)), parameters.get(id(term)), weights
            )
            parameters[id(term)] = theta
            prediction[id(term)] = sampled.predict(term, theta, "train")
        error = float(np.sum(w[:, None] * left_by(None) ** 2))
        if not error < best * (1.0 - BACKFIT_TOLERANCE):
            break
        best = error
    return FittedModel(
        terms=tuple(terms),
        parameters=tuple(parameters[id(t)] for t in terms),
        messages=tuple(messages[id(t)] for t in terms),
    )


def _coupled(linear: Sequence[CandidateEffect], nonlinear: Sequence[CandidateEffect]) -> bool:
    """Whether the blocks of a joint fit share stack columns (else one pass is exact)."""
    blocks = ([linear] if linear else []) + [[t] for t in nonlinear]
    if len(blocks) < 2:
        return False
    if not all(isinstance(t, Embedded) for block in blocks for t in block):
        return True
    seen: set[int] = set()
    for block in blocks:
        columns = {int(c) for t in block for c in t.own_columns()}
        if seen & columns:
            return True
        seen |= columns
    return False


def group_scores(layout: Layout, residual: FloatArray, prediction: FloatArray) -> dict[str, float]:
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


class Confounding:
    """Orthonormal bases of linear terms' training regressors, for the confounding test."""

    def __init__(self, sampled: Sampled) -> None:
        self.sampled = sampled
        self.cache: dict[int, FloatArray] = {}
        self._span: tuple[tuple[int, ...], FloatArray] | None = None

    def basis(self, term: CandidateEffect) -> FloatArray:
        """An orthonormal basis of a linear term's (thinned) training regressor."""
        if id(term) not in self.cache:
            design = self.sampled.design(term, "train")[::_CONFOUNDING_STRIDE]
            matrix = design.reshape(-1, design.shape[2])
            matrix = matrix / np.maximum(np.linalg.norm(matrix, axis=0), 1e-300)
            u, singular, _ = np.linalg.svd(matrix, full_matrices=False)
            keep = singular > 1e-8 * max(float(singular.max(initial=0.0)), 1e-300)
            self.cache[id(term)] = u[:, keep]
        return self.cache[id(term)]

    def span(self, terms: Sequence[CandidateEffect]) -> FloatArray:
        """An orthonormal basis of linear terms' regressors together (the last set's kept)."""
        key = tuple(id(t) for t in terms)
        if self._span is None or self._span[0] != key:
            together = np.concatenate([self.basis(t) for t in terms], axis=1)
            span, singular, _ = np.linalg.svd(together, full_matrices=False)
            self._span = (key, span[:, singular > 1e-8 * singular.max(initial=1.0)])
        return self._span[1]

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
        span = self.span(linear)
        correlation = float(np.linalg.svd(own.T @ span, compute_uv=False).max(initial=0.0))
        if correlation <= CONFOUNDING_LIMIT:
            return None
        names = ", ".join(t.name for t in linear)
        return (
            f"its regressor lies in the span of {names} (canonical correlation "
            f"{correlation:.4f} > {CONFOUNDING_LIMIT})"
        )


def own_gain(groups: Sequence[str], before: dict[str, float], after: dict[str, float]) -> float:
    """Gain of the explained share, averaged over the groups a term acts on [-]."""
    return float(np.mean([after[g] - before[g] for g in groups]))


def channel_rmse(values: FloatArray) -> FloatArray:
    """RMS of each column, ``(T, k) -> (k,)``."""
    return np.sqrt(np.mean(values**2, axis=0))


def pooled_rmse(values: FloatArray) -> float:
    """RMS over all entries."""
    return float(np.sqrt(np.mean(values**2)))


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
        spec: The residual settings the logs were read with; the held-out replay of the
            result (the gap as motion) uses its window, steps and source too.
        log_paths: The logs' absolute paths, ``{"train": (...), "holdout": (...)}`` in the
            order of ``train_runs`` and ``holdout_runs``; empty when not known.
    """

    model: RobotModel
    train: Signals
    hold: Signals
    layout: Layout
    r_train: FloatArray
    r_hold: FloatArray
    candidates: tuple[Embedded, ...]
    skipped: dict[str, str]
    train_runs: tuple[str, ...]
    holdout_runs: tuple[str, ...]
    channel_names: dict[str, tuple[str, ...]]
    spec: ResidualSpec = field(default_factory=ResidualSpec)
    log_paths: dict[str, tuple[str, ...]] = field(default_factory=dict)
