"""The examples refuse bad input up front, clean up on SIGTERM and write their results last.

Each script is loaded from its path and its ``main(argv)`` called in this process; nothing
here simulates for long or needs the mis-tool data (synthetic files are written instead).
"""

from __future__ import annotations

import gzip
import importlib.util
import json
import os
import signal
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np
import pytest

from msarm import interrupts
from msarm.diagnose.effects import CANDIDATES as REGISTRY

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
PITCHES = (
    "Tool_4_Maryland_L_Pitch_1",
    "Tool_4_Maryland_L_Pitch_2",
    "Tool_4_Maryland_L_Pitch_3",
)
main_thread_only = pytest.mark.skipif(
    threading.current_thread() is not threading.main_thread(),
    reason="a SIGTERM handler can only be set in the main thread",
)


def _load(name: str):
    """Load ``examples/<name>.py`` as a module of its own (not the one other tests load)."""
    spec = importlib.util.spec_from_file_location(f"{name}_under_input_test", EXAMPLES / name)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def rct():
    return _load("real_cable_transmission.py")


@pytest.fixture(scope="module")
def dcc():
    """diagnose_custom_candidate.py (its candidate registered for the module only)."""
    REGISTRY.pop("pulley_loss", None)
    sys.path.insert(0, str(EXAMPLES))  # as `python examples/<name>.py` would
    try:
        yield _load("diagnose_custom_candidate.py")
    finally:
        sys.path.remove(str(EXAMPLES))
        REGISTRY.pop("pulley_loss", None)
        sys.modules.pop("custom_effect", None)


