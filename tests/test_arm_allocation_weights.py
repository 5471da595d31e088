"""The arm controller allocates with weights ``1 / F_max``: it minimises ``sum (f_i / F_max,i)^2``.

On the shipped arm these weights cannot be told from any other per-group constant: the muscle
Jacobian is block diagonal (the seven shoulder muscles span the three shoulder joints only,
biceps and triceps the elbow only) and ``F_max`` is constant within each block (500 N and
400 N), so the allocation QP splits into two problems whose minimiser does not change when
their weights are scaled. Weights of ones, or of ``F_max``, give the same forces there, and a
mutation test found that no test noticed. The tests below therefore give the muscles unequal
strengths within each block (a copy of the arm with other ``F_max``; the geometry and the
dynamics are the shipped ones) and check the forces of :meth:`MuscleSpaceController.update`.
"""

from __future__ import annotations

from dataclasses import replace

import cvxpy as cp
import numpy as np

from msarm.control import ArmControllerConfig, MuscleSpaceController
from msarm.muscle.hill import HillMuscles
from msarm.plant.effects import SensorReadings

#: Strengths [N] of the copy of the arm, in cable order (deltoid anterior, lateral,
#: posterior, pectoralis major, latissimus dorsi, teres minor, infraspinatus, biceps,
#: triceps): unequal within the shoulder block and within the elbow block.
UNEQUAL_F_MAX = np.array([1000.0, 250.0, 700.0, 400.0, 900.0, 300.0, 600.0, 800.0, 200.0])


def _with_strengths(arm, f_max):
    """The arm with the muscles' ``F_max`` [N] set to ``f_max``, shape ``(m,)``."""
    params = [
        replace(p, max_isometric_force=float(f))
        for p, f in zip(arm.muscles.params, f_max, strict=True)
    ]
    return replace(arm, muscles=HillMuscles(params), _scratch=[])


def _posture(arm):
    """A posture in the middle of the joint range [rad], shape ``(n,)``."""
    lower, upper = np.asarray(arm.joint_lower), np.asarray(arm.joint_upper)
    return lower + np.array([0.55, 0.4, 0.6, 0.45]) * (upper - lower)


def _bounds(model, q, min_tension):
    """The controller's documented force bounds at rest at ``q`` [N], each ``(m,)``:
    ``[max(passive, T_min), max(full activation, that)]`` (Hill model, zero MTU speed)."""
    lengths = model.geometry(q, with_wrap_angles=False).lengths
    passive, full = model.muscles.force_capacity(lengths, np.zeros(model.n_cables))
    f_min = np.maximum(passive, min_tension)
    return f_min, np.maximum(full, f_min)


def _first_tick(model, q, tau):
    """One update of a fresh controller at rest at ``q`` whose wanted torque is ``tau``.

    The reference is ``q`` at rest, so the PID adds nothing on the first tick; a feedforward
    ``tau - ID(q)`` brings the wanted torque to ``tau`` [N m].
    """
    controller = MuscleSpaceController(model, ArmControllerConfig())
    controller.reset(q)
    n, m = model.n_joints, model.n_cables
    zero = np.zeros(n)
    gravity = controller.reference_torques(q[None], zero[None], zero[None])[0]
    readings = SensorReadings(0.0, q, np.zeros(m), np.zeros(m), np.zeros(m))
    out = controller.update(readings, q, zero, zero, feedforward=tau - gravity)
    np.testing.assert_array_equal(out.qdot_estimate, zero)  # the bounds are those at rest
    np.testing.assert_allclose(out.joint_torque, tau, rtol=0, atol=1e-12)
    return out


def _weighted_allocation(jacobian, tau, f_min, f_max):
    """Independent reference (cvxpy, Clarabel): a function of weights ``w`` [1/N], ``(m,)``,
    giving ``argmin sum (w_i f_i)^2`` s.t. ``-J^T f = tau``, ``f_min <= f <= f_max`` [N]."""
    weights = cp.Parameter(jacobian.shape[0], pos=True)
    f = cp.Variable(jacobian.shape[0])
    problem = cp.Problem(
        cp.Minimize(cp.sum_squares(cp.multiply(weights, f))),
        [-jacobian.T @ f == tau, f >= f_min, f <= f_max],
    )

    def solve(w):
        weights.value = w / np.max(w)  # same minimiser, better scaled for the solver
        problem.solve(solver=cp.CLARABEL, tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12)
        assert problem.status == cp.OPTIMAL
        return f.value.copy()

    return solve


def test_controller_forces_minimise_the_squared_forces_over_max_isometric_force(arm):
    """The allocated forces equal the cvxpy minimiser of ``sum (f_i / F_max,i)^2`` within the
    muscles' bounds, and differ from those of weights 1 or ``F_max`` by newtons."""
    model = _with_strengths(arm, UNEQUAL_F_MAX)
    config = ArmControllerConfig()
    q = _posture(model)
    f_min, f_max = _bounds(model, q, config.min_tension)
    jacobian = np.asarray(model.geometry(q, with_wrap_angles=False).jacobian)
    # a torque the muscles can make: from forces between 10 % and 30 % of their range
    share = np.random.default_rng(7).uniform(0.1, 0.3, model.n_cables)
    tau = -jacobian.T @ (f_min + share * (f_max - f_min))

    out = _first_tick(model, q, tau)

    assert out.feasible
    reference = _weighted_allocation(jacobian, out.joint_torque, f_min, f_max)
    expected = reference(1.0 / UNEQUAL_F_MAX)
    np.testing.assert_allclose(out.muscle_force, expected, rtol=0, atol=1e-5)
    # the check is sharp: other weights move the forces far beyond its tolerance
    for weights in (np.ones(model.n_cables), UNEQUAL_F_MAX):
        other = reference(weights)
        assert np.abs(other - expected).max() > 1.0


def test_a_stronger_muscle_takes_a_larger_share_of_the_load(arm):
    """Doubling one muscle's ``F_max`` makes the controller ask more of it for the same torque,
    since ``1 / F_max`` then weighs its force less. With weights that ignore ``F_max`` its
    force, away from its bounds, would not change; with weights ``F_max`` it would drop."""
    config = ArmControllerConfig()
    shipped = np.asarray(arm.muscles.max_isometric_force, dtype=float)
    stronger = shipped.copy()
    stronger[2] *= 2.0  # the deltoid posterior, 500 N -> 1000 N
    weak, strong = _with_strengths(arm, shipped), _with_strengths(arm, stronger)
    q = _posture(arm)
    f_min, f_max = _bounds(weak, q, config.min_tension)
    jacobian = np.asarray(weak.geometry(q, with_wrap_angles=False).jacobian)
    share = np.random.default_rng(7).uniform(0.1, 0.3, arm.n_cables)
    tau = -jacobian.T @ (f_min + share * (f_max - f_min))

    before = _first_tick(weak, q, tau).muscle_force[2]
    after = _first_tick(strong, q, tau).muscle_force[2]

    assert f_min[2] + 10.0 < before < f_max[2] - 10.0  # away from its bounds
    assert after > 1.2 * before  # about 1.39 times
