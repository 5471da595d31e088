"""``msarm bench allocation``: report structure and CLI (no timing is asserted)."""

import json

import numpy as np
from typer.testing import CliRunner

from msarm.allocation.benchmark import arm_problems, cdpr_problems, run_benchmark
from msarm.cli import app


def test_report_structure():
    report = run_benchmark(n_problems=12, seed=3, batch_repeats=1)
    assert set(report["robots"]) == {"arm", "cdpr"}
    for entry in report["robots"].values():
        assert set(entry["methods"]) == {
            "cvxpy",
            "fast",
            "newton",
            "closed_form",
            "improved_closed_form",
            "batched",
        }
        for name in ("fast", "newton", "batched"):
            row = entry["methods"][name]
            assert row["feasibility_agrees_with_cvxpy"]
            assert row["max_rel_objective_diff_vs_cvxpy"] < 1e-6
            assert row["median_us"] > 0 and row["speedup_vs_cvxpy"] > 0
        assert entry["methods"]["batched"]["solves_per_s"] > 0
    assert set(report["targets_met"]["arm"]) == {
        "fast_speedup_ok",
        "fast_median_ok",
        "batched_throughput_ok",
    }
    json.dumps(report)  # serialisable


def test_problem_generators_are_seeded():
    a1 = cdpr_problems(5, np.random.default_rng(1))
    a2 = cdpr_problems(5, np.random.default_rng(1))
    np.testing.assert_array_equal(a1.M, a2.M)
    np.testing.assert_array_equal(a1.b, a2.b)
    b1 = arm_problems(5, np.random.default_rng(1))
    b2 = arm_problems(5, np.random.default_rng(1))
    np.testing.assert_array_equal(b1.M, b2.M)
    assert b1.M.shape == (5, 4, 9) and a1.M.shape == (5, 6, 8)


def test_cli_json_and_table():
    runner = CliRunner()
    result = runner.invoke(app, ["bench", "allocation", "--n-problems", "5", "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["n_problems"] == 5 and report["seed"] == 0
    result = runner.invoke(app, ["bench", "allocation", "--n-problems", "5", "--seed", "2"])
    assert result.exit_code == 0, result.output
    assert "batched" in result.output and "cvxpy" in result.output
