"""Features, target and data of the compensator."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from conftest import ideal_plant_with

from msarm.compensation.dataset import DataConfig, build_arrays, split_runs
from msarm.compensation.features import FeatureExtractor, FeatureSpec
from msarm.compensation.target import (
    TENSION_TIMINGS,
    TargetSpec,
    delivered_torque,
    filtered_motion,
    torque_error,
)
from msarm.control import ArmControllerConfig
from msarm.errors import InputError, LogError
from msarm.io.logs import LogMetadata, RunLog, read_log, write_log
from msarm.muscle.batch_kinematics import cable_kinematics_batch
from msarm.plant import DEFAULT_PLANT, IDEAL_PLANT
from msarm.plant.effects import SensorReadings
from msarm.tasks.track import TrackSettings, track
from msarm.tasks.trajectories import hold_then_move

HOME = np.array([0.0, 0.0, 0.0, -0.2])
SHORT = hold_then_move(
    "short", HOME, [0.1, 0.35, -0.3, -0.9], wait=0.3, move_time=1.2, duration=2.5
)


def hand_log(arm) -> RunLog:
    """Three samples with simple, known values."""
    t = np.array([0.0, 0.004, 0.008])
    q = np.array([[0.1, 0.2, -0.1, -0.5], [0.1, 0.21, -0.1, -0.5], [0.1, 0.22, -0.1, -0.49]])
    q_ref = q + 0.01
    qd_ref = np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 2.5, 0.0, 0.0], [0.0, 2.5, 0.0, 2.5]])
    qdot = qd_ref * 0.9
    motor = np.array([np.zeros(9), np.full(9, 0.1), np.full(9, 0.3)])
    tension = np.array([np.full(9, 10.0), np.full(9, 11.0), np.full(9, 12.0)])
    channels = {
        "q": (arm.joint_names, q),
        "q_ref": (arm.joint_names, q_ref),
        "qd_ref": (arm.joint_names, qd_ref),
        "qdot_est": (arm.joint_names, qdot),
        "motor_angle": (arm.cable_names, motor),
        "tension_motor": (arm.cable_names, tension),
    }
    units = {
        "q": "rad",
        "q_ref": "rad",
        "qd_ref": "rad/s",
        "qdot_est": "rad/s",
        "motor_angle": "rad",
        "tension_motor": "N",
    }
    return RunLog.from_quantities(t, channels, LogMetadata.for_model(arm, 250.0, units=units))


def test_features_from_a_hand_made_log_are_the_hand_computed_values(arm):
    spec = FeatureSpec(
        groups=(
            "q",
            "qdot",
            "sign_qdot",
            "exp_sign_qdot",
            "joint_memory",
            "cable_length_error",
            "tension",
            "sign_error",
        ),
        sign_error_angle=0.02,
    )
    x = FeatureExtractor(arm, spec).from_log(hand_log(arm))
    q_ref = hand_log(arm).matrix("q_ref")
    qd_ref = hand_log(arm).matrix("qd_ref")
    np.testing.assert_array_equal(x[:, 0:4], q_ref)  # source = reference
    np.testing.assert_array_equal(x[:, 4:8], qd_ref)
    sign = np.tanh(qd_ref / 0.05)
    np.testing.assert_allclose(x[:, 8:12], sign, rtol=1e-15)
    np.testing.assert_allclose(x[:, 12:16], np.exp(-sign) * sign, rtol=1e-15)
    # joint memory: m_k = m_{k-1} + (s_k - m_{k-1}) min(1, |v_k| dt / 0.05); dt = 0.004
    rate = np.minimum(1.0, np.abs(qd_ref) * 0.004 / 0.05)  # 0.2 where moving at 2.5 rad/s
    memory = np.zeros(4)
    for k in range(3):
        memory = memory + (sign[k] - memory) * (rate[k] if k else 0.0)
        np.testing.assert_allclose(x[k, 16:20], memory, rtol=1e-12)
    assert x[2, 17] == pytest.approx(0.2 * 1.0 + 0.8 * 0.2 * 1.0, rel=1e-6)  # 0.36
    # cable length error: l(q0) - r (theta - theta0) - l(q) from the measured posture
    q = hand_log(arm).matrix("q")
    l0 = arm.geometry(q[0]).lengths
    for k, theta in enumerate((0.0, 0.1, 0.3)):
        expected = l0 - 0.003 * theta - arm.geometry(q[k]).lengths
        np.testing.assert_allclose(x[k, 20:29], expected, atol=1e-15)
    np.testing.assert_array_equal(x[:, 29:38], hand_log(arm).matrix("tension_motor"))
    # sign of the tracking error, from the measured q: q_ref - q = 0.01 rad everywhere
    np.testing.assert_allclose(x[:, 38:42], np.tanh(0.01 / 0.02), rtol=1e-12)
    assert x.shape == (3, 42)


def test_the_joint_memory_rate_is_capped_at_one(arm):
    """Travel beyond ``memory_angle`` in one tick sets the memory to the sign, no overshoot."""
    spec = FeatureSpec(groups=("joint_memory",), memory_angle=0.002)
    x = FeatureExtractor(arm, spec).from_log(hand_log(arm))
    qd_ref = hand_log(arm).matrix("qd_ref")
    sign = np.tanh(qd_ref / 0.05)
    rate = np.abs(qd_ref) * 0.004 / 0.002  # 5 at 2.5 rad/s: capped at 1
    assert rate.max() > 1.0
    memory = np.zeros(4)
    for k in range(3):
        step = np.minimum(1.0, rate[k]) if k else np.zeros(4)
        memory = memory + (sign[k] - memory) * step
        np.testing.assert_allclose(x[k], memory, rtol=1e-12)
    assert np.abs(x).max() <= 1.0


def _online(extractor, log, commands=None):
    """The features of every tick of ``log`` computed online (told the commands if given)."""
    extractor.reset()
    rows = []
    for k in range(len(log)):
        readings = SensorReadings(
            t=float(log.t[k]),
            q=log.matrix("q")[k],
            motor_angle=log.matrix("motor_angle")[k],
            motor_torque=np.zeros(9),
            tension_motor=log.matrix("tension_motor")[k],
        )
        rows.append(
            extractor(
                readings, log.matrix("qdot_est")[k], log.matrix("q_ref")[k], log.matrix("qd_ref")[k]
            )
        )
        if commands is not None:
            extractor.observe_command(commands[k])
    return np.array(rows)


def test_online_features_equal_offline_features(arm):
    log = hand_log(arm)
    extractor = FeatureExtractor(
        arm, FeatureSpec(groups=tuple(FeatureSpec().groups) + ("tension",))
    )
    offline = extractor.from_log(log)
    np.testing.assert_array_equal(_online(extractor, log), offline)


def test_target_is_zero_on_the_ideal_plant_and_not_on_the_default_plant(arm, tmp_path):
    gains = ArmControllerConfig()
    values = {}
    for plant in (IDEAL_PLANT, DEFAULT_PLANT):
        result = track(
            arm,
            SHORT,
            TrackSettings("short", 0, plant, gains),
            tmp_path / plant.name,
            plots_too=False,
        )
        log = read_log(result.files["log"])
        tf = torque_error(arm, log, TargetSpec())
        values[plant.name] = np.sqrt(np.mean(tf[15:-15] ** 2, axis=0))  # filter edges left out
    assert values["ideal"].max() < 0.02  # N m: filtering error only
    assert values["default"].min() > 0.2
    # the caller's Jacobians of the logged postures give the same target; wrong ones: refused
    jacobians = cable_kinematics_batch(arm, log.matrix("q")).jacobian
    np.testing.assert_array_equal(torque_error(arm, log, TargetSpec(), jacobians=jacobians), tf)
    # and so does the caller's filtered motion (the diagnosis computes it once for both)
    q_raw = log.matrix("q", list(arm.joint_names))
    motion = filtered_motion(q_raw, TargetSpec(), 1.0 / log.metadata.sample_rate_hz)
    np.testing.assert_array_equal(torque_error(arm, log, TargetSpec(), motion=motion), tf)
    with pytest.raises(InputError, match="motion"):
        torque_error(arm, log, TargetSpec(), motion=tuple(m[1:] for m in motion))
    with pytest.raises(InputError, match="jacobians must have shape"):
        torque_error(arm, log, TargetSpec(), jacobians=jacobians[1:])


def test_parallel_filtering_takes_the_noise_out_of_the_target(arm, tmp_path):
    # a plant whose only effect is sensor noise: the target should be near zero, and the
    # load cells' noise (and the controller's fast answer to the encoders' noise) in the
    # unfiltered delivered torque is most of what it has
    noisy = ideal_plant_with("noise_only", "sensor_noise")
    settings = TrackSettings("short", 0, noisy, ArmControllerConfig())
    result = track(arm, SHORT, settings, tmp_path, plots_too=False)
    log = read_log(result.files["log"])
    rms = {}
    for name, spec in (
        ("filtered", TargetSpec()),
        ("unfiltered", TargetSpec(smooth_tension=False)),
    ):
        tf = torque_error(arm, log, spec)[15:-15]
        rms[name] = float(np.sqrt(np.mean(tf**2)))
    assert rms["filtered"] < 0.4 * rms["unfiltered"], rms
    # from the noise-free signals (the sidecar's): the rigid cables' tension follows each
    # command, held over a period, so that timing leaves half the residual of the other
    truth = dict(log.columns)
    for quantity, names in (("q", arm.joint_names), ("tension_motor", arm.cable_names)):
        for name in names:
            truth[f"{quantity}.{name}"] = np.asarray(result.run.truth[f"{quantity}.{name}"])
    noise_free = RunLog(truth, log.metadata)
    for timing in TENSION_TIMINGS:
        tf = torque_error(arm, noise_free, TargetSpec(tension_timing=timing))[15:-15]
        rms[timing] = float(np.sqrt(np.mean(tf**2)))
    assert rms["period"] < 0.7 * rms["instant"], rms
    assert rms["period"] < 0.2 * rms["filtered"], rms


def test_the_delivered_torque_is_the_motions_filter_of_the_torque():
    dt = 0.004
    t = np.arange(80) * dt
    rng = np.random.default_rng(3)
    jacobians = rng.normal(size=(80, 9, 4))
    tension = rng.uniform(5.0, 50.0, size=(80, 9))
    per_sample = -np.einsum("tmn,tm->tn", jacobians, tension)
    unfiltered = TargetSpec(smooth_tension=False)
    np.testing.assert_allclose(delivered_torque(jacobians, tension, unfiltered, dt), per_sample)
    # a torque that is a quadratic in time, read at its instants: integrated twice it is a
    # quartic, whose second derivative the cubic Savitzky-Golay filter gets exactly only in
    # its cubic part; a linear torque comes back exactly
    flat = np.zeros((80, 1, 1))
    flat[:, 0, 0] = -1.0
    linear = (2.0 + 30.0 * t)[:, None]
    spec = TargetSpec(window=11, polyorder=3, tension_timing="instant")
    np.testing.assert_allclose(delivered_torque(flat, linear, spec, dt), linear, atol=1e-9)
    # each sample held over the period that ends at it: the torque around a sample's instant
    # is the mean of it and the next one, half a period's rise above the sample
    held = delivered_torque(flat, linear, replace(spec, tension_timing="period"), dt)
    np.testing.assert_allclose(held[10:-10], linear[10:-10] + 30.0 * dt / 2, atol=1e-9)
    # noise is damped
    noise = rng.normal(size=(80, 1))
    assert np.std(delivered_torque(flat, noise, spec, dt)) < 0.6 * np.std(noise)
    with pytest.raises(ValueError, match="tension_timing"):
        TargetSpec(tension_timing="late")


def test_nan_in_training_data_names_the_file_and_column(arm, tmp_path):
    log = hand_log(arm)
    path = write_log(tmp_path / "good.parquet", log)
    table = pq.read_table(path)
    column = table.column("tension_motor.biceps").to_numpy().copy()
    column[1] = np.nan
    bad = table.set_column(
        table.schema.get_field_index("tension_motor.biceps"),
        "tension_motor.biceps",
        pa.array(column),
    )
    bad_path = tmp_path / "bad.parquet"
    pq.write_table(bad.replace_schema_metadata(table.schema.metadata), bad_path)
    with pytest.raises(LogError, match=r"bad\.parquet.*tension_motor\.biceps"):
        build_arrays(arm, [bad_path], FeatureSpec(), TargetSpec(window=3, polyorder=1))


def test_missing_channel_is_named(arm, tmp_path):
    log = hand_log(arm)
    columns = {k: v for k, v in log.columns.items() if k != "q_ref.elbow"}
    slim = RunLog(columns, log.metadata)
    with pytest.raises(InputError, match=r"q_ref.elbow"):
        FeatureExtractor(arm).from_log(slim, source="slim.parquet")


def test_runs_not_samples_are_split():
    split = split_runs(list(range(1000, 1014)), (0.7, 0.15, 0.15))
    assert split.train == tuple(range(1000, 1010))
    assert split.validation == (1010, 1011) and split.test == (1012, 1013)
    with pytest.raises(InputError, match="at least 3 runs"):
        split_runs([1, 2], (0.7, 0.15, 0.15))


def test_feature_spec_refuses_unknown_groups():
    with pytest.raises(ValueError, match="unknown feature groups"):
        FeatureSpec(groups=("q", "torque"))
    assert replace(FeatureSpec(), source="measured").source == "measured"


def _log_with_commands(arm) -> tuple[RunLog, np.ndarray]:
    log = hand_log(arm)
    commands = np.array([np.full(9, 20.0), np.linspace(15.0, 40.0, 9), np.linspace(30.0, 5.0, 9)])
    columns = dict(log.columns)
    for i, name in enumerate(arm.cable_names):
        columns[f"tension_cmd.{name}"] = commands[:, i]
    metadata = replace(log.metadata, units={**log.metadata.units, "tension_cmd": "N"})
    return RunLog(columns, metadata), commands


def test_sheath_stiction_from_the_previous_commands_is_the_hand_computed_value(arm):
    log, commands = _log_with_commands(arm)
    spec = FeatureSpec(groups=("sheath_stiction",), stiction_mus=(0.05, 0.5))
    extractor = FeatureExtractor(arm, spec)
    assert extractor.size == 8
    assert extractor.names[0] == "sheath_stiction[mu=0.05].shoulder_abduction"
    x = extractor.from_log(log)
    # tick 0: no command sent yet; tick 1: the element starts balanced at the command of tick 0
    np.testing.assert_array_equal(x[0], 0.0)
    np.testing.assert_allclose(x[1], 0.0, atol=1e-12)  # exp(log F) - F: round-off
    # tick 2: the command of tick 1 moved within the band or beyond it, cable by cable
    geometry = arm.geometry(log.matrix("q")[2])
    for j, mu in enumerate((0.05, 0.5)):
        band = mu * geometry.wrap_angles
        kept = np.clip(commands[0], commands[1] * np.exp(-band), commands[1] * np.exp(band))
        expected = geometry.jacobian.T @ (kept - commands[1])
        np.testing.assert_allclose(x[2, 4 * j : 4 * j + 4], expected, rtol=1e-9, atol=1e-12)
    # both cases are exercised: cables that slipped to the band's edge and cables that stuck
    step = np.abs(np.log(commands[0] / commands[1]))
    assert np.any(step > 0.05 * geometry.wrap_angles) and np.any(step < 0.05 * geometry.wrap_angles)
    assert np.all(step < 0.5 * geometry.wrap_angles)  # mu = 0.5: every cable stuck


def test_sheath_stiction_online_equals_offline_and_needs_the_commands(arm):
    log, commands = _log_with_commands(arm)
    spec = FeatureSpec(groups=(*FeatureSpec().groups, "sheath_stiction"))
    extractor = FeatureExtractor(arm, spec)
    offline = extractor.from_log(log)
    online = _online(extractor, log, commands)
    np.testing.assert_allclose(online, offline, rtol=1e-12, atol=1e-12)
    assert np.any(online[2, -16:] != 0)  # the stick-slip inputs are exercised
    with pytest.raises(InputError, match="tension_cmd"):
        extractor.from_log(hand_log(arm))


def test_the_controller_tells_a_feedforward_its_commands(arm):
    from msarm.control import MuscleSpaceController

    class Recorder:
        def __init__(self) -> None:
            self.seen: list[np.ndarray] = []

        def __call__(self, readings, qdot, q_ref, qd_ref):
            return np.zeros(4)

        def observe_command(self, tension_command):
            self.seen.append(np.array(tension_command))

    controller = MuscleSpaceController(arm)
    controller.reset(HOME)
    recorder = Recorder()
    readings = SensorReadings(
        t=0.0, q=HOME, motor_angle=np.zeros(9), motor_torque=np.zeros(9), tension_motor=np.ones(9)
    )
    outputs = [controller.update(readings, HOME, np.zeros(4), np.zeros(4), recorder) for _ in "ab"]
    assert len(recorder.seen) == 2
    for seen, out in zip(recorder.seen, outputs, strict=True):
        np.testing.assert_array_equal(seen, out.tension_command)


def _with_a_rest_sample(log: RunLog) -> RunLog:
    """``log`` with one more sample 4 ms later: the reference at rest where it ended."""
    columns = {}
    for name, values in log.columns.items():
        if name == "t":
            extra = values[-1] + 0.004
        elif name.startswith("qd_ref."):
            extra = 0.0
        else:
            extra = values[-1]
        columns[name] = np.append(values, extra)
    return RunLog(columns, log.metadata)


def test_cable_velocity_features_from_a_hand_made_log_are_the_hand_computed_values(arm):
    """``exp_sign_ldot`` (U_E = exp(-tanh(ldot / eps_l))) and the cable direction memory.

    ``ldot`` is taken here by central differences of the cable lengths along the reference
    velocity (not from the Jacobian the extractor uses); the memory follows
    ``m_k = m_{k-1} + (tanh(ldot / eps_l) - m_{k-1}) min(1, |ldot| dt / memory_length)``
    from 0 at the first sample and keeps its value while the reference rests.
    """
    eps_l, travel = 0.2, 0.002  # m/s, m: tanh and the memory's rate away from saturation
    spec = FeatureSpec(
        groups=("exp_sign_ldot", "cable_memory"),
        sign_cable_speed=eps_l,
        memory_length=travel,
        memory_angle=0.05,
    )
    log = _with_a_rest_sample(hand_log(arm))
    x = FeatureExtractor(arm, spec).from_log(log)
    assert x.shape == (4, 18)
    q_ref, qd_ref, t = log.matrix("q_ref"), log.matrix("qd_ref"), log.t
    h = 1e-6
    ldot = []
    for k in range(4):
        plus = arm.geometry(q_ref[k] + h * qd_ref[k], with_wrap_angles=False).lengths
        minus = arm.geometry(q_ref[k] - h * qd_ref[k], with_wrap_angles=False).lengths
        ldot.append((plus - minus) / (2 * h))
    sign = np.array([[math.tanh(v / eps_l) for v in row] for row in ldot])
    expected = np.array([[math.exp(-s) for s in row] for row in sign])
    np.testing.assert_allclose(x[:, 0:9], expected, rtol=0, atol=1e-8)
    # a memory that forgets over 0.1 mm: most cables reach their sign in one tick (rate 1)
    short = FeatureExtractor(arm, replace(spec, memory_length=1e-4)).from_log(log)
    for features, length in ((x, travel), (short, 1e-4)):
        memory = np.zeros(9)
        for k in range(4):
            dt = t[k] - t[k - 1] if k else 0.0
            rate = np.minimum(1.0, np.abs(ldot[k]) * dt / length)
            memory = memory + (sign[k] - memory) * rate
            np.testing.assert_allclose(features[k, 9:18], memory, rtol=0, atol=1e-8)
    assert abs(ldot[2][0]) * 0.004 / 1e-4 > 1.0  # cable 0 saturated: its memory is its sign
    assert short[2, 9] == pytest.approx(sign[2, 0], abs=1e-8)
    # the hand-made log exercises what it should: cables paid out and reeled in, a memory
    # that moved part of the way (no rate saturated at 1), and one that rests
    assert np.all(x[0] == [1.0] * 9 + [0.0] * 9)  # the reference at rest at the start
    assert np.any(x[2, 0:9] > 1.05) and np.any(x[2, 0:9] < 0.95)
    assert 0.05 < np.max(np.abs(x[2, 9:18])) < 0.95
    np.testing.assert_array_equal(x[3, 9:18], x[2, 9:18])  # at rest the memory keeps its value
    np.testing.assert_array_equal(x[3, 0:9], 1.0)
    # biceps (cable 7): ldot = 0.1103 m/s at sample 2, hand-worked from its central difference
    s = math.tanh(0.1103 / eps_l)
    assert x[2, 7] == pytest.approx(math.exp(-s), rel=1e-3)  # ~0.60, exp(+s) ~1.65


def test_arrays_built_once_per_log_with_a_cache(arm, tmp_path):
    """A training's rounds stack the same runs again: a cache gives the same arrays."""
    first = write_log(tmp_path / "first.parquet", hand_log(arm))
    log = hand_log(arm)
    shifted = {k: v + 0.01 if k.startswith("q.") else v for k, v in log.columns.items()}
    second = write_log(tmp_path / "second.parquet", RunLog(shifted, log.metadata))
    spec, target = FeatureSpec(), TargetSpec(window=3, polyorder=1)
    paths = [first, second, first]
    expected = build_arrays(arm, paths, spec, target)
    cache = {}
    for _ in range(2):  # filled by the first call, read by the second
        got = build_arrays(arm, paths, spec, target, cache)
        for a, b in zip(got, expected, strict=True):
            np.testing.assert_array_equal(a, b)
    assert set(cache) == {first, second}
    # what the cache holds is what a cached log contributes (the file is not read again)
    x, y = cache[first]
    cache[first] = (x + 1.0, y)
    assert np.array_equal(build_arrays(arm, [first], spec, target, cache)[0], x + 1.0)


