"""Force-distribution sensitivity index sigma for choosing the force-controlled cables.

Paper 000 (Sec. 3) picks the pair of force-controlled cables of its 8-cable, 6-DOF robot by
the "force distribution sensitivity index" sigma_ij of its reference [40] (Mattioni et al.),
in newtons, calling sigma_ij < 1.5 N good and < 2 N acceptable. Paper 000 does not restate the
definition, and [40] is not available here, so msarm defines it as follows (this is msarm's
definition, built on the same idea, not a transcription of [40]).

In hybrid joint-space control the ``n = 6`` position-controlled cables P hold the platform
pose, and the ``r = m - 6`` force-controlled cables C are given tensions by a force loop. With
rigid cables the equilibrium ``A^T f + w = 0`` (eq. 2) then fixes the tensions of P::

    f_P = -(A_P^T)^-1 (w + A_C^T f_C)

so a tension error ``Delta f_C`` of the force loop moves the position-controlled tensions by
``Delta f_P = -S Delta f_C`` with the sensitivity matrix ``S = (A_P^T)^-1 A_C^T`` (6 x r,
unitless). With every force-controlled tension wrong by at most ``e`` (default 1 N)::

    sigma_k = e sum_l |S_kl|        worst change of the tension of cable k in P  [N]
    sigma_C = max_k sigma_k         the index of the set C (sigma_ij for a pair)  [N]

i.e. the largest change of any position-controlled tension caused by force errors within
``+-e`` on the controlled cables (the worst case lies at a corner of the error box). It
depends on the geometry only, not on the force distribution. Where ``A_P^T`` is singular
the pose cannot be held by P alone and sigma is ``inf``.

The force distribution enters through the *margin*: with the nominal minimum-2-norm
distribution ``f*`` (paper 000, Sec. 2.1; ``msarm.allocation.make_allocator`` with
``f_ref=None``), the smallest distance of any tension to its bounds under the worst error::

    margin = min_k min(f*_k - s_k - f_min_k, f_max_k - f*_k - s_k)   [N]

with ``s_k = sigma_k`` for k in P and ``s_k = e`` for k in C. ``margin >= 0`` means that any
force error within ``+-e`` keeps every cable inside ``[f_min, f_max]``.

Cables are numbered from 0 in the order of the robot's anchors; the paper's pair "1, 2" is
``(0, 1)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.cdpr.kinematics import CableRobot
from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = [
    "DEFAULT_ERROR",
    "SensitivityMap",
    "cable_sensitivities",
    "pair_sensitivities",
    "sensitivity_index",
    "sensitivity_map",
    "sensitivity_matrix",
]

DEFAULT_ERROR = 1.0
"""Default bound e on the force-controlled tensions' error [N]."""
N_DOF = 6
_SINGULAR_COND = 1e12


def _structure(structure_matrix: ArrayLike) -> tuple[FloatArray, bool]:
    At = np.asarray(structure_matrix, dtype=np.float64)
    if At.ndim == 2:
        At, batched = At[None], False
    elif At.ndim == 3:
        batched = True
    else:
        raise InputError(f"structure_matrix must have shape (6, m) or (N, 6, m), got {At.shape}")
    if At.shape[1] != N_DOF or At.shape[2] <= N_DOF:
        raise InputError(
            f"structure_matrix needs 6 rows and more than 6 cables (an overconstrained "
            f"robot), got shape {At.shape[1:]}"
        )
    if not np.all(np.isfinite(At)):
        raise InputError("structure_matrix must be finite")
    return At, batched


