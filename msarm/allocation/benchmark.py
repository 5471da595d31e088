"""``msarm bench allocation``: every solver on the same varying problems, timed in one run.

Two robots, ``n_problems`` problems each (seeded):

- ``arm`` (M = -J_c^T, 4 x 9): the arm of ``msarm.model.load_arm`` at random postures and
  joint velocities, with the bounds from the muscles' force capacity. Weights ``1/F_max``,
  ``f_ref = 0`` (sum of squared activations); torques that forces within the capacity produce.
- ``cdpr`` (M = A^T, 6 x 8): the WireX-like robot of the unit test (frame 4 x 3 x 2 m,
  platform 0.12 m) at random poses in the central part of the frame (rotations up to 5 deg),
  holding a 0.25 kg platform plus a random disturbance wrench, cable forces in [1, 10] N,
  Pott's reference (bounds midpoint), W = I.

Per solver: the median wall time of ``solve`` (validation and result included) over the
problems, its speed-up over cvxpy measured in the same run, the statuses, and for the exact
solvers the largest relative difference of the objective from cvxpy's. Batched: the
throughput of one ``solve_batch`` call over all problems (best of a few repeats).
"""

from __future__ import annotations

import platform
from dataclasses import dataclass
from time import perf_counter, perf_counter_ns
from typing import Any

import numpy as np
from numpy.typing import NDArray

from msarm.allocation import make_allocator
from msarm.cdpr import CableRobot
from msarm.cdpr.forward_kinematics import rotation_matrix

FloatArray = NDArray[np.float64]

__all__ = [
    "BenchProblems",
    "TARGETS",
    "arm_problems",
    "cdpr_problems",
    "run_benchmark",
    "wirex_robot",
]

TARGETS = {"fast_min_speedup": 50.0, "fast_max_median_us": 20.0, "batched_min_solves_per_s": 1e5}
"""The issue's targets for the exact fast path and the batched path."""

PER_TICK_METHODS = ("cvxpy", "fast", "newton", "closed_form", "improved_closed_form")


@dataclass(frozen=True)
class BenchProblems:
    """A set of N allocation problems for one robot.

    Attributes:
        name: Robot name.
        source: Where M comes from (a model, or random).
        M: Shape (N, n, m).
        b: Shape (N, n).
        f_min: Lower bounds [N], shape (N, m).
        f_max: Upper bounds [N], shape (N, m).
        weights: Diagonal of W [1/N], shape (m,).
        f_ref: ``None`` or ``"midpoint"``.
    """

    name: str
    source: str
    M: FloatArray
    b: FloatArray
    f_min: FloatArray
    f_max: FloatArray
    weights: FloatArray
    f_ref: str | None


def wirex_robot() -> CableRobot:
    """The 8-cable robot of the WireX unit test: frame 4 x 3 x 2 m, platform 0.12 x 0.12 m."""
    top = np.array([[-2.0, 1.5, 2.0], [2.0, 1.5, 2.0], [2.0, -1.5, 2.0], [-2.0, -1.5, 2.0]])
    bottom = top * np.array([1.0, 1.0, 0.0])
    plate = np.array(
        [[-0.06, 0.06, 0.0], [0.06, 0.06, 0.0], [0.06, -0.06, 0.0], [-0.06, -0.06, 0.0]]
    )
    return CableRobot(np.vstack([top, bottom]), np.vstack([plate, plate]))


def cdpr_problems(n_problems: int, rng: np.random.Generator) -> BenchProblems:
    """Force distribution problems of the WireX-like robot at random poses (see module doc)."""
    robot = wirex_robot()
    r = rng.uniform([-1.0, -0.75, 0.6], [1.0, 0.75, 1.4], size=(n_problems, 3))
    R = rotation_matrix(rng.uniform(-1.0, 1.0, size=(n_problems, 3)) * np.deg2rad(5.0) / np.sqrt(3))
    At = robot.structure_matrix(r, R)
    w = np.zeros((n_problems, 6))
    w[:, 2] = -0.25 * 9.81
    w[:, :3] += rng.uniform(-1.0, 1.0, size=(n_problems, 3))
    w[:, 3:] += rng.uniform(-0.02, 0.02, size=(n_problems, 3))
    m = robot.n_cables
    return BenchProblems(
        "cdpr",
        "WireX-like 8-cable robot",
        At,
        -w,
        np.full((n_problems, m), 1.0),
        np.full((n_problems, m), 10.0),
        np.ones(m),
        "midpoint",
    )


def arm_problems(n_problems: int, rng: np.random.Generator) -> BenchProblems:
    """Muscle force problems of the arm of ``msarm.model.load_arm`` (see module doc).

    Args:
        n_problems: Number of problems (postures and joint velocities).
        rng: Generator for the postures (uniform in the joint range), the joint velocities
            (uniform in [-1, 1] rad/s) and the forces that make the torques.

    Returns:
        The problems: ``M`` (n_problems, 4, 9), bounds (n_problems, 9) in N from the muscles'
        force capacity, weights ``1 / F_max`` (9,) in 1/N.
    """
    from msarm.model import load_arm

    arm = load_arm()
    m, n = arm.n_cables, arm.n_joints
    muscles = arm.muscles
    f_scale = np.asarray(muscles.max_isometric_force, dtype=np.float64)
    M = np.empty((n_problems, n, m))
    f_min = np.empty((n_problems, m))
    f_max = np.empty((n_problems, m))
    for k in range(n_problems):
        q = rng.uniform(arm.joint_lower, arm.joint_upper)
        qd = rng.uniform(-1.0, 1.0, n)
        geo = arm.geometry(q, with_wrap_angles=False)
        f_min[k], f_max[k] = muscles.force_capacity(geo.lengths, geo.jacobian @ qd)
        M[k] = -geo.jacobian.T
    f0 = f_min + rng.uniform(0.0, 0.3, size=(n_problems, m)) * (f_max - f_min)
    b = (M @ f0[..., None])[..., 0]
    return BenchProblems("arm", "msarm.model.load_arm", M, b, f_min, f_max, 1.0 / f_scale, None)


