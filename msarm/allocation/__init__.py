"""The allocation core: actuator forces from a wanted joint torque or platform wrench.

One problem serves the arm and the cable robots (see ``msarm.allocation.problem``)::

    find f   minimising 1/2 ||W (f - f_ref)||^2   subject to   M f = b,  f_min <= f <= f_max

- arm (paper 003): ``M = -J_c^T`` (4 x 9), ``b = tau`` [N m], ``weights = 1/F_max`` and
  ``f_ref = None``: a stand-in for the sum of squared activations (see
  ``msarm.allocation.problem``), bounds from the muscles' force capacity;
- cable robot (papers 000, 001): ``M = A^T`` (6 x 8, ``msarm.cdpr``), ``b = -w``;
  ``f_ref = None`` is the minimum 2-norm distribution, ``f_ref="midpoint"`` Pott's.

Build an allocator once per robot and call ``solve`` every tick (``At`` the structure
matrix, ``w`` the wrench, ``f_min``, ``f_max`` the force bounds of the tick)::

    alloc = make_allocator(n_actuators=8, n_dof=6, solver="fast", f_ref="midpoint")
    result = alloc.solve(At, -w, f_min, f_max)   # result.f, .feasible, .status, .residual

Solvers (``SOLVERS``): ``"fast"`` (DAQP, exact, about 15 us a tick), ``"newton"`` (exact, a
compiled dual Newton method that a compiled control loop calls directly), ``"batched"`` (exact,
N problems at once with ``solve_batch``, over 100,000 a second), ``"cvxpy"`` (the exact
reference, about 1 ms), ``"closed_form"`` and ``"improved_closed_form"`` (Pott's, not the QP
optimum when a bound is active). The exact ones give one answer (to round-off, about 1e-12
relative). An infeasible problem never raises: the result holds the bounded f closest to
``M f = b`` with ``feasible=False``.
"""

from __future__ import annotations

from typing import Literal

from numpy.typing import ArrayLike

from msarm.allocation.batched import BatchedAllocator
from msarm.allocation.problem import (
    CLOSED_FORM,
    FALLBACK,
    INFEASIBLE,
    OPTIMAL,
    STATUSES,
    AllocationResult,
    AllocationSpec,
    BatchAllocationResult,
)
from msarm.allocation.solvers import (
    Allocator,
    ClosedFormAllocator,
    CvxpyAllocator,
    DaqpAllocator,
    ImprovedClosedFormAllocator,
)
from msarm.allocation.solvers.newton import NewtonAllocator
from msarm.allocation.workspace import (
    WorkspaceGrid,
    is_wrench_feasible,
    wrench_feasible_grid,
    wrench_feasible_poses,
)
from msarm.errors import InputError

__all__ = [
    "CLOSED_FORM",
    "EXACT_SOLVERS",
    "FALLBACK",
    "INFEASIBLE",
    "OPTIMAL",
    "SOLVERS",
    "STATUSES",
    "AllocationResult",
    "AllocationSpec",
    "Allocator",
    "BatchAllocationResult",
    "BatchedAllocator",
    "ClosedFormAllocator",
    "CvxpyAllocator",
    "DaqpAllocator",
    "ImprovedClosedFormAllocator",
    "NewtonAllocator",
    "SolverName",
    "WorkspaceGrid",
    "is_wrench_feasible",
    "make_allocator",
    "wrench_feasible_grid",
    "wrench_feasible_poses",
]

SolverName = Literal["fast", "newton", "batched", "cvxpy", "closed_form", "improved_closed_form"]

_CLASSES: dict[str, type[Allocator]] = {
    "fast": DaqpAllocator,
    "newton": NewtonAllocator,
    "batched": BatchedAllocator,
    "cvxpy": CvxpyAllocator,
    "closed_form": ClosedFormAllocator,
    "improved_closed_form": ImprovedClosedFormAllocator,
}
_ALIASES = {"daqp": "fast"}

SOLVERS: tuple[str, ...] = tuple(_CLASSES)
"""Names accepted by ``make_allocator``."""
EXACT_SOLVERS: tuple[str, ...] = ("fast", "newton", "batched", "cvxpy")
"""Solvers that return the QP optimum (one answer whichever is used)."""


def make_allocator(
    n_actuators: int,
    n_dof: int,
    solver: str = "fast",
    *,
    weights: ArrayLike | None = None,
    f_ref: ArrayLike | str | None = None,
    tol: float = 1e-9,
) -> Allocator:
    """Build an allocator once for a robot; call its ``solve`` every tick.

    Args:
        n_actuators: m, number of cables or muscles (length of f).
        n_dof: n, number of rows of M (4 joints for the arm, 6 for a platform).
        solver: One of ``SOLVERS`` (``"daqp"`` is an alias of ``"fast"``).
        weights: Diagonal of W [1/N], shape (m,), all > 0; ``None`` for ones. For muscles
            ``1 / F_max`` makes the objective the sum of squared activations.
        f_ref: Reference force [N]: ``None`` (zero: minimum weighted 2-norm),
            ``"midpoint"`` (the midpoint of each tick's bounds, Pott's choice), or an array of
            shape (m,).
        tol: Feasibility tolerance, relative to 1 + magnitude (see ``AllocationSpec``).

    Returns:
        The allocator.

    Raises:
        InputError: For an unknown solver name or an invalid argument.
    """
    key = _ALIASES.get(solver, solver)
    if key not in _CLASSES:
        raise InputError(f"solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
    spec = AllocationSpec.build(n_actuators, n_dof, weights=weights, f_ref=f_ref, tol=tol)
    return _CLASSES[key](spec)
