"""Candidate unmodelled effects: parametric terms fitted to a joint-torque residual.

The residual of a run is, per sample,

``r = tau_MS - ID(q, qd, qdd)``  [N m], shape ``(T, n)``,

with ``tau_MS = -J_c(q)^T F`` the torque the logged motor-side tensions ``F`` would deliver
through ideal cables and ``ID`` the nominal (rigid, frictionless) inverse dynamics. ``r`` is the
torque *lost* between the motors and the joints: positive friction (opposing a positive
velocity) gives a positive ``r``. Every candidate's :meth:`CandidateEffect.torque` is its
prediction of ``r`` (not of the torque it adds to the joints, which is ``-r``).

Sign conventions of msarm: ``J_c = dl/dq`` (``m x n``), ``tau = -J_c^T f``, the cable velocity
``ldot = J_c qd`` is negative while the motor pulls the cable in.

A candidate is **linear** when its prediction is ``design(signals) @ theta`` for a regressor of
shape ``(T, n, p)``; :func:`msarm.diagnose.fitting.fit` then solves a least-squares problem.
A **nonlinear** candidate writes its prediction once, in :meth:`CandidateEffect.torque`, with the
operations of an :class:`Ops` backend, so that the same code evaluates it on numpy arrays and
builds the casadi expression that IPOPT fits.

Adding a candidate::

    import numpy as np
    from msarm.diagnose.effects import CandidateEffect, register

    @register
    class ConstantOffset(CandidateEffect):
        '''Constant joint-torque offset: r_j = c_j.'''

        name = "constant_offset"
        description = "r_j = c_j, a constant torque per joint"
        linear = True

        def __init__(self, n_joints: int = 4) -> None:
            self.channels = tuple(range(n_joints))
            self.parameter_names = tuple(f"c[{j}]" for j in self.channels)

        def design(self, signals):
            T, n = signals.n_samples, signals.n_joints
            return np.broadcast_to(np.eye(n)[None, :, :], (T, n, n)).copy()

A nonlinear one sets ``linear = False`` and overrides :meth:`CandidateEffect.torque` (using only
``ops``), :meth:`CandidateEffect.initial_guess` and :meth:`CandidateEffect.bounds`.
``CANDIDATES`` maps names to the registered classes; :func:`create` builds one by name.
"""

from __future__ import annotations

from abc import ABC
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, TypeVar

import casadi
import numpy as np
import pinocchio
from numpy.typing import ArrayLike, NDArray

from msarm.diagnose.signals import Signals, direction_memory, stick_slip_tension
from msarm.errors import InputError

__all__ = [
    "CANDIDATES",
    "CAPSTAN_STICTION_MUS",
    "CableCapstanFriction",
    "CableCapstanHysteresis",
    "CandidateEffect",
    "CasadiOps",
    "CoulombFriction",
    "DahlFriction",
    "InertiaError",
    "MotorCogging",
    "NumpyOps",
    "Ops",
    "SensorBiasScale",
    "StribeckFriction",
    "TensionDelay",
    "ViscousFriction",
    "create",
    "register",
]

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------- backends
class Ops:
    """The operations a nonlinear candidate may use: 2-D arrays ``(T, k)`` and parameters.

    Data arrays come in as numpy arrays and are wrapped with :meth:`const`; parameters are
    ``theta[i]`` (scalars) or :meth:`row` of a slice (a ``(1, k)`` row broadcast over ``T``
    samples). ``*``, ``+``, ``-``, ``/`` and ``**`` between same-shape arrays and scalars work in
    both backends; numpy-style broadcasting of rows does not (use :meth:`row`).
    """

    def const(self, a: FloatArray) -> Any:
        """A data array ``(T, k)`` as a backend array.

        Args:
            a: Data (signals, in their units), shape ``(T, k)``.

        Returns:
            The same values as a backend array ``(T, k)`` (numpy: float array; casadi: ``DM``).
        """
        raise NotImplementedError

    def row(self, theta: Any, start: int, stop: int, n_rows: int) -> Any:
        """Parameters ``theta[start:stop]`` as a ``(n_rows, stop - start)`` array (rows equal).

        Args:
            theta: The parameters, ``(p,)`` (numpy array, or casadi ``MX`` symbol of ``p``
                elements).
            start: First parameter index.
            stop: One past the last parameter index.
            n_rows: Number of rows, usually ``T``.

        Returns:
            ``theta[start:stop]`` repeated in every row, shape ``(n_rows, stop - start)``
            (numpy: a ``(1, stop - start)`` row, which broadcasts).
        """
        raise NotImplementedError

    def exp(self, x: Any) -> Any:
        """Elementwise exponential.

        Args:
            x: Backend array of any shape, or a scalar.

        Returns:
            ``exp(x)``, shape of ``x``.
        """
        raise NotImplementedError

    def tanh(self, x: Any) -> Any:
        """Elementwise hyperbolic tangent.

        Args:
            x: Backend array of any shape, or a scalar.

        Returns:
            ``tanh(x)``, shape of ``x``.
        """
        raise NotImplementedError

    def column(self, x: Any, j: int) -> Any:
        """Column ``j`` of ``x`` as a ``(T, 1)`` array.

        Args:
            x: Backend array, shape ``(T, k)``.
            j: Column index, ``0 <= j < k``.

        Returns:
            ``x[:, j]`` as a column, shape ``(T, 1)``.
        """
        return x[:, j : j + 1]

    def sum_columns(self, x: Any) -> Any:
        """Sum over columns, ``(T, k) -> (T, 1)``.

        Args:
            x: Backend array, shape ``(T, k)``.

        Returns:
            The row sums, shape ``(T, 1)``.
        """
        raise NotImplementedError

    def hcat(self, columns: Sequence[Any]) -> Any:
        """Concatenate ``(T, 1)`` columns into ``(T, k)``.

        Args:
            columns: ``k`` backend arrays, each of shape ``(T, 1)``.

        Returns:
            The columns side by side, shape ``(T, k)``.
        """
        raise NotImplementedError

    def zeros(self, n_rows: int) -> Any:
        """A ``(n_rows, 1)`` column of zeros.

        Args:
            n_rows: Number of rows, usually ``T``.

        Returns:
            Backend zeros, shape ``(n_rows, 1)``.
        """
        return self.const(np.zeros((n_rows, 1)))

    def cable_to_joint(self, jacobian: FloatArray, g: Any) -> Any:
        """``J_c^T g`` per sample: ``(T, m, n)`` data and ``(T, m)`` cable forces -> ``(T, n)``.

        Args:
            jacobian: Muscle Jacobians ``J_c = dl/dq`` [m/rad], numpy, shape ``(T, m, n)``.
            g: Backend array of cable forces [N], shape ``(T, m)``.

        Returns:
            ``J_c^T g`` of every sample [N m], shape ``(T, n)``.
        """
        return self.hcat(
            [self.sum_columns(self.const(jacobian[:, :, j]) * g) for j in range(jacobian.shape[2])]
        )


class NumpyOps(Ops):
    """Implements :class:`Ops` on numpy float arrays (evaluation); see :class:`Ops`'s methods."""

    def const(self, a: FloatArray) -> FloatArray:  # noqa: D102
        return np.asarray(a, dtype=float)

    def row(self, theta: Any, start: int, stop: int, n_rows: int) -> FloatArray:  # noqa: D102
        return np.asarray(theta, dtype=float)[start:stop].reshape(1, -1)

    def exp(self, x: Any) -> Any:  # noqa: D102
        return np.exp(x)

    def tanh(self, x: Any) -> Any:  # noqa: D102
        return np.tanh(x)

    def sum_columns(self, x: Any) -> Any:  # noqa: D102
        return np.sum(x, axis=1, keepdims=True)

    def hcat(self, columns: Sequence[Any]) -> Any:  # noqa: D102
        return np.hstack(list(columns))


class CasadiOps(Ops):
    """Implements :class:`Ops` on casadi matrices (data as ``DM``, parameters as ``MX`` symbols).

    Builds the symbolic prediction that IPOPT fits; see :class:`Ops`'s methods.
    """

    def const(self, a: FloatArray) -> casadi.DM:  # noqa: D102
        return casadi.DM(np.asarray(a, dtype=float))

    def row(self, theta: Any, start: int, stop: int, n_rows: int) -> Any:  # noqa: D102
        return casadi.repmat(casadi.reshape(theta[start:stop], 1, stop - start), n_rows, 1)

    def exp(self, x: Any) -> Any:  # noqa: D102
        return casadi.exp(x)

    def tanh(self, x: Any) -> Any:  # noqa: D102
        return casadi.tanh(x)

    def sum_columns(self, x: Any) -> Any:  # noqa: D102
        return casadi.sum2(x)

    def hcat(self, columns: Sequence[Any]) -> Any:  # noqa: D102
        return casadi.horzcat(*columns)


