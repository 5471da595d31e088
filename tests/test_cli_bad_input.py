"""Bad input to ``msarm train``, ``track``, ``compare`` and ``arm``: one line, exit code 2.

Each mistake is refused up front (before any run is collected or any output folder made),
with the file and the key named and what was expected, not as a traceback or after minutes
of work.
"""

from __future__ import annotations

import json
import re
import sys
import zipfile
from pathlib import Path

import pytest
import torch

from msarm.compensation.checkpoint import CheckpointError, Compensator

#: A small recipe: three short runs, no further round, no sheath stage.
TINY = """\
name: tiny
data:
  n_runs: 3
  rounds: 0
  folder: {folder}
  first_seed: {first_seed}
network:
  max_epochs: 2
sheath:
  enabled: false
checkpoint: {checkpoint}
"""


def _error(monkeypatch, capsys, *args: str) -> str:
    """Run ``msarm ARGS`` through the console entry point; the error line (exit code 2)."""
    from msarm.cli import main

    monkeypatch.setattr(sys, "argv", ["msarm", *args])
    with pytest.raises(SystemExit) as exit_info:
        main()
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("msarm: error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture
def no_training(monkeypatch):
    """Fail the test if ``msarm train`` gets as far as training (collecting runs)."""
    import msarm.compensation.pipeline as pipeline

    def fake(*args, **kwargs):
        raise AssertionError("train_compensator was called: the recipe was not checked first")

    monkeypatch.setattr(pipeline, "train_compensator", fake)


def _recipe(tmp_path: Path, extra: str = "", **values) -> Path:
    fields = {
        "folder": tmp_path / "data",
        "first_seed": 1000,
        "checkpoint": tmp_path / "out" / "c.pt",
        **values,
    }
    path = tmp_path / "recipe.yaml"
    path.write_text(TINY.format(**fields) + extra)
    return path


def test_train_refuses_a_data_folder_that_is_a_file(monkeypatch, capsys, tmp_path, no_training):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    recipe = _recipe(tmp_path, folder=blocker)
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert f"{recipe}: key 'data.folder': {blocker} is a file; expected a folder" in line
    recipe = _recipe(tmp_path, folder=blocker / "runs")  # a file on the way
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert f"{recipe}: key 'data.folder'" in line and f"{blocker} is a file" in line


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_train_refuses_a_data_folder_that_cannot_be_created(
    monkeypatch, capsys, tmp_path, no_training
):
    """A folder under /proc cannot be made, even by root: before, a traceback at the first
    write (FileNotFoundError); now one line naming the key, the folder and the reason."""
    recipe = _recipe(tmp_path, folder="/proc/msarm-no-such-folder/runs")
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert (
        f"{recipe}: key 'data.folder': cannot create the folder /proc/msarm-no-such-folder/runs ("
        in line
    )
    assert "expected a folder that can be written" in line


def test_train_names_the_recipe_for_a_split_that_leaves_no_training_run(
    monkeypatch, capsys, tmp_path, no_training
):
    recipe = _recipe(tmp_path)
    recipe.write_text(
        recipe.read_text().replace("n_runs: 3", "n_runs: 4\n  split: [0.1, 0.45, 0.45]")
    )
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert f"{recipe}: key 'data': invalid DataConfig: n_runs and split: 4 runs leave none" in line
    assert "expected more runs or a larger training share" in line


def test_train_refuses_an_empty_data_folder(monkeypatch, capsys, tmp_path, no_training):
    # Path("") is the working directory: the runs were written all over it
    recipe = _recipe(tmp_path, folder='""')
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert f"{recipe}: key 'data': invalid DataConfig: folder must name a folder" in line


def test_train_names_the_recipe_for_gains_of_the_wrong_count(
    monkeypatch, capsys, tmp_path, no_training
):
    recipe = _recipe(tmp_path, extra="controller:\n  kp: [90, 90, 45]\n")
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert f"{recipe}: key 'controller': controller kp needs 4 gains, got (90.0, 90.0, 45.0)" in (
        line
    )


def test_train_refuses_a_checkpoint_in_a_file(monkeypatch, capsys, tmp_path, no_training):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    recipe = _recipe(tmp_path, checkpoint=blocker / "c.pt")
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert f"{recipe}: key 'checkpoint': {blocker / 'c.pt'}: {blocker} is a file" in line
    assert not (tmp_path / "data").exists()


def test_train_refuses_features_that_read_another_drum_than_the_plants(
    monkeypatch, capsys, tmp_path, no_training
):
    plant = tmp_path / "plant.yaml"
    plant.write_text("name: big-drums\nwinch: {drum_radius: 0.005}\n")
    recipe = _recipe(tmp_path, extra="features:\n  drum_radius: 0.003\n")
    text = recipe.read_text().replace("data:\n", f"data:\n  plant: {plant}\n")
    recipe.write_text(text)
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert f"{recipe}: key 'features.drum_radius' is 0.003 m" in line
    assert "'big-drums' has winch.drum_radius 0.005 m" in line
    assert "set features.drum_radius: 0.005" in line
    assert not (tmp_path / "data").exists()


def test_train_refuses_a_checkpoint_that_is_a_folder(monkeypatch, capsys, tmp_path, no_training):
    folder = tmp_path / "a_folder"
    folder.mkdir()
    recipe = _recipe(tmp_path, checkpoint=folder)
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert f"{recipe}: key 'checkpoint': {folder} is a folder; expected the path of" in line
    assert str(folder / "compensator.pt") in line


def test_train_compensator_checks_its_paths_before_collecting(arm, monkeypatch, tmp_path):
    import msarm.compensation.pipeline as pipeline
    from msarm.errors import ConfigError
    from msarm.io.config import load_config
    from msarm.plant.config import DEFAULT_PLANT

    def collect(*args, **kwargs):
        raise AssertionError("runs collected before the recipe's paths were checked")

    monkeypatch.setattr(pipeline, "collect_runs", collect)
    (tmp_path / "a_folder").mkdir()
    recipe = load_config(
        _recipe(tmp_path, checkpoint=tmp_path / "a_folder"), pipeline.CompensatorRecipe
    )
    with pytest.raises(ConfigError, match=r"the recipe: key 'checkpoint': .* is a folder"):
        pipeline.train_compensator(arm, recipe, DEFAULT_PLANT)


@pytest.mark.parametrize(
    "extra,first_seed,expected",
    [
        ("", -5, "key 'data.first_seed' must be an integer >= 0"),
        ("target:\n  window: 1\n  polyorder: -1\n", 1000, "key 'target.polyorder' must be"),
        (  # refused before any run (until 2026-11-29: after collecting them all)
            "target:\n  window: 5001\n",
            1000,
            "key 'target.window' is 5001 samples, more than a run has (5000: a 20 s random "
            "task at controller.rate_hz 250 Hz)",
        ),
    ],
)
def test_train_refuses_negative_seeds_and_orders(
    monkeypatch, capsys, tmp_path, no_training, extra, first_seed, expected
):
    recipe = _recipe(tmp_path, extra, first_seed=first_seed)
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert str(recipe) in line and expected in line
    assert "unknown task" not in line


def test_train_names_the_recipes_control_rate(monkeypatch, capsys, tmp_path, no_training):
    recipe = _recipe(tmp_path, "controller:\n  rate_hz: 333\n")
    line = _error(monkeypatch, capsys, "train", "--config", str(recipe))
    assert f"{recipe}: controller.rate_hz 333 gives a control period of 0.003003 s" in line
    assert "expected a rate that divides 1000 Hz" in line


def test_track_names_a_plant_step_that_does_not_fit_before_making_the_folder(
    monkeypatch, capsys, tmp_path
):
    plant = tmp_path / "fine.yaml"
    plant.write_text("timestep: 0.0007\n")
    out = tmp_path / "run"
    line = _error(monkeypatch, capsys, "track", "--plant", str(plant), "--out", str(out))
    assert f"{plant}: the plant's timestep 0.0007 s does not divide the control period" in line
    assert "e.g. 0.001, 0.0008, 0.0005" in line
    assert not out.exists()


@pytest.mark.parametrize(
    "args,expected",
    [
        (("track", "--plant"), "is a folder, expected a plant YAML file"),
        (("track", "--ff"), "is a folder, expected the compensator checkpoint file"),
        (("track", "--controller"), "--controller: {} is a folder, expected a YAML file"),
        (("arm", "--model"), "is a folder, expected an MJCF .xml model file"),
        (("train", "--config"), "--config: {} is a folder, expected a training recipe file"),
        (("compare", "--ff"), "--ff: {} is a folder, expected a compensator checkpoint file"),
    ],
)
def test_a_folder_given_for_a_file_is_said_to_be_one(monkeypatch, capsys, tmp_path, args, expected):
    line = _error(monkeypatch, capsys, *args, str(tmp_path))
    assert expected.format(tmp_path) in line and str(tmp_path) in line
    assert "not found" not in line


def test_a_file_that_is_not_a_checkpoint_is_said_to_be_not_one(monkeypatch, capsys, tmp_path):
    archive = tmp_path / "archive.pt"
    with zipfile.ZipFile(archive, "w") as z:
        z.writestr("hello.txt", "hi")
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    for path in (archive, other):
        line = _error(monkeypatch, capsys, "track", "--ff", str(path))
        assert f"{path}: not " in line and "not an msarm compensator checkpoint" in line
        assert "expected the compensator checkpoint file that msarm train writes" in line
        assert "enforce" not in line and "inline_container" not in line
        assert "format None" not in line
    with pytest.raises(CheckpointError, match="no 'format' tag; its keys: 'weights'"):
        Compensator.load(other)


def test_track_names_a_cable_robots_run_config_given_as_controller(monkeypatch, capsys, tmp_path):
    """It said "unknown key 'controller'" of a file that has one."""
    config = tmp_path / "config.yaml"
    config.write_text("controller: hc-e\ncontroller_options: {}\ntrajectory: triangle-12\n")
    line = _error(monkeypatch, capsys, "track", "--controller", str(config))
    assert f"{config}: its 'controller' is the name 'hc-e'" in line
    assert "this is a cable robot's run config (msarm cdpr run), not one of the arm's" in line


def test_an_out_folder_made_for_a_refused_command_is_not_left_behind(monkeypatch, capsys, tmp_path):
    """diagnose made --out, then refused its logs, and left the empty folders; an --out that
    existed, or holds files, is kept."""
    from msarm.cli import common

    monkeypatch.setattr(common, "CREATED_FOLDERS", [])
    out = tmp_path / "new" / "deeper"
    first, second = tmp_path / "a.parquet", tmp_path / "b.parquet"
    first.write_text("not a log")
    second.write_text("not a log")  # refused after --out is made: one run under two names
    from msarm.cli import main

    def refused(folder):
        monkeypatch.setattr(sys, "argv", ["msarm", "diagnose", str(first), str(second)])
        sys.argv += ["--out", str(folder)]
        with pytest.raises(SystemExit) as exit_info:
            main()
        assert exit_info.value.code == 2
        return capsys.readouterr().err

    assert "has the same contents as" in refused(out)
    assert common.CREATED_FOLDERS == [] and not (tmp_path / "new").exists()
    kept = tmp_path / "kept"
    kept.mkdir()
    refused(kept)
    assert kept.is_dir()


def test_a_plant_named_like_a_run_folders_suffix_is_refused(monkeypatch, capsys, tmp_path):
    """A plant file default-s3.yaml wrote into the default plant's seed-3 folder."""
    plant = tmp_path / "default-s3.yaml"
    plant.write_text("effects:\n  sheath_friction:\n    enabled: false\n")
    line = _error(monkeypatch, capsys, "track", "--plant", str(plant))
    assert "the file's plant is named 'default-s3', which ends like a run folder's suffix" in line
    named = tmp_path / "mine.yaml"
    named.write_text("name: mine-ff\n")
    line = _error(monkeypatch, capsys, "cdpr", "run", "--plant", str(named))
    assert "named 'mine-ff', which ends like a run folder's suffix (-ff:" in line
    bare = tmp_path / "s3.yaml"  # the cable robot's default plant leaves its name out
    bare.write_text("drive: {default_mode: p}\n")
    line = _error(monkeypatch, capsys, "cdpr", "run", "--plant", str(bare))
    assert "named 's3', which ends like a run folder's suffix (s3:" in line


def test_bench_sim_names_an_odd_plant_step_and_a_diverging_plant(monkeypatch, capsys, tmp_path):
    """The step was refused without its file; a diverging plant was reported at the end of
    a 20 s timed call (t = 20 s, a wrong state) instead of where it diverged."""
    odd = tmp_path / "odd.yaml"
    odd.write_text("timestep: 0.0003\n")
    line = _error(monkeypatch, capsys, "bench", "sim", "--plant", str(odd))
    assert f"{odd}: the plant's timestep 0.0003 s does not divide the control period" in line
    stiff = tmp_path / "stiff.yaml"
    stiff.write_text("effects:\n  elasticity:\n    stiffness: 1.0e9\n    damping: 0\n")
    line = _error(monkeypatch, capsys, "bench", "sim", "--plant", str(stiff), "--best-of", "1")
    found = re.search(
        r"plant 'stiff': the closed loop diverges on table1-1 \(simulation diverged at "
        r"t = ([0-9.]+) s",
        line,
    )
    assert found and float(found.group(1)) < 1.0  # where it diverged, not the call's end


def test_track_refuses_a_delay_as_long_as_the_task(monkeypatch, capsys, tmp_path):
    """A 40 s delay on a 20 s task ran to the end with a 565 mm final error and exit 0."""
    slow = tmp_path / "slow.yaml"
    slow.write_text("effects:\n  delay: {enabled: true, sensing_periods: 5000}\n")
    out = tmp_path / "run"
    line = _error(monkeypatch, capsys, "track", "--plant", str(slow), "--out", str(out))
    assert "effects.delay: a delay of 5000 control periods is as long as task 'table1-1'" in line
    assert not out.exists()


def test_track_says_on_stderr_where_a_run_diverged(monkeypatch, capsys, tmp_path):
    """The error went to stdout (into the --json result only) while MuJoCo's own warning, with
    another time, went to stderr and to MUJOCO_LOG.TXT in the working folder."""
    from msarm.cli import main

    stiff = tmp_path / "stiff.yaml"
    stiff.write_text("name: stiff\neffects:\n  elasticity: {stiffness: 1.0e9}\n")
    monkeypatch.chdir(tmp_path)
    argv = ["msarm", "track", "--plant", str(stiff), "--out", "run", "--json"]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 1
    captured = capsys.readouterr()
    lines = [line for line in captured.err.splitlines() if line.startswith("msarm: error:")]
    found = re.search(r"simulation diverged at t = ([0-9.]+) s", lines[0] if lines else "")
    assert len(lines) == 1 and found and float(found.group(1)) < 1.0
    assert lines[0].endswith(f"(partial log kept: {Path('run') / 'log.parquet'})")
    assert "MuJoCo" not in captured.err.replace("MuJoCo found", "")  # no raw MuJoCo line
    assert "diverged" in json.loads(captured.out)
    assert (tmp_path / "run" / "log.parquet").is_file()
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
