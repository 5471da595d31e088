"""Gaps found by mutation-testing the numerical core (muscle, allocation, tasks, model).

Each test pins a documented behaviour that the rest of the suite left unchecked, against an
independent reference: a value worked out by hand from the documented formula, a KKT system
solved with numpy, or a path whose geometry is known exactly.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from msarm.allocation import make_allocator
from msarm.allocation.batched import _exact_line_search
from msarm.allocation.fallback import bounded_least_squares
from msarm.allocation.problem import OPTIMAL, AllocationSpec, active_set
from msarm.allocation.solvers.base import Allocator
from msarm.allocation.solvers.closed_form import weighted_closed_form
from msarm.allocation.solvers.newton import _line_search, dual_newton_tick
from msarm.allocation.workspace import feasibility_batch, wrench_feasible_poses
from msarm.cdpr import CableRobot
from msarm.errors import InputError, ModelError
from msarm.model import ARM_MODEL_PATH, load_robot
from msarm.muscle.batch_kinematics import current_wrap_angles
from msarm.muscle.fast import FastHill
from msarm.muscle.geometry import path_points, positive_spanning_margin, wrap_angles
from msarm.muscle.hill import HillMuscles
from msarm.muscle.sizing import size_fibres
from msarm.tasks.trajectories import (
    MIN_FINAL_HOLD,
    MIN_HOLD,
    Move,
    Task,
    minimum_jerk,
    random_reach_task,
)

# --------------------------------------------------------------------------- muscle

# Published De Groote et al. (2016) constants, written out here (not imported) so that the
# reference values below do not come from the code under test.
_B = [(0.815, 1.055, 0.162, 0.063), (0.433, 0.717, -0.030, 0.200), (0.100, 1.000, 0.354, 0.0)]
_D1, _D2, _D3, _D4 = -0.318, -8.149, -0.374, 0.886


def _f_l(length: float) -> float:
    return sum(
        b1 * math.exp(-0.5 * (length - b2) ** 2 / (b3 + b4 * length) ** 2) for b1, b2, b3, b4 in _B
    )


def _f_v(v: float) -> float:
    return _D1 * math.asinh(_D2 * v + _D3) + _D4


# lengths exact in binary: l_MT - l_Ts = l_opt, so the fibre is at its optimal length
_F_MAX, _L_OPT, _L_SLACK, _V_MAX = 1000.0, 0.125, 0.25, 10.0
_AT_OPTIMAL = _L_SLACK + _L_OPT


def _muscle(pennation: float = 0.0) -> HillMuscles:
    return HillMuscles.from_arrays(["m"], _F_MAX, _L_OPT, _L_SLACK, _V_MAX, pennation)


def test_force_just_below_what_full_speed_shortening_gives_is_refused():
    """Eq. 15 has no solution below ``F_max a f_l f_v(-1)``: 1e-6 below it must raise."""
    muscles, a = _muscle(), 0.5
    least = _F_MAX * a * _f_l(1.0) * _f_v(-1.0)  # f_PE(1) = 0, cos(alpha) = 1
    with pytest.raises(InputError, match="below"):
        muscles.fiber_velocity_for_force([a], [least * (1 - 1e-6)], [_AT_OPTIMAL])
    v = muscles.fiber_velocity_for_force([a], [least * (1 + 1e-9)], [_AT_OPTIMAL])
    assert v[0] == pytest.approx(-_V_MAX * _L_OPT, rel=1e-4)


def test_fast_path_limits_the_fibre_velocity_at_full_speed_shortening():
    """FastHill clamps v_norm at -1: a faster MTU speed gives the force at v_max, >= 0."""
    fast = FastHill(_muscle())
    active, passive = fast.parts(np.array([_AT_OPTIMAL]), np.array([-4.0 * _V_MAX * _L_OPT]))
    assert active[0] == pytest.approx(_F_MAX * _f_l(1.0) * _f_v(-1.0), rel=1e-12)
    assert active[0] > 0.0 and passive[0] == 0.0


def test_max_shortening_speed_accounts_for_pennation():
    """With a rigid tendon v_M = v_MT cos(alpha): v_max is reached at v_max l_opt / cos(a0)."""
    alpha0 = 0.3
    muscles = _muscle(alpha0)
    speed = FastHill(muscles).max_shortening_speed
    assert speed[0] == pytest.approx(_V_MAX * _L_OPT / math.cos(alpha0), rel=1e-12)
    # at the optimal fibre length the fibre then shortens at exactly v_max
    length = _L_SLACK + _L_OPT * math.cos(alpha0)
    state = muscles.fiber_state([length], [-speed[0]])
    assert state.length_norm[0] == pytest.approx(1.0, rel=1e-12)
    assert state.velocity_norm[0] == pytest.approx(-1.0, rel=1e-12)


def test_size_fibres_refuses_a_span_starting_at_sin_of_the_pennation():
    """The documented condition is strict: ``sin(a0) < s_lo``."""
    alpha = np.array([0.5])
    lengths = np.array([[0.30], [0.40]])
    with pytest.raises(InputError, match="span"):
        size_fibres(lengths, alpha, span=(float(np.sin(0.5)), 1.2))
    size_fibres(lengths, alpha, span=(float(np.sin(0.5)) + 1e-6, 1.2))  # just inside: fine


def test_positive_spanning_margin_of_a_rank_deficient_jacobian_is_minus_inf():
    """Cables that all act on joint 0 balance (t = 1/3 there) but cannot move joint 1."""
    jacobian = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 0.0]])
    assert positive_spanning_margin(jacobian) == -np.inf
    # and the full-rank case: an antagonist pair on one joint balances at f = (1/2, 1/2)
    assert positive_spanning_margin(np.array([[1.0], [-1.0]])) == pytest.approx(0.5)


_PULLEY_MODEL = """<mujoco><worldbody>
<site name="a" pos="0 0 0"/><site name="b" pos="1 0 0"/><site name="b2" pos="1 0 0"/>
<body name="arm"><joint name="j" type="hinge" axis="0 0 1" range="-1 1"/>
<geom size="0.05" mass="1"/>
<site name="c" pos="1 1 0"/><site name="d" pos="2 1 0"/><site name="e" pos="2 2 0"/></body>
</worldbody><tendon>
<spatial name="pulley"><site site="a"/><site site="b"/><site site="c"/>
<pulley divisor="2"/><site site="c"/><site site="d"/><site site="e"/></spatial>
<spatial name="plain"><site site="a"/><site site="b"/><site site="d"/></spatial>
<spatial name="repeated"><site site="a"/><site site="b"/><site site="b2"/><site site="d"/></spatial>
</tendon></mujoco>"""


def test_wrap_angles_do_not_turn_across_a_pulley():
    """a-b-c turns 90 deg at b, c-d-e 90 deg at d; nothing is counted across the pulley.

    And a turn at two sites on one point (a zero-length segment) is counted once.
    """
    m_model = mujoco.MjModel.from_xml_string(_PULLEY_MODEL)
    m_data = mujoco.MjData(m_model)
    mujoco.mj_forward(m_model, m_data)
    want = [math.pi, math.pi / 4]  # pulley tendon; a-b-d turns 45 deg at b
    np.testing.assert_allclose(wrap_angles(m_model, m_data)[:2], want, rtol=0, atol=1e-12)
    compiled = current_wrap_angles(m_model, m_data)
    np.testing.assert_allclose(compiled[:2], want, rtol=0, atol=1e-12)
    branches = path_points(m_model, m_data, 0)
    assert len(branches) == 2
    np.testing.assert_array_equal(branches[0], [[0, 0, 0], [1, 0, 0], [1, 1, 0]])
    np.testing.assert_array_equal(branches[1], [[1, 1, 0], [2, 1, 0], [2, 2, 0]])
    # a zero-length segment (two sites at one point, b and b2) is passed over: the 45 deg
    # turn there is still counted (it was lost: 0 rad)
    assert wrap_angles(m_model, m_data)[2] == pytest.approx(math.pi / 4, abs=1e-12)
    assert compiled[2] == pytest.approx(math.pi / 4, abs=1e-12)


# --------------------------------------------------------------------------- allocation


def test_active_set_uses_the_documented_tolerance():
    """-1 at f_min, +1 at f_max, to ``tol (1 + |bound|)``, bounds included."""
    f_min = np.array([0.0, 0.0, 0.0, -1.0])
    f_max = np.array([5.0, 5.0, 5.0, 0.0])
    f = np.array([0.0, 5.0 - 1e-9, 2.5, -5e-10])
    np.testing.assert_array_equal(active_set(f, f_min, f_max, 1e-9), [-1, 1, 0, 1])


def test_spec_tolerance_above_1e3_is_refused():
    AllocationSpec.build(9, 4, tol=1e-3)
    with pytest.raises(InputError, match="tol"):
        AllocationSpec.build(9, 4, tol=5e-3)


def _kkt(M, b, w, ref):
    """The equality-constrained weighted minimum: [[W^2, M^T], [M, 0]] [f, mu] = [W^2 ref, b]."""
    n, m = M.shape
    K = np.zeros((m + n, m + n))
    K[:m, :m] = np.diag(w * w)
    K[:m, m:] = M.T
    K[m:, :m] = M
    return np.linalg.solve(K, np.concatenate([w * w * ref, b]))[:m]


def test_a_solver_answer_that_misses_m_f_equals_b_is_not_trusted():
    """Allocator.solve re-checks ``||M f - b|| <= tol (1 + ||b||)`` and falls back."""
    rng = np.random.default_rng(3)
    M, b = rng.standard_normal((2, 4)), rng.standard_normal(2)
    exact = _kkt(M, b, np.ones(4), np.zeros(4))

    class Sloppy(Allocator):
        name = "sloppy"

        def _solve(self, M, b, f_min, f_max, f_ref):
            # off by 1e-7 along the row space: residual ~1e-7, well above tol = 1e-9
            return exact + 1e-7 * M[0] / np.linalg.norm(M[0]), OPTIMAL, 1, None

    res = Sloppy(AllocationSpec.build(4, 2)).solve(M, b, -1e3, 1e3)
    assert res.status == "fallback"
    assert res.residual <= 1e-9 * (1 + np.linalg.norm(b))
    np.testing.assert_allclose(res.f, exact, rtol=0, atol=1e-9)


def test_weighted_closed_form_allocator_uses_w_squared():
    """f = f_ref + W^-2 M^T (M W^-2 M^T)^-1 (b - M f_ref): the KKT solution, bounds inactive."""
    rng = np.random.default_rng(4)
    M, b = rng.standard_normal((2, 4)), rng.standard_normal(2)
    w, ref = np.array([1.0, 2.0, 0.5, 3.0]), np.array([0.3, -0.2, 0.1, 0.4])
    res = make_allocator(4, 2, "closed_form", weights=w, f_ref=ref).solve(M, b, -1e6, 1e6)
    assert res.status == "closed_form"
    np.testing.assert_allclose(res.f, _kkt(M, b, w, ref), rtol=1e-12, atol=1e-12)


def test_weighted_closed_form_refuses_a_numerically_singular_system():
    """Rows parallel up to round-off: np.linalg.solve does not raise, the residual check must."""
    row = np.array([0.1, 0.2, 0.3, 0.7])
    M = np.vstack([row, 7.0 * row])
    assert np.linalg.matrix_rank(M) == 1
    # b not in the range of M: no f meets M f = b
    assert weighted_closed_form(M, np.array([1.0, 0.0]), np.ones(4), np.zeros(4)) is None


def test_improved_closed_form_fixes_the_largest_violation_each_solve():
    """sum f = 6, f <= (0.5, 1, 10): f = (2, 2, 2) -> fix f0 = 0.5 (violation 1.5) ->
    (2.75, 2.75) -> fix f1 = 1 -> f2 = 4.5, the last of m - n + 1 = 3 solves."""
    alloc = make_allocator(3, 1, "improved_closed_form")
    res = alloc.solve([[1.0, 1.0, 1.0]], [6.0], 0.0, [0.5, 1.0, 10.0])
    assert res.status == "closed_form" and res.iterations == 3
    np.testing.assert_allclose(res.f, [0.5, 1.0, 4.5], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(res.active, [1, 1, 0])


def test_improved_closed_form_fixes_a_force_below_its_minimum_at_the_minimum():
    """sum f = -3, f >= (-0.5, -10, -10): f = -1 each -> fix f0 = -0.5 -> (-1.25, -1.25)."""
    alloc = make_allocator(3, 1, "improved_closed_form")
    res = alloc.solve([[1.0, 1.0, 1.0]], [-3.0], [-0.5, -10.0, -10.0], 10.0)
    assert res.status == "closed_form" and res.iterations == 2
    np.testing.assert_allclose(res.f, [-0.5, -1.25, -1.25], rtol=0, atol=1e-12)


def test_a_problem_feasible_only_at_a_corner_of_the_box_is_not_called_infeasible():
    """f1 + 2 f2 = 3 with 0 <= f <= 1 holds at f = (1, 1) only: feasible, on the edge."""
    M, b = np.array([[1.0, 2.0]]), np.array([3.0])
    f, active = np.empty(2), np.empty(2, dtype=np.int8)
    code = dual_newton_tick(M, b, np.ones(2), np.zeros(2), np.zeros(2), np.ones(2), f, active, 15)
    assert code >= 0
    np.testing.assert_allclose(f, [1.0, 1.0], rtol=0, atol=1e-12)
    assert feasibility_batch(M[None], b[None], 0.0, 1.0).tolist() == [True]
    batch = make_allocator(2, 1, "batched").solve_batch(M[None], b[None], 0.0, 1.0)
    assert batch.status.tolist() == ["optimal"]


def test_exact_line_search_walks_past_the_last_breakpoint():
    """phi'(t) = 0.5 - (clip(-2 + t, -1, hi) + 1): flat to t = 1, then slope -1: root 1.5."""
    times, deltas = np.empty(2), np.empty(2)
    for hi in (np.inf, 5.0):  # no breakpoint after the root / one after it
        args = (np.array([-2.0]), np.array([1.0]), np.array([-1.0]), np.array([hi]))
        t = _exact_line_search(*(a[None] for a in args), np.array([0.5]))
        assert t[0] == pytest.approx(1.5, rel=1e-14)
        assert _line_search(*args, 0.5, times, deltas) == pytest.approx(1.5, rel=1e-14)


