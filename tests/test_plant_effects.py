"""Each plant effect, switched on alone, changes what it should and nothing else."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from msarm.errors import InputError
from msarm.plant import IDEAL_PLANT, ArmPlant, Effect, PlantConfig
from msarm.plant.config import (
    CoggingConfig,
    DelayConfig,
    ElasticityConfig,
    JointFrictionConfig,
    SensorNoiseConfig,
    SheathFrictionConfig,
    WinchFrictionConfig,
)

POSTURE = np.array([0.2, 0.4, -0.3, -0.9])
# a joint velocity that shortens some cables and lengthens others
MOTION = np.array([0.6, -0.5, 0.4, -0.8])


def only(**effects) -> PlantConfig:
    """The ideal plant with the given effects switched on."""
    return replace(IDEAL_PLANT, name="test", effects=replace(IDEAL_PLANT.effects, **effects))


def moving_plant(arm, config: PlantConfig, tension: float = 30.0, steps: int = 3) -> ArmPlant:
    plant = ArmPlant(arm, config, seed=1)
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, tension), qdot=MOTION)
    plant.step(steps)
    return plant


def cable_speeds(arm, plant: ArmPlant) -> np.ndarray:
    return plant.mj_data.ten_velocity.copy()


def test_ideal_plant_renders_the_command_exactly(arm):
    plant = moving_plant(arm, IDEAL_PLANT)
    truth = plant.ground_truth()
    np.testing.assert_allclose(truth["tension_motor"], 30.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(truth["tension_insertion"], 30.0, rtol=0, atol=1e-12)
    readings = plant.sense()
    np.testing.assert_array_equal(readings.q, truth["q"])
    np.testing.assert_array_equal(readings.tension_motor, truth["tension_motor"])


def test_a_saturated_drive_holds_what_its_torque_limit_balances(arm):
    """Rigid or elastic cables, a command above F_max gives F_max (r T = torque limit), and
    the logged motor torque and the tension agree (rigid: the tension was the command)."""
    biceps = list(arm.cable_names).index("biceps")  # F_max 400 N, 1.2 N m on a 3 mm drum
    for config in (IDEAL_PLANT, only(elasticity=ElasticityConfig(enabled=True))):
        plant = ArmPlant(arm, replace(config, name="saturated"), seed=0)
        plant.reset(POSTURE, tensions=np.full(plant.n_cables, 100.0))
        command = np.full(plant.n_cables, 100.0)
        command[biceps] = 700.0
        plant.command(command)
        plant.step(20 if config is IDEAL_PLANT else 400)
        readings = plant.sense()  # no sensor noise on these plants: the true values
        limit = plant.torque_limit[biceps]
        radius = config.winch.drum_radius
        assert readings.motor_torque[biceps] == pytest.approx(limit)
        assert readings.tension_motor[biceps] <= limit / radius + 1e-9
        assert readings.tension_motor[biceps] > 0.9 * limit / radius


# the default sheath (its tanh saturated at these cable speeds), and one whose wider smoothing
# keeps tanh(v / v_s) well inside (-1, 1), so that v_s and the velocity used both count
@pytest.mark.parametrize(
    "sheath",
    [
        SheathFrictionConfig(enabled=True),
        SheathFrictionConfig(enabled=True, mu=0.2, smoothing_velocity=0.05),
    ],
    ids=["default", "wide_smoothing"],
)
def test_sheath_friction_alone_rigid_cable(arm, sheath):
    """Pulled in: insertion < motor side; paid out: insertion > motor side; the smooth capstan
    law ``T_i = T_m exp(-mu Theta tanh(v_in / v_s))``, ``v_in = -dl/dt``, exactly."""
    assert not IDEAL_PLANT.effects.elasticity.enabled  # a rigid cable
    plant = moving_plant(arm, only(sheath_friction=sheath))
    truth = plant.ground_truth()
    # the plant's last step computed its tensions at MuJoCo's tendon velocities of that step
    # (mj_step1; mj_step2 integrates the state but leaves ten_velocity as it was)
    speed = cable_speeds(arm, plant)
    pulled_in, paid_out = speed < -0.01, speed > 0.01
    assert pulled_in.any() and paid_out.any()
    assert np.all(truth["tension_insertion"][pulled_in] < truth["tension_motor"][pulled_in])
    assert np.all(truth["tension_insertion"][paid_out] > truth["tension_motor"][paid_out])
    # the capstan bound: at most a factor exp(mu Theta) either way
    ratio = truth["tension_insertion"] / truth["tension_motor"]
    bound = np.exp(sheath.mu * truth["wrap_angle"])
    assert np.all(ratio <= bound + 1e-12) and np.all(ratio >= 1 / bound - 1e-12)
    # the closed form, from the configured mu and v_s
    smooth_sign = np.tanh(-speed / sheath.smoothing_velocity)
    if sheath.smoothing_velocity > 0.01:
        assert np.all(np.abs(smooth_sign) < 0.95) and np.ptp(np.abs(smooth_sign)) > 0.3
    expected = truth["tension_motor"] * np.exp(-sheath.mu * truth["wrap_angle"] * smooth_sign)
    np.testing.assert_allclose(truth["tension_insertion"], expected, rtol=1e-12, atol=0)
    # nothing else: the motor side still renders the command
    np.testing.assert_allclose(truth["tension_motor"], 30.0, atol=1e-12)


def _one_cable(mu: float, wrap: float = 3.0, tension: float = 30.0):
    """A single elastic cable on a fixed path: the kernel alone, with its state arrays."""
    from msarm.plant.cable_kernel import PARAMS

    values = dict.fromkeys(PARAMS, 0.0)
    values.update(
        timestep=1e-3,
        drum_radius=0.003,
        rotor_inertia=3e-5,
        drive_gain=4.0,
        stiffness=2e4,
        mu=mu,
        smoothing_velocity=0.002,
        smoothing_speed=0.5,
        elastic=1.0,
    )
    arrays = {
        "params": np.array([values[name] for name in PARAMS]),
        "lengths": np.array([0.7]),
        "velocities": np.zeros(1),
        "wrap": np.array([wrap]),
        "command": np.array([tension]),
        "torque_limit": np.array([1.5]),
        "length_ref": np.array([0.7]),
        "stretch_motor0": np.array([tension / 4e4]),
        "stretch_insertion0": np.array([tension / 4e4]),
        "user_torque": np.zeros(1),
        "user_slope": np.zeros(1),
        "user_factor": np.ones(1),
        "theta": np.zeros(1),
        "omega": np.zeros(1),
        "slide": np.zeros(1),
        "tension_motor": np.array([tension]),
        "tension_insertion": np.array([tension]),
        "motor_torque": np.zeros(1),
        "jac_data": np.array([0.02]),
        "jac_rownnz": np.array([1], dtype=np.int32),
        "jac_rowadr": np.array([0], dtype=np.int32),
        "jac_colind": np.array([0], dtype=np.int32),
        "qfrc": np.zeros(1),
    }
    return arrays


def _settle(arrays, command: float, ramp: int = 4000, hold: int = 2000):
    """Ramp the command slowly (quasi-static: no overshoot of the drive), then hold it."""
    from msarm.plant.cable_kernel import step_cables

    start = float(arrays["command"][0])
    for k in range(ramp + hold):
        arrays["command"][:] = start + (command - start) * min(1.0, (k + 1) / ramp)
        step_cables(*arrays.values())
    return float(arrays["tension_motor"][0]), float(arrays["tension_insertion"][0])


def test_sheath_friction_with_elastic_cable_sticks_and_slips():
    """On a fixed path the capstan node sticks inside the band and slides at its edges."""
    beta = np.exp(0.12 * 3.0)
    cable = _one_cable(mu=0.12)
    motor, insertion = _settle(cable, 36.0)  # inside the band: the node sticks
    assert motor == pytest.approx(36.0, abs=1e-6)
    assert insertion == pytest.approx(30.0, abs=1e-9)
    motor, insertion = _settle(cable, 50.0)  # beyond: the node slides, T_m = beta T_i
    assert motor == pytest.approx(50.0, abs=1e-6)
    assert insertion == pytest.approx(50.0 / beta, rel=1e-3)
    held = insertion
    motor, insertion = _settle(cable, 30.0)  # back inside: the insertion holds (hysteresis)
    assert motor == pytest.approx(30.0, abs=1e-6)
    assert insertion == pytest.approx(held, rel=1e-9)
    assert insertion > motor
    motor, insertion = _settle(cable, 10.0)  # below the band: slides the other way
    assert insertion == pytest.approx(10.0 * beta, rel=1e-2)


def test_without_sheath_friction_the_elastic_cable_is_one_spring():
    cable = _one_cable(mu=0.0)
    motor, insertion = _settle(cable, 45.0)
    assert motor == pytest.approx(45.0, abs=1e-6)
    assert insertion == pytest.approx(motor, rel=1e-12)
    # joint force: -J^T T_i
    assert cable["qfrc"][0] == pytest.approx(-0.02 * insertion, rel=1e-12)


@pytest.mark.parametrize("mu", [0.0, 0.12])
@pytest.mark.parametrize("speed", [-0.03, 0.03])
def test_a_winch_following_a_moving_path_renders_the_command(mu, speed):
    """A frictionless winch that reels in (or pays out) as the path moves at a steady speed
    holds the commanded tension: the implicit winch step sees the node where the path has
    put it, not where it was a step before (that lag was a drag r^2 k h omega, 0.12 N here)."""
    from msarm.plant.cable_kernel import step_cables

    cable = _one_cable(mu=mu)
    cable["params"][-1] = 40.0  # the rope's damping settles the drive's transient
    for _ in range(4000):
        cable["velocities"][:] = speed
        cable["lengths"][:] += speed * 1e-3
        step_cables(*cable.values())
    assert cable["omega"][0] == pytest.approx(-speed / 0.003, rel=1e-9)
    assert cable["tension_motor"][0] == pytest.approx(30.0, abs=1e-9)


@pytest.mark.parametrize("mu", [0.0, 0.12])
def test_a_winch_whose_cable_goes_slack_in_a_step_feels_no_tension(mu):
    """The path takes 2 mm in one step from a cable stretched 1.5 mm: the cable is slack at
    the step's end, and the winch turns under the drive's torque alone (0.09 N m over 3e-5
    kg m^2 for 1 ms: 3 rad/s); it was held back by the last step's 30 N (omega 0)."""
    from msarm.plant.cable_kernel import step_cables

    cable = _one_cable(mu=mu)
    cable["velocities"][:] = -2.0
    cable["lengths"][:] -= 0.002
    step_cables(*cable.values())
    assert cable["tension_motor"][0] == 0.0 and cable["tension_insertion"][0] == 0.0
    assert cable["omega"][0] == pytest.approx(3.0, rel=1e-9)


