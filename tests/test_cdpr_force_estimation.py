"""Cable force without a load cell (msarm.cdpr.force_estimation) against the simulated robot.

The run: HC-e on the first 2.5 s of triangle-12 (0.5 s hold, 0.5 s speed ramp, 1.5 s at
4 m/min), default plant (Table 1 friction, sensor noise). Estimates use only the run's log
(motor torque, following error, encoder length; the speed is the length differentiated) and
are compared with the platform-side tension (``run.truth``), from 1.0 s (the cruise) unless
said otherwise. Tolerances are about twice what was measured
(``python examples/cdpr_force_estimation.py --seconds 2.5`` prints the same numbers):

- following error (pure-P drives, cables 0-3): max 0.054 N, RMS 0.012 N, mean 0.003 N;
- motor torque: RMS 0.47 N, mean 0.000 N; the floor is the torque sensor's noise,
  0.01 N m / r_D = 0.5 N;
- without tau_F (motor torque / r_D, or the FE's torque / r_D): mean +0.74 / +0.80 N, RMS 2.9 /
  3.0 N: the friction the paper models.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import trajectory_head

from msarm.cdpr import (
    WinchParameters,
    force_from_following_error,
    force_from_motor_current,
    force_from_motor_torque,
)
from msarm.cdpr.robot_model import load_cable_robot
from msarm.control.cdpr_controllers import DRIVE_P, make_cdpr_controller
from msarm.errors import InputError
from msarm.plant.cdpr_config import DEFAULT_CDPR_PLANT
from msarm.plant.cdpr_plant import CdprPlant
from msarm.tasks.cdpr_runner import run_cdpr
from msarm.tasks.cdpr_trajectories import get_cdpr_trajectory

SECONDS = 2.5
CRUISE = 1.0  # motion start 0.5 s + ramp 0.5 s


def _head(trajectory, seconds):
    return trajectory_head(trajectory, int(round(seconds / trajectory.dt)) + 1)


@pytest.fixture(scope="module")
def robot():
    return load_cable_robot()


@pytest.fixture(scope="module")
def log(robot):
    """Log arrays (n, m) of an HC-e run, the true tension and the P-drive cables."""
    trajectory = _head(get_cdpr_trajectory("triangle-12"), SECONDS)
    run = run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-e", trajectory)
    assert run.metrics.completed

    def columns(quantity, source):
        return np.column_stack([source[f"{quantity}.{c}"] for c in robot.cable_names])

    t = run.columns["t"]
    length = columns("cable_length", run.columns)
    modes = make_cdpr_controller("hc-e", robot).drive_mode
    return {
        "t": t,
        "v": np.gradient(length, t, axis=0),
        "torque": columns("motor_torque", run.columns),
        "fe": columns("following_error", run.columns),
        "truth": columns("tension", run.truth),
        "p_drive": [i for i, mode in enumerate(modes) if mode == DRIVE_P],
        "cruise": t >= CRUISE,
    }


def _stats(error):
    return np.abs(error).max(), np.sqrt(np.mean(error**2)), error.mean()


def test_following_error_gives_the_platform_tension_to_a_tenth_of_a_newton(log):
    p, cruise = log["p_drive"], log["cruise"]
    assert p == [0, 1, 2, 3]
    fe, v = log["fe"][:, p], log["v"][:, p]
    estimate = force_from_following_error(fe, v, velocity_feedforward=True)
    worst, rms, mean = _stats((estimate - log["truth"][:, p])[cruise])
    assert worst < 0.1 and rms < 0.025 and abs(mean) < 0.01, (worst, rms, mean)


def test_motor_torque_gives_the_tension_without_bias_within_the_sensor_noise(log):
    estimate = force_from_motor_torque(log["torque"], log["v"])
    worst, rms, mean = _stats((estimate - log["truth"])[log["cruise"]])
    noise = DEFAULT_CDPR_PLANT.noise.torque / DEFAULT_CDPR_PLANT.winch.drum_radius  # 0.5 N
    assert rms < 1.2 * noise and abs(mean) < 0.05 and worst < 6.0 * noise, (worst, rms, mean)


def test_without_the_friction_model_the_estimates_are_clearly_worse(log):
    """Paper 000's point: motor torque / r_D misses tau_F (Fig. 10, last column)."""
    cruise, p, truth = log["cruise"], log["p_drive"], log["truth"]
    for with_model, without in (
        (
            force_from_motor_torque(log["torque"], log["v"]),
            force_from_motor_torque(log["torque"], log["v"], friction_model=False),
        ),
        (
            force_from_following_error(log["fe"][:, p], log["v"][:, p], velocity_feedforward=True),
            force_from_following_error(
                log["fe"][:, p], log["v"][:, p], friction_model=False, velocity_feedforward=True
            ),
        ),
    ):
        cables = slice(None) if with_model.shape[1] == truth.shape[1] else p
        _, rms_with, mean_with = _stats((with_model - truth[:, cables])[cruise])
        _, rms_without, mean_without = _stats((without - truth[:, cables])[cruise])
        assert rms_without > 4.0 * rms_with, (rms_without, rms_with)
        assert mean_without > 0.5 > 10.0 * abs(mean_with), (mean_without, mean_with)