NUMPY_OPS = NumpyOps()


# --------------------------------------------------------------------------- base class
class CandidateEffect(ABC):
    """A parametric unmodelled effect that predicts the joint-torque residual ``r``.

    Attributes:
        name: Registry name (class attribute).
        description: The term's equation in words (class attribute).
        linear: Whether the prediction is linear in the parameters (class attribute).
        parameter_names: Names of the ``p`` parameters, in the order of ``theta``.
        channels: Indices of the joints the term acts on (of the cables, for a term on the
            drive or length group); its prediction is zero elsewhere.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    linear: ClassVar[bool] = True
    groups: tuple[str, ...] = ("joint",)
    parameter_names: tuple[str, ...]
    channels: tuple[int, ...]
    #: Unit of each kind of parameter (:func:`parameter_kind` of its name), e.g.
    #: ``{"coulomb": "N m"}``; ``"-"``: dimensionless. A kind not listed has no stated unit.
    parameter_units: ClassVar[Mapping[str, str]] = {}
    #: Parameter kinds that no physical effect of this kind has below zero (a friction level,
    #: a compliance, a play): a fit that lands below zero is flagged in the diagnosis.
    nonnegative: ClassVar[frozenset[str]] = frozenset()
    #: Whether a linear term's design at a sample depends on that sample's signals alone (no
    #: state, delay tap or per-run mean): the selection then computes it on the samples it
    #: fits and scores on only, not on the whole runs first. False (the safe default) for a
    #: term with memory.
    memoryless: ClassVar[bool] = False
    #: What a whole number in brackets at the end of a parameter's name counts: ``"joint"``
    #: (``coulomb[3]``: the model's joint 3), ``"cable"`` (``mu[2]``: cable 2) or None (a tap,
    #: a level: nothing to name). The diagnosis shows such a parameter with the joint's or
    #: cable's name (``coulomb[elbow]``).
    indexed_by: ClassVar[str | None] = None
    #: The fixed (not fitted) constants of the term's equation: each symbol of
    #: :attr:`description` by the attribute that holds its value, e.g. ``{"eps": "eps"}``
    #: (see :meth:`constants`).
    constant_symbols: ClassVar[Mapping[str, str]] = {}

    def constants(self) -> dict[str, float | list[float]]:
        """The fixed constants of the term's equation, by their symbol in :attr:`description`.

        Read from the attributes :attr:`constant_symbols` names; a symbol that is also a fitted
        parameter (a capstan's ``eps`` with ``fit_eps``) or whose attribute the term lacks is
        left out. A per-channel constant with one value for every channel is that value.

        Returns:
            ``{symbol: value}`` in the constants' own units (see the term's docstring), e.g.
            ``{"rho": 0.003, "K": 4.0, "omega_s": 0.5}``; empty when the term states none.
        """
        out: dict[str, float | list[float]] = {}
        for symbol, attribute in self.constant_symbols.items():
            if symbol in self.parameter_names or not hasattr(self, attribute):
                continue
            value = np.asarray(getattr(self, attribute), dtype=float)
            if value.ndim and value.size and np.all(value == value.flat[0]):
                value = value.flat[0]
            out[symbol] = float(value) if value.ndim == 0 else [float(v) for v in value.flat]
        return out

    def unit_of(self, parameter: str) -> str:
        """The unit of a parameter, by its kind (``""`` when the term states none).

        Args:
            parameter: A parameter name, e.g. ``"coulomb[1]"`` (see :func:`parameter_kind`).

        Returns:
            The unit from :attr:`parameter_units`, e.g. ``"N m"`` (``"-"``: dimensionless), or
            ``""``.
        """
        return self.parameter_units.get(parameter_kind(parameter), "")

    @property
    def n_parameters(self) -> int:
        """Number of parameters ``p``."""
        return len(self.parameter_names)

    def width(self, signals: Signals) -> int:
        """Number of residual columns the term predicts: its groups' channels side by side.

        The channel groups (see :mod:`msarm.diagnose.builder`) are ``"joint"`` (``n``
        joint-torque columns [N m]), ``"drive"`` (``m`` load-cell-minus-command columns [N])
        and ``"length"`` (``m`` cable length error columns [m]); a term's prediction holds the
        columns of its ``groups`` side by side, in the order of its ``groups`` tuple.

        Args:
            signals: The signals (for ``n`` and ``m``).

        Returns:
            ``W``, the summed sizes of the term's groups (``n`` for a joint-torque term).
        """
        sizes = {"joint": signals.n_joints, "drive": signals.n_cables, "length": signals.n_cables}
        return sum(sizes[g] for g in self.groups)

    def design(self, signals: Signals) -> FloatArray:
        """The regressor of a linear term [residual unit per parameter unit], ``(T, W, p)``.

        ``W`` is :meth:`width` (``n`` for a joint-torque term).

        Args:
            signals: Signals of ``T`` samples.

        Returns:
            The regressor, shape ``(T, W, p)``: the prediction is ``design @ theta``, zero in
            the columns of joints outside :attr:`channels`.

        Raises:
            NotImplementedError: The term is nonlinear.
        """
        raise NotImplementedError(f"{self.name} is nonlinear: it has no design matrix")

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:
        """The predicted residual, shape ``(T, W)`` (:meth:`width`), for ``theta`` ``(p,)``.

        For a joint-torque term this is ``(T, n)`` [N m]; the name is historical.

        Linear terms evaluate ``design @ theta`` (numpy only); nonlinear terms override this
        with code written in ``ops`` so that it works with numpy and casadi (no numpy function
        of ``theta``, no ``if`` on it: the diagnosis builds the casadi expression on a few
        samples before any fit and refuses a term it cannot build, or whose output is not
        ``(T, W)`` and finite at its :meth:`initial_guess`).

        The diagnosis evaluates a nonlinear term on the samples its fits use, which may be
        every k-th sample of a run (thinned). A term with memory (a state, a delay) computes
        it on the whole runs, ``whole, rows = signals.origin`` (:meth:`Signals.take`), and
        then takes ``rows``, as :class:`CableCapstanHysteresis` does; a linear term's
        :meth:`design` is always computed on the whole runs first.

        Args:
            signals: Signals of ``T`` samples.
            theta: Parameters, ``(p,)`` (units of :attr:`parameter_names`): a numpy array with
                :class:`NumpyOps`, a casadi ``MX`` symbol of ``p`` elements with
                :class:`CasadiOps`.
            ops: The backend the prediction is written in: ``NUMPY_OPS`` (a
                :class:`NumpyOps`) to evaluate it, a :class:`CasadiOps` to build the
                expression IPOPT fits.

        Returns:
            The predicted residual ``r`` (residual units: [N m] for joint columns, [N] for
            drive columns, [m] for length columns), shape ``(T, W)``: a numpy array, or a
            casadi expression with :class:`CasadiOps`.

        Raises:
            InputError: ``theta`` is not of shape ``(p,)`` (linear terms, numpy), or the
                signals do not fit the term.
            NotImplementedError: A nonlinear term that does not override it.
        """
        if not self.linear:
            raise NotImplementedError(f"{type(self).__name__} must implement torque()")
        if not isinstance(ops, NumpyOps):
            design = self.design(signals)
            T, n, p = design.shape
            return casadi.reshape(casadi.DM(design.reshape(T * n, p)) @ theta, n, T).T
        theta = self._check_theta(theta)
        return np.einsum("tnp,p->tn", self.design(signals), theta)

    def initial_guess(self, signals: Signals, residual: FloatArray | None = None) -> FloatArray:
        """Starting parameters of a nonlinear fit, shape ``(p,)`` (zeros by default).

        Args:
            signals: The training signals.
            residual: The training residual [N m], ``(T, W)`` (:meth:`width`), for
                data-driven guesses.

        Returns:
            The starting parameters, shape ``(p,)`` (clipped to :meth:`bounds` by the fit).
        """
        return np.zeros(self.n_parameters)

    def bounds(self) -> tuple[FloatArray, FloatArray]:
        """Lower and upper parameter bounds of a nonlinear fit, each ``(p,)`` (none by default).

        Returns:
            ``(lower, upper)``, each of shape ``(p,)`` in the parameters' units; ``-inf`` /
            ``inf`` for an unbounded parameter.
        """
        return np.full(self.n_parameters, -np.inf), np.full(self.n_parameters, np.inf)

    def constraints(self) -> FloatArray:
        """Linear inequalities ``G @ theta >= 0`` a nonlinear fit keeps (none by default).

        For an order between parameters that :meth:`bounds` cannot state, e.g. a Stribeck
        friction's breakaway level at or above its Coulomb level. IPOPT keeps them (to its
        constraint tolerance, about 1e-8); a start that breaks them is allowed. A linear
        term's least squares does not read them.

        Returns:
            ``G``, shape ``(k, p)`` (``k = 0``: none).
        """
        return np.zeros((0, self.n_parameters))

    def check(self, signals: Signals) -> None:
        """Raise :class:`InputError` when ``signals`` do not fit this term (sizes).

        The default accepts any signals.

        Args:
            signals: The signals the term is about to be fitted to or evaluated on.
        """
        return None

    def parameter_groups(self) -> tuple[tuple[int, ...], ...]:
        """Sets of a linear term's parameters the diagnosis may leave out, each as a whole.

        After the selection, the diagnosis fixes a set at zero when the held-out runs do not
        need it (see ``msarm.diagnose.select.PRUNE_TOLERANCE``): a load cell's scale error
        beside its bias, any of a delay kernel's taps. Default: one set per parameter kind
        (:func:`parameter_kind`; every joint's or cable's together) when the term has two
        kinds or more, else none (the term is all or nothing). A term whose parameters only
        mean something together (a cogging's sine and cosine) returns ``()``.

        Returns:
            Index tuples into :attr:`parameter_names`, tried in this order.
        """
        kinds = list(dict.fromkeys(parameter_kind(p) for p in self.parameter_names))
        if not self.linear or len(kinds) < 2:
            return ()
        return tuple(
            tuple(k for k, p in enumerate(self.parameter_names) if parameter_kind(p) == kind)
            for kind in kinds
        )

    def restricted(self, groups: Sequence[str]) -> CandidateEffect | None:
        """The same effect predicting only ``groups`` (a subset of its own), if it can.

        The diagnosis asks this when the logs lack one of the term's groups. Default: None
        (the term needs all its groups).

        Args:
            groups: The channel groups to keep (``"joint"``, ``"drive"``, ``"length"``), a
                subset of :attr:`groups`.

        Returns:
            A new candidate whose prediction has only those groups' columns, or ``None`` when
            the term cannot predict them without the others.
        """
        return None

    def _check_theta(self, theta: Any) -> FloatArray:
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_parameters,):
            raise InputError(
                f"{self.name}: theta has shape {theta.shape}, expected ({self.n_parameters},) "
                f"for parameters {self.parameter_names}"
            )
        return theta

    def _check_joints(self, signals: Signals, n_joints: int) -> None:
        if signals.n_joints != n_joints:
            raise InputError(
                f"{self.name}: built for {n_joints} joints, signals have {signals.n_joints}"
            )

    def _check_cables(self, signals: Signals, n_cables: int) -> None:
        if signals.n_cables != n_cables:
            raise InputError(
                f"{self.name}: built for {n_cables} cables, signals have {signals.n_cables}"
            )

    def __repr__(self) -> str:
        return f"{type(self).__name__}(p={self.n_parameters}, channels={self.channels})"


class ParameterSubset(CandidateEffect):
    """A linear term with some of its parameters fixed at zero (its design's other columns).

    What the diagnosis fits when the held-out runs do not need a set of a term's parameters
    (:meth:`CandidateEffect.parameter_groups`). It keeps the term's name, groups, channels
    and units; :meth:`full` puts fitted values back in the term's own parameter order.

    Args:
        term: The linear term.
        keep: Indices of the parameters still fitted, a non-empty increasing subset of
            ``range(term.n_parameters)``.

    Raises:
        InputError: A nonlinear term, or ``keep`` empty, unordered or out of range.
    """

    linear = True

    def __init__(self, term: CandidateEffect, keep: Sequence[int]) -> None:
        keep = tuple(int(k) for k in keep)
        if not term.linear:
            raise InputError(f"{term.name}: only a linear term's parameters can be left out")
        if (
            not keep
            or list(keep) != sorted(set(keep))
            or not 0 <= keep[0] <= keep[-1] < len(term.parameter_names)
        ):
            raise InputError(
                f"{term.name}: keep must be increasing indices of its "
                f"{term.n_parameters} parameters, at least one, got {keep}"
            )
        self.term, self.keep = term, keep
        self.name = term.name  # type: ignore[misc]
        self.description = term.description  # type: ignore[misc]
        self.memoryless = term.memoryless  # type: ignore[misc]
        self.indexed_by = term.indexed_by  # type: ignore[misc]
        self.parameter_units = term.parameter_units  # type: ignore[misc]
        self.nonnegative = term.nonnegative  # type: ignore[misc]
        self.groups = term.groups
        self.channels = term.channels
        self.parameter_names = tuple(term.parameter_names[k] for k in keep)

    @property
    def left_out(self) -> tuple[str, ...]:
        """Names of the term's parameters fixed at zero."""
        return tuple(p for k, p in enumerate(self.term.parameter_names) if k not in self.keep)

    def constants(self) -> dict[str, float | list[float]]:
        """The whole term's fixed constants (:meth:`CandidateEffect.constants`)."""
        return self.term.constants()

    def full(self, theta: ArrayLike, fill: float = 0.0) -> FloatArray:
        """``theta`` of the kept parameters, ``(len(keep),)``, as the term's ``(p,)``.

        Args:
            theta: Values of the kept parameters.
            fill: The value of the parameters left out (0 for values; for a bootstrap
                spread 0, or NaN when there was none).

        Returns:
            Shape ``(term.n_parameters,)``.
        """
        out = np.full(self.term.n_parameters, float(fill))
        out[list(self.keep)] = self._check_theta(theta)
        return out

    def width(self, signals: Signals) -> int:  # noqa: D102
        return self.term.width(signals)

    def check(self, signals: Signals) -> None:  # noqa: D102
        self.term.check(signals)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        return np.asarray(self.term.design(signals))[..., list(self.keep)]


def parameter_kind(parameter: str) -> str:
    """A parameter's kind: its name without index or body (``elbow.mcx[1]`` -> ``mcx``)."""
    base = parameter.split("[", 1)[0]
    return base.rsplit(".", 1)[-1]


def parameter_index(parameter: str) -> int | None:
    """The whole number in brackets that ends a parameter's name, else None.

    ``coulomb[3]`` -> 3; ``mu``, ``bias[all]``, ``a[mu=0.03]`` -> None.
    """
    base, bracket, rest = parameter.partition("[")
    index = rest[:-1] if bracket and rest.endswith("]") else ""
    return int(index) if index.isdigit() else None


#: Registered candidate classes by name.
CANDIDATES: dict[str, type[CandidateEffect]] = {}

_E = TypeVar("_E", bound=type[CandidateEffect])


def register(cls: _E) -> _E:
    """Class decorator: add a :class:`CandidateEffect` subclass to :data:`CANDIDATES`.

    A class registered again under its name by the same module and qualified name (a
    notebook cell run twice) replaces the first.

    Args:
        cls: The candidate class, with a non-empty class attribute ``name``.

    Returns:
        ``cls`` itself (unchanged), so that it can decorate the class.

    Raises:
        InputError: The class has no ``name`` or the name is taken by another class.
    """
    if not cls.name:
        raise InputError(f"{cls.__name__}: a candidate needs a non-empty class attribute 'name'")
    old = CANDIDATES.get(cls.name)
    same = old is not None and (old.__module__, old.__qualname__) == (
        cls.__module__,
        cls.__qualname__,
    )
    if old is not None and old is not cls and not same:  # a notebook cell run again: same
        raise InputError(
            f"candidate name {cls.name!r} is already registered by "
            f"{old.__module__}.{old.__qualname__}"
        )
    CANDIDATES[cls.name] = cls
    return cls


def create(name: str, **kwargs: Any) -> CandidateEffect:
    """Build the registered candidate ``name`` with its constructor's keyword arguments.

    Raises:
        InputError: No candidate of that name.
    """
    if name not in CANDIDATES:
        raise InputError(f"unknown candidate {name!r}; known: {sorted(CANDIDATES)}")
    return CANDIDATES[name](**kwargs)


def _joint_channels(n_joints: int, joints: Sequence[int] | None) -> tuple[int, ...]:
    channels = tuple(range(n_joints)) if joints is None else tuple(int(j) for j in joints)
    if not channels or any(j < 0 or j >= n_joints for j in channels):
        raise InputError(f"joints: expected indices in [0, {n_joints}), got {joints}")
    if len(set(channels)) != len(channels):
        raise InputError(f"joints: repeated index in {joints}")
    return channels


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0.0:
        raise InputError(f"{name}: expected a finite value > 0, got {value}")
    return value


def _per_joint_design(signals: Signals, channels: tuple[int, ...], feature: FloatArray):
    """Design ``(T, n, k)`` with ``feature[:, j]`` of each channel ``j`` in its own column."""
    T, n = signals.n_samples, signals.n_joints
    out = np.zeros((T, n, len(channels)))
    for column, j in enumerate(channels):
        out[:, j, column] = feature[:, j]
    return out


# --------------------------------------------------------------------------- joint friction
@register
class CoulombFriction(CandidateEffect):
    """Joint Coulomb friction with a smoothed sign.

    ``r_j = c_j tanh(qd_j / eps)``; ``c_j`` [N m] per joint, ``eps`` [rad/s] fixed.
    """

    indexed_by = "joint"
    name = "coulomb"
    constant_symbols: ClassVar[Mapping[str, str]] = {"eps": "eps"}
    parameter_units: ClassVar[Mapping[str, str]] = {"coulomb": "N m"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"coulomb"})
    description = "r_j = c_j * tanh(qd_j / eps): Coulomb friction of joint j, smoothed sign"
    linear = True

    def __init__(
        self, n_joints: int = 4, joints: Sequence[int] | None = None, eps: float = 0.01
    ) -> None:
        """Build the term.

        Args:
            n_joints: Number of joints ``n`` of the robot.
            joints: Joints with friction (all when ``None``).
            eps: Velocity scale of the smoothed sign [rad/s].
        """
        self.n_joints = int(n_joints)
        self.channels = _joint_channels(self.n_joints, joints)
        self.eps = _positive("eps", eps)
        self.parameter_names = tuple(f"coulomb[{j}]" for j in self.channels)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        return _per_joint_design(signals, self.channels, np.tanh(signals.qd / self.eps))


@register
class ViscousFriction(CandidateEffect):
    """Joint viscous friction: ``r_j = b_j qd_j``, ``b_j`` [N m s/rad] per joint."""

    indexed_by = "joint"
    name = "viscous"
    parameter_units: ClassVar[Mapping[str, str]] = {"viscous": "N m s/rad"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"viscous"})
    description = "r_j = b_j * qd_j: viscous friction of joint j"
    linear = True

    def __init__(self, n_joints: int = 4, joints: Sequence[int] | None = None) -> None:
        """Build the term.

        Args:
            n_joints: Number of joints ``n`` of the robot.
            joints: Joints with friction (all when ``None``).
        """
        self.n_joints = int(n_joints)
        self.channels = _joint_channels(self.n_joints, joints)
        self.parameter_names = tuple(f"viscous[{j}]" for j in self.channels)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        return _per_joint_design(signals, self.channels, signals.qd)


