"""The allocation problem's contract: validation errors, results, the factory."""

import numpy as np
import pytest

from msarm.allocation import EXACT_SOLVERS, SOLVERS, AllocationSpec, make_allocator
from msarm.allocation.testing import random_problem
from msarm.errors import InputError

ALL = [*SOLVERS, "daqp"]


@pytest.fixture(scope="module")
def problem():
    return random_problem(np.random.default_rng(11), 6, 8)


@pytest.fixture(scope="module")
def allocs():
    return {name: make_allocator(8, 6, name) for name in SOLVERS}


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("M", np.zeros((8, 6)), r"M must have shape \(6, 8\)"),
        ("M", np.zeros(48), r"M must have shape"),
        ("b", np.zeros(5), r"b must have shape \(6,\)"),
        ("f_min", np.zeros(7), r"f_min must have shape \(8,\)"),
        ("f_max", np.zeros((8, 1)), r"f_max must have shape"),
        ("M", "nan", r"M must be finite"),
        ("b", "nan", r"b must be finite"),
        ("f_min", "nan", r"f_min .* must be finite"),
        ("f_max", "nan", r"f_max .* must be finite"),
        ("f_max", "inf", r"f_max .* must be finite"),
        ("f_min", "-inf", r"f_min .* must be finite"),
        ("f_min", "above", r"f_min must be <= f_max"),
        ("b", "text", r"b must be an array of real numbers"),
        ("M", "complex", r"M must be real numbers; got complex values"),
    ],
)
def test_bad_input_raises_a_clear_error(allocs, problem, solver, field, value, match):
    args = {"M": problem.M, "b": problem.b, "f_min": problem.f_min, "f_max": problem.f_max}
    arr = np.array(args[field], dtype=np.float64)
    if isinstance(value, str):
        if value == "text":
            arr = ["a"] * 6
        elif value == "above":
            arr = problem.f_max + 1.0
        elif value == "complex":  # the imaginary part was dropped with a mere warning
            arr = arr * (1.0 + 1.0j)
        else:
            arr[(0,) * arr.ndim] = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf}[value]
    else:
        arr = value
    args[field] = arr
    with pytest.raises(InputError, match=match):
        allocs[solver].solve(**args)


@pytest.mark.parametrize("solver", SOLVERS)
def test_bounds_out_of_order_at_one_index(allocs, problem, solver):
    f_min = problem.f_min.copy()
    f_min[3] = problem.f_max[3] + 1e-6
    with pytest.raises(InputError, match=r"f_min must be <= f_max.*index \(3,\)"):
        allocs[solver].solve(problem.M, problem.b, f_min, problem.f_max)


@pytest.mark.parametrize("solver", SOLVERS)
def test_batch_validation(allocs, problem, solver):
    M = np.stack([problem.M] * 3)
    b = np.stack([problem.b] * 3)
    with pytest.raises(InputError, match=r"M must have shape \(N, 6, 8\)"):
        allocs[solver].solve_batch(problem.M, b, problem.f_min, problem.f_max)
    with pytest.raises(InputError, match=r"b must have shape \(3, 6\)"):
        allocs[solver].solve_batch(M, b[:2], problem.f_min, problem.f_max)
    with pytest.raises(InputError, match=r"f_min must have shape \(8,\) or \(3, 8\)"):
        allocs[solver].solve_batch(M, b, np.zeros((2, 8)), problem.f_max)
    bad = np.stack([problem.f_min] * 3)
    bad[1, 2] = np.nan
    with pytest.raises(InputError, match=r"f_min .* must be finite.*\(1, 2\)"):
        allocs[solver].solve_batch(M, b, bad, problem.f_max)


@pytest.mark.parametrize("solver", ALL)
def test_scalar_bounds_lists_and_views_are_accepted(problem, solver):
    alloc = make_allocator(8, 6, solver)
    ref = make_allocator(8, 6, "fast").solve(problem.M, problem.b, 0.5, 30.0)
    M_view = np.asfortranarray(problem.M)
    M_view.setflags(write=False)
    res = alloc.solve(M_view, list(problem.b), 0.5, 30.0)
    assert res.f.shape == (8,) and res.active.shape == (8,)
    assert res.feasible
    if alloc.exact:
        np.testing.assert_allclose(res.f, ref.f, rtol=1e-7, atol=1e-8)


def test_factory_and_spec_errors():
    with pytest.raises(InputError, match="solver must be one of"):
        make_allocator(8, 6, "gurobi")
    with pytest.raises(InputError, match="n_actuators must be >= n_dof"):
        make_allocator(4, 6)
    with pytest.raises(InputError, match="n_dof must be >= 1"):
        make_allocator(4, 0)
    with pytest.raises(InputError, match="n_actuators must be an int"):
        make_allocator(8.0, 6)
    with pytest.raises(InputError, match=r"weights must have shape \(8,\)"):
        make_allocator(8, 6, weights=np.ones(7))
    with pytest.raises(InputError, match="weights must be finite and > 0"):
        make_allocator(8, 6, weights=np.r_[np.ones(7), 0.0])
    with pytest.raises(InputError, match="f_ref must be None, 'midpoint' or an array"):
        make_allocator(8, 6, f_ref="mean")
    with pytest.raises(InputError, match=r"f_ref must have shape \(8,\)"):
        make_allocator(8, 6, f_ref=np.ones(3))
    with pytest.raises(InputError, match="tol must be in"):
        make_allocator(8, 6, tol=0.0)
    alloc = make_allocator(8, 6, "daqp")
    assert alloc.name == "fast" and "DaqpAllocator" in repr(alloc)


