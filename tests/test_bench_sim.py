"""`msarm bench sim` runs and reports its numbers (no timing is asserted)."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from msarm.cli import app


def test_bench_sim_reports_json():
    result = CliRunner().invoke(
        app, ["bench", "sim", "--plant", "ideal", "--best-of", "1", "--json"]
    )
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    for key in (
        "bare_mujoco_s",
        "plant_only_s",
        "closed_loop_s",
        "closed_loop_python_s",
        "controller_tick_us",
        "closed_loop_real_time_factor",
        "closed_loop_ratio_to_bare_mujoco",
        "target_met",
    ):
        assert key in report
    assert report["closed_loop_s"] > 0 and report["simulated_s"] == 20.0
    assert report["closed_loop_path"] == "compiled"  # the ideal plant qualifies
