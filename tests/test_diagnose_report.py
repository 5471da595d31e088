"""The report of a gap diagnosis (issue 7): plots, Markdown, HTML, JSON, the CLI, the example."""

from __future__ import annotations

import base64
import importlib.util
import json
import os
import re
import shutil
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest
from conftest import short_move_logs

from msarm.cli.diagnose import diagnose_command, where_breakdowns
from msarm.diagnose.effects import CANDIDATES as REGISTRY
from msarm.diagnose.fitting import fit
from msarm.diagnose.report import REPORT_FILES, plot_gap, plot_waterfall, write_report
from msarm.diagnose.select import diagnose
from msarm.diagnose.signals import Signals
from msarm.errors import InputError
from msarm.plant import IDEAL_PLANT
from msarm.plant.config import JointFrictionConfig

# The noise-free simulated logs hold a cable at its floor tension over a whole run
# ('tension_motor.teres_minor'): the dead-sensor warning is expected on them (asserted in
# test_diagnose_where.py::test_a_noise_free_log_warns_about_the_cable_held_at_its_floor).
pytestmark = pytest.mark.filterwarnings(
    "ignore:.*hold one value over the whole log:msarm.diagnose.residuals.DiagnosisWarning"
)

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "diagnose_custom_candidate.py"
PNG = b"\x89PNG\r\n\x1a\n"
CANDIDATES = ["coulomb", "viscous"]
N_RUNS = 3


@pytest.fixture(scope="module")
def friction_logs(arm, tmp_path_factory):
    root = tmp_path_factory.mktemp("report_friction")
    plant = replace(
        IDEAL_PLANT,
        name="test",
        effects=replace(IDEAL_PLANT.effects, joint_friction=JointFrictionConfig(enabled=True)),
    )
    return short_move_logs(arm, root, plant, N_RUNS)


@pytest.fixture(scope="module")
def diagnosis(arm, friction_logs):
    return diagnose(arm, friction_logs[:-1], friction_logs[-1:], candidates=CANDIDATES, n_boot=4)


@pytest.fixture(scope="module")
def nothing_selected(diagnosis):
    """The same diagnosis as if no candidate had been selected."""
    return replace(
        diagnosis,
        selected=(),
        explained_variance=diagnosis.explained_variance[:1],
        waterfall=diagnosis.waterfall[:1],
        gap_after=dict(diagnosis.gap_before),
    )


