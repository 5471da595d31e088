"""Wrench-feasible workspace helpers on the WireX-like robot."""

import numpy as np
import pytest

from msarm.allocation import is_wrench_feasible, wrench_feasible_grid, wrench_feasible_poses
from msarm.allocation.benchmark import wirex_robot
from msarm.allocation.workspace import feasibility_batch
from msarm.errors import InputError

GRAVITY = np.array([0.0, 0.0, -0.25 * 9.81, 0.0, 0.0, 0.0])


def test_centre_pose_is_feasible_and_a_huge_wrench_is_not():
    robot = wirex_robot()
    At = robot.structure_matrix(np.array([0.0, 0.0, 1.0]), np.eye(3))
    assert is_wrench_feasible(At, np.zeros(6), 1.0, 10.0)
    assert is_wrench_feasible(At, GRAVITY, 1.0, 10.0)
    assert not is_wrench_feasible(At, [0.0, 0.0, -500.0, 0, 0, 0], 1.0, 10.0)
    # A set of wrenches: feasible only if each vertex is.
    vertices = np.array([GRAVITY, GRAVITY + [0, 0, 0, 5.0, 0, 0]])
    assert not is_wrench_feasible(At, vertices, 1.0, 10.0)


def test_feasibility_matches_the_allocator():
    from msarm.allocation import make_allocator

    robot = wirex_robot()
    rng = np.random.default_rng(31)
    r = rng.uniform([-1.9, -1.4, 0.1], [1.9, 1.4, 1.9], size=(300, 3))
    flags = wrench_feasible_poses(robot, r, np.eye(3), GRAVITY, 1.0, 10.0)
    alloc = make_allocator(8, 6, "fast", f_ref="midpoint")
    At = robot.structure_matrix(r, np.eye(3))
    expected = [alloc.solve(At[k], -GRAVITY, 1.0, 10.0).feasible for k in range(300)]
    np.testing.assert_array_equal(flags, expected)
    assert 0 < flags.sum() < 300


def test_feasibility_holds_at_any_force_scale():
    """Bounds scaled by 1e6 (and the wrench with them) change nothing: the tolerance scales.

    With a tolerance on the wrench alone, the rounding of ``A^T f`` at 1e7 N exceeded it and
    feasible poses were refused (``msarm cdpr run --option f_max=1e9`` was refused).
    """
    robot = wirex_robot()
    rng = np.random.default_rng(32)
    r = rng.uniform([-1.9, -1.4, 0.1], [1.9, 1.4, 1.9], size=(200, 3))
    flags = wrench_feasible_poses(robot, r, np.eye(3), GRAVITY, 1.0, 10.0)
    assert 0 < flags.sum() < 200
    for scale in (1e3, 1e6, 1e9):
        scaled = wrench_feasible_poses(robot, r, np.eye(3), scale * GRAVITY, scale, 10.0 * scale)
        np.testing.assert_array_equal(scaled, flags)
    # a huge upper bound: the lower bound and the geometry still decide
    wide = wrench_feasible_poses(robot, r, np.eye(3), GRAVITY, 1.0, 1e12)
    assert wide[flags].all()
    outside = np.array([[0.0, 0.0, 2.5], [2.5, 0.0, 1.0]])  # above and beside the frame
    assert not wrench_feasible_poses(robot, outside, np.eye(3), GRAVITY, 1.0, 1e12).any()


def test_grid():
    robot = wirex_robot()
    x = np.linspace(-1.5, 1.5, 7)
    y = np.linspace(-1.0, 1.0, 5)
    z = np.array([0.5, 1.0, 1.5])
    grid = wrench_feasible_grid(robot, x, y, z, GRAVITY, 1.0, 10.0)
    assert grid.feasible.shape == (7, 5, 3)
    assert grid.positions.shape == (7, 5, 3, 3)
    assert grid.feasible[3, 2, 1]  # the centre
    assert 0.0 < grid.fraction < 1.0
    np.testing.assert_array_equal(grid.positions[2, 1, 0], [x[2], y[1], z[0]])
    assert grid.feasible_positions.shape == (int(grid.feasible.sum()), 3)
    # Symmetric robot, symmetric grid, vertical wrench: a symmetric feasible set.
    np.testing.assert_array_equal(grid.feasible, grid.feasible[::-1, ::-1, :])


def test_workspace_errors():
    robot = wirex_robot()
    with pytest.raises(InputError, match="wrenches must have shape"):
        wrench_feasible_poses(robot, np.zeros((2, 3)) + [0, 0, 1], np.eye(3), np.zeros(5), 1, 10)
    with pytest.raises(InputError, match="positions must have shape"):
        wrench_feasible_poses(robot, np.zeros(3), np.eye(3), GRAVITY, 1, 10)
    with pytest.raises(InputError, match="must be a non-empty finite 1-D array"):
        wrench_feasible_grid(robot, [], [0.0], [1.0], GRAVITY, 1, 10)
    with pytest.raises(InputError, match="f_min must be <= f_max"):
        feasibility_batch(np.ones((1, 1, 2)), np.ones((1, 1)), 2.0, 1.0)
