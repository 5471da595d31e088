"""``msarm log check``: what the diagnosis can make of each log, said before it runs."""

from __future__ import annotations

import json
import sys
from dataclasses import replace

import numpy as np
import pytest
from conftest import short_move_logs

from msarm.diagnose.log_check import RESIDUALS_CHECKED, check_log
from msarm.io.logs import RunLog, read_log, write_log
from msarm.plant import IDEAL_PLANT
from msarm.plant.config import SensorNoiseConfig


@pytest.fixture(scope="module")
def logs(arm, tmp_path_factory):
    effects = replace(IDEAL_PLANT.effects, sensor_noise=SensorNoiseConfig(enabled=True))
    plant = replace(IDEAL_PLANT, name="checked", effects=effects)
    return short_move_logs(arm, tmp_path_factory.mktemp("checked"), plant, 1, first_seed=60)


def _without(path, out, prefix):
    log = read_log(path)
    columns = {k: v for k, v in log.columns.items() if not k.startswith(prefix)}
    return write_log(out, RunLog(columns, log.metadata))


def test_a_complete_log_supports_every_residual(arm, logs):
    check = check_log(arm, logs[0])
    assert check.ok and check.error is None and check.warnings == ()
    assert check.residuals == dict.fromkeys(RESIDUALS_CHECKED, True)
    log = read_log(logs[0])
    assert check.samples == len(log) and check.sample_rate_hz == log.metadata.sample_rate_hz
    assert check.duration_s == pytest.approx(float(log.t[-1] - log.t[0]))
    assert check.diagnosed_share == 1.0  # no time gap, so no segment too short to diagnose
    assert check.joint_travel_rad > 0.1
    assert json.loads(json.dumps(check.as_dict()))["residuals"] == check.residuals


def test_what_a_log_lacks_is_said_as_the_diagnosis_says_it(arm, logs, tmp_path):
    path = _without(logs[0], tmp_path / "no_cmd.parquet", "tension_cmd.")
    check = check_log(arm, path)
    assert check.ok and not check.residuals["drive"] and check.residuals["cable_length"]
    assert len(check.warnings) == 1
    assert "columns 'tension_cmd.*' are missing (all 9): no drive residual" in check.warnings[0]


def test_channels_that_name_no_joint_or_cable_of_the_model_are_warned(arm, logs, tmp_path):
    """A column ``q.wrist`` or ``tension_motor.wrist_flexor`` in a log: the import refuses it,
    the diagnosis does not read it; before, the check said nothing (0 warnings)."""
    log = read_log(logs[0])
    zeros = np.zeros(len(log))
    extra = {"q.wrist": zeros, "q_ref.Elbow": zeros, "tension_motor.wrist_flexor": zeros}
    path = write_log(tmp_path / "wrist.parquet", RunLog({**log.columns, **extra}, log.metadata))
    check = check_log(arm, path)
    assert check.ok and check.residuals == dict.fromkeys(RESIDUALS_CHECKED, True)
    joints, cables = check.warnings
    assert joints.startswith(
        f"{path}: columns 'q.wrist', 'q_ref.Elbow' name no joint of the model 'msarm_arm' "
        "(its joints: shoulder_abduction, "
    )
    assert "the diagnosis does not read them (a misspelt name, or a joint" in joints
    assert cables.startswith(
        f"{path}: column 'tension_motor.wrist_flexor' names no cable of the model 'msarm_arm'"
    )
    assert "the diagnosis does not read it (a misspelt name, or a cable" in cables


def test_a_log_the_diagnosis_refuses_keeps_its_error(arm, logs, tmp_path):
    log = read_log(logs[0])
    other = write_log(
        tmp_path / "other.parquet",
        RunLog(log.columns, replace(log.metadata, model_sha256="ab" * 32)),
    )
    check = check_log(arm, other)
    assert not check.ok and "the log is of another robot model" in check.error
    assert check.residuals == dict.fromkeys(RESIDUALS_CHECKED, False) and check.samples is None
    csv = tmp_path / "run.csv"
    csv.write_text("t,q.elbow\n0,1\n")
    assert "a CSV file, expected a log (Parquet); msarm log import" in check_log(arm, csv).error
    assert "no such log file" in check_log(arm, tmp_path / "nope.parquet").error