def test_the_current_path_is_the_torque_path_with_the_torque_constant(log):
    torque, v = log["torque"], log["v"]
    reference = force_from_motor_torque(torque, v)
    for k_t in (0.35, np.linspace(0.3, 0.4, torque.shape[1])):
        estimate = force_from_motor_current(torque / k_t, k_t, v)
        np.testing.assert_allclose(estimate, reference, rtol=0.0, atol=1e-12)
    same = force_from_motor_current(torque, 1.0, v, friction_model=False)
    np.testing.assert_array_equal(same, force_from_motor_torque(torque, v, friction_model=False))


def test_the_estimates_invert_the_set_values_of_hc_tau_and_hc_e(robot):
    """One copy of eq. 3 and 9: the controllers' targets map back to their desired forces."""
    trajectory = get_cdpr_trajectory("triangle-12")
    k = int(1.5 / trajectory.dt)
    for name, options in (
        ("hc-tau", {}),
        ("hc-tau", {"friction_model": False}),
        ("hc-e", {}),
        ("hc-e", {"velocity_feedforward": False}),
    ):
        ctrl = make_cdpr_controller(name, robot, **options)
        nominal = ctrl.nominal(
            trajectory.position[k], trajectory.velocity[k], trajectory.acceleration[k]
        )
        cables = np.arange(ctrl.m)
        target = ctrl.targets(nominal, cables)
        v, a = nominal.velocities, nominal.accelerations
        kwargs = {"winch": ctrl.winch, "friction_model": ctrl.friction_model}
        if name == "hc-tau":
            estimate = force_from_motor_torque(target, v, a, **kwargs)
        else:
            kwargs["velocity_feedforward"] = ctrl.velocity_feedforward
            estimate = force_from_following_error(target, v, a, **kwargs)
        np.testing.assert_allclose(estimate, nominal.forces, rtol=0.0, atol=1e-10)


def test_random_round_trips_over_the_fitted_speeds():
    rng = np.random.default_rng(0)
    f = rng.uniform(0.0, 40.0, (200, 8))
    v = rng.uniform(-0.1, 0.1, (200, 8))
    v[:20] = rng.uniform(-0.005, 0.005, (20, 8))  # inside the eq. 6 blend
    a = rng.normal(0.0, 2.0, (200, 8))
    winch = WinchParameters(drum_radius=0.025, drum_inertia=5e-5)
    tau = winch.motor_torque(f, v, a)
    np.testing.assert_allclose(force_from_motor_torque(tau, v, a, winch=winch), f, atol=1e-11)
    for feedforward in (True, False):
        fe = winch.following_error_for_force(f, v, a, velocity_feedforward=feedforward)
        back = force_from_following_error(fe, v, a, winch=winch, velocity_feedforward=feedforward)
        np.testing.assert_allclose(back, f, atol=1e-10)
    # at rest without friction and inertia, eq. 3 is tau = f r_D
    np.testing.assert_allclose(force_from_motor_torque(tau, 0.0, friction_model=False), tau / 0.02)


