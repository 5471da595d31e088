"""Cable-robot runs: the paper 000 findings on short runs, refusals, the commands."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import yaml
from conftest import trajectory_head
from typer.testing import CliRunner

from msarm.cdpr.robot_model import load_cable_robot
from msarm.cli import app
from msarm.errors import InputError, MsarmWarning
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
    with pytest.raises(InputError, match=r"leaves the wrench-feasible workspace .* sample 0"):
        run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-e", high)


def test_compare_writes_tables_and_repeatability(
    robot, tmp_path, monkeypatch, short_cdpr_trajectories
):
    import msarm.tasks.cdpr_compare as cdpr_compare

    runs = []  # every run the comparison simulates, with its arguments

    def recorded(*args, **kwargs):
        run = run_cdpr(*args, **kwargs)
        runs.append((args, kwargs, run))
        return run

    monkeypatch.setattr(cdpr_compare, "run_cdpr", recorded)
    result = compare_cdpr(robot, DEFAULT_CDPR_PLANT, tmp_path, repeats=2, tests=["41"])
    assert set(result.tests) == {"41"}
    assert "41" in result.repeatability
    rho_max, rho_mean = result.repeatability["41"]
    assert 0.0 < rho_mean < rho_max
    # the plant matches the model exactly: near zero over these first 3 s too, as the README
    # reports for the whole path (<= 0.1 mm; the paper's 0.076 mm for test 41 comes from the
    # real robot)
    assert rho_max <= 0.1
    # Table 5 recomputed from the two runs of test 41 (Table 3: NC, controller 4, along the
    # triangle of cables 1, 2, trajectory 1), seeds 0 and 1 (different sensor noise): rho(t)
    # is the standard deviation over the repeats of the marker's distance to the path at t
    assert [(a[2], a[3].name, a[4] if len(a) > 4 else k.get("seed", 0)) for a, k, _ in runs] == [
        ("nc", "triangle-12", 0),
        ("nc", "triangle-12", 1),
    ]
    path = short_cdpr_trajectories("triangle-12").position
    errors = []
    for _, _, run in runs:
        marker = np.column_stack([run.columns[f"marker.{a}"] for a in "xyz"])
        errors.append(np.linalg.norm(marker - path[: len(marker)], axis=1))
    n = min(len(e) for e in errors)
    rho = 1000.0 * np.abs(errors[0][:n] - errors[1][:n]) / 2  # the std of two values
    assert rho_max == pytest.approx(rho.max(), rel=1e-12)
    assert rho_mean == pytest.approx(rho.mean(), rel=1e-12)
    data = json.loads((tmp_path / "cdpr_comparison.json").read_text())
    assert data["tests"]["41"]["controller"] == "nc"
    # the largest error after the start-up too (path and run as above, seed 0)
    assert data["start_up_time_s"] == 0.5
    after = 1000.0 * errors[0][runs[0][2].columns["t"] >= 0.5].max()
    assert data["tests"]["41"]["max_position_error_after_start_up_mm"] == pytest.approx(after)
    assert data["switching"] == {}  # test 25 not run
    assert (tmp_path / "forces_test_41.png").is_file()

    # a second call takes both runs from tmp_path/runs: no simulation, the same numbers
    def refuse(*args, **kwargs):
        raise AssertionError("a kept run was simulated again")

    monkeypatch.setattr(cdpr_compare, "run_cdpr", refuse)
    labels = []
    again = compare_cdpr(
        robot, DEFAULT_CDPR_PLANT, tmp_path, repeats=2, tests=["41"], progress=labels.append
    )
    assert labels == ["test 41: nc, triangle-12 (cached)", "repeatability 41: run 2/2 (cached)"]
    assert again.repeatability == result.repeatability
    assert [(c, t, m.as_dict()) for c, t, m in again.tests.values()] == [
        (c, t, m.as_dict()) for c, t, m in result.tests.values()
    ]  # (as dicts: a metric that does not apply is NaN, which equals nothing)
    assert json.loads((tmp_path / "cdpr_comparison.json").read_text())["tests"] == data["tests"]
    # a cut-off file, another plant or resume=False: simulated again
    monkeypatch.setattr(cdpr_compare, "run_cdpr", recorded)
    kept = sorted((tmp_path / "runs").glob("*.npz"))
    assert [p.name for p in kept] == ["41-s0.npz", "41-s1.npz"]
    kept[1].write_bytes(kept[1].read_bytes()[:100])
    runs.clear()
    compare_cdpr(robot, DEFAULT_CDPR_PLANT, tmp_path, repeats=2, tests=["41"])
    assert [a[4] if len(a) > 4 else k.get("seed", 0) for a, k, _ in runs] == [1]
    runs.clear()
    other = replace(DEFAULT_CDPR_PLANT, name="other", timestep=0.0005)
    compare_cdpr(robot, other, tmp_path, repeats=0, tests=["41"])
    compare_cdpr(robot, DEFAULT_CDPR_PLANT, tmp_path, repeats=0, tests=["41"], resume=False)
    assert len(runs) == 2
    # a run kept by another msarm version (or library version): simulated again
    import msarm.tasks.cdpr_run_cache as run_cache

    runs.clear()
    monkeypatch.setattr(run_cache, "code_fingerprint", lambda scope: "f" * 64)
    compare_cdpr(robot, DEFAULT_CDPR_PLANT, tmp_path, repeats=0, tests=["41"])
    assert len(runs) == 1


@pytest.mark.usefixtures("short_cdpr_trajectories")
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
    assert payload["force_rms_error"] is None  # NC keeps its own mean force, not the distribution


@pytest.mark.usefixtures("short_cdpr_trajectories")
def test_a_cdpr_run_cut_off_leaves_no_mix_of_two_runs_nor_an_empty_folder(
    monkeypatch, tmp_path, capsys
):
    """A SIGTERM while the plot was drawn (about 5 s after the other files) left the new
    log, metrics and config beside the old run's forces.png; one during the simulation left
    an empty run folder behind."""
    import os
    import signal
    import sys
    import time

    import msarm.cli
    import msarm.tasks.cdpr_compare as cdpr_compare
    import msarm.tasks.cdpr_runner as cdpr_runner
    from msarm.cli import common

    def killed(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(10)  # interrupted by the handler
        raise AssertionError("not terminated")

    def cut_off(folder, where):
        with monkeypatch.context() as patch:
            patch.setattr(*where, killed)
            patch.setattr(sys, "argv", ["msarm", "cdpr", "run", "--controller", "ikc", "--out"])
            sys.argv.append(str(folder))
            with pytest.raises(SystemExit) as exit_:
                msarm.cli.main()
        assert exit_.value.code == 128 + signal.SIGTERM
        assert capsys.readouterr().err.endswith("msarm: terminated\n")

    folder = tmp_path / "run"
    old = CliRunner().invoke(app, ["cdpr", "run", "--controller", "ikc", "--out", str(folder)])
    assert old.exit_code == 0, old.output
    written = {p.name for p in folder.iterdir()}
    assert {"metrics.json", "forces.png", "log.parquet"} <= written
    cut_off(folder, (cdpr_compare, "plot_forces"))  # the last file before metrics.json
    left = sorted(p.name for p in folder.iterdir())
    assert "metrics.json" not in left and "forces.png" not in left  # no whole run, no old plot
    assert (folder / "log.parquet").is_file()  # the new run's
    monkeypatch.setattr(common, "CREATED_FOLDERS", [])
    fresh = tmp_path / "new" / "run"
    cut_off(fresh, (cdpr_runner, "run_cdpr"))  # during the simulation
    assert not (tmp_path / "new").exists()
    from msarm.cli.cdpr import RUN_FILES  # what a run removes first: all it writes

    assert set(RUN_FILES) == written and RUN_FILES[0] == "metrics.json"


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


def test_a_plant_step_finer_than_the_cycle_keeps_the_timing(robot):
    """A 0.5 ms plant advances two steps a 1 ms cycle: the platform keeps up with the path."""
    from dataclasses import replace

    from msarm.plant.cdpr_config import IDEAL_CDPR_PLANT

    fine = replace(IDEAL_CDPR_PLANT, name="fine", timestep=0.0005)
    path = get_cdpr_trajectory("triangle-12", hold=0.1, speed=0.09)
    coarse = run_cdpr(robot, IDEAL_CDPR_PLANT, "ikc", path).metrics
    finer = run_cdpr(robot, fine, "ikc", path).metrics
    assert finer.completed
    assert finer.max_position_error_mm < 2 * coarse.max_position_error_mm + 0.1
    with pytest.raises(InputError, match=r"timestep 0\.0003 s does not divide .* 0\.001 s"):
        run_cdpr(robot, replace(fine, timestep=0.0003), "ikc", path)
    slow = get_cdpr_trajectory("triangle-12", dt=0.002)
    with pytest.raises(InputError, match=r"every 0\.002 s but controller 'ikc' runs every 0\.001"):
        run_cdpr(robot, IDEAL_CDPR_PLANT, "ikc", slow)


def test_feasibility_is_checked_with_the_controllers_force_bounds(robot):
    """y = 0.37 m is feasible within the file's [5, 35] N, not the controllers' [8, 35] N."""
    from msarm.tasks.cdpr_runner import check_feasible
    from msarm.tasks.cdpr_trajectories import PathSegment, sample_path

    edge = sample_path(
        [PathSegment.line([0.0, 0.30], [0.0, 0.37])], name="edge", hold=0.05, ramp_time=0.2
    )
    check_feasible(robot, edge)  # the file's bounds
    with pytest.raises(InputError, match=r"sample \d+ .*\[8, 35\] N"):
        run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-e", edge)


@pytest.mark.parametrize("controller", ["hc-e", "hc-tau"])
def test_the_plant_starts_holding_the_distribution_the_controller_commands(
    robot, triangle, controller
):
    run = run_cdpr(robot, DEFAULT_CDPR_PLANT, controller, trajectory_head(triangle, 30))
    names = robot.cable_names
    start = np.array([run.truth[f"tension.{n}"][0] for n in names])
    desired = np.array([run.columns[f"f_desired.{n}"][0] for n in names])
    np.testing.assert_allclose(start, desired, atol=0.05)
    assert start.min() >= 8.0 - 0.05  # the controllers' lower bound, not the file's 5 N


def test_a_cable_speed_beyond_the_friction_fit_is_refused_before_the_run(robot):
    fast = get_cdpr_trajectory("triangle-12", speed=0.2)
    with pytest.raises(InputError, match=r"m/min.*'hc-tau'.*expected a slower trajectory"):
        run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-tau", fast)
    # without the friction model the controller never evaluates it: the check does not apply
    from msarm.tasks.cdpr_runner import check_cdpr_run

    check_cdpr_run(robot, DEFAULT_CDPR_PLANT, "hc-tau", fast, {"friction_model": False})


def test_a_controller_modelling_other_winches_than_the_plants_is_warned_about(robot):
    import warnings

    from msarm.control.cdpr_controllers import WinchParameters
    from msarm.errors import MsarmWarning
    from msarm.tasks.cdpr_runner import check_cdpr_run

    trajectory = get_cdpr_trajectory("triangle-12")
    big = replace(
        DEFAULT_CDPR_PLANT, name="big", winch=replace(DEFAULT_CDPR_PLANT.winch, drum_radius=0.03)
    )
    for controller in ("hc-tau", "hc-e"):
        with pytest.warns(
            MsarmWarning,
            match=rf"'{controller}'.*drum radius r_D \[m\] 0.02 \(the plant's winch.drum_radius: "
            r"0.03\) on plant 'big'",
        ):
            check_cdpr_run(robot, big, controller, trajectory)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MsarmWarning)
        check_cdpr_run(robot, big, "hc-f", trajectory)  # load cells: no winch model in the loop
        check_cdpr_run(robot, big, "ikc", trajectory)
        check_cdpr_run(robot, DEFAULT_CDPR_PLANT, "hc-e", trajectory)  # the same winches
        check_cdpr_run(robot, big, "hc-e", trajectory, {"winch": WinchParameters(drum_radius=0.03)})


def test_a_controller_modelling_other_drives_or_friction_than_the_plants_is_warned_about(robot):
    """A plant file with drive.fe_compliance -5e-3 ran HC-e without a word (0.1 % of the run
    in [5, 35] N, force RMS 5.95 N): the FE law, c_v and friction feed eq. 3, 7 and 9 too."""
    import warnings

    from msarm.cdpr.following_error import FollowingErrorModel
    from msarm.cdpr.winch_friction import WinchFrictionModel
    from msarm.control.cdpr_controllers import WinchParameters
    from msarm.errors import MsarmWarning
    from msarm.tasks.cdpr_runner import check_cdpr_run

    trajectory = get_cdpr_trajectory("triangle-12")
    plant = DEFAULT_CDPR_PLANT

    def warned(config, controller, options=None):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MsarmWarning)
            check_cdpr_run(robot, config, controller, trajectory, options)
        return " | ".join(str(w.message) for w in caught if w.category is MsarmWarning)

    soft = replace(plant, name="softfe", drive=replace(plant.drive, fe_compliance=-5.0e-3))
    for controller in ("hc-e", "hc-e-all"):
        text = warned(soft, controller)
        assert "c_f / K_p [m/(N m)] -0.002555 (the plant's drive.fe_compliance: -0.005)" in text
        assert "plant 'softfe'" in text and "command line has no option" in text
    assert warned(soft, "hc-tau") == warned(soft, "hc-f") == ""  # no FE in their set values
    matched = WinchParameters(following_error=FollowingErrorModel(c_f=-1.0, k_p=200.0))
    assert warned(soft, "hc-e", {"winch": matched}) == ""
    # c_v enters only without velocity feed-forward (the P loop then lags by c_v v)
    slow = replace(plant, name="slow", drive=replace(plant.drive, position_gain=100.0))
    assert warned(slow, "hc-e") == ""
    text = warned(slow, "hc-e", {"velocity_feedforward": False})
    assert "c_v [s] 0.005336 (the plant's 1 / drive.position_gain: 0.01)" in text
    # friction: the torque's coefficients for HC-tau and HC-e, the load cell's for HC-f and NC
    torque = (-5.97e-3, -2.31e-4, 6.0e-3, 2.52e-2)
    rough = replace(plant, name="rough", friction=replace(plant.friction, torque_negative=torque))
    for controller in ("hc-tau", "hc-e"):
        text = warned(rough, controller)
        assert "(the plant's friction.torque_negative: [-0.00597, -0.000231, 0.006, 0.0252])" in (
            text
        )
        assert "--option friction_model=false" in text
        assert warned(rough, controller, {"friction_model": False}) == ""
    assert warned(rough, "hc-f") == warned(rough, "nc") == warned(rough, "ikc") == ""
    force = (-1.73e-1, 1.62e-2, -2.51e-2, 0.5)
    sticky = replace(plant, name="sticky", friction=replace(plant.friction, force_positive=force))
    for controller in ("hc-f", "nc"):
        assert "friction.force_positive: [-0.173, 0.0162, -0.0251, 0.5]" in warned(
            sticky, controller
        )
    assert warned(sticky, "hc-e") == ""
    same = WinchParameters(friction=WinchFrictionModel.from_paper_units(force_positive=force))
    assert warned(sticky, "hc-f", {"winch": same}) == ""
    smooth = replace(plant, name="smooth", friction=replace(plant.friction, enabled=False))
    assert "the plant has none: friction.enabled false" in warned(smooth, "hc-e")
    assert warned(smooth, "hc-e", {"friction_model": False}) == ""
    assert warned(plant, "hc-e") == warned(plant, "hc-f") == warned(plant, "nc") == ""


def test_drives_too_weak_for_the_controllers_forces_are_warned_about_and_counted(robot, triangle):
    """winch.torque_limit 0.15 N m (7.5 N at the drum, below the controllers' 8 N) ran with
    exit 0, 10.98 mm mean error and 4 % of the run in bounds, without a word."""
    import warnings

    from msarm.errors import MsarmWarning
    from msarm.tasks.cdpr_runner import check_cdpr_run

    weak = replace(
        DEFAULT_CDPR_PLANT, name="weak", winch=replace(DEFAULT_CDPR_PLANT.winch, torque_limit=0.15)
    )
    short = trajectory_head(triangle, 100)
    for controller in ("hc-e", "ikc"):
        with pytest.warns(
            MsarmWarning,
            match=rf"plant 'weak': winch.torque_limit 0.15 N m gives at most 7.5 N at the drum "
            rf".*below the 8 N lower bound of the force distribution of controller '{controller}'",
        ):
            check_cdpr_run(robot, weak, controller, short)
    with pytest.warns(MsarmWarning, match="torque_limit"):
        saturated = run_cdpr(robot, weak, "hc-e", short).metrics
    with warnings.catch_warnings():
        warnings.simplefilter("error", MsarmWarning)
        fine = run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-e", short).metrics
    assert fine.drive_saturated_samples == 0
    assert 0 < saturated.drive_saturated_samples <= len(short)
    assert saturated.as_dict()["drive_saturated_samples"] == saturated.drive_saturated_samples


def test_cdpr_run_refuses_bad_input_before_creating_its_folder(tmp_path):
    folder = tmp_path / "run"
    bad = CliRunner().invoke(app, ["cdpr", "run", "--controller", "foo", "--out", str(folder)])
    assert isinstance(bad.exception, InputError) and "hc-e" in str(bad.exception)
    assert not folder.exists()
    plant = tmp_path / "coarse.yaml"
    plant.write_text("timestep: 0.0003\n")
    bad = CliRunner().invoke(app, ["cdpr", "run", "--plant", str(plant), "--out", str(folder)])
    assert isinstance(bad.exception, InputError) and "0.0003" in str(bad.exception)
    assert not folder.exists()


@pytest.mark.parametrize(
    "name,match",
    [
        ("a/b", "simple identifier"),
        ("../../x", "simple identifier"),
        ("''", "simple identifier"),
        ("default", "name of a preset"),
        ("ideal", "name of a preset"),
        ("lab-delta=0.5", "without '='"),  # the folder of plant lab with --option delta=0.5
    ],
)
def test_plant_names_that_would_misplace_the_run_folder_are_refused(tmp_path, name, match):
    from msarm.errors import MsarmError

    plant = tmp_path / "plant.yaml"
    plant.write_text(f"name: {name}\ntimestep: 0.0005\n")  # not the preset (that one is taken)
    folder = tmp_path / "run"
    bad = CliRunner().invoke(app, ["cdpr", "run", "--plant", str(plant), "--out", str(folder)])
    assert isinstance(bad.exception, MsarmError), bad.output
    assert match in str(bad.exception) and "name" in str(bad.exception)
    assert not folder.exists()


def test_a_diverged_run_says_why_on_the_console(tmp_path):
    plant = tmp_path / "stiff.yaml"
    plant.write_text("cable: {axial_stiffness: 1.0e30}\n")
    result = CliRunner().invoke(
        app, ["cdpr", "run", "--plant", str(plant), "--out", str(tmp_path / "run")]
    )
    assert result.exit_code == 1
    assert "msarm: error: CDPR simulation diverged at t = " in result.output
    assert "DIVERGED at t = " in result.output
    assert "diverged" in json.loads((tmp_path / "run" / "metrics.json").read_text())


@pytest.mark.usefixtures("short_cdpr_trajectories")
def test_cdpr_compare_records_its_plant_in_a_folder_of_its_own(tmp_path, monkeypatch):
    """Default folder per plant, plant in the JSON, config.yaml, test ids never cut."""
    import msarm.tasks.cdpr_compare as cdpr_compare
    from msarm.io.config import load_config
    from msarm.plant.cdpr_config import IDEAL_CDPR_PLANT, CdprPlantConfig

    long_id = "hc-tau-no-friction/1-with-a-long-id"
    monkeypatch.setattr(cdpr_compare, "_grid", lambda: [(long_id, "ikc", "circle-34", {})])
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["cdpr", "compare", "--plant", "ideal", "--repeats", "0"])
    assert result.exit_code == 0, result.output
    folder = tmp_path / "runs" / "cdpr-compare-ideal"
    data = json.loads((folder / "cdpr_comparison.json").read_text())
    assert load_config(data["plant"], CdprPlantConfig) == IDEAL_CDPR_PLANT
    config = yaml.safe_load((folder / "config.yaml").read_text())
    assert load_config(config["plant"], CdprPlantConfig) == IDEAL_CDPR_PLANT
    assert long_id in result.output


def test_the_forces_plot_names_controller_and_trajectory_once(robot, triangle):
    from msarm.tasks.cdpr_compare import forces_title

    run = run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-e", trajectory_head(triangle, 5))
    assert forces_title(run).startswith("hc-e on triangle-12 (")
    assert forces_title(run, "test 21").startswith("test 21: hc-e on triangle-12 (")
    # the plant, seed and options, where given (msarm cdpr run gives all three)
    title = forces_title(run, "", "ideal", 3, {"fe_feedforward": True, "filter_time": 0.005})
    assert title.startswith("hc-e on triangle-12, ideal plant, seed 3, ")
    assert "fe_feedforward=true filter_time=0.005 (" in title
    assert "default plant, seed 0, no options (" in forces_title(run, "test 21", "default", 0, {})


def test_the_forces_plot_fits_any_cable_count_and_every_peak(tmp_path, monkeypatch):
    """A 9-cable run crashed the fixed 2 x 4 grid (zip strict); a 129 N peak was cut off by
    the fixed 0-40 N axis."""
    from types import SimpleNamespace

    from msarm.tasks.cdpr_compare import plot_forces
    from msarm.tasks.cdpr_runner import CdprMetrics, CdprRun

    figures = _saved_figures(monkeypatch)
    names = [f"cable_{i}" for i in range(9)]
    t = np.arange(0.0, 0.2, 1e-3)
    flat = np.full(len(t), 12.0)
    columns = {"t": t, **{f"f_desired.{n}": flat for n in names}}
    columns.update({f"h.{n}": np.zeros(len(t)) for n in names})
    truth = {"t": t, **{f"tension.{n}": flat.copy() for n in names}}
    truth["tension.cable_8"][100] = 129.0
    run = CdprRun(
        "nc", "made-up", columns, truth, CdprMetrics(1.0, 0.1, 99.0, 12.0, 129.0, 0.1, True)
    )
    model = SimpleNamespace(
        n_cables=9, cable_names=tuple(names), f_min=np.full(9, 5.0), f_max=np.full(9, 35.0)
    )
    plot_forces(run, model, tmp_path / "forces.png")
    (fig,) = figures
    assert len(fig.axes) == 9  # 4 + 4 + 1, the empty places removed
    bottom, top = fig.axes[0].get_ylim()
    assert bottom == 0.0 and top > 129.0
    assert all(ax.get_ylim() == (bottom, top) for ax in fig.axes)  # one shared axis
    assert len(fig.axes[8].get_lines()) == 4  # force, desired and both bounds
    assert fig.axes[8].get_xlabel() == "time [s]" and fig.axes[7].get_xlabel() == "time [s]"


def _saved_figures(monkeypatch) -> list:
    """The figures ``msarm.plots.save_figure`` writes from now on (still written)."""
    import msarm.plots

    figures = []
    save = msarm.plots.save_figure
    monkeypatch.setattr(
        msarm.plots, "save_figure", lambda fig, path: figures.append(fig) or save(fig, path)
    )
    return figures


def _switching_run(trajectory, delta_ms: int = 79):
    """A made-up HC-e run on the rectangle: the activation of pair 3,4 from t = 0, a switch
    to pair 1,2 at 1 s, each over ``delta_ms``; a start-up error spike (1.5 mm at 28 ms) and
    force dip (4.7 N on cable_5 at 26 ms), then a smaller spike (0.9 mm) and dip (6.5 N on
    cable_4) at the switch."""
    from msarm.tasks.cdpr_runner import CdprMetrics, CdprRun

    t = trajectory.t[:2000]
    error = np.full(len(t), 1e-4)
    error[28], error[1050] = 1.5e-3, 0.9e-3
    marker = trajectory.position[: len(t)] + np.outer(error, [1.0, 0.0, 0.0])
    # eq. 10: h = sin^2(alpha), alpha one step delta up at the first cycle already
    ramp = delta_ms * 1e-3
    rising = np.sin(0.5 * np.pi * np.clip((t + 1e-3) / ramp, 0.0, 1.0)) ** 2
    switching = np.sin(0.5 * np.pi * np.clip((t - 0.999) / ramp, 0.0, 1.0)) ** 2
    columns = {"t": t, **{f"marker.{a}": marker[:, k] for k, a in enumerate("xyz")}}
    for i in range(8):
        share = switching if i < 2 else rising - switching if i < 4 else np.zeros(len(t))
        columns[f"h.cable_{i}"] = share
    truth = {"t": t, **{f"tension.cable_{i}": np.full(len(t), 10.0) for i in range(8)}}
    truth["tension.cable_5"][26] = 4.7
    truth["tension.cable_4"][1040] = 6.5
    metrics = CdprMetrics(1.5, 0.1, 99.9, 4.7, 10.0, 0.1, True)
    return CdprRun("hc-e", trajectory.name, columns, truth, metrics)


def test_switching_statistics_leave_the_start_up_out():
    from msarm.tasks.cdpr_compare import START_UP_TIME, switch_intervals, switching_statistics

    assert START_UP_TIME == 0.5  # the trajectories' initial hold
    run = _switching_run(get_cdpr_trajectory("rectangle-switch"))
    # from the last sample before h moves to the first at its end value: a switch of 79
    # cycles is 79 ms long (the in-between samples alone gave 77 ms, and 2 ms for 4 cycles)
    intervals = switch_intervals(run)
    np.testing.assert_allclose(intervals, [(0.0, 0.078), (0.999, 1.078)], atol=1e-9)
    short = switch_intervals(_switching_run(get_cdpr_trajectory("rectangle-switch"), 4))
    np.testing.assert_allclose(short[1], (0.999, 1.003), atol=1e-9)
    stats = switching_statistics(run)
    assert stats["start_up_time_s"] == START_UP_TIME
    assert stats["whole_run"] == {
        "max_position_error_mm": pytest.approx(1.5),
        "max_position_error_time_s": 0.028,
        "min_force_N": 4.7,
        "min_force_time_s": 0.026,
        "min_force_cable": "cable_5",
    }
    after = stats["after_start_up"]
    assert after["max_position_error_mm"] == pytest.approx(0.9)
    assert after["max_position_error_time_s"] == 1.05
    assert (after["min_force_N"], after["min_force_cable"]) == (6.5, "cable_4")
    assert stats["activation_s"] == list(intervals[0])
    (switch,) = stats["switches"]
    assert (switch["start_s"], switch["end_s"]) == intervals[1]
    assert switch["max_position_error_mm"] == pytest.approx(0.9)
    assert switch["min_force_time_s"] == 1.04


def test_the_switching_plot_scales_the_error_to_after_the_start_up(tmp_path, monkeypatch):
    from msarm.tasks.cdpr_compare import plot_switching

    figures = _saved_figures(monkeypatch)
    rectangle = get_cdpr_trajectory("rectangle-switch")
    plot_switching(
        {0.02: _switching_run(rectangle), 0.5: _switching_run(rectangle, 4)}, tmp_path / "s.png"
    )
    (fig,) = figures
    forces, _, errors, _ = fig.axes
    assert len(forces.get_lines()) >= 8  # every cable drawn
    legend = [t.get_text() for t in forces.get_legend().get_texts()]
    assert "cables 5-8 (paper), never switched" in legend
    assert "start-up (first 0.5 s), left out" in legend
    assert "switch starts / ends" in legend
    # the error axis is set by the largest error after the start-up, the spike named instead
    assert errors.get_ylim()[1] == pytest.approx(1.3 * 0.9)
    notes = [t.get_text() for t in errors.texts]
    assert any(n.startswith("start-up peak 1.50 mm at 0.028 s") for n in notes)
    assert "after 0.5 s: max error 0.90 mm" in errors.get_title()
    assert "whole run: max error 1.50 mm" in errors.get_title()


def test_the_sensitivity_maps_share_one_scale_that_says_when_it_clips():
    from msarm.tasks.cdpr_compare import SIGMA_CLIP, sigma_colour_scale

    low = [np.array([[1.0, np.nan], [2.0, 3.0]]), np.array([[1.5, 3.5]])]
    norm, extend, label = sigma_colour_scale(low)
    assert (norm.vmin, norm.vmax, extend) == (0.0, SIGMA_CLIP, "neither")
    assert "clipped" not in label
    norm, extend, label = sigma_colour_scale([*low, np.array([[6.0]])])
    assert (norm.vmax, extend) == (SIGMA_CLIP, "max")
    assert "clipped at 4 N" in label


def test_fe_feedforward_holds_hc_e_position_controlled_cables_at_their_set_length(robot):
    """HC-e's P drives leave position-controlled switchable cables a following error long;
    the option feeds eq. 9's following error forward, so they end at the length asked."""
    trajectory = trajectory_head(get_cdpr_trajectory("triangle-12"), 2000)  # hold, ramp, 1 s moving
    names = robot.cable_names
    ik = np.array([robot.cable_lengths(p, trajectory.rotation) for p in trajectory.position])
    off = {}
    for option in (False, True):
        run = run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-e", trajectory, 0, {"fe_feedforward": option})
        c = run.columns
        moving = c["t"] > 1.0
        # cables 3 and 4 (indices 2, 3) are switchable, position-controlled on triangle-12
        assert np.all(c[f"h.{names[2]}"][moving] == 0.0)
        off[option] = [
            float(np.mean(np.abs(c[f"cable_length.{names[i]}"] - ik[:, i])[moving])) for i in (2, 3)
        ]
    assert min(off[False]) > 3e-4  # the P drive's deflection: about 0.5 mm
    assert max(off[True]) < 0.2 * min(off[False])
    with pytest.raises(InputError, match="fe_feedforward: only HC-e"):
        run_cdpr(robot, DEFAULT_CDPR_PLANT, "hc-f", trajectory, 0, {"fe_feedforward": True})


def test_cdpr_run_takes_controller_options(tmp_path, monkeypatch):
    from msarm.cli.cdpr import controller_options

    assert controller_options(["fe_feedforward=true", "filter_time=0.005"]) == {
        "fe_feedforward": True,
        "filter_time": 0.005,
    }
    for bad, message in (
        (["fe_feedforward"], "expected KEY=VALUE"),
        (["a=1", "a=2"], "a given twice"),
        (["gains=[1, 2]"], "expected a number, true/false or a word"),
    ):
        with pytest.raises(InputError, match=message):
            controller_options(bad)
    monkeypatch.chdir(tmp_path)
    figures = _saved_figures(monkeypatch)
    args = ["cdpr", "run", "--controller", "hc-e", "--option", "fe_feedforward=true", "--json"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    folder = tmp_path / "runs" / "cdpr-hc-e-triangle-12-fe_feedforward=true"
    config = yaml.safe_load((folder / "config.yaml").read_text())
    assert config["controller_options"] == {"fe_feedforward": True}
    # the feed-forward brings HC-e's mean error to HC-f's (0.26 mm on triangle-12)
    assert json.loads(result.output)["mean_position_error_mm"] < 0.35
    # forces.png names the plant, the seed and the options, and what its line is
    (fig,) = figures
    assert "hc-e on triangle-12, default plant, seed 0, fe_feedforward=true (" in (
        fig._suptitle.get_text()
    )
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels[0] == "true force (simulation)"
    wrong = CliRunner().invoke(app, ["cdpr", "run", "--controller", "hc-f", "--option", "x=1"])
    assert wrong.exit_code != 0 and "invalid option" in str(wrong.exception)


def _cdpr_error(monkeypatch, capsys, tmp_path, *args: str) -> str:
    """``msarm cdpr run ARGS`` through the console script: exit code 2, one line, no folder."""
    import sys

    from msarm.cli import main

    out = tmp_path / "run"
    monkeypatch.setattr(sys, "argv", ["msarm", "cdpr", "run", *args, "--out", str(out)])
    with pytest.raises(SystemExit) as exit_info:
        main()
    err = capsys.readouterr().err
    assert exit_info.value.code == 2, err
    assert err.startswith("msarm: error: ") and err.count("\n") == 1, err
    assert not out.exists()  # refused before any folder was made
    return err


def test_an_object_option_is_refused_on_the_command_line(monkeypatch, capsys, tmp_path):
    for controller, item in (("hc-e", "gains=foo"), ("hc-f", "gains=1"), ("ikc", "winch=foo")):
        key = item.split("=")[0]
        err = _cdpr_error(
            monkeypatch, capsys, tmp_path, "--controller", controller, "--option", item
        )
        assert f"option '{key}' of CDPR controller '{controller}'" in err
        assert "cannot be set from the command line" in err and "make_cdpr_controller" in err
    err = _cdpr_error(monkeypatch, capsys, tmp_path, "--option", "gain=1")
    assert "invalid option for CDPR controller 'hc-e': 'gain'" in err
    listed = err.split("valid options: ")[1].strip().split(", ")
    assert "gains" not in listed and "winch" not in listed and "delta" in listed


def test_an_option_value_of_the_wrong_type_is_refused(monkeypatch, capsys, tmp_path):
    for item, expected in (
        (
            "fe_feedforward=flase",
            "'fe_feedforward' of CDPR controller 'hc-e' expects true or false",
        ),
        ("start_active=maybe", "'start_active' of CDPR controller 'hc-e' expects true or false"),
        ("velocity_feedforward=2", "'velocity_feedforward' of CDPR controller 'hc-e' expects true"),
        ("delta=fast", "'delta' of CDPR controller 'hc-e' expects a number, got 'fast'"),
    ):
        err = _cdpr_error(monkeypatch, capsys, tmp_path, "--option", item)
        assert expected in err and repr(yaml.safe_load(item.split("=")[1])) in err


def test_option_numbers_in_exponent_form_are_floats():
    from msarm.cli.cdpr import controller_options
    from msarm.tasks.cdpr_runner import check_cdpr_run

    options = controller_options(["f_max=4e1", "dt=1e-3", "f_min=5e0"])
    assert options == {"f_max": 40.0, "dt": 0.001, "f_min": 5.0}
    assert controller_options(["f_max=4e1", "dt=1e-3", "f_min=5e0"], "hc-e") == options
    robot = load_cable_robot()
    with pytest.warns(MsarmWarning, match=r"within \[5, 40\] N, beyond the model file's"):
        ctrl = check_cdpr_run(
            robot, DEFAULT_CDPR_PLANT, "hc-e", get_cdpr_trajectory("triangle-12"), options
        )
    assert (ctrl.f_min, ctrl.f_max, ctrl.dt) == (5.0, 40.0, 0.001)
    assert controller_options(["delta_l_limit=null"], "nc") == {"delta_l_limit": None}


def test_an_option_that_is_no_yaml_is_one_line(monkeypatch, capsys, tmp_path):
    err = _cdpr_error(monkeypatch, capsys, tmp_path, "--option", "fe_feedforward=[1")
    assert "--option fe_feedforward: '[1' is not a YAML value: column 3: expected ','" in err


def test_plant_file_friction_speeds_are_refused_in_the_files_unit(tmp_path):
    from msarm.errors import ConfigError
    from msarm.io.config import load_config
    from msarm.plant.cdpr_config import CdprPlantConfig

    (tmp_path / "plant.yaml").write_text("friction: {v_low: 10, v_high: 1}\n")
    with pytest.raises(ConfigError, match=r"key 'friction'.*\[m/min\], got v_low=10, v_high=1$"):
        load_config(tmp_path / "plant.yaml", CdprPlantConfig)


def test_a_plant_file_of_the_other_robot_gets_a_hint(tmp_path):
    from msarm.cli.cdpr import _plant
    from msarm.cli.common import resolve_plant
    from msarm.errors import ConfigError
    from msarm.io.config import write_config
    from msarm.plant.config import DEFAULT_PLANT

    arm = write_config(DEFAULT_PLANT, tmp_path / "arm.yaml")
    arm_run = write_config({"task": "table1-1", "plant": DEFAULT_PLANT}, tmp_path / "config.yaml")
    for path in (arm, arm_run):
        with pytest.raises(ConfigError, match="unknown key 'effects'") as info:
            _plant(str(path))
        assert str(info.value).endswith(
            "; this looks like an arm plant (key 'effects'; for msarm track --plant), not a "
            "cable robot's plant"
        )
    cdpr = write_config(DEFAULT_CDPR_PLANT, tmp_path / "cdpr.yaml")
    with pytest.raises(ConfigError, match=r"this looks like a cable robot's plant .*'drive'"):
        resolve_plant(str(cdpr))
    (tmp_path / "typo.yaml").write_text("winch: {drum_radiu: 0.02}\n")  # no hint for a typo
    for resolve in (_plant, resolve_plant):
        with pytest.raises(ConfigError) as info:
            resolve(str(tmp_path / "typo.yaml"))
        assert "looks like" not in str(info.value)


def test_the_readme_plant_file_is_the_default_plant(tmp_path):
    """The README's "default plant, written out" YAML gives ``CdprPlantConfig()`` but its name."""
    from pathlib import Path

    from msarm.io.config import load_config
    from msarm.plant.cdpr_config import CdprPlantConfig

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    after = readme.split("The\ndefault plant, written out", 1)[1]
    block = after.split("```yaml\n", 1)[1].split("```", 1)[0]
    (tmp_path / "plant.yaml").write_text(block)
    written = load_config(tmp_path / "plant.yaml", CdprPlantConfig)
    assert replace(written, name=CdprPlantConfig().name) == CdprPlantConfig()


def test_the_time_in_bounds_is_not_rounded_up_to_100():
    """99.96 % was printed 100.0, which reads as "always inside"."""
    from msarm.cli.cdpr import _share_inside

    assert _share_inside(99.96) == "99.96"
    assert _share_inside(99.999) == "99.99"
    assert _share_inside(100.0) == "100"
    assert _share_inside(98.94) == "98.9"
    assert _share_inside(float("nan")) == "-"


def test_every_run_metric_of_a_hand_made_run_is_its_hand_value(robot, triangle):
    """msarm.tasks.cdpr_runner._metrics on four samples whose metrics are worked out by hand
    (the definitions of CdprMetrics and the module docstring, paper 000 section 4): the
    marker's errors, the share of samples with every force within the model's bounds (both
    ends inside), the force extremes and the RMS error of the force-controlled entries only."""
    from msarm.tasks.cdpr_runner import _metrics

    lower, upper = float(robot.f_min[0]), float(robot.f_max[0])
    assert np.all(robot.f_min == lower) and np.all(robot.f_max == upper)
    reference = triangle.position[:4]  # the run stopped after 4 samples (a shorter marker)
    offsets_mm = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 0.0, -2.0], [1.0, 0.0, 0.0]])
    marker = reference + offsets_mm / 1000.0  # errors 0, 5, 2 and 1 mm
    force = np.full((4, 8), 20.0)
    force[1, 2] = lower - 0.5  # below: sample 1 is outside the bounds
    force[2, 0] = lower  # on the bounds: inside
    force[3, 5] = upper  # on the bounds: inside
    controlled = np.zeros((4, 8), dtype=bool)
    controlled[0, :2] = controlled[2, 6:] = True
    desired = force + 50.0  # far off where the cable is not force-controlled
    desired[0, 0], desired[0, 1] = force[0, 0] - 3.0, force[0, 1] + 4.0  # errors 3 and -4 N
    desired[2, 6:] = force[2, 6:]  # errors 0 and 0 N
    metrics = _metrics(robot, triangle, marker, force, desired, controlled, True)
    assert metrics.max_position_error_mm == pytest.approx(5.0, rel=1e-9)
    assert metrics.mean_position_error_mm == pytest.approx((0 + 5 + 2 + 1) / 4, rel=1e-9)
    assert metrics.time_in_bounds_percent == 75.0  # 3 of 4 samples
    assert metrics.min_force == lower - 0.5
    assert metrics.max_force == upper
    assert metrics.force_rms_error == pytest.approx(np.sqrt((9 + 16 + 0 + 0) / 4))  # 2.5 N
    assert metrics.completed is True
    # no force-controlled cable (IKC, NC): no force error; a run that stopped is not completed
    idle = _metrics(robot, triangle, marker, force, desired, controlled & False, False)
    assert math.isnan(idle.force_rms_error) and idle.completed is False


