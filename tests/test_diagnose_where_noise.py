"""The noise floor of the "where" breakdown: the sensors' white noise, estimated from a log,
propagated to the joint-torque residual, and taken off before hot spots are named."""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest
from scipy.signal import savgol_coeffs, savgol_filter

import msarm.diagnose.where as where_module
from msarm.compensation.target import TargetSpec, delivered_torque
from msarm.control import ArmControllerConfig
from msarm.diagnose.noise_floor import (
    NoiseFloor,
    SensorNoise,
    filter_noise_gains,
    joint_torque_noise,
    sensor_noise,
    stretches,
    white_noise_std,
)
from msarm.diagnose.residuals import ResidualSpec, residuals_from_log
from msarm.diagnose.scenarios import noisy_base_plant
from msarm.diagnose.where import PhaseSettings, break_down
from msarm.io.logs import RunLog, read_log
from msarm.muscle.batch_kinematics import cable_kinematics_batch
from msarm.plant.config import JointFrictionConfig
from msarm.tasks.track import TrackSettings, track
from msarm.tasks.trajectories import random_reach_task

# The noise-free simulated logs hold a cable at its floor tension over a whole run
# ('tension_motor.teres_minor'): the dead-sensor warning is expected on them.
pytestmark = pytest.mark.filterwarnings(
    "ignore:.*hold one value over the whole log:msarm.diagnose.residuals.DiagnosisWarning"
)

SPEC = ResidualSpec(replay=False)
DT = 1.0 / 250.0


def test_the_white_noise_level_is_found_under_a_smooth_signal_within_a_few_percent():
    """Known white noise on a moving signal (1 rad swings, 2 rad/s): the third differences
    leave the motion out, a few spikes do not move the median, and a step across a time gap
    (between two parts) is not differenced."""
    rng = np.random.default_rng(0)
    t = np.arange(6000) * DT
    smooth = np.column_stack([np.sin(2.0 * t), 0.5 * np.cos(3.0 * t), t, np.zeros_like(t)])
    sigma = np.array([1e-4, 3e-4, 2e-5, 0.3])
    x = smooth + sigma * rng.standard_normal(smooth.shape)
    x[::500] += 50 * sigma  # a spike every 2 s
    x[3000:] += 10.0  # a jump at a time gap
    got = white_noise_std(x, [(0, 3000), (3000, 6000)])
    np.testing.assert_allclose(got, sigma, rtol=0.04)
    # over the jump the differences would see it (the median barely: a handful of samples)
    assert white_noise_std(x)[3] == pytest.approx(0.3, rel=0.04)
    assert np.isnan(white_noise_std(x[:3])).all()  # no third difference


def test_the_filter_gains_are_the_filters_own_on_white_noise():
    """The interior gain of the acceleration filter is ``sum d^2 / dt^4`` (the Savitzky-Golay
    coefficients); every gain, edges included, is the variance of the filters' output on
    white noise of unit variance (20,000 draws of 130 samples)."""
    target = TargetSpec()
    length = 130  # longer than four windows: the interior is filled in
    gains = filter_noise_gains(length, target, DT)
    d = savgol_coeffs(25, 3, deriv=2, delta=DT)
    assert gains.acceleration[60] == pytest.approx(np.sum(d**2), rel=1e-9)
    rng = np.random.default_rng(1)
    draws = rng.standard_normal((length, 20_000))
    second = savgol_filter(draws, 25, 3, deriv=2, delta=DT, axis=0)
    smoothed = delivered_torque(-draws[:, None, :], np.ones((length, 1)), target, DT)
    np.testing.assert_allclose(second.var(axis=1), gains.acceleration, rtol=0.05)
    np.testing.assert_allclose(smoothed.var(axis=1), gains.tension, rtol=0.05)
    # the edges pass far more noise than the interior (the cubic fit at the window's end)
    assert gains.acceleration[0] > 30 * gains.acceleration[60]
    # a stretch just one window long is taken whole
    short = filter_noise_gains(25, target, DT)
    assert short.acceleration.shape == (25,)


@pytest.fixture(scope="module")
def logs(arm, tmp_path_factory):
    """Two 13 s random reaches from the home posture (a hold there first) on a plant with
    sensor noise alone, and the first on a plant with joint friction too."""
    root = tmp_path_factory.mktemp("where_noise")
    noisy = noisy_base_plant("noisy")
    friction = replace(
        noisy,
        name="friction",
        effects=replace(noisy.effects, joint_friction=JointFrictionConfig(enabled=True)),
    )
    out = {}
    for name, plant, seed in (
        ("noise0", noisy, 0),
        ("noise1", noisy, 1),
        ("friction", friction, 0),
    ):
        task = random_reach_task(seed, arm.joint_lower, arm.joint_upper, duration=13.0, n_moves=2)
        settings = TrackSettings(name, 10 + seed, plant, ArmControllerConfig())
        out[name] = track(arm, task, settings, root / name, plots_too=False).files["log"]
    return out


