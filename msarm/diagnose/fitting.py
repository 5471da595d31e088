"""Fit a candidate effect to a joint-torque residual and judge it on held-out samples.

:func:`fit` minimises ``sum over samples and joints of (r - torque(theta))^2`` on the training
samples: by linear least squares (``numpy.linalg.lstsq`` on column-normalised regressors) for a
linear candidate, by IPOPT (``casadi.nlpsol``, exact Hessian, within the candidate's bounds)
for a nonlinear one. :meth:`FitResult.explained_variance` scores the fitted term on samples it
was not fitted on; :func:`bootstrap` gives the parameters' spread by resampling whole runs
(samples within a run are correlated, so resampling samples would understate it).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import ParamSpec, TypeVar

import casadi
import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from msarm.diagnose.builder import GROUPS
from msarm.diagnose.effects import NUMPY_OPS, CandidateEffect
from msarm.diagnose.nlp import IPOPT_OPTIONS, BufferedNlpsol, DataOps, shared_solver
from msarm.diagnose.signals import Signals
from msarm.errors import InputError
from msarm.interrupts import raise_if_terminated

__all__ = [
    "IPOPT_OPTIONS",
    "BlockSolver",
    "BootstrapResult",
    "BufferedNlpsol",
    "FitResult",
    "INDEXED_BY",
    "LinearSolver",
    "bootstrap",
    "bounds_of",
    "check_interface",
    "column_scale",
    "constraint_matrix",
    "fit",
    "one_blas_thread",
    "stacked_constraints",
]

P = ParamSpec("P")
R = TypeVar("R")

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class FitResult:
    """A candidate effect fitted to a residual.

    Attributes:
        effect: The fitted candidate.
        parameters: Fitted parameters ``theta`` (units of ``effect.parameter_names``), ``(p,)``.
        rms_before: RMS of the residual on the training samples [N m].
        rms_after: RMS of the residual minus the fitted term on the training samples [N m].
        n_train: Number of training samples.
        success: Whether the solver reports convergence (always true for least squares).
        message: Solver status.
    """

    effect: CandidateEffect
    parameters: FloatArray
    rms_before: float
    rms_after: float
    n_train: int
    success: bool
    message: str

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the parameters, in the order of :attr:`parameters`."""
        return self.effect.parameter_names

    @property
    def reduction(self) -> float:
        """Training residual reduction ``1 - sum(e^2) / sum(r^2)`` [-] (1: all explained)."""
        if self.rms_before == 0.0:
            return 0.0
        return 1.0 - (self.rms_after / self.rms_before) ** 2

    def as_dict(self) -> dict[str, float]:
        """Parameters by name."""
        return dict(zip(self.parameter_names, map(float, self.parameters), strict=True))

    def predict(self, signals: Signals) -> FloatArray:
        """The fitted term's predicted residual [N m], shape ``(T, n)``."""
        return np.asarray(self.effect.torque(signals, self.parameters, NUMPY_OPS), dtype=float)

    def explained_variance(
        self,
        signals: Signals,
        residual: FloatArray,
        mask: NDArray[np.bool_] | None = None,
        per_joint: bool = False,
    ) -> float | FloatArray:
        """Share of the residual's variance the fitted term explains on the samples ``mask``.

        ``1 - var(r - pred) / var(r)``, variances about each joint's mean, pooled over joints
        (or one value per joint with ``per_joint``). Pass the samples the term was *not* fitted
        on. 1: all explained; 0: nothing; negative: the term makes the residual worse.

        Args:
            signals: Signals of the samples, ``T`` of them.
            residual: The residual ``r`` [N m], shape ``(T, n)``.
            mask: Samples to score, boolean ``(T,)``; all when ``None``.
            per_joint: Return one value per joint, shape ``(n,)``.

        Raises:
            InputError: Wrong shapes, non-finite residual, an empty mask, or a residual
                without variance.
        """
        residual = _check_residual(signals, residual, self.effect)
        mask = _check_mask(signals, mask, "mask")
        if not mask.any():
            raise InputError("mask: selects no samples")
        r = residual[mask]
        e = r - self.predict(signals)[mask]  # terms with memory run over the whole runs
        var_r = np.sum((r - r.mean(axis=0)) ** 2, axis=0)
        var_e = np.sum((e - e.mean(axis=0)) ** 2, axis=0)
        if per_joint:
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(var_r > 0, 1.0 - var_e / np.where(var_r > 0, var_r, 1.0), np.nan)
        if var_r.sum() <= 0.0:
            raise InputError("residual: no variance on the masked samples")
        return float(1.0 - var_e.sum() / var_r.sum())