def test_winch_friction_alone_rigid_cable(arm):
    """Reeling in, the motor-side tension falls short of the command; paying out, exceeds it."""
    plant = moving_plant(arm, only(winch_friction=WinchFrictionConfig(enabled=True)))
    truth = plant.ground_truth()
    speed = cable_speeds(arm, plant)
    reeling_in, paying_out = speed < -0.01, speed > 0.01
    assert np.all(truth["tension_motor"][reeling_in] < 30.0)
    assert np.all(truth["tension_motor"][paying_out] > 30.0)
    np.testing.assert_array_equal(truth["tension_insertion"], truth["tension_motor"])


def test_elasticity_alone_slack_cable_carries_zero_tension(arm):
    config = only(elasticity=ElasticityConfig(enabled=True))
    plant = ArmPlant(arm, config, seed=1)
    # no tension and motion: cables whose path shortens go slack
    plant.reset(POSTURE, tensions=np.zeros(arm.n_cables), qdot=MOTION)
    plant.command(np.zeros(arm.n_cables))
    plant.step(5)
    truth = plant.ground_truth()
    slack = truth["stretch"] < 0
    assert slack.any()
    np.testing.assert_array_equal(truth["tension_motor"][slack], 0.0)
    np.testing.assert_array_equal(truth["tension_insertion"][slack], 0.0)