def test_data_config_refuses_mistyped_counts_and_shares_that_are_not_finite():
    """``rounds=1.5`` was accepted and failed after the runs were collected, ``n_runs='14'``
    with a TypeError about ``<``, and a NaN share passed the share check to be reported as
    "14 runs leave none for training"."""
    for name, value in (
        ("rounds", 1.5),
        ("rounds", True),
        ("n_runs", "14"),
        ("n_runs", 14.0),
        ("first_seed", 1000.5),
    ):
        with pytest.raises(InputError, match=rf"{name} must be an integer .*got \w+ {value!r}"):
            DataConfig(**{name: value})
    for split in ((math.nan, 0.5, 0.5), (math.inf, 0.5, 0.5), ("0.7", 0.15, 0.15), 0.7):
        with pytest.raises(InputError, match=r"split must be three finite positive shares"):
            DataConfig(split=split)
    assert DataConfig(n_runs=np.int64(4), split=(0.5, 0.25, 0.25)).seeds == [1000, 1001, 1002, 1003]


def test_build_arrays_refuses_a_single_path_or_no_logs(arm):
    """A bare path was read character by character ("/: not a file"), an empty list gave
    numpy's "need at least one array to concatenate"."""
    spec, target = FeatureSpec(), TargetSpec(window=3, polyorder=1)
    for bare in ("runs/run-1000/log.parquet", Path("runs/run-1000/log.parquet")):
        with pytest.raises(InputError, match=r"log_paths must be a sequence of log paths, got a"):
            build_arrays(arm, bare, spec, target)
    with pytest.raises(InputError, match=r"log_paths must be a non-empty sequence .*\[\]"):
        build_arrays(arm, [], spec, target)


