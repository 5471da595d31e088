"""The compensator end to end: train on a few runs, compare on a held-out run."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from msarm.cli import app
from msarm.compensation.checkpoint import CheckpointError, Compensator
from msarm.compensation.compare import SHEATH_ONLY, WITH, WITHOUT, compare_feedforward
from msarm.compensation.feedforward import (
    LearnedFeedforward,
    load_feedforward,
    trained_controller,
)
from msarm.compensation.pipeline import TUNED_CONTROLLER, CompensatorRecipe, train_compensator
from msarm.control import ArmControllerConfig
from msarm.io.code_version import code_fingerprint
from msarm.io.config import load_config
from msarm.model import load_arm
from msarm.plant import DEFAULT_PLANT
from msarm.tasks.evaluate import SLACK_THRESHOLD

RECIPE = Path(__file__).resolve().parents[1] / "training" / "compensator.yaml"


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """The shipped recipe (paper-sized data set, 14 runs: 10/2/2; its features, controller
    gains and iterative rounds), with its files in a temporary folder."""
    folder = tmp_path_factory.mktemp("compensator")
    shipped = load_config(RECIPE, CompensatorRecipe)
    recipe = replace(
        shipped,
        data=replace(shipped.data, folder=str(folder / "data")),
        checkpoint=str(folder / "compensator.pt"),
    )
    arm = load_arm()
    report = train_compensator(arm, recipe, DEFAULT_PLANT)
    return arm, recipe, report, folder


def test_training_writes_a_checkpoint_for_this_model(trained):
    arm, recipe, report, _ = trained
    assert report.split == {
        "train": list(range(1000, 1010)),
        "validation": [1010, 1011],
        "test": [1012, 1013],
    }
    compensator = Compensator.load(recipe.checkpoint, expected_model_sha256=arm.sha256)
    assert compensator.metadata["feature_spec"]["groups"] == list(recipe.features.groups)
    # the gains it was trained with travel with it (compare and track --ff run them)
    assert trained_controller(compensator) == recipe.controller != ArmControllerConfig()
    del compensator.metadata["recipe"]
    with pytest.raises(CheckpointError, match="records no controller gains"):
        trained_controller(compensator)
    assert all(r2 > 0 for r2 in report.test_r2)  # explains some held-out T_f variance
    # the sheath stage was identified from the runs and travels with the network
    mu = DEFAULT_PLANT.effects.sheath_friction.mu
    assert report.sheath is not None and abs(report.sheath.mu - mu) < 0.1 * mu
    saved = Compensator.load(recipe.checkpoint).metadata["sheath"]
    assert saved["parameters"]["mu"] == report.sheath.mu
    assert load_feedforward(recipe.checkpoint, arm).sheath is not None


def test_feedforward_improves_tracking_and_final_error_on_the_held_out_tasks(trained, monkeypatch):
    arm, recipe, report, folder = trained
    feedforward = load_feedforward(recipe.checkpoint, arm)
    stage_alone = LearnedFeedforward(arm, None, feedforward.sheath)

    def run_comparison(feedforward_id="checkpoint-1", progress=None):
        return compare_feedforward(
            arm,
            feedforward,
            DEFAULT_PLANT,
            recipe.controller,
            report.split["test"],
            folder / "compare",
            parts={SHEATH_ONLY: stage_alone},
            feedforward_id=feedforward_id,
            progress=progress,
        )

    comparison = run_comparison()
    assert comparison.labels == (WITHOUT, WITH, SHEATH_ONLY)
    for task in comparison.held_out:
        without, with_ff = comparison.metrics[task][WITHOUT], comparison.metrics[task][WITH]
        assert with_ff.completed
        assert np.mean(with_ff.joint_rmse) < 0.8 * np.mean(without.joint_rmse)
        assert with_ff.final_error_mm < without.final_error_mm
        assert comparison.metrics[task][SHEATH_ONLY].final_error_mm < without.final_error_mm
    # the true joint angles' final error is the encoders' one up to their noise (1e-4 rad)
    for task in comparison.tasks:
        for label in comparison.labels:
            measured = comparison.metrics[task][label].final_error_mm
            assert abs(comparison.true_final_error_mm[task][label] - measured) < 0.15
    assert comparison.as_dict()["true_final_error_ratio_held_out"] > 1
    # the stage asks the motors for less than the 5 N floor while a cable pays out; the
    # cables stay taut at their insertions all the same (ground truth, above the slack level)
    for task in comparison.tasks:
        for label in comparison.labels:
            assert comparison.true_min_insertion_tension[task][label] > SLACK_THRESHOLD
    assert (folder / "compare" / "error_statistics.png").is_file()

    # run again: every run is taken from the folder (none simulated), the same numbers
    import msarm.compensation.compare as compare_module

    def refuse(*args, **kwargs):
        raise AssertionError("a kept run was simulated again")

    monkeypatch.setattr(compare_module, "track", refuse)
    labels = []
    again = run_comparison(progress=labels.append)
    assert len(labels) == 3 * len(comparison.tasks)
    assert all(label.endswith("(cached)") for label in labels)
    assert json.dumps(again.as_dict()) == json.dumps(comparison.as_dict())
    # another checkpoint: the runs without feedforward are kept, the others run again
    labels.clear()
    with pytest.raises(AssertionError, match="simulated again"):
        run_comparison(feedforward_id="checkpoint-2", progress=labels.append)
    assert labels == ["table1-1, without feedforward (cached)", "table1-1, with feedforward"]


def test_checkpoint_for_another_model_is_refused(trained, tmp_path):
    arm, recipe, _, _ = trained
    other = replace(arm, sha256="0" * 64)
    with pytest.raises(CheckpointError, match="made for another robot model: its model SHA-256 is"):
        load_feedforward(recipe.checkpoint, other)


def test_compare_parts_needs_a_compensator_with_a_sheath_stage(tmp_path, trained):
    _, recipe, _, _ = trained
    compensator = Compensator.load(recipe.checkpoint)
    del compensator.metadata["sheath"]
    path = compensator.save(tmp_path / "network_alone.pt")
    result = CliRunner().invoke(app, ["compare", "--ff", str(path), "--parts"])
    assert result.exit_code != 0
    assert "has no sheath stage" in result.output


def test_compare_refuses_extra_tasks_that_were_trained_on(tmp_path, trained):
    _, recipe, _, _ = trained
    compensator = Compensator.load(recipe.checkpoint)
    compensator.metadata["split"]["train"] = [5001, *compensator.metadata["split"]["train"]]
    path = compensator.save(tmp_path / "trained_on_5001.pt")
    result = CliRunner().invoke(app, ["compare", "--ff", str(path), "--extra", "2"])
    assert result.exit_code != 0
    assert "random-[5001]" in result.output and "were trained on" in result.output


def test_the_shipped_recipe_is_the_default():
    """msarm train outside the repository (no training/compensator.yaml) trains the same."""
    assert load_config(RECIPE, CompensatorRecipe) == CompensatorRecipe()
    assert CompensatorRecipe().controller == TUNED_CONTROLLER != ArmControllerConfig()


def test_a_checkpoint_whose_parts_do_not_fit_is_refused_with_its_file(trained, tmp_path):
    arm, recipe, _, _ = trained

    def edited(name, change):
        compensator = Compensator.load(recipe.checkpoint)
        change(compensator.metadata)
        return compensator.save(tmp_path / f"{name}.pt")

    cases = {
        "no_recipe": (lambda m: m.pop("recipe"), "records no controller gains"),
        "two_gains": (
            lambda m: m["recipe"]["controller"].update(kp=[1.0, 2.0]),
            r"its recipe.controller kp has 2 gains, the arm has 4 joints",
        ),
        "bad_mu": (
            lambda m: m["sheath"]["parameters"].update(mu=-1.0),
            "invalid sheath stage: sheath mu must be",
        ),
        "other_features": (
            lambda m: m["feature_spec"].update(groups=["q", "qdot"]),
            "its feature spec gives 8 inputs, its network takes 25",
        ),
    }
    for name, (change, message) in cases.items():
        path = edited(name, change)
        with pytest.raises(CheckpointError, match=message) as caught:
            load_feedforward(path, arm)
        assert str(path) in str(caught.value)
    path = edited("no_split", lambda m: m["split"].pop("test"))
    result = CliRunner().invoke(app, ["compare", "--ff", str(path)])
    assert isinstance(result.exception, CheckpointError)
    assert "records no run split" in str(result.exception)


def test_a_cached_run_is_reused_only_whole_undiverged_of_this_model_and_code(trained, tmp_path):
    import json
    import shutil

    from msarm.compensation.dataset import reusable_run as _reusable
    from msarm.tasks.track import TrackSettings

    arm, recipe, _, _ = trained
    run = tmp_path / "run-1000"
    shutil.copytree(Path(recipe.data.folder) / "run-1000", run)
    settings = load_config(run / "config.yaml", TrackSettings)
    assert _reusable(run, settings, arm.sha256)
    assert _reusable(run, settings, arm.sha256.upper())  # a hash is compared without case
    assert not _reusable(run, settings, "0" * 64)  # recorded with another model file
    assert not _reusable(run, replace(settings, seed=settings.seed + 1), arm.sha256)
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["code"] == code_fingerprint("simulation")  # recorded by the run
    # made by another version of msarm (or of its libraries): simulated again
    (run / "metrics.json").write_text(json.dumps({**metrics, "code": "0" * 64}))
    assert not _reusable(run, settings, arm.sha256)
    (run / "metrics.json").write_text(json.dumps({k: v for k, v in metrics.items() if k != "code"}))
    assert not _reusable(run, settings, arm.sha256)  # from before the code was recorded
    (run / "metrics.json").write_text(json.dumps(metrics))
    assert _reusable(run, settings, arm.sha256)
    (run / "metrics.json").write_text(json.dumps({**metrics, "diverged": {"time": 3.0}}))
    assert not _reusable(run, settings, arm.sha256)  # a diverged run is simulated again
    (run / "metrics.json").unlink()
    assert not _reusable(run, settings, arm.sha256)  # metrics are written last: cut short