@dataclass(frozen=True)
class BootstrapResult:
    """Parameter spread of a candidate from refits on runs drawn with replacement.

    Attributes:
        parameter_names: Names of the ``p`` parameters.
        samples: Parameters of every refit, shape ``(n_boot, p)``.
        mean: Mean over the refits, ``(p,)``.
        std: Standard deviation over the refits (``ddof=1``), ``(p,)``.
        n_runs: Number of distinct runs resampled.
    """

    parameter_names: tuple[str, ...]
    samples: FloatArray
    mean: FloatArray
    std: FloatArray
    n_runs: int


def _check_residual(
    signals: Signals, residual: FloatArray, effect: CandidateEffect | None = None
) -> FloatArray:
    residual = np.asarray(residual, dtype=float)
    width = signals.n_joints if effect is None else effect.width(signals)
    expected = (signals.n_samples, width)
    if residual.shape != expected:
        groups = "joint" if effect is None else "+".join(effect.groups)
        raise InputError(
            f"residual: expected shape (T, W) = {expected} (groups {groups}), got {residual.shape}"
        )
    if not np.all(np.isfinite(residual)):
        bad = np.argwhere(~np.isfinite(residual))[0]
        raise InputError(f"residual: non-finite value (NaN or inf) at index {tuple(bad)}")
    return residual


def _check_mask(signals: Signals, mask: NDArray[np.bool_] | None, name: str) -> NDArray[np.bool_]:
    if mask is None:
        return np.ones(signals.n_samples, dtype=bool)
    mask = np.asarray(mask)
    if mask.dtype != bool or mask.shape != (signals.n_samples,):
        raise InputError(
            f"{name}: expected a boolean array of shape ({signals.n_samples},), "
            f"got {mask.dtype} {mask.shape}"
        )
    return mask


def one_blas_thread(function: Callable[P, R]) -> Callable[P, R]:
    """Run ``function`` with BLAS on one thread: the same bits whatever the thread settings.

    A multi-threaded BLAS sums in another order with another number of threads (the SVD, the
    products of the least squares), so answers differed in their last digits (1e-13) between
    ``OMP_NUM_THREADS=1`` and 2. The fits here are small; one thread was no slower.
    """

    @functools.wraps(function)
    def wrapped(*args: P.args, **kwargs: P.kwargs) -> R:
        with threadpool_limits(limits=1, user_api="blas"):
            return function(*args, **kwargs)

    return wrapped