def test_feature_spec_refuses_widths_that_are_not_finite_numbers():
    """``sign_joint_speed=inf`` made every sign feature 0; ``drum_radius=inf`` went through."""
    for name in (
        "sign_joint_speed",
        "sign_cable_speed",
        "drum_radius",
        "memory_angle",
        "memory_length",
        "sign_error_angle",
    ):
        for value in (math.inf, math.nan, 0.0, -1.0):
            with pytest.raises(InputError, match=rf"{name} must be a finite value > 0, got"):
                FeatureSpec(**{name: value})
        with pytest.raises(InputError, match=rf"{name} must be a number, got '1'"):
            FeatureSpec(**{name: "1"})


def test_reference_features_refuse_a_reference_of_the_wrong_shape_or_not_finite(arm):
    """A (T, 3) reference gave a broadcast error, a single row a matmul error, references of
    two lengths an IndexError, and a NaN NaN features without a word."""
    extractor = FeatureExtractor(arm)
    q_ref = np.tile(HOME, (5, 1))
    qd_ref = np.zeros((5, 4))
    expected = extractor.from_reference(q_ref, qd_ref)
    with pytest.raises(InputError, match=r"q_ref: expected shape \(T, 4\).*got \(5, 3\)"):
        extractor.from_reference(q_ref[:, :3], qd_ref[:, :3])
    with pytest.raises(InputError, match=r"qd_ref: expected shape \(T, 4\).*got \(4,\)"):
        extractor.from_reference(q_ref, qd_ref[0])
    with pytest.raises(InputError, match="q_ref has 5 ticks but qd_ref has 3"):
        extractor.from_reference(q_ref, qd_ref[:3])
    bad = q_ref.copy()
    bad[2, 1] = np.nan
    with pytest.raises(
        InputError, match=rf"q_ref has 1 non-finite .* tick 2, joint '{arm.joint_names[1]}'"
    ):
        extractor.from_reference(bad, qd_ref)
    bad = qd_ref.copy()
    bad[4, 3] = np.inf
    with pytest.raises(InputError, match="qd_ref has 1 non-finite value"):
        extractor.from_reference(q_ref, bad)
    # the refused calls left no state behind
    np.testing.assert_array_equal(extractor.from_reference(q_ref, qd_ref), expected)
