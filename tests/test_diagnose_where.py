"""The "where" step of the gap diagnosis: residuals of a log and their breakdown."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from msarm.control import ArmControllerConfig
from msarm.diagnose.residuals import DiagnosisWarning, Residuals, residuals_from_log
from msarm.diagnose.where import (
    GROUPS,
    LOAD_PHASES,
    MOTION_PHASES,
    PhaseSettings,
    break_down,
    diagnose_where,
    plot_heatmap,
)
from msarm.errors import LogError
from msarm.io.logs import TIME, RunLog, read_log, sidecar_path, write_log
from msarm.plant import IDEAL_PLANT
from msarm.plant.config import JointFrictionConfig
from msarm.tasks.track import TrackSettings, track
from msarm.tasks.trajectories import hold_then_move

# The noise-free simulated logs hold a cable at its floor tension over a whole run
# ('tension_motor.teres_minor'): the dead-sensor warning is expected on them (asserted in
# test_diagnose_where.py::test_a_noise_free_log_warns_about_the_cable_held_at_its_floor).
pytestmark = pytest.mark.filterwarnings(
    "ignore:.*hold one value over the whole log:msarm.diagnose.residuals.DiagnosisWarning"
)

HOME = np.array([0.0, 0.0, 0.0, -0.2])
SHORT = hold_then_move(
    "short", HOME, [0.15, 0.4, -0.3, -0.9], wait=0.5, move_time=1.5, duration=3.0
)


def _plant(name: str, **effects):
    return replace(IDEAL_PLANT, name=name, effects=replace(IDEAL_PLANT.effects, **effects))


@pytest.fixture(scope="module")
def logs(arm, tmp_path_factory):
    """Log files of the short task on the ideal plant and with joint friction alone."""
    root = tmp_path_factory.mktemp("diagnose_where")
    plants = {
        "ideal": _plant("ideal"),
        "joint_friction": _plant(
            "joint_friction", joint_friction=JointFrictionConfig(enabled=True)
        ),
    }
    out = {}
    for name, plant in plants.items():
        settings = TrackSettings("short", 1, plant, ArmControllerConfig())
        result = track(arm, SHORT, settings, root / name, plots_too=False)
        out[name] = result.files["log"]
    return out


@pytest.fixture(scope="module")
def residuals(arm, logs):
    return {name: residuals_from_log(arm, path) for name, path in logs.items()}


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def test_ideal_plant_has_a_small_residual_and_joint_friction_not(residuals):
    ideal, friction = residuals["ideal"], residuals["joint_friction"]
    assert ideal.valid.all() and friction.valid.all()
    assert ideal.joint_torque.shape == (len(ideal), 4)
    assert ideal.cable_length.shape == (len(ideal), 9)
    # ideal: filtering error only; joint friction: Coulomb 0.15 N m plus viscous
    assert _rms(ideal.joint_torque) < 0.02
    assert _rms(friction.joint_torque) > 0.08
    assert _rms(friction.joint_torque) > 10 * _rms(ideal.joint_torque)
    # the replay (nominal dynamics under the logged tensions) drifts away with friction; on the
    # ideal plant it stays within integration error (2e-5 rad; 2e-4 when it drove the step
    # from t_k with the tension of the period before)
    assert _rms(ideal.replay) < 5e-5
    assert _rms(friction.replay) > 10 * _rms(ideal.replay)
    # rigid cables: the motor encoders agree with the path lengths
    assert np.abs(ideal.cable_length).max() < 2e-4
    assert np.abs(friction.cable_length).max() < 2e-4


def test_joint_friction_concentrates_in_motion_not_in_hold(residuals):
    """Coulomb + viscous friction acts while the joints move; in hold only what stiction takes.

    Checked: the acceleration and constant-velocity phases each have an energy density above
    1, hold below 1, and the moving phases together carry most of the energy although the
    arm holds more than half of the time.
    """
    breakdown = break_down(residuals["joint_friction"])
    hold = breakdown.density("motion", "hold")
    assert hold < 0.7
    assert breakdown.density("motion", "acceleration") > 1.2
    assert breakdown.density("motion", "constant_velocity") > 1.2
    hold_row = next(r for r in breakdown.group("motion") if r.where == "hold")
    assert hold_row.time_share > 50
    moving = breakdown.share("motion", "acceleration") + breakdown.share(
        "motion", "constant_velocity"
    )
    assert moving > 60
    # joint friction is the same on every joint: no joint carries (nearly) all of it
    assert max(r.share for r in breakdown.group("channel")) < 40


def test_shares_sum_to_100_percent_and_logs_combine(residuals):
    single = {name: break_down(r) for name, r in residuals.items()}
    both = break_down(list(residuals.values()))
    for breakdown in [*single.values(), both]:
        for group in GROUPS:
            rows = breakdown.group(group)
            assert rows, group
            assert sum(r.share for r in rows) == pytest.approx(100.0, abs=1e-9)
            if group != "channel":
                assert sum(r.time_share for r in rows) == pytest.approx(100.0, abs=1e-9)
                assert sum(r.samples for r in rows) == breakdown.samples
        assert np.nansum(breakdown.posture_samples) == breakdown.samples
    assert both.samples == sum(b.samples for b in single.values())
    assert both.total_energy == pytest.approx(sum(b.total_energy for b in single.values()))
    assert both.sources == tuple(r.source for r in residuals.values())


def _hand_residuals() -> Residuals:
    """40 samples at 100 Hz, 2 joints and 2 cables, phases laid out by hand."""
    t = np.arange(40) / 100.0
    qd = np.zeros((40, 2))
    qdd = np.zeros((40, 2))
    qd[10:30, 0] = 0.3  # 10-19 constant velocity
    qdd[20:30, 0] = 2.0  # 20-29 acceleration
    qd[30:35, 1] = 0.3  # 30-39 reversal of joint 1 (also accelerating)
    qd[35:40, 1] = -0.3
    qdd[30:40, 1] = 5.0
    tension = np.full((40, 2), 10.0)
    tension[0:4] = [1.0, 100.0]  # low tension, also the highest load: counted as low
    tension[4:8] = [10.0, 50.0]  # high load
    torque = np.zeros((40, 2))
    torque[:, 0] = 1.0
    torque[30:40, 1] = 2.0
    q = np.column_stack([np.linspace(0, 1, 40), np.linspace(-1, 0, 40)])
    return Residuals(
        source="hand",
        joint_names=("a", "b"),
        cable_names=("c1", "c2"),
        sample_rate_hz=100.0,
        t=t,
        valid=np.ones(40, dtype=bool),
        joint_torque=torque,
        cable_length=None,
        drive=None,
        replay=None,
        q=q,
        qd=qd,
        qdd=qdd,
        cable_velocity=np.zeros((40, 2)),
        tension=tension,
    )


def test_each_sample_counts_in_the_first_matching_phase():
    breakdown = break_down(
        _hand_residuals(), settings=PhaseSettings(high_load_percentile=80.0), bins=2
    )
    motion = {r.where: r for r in breakdown.group("motion")}
    assert {k: r.samples for k, r in motion.items()} == {
        "hold": 10,
        "constant_velocity": 10,
        "acceleration": 10,
        "reversal": 10,
    }
    assert set(motion) == set(MOTION_PHASES)
    # energy: joint a 1 per sample (40), joint b 4 per reversal sample (40): total 80
    assert breakdown.total_energy == pytest.approx(80.0)
    assert motion["reversal"].share == pytest.approx(62.5)
    assert motion["hold"].share == pytest.approx(12.5)
    assert motion["hold"].density == pytest.approx(0.5)
    assert motion["reversal"].density == pytest.approx(2.5)
    load = {r.where: r.samples for r in breakdown.group("load")}
    assert load == {"low_tension": 4, "high_load": 4, "normal_load": 32}
    assert set(load) == set(LOAD_PHASES)
    channel = {r.where: r.share for r in breakdown.group("channel")}
    assert channel == pytest.approx({"a": 50.0, "b": 50.0})
    # the posture grid: 2 x 2 bins over the logged range, the samples on its diagonal
    assert breakdown.posture_samples.tolist() == [[20, 0], [0, 20]]
    assert np.isnan(breakdown.posture_rms[0, 1])
    assert breakdown.posture_rms[1, 1] == pytest.approx(np.sqrt(60 / (20 * 2)))


def test_cable_residual_is_the_motor_length_minus_the_path_length(arm, logs):
    log = read_log(logs["ideal"])
    columns = dict(log.columns)
    cable = arm.cable_names[0]
    extra = 0.5 * log.t  # the motor turns on by 0.5 rad/s more than the cable needs
    columns[f"motor_angle.{cable}"] = columns[f"motor_angle.{cable}"] + extra
    shifted = RunLog(columns, log.metadata)
    before = residuals_from_log(arm, log)
    after = residuals_from_log(arm, shifted)
    # winding the drum shortens the cable the encoder reckons: l_hat = l0 - r (theta - theta0)
    np.testing.assert_allclose(
        after.cable_length[:, 0] - before.cable_length[:, 0],
        -0.003 * (extra - extra[0]),
        atol=1e-12,
    )
    np.testing.assert_array_equal(after.cable_length[:, 1:], before.cable_length[:, 1:])


def test_the_cable_length_breakdown_is_about_each_logs_mean(residuals):
    """The encoders give lengths up to an offset (their zero at the log's start): the length
    breakdown is the same whatever offset each log's estimate starts from, and its energy is
    that of each log's residual about its mean, as the diagnosis's length group scores it."""
    runs = [r for r in residuals.values() if r.cable_length is not None]
    assert runs
    base = break_down(runs, "cable_length")
    expected = 0.0
    for run in runs:
        values = run.cable_length[run.valid]
        expected += float(np.sum((values - values.mean(axis=0)) ** 2))
    assert base.total_energy == pytest.approx(expected, rel=1e-12)
    rng = np.random.default_rng(0)
    shifted = [
        replace(run, cable_length=run.cable_length + rng.normal(0, 1e-3, run.cable_length.shape[1]))
        for run in runs
    ]
    moved = break_down(shifted, "cable_length")
    assert moved.total_energy == pytest.approx(base.total_energy, rel=1e-9)
    shares = {(r.group, r.where): r.share for r in base.rows}
    assert {(r.group, r.where): r.share for r in moved.rows} == pytest.approx(shares, abs=1e-9)


def test_a_log_of_another_model_is_refused(arm, logs, tmp_path):
    log = read_log(logs["ideal"])
    other = "0" * 64
    path = write_log(
        tmp_path / "other.parquet", RunLog(log.columns, replace(log.metadata, model_sha256=other))
    )
    with pytest.raises(LogError) as info:
        residuals_from_log(arm, path)
    message = str(info.value)
    assert str(path) in message and other in message and arm.sha256 in message


def test_a_missing_channel_is_named(arm, logs, tmp_path):
    log = read_log(logs["ideal"])
    column = f"tension_motor.{arm.cable_names[-1]}"
    columns = {k: v for k, v in log.columns.items() if k != column}
    path = write_log(tmp_path / "missing.parquet", RunLog(columns, log.metadata))
    with pytest.raises(LogError, match=f"{path}.*{column}"):
        residuals_from_log(arm, path)
    # without motor encoders the cable residual is skipped, with a warning
    columns = {k: v for k, v in log.columns.items() if not k.startswith("motor_angle.")}
    path = write_log(tmp_path / "no_motor.parquet", RunLog(columns, log.metadata))
    with pytest.warns(DiagnosisWarning, match="motor_angle"):
        result = residuals_from_log(arm, path)
    assert result.cable_length is None and result.kinds() == ["joint_torque", "drive", "replay"]


def test_a_noise_free_log_warns_about_the_cable_held_at_its_floor(arm, logs):
    """The noise-free simulation keeps teres_minor at its floor tension over the whole run:
    the log is diagnosed as it is, with the dead-sensor warning (the one this module's
    ``pytestmark`` hides in the other tests)."""
    import re

    from msarm.diagnose.residuals import ResidualSpec

    for path in logs.values():
        assert np.ptp(read_log(path).columns["tension_motor.teres_minor"]) == 0.0
        with pytest.warns(
            DiagnosisWarning,
            match=rf"^{re.escape(str(path))}: column\(s\) .*'tension_motor\.teres_minor'.* "
            r"hold one value over the whole log: a dead or disconnected sensor\?",
        ):
            result = residuals_from_log(arm, path, spec=ResidualSpec(replay=False))
        assert result.valid.all()


def test_time_gaps_split_the_log_and_warn(arm, logs, residuals, tmp_path):
    log = read_log(logs["ideal"])
    keep = np.ones(len(log), dtype=bool)
    keep[10:13] = False  # leaves a 10-sample head, too short for the filter
    keep[300:310] = False
    path = write_log(
        tmp_path / "gaps.parquet",
        RunLog({k: v[keep] for k, v in log.columns.items()}, log.metadata),
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = residuals_from_log(arm, path)
    messages = [str(w.message) for w in caught if issubclass(w.category, DiagnosisWarning)]
    assert any(str(path) in m and "'t'" in m and "gap" in m for m in messages)
    assert any("left out" in m for m in messages)
    assert not result.valid[:10].any() and result.valid[10:].all()
    assert np.isnan(result.joint_torque[:10]).all()
    assert _rms(result.joint_torque[result.valid]) < 0.02
    breakdown = break_down(result)
    assert breakdown.samples == int(result.valid.sum())


def test_a_time_gap_does_not_restart_the_cable_length_estimate(arm, logs, tmp_path):
    """The motor angles are absolute: after a dropout the length error goes on where it was."""
    log = read_log(logs["ideal"])
    columns = dict(log.columns)
    for name in arm.cable_names:  # a drum slip that grows with time: 1 mrad/s on each motor
        columns[f"motor_angle.{name}"] = columns[f"motor_angle.{name}"] + 1e-3 * log.t
    whole = RunLog(columns, log.metadata)
    keep = np.ones(len(log), dtype=bool)
    keep[400:500] = False  # a 0.4 s dropout
    full_path = write_log(tmp_path / "whole.parquet", whole)
    gap_path = write_log(
        tmp_path / "dropout.parquet", RunLog({k: v[keep] for k, v in columns.items()}, log.metadata)
    )
    full = residuals_from_log(arm, full_path)
    with pytest.warns(DiagnosisWarning, match="gap"):
        dropped = residuals_from_log(arm, gap_path)
    assert dropped.valid.all()
    np.testing.assert_allclose(dropped.cable_length, full.cable_length[keep], rtol=0, atol=1e-12)
    # the slip is there to be seen after the gap: r * 1 mrad/s * 0.4 s more than before it
    assert np.abs(full.cable_length[500] - full.cable_length[399]).max() > 1e-6


def test_the_diagnosis_never_opens_the_sidecar(arm, logs, tmp_path):
    log = read_log(logs["joint_friction"])
    path = write_log(tmp_path / "log.parquet", log)
    sidecar = sidecar_path(logs["joint_friction"])
    assert sidecar.is_file()
    sidecar_path(path).write_bytes(sidecar.read_bytes())
    with_sidecar = diagnose_where(arm, [path])
    sidecar_path(path).unlink()
    without = diagnose_where(arm, [path])
    assert with_sidecar.to_markdown() == without.to_markdown()
    assert with_sidecar.rows == without.rows


def test_markdown_and_heat_map(arm, residuals, tmp_path):
    breakdown = break_down(list(residuals.values()), model=arm)
    text = breakdown.to_markdown()
    for group in GROUPS:
        assert f"### By {group}" in text
    assert "| hold |" in text
    png = plot_heatmap(breakdown, tmp_path / "where.png")
    assert png.is_file() and png.read_bytes()[:4] == b"\x89PNG"
    assert breakdown.posture_rms.shape == (5, 5)
    # the grid spans the model's range of the posture joints
    j = arm.joint_names.index(breakdown.posture_joints[0])
    assert breakdown.posture_edges[0][0] == arm.joint_lower[j]
    for kind in ("cable_length", "replay"):
        assert break_down(residuals["joint_friction"], kind=kind).unit in ("m", "rad")


def _saved_figures(monkeypatch) -> list:
    """The figures ``msarm.plots.save_figure`` writes from now on (still written)."""
    import msarm.plots

    figures = []
    save = msarm.plots.save_figure

    def keep(fig, path):
        figures.append(fig)
        return save(fig, path)

    monkeypatch.setattr(msarm.plots, "save_figure", keep)
    return figures


def test_the_heat_map_shows_degrees_millimetres_and_names_the_even_share(
    arm, residuals, tmp_path, monkeypatch
):
    figures = _saved_figures(monkeypatch)
    breakdown = break_down(residuals["joint_friction"], kind="cable_length", model=arm)
    plot_heatmap(breakdown, tmp_path / "where.png")
    grid, channels, _ = figures[-1].axes[:3]
    assert grid.get_xlabel().endswith("[deg]") and grid.get_ylabel().endswith("[deg]")
    x0, x1 = sorted(grid.get_xlim())
    edges = np.degrees(breakdown.posture_edges[1])
    assert (x0, x1) == pytest.approx((edges[0], edges[-1]))
    colourbar = figures[-1].axes[-1]
    assert colourbar.get_ylabel() == "cable_length RMS [mm]"
    mesh = grid.collections[0]
    finite = np.isfinite(breakdown.posture_rms)
    assert mesh.get_array().compressed() == pytest.approx(1000 * breakdown.posture_rms[finite])
    legend = [t.get_text() for t in channels.get_legend().get_texts()]
    assert legend == [f"even share (100 % / {len(breakdown.group('channel'))})"]
    assert breakdown.unit == "m"  # the data stay SI


def _replay_one_window_at_a_time(
    work, q_log, q_start, qd_start, tension, dt, spec, period_ending, lost
):
    """The reference: each window integrated alone, sample by sample; the step from t_k is
    driven by the tension over [t_k, t_k+1]: tension[k + 1] when each sample is the tension
    over the period ending at it, tension[k] when read at its instant."""
    from msarm.diagnose.residuals import _REPLAY_LIMIT

    per_window = max(1, round(spec.replay_window / dt))
    h = dt / spec.replay_substeps
    out = np.empty_like(q_log)
    for start in range(0, len(q_log), per_window):
        stop = min(start + per_window, len(q_log))
        q, v = q_start[start].copy(), qd_start[start].copy()
        for k in range(start, stop):
            error = q - q_log[k]
            diverged = not np.all(np.abs(error) < _REPLAY_LIMIT)
            if diverged:
                error = np.clip(np.nan_to_num(error, nan=np.pi), -_REPLAY_LIMIT, _REPLAY_LIMIT)
            out[k] = error
            if diverged:  # start again from the logged state of the next sample
                if k + 1 < stop:
                    q, v = q_start[k + 1].copy(), qd_start[k + 1].copy()
                continue
            if k + 1 == stop:
                break  # the window's last sample: nothing after it is compared
            acting = tension[k + 1] if period_ending else tension[k]
            for _ in range(spec.replay_substeps):  # the explicit midpoint rule
                with np.errstate(over="ignore", invalid="ignore"):
                    a_start = work.acceleration(q, v, acting, lost[k])
                    q_mid, v_mid = q + 0.5 * h * v, v + 0.5 * h * a_start
                    a_mid = work.acceleration(q_mid, v_mid, acting, lost[k])
                    q, v = q + h * v_mid, v + h * a_mid
    return out


def test_the_windows_replayed_side_by_side_are_each_replayed_alone(arm, logs):
    """The replay integrates its windows together: the bits of one window at a time."""
    from msarm.diagnose.residuals import ResidualSpec, _replay, _Work

    log = read_log(logs["joint_friction"])
    q = log.matrix("q", arm.joint_names)[:230]  # 4 windows of 50 samples and a short one
    tension = log.matrix("tension_motor", arm.cable_names)[: len(q)]
    qd = np.gradient(q, axis=0) * 250.0
    spec = ResidualSpec()
    rng = np.random.default_rng(1)
    lost = rng.normal(0.0, 0.2, size=q.shape)
    lost[60:64] = 1e5  # the second window diverges at its 12th sample and starts again
    work = _Work(arm)
    for instant in (True, False):
        alone = _replay_one_window_at_a_time(work, q, q, qd, tension, 1 / 250, spec, instant, lost)
        np.testing.assert_array_equal(
            _replay(work, q, q, qd, tension, 1 / 250, spec, instant, lost), alone
        )
    got = _replay(work, q, q, qd, tension, 1 / 250, spec, True, lost)
    clipped = np.flatnonzero(np.any(np.abs(got) >= np.pi, axis=1))
    assert clipped.size and clipped.min() > 60 and clipped.max() < 100
    assert np.all(np.abs(got[100:]) < np.pi)  # the windows after it are not touched
    # the path that reorders joints for Pinocchio (here the identity order) gives the same
    work.identity = False
    np.testing.assert_array_equal(_replay(work, q, q, qd, tension, 1 / 250, spec, True, lost), got)


def test_the_replay_converges_at_second_order(arm, logs):
    """Halving the replay's step quarters its error against a fine integration."""
    from msarm.diagnose.residuals import ResidualSpec, _replay, _Work

    log = read_log(logs["joint_friction"])
    middle = len(log.columns[TIME]) // 2
    moving = slice(middle, middle + 100)  # two windows, in motion
    q = log.matrix("q", arm.joint_names)[moving]
    tension = log.matrix("tension_motor", arm.cable_names)[moving]
    qd = np.gradient(q, axis=0) * 250.0
    work = _Work(arm)

    def replay(substeps: int) -> np.ndarray:
        spec = ResidualSpec(replay_substeps=substeps)
        return _replay(work, q, q, qd, tension, 1 / 250, spec, True)

    fine = replay(32)
    errors = [float(np.max(np.abs(replay(s) - fine))) for s in (1, 2, 4)]
    assert errors[0] > 0.0
    for coarse, finer in zip(errors[:-1], errors[1:], strict=True):
        assert 3.0 < coarse / finer < 5.0  # second order: a quarter (first order: a half)
    # one step a sample is already close: well under a percent of the residual it measures
    assert errors[0] < 0.01 * float(np.max(np.abs(fine)))


def test_diagnose_where_checks_its_arguments_before_reading_a_log(arm, tmp_path):
    """A bad kind, bins or posture joints were found only after every log's residuals were
    computed (or hidden behind a missing file's error); two equal joints gave a grid of a
    joint against itself."""
    from msarm.diagnose.where import diagnose_where
    from msarm.errors import InputError

    missing = [tmp_path / "not-there.parquet"]
    for kwargs, match in (
        ({"kind": "torque"}, r"kind: unknown residual kind 'torque'"),
        ({"bins": 0}, r"bins: expected a whole number >= 1"),
        ({"posture_joints": ("elbow", "elbow")}, r"posture_joints: expected two different"),
        ({"posture_joints": ("elbow", "wrist")}, r"posture_joints: expected two different"),
    ):
        with pytest.raises(InputError, match=match):
            diagnose_where(arm, missing, **kwargs)
    with pytest.raises(InputError, match=r"logs: expected a list of one or more log files"):
        diagnose_where(arm, [])


def test_replays_of_one_motion_at_once_are_each_replayed_alone(arm, logs):
    """Several tensions and losses over one motion, replayed together: each one's bits."""
    from msarm.diagnose.residuals import ResidualSpec, replay_runs

    log = read_log(logs["joint_friction"])
    q = log.matrix("q", arm.joint_names)[:330]
    tension = log.matrix("tension_motor", arm.cable_names)[: len(q)]
    qd = np.gradient(q, axis=0) * 250.0
    run = np.repeat([0, 1], [230, 100])  # two stretches: a short last window in each
    lost = np.random.default_rng(1).normal(0.0, 0.2, size=q.shape)
    spec = ResidualSpec()
    alone = [
        replay_runs(arm, q, qd, tension, run, 1 / 250, None, spec),
        replay_runs(arm, q, qd, 1.01 * tension, run, 1 / 250, lost, spec),
    ]
    together = replay_runs(
        arm, q, qd, np.stack([tension, 1.01 * tension]), run, 1 / 250,
        np.stack([np.zeros_like(lost), lost]), spec,
    )  # fmt: skip
    assert together.shape == (2, *q.shape)
    for k in range(2):
        np.testing.assert_array_equal(together[k], alone[k])