@pytest.fixture(scope="module")
def residuals(arm, logs):
    return {name: residuals_from_log(arm, path, spec=SPEC) for name, path in logs.items()}


def test_the_noise_levels_of_a_log_are_the_plants(residuals):
    """The plant's encoders have 1e-4 rad and its load cells 0.3 N of white noise."""
    for run in residuals.values():
        levels = sensor_noise(run)
        np.testing.assert_allclose(levels.joint, 1e-4, rtol=0.1)
        np.testing.assert_allclose(levels.tension, 0.3, rtol=0.1)
        assert levels.samples == int(run.valid.sum())


def _mass_matrices(model, q: np.ndarray) -> np.ndarray:
    """MuJoCo's mass matrix at each posture (the plant's engine, not Pinocchio's)."""
    data = mujoco.MjData(model.mj_model)
    out = np.empty((len(q), q.shape[1], q.shape[1]))
    for k, posture in enumerate(q):
        data.qpos[:] = posture
        mujoco.mj_forward(model.mj_model, data)
        mujoco.mj_fullM(model.mj_model, data, out[k])
    return out


def test_the_propagation_agrees_with_the_full_covariance_of_a_stretch(arm, residuals):
    """The floor against brute force: on 130 samples in motion, the covariance of every
    residual sample with every other, built from the whole filters' matrices, MuJoCo's mass
    matrix at the output's posture and the cable Jacobian at the input's (as the residual
    has them). Its diagonal is the expected energy of each sample; twice its squared norm the
    variance of the stretch's energy."""
    run = residuals["noise0"]
    moving = np.flatnonzero(np.abs(run.qd).max(axis=1) > 0.5)
    start = int(moving[0])
    part = slice(start, start + 130)
    cut = replace(
        run,
        t=run.t[part],
        valid=run.valid[part],
        joint_torque=run.joint_torque[part],
        q=run.q[part],
        tension=run.tension[part],
        drive=None,
    )
    levels = SensorNoise(
        joint=np.array([1e-4, 2e-4, 1.5e-4, 1e-4]), tension=np.linspace(0.2, 0.4, 9), samples=130
    )
    floor = joint_torque_noise(arm, cut, levels)
    assert isinstance(floor, NoiseFloor) and not floor.edge[12:-12].any() and floor.edge[:12].all()

    length, n = cut.q.shape
    eye = np.eye(length)
    second = savgol_filter(eye, 25, 3, deriv=2, delta=DT, axis=0)  # (out, in)
    smoothed = delivered_torque(-eye[:, None, :], np.ones((length, 1)), TargetSpec(), DT)
    jacobian = cable_kinematics_batch(arm, cut.q, with_wrap_angles=False).jacobian  # (T, m, n)
    mass = _mass_matrices(arm, cut.q)
    # the residual's response to unit noise on joint k at t: -M(q_i)[:, k] S2[i, t]; on
    # cable c at t: -SF[i, t] J_c(q_t)[c, :] (the delivered torque, then the filter)
    encoder = -np.einsum("ijk,it->ijtk", mass, second) * levels.joint
    cable = -np.einsum("it,tcj->ijtc", smoothed, jacobian) * levels.tension
    maps = np.concatenate([encoder.reshape(length * n, -1), cable.reshape(length * n, -1)], axis=1)
    covariance = maps @ maps.T
    expected = np.diag(covariance).reshape(length, n)
    np.testing.assert_allclose(floor.energy, expected, rtol=0.01)
    assert floor.variance.sum() == pytest.approx(2.0 * np.sum(covariance**2), rel=0.01)


