"""The compiled loop runs a learned feedforward (network and sheath stage) to the Python loop's
bits, and leaves a feedforward that reads the sensors to the Python loop."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import assert_same_run_bits

from msarm.compensation import Compensator, NetworkConfig, Normalizer, build_mlp
from msarm.compensation.features import FeatureExtractor, FeatureSpec
from msarm.compensation.feedforward import LearnedFeedforward
from msarm.compensation.sheath import SheathInverse, SheathParameters, SheathSpec
from msarm.control import MuscleSpaceController
from msarm.errors import InputError
from msarm.plant import DEFAULT_PLANT, ArmPlant
from msarm.tasks import runner as runner_module
from msarm.tasks.runner import run_tracking
from msarm.tasks.trajectories import hold_then_move

HOME = np.array([0.0, 0.0, 0.0, -0.2])
TARGET = np.array([0.1, 0.3, -0.2, -0.8])
SHORT = hold_then_move("short", HOME, TARGET, wait=0.2, move_time=1.0, duration=2.0)
PERIOD = 1.0 / 250.0


def _network(arm, spec: FeatureSpec, seed: int = 0) -> Compensator:
    """A random network for ``spec``'s features of the arm, giving torques of about 0.3 N m."""
    extractor = FeatureExtractor(arm, spec)
    rng = np.random.default_rng(seed)
    config = NetworkConfig(hidden=(16,), activation="tanh")
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = build_mlp(extractor.size, arm.n_joints, config)
    x = rng.normal(size=(100, extractor.size))
    y = 0.3 * rng.normal(size=(100, arm.n_joints))
    metadata = {"model_sha256": arm.sha256, "feature_spec": spec.as_dict()}
    return Compensator(
        net.state_dict(), Normalizer.fit(x), Normalizer.fit(y), config, metadata=metadata
    )


def _stage(arm, mu: float = 0.1) -> SheathInverse:
    return SheathInverse(arm, SheathSpec(), SheathParameters(mu=mu, compliance=1e-4), PERIOD)


def _runs(arm, feedforward, seed: int = 3):
    """The run through the Python loop, then the compiled one, with the stage's end state."""
    runs, calls, sides = [], [], []
    for compiled in (False, True):
        plant = ArmPlant(arm, DEFAULT_PLANT, seed=seed)
        controller = MuscleSpaceController(arm)
        seen: list[float] = []
        runs.append(
            run_tracking(
                plant, controller, SHORT, feedforward, progress=seen.append, compiled=compiled
            )
        )
        calls.append(seen)
        sides.append(None if feedforward.sheath is None else feedforward.sheath.side)
    return runs, calls, sides


@pytest.mark.parametrize("parts", ["network and stage", "stage alone", "network alone"])
def test_a_learned_feedforward_runs_compiled_to_the_python_loops_bits(arm, parts):
    network = None if parts == "stage alone" else _network(arm, FeatureSpec())
    stage = None if parts == "network alone" else _stage(arm)
    feedforward = LearnedFeedforward(arm, network, stage)
    (python, compiled), (python_calls, compiled_calls), sides = _runs(arm, feedforward)
    assert python.completed and compiled.completed
    assert_same_run_bits(python, compiled)
    assert compiled_calls == python_calls and len(python_calls) > 40
    # the feedforward did act (what is compared is not the loop without it)
    tau_ff = np.abs(
        np.column_stack([v for k, v in python.columns.items() if k.startswith("tau_ff")])
    )
    tension_ff = np.abs(
        np.column_stack([v for k, v in python.columns.items() if k.startswith("tension_ff")])
    )
    assert (tau_ff.max() > 0.01) == (network is not None)
    assert (tension_ff.max() > 0.1) == (stage is not None)
    # the compiled loop left the stage where the Python loop did
    if stage is not None:
        np.testing.assert_array_equal(sides[0], sides[1])
        assert np.any(sides[1] != 0)


def test_a_feedforward_that_reads_the_sensors_takes_the_python_loop(arm, monkeypatch):
    sensing = LearnedFeedforward(arm, _network(arm, FeatureSpec(groups=("q", "tension"))))
    assert sensing.precompute(np.zeros((3, 4)), np.zeros((3, 4))) is None
    plant, controller = ArmPlant(arm, DEFAULT_PLANT, seed=0), MuscleSpaceController(arm)
    with pytest.raises(InputError, match="its feedforward's torques need the robot's sensors"):
        run_tracking(plant, controller, SHORT, sensing, compiled=True)

    def refuse(*args, **kwargs):
        raise AssertionError("the compiled loop ran a feedforward that reads the sensors")

    monkeypatch.setattr(runner_module, "run_compiled", refuse)
    run = run_tracking(plant, controller, SHORT, sensing)
    assert run.completed and np.any(run.columns["tau_ff.shoulder_flexion"] != 0)


def test_a_stage_command_that_overflows_raises_the_same_error_in_both_loops(arm):
    messages = []
    for compiled in (False, True):
        feedforward = LearnedFeedforward(arm, None, _stage(arm, mu=1e9))
        plant, controller = ArmPlant(arm, DEFAULT_PLANT, seed=0), MuscleSpaceController(arm)
        with pytest.raises(InputError, match="tension_command must give") as caught:
            run_tracking(plant, controller, SHORT, feedforward, compiled=compiled)
        messages.append(str(caught.value))
    assert messages[0] == messages[1] and "inf" in messages[0]


def test_reference_features_do_not_depend_on_the_sensors(arm):
    """from_reference gives the rows of the online calls, whatever the sensors read."""
    from types import SimpleNamespace

    extractor = FeatureExtractor(arm, FeatureSpec())
    t = np.arange(200) * PERIOD
    q_ref, qd_ref, _ = SHORT.reference(t + 0.9)  # mid-move: every group varies
    planned = extractor.from_reference(q_ref, qd_ref)
    rng = np.random.default_rng(1)
    extractor.reset()
    for k in range(len(t)):
        readings = SimpleNamespace(
            t=t[k],
            q=q_ref[k] + rng.normal(0, 0.05, 4),
            motor_angle=rng.normal(size=9),
            tension_motor=rng.uniform(5, 50, 9),
        )
        online = extractor(readings, rng.normal(size=4), q_ref[k], qd_ref[k])
        np.testing.assert_array_equal(online.view(np.uint64), planned[k].view(np.uint64))
    assert np.ptp(planned, axis=0).min() > 0
    with pytest.raises(InputError, match="from the reference to compute them before the run"):
        FeatureExtractor(arm, FeatureSpec(groups=("q", "sign_error"))).from_reference(q_ref, qd_ref)
