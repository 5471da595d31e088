"""The batched path: the dual Newton core, Farkas certificates, hand-off to DAQP."""

import numpy as np
import pytest

from msarm.allocation import make_allocator
from msarm.allocation.batched import dual_newton
from msarm.allocation.benchmark import arm_problems, cdpr_problems
from msarm.allocation.testing import random_problem
from msarm.errors import InputError


def stack(problems):
    return tuple(np.stack([getattr(p, k) for p in problems]) for k in ("M", "b", "f_min", "f_max"))


def test_dual_newton_solves_the_scaled_problem_exactly():
    rng = np.random.default_rng(21)
    problems = [random_problem(rng, 6, 8) for _ in range(200)]
    A, c, lo, hi = stack(problems)
    x, converged, iterations, y, infeasible = dual_newton(A, c, lo, hi, handoff_cost=None)
    assert converged.all() and not infeasible.any()
    assert iterations.max() <= 15
    np.testing.assert_allclose(np.einsum("knm,km->kn", A, x), c, atol=1e-10)
    assert np.all(x >= lo) and np.all(x <= hi)
    # KKT: x = clip(A^T lambda) is the projection, so y outside the box marks the bounds.
    np.testing.assert_array_equal(x, np.clip(y, lo, hi))


def test_dual_newton_certifies_infeasibility():
    rng = np.random.default_rng(22)
    problems = [random_problem(rng, 6, 8, feasible=False) for _ in range(50)]
    A, c, lo, hi = stack(problems)
    _, converged, _, _, infeasible = dual_newton(A, c, lo, hi, handoff_cost=None)
    assert not converged.any()
    assert infeasible.mean() > 0.5  # the rest are left to DAQP, never called feasible


def test_dual_newton_handles_an_empty_batch():
    x, converged, *_ = dual_newton(
        np.zeros((0, 2, 3)), np.zeros((0, 2)), np.zeros((0, 3)), np.ones((0, 3))
    )
    assert x.shape == (0, 3) and converged.shape == (0,)


@pytest.mark.parametrize("make", [arm_problems, cdpr_problems])
def test_batch_of_benchmark_problems_equals_fast_path(make):
    P = make(150, np.random.default_rng(23))
    n, m = P.M.shape[1:]
    batched = make_allocator(m, n, "batched", weights=P.weights, f_ref=P.f_ref)
    fast = make_allocator(m, n, "fast", weights=P.weights, f_ref=P.f_ref)
    res = batched.solve_batch(P.M, P.b, P.f_min, P.f_max)
    assert res.f.shape == (150, m) and res.solve_time > 0
    for i in range(150):
        one = fast.solve(P.M[i], P.b[i], P.f_min[i], P.f_max[i])
        assert res.feasible[i] == one.feasible
        assert res.status[i] == one.status
        scale = 1.0 + np.abs(one.f).max()
        np.testing.assert_allclose(res.f[i], one.f, rtol=0, atol=1e-7 * scale)
        single = batched.solve(P.M[i], P.b[i], P.f_min[i], P.f_max[i])
        np.testing.assert_allclose(single.f, res.f[i], rtol=0, atol=1e-7 * scale)


def test_shared_bounds_and_reference_override():
    rng = np.random.default_rng(24)
    problems = [random_problem(rng, 4, 9) for _ in range(20)]
    M, b, _, _ = stack(problems)
    f_min, f_max = np.full(9, 0.5), np.full(9, 40.0)
    ref = rng.uniform(1.0, 5.0, 9)
    batched = make_allocator(9, 4, "batched").solve_batch(M, b, f_min, f_max, f_ref=ref)
    looped = make_allocator(9, 4, "fast").solve_batch(M, b, f_min, f_max, f_ref=ref)
    np.testing.assert_array_equal(batched.feasible, looped.feasible)
    np.testing.assert_allclose(batched.f, looped.f, rtol=1e-7, atol=1e-8)


@pytest.mark.parametrize(
    "solver", ["fast", "newton", "batched", "cvxpy", "closed_form", "improved_closed_form"]
)
def test_a_tick_may_ask_for_the_midpoint_reference_by_name(solver):
    """``solve(..., f_ref="midpoint")`` is the midpoint of that tick's bounds, as the spec's
    ``make_allocator(f_ref="midpoint")`` (it raised a bare ValueError before); another word
    is refused by name."""
    rng = np.random.default_rng(25)
    problem = random_problem(rng, 6, 8)
    args = (problem.M, problem.b, problem.f_min, problem.f_max)
    alloc = make_allocator(8, 6, solver)
    by_name = alloc.solve(*args, f_ref="midpoint")
    by_value = alloc.solve(*args, f_ref=0.5 * (problem.f_min + problem.f_max))
    spec = make_allocator(8, 6, solver, f_ref="midpoint").solve(*args)
    np.testing.assert_allclose(by_name.f, by_value.f, rtol=0, atol=1e-9)
    np.testing.assert_allclose(by_name.f, spec.f, rtol=0, atol=1e-9)
    M, b, f_min, f_max = stack([problem, random_problem(rng, 6, 8)])
    batch = alloc.solve_batch(M, b, f_min, f_max, f_ref="midpoint")
    np.testing.assert_allclose(batch.f[0], by_name.f, rtol=0, atol=1e-7)
    for bad in ("mid", ["a"] * 8):
        with pytest.raises(InputError, match=r"f_ref must be None, 'midpoint' or an array"):
            alloc.solve(*args, f_ref=bad)