def test_elasticity_alone_taut_cable_is_a_spring(arm):
    config = only(elasticity=ElasticityConfig(enabled=True, stiffness=2.0e4))
    plant = ArmPlant(arm, config, seed=1)
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 25.0))
    truth = plant.ground_truth()
    np.testing.assert_allclose(truth["stretch"], 25.0 / 2.0e4, rtol=1e-12)
    np.testing.assert_allclose(truth["tension_insertion"], 25.0, rtol=1e-12)


def test_joint_friction_alone_sets_the_joints_friction_only(arm):
    config = only(joint_friction=JointFrictionConfig(enabled=True, coulomb=0.2, viscous=0.07))
    plant = moving_plant(arm, config)
    np.testing.assert_allclose(plant.mj_model.dof_frictionloss, 0.2)
    np.testing.assert_allclose(plant.mj_model.dof_damping, 0.07)
    np.testing.assert_allclose(plant.ground_truth()["tension_insertion"], 30.0, atol=1e-12)
    # the shared nominal model is untouched
    assert np.all(arm.mj_model.dof_frictionloss == 0) and np.all(arm.mj_model.dof_damping == 0)


def test_cogging_alone_is_periodic_in_the_motor_angle(arm):
    cogging = CoggingConfig(enabled=True, amplitude=0.01, periods_per_revolution=24)
    plant = moving_plant(arm, only(cogging=cogging))
    truth = plant.ground_truth()
    gain = plant.config.winch.drive_gain
    expected = 30.0 + 0.01 * np.sin(24 * truth["winch_angle"]) / (0.003 * (1 + gain))
    np.testing.assert_allclose(truth["tension_motor"], expected, rtol=1e-9)