@register
class DahlFriction(CandidateEffect):
    """Joint Dahl friction: Coulomb friction with a pre-sliding (hysteretic) transition.

    Dahl's model ``dF/dx = sigma (1 - F / F_c sgn(qd))`` written for ``z = F / F_c``:
    ``dz/dt = a (qd - |qd| z)`` with ``a = sigma / F_c`` [1/rad] (the inverse of the
    pre-sliding angle), integrated per run from ``z = 0`` (implicit Euler, stable for any
    ``a dt |qd|``). Then ``r_j = F_c,j z_j``: linear in the Coulomb levels ``F_c,j`` [N m] for
    a fixed ``a``, so the hysteresis (a lag of the friction behind each reversal) is fitted
    by least squares.
    """

    indexed_by = "joint"
    name = "dahl"
    constant_symbols: ClassVar[Mapping[str, str]] = {"a": "rate"}
    parameter_units: ClassVar[Mapping[str, str]] = {"coulomb": "N m"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"coulomb"})
    description = (
        "r_j = F_c,j z_j, dz/dt = a (qd_j - |qd_j| z_j): Dahl friction of joint j "
        "(Coulomb level F_c with a pre-sliding hysteresis of angle 1/a)"
    )
    linear = True

    def __init__(
        self, n_joints: int = 4, joints: Sequence[int] | None = None, rate: float = 100.0
    ) -> None:
        """Build the term.

        Args:
            n_joints: Number of joints ``n`` of the robot.
            joints: Joints with friction (all when ``None``).
            rate: ``a = sigma / F_c`` [1/rad], the inverse of the pre-sliding angle.
        """
        self.n_joints = int(n_joints)
        self.channels = _joint_channels(self.n_joints, joints)
        self.rate = _positive("rate", rate)
        self.parameter_names = tuple(f"coulomb[{j}]" for j in self.channels)

    def state(self, signals: Signals) -> FloatArray:
        """The normalised Dahl state ``z`` [-] of every joint, shape ``(T, n)``."""
        return direction_memory(signals.qd, signals.t, signals.run, self.rate)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        return _per_joint_design(signals, self.channels, self.state(signals))


