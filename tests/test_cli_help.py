"""Every ``msarm … --help`` shows its options' help texts whole.

Typer renders help through rich, whose markup reads ``[s]``, ``[b]``, ``[i]`` … as styles: a
unit written as ``[s]`` would vanish from the help unless escaped. This walks the whole
command tree and checks that every bracketed piece of every option's help is printed.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from msarm.cli import app

_BRACKETED = re.compile(r"\[[^\]\[]*\]")


def _commands(command, path: tuple[str, ...] = ()):
    yield path, command
    for name, sub in getattr(command, "commands", {}).items():
        yield from _commands(sub, (*path, name))


_TREE = list(_commands(typer.main.get_command(app)))


def _plain(text: str) -> str:
    """Help text as rich prints it, without escapes, box drawing or line breaks."""
    text = re.sub(r"[│╭╮╰╯─]", " ", text)
    return re.sub(r"\s+", " ", text.replace("\\[", "["))


@pytest.mark.parametrize("path,command", _TREE, ids=[" ".join(p) or "msarm" for p, _ in _TREE])
def test_help_keeps_bracketed_units(path, command):
    result = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": "400"})
    assert result.exit_code == 0, result.output
    shown = _plain(result.output)
    for param in command.params:
        for piece in _BRACKETED.findall(_plain(getattr(param, "help", None) or "")):
            assert piece in shown, f"{' '.join(path)} {param.opts}: {piece!r} lost in --help"


def test_the_console_script_prints_msarm_warnings_as_one_line(monkeypatch, capsys):
    import sys
    import warnings

    import msarm.cli
    from msarm.diagnose.residuals import DiagnosisWarning

    passed_on = []  # what the console script hands to the warnings' previous printer
    printer = lambda *args, **kw: passed_on.append(args)  # noqa: E731
    monkeypatch.setattr(warnings, "showwarning", printer)
    message = "log.parquet: column 't' has 1 gap(s)"

    def command(**kwargs):  # warnings shown while a command runs
        warnings.showwarning(DiagnosisWarning(message), DiagnosisWarning, "residuals.py", 398)
        # anything else keeps where it came from (it may be a bug): the usual printer
        warnings.showwarning(RuntimeWarning("overflow"), RuntimeWarning, "x.py", 7)

    monkeypatch.setattr(msarm.cli, "app", command)
    monkeypatch.setattr(sys, "argv", ["msarm", "diagnose"])
    msarm.cli.main()
    assert capsys.readouterr().err == f"msarm: warning: {message}\n"
    assert len(passed_on) == 1 and passed_on[0][2:4] == ("x.py", 7)
    assert warnings.showwarning is printer  # given back when the command ends


def test_progress_is_printed_line_by_line_where_no_bar_shows(capsys):
    from msarm.cli.common import progress_lines

    step = progress_lines("compare", 2)  # stderr is captured: not a terminal
    step("table1-1, without feedforward")
    step("table1-1, with feedforward")
    assert capsys.readouterr().err.splitlines() == [
        "compare [1/2]: table1-1, without feedforward",
        "compare [2/2]: table1-1, with feedforward",
    ]
    progress_lines("compare", 2, enabled=False)("quiet")  # --json: nothing
    assert capsys.readouterr().err == ""


def test_bench_allocation_shows_the_fallback_count(monkeypatch):
    """A method that handed problems to its fallback says so next to "feasible"."""
    import msarm.allocation.benchmark as benchmark

    row = {"median_us": 1.0, "speedup_vs_cvxpy": 2.0, "feasible": 5, "statuses": {"fallback": 5}}
    report = {
        "robots": {"arm": {"shape": [4, 9], "n_problems": 5, "methods": {"closed_form": row}}},
        "targets": {"fast_min_speedup": 1, "fast_max_median_us": 1, "batched_min_solves_per_s": 1},
        "targets_met": {},
    }
    report["robots"]["arm"].update(source="random", f_ref=None)
    monkeypatch.setattr(benchmark, "run_benchmark", lambda **_: report)
    result = CliRunner().invoke(app, ["bench", "allocation"])
    assert result.exit_code == 0, result.output
    assert "fallback" in result.output
    line = next(x for x in result.output.splitlines() if "closed_form" in x)
    assert "5/5" in line and line.split("│")[7].strip() == "5"


@pytest.mark.parametrize(
    "argv,expected",
    [
        (
            ["bench", "allocation", "--n-problems", "0"],
            "msarm: error: Invalid value for '--n-problems': Input should be greater than or "
            "equal to 1 (see 'msarm bench allocation --help')",
        ),
        (["track", "--nope"], "msarm: error: No such option: --nope (see 'msarm track --help')"),
    ],
)
def test_a_command_line_error_is_one_line_with_exit_code_2(monkeypatch, capsys, argv, expected):
    import sys

    from msarm.cli import main

    monkeypatch.setattr(sys, "argv", ["msarm", *argv])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip() == expected


def test_help_and_a_commands_own_exit_code_pass_through(monkeypatch, capsys):
    import sys

    from msarm.cli import main

    monkeypatch.setattr(sys, "argv", ["msarm", "track", "--help"])
    main()  # no SystemExit: help is a success
    assert "Usage: msarm track" in capsys.readouterr().out


def test_a_controller_file_is_checked_up_front_and_may_be_a_section(monkeypatch, capsys, tmp_path):
    import sys

    import yaml

    from msarm.cli import main

    three = tmp_path / "three.yaml"
    three.write_text("kp: [60, 60, 30]\n")
    rate = tmp_path / "rate.yaml"
    rate.write_text("rate_hz: 300\n")
    for path, expected in (
        (three, "three.yaml: controller kp needs 4 gains"),
        (rate, "rate.yaml: rate_hz 300 gives a control period of 0.00333333 s, not a whole"),
    ):
        argv = ["msarm", "track", "--task", "table1-1", "--controller", str(path)]
        monkeypatch.setattr(sys, "argv", [*argv, "--out", str(tmp_path / "run")])
        with pytest.raises(SystemExit) as exit_info:
            main()
        assert exit_info.value.code == 2
        assert expected in capsys.readouterr().err
        assert not (tmp_path / "run").exists()  # refused before any folder was made
    # a training recipe's controller: section is read as the gains
    recipe = Path(__file__).resolve().parents[1] / "training" / "compensator.yaml"
    out = tmp_path / "recipe-gains"
    result = CliRunner().invoke(
        app,
        ["track", "--task", "table1-1", "--controller", str(recipe), "--out", str(out), "--json"],
    )
    assert result.exit_code == 0, result.output
    ran_with = yaml.safe_load((out / "config.yaml").read_text())["controller"]
    wanted = yaml.safe_load(recipe.read_text())["controller"]
    assert {k: ran_with[k] for k in wanted} == wanted


def test_a_recipes_plant_file_is_found_beside_the_recipe(monkeypatch, tmp_path):
    import msarm.cli.compensator as compensator_cli

    (tmp_path / "plant.yaml").write_text("name: mine\n")
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text("data:\n  plant: plant.yaml\n")
    seen = []

    def stop(spec):
        seen.append(spec)
        raise RuntimeError("stop before training")

    monkeypatch.setattr(compensator_cli, "resolve_plant", stop)
    monkeypatch.chdir(tmp_path.parent)  # plant.yaml is not in the working folder
    with pytest.raises(RuntimeError, match="stop before training"):
        compensator_cli.train_command(config=recipe)
    assert seen == [str(tmp_path / "plant.yaml")]


def test_cdpr_run_help_names_every_controller_and_trajectory():
    """The help lists are written out for the CLI; they must name what the registries hold."""
    from msarm.control.cdpr_controllers import list_cdpr_controllers
    from msarm.tasks.cdpr_trajectories import list_cdpr_trajectories

    run = typer.main.get_command(app).commands["cdpr"].commands["run"]
    helps = {param.name: param.help for param in run.params}
    listed = {
        name: set(re.findall(r"[a-z0-9-]+", helps[name].rstrip(".")))
        for name in ("controller", "trajectory")
    }
    assert listed["controller"] == set(list_cdpr_controllers())
    assert listed["trajectory"] == set(list_cdpr_trajectories())


def test_track_list_prints_json_with_json(monkeypatch, capsys):
    import json
    import sys

    from msarm.cli import main
    from msarm.plant.config import EFFECT_NAMES

    monkeypatch.setattr(sys, "argv", ["msarm", "track", "--list", "--json"])
    main()
    choices = json.loads(capsys.readouterr().out)
    assert "table1-1" in choices["tasks"]
    assert choices["plants"]["ideal"] == []
    assert set(choices["effects"]) == set(EFFECT_NAMES)
    assert choices["effects"]["sheath_friction"]["default_plant"] is True


def test_a_partial_controller_file_with_ff_keeps_the_trained_gains(tmp_path):
    """With --ff, a --controller file that gives kp alone changed ki, kd and the integral
    limit to ArmControllerConfig's defaults (the ideal plant's) without a word; now the
    others stay the compensator's, and the gains that differ are named."""
    import dataclasses
    import warnings

    from msarm.cli.common import read_config_section
    from msarm.cli.track import _over_trained_gains
    from msarm.control import ArmControllerConfig
    from msarm.errors import MsarmWarning

    trained = dataclasses.replace(
        ArmControllerConfig(), ki=(640.0, 640.0, 320.0, 320.0), integral_limit=10.0
    )
    path = tmp_path / "kp.yaml"
    path.write_text("kp: [70, 70, 35, 35]\n")
    gains, given = read_config_section(path, ArmControllerConfig, "controller")
    with pytest.warns(MsarmWarning, match=r"kp differ from the gains the compensator c\.pt"):
        chosen = _over_trained_gains(gains, set(given), trained, path, Path("c.pt"))
    assert chosen.kp == (70.0, 70.0, 35.0, 35.0)
    assert chosen.ki == trained.ki and chosen.integral_limit == 10.0
    path.write_text(f"ki: {list(trained.ki)}\n")  # the trained gains again: no warning
    gains, given = read_config_section(path, ArmControllerConfig, "controller")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _over_trained_gains(gains, set(given), trained, path, Path("c.pt")) == trained


def test_help_names_no_value_for_a_flag():
    """`--json <bool>` in the help invited `--json true`, which is refused."""
    result = CliRunner().invoke(app, ["track", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "--json" in result.output and "<bool>" not in result.output
    assert re.search(r"--seed\s+<int", result.output)  # an option with a value keeps its type
