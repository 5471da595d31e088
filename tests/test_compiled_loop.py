"""The compiled closed loop gives the Python loop's bits, and hands back what it cannot do."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import assert_same_run_bits

from msarm.control import ArmControllerConfig, MuscleSpaceController
from msarm.errors import InputError
from msarm.plant import DEFAULT_PLANT, IDEAL_PLANT, ArmPlant
from msarm.plant.config import CoggingConfig, DelayConfig, SensorNoiseConfig
from msarm.plant.effects import SensorNoise
from msarm.tasks.compiled_loop import compiled_loop_supported
from msarm.tasks.runner import run_tracking
from msarm.tasks.trajectories import hold_then_move

HOME = np.array([0.0, 0.0, 0.0, -0.2])
TARGET = np.array([0.1, 0.3, -0.2, -0.8])
SHORT = hold_then_move("short", HOME, TARGET, wait=0.2, move_time=1.0, duration=2.0)
WITH_DELAY = replace(
    DEFAULT_PLANT, effects=replace(DEFAULT_PLANT.effects, delay=DelayConfig(enabled=True))
)
WITH_COGGING = replace(
    DEFAULT_PLANT,
    effects=replace(DEFAULT_PLANT.effects, cogging=CoggingConfig(enabled=True, amplitude=0.02)),
)


def _both_loops(arm, plant_config, controller_config=None, seed=3, task=SHORT):
    """The same run through the Python loop and the compiled one, with their progress calls."""
    runs, calls = [], []
    for compiled in (False, True):
        plant = ArmPlant(arm, plant_config, seed=seed)
        controller = MuscleSpaceController(arm, controller_config)
        seen: list[float] = []
        runs.append(run_tracking(plant, controller, task, progress=seen.append, compiled=compiled))
        calls.append(seen)
    return runs, calls


@pytest.mark.parametrize(
    "plant_config",
    [
        DEFAULT_PLANT,
        IDEAL_PLANT,
        WITH_COGGING,
        replace(DEFAULT_PLANT, timestep=0.0005),
        WITH_DELAY,
        replace(
            IDEAL_PLANT,
            effects=replace(
                IDEAL_PLANT.effects, delay=DelayConfig(True, sensing_periods=0, actuation_periods=2)
            ),
        ),
    ],
    ids=["default", "ideal", "cogging", "2 kHz", "sensing delay", "actuation delay"],
)
def test_compiled_loop_gives_the_python_loops_bits(arm, plant_config):
    (python, compiled), (python_calls, compiled_calls) = _both_loops(arm, plant_config)
    assert python.completed and compiled.completed
    assert_same_run_bits(python, compiled)
    assert compiled_calls == python_calls and len(python_calls) > 40


def test_unsettled_allocations_are_handed_to_the_allocator_and_the_loop_goes_on(arm):
    # every cable at least 200 N: most ticks have no force within the bounds that makes the
    # torque, the Newton method proves it and the allocator's least squares answers
    config = ArmControllerConfig(min_tension=200.0)
    counted = []
    python_solve = None
    for compiled in (False, True):
        plant = ArmPlant(arm, DEFAULT_PLANT, seed=1)
        controller = MuscleSpaceController(arm, config)
        solve = controller._allocator.solve

        def counting(*args, solve=solve, **kwargs):
            result = solve(*args, **kwargs)
            counted[-1].append(result.status)
            return result

        controller._allocator.solve = counting
        counted.append([])
        run = run_tracking(plant, controller, SHORT, compiled=compiled)
        if python_solve is None:
            python_solve = run
    python_statuses, compiled_statuses = counted
    assert "infeasible" in python_statuses and "optimal" in python_statuses[1:]
    # the compiled loop called the allocator only for those ticks (and the runner's first)
    assert compiled_statuses[1:] == [s for s in python_statuses[1:] if s != "optimal"]
    assert_same_run_bits(python_solve, run)


def test_a_diverged_run_stops_the_same_in_both_loops(arm):
    # stiff enough to diverge (1e8 N/m settled once a cable going slack in a step no longer
    # held its winch back)
    stiff = replace(
        DEFAULT_PLANT.effects,
        elasticity=replace(DEFAULT_PLANT.effects.elasticity, stiffness=1e9, damping=0.0),
    )
    (python, compiled), _ = _both_loops(arm, replace(DEFAULT_PLANT, effects=stiff))
    assert not python.completed and not compiled.completed
    assert str(compiled.error) == str(python.error)
    assert compiled.error.time == python.error.time
    assert compiled.error.state == python.error.state
    assert_same_run_bits(python, compiled)


def test_a_bad_muscle_length_mid_run_raises_the_hill_models_error(arm):
    # a tendon slack length between the cable's lengths at the start and at the end of the
    # move: fine at the start, refused once the cable is shorter than that
    from msarm.muscle.geometry import cable_kinematics

    data = arm.create_data()
    jacobian = np.zeros((arm.n_cables, arm.n_joints))
    start = cable_kinematics(arm.mj_model, data.mj, HOME, jacobian)
    end = cable_kinematics(arm.mj_model, data.mj, TARGET, jacobian)
    cable = int(np.argmax(start - end))
    messages = []
    for compiled in (False, True):
        controller = MuscleSpaceController(arm)
        controller._hill._l_slack[cable] = 0.5 * (start[cable] + end[cable])
        with pytest.raises(InputError, match="is not longer than its tendon slack") as caught:
            run_tracking(ArmPlant(arm, DEFAULT_PLANT, seed=0), controller, SHORT, compiled=compiled)
        messages.append(str(caught.value))
    assert messages[0] == messages[1]


def test_runs_the_compiled_loop_cannot_do_take_the_python_one(arm):
    plant = ArmPlant(arm, DEFAULT_PLANT, seed=0)
    controller = MuscleSpaceController(arm)
    assert compiled_loop_supported(plant, controller, None)
    assert not compiled_loop_supported(plant, controller, lambda *args: np.zeros(4))
    fast = MuscleSpaceController(arm, ArmControllerConfig(solver="fast"))
    assert not compiled_loop_supported(plant, fast, None)
    dynamics = MuscleSpaceController(arm, ArmControllerConfig(activation_dynamics=True))
    assert not compiled_loop_supported(plant, dynamics, None)
    assert compiled_loop_supported(ArmPlant(arm, WITH_DELAY, seed=0), controller, None)

    class LouderNoise(SensorNoise):  # a user's sensor effect runs in Python
        name = "louder_noise"  # a name of its own (the built-in one is taken)

    louder = ArmPlant(arm, DEFAULT_PLANT, seed=0, extra_effects=[LouderNoise(SensorNoiseConfig())])
    assert louder.compiled and not compiled_loop_supported(louder, controller, None)
    with pytest.raises(InputError, match="cannot take the compiled loop"):
        run_tracking(plant, fast, SHORT, compiled=True)
    # and without asking, such a run simply takes the Python loop
    assert run_tracking(plant, fast, SHORT).completed