#: Samples (evenly spread) on which a nonlinear term's starting parameters are scanned.
GUESS_SAMPLES = 4000
#: Largest smoothed sign ``|tanh(qd / eps)|`` [-] of a joint said to be still in those samples
#: (its friction columns are zero: :class:`StribeckFriction` keeps its default start there).
STILL_SIGN = 1e-9


@register
class StribeckFriction(CandidateEffect):
    """Joint Stribeck friction (nonlinear).

    ``r_j = (c_j + (s_j - c_j) exp(-(qd_j / v_j)^2)) tanh(qd_j / eps) + b_j qd_j``

    Parameters per joint: Coulomb level ``c_j`` [N m], static (breakaway) level ``s_j`` [N m],
    Stribeck velocity ``v_j`` [rad/s] (> 0) and, when ``viscous`` is set, ``b_j`` [N m s/rad].
    ``eps`` [rad/s] is fixed. The fits keep ``s_j >= c_j`` (:meth:`constraints`): the friction
    falls from its breakaway level to the Coulomb level as the joint speeds up. Without that
    order the term's "Stribeck" branch rises with speed instead, which is viscous friction's
    job: on plants with Coulomb and viscous friction it then stood in for the viscous part
    with a Coulomb level many times the plant's at a Stribeck velocity on its bound.
    """

    indexed_by = "joint"
    name = "stribeck"
    constant_symbols: ClassVar[Mapping[str, str]] = {"eps": "eps"}
    parameter_units: ClassVar[Mapping[str, str]] = {
        "coulomb": "N m",
        "static": "N m",
        "stribeck_velocity": "rad/s",
        "viscous": "N m s/rad",
    }
    nonnegative: ClassVar[frozenset[str]] = frozenset(
        {"coulomb", "static", "stribeck_velocity", "viscous"}
    )
    description = (
        "r_j = (c_j + (s_j - c_j) exp(-(qd_j/v_j)^2)) tanh(qd_j/eps) [+ b_j qd_j]: "
        "Coulomb level c, static level s >= c, Stribeck velocity v [, viscous b]"
    )
    linear = False

    def __init__(
        self,
        n_joints: int = 4,
        joints: Sequence[int] | None = None,
        eps: float = 0.01,
        viscous: bool = False,
        max_stribeck_velocity: float = 10.0,
    ) -> None:
        """Build the term.

        Args:
            n_joints: Number of joints ``n`` of the robot.
            joints: Joints with friction (all when ``None``).
            eps: Velocity scale of the smoothed sign [rad/s].
            viscous: Add a viscous coefficient per joint.
            max_stribeck_velocity: Upper bound of ``v_j`` [rad/s]; the lower bound is a
                thousandth of it.
        """
        self.n_joints = int(n_joints)
        self.channels = _joint_channels(self.n_joints, joints)
        self.eps = _positive("eps", eps)
        self.viscous = bool(viscous)
        self.max_stribeck_velocity = _positive("max_stribeck_velocity", max_stribeck_velocity)
        per = ("coulomb", "static", "stribeck_velocity") + (("viscous",) if viscous else ())
        self._per = len(per)
        self.parameter_names = tuple(f"{p}[{j}]" for j in self.channels for p in per)

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        if isinstance(ops, NumpyOps):
            theta = self._check_theta(theta)
        T = signals.n_samples
        qd = ops.const(signals.qd)
        columns = [ops.zeros(T) for _ in range(self.n_joints)]
        for k, j in enumerate(self.channels):
            c, s, v = (theta[self._per * k + i] for i in range(3))
            w = ops.column(qd, j)
            friction = (c + (s - c) * ops.exp(-((w / v) ** 2))) * ops.tanh(w / self.eps)
            if self.viscous:
                friction = friction + theta[self._per * k + 3] * w
            columns[j] = friction
        return ops.hcat(columns)

    def initial_guess(  # noqa: D102
        self, signals: Signals, residual: FloatArray | None = None
    ) -> FloatArray:
        # For a fixed Stribeck velocity the term is linear in (c, s, b): scan v on a log grid,
        # solve least squares for the rest, start from the best (the fit is multimodal in v).
        # A start needs no more than GUESS_SAMPLES evenly spread samples; every grid point's
        # least squares is solved at once, A (V, T, p) by reduced QR.
        lower, _ = self.bounds()
        guess: list[float] = []
        rows = np.unique(np.linspace(0, signals.n_samples - 1, GUESS_SAMPLES).astype(int))
        grid = np.geomspace(float(lower[2]), self.max_stribeck_velocity, 40)
        for j in self.channels:
            best = [0.0, 0.0, float(np.sqrt(grid[0] * grid[-1]))] + [0.0] * self.viscous
            w = signals.qd[rows, j]
            sign = np.tanh(w / self.eps)
            # a joint that does not move (in these samples) tells nothing: the default start
            if residual is not None and np.max(np.abs(sign), initial=0.0) > STILL_SIGN:
                best = self._best_start(w, sign, residual[rows, j], grid)
            guess += best
        return np.asarray(guess, dtype=float)

    def _best_start(
        self, w: FloatArray, sign: FloatArray, r: FloatArray, grid: FloatArray
    ) -> list[float]:
        """One joint's start ``[c, s, v(, b)]``: the least squares at the best grid velocity.

        Where a grid velocity's least squares breaks ``s >= c``, the best start that keeps it
        has ``s = c`` (the constraint's edge, where ``v`` plays no part): the Coulomb (and
        viscous) fit, scored as such.
        """
        viscous = [w] if self.viscous else []
        bump = np.exp(-((w[None, :] / grid[:, None]) ** 2)) * sign
        columns = [sign - bump, bump] + [np.broadcast_to(x, bump.shape) for x in viscous]
        Q, R = np.linalg.qr(np.stack(columns, axis=2))
        projected = np.einsum("vtp,t->vp", Q, r)
        energy = np.sum(projected**2, axis=1)  # least cost: most explained
        x = np.stack([np.linalg.lstsq(R[k], projected[k], rcond=None)[0] for k in range(len(grid))])
        flat, *_ = np.linalg.lstsq(np.stack([sign, *viscous], axis=1), r, rcond=None)
        flat_energy = float(np.sum((np.stack([sign, *viscous], axis=1) @ flat) ** 2))
        ordered = x[:, 1] >= x[:, 0]
        if not ordered.any() or flat_energy >= energy[ordered].max():
            middle = float(np.sqrt(grid[0] * grid[-1]))
            return [flat[0], flat[0], middle] + ([flat[1]] if self.viscous else [])
        k = int(np.flatnonzero(ordered)[np.argmax(energy[ordered])])
        return [x[k, 0], x[k, 1], grid[k]] + ([x[k, 2]] if self.viscous else [])

    def constraints(self) -> FloatArray:
        """``s_j - c_j >= 0`` for each joint: the breakaway level at or above the Coulomb one."""
        G = np.zeros((len(self.channels), self.n_parameters))
        for k in range(len(self.channels)):
            G[k, self._per * k] = -1.0
            G[k, self._per * k + 1] = 1.0
        return G

    def bounds(self) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        lower = [0.0, 0.0, 1e-3 * self.max_stribeck_velocity]
        upper = [np.inf, np.inf, self.max_stribeck_velocity]
        if self.viscous:
            lower.append(-np.inf)
            upper.append(np.inf)
        k = len(self.channels)
        return np.tile(lower, k), np.tile(upper, k)


