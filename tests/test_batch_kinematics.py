"""Cable kinematics of many postures (compiled) against the posture-by-posture reference."""

from __future__ import annotations

import numpy as np
import pytest

from msarm.errors import InputError
from msarm.mujoco_c import function_addresses
from msarm.muscle.batch_kinematics import cable_kinematics_batch


def _postures(arm, count, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(arm.joint_lower, arm.joint_upper, size=(count, arm.n_joints))


def test_compiled_loop_is_found():
    # the compiled loop is the one the diagnosis runs: it must not silently fall back here
    assert function_addresses("mj_kinematics", "mj_comPos", "mj_tendon") is not None


def test_compiled_equals_the_python_reference(arm):
    q = _postures(arm, 300, seed=3)
    fast = cable_kinematics_batch(arm, q)
    slow = cable_kinematics_batch(arm, q, compiled=False)
    # the same MuJoCo functions on the same data: lengths and Jacobians bit for bit
    np.testing.assert_array_equal(fast.lengths, slow.lengths)
    np.testing.assert_array_equal(fast.jacobian, slow.jacobian)
    # wrap angles: the same formula, summed in another order (acos is steep near 0)
    np.testing.assert_allclose(fast.wrap_angles, slow.wrap_angles, rtol=0, atol=1e-10)
    assert np.all(fast.wrap_angles > 0)


def test_matches_the_single_posture_geometry(arm):
    q = _postures(arm, 20, seed=5)
    batch = cable_kinematics_batch(arm, q)
    for k in range(len(q)):
        one = arm.geometry(q[k])
        np.testing.assert_array_equal(batch.lengths[k], one.lengths)
        np.testing.assert_array_equal(batch.jacobian[k], one.jacobian)
        np.testing.assert_allclose(batch.wrap_angles[k], one.wrap_angles, atol=1e-10)


def test_wrap_angles_only_when_asked(arm):
    q = _postures(arm, 5, seed=1)
    without = cable_kinematics_batch(arm, q, with_wrap_angles=False)
    assert np.all(np.isnan(without.wrap_angles))
    np.testing.assert_array_equal(without.jacobian, cable_kinematics_batch(arm, q).jacobian)


def test_bad_postures_are_refused(arm):
    with pytest.raises(InputError, match=r"shape \(T, 4\)"):
        cable_kinematics_batch(arm, np.zeros(4))
    q = np.zeros((3, 4))
    q[2, 1] = np.nan
    with pytest.raises(InputError, match=r"finite.*\(2, 1\)"):
        cable_kinematics_batch(arm, q)


def test_jacobian_at_one_posture_after_another(arm):
    from msarm.muscle.batch_kinematics import JacobianAt

    jacobian_at = JacobianAt(arm, arm.create_data())
    for q in _postures(arm, 30, seed=9):
        np.testing.assert_array_equal(jacobian_at(q), arm.geometry(q).jacobian)
    # without MuJoCo's library the Python functions give the same
    fallback = JacobianAt(arm, arm.create_data())
    fallback._args = None
    q = _postures(arm, 1, seed=2)[0]
    np.testing.assert_array_equal(fallback(q), jacobian_at(q))
    # several postures at once: the same bits, compiled or not
    many = _postures(arm, 7, seed=5)
    expected = np.stack([arm.geometry(p).jacobian for p in many])
    np.testing.assert_array_equal(jacobian_at.many(many), expected)
    np.testing.assert_array_equal(fallback.many(many), expected)
    out = np.empty_like(expected)
    assert jacobian_at.many(many, out) is out