class LinearSolver:
    """Least squares ``design (T, n, p) @ theta = residual (T, n)`` for many residuals.

    The columns are normalised, then factored once by a thin SVD; each :meth:`solve` is the
    minimum-norm solution with singular values below ``eps * max(T n, p)`` of the largest
    dropped (``numpy.linalg.lstsq``'s default cut). The selection refits the same design to a
    new residual at every round of a joint fit, so factoring once is most of the saving.

    Rows of the design that are zero in every column (the channels of groups the terms do not
    act on; the samples of runs a bootstrap draw left out) take no part in the solution, so
    they are left out of the factorisation and of each solve: a joint-friction set fills 4 of
    the 22 stacked channels, and its SVD is that much smaller.
    """

    def __init__(self, design: FloatArray, cut: float | None = None) -> None:
        """Factor ``design`` ``(T, n, p)``.

        Args:
            design: The design.
            cut: Singular values of the normalised design at or below it are dropped; None:
                ``eps * max(T n, p)`` times the largest (``lstsq``'s). A :class:`BlockSolver`
                gives its blocks the whole design's.
        """
        self.shape = design.shape
        A = design.reshape(-1, design.shape[2])
        # the rows with a non-zero value (|A| @ 1 > 0 is np.any(A != 0, axis=1) for finite
        # values, a few times faster on rows of a few columns)
        used = np.flatnonzero(np.abs(A) @ np.ones(A.shape[1]) > 0.0)
        #: Indices of the rows that take part, or None for all of them.
        self.rows = None if used.size == A.shape[0] else used
        A_used = A if self.rows is None else A[self.rows]
        self.scale = column_scale(A_used)  # zero rows add nothing to the norms
        u, singular, vt = np.linalg.svd(A_used / self.scale, full_matrices=False)
        if cut is None:
            cut = np.finfo(float).eps * max(A.shape) * float(singular.max(initial=0.0))
        keep = singular > cut
        #: The singular values kept (of the column-normalised design), descending.
        self.singular = singular[keep]
        self.ut = np.ascontiguousarray(u[:, keep].T)
        self.v_over_s = vt[keep].T / singular[keep]

    def solve(self, residual: FloatArray) -> FloatArray:
        """Parameters ``theta`` of ``residual`` ``(T, n)``, shape ``(p,)``."""
        if residual.shape != self.shape[:2]:
            raise InputError(f"residual: expected shape {self.shape[:2]}, got {residual.shape}")
        b = residual.reshape(-1)
        return (self.v_over_s @ (self.ut @ (b if self.rows is None else b[self.rows]))) / self.scale


class BlockSolver:
    """:class:`LinearSolver` of a design whose parameters fall into blocks on disjoint rows.

    Linear terms that act on different residual groups have their designs on different rows
    of the stack: the joint least squares is then one least squares per block, and the
    blocks' SVDs are together the whole design's, at a fraction of its cost (an SVD costs
    rows times columns squared). Each block keeps the singular values above the whole
    design's cut (``eps * max(T n, p)`` times the largest of all the blocks), so the solution
    is the whole design's minimum-norm one, to round-off.

    Args:
        parts: For each block, the indices of its parameters among the whole design's and its
            factored :class:`LinearSolver` (built with no ``cut``; a block with a singular
            value at or below the whole design's cut is factored again with it, by
            ``refactor(k, cut)``).
        shape: The whole design's shape ``(T, n, p)``.
        refactor: ``refactor(k, cut)`` factors block ``k`` again with that cut.
    """

    def __init__(
        self,
        parts: Sequence[tuple[NDArray[np.intp], LinearSolver]],
        shape: tuple[int, int, int],
        refactor: Callable[[int, float], LinearSolver],
    ) -> None:
        self.shape = shape
        largest = max((float(s.singular.max(initial=0.0)) for _, s in parts), default=0.0)
        cut = np.finfo(float).eps * max(shape[0] * shape[1], shape[2]) * largest
        self.parts = [
            (index, solver if solver.singular.min(initial=np.inf) > cut else refactor(k, cut))
            for k, (index, solver) in enumerate(parts)
        ]

    def solve(self, residual: FloatArray) -> FloatArray:
        """Parameters ``theta`` of ``residual`` ``(T, n)``, shape ``(p,)``."""
        if residual.shape != self.shape[:2]:
            raise InputError(f"residual: expected shape {self.shape[:2]}, got {residual.shape}")
        theta = np.empty(self.shape[2])
        for index, solver in self.parts:
            theta[index] = solver.solve(residual)
        return theta


def _solve_linear(design: FloatArray, residual: FloatArray) -> FloatArray:
    """Least squares of ``design (T, n, p) @ theta = residual (T, n)``, columns normalised.

    One solve: ``numpy.linalg.lstsq`` (cheaper than factoring for :class:`LinearSolver`).
    """
    A = design.reshape(-1, design.shape[2])
    scale = column_scale(A)
    solution, *_ = np.linalg.lstsq(A / scale, residual.reshape(-1), rcond=None)
    return solution / scale


def column_scale(A: FloatArray) -> FloatArray:
    """Each column's norm (1 for a zero column): the least squares' normalisation, ``(p,)``."""
    scale = np.linalg.norm(A, axis=0)
    return np.where(scale > 0, scale, 1.0)


