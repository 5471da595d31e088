"""The sheath stage: a tension-space inverse of a sheath that sticks, and its identification."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
from conftest import ideal_plant_with, short_move_logs

from msarm.compensation.feedforward import LearnedFeedforward
from msarm.compensation.identify import identify_sheath, plant_reading, reuse_or_identify_sheath
from msarm.compensation.sheath import SheathInverse, SheathParameters, SheathSpec
from msarm.compensation.target import TargetSpec, delivered_torque, torque_error
from msarm.control import ArmControllerConfig, MuscleSpaceController
from msarm.errors import InputError, MsarmWarning
from msarm.io.logs import RunLog, read_log
from msarm.plant import DEFAULT_PLANT, IDEAL_PLANT, ArmPlant
from msarm.plant.effects import SensorReadings
from msarm.tasks.registry import get_task
from msarm.tasks.runner import run_tracking
from msarm.tasks.track import TrackSettings, track
from msarm.tasks.trajectories import hold_then_move

POSTURE = np.array([0.1, 0.3, -0.2, -0.8])
PERIOD = 0.004


def _stage(arm, **spec) -> SheathInverse:
    settings = {"enabled": True, "width": 1e-3, "gain": 1.0, "filter_time": 0.0}
    settings.update(spec)
    return SheathInverse(
        arm, SheathSpec(**settings), SheathParameters(mu=0.1, compliance=2e-5), PERIOD
    )


@pytest.mark.parametrize("gain", [1.0, 0.5])
def test_the_memory_is_a_stop_operator_of_the_tension_and_the_command_its_capstan_factor(arm, gain):
    """s follows the tension as a stop operator and the command is ``F exp(g mu Theta s)``
    (the law of msarm.compensation.sheath's module docstring): a gain g < 1 scales the
    identified mu (0.1) in the exponent, not the memory."""
    # c_s = 1e-5 m/N: 10 N turns the memory fully
    stage = _stage(arm, width=1e-4, compliance_share=0.5, gain=gain)
    wrap = arm.geometry(POSTURE).wrap_angles
    tensions = [20.0, 24.0, 40.0, 37.0, 25.0, 26.0]
    expected_side = [0.0, 0.4, 1.0, 0.7, -0.5, -0.4]  # clip(s + 1e-5 dF / 1e-4, -1, 1)
    for force, side in zip(tensions, expected_side, strict=True):
        command = stage(np.full(9, force), POSTURE)
        np.testing.assert_allclose(stage.side, side, atol=1e-12)
        expected = force * np.exp(gain * 0.1 * wrap * side)
        np.testing.assert_allclose(command, expected, rtol=1e-12)
    stage.reset()
    np.testing.assert_array_equal(stage(np.full(9, 30.0), POSTURE), np.full(9, 30.0))


def test_a_floor_bounds_the_command_of_a_cable_that_pays_out(arm):
    wrap = arm.geometry(POSTURE).wrap_angles
    free, floored = (
        _stage(arm, width=1e-4, compliance_share=0.5),
        _stage(arm, width=1e-4, compliance_share=0.5, floor=5.0),
    )
    for force in (20.0, 5.5, 5.0):  # the wanted tension falls: every memory turns to -1
        below, bounded = free(np.full(9, force), POSTURE), floored(np.full(9, force), POSTURE)
    np.testing.assert_allclose(free.side, -1.0)
    np.testing.assert_allclose(below, 5.0 * np.exp(-0.1 * wrap), rtol=1e-12)
    assert below.min() < 5.0  # the stage alone asks a motor for less than the floor
    np.testing.assert_array_equal(bounded, np.maximum(below, 5.0))


def test_the_wanted_tension_reaches_the_memory_through_a_low_pass(arm):
    stage = _stage(arm, width=1.0, compliance_share=1.0, filter_time=0.012)  # alpha = 0.25
    stage(np.full(9, 10.0), POSTURE)
    stage(np.full(9, 18.0), POSTURE)  # filtered 12: s = 2e-5 (12 - 10) / 1
    np.testing.assert_allclose(stage.side, 4e-5, atol=1e-15)
    stage(np.full(9, 18.0), POSTURE)  # filtered 13.5
    np.testing.assert_allclose(stage.side, 2e-5 * 3.5, atol=1e-15)


def test_the_low_pass_steps_with_the_controller_that_runs_the_stage(arm):
    """A stage trained at 250 Hz run by a 500 Hz controller (msarm track --controller): its
    filter's step is the running period, so filter_time stays a time constant in seconds."""
    stage = _stage(arm, width=1.0, compliance_share=1.0, filter_time=0.012)
    stage.run_at(0.002)  # alpha = 0.002 / 0.014 = 1/7
    stage(np.full(9, 10.0), POSTURE)
    stage(np.full(9, 17.0), POSTURE)  # filtered 11: s = 2e-5 (11 - 10) / 1
    np.testing.assert_allclose(stage.side, 2e-5, atol=1e-15)
    with pytest.raises(InputError, match="period must be > 0"):
        stage.run_at(0.0)
    # the runner tells a feedforward its period before the run
    built = _stage(arm)
    assert built.period == PERIOD
    task = hold_then_move("short", POSTURE, POSTURE + 0.05, wait=0.05, move_time=0.1, duration=0.2)
    controller = MuscleSpaceController(arm, ArmControllerConfig(rate_hz=500.0))
    run = run_tracking(
        ArmPlant(arm, IDEAL_PLANT), controller, task, LearnedFeedforward(arm, None, built)
    )
    assert run.error is None and built.period == 0.002


def test_a_cable_the_reference_shortens_turns_its_memory_towards_the_motor(arm):
    stage = _stage(arm, width=1e-3, compliance_share=0.0)  # the path alone drives it
    other = POSTURE + np.array([0.0, 0.0, 0.0, -0.05])  # elbow flexes: biceps shortens
    lengths = [arm.geometry(q).lengths for q in (POSTURE, other)]
    stage(np.full(9, 30.0), POSTURE)
    stage(np.full(9, 30.0), other)
    expected = np.clip(-(lengths[1] - lengths[0]) / 1e-3, -1, 1)
    np.testing.assert_allclose(stage.side, expected, atol=1e-12)
    biceps = arm.cable_names.index("biceps")
    assert stage.side[biceps] > 0 > stage.side[arm.cable_names.index("triceps")]


def _sticking_sheath(command, wrap, mu, start):
    """Reference sheath: the insertion keeps its tension unless the motor side leaves the
    capstan band [T_i / beta, beta T_i], then it slides (beta = exp(mu Theta))."""
    beta = np.exp(mu * wrap)
    insertion = [start]
    for t_m in command:
        insertion.append(np.clip(insertion[-1], t_m / beta, t_m * beta))
    return np.array(insertion[1:])


def test_the_stage_inverts_a_sticking_sheath_once_its_memory_has_turned(arm):
    wrap = arm.geometry(POSTURE).wrap_angles
    # a wanted tension with reversals, at a fixed posture (the tension drives the memory alone)
    wanted = np.concatenate(
        [np.linspace(30, 60, 40), np.linspace(60, 35, 40), np.linspace(35, 50, 30)]
    )
    stage = _stage(arm, width=1e-6, compliance_share=0.5)  # turns over within 0.2 N
    commands = np.array([stage(np.full(9, f), POSTURE) for f in wanted])
    arrived = _sticking_sheath(commands, wrap, 0.1, np.full(9, 30.0))
    np.testing.assert_allclose(arrived, wanted[:, None] * np.ones(9), rtol=1e-12)
    # a wide memory turns over slowly: after a reversal the insertion sticks for a while
    slow = _stage(arm, width=1e-4, compliance_share=0.5)  # 20 N to turn over
    late = _sticking_sheath(
        np.array([slow(np.full(9, f), POSTURE) for f in wanted]), wrap, 0.1, np.full(9, 30.0)
    )
    assert np.max(np.abs(late - wanted[:, None])) > 1.0
    # without the stage the insertion lags the wanted tension by up to the friction band
    stuck = _sticking_sheath(wanted[:, None] * np.ones(9), wrap, 0.1, np.full(9, 30.0))
    assert np.max(np.abs(stuck - wanted[:, None])) > 0.2 * 50


def test_bad_inputs_and_settings_are_refused(arm):
    stage = _stage(arm)
    with pytest.raises(InputError, match="shape"):
        stage(np.full(8, 10.0), POSTURE)
    with pytest.raises(InputError, match="non-finite"):
        stage(np.full(9, np.nan), POSTURE)
    with pytest.raises(InputError, match=">= 0"):
        stage(np.full(9, -1.0), POSTURE)
    for bad in (
        {"width": 0.0},
        {"gain": 1.5},
        {"filter_time": -1.0},
        {"compliance_share": 2.0},
        {"floor": float("nan")},
    ):
        with pytest.raises(ValueError, match=next(iter(bad))):
            SheathSpec(**bad)
    with pytest.raises(ValueError, match="mu"):
        SheathParameters(mu=-0.1, compliance=1e-5)
    with pytest.raises(InputError, match="period"):
        SheathInverse(arm, SheathSpec(), SheathParameters(0.1, 1e-5), 0.0)
    saved = SheathParameters(0.1, 2e-5, mu_share=0.5)  # compliance_share: NaN, None saved
    assert saved.as_dict()["compliance_share"] is None
    assert SheathParameters.from_dict(saved.as_dict()).as_dict() == saved.as_dict()


def test_the_controller_sends_the_reshaped_command_and_logs_what_it_added(arm):
    stage = _stage(arm, width=1e-4)
    feedforward = LearnedFeedforward(arm, None, stage)
    controller = MuscleSpaceController(arm)
    controller.reset(POSTURE)
    feedforward.reset()
    readings = SensorReadings(
        t=0.0,
        q=POSTURE,
        motor_angle=np.zeros(9),
        motor_torque=np.zeros(9),
        tension_motor=np.ones(9),
    )
    for tick in range(3):  # the PID's integral changes the wanted tensions: the memory moves
        q_ref = POSTURE + 0.002 * tick
        out = controller.update(readings, q_ref, np.zeros(4), np.zeros(4), feedforward)
        wanted = out.tension_command - out.tension_feedforward
        np.testing.assert_allclose(
            out.tension_command,
            wanted * np.exp(0.1 * arm.geometry(q_ref).wrap_angles * stage.side),
            rtol=1e-12,
        )
        np.testing.assert_array_equal(out.feedforward, np.zeros(4))
    assert np.any(out.tension_feedforward != 0)
    plain = MuscleSpaceController(arm)
    plain.reset(POSTURE)
    assert not np.any(plain.update(readings, POSTURE, np.zeros(4), np.zeros(4)).tension_feedforward)


def test_the_target_takes_off_what_the_stage_added(arm, tmp_path):
    task = get_task("table1-2", arm)
    settings = TrackSettings("table1-2", 0, DEFAULT_PLANT, ArmControllerConfig())
    stage = LearnedFeedforward(arm, None, _stage(arm, width=4e-5, gain=0.9, filter_time=0.02))
    result = track(arm, task, settings, tmp_path / "staged", feedforward=stage, plots_too=False)
    log = read_log(result.files["log"])
    added = log.matrix("tension_ff")
    assert np.abs(added).max() > 1.0  # N: the stage was at work
    without = RunLog(
        {k: v for k, v in log.columns.items() if not k.startswith("tension_ff.")}, log.metadata
    )
    q = log.matrix("q")
    # per sample, without the alignment and the smoothing: J^T of what the stage added
    spec = TargetSpec(smooth_tension=False)
    difference = torque_error(arm, log, spec) - torque_error(arm, without, spec)
    for k in (100, 2500, 4000):
        jacobians = arm.geometry(q[k]).jacobian
        np.testing.assert_allclose(difference[k], jacobians.T @ added[k], rtol=1e-9, atol=1e-9)
    # with them (the default), the same torque filtered as the joint angles are
    per_sample = np.array([arm.geometry(q[k]).jacobian.T @ added[k] for k in range(len(q))])
    flat = np.zeros((len(q), 1, 1))
    flat[:, 0, 0] = -1.0
    dt = 1.0 / log.metadata.sample_rate_hz
    difference = torque_error(arm, log, TargetSpec()) - torque_error(arm, without, TargetSpec())
    for j in range(arm.n_joints):
        expected = delivered_torque(flat, per_sample[:, j : j + 1], TargetSpec(), dt)[:, 0]
        np.testing.assert_allclose(difference[:, j], expected, rtol=1e-7, atol=1e-7)


def test_the_logs_identify_the_plants_sheath_and_cables(arm, tmp_path, monkeypatch):
    plant = replace(
        DEFAULT_PLANT,
        effects=replace(
            DEFAULT_PLANT.effects,
            winch_friction=replace(DEFAULT_PLANT.effects.winch_friction, enabled=False),
            joint_friction=replace(DEFAULT_PLANT.effects.joint_friction, enabled=False),
        ),
    )
    logs = short_move_logs(arm, tmp_path, plant, 3)
    found = identify_sheath(arm, logs[:2], logs[2:])
    mu = plant.effects.sheath_friction.mu
    assert abs(found.mu - mu) < 0.15 * mu
    assert found.mu_share > 0.5 and found.compliance_share > 0.5
    # the length residual sees the stretch of a cable whose far end loses its tension
    assert 0.5 / plant.effects.elasticity.stiffness < found.compliance
    assert found.compliance < 1.0 / plant.effects.elasticity.stiffness
    with pytest.raises(InputError, match="training and validation"):
        identify_sheath(arm, logs[:1], [])
    _check_the_identification_is_reused_only_for_the_same_input(
        arm, logs, found, tmp_path, monkeypatch
    )


def test_the_identification_reads_motor_angles_with_the_plants_drums(arm, tmp_path):
    # winch drums of 5 mm: read with the default 3 mm, a motor angle is 40 % less cable than
    # it moved, and the length residual is then mostly that (the compliance found is not the
    # cables'); read with the plant's radius it is the stretch again
    from msarm.diagnose.residuals import ResidualSpec

    plant = replace(
        DEFAULT_PLANT,
        winch=replace(DEFAULT_PLANT.winch, drum_radius=0.005),
        effects=replace(
            DEFAULT_PLANT.effects,
            winch_friction=replace(DEFAULT_PLANT.effects.winch_friction, enabled=False),
            joint_friction=replace(DEFAULT_PLANT.effects.joint_friction, enabled=False),
        ),
    )
    logs = short_move_logs(arm, tmp_path, plant, 3)
    stiffness = plant.effects.elasticity.stiffness
    reading = plant_reading(plant.winch, TargetSpec())  # what msarm train passes
    assert reading == ResidualSpec(drum_radius=0.005, drive_gain=plant.winch.drive_gain)
    found = identify_sheath(arm, logs[:2], logs[2:], reading)
    assert 0.5 / stiffness < found.compliance < 1.0 / stiffness
    assert found.compliance_share > 0.5
    with pytest.warns(MsarmWarning, match="negative compliance"):
        misread = identify_sheath(arm, logs[:2], logs[2:])
    assert misread.compliance == 0.0
    assert misread.compliance_share < found.compliance_share


def _check_the_identification_is_reused_only_for_the_same_input(
    arm, logs, found, tmp_path, monkeypatch
):
    import msarm.compensation.identify as identify
    from msarm.diagnose.residuals import ResidualSpec

    record = tmp_path / "record" / "sheath-identification.json"
    assert reuse_or_identify_sheath(arm, logs[:2], logs[2:], record) == (found, False)
    assert record.is_file()
    assert reuse_or_identify_sheath(arm, logs[:2], logs[2:], record) == (found, True)
    # another split, other code, or an unreadable record: identified again
    again, reused = reuse_or_identify_sheath(arm, logs[1:], logs[:1], record)
    assert not reused and again != found
    assert reuse_or_identify_sheath(arm, logs[1:], logs[:1], record) == (again, True)
    # the logs read with other settings (another drum radius): not the same input
    other = ResidualSpec(drum_radius=0.004)
    assert reuse_or_identify_sheath(arm, logs[1:], logs[:1], record, other)[1] is False
    assert reuse_or_identify_sheath(arm, logs[1:], logs[:1], record, other)[1] is True
    assert reuse_or_identify_sheath(arm, logs[1:], logs[:1], record) == (again, False)
    with monkeypatch.context() as patch:
        patch.setattr(identify, "code_fingerprint", lambda scope: "other code")
        assert reuse_or_identify_sheath(arm, logs[1:], logs[:1], record) == (again, False)
    record.write_text("{not json")
    assert reuse_or_identify_sheath(arm, logs[1:], logs[:1], record) == (again, False)
    # a log whose bytes changed (its name the same) is not the same input
    copy = tmp_path / "changed.parquet"
    copy.write_bytes(logs[0].read_bytes())
    assert reuse_or_identify_sheath(arm, [copy, logs[1]], logs[2:], record) == (found, False)
    copy.write_bytes(logs[2].read_bytes())
    assert reuse_or_identify_sheath(arm, [copy, logs[1]], logs[2:], record)[1] is False
    with pytest.raises(InputError, match="training and validation"):
        reuse_or_identify_sheath(arm, logs[:1], [], record)
    # a capstan fit that stopped short (IPOPT out of iterations, or interrupted) is warned
    # about and used, but not kept: the next run fits again
    fit = identify.fit

    def stopped_short(effect, *args, **kwargs):
        result = fit(effect, *args, **kwargs)
        if effect.linear:
            return result
        return replace(result, success=False, message="Maximum_Iterations_Exceeded")

    record.unlink()
    with monkeypatch.context() as patch:
        patch.setattr(identify, "fit", stopped_short)
        with pytest.warns(MsarmWarning, match="did not converge .*Maximum_Iterations_Exceeded"):
            assert reuse_or_identify_sheath(arm, logs[:2], logs[2:], record) == (found, False)
    assert not record.exists()
    assert reuse_or_identify_sheath(arm, logs[:2], logs[2:], record) == (found, False)
    assert record.is_file()


def test_the_stage_brings_the_arm_closer_to_its_target_on_the_default_plant(arm):
    gains = ArmControllerConfig(
        kp=(90.0, 90.0, 45.0, 45.0), ki=(640.0, 640.0, 320.0, 320.0), integral_limit=10.0
    )
    task = get_task("random-3001", arm)
    settings = TrackSettings("random-3001", 3001, DEFAULT_PLANT, gains)
    friction = DEFAULT_PLANT.effects
    stage = SheathInverse(
        arm,
        SheathSpec(enabled=True),
        SheathParameters(
            mu=friction.sheath_friction.mu, compliance=1 / friction.elasticity.stiffness
        ),
        1.0 / gains.rate_hz,
    )
    plain = track(arm, task, settings, plots_too=False).metrics
    staged = track(
        arm, task, settings, feedforward=LearnedFeedforward(arm, None, stage), plots_too=False
    ).metrics
    assert staged.completed and sum(staged.slack_events) == 0
    assert staged.final_error_mm < 0.5 * plain.final_error_mm
    assert np.mean(staged.joint_rmse) < 0.5 * np.mean(plain.joint_rmse)


@pytest.mark.filterwarnings("ignore:.*hold one value over the whole log")
def test_the_shares_are_scored_on_the_validation_logs(arm, tmp_path):
    """Fitted on friction logs, scored on logs without friction: nothing is explained there."""
    from msarm.plant import IDEAL_PLANT

    sheath_only = ideal_plant_with("sheath", "sheath_friction")
    rubbing = short_move_logs(arm, tmp_path / "sheath", sheath_only, 3)
    smooth = short_move_logs(arm, tmp_path / "ideal", IDEAL_PLANT, 1, first_seed=2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        on_friction = identify_sheath(arm, rubbing[:2], rubbing[2:])
        on_none = identify_sheath(arm, rubbing[:2], smooth)
    # rigid cables: the compliance fit is about 0; a negative one is said and taken as 0
    assert 0.0 <= on_friction.compliance < 1e-6
    if any("negative compliance" in str(w.message) for w in caught):
        assert on_friction.compliance == 0.0
    assert on_none.mu == on_friction.mu  # the same fit ...
    assert on_friction.mu_share > 0.5
    assert on_none.mu_share < 0.0  # ... predicts a friction the validation logs do not have
