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


def test_the_table_has_the_feedforward_rows_only_when_timed():
    from dataclasses import replace

    from msarm.tasks.bench import SimBenchmark

    plain = SimBenchmark("table1-1", "default", 20.0, 0.1, 0.2, 30.0, 0.4, 0.8, "compiled")
    assert [row[0] for row in plain.rows()][-1] == "closed loop, Python ticks"
    timed = replace(plain, feedforward_s=0.5, feedforward_python_s=2.0, feedforward_path="compiled")
    rows = {row[0]: row[1:] for row in timed.rows()}
    assert len(rows) == 6
    assert rows["closed loop with the feedforward, compiled ticks"] == (0.5, 40.0, 5.0)
    assert rows["closed loop with the feedforward, Python ticks"] == (2.0, 10.0, 20.0)
