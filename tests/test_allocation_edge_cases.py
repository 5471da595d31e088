"""Edge cases of the allocation core that every solver must get right.

Forces exactly within their bounds (a plant refuses -3e-15 N of tension), a wrench direction
no cable acts on (a zero row of M), a structure matrix of zeros or of 1e-160 (the Newton
kernel's regulariser underflowed and NaN forces came back as "optimal"), and the cvxpy
reference at other force scales. The references are independent of the solvers: scipy's
bounded least squares, and the KKT conditions of the allocation QP.
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest
from scipy.optimize import lsq_linear

from msarm.allocation import EXACT_SOLVERS, SOLVERS, make_allocator
from msarm.allocation.batched import MAX_ITER
from msarm.allocation.solvers.newton import dual_newton_tick
from msarm.cdpr.robot_model import load_cable_robot
from msarm.plant import IDEAL_PLANT, ArmPlant


def _arm_ticks(arm, count, seed, *, scale=1.0, infeasible_every=0):
    """The README example's set-up at random postures: ``(M, tau, f_min, f_max)`` per tick.

    Bounds [N] are the muscles' capacity at rest, times ``scale``; ``tau`` [N m] is made by
    random forces within them, or every ``infeasible_every``-th tick a random torque (often
    beyond the muscles).
    """
    rng = np.random.default_rng(seed)
    ticks = []
    for k in range(count):
        geometry = arm.geometry(rng.uniform(arm.joint_lower, arm.joint_upper))
        f_min, f_max = arm.muscles.force_capacity(geometry.lengths, np.zeros(arm.n_cables))
        f_min, f_max = scale * np.asarray(f_min), scale * np.asarray(f_max)
        M = -np.asarray(geometry.jacobian).T
        if infeasible_every and k % infeasible_every == 0:
            tau = scale * rng.normal(scale=[200.0, 200.0, 100.0, 100.0])
        else:
            tau = M @ (f_min + rng.uniform(0.0, 1.0, arm.n_cables) * (f_max - f_min))
        ticks.append((M, tau, f_min, f_max))
    return ticks


def kkt_optimum(M, b, f_min, f_max, w, f_ref, active):
    """The optimum of ``min 1/2 ||W (f - f_ref)||^2, M f = b, f_min <= f <= f_max`` [N].

    With the forces of ``active`` (-1/+1) held at their bounds, the free ones solve the
    equality-constrained problem exactly; the result is the QP's optimum (strictly convex: the
    only one) when the KKT conditions hold, which this asserts: free forces within their
    bounds, the bound multipliers ``W^2 (f - f_ref) - M^T lambda`` >= 0 at f_min, <= 0 at f_max.
    """
    free = active == 0
    f = np.where(active < 0, f_min, np.where(active > 0, f_max, f_ref)).astype(np.float64)
    inv_w2 = 1.0 / w[free] ** 2
    K = (M[:, free] * inv_w2) @ M[:, free].T
    lam = np.linalg.solve(K, b - M @ f)
    f[free] += inv_w2 * (M[:, free].T @ lam)
    mu = w**2 * (f - f_ref) - M.T @ lam
    slack = 1e-9 * (np.abs(w**2 * (f - f_ref)).max() + np.abs(M.T @ lam).max() + 1e-300)
    span = 1e-12 * (1.0 + np.abs(f_max).max())
    assert np.all(f[free] >= f_min[free] - span) and np.all(f[free] <= f_max[free] + span)
    assert np.all(mu[active < 0] >= -slack) and np.all(mu[active > 0] <= slack)
    np.testing.assert_allclose(M @ f, b, rtol=0, atol=1e-10 * (1.0 + np.abs(b).max()))
    return f


@pytest.mark.parametrize("solver", SOLVERS)
def test_forces_lie_exactly_within_their_bounds_and_the_plant_takes_them(arm, solver):
    """DAQP met an active bound only to round-off: 232 of 300 arm ticks gave forces up to
    1.4e-13 N outside [f_min, f_max], and ArmPlant.command refused -3.47e-15 N of tension."""
    weights = 1.0 / np.asarray(arm.muscles.max_isometric_force)
    alloc = make_allocator(9, 4, solver, weights=weights)
    plant = ArmPlant(arm, IDEAL_PLANT, seed=0)
    ticks = _arm_ticks(arm, 100 if solver == "cvxpy" else 300, seed=0, infeasible_every=5)
    for M, tau, f_min, f_max in ticks:
        res = alloc.solve(M, tau, f_min, f_max)
        assert np.all(res.f >= f_min) and np.all(res.f <= f_max), (res.status, res.f - f_min)
        np.testing.assert_array_equal(res.f[res.active < 0], f_min[res.active < 0])
        np.testing.assert_array_equal(res.f[res.active > 0], f_max[res.active > 0])
        plant.command(res.f)  # raises InputError on a negative tension
    if solver == "batched":
        M, tau, f_min, f_max = (np.stack(a) for a in zip(*ticks, strict=True))
        batch = alloc.solve_batch(M, tau, f_min, f_max)
        assert np.all(batch.f >= f_min) and np.all(batch.f <= f_max)


@pytest.mark.parametrize("solver", ["fast", "newton", "closed_form", "improved_closed_form"])
def test_a_methods_answer_is_checked_against_the_bounds(arm, solver, monkeypatch):
    """A method's f within round-off of a bound is set onto it; one farther out (though it
    meets M f = b) or a NaN is not an answer: the tick goes to the fallback (DAQP's optimum)."""
    weights = 1.0 / np.asarray(arm.muscles.max_isometric_force)
    M, tau, f_min, f_max = _arm_ticks(arm, 1, seed=3)[0]
    exact = make_allocator(9, 4, "fast", weights=weights).solve(M, tau, f_min, f_max)
    at_min = int(np.flatnonzero(exact.active < 0)[0])
    null = np.linalg.svd(M)[2][-1]  # M null = 0: moves f along M f = b
    step = -1e-3 * null / null[at_min]  # f[at_min] 1 mN below f_min
    alloc = make_allocator(9, 4, solver, weights=weights)
    for f, expect in (
        (exact.f - 1e-13 * (np.arange(9) == at_min), "snapped"),
        (exact.f + step, "refused"),
        (np.full(9, np.nan), "refused"),
    ):
        monkeypatch.setattr(alloc, "_solve", lambda *a, f=f: (f.copy(), "optimal", 1, None))
        res = alloc.solve(M, tau, f_min, f_max)
        assert np.all(res.f >= f_min) and np.all(res.f <= f_max)
        if expect == "snapped":
            assert res.status == "optimal" and res.f[at_min] == f_min[at_min]
        else:
            assert res.status == "fallback" and res.feasible
            np.testing.assert_allclose(res.f, exact.f, rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def zero_row_problem():
    """An 8-cable robot's structure matrix with row 5 (a moment no cable makes) zeroed."""
    model = load_cable_robot()
    M = model.robot.structure_matrix(model.workspace_center, np.eye(3))
    M[5] = 0.0
    b = np.array([0.0, 0.0, 5.0, 0.0, 0.0, 1.0])  # b[5] = 1: out of reach
    return M, b, np.ones(8), np.full(8, 10.0)


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_wrench_direction_no_cable_acts_on_gets_the_bounded_least_squares(
    zero_row_problem, solver
):
    """newton and the closed forms returned f = 0 (below f_min) and a residual of 7.13 where
    the bounded least squares has 1: DAQP called x = 0 optimal and the fallback trusted it."""
    M, b, f_min, f_max = zero_row_problem
    ref = lsq_linear(M, b, bounds=(f_min, f_max), method="bvls", tol=1e-14)
    best = np.linalg.norm(M @ ref.x - b)
    res = make_allocator(8, 6, solver).solve(M, b, f_min, f_max)
    assert np.all(res.f >= f_min) and np.all(res.f <= f_max)
    assert res.status == "infeasible" and not res.feasible
    assert res.residual == pytest.approx(best, rel=1e-9)
    assert res.residual == pytest.approx(np.linalg.norm(M @ res.f - b), rel=1e-12)
    fast = make_allocator(8, 6, "fast").solve(M, b, f_min, f_max)
    np.testing.assert_allclose(res.f, fast.f, rtol=0, atol=1e-6)  # the ties broken alike


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("size", [0.0, 1e-160])
def test_a_vanishing_structure_matrix_gives_finite_forces_not_nan(solver, size):
    """newton returned all-NaN forces as "optimal" (feasible): its regulariser underflowed
    to 0 and max() dropped the NaN residual. No bounded f comes near b here."""
    M, b = np.full((6, 8), size), np.full(6, 1e-3)
    res = make_allocator(8, 6, solver).solve(M, b, 1.0, 10.0)
    assert np.isfinite(res.f).all() and np.all(res.f >= 1.0) and np.all(res.f <= 10.0)
    assert res.status == "infeasible" and not res.feasible
    assert res.residual == pytest.approx(np.linalg.norm(b), rel=1e-9)


@pytest.mark.parametrize("size", [0.0, 1e-160])
def test_newton_kernel_gives_no_answer_rather_than_nan(size):
    f, active = np.full(8, -1.0), np.zeros(8, dtype=np.int8)
    code = dual_newton_tick(
        np.full((6, 8), size), np.full(6, 1e-3), np.ones(8), np.zeros(8), np.ones(8),
        np.full(8, 10.0), f, active, MAX_ITER,
    )  # fmt: skip
    assert code < 0  # no bounded f meets M f = b: no optimum to report (was NaN forces)
    np.testing.assert_array_equal(f, -1.0)  # not written


@pytest.mark.parametrize("scale", [1.0, 30.0])
def test_cvxpy_reference_is_exact_at_any_force_scale(arm, scale):
    """Forces and bounds 30 times the arm's, weights 30 times smaller: Clarabel stopped short
    on 23 of 100 problems and objectives up to 94 times the optimum came back (status
    "fallback", feasible). The reference now holds the KKT optimum to 1e-10 of the force
    scale, at both scales."""
    weights = 1.0 / (scale * np.asarray(arm.muscles.max_isometric_force))
    ref_alloc = make_allocator(9, 4, "cvxpy", weights=weights)
    fast = make_allocator(9, 4, "fast", weights=weights)
    for M, tau, f_min, f_max in _arm_ticks(arm, 40, seed=1, scale=scale):
        res = ref_alloc.solve(M, tau, f_min, f_max)
        assert res.status == "optimal"
        active = fast.solve(M, tau, f_min, f_max).active  # a guess, which the KKT check proves
        f_star = kkt_optimum(M, tau, f_min, f_max, weights, np.zeros(9), active)
        np.testing.assert_allclose(res.f, f_star, rtol=0, atol=1e-10 * np.abs(f_max).max())


@pytest.mark.parametrize("feasible", [True, False])
def test_cvxpy_hands_a_failed_solve_to_the_exact_path(arm, feasible, monkeypatch):
    """Clarabel's SolverError (e.g. InsufficientProgress) was swallowed in the QP, and raised
    from the fallback's least squares; now DAQP's exact answer is returned."""
    weights = 1.0 / np.asarray(arm.muscles.max_isometric_force)
    alloc = make_allocator(9, 4, "cvxpy", weights=weights)

    def fail(*args, **kwargs):
        raise cp.SolverError("Solver 'CLARABEL' failed. InsufficientProgress")

    monkeypatch.setattr(alloc._qp, "solve", fail)
    monkeypatch.setattr(alloc._ls, "solve", fail)
    M, tau, f_min, f_max = _arm_ticks(arm, 2, seed=5, infeasible_every=2)[0 if not feasible else 1]
    exact = make_allocator(9, 4, "fast", weights=weights).solve(M, tau, f_min, f_max)
    assert exact.feasible is feasible
    res = alloc.solve(M, tau, f_min, f_max)
    assert res.feasible is feasible
    assert res.status == ("fallback" if feasible else "infeasible")
    np.testing.assert_array_equal(res.f, exact.f)


def test_the_exact_solvers_agree_with_the_kkt_optimum_on_arm_problems(arm):
    """Every exact solver's answer is the KKT optimum (to 1e-9 of the force scale)."""
    weights = 1.0 / np.asarray(arm.muscles.max_isometric_force)
    allocs = {name: make_allocator(9, 4, name, weights=weights) for name in EXACT_SOLVERS}
    for M, tau, f_min, f_max in _arm_ticks(arm, 20, seed=2):
        for name, alloc in allocs.items():
            res = alloc.solve(M, tau, f_min, f_max)
            f_star = kkt_optimum(M, tau, f_min, f_max, weights, np.zeros(9), res.active)
            np.testing.assert_allclose(
                res.f, f_star, rtol=0, atol=1e-9 * np.abs(f_max).max(), err_msg=name
            )


def test_an_infinite_bound_is_refused_without_a_numpy_warning():
    """The fast finiteness check's 0 * inf leaked a RuntimeWarning before the clear error."""
    import warnings

    from msarm.allocation import make_allocator
    from msarm.errors import InputError

    allocator = make_allocator(3, 2)
    M = np.array([[1.0, -1.0, 0.0], [0.0, 1.0, -1.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match=r"f_max \[N\] must be finite, got inf"):
            allocator.solve(M, np.zeros(2), np.zeros(3), np.full(3, np.inf))


def _balanced_problem(seed: int, force: float) -> tuple:
    """A 6 x 8 problem with a strictly positive f0 in [force, 10 force] balancing M f0 = 0,
    and a small wanted b: ``M f`` is a difference of terms of order |M| force."""
    rng = np.random.default_rng(seed)
    M = rng.normal(size=(6, 8))
    f0 = rng.uniform(2.0 * force, 9.0 * force, 8)
    M[:, -1] = -(M[:, :-1] @ f0[:-1]) / f0[-1]  # M f0 = 0
    b = 0.01 * rng.normal(size=6)
    return M, b, np.full(8, force), np.full(8, 10.0 * force)


@pytest.mark.parametrize("solver", EXACT_SOLVERS)
def test_large_forces_with_a_small_wrench_are_feasible_at_any_force_scale(solver):
    """Bounds of 1e6-1e7 N and a wrench of 0.01: the rounding of M f alone is about 1e-9,
    above tol (1 + |b|); every solver called the problem infeasible. The acceptance counts the
    size of M f's terms, as the workspace test does."""
    for seed in range(5):
        M, b, f_min, f_max = _balanced_problem(seed, 1e6)
        res = make_allocator(8, 6, solver).solve(M, b, f_min, f_max)
        assert res.feasible, (seed, res.status, res.residual)
        assert res.residual <= 1e-9 * np.linalg.norm(np.abs(M) @ np.abs(res.f))
    batched = make_allocator(8, 6, "batched")
    problems = [_balanced_problem(seed, 1e6) for seed in range(5)]
    out = batched.solve_batch(
        np.array([p[0] for p in problems]), np.array([p[1] for p in problems]),
        problems[0][2], problems[0][3],
    )  # fmt: skip
    assert out.feasible.all(), out.status


def test_cvxpy_reference_solves_feasible_problems_with_weights_spanning_1e6():
    """With weights spanning 1e5-1e6 Clarabel failed on up to 17 of 60 feasible problems and
    the bounded least squares called them infeasible (residual 46 on one); DAQP's optimum is
    tried first now, as the module's docstring says."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        M = rng.normal(size=(4, 9))
        f_min = rng.uniform(1.0, 10.0, 9)
        f_max = f_min + rng.uniform(10.0, 100.0, 9)
        b = M @ rng.uniform(f_min, f_max)
        weights = np.exp(rng.uniform(-np.log(1e6) / 2, np.log(1e6) / 2, 9))
        res = make_allocator(9, 4, "cvxpy", weights=weights).solve(M, b, f_min, f_max)
        assert res.feasible, res.status
        assert res.residual <= 1e-9 * (1.0 + np.linalg.norm(b) + np.linalg.norm(np.abs(M) @ res.f))
