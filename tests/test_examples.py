"""The documented examples run as the README says (``python examples/<name>.py``) and print
sane numbers.

Each runs in a subprocess from the repository root with this interpreter, on its smallest
options (a few seconds each). The bounds keep margins on what the scripts printed when these
tests were written (seeded: the same numbers every run) and on the README's numbers.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _run_example(name: str, *args: str) -> str:
    """Run ``examples/<name>`` from the repository root; its standard output (exit code 0).

    The script imports ``msarm`` from this checkout (``PYTHONPATH``), whatever is installed.
    """
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    done = subprocess.run(
        [sys.executable, str(ROOT / "examples" / name), *args],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": path, "MPLBACKEND": "Agg"},
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_custom_effect_example_shows_the_pulley_loss():
    """Table I task 1 on the ideal plant without and with a 20 % pulley loss.

    Printed: ideal joint RMSE [0.0 0.1 0.1 0.1] mrad, final error 0.0 um; with the loss
    [0.8 3.6 0.7 3.5] mrad and 0.2 um (the feedback still reaches the target).
    """
    out = _run_example("custom_effect.py")
    pattern = re.compile(
        r"^(ideal plant|with PulleyLoss)\s+joint RMSE \[([^\]]*)\] mrad, "
        r"final error\s+(\S+) um, effects (.*)$"
    )
    rows = {}
    for line in out.splitlines():
        match = pattern.match(line)
        if match:
            label, rmse, final, effects = match.groups()
            rows[label] = (float(final), np.array(rmse.split(), dtype=float), effects)
    assert set(rows) == {"ideal plant", "with PulleyLoss"}, out
    ideal, lossy = rows["ideal plant"], rows["with PulleyLoss"]
    # the plant reports the user effect and its parameter (the sidecar's ground truth)
    assert ideal[2] == "{}"
    assert lossy[2] == "{'pulley_loss': {'loss': 0.2}}"
    # both reach the target; the loss shows while tracking: every joint's RMSE grows, and
    # the largest several-fold (a fifth of every insertion tension missing)
    assert 0.0 <= ideal[0] < 500.0 and 0.0 <= lossy[0] < 500.0  # [um]
    assert ideal[1].shape == lossy[1].shape == (4,)
    assert ideal[1].max() < 0.5
    assert np.all(lossy[1] > ideal[1])
    assert lossy[1].max() > 2.0


def test_cdpr_force_estimation_example_matches_the_readme():
    """HC-e on the first second of triangle-12: the estimates' errors on moving cables.

    README (the whole 11.3 s run), moving samples, RMS / mean [N]: following error with the
    friction model 0.023 / 0.001; motor torque with it 0.47 / -0.001 (the torque sensor's
    noise, 0.01 N m / r_D = 0.5 N), with a 20 ms average 0.10 / -0.001; without the friction
    model 2.87-2.90 / +0.76-0.81 (the friction torque's bias). The first second printed
    0.057 / 0.018, 0.48 / -0.009, 0.105 / -0.009, and 2.67-2.72 / +0.69-0.79.
    """
    out = _run_example("cdpr_force_estimation.py", "--seconds", "1")
    lines = out.splitlines()
    assert lines[0].startswith("hc-e on triangle-12, 1.000 s, default plant")
    pattern = re.compile(r"^(.+?)\s+(\d+)-(\d+)\s+(moving|slow|all)\s+(\S+)\s+(\S+)\s+(\S+)$")
    table = {}
    for line in lines[2:]:
        match = pattern.match(line)
        assert match, line
        label, first, last, which, worst, rms, mean = match.groups()
        table[label, which] = (int(first), int(last), float(worst), float(rms), float(mean))
    labels = {label for label, _ in table}
    assert labels == {
        "motor torque, friction model",
        "motor torque, 20 ms average",
        "motor torque / r_D (no tau_F)",
        "following error, friction model",
        "following error, no tau_F",
    }
    assert all((label, "moving") in table for label in labels)  # the first second moves
    # every cable for the torque, the four pure-P drives for the following error
    for label in labels:
        cables = (0, 3) if label.startswith("following") else (0, 7)
        assert table[label, "moving"][:2] == cables
        assert table[label, "all"][3] >= 0 and table[label, "all"][2] >= table[label, "all"][3]

    def moving(label):
        return table[label, "moving"][2:]  # max, rms, mean

    fe, fe_raw = moving("following error, friction model"), moving("following error, no tau_F")
    torque, smooth = moving("motor torque, friction model"), moving("motor torque, 20 ms average")
    torque_raw = moving("motor torque / r_D (no tau_F)")
    # with the friction model: unbiased, the FE estimate within a tenth of a newton RMS, the
    # torque one at the sensor's noise (0.5 N), a fifth of it after the 20 ms average
    assert fe[1] < 0.1 and fe[0] < 1.0 and abs(fe[2]) < 0.05
    assert torque[1] < 0.6 and abs(torque[2]) < 0.05
    assert smooth[1] < 0.2 and abs(smooth[2]) < 0.05
    # without it: biased by the friction torque (README: +0.76 N and +0.81 N)
    for raw in (fe_raw, torque_raw):
        assert raw[1] > 2.0 and 0.5 < raw[2] < 1.2
    assert fe_raw[1] > 10 * fe[1] and torque_raw[1] > 4 * torque[1]


def test_the_arm_tour_and_the_arm_command_draw_their_plots(tmp_path):
    """``make tour`` (``examples/arm_tour.py``) and ``msarm arm --out``: tables and 3 plots."""
    from typer.testing import CliRunner

    from msarm.cli import app
    from msarm.model import load_arm

    plots = {"controllability_shoulder.png", "hill_curves.png", "moment_arms.png"}
    out = _run_example("arm_tour.py", "--out", str(tmp_path / "tour"))
    assert plots <= {p.name for p in (tmp_path / "tour").iterdir()}
    arm = load_arm()
    assert all(name in out for name in arm.cable_names)  # every muscle is listed
    result = CliRunner().invoke(app, ["arm", "--out", str(tmp_path / "arm")])
    assert result.exit_code == 0, result.output
    assert plots <= {p.name for p in (tmp_path / "arm").iterdir()}
    assert all(name in result.stdout for name in arm.joint_names)
    for name in plots:
        assert (tmp_path / "arm" / name).read_bytes().startswith(b"\x89PNG")