# --------------------------------------------------------------------------- cable friction
@register
class CableCapstanFriction(CandidateEffect):
    """Sheath (capstan) friction of the cables, load-dependent, with posture-dependent wrap.

    The tension reaching a cable's insertion is ``F exp(-mu Theta(q) s)``, ``s =
    tanh(-ldot / eps)`` (``s > 0`` while the motor pulls the cable in: less tension arrives;
    ``s < 0`` while the cable is paid out: more arrives). The residual is then

    ``r = -J_c^T F + J_c^T F exp(-mu Theta s) = J_c^T (F (exp(-mu Theta s) - 1))``

    (the brief's ``-J_c^T (F (exp(-mu Theta s) - 1))`` is the change of the *delivered* torque,
    ``-r``). Parameter: one friction coefficient ``mu`` [1/rad] shared by all cables, or one per
    cable (``per_cable``); with ``fit_eps`` also the smoothing speed ``eps`` [m/s] of the sign, last
    (how fast the friction turns over as a cable reverses: a property of the sheath, and of how the
    cable speed is estimated, that a real robot does not tell). With ``linearised`` the term is its
    first order in ``mu``, ``r = mu * J_c^T (-F Theta s)`` (``eps`` fixed), and is
    fitted by least squares.
    """

    indexed_by = "cable"
    name = "capstan"
    constant_symbols: ClassVar[Mapping[str, str]] = {"eps": "eps"}
    parameter_units: ClassVar[Mapping[str, str]] = {"mu": "1/rad", "eps": "m/s"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"mu", "eps"})
    description = (
        "r = J_c^T (F (exp(-mu Theta s) - 1)), s = tanh(-ldot/eps): sheath friction with "
        "wrap angle Theta(q) reduces the tension of a cable pulled in (mu shared or per cable)"
    )
    linear = False

    def __init__(
        self,
        n_cables: int = 9,
        n_joints: int = 4,
        eps: float = 1e-3,
        per_cable: bool = False,
        linearised: bool = False,
        max_mu: float = 2.0,
        fit_eps: bool = False,
        eps_bounds: tuple[float, float] = (1e-4, 0.05),
    ) -> None:
        """Build the term.

        Args:
            n_cables: Number of cables ``m``.
            n_joints: Number of joints ``n``.
            eps: Cable-velocity scale of the smoothed sign [m/s] (the start of its fit with
                ``fit_eps``).
            per_cable: One ``mu`` per cable instead of one shared.
            linearised: Use the first-order (linear) term.
            max_mu: Upper bound of ``mu`` in the nonlinear fit.
            fit_eps: Fit ``eps`` too (a last parameter; not with ``linearised``).
            eps_bounds: Bounds of the fitted ``eps`` [m/s].
        """
        self.n_cables, self.n_joints = int(n_cables), int(n_joints)
        self.channels = tuple(range(self.n_joints))
        self.eps = _positive("eps", eps)
        self.per_cable = bool(per_cable)
        self.max_mu = _positive("max_mu", max_mu)
        self.fit_eps = bool(fit_eps)
        if self.fit_eps and linearised:
            raise InputError("capstan: the linearised term keeps eps fixed (fit_eps=False)")
        low, high = (float(v) for v in eps_bounds)
        if not (0 < low <= self.eps <= high and np.isfinite(high)):
            raise InputError(
                f"capstan: eps_bounds must be 0 < low <= eps <= high [m/s], got {eps_bounds} "
                f"with eps = {self.eps}"
            )
        self.eps_bounds = (low, high)
        self.parameter_names = (
            tuple(f"mu[{c}]" for c in range(self.n_cables)) if per_cable else ("mu",)
        ) + (("eps",) if self.fit_eps else ())
        # Instance attribute shadows the class default: the linearised term is linear.
        self.linear = bool(linearised)  # type: ignore[misc]

    def _direction(self, signals: Signals) -> FloatArray:
        return np.tanh(-signals.cable_velocity / self.eps)

    def check(self, signals: Signals) -> None:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        self._check_cables(signals, self.n_cables)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        if not self.linear:
            return super().design(signals)
        self.check(signals)
        g = -signals.tension * signals.wrap * self._direction(signals)  # (T, m)
        per_cable = signals.jacobian * g[:, :, None]  # J_c[c, :] g_c, (T, m, n)
        if self.per_cable:
            return np.transpose(per_cable, (0, 2, 1))
        return per_cable.sum(axis=1)[:, :, None]

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:  # noqa: D102
        if self.linear:
            return super().torque(signals, theta, ops)
        self.check(signals)
        if isinstance(ops, NumpyOps):
            theta = self._check_theta(theta)
        T, m = signals.n_samples, signals.n_cables
        mu = ops.row(theta, 0, m, T) if self.per_cable else theta[0]
        if self.fit_eps:
            eps = theta[self.n_parameters - 1]
            direction = ops.tanh(ops.const(-signals.cable_velocity) / eps)
            exponent = ops.const(-signals.wrap) * direction
        else:
            exponent = ops.const(-signals.wrap * self._direction(signals))
        g = ops.const(signals.tension) * (ops.exp(mu * exponent) - 1.0)
        return ops.cable_to_joint(signals.jacobian, g)

    def initial_guess(  # noqa: D102
        self, signals: Signals, residual: FloatArray | None = None
    ) -> FloatArray:
        guess = np.full(self.n_parameters, 0.05)
        if self.fit_eps:
            guess[-1] = self.eps
        return guess

    def bounds(self) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        lower, upper = np.zeros(self.n_parameters), np.full(self.n_parameters, self.max_mu)
        if self.fit_eps:
            lower[-1], upper[-1] = self.eps_bounds
        return lower, upper