def test_a_turned_platform_is_controlled_at_its_rotation(robot):
    """The loop took the inverse kinematics at R = I whatever the trajectory's rotation: the
    platform turned back and its cables went slack (0 N), with a position error that looked
    fine. At its rotation (0.1 rad about z) every cable stays taut."""
    from msarm.tasks.cdpr_trajectories import PathSegment, sample_path

    path = sample_path(
        [PathSegment.line([0.0, 0.0], [0.05, 0.0])], name="turned", hold=0.2, ramp_time=0.1
    )
    c, s = math.cos(0.1), math.sin(0.1)
    turned = replace(path, rotation=np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]))
    for controller in ("ikc", "hc-e"):
        metrics = run_cdpr(robot, DEFAULT_CDPR_PLANT, controller, turned).metrics
        assert metrics.completed
        assert metrics.min_force > 3.0, controller


def test_controller_bounds_beyond_the_robots_are_warned_about(robot, triangle):
    """f_min=0 let a controller plan slack cables on a robot whose file says [5, 35] N; the run
    left the bounds all the time with no message. The shipped [8, 35] N say nothing."""
    import warnings

    from msarm.tasks.cdpr_runner import check_cdpr_run

    with pytest.warns(MsarmWarning, match=r"within \[0, 35\] N, beyond the model file's cable"):
        check_cdpr_run(robot, DEFAULT_CDPR_PLANT, "hc-f", triangle, {"f_min": 0.0})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_cdpr_run(robot, DEFAULT_CDPR_PLANT, "hc-f", triangle)
