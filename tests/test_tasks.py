"""msarm.tasks: minimum-jerk references, the Table I tasks and seeded random reaches."""

from __future__ import annotations

import numpy as np
import pytest

from msarm.errors import InputError
from msarm.tasks import HOME_POSTURE, Move, Task, get_task, list_tasks, minimum_jerk
from msarm.tasks.registry import (
    TABLE1_DURATION,
    TABLE1_MOVE_TIME,
    TABLE1_TARGETS,
    TABLE1_WAIT,
)
from msarm.tasks.trajectories import MIN_FINAL_HOLD, MOVE_TIME_RANGE, random_reach_task

Q0 = np.array([0.1, -0.3, 0.0])
Q1 = np.array([0.5, 0.2, -1.0])


def test_minimum_jerk_boundary_values_and_midpoint():
    T = 2.0
    q, qd, qdd = minimum_jerk(Q0, Q1, T, np.array([0.0, T / 2, T]))
    np.testing.assert_allclose(q[0], Q0, atol=0)
    np.testing.assert_array_equal(q[2], Q1)
    np.testing.assert_allclose(q[1], (Q0 + Q1) / 2, atol=1e-15)
    np.testing.assert_array_equal(qd[[0, 2]], 0.0)
    np.testing.assert_allclose(qdd[[0, 2]], 0.0, atol=1e-14)
    # Peak speed of the quintic: 15/8 d / T at the midpoint; zero acceleration there.
    np.testing.assert_allclose(qd[1], 1.875 * (Q1 - Q0) / T, rtol=1e-14)
    np.testing.assert_allclose(qdd[1], 0.0, atol=1e-14)


def test_minimum_jerk_matches_finite_differences():
    T = 1.7
    t = np.linspace(0.01, T - 0.01, 200)
    h = 1e-6
    q, qd, qdd = minimum_jerk(Q0, Q1, T, t)
    qp, qdp, _ = minimum_jerk(Q0, Q1, T, t + h)
    qm, qdm, _ = minimum_jerk(Q0, Q1, T, t - h)
    np.testing.assert_allclose(qd, (qp - qm) / (2 * h), atol=1e-8)
    np.testing.assert_allclose(qdd, (qdp - qdm) / (2 * h), atol=1e-7)
    assert q.shape == qd.shape == qdd.shape == (200, 3)


def test_minimum_jerk_holds_outside_the_move_and_accepts_scalar_t():
    q, qd, qdd = minimum_jerk(Q0, Q1, 1.0, np.array([-1.0, 1.0, 5.0]))
    np.testing.assert_array_equal(q[0], Q0)
    np.testing.assert_array_equal(q[1:], [Q1, Q1])
    np.testing.assert_array_equal(qd[[0, 2]], 0.0)
    np.testing.assert_array_equal(qdd[[0, 2]], 0.0)
    qs, qds, qdds = minimum_jerk(Q0, Q1, 1.0, 0.3)
    assert qs.shape == qds.shape == qdds.shape == (3,)
    np.testing.assert_array_equal(qs, minimum_jerk(Q0, Q1, 1.0, [0.3])[0][0])


def test_minimum_jerk_bad_input():
    with pytest.raises(InputError, match="q1 must have shape"):
        minimum_jerk(Q0, Q1[:2], 1.0, 0.0)
    with pytest.raises(InputError, match="duration"):
        minimum_jerk(Q0, Q1, 0.0, 0.0)
    with pytest.raises(InputError, match="t has NaN"):
        minimum_jerk(Q0, Q1, 1.0, [0.0, np.nan])


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_table1_tasks_reach_and_hold_their_targets(k, arm):
    task = get_task(f"table1-{k}", arm)
    assert task.name == f"table1-{k}" and task.duration == TABLE1_DURATION == 20.0
    np.testing.assert_array_equal(task.home, HOME_POSTURE)
    np.testing.assert_array_equal(task.target, TABLE1_TARGETS[k - 1])
    t = np.linspace(0.0, task.duration, 2001)
    q, qd, qdd = task.reference(t)
    waiting = t <= TABLE1_WAIT
    holding = t >= TABLE1_WAIT + TABLE1_MOVE_TIME
    np.testing.assert_array_equal(q[waiting], np.broadcast_to(HOME_POSTURE, q[waiting].shape))
    np.testing.assert_array_equal(q[holding], np.broadcast_to(task.target, q[holding].shape))
    assert np.all(qd[waiting | holding] == 0) and np.all(qdd[waiting | holding] == 0)
    moving = ~(waiting | holding)
    assert np.all(np.abs(qd[moving]).sum(axis=1) > 0)


def test_table1_targets_are_paper_003_table1():
    # paper 003, Table I ("Target expectation of joint angle for the second experiment"):
    # one row per target, columns Joint1..Joint4 [rad], typed from the paper
    paper = np.array(
        [
            [0.0, 0.4363, -0.5236, -1.2217],
            [0.0, 0.3491, -0.6109, -0.9599],
            [0.0, 0.5236, -0.4363, -0.8727],
            [-0.0873, 0.3491, -0.4363, -0.6109],
        ]
    )
    assert TABLE1_TARGETS.shape == (4, 4)
    np.testing.assert_array_equal(TABLE1_TARGETS, paper)