def constraint_matrix(effect: CandidateEffect) -> FloatArray:
    """A term's :meth:`~CandidateEffect.constraints`, checked: ``G`` of shape ``(k, p)``.

    An empty answer (``[]``) is taken as no constraint.

    Raises:
        InputError: ``G`` is not a matrix of numbers with one column per parameter, or holds
            a NaN or infinity (the term named).
    """
    p = effect.n_parameters
    expected = f"a matrix of numbers of shape (k, {p}) (one column per parameter)"
    try:
        G = np.asarray(effect.constraints(), dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{effect.name}: constraints() must be {expected} ({exc})") from exc
    if G.size == 0:
        return np.zeros((0, p))
    if G.ndim != 2 or G.shape[1] != p:
        raise InputError(f"{effect.name}: constraints() must be {expected}, got shape {G.shape}")
    if not np.all(np.isfinite(G)):
        row, column = (int(i) for i in np.argwhere(~np.isfinite(G))[0])
        raise InputError(
            f"{effect.name}: constraints() has a non-finite value (NaN or inf) at row {row}, "
            f"column {column} ({effect.parameter_names[column]})"
        )
    return G


def bounds_of(effect: CandidateEffect) -> tuple[FloatArray, FloatArray]:
    """A term's :meth:`~CandidateEffect.bounds`, checked: ``(lower, upper)``, each ``(p,)``.

    Raises:
        InputError: Not two arrays of ``p`` numbers, a NaN bound, a lower bound of +inf or an
            upper one of -inf, or a lower bound above its upper one (the term and the
            parameter named). Equal bounds (a parameter held fixed) are allowed.
    """
    p = effect.n_parameters
    expected = f"two arrays (lower, upper) of {p} numbers each, -inf / inf for none"
    try:
        lower, upper = (np.asarray(b, dtype=float) for b in effect.bounds())
    except (TypeError, ValueError) as exc:
        raise InputError(f"{effect.name}: bounds() must return {expected} ({exc})") from exc
    if lower.shape != (p,) or upper.shape != (p,):
        raise InputError(
            f"{effect.name}: bounds() must return {expected}, got shapes {lower.shape} and "
            f"{upper.shape}"
        )
    for which, values in (("lower", lower), ("upper", upper)):
        if np.isnan(values).any():
            k = int(np.flatnonzero(np.isnan(values))[0])
            raise InputError(
                f"{effect.name}: bounds(): the {which} bound of {effect.parameter_names[k]} is "
                "NaN (use -inf / inf for none)"
            )
    for which, values, bad in (("lower", lower, np.inf), ("upper", upper, -np.inf)):
        if (values == bad).any():
            k = int(np.flatnonzero(values == bad)[0])
            raise InputError(
                f"{effect.name}: bounds(): the {which} bound of {effect.parameter_names[k]} is "
                f"{bad:+g}, which leaves the parameter no value"
            )
    crossed = np.flatnonzero(lower > upper)
    if crossed.size:
        k = int(crossed[0])
        raise InputError(
            f"{effect.name}: bounds(): the lower bound of {effect.parameter_names[k]} "
            f"({lower[k]:g}) is above its upper bound ({upper[k]:g})"
        )
    return lower, upper


#: What :attr:`CandidateEffect.indexed_by` may be.
INDEXED_BY = (None, "joint", "cable")


def check_name(effect: CandidateEffect) -> None:
    """Refuse a candidate whose ``name`` is not a non-empty string (InputError, class named)."""
    if not isinstance(effect.name, str) or not effect.name.strip():
        raise InputError(
            f"{type(effect).__name__}: a candidate needs a non-empty class attribute 'name' "
            f"(what the diagnosis calls it), got {effect.name!r}"
        )


def check_interface(effect: CandidateEffect) -> None:
    """Refuse a candidate whose declared interface is malformed (the term named).

    Checks the :attr:`~CandidateEffect.name` (what the answer calls it), its ``groups`` and
    :attr:`~CandidateEffect.parameter_names`, the :attr:`~CandidateEffect.indexed_by`, and
    :meth:`~CandidateEffect.constraints` and :meth:`~CandidateEffect.bounds` of a nonlinear
    term (a linear term may state no constraint, since its least squares cannot keep one),
    and
    :meth:`~CandidateEffect.parameter_groups`.

    Raises:
        InputError: What is wrong and what was expected.
    """
    check_name(effect)
    check_groups(effect)
    check_parameter_names(effect)
    if effect.indexed_by not in INDEXED_BY:
        raise InputError(
            f"{effect.name}: indexed_by must be 'joint', 'cable' or None (what a bracketed "
            f"index in a parameter's name counts), got {effect.indexed_by!r}"
        )
    G = constraint_matrix(effect)
    if effect.linear and G.shape[0]:
        raise InputError(
            f"{effect.name}: a linear term is fitted by least squares, which cannot keep the "
            f"{G.shape[0]} constraint(s) its constraints() states: set linear = False (its "
            "torque() written with ops) for IPOPT to keep them, or state none"
        )
    if not effect.linear:
        bounds_of(effect)
    check_parameter_groups(effect)


def check_groups(effect: CandidateEffect) -> None:
    """Refuse ``groups`` that are not distinct residual groups (InputError, term named)."""
    groups = getattr(effect, "groups", None)
    if (
        not isinstance(groups, tuple | list)
        or not groups
        or any(g not in GROUPS for g in groups)
        or len(set(groups)) != len(groups)
    ):
        raise InputError(
            f"{effect.name}: groups must be a non-empty tuple of distinct residual groups from "
            f"{', '.join(GROUPS)} (those its prediction has columns for, in that tuple's order), "
            f"got {groups!r}"
        )


def check_parameter_names(effect: CandidateEffect) -> None:
    """Refuse missing, repeated or non-string ``parameter_names`` (InputError, term named)."""
    names = getattr(effect, "parameter_names", None)
    expected = "a tuple of distinct non-empty strings, one a parameter in the order of theta"
    if names is None:
        raise InputError(f"{effect.name}: parameter_names is not set; expected {expected}")
    if (
        not isinstance(names, tuple | list)
        or not all(isinstance(n, str) and n.strip() for n in names)
        or len(set(names)) != len(names)
    ):
        raise InputError(f"{effect.name}: parameter_names must be {expected}, got {names!r}")


def check_parameter_groups(effect: CandidateEffect) -> None:
    """Refuse a malformed :meth:`~CandidateEffect.parameter_groups` (the term named).

    Raises:
        InputError: Not a sequence of non-empty sequences of parameter indices in
            ``range(p)``.
    """
    p = effect.n_parameters
    given = effect.parameter_groups()
    try:
        groups = [list(group) for group in given]
    except TypeError:
        groups = None
    if groups is None or any(
        not group
        or any(isinstance(i, bool) or not isinstance(i, int | np.integer) for i in group)
        or any(not 0 <= i < p for i in group)
        for group in groups
    ):
        raise InputError(
            f"{effect.name}: parameter_groups() must give sets of parameter indices, each a "
            f"non-empty tuple of whole numbers in 0..{p - 1} (e.g. ((0,), (1, 2))), got "
            f"{given!r}"
        )


def stacked_constraints(effects: Sequence[CandidateEffect]) -> FloatArray:
    """The terms' checked constraints on their parameters side by side (block diagonal).

    Args:
        effects: Terms whose parameters are stacked in this order.

    Returns:
        ``G``, shape ``(sum k_i, sum p_i)``.
    """
    blocks = [constraint_matrix(e) for e in effects]
    G = np.zeros((sum(b.shape[0] for b in blocks), sum(b.shape[1] for b in blocks)))
    row = column = 0
    for b in blocks:
        G[row : row + b.shape[0], column : column + b.shape[1]] = b
        row, column = row + b.shape[0], column + b.shape[1]
    return G


class _NonlinearProblem:
    """IPOPT problem of a nonlinear candidate on fixed samples, with per-sample weights.

    Minimises ``sum_t w_t |r_t - torque_t(theta)|^2 / sum_t w_t |r_t|^2``. The weights and the
    residual are NLP parameters, so that a bootstrap, or a selection that fits the same term
    to several residuals, builds (and differentiates) the problem once per set of samples;
    the samples' data are NLP parameters too, and the solver is shared with every problem of
    the same term on as many samples (:func:`~msarm.diagnose.nlp.shared_solver`).
    """

    def __init__(self, effect: CandidateEffect, signals: Signals, residual: FloatArray) -> None:
        self.effect, self.signals, self.residual = effect, signals, residual
        p, T = effect.n_parameters, signals.n_samples
        width = residual.shape[1]
        theta = casadi.MX.sym("theta", p)
        weights = casadi.MX.sym("w", T)
        target = casadi.MX.sym("r", T, width)
        data = DataOps()
        error = target - effect.torque(signals, theta, data)
        squared = casadi.sum2(error * error)
        reference = casadi.sum2(target * target)
        objective = casadi.dot(weights, squared) / casadi.fmax(
            casadi.dot(weights, reference), 1e-300
        )
        self.solver, self.data, self.constraint_bounds = shared_solver(
            f"fit_{effect.name}", theta, [weights, target], objective, data,
            constraint_matrix(effect),
        )  # fmt: skip
        self.lower, self.upper = bounds_of(effect)

    def solve(
        self,
        initial: FloatArray | None,
        weights: FloatArray | None = None,
        residual: FloatArray | None = None,
    ) -> tuple[FloatArray, bool, str]:
        """Fit; ``residual`` replaces the one the problem was built with (same shape)."""
        p, T = self.effect.n_parameters, self.signals.n_samples
        r = self.residual if residual is None else np.asarray(residual, dtype=float)
        if r.shape != self.residual.shape:
            raise InputError(f"residual: expected shape {self.residual.shape}, got {r.shape}")
        if initial is None:
            initial = self.effect.initial_guess(self.signals, r)
        x0 = np.asarray(initial, dtype=float)
        if x0.shape != (p,):
            raise InputError(
                f"{self.effect.name}: starting parameters (its initial_guess(), or the start "
                f"given) have shape {x0.shape}, expected ({p},) for {self.effect.parameter_names}"
            )
        x0 = np.clip(x0, self.lower, self.upper)
        w = np.ones(T) if weights is None else weights
        values = np.concatenate([w, r.reshape(-1, order="F"), self.data])
        solution = self.solver(
            x0=x0, p=values, lbx=self.lower, ubx=self.upper, **self.constraint_bounds
        )
        raise_if_terminated()  # IPOPT stops early on a SIGTERM and swallows its exception
        stats = self.solver.stats()
        # IPOPT relaxes the bounds by up to 1e-8 (bound_relax_factor): a parameter at a bound
        # comes back just outside it (a friction coefficient of -1e-8); report it on the bound.
        return (
            np.clip(np.asarray(solution["x"], dtype=float).reshape(-1), self.lower, self.upper),
            bool(stats["success"]),
            str(stats["return_status"]),
        )


def fit(
    effect: CandidateEffect,
    signals: Signals,
    residual: FloatArray,
    train_mask: NDArray[np.bool_] | None = None,
    initial: FloatArray | None = None,
) -> FitResult:
    """Fit a candidate to the residual on the training samples.

    Args:
        effect: The candidate.
        signals: Signals of ``T`` samples.
        residual: The residual ``r = tau_MS - ID`` [N m], shape ``(T, n)``.
        train_mask: Training samples, boolean ``(T,)``; all when ``None``. It may cut
            inside runs: a term with memory (delay taps, a Dahl or direction state, per-run
            means, play operators) is evaluated over the whole runs, then these samples taken.
        initial: Starting parameters of a nonlinear fit, ``(p,)`` (the candidate's
            :meth:`~CandidateEffect.initial_guess` when ``None``).

    Returns:
        The fitted :class:`FitResult`.

    Raises:
        InputError: Wrong shapes, non-finite values, or fewer training residual values
            (samples times the term's width, its channels) than parameters.
    """
    residual = _check_residual(signals, residual, effect)
    mask = _check_mask(signals, train_mask, "train_mask")
    effect.check(signals)
    n_train = int(mask.sum())
    if n_train * effect.width(signals) < effect.n_parameters:
        raise InputError(
            f"train_mask: {n_train} samples of {effect.width(signals)} channel(s) give "
            f"{n_train * effect.width(signals)} residual values for {effect.n_parameters} "
            f"parameters of {effect.name}; expected at least as many values as parameters"
        )
    r = residual[mask]
    if effect.linear:  # the design on the whole runs (terms with memory), then the samples
        parameters = _solve_linear(effect.design(signals)[mask], r)
        success, message = True, "least squares"
    else:
        train = signals if mask.all() else signals.take(mask)
        parameters, success, message = _NonlinearProblem(effect, train, r).solve(initial)
    error = r - np.asarray(effect.torque(signals, parameters, NUMPY_OPS), dtype=float)[mask]
    return FitResult(
        effect=effect,
        parameters=parameters,
        rms_before=float(np.sqrt(np.mean(r**2))),
        rms_after=float(np.sqrt(np.mean(error**2))),
        n_train=n_train,
        success=success,
        message=message,
    )


def bootstrap(
    effect: CandidateEffect,
    signals: Signals,
    residual: FloatArray,
    runs: NDArray[np.int64] | None = None,
    n_boot: int = 100,
    seed: int | np.random.Generator = 0,
    train_mask: NDArray[np.bool_] | None = None,
) -> BootstrapResult:
    """Parameter spread by refitting on runs drawn with replacement (not samples).

    Each refit draws as many runs as there are, with replacement, and fits on all their
    (training) samples; a run drawn twice counts twice. Nonlinear refits start from the fit
    on all runs.

    Args:
        effect: The candidate.
        signals: Signals of ``T`` samples.
        residual: The residual [N m], shape ``(T, n)``.
        runs: Run label of every sample, ``(T,)``; ``signals.run`` when ``None``.
        n_boot: Number of refits (>= 2).
        seed: Seed or generator of the draws (same seed, same result).
        train_mask: Samples that may be used, boolean ``(T,)``; all when ``None``.

    Returns:
        The :class:`BootstrapResult`.

    Raises:
        InputError: Fewer than two runs, ``n_boot < 2``, or bad shapes.
    """
    residual = _check_residual(signals, residual, effect)
    mask = _check_mask(signals, train_mask, "train_mask")
    labels = signals.run if runs is None else np.asarray(runs)
    if labels.shape != (signals.n_samples,):
        raise InputError(f"runs: expected shape ({signals.n_samples},), got {labels.shape}")
    if int(n_boot) < 2:
        raise InputError(f"n_boot: expected >= 2, got {n_boot}")
    unique = np.unique(labels[mask])
    if unique.size < 2:
        raise InputError(
            f"runs: bootstrap over runs needs at least 2 runs, got {unique.size} "
            "(label samples by run in Signals.run or pass runs=)"
        )
    rng = np.random.default_rng(seed)
    members = [np.flatnonzero(mask & (labels == label)) for label in unique]
    index = np.flatnonzero(mask)
    position = np.full(signals.n_samples, -1)
    position[index] = np.arange(index.size)
    r = residual[index]
    if effect.linear:
        design = effect.design(signals)[index]
    else:
        problem = _NonlinearProblem(effect, signals.take(index), r)
        start, *_ = problem.solve(None)
    samples = np.empty((int(n_boot), effect.n_parameters))
    for b in range(int(n_boot)):
        drawn = rng.integers(0, unique.size, size=unique.size)
        # A run drawn k times weighs its samples k times (same as repeating them).
        weights = np.zeros(index.size)
        for k in drawn:
            weights[position[members[k]]] += 1.0
        if effect.linear:
            root = np.sqrt(weights)
            samples[b] = _solve_linear(design * root[:, None, None], r * root[:, None])
        else:
            samples[b], *_ = problem.solve(start, weights)
    return BootstrapResult(
        parameter_names=effect.parameter_names,
        samples=samples,
        mean=samples.mean(axis=0),
        std=samples.std(axis=0, ddof=1),
        n_runs=int(unique.size),
    )
