"""Property-based tests: every exact solver gives the cvxpy answer; infeasibility is reported.

Random problems of both sizes (the arm, 4 x 9, and an 8-cable robot, 6 x 8), built with a
known feasibility (``msarm.allocation.testing``). Allocators are built once per
configuration (cvxpy compiles its problem once) and reused across examples.
"""

from functools import cache

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msarm.allocation import EXACT_SOLVERS, SOLVERS, make_allocator
from msarm.allocation.testing import box_support, random_problem

SIZES = [(4, 9), (6, 8)]
CONFIGS = ["min_norm", "midpoint", "weighted"]
PROPERTY = settings(
    max_examples=100,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)


@cache
def allocators(n: int, m: int, config: str) -> dict:
    if config == "min_norm":
        kwargs = {}
    elif config == "midpoint":
        kwargs = {"f_ref": "midpoint"}
    else:  # muscle-like weights 1/F_max and a fixed reference force
        rng = np.random.default_rng(100 * n + m)
        kwargs = {"weights": 1.0 / rng.uniform(50.0, 500.0, m), "f_ref": rng.uniform(0, 8, m)}
    return {name: make_allocator(m, n, name, **kwargs) for name in SOLVERS}


def objective(alloc, f, p):
    return alloc.spec.objective(f, p.f_min, p.f_max)


@pytest.mark.parametrize(("n", "m"), SIZES)
@pytest.mark.parametrize("config", CONFIGS)
@PROPERTY
@given(seed=st.integers(0, 2**32 - 1))
def test_exact_methods_agree_with_cvxpy_on_feasible_problems(n, m, config, seed):
    p = random_problem(np.random.default_rng(seed), n, m, feasible=True)
    allocs = allocators(n, m, config)
    ref = allocs["cvxpy"].solve(p.M, p.b, p.f_min, p.f_max)
    assert ref.feasible and ref.status == "optimal"
    ref_obj = objective(allocs["cvxpy"], ref.f, p)
    for name in EXACT_SOLVERS:
        res = allocs[name].solve(p.M, p.b, p.f_min, p.f_max)
        assert res.feasible, name
        assert res.status == "optimal", name
        assert res.solver == name
        assert np.abs(p.M @ res.f - p.b).max() <= 1e-9, name
        assert np.all(res.f >= p.f_min - 1e-9) and np.all(res.f <= p.f_max + 1e-9), name
        # the residual reported is f's, to round-off (msarm sums M f - b in its own order)
        scale = 1e-14 * (1.0 + np.linalg.norm(p.b))
        assert res.residual == pytest.approx(np.linalg.norm(p.M @ res.f - p.b), abs=scale)
        obj = objective(allocs[name], res.f, p)
        assert abs(obj - ref_obj) <= 1e-6 * max(abs(ref_obj), 1e-12), (name, obj, ref_obj)
        if name != "cvxpy":  # (an interior-point answer sits ~1e-9 inside its bounds)
            # The active set marks the forces at their bounds (to round-off).
            lo, hi = res.active < 0, res.active > 0
            np.testing.assert_allclose(res.f[lo], p.f_min[lo], rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(res.f[hi], p.f_max[hi], rtol=1e-12, atol=1e-12)
            inner = res.active == 0
            assert np.all(res.f[inner] > p.f_min[inner]) and np.all(res.f[inner] < p.f_max[inner])


@pytest.mark.parametrize(("n", "m"), SIZES)
@pytest.mark.parametrize("config", CONFIGS)
@PROPERTY
@given(seed=st.integers(0, 2**32 - 1))
def test_closed_forms_are_feasible_when_they_succeed(n, m, config, seed):
    p = random_problem(np.random.default_rng(seed), n, m, feasible=True)
    allocs = allocators(n, m, config)
    for name in ("closed_form", "improved_closed_form"):
        res = allocs[name].solve(p.M, p.b, p.f_min, p.f_max)
        # A closed form either succeeds within the bounds or falls back; either way the
        # problem is feasible and the answer meets the constraints.
        assert res.feasible and res.status in ("closed_form", "fallback"), name
        assert np.abs(p.M @ res.f - p.b).max() <= 1e-9, name
        assert np.all(res.f >= p.f_min - 1e-9) and np.all(res.f <= p.f_max + 1e-9), name


@pytest.mark.parametrize(("n", "m"), SIZES)
@pytest.mark.parametrize("config", CONFIGS)
@PROPERTY
@given(seed=st.integers(0, 2**32 - 1))
def test_every_method_reports_infeasible_problems(n, m, config, seed):
    p = random_problem(np.random.default_rng(seed), n, m, feasible=False)
    # The Farkas certificate proves it: y^T b exceeds what any bounded f reaches.
    assert p.certificate @ p.b > box_support(p.M, p.certificate, p.f_min, p.f_max)
    allocs = allocators(n, m, config)
    residuals = {}
    for name in SOLVERS:
        res = allocs[name].solve(p.M, p.b, p.f_min, p.f_max)
        assert not res.feasible, name
        assert res.status == "infeasible", name
        # The bounded f closest to M f = b, and how far off it is.
        assert np.all(res.f >= p.f_min) and np.all(res.f <= p.f_max), name
        assert res.residual == pytest.approx(np.linalg.norm(p.M @ res.f - p.b), rel=1e-12)
        residuals[name] = res.residual
    # No bounded f gets closer than the certificate allows ...
    gap = p.certificate @ p.b - box_support(p.M, p.certificate, p.f_min, p.f_max)
    # ... and all methods find the same least-squares distance.
    for name, value in residuals.items():
        assert value >= gap * (1 - 1e-9), name
        assert value == pytest.approx(residuals["cvxpy"], rel=1e-6), name


@pytest.mark.parametrize(("n", "m"), SIZES)
@settings(max_examples=15, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**32 - 1), n_feasible=st.integers(0, 12), n_infeasible=st.integers(0, 5)
)
def test_batched_matches_fast_per_problem(n, m, seed, n_feasible, n_infeasible):
    rng = np.random.default_rng(seed)
    problems = [random_problem(rng, n, m, feasible=True) for _ in range(n_feasible)]
    problems += [random_problem(rng, n, m, feasible=False) for _ in range(n_infeasible)]
    if not problems:
        return
    order = rng.permutation(len(problems))
    problems = [problems[i] for i in order]
    allocs = allocators(n, m, "weighted")
    batch = allocs["batched"].solve_batch(
        np.stack([p.M for p in problems]),
        np.stack([p.b for p in problems]),
        np.stack([p.f_min for p in problems]),
        np.stack([p.f_max for p in problems]),
    )
    assert len(batch) == len(problems)
    for i, p in enumerate(problems):
        single = allocs["fast"].solve(p.M, p.b, p.f_min, p.f_max)
        assert batch.feasible[i] == single.feasible == p.feasible
        assert batch.status[i] == single.status
        np.testing.assert_allclose(batch.f[i], single.f, rtol=1e-6, atol=1e-8)
        np.testing.assert_array_equal(batch.active[i], single.active)
