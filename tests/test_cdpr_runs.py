"""Cable-robot runs: the paper 000 findings on short runs, refusals, the commands."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from msarm.cdpr.robot_model import load_cable_robot
from msarm.cli import app
from msarm.errors import InputError
from msarm.plant.cdpr_config import DEFAULT_CDPR_PLANT
from msarm.tasks.cdpr_compare import compare_cdpr
from msarm.tasks.cdpr_runner import run_cdpr
from msarm.tasks.cdpr_trajectories import get_cdpr_trajectory


@pytest.fixture(scope="module")
def robot():
    return load_cable_robot()


@pytest.fixture(scope="module")
def triangle():
    return get_cdpr_trajectory("triangle-12")


def test_hc_e_keeps_forces_in_bounds_where_ikc_does_not(robot, triangle):
    ikc = run_cdpr(robot, DEFAULT_CDPR_PLANT, "ikc", triangle).metrics
    hce = run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-e", triangle).metrics
    assert ikc.completed and hce.completed
    assert hce.time_in_bounds_percent >= 95.0
    assert ikc.time_in_bounds_percent < 50.0
    assert hce.mean_position_error_mm < 5.0


def test_hc_tau_without_its_friction_model_tracks_forces_worse(robot, triangle):
    with_model = run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-tau", triangle).metrics
    without = run_cdpr(
        robot, DEFAULT_CDPR_PLANT, "hc-tau", triangle, controller_options={"friction_model": False}
    ).metrics
    assert without.force_rms_error > 3 * with_model.force_rms_error
    assert without.min_force < 5.0 <= with_model.min_force + 0.05


def test_trajectory_outside_the_workspace_is_refused_before_it_runs(robot):
    high = get_cdpr_trajectory("triangle-12", z=0.34)
    with pytest.raises(InputError, match="leaves the wrench-feasible workspace .* sample 0"):
        run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-e", high)


def test_compare_writes_tables_and_repeatability(robot, tmp_path):
    result = compare_cdpr(robot, DEFAULT_CDPR_PLANT, tmp_path, repeats=2, tests=["41"])
    assert set(result.tests) == {"41"}
    assert "41" in result.repeatability
    rho_max, rho_mean = result.repeatability["41"]
    assert 0.0 <= rho_mean <= rho_max
    data = json.loads((tmp_path / "cdpr_comparison.json").read_text())
    assert data["tests"]["41"]["controller"] == "nc"
    assert (tmp_path / "forces_test_41.png").is_file()


def test_cdpr_run_command(tmp_path):
    result = CliRunner().invoke(
        app,
        [
            "cdpr",
            "run",
            "--controller",
            "nc",
            "--trajectory",
            "circle-34",
            "--out",
            str(tmp_path),
            "--json",
        ],
    )
    assert result.exit_code == 0, result.output
    payload = json.loads(result.output)
    assert payload["time_in_bounds_percent"] > 90.0
    assert (tmp_path / "log.parquet").is_file() and (tmp_path / "forces.png").is_file()
    from msarm.io.config import load_config
    from msarm.io.logs import read_log
    from msarm.plant.cdpr_config import CdprPlantConfig

    config = yaml.safe_load((tmp_path / "config.yaml").read_text())  # the resolved config
    assert (config["controller"], config["trajectory"], config["seed"]) == ("nc", "circle-34", 0)
    assert load_config(config["plant"], CdprPlantConfig) == DEFAULT_CDPR_PLANT
    assert read_log(tmp_path / "log.parquet").metadata.extra["plant"] == "default"
    bad = CliRunner().invoke(app, ["cdpr", "run", "--trajectory", "star"])
    assert bad.exit_code != 0 and "triangle-12" in str(bad.exception)
    assert np.isfinite(payload["mean_position_error_mm"])


def test_sensitivity_map_shows_each_pair_good_on_its_side(robot, tmp_path):
    from msarm.cdpr.sensitivity import sensitivity_map
    from msarm.tasks.cdpr_compare import MAP_HEIGHT, plot_sensitivity

    weight = np.concatenate([robot.mass * np.asarray(robot.gravity), np.zeros(3)])
    x, y = [-0.025], [-0.15, 0.15]
    low = {
        pair: sensitivity_map(
            robot.robot,
            pair,
            x,
            y,
            [MAP_HEIGHT],
            wrench=weight,
            f_min=robot.f_min,
            f_max=robot.f_max,
        ).sigma[0, :, 0]
        for pair in ((0, 1), (2, 3))
    }
    assert low[(0, 1)][1] < 1.5 < low[(0, 1)][0]  # cables 1,2: good where y > 0
    assert low[(2, 3)][0] < 1.5 < low[(2, 3)][1]  # cables 3,4: good where y < 0
    assert plot_sensitivity(robot, tmp_path / "map.png", points=11).is_file()
