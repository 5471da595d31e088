"""Seeded random allocation problems with a known answer to "is it feasible?".

For tests, benchmarks and data generation. A feasible problem is built around an interior
point ``f0`` (``b = M f0`` with ``f0`` strictly inside the bounds); an infeasible one puts
``b`` beyond a separating hyperplane: for a random unit direction ``y``,
``y^T b = max over the box of y^T M f + margin``, which no bounded f can reach (a Farkas
certificate, checked in ``is_certified_infeasible``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

__all__ = ["RandomProblem", "box_support", "random_problem"]


@dataclass(frozen=True)
class RandomProblem:
    """One allocation problem ``M f = b, f_min <= f <= f_max``.

    Attributes:
        M: Shape (n, m).
        b: Shape (n,).
        f_min: Lower bounds [N], shape (m,).
        f_max: Upper bounds [N], shape (m,).
        feasible: Whether it was built feasible (with a margin).
        certificate: For an infeasible problem, the unit direction y of the Farkas
            certificate, shape (n,); ``None`` for a feasible one.
    """

    M: FloatArray
    b: FloatArray
    f_min: FloatArray
    f_max: FloatArray
    feasible: bool
    certificate: FloatArray | None


def box_support(M: FloatArray, y: FloatArray, f_min: FloatArray, f_max: FloatArray) -> float:
    """``max over f_min <= f <= f_max of y^T M f`` (the support function of the box's image)."""
    s = M.T @ y
    return float(np.maximum(f_min * s, f_max * s).sum())


def random_problem(
    rng: np.random.Generator,
    n_dof: int,
    n_actuators: int,
    *,
    feasible: bool = True,
    margin: float = 0.05,
) -> RandomProblem:
    """A random allocation problem of the given size and feasibility.

    M has standard normal entries with row scales between 0.1 and 10; lower bounds lie in
    [0, 5] N and widths in [0.5, 20] N.

    Args:
        rng: Random generator (the only source of randomness).
        n_dof: n, rows of M.
        n_actuators: m, columns of M.
        feasible: Build a feasible problem (b from an interior point) or an infeasible one.
        margin: Feasible: the interior point keeps this share of each bound's width from the
            bounds. Infeasible: b lies this far (relative to 1 + |support|) beyond reach.

    Returns:
        The problem.
    """
    n, m = n_dof, n_actuators
    scales = 10.0 ** rng.uniform(-1.0, 1.0, size=(n, 1))
    M = rng.standard_normal((n, m)) * scales
    f_min = rng.uniform(0.0, 5.0, m)
    f_max = f_min + rng.uniform(0.5, 20.0, m)
    if feasible:
        share = rng.uniform(margin, 1.0 - margin, m)
        b = M @ (f_min + share * (f_max - f_min))
        return RandomProblem(M, b, f_min, f_max, True, None)
    y = rng.standard_normal(n)
    y /= np.linalg.norm(y)
    b0 = M @ (0.5 * (f_min + f_max))
    h = box_support(M, y, f_min, f_max)
    b = b0 + (h + margin * (1.0 + abs(h)) - float(y @ b0)) * y
    return RandomProblem(M, b, f_min, f_max, False, y)