def test_the_formula_inverts_the_plant_given_the_true_torque_and_speed(robot):
    """Eq. 3's signs and terms are the plant's: noise-free, the error is the plant's step.

    HC-e, 1.2 s: max 0.035 N (0.039 N with a = 0). The plant evaluates tau_F at the speed of
    the step's start, so where PI drives shake the drums (HC-tau) the error is larger (up to
    0.36 N with a = 0, measured, below v_L = 0.25 m/min where eq. 6 is steep).
    """
    trajectory = _head(get_cdpr_trajectory("triangle-12"), 1.2)
    ctrl = make_cdpr_controller("hc-e", robot)
    plant = CdprPlant(robot, DEFAULT_CDPR_PLANT, seed=0)
    start = ctrl.nominal(trajectory.position[0])
    plant.reset(
        (trajectory.position[0], trajectory.rotation),
        tensions=start.forces,
        drive_mode=ctrl.drive_mode,
    )
    errors, speed = [], np.zeros(ctrl.m)
    for k in range(len(trajectory)):
        readings = plant.sense()
        truth = plant.ground_truth()
        # the drum's acceleration over the last step, for tau_In of eq. 3
        a = (truth["cable_speed"] - speed) / trajectory.dt
        speed = truth["cable_speed"]
        if trajectory.t[k] >= 0.05:
            estimate = force_from_motor_torque(truth["motor_torque"], speed, a)
            errors.append(estimate - truth["tension"])
        command = ctrl.step(
            trajectory.position[k], trajectory.velocity[k], trajectory.acceleration[k], readings
        )
        plant.command(command.l_set, command.v_ff, command.drive_mode)
        plant.step()
    assert np.abs(np.array(errors)).max() < 0.07


_tau, _cur, _fe = force_from_motor_torque, force_from_motor_current, force_from_following_error
_NAN = np.nan


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: _tau([0.2, _NAN], [0.0, 0.0]), r"motor_torque .* index \(1,\)"),
        (lambda: _tau(np.ones((5, 8)), np.zeros((5, 7))), r"v \[m/s\] has shape \(5, 7\)"),
        (lambda: _tau(np.ones(8), np.zeros((5, 8))), r"to the motor torque's \(8,\)"),
        (lambda: _tau(np.ones(8), 0.0, np.full(8, np.inf)), r"a \[m/s\^2\] must be finite"),
        (lambda: _tau(0.2, 0.2), r"beyond v_H"),
        (lambda: _tau(0.2, 0.0, winch=0.02), r"winch must be a WinchParameters"),
        (lambda: _cur(1.0, 0.0, 0.0), r"torque_constant .* must be > 0"),
        (lambda: _cur(1.0, _NAN, 0.0), r"torque_constant .* must be finite"),
        (lambda: _cur([1.0, 2.0], [0.3, 0.3, 0.3], 0.0), r"torque_constant .* \(3,\)"),
        (
            lambda: _fe([[-1e-3, _NAN]], 0.0, velocity_feedforward=True),
            r"following_error \[m\] .* index \(0, 1\)",
        ),
        (
            lambda: _fe(np.zeros(3), np.zeros(4), velocity_feedforward=True),
            r"following error's \(3,\)",
        ),
    ],
)
def test_bad_inputs_are_refused_with_the_argument_named(call, match):
    with pytest.raises(InputError, match=match):
        call()


def test_the_following_error_estimate_is_told_whether_the_plc_sent_velocity_feedforward():
    """A default (msarm's PLC, which sends it) read a paper-000 robot's 10 N as 2.9 N."""
    winch = WinchParameters()
    fe = winch.following_error_for_force(10.0, 4 / 60, 0.0, velocity_feedforward=False)
    assert force_from_following_error(fe, 4 / 60, velocity_feedforward=False) == pytest.approx(10)
    assert abs(force_from_following_error(fe, 4 / 60, velocity_feedforward=True) - 10.0) > 5.0
    with pytest.raises(TypeError, match="velocity_feedforward"):
        force_from_following_error(fe, 4 / 60)  # no default: the caller says which


def test_the_winch_model_takes_lists_as_its_docstring_says():
    """`any shape broadcastable`: a list of tensions was a TypeError (list times float)."""
    winch = WinchParameters()
    np.testing.assert_allclose(
        winch.motor_torque([10.0, 5.0], [0.0, 0.01], [0.0, 0.0]),
        winch.motor_torque(np.array([10.0, 5.0]), np.array([0.0, 0.01]), np.zeros(2)),
    )
    fe = winch.following_error_for_force([10.0], [0.01], [0.0])
    assert fe.shape == (1,) and np.isfinite(fe).all()