def _bench_robot(problems: BenchProblems, batch_repeats: int) -> dict[str, Any]:
    count, n, m = problems.M.shape
    allocators = {
        name: make_allocator(m, n, name, weights=problems.weights, f_ref=problems.f_ref)
        for name in (*PER_TICK_METHODS, "batched")
    }
    P = problems
    for alloc in allocators.values():  # warm-up (cvxpy compiles its problem on first solve)
        for i in range(min(count, 5)):
            alloc.solve(P.M[i], P.b[i], P.f_min[i], P.f_max[i])
    objective = {}
    methods: dict[str, dict[str, Any]] = {}
    for name in PER_TICK_METHODS:
        alloc = allocators[name]
        times = np.empty(count)
        obj = np.empty(count)
        feasible = np.empty(count, dtype=bool)
        statuses: dict[str, int] = {}
        for i in range(count):
            t0 = perf_counter_ns()
            res = alloc.solve(P.M[i], P.b[i], P.f_min[i], P.f_max[i])
            times[i] = perf_counter_ns() - t0
            obj[i] = alloc.spec.objective(res.f, P.f_min[i], P.f_max[i])
            feasible[i] = res.feasible
            statuses[res.status] = statuses.get(res.status, 0) + 1
        objective[name] = (obj, feasible)
        methods[name] = {
            "median_us": float(np.median(times)) / 1e3,
            "p90_us": float(np.percentile(times, 90)) / 1e3,
            "feasible": int(feasible.sum()),
            "statuses": statuses,
        }
    batch = allocators["batched"]
    best = np.inf
    result = None
    for _ in range(batch_repeats):
        t0 = perf_counter()
        result = batch.solve_batch(P.M, P.b, P.f_min, P.f_max)
        best = min(best, perf_counter() - t0)
    assert result is not None
    obj_b = np.array(
        [batch.spec.objective(result.f[i], P.f_min[i], P.f_max[i]) for i in range(count)]
    )
    objective["batched"] = (obj_b, result.feasible)
    statuses_b = dict(zip(*np.unique(result.status, return_counts=True), strict=True))
    methods["batched"] = {
        "median_us": best / count * 1e6,
        "solves_per_s": count / best,
        "feasible": int(result.feasible.sum()),
        "statuses": {str(k): int(v) for k, v in statuses_b.items()},
    }
    ref_obj, ref_feasible = objective["cvxpy"]
    cvx_us = methods["cvxpy"]["median_us"]
    for name, entry in methods.items():
        entry["speedup_vs_cvxpy"] = cvx_us / entry["median_us"]
        obj, feas = objective[name]
        both = feas & ref_feasible
        if allocators[name].exact and both.any():
            rel = np.abs(obj[both] - ref_obj[both]) / np.maximum(np.abs(ref_obj[both]), 1e-300)
            entry["max_rel_objective_diff_vs_cvxpy"] = float(rel.max())
            entry["feasibility_agrees_with_cvxpy"] = bool(np.array_equal(feas, ref_feasible))
    return {
        "shape": [n, m],
        "source": problems.source,
        "n_problems": count,
        "f_ref": problems.f_ref or "zero",
        "infeasible_problems": int((~ref_feasible).sum()),
        "methods": methods,
    }


def run_benchmark(n_problems: int = 1000, seed: int = 0, batch_repeats: int = 5) -> dict[str, Any]:
    """Run the allocation benchmark.

    Args:
        n_problems: Problems per robot (>= 1).
        seed: Seed of the problem generator.
        batch_repeats: Repeats of the batched call (the best is kept).

    Returns:
        A JSON-serialisable report: per robot and method the median us per solve, the
        speed-up over cvxpy, statuses, agreement with cvxpy; the targets and whether they
        are met.
    """
    if n_problems < 1:
        from msarm.errors import InputError

        raise InputError(f"n_problems must be >= 1, got {n_problems}")
    rng_arm, rng_cdpr = np.random.default_rng(seed).spawn(2)
    robots = {
        "arm": _bench_robot(arm_problems(n_problems, rng_arm), batch_repeats),
        "cdpr": _bench_robot(cdpr_problems(n_problems, rng_cdpr), batch_repeats),
    }
    checks = {}
    for name, rob in robots.items():
        fast, batched = rob["methods"]["fast"], rob["methods"]["batched"]
        checks[name] = {
            "fast_speedup_ok": fast["speedup_vs_cvxpy"] >= TARGETS["fast_min_speedup"],
            "fast_median_ok": fast["median_us"] <= TARGETS["fast_max_median_us"],
            "batched_throughput_ok": batched["solves_per_s"] >= TARGETS["batched_min_solves_per_s"],
        }
    return {
        "benchmark": "allocation",
        "n_problems": n_problems,
        "seed": seed,
        "machine": {"python": platform.python_version(), "processor": platform.machine()},
        "targets": TARGETS,
        "robots": robots,
        "targets_met": checks,
        "all_targets_met": all(all(c.values()) for c in checks.values()),
    }