#: How many ``Signals`` a :class:`CableCapstanHysteresis` keeps its columns for.
_COLUMN_CACHE_SIZE = 8

#: Friction coefficients of the stick-slip elements of :class:`CableCapstanHysteresis` [1/rad].
CAPSTAN_STICTION_MUS = (0.03, 0.06, 0.12, 0.24)


@register
class CableCapstanHysteresis(CandidateEffect):
    """Sheath (capstan) friction with stiction: stick-slip elements in log tension.

    :class:`CableCapstanFriction` takes the direction of the friction from the cable's
    velocity, so it predicts no loss while a cable rests. In a sheath with static friction the
    cable sticks instead while the tensions at its ends differ by less than the capstan factor
    ``exp(mu Theta)``, and the insertion keeps the tension of the last slip. One such element
    is :func:`msarm.diagnose.signals.stick_slip_tension` ``S_mu(F)`` of the motor-side tension
    ``F``; friction spread along a sheath sticks and slips at several thresholds, so the term
    is a Prandtl-Ishlinskii sum of elements at the coefficients ``mu_k`` of
    :data:`CAPSTAN_STICTION_MUS`:

    ``T_insertion = F + sum_k a_k (S_mu_k(F) - F)``,
    ``r = J_c^T (T_insertion - F) = sum_k a_k J_c^T (S_mu_k(F) - F)``

    ``F`` here is the tension the drives were commanded (``Signals.tension_cmd``), not the
    load cells' reading: while a cable sticks, ``S(F) - F`` is ``-F`` plus a constant, and with
    the reading it would carry the load cells' noise, which is in the residual too, so the term
    would "explain" sensor noise on held-out runs as well (it did, on the benchmark's null
    plants). Logs without commands cannot use the term.

    Parameters: the weights ``a_k >= 0`` [-] (one element of friction ``mu`` alone is
    ``a = 1`` at that ``mu``); linear in them, fitted by IPOPT within the bounds (a least
    squares would trade weights of opposite signs between the strongly correlated elements).
    With ``linearised`` the same design is fitted by plain least squares.
    """

    name = "capstan_hysteresis"
    parameter_units: ClassVar[Mapping[str, str]] = {"a": "-"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"a"})
    description = (
        "r = sum_k a_k J_c^T (S_mu_k(F) - F), F the commanded tension: sheath friction with "
        "stiction, stick-slip elements (a play in log tension of half-width mu_k Theta)"
    )
    linear = False

    def __init__(
        self,
        n_cables: int = 9,
        n_joints: int = 4,
        mus: Sequence[float] = CAPSTAN_STICTION_MUS,
        linearised: bool = False,
        max_weight: float = 10.0,
    ) -> None:
        """Build the term.

        Args:
            n_cables: Number of cables ``m``.
            n_joints: Number of joints ``n``.
            mus: Friction coefficients ``mu_k`` of the elements [1/rad], each > 0.
            linearised: Fit the weights by plain least squares (no bounds).
            max_weight: Upper bound of each weight in the bounded fit.
        """
        self.n_cables, self.n_joints = int(n_cables), int(n_joints)
        self.channels = tuple(range(self.n_joints))
        self.mus = tuple(_positive("mus", float(mu)) for mu in mus)
        if not self.mus:
            raise InputError("capstan_hysteresis needs at least one friction coefficient")
        self.max_weight = _positive("max_weight", max_weight)
        self.parameter_names = tuple(f"a[mu={mu:g}]" for mu in self.mus)
        # Instance attribute shadows the class default: the linearised term is linear.
        self.linear = bool(linearised)  # type: ignore[misc]
        # the elements' columns of the last few Signals (they do not depend on the weights)
        self._columns_of: dict[int, tuple[Signals, FloatArray]] = {}

    def check(self, signals: Signals) -> None:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        self._check_cables(signals, self.n_cables)
        signals.require("tension_cmd", self.name)

    def _columns(self, signals: Signals) -> FloatArray:
        """``J_c^T (S_mu_k(F) - F)`` of every element [N m], shape ``(T, n, K)``.

        The play operators have memory: on signals taken from others (thinned, or some runs'
        samples, :meth:`Signals.take`) they run on the whole runs first, then these samples
        are taken. Kept for the last few ``Signals`` objects (a fit predicts on the same
        samples many times); a ``Signals`` is not to be changed in place once used.
        """
        cached = self._columns_of.get(id(signals))
        if cached is not None and cached[0] is signals:
            return cached[1]
        if signals.origin is None:
            columns = self._compute_columns(signals)
        else:
            whole, rows = signals.origin
            columns = self._columns(whole)[rows]
        columns.setflags(write=False)  # shared between calls
        if len(self._columns_of) >= _COLUMN_CACHE_SIZE:
            self._columns_of.pop(next(iter(self._columns_of)))
        self._columns_of[id(signals)] = (signals, columns)
        return columns

    def _compute_columns(self, signals: Signals) -> FloatArray:
        self.check(signals)
        command = signals.tension_cmd
        return np.stack(
            [
                np.einsum(
                    "tm,tmn->tn",
                    stick_slip_tension(command, signals.wrap, signals.run, mu) - command,
                    signals.jacobian,
                )
                for mu in self.mus
            ],
            axis=2,
        )

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        if not self.linear:
            return super().design(signals)
        return self._columns(signals)

    def torque(self, signals: Signals, theta: Any, ops: Ops = NUMPY_OPS) -> Any:  # noqa: D102
        if self.linear:
            return super().torque(signals, theta, ops)
        if isinstance(ops, NumpyOps):
            theta = self._check_theta(theta)
        columns = self._columns(signals)
        total = None
        for k in range(columns.shape[2]):
            part = theta[k] * ops.const(columns[:, :, k])
            total = part if total is None else total + part
        return total

    def initial_guess(  # noqa: D102
        self, signals: Signals, residual: FloatArray | None = None
    ) -> FloatArray:
        return np.full(self.n_parameters, 1.0 / self.n_parameters)

    def bounds(self) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        return np.zeros(self.n_parameters), np.full(self.n_parameters, self.max_weight)