def test_sensor_noise_alone_changes_readings_not_the_robot(arm):
    config = only(sensor_noise=SensorNoiseConfig(enabled=True, tension_noise=0.5, tension_bias=2.0))
    plant = ArmPlant(arm, config, seed=5)
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 30.0))
    errors = np.array([plant.sense().tension_motor - 30.0 for _ in range(400)])
    assert abs(errors.mean() - 2.0) < 0.1
    assert abs(errors.std() - 0.5) < 0.05
    np.testing.assert_allclose(plant.ground_truth()["tension_motor"], 30.0)


def test_delay_alone_returns_old_readings(arm):
    plant = ArmPlant(arm, only(delay=DelayConfig(enabled=True, sensing_periods=2)), seed=1)
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 30.0), qdot=MOTION)
    times = []
    for _ in range(5):
        times.append(plant.sense().t)
        plant.step(4)
    np.testing.assert_allclose(times, [0.0, 0.0, 0.0, 0.004, 0.008])


def test_delayed_drives_hold_the_reset_tension_until_the_first_command_arrives(arm):
    """u_drive(k) = u(k - d): the first command is felt d periods after it is sent, the reset
    tension before (it went through at once and was held for d + 1 periods)."""
    config = only(delay=DelayConfig(enabled=True, sensing_periods=0, actuation_periods=3))
    plant = ArmPlant(arm, config, seed=1)
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 20.0))
    drives = []
    for tension in (30.0, 40.0, 50.0, 60.0, 70.0):
        plant.command(np.full(arm.n_cables, tension))
        drives.append(float(plant._command[0]))
        plant.step(4)
    assert drives == [20.0, 20.0, 20.0, 30.0, 40.0]
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 25.0))  # a new run starts afresh
    plant.command(np.full(arm.n_cables, 30.0))
    assert float(plant._command[0]) == 25.0


def test_user_effect_through_the_documented_interface(arm):
    class HalfTransmission(Effect):
        name = "half"

        def transmission(self, state):
            return np.full(state.lengths.shape, 0.5)

    plant = ArmPlant(arm, IDEAL_PLANT, seed=0, extra_effects=[HalfTransmission()])
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 30.0))
    plant.step(1)
    np.testing.assert_allclose(plant.ground_truth()["tension_insertion"], 15.0)
    assert "half" in plant.effect_parameters()


def test_bad_reset_is_refused(arm):
    plant = ArmPlant(arm, IDEAL_PLANT)
    with pytest.raises(InputError, match="q must have shape"):
        plant.reset(np.zeros(3))
    with pytest.raises(InputError, match="tensions must be >= 0"):
        plant.reset(POSTURE, tensions=-np.ones(arm.n_cables))
    # more than a drive holds (biceps: 1.2 N m on a 3 mm drum, 400 N): a state it cannot keep
    too_much = np.full(arm.n_cables, 100.0)
    too_much[list(arm.cable_names).index("biceps")] = 700.0
    with pytest.raises(InputError, match=r"700.0 N on cable 7 \('biceps'\) is more than its drive"):
        plant.reset(POSTURE, tensions=too_much)
    plant.reset(POSTURE, tensions=plant.torque_limit / plant.drum_radius)  # at the limit: held


