"""CDPR geometry: inverse kinematics and structure matrix (paper 000, eq. 1-2)."""

import doctest
import warnings

import numpy as np
import pytest

from msarm.cdpr import CableRobot, kinematics
from msarm.errors import InputError

WIREX_LENGTH = 2.6148040079516472


def wirex() -> CableRobot:
    top = np.array([[-2.0, 1.5, 2.0], [2.0, 1.5, 2.0], [2.0, -1.5, 2.0], [-2.0, -1.5, 2.0]])
    bottom = top * [1.0, 1.0, 0.0]
    plate = np.array(
        [[-0.06, 0.06, 0.0], [0.06, 0.06, 0.0], [0.06, -0.06, 0.0], [-0.06, -0.06, 0.0]]
    )
    return CableRobot(np.vstack([top, bottom]), np.vstack([plate, plate]))


def rot(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [k for k in range(3) if k != axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def test_wirex_cable_lengths():
    robot = wirex()
    kin = robot.inverse_kinematics(np.array([0.0, 0.0, 1.0]), np.eye(3))
    np.testing.assert_allclose(kin.lengths, WIREX_LENGTH, rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(kin.unit_vectors, axis=1), 1.0, atol=1e-15)
    # u_1 points from the platform anchor (-0.06, 0.06, 1) to the frame anchor (-2, 1.5, 2).
    np.testing.assert_allclose(
        kin.unit_vectors[0], np.array([-1.94, 1.44, 1.0]) / WIREX_LENGTH, atol=1e-15
    )


def test_structure_matrix_columns():
    robot = wirex()
    R = rot(2, 0.3) @ rot(0, -0.2)
    r = np.array([0.3, -0.2, 0.9])
    At = robot.structure_matrix(r, R)
    assert At.shape == (6, 8)
    kin = robot.inverse_kinematics(r, R)
    for i in range(8):
        u = kin.unit_vectors[i]
        np.testing.assert_allclose(At[:3, i], u, atol=1e-15)
        np.testing.assert_allclose(
            At[3:, i], np.cross(R @ robot.platform_anchors[i], u), atol=1e-15
        )


def test_structure_matrix_is_minus_length_jacobian():
    """Virtual work: a platform twist (v, w) changes the lengths by -A (v, w) (finite diff.)."""
    robot = wirex()
    r = np.array([0.4, 0.1, 1.2])
    R = rot(1, 0.25) @ rot(2, -0.4)
    At = robot.structure_matrix(r, R)
    h = 1e-6
    for k in range(3):
        dr = np.zeros(3)
        dr[k] = h
        dl = (robot.cable_lengths(r + dr, R) - robot.cable_lengths(r - dr, R)) / (2 * h)
        np.testing.assert_allclose(dl, -At[k], atol=1e-8)
        w = np.zeros(3)
        w[k] = h
        Rp = (np.eye(3) + skew(w) + skew(w) @ skew(w) / 2) @ R
        Rm = (np.eye(3) - skew(w) + skew(w) @ skew(w) / 2) @ R
        dl = (robot.cable_lengths(r, Rp) - robot.cable_lengths(r, Rm)) / (2 * h)
        np.testing.assert_allclose(dl, -At[3 + k], atol=1e-7)


def test_tension_pulls_towards_frame_anchor():
    """One cable alone: its force on the platform points at its frame anchor."""
    robot = CableRobot([[0.0, 0.0, 3.0]], [[0.0, 0.0, 0.0]])
    At = robot.structure_matrix(np.array([0.0, 0.0, 1.0]), np.eye(3))
    np.testing.assert_allclose(At[:, 0], [0, 0, 1, 0, 0, 0])


def test_batch_matches_single_poses():
    robot = wirex()
    rng = np.random.default_rng(3)
    r = rng.uniform(-0.5, 0.5, (5, 3)) + [0, 0, 1]
    R = np.stack([rot(k % 3, 0.1 * k) for k in range(5)])
    At = robot.structure_matrix(r, R)
    lengths = robot.cable_lengths(r, R)
    assert At.shape == (5, 6, 8) and lengths.shape == (5, 8)
    for k in range(5):
        np.testing.assert_array_equal(At[k], robot.structure_matrix(r[k], R[k]))
        np.testing.assert_array_equal(lengths[k], robot.cable_lengths(r[k], R[k]))
    shared = robot.structure_matrix(r, np.eye(3))
    np.testing.assert_array_equal(shared[2], robot.structure_matrix(r[2], np.eye(3)))


@pytest.mark.parametrize(
    ("frame", "platform", "match"),
    [
        (np.zeros((8, 2)), np.zeros((8, 3)), "frame_anchors"),
        (np.zeros((8, 3)), np.zeros((7, 3)), "same shape"),
        (np.full((8, 3), np.nan), np.zeros((8, 3)), "finite"),
        # complex (only numpy's ComplexWarning before), numeric strings (accepted before),
        # ragged rows (a bare numpy ValueError before)
        (np.ones((8, 3)) + 1j, np.zeros((8, 3)), r"frame_anchors .*\(m, 3\) of real .*complex"),
        (np.zeros((8, 3)), np.full((8, 3), "0.1"), r"platform_anchors .*real numbers.*strings"),
        ([[0.0, 0.0, 1.0], [0.0, 1.0]], np.zeros((2, 3)), r"frame_anchors .*different lengths"),
        (np.zeros((2, 3)), [[0.0, 0.0], [0.0, 1.0, 2.0]], r"platform_anchors .*\(m, 3\)"),
    ],
)
def test_bad_anchors(frame, platform, match):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an InputError, not a warning
        with pytest.raises(InputError, match=match):
            CableRobot(frame, platform)


def test_the_class_example_runs_and_holds_the_rotation():
    """The docstring's robot: A^T of rank 6 (the former 0.1 * corners platform had rank 3
    everywhere, its cables all meeting in one point)."""
    results = doctest.testmod(kinematics, extraglobs={"np": np})
    assert results.attempted >= 5 and results.failed == 0
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (0, 2)])
    old = CableRobot(corners, 0.1 * corners).structure_matrix(np.array([0.0, 0.0, 1.0]), np.eye(3))
    assert np.linalg.matrix_rank(old) == 3


def test_bad_poses():
    robot = wirex()
    with pytest.raises(InputError, match="r must have shape"):
        robot.structure_matrix(np.zeros(2), np.eye(3))
    with pytest.raises(InputError, match="R must have shape"):
        robot.structure_matrix(np.zeros(3), np.eye(2))
    with pytest.raises(InputError, match="rotation matrix"):
        robot.structure_matrix(np.zeros(3), 2 * np.eye(3))
    with pytest.raises(InputError, match="rotation matrix"):
        robot.structure_matrix(np.zeros(3), -np.eye(3))
    with pytest.raises(InputError, match="finite"):
        robot.structure_matrix(np.array([np.nan, 0, 0]), np.eye(3))
    one = CableRobot([[0.0, 0.0, 3.0]], [[0.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="zero length"):
        one.structure_matrix(np.array([0.0, 0.0, 3.0]), np.eye(3))