@pytest.fixture(scope="module")
def example():
    """The example module, loaded from its path (its candidate registered for the module)."""
    REGISTRY.pop("pulley_loss", None)
    spec = importlib.util.spec_from_file_location("diagnose_custom_candidate", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    yield module
    REGISTRY.pop("pulley_loss", None)
    sys.modules.pop("custom_effect", None)


def _embedded_pngs(page: str) -> list[bytes]:
    return [
        base64.b64decode(data) for data in re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    ]


def test_write_report_writes_every_file(arm, diagnosis, friction_logs, tmp_path):
    assert diagnosis.names, "joint friction should be named"
    # perfect drives and rigid cables: only the joint group is diagnosed and broken down
    assert diagnosis.groups == ("joint",)
    breakdowns, skipped = where_breakdowns(arm, friction_logs[:-1], diagnosis.groups)
    assert list(breakdowns) == ["joint_torque"]
    assert set(skipped) == {"drive", "cable_length"}
    every, _ = where_breakdowns(arm, friction_logs[:-1])
    assert "joint_torque" in every and "drive" not in every
    out = tmp_path / "report"
    # a staging folder a SIGKILLed writer left (stale) and one a writer may still be using
    stale, young = out / ".report-killed", out / ".report-busy"
    for folder in (stale, young):
        folder.mkdir(parents=True)
        (folder / "diagnosis.json").write_text("{}")
    os.utime(stale, (time.time() - 120, time.time() - 120))
    paths = write_report(diagnosis, out, breakdowns)
    assert not stale.exists() and young.exists()  # the stale one removed, the young kept
    shutil.rmtree(young)
    expected = {**REPORT_FILES, **{f"where-{k}": f"where-{k}.png" for k in breakdowns}}
    assert set(paths) == set(expected)
    for key, name in expected.items():
        assert paths[key] == out / name
        assert paths[key].stat().st_size > 0
        if name.endswith(".png"):
            assert paths[key].read_bytes().startswith(PNG)
    assert not list(out.glob(".*.tmp")), "temporary files left behind"

    # the JSON is the diagnosis with its "where" section: the breakdowns given
    payload = json.loads(paths["json"].read_text())
    assert payload == json.loads(json.dumps(diagnosis.with_where(breakdowns).as_dict()))
    assert payload["where"]["joint_torque"] == json.loads(
        json.dumps(breakdowns["joint_torque"].as_dict())
    )

    markdown = paths["markdown"].read_text()
    assert markdown.startswith("# Sim-to-real gap report")
    first = diagnosis.selected[0].name
    assert f"**{first}**" in markdown
    assert f"| 1 | {first} |" in markdown
    for name in ("waterfall.png", "gap.png", "where-joint_torque.png"):
        assert re.search(rf"!\[[^\]]*\]\({re.escape(name)}\)", markdown), name
    assert "## Where the gap lies (training runs)" in markdown
    assert "### How far: the held-out gap before and after" in markdown
    assert markdown.index("where-joint_torque.png") < markdown.index("waterfall.png")

    # every parameter of every named effect has its row, named by its joint
    for effect in diagnosis.selected:
        assert effect.parameter_labels == tuple(
            n.replace(f"[{k}]", f"[{arm.joint_names[k]}]")
            for n, k in zip(effect.parameter_names, range(arm.n_joints), strict=True)
        )
        for label, value in zip(effect.labels, effect.parameters, strict=True):
            assert f"| {effect.name} | {label} | {value:.4g} |" in markdown
    assert json.loads(paths["json"].read_text())["selected"][0]["labels"] == dict(
        zip(diagnosis.selected[0].parameter_names, diagnosis.selected[0].labels, strict=True)
    )

    page = paths["html"].read_text()
    assert page.startswith("<!DOCTYPE html>")
    assert "<table>" in page and first in page
    assert 'src="waterfall.png"' not in page, "images must be embedded, not linked"
    embedded = _embedded_pngs(page)
    files = {p.read_bytes() for k, p in paths.items() if p.suffix == ".png"}
    assert len(embedded) == 2 + len(breakdowns) and set(embedded) == files


def test_plots_with_nothing_selected(nothing_selected, tmp_path):
    assert nothing_selected.selected == ()
    for plot in (plot_waterfall, plot_gap):
        path = plot(nothing_selected, tmp_path / f"{plot.__name__}.png")
        assert path.read_bytes().startswith(PNG)
    paths = write_report(nothing_selected, tmp_path / "empty")
    assert "where-joint_torque" not in paths
    markdown = paths["markdown"].read_text()
    assert "nothing named" in markdown and "No breakdown was computed." in markdown
    assert len(_embedded_pngs(paths["html"].read_text())) == 2


def test_write_report_refuses_bad_input(diagnosis, tmp_path):
    with pytest.raises(InputError, match="diagnosis"):
        write_report(diagnosis.as_dict(), tmp_path / "a")
    afile = tmp_path / "file"
    afile.write_text("x")
    with pytest.raises(InputError, match="out_dir"):
        write_report(diagnosis, afile)
    # a folder under a file cannot be made: msarm's error naming it, not a raw OSError
    with pytest.raises(InputError, match=f"out_dir: cannot create the folder {afile / 'sub'}: "):
        write_report(diagnosis, afile / "sub")
    with pytest.raises(InputError, match="breakdowns"):
        write_report(diagnosis, tmp_path / "b", {"../evil": None})
    with pytest.raises(InputError, match="breakdowns"):
        write_report(diagnosis, tmp_path / "c", {"joint_torque": "not a breakdown"})


def test_cli_writes_the_report_and_prints_the_tables(friction_logs, tmp_path, capsys):
    out = tmp_path / "cli"
    diagnose_command(
        friction_logs[:2], friction_logs[2:3], False, out, candidates=CANDIDATES, boot=3, seed=1
    )
    printed = capsys.readouterr().out
    for name in ("report.md", "report.html", "diagnosis.json", "diagnosis.md", "gap.png"):
        assert (out / name).is_file(), name
    assert (out / "where-joint_torque.png").is_file()
    assert "held-out gap per channel group" in printed
    assert "joint" in printed and "N m" in printed and "%" in printed
    assert any(name in printed for name in CANDIDATES)
    assert "report.md" in printed and "report.html" in printed
    assert "where: no drive breakdown" in printed
    # --json keeps stdout pure JSON, the report is still written
    diagnose_command(
        friction_logs[:2], friction_logs[2:3], True, out, candidates=CANDIDATES, boot=0
    )
    payload = json.loads(capsys.readouterr().out)
    assert json.loads((out / "diagnosis.json").read_text()) == payload


def test_the_answer_records_what_made_it(arm, diagnosis, friction_logs, tmp_path):
    """Model and its SHA-256, code fingerprint, residual settings and the logs' absolute paths
    are in the JSON and the report's header; each equation's fixed constants beside it."""
    from msarm.diagnose.residuals import ResidualSpec
    from msarm.io.code_version import code_fingerprint

    payload = json.loads(json.dumps(diagnosis.as_dict(), allow_nan=False))
    assert payload["residual_spec"] == asdict(ResidualSpec())  # the fixture's: the defaults
    assert payload["model"] == {
        "name": arm.name,
        "sha256": arm.sha256,
        "path": str(Path(arm.path).resolve()),
    }
    assert payload["code_fingerprint"] == code_fingerprint("diagnosis")
    assert payload["log_paths"] == {
        "train": [str(Path(p).resolve()) for p in friction_logs[:-1]],
        "holdout": [str(Path(p).resolve()) for p in friction_logs[-1:]],
    }
    terms = {name: REGISTRY[name]() for name in CANDIDATES}  # the joint terms: no arguments
    for effect, given in zip(diagnosis.selected, payload["selected"], strict=True):
        assert effect.constants == terms[effect.name].constants()
        assert given["constants"] == effect.constants
    paths = write_report(diagnosis, tmp_path / "report")
    for name in ("markdown", "html"):
        text = paths[name].read_text()
        header = text[: text.index("Where the gap lies")]
        for value in (arm.sha256, code_fingerprint("diagnosis"), str(Path(arm.path).resolve())):
            assert value in header, (name, value)
        for log in friction_logs:
            assert str(Path(log).resolve()) in header, (name, log)
        spec = ResidualSpec()
        assert f"drive_gain {spec.drive_gain:g}" in header
        assert f"drum_radius {spec.drum_radius:g} m" in header
        assert f"window {spec.target.window} samples" in header
    markdown = paths["markdown"].read_text()
    for effect in diagnosis.selected:
        line = next(x for x in markdown.splitlines() if x.startswith(f"- {effect.name}: "))
        assert effect.description in line
        for symbol, value in effect.constants.items():
            assert f"{symbol} = {value:.4g}" in line, line


def test_the_cli_json_has_the_residual_settings_and_the_where_breakdown(friction_logs, capsys):
    """--drive-gain and the other residual settings reach the JSON, and --json alone has the
    "where" section: each kind's rows and thresholds, or why it was skipped."""
    diagnose_command(
        friction_logs[:2],
        friction_logs[2:3],
        True,
        None,
        candidates=CANDIDATES,
        boot=0,
        drive_gain=8.0,
        filter_window=31,
        tension_timing="instant",
    )
    text = capsys.readouterr().out

    def refuse(token: str) -> None:
        raise AssertionError(f"{token} in the JSON")

    payload = json.loads(text, parse_constant=refuse)
    spec = payload["residual_spec"]
    assert spec["drive_gain"] == 8.0 and spec["drum_radius"] == 0.003  # --drum-radius's default
    assert spec["target"]["window"] == 31 and spec["target"]["tension_timing"] == "instant"
    where = payload["where"]
    assert set(where) == {"joint_torque", "drive", "cable_length"}
    joint = where["joint_torque"]
    assert joint["unit"] == "N m" and joint["settings"]["hot_spot_density"] > 1
    assert {r["group"] for r in joint["rows"]} == {"channel", "motion", "load", "posture"}
    assert sum(r["share"] for r in joint["rows"] if r["group"] == "motion") == pytest.approx(100)
    for kind in ("drive", "cable_length"):  # perfect drives and rigid cables
        assert set(where[kind]) == {"skipped"} and where[kind]["skipped"]


def test_the_report_says_which_gain_is_which_and_explains_its_terms(
    diagnosis, tmp_path, monkeypatch
):
    import msarm.plots

    markdown = diagnosis.to_markdown()
    assert "gain when selected (fit at that step)" in markdown
    assert "the final model, its terms added in selection order" in markdown
    glossary = markdown[markdown.index("## Terms used") : markdown.index("## Which")]
    for term in ("Explained share", "Confidence", "Screening", "Shrink", "joint_torque"):
        assert term in glossary, term
    # an explained share e is a shrink of the RMSE by 1 - sqrt(1 - e), as the glossary says
    share = re.search(r"(\d\.\d+) is a shrink of (\d+\.\d) %", glossary)
    assert share, glossary
    e, shrink = float(share.group(1)), float(share.group(2))
    assert 100 * (1 - np.sqrt(1 - e)) == pytest.approx(shrink, abs=0.05)
    notes = []
    save = msarm.plots.save_figure

    legends = []

    def saved(fig, path):
        notes.append((fig._suptitle.get_text(), fig._supxlabel.get_text()))
        legends.append([t.get_text() for legend in fig.legends for t in legend.get_texts()])
        return save(fig, path)

    monkeypatch.setattr(msarm.plots, "save_figure", saved)
    plot_waterfall(diagnosis, tmp_path / "waterfall.png")
    title, note = notes[0]
    assert "final model" in title and "selection order" in title
    assert "share of the nominal model's RMSE" in note and "not the gain when selected" in note
    # the bar colours are named: the nominal bar, the effect's bars and the drop each shows
    assert legends[0][0] == "nominal model"
    assert "after an effect acting on this group" in legends[0]
    assert "the step's drop" in legends[0] and "final RMSE" in legends[0]


def test_the_waterfall_legend_names_each_colour_drawn():
    from msarm.diagnose.report import _waterfall_legend

    every = {"nominal", "kept", "other", "drop", "rise", "final"}
    labels = [a.get_label() for a in _waterfall_legend(every)]
    assert labels == [
        "nominal model",
        "after an effect acting on this group",
        "after an effect on other groups only",
        "the step's drop",
        "the step's rise",
        "final RMSE",
    ]
    assert [a.get_label() for a in _waterfall_legend({"nominal"})] == ["nominal model"]


def test_cli_refuses_unknown_candidates_and_bad_boot(friction_logs, tmp_path):
    with pytest.raises(InputError, match="unknown name 'no_such_effect'"):
        diagnose_command(friction_logs[:2], friction_logs[2:3], False, None, ["no_such_effect"])
    with pytest.raises(InputError, match="--boot"):
        diagnose_command(friction_logs[:2], friction_logs[2:3], False, None, boot=-1)


def _random_signals(arm, T: int = 300, seed: int = 0) -> Signals:
    rng = np.random.default_rng(seed)
    n, m = arm.n_joints, arm.n_cables
    q = rng.uniform(arm.joint_lower, arm.joint_upper, size=(T, n))
    qd = rng.normal(0.0, 0.5, size=(T, n))
    jacobian = rng.normal(0.0, 0.02, size=(T, m, n))
    return Signals(
        t=np.arange(T) * 0.01,
        q=q,
        qd=qd,
        qdd=rng.normal(0.0, 1.0, size=(T, n)),
        tension=rng.uniform(5.0, 60.0, size=(T, m)),
        lengths=rng.uniform(0.3, 0.8, size=(T, m)),
        cable_velocity=np.einsum("tmn,tn->tm", jacobian, qd),
        jacobian=jacobian,
        wrap=rng.uniform(2.0, 4.0, size=(T, m)),
        motor_angle=rng.uniform(0.0, 6.0, size=(T, m)),
        dt=0.01,
    )


def test_example_candidate_recovers_a_known_loss(arm, example):
    candidate = example.PulleyLossCandidate(arm.n_joints, arm.n_cables)
    assert REGISTRY["pulley_loss"] is example.PulleyLossCandidate
    assert candidate.groups == ("joint",) and candidate.linear
    signals = _random_signals(arm)
    loss = 0.15
    design = candidate.design(signals)
    assert design.shape == (signals.n_samples, arm.n_joints, 1)
    # the residual r = tau_MS - tau_delivered of a lossy pulley, from its definition
    F, J = signals.tension, signals.jacobian
    tau_ms = -np.einsum("tmn,tm->tn", J, F)
    delivered = -np.einsum("tmn,tm->tn", J, (1.0 - loss) * F)
    np.testing.assert_allclose(design[:, :, 0] * loss, tau_ms - delivered, atol=1e-12)
    noise = np.random.default_rng(1).normal(0.0, 1e-3, size=tau_ms.shape)
    result = fit(candidate, signals, design[:, :, 0] * loss + noise)
    assert result.parameters[0] == pytest.approx(loss, abs=2e-3)
    assert result.reduction > 0.99
    with pytest.raises(InputError, match="cables"):
        example.PulleyLossCandidate(arm.n_joints, arm.n_cables + 1).design(signals)


def test_example_names_the_pulley_loss_end_to_end(example, tmp_path):
    result, files = example.run_example(loss=0.15, out=tmp_path / "example")
    assert result.names[0] == "pulley_loss"
    assert result.selected[0].parameters[0] == pytest.approx(0.15, abs=0.01)
    assert files["html"].is_file() and files["markdown"].is_file()


def test_a_report_replaces_the_last_one_whole_or_not_at_all(
    diagnosis, nothing_selected, tmp_path, monkeypatch
):
    import msarm.diagnose.report as report

    out = tmp_path / "report"
    first = write_report(diagnosis, out, extra_files={"notes.md": b"first"})
    (out / "where-drive.png").write_bytes(PNG)  # a map of a residual the next one lacks
    (out / "mine.txt").write_text("the user's")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert (out / "notes.md").read_bytes() == b"first" and first["notes.md"].parent == out

    def broken(*args, **kwargs):
        raise RuntimeError("killed while writing")

    monkeypatch.setattr(report, "render_html", broken)  # fails after the plots are drawn
    with pytest.raises(RuntimeError, match="killed"):
        write_report(nothing_selected, out, extra_files={"notes.md": b"second"})
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing mixed, no temp
    monkeypatch.undo()
    second = write_report(nothing_selected, out, extra_files={"notes.md": b"second"})
    names = {p.name for p in out.iterdir()}
    assert names == {*REPORT_FILES.values(), "notes.md", "mine.txt"}  # stale map gone
    assert json.loads(second["json"].read_text())["selected"] == []
    with pytest.raises(InputError, match="extra_files"):
        write_report(diagnosis, out, extra_files={"report.md": b"x"})


def test_a_signal_during_the_moves_acts_after_the_last_one(
    diagnosis, nothing_selected, tmp_path, monkeypatch
):
    """A Ctrl-C between two moves left the new plots beside the old report.md and JSON (and
    the old report's heat map of another residual deleted): the signal now waits for them."""
    import os
    import signal

    import msarm.diagnose.report as report

    out = tmp_path / "report"
    write_report(diagnosis, out)
    (out / "where-drive.png").write_bytes(PNG)  # a map of a residual the next one lacks
    real = os.replace
    calls = []

    def replace_and_interrupt(source, target):
        if Path(target).parent == out:  # a move into place (not a write into the staging)
            calls.append(target)
            if len(calls) == 2:
                os.kill(os.getpid(), signal.SIGINT)  # held back until every file is in place
        real(source, target)

    monkeypatch.setattr(report.os, "replace", replace_and_interrupt)
    with pytest.raises(KeyboardInterrupt):
        write_report(nothing_selected, out)
    assert len(calls) == len(REPORT_FILES)
    assert json.loads((out / "diagnosis.json").read_text())["selected"] == []  # the new one
    assert {p.name for p in out.iterdir()} == set(REPORT_FILES.values())  # stale map gone
