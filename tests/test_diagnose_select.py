"""Forward selection of candidate effects, scored on held-out runs (issue 7, "which")."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
from conftest import short_move_logs

from msarm.cli.diagnose import diagnose_command, split_runs
from msarm.diagnose.builder import signals_from_logs
from msarm.diagnose.select import DEFAULT_THRESHOLD, diagnose
from msarm.errors import InputError
from msarm.io.logs import sidecar_path
from msarm.plant import IDEAL_PLANT
from msarm.plant.config import JointFrictionConfig, SensorNoiseConfig

# The noise-free simulated logs hold a cable at its floor tension over a whole run
# ('tension_motor.teres_minor'): the dead-sensor warning is expected on them (asserted in
# test_diagnose_where.py::test_a_noise_free_log_warns_about_the_cable_held_at_its_floor).
pytestmark = pytest.mark.filterwarnings(
    "ignore:.*hold one value over the whole log:msarm.diagnose.residuals.DiagnosisWarning"
)

# the slow nonlinear Stribeck term is left out to keep the tests short
CANDIDATES = ["coulomb", "viscous", "capstan", "cogging", "sensor", "delay", "inertia"]
N_RUNS = 4


def only(**effects):
    """The ideal plant with the given effects switched on."""
    return replace(IDEAL_PLANT, name="test", effects=replace(IDEAL_PLANT.effects, **effects))


def _logs(arm, root, plant):
    return short_move_logs(arm, root, plant, N_RUNS)


@pytest.fixture(scope="module")
def friction_logs(arm, tmp_path_factory):
    plant = only(joint_friction=JointFrictionConfig(enabled=True))
    return _logs(arm, tmp_path_factory.mktemp("select_friction"), plant)


@pytest.fixture(scope="module")
def noise_logs(arm, tmp_path_factory):
    plant = only(sensor_noise=SensorNoiseConfig(enabled=True))
    return _logs(arm, tmp_path_factory.mktemp("select_noise"), plant)


def test_signals_from_logs_concatenates_runs(arm, noise_logs):
    signals, residual, names = signals_from_logs(arm, noise_logs[:2])
    assert names == tuple(str(p) for p in noise_logs[:2])
    assert residual.shape == (signals.n_samples, arm.n_joints)
    assert set(np.unique(signals.run)) == {0, 1}
    assert signals.jacobian.shape == (signals.n_samples, arm.n_cables, arm.n_joints)
    assert np.all(signals.wrap > 0)
    # the Jacobian agrees with the nominal model at a sample
    k = signals.n_samples // 3
    np.testing.assert_allclose(signals.jacobian[k], arm.geometry(signals.q[k]).jacobian)


def test_joint_friction_is_found_and_the_gap_shrinks(arm, friction_logs):
    result = diagnose(arm, friction_logs[:-1], friction_logs[-1:], candidates=CANDIDATES)
    assert result.names, "nothing selected"
    assert result.names[0] in ("coulomb", "viscous")
    assert result.explained_variance[1] > 0.3
    assert all(s.gain > DEFAULT_THRESHOLD for s in result.selected)
    assert np.all(np.diff(result.explained_variance) > 0)
    assert result.total_shrink > 0.3
    assert np.all(result.shrink("joint") > 0.1)
    assert result.group_shrink("joint") > 0.3
    assert np.all(result.gap_after["joint"] < result.gap_before["joint"])
    assert result.acted_groups == ("joint",)
    # each waterfall step lowers the joint gap, ending at the final model's gap
    steps = [w["joint"] for w in result.waterfall]
    assert np.all(np.diff(steps) < 0)
    assert steps[-1] == pytest.approx(np.sqrt(np.mean(result.gap_after["joint"] ** 2)))
    first = result.selected[0]
    assert first.parameters.shape == (arm.n_joints,)
    assert np.all(first.parameters > 0)  # friction opposes motion: r > 0 for qd > 0
    assert np.all(np.isfinite(first.std))
    assert 0.5 < first.confidence <= 1.0
    payload = json.loads(json.dumps(result.as_dict()))
    assert payload["selected"][0]["name"] == first.name
    text = result.to_markdown()
    assert "| joint | shoulder_abduction |" in text
    assert f"- {first.name}: {first.description}" in text  # what the effect is, in words
    assert payload["selected"][0]["units"][first.parameter_names[0]] in ("N m", "N m s/rad")
    assert all("below zero" not in note for note in first.notes)  # a physical friction


def test_null_plant_names_nothing_and_never_reads_the_sidecar(
    arm, noise_logs, monkeypatch, tmp_path
):
    import msarm.diagnose.select as select

    replays = []
    replay_runs = select.replay_runs

    def counted(*args, **kwargs):
        replays.append(1)
        return replay_runs(*args, **kwargs)

    monkeypatch.setattr(select, "replay_runs", counted)
    result = diagnose(arm, noise_logs[:-1], noise_logs[-1:], candidates=CANDIDATES, n_boot=0)
    assert result.names == ()
    # nothing to add to the nominal model: its replay is the replay "with the effects"
    assert len(replays) == 1
    assert result.replay["joint_rmse_after"] == result.replay["joint_rmse_before"] > 0
    assert result.explained_variance == (0.0,)
    assert max(result.step_scores[0].values()) < DEFAULT_THRESHOLD
    for group in result.groups:
        np.testing.assert_array_equal(result.gap_after[group], result.gap_before[group])
    assert result.total_shrink == 0.0
    assert "None: no candidate" in result.to_markdown()
    # remove every sidecar (of copies: the module's logs stay whole for the other tests): the
    # same diagnosis, bit for bit
    copies = []
    for k, path in enumerate(noise_logs):
        copy = tmp_path / f"run{k}" / path.name
        copy.parent.mkdir()
        shutil.copyfile(path, copy)
        shutil.copyfile(sidecar_path(path), sidecar_path(copy))
        sidecar_path(copy).unlink()
        copies.append(copy)
    again = diagnose(arm, copies[:-1], copies[-1:], candidates=CANDIDATES, n_boot=0)
    assert again.train_runs == tuple(str(p) for p in copies[:-1])
    # the logs' names and paths differ, nothing else
    names = ("_runs", "_paths")
    same = {key: value for key, value in again.as_dict().items() if not key.endswith(names)}
    assert same == {k: v for k, v in result.as_dict().items() if not k.endswith(names)}
    assert all(sidecar_path(path).is_file() for path in noise_logs)


def test_the_held_out_replay_takes_the_diagnosis_residual_settings(arm, friction_logs):
    # the gap as motion replays with the window, steps and source the logs were read with,
    # as the "where" step's replay residual does (it took the defaults before 2026-11-28)
    from msarm.diagnose.residuals import ResidualSpec, replay_runs
    from msarm.diagnose.select import load_data, select_effects
    from msarm.diagnose.stack import pooled_rmse

    train, held = friction_logs[:-1], friction_logs[-1:]
    spec = ResidualSpec(replay_window=0.4, replay_source="tension", replay_substeps=2)
    data = load_data(arm, train, held, candidates=["coulomb"], spec=spec)
    assert data.spec is spec
    result = select_effects(data, n_boot=0)
    assert result.names == ("coulomb",)
    assert result.replay["source"] == "tension" and result.replay["window_s"] == 0.4
    hold = data.hold
    before = replay_runs(arm, hold.q, hold.qd, hold.tension, hold.run, hold.dt, None, spec)
    assert result.replay["joint_rmse_before"] == pytest.approx(pooled_rmse(before), rel=1e-12)
    default = select_effects(load_data(arm, train, held, candidates=["coulomb"]), n_boot=0)
    assert default.replay["source"] == "command" and default.replay["window_s"] == 0.2
    assert default.replay["joint_rmse_before"] != result.replay["joint_rmse_before"]


def test_the_score_is_taken_on_the_held_out_runs(arm, friction_logs, noise_logs):
    """Trained on runs with joint friction: held-out runs with friction name it, held-out runs
    without it (the same moves, only sensor noise) leave nothing a term predicts."""
    from msarm.diagnose.select import load_data, select_effects

    train = friction_logs[:-1]
    found = select_effects(
        load_data(arm, train, friction_logs[-1:], candidates=["coulomb", "viscous", "inertia"]),
        n_boot=0,
        replay=False,
    )
    assert found.names and found.names[0] in ("coulomb", "viscous")
    assert found.explained_variance[1] > 0.5
    data = load_data(arm, train, noise_logs[-1:], candidates=CANDIDATES)
    assert data.holdout_runs == (str(noise_logs[-1]),)
    missed = select_effects(data, n_boot=0, replay=False)
    # the friction fitted on the training runs predicts a torque the held-out runs lack: it
    # adds error there, whatever it explained on the runs it was fitted on
    assert missed.names == ()
    assert missed.explained_variance == (0.0,)
    assert missed.step_scores[0]["coulomb"] < 0 and missed.step_scores[0]["viscous"] < 0
    assert max(missed.step_scores[0].values()) < DEFAULT_THRESHOLD


def test_the_score_is_the_explained_share_of_the_held_out_residual(arm, friction_logs):
    """Step 1's score, recomputed from the held-out log read on its own: ``1 - sum (r -
    pred)^2 / sum r^2`` with the fitted Coulomb term's prediction, mean over the groups."""
    from msarm.diagnose.builder import channels_from_logs
    from msarm.diagnose.effects import CoulombFriction
    from msarm.diagnose.select import load_data, select_effects

    data = load_data(arm, friction_logs[:-1], friction_logs[-1:], candidates=["coulomb"])
    # every held-out sample scored (no thinning), so the recomputation uses them all
    result = select_effects(data, n_boot=0, replay=False, max_score_samples=data.hold.n_samples)
    assert result.names == ("coulomb",)
    signals, groups, _ = channels_from_logs(arm, friction_logs[-1:])
    r = groups["joint"]
    assert r.shape == (data.hold.n_samples, arm.n_joints)
    theta = result.selected[0].parameters
    predicted = np.asarray(CoulombFriction(n_joints=arm.n_joints).torque(signals, theta))
    joint = 1.0 - np.sum((r - predicted) ** 2) / np.sum(r**2)
    assert 0.3 < joint < 1.0
    # the term acts on the joint group only: every other group explains nothing
    expected = joint / len(result.groups)
    assert result.explained_variance[1] == pytest.approx(expected, rel=1e-9)
    assert result.selected[0].explained_variance == pytest.approx(expected, rel=1e-9)
    assert result.step_scores[0]["coulomb"] == pytest.approx(joint, rel=1e-9)  # its own groups


