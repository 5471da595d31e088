"""The arm (paper 003): muscle forces for wanted joint torques, within the muscles' capacity.

M = -J_c^T (torque from cable forces is tau = -J_c^T f), b = tau, weights 1/F_max (the sum
of squared activations), bounds from the Hill muscles' force capacity at the current MTU
length and velocity.
"""

import numpy as np
import pytest

from msarm.allocation import EXACT_SOLVERS, make_allocator
from msarm.model import load_arm


@pytest.fixture(scope="module")
def arm():
    return load_arm()


@pytest.fixture(scope="module")
def ticks(arm):
    """(M, f_min, f_max, f0) at random postures and joint velocities within the limits."""
    rng = np.random.default_rng(2024)
    n, m = arm.n_joints, arm.n_cables
    out = []
    while len(out) < 40:
        q = rng.uniform(arm.joint_lower, arm.joint_upper)
        qdot = rng.uniform(-1.0, 1.0, n)
        geo = arm.geometry(q)
        J = np.asarray(geo.jacobian)
        assert J.shape == (m, n) and geo.lengths.shape == (m,)
        f_min, f_max = arm.muscles.force_capacity(geo.lengths, J @ qdot)
        f0 = f_min + rng.uniform(0.0, 1.0, m) * (f_max - f_min)
        out.append((-J.T, np.asarray(f_min), np.asarray(f_max), f0))
    return out


def test_sizes(arm):
    assert (arm.n_joints, arm.n_cables) == (4, 9)
    assert len(arm.cable_names) == 9


@pytest.mark.parametrize("solver", EXACT_SOLVERS)
def test_producible_torques_are_reproduced_within_capacity(arm, ticks, solver):
    weights = 1.0 / np.asarray(arm.muscles.max_isometric_force)
    alloc = make_allocator(9, 4, solver, weights=weights)
    for M, f_min, f_max, f0 in ticks:
        tau = M @ f0  # a torque the muscles can produce: tau = -J_c^T f0
        res = alloc.solve(M, tau, f_min, f_max)
        assert res.feasible and res.status == "optimal"
        np.testing.assert_allclose(M @ res.f, tau, rtol=0, atol=1e-9)
        assert np.all(res.f >= f_min - 1e-9) and np.all(res.f <= f_max + 1e-9)
        # The least activation: no more than the forces that were used to make tau.
        assert alloc.spec.objective(res.f, f_min, f_max) <= alloc.spec.objective(f0, f_min, f_max)


def test_all_exact_solvers_give_one_answer(arm, ticks):
    weights = 1.0 / np.asarray(arm.muscles.max_isometric_force)
    allocs = {name: make_allocator(9, 4, name, weights=weights) for name in EXACT_SOLVERS}
    M = np.stack([t[0] for t in ticks])
    f_min = np.stack([t[1] for t in ticks])
    f_max = np.stack([t[2] for t in ticks])
    tau = np.einsum("knm,km->kn", M, np.stack([t[3] for t in ticks]))
    batch = allocs["batched"].solve_batch(M, tau, f_min, f_max)
    assert batch.feasible.all()
    for k in range(len(ticks)):
        ref = allocs["cvxpy"].solve(M[k], tau[k], f_min[k], f_max[k])
        fast = allocs["fast"].solve(M[k], tau[k], f_min[k], f_max[k])
        obj_ref = allocs["cvxpy"].spec.objective(ref.f, f_min[k], f_max[k])
        for f in (fast.f, batch.f[k]):
            obj = allocs["fast"].spec.objective(f, f_min[k], f_max[k])
            assert obj == pytest.approx(obj_ref, rel=1e-6)


def test_torques_beyond_the_muscles_are_reported_not_raised(arm, ticks):
    weights = 1.0 / np.asarray(arm.muscles.max_isometric_force)
    alloc = make_allocator(9, 4, "fast", weights=weights)
    M, f_min, f_max, _ = ticks[0]
    tau = np.array([1e4, -1e4, 1e4, 1e4])  # N m: far beyond any muscle
    res = alloc.solve(M, tau, f_min, f_max)
    assert not res.feasible and res.status == "infeasible"
    assert np.all(res.f >= f_min) and np.all(res.f <= f_max)
    assert res.residual == pytest.approx(np.linalg.norm(M @ res.f - tau))
    assert res.residual > 1e3


def test_the_exact_solvers_break_an_infeasible_problems_ties_alike(arm):
    """Beyond the muscles, many bounded f are equally close to M f = b; every exact solver
    gives the one of least objective. The cvxpy reference gave another (its interior point
    resolved the 1e-8 regularisation only to its tolerance): up to 48 N off, same residual."""
    weights = 1.0 / np.asarray(arm.muscles.max_isometric_force)
    allocs = {s: make_allocator(9, 4, s, weights=weights) for s in ("fast", "newton", "cvxpy")}
    rng = np.random.default_rng(3)
    for _ in range(13):  # the 13th tied the old reference: 48 N off
        q = rng.uniform(arm.joint_lower, arm.joint_upper)
        geometry = arm.geometry(q)
        f_min, f_max = arm.muscles.force_capacity(geometry.lengths, np.zeros(9))
        tau = rng.normal(scale=[200.0, 200.0, 100.0, 100.0])
        answers = {s: a.solve(-geometry.jacobian.T, tau, f_min, f_max) for s, a in allocs.items()}
        assert not answers["fast"].feasible
        for name in ("newton", "cvxpy"):
            np.testing.assert_allclose(answers[name].f, answers["fast"].f, rtol=0, atol=1e-4)
