"""Pott's closed forms: the published WireX numbers, exactness, feasibility detection."""

import numpy as np
import pytest

from msarm.allocation import make_allocator
from msarm.allocation.solvers.closed_form import weighted_closed_form
from msarm.allocation.testing import random_problem
from msarm.cdpr import CableRobot

WIREX_LENGTH = 2.6148040079516472


def wirex() -> CableRobot:
    top = np.array([[-2.0, 1.5, 2.0], [2.0, 1.5, 2.0], [2.0, -1.5, 2.0], [-2.0, -1.5, 2.0]])
    plate = np.array(
        [[-0.06, 0.06, 0.0], [0.06, 0.06, 0.0], [0.06, -0.06, 0.0], [-0.06, -0.06, 0.0]]
    )
    return CableRobot(np.vstack([top, top * [1.0, 1.0, 0.0]]), np.vstack([plate, plate]))


@pytest.mark.parametrize("solver", ["closed_form", "improved_closed_form", "fast", "cvxpy"])
def test_wirex_unit_test(solver):
    """The published WireX test: 5.5 N in every cable for w = 0 and f in [1, 10] N."""
    robot = wirex()
    r, R = np.array([0.0, 0.0, 1.0]), np.eye(3)
    np.testing.assert_allclose(robot.cable_lengths(r, R), WIREX_LENGTH, rtol=0, atol=1e-15)
    At = robot.structure_matrix(r, R)
    alloc = make_allocator(8, 6, solver, f_ref="midpoint")
    res = alloc.solve(At, -np.zeros(6), 1.0, 10.0)
    assert res.feasible
    np.testing.assert_allclose(res.f, 5.5, rtol=0, atol=1e-9)
    if solver.endswith("closed_form"):
        assert res.status == "closed_form"
        assert res.iterations == 1


def test_closed_form_is_the_qp_optimum_when_no_bound_is_active():
    rng = np.random.default_rng(5)
    checked = 0
    for _ in range(200):
        p = random_problem(rng, 6, 8)
        for ref in (None, "midpoint"):
            cf = make_allocator(8, 6, "closed_form", f_ref=ref).solve(p.M, p.b, p.f_min, p.f_max)
            qp = make_allocator(8, 6, "fast", f_ref=ref).solve(p.M, p.b, p.f_min, p.f_max)
            if cf.status == "closed_form" and not qp.active.any():
                np.testing.assert_allclose(cf.f, qp.f, rtol=1e-10, atol=1e-10)
                checked += 1
    assert checked > 20


def test_weighted_closed_form_is_the_weighted_minimum_norm_solution():
    rng = np.random.default_rng(6)
    M = rng.standard_normal((4, 9))
    b = rng.standard_normal(4)
    w = rng.uniform(0.1, 2.0, 9)
    ref = rng.uniform(0.0, 3.0, 9)
    f = weighted_closed_form(M, b, 1.0 / w**2, ref)
    np.testing.assert_allclose(M @ f, b, atol=1e-12)
    # Optimality: W^2 (f - ref) lies in the row space of M.
    g = w**2 * (f - ref)
    lam = np.linalg.lstsq(M.T, g, rcond=None)[0]
    np.testing.assert_allclose(M.T @ lam, g, atol=1e-12)
    assert weighted_closed_form(np.zeros((4, 9)), b, 1.0 / w**2, ref) is None


def test_improved_closed_form_fixes_the_worst_violation():
    """A force the closed form drives below its bound is fixed there; the rest re-solved."""
    rng = np.random.default_rng(7)
    found = 0
    for _ in range(300):
        p = random_problem(rng, 6, 8)
        simple = make_allocator(8, 6, "closed_form", f_ref="midpoint")
        improved = make_allocator(8, 6, "improved_closed_form", f_ref="midpoint")
        s = simple.solve(p.M, p.b, p.f_min, p.f_max)
        i = improved.solve(p.M, p.b, p.f_min, p.f_max)
        if s.status == "fallback" and i.status == "closed_form":
            found += 1
            assert 2 <= i.iterations <= 8 - 6 + 1
            assert i.active.any()
            fixed = i.active != 0
            np.testing.assert_array_equal(
                i.f[fixed], np.where(i.active[fixed] < 0, p.f_min[fixed], p.f_max[fixed])
            )
            np.testing.assert_allclose(p.M @ i.f, p.b, atol=1e-9)
    assert found > 5


@pytest.mark.parametrize("solver", ["closed_form", "improved_closed_form"])
def test_closed_forms_report_infeasible_problems(solver):
    rng = np.random.default_rng(8)
    for _ in range(30):
        p = random_problem(rng, 6, 8, feasible=False)
        res = make_allocator(8, 6, solver, f_ref="midpoint").solve(p.M, p.b, p.f_min, p.f_max)
        assert not res.feasible and res.status == "infeasible"
        assert np.all(res.f >= p.f_min) and np.all(res.f <= p.f_max)
        assert res.residual > 0


def test_improved_closed_form_gives_up_after_m_minus_n_fixes():
    """With the bounds so tight that n free forces cannot reach b, it reports failure."""
    rng = np.random.default_rng(9)
    M = rng.standard_normal((4, 6))
    f_min, f_max = np.full(6, 1.0), np.full(6, 1.1)
    b = M @ np.full(6, 5.0)  # needs forces near 5: out of reach
    res = make_allocator(6, 4, "improved_closed_form").solve(M, b, f_min, f_max)
    assert res.status == "infeasible"
    assert res.iterations >= 6 - 4 + 1