def test_too_few_runs_and_bad_input_are_refused(arm, noise_logs, tmp_path):
    with pytest.raises(InputError, match="too few runs to hold any out"):
        split_runs(noise_logs[:1], None)
    with pytest.raises(InputError, match="too few runs to hold any out"):
        diagnose_command(noise_logs[:1], None, False, None)
    with pytest.raises(InputError, match=r"--tension-timing: expected one of period, instant"):
        diagnose_command(noise_logs[:2], noise_logs[2:3], False, None, tension_timing="late")
    train, held = split_runs(list(noise_logs), None)
    assert held == noise_logs[-1:] and train == noise_logs[:-1]
    with pytest.raises(InputError, match="holdout_paths"):
        diagnose(arm, noise_logs, [])
    with pytest.raises(InputError, match="also used for training"):
        diagnose(arm, noise_logs[:2], noise_logs[1:2])
    with pytest.raises(InputError, match="unknown name"):
        diagnose(arm, noise_logs[:1], noise_logs[1:2], candidates=["no_such_effect"])
    missing = tmp_path / "missing.parquet"
    with pytest.raises(InputError, match=r"missing.parquet"):
        signals_from_logs(arm, [missing])
    # a missing file is named before the run count: one log that does not exist is not
    # reported as too few runs, and a held-out one is checked too
    with pytest.raises(InputError, match=r"missing\.parquet: no such log file"):
        diagnose_command([missing], None, False, None)
    with pytest.raises(InputError, match=r"missing\.parquet: no such log file"):
        diagnose_command(noise_logs[:2], [missing], False, None)
    with pytest.raises(InputError, match=r"a folder, expected a log file"):
        diagnose_command([tmp_path, *noise_logs[:1]], None, False, None)
    with pytest.raises(InputError, match="given more than once"):
        diagnose(arm, [noise_logs[0], noise_logs[0]], noise_logs[1:2])
    for threshold in (1.0, 5.0, -0.1, float("nan")):
        with pytest.raises(InputError, match=r"threshold: expected a value in \[0, 1\)"):
            diagnose(arm, noise_logs[:2], noise_logs[2:3], threshold=threshold)