class _Loss(Effect):
    """A user effect with a fixed transmission factor."""

    name = "loss"

    def __init__(self, factor: float = 0.8) -> None:
        self.factor = factor

    def transmission(self, state):
        return np.full(state.lengths.shape, self.factor)

    def parameters(self):
        return {"factor": self.factor}


def test_effects_of_one_name_are_refused(arm):
    """Two effects of one name would overwrite each other's ground truth."""
    with pytest.raises(InputError, match=r"extra_effects\[0\] \(_Loss\) and extra_effects\[1\]"):
        ArmPlant(arm, IDEAL_PLANT, extra_effects=[_Loss(0.8), _Loss(0.5)])

    class MyFriction(_Loss):
        name = "sheath_friction"

    default = only(sheath_friction=SheathFrictionConfig(enabled=True))
    for config in (default, IDEAL_PLANT):  # a built-in name is reserved, on or off
        with pytest.raises(InputError, match="'sheath_friction', the name of msarm's built-in"):
            ArmPlant(arm, config, extra_effects=[MyFriction()])

    class Stretchy(_Loss):
        name = "elasticity"

    with pytest.raises(InputError, match="built-in effect 'elasticity'"):
        ArmPlant(arm, IDEAL_PLANT, extra_effects=[Stretchy()])
    with pytest.raises(InputError, match=r"extra_effects\[0\] must be an msarm.plant.Effect"):
        ArmPlant(arm, IDEAL_PLANT, extra_effects=["loss"])


class _Hooks(Effect):
    """A user effect whose hooks return what the test asks for."""

    name = "hooks"

    def __init__(self, hook: str, value) -> None:
        self.hook, self.value = hook, value

    def transmission(self, state):
        return self.value if self.hook == "transmission" else np.ones(state.lengths.shape)

    def winch_torque(self, state):
        m = state.lengths.shape[0]
        return self.value if self.hook == "winch_torque" else (np.zeros(m), np.zeros(m))

    def actuate(self, command):
        return self.value if self.hook == "actuate" else command

    def sense(self, readings, rng):
        return self.value(readings) if self.hook == "sense" else readings


@pytest.mark.parametrize(
    ("hook", "value", "message"),
    [
        ("transmission", -np.ones(9), r"transmission\(\) must return values >= 0.0, got -1.0"),
        (
            "transmission",
            np.ones(3),
            r"transmission\(\) must return shape \(9,\), got shape \(3,\)",
        ),
        ("transmission", np.r_[np.nan, np.ones(8)], r"transmission\(\) must return finite"),
        ("transmission", None, r"transmission\(\) must return shape \(9,\)"),
        ("winch_torque", np.zeros(9), r"winch_torque\(\) must return a pair"),
        ("winch_torque", (np.zeros(9), np.full(9, np.inf)), r"winch_torque\(\) slope must"),
        ("winch_torque", (np.zeros(2), np.zeros(9)), r"winch_torque\(\) torque must return shape"),
        ("actuate", -np.ones(9), r"actuate\(\) must return values >= 0.0"),
        ("actuate", np.ones(2), r"actuate\(\) must return shape"),
        ("sense", lambda r: r.q, r"sense\(\) must return SensorReadings, got ndarray"),
        (
            "sense",
            lambda r: replace(r, tension_motor=r.tension_motor[:3]),
            r"sense\(\).tension_motor must return shape \(9,\)",
        ),
        ("sense", lambda r: replace(r, q=r.q * np.nan), r"sense\(\).q must return finite"),
    ],
)
def test_bad_user_hook_outputs_are_refused(arm, hook, value, message):
    """A user hook's bad output is named (effect and hook), not broadcast or simulated."""
    plant = ArmPlant(arm, IDEAL_PLANT, extra_effects=[_Hooks(hook, value)])
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 20.0))
    with pytest.raises(InputError, match="effect 'hooks' \\(_Hooks\\): " + message):
        plant.command(np.full(arm.n_cables, 20.0))
        plant.sense()
        plant.step(2)