def test_task_reference_is_continuous_across_moves():
    task = random_reach_task(11, -np.ones(4), np.ones(4))
    t = np.linspace(0, task.duration, 20001)
    q, qd, _ = task.reference(t)
    dt = t[1] - t[0]
    assert np.max(np.abs(np.diff(q, axis=0))) < 2.0 * dt * np.max(np.abs(qd)) + 1e-12
    for k, move in enumerate(task.moves):
        previous = task.home if k == 0 else task.moves[k - 1].target
        q_at, qd_at, _ = task.reference(move.start)
        np.testing.assert_array_equal(q_at, previous)
        np.testing.assert_array_equal(qd_at, 0.0)


def test_random_tasks_are_reproducible_and_within_limits(arm):
    lower, upper = arm.joint_lower, arm.joint_upper
    a = get_task("random-42", arm)
    b = random_reach_task(42, lower, upper)
    assert a == b and a.name == "random-42"
    t = np.linspace(0, a.duration, 5001)
    for ref_a, ref_b in zip(a.reference(t), b.reference(t), strict=True):
        assert ref_a.tobytes() == ref_b.tobytes()
    assert get_task("random-43", arm) != a
    width = upper - lower
    for seed in range(30):
        task = random_reach_task(seed, lower, upper)
        targets = np.array([m.target for m in task.moves])
        assert targets.shape == (3, 4)
        assert np.all(targets >= lower + 0.15 * width) and np.all(targets <= upper - 0.15 * width)
        durations = np.array([m.duration for m in task.moves])
        assert np.all((durations >= MOVE_TIME_RANGE[0]) & (durations <= MOVE_TIME_RANGE[1]))
        starts = [m.start for m in task.moves]
        ends = [m.end for m in task.moves]
        assert starts[0] > 0 and all(s > e for s, e in zip(starts[1:], ends[:-1], strict=True))
        assert task.duration - ends[-1] >= MIN_FINAL_HOLD - 1e-9
        q, _, _ = task.reference(np.linspace(0, task.duration, 2001))
        assert np.all(q >= lower) and np.all(q <= upper)
        np.testing.assert_array_equal(task.home, HOME_POSTURE)


def test_random_task_bad_input():
    with pytest.raises(InputError, match="too short"):
        random_reach_task(1, -np.ones(4), np.ones(4), duration=8.0)
    with pytest.raises(InputError, match="seed"):
        random_reach_task(-1, -np.ones(4), np.ones(4))
    with pytest.raises(InputError, match="margin"):
        random_reach_task(1, -np.ones(4), np.ones(4), margin=0.5)
    with pytest.raises(InputError, match="upper must exceed lower"):
        random_reach_task(1, np.ones(4), np.ones(4))


def test_unknown_task_lists_the_valid_ones(arm):
    with pytest.raises(InputError) as info:
        get_task("table1-5", arm)
    msg = str(info.value)
    assert "'table1-5'" in msg
    for name in list_tasks():
        assert name in msg
    assert set(list_tasks()) == {"table1-1", "table1-2", "table1-3", "table1-4", "random-<seed>"}
    with pytest.raises(InputError, match="needs the robot model"):
        get_task("random-3")
    with pytest.raises(InputError, match="valid tasks"):
        get_task("random-x", arm)
    with pytest.raises(InputError, match="unknown task 'random-\u0663'"):  # Arabic-Indic 3
        get_task("random-\u0663", arm)  # int() reads it: the answer was "write random-3"


@pytest.mark.parametrize(
    ("name", "canonical"), [("table1-01", "table1-1"), ("random-007", "random-7")]
)
def test_one_task_one_name(arm, name, canonical):
    """A number with leading zeros is refused (runs are stored by task name)."""
    with pytest.raises(InputError, match=f"{name!r}: write .* without leading zeros, {canonical}"):
        get_task(name, arm)


def test_task_checks_its_moves():
    home = np.zeros(2)
    with pytest.raises(InputError, match="before the previous move ends"):
        Task("x", 5.0, home, (Move(0.0, 2.0, np.ones(2)), Move(1.0, 1.0, home)))
    with pytest.raises(InputError, match="after the task's"):
        Task("x", 1.0, home, (Move(0.0, 2.0, np.ones(2)),))
    with pytest.raises(InputError, match="shape"):
        Task("x", 5.0, home, (Move(0.0, 2.0, np.ones(3)),))
    still = Task("still", 1.0, home, ())
    q, qd, _ = still.reference([0.0, 2.0])
    np.testing.assert_array_equal(q, np.zeros((2, 2)))
    np.testing.assert_array_equal(still.target, home)


def test_task_outside_model_limits_is_refused(arm, monkeypatch):
    import msarm.tasks.registry as registry

    targets = TABLE1_TARGETS.copy()
    targets[0, 3] = 1.0  # elbow beyond its upper limit
    monkeypatch.setattr(registry, "TABLE1_TARGETS", targets)
    with pytest.raises(InputError, match="joint 'elbow'"):
        get_task("table1-1", arm)


def test_a_random_task_refuses_a_home_outside_the_range_and_strings():
    from msarm.errors import InputError
    from msarm.tasks.trajectories import minimum_jerk, random_reach_task

    lower, upper = -np.ones(4), np.ones(4)
    with pytest.raises(InputError, match=r"home must lie in the joint range: joint 0 is 2 rad"):
        random_reach_task(1, lower, upper, home=np.full(4, 2.0))
    with pytest.raises(InputError, match=r"duration must be a finite time"):
        random_reach_task(1, lower, upper, duration=float("nan"))
    with pytest.raises(InputError, match=r"q0 must be numbers"):
        minimum_jerk(["a"] * 4, np.zeros(4), 1.0, 0.5)