def test_least_squares_fallback_breaks_ties_by_the_objective_exactly():
    """f0 + f1 = 1 and f2 = 10 with 0 <= f <= 5: f2 = 5 (residual 5) and, among the ties,
    min f0^2 + 4 f1^2 on f0 + f1 = 1: f = (0.8, 0.2)."""
    M = np.array([[1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    b = np.array([1.0, 10.0])
    w = np.array([1.0, 2.0, 1.0])
    want = [0.8, 0.2, 5.0]
    f, _ = bounded_least_squares(M, b, np.zeros(3), np.full(3, 5.0), w, np.zeros(3))
    np.testing.assert_allclose(f, want, rtol=0, atol=1e-12)
    for solver in ("fast", "batched"):
        res = make_allocator(3, 2, solver, weights=w).solve(M, b, 0.0, 5.0)
        assert res.status == "infeasible" and res.residual == pytest.approx(5.0, rel=1e-12)
        np.testing.assert_allclose(res.f, want, rtol=0, atol=1e-12)


def test_a_pose_must_hold_every_wrench_to_be_feasible():
    """WireX at its centre holds w = 0 (5.5 N each) but not a 1 MN push with f <= 10 N."""
    top = np.array([[-2.0, 1.5, 2.0], [2.0, 1.5, 2.0], [2.0, -1.5, 2.0], [-2.0, -1.5, 2.0]])
    plate = np.array(
        [[-0.06, 0.06, 0.0], [0.06, 0.06, 0.0], [0.06, -0.06, 0.0], [-0.06, -0.06, 0.0]]
    )
    robot = CableRobot(np.vstack([top, top * [1.0, 1.0, 0.0]]), np.vstack([plate, plate]))
    centre, zero, huge = np.array([[0.0, 0.0, 1.0]]), np.zeros(6), np.array([0, 0, -1e6, 0, 0, 0])
    assert wrench_feasible_poses(robot, centre, np.eye(3), zero, 1.0, 10.0).tolist() == [True]
    both = np.vstack([zero, huge])
    assert wrench_feasible_poses(robot, centre, np.eye(3), both, 1.0, 10.0).tolist() == [False]


# --------------------------------------------------------------------------- tasks


def test_minimum_jerk_ends_exactly_at_the_target():
    """q0 + (q1 - q0) rounds to -1.9889999999999999 here; the move must end at q1 itself."""
    q, qd, qdd = minimum_jerk([1.263], [-1.989], 2.0, [2.0, 3.0])
    np.testing.assert_array_equal(q, [[-1.989], [-1.989]])
    np.testing.assert_array_equal(qd, 0.0)
    np.testing.assert_array_equal(qdd, 0.0)


def test_overlapping_moves_are_refused_even_by_a_little():
    home = np.zeros(2)
    with pytest.raises(InputError, match="before the previous move ends"):
        Task("x", 9.0, home, (Move(0.0, 2.0, np.ones(2)), Move(1.9, 1.0, home)))


def test_random_tasks_keep_the_minimum_holds_and_give_the_final_hold_its_share():
    """Each move follows a hold >= MIN_HOLD, the task ends with one >= MIN_FINAL_HOLD, and
    the spare time is split flat (Dirichlet) among the n + 1 holds: the final hold gets on
    average 1 / (n + 1) of it."""
    lower, upper = np.array([-1.0, -0.5]), np.array([1.0, 0.5])
    n_moves, duration, shares = 3, 20.0, []
    for seed in range(200):
        task = random_reach_task(seed, lower, upper, duration, n_moves, home=np.zeros(2))
        clock = 0.0
        for move in task.moves:
            assert move.start - clock >= MIN_HOLD - 1e-12
            clock = move.end
        final = duration - clock
        assert final >= MIN_FINAL_HOLD - 1e-9
        spare = duration - sum(mv.duration for mv in task.moves) - n_moves * MIN_HOLD
        spare -= MIN_FINAL_HOLD
        shares.append((final - MIN_FINAL_HOLD) / spare)
    assert abs(np.mean(shares) - 1 / (n_moves + 1)) < 0.06


# --------------------------------------------------------------------------- model


def test_a_hinge_range_a_little_wider_than_a_turn_is_refused(tmp_path: Path):
    elbow = '<joint name="elbow" type="hinge" axis="0 1 0" range="-2.3 0.05"/>'
    wide = '<joint name="elbow" type="hinge" axis="0 1 0" range="-3.2 3.2"/>'
    text = ARM_MODEL_PATH.read_text()
    assert elbow in text
    path = tmp_path / "wide.xml"
    path.write_text(text.replace(elbow, wide))
    with pytest.raises(ModelError, match="wider than a turn"):
        load_robot(path)