def test_the_console_script_refuses_a_negative_seed_before_any_work(noise_logs, capsys):
    from typer.testing import CliRunner

    from msarm.cli import app

    args = ["diagnose", *(str(p) for p in noise_logs), "--seed", "-3"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and result.exception is not None
    assert "--seed" in result.output and "greater than or equal to 0" in result.output


def test_held_out_logs_without_a_channel_skip_the_terms_that_need_it(arm, noise_logs, tmp_path):
    from msarm.diagnose.residuals import DiagnosisWarning
    from msarm.diagnose.select import load_data
    from msarm.io.logs import RunLog, read_log, write_log

    log = read_log(noise_logs[-1])
    columns = {k: v for k, v in log.columns.items() if not k.startswith("tension_cmd.")}
    held = write_log(tmp_path / "no_commands.parquet", RunLog(columns, log.metadata))
    # the default library: the terms that read the commands are skipped, the held-out logs
    # named as the ones that lack them
    with pytest.warns(DiagnosisWarning) as caught:
        data = load_data(arm, noise_logs[:2], [held])
    text = " ".join(str(w.message) for w in caught)
    assert "no_commands.parquet: columns 'tension_cmd.*' are missing (all 9)" in text
    reason = data.skipped["capstan_hysteresis"]
    assert reason.startswith("in the held-out logs") and "tension_cmd" in reason
    assert "coulomb" not in data.skipped
    # the answer keeps what the logs lacked (shown as a warning too), not the skip list
    with pytest.warns(DiagnosisWarning) as shown:
        result = diagnose(arm, noise_logs[:2], [held], candidates=["coulomb"], n_boot=0)
    (lacked,) = result.log_warnings
    assert lacked.startswith(f"{held}: columns 'tension_cmd.*' are missing (all 9)")
    assert lacked in [str(w.message) for w in shown]
    assert json.loads(json.dumps(result.as_dict()))["log_warnings"] == [lacked]
    assert f"## What the logs lacked (warnings)\n\n- {lacked}" in result.to_markdown()
    clean = diagnose(arm, noise_logs[:2], noise_logs[2:3], candidates=["coulomb"], n_boot=0)
    assert clean.log_warnings == () and "What the logs lacked" not in clean.to_markdown()
    # a term the user asked for: an error that says so
    with pytest.raises(InputError, match=r"capstan_hysteresis cannot be fitted.*held-out logs"):
        with pytest.warns(DiagnosisWarning):
            load_data(arm, noise_logs[:2], [held], candidates=["coulomb", "capstan_hysteresis"])


def test_logs_without_motor_angles_skip_the_cogging_terms(arm, noise_logs, tmp_path):
    """Without motor encoders the cogging terms are not fitted to stand-in zero angles."""
    from msarm.diagnose.residuals import DiagnosisWarning
    from msarm.diagnose.select import load_data
    from msarm.io.logs import RunLog, read_log, write_log

    stripped = []
    for k, path in enumerate(noise_logs[:3]):
        log = read_log(path)
        columns = {c: v for c, v in log.columns.items() if not c.startswith("motor_angle.")}
        stripped.append(write_log(tmp_path / f"no_motor{k}.parquet", RunLog(columns, log.metadata)))
    with pytest.warns(DiagnosisWarning) as caught:
        data = load_data(arm, stripped[:2], stripped[2:])
    said = [str(w.message) for w in caught]
    assert any("encoder skew and motor cogging are left out" in text for text in said)
    assert any(text.startswith("candidates not tried: ") for text in said)
    assert "motor_angle.<cable> columns" in data.skipped["motor_cogging"]
    assert "motor_cogging" not in [c.name for c in data.candidates]
    for name in ("cogging", "motor_cogging"):  # the joint-torque form too, when named
        with pytest.raises(InputError, match=f"{name} cannot be fitted"):
            with pytest.warns(DiagnosisWarning):
                load_data(arm, stripped[:2], stripped[2:], candidates=["coulomb", name])


def test_cli_writes_the_report(arm, noise_logs, tmp_path, capsys):
    out = tmp_path / "report"
    diagnose_command(noise_logs[:2], noise_logs[2:3], True, out)
    printed = json.loads(capsys.readouterr().out)
    # a null plant (sensor noise alone): the default candidates name nothing, as in
    # test_null_plant_names_nothing_and_never_reads_the_sidecar
    assert printed["selected"] == []
    assert printed["train_runs"] == [str(p) for p in noise_logs[:2]]
    assert printed["holdout_runs"] == [str(noise_logs[2])]
    scores = [v for v in printed["step_scores"][0].values() if v is not None]
    assert scores and max(scores) < DEFAULT_THRESHOLD
    assert (out / "diagnosis.md").read_text().startswith("# Sim-to-real gap diagnosis")
    assert json.loads((out / "diagnosis.json").read_text()) == printed


def test_a_candidate_the_data_cannot_tell_apart_is_not_selected(arm, friction_logs):
    from msarm.diagnose.effects import CoulombFriction

    class CoulombCopy(CoulombFriction):
        name = "coulomb_copy"

    result = diagnose(
        arm,
        friction_logs[:-1],
        friction_logs[-1:],
        candidates=["coulomb", "viscous"],
        extra_candidates=[CoulombCopy()],
        n_boot=0,
    )
    assert result.names[0] in ("coulomb", "coulomb_copy")
    other = "coulomb_copy" if result.names[0] == "coulomb" else "coulomb"
    assert other not in result.names
    assert "canonical correlation" in result.confounded[other]
    assert other in result.to_markdown()
    payload = json.loads(json.dumps(result.as_dict(), allow_nan=False))  # strict JSON
    assert payload["confounded"] == result.confounded
    with pytest.raises(InputError, match=r"'coulomb' is also the name of a default candidate"):
        diagnose(arm, friction_logs[:1], friction_logs[1:2], extra_candidates=[CoulombFriction()])
    with pytest.raises(InputError, match=r"'coulomb' is also the name of a candidate given in"):
        diagnose(
            arm,
            friction_logs[:1],
            friction_logs[1:2],
            candidates=["coulomb"],
            extra_candidates=[CoulombFriction()],
        )
    with pytest.raises(InputError, match=r"names must be unique; 'coulomb_copy' given more"):
        diagnose(
            arm,
            friction_logs[:1],
            friction_logs[1:2],
            extra_candidates=[CoulombCopy(), CoulombCopy()],
        )


def test_cli_takes_the_nominal_model(arm, noise_logs, capsys):
    from msarm.errors import ModelError
    from msarm.model import ARM_MODEL_PATH

    diagnose_command(noise_logs[:2], noise_logs[2:3], True, None, boot=0, model_path=ARM_MODEL_PATH)
    assert json.loads(capsys.readouterr().out)["train_runs"] == [str(p) for p in noise_logs[:2]]
    cable_robot = ARM_MODEL_PATH.parent / "ipanema_mini.xml"
    with pytest.raises(ModelError, match=r"ipanema_mini.xml"):
        diagnose_command(noise_logs[:2], noise_logs[2:3], True, None, model_path=cable_robot)


def _synthetic_data(arm, viscous=(0.4, 0.5, 0.3, 0.35), noise=0.02, capstan=True):
    """Diagnosis data whose joint residual is Coulomb + viscous friction + noise."""
    from test_diagnose_effects import _make_signals
    from test_diagnose_stack import diagnosis_data

    from msarm.diagnose.effects import (
        CableCapstanFriction,
        CoulombFriction,
        DahlFriction,
        InertiaError,
        ViscousFriction,
    )

    signals = _make_signals(arm, seed=5)
    coulomb, viscous_term = CoulombFriction(), ViscousFriction()
    rng = np.random.default_rng(5)
    torque = (
        np.asarray(coulomb.torque(signals, np.array([0.3, 0.2, 0.25, 0.15])))
        + np.asarray(viscous_term.torque(signals, np.array(viscous)))
        + rng.normal(0.0, noise, size=(signals.n_samples, arm.n_joints))
    )
    pool = [coulomb, viscous_term, DahlFriction(), InertiaError(arm)]
    return diagnosis_data(arm, signals, torque, pool + [CableCapstanFriction()] * capstan)


def test_a_small_term_that_explains_most_of_what_is_left_is_named(arm, monkeypatch):
    """Coulomb friction with a viscous part that is 1.4 % of the residual's energy and little
    noise: after the Coulomb term, the viscous one gains less than the threshold but nearly
    all of what is left, and is named (the second way of the rule); without that way it is
    not."""
    import msarm.diagnose.select as select

    data = _synthetic_data(arm, viscous=(0.16, 0.2, 0.12, 0.14), noise=0.005, capstan=False)
    result = select.select_effects(data, n_boot=0, replay=False)
    assert result.names == ("coulomb", "viscous")
    gain = result.selected[1].gain
    left = 1.0 - result.explained_variance[1]
    assert DEFAULT_THRESHOLD / 4 < gain < DEFAULT_THRESHOLD and gain >= 0.5 * left
    assert result.explained_variance[2] > 0.999
    monkeypatch.setattr(select, "RELATIVE_GAIN", float("inf"))
    assert select.select_effects(data, n_boot=0, replay=False).names == ("coulomb",)


def test_the_shortlist_makes_the_choice_of_the_full_search(arm, monkeypatch):
    """Screening, then a joint fit of the shortlist: the same effects as fitting every one."""
    import msarm.diagnose.select as select

    data = _synthetic_data(arm)
    joint_fits, final_fits = [], []
    fit_together = select.fit_together

    def counted(terms, *args, **kwargs):
        # the search fits by blocks; the chosen terms' final fit (projection) comes after
        (joint_fits if kwargs.get("method") == "blocks" else final_fits).append(len(terms))
        return fit_together(terms, *args, **kwargs)

    monkeypatch.setattr(select, "fit_together", counted)
    full = select.select_effects(data, n_boot=0, replay=False, shortlist=None)
    n_full = len(joint_fits)
    assert final_fits == [len(full.names)]
    joint_fits.clear()
    said = []
    short = select.select_effects(data, n_boot=0, replay=False, shortlist=1, progress=said.append)
    assert said[0] == "step 1: screening 5 candidate(s)"
    assert f"step 2: fitting {short.names[1]} with the 1 effect(s) chosen" in said
    assert len(full.names) >= 2 and short.names == full.names
    # the settings are recorded with the answer
    assert full.search["shortlist"] is None and short.search["shortlist"] == 1
    assert "fits every one jointly" in full.to_markdown()
    assert "fits the best 1 jointly" in short.to_markdown()
    assert short.search["final_fit"] == "projection"
    assert "are their joint optimum (variable projection)" in short.to_markdown()
    assert json.loads(json.dumps(short.as_dict()))["search"]["screen_samples"] == 2500
    # the first step fits each candidate alone either way: the same scores, bit for bit
    assert short.step_scores[0] == full.step_scores[0]
    # later steps fit one candidate jointly with the chosen terms, not every one
    assert len(joint_fits) == len(short.step_scores) - 1 < n_full
    for k, name in enumerate(short.names[1:], start=1):  # a step that added a term
        assert name == max(full.step_scores[k], key=lambda c: full.step_scores[k][c])
        assert short.step_scores[k][name] == pytest.approx(full.step_scores[k][name], abs=1e-6)
    for bad in (0, -1, 1.5):
        with pytest.raises(InputError, match="shortlist: expected None or an integer >= 1"):
            select.select_effects(data, shortlist=bad)
    # screening on thinned samples: the shortlist, refitted on all of them, makes the choice
    joint_fits.clear()
    thinned = select.select_effects(data, n_boot=0, replay=False, screen_samples=100)
    assert thinned.names == full.names
    assert len(joint_fits) == 3 * len(thinned.step_scores)  # the first step's shortlist too
    for k, name in enumerate(thinned.names):
        assert thinned.step_scores[k][name] == pytest.approx(full.step_scores[k][name], abs=1e-6)
    for bad in (99, 150.5):
        with pytest.raises(InputError, match="screen_samples: expected an integer >= 100"):
            select.select_effects(data, screen_samples=bad)


def test_each_step_says_which_scores_are_joint_fits_and_which_screening(arm):
    """``shortlisted``: the candidates of a step fitted jointly with the effects named before;
    the report marks the others' scores "(screening)"."""
    import msarm.diagnose.select as select

    data = _synthetic_data(arm)
    for thinned in (False, True):
        settings = {"screen_samples": 100} if thinned else {}
        result = select.select_effects(data, n_boot=0, replay=False, shortlist=1, **settings)
        assert len(result.shortlisted) == len(result.step_scores) >= 2
        tried = [[n for n, v in scores.items() if np.isfinite(v)] for scores in result.step_scores]
        # the first step on all samples: the screening fit is the joint fit, every one counts;
        # screened on thinned samples, the shortlist (of 1) is refitted at that step too
        if thinned:
            assert len(result.shortlisted[0]) == 1
        else:
            assert sorted(result.shortlisted[0]) == sorted(tried[0])
        for k, names in enumerate(result.shortlisted[1:], start=1):
            assert len(names) == 1 and set(names) <= set(tried[k])
        for k, name in enumerate(result.names):  # a step selects from its shortlist
            assert name in result.shortlisted[k]
        payload = json.loads(json.dumps(result.as_dict(), allow_nan=False))
        assert payload["shortlisted"] == [list(names) for names in result.shortlisted]
        lines = result.to_markdown().split("## Candidates tried at each step")[1].splitlines()
        for k, names in enumerate(result.shortlisted, start=1):
            line = next(text for text in lines if text.startswith(f"{k}. "))
            for name in tried[k - 1]:
                score = f"{name} {result.step_scores[k - 1][name]:+.3f}"
                marked = f"{score} (screening)" in line
                assert score in line and marked == (name not in names), (k, name, line)


def test_several_values_after_one_multi_value_option():
    """`--holdout H1 H2` holds out both logs (click alone would train on H2)."""
    from msarm.cli import spread_multi_value_options as spread

    assert spread(["diagnose", "t1", "t2", "--holdout", "h1", "h2", "--out", "d", "--json"]) == [
        "diagnose", "t1", "t2", "--holdout", "h1", "--holdout", "h2", "--out", "d", "--json"
    ]  # fmt: skip
    assert spread(["diagnose", "t", "--holdout=h1", "h2", "--candidates", "a", "b"]) == [
        "diagnose", "t", "--holdout=h1", "--holdout", "h2", "--candidates", "a", "--candidates", "b"
    ]  # fmt: skip
    # repeated flags, other sub-commands, and values after "--" are left alone
    same = ["diagnose", "t", "--holdout", "h1", "--holdout", "h2"]
    assert spread(same) == same
    for same in (
        ["bench", "diagnose", "--holdout", "2"],
        ["diagnose", "--holdout", "h", "--", "x"],
        ["track", "--holdout", "a", "b"],
    ):
        assert spread(same) == same
    # names end where a path starts: the logs after --candidates stay logs
    assert spread(["diagnose", "--candidates", "capstan", "dahl", "a/t1.parquet", "t2"]) == [
        "diagnose", "--candidates", "capstan", "--candidates", "dahl", "a/t1.parquet", "t2"
    ]  # fmt: skip
    assert spread(["bench", "diagnose", "--effect", "a", "b"]) == [
        "bench", "diagnose", "--effect", "a", "--effect", "b"
    ]  # fmt: skip


def test_the_console_script_holds_out_every_log_after_holdout(noise_logs, monkeypatch, capsys):
    import sys

    from msarm.cli import main

    train, held = [str(p) for p in noise_logs[:2]], [str(p) for p in noise_logs[2:]]
    argv = ["msarm", "diagnose", *train, "--holdout", *held, "--candidates", "coulomb", "viscous"]
    monkeypatch.setattr(sys, "argv", [*argv, "--boot", "0", "--shortlist", "0", "--json"])
    main()  # a success: no SystemExit
    payload = json.loads(capsys.readouterr().out)
    assert payload["train_runs"] == train and payload["holdout_runs"] == held
    assert set(payload["step_scores"][0]) == {"coulomb", "viscous"}
    with pytest.raises(InputError, match="--shortlist: expected a number of candidates >= 0"):
        diagnose_command(noise_logs[:2], noise_logs[2:], True, None, shortlist=-1)


def test_fits_thin_the_training_samples_and_scores_keep_the_held_out_ones(arm):
    """``max_samples`` caps the fits' training samples, ``max_score_samples`` the scores'."""
    import msarm.diagnose.select as select
    from msarm.diagnose.stack import Sampled

    data = _synthetic_data(arm)
    n_train, n_hold = data.train.n_samples, data.hold.n_samples
    assert n_train > 200 and n_hold > 600
    sampled = Sampled(data, 150, max_hold=600)
    assert len(sampled.rows["train"]) == 150 and len(sampled.rows["hold"]) == 600
    assert sampled.rows["hold"][0] == 0 and sampled.rows["hold"][-1] == n_hold - 1  # even
    assert sampled.residual["hold"].shape[0] == 600
    assert len(Sampled(data, 150).rows["hold"]) == 150  # one cap for both by default
    full = select.select_effects(data, n_boot=0, replay=False)
    thin = select.select_effects(
        data, n_boot=0, replay=False, max_samples=n_train // 2, max_score_samples=n_hold
    )
    assert thin.names == full.names
    assert thin.search["max_samples"] == n_train // 2
    assert thin.search["max_score_samples"] == n_hold
    assert (
        f"on at most {n_train // 2} training samples, scored on at most {n_hold} held-out ones"
        in thin.to_markdown()
    )
    for k, name in enumerate(thin.names):  # half the fitting samples, about the same gains
        assert thin.step_scores[k][name] == pytest.approx(full.step_scores[k][name], abs=0.01)
    for bad in (99, 150.5):
        with pytest.raises(InputError, match="max_score_samples: expected an integer >= 100"):
            select.select_effects(data, max_score_samples=bad)
        with pytest.raises(InputError, match="max_samples: expected an integer >= 100"):
            select.select_effects(data, max_samples=bad)


def test_the_load_cells_timing_reaches_the_residual(arm, noise_logs, capsys):
    """``--tension-timing`` sets how the joint residual reads the load cells (and only that)."""
    answers = {}
    for timing in ("period", "instant"):
        diagnose_command(noise_logs[:2], noise_logs[2:3], True, None, boot=0, tension_timing=timing)
        answers[timing] = json.loads(capsys.readouterr().out)
    period, instant = (answers[k]["gap"] for k in ("period", "instant"))
    assert period["drive"] == instant["drive"]
    joint = [period["joint"]["channels"][j]["before"] for j in arm.joint_names]
    other = [instant["joint"]["channels"][j]["before"] for j in arm.joint_names]
    assert joint != other


def test_the_diagnosis_does_not_import_torch():
    """torch (1.5 s to import) is for the compensator's network only, not for a diagnosis."""
    import subprocess
    import sys

    code = "import sys, msarm.diagnose.select, msarm.cli.diagnose; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_the_package_exports_its_entry_points_and_the_cli_its_default_threshold():
    import inspect

    import msarm.diagnose as package
    from msarm.cli.diagnose import diagnose_command
    from msarm.diagnose import CandidateEffect, Diagnosis, diagnose, register
    from msarm.diagnose.select import DEFAULT_THRESHOLD

    assert diagnose is package.select.diagnose and register is package.effects.register
    assert CandidateEffect.__module__ == "msarm.diagnose.effects" and Diagnosis is not None
    assert all(getattr(package, name) is not None for name in package.__all__)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        package.nope  # noqa: B018
    default = inspect.signature(diagnose_command).parameters["threshold"].default
    assert default == DEFAULT_THRESHOLD


def test_the_fits_run_with_one_blas_thread_whatever_the_settings():
    """Multi-threaded BLAS sums in another order: answers moved in their last digits with it."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from msarm.diagnose.baseline import sindy_baseline
    from msarm.diagnose.fitting import one_blas_thread
    from msarm.diagnose.select import select_effects

    def blas_threads() -> set[int]:
        return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}

    with threadpool_limits(limits=2, user_api="blas"):
        assert one_blas_thread(blas_threads)() == {1}
    for entry in (select_effects, sindy_baseline):
        assert entry.__wrapped__ is not entry  # both entry points are wrapped


def test_the_bootstrap_fits_each_distinct_draw_of_runs_once(arm, monkeypatch):
    """A draw of the same runs as an earlier one reuses its refit: the same std and confidence."""
    import msarm.diagnose.select as select
    from msarm.diagnose.stack import Sampled

    data = _synthetic_data(arm)  # two training runs: three distinct draws of two
    weighted = []
    fit_together = select.fit_together

    def counted(terms, sampled, weights=None, *args, **kwargs):
        if weights is not None:
            weighted.append(weights.copy())
        return fit_together(terms, sampled, weights, *args, **kwargs)

    monkeypatch.setattr(select, "fit_together", counted)
    result = select.select_effects(data, n_boot=12, seed=3, replay=False)
    assert len(result.names) >= 2
    distinct = {w.tobytes() for w in weighted}
    assert 1 < len(weighted) == len(distinct) <= 3  # each distinct draw once
    # the slow reference: every one of the 12 draws refitted from the final fit
    sampled = Sampled(data, 5000, max_hold=data.hold.n_samples)
    terms = [c for name in result.names for c in data.candidates if c.name == name]
    final = fit_together(terms, sampled)
    rng = np.random.default_rng(3)
    runs = sampled.signals["train"].run
    labels = np.unique(runs)
    draws = []
    for _ in range(12):
        weights = np.zeros(runs.size)
        for k in rng.integers(0, labels.size, size=labels.size):
            weights[runs == labels[k]] += 1.0
        draws.append(fit_together(terms, sampled, weights, final.parameters).parameters)
    for k, effect in enumerate(result.selected):
        spread = np.std([d[k] for d in draws], axis=0, ddof=1)
        np.testing.assert_allclose(effect.std, spread, rtol=1e-9, atol=1e-15)


def _held_out_gains(sampled, layout, terms, thetas):
    """Each term's rise of the explained share on each held-out run, by hand.

    Per group the explained share is ``1 - sum (r - pred)^2 / sum r^2`` over the run's
    samples (the module docstring's score); a term's gain is the share with all terms less
    the share without it, averaged over the groups it acts on. Shapes ``(n_runs, n_terms)``:
    the gains, and what the term's groups leave unexplained without it (1 minus their mean
    share).
    """
    r_hold = sampled.residual["hold"]
    pairs = zip(terms, thetas, strict=True)
    parts = [sampled.predict(term, theta, "hold") for term, theta in pairs]
    full = np.sum(parts, axis=0)
    runs = sampled.signals["hold"].run
    gains, unexplained = [], []
    for label in np.unique(runs):
        rows = runs == label

        def share(prediction, g, rows=rows):
            r = r_hold[rows][:, layout.slices[g]]
            return 1.0 - np.sum((r - prediction[rows][:, layout.slices[g]]) ** 2) / np.sum(r**2)

        gains.append(
            [
                np.mean([share(full, g) - share(full - part, g) for g in term.term.groups])
                for term, part in zip(terms, parts, strict=True)
            ]
        )
        unexplained.append(
            [
                1.0 - np.mean([share(full - part, g) for g in term.term.groups])
                for term, part in zip(terms, parts, strict=True)
            ]
        )
    return np.array(gains), np.array(unexplained)


def test_the_confidence_is_the_share_of_draws_and_held_out_runs_that_need_the_term(arm):
    """Confidence = the share of (bootstrap draw, held-out run) pairs in which leaving the
    term out of the refitted model lowers the run's explained share by a gain that earns it
    its place (more than the threshold, or more than a quarter of it and at least half of
    what its groups leave unexplained without it: the module docstring of
    msarm.diagnose.select), recomputed by hand from every draw's refit. A term fitted to the
    noise (inertia, absent from the Coulomb + viscous residual) gets 0; the threshold is set
    between two of viscous's distinct critical thresholds so that its confidence is a
    fraction."""
    import msarm.diagnose.select as select
    from msarm.diagnose.stack import Sampled, fit_together

    data = _synthetic_data(arm)  # two training runs, six held-out runs
    sampled = Sampled(data, 5000, max_hold=data.hold.n_samples)
    by_name = {c.name: c for c in data.candidates}
    terms = [by_name["coulomb"], by_name["viscous"], by_name["inertia"]]
    final = fit_together(terms, sampled)
    n_boot, seed = 8, 1
    rng = np.random.default_rng(seed)
    runs = sampled.signals["train"].run
    labels = np.unique(runs)
    gains, unexplained = [], []  # (draw, held-out run, term)
    for _ in range(n_boot):
        weights = np.zeros(runs.size)
        for k in rng.integers(0, labels.size, size=labels.size):
            weights[runs == labels[k]] += 1.0
        thetas = fit_together(terms, sampled, weights, final.parameters).parameters
        gain, left = _held_out_gains(sampled, data.layout, terms, thetas)
        gains.append(gain)
        unexplained.append(left)
    gains, unexplained = np.array(gains), np.array(unexplained)

    def needed(threshold):
        return (gains > threshold) | ((gains > threshold / 4) & (gains >= 0.5 * unexplained))

    # the highest threshold at which each (draw, run) still needs the term
    critical = np.where(gains >= 0.5 * unexplained, 4 * gains, gains)
    viscous = np.unique(critical[:, :, 1])  # sorted; repeated draws give the same gains
    middle = viscous.size // 2
    threshold = 0.5 * (viscous[middle - 1] + viscous[middle])
    assert viscous[middle - 1] < threshold < viscous[middle]
    _, confidence, _ = select._bootstrap(final, sampled, data.layout, n_boot, threshold, seed)
    expected = needed(threshold).mean(axis=(0, 1))
    assert confidence == pytest.approx(list(expected), abs=1e-12)
    assert confidence[0] == 1.0  # Coulomb friction: every draw and run needs it
    assert 0.0 < confidence[1] < 1.0  # viscous, at a threshold amid its critical ones
    assert confidence[2] < 0.5  # the inertia term only fits the noise


def test_a_term_that_takes_most_of_what_is_left_earns_its_place_under_the_threshold():
    """The selection's rule (select.earns_place): a gain above the threshold, or above a
    quarter of it that is at least half of what the term's groups leave unexplained."""
    from msarm.diagnose.select import earns_place

    assert earns_place(0.021, 0.9, 0.02)
    assert not earns_place(0.019, 0.9, 0.02)  # most of the residual is still unexplained
    # after an elasticity term explains 98.6 % of a length residual: 1.2 of the 1.4 % left
    assert earns_place(0.012, 0.014, 0.02)
    assert earns_place(0.006, 0.012, 0.02)  # exactly half of what is left
    assert not earns_place(0.0059, 0.012, 0.02)
    assert not earns_place(0.005, 0.006, 0.02)  # not above a quarter of the threshold
    assert not earns_place(float("nan"), 0.0, 0.02)
    # on a first step nothing is explained yet: the second way needs half of everything
    assert not earns_place(0.4, 1.0, 0.5) and earns_place(0.5, 1.0, 0.5)


def test_parameters_the_held_out_runs_do_not_need_are_left_out(arm, tmp_path):
    """A load cell with a bias and no scale error, commands a control period late: the
    sensor term's scale and the delay kernel's later taps are fixed at zero (said in a note),
    the rest found. Before, they took small values (scale -2e-4, taps up to 0.005) that
    pulled the bias 0.3 % and the delay 1 % off the plant's."""
    from msarm.plant.config import DelayConfig

    plant = only(
        sensor_noise=SensorNoiseConfig(enabled=True, tension_bias=-2.0),
        delay=DelayConfig(enabled=True, sensing_periods=0, actuation_periods=1),
    )
    logs = _logs(arm, tmp_path, plant)
    result = diagnose(arm, logs[:3], logs[3:], candidates=["sensor", "command_delay"], n_boot=0)
    assert set(result.names) == {"sensor", "command_delay"}
    by_name = {s.name: s for s in result.selected}
    effect = by_name["sensor"]
    sensor = dict(zip(effect.parameter_names, effect.parameters, strict=True))
    assert sensor["scale_minus_1[all]"] == 0.0
    assert np.isnan(effect.std).all()  # no bootstrap: no spread, not "0 +- 0" for those left out
    assert sensor["bias[all]"] == pytest.approx(-2.0, rel=0.01)
    assert any("scale_minus_1[all] left out (fixed at 0)" in n for n in by_name["sensor"].notes)
    delay = by_name["command_delay"]
    assert list(delay.parameters[1:]) == [0.0, 0.0, 0.0]
    assert delay.parameters[0] == pytest.approx(1.0, abs=0.01)
    assert any("w[2], w[3], w[4] left out" in n for n in delay.notes), delay.notes


def test_a_parameter_subset_is_its_terms_columns():
    from msarm.diagnose.cable_effects import CommandDelay, DriveCogging
    from msarm.diagnose.effects import (
        CoulombFriction,
        ParameterSubset,
        SensorBiasScale,
        StribeckFriction,
    )

    sensor = SensorBiasScale(shared=True, drive=True)
    assert sensor.parameter_groups() == ((0,), (1,))  # bias, scale: each kind alone
    assert CommandDelay(taps=3).parameter_groups() == ((2,), (1,), (0,))  # last tap first
    assert DriveCogging(24, 0.003, 4.0).parameter_groups() == ()
    assert CoulombFriction(n_joints=4).parameter_groups() == ()  # one kind: all or nothing
    subset = ParameterSubset(sensor, [0])
    assert subset.parameter_names == ("bias[all]",) and subset.left_out == ("scale_minus_1[all]",)
    from test_diagnose_effects import _make_signals

    from msarm.model import load_arm

    signals = _make_signals(load_arm(), seed=2)
    np.testing.assert_array_equal(subset.design(signals), sensor.design(signals)[..., [0]])
    assert subset.name == "sensor" and subset.groups == sensor.groups
    np.testing.assert_array_equal(subset.full([1.5]), [1.5, 0.0])
    for bad in ([], [1, 0], [2]):
        with pytest.raises(InputError, match="keep must be increasing indices"):
            ParameterSubset(sensor, bad)
    with pytest.raises(InputError, match="only a linear term"):
        ParameterSubset(StribeckFriction(joints=[0]), [0])


def _waves_term():
    """A linear term of five kinds: one strong, four weak, each weak one a sine of its own."""
    from msarm.diagnose.effects import CandidateEffect

    class Waves(CandidateEffect):
        name = "test_waves"
        memoryless = True
        kinds = ("a", "b", "c", "d", "e")

        def __init__(self, n_joints=4):
            self.channels = tuple(range(n_joints))
            self.parameter_names = tuple(f"{k}[{j}]" for k in self.kinds for j in self.channels)

        def design(self, signals):
            T, n = signals.q.shape
            time = signals.t[:, None] + np.zeros((1, n))
            features = [signals.qd / 0.3] + [
                np.sqrt(2.0) * np.sin(2.0 * np.pi * f * time + j)
                for j, f in enumerate((0.37, 0.53, 0.71, 0.89))
            ]
            out = np.zeros((T, n, len(features) * n))
            for k, feature in enumerate(features):
                for j in range(n):
                    out[:, j, k * n + j] = feature[:, j]
            return out

    return Waves()


def test_sets_left_out_together_stay_within_the_tolerance(arm, monkeypatch):
    """Four weak sets, each below the tolerance alone. Tried one by one against the last
    pruned state, sets could add up beyond it (a review measured a fall of 0.0025 on a
    benchmark's logs while the note said under 0.001). The budget is now the whole term's,
    against the unpruned model: here three of the four weak sets go, and the held-out share
    stays within 0.001 of the unpruned model's (0.00097 below it)."""
    from test_diagnose_effects import _make_signals
    from test_diagnose_stack import diagnosis_data

    import msarm.diagnose.select as select

    term = _waves_term()
    signals = _make_signals(arm, seed=7)
    theta = np.concatenate([np.ones(4)] + [np.full(4, 0.04)] * 4)
    pure = np.asarray(term.torque(signals, theta))
    rng = np.random.default_rng(7)
    torque = pure + 0.6 * pure.std() * rng.standard_normal(pure.shape)
    data = diagnosis_data(arm, signals, torque, [term])

    def share(result):
        before, after = result.waterfall[0]["joint"], result.waterfall[-1]["joint"]
        return 1.0 - (after / before) ** 2

    pruned = select.select_effects(data, n_boot=0, replay=False)
    monkeypatch.setattr(select, "PRUNE_TOLERANCE", -np.inf)  # never prune
    whole = select.select_effects(data, n_boot=0, replay=False)
    assert pruned.names == whole.names == ("test_waves",)
    assert share(whole) - share(pruned) < select.DEFAULT_THRESHOLD / 20  # 0.001
    left_out = [n for n in pruned.selected[0].notes if "left out" in n]
    assert int(np.sum(pruned.selected[0].parameters == 0.0)) == 12 and left_out


def test_a_set_the_training_runs_resolve_is_kept_though_the_held_out_runs_barely_need_it(
    arm, monkeypatch
):
    """A weak set (under the 0.001 tolerance on the held-out share) that six training runs
    resolve far from zero is kept; with the rule off it is fixed at 0 and the kind beside it
    absorbs it. Before, a winch's viscous level 31 jackknife errors from zero went that way,
    reported as 0 ± 0, with the Coulomb level 9 bootstrap deviations off the plant's."""
    from test_diagnose_effects import _make_signals
    from test_diagnose_stack import diagnosis_data

    import msarm.diagnose.select as select

    term = _waves_term()
    signals = _make_signals(arm, seed=3)
    strong = np.concatenate([np.ones(4), np.zeros(16)])
    scale = float(np.asarray(term.torque(signals, strong)).std())
    theta = strong + np.concatenate([np.zeros(4), np.full(4, 0.02 * scale), np.zeros(12)])
    pure = np.asarray(term.torque(signals, theta))
    torque = pure + 0.002 * scale * np.random.default_rng(3).standard_normal(pure.shape)
    data = diagnosis_data(arm, signals, torque, [term], n_train=6)
    kept = select.select_effects(data, n_boot=0, replay=False)
    (effect,) = kept.selected
    np.testing.assert_allclose(effect.parameters[4:8], theta[4:8], rtol=0.05)
    assert not any("b[0]" in n and "left out" in n for n in effect.notes), effect.notes
    monkeypatch.setattr(select, "RESOLVED_Z", np.inf)  # the rule off: held-out share alone
    pruned = select.select_effects(data, n_boot=0, replay=False)
    (effect,) = pruned.selected
    assert list(effect.parameters[4:8]) == [0.0] * 4  # left out: it adds under 0.001
    assert np.isnan(effect.std[4:8]).all()  # fixed, not estimated


def test_a_parameter_its_design_never_excites_is_not_resolved():
    """Zero in every fit and every jackknife error zero: `0 >= 10 * 0` had counted it as
    resolved, so a never-excited set could not be left out."""
    from types import SimpleNamespace

    import msarm.diagnose.select as select
    from msarm.diagnose.fitting import LinearSolver

    rng = np.random.default_rng(0)
    runs = np.repeat(np.arange(3), 50)
    design = np.zeros((150, 1, 2))
    design[:, 0, 0] = rng.standard_normal(150)  # parameter 0 excited, parameter 1 never
    left = 2.0 * design[:, :, 0] + 0.01 * rng.standard_normal((150, 1))
    sampled = SimpleNamespace(
        signals={"train": SimpleNamespace(run=runs)},
        design=lambda term, split: design,
        solver=lambda terms: LinearSolver(design),
    )
    term = SimpleNamespace(n_parameters=2)
    np.testing.assert_array_equal(select._resolved_by_runs(term, left, sampled), [True, False])


def _negative_coulomb_data(arm, scale):
    """Diagnosis data of a joint residual ``scale`` times a negative Coulomb friction with a
    friction rising as the speed squared and noise (four training runs, four held out)."""
    from test_diagnose_effects import _make_signals
    from test_diagnose_stack import diagnosis_data

    from msarm.diagnose.effects import CoulombFriction, StribeckFriction

    signals = _make_signals(arm, seed=4)
    rng = np.random.default_rng(0)
    torque = scale * (
        -0.2 * np.tanh(signals.qd / 0.01)
        + 0.3 * signals.qd * np.abs(signals.qd)
        + rng.normal(0.0, 0.002, size=signals.qd.shape)
    )
    pool = [StribeckFriction(viscous=True), CoulombFriction()]
    return diagnosis_data(arm, signals, torque, pool, n_train=4)


def test_a_final_fit_that_predicts_worse_than_the_step_wise_one_is_not_the_answer(arm):
    """Coulomb friction beside a Stribeck term (which has a Coulomb level of its own) can trade
    their levels along a direction the fit cannot see. On a residual of 0.1 mN m, as a
    noise-free simulation leaves, their joint optimum by variable projection ran off along it
    (IPOPT: Maximum_Iterations_Exceeded) and made the held-out gap up to 30,000 times the
    nominal model's; the answer is then the selection's step-wise fit, with a note, and the gap
    shrinks as the step scores say. The same residual 10 times larger keeps the optimum."""
    import msarm.diagnose.select as select
    from msarm.diagnose.stack import group_scores

    data = _negative_coulomb_data(arm, 1e-3)
    result = select.select_effects(data, n_boot=3, replay=False)
    assert result.names == ("coulomb", "stribeck")
    before, after = result.gap_before["joint"], result.gap_after["joint"]
    assert np.all(after < 0.5 * before)  # was up to 30,000 times ``before``
    assert result.search["final_fit"] == "blocks"
    assert "IPOPT: " in result.search["final_fit_rejected"]
    assert "held-out explained share" in result.search["final_fit_rejected"]
    # the answer is the model the step scores were taken on: its held-out share is the last
    prediction = sum(
        np.asarray(term.torque(data.hold, s.parameters))
        for s in result.selected
        for term in data.candidates
        if term.name == s.name
    )
    share = group_scores(data.layout, data.r_hold, prediction)["joint"]
    assert share == pytest.approx(result.explained_variance[-1], abs=1e-9)
    for effect in result.selected:
        assert np.all(np.isfinite(effect.parameters)) and np.all(np.isfinite(effect.std))
        levels = np.array([unit == "N m" for unit in effect.parameter_units])
        assert np.max(np.abs(effect.parameters[levels])) < 1e-2  # not 1e7 N m
        assert any("not the named effects' joint optimum" in note for note in effect.notes)
    assert "joint optimum (variable projection) was not kept (IPOPT: " in result.to_markdown()
    # ten times larger, the joint optimum is sound and predicts as well: it is kept
    kept = select.select_effects(_negative_coulomb_data(arm, 1e-2), n_boot=0, replay=False)
    assert kept.names == ("coulomb", "stribeck")
    assert kept.search["final_fit"] == "projection" and kept.search["final_fit_rejected"] is None
    assert not any("joint optimum" in note for s in kept.selected for note in s.notes)


def test_a_bootstrap_draw_whose_joint_fit_goes_astray_is_refitted_by_blocks(arm, monkeypatch):
    """A draw's joint optimum that ends worse on its training runs than its start (the answer)
    is not an optimum: that draw is refitted by blocks, and the answer says how many were."""
    import msarm.diagnose.select as select

    data = _synthetic_data(arm, capstan=False)
    healthy = select.select_effects(data, n_boot=6, seed=1, replay=False)
    assert healthy.search["bootstrap_refits_by_blocks"] == 0
    fit_together = select.fit_together

    def astray(terms, sampled, weights=None, initial=None, rounds=10, method="projection"):
        fitted = fit_together(terms, sampled, weights, initial, rounds, method)
        if weights is None or method != "projection":
            return fitted
        return replace(fitted, parameters=tuple(1e6 * (p + 1.0) for p in fitted.parameters))

    monkeypatch.setattr(select, "fit_together", astray)
    result = select.select_effects(data, n_boot=6, seed=1, replay=False)
    assert result.names == healthy.names and result.search["final_fit"] == "projection"
    assert result.search["bootstrap_refits_by_blocks"] == 6
    for effect, reference in zip(result.selected, healthy.selected, strict=True):
        np.testing.assert_array_equal(effect.parameters, reference.parameters)
        # refitted by blocks from the answer: a spread of the same size, not 1e6
        assert np.all(effect.std < 10 * reference.std + 1e-6)