# --------------------------------------------------------------------------- motor cogging
@register
class MotorCogging(CandidateEffect):
    """Motor cogging: a torque periodic in the motor angle, seen by the cable through the drum.

    The motor of cable ``c`` has a cogging torque ``A_c sin(N theta_c + phi_c)`` [N m]; the logged
    tension exceeds the one the cable delivers by ``dF_c = A_c sin(N theta_c + phi_c) / rho``
    (``rho`` the drum radius [m]), so ``r = -J_c^T dF``. Linear in ``a_c = A_c cos(phi_c)`` and
    ``b_c = A_c sin(phi_c)`` [N m] (``dF_c = (a_c sin(N theta_c) + b_c cos(N theta_c)) / rho``) for
    a known number ``N`` of cogging periods per motor revolution. One pair per cable, or one pair
    shared by all motors (``shared``: identical motors mounted in phase).
    """

    indexed_by = "cable"
    name = "cogging"
    constant_symbols: ClassVar[Mapping[str, str]] = {"N": "n_periods", "rho": "drum_radius"}
    parameter_units: ClassVar[Mapping[str, str]] = {"cogging_a": "N m", "cogging_b": "N m"}
    description = (
        "r = -J_c^T dF, dF_c = (a_c sin(N theta_c) + b_c cos(N theta_c)) / rho (amplitude "
        "hypot(a_c, b_c)): motor cogging torque periodic in the motor angle theta_c, through the "
        "drum radius rho; dF the logged tension less the delivered one"
    )
    linear = True

    def __init__(
        self,
        n_periods: int,
        drum_radius: float | Sequence[float],
        n_cables: int = 9,
        n_joints: int = 4,
        shared: bool = False,
    ) -> None:
        """Build the term.

        Args:
            n_periods: Cogging periods per motor revolution ``N``.
            drum_radius: Drum radius ``rho`` [m], one or per cable ``(m,)``.
            n_cables: Number of cables ``m``.
            n_joints: Number of joints ``n``.
            shared: One amplitude-phase pair for all motors instead of one per motor.
        """
        if int(n_periods) < 1:
            raise InputError(f"n_periods: expected an integer >= 1, got {n_periods}")
        self.n_periods = int(n_periods)
        self.n_cables, self.n_joints = int(n_cables), int(n_joints)
        radius = np.broadcast_to(np.asarray(drum_radius, dtype=float), (self.n_cables,))
        if not np.all(np.isfinite(radius)) or np.any(radius <= 0):
            raise InputError(f"drum_radius: expected values > 0 m, got {drum_radius}")
        self.drum_radius = radius.copy()
        self.shared = bool(shared)
        self.channels = tuple(range(self.n_joints))
        cables = ("all",) if shared else tuple(str(c) for c in range(self.n_cables))
        self.parameter_names = tuple(f"cogging_{p}[{c}]" for c in cables for p in ("a", "b"))

    def parameter_groups(self) -> tuple[tuple[int, ...], ...]:
        """None: the sine and cosine parts make one amplitude and phase together."""
        return ()

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        self._check_cables(signals, self.n_cables)
        # the motor speed is there exactly when every log has its motor angles (else they
        # would be zeros standing in for the missing columns)
        signals.require("motor_speed", self.name)
        angle = self.n_periods * signals.motor_angle
        T, m, n = signals.jacobian.shape
        out = np.empty((T, n, 2 * m))
        for k, basis in enumerate((np.sin(angle), np.cos(angle))):
            dF = basis / self.drum_radius  # (T, m) per unit parameter
            out[:, :, k::2] = -np.transpose(signals.jacobian * dF[:, :, None], (0, 2, 1))
        if self.shared:
            return out.reshape(T, n, m, 2).sum(axis=2)
        return out


# --------------------------------------------------------------------------- sensors
@register
class SensorBiasScale(CandidateEffect):
    """Load-cell bias and scale error.

    A load cell reads ``F = F_true + b + (k - 1) F`` (bias ``b`` [N], scale ``k`` [-], to first
    order in ``k - 1``), so the delivered tension is ``F - b - (k - 1) F`` and

    ``r = -J_c^T (b + (k - 1) F)``.

    Linear in ``b`` and ``g = k - 1``, per cable (``2 m`` parameters, default) or shared by all
    cables (``shared``: 2 parameters). ``bias`` / ``scale`` switch either part off.

    With ``drive`` the term also predicts the drive residual (groups ``joint`` and ``drive``):
    a drive that closes its loop on the true tension makes the reading differ from the
    command by ``e = b + (k - 1) F``.

    On logs without the drive residual, the diagnosis tries the term's joint-only form
    (:meth:`restricted`) with the bias alone. The scale's regressor on the joint group is the
    torque the load cells deliver, ``J_c^T F``, which the mass-error term (its regressor spans
    the inverse dynamics that torque balances) and the friction terms span but for the gap
    itself: fitted together they take the nominal model apart and "explain" any residual.
    On logs of the default plant without ``tension_cmd`` columns they did, naming a load-cell
    scale of +0.98 and a forearm mass error of -3.3 kg (a negative mass), both with
    confidence 1. The drive residual, ``F - F_cmd``, is what tells a scale error apart.
    """

    indexed_by = "cable"
    name = "sensor"
    parameter_units: ClassVar[Mapping[str, str]] = {"bias": "N", "scale_minus_1": "-"}
    description = (
        "r = -J_c^T (b + (k - 1) F): load-cell bias b [N] and scale k, per cable or shared"
    )
    linear = True

    def __init__(
        self,
        n_cables: int = 9,
        n_joints: int = 4,
        shared: bool = False,
        bias: bool = True,
        scale: bool = True,
        drive: bool = False,
    ) -> None:
        """Build the term.

        Args:
            n_cables: Number of cables ``m``.
            n_joints: Number of joints ``n``.
            shared: One bias and one scale for all cables.
            bias: Fit the bias.
            scale: Fit the scale.
            drive: Also predict the drive residual (groups ``joint`` and ``drive``).
        """
        if not (bias or scale):
            raise InputError("SensorBiasScale: at least one of bias and scale must be fitted")
        self.n_cables, self.n_joints = int(n_cables), int(n_joints)
        self.shared, self.bias, self.scale = bool(shared), bool(bias), bool(scale)
        self.channels = tuple(range(self.n_joints))
        cables = ("all",) if shared else tuple(str(c) for c in range(self.n_cables))
        kinds = (("bias",) if bias else ()) + (("scale_minus_1",) if scale else ())
        self.parameter_names = tuple(f"{k}[{c}]" for k in kinds for c in cables)
        self.groups = ("joint", "drive") if drive else ("joint",)

    def restricted(self, groups: Sequence[str]) -> CandidateEffect | None:
        """The joint-only form: the bias alone (None for a scale-only term; see above)."""
        if "joint" not in groups or not self.bias:
            return None
        return SensorBiasScale(
            self.n_cables, self.n_joints, self.shared, bias=True, scale=False, drive=False
        )

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        self._check_cables(signals, self.n_cables)
        JT = -np.transpose(signals.jacobian, (0, 2, 1))  # (T, n, m)
        F = signals.tension
        joint = []
        if self.bias:
            joint.append(JT)
        if self.scale:
            joint.append(JT * F[:, None, :])
        if self.shared:
            joint = [j.sum(axis=2, keepdims=True) for j in joint]
        joint_part = np.concatenate(joint, axis=2)
        if "drive" not in self.groups:
            return joint_part
        # cable c's reading: 1 (bias) and F_c (scale) on drive column c; shared, their sums
        # over the cables' diagonal matrices, which are those values
        eye = np.broadcast_to(np.eye(self.n_cables), (signals.n_samples,) + JT.shape[2:] * 2)
        drive = []
        if self.bias:
            drive.append(np.ones_like(F)[:, :, None] if self.shared else eye)
        if self.scale:
            drive.append(F[:, :, None] if self.shared else eye * F[:, None, :])
        return np.concatenate([joint_part, np.concatenate(drive, axis=2)], axis=1)


@register
class TensionDelay(CandidateEffect):
    """A time offset of the logged tensions, to first order.

    The load cells are logged ``d`` [s] late: the tension delivered at ``t`` is ``F(t + d)``,
    so ``r = -J_c^T (F(t) - F(t + d)) ~= d J_c^T dF/dt`` (``dF/dt`` by central differences within
    each segment: a run, restarted after a time gap). Linear in ``d``; valid while ``d`` is
    small against the tensions' time scale (a negative ``d``: the tensions lead).
    """

    name = "delay"
    parameter_units: ClassVar[Mapping[str, str]] = {"delay": "s"}
    description = "r = d * J_c^T dF/dt: logged tensions late by d [s] (first order in d)"
    linear = True

    def __init__(self, n_cables: int = 9, n_joints: int = 4) -> None:
        """Build the term.

        Args:
            n_cables: Number of cables ``m``.
            n_joints: Number of joints ``n``.
        """
        self.n_cables, self.n_joints = int(n_cables), int(n_joints)
        self.channels = tuple(range(self.n_joints))
        self.parameter_names = ("delay",)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        self._check_cables(signals, self.n_cables)
        rate = signals.tension_rate()
        return np.einsum("tmn,tm->tn", signals.jacobian, rate)[:, :, None]


