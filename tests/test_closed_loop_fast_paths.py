"""The closed loop's fast paths give the same numbers, to the bit, as the plain formulas."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from msarm.control import MuscleSpaceController
from msarm.control.kernels import activation_and_reach, filter_and_pid, force_bounds
from msarm.errors import InputError
from msarm.plant import DEFAULT_PLANT, ArmPlant, Effect, SimulationDivergedError
from msarm.plant.config import SensorNoiseConfig
from msarm.plant.effects import SensorNoise, SensorReadings

POSTURE = np.array([0.2, 0.4, -0.3, -0.9])


def _bits(value: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(value, dtype=np.float64).view(np.uint64)


def test_filter_and_pid_matches_the_numpy_formulas_bit_for_bit():
    rng = np.random.default_rng(3)
    n, period, alpha = 4, 0.004, 0.43
    kp, ki, kd = rng.uniform(1, 60, n), rng.uniform(1, 40, n), rng.uniform(0.5, 4, n)
    bound = 3.0 / ki
    q_prev, qdot, integral = rng.normal(size=n), rng.normal(size=n), rng.normal(size=n) * bound
    for _ in range(200):
        q, q_ref, qd_ref = rng.normal(size=n), rng.normal(size=n), rng.normal(size=n)
        tau_id = rng.normal(size=n)
        # the formulas the kernel replaces, as the controller wrote them in NumPy
        want_qdot = qdot + alpha * ((q - q_prev) / period - qdot)
        error = q_ref - q
        want_integral = np.clip(integral + error * period, -bound, bound)
        want_tau = tau_id + kp * error + ki * want_integral
        want_tau += kd * (qd_ref - want_qdot)
        tau = tau_id.copy()
        filter_and_pid(
            q, q_ref, qd_ref, period, alpha, kp, ki, kd, bound, q_prev, qdot, integral, tau
        )
        for got, want in [(qdot, want_qdot), (integral, want_integral), (tau, want_tau)]:
            np.testing.assert_array_equal(_bits(got), _bits(want))
        np.testing.assert_array_equal(q_prev, q)


def test_force_and_activation_kernels_match_numpy_bit_for_bit():
    rng = np.random.default_rng(4)
    m = 9
    for _ in range(200):
        active, passive = rng.uniform(1, 300, m), rng.uniform(0, 20, m) * (rng.random(m) < 0.5)
        f_min, f_max = np.empty(m), np.empty(m)
        force_bounds(active, passive, 5.0, f_min, f_max)
        want_min = np.maximum(passive, 5.0)
        np.testing.assert_array_equal(_bits(f_min), _bits(want_min))
        np.testing.assert_array_equal(_bits(f_max), _bits(np.maximum(passive + active, want_min)))
        force = rng.uniform(-10, 350, m)
        force[:2] = passive[:2]  # at the passive force: activation zero
        activation, reachable = np.empty(m), np.empty(m, dtype=bool)
        activation_and_reach(force, active, passive, activation, reachable)
        want = np.clip((force - passive) / active, 0.0, 1.0)
        np.testing.assert_array_equal(_bits(activation), _bits(want))
        want_reach = (force >= passive - 1e-9) & (force <= passive + active + 1e-9)
        np.testing.assert_array_equal(reachable, want_reach)


def test_kernels_keep_nan_like_numpy():
    activation, reachable = np.empty(1), np.empty(1, dtype=bool)
    activation_and_reach(np.array([np.nan]), np.ones(1), np.zeros(1), activation, reachable)
    assert np.isnan(activation[0]) and not reachable[0]
    f_min, f_max = np.empty(1), np.empty(1)
    force_bounds(np.ones(1), np.array([np.nan]), 5.0, f_min, f_max)
    assert np.isnan(f_min[0]) and np.isnan(f_max[0])


def test_sensor_noise_draws_the_stream_of_one_draw_per_channel():
    """One draw for all channels equals four draws in the order q, angle, torque, tension."""
    config = SensorNoiseConfig(tension_bias=0.7)
    effect = SensorNoise(config)
    n, m = 4, 9
    readings = SensorReadings(
        t=0.5,
        q=np.linspace(-1, 1, n),
        motor_angle=np.linspace(0, 2, m),
        motor_torque=np.linspace(-0.3, 0.3, m),
        tension_motor=np.linspace(5, 80, m),
    )
    got = effect.sense(readings, np.random.default_rng(11))
    rng = np.random.default_rng(11)
    want = {
        "q": readings.q + config.joint_noise * rng.standard_normal(n),
        "motor_angle": readings.motor_angle + config.motor_angle_noise * rng.standard_normal(m),
        "motor_torque": readings.motor_torque + config.torque_noise * rng.standard_normal(m),
        "tension_motor": readings.tension_motor
        + config.tension_bias
        + config.tension_noise * rng.standard_normal(m),
    }
    assert got.t == readings.t
    for key, value in want.items():
        np.testing.assert_array_equal(_bits(getattr(got, key)), _bits(value))


def test_record_ground_truth_writes_what_ground_truth_returns(arm):
    plant = ArmPlant(arm, DEFAULT_PLANT, seed=2)
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 25.0))
    plant.command(np.full(arm.n_cables, 40.0))
    plant.step(8)
    truth = plant.ground_truth()
    out = {key: np.full(value.shape, np.nan) for key, value in truth.items()}
    plant.record_ground_truth(out)
    for key, value in truth.items():
        np.testing.assert_array_equal(_bits(out[key]), _bits(value), err_msg=key)


def test_plant_steps_the_same_one_step_at_a_time_or_many(arm):
    plants = [ArmPlant(arm, replace(DEFAULT_PLANT, name="t"), seed=0) for _ in range(2)]
    for plant in plants:
        plant.reset(POSTURE, tensions=np.full(arm.n_cables, 25.0))
        plant.command(np.full(arm.n_cables, 35.0))
    plants[0].step(12)
    for _ in range(12):
        plants[1].step(1)
    for key, value in plants[0].ground_truth().items():
        np.testing.assert_array_equal(value, plants[1].ground_truth()[key], err_msg=key)


class _NoWinchTorque(Effect):
    """A user effect that adds nothing: it only makes the plant step in its Python loop."""

    name = "nothing"

    def winch_torque(self, state):
        return np.zeros(state.lengths.shape), np.zeros(state.lengths.shape)


def test_compiled_step_loop_gives_the_python_loops_bits(arm):
    compiled = ArmPlant(arm, DEFAULT_PLANT, seed=0)
    python = ArmPlant(arm, DEFAULT_PLANT, seed=0, extra_effects=[_NoWinchTorque()])
    assert compiled.compiled and not python.compiled
    rng = np.random.default_rng(5)
    for plant in (compiled, python):
        plant.reset(POSTURE, tensions=np.full(arm.n_cables, 25.0))
    for _ in range(150):  # 0.6 s of changing commands, 4 plant steps each
        command = rng.uniform(10.0, 80.0, arm.n_cables)
        for plant in (compiled, python):
            plant.command(command)
            plant.step(4)
    assert compiled.time == python.time
    want = python.ground_truth()
    for key, value in compiled.ground_truth().items():
        np.testing.assert_array_equal(_bits(value), _bits(want[key]), err_msg=key)
    np.testing.assert_array_equal(_bits(compiled.motor_torque), _bits(python.motor_torque))


def _push_the_hand_infinitely(plant):
    plant.mj_data.xfrc_applied[-1, 0] = np.inf


def _nan_joint_speed(plant):
    plant.mj_data.qvel[1] = np.nan


@pytest.mark.parametrize("extra", [[], [_NoWinchTorque()]], ids=["compiled", "python"])
@pytest.mark.parametrize(
    "poison, found",
    [(_push_the_hand_infinitely, "acceleration at DOF 0"), (_nan_joint_speed, "velocity at DOF 1")],
    ids=["acceleration", "velocity"],
)
def test_both_step_loops_stop_on_divergence_with_time_and_state(arm, extra, poison, found):
    """MuJoCo resets its state on a bad one; the plant still stops, naming the period's end."""
    plant = ArmPlant(arm, DEFAULT_PLANT, seed=0, extra_effects=extra)
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 25.0))
    plant.step(4)
    poison(plant)
    before = {"q": plant.mj_data.qpos.tolist(), "qdot": plant.mj_data.qvel.tolist()}
    with pytest.raises(SimulationDivergedError, match=r"diverged at t = 0.0080 s") as caught:
        plant.step(4)
    assert found in str(caught.value) and "reset its state" in str(caught.value)
    assert caught.value.time == pytest.approx(0.008)
    assert set(caught.value.state) == {"q", "qdot", "winch_angle"}
    # the state named is the one the failed period started from, not MuJoCo's reset one
    assert "at the start of that period" in str(caught.value)
    np.testing.assert_array_equal(caught.value.state["q"], before["q"])
    np.testing.assert_array_equal(caught.value.state["qdot"], before["qdot"])
    assert not np.allclose(plant.mj_data.qpos, before["q"])  # MuJoCo did reset


def test_controller_refuses_references_of_the_wrong_shape(arm):
    controller = MuscleSpaceController(arm)
    plant = ArmPlant(arm, DEFAULT_PLANT, seed=0)
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 25.0))
    controller.reset(POSTURE)
    readings = plant.sense()
    zeros = np.zeros(arm.n_joints)
    with pytest.raises(InputError, match="q_ref"):
        controller.update(readings, POSTURE[:3], zeros, zeros)
    with pytest.raises(InputError, match=r"readings.q"):
        controller.update(replace(readings, q=np.zeros(7)), POSTURE, zeros, zeros)
    out = controller.update(readings, list(POSTURE), [0.0] * 4, zeros)  # lists are fine
    assert out.tension_command.shape == (arm.n_cables,)