def test_built_in_effects_keep_the_compiled_step(arm):
    """User-hook checks cost nothing to a plant of built-in effects."""
    from msarm.mujoco_c import step_functions
    from msarm.plant import DEFAULT_PLANT

    if step_functions() is None:
        pytest.skip("MuJoCo's library was not found: no compiled step")
    assert ArmPlant(arm, DEFAULT_PLANT).compiled
    assert not ArmPlant(arm, DEFAULT_PLANT, extra_effects=[_Loss()]).compiled


def test_bad_command_and_step_count_are_refused(arm):
    plant = ArmPlant(arm, IDEAL_PLANT)
    plant.reset(POSTURE, tensions=np.full(arm.n_cables, 20.0))
    with pytest.raises(InputError, match=r"tension must be >= 0 N .* -100.0 N for cable 0"):
        plant.command(np.r_[-100.0, np.full(arm.n_cables - 1, 20.0)])
    with pytest.raises(InputError, match="tension must be finite, got nan at index 2"):
        plant.command(np.r_[20.0, 20.0, np.nan, np.full(arm.n_cables - 3, 20.0)])
    with pytest.raises(InputError, match="tension must be an array of shape \\(9,\\), got None"):
        plant.command(None)
    for bad in (-5, 2.5, "3", True):
        with pytest.raises(InputError, match="n_steps must be an integer >= 0"):
            plant.step(bad)
    time = plant.time
    plant.step(0)  # documented: nothing happens
    plant.step(np.int64(2))
    assert plant.time == pytest.approx(time + 2 * IDEAL_PLANT.timestep)


def test_bad_seed_and_config_are_refused(arm):
    for bad in (None, 1.5, "a", True):
        with pytest.raises(InputError, match="seed must be a non-negative integer or a numpy"):
            ArmPlant(arm, IDEAL_PLANT, seed=bad)
    with pytest.raises(InputError, match="seed must be a non-negative integer, got -1"):
        ArmPlant(arm, IDEAL_PLANT, seed=np.int64(-1))
    with pytest.raises(
        InputError, match=r"config must be an msarm.plant.PlantConfig, got NoneType"
    ):
        ArmPlant(arm, None)


def test_a_generator_seed_gives_the_same_run_at_every_reset(arm):
    from msarm.plant import DEFAULT_PLANT

    def noise(plant):
        plant.reset(POSTURE, tensions=np.full(arm.n_cables, 20.0))
        plant.step(4)
        return plant.sense().tension_motor

    generator = np.random.default_rng(7)
    plant = ArmPlant(arm, DEFAULT_PLANT, seed=generator)
    first = noise(plant)
    generator.standard_normal(5)  # the caller's generator moving on changes nothing
    np.testing.assert_array_equal(noise(plant), first)
    np.testing.assert_array_equal(
        noise(ArmPlant(arm, DEFAULT_PLANT, seed=np.random.default_rng(7))), first
    )
    np.testing.assert_array_equal(noise(ArmPlant(arm, DEFAULT_PLANT, seed=7)), first)


def test_reset_outside_the_joint_range_is_refused(arm):
    plant = ArmPlant(arm, IDEAL_PLANT)
    q = POSTURE.copy()
    q[3] = arm.joint_upper[3] + 0.1
    name = arm.joint_names[3]
    with pytest.raises(InputError, match=rf"q: joint 3 \('{name}'\) at .* outside the model's"):
        plant.reset(q)
    plant.reset(np.asarray(arm.joint_upper))  # the range's edges are inside


@pytest.mark.parametrize(
    "effects",
    [
        {"elasticity": ElasticityConfig(enabled=True)},
        {
            "elasticity": ElasticityConfig(enabled=True),
            "sheath_friction": SheathFrictionConfig(enabled=True),
        },
    ],
    ids=["elasticity", "elasticity+sheath"],
)
def test_cable_effects_alone_keep_tracking_stable(arm, effects):
    """The rope's damping keeps the cable-arm oscillation from running away."""
    from msarm.control import ArmControllerConfig
    from msarm.tasks.registry import get_task
    from msarm.tasks.track import TrackSettings, track

    task = get_task("table1-1", arm)
    metrics = track(
        arm, task, TrackSettings(task.name, 0, only(**effects), ArmControllerConfig())
    ).metrics
    assert metrics.completed
    assert metrics.final_error_mm < 10.0
    assert max(metrics.joint_rmse) < 0.05