def test_spec_reference_and_objective():
    spec = AllocationSpec.build(3, 1, f_ref="midpoint", weights=[1.0, 2.0, 3.0])
    lo, hi = np.array([0.0, 1.0, 2.0]), np.array([2.0, 3.0, 4.0])
    np.testing.assert_array_equal(spec.reference(lo, hi), [1.0, 2.0, 3.0])
    assert spec.objective([1.0, 2.0, 4.0], lo, hi) == pytest.approx(0.5 * 9.0)
    assert spec.weights.flags.writeable is False


@pytest.mark.parametrize("solver", EXACT_SOLVERS)
def test_per_call_reference_overrides_the_spec(problem, solver):
    """f_ref = the previous answer gives that answer back: a smooth control loop."""
    alloc = make_allocator(8, 6, solver)
    first = make_allocator(8, 6, "fast", f_ref="midpoint").solve(
        problem.M, problem.b, problem.f_min, problem.f_max
    )
    again = alloc.solve(problem.M, problem.b, problem.f_min, problem.f_max, f_ref=first.f)
    np.testing.assert_allclose(again.f, first.f, rtol=1e-7, atol=1e-7)


def test_result_fields(problem, allocs):
    res = allocs["fast"].solve(problem.M, problem.b, problem.f_min, problem.f_max)
    assert res.solver == "fast" and res.status == "optimal" and res.feasible
    assert res.iterations >= 0 and res.solve_time > 0
    assert res.active.dtype == np.int8
    batch = allocs["fast"].solve_batch(
        problem.M[None], problem.b[None], problem.f_min, problem.f_max
    )
    assert len(batch) == 1 and batch[0].status == "optimal"
    np.testing.assert_array_equal(batch[0].f, res.f)


def test_degenerate_problems_do_not_raise():
    """Rank-deficient M (a singular posture) with a consistent b is still solved."""
    rng = np.random.default_rng(12)
    M = rng.standard_normal((6, 8))
    M[5] = M[4]  # two equal rows
    f0 = rng.uniform(2.0, 8.0, 8)
    b = M @ f0
    for name in SOLVERS:
        res = make_allocator(8, 6, name).solve(M, b, 0.0, 10.0)
        assert res.feasible, name
        np.testing.assert_allclose(M @ res.f, b, atol=1e-8)
    b_bad = b.copy()
    b_bad[5] += 1.0  # inconsistent rows: infeasible, least squares
    for name in SOLVERS:
        res = make_allocator(8, 6, name).solve(M, b_bad, 0.0, 10.0)
        assert not res.feasible and res.status == "infeasible", name
        assert res.residual == pytest.approx(np.sqrt(0.5), rel=1e-6), name


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_per_tick_reference_does_not_stay_for_later_ticks(solver):
    problem = random_problem(np.random.default_rng(3), 4, 9)
    alloc = make_allocator(9, 4, solver)
    before = alloc.solve(problem.M, problem.b, problem.f_min, problem.f_max).f.copy()
    moved = alloc.solve(
        problem.M, problem.b, problem.f_min, problem.f_max, f_ref=problem.f_max
    ).f.copy()
    after = alloc.solve(problem.M, problem.b, problem.f_min, problem.f_max).f
    assert np.abs(moved - before).max() > 1e-3  # the reference matters on this problem
    np.testing.assert_allclose(after, before, atol=1e-9)


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("zero_b", [True, False])
def test_swapped_bounds_are_refused_by_every_solver(solver, zero_b):
    problem = random_problem(np.random.default_rng(5), 4, 9)
    f_min = problem.f_min.copy()
    f_min[8] = problem.f_max[8] + 1.0
    b = np.zeros(4) if zero_b else problem.b
    with pytest.raises(InputError, match="f_min must be <= f_max"):
        make_allocator(9, 4, solver).solve(problem.M, b, f_min, problem.f_max)


def test_a_tolerance_that_is_not_a_number_is_named():
    with pytest.raises(InputError, match="tol must be a number"):
        make_allocator(9, 4, "newton", tol="x")


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_complex_reference_is_refused(problem, solver):
    """Per tick and in the spec, f_ref's imaginary part was dropped with a mere warning."""
    args = (problem.M, problem.b, problem.f_min, problem.f_max)
    with pytest.raises(InputError, match=r"f_ref must be real forces \[N\]; got complex values"):
        make_allocator(8, 6, solver).solve(*args, f_ref=np.ones(8) * (1 + 1j))
    with pytest.raises(InputError, match="f_ref must be real numbers; got complex values"):
        make_allocator(8, 6, solver, f_ref=np.ones(8) * (1 + 1j))
