"""The compensator's commands and its resumable training, on a small recipe of their own.

The recipe: 4 runs of 20 s (2 / 1 / 1), one feedforward round, 6 epochs a round. These tests
need a trained compensator and its kept runs but not the shipped recipe's numbers, so they run
beside the shipped recipe's end-to-end tests (``test_compensation_pipeline.py``) instead of
after them on the same worker: an interrupted training resumes to the uninterrupted one's
weights; ``msarm train`` reads a recipe; ``msarm compare`` and ``msarm track --ff`` run with
the compensator.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from msarm.cli import app
from msarm.compensation.checkpoint import CheckpointError, Compensator
from msarm.compensation.pipeline import CompensatorRecipe, train_compensator
from msarm.errors import MsarmWarning
from msarm.io.config import write_config
from msarm.plant import DEFAULT_PLANT


class StopTrainingError(Exception):
    """Raised from an epoch callback: the training is cut there."""


@pytest.fixture(scope="module")
def small(tmp_path_factory, arm):
    """The small recipe and its report, trained once without interruption; its runs are kept."""
    folder = tmp_path_factory.mktemp("small_recipe")
    shipped = CompensatorRecipe()
    recipe = replace(
        shipped,
        data=replace(
            shipped.data, n_runs=4, split=(0.5, 0.25, 0.25), rounds=1, folder=str(folder / "data")
        ),
        network=replace(shipped.network, max_epochs=6, patience=20),
        checkpoint=str(folder / "compensator.pt"),
    )
    report = train_compensator(arm, recipe, DEFAULT_PLANT)
    return recipe, report


def test_an_interrupted_training_resumes_to_the_same_compensator(small, arm, tmp_path):
    """The recipe again on the kept runs, cut in round 1 at epoch 3 and resumed: the
    uninterrupted training's weights bit for bit, no run simulated again; then another
    learning rate's state starts over."""
    recipe, _ = small
    rounds: list[int] = []
    epochs: dict[int, list[int]] = {}

    def note_round(round_, _):
        rounds.append(round_)

    def stop_in_round_1_at_epoch_3(epoch, *_):
        if rounds[-1] == 1 and epoch == 3:
            raise StopTrainingError

    def note_epoch(epoch, *_):
        epochs.setdefault(rounds[-1], []).append(epoch)

    cut = replace(recipe, checkpoint=str(tmp_path / "cut.pt"))
    with pytest.raises(StopTrainingError):
        train_compensator(
            arm, cut, DEFAULT_PLANT, on_round=note_round, on_epoch=stop_in_round_1_at_epoch_3
        )
    assert rounds == [0, 1]
    rounds.clear()
    reused = []
    train_compensator(
        arm,
        cut,
        DEFAULT_PLANT,
        on_round=note_round,
        on_epoch=note_epoch,
        on_run=lambda done, total, was_reused: reused.append(was_reused),
    )
    assert rounds == [0, 1] and reused and all(reused)  # no run simulated again
    assert 0 not in epochs  # round 0 had finished: taken as it was
    assert epochs[1] == [4, 5, 6]  # round 1 resumed after epoch 3
    for first, second in zip(
        Compensator.load(recipe.checkpoint).layer_weights(),
        Compensator.load(cut.checkpoint).layer_weights(),
        strict=True,
    ):
        for a, b in zip(first, second, strict=True):
            np.testing.assert_array_equal(a, b)
    # a finished training's state, then another learning rate: the round starts over
    other = replace(cut, network=replace(cut.network, learning_rate=cut.network.learning_rate / 2))
    other = replace(other, data=replace(other.data, rounds=0))
    rounds.clear()
    epochs.clear()

    def stop_at_the_first_epoch(epoch, *_):
        note_epoch(epoch)
        raise StopTrainingError

    with (
        pytest.warns(MsarmWarning, match="learning_rate.*round 0 of the training starts over"),
        pytest.raises(StopTrainingError),
    ):
        train_compensator(
            arm, other, DEFAULT_PLANT, on_round=note_round, on_epoch=stop_at_the_first_epoch
        )
    assert epochs == {0: [1]}


def test_train_command_reads_a_recipe(tmp_path, small):
    recipe, _ = small
    path = tmp_path / "recipe.yaml"
    short = replace(
        recipe,
        data=replace(recipe.data, rounds=0),
        network=replace(recipe.network, max_epochs=3),
    )
    write_config(replace(short, checkpoint=str(tmp_path / "cli.pt")), path)
    result = CliRunner().invoke(app, ["train", "--config", str(path), "--json"])
    assert result.exit_code == 0, result.output
    assert '"test_r2"' in result.output