def _refused(main, argv, capsys) -> str:
    """Call ``main(argv)``: it must exit with 2 (argparse's error); return its stderr."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()[-1]) > 0
    return err.strip().splitlines()[-1]


def _write_data_file(
    path: Path, rows: int, freq: float = 0.5, yaw: float = 0.0, torque: float = 20.0
) -> Path:
    """A mis-tool-like file: the header keys and ``rows`` rows of 10 columns at 1 kHz."""
    path.parent.mkdir(parents=True, exist_ok=True)
    t = np.arange(rows) * 1e-3
    sine = np.sin(2 * np.pi * freq * t)
    data = np.zeros((rows, 10))
    data[:, 0] = t
    data[:, 1] = np.round(2048 + 680 * sine)  # input encoder [counts]
    data[:, 2] = -500 - 300 * np.cos(2 * np.pi * freq * t)  # input torque [counts]
    data[:, 4] = np.round(500 - 290 * sine)  # jaw encoder [counts]
    data[:, 5] = -torque * 25  # load torque [counts]
    lines = [
        "%synthetic",
        f"%a {freq:.2f} Hz Sine wave was implemented with and amplitude of 30.00 degrees",
        f"%Yaw_rad={yaw:.2f}",
        f"%Freq_Hz={freq:.2f}",
        f"%Torque_Pct={torque:.2f}",
        "%columns",
    ]
    body = "\n".join(",".join(f"{v:.4f}" for v in row) for row in data)
    with gzip.open(path, "wt") as handle:
        handle.write("\n".join(lines) + "\n" + body + ("\n" if rows else ""))
    return path


# --------------------------------------------------------------------------- argument checks
def test_real_cable_transmission_refuses_bad_arguments_before_any_work(rct, tmp_path, capsys):
    out = ["--out", str(tmp_path / "out")]
    assert "--seed: expected a seed >= 0, got -1" in _refused(
        rct.main, ["--seed", "-1", *out], capsys
    )
    assert "--data: empty" in _refused(rct.main, ["--data", "", *out], capsys)
    afile = tmp_path / "afile"
    afile.write_text("x")
    line = _refused(rct.main, ["--out", str(afile / "sub")], capsys)
    assert f"--out: cannot create the folder {afile / 'sub'}: Not a directory" in line
    assert not (tmp_path / "out").exists()


def test_the_other_examples_refuse_an_out_under_a_file(dcc, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    for main in (_load("arm_tour.py").main, dcc.main):
        line = _refused(main, ["--out", str(afile / "sub")], capsys)
        assert f"cannot create the folder {afile / 'sub'}" in line


def test_cdpr_force_estimation_refuses_more_seconds_than_the_trajectory(capsys):
    example = _load("cdpr_force_estimation.py")
    line = _refused(example.main, ["--seconds", "100"], capsys)
    assert "--seconds: triangle-12 is 11.347 s long" in line and "got 100" in line
    note = example.no_following_error_note("ikc", None)
    assert note.startswith("no following-error estimates: ikc has no cable on a pure-P drive")


@pytest.mark.parametrize(("name", "default"), [("custom_effect.py", "0.2"), ("dcc", "0.15")])
def test_help_shows_the_loss_default(name, default, dcc, capsys):
    main = dcc.main if name == "dcc" else _load(name).main
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    assert f"(default {default})" in " ".join(capsys.readouterr().out.split())


# --------------------------------------------------------------------------- data checks
def test_read_run_refuses_a_file_shorter_than_settling_and_a_cycle(rct, tmp_path):
    need = rct.min_samples(0.5)
    assert need == 1000 + 2000  # 1 s dropped, then one 0.5 Hz cycle
    short = _write_data_file(tmp_path / "short.TXT.gz", 900)
    with pytest.raises(ValueError, match=r"short\.TXT\.gz: 900 samples \(0\.9 s\); expected at"):
        rct.read_run(short, 0.0)
    with pytest.raises(ValueError, match=f"expected at least {need}"):
        rct.read_run(_write_data_file(tmp_path / "almost.TXT.gz", need - 1), 0.0)
    run = rct.read_run(_write_data_file(tmp_path / "enough.TXT.gz", need), 0.0)
    assert run.t.size == (need - 1000) // 10  # thinned to 100 Hz after the settling cut
    empty = _write_data_file(tmp_path / "empty.TXT.gz", 0)
    with pytest.raises(ValueError, match=r"empty\.TXT\.gz: no data rows"):
        rct.read_run(empty, 0.0)


def test_plain_txt_files_are_read_as_the_gzipped_ones(rct, tmp_path):
    """The upstream files are plain .TXT: they were "no data" (only *.TXT.gz was looked for);
    where both are there the gzipped copy is taken, once."""
    import gzip
    import shutil

    gz = _write_data_file(tmp_path / "a" / PITCHES[0] / "000.TXT.gz", 3000)
    plain = tmp_path / "b" / PITCHES[0] / "000.TXT"
    plain.parent.mkdir(parents=True)
    with gzip.open(gz, "rb") as source, open(plain, "wb") as target:
        shutil.copyfileobj(source, target)
    assert rct.data_files(tmp_path / "b") == [(plain, rct.PITCH_DEG[PITCHES[0]])]
    np.testing.assert_array_equal(rct.read_run(plain, 0.0).t, rct.read_run(gz, 0.0).t)
    assert rct.read_header(plain) == rct.read_header(gz)
    shutil.copy(gz, plain.parent / "000.TXT.gz")
    assert rct.data_files(tmp_path / "b") == [
        (plain.parent / "000.TXT.gz", rct.PITCH_DEG[PITCHES[0]])
    ]


def test_a_family_with_one_level_is_refused_with_exit_2(rct, tmp_path, capsys):
    """One frequency (0.5 Hz) and one file in a pitch: named, nothing done, no --out left."""
    root = tmp_path / "data"
    for k, folder in enumerate(PITCHES):
        files = 1 if k == 2 else 2
        for i in range(files):
            yaw, torque = (0.0, 20.0) if i == 0 else (0.52, 80.0)
            _write_data_file(root / folder / f"0{i}{i}.TXT.gz", 3000, 0.5, yaw, torque)
    out = tmp_path / "out"
    assert rct.main(["--data", str(root), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "one level only of: frequency (0.5 Hz)" in err and "at least 2 levels" in err
    assert "one file only in: Tool_4_Maryland_L_Pitch_3" in err
    assert "torque level" not in err and "yaw stop" not in err  # these have 2 levels
    assert not out.exists()  # made up front, removed again: nothing was written


# --------------------------------------------------------------------------- writes
def test_results_json_is_removed_first_and_written_last(rct, tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.json").write_text('{"old": true}')
    seen = []

    def plot(name):
        def write(*args):
            seen.append((name, (out / "results.json").exists()))
            (out / name).write_bytes(b"png")

        return write

    monkeypatch.setattr(rct, "plot_scores", plot("held_out.png"))
    monkeypatch.setattr(rct, "plot_loops", plot("loops_per_pitch.png"))
    rct.write_outputs({"held_out": {}, "chosen": ["dahl"], "new": 1}, [], out)
    assert seen == [("held_out.png", False), ("loops_per_pitch.png", False)]
    assert json.loads((out / "results.json").read_text())["new"] == 1

    def cut_off(*args):
        raise interrupts.Terminated(143)

    monkeypatch.setattr(rct, "plot_loops", cut_off)
    with pytest.raises(interrupts.Terminated):
        rct.write_outputs({"held_out": {}, "chosen": ["dahl"]}, [], out)
    # the new held_out.png and the old loops plot, but no results.json: not one whole run
    assert sorted(p.name for p in out.iterdir()) == ["held_out.png", "loops_per_pitch.png"]


# --------------------------------------------------------------------------- SIGTERM
@main_thread_only
def test_sigterm_raises_inside_the_block_and_restores_the_handler(tmp_path):
    before = signal.getsignal(signal.SIGTERM)
    folder = None
    with pytest.raises(interrupts.Terminated) as exit_:
        with interrupts.sigterm_raises():
            with tempfile.TemporaryDirectory(dir=tmp_path) as tmp:
                folder = Path(tmp)
                os.kill(os.getpid(), signal.SIGTERM)
    assert exit_.value.code == 143
    assert folder is not None and not folder.exists()
    assert signal.getsignal(signal.SIGTERM) == before


@main_thread_only
def test_diagnose_custom_candidate_removes_its_logs_on_sigterm(dcc, monkeypatch, capsys):
    made = []

    def make_logs(arm, folder, **kwargs):
        (folder / "run0").mkdir()
        (folder / "run0" / "log.parquet").write_bytes(b"log")
        made.append(folder)
        os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(dcc, "make_logs", make_logs)
    assert dcc.main(["--loss", "0.15"]) == 143
    assert capsys.readouterr().err.strip().endswith(": terminated")  # one line, then 143
    (folder,) = made
    assert not folder.exists()
