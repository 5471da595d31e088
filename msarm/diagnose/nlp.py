"""IPOPT solvers of the fits, built once per problem structure and shared.

A fit's NLP is a casadi expression of the parameters ``theta``, the per-sample weights and the
residual (NLP parameters), and the data of its samples. Building the solver
(``casadi.nlpsol``: the derivatives, their sparsity, IPOPT's set-up) costs about as much as a
few of its solves, and most of it grows with the samples. :class:`DataOps` builds the
expression with each data array as a symbol instead of a constant: the same term on as many
samples then gives the same expression whatever the samples' values, and
:func:`shared_solver` builds its solver once and hands it to every problem of that structure
(the benchmark's scenarios, say), each solve passing its own data as NLP parameters. What
depends on the data alone (the smoothed sign of a logged speed, a column of it) is computed
once per problem, as a constant was (``casadi.extract_parametric``), not at each evaluation.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

import casadi
import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.effects import CasadiOps
from msarm.errors import InputError

__all__ = [
    "IPOPT_OPTIONS",
    "SOLVERS_KEPT",
    "BufferedNlpsol",
    "DataOps",
    "shared_solver",
]

FloatArray = NDArray[np.float64]

#: IPOPT's settings for the fits (``casadi.nlpsol`` options), on objectives normalised by the
#: residual's weighted energy.
IPOPT_OPTIONS: dict[str, object] = {
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "print_time": False,
    # the multipliers of the NLP parameters (the weights, the residual, the data) are not used
    "calc_lam_p": False,
    # 1e-10 on the normalised objective: parameters within 1e-6 relative of the optimum
    # (1e-14 took a third more iterations for the same answer to 1e-9)
    "ipopt.tol": 1e-10,
    "ipopt.max_iter": 500,
    # Start near the guess: the residual objective may be far below the default barrier
    # parameter (0.1), which would push the iterate away from a good start.
    "ipopt.mu_init": 1e-8,
    "ipopt.warm_start_init_point": "yes",
    "ipopt.bound_push": 1e-10,
    "ipopt.bound_frac": 1e-10,
}

#: How many built solvers :func:`shared_solver` keeps (the last used).
SOLVERS_KEPT = 16

#: casadi operations whose line in a function's printed algorithm says all they do (with the
#: constants' values and each result's shape, which the key adds): an expression with any
#: other (a call of another function, a look-up table) gets a solver of its own.
_PRINTED_IN_FULL = frozenset(
    [*range(casadi.OP_ATAN2 + 1)]  # arithmetic and elementwise functions
    + [
        casadi.OP_CONST,
        casadi.OP_INPUT,
        casadi.OP_OUTPUT,
        casadi.OP_PARAMETER,
        casadi.OP_MTIMES,
        casadi.OP_TRANSPOSE,
        casadi.OP_DOT,
        casadi.OP_BILIN,
        casadi.OP_RANK1,
        casadi.OP_HORZCAT,
        casadi.OP_VERTCAT,
        casadi.OP_DIAGCAT,
        casadi.OP_RESHAPE,
        casadi.OP_GETNONZEROS,
        casadi.OP_ADDNONZEROS,
        casadi.OP_SETNONZEROS,
        casadi.OP_NORM2,
        casadi.OP_NORM1,
        casadi.OP_NORMINF,
        casadi.OP_NORMF,
        casadi.OP_MMIN,
        casadi.OP_MMAX,
        casadi.OP_HORZREPMAT,
        casadi.OP_HORZREPSUM,
        casadi.OP_LOG1P,
        casadi.OP_EXPM1,
        casadi.OP_HYPOT,
    ]
)

_SOLVERS: OrderedDict[bytes, tuple[BufferedNlpsol, _BufferedFunction]] = OrderedDict()
_SOLVERS_LOCK = threading.Lock()


class BufferedNlpsol:
    """A ``casadi.nlpsol`` called on numpy arrays' memory (:meth:`casadi.Function.buffer`).

    Called as the solver is (``solver(x0=..., p=..., lbx=..., ...)``, inputs not given take
    the solver's defaults) and returning ``{"x": theta}``; :meth:`stats` gives the last
    solve's status (its timings and call counts add up over the solves). casadi copies a
    numpy argument into a ``DM`` value by value (about 50 ns a value): a fit's parameter
    vector (the per-sample weights and the residual, 12,000-110,000 values) took 1-5 ms a
    solve, a tenth of a typical one, and the outputs (multipliers for each NLP parameter) as
    much again. Here the inputs are copied into arrays bound once and only ``x`` is asked
    for: the same function on the same numbers, so the same ``x``, bit for bit. One solve at
    a time (a lock: the arrays are shared); problems of one structure share a solver
    (:func:`shared_solver`), and :meth:`stats` is the calling thread's last solve's.
    """

    def __init__(self, solver: casadi.Function) -> None:
        self.function = solver
        self._lock = threading.Lock()
        self._buffer, self._evaluate = solver.buffer()
        self._index = {name: i for i, name in enumerate(solver.name_in())}
        self._defaults = [float(solver.default_in(i)) for i in range(solver.n_in())]
        self._inputs = [np.zeros(solver.nnz_in(i)) for i in range(solver.n_in())]
        for i, values in enumerate(self._inputs):
            if values.size:
                self._buffer.set_arg(i, memoryview(values))
        self._x = np.zeros(solver.nnz_out(solver.index_out("x")))
        self._buffer.set_res(solver.index_out("x"), memoryview(self._x))
        self._local = threading.local()

    def __call__(self, **arguments: Any) -> dict[str, FloatArray]:
        """Solve; ``arguments`` by the solver's input names (column-major values)."""
        unknown = set(arguments) - set(self._index)
        if unknown:
            raise InputError(f"nlpsol: unknown input(s) {sorted(unknown)}")
        with self._lock:
            for name, i in self._index.items():
                target = self._inputs[i]
                if name not in arguments:
                    target.fill(self._defaults[i])
                    continue
                value = np.asarray(arguments[name], dtype=float).reshape(-1, order="F")
                if value.size == 1 and target.size != 1:  # a scalar for every value, as casadi
                    target.fill(float(value[0]))
                elif value.size != target.size:
                    raise InputError(
                        f"nlpsol: input {name} has {value.size} values, expected {target.size}"
                    )
                else:
                    target[:] = value
            self._evaluate()
            self._local.stats = self._buffer.stats()
            return {"x": self._x.copy()}

    def stats(self) -> dict[str, Any]:
        """The calling thread's last solve's statistics (IPOPT's status; timings add up)."""
        return getattr(self._local, "stats", {})


class _BufferedFunction:
    """A casadi function evaluated on numpy arrays' memory (no copies into ``DM`` values).

    Called with its inputs (numpy arrays of the inputs' shapes, dense); returns all its
    outputs' nonzeros (column-major) one after the other. One evaluation at a time.
    """

    def __init__(self, function: casadi.Function) -> None:
        self._lock = threading.Lock()
        self._buffer, self._evaluate = function.buffer()
        self._outputs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        for i, values in enumerate(self._outputs):
            if values.size:
                self._buffer.set_res(i, memoryview(values))

    def __call__(self, inputs: Sequence[FloatArray]) -> FloatArray:
        """The outputs' nonzeros, concatenated, for ``inputs``."""
        columns = [
            np.ascontiguousarray(np.asarray(a, dtype=float).reshape(-1, order="F")) for a in inputs
        ]
        with self._lock:
            for i, values in enumerate(columns):
                if values.size:
                    self._buffer.set_arg(i, memoryview(values))
            self._evaluate()
            return np.concatenate(self._outputs) if self._outputs else np.zeros(0)


class DataOps(CasadiOps):
    """:class:`CasadiOps` with each data array a symbol: the expression holds no data.

    Each :meth:`const` array becomes a new ``MX`` symbol of its shape (as ``casadi.DM`` shapes
    it: ``(T, k)``, ``(n,)`` as ``(n, 1)``, a number as ``(1, 1)``); :attr:`symbols` and
    :attr:`values` (the arrays in those shapes) keep them in order.
    """

    def __init__(self) -> None:
        self.symbols: list[casadi.MX] = []
        self.values: list[FloatArray] = []

    def const(self, a: FloatArray) -> Any:  # noqa: D102
        values = np.asarray(a, dtype=float)
        if values.ndim > 2:
            return super().const(values)  # refused by casadi, as before
        shape = values.shape if values.ndim == 2 else (values.size, 1) if values.ndim else (1, 1)
        symbol = casadi.MX.sym(f"data{len(self.symbols)}", *shape)
        self.symbols.append(symbol)
        self.values.append(values.reshape(shape))
        return symbol


def shared_solver(
    name: str,
    x: casadi.MX,
    given: Sequence[casadi.MX],
    objective: casadi.MX,
    data: DataOps,
    G: FloatArray,
) -> tuple[BufferedNlpsol, FloatArray, dict[str, FloatArray]]:
    """IPOPT's solver of ``min objective s.t. G x >= 0`` (bounds at each solve), shared.

    The parts of ``objective`` that depend on ``data``'s symbols alone are taken out
    (``casadi.extract_parametric``) and computed here, once per problem; the solver's NLP
    parameters are ``given`` (the problem's own, set at each solve), then the data it uses.
    Problems whose expressions are the same (:func:`_structure`) share one solver (the last
    :data:`SOLVERS_KEPT` kept); an expression that calls other functions gets its own.

    Args:
        name: The solver's name.
        x: The decision variables, a symbol ``(p, 1)``.
        given: The problem's own NLP parameters, symbols (each passed ``vec``-ed).
        objective: The objective, scalar.
        data: The ops the objective's data were built with.
        G: The linear inequalities ``G @ x >= 0``, ``(k, p)``.

    Returns:
        ``(solver, values, bounds)``: the solver; the data's values, to append to ``given``'s
        at each solve; and the inequalities' bounds to pass with each solve (empty without).
    """
    key = _structure(name, [x, *given, *data.symbols], objective, G)
    with _SOLVERS_LOCK:
        shared = None if key is None else _SOLVERS.get(key)
        if shared is not None:
            _SOLVERS.move_to_end(key)
    if shared is None:
        shared = _build(name, x, given, objective, data, G)
        if key is not None:
            with _SOLVERS_LOCK:
                _SOLVERS[key] = shared
                while len(_SOLVERS) > SOLVERS_KEPT:
                    _SOLVERS.popitem(last=False)
    solver, parts = shared
    k = int(G.shape[0])
    bounds = {"lbg": np.zeros(k), "ubg": np.full(k, np.inf)} if k else {}
    return solver, parts(data.values), bounds


def _build(
    name: str,
    x: casadi.MX,
    given: Sequence[casadi.MX],
    objective: casadi.MX,
    data: DataOps,
    G: FloatArray,
) -> tuple[BufferedNlpsol, _BufferedFunction]:
    """The solver of :func:`shared_solver`'s problem and the function of its data parameters.

    Returns:
        ``(solver, parts)``: ``parts`` maps ``data``'s arrays to the solver's data parameters
        (those arrays the objective still uses, then the data-only parts taken out of it).
    """
    symbols: list[casadi.MX] = []
    values: list[casadi.MX] = []
    if data.symbols:
        objective, extracted, extracted_values = casadi.extract_parametric(objective, data.symbols)
        used = {s.name() for s in casadi.symvar(objective)}
        symbols = [s for s in data.symbols if s.name() in used] + list(extracted)
        values = [s for s in data.symbols if s.name() in used] + list(extracted_values)
    problem = {
        "x": x,
        "p": casadi.vertcat(*[casadi.vec(s) for s in [*given, *symbols]]),
        "f": objective,
    }
    if G.shape[0]:
        problem["g"] = casadi.mtimes(casadi.DM(G), x)
    solver = BufferedNlpsol(casadi.nlpsol(name, "ipopt", problem, IPOPT_OPTIONS))
    return solver, _BufferedFunction(casadi.Function(f"{name}_data", data.symbols, values))


#: Operations whose printed line does not tell the shape or the sparsity of their result (the
#: key adds them). An input's shape and count of nonzeros are printed, not where its nonzeros
#: are: a sparse symbol of ``given`` (``(2, 2)`` with 2 nonzeros on the diagonal or in the
#: first column) would otherwise share the solver of another pattern.
_SHAPE_NOT_PRINTED = frozenset(
    [
        casadi.OP_CONST,
        casadi.OP_INPUT,
        casadi.OP_RESHAPE,
        casadi.OP_GETNONZEROS,
        casadi.OP_HORZREPSUM,
    ]
)


def _structure(
    name: str, inputs: Sequence[casadi.MX], objective: casadi.MX, G: FloatArray
) -> bytes | None:
    """A digest of a problem: equal for problems one solver serves, or None (not shared).

    The objective's printed algorithm (every operation, its operands and any indices; the
    inputs' shapes), the shapes and sparsity patterns of results it does not print (the
    inputs' patterns among them) and the constants' exact values, and ``G``: data values,
    held as NLP parameters, do not enter. None when an operation is not one of
    :data:`_PRINTED_IN_FULL`.
    """
    function = casadi.Function(name, list(inputs), [objective])
    digest = hashlib.sha256(name.encode())
    digest.update(function.str(True).encode())
    digest.update(np.asarray(G.shape, dtype=np.int64).tobytes())
    digest.update(np.asarray(G, dtype=float).tobytes())
    for k in range(function.n_instructions()):
        op = function.instruction_id(k)
        if op not in _PRINTED_IN_FULL:
            return None
        if op not in _SHAPE_NOT_PRINTED:
            continue
        node = function.instruction_MX(k)
        sparsity = node.sparsity()
        digest.update(np.array([k, *sparsity.shape, sparsity.nnz()], dtype=np.int64).tobytes())
        if not sparsity.is_dense():
            digest.update(np.asarray(sparsity.colind() + sparsity.row()).tobytes())
        if op == casadi.OP_CONST:
            digest.update(np.asarray(node.to_DM().nonzeros(), dtype=float).tobytes())
    return digest.digest()
