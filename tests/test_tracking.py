"""The runner, tracking metrics, logs and the track command on the arm."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from msarm.cli import app
from msarm.control import ArmControllerConfig, MuscleSpaceController
from msarm.errors import InputError
from msarm.io.logs import read_log, read_sidecar, sidecar_path
from msarm.plant import DEFAULT_PLANT, IDEAL_PLANT, ArmPlant, Effect
from msarm.tasks.registry import get_task
from msarm.tasks.runner import run_tracking
from msarm.tasks.track import TrackSettings, track
from msarm.tasks.trajectories import hold_then_move

HOME = np.array([0.0, 0.0, 0.0, -0.2])
SHORT = hold_then_move("short", HOME, [0.1, 0.3, -0.2, -0.8], wait=0.2, move_time=1.0, duration=2.0)


def settings(plant=DEFAULT_PLANT, seed=0) -> TrackSettings:
    return TrackSettings("short", seed, plant, ArmControllerConfig())


def test_ideal_plant_converges_to_a_table1_target(arm):
    task = get_task("table1-1", arm)
    result = track(arm, task, settings(IDEAL_PLANT))
    assert result.metrics.completed
    assert result.metrics.final_error_mm < 1.0
    assert sum(result.metrics.slack_events) == 0


def test_default_plant_shows_a_gap_to_the_ideal_plant(arm):
    task = get_task("table1-1", arm)
    ideal = track(arm, task, settings(IDEAL_PLANT)).metrics
    default = track(arm, task, settings(DEFAULT_PLANT)).metrics
    assert default.final_error_mm > 5 * max(ideal.final_error_mm, 0.05)
    # half a second after the move the default plant is further off than at the end
    assert default.settle_error_mm > default.final_error_mm > 0
    assert default.settle_error_mm > 5 * ideal.settle_error_mm
    assert min(default.joint_rmse) > 10 * max(ideal.joint_rmse)
    assert max(default.cable_length_error_percent) > 10 * max(ideal.cable_length_error_percent)


def test_a_weak_drive_starts_at_the_tension_it_holds(arm):
    """The controller may want more at home than a weak drive holds (torque limit / drum
    radius): the run starts with the drive at its limit (the plant refuses more at rest)."""
    weak = replace(
        IDEAL_PLANT, name="weak", winch=replace(IDEAL_PLANT.winch, torque_limit_factor=0.04)
    )
    plant = ArmPlant(arm, weak, seed=0)
    hold = plant.holding_tension
    controller = MuscleSpaceController(arm, ArmControllerConfig())
    wanted = controller.update(plant.sense(), HOME, np.zeros(4), np.zeros(4)).tension_command
    assert np.any(wanted > hold)  # the case: more than the weakest drive holds
    run = run_tracking(plant, MuscleSpaceController(arm, ArmControllerConfig()), SHORT)
    assert run.error is None
    tensions = np.column_stack([run.columns[f"tension_motor.{c}"] for c in arm.cable_names])
    assert np.all(tensions[0] <= hold + 1e-9)


def test_same_seed_same_log_bit_for_bit(arm, tmp_path):
    first = track(arm, SHORT, settings(seed=3), tmp_path / "a", plots_too=False)
    second = track(arm, SHORT, settings(seed=3), tmp_path / "b", plots_too=False)
    other = track(arm, SHORT, settings(seed=4), tmp_path / "c", plots_too=False)
    log_a, log_b = read_log(first.files["log"]), read_log(second.files["log"])
    assert log_a == log_b
    assert log_a != read_log(other.files["log"])  # the noise differs


def test_a_run_cut_off_in_an_old_run_s_folder_is_not_taken_for_whole(arm, tmp_path, monkeypatch):
    """Killed between its config and its metrics, a rerun must not inherit the old metrics."""
    import msarm.tasks.track as track_module
    from msarm.compensation.dataset import reusable_run

    track(arm, SHORT, settings(seed=3), tmp_path, plots_too=False)
    assert reusable_run(tmp_path, settings(seed=3), arm.sha256)

    def killed(*args, **kwargs):
        raise KeyboardInterrupt  # the process dies after the log, before config and metrics

    monkeypatch.setattr(track_module, "write_config", killed)
    with pytest.raises(KeyboardInterrupt):
        track(arm, SHORT, settings(seed=4), tmp_path, plots_too=False)
    assert not (tmp_path / "metrics.json").exists()
    assert not reusable_run(tmp_path, settings(seed=3), arm.sha256)  # the log is seed 4's
    assert not reusable_run(tmp_path, settings(seed=4), arm.sha256)


def test_a_run_in_an_old_run_s_folder_leaves_none_of_its_plots(arm, tmp_path):
    """A run too short to plot (diverged at once) left the old run's plots beside its log;
    and metrics.json, which marks a whole run, is now written after the plots."""
    from msarm.plant.config import ElasticityConfig

    track(arm, SHORT, settings(seed=3), tmp_path)
    assert (tmp_path / "joints.png").is_file() and (tmp_path / "tensions.png").is_file()
    stiff = DEFAULT_PLANT.effects
    # so stiff that the run diverges in its first control period
    stiff = replace(stiff, elasticity=ElasticityConfig(stiffness=1.0e18, damping=0.0))
    broken = replace(DEFAULT_PLANT, name="stiff", effects=stiff)
    result = track(arm, SHORT, settings(broken), tmp_path)
    assert result.run.error is not None and len(result.run.columns["t"]) <= 1
    assert not (tmp_path / "joints.png").exists() and not (tmp_path / "tensions.png").exists()
    assert list(track(arm, SHORT, settings(seed=3), tmp_path).files)[-1] == "metrics"


def test_log_round_trips_and_holds_no_ground_truth(arm, tmp_path):
    result = track(arm, SHORT, settings(seed=1), tmp_path, plots_too=False)
    log = read_log(result.files["log"])
    for name, values in result.run.columns.items():
        np.testing.assert_array_equal(log.columns[name], values)
    assert set(log.columns) == set(result.run.columns)
    forbidden = {"tension_insertion", "stretch", "wrap_angle", "qdot"}
    assert not forbidden & set(log.quantities())
    text = str(log.metadata)
    assert "sheath_friction" not in text and "stiffness" not in text
    truth = read_sidecar(result.files["log"])
    assert "sheath_friction" in truth.ground_truth
    assert "tension_insertion" in truth.quantities()
    # the log is read without its sidecar
    sidecar_path(result.files["log"]).unlink()
    assert read_log(result.files["log"]) == log


def test_divergence_stops_with_time_and_state_and_keeps_the_partial_log(arm, tmp_path):
    class Explode(Effect):
        name = "explode"

        def winch_torque(self, state):
            # finite (a NaN from a hook is refused by name), but far beyond any motor
            blow = np.full(state.lengths.shape, 1e200 if state.q[3] < -0.3 else 0.0)
            return blow, np.zeros_like(blow)

    plant = ArmPlant(arm, DEFAULT_PLANT, seed=0, extra_effects=[Explode()])
    run = run_tracking(plant, MuscleSpaceController(arm), SHORT)
    assert not run.completed
    assert "diverged at t =" in str(run.error) and "q =" in str(run.error)
    assert 0 < len(run.columns["t"]) < int(SHORT.duration * 250)
    assert np.all(np.isfinite(run.columns["q.elbow"]))


def test_control_period_must_be_whole_plant_steps(arm):
    plant = ArmPlant(arm, replace(IDEAL_PLANT, timestep=0.0003))
    with pytest.raises(InputError, match="whole number of plant steps"):
        run_tracking(plant, MuscleSpaceController(arm), SHORT)


def test_track_command_writes_its_outputs(tmp_path):
    runner = CliRunner()
    result = runner.invoke(
        app, ["track", "--task", "table1-2", "--plant", "ideal", "--out", str(tmp_path), "--json"]
    )
    assert result.exit_code == 0, result.output
    assert '"final_error_mm"' in result.output
    for name in ("log.parquet", "log.truth.parquet", "config.yaml", "metrics.json", "joints.png"):
        assert (tmp_path / name).is_file()


def test_unknown_names_list_the_valid_ones(tmp_path):
    runner = CliRunner()
    bad_task = runner.invoke(app, ["track", "--task", "nope", "--out", str(tmp_path)])
    assert bad_task.exit_code != 0
    assert "table1-1" in str(bad_task.exception)
    bad_plant = runner.invoke(app, ["track", "--plant", "nope", "--out", str(tmp_path)])
    assert "default" in str(bad_plant.exception) and "ideal" in str(bad_plant.exception)


def test_plant_file_with_an_unknown_key_is_refused(tmp_path):
    path = tmp_path / "plant.yaml"
    path.write_text("name: mine\neffects:\n  sheath_friction:\n    muu: 0.1\n")
    runner = CliRunner()
    result = runner.invoke(app, ["track", "--plant", str(path), "--out", str(tmp_path)])
    assert result.exit_code != 0
    assert "muu" in str(result.exception)


def test_list_shows_tasks_plants_and_effects():
    result = CliRunner().invoke(app, ["track", "--list"])
    assert result.exit_code == 0
    for word in ("table1-1", "random-<seed>", "ideal", "sheath_friction", "cogging"):
        assert word in result.output


def test_metrics_that_do_not_apply_are_null_in_json():
    import json
    from dataclasses import fields

    from msarm.tasks.cdpr_runner import CdprMetrics
    from msarm.tasks.evaluate import TrackingMetrics

    values = {"final_error_mm": 1.0, "final_error_percent": 0.1, "settle_error_mm": float("nan")}
    values |= {"joint_rmse": (0.1,), "cable_length_error_percent": (0.2,), "slack_events": (0,)}
    values |= {"cable_length_end_percent": (0.1,)}
    values |= {"time_outside_bounds": (0.0,), "completed": True}
    tracking = TrackingMetrics(**values).as_dict()
    assert tracking["settle_error_mm"] is None and tracking["final_error_mm"] == 1.0
    cdpr = CdprMetrics(**{f.name: 1.0 for f in fields(CdprMetrics)} | {"force_rms_error": np.nan})
    for payload in (tracking, cdpr.as_dict()):  # strict JSON: no NaN
        json.loads(json.dumps(payload, allow_nan=False))


def test_a_task_too_short_or_out_of_range_is_refused_before_it_runs(arm):
    plant = ArmPlant(arm, IDEAL_PLANT, seed=0)
    controller = MuscleSpaceController(arm, ArmControllerConfig())
    home = np.array([0.0, 0.0, 0.0, -0.2])
    short = hold_then_move("x", home, [0.1, 0.1, 0.0, -0.5], 0.0, 0.001, 0.002)
    with pytest.raises(InputError, match="at least two control periods"):
        run_tracking(plant, controller, short)
    far = hold_then_move("far", home, [3.0, 0.0, 0.0, -0.5], 0.5, 1.0, 2.0)
    with pytest.raises(InputError, match=r"'shoulder_abduction' at 3.0 rad, outside"):
        run_tracking(plant, controller, far)
    with pytest.raises(InputError, match="without leading zeros, random-7"):
        get_task("random-007", arm)


def _readings(arm, q):
    from msarm.plant.effects import SensorReadings

    m = arm.n_cables
    return SensorReadings(0.0, np.asarray(q, float), np.zeros(m), np.zeros(m), np.zeros(m))


def test_the_controller_refuses_bad_input_and_keeps_its_state(arm):
    controller = MuscleSpaceController(arm)
    home, zero = np.array([0.0, 0.0, 0.0, -0.2]), np.zeros(4)
    with pytest.raises(InputError, match=r"q must have shape \(4,\), got \(2,\)"):
        controller.reset(np.zeros(2))  # the compiled filter would write past its end
    with pytest.raises(InputError, match="q must be finite"):
        controller.reset([0.0, np.nan, 0.0, 0.0])
    controller.reset(home)
    first = controller.update(_readings(arm, home), home, zero, zero).tension_command
    controller.reset(home)
    bad = home.copy()
    bad[0] = np.nan
    with pytest.raises(InputError, match="q_ref must be finite, got nan at index 0"):
        controller.update(_readings(arm, home), bad, zero, zero)
    with pytest.raises(InputError, match="feedforward must be"):
        controller.update(_readings(arm, home), home, zero, zero, feedforward=np.full(4, np.inf))
    # neither refusal left anything in the filter, integral or activation state
    again = controller.update(_readings(arm, home), home, zero, zero).tension_command
    np.testing.assert_array_equal(again, first)


def test_controller_settings_the_arm_cannot_meet_are_refused(arm):
    with pytest.raises(InputError, match=r"min_tension 600.0 N is above the strength of biceps"):
        MuscleSpaceController(arm, ArmControllerConfig(min_tension=600.0))
    with pytest.raises(ValueError, match=r"kp must be a list of finite gains >= 0.*got 60.0"):
        ArmControllerConfig(kp=60.0)