def _split(force_controlled: ArrayLike, m: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(C, P): sorted force-controlled and position-controlled cable indices."""
    raw = np.asarray(force_controlled)
    if raw.ndim != 1 or not np.issubdtype(raw.dtype, np.integer):
        raise InputError(f"force_controlled must be a 1-D sequence of cable indices, got {raw}")
    c = np.sort(raw.astype(np.intp))
    if c.size != m - N_DOF:
        raise InputError(
            f"force_controlled must name m - 6 = {m - N_DOF} cables (the rest hold the pose), "
            f"got {c.size}: {raw.tolist()}"
        )
    if c.size and (c[0] < 0 or c[-1] >= m or np.any(np.diff(c) == 0)):
        raise InputError(
            f"force_controlled must be distinct indices in [0, {m}), got {raw.tolist()}"
        )
    p = np.setdiff1d(np.arange(m), c)
    return c, p


def _error(error: float) -> float:
    e = float(error)
    if not (np.isfinite(e) and e > 0.0):
        raise InputError(
            f"error (the force-control error bound) must be finite and > 0 N, got {error}"
        )
    return e


def sensitivity_matrix(structure_matrix: ArrayLike, force_controlled: ArrayLike) -> FloatArray:
    """S = (A_P^T)^-1 A_C^T: position-controlled tension change per controlled tension error.

    ``Delta f_P = -S Delta f_C`` keeps ``A^T f + w = 0`` with the pose held by P.

    Args:
        structure_matrix: A^T, shape (6, m) or (N, 6, m) (``CableRobot.structure_matrix``).
        force_controlled: The m - 6 force-controlled cable indices C (a pair for m = 8).

    Returns:
        S [-], shape (6, r) or (N, 6, r); rows in the order of the position-controlled
        cables P (ascending index), columns in ascending order of C. ``inf`` where A_P^T is
        singular (condition number above 1e12).

    Raises:
        InputError: On wrong shapes, non-finite values or an invalid cable set.
    """
    At, batched = _structure(structure_matrix)
    c, p = _split(force_controlled, At.shape[2])
    A_P, A_C = At[:, :, p], At[:, :, c]
    S = np.full((At.shape[0], N_DOF, c.size), np.inf)
    ok = np.linalg.cond(A_P) < _SINGULAR_COND
    if np.any(ok):
        S[ok] = np.linalg.solve(A_P[ok], A_C[ok])
    return S if batched else S[0]


def cable_sensitivities(
    structure_matrix: ArrayLike, force_controlled: ArrayLike, error: float = DEFAULT_ERROR
) -> FloatArray:
    """Worst tension change s_k of every cable for controlled-force errors within +-error [N].

    Args:
        structure_matrix: A^T, shape (6, m) or (N, 6, m).
        force_controlled: The m - 6 force-controlled cable indices C.
        error: Bound e on each force-controlled tension's error [N], > 0.

    Returns:
        s, shape (m,) or (N, m) [N]: ``e sum_l |S_kl|`` for a position-controlled cable k,
        ``e`` for a force-controlled one; ``inf`` where A_P^T is singular.

    Raises:
        InputError: As :func:`sensitivity_matrix`, or for an invalid error bound.
    """
    e = _error(error)
    At, batched = _structure(structure_matrix)
    c, p = _split(force_controlled, At.shape[2])
    S = sensitivity_matrix(At, c)
    s = np.empty((At.shape[0], At.shape[2]))
    s[:, p] = e * np.abs(S).sum(axis=2)
    s[:, c] = e
    return s if batched else s[0]


def sensitivity_index(
    structure_matrix: ArrayLike, force_controlled: ArrayLike, error: float = DEFAULT_ERROR
) -> FloatArray:
    """The index sigma_C = max_k e sum_l |S_kl| over the position-controlled cables [N].

    Args:
        structure_matrix: A^T, shape (6, m) or (N, 6, m).
        force_controlled: The m - 6 force-controlled cable indices C (a pair for m = 8).
        error: Bound e on each force-controlled tension's error [N], > 0.

    Returns:
        sigma [N], shape () or (N,); ``inf`` where A_P^T is singular.

    Raises:
        InputError: As :func:`cable_sensitivities`.
    """
    e = _error(error)
    S = sensitivity_matrix(structure_matrix, force_controlled)
    return e * np.abs(S).sum(axis=-1).max(axis=-1)


def pair_sensitivities(
    structure_matrix: ArrayLike, error: float = DEFAULT_ERROR
) -> dict[tuple[int, ...], float]:
    """The index sigma of every possible set of m - 6 force-controlled cables at one pose [N].

    Args:
        structure_matrix: A^T at one pose, shape (6, m).
        error: Bound e on each force-controlled tension's error [N], > 0.

    Returns:
        ``{(i, j): sigma_ij}`` for all pairs i < j when m = 8 (tuples of m - 6 indices in
        general), in lexicographic order.

    Raises:
        InputError: On a batch of poses or the errors of :func:`sensitivity_index`.
    """
    At, batched = _structure(structure_matrix)
    if batched:
        raise InputError(f"pair_sensitivities takes one pose, shape (6, m); got {At.shape}")
    m = At.shape[2]
    sets = list(combinations(range(m), m - N_DOF))
    return {cset: float(sensitivity_index(At[0], list(cset), error)) for cset in sets}


@dataclass(frozen=True)
class SensitivityMap:
    """The index sigma of one force-controlled cable set over a grid of positions, one orientation.

    Arrays of shape (nx, ny, nz) are indexed ``[i, j, k]`` for ``(x[i], y[j], z[k])``.

    Attributes:
        x: Grid x coordinates [m], shape (nx,).
        y: Grid y coordinates [m], shape (ny,).
        z: Grid z coordinates [m], shape (nz,).
        rotation: Platform orientation of every grid pose, shape (3, 3).
        force_controlled: The force-controlled cable indices (ascending).
        error: Bound e on the force-controlled tensions' error [N].
        sigma: The index sigma [N], shape (nx, ny, nz); ``inf`` where A_P^T is singular.
        feasible: Shape (nx, ny, nz) bool: the nominal distribution meets the equilibrium
            within the bounds (the pose is wrench-feasible).
        forces: The nominal minimum-2-norm distribution f* [N], shape (nx, ny, nz, m); where
            not feasible, the allocator's bounded least-squares answer.
        margin: Distance of the worst-case tensions to the bounds [N], shape (nx, ny, nz);
            meaningful where ``feasible``.
    """

    x: FloatArray
    y: FloatArray
    z: FloatArray
    rotation: FloatArray
    force_controlled: tuple[int, ...]
    error: float
    sigma: FloatArray
    feasible: NDArray[np.bool_]
    forces: FloatArray
    margin: FloatArray

    @property
    def positions(self) -> FloatArray:
        """All grid positions [m], shape (nx, ny, nz, 3)."""
        return np.stack(np.meshgrid(self.x, self.y, self.z, indexing="ij"), axis=-1)

    def acceptable(self, threshold: float = 1.5) -> NDArray[np.bool_]:
        """Feasible poses with ``sigma < threshold`` [N] (paper 000 Fig. 7 uses 1.5 N)."""
        return self.feasible & (self.sigma < threshold)

    def fraction_acceptable(self, threshold: float = 1.5) -> float:
        """Share of the feasible grid points with ``sigma < threshold``, in [0, 1]."""
        n = int(self.feasible.sum())
        return float(self.acceptable(threshold).sum()) / n if n else 0.0


def _axis(value: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 1 or a.size < 1 or not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be a non-empty finite 1-D array [m], got shape {a.shape}")
    return a


def sensitivity_map(
    robot: CableRobot,
    force_controlled: ArrayLike,
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    *,
    wrench: ArrayLike,
    f_min: ArrayLike,
    f_max: ArrayLike,
    rotation: ArrayLike | None = None,
    error: float = DEFAULT_ERROR,
    solver: str = "batched",
) -> SensitivityMap:
    """The index sigma, nominal force distribution and margin over a grid of positions.

    Args:
        robot: The cable robot (m > 6 cables).
        force_controlled: The m - 6 force-controlled cable indices (a pair for m = 8).
        x: Grid x coordinates [m], shape (nx,).
        y: Grid y coordinates [m], shape (ny,).
        z: Grid z coordinates [m], shape (nz,).
        wrench: External wrench on the platform (e.g. its weight) [N, N m], shape (6,), K_0.
        f_min: Lower cable force bounds [N], shape (m,) or scalar, >= 0 (cables only pull).
        f_max: Upper cable force bounds [N], shape (m,) or scalar, >= f_min.
        rotation: Platform rotation, shape (3, 3); identity (paper 000's R = I_3) if None.
        error: Bound e on each force-controlled tension's error [N], > 0.
        solver: Allocation solver name for the minimum-2-norm distribution (an exact one).

    Returns:
        The map; see :class:`SensitivityMap`.

    Raises:
        InputError: On invalid axes, pose, wrench, bounds (as
            :func:`msarm.allocation.problem.tension_bounds`: not of shape (m,) or a number,
            not finite, negative, or f_min > f_max), cable set or error bound.
    """
    # Imported here, not at module level: msarm.allocation imports msarm.cdpr.kinematics, so a
    # top-level import would make ``msarm.cdpr`` and ``msarm.allocation`` import each other
    # once the package exports this module.
    from msarm.allocation import make_allocator
    from msarm.allocation.problem import tension_bounds

    axes = [_axis(v, n) for n, v in (("x", x), ("y", y), ("z", z))]
    R = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    w = np.asarray(wrench, dtype=np.float64)
    if w.shape != (N_DOF,) or not np.all(np.isfinite(w)):
        raise InputError(f"wrench must be a finite array of shape (6,) [N, N m], got {w.shape}")
    e = _error(error)
    m = robot.n_cables
    c, _ = _split(force_controlled, m)
    lo, hi = tension_bounds(f_min, f_max, m)
    shape = tuple(a.size for a in axes)
    positions = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    At = robot.structure_matrix(positions, R)  # (N, 6, m)
    s = cable_sensitivities(At, c, e)  # (N, m)
    allocator = make_allocator(m, N_DOF, solver=solver)
    count = positions.shape[0]
    if hasattr(allocator, "solve_batch"):
        result = allocator.solve_batch(At, np.broadcast_to(-w, (count, N_DOF)), lo, hi)
        forces, feasible = result.f, np.asarray(result.feasible, dtype=bool)
    else:
        answers = [allocator.solve(At[k], -w, lo, hi) for k in range(count)]
        forces = np.array([a.f for a in answers])
        feasible = np.array([a.feasible for a in answers], dtype=bool)
    margin = np.minimum(forces - s - lo, hi - forces - s).min(axis=1)
    return SensitivityMap(
        x=axes[0],
        y=axes[1],
        z=axes[2],
        rotation=R,
        force_controlled=tuple(int(i) for i in c),
        error=e,
        sigma=s[:, np.setdiff1d(np.arange(m), c)].max(axis=1).reshape(shape),
        feasible=feasible.reshape(shape),
        forces=forces.reshape(*shape, m),
        margin=margin.reshape(shape),
    )
