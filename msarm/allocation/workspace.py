"""Wrench-feasible workspace of a cable robot: where can the platform hold the wanted wrenches?

A pose is wrench-feasible for a wrench ``w`` [N, N m] when some cable forces within the bounds
hold the platform in equilibrium, ``A^T f + w = 0`` with ``f_min <= f <= f_max`` (paper 000,
eq. 2). The set of feasible wrenches at a pose is convex, so a pose is feasible for a
polytope of wrenches exactly when it is feasible for each of its vertices: pass the vertices.

Feasibility is decided by the exact batched path (dual Newton over all poses and wrenches at
once), the problems it leaves by DAQP; no least-squares fallback is run. A problem counts as
feasible when forces meet ``A^T f + w = 0`` to ``tol (1 + ||w||)`` within the bounds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.allocation.batched import dual_newton
from msarm.allocation.problem import AllocationSpec, validate_batch
from msarm.allocation.solution_check import residual_limits
from msarm.allocation.solvers.daqp_solver import DaqpAllocator
from msarm.cdpr.kinematics import CableRobot
from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = [
    "WorkspaceGrid",
    "feasibility_batch",
    "is_wrench_feasible",
    "wrench_feasible_grid",
    "wrench_feasible_poses",
]


def feasibility_batch(
    M: ArrayLike, b: ArrayLike, f_min: ArrayLike, f_max: ArrayLike, *, tol: float = 1e-9
) -> NDArray[np.bool_]:
    """For N problems: does some ``f_min <= f <= f_max`` meet ``M f = b``?

    Args:
        M: Shape (N, n, m).
        b: Shape (N, n).
        f_min: Lower bounds [N], shape (m,), (N, m) or scalar.
        f_max: Upper bounds [N], shape (m,), (N, m) or scalar.
        tol: Tolerance on ``||M f - b||``, relative to ``1 + ||b|| + || |M| |f| ||``.

    Returns:
        Shape (N,) bool.

    Raises:
        InputError: On wrong shapes, NaN or infinite values, or f_min > f_max.
    """
    M_arr = np.asarray(M, dtype=np.float64)
    if M_arr.ndim != 3:
        raise InputError(f"M must have shape (N, n, m), got {M_arr.shape}")
    n, m = M_arr.shape[1:]
    if n < 1 or m < n:
        raise InputError(f"M must have shape (N, n, m) with 1 <= n <= m, got {M_arr.shape}")
    spec = AllocationSpec.build(m, n, tol=tol)
    M_arr, b_arr, lo, hi = validate_batch(spec, M_arr, b, f_min, f_max)
    # The objective does not matter for feasibility; the midpoint keeps the scaling tame.
    ref = 0.5 * (lo + hi)
    c = b_arr - (M_arr @ ref[..., None])[..., 0]
    x, converged, _, _, infeasible = dual_newton(M_arr, c, lo - ref, hi - ref)
    r = (M_arr @ x[..., None])[..., 0] - c
    limit = residual_limits(M_arr, b_arr, x + ref, tol)
    feasible = converged & (np.sqrt((r * r).sum(axis=1)) <= limit)
    rest = np.flatnonzero(~feasible & ~infeasible)  # certified infeasible ones stay False
    if rest.size:
        f, solved, _, _ = DaqpAllocator(spec).solve_many(
            M_arr[rest], b_arr[rest], lo[rest], hi[rest], ref[rest]
        )
        e = (M_arr[rest] @ f[..., None])[..., 0] - b_arr[rest]
        limit_rest = residual_limits(M_arr[rest], b_arr[rest], f, tol)
        feasible[rest] = solved & (np.sqrt((e * e).sum(axis=1)) <= limit_rest)
    return feasible


def _wrench_array(wrenches: ArrayLike, n: int) -> FloatArray:
    w = np.asarray(wrenches, dtype=np.float64)
    if w.ndim == 1:
        w = w[None, :]
    if w.ndim != 2 or w.shape[1] != n or w.shape[0] < 1:
        raise InputError(f"wrenches must have shape ({n},) or (k, {n}) [N, N m], got {w.shape}")
    if not np.isfinite(w).all():
        raise InputError("wrenches must be finite [N, N m]")
    return w


def is_wrench_feasible(
    structure_matrix: ArrayLike,
    wrenches: ArrayLike,
    f_min: ArrayLike,
    f_max: ArrayLike,
    *,
    tol: float = 1e-9,
) -> bool:
    """Is one pose wrench-feasible: can bounded forces balance every given wrench?

    Args:
        structure_matrix: A^T at the pose, shape (n, m) (``CableRobot.structure_matrix``).
        wrenches: External wrench(es) on the platform [N, N m], shape (n,) or (k, n); for a
            polytope of wrenches, its vertices.
        f_min: Lower cable force bounds [N], shape (m,) or scalar.
        f_max: Upper cable force bounds [N], shape (m,) or scalar.
        tol: Equilibrium tolerance, relative to ``1 + ||w||``.

    Returns:
        True when ``A^T f + w = 0`` has a solution within the bounds for every wrench.

    Raises:
        InputError: On wrong shapes, NaN or infinite values, or f_min > f_max.
    """
    At = np.asarray(structure_matrix, dtype=np.float64)
    if At.ndim != 2:
        raise InputError(f"structure_matrix must have shape (n, m), got {At.shape}")
    n, m = At.shape
    size = np.shape(wrenches)[-1] if np.ndim(wrenches) else None
    if size is not None and size != n:
        hint = " (transposed? expected A^T, not A)" if size == m else ""
        raise InputError(
            f"structure_matrix has shape {At.shape}: expected (n, m) with n = {size}, the "
            f"wrench's size, and m the number of cables{hint}"
        )
    for name, bound in (("f_min", f_min), ("f_max", f_max)):
        if np.size(bound) not in (1, m):
            raise InputError(
                f"{name} has {np.size(bound)} entries but structure_matrix {At.shape} has "
                f"m = {m} columns (cables): expected a scalar or shape ({m},)"
            )
    w = _wrench_array(wrenches, n)
    M = np.broadcast_to(At, (w.shape[0], *At.shape))
    return bool(feasibility_batch(M, -w, f_min, f_max, tol=tol).all())


def wrench_feasible_poses(
    robot: CableRobot,
    positions: ArrayLike,
    rotations: ArrayLike,
    wrenches: ArrayLike,
    f_min: ArrayLike,
    f_max: ArrayLike,
    *,
    tol: float = 1e-9,
) -> NDArray[np.bool_]:
    """Which of N poses are wrench-feasible for all the given wrenches.

    Args:
        robot: The cable robot.
        positions: Platform positions r [m], shape (N, 3).
        rotations: Platform rotation(s), shape (3, 3) (shared) or (N, 3, 3).
        wrenches: Wrench(es) on the platform [N, N m], shape (6,) or (k, 6), in K_0.
        f_min: Lower cable force bounds [N], shape (m,) or scalar.
        f_max: Upper cable force bounds [N], shape (m,) or scalar.
        tol: Equilibrium tolerance, relative to ``1 + ||w||``.

    Returns:
        Shape (N,) bool.

    Raises:
        InputError: On invalid poses, wrenches or bounds.
    """
    r = np.asarray(positions, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 3:
        raise InputError(f"positions must have shape (N, 3) [m], got {r.shape}")
    At = robot.structure_matrix(r, rotations)  # (N, 6, m)
    w = _wrench_array(wrenches, 6)
    count, k = At.shape[0], w.shape[0]
    M = np.repeat(At, k, axis=0)
    b = -np.tile(w, (count, 1))
    flags = feasibility_batch(M, b, f_min, f_max, tol=tol)
    return flags.reshape(count, k).all(axis=1)


@dataclass(frozen=True)
class WorkspaceGrid:
    """The wrench-feasible set over a grid of positions at one orientation.

    Attributes:
        x: Grid x coordinates [m], shape (nx,).
        y: Grid y coordinates [m], shape (ny,).
        z: Grid z coordinates [m], shape (nz,).
        rotation: The platform orientation of every grid pose, shape (3, 3).
        feasible: Shape (nx, ny, nz) bool, indexed ``[i, j, k]`` for ``(x[i], y[j], z[k])``.
    """

    x: FloatArray
    y: FloatArray
    z: FloatArray
    rotation: FloatArray
    feasible: NDArray[np.bool_]

    @property
    def positions(self) -> FloatArray:
        """All grid positions [m], shape (nx, ny, nz, 3)."""
        return np.stack(np.meshgrid(self.x, self.y, self.z, indexing="ij"), axis=-1)

    @property
    def feasible_positions(self) -> FloatArray:
        """The feasible positions [m], shape (K, 3)."""
        return self.positions[self.feasible]

    @property
    def fraction(self) -> float:
        """Share of feasible grid points, in [0, 1]."""
        return float(self.feasible.mean()) if self.feasible.size else 0.0


def wrench_feasible_grid(
    robot: CableRobot,
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    wrenches: ArrayLike,
    f_min: ArrayLike,
    f_max: ArrayLike,
    *,
    rotation: ArrayLike | None = None,
    tol: float = 1e-9,
) -> WorkspaceGrid:
    """The wrench-feasible positions on a grid, at one platform orientation.

    Args:
        robot: The cable robot.
        x: Grid x coordinates [m], shape (nx,).
        y: Grid y coordinates [m], shape (ny,).
        z: Grid z coordinates [m], shape (nz,).
        wrenches: Wrench(es) on the platform [N, N m], shape (6,) or (k, 6), in K_0.
        f_min: Lower cable force bounds [N], shape (m,) or scalar.
        f_max: Upper cable force bounds [N], shape (m,) or scalar.
        rotation: Platform rotation, shape (3, 3); identity when ``None``.
        tol: Equilibrium tolerance, relative to ``1 + ||w||``.

    Returns:
        The grid and its feasibility mask.

    Raises:
        InputError: On invalid axes, orientation, wrenches or bounds.
    """
    axes = []
    for name, value in (("x", x), ("y", y), ("z", z)):
        a = np.asarray(value, dtype=np.float64)
        if a.ndim != 1 or a.size < 1 or not np.isfinite(a).all():
            raise InputError(f"{name} must be a non-empty finite 1-D array [m], got {a.shape}")
        axes.append(a)
    R = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    grid = WorkspaceGrid(*axes, rotation=R, feasible=np.zeros(0, dtype=bool))
    positions = grid.positions.reshape(-1, 3)
    flags = wrench_feasible_poses(robot, positions, R, wrenches, f_min, f_max, tol=tol)
    shape = tuple(a.size for a in axes)
    return WorkspaceGrid(*axes, rotation=R, feasible=flags.reshape(shape))