# --------------------------------------------------------------------------- inertia
_INERTIAL_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")


def _moved_bodies(pin_model: Any) -> list[str]:
    """For each Pinocchio joint but the universe, the first body it moves (else its name)."""
    names = []
    for joint in range(1, pin_model.njoints):
        bodies = [
            f.name
            for f in pin_model.frames
            if f.parentJoint == joint and f.type == pinocchio.FrameType.BODY
        ]
        names.append(bodies[0] if bodies else pin_model.names[joint])
    return names


@register
class InertiaError(CandidateEffect):
    """Mass and inertia error of the links, through Pinocchio's joint-torque regressor.

    The true dynamics have inertial parameters ``pi + dpi``; inverse dynamics is linear in
    them, so ``r = Y(q, qd, qdd) dpi`` with ``Y`` = ``pinocchio.computeJointTorqueRegressor``
    (``n x 10 nbodies``; per body ``m`` [kg], ``m c`` [kg m], ``I`` [kg m^2] about the joint
    frame, Pinocchio's order ``m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz``).

    Parameters are named ``<body>.<kind>`` after the first body each Pinocchio joint moves
    (``upper_arm.m``, ``forearm.mcx``; the bodies fixed to it, such as the hand, are in its
    inertia), not after the joint (the parser merges the shoulder's three hinges into one
    ``Composite_shoulder_abduction`` joint).

    Parameter set: ``subset="mass"`` keeps each body's mass and first moments (4 per body);
    ``subset="all"`` all 10. Either way, the kept columns are reduced to an identifiable set
    (a *base* set): the regressor is evaluated on random states inside the joint limits (seeded)
    and a rank-revealing QR with column pivoting keeps independent columns only (e.g. the mass of
    the first body of a fixed-base arm has no effect and is dropped). A kept parameter's
    estimate then also carries the dropped columns that depend on it.

    The accelerations in ``Y`` are the logged reference's (``Signals.qdd_ref``) where the logs
    have one, else the measured ones. The measured accelerations carry the encoders' noise,
    which the residual carries too, through the inverse dynamics of the logged motion: with
    them the term "predicts" that noise on held-out runs (a held-out gain of 0.034 on 4 s
    runs of a plant with sensor noise alone, where the reference's give -0.001). A tracking
    controller's motion follows its reference closely, so the error this makes is of the
    order of ``dpi`` times the tracking error's acceleration.
    """

    name = "inertia"
    parameter_units: ClassVar[Mapping[str, str]] = {
        "m": "kg",
        "mcx": "kg m",
        "mcy": "kg m",
        "mcz": "kg m",
        "Ixx": "kg m^2",
        "Ixy": "kg m^2",
        "Iyy": "kg m^2",
        "Ixz": "kg m^2",
        "Iyz": "kg m^2",
        "Izz": "kg m^2",
    }
    description = (
        "r = Y(q, qd, qdd) dpi: inertial parameter error dpi of the links through the "
        "joint-torque regressor (base set of masses and first moments, or of all parameters)"
    )
    linear = True
    memoryless = True  # Pinocchio's regressor at each sample's q, qd, qdd

    def __init__(self, robot: Any, subset: str = "mass", n_probe: int = 200, seed: int = 0) -> None:
        """Build the term.

        Args:
            robot: A :class:`msarm.model.RobotModel` (``pin_model``, ``pin_q_index``,
                ``joint_lower``, ``joint_upper``).
            subset: ``"mass"`` (mass and first moments) or ``"all"``.
            n_probe: Random states used to find the identifiable columns.
            seed: Seed of the random states.
        """
        if subset not in ("mass", "all"):
            raise InputError(f"subset: expected 'mass' or 'all', got {subset!r}")
        self.pin_model = robot.pin_model
        self.pin_data = self.pin_model.createData()
        self.index = np.asarray(robot.pin_q_index, dtype=np.intp)
        self.inverse = np.argsort(self.index)
        self.n_joints = len(self.index)
        if self.pin_model.nq != self.n_joints or self.pin_model.nv != self.n_joints:
            raise InputError(
                f"robot: InertiaError needs nq == nv == {self.n_joints} joints, got "
                f"nq={self.pin_model.nq}, nv={self.pin_model.nv}"
            )
        self.channels = tuple(range(self.n_joints))
        bodies = _moved_bodies(self.pin_model)
        per = 4 if subset == "mass" else 10
        candidates = [10 * b + k for b in range(len(bodies)) for k in range(per)]
        rng = np.random.default_rng(seed)
        lower = np.where(np.isfinite(robot.joint_lower), robot.joint_lower, -np.pi)
        upper = np.where(np.isfinite(robot.joint_upper), robot.joint_upper, np.pi)
        rows = []
        for _ in range(int(n_probe)):
            q = rng.uniform(lower, upper)
            qd, qdd = rng.normal(size=self.n_joints), rng.normal(size=self.n_joints)
            rows.append(self._regressor(q, qd, qdd)[:, candidates])
        stacked = np.vstack(rows)
        stacked = stacked / np.maximum(np.linalg.norm(stacked, axis=0), 1e-300)
        from scipy.linalg import qr

        _, r_factor, pivot = qr(stacked, mode="economic", pivoting=True)
        diagonal = np.abs(np.diag(r_factor))
        rank = int(np.sum(diagonal > 1e-8 * diagonal[0])) if diagonal.size else 0
        self.columns = np.sort(np.asarray(candidates)[pivot[:rank]])
        #: Why the term has no parameter on this model (``""`` when it has some): the
        #: diagnosis then leaves it out, with this reason, instead of fitting nothing.
        self.why_no_parameters = (
            ""
            if rank
            else (
                "none of the links' masses and first moments changes the joint torques of "
                "this model (gravity does not act about its joint axes: a vertical hinge, say)"
                if subset == "mass"
                else "no inertial parameter of the links changes the joint torques of this model"
            )
        )
        self.parameter_names = tuple(
            f"{bodies[c // 10]}.{_INERTIAL_NAMES[c % 10]}" for c in self.columns
        )
        nominal = [
            np.asarray(self.pin_model.inertias[j].toDynamicParameters(), dtype=float)
            for j in range(1, self.pin_model.njoints)
        ]
        #: The nominal model's value of each kept parameter, shape ``(p,)`` (units as above).
        self.nominal = np.concatenate(nominal)[self.columns]

    def impossible_masses(self, theta: ArrayLike) -> list[tuple[str, float, float]]:
        """The bodies that a fitted error ``theta`` leaves with no positive mass.

        Args:
            theta: Fitted parameter errors, shape ``(p,)``.

        Returns:
            ``(parameter, nominal, nominal + error)`` [kg] for each mass parameter whose
            corrected value is ``<= 0``: no physical body, so the term stands in for
            something else.
        """
        theta = self._check_theta(theta)
        return [
            (name, float(nominal), float(nominal + value))
            for name, nominal, value in zip(self.parameter_names, self.nominal, theta, strict=True)
            if parameter_kind(name) == "m" and nominal + value <= 0.0
        ]

    def _regressor(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """Joint-torque regressor in msarm joint order, shape ``(n, 10 nbodies)``."""
        Y = pinocchio.computeJointTorqueRegressor(
            self.pin_model, self.pin_data, q[self.index], qd[self.index], qdd[self.index]
        )
        # a one-joint model's regressor comes back as a vector (Eigen's 1 x p matrix)
        return np.asarray(Y).reshape(self.n_joints, -1)[self.inverse]

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_joints(signals, self.n_joints)
        qdd = signals.qdd if signals.qdd_ref is None else signals.qdd_ref
        # in Pinocchio's joint order, every column, sample by sample (the regressor's own
        # copy), then the joints' order and the kept columns taken for all samples at once
        q, qd, qdd = (
            np.ascontiguousarray(x[:, self.index], dtype=float)
            for x in (signals.q, signals.qd, qdd)
        )
        full = np.empty((signals.n_samples, self.n_joints, 10 * (self.pin_model.njoints - 1)))
        regressor = pinocchio.computeJointTorqueRegressor
        for k in range(signals.n_samples):
            full[k] = regressor(self.pin_model, self.pin_data, q[k], qd[k], qdd[k])
        return full[:, self.inverse][:, :, self.columns]