def test_the_floor_matches_the_residual_energy_of_added_noise(arm, logs):
    """End to end: white noise of known levels added to a log's joint angles and tensions
    makes as much residual energy as the floor expects, over the whole log and in its
    phases (within 20 %), and the noise levels are found again from the log."""
    log = read_log(logs["noise0"])
    rng = np.random.default_rng(2)
    columns = dict(log.columns)
    for name in arm.joint_names:
        columns[f"q.{name}"] = columns[f"q.{name}"] + 4e-4 * rng.standard_normal(len(log))
    for name in arm.cable_names:
        columns[f"tension_motor.{name}"] = columns[
            f"tension_motor.{name}"
        ] + 1.2 * rng.standard_normal(len(log))
    run = residuals_from_log(arm, RunLog(columns, log.metadata), spec=SPEC)
    levels = sensor_noise(run)
    # the plant's own noise is there too: sqrt(1 + 16) and sqrt(0.09 + 1.44)
    np.testing.assert_allclose(levels.joint, np.hypot(1e-4, 4e-4), rtol=0.1)
    np.testing.assert_allclose(levels.tension, np.hypot(0.3, 1.2), rtol=0.1)
    breakdown = break_down(run, model=arm)
    assert breakdown.total_energy == pytest.approx(breakdown.noise_energy, rel=0.2)
    for row in breakdown.group("motion"):
        if row.samples >= 500:
            assert row.energy == pytest.approx(row.noise_energy, rel=0.2), row.where


def test_a_plant_with_sensor_noise_alone_has_no_hot_spot(arm, residuals):
    """The home posture's cell was a hot spot on noise alone; beyond the noise it is not."""
    runs = [residuals["noise0"], residuals["noise1"]]
    for logs in ([runs[0]], [runs[1]], runs):
        before = break_down(logs, model=arm, noise_floor=False)
        assert before.noise_energy == 0 and before.sensor_noise == {}
        after = break_down(logs, model=arm)
        assert after.hot_spots() == []
        assert 0.7 < after.total_energy / after.noise_energy < 1.3
        # the breakdown's own numbers do not change
        assert [(r.where, r.energy, r.share, r.density) for r in after.rows] == [
            (r.where, r.energy, r.share, r.density) for r in before.rows
        ]
        assert "Hot spots: none" in after.to_markdown()
    # without the floor, the cell of the first posture (the home posture, held first) is a hot
    # spot: densest of the cells with enough samples
    home = break_down(runs[0], model=arm, noise_floor=False)
    assert home.hot_spots() and home.hot_spots()[0].group == "posture"
    counts = home.posture_samples
    density = np.asarray(home.posture_rms) ** 2 / home.rms**2  # share of energy / of time
    density[counts < home.settings.hot_spot_samples] = 0.0
    a, b = (arm.joint_names.index(j) for j in home.posture_joints)
    first = [
        int(np.clip(np.searchsorted(e, runs[0].q[0, j], side="right") - 1, 0, len(e) - 2))
        for e, j in zip(home.posture_edges, (a, b), strict=True)
    ]
    assert np.unravel_index(np.nanargmax(density), density.shape) == tuple(first)
    assert home.hot_spots()[0].density == pytest.approx(density[tuple(first)])


def test_joint_friction_keeps_its_hot_spots_in_motion(arm, residuals):
    breakdown = break_down(residuals["friction"], model=arm)
    assert breakdown.total_energy > 20 * breakdown.noise_energy
    hot = {(r.group, r.where) for r in breakdown.hot_spots()}
    assert ("motion", "acceleration") in hot or ("motion", "constant_velocity") in hot
    without = break_down(residuals["friction"], model=arm, noise_floor=False)
    for row, old in zip(breakdown.rows, without.rows, strict=True):
        assert row.excess_density == pytest.approx(old.density, abs=0.1)


def test_only_the_joint_torque_has_a_floor_and_the_json_says_so(arm, residuals):
    run = residuals["noise0"]
    torque = break_down(run, model=arm).as_dict()
    assert torque["noise_energy"] > 0
    assert set(torque["sensor_noise"]) == {f"q.{j}" for j in arm.joint_names} | {
        f"tension_motor.{c}" for c in arm.cable_names
    }
    for row in torque["rows"]:
        assert {"noise_energy", "excess_energy", "noise_std", "excess_density"} <= set(row)
    assert torque["settings"]["hot_spot_noise_ratio"] == 1.5
    for kind in ("drive", "cable_length"):
        other = break_down(run, kind, model=arm)
        assert other.noise_energy == 0 and other.sensor_noise == {}
        for row in other.rows:
            assert row.excess_density == row.density and row.excess_energy == row.energy
            assert row.noise_std == 0
    text = break_down(run, model=arm).to_markdown()
    assert "Noise floor:" in text and "| excess density |" in text


def _hand_floor(run, noise, variance, edge):
    """A floor laid out by hand, in place of the one estimated from the log."""

    def floor(model, residuals, levels=None):
        n = residuals.joint_torque.shape[1]
        return NoiseFloor(
            energy=np.tile(noise[:, None] / n, (1, n)),
            variance=variance,
            channel_variance=np.tile(variance[:, None] / n, (1, n)),
            edge=edge,
        )

    return floor