def test_msarm_log_check_reports_every_log_then_fails_on_the_bad_ones(
    arm, logs, tmp_path, monkeypatch, capsys
):
    from msarm.cli import main

    bad = tmp_path / "bad.parquet"
    bad.write_text("not parquet")
    monkeypatch.setattr(sys, "argv", ["msarm", "log", "check", str(logs[0]), str(bad), "--json"])
    with pytest.raises(SystemExit) as exit_info:
        main()
    captured = capsys.readouterr()
    assert exit_info.value.code == 2
    rows = json.loads(captured.out)["logs"]
    assert [row["error"] is None for row in rows] == [True, False]
    assert "not a readable Parquet file" in rows[1]["error"]
    assert captured.err.strip() == (
        f"msarm: error: 1 of 2 log(s) cannot be diagnosed: {bad} (see the JSON)"
    )
    monkeypatch.setattr(sys, "argv", ["msarm", "log", "check", str(logs[0])])
    main()  # all good: exit code 0
    out = capsys.readouterr().out
    assert "what msarm diagnose can make of them" in out and "yes" in out
    monkeypatch.setattr(
        sys, "argv", ["msarm", "log", "check", str(logs[0]), "--filter-window", "4"]
    )
    with pytest.raises(SystemExit):
        main()
    assert (
        "--filter-window: expected an odd number of samples >= 5, got 4" in capsys.readouterr().err
    )
    # the window the diagnosis would use decides the filter-span warning
    monkeypatch.setattr(
        sys, "argv", ["msarm", "log", "check", str(logs[0]), "--filter-window", "301", "--json"]
    )
    main()
    (row,) = json.loads(capsys.readouterr().out)["logs"]
    assert any("span 1.2 s" in text for text in row["warnings"]), row["warnings"]
    assert np.isfinite(row["diagnosed_share"])
    # and the drum radius it would read the motor angles with
    argv = ["msarm", "log", "check", str(logs[0]), "--drum-radius", "0.012", "--json"]
    monkeypatch.setattr(sys, "argv", argv)
    main()
    (row,) = json.loads(capsys.readouterr().out)["logs"]
    assert [text for text in row["warnings"] if "drum radius 0.012 m) do not follow" in text]
    monkeypatch.setattr(sys, "argv", argv[:-2] + ["0", "--json"])
    with pytest.raises(SystemExit):
        main()
    assert "--drum-radius: expected a radius > 0 in metres, got 0.0" in capsys.readouterr().err


def test_logs_the_diagnosis_refuses_together_are_said(arm, logs, tmp_path, monkeypatch, capsys):
    """One run under two names, and logs of two sample rates: each log is fine alone."""
    from msarm.cli import main
    from msarm.diagnose.log_check import check_logs

    copy = tmp_path / "copy.parquet"
    copy.write_bytes(logs[0].read_bytes())
    log = read_log(logs[0])
    halved = {**log.columns, "t": 2.0 * log.columns["t"]}
    rate = log.metadata.sample_rate_hz
    slow = write_log(
        tmp_path / "slow.parquet",
        RunLog(halved, replace(log.metadata, sample_rate_hz=rate / 2)),
    )
    checks, together = check_logs(arm, [logs[0], copy, slow])
    assert all(check.ok for check in checks)
    assert len(together) == 2
    assert together[0].startswith(f"logs: {copy} has the same contents as {logs[0]}")
    assert together[1] == (
        f"logs of 2 sample rates ({rate / 2:g} Hz: {slow}; {rate:g} Hz: {logs[0]}, {copy}); "
        "the diagnosis takes logs of one sample rate together"
    )
    assert check_logs(arm, [logs[0]])[1] == []
    (twice,) = check_logs(arm, [logs[0], logs[0]])[1]
    assert twice.startswith(f"logs: {logs[0]} is given twice; expected each run once")
    # a rate that differs in its ninth digit is the diagnosis's one rate (it was "logs of 2
    # sample rates (250 Hz: ...; 250 Hz: ...)")
    near = write_log(
        tmp_path / "near.parquet",
        RunLog(log.columns, replace(log.metadata, sample_rate_hz=rate * (1 + 1e-8))),
    )
    assert check_logs(arm, [logs[0], near])[1] == []
    monkeypatch.setattr(sys, "argv", ["msarm", "log", "check", str(logs[0]), str(copy)])
    with pytest.raises(SystemExit) as exit_info:
        main()
    captured = capsys.readouterr()
    assert exit_info.value.code == 2
    assert "error (the logs together): logs:" in captured.out
    assert captured.err.startswith("msarm: error: the logs cannot be diagnosed together: logs:")


def test_a_warning_of_another_kind_is_passed_on_when_the_log_is_refused(arm, logs, monkeypatch):
    """check_log records the diagnosis's warnings; any other is passed on once (a loop that
    re-warned into its own record never ended)."""
    import warnings

    import msarm.diagnose.residuals as residuals
    from msarm.errors import LogError

    def refuse(*args, **kwargs):
        warnings.warn("overflow", RuntimeWarning, stacklevel=1)
        warnings.warn("log.parquet: a gap", residuals.DiagnosisWarning, stacklevel=1)
        raise LogError("log.parquet: refused")

    monkeypatch.setattr(residuals, "residuals_from_log", refuse)
    with pytest.warns(RuntimeWarning, match="overflow"):
        check = check_log(arm, logs[0])
    assert check.error == "log.parquet: refused" and check.warnings == ("log.parquet: a gap",)