def test_the_compare_and_track_commands_run_with_the_compensator(tmp_path, small):
    recipe, report = small
    out = tmp_path / "compare"
    result = CliRunner().invoke(
        app, ["compare", "--ff", recipe.checkpoint, "--out", str(out), "--json"]
    )
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)  # progress went to stderr
    assert payload["held_out"] == [f"random-{seed}" for seed in report.split["test"]]
    assert payload["tasks"][:4] == [f"table1-{k}" for k in range(1, 5)]
    assert payload["final_error_ratio_held_out"] > 1  # the compensator helps on held-out tasks
    assert all(Path(path).is_file() for path in payload["files"].values())
    assert {"error_statistics", "json", "trajectories_table1-1"} <= set(payload["files"])
    # the same network retrained (its file records other times): every run is reused
    retrained = Compensator.load(recipe.checkpoint)
    retrained.metadata["training"] = {**retrained.metadata["training"], "collect_time_s": -1.0}
    copy = retrained.save(tmp_path / "retrained.pt")
    assert copy.read_bytes() != Path(recipe.checkpoint).read_bytes()
    again = CliRunner().invoke(app, ["compare", "--ff", str(copy), "--out", str(out), "--json"])
    assert again.exit_code == 0, again.output
    labels = [line for line in again.stderr.splitlines() if line.startswith("compare [")]
    assert len(labels) == 2 * len(payload["tasks"])
    assert all(line.endswith("(cached)") for line in labels), labels
    assert json.loads(again.stdout)["tasks"] == payload["tasks"]
    track_out = tmp_path / "track"
    ff = ["track", "--task", "table1-2", "--ff", recipe.checkpoint, "--out", str(track_out)]
    with warnings.catch_warnings():  # on the plant it was trained on: no warning about it
        warnings.filterwarnings("error", "was trained on the plant", MsarmWarning)
        result = CliRunner().invoke(app, [*ff, "--json"])
    assert result.exit_code == 0, result.output
    metrics = json.loads(result.stdout)
    assert metrics["task"] == "table1-2" and metrics["final_error_mm"] < 1.0
    names = {"log.parquet", "log.truth.parquet", "config.yaml", "metrics.json", "joints.png"}
    assert names <= {p.name for p in track_out.iterdir()}
    # the run records the compensator it ran with
    assert f"feedforward: {recipe.checkpoint}" in (track_out / "config.yaml").read_text()
    # on the plant it was trained on: no warning; on another: one that names the differences
    other = [*ff[:-1], str(tmp_path / "track-ideal"), "--plant", "ideal", "--json"]
    with pytest.warns(MsarmWarning) as caught:
        result = CliRunner().invoke(app, other)
    assert result.exit_code == 0, result.output
    (warning,) = [str(w.message) for w in caught if "was trained on the plant" in str(w.message)]
    assert "trained on the plant 'default'; this plant 'ideal' differs in 5" in warning
    assert "effects.sheath_friction.enabled: True -> False" in warning


def test_the_checkpoint_records_the_plant_it_was_trained_on(small):
    from msarm.compensation.feedforward import (
        plant_differences,
        trained_plant,
        warn_if_other_plant,
    )
    from msarm.io.config import config_to_dict
    from msarm.plant import IDEAL_PLANT

    recipe, _ = small
    compensator = Compensator.load(recipe.checkpoint)
    assert compensator.metadata["training"]["plant"] == config_to_dict(DEFAULT_PLANT)
    assert trained_plant(compensator) == DEFAULT_PLANT
    renamed = replace(DEFAULT_PLANT, name="my-robot")
    assert plant_differences(DEFAULT_PLANT, renamed) == []  # names aside
    slower = replace(DEFAULT_PLANT, timestep=0.0005)
    assert plant_differences(DEFAULT_PLANT, slower) == ["timestep: 0.001 -> 0.0005"]
    with pytest.warns(MsarmWarning, match=r"differs in 1 setting\(s\) \(timestep"):
        assert warn_if_other_plant(compensator, slower, "mine.pt") == ["timestep: 0.001 -> 0.0005"]
    with pytest.warns(MsarmWarning, match=r"differs in 5 setting.*; and 2 more\)"):
        warn_if_other_plant(compensator, IDEAL_PLANT, "mine.pt")
    # a checkpoint from before the record: its recipe's preset, or nothing for a plant file
    older = Compensator.load(recipe.checkpoint)
    del older.metadata["training"]["plant"]
    assert trained_plant(older) == DEFAULT_PLANT
    older.metadata["recipe"]["data"]["plant"] = "my_plant.yaml"
    assert trained_plant(older) is None
    assert warn_if_other_plant(older, IDEAL_PLANT) == []
    older.metadata["training"]["plant"] = {"timestep": "fast"}  # not a plant: unknown
    assert trained_plant(older) is None


def test_bench_sim_times_the_loop_with_the_compensator(small):
    recipe, _ = small
    command = ["bench", "sim", "--plant", "ideal", "--best-of", "1", "--ff", recipe.checkpoint]
    result = CliRunner().invoke(app, [*command, "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    # its features are the reference's: the loop with the feedforward runs compiled
    assert report["feedforward_path"] == "compiled"
    assert report["feedforward_s"] > 0 and report["feedforward_python_s"] > 0
    missing = CliRunner().invoke(app, ["bench", "sim", "--ff", "no/such/compensator.pt"])
    # msarm's entry point prints it as "msarm: error: ..." (exit status 2)
    assert isinstance(missing.exception, CheckpointError)
    assert "no/such/compensator.pt: compensator file not found" in str(missing.exception)
    assert "run `msarm train`, or `make demo`, to make one" in str(missing.exception)