def test_the_excess_and_the_hot_spot_margins_by_hand(arm, monkeypatch):
    """200 samples of 1 (N m)^2 each, noise 0.5 each: an excess of 0.5 a sample, except in
    samples 100-149 (motion: constant velocity), whose energy is 3; the first 10 samples are
    filter edges, their energy 40 (noise alone, a wild draw), counted at their noise."""
    n_samples, n = 200, arm.n_joints
    per_sample = np.ones(n_samples)
    per_sample[100:150] = 3.0
    per_sample[:10] = 40.0
    torque = np.sqrt(np.tile(per_sample[:, None] / n, (1, n)))
    qd = np.zeros((n_samples, n))
    qd[100:150, 0] = 1.0
    from msarm.diagnose.residuals import Residuals

    run = Residuals(
        source="hand",
        joint_names=tuple(arm.joint_names),
        cable_names=tuple(arm.cable_names),
        sample_rate_hz=250.0,
        t=np.arange(n_samples) * DT,
        valid=np.ones(n_samples, dtype=bool),
        joint_torque=torque,
        cable_length=None,
        drive=None,
        replay=None,
        q=np.zeros((n_samples, n)),
        qd=qd,
        qdd=np.zeros((n_samples, n)),
        cable_velocity=np.zeros((n_samples, arm.n_cables)),
        tension=np.full((n_samples, arm.n_cables), 10.0),
    )
    noise = np.full(n_samples, 0.5)
    variance = np.full(n_samples, 0.01)
    edge = np.zeros(n_samples, dtype=bool)
    edge[:10] = True
    monkeypatch.setattr(where_module, "joint_torque_noise", _hand_floor(run, noise, variance, edge))
    monkeypatch.setattr(
        where_module, "sensor_noise", lambda r: SensorNoise(np.full(n, 1e-4), np.full(9, 0.3), 200)
    )
    settings = PhaseSettings(hot_spot_samples=10)
    breakdown = break_down(run, model=arm, settings=settings)
    motion = {r.where: r for r in breakdown.group("motion")}
    moving, hold = motion["constant_velocity"], motion["hold"]
    assert breakdown.noise_energy == pytest.approx(100.0)
    assert moving.noise_energy == pytest.approx(25.0) and hold.noise_energy == pytest.approx(75.0)
    # excess away from the edges: moving 50 * 2.5 = 125, hold 140 * 0.5 = 70 (of 195)
    assert moving.excess_energy == pytest.approx(125.0) and hold.excess_energy == pytest.approx(
        70.0
    )
    assert moving.excess_density == pytest.approx((125 / 195) / (50 / 190))
    assert hold.excess_density == pytest.approx((70 / 195) / (140 / 190))
    assert moving.noise_std == pytest.approx(np.sqrt(50 * 0.01))
    # the edges' 400 make hold the densest by energy, not beyond the noise
    assert hold.density > moving.density
    assert [r.where for r in breakdown.hot_spots()] == ["constant_velocity"]
    # the margins: an excess of 5 times the noise is enough for a ratio of 5.9, not of 6.1 ...
    loose = break_down(run, model=arm, settings=replace(settings, hot_spot_noise_ratio=5.9))
    assert [r.where for r in loose.hot_spots()] == ["constant_velocity"]
    strict = break_down(run, model=arm, settings=replace(settings, hot_spot_noise_ratio=6.1))
    assert strict.hot_spots() == []
    # ... and 125 / sqrt(0.5) = 177 standard deviations for sigmas up to that
    assert break_down(
        run, model=arm, settings=replace(settings, hot_spot_noise_sigmas=170.0)
    ).hot_spots()
    assert not break_down(
        run, model=arm, settings=replace(settings, hot_spot_noise_sigmas=180.0)
    ).hot_spots()
    with pytest.raises(ValueError, match="hot_spot_noise_sigmas"):
        PhaseSettings(hot_spot_noise_sigmas=-1.0)
    with pytest.raises(ValueError, match="hot_spot_noise_ratio"):
        PhaseSettings(hot_spot_noise_ratio=0.9)


def test_stretches_split_at_gaps_and_skip_invalid_samples(residuals):
    run = residuals["noise0"]
    assert stretches(run) == [(0, len(run))]
    valid = run.valid.copy()
    valid[:30] = False
    t = run.t.copy()
    t[500:] += 1.0  # a gap before sample 500
    assert stretches(replace(run, valid=valid, t=t)) == [(30, 500), (500, len(run))]
