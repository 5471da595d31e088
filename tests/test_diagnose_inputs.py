"""The diagnosis refuses one run given twice: by the same path, or as a byte copy."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from msarm.cli import spread_multi_value_options
from msarm.cli.diagnose import split_runs
from msarm.diagnose.select import load_data
from msarm.errors import InputError

pytestmark = pytest.mark.filterwarnings(
    "ignore:.*hold one value over the whole log:msarm.diagnose.residuals.DiagnosisWarning"
)


def test_a_multi_value_option_followed_by_another_option_is_refused():
    with pytest.raises(InputError, match=r"--candidates: expected at least one value.*--boot"):
        spread_multi_value_options(["diagnose", "a", "b", "--candidates", "--boot", "0"])
    with pytest.raises(InputError, match="--holdout: expected at least one value"):
        spread_multi_value_options(["diagnose", "a", "--holdout", "--", "b"])
    assert spread_multi_value_options(["diagnose", "a", "--holdout", "b", "c", "--boot", "0"]) == [
        *("diagnose", "a", "--holdout", "b", "--holdout", "c", "--boot", "0")
    ]


def test_a_log_named_twice_is_refused_before_the_split(tmp_path):
    log = tmp_path / "r1.parquet"
    with pytest.raises(InputError, match=r"r1\.parquet given more than once"):
        split_runs([log, tmp_path / "." / "r1.parquet"], None)
    assert split_runs([log, tmp_path / "r2.parquet"], None) == (
        [log],
        [tmp_path / "r2.parquet"],
    )


def test_a_log_also_held_out_is_held_out_only_and_named(tmp_path):
    from msarm.diagnose.residuals import DiagnosisWarning

    a, b, c = (tmp_path / f"{name}.parquet" for name in "abc")
    with pytest.warns(DiagnosisWarning) as caught:
        train, held = split_runs([a, b, c], [tmp_path / "." / "c.parquet"])
    assert train == [a, b] and held == [tmp_path / "." / "c.parquet"]
    (warning,) = caught
    assert str(warning.message) == (
        f"{c}: given as a log and in --holdout: held out, not trained on (2 training log(s) left)"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overlap, no warning
        assert split_runs([a, b], [c]) == ([a, b], [c])


def test_the_threshold_option_is_checked_before_the_logs_are_read(tmp_path):
    from msarm.cli.diagnose import diagnose_command

    logs = [tmp_path / "a.parquet", tmp_path / "b.parquet"]
    for log in logs:
        log.write_bytes(b"not read")  # the option is refused before any log is parsed
    for bad in (1.0, 1.5, -0.1, float("nan")):
        with pytest.raises(InputError, match=r"--threshold: expected a value in \[0, 1\)"):
            diagnose_command(logs, None, False, None, threshold=bad)


def test_a_copy_of_a_training_log_is_not_taken_as_a_held_out_run(arm, tmp_path):
    # refused from the bytes alone, before any log is parsed
    first, second, copy = (tmp_path / f"{name}.parquet" for name in ("a", "b", "copy_of_a"))
    first.write_bytes(b"run a")
    second.write_bytes(b"run b")
    copy.write_bytes(first.read_bytes())
    with pytest.raises(
        InputError, match=r"copy_of_a\.parquet has the same contents as \S*a\.parquet"
    ):
        load_data(arm, [first, second], [copy])
    with pytest.raises(InputError, match="same contents"):
        load_data(arm, [first, copy], [second])


def test_distinct_logs_pass_the_copy_check_and_reach_the_log_reader(arm, tmp_path):
    paths = [tmp_path / f"{name}.parquet" for name in ("a", "b")]
    for path in paths:
        path.write_bytes(path.name.encode())
    with pytest.raises(Exception) as raised:
        load_data(arm, paths[:1], paths[1:])
    assert "same contents" not in str(raised.value)
    assert "not a readable Parquet file" in str(raised.value)
    assert Path(paths[0]).name in str(raised.value)


def test_a_gap_at_numerical_precision_is_called_so(arm, tmp_path):
    """Noise-free logs of the nominal model itself: whatever is named fits numerical error."""
    from conftest import ideal_plant_with, short_move_logs

    from msarm.diagnose.residuals import DiagnosisWarning
    from msarm.plant import IDEAL_PLANT

    ideal = short_move_logs(arm, tmp_path / "ideal", IDEAL_PLANT, 2)
    with pytest.warns(DiagnosisWarning, match=r"numerical precision") as caught:
        load_data(arm, ideal[:1], ideal[1:], candidates=["coulomb"])
    assert any("% of the torque the cables deliver" in str(w.message) for w in caught)
    friction = ideal_plant_with("friction", "joint_friction")
    rubbing = short_move_logs(arm, tmp_path / "friction", friction, 2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_data(arm, rubbing[:1], rubbing[1:], candidates=["coulomb"])
    assert not [w for w in caught if "numerical precision" in str(w.message)]


def test_logs_after_holdout_get_a_hint_when_none_is_left(monkeypatch, capsys):
    """``--holdout H A B`` takes A and B too; click said only "Missing argument 'LOG'"."""
    from msarm.cli import main

    monkeypatch.setattr("sys.argv", ["msarm", "diagnose", "--holdout", "h", "a", "b"])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "Missing argument 'LOG': --holdout takes every value after it up to the next" in err
    monkeypatch.setattr("sys.argv", ["msarm", "diagnose", "--holdout=h", "a"])
    with pytest.raises(SystemExit):
        main()
    assert "--holdout takes every value" in capsys.readouterr().err  # its value given inline
    # no hint where the option took no log: one value, or a names option (it stops at a path)
    for args in (["--holdout", "h"], ["--candidates", "coulomb"]):
        monkeypatch.setattr("sys.argv", ["msarm", "diagnose", *args])
        with pytest.raises(SystemExit):
            main()
        assert "takes every value" not in capsys.readouterr().err, args


def test_one_string_for_a_list_and_a_bad_seed_are_refused_up_front(arm, tmp_path):
    """A single path was iterated letter by letter ("the log(s) ['/', '-', ...] are given
    more than once"), and a bad seed failed in numpy after the whole selection had run."""
    from msarm.diagnose.select import diagnose

    log = str(tmp_path / "a.parquet")  # never read: each is refused before
    held = [str(tmp_path / "b.parquet")]
    with pytest.raises(InputError, match=r"train_paths \(the training logs\): expected a list"):
        diagnose(arm, log, held)
    with pytest.raises(InputError, match=r"holdout_paths .*: expected a list of log files"):
        diagnose(arm, [log], held[0])
    with pytest.raises(InputError, match=r"candidates: expected a list of names"):
        diagnose(arm, [log], held, candidates="elasticity")
    with pytest.raises(InputError, match=r"groups: expected a list of group names"):
        diagnose(arm, [log], held, groups="joint")
    for seed in (-1, 1.5, "abc", True):
        with pytest.raises(InputError, match=r"seed: expected a whole number >= 0"):
            diagnose(arm, [log], held, seed=seed)
    with pytest.raises(InputError, match=r"n_boot: expected a whole number >= 0, got 2\.5"):
        diagnose(arm, [log], held, n_boot=2.5)
    from msarm.diagnose.effects import CoulombFriction

    lone = CoulombFriction(n_joints=4)
    with pytest.raises(InputError, match=r"extra_candidates: expected a list of CandidateEffect"):
        diagnose(arm, [log], held, extra_candidates=lone)
    with pytest.raises(InputError, match=r"candidates: expected a list of names"):
        diagnose(arm, [log], held, candidates=lone)

    class Nameless(CoulombFriction):
        name = ""

    class Listed(CoulombFriction):
        name = ["a"]  # unhashable: a bare TypeError in the uniqueness check before

    for bad in ([Nameless(n_joints=4), Nameless(n_joints=4)], [Listed(n_joints=4)]):
        with pytest.raises(InputError, match="a candidate needs a non-empty class attribute"):
            diagnose(arm, [log], held, candidates=["coulomb"], extra_candidates=bad)
