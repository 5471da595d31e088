"""The simulated IPAnema 3 Mini: statics, drives (eq. 8-9, anti-windup), friction, slack, seeds."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from msarm.cdpr.following_error import PAPER_000_FOLLOWING_ERROR
from msarm.cdpr.robot_model import load_cable_robot
from msarm.cdpr.winch_friction import PAPER_000_WINCH_FRICTION
from msarm.errors import InputError
from msarm.plant.cdpr_config import (
    DEFAULT_CDPR_PLANT,
    IDEAL_CDPR_PLANT,
    CdprFrictionConfig,
    CdprNoiseConfig,
    CdprPlantConfig,
)
from msarm.plant.cdpr_plant import CdprPlant, _friction_eval

QUIET = replace(DEFAULT_CDPR_PLANT, name="quiet", noise=CdprNoiseConfig(enabled=False))
NO_FRICTION = replace(QUIET, name="no_friction", friction=CdprFrictionConfig(enabled=False))


@pytest.fixture(scope="module")
def cdpr():
    return load_cable_robot()


def rotation(axis_angle) -> np.ndarray:
    """Rotation matrix of a rotation vector [rad] (Rodrigues)."""
    w = np.asarray(axis_angle, dtype=float)
    angle = np.linalg.norm(w)
    k = w / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def off_home_pose(cdpr):
    r, _ = cdpr.home_pose
    return r + np.array([0.06, -0.04, 0.02]), rotation([0.02, -0.03, 0.04])


def hold(plant: CdprPlant, lengths: np.ndarray, steps: int) -> list[np.ndarray]:
    """Command constant lengths every cycle; return the tensions of every step."""
    tensions = []
    for _ in range(steps):
        plant.command(lengths)
        plant.step()
        tensions.append(plant.ground_truth()["tension"])
    return tensions


def ramp(plant: CdprPlant, cdpr, r0, R, velocity, steps: int) -> None:
    """Command the inverse kinematics of a constant-velocity path (no feedforward)."""
    for k in range(steps):
        plant.command(cdpr.robot.cable_lengths(r0 + velocity * (k + 1) * plant.config.timestep, R))
        plant.step()


# ----------------------------------------------------------------- the friction kernel
def test_compiled_friction_is_the_paper_model():
    """The plant's compiled eq. 5/7 equals msarm.cdpr.winch_friction, and its slope is dτ/dv."""
    model = PAPER_000_WINCH_FRICTION
    fric = np.array(
        [
            [b.c1, b.c2, b.c3, b.c4]
            for b in (
                model.torque_branches.negative,
                model.torque_branches.positive,
                model.force_branches.negative,
                model.force_branches.positive,
            )
        ]
    )
    v_grid = np.concatenate([np.linspace(-model.v_high, model.v_high, 41), [0.0, 1e-4, -3e-3]])
    for f in (0.0, 5.0, 17.3, 35.0):
        for v in v_grid:
            tau, slope = _friction_eval(fric, 0, f, v, model.v_low)
            force, _ = _friction_eval(fric, 2, f, v, model.v_low)
            assert tau == pytest.approx(float(model.torque(f, v)), abs=1e-13)
            assert force == pytest.approx(float(model.force(f, v)), abs=1e-12)
            dv = 1e-7
            wide = replace(model, extrapolate=True)  # the difference may step past v_H
            fd = (float(wide.torque(f, v + dv)) - float(wide.torque(f, v - dv))) / (2 * dv)
            assert slope == pytest.approx(fd, rel=1e-5, abs=1e-6)


# --------------------------------------------------------------------- holding a pose
@pytest.mark.parametrize("mode", ["pi", "p"])
def test_holds_an_inverse_kinematics_pose(cdpr, mode):
    """From tensions that do not balance the platform (12 N each), it settles within 1 mm."""
    r, R = off_home_pose(cdpr)
    plant = CdprPlant(cdpr, DEFAULT_CDPR_PLANT, seed=3)
    plant.reset((r, R), tensions=np.full(cdpr.n_cables, 12.0), drive_mode=mode)
    tensions = np.array(hold(plant, cdpr.robot.cable_lengths(r, R), 1500))
    truth = plant.ground_truth()
    assert np.linalg.norm(truth["position"] - r) < 1e-3
    angle = np.arccos(np.clip((np.trace(R.T @ truth["rotation"]) - 1) / 2, -1, 1))
    assert angle < 1e-2
    # the tensions settle: no change over the last 0.2 s, all cables taut
    last = tensions[-200:]
    assert np.ptp(last, axis=0).max() < 1e-3
    assert np.all(last[-1] > 1.0)
    assert not np.any(truth["drive_saturated"])


def test_ideal_plant_tensions_balance_the_platform(cdpr):
    """At rest A^T f + w = 0 (eq. 2) at the pose the platform settles in.

    The residual is the platform's inertial wrench plus the O(h) gap between the end-of-step
    cable force and the geometry; after 1.5 s the platform's speed is below 1e-7 m/s, so both
    are far below 1e-6 N (and N m), a millionth of the platform's 2.45 N weight.
    """
    r, R = off_home_pose(cdpr)
    assert cdpr.is_feasible(r, R)
    plant = CdprPlant(cdpr, IDEAL_CDPR_PLANT)
    start = np.array([9.0, 14.0, 11.0, 16.0, 12.0, 8.0, 15.0, 10.0])  # not in equilibrium
    plant.reset((r, R), tensions=start)
    hold(plant, cdpr.robot.cable_lengths(r, R), 1500)
    truth = plant.ground_truth()
    assert np.abs(truth["qvel"]).max() < 1e-7
    f = truth["tension"]
    assert np.all(f > 0.0)
    assert np.abs(f - start).max() > 0.5  # the forces did redistribute
    At = cdpr.robot.structure_matrix(truth["position"], truth["rotation"])
    w = cdpr.platform_wrench(truth["position"], truth["rotation"])
    np.testing.assert_allclose(At @ f + w, 0.0, atol=1e-6)
    # stiff cables: the platform hardly moved from the commanded pose
    assert np.linalg.norm(truth["position"] - r) < 1e-4


def test_reset_tensions_hold_the_platform_still(cdpr):
    """With the default force distribution the run starts in equilibrium (both drive modes)."""
    r, R = cdpr.home_pose
    for mode in ("pi", "p"):
        plant = CdprPlant(cdpr, QUIET)
        plant.reset((r, R), drive_mode=mode)
        f0 = plant.ground_truth()["tension"]
        assert np.all(f0 >= cdpr.f_min - 1e-9)
        plant.step(300)
        truth = plant.ground_truth()
        assert np.linalg.norm(truth["position"] - r) < 1e-9
        np.testing.assert_allclose(truth["tension"], f0, atol=1e-6)


# ------------------------------------------------------------- drives: eq. 8 and eq. 9
def test_pure_p_drive_gives_the_following_error_law_of_eq_8(cdpr):
    """At rest under a static load FE / tau = c_f / K_p = -2.55e-3 m/(N m)."""
    r, R = cdpr.home_pose
    plant = CdprPlant(cdpr, QUIET)
    plant.reset((r, R), drive_mode="p")
    lengths = cdpr.robot.cable_lengths(r, R)
    hold(plant, lengths, 800)
    s0 = plant.sense()
    plant.set_external_wrench([0.4, -0.3, -3.0], [0.01, 0.0, -0.02])  # a static load
    hold(plant, lengths, 800)
    s1 = plant.sense()
    truth = plant.ground_truth()
    c = PAPER_000_FOLLOWING_ERROR.compliance
    assert c == pytest.approx(-2.55e-3, rel=0.01)
    for s in (s0, s1):
        np.testing.assert_allclose(s.following_error / s.motor_torque, c, rtol=0.02)
    slope = (s1.following_error - s0.following_error) / (s1.motor_torque - s0.motor_torque)
    np.testing.assert_allclose(slope, c, rtol=0.02)
    # at rest the drive torque is the cable's (eq. 3 with v = 0: dynamic friction only)
    np.testing.assert_allclose(s1.motor_torque, truth["tension"] * plant.drum_radius, atol=1e-6)
    # ... and the platform sank under the load: the winches gave way like springs
    assert truth["position"][2] < r[2] - 1e-4


def test_pi_drive_following_error_grows_with_speed_as_eq_9(cdpr):
    """With PI drives and no feedforward FE = c_v v on a ramp, whatever the cable force."""
    r, R = cdpr.home_pose
    plant = CdprPlant(cdpr, QUIET)
    plant.reset((r, R), drive_mode="pi")
    ramp(plant, cdpr, r, R, np.array([2.0, 0.0, 0.5]) / 60.0, 700)
    s = plant.sense()
    assert np.all(np.abs(s.cable_velocity) > 0.01)
    np.testing.assert_allclose(s.following_error / s.cable_velocity, 60 * 8.893e-5, rtol=0.02)


# ------------------------------------------------------------------- load cell friction
@pytest.mark.parametrize("friction", [True, False])
def test_load_cell_differs_from_platform_force_by_eq_7(cdpr, friction):
    """Paying out the load cell reads less than the platform feels, hauling in more (f_F)."""
    r, R = cdpr.home_pose
    plant = CdprPlant(cdpr, QUIET if friction else NO_FRICTION)
    plant.reset((r, R))
    ramp(plant, cdpr, r, R, np.array([2.0, 0.0, 0.0]) / 60.0, 600)  # 2 m/min along x
    truth, s = plant.ground_truth(), plant.sense()
    f, v = truth["tension"], truth["cable_speed"]
    paid_out, hauled_in = v > 0.01, v < -0.01
    assert paid_out.sum() >= 2 and hauled_in.sum() >= 2
    if not friction:
        np.testing.assert_array_equal(s.load_cell, f)
        return
    f_F = PAPER_000_WINCH_FRICTION.force(f, v)
    np.testing.assert_allclose(s.load_cell - f, f_F, rtol=0, atol=1e-12)
    assert np.all(s.load_cell[paid_out] < f[paid_out])
    assert np.all(s.load_cell[hauled_in] > f[hauled_in])
    # eq. 3 at (nearly) constant speed: the motor gives f r_D + tau_F(f, v)
    tau_F = PAPER_000_WINCH_FRICTION.torque(f, v)
    np.testing.assert_allclose(s.motor_torque, f * plant.drum_radius + tau_F, atol=1e-4)
    assert np.all(tau_F[paid_out] < 0.0) and np.all(tau_F[hauled_in] > 0.0)


# ------------------------------------------------------------------------- slack cables
def test_a_slack_cable_carries_no_force(cdpr):
    r, R = cdpr.home_pose
    plant = CdprPlant(cdpr, QUIET)
    plant.reset((r, R))
    lengths = cdpr.robot.cable_lengths(r, R)
    lengths[0] += 0.02  # pay 2 cm of cable 0 out
    tensions = np.array(hold(plant, lengths, 400))
    assert tensions.min() == 0.0  # one-sided at every step, also while it goes slack
    truth, s = plant.ground_truth(), plant.sense()
    assert truth["slack"][0]
    assert truth["tension"][0] == 0.0
    assert truth["stretch"][0] < -1e-3
    assert s.load_cell[0] == 0.0
    # the generalised force on the platform is that of the other cables only
    data = plant.mj_data
    import mujoco

    J = np.zeros((cdpr.n_cables, 6))
    mujoco.mju_sparse2dense(
        J,
        data.ten_J,
        plant.mj_model.ten_J_rownnz,
        plant.mj_model.ten_J_rowadr,
        plant.mj_model.ten_J_colind,
    )
    np.testing.assert_allclose(data.qfrc_applied, -J.T @ truth["tension"], atol=1e-9)


# ---------------------------------------------------------------------- reproducibility
def _run(cdpr, seed: int) -> tuple[np.ndarray, np.ndarray]:
    r, R = off_home_pose(cdpr)
    plant = CdprPlant(cdpr, DEFAULT_CDPR_PLANT, seed=seed)
    plant.reset((r, R), tensions=np.full(cdpr.n_cables, 12.0), drive_mode=["pi"] * 4 + ["p"] * 4)
    readings, truths = [], []
    for k in range(300):
        lengths = cdpr.robot.cable_lengths(r + np.array([1e-4 * k, 0.0, 0.0]), R)
        plant.command(lengths, v_ff=np.zeros(cdpr.n_cables))
        plant.step()
        s = plant.sense()
        readings.append(np.concatenate([s.cable_length, s.motor_torque, s.load_cell]))
        truths.append(
            np.concatenate([plant.ground_truth()["qpos"], plant.ground_truth()["tension"]])
        )
    return np.array(readings), np.array(truths)


def test_same_seed_same_run_bit_for_bit(cdpr):
    readings_a, truth_a = _run(cdpr, seed=7)
    readings_b, truth_b = _run(cdpr, seed=7)
    np.testing.assert_array_equal(readings_a, readings_b)
    np.testing.assert_array_equal(truth_a, truth_b)
    readings_c, truth_c = _run(cdpr, seed=8)
    assert not np.array_equal(readings_a, readings_c)  # other noise ...
    np.testing.assert_array_equal(truth_a, truth_c)  # ... same physics


# ------------------------------------------------------------- transients and bad input
@pytest.mark.parametrize("beyond", ["clamp", "extrapolate"])
def test_fast_transients_beyond_the_friction_fit_are_counted(cdpr, beyond):
    r, R = cdpr.home_pose
    config = replace(QUIET, friction=replace(QUIET.friction, beyond_v_high=beyond))
    plant = CdprPlant(cdpr, config)
    plant.reset((r, R))
    lengths = cdpr.robot.cable_lengths(r, R)
    lengths[2] -= 0.01  # a 1 cm step of one set-point
    hold(plant, lengths, 300)
    truth = plant.ground_truth()
    assert truth["friction_beyond_v_high"][2] > 0
    assert np.isfinite(truth["qpos"]).all()


def accelerate_along_x(plant: CdprPlant, cdpr, top_speed: float, steps: int) -> list[dict]:
    """Command the IK of a path along x that speeds up evenly to ``top_speed`` [m/s].

    The platform reaches ``top_speed`` at half the ``steps`` and keeps it; no feedforward.

    Returns:
        The ground truth after the reset and after every step (``steps + 1`` of them).
    """
    truths = [plant.ground_truth()]
    r, R = truths[0]["position"], truths[0]["rotation"]
    h = plant.config.timestep
    t_acc = steps // 2 * h
    for k in range(1, steps + 1):
        t = k * h
        ta = min(t, t_acc)
        x = 0.5 * top_speed / t_acc * ta**2 + top_speed * (t - ta)
        plant.command(cdpr.robot.cable_lengths(r + np.array([x, 0.0, 0.0]), R))
        plant.step()
        truths.append(plant.ground_truth())
    return truths


@pytest.mark.parametrize("beyond", ["clamp", "extrapolate"])
def test_friction_beyond_v_high_is_eq_5_at_v_high_or_at_the_speed(cdpr, beyond):
    """Beyond v_H the winch friction is eq. 5 at +-v_H ("clamp") or at the speed ("extrapolate").

    The platform speeds up along x to 18 m/min (3 v_H): four cables pay out, four haul in, all
    taut and beyond v_H for most of the run. Each step's friction torque is eq. 5 at the
    tension and speed the step started from (``msarm.cdpr.winch_friction`` is the reference),
    clamped to +-v_H or not; within v_H, and extrapolated, it carries the implicit step's slope
    term ``min(dtau_F/dv, 0) (v' - v)`` (none on the plateau). The load cell's f_F is eq. 7 at
    the new tension and speed, clamped the same way, and ``friction_beyond_v_high`` counts the
    steps that ended faster than v_H.
    """
    config = replace(QUIET, friction=replace(QUIET.friction, beyond_v_high=beyond))
    plant = CdprPlant(cdpr, config)
    plant.reset(cdpr.home_pose)
    truths = accelerate_along_x(plant, cdpr, 18.0 / 60.0, 200)

    def stack(key: str, start: int) -> np.ndarray:
        return np.array([g[key] for g in truths[start : len(truths) - 1 + start]])

    f0, u = stack("tension", 0), stack("cable_speed", 0)  # where each step starts
    f, v, tau_F, f_F = (
        stack(key, 1) for key in ("tension", "cable_speed", "friction_torque", "friction_force")
    )
    fitted = PAPER_000_WINCH_FRICTION  # refuses |v| > v_H: the clamp must give +-v_H exactly
    wide = replace(fitted, extrapolate=True)
    v_high, v_low = fitted.v_high, fitted.v_low
    assert np.all(f > 0.0)
    assert (u > v_high).sum() >= 400 and (u < -v_high).sum() >= 400  # both directions
    outer = np.abs(u) >= v_low  # eq. 4's branches, where dtau_F/dv is c1 + 2 c2 v
    beyond_fit = np.abs(u) > v_high
    branches = wide.torque_branches
    slope = np.where(u < 0.0, branches.negative.slope(u), branches.positive.slope(u))
    implicit = wide.torque(f0, u) + np.minimum(slope, 0.0) * (v - u)
    if beyond == "clamp":
        at_v_high = fitted.torque(f0, np.clip(u, -v_high, v_high))
        expected = np.where(beyond_fit, at_v_high, implicit)
        expected_force = fitted.force(f, np.clip(v, -v_high, v_high))
    else:
        expected = implicit
        expected_force = wide.force(f, v)
    np.testing.assert_allclose(tau_F[outer], expected[outer], rtol=0, atol=1e-12)
    np.testing.assert_allclose(f_F, expected_force, rtol=0, atol=1e-12)
    # friction opposes the motion: it brakes the paying out, loads the hauling in
    assert np.all(tau_F[u > v_high] < 0.0) and np.all(tau_F[u < -v_high] > 0.0)
    counts = np.array([g["friction_beyond_v_high"] for g in truths])
    steps_beyond = np.cumsum(np.abs(v) > v_high, axis=0)
    np.testing.assert_array_equal(counts, np.vstack([np.zeros((1, cdpr.n_cables)), steps_beyond]))


def test_a_saturated_drive_holds_its_integral(cdpr):
    """Anti-windup: while a drive's torque is at +-tau_max its PI integral is held.

    Hauling cable 2 in by 5 cm stalls its winch at +tau_max for about 0.1 s (the other cables
    hold the platform); setting the length back pays it out at -tau_max for a few steps. The
    torque law ``tau = K_v (v - v_cmd) + (K_v / T_n) I`` with ``v_cmd = K_pos FE`` gives the
    integral at every unsaturated step (and at the reset); from one such step to the next it
    grows by ``h (v - v_cmd)`` of the later step only, so across a saturated interval it is
    the held value: the torque leaves saturation where the held integral puts it.
    """
    plant = CdprPlant(cdpr, QUIET)
    r, R = cdpr.home_pose
    plant.reset((r, R), drive_mode="pi")
    home = cdpr.robot.cable_lengths(r, R)
    hauled = home.copy()
    hauled[2] -= 0.05
    truths = [plant.ground_truth()]
    for k in range(200):
        plant.command(hauled if k < 100 else home)
        plant.step()
        truths.append(plant.ground_truth())
    drive, h = QUIET.drive, QUIET.timestep
    kv, tn, tau_max = drive.velocity_gain, drive.integral_time, QUIET.winch.torque_limit
    tau, v, fe, saturated = (
        np.array([g[key] for g in truths])
        for key in ("motor_torque", "cable_speed", "following_error", "drive_saturated")
    )
    slip = v - drive.position_gain * fe  # v - v_cmd
    integral = tn * (tau / kv - slip)  # valid where the drive is not saturated
    for i in range(cdpr.n_cables):  # the integral moves at the unsaturated steps only
        free = np.flatnonzero(~saturated[:, i])
        np.testing.assert_allclose(
            np.diff(integral[free, i]), h * slip[free[1:], i], rtol=0, atol=1e-12, err_msg=f"{i}"
        )
    np.testing.assert_allclose(np.abs(tau[saturated]), tau_max, rtol=1e-14)
    # the run did stall cable 2 at +tau_max, pay it out at -tau_max and let it go again
    sat = saturated[:, 2]
    assert sat[1:101].sum() >= 90 and np.all(tau[1:101, 2][sat[1:101]] > 0.0)
    assert np.any(tau[101:, 2][sat[101:]] < 0.0)
    assert not sat[0] and not sat[-1]


def test_effect_parameters_name_what_is_switched_on(cdpr):
    quiet = CdprPlant(cdpr, QUIET).effect_parameters()
    assert {"winch_friction", "load_cell_friction", "elasticity", "drive"} <= set(quiet)
    assert "sensor_noise" not in quiet
    assert quiet["drive"]["velocity_gain"] * quiet["drive"]["position_gain"] == pytest.approx(
        -1.0 / PAPER_000_FOLLOWING_ERROR.compliance
    )
    ideal = CdprPlant(cdpr, IDEAL_CDPR_PLANT).effect_parameters()
    assert "winch_friction" not in ideal and "sensor_noise" not in ideal
    assert "sensor_noise" in CdprPlant(cdpr, DEFAULT_CDPR_PLANT).effect_parameters()


def test_bad_input_is_refused(cdpr):
    plant = CdprPlant(cdpr, QUIET)
    with pytest.raises(InputError, match="reset"):
        plant.step()
    r, R = cdpr.home_pose
    plant.reset((r, R))
    with pytest.raises(InputError, match="drive_mode"):
        plant.command(cdpr.robot.cable_lengths(r, R), drive_mode="pid")
    with pytest.raises(InputError, match="l_set"):
        plant.command(np.zeros(3))
    with pytest.raises(InputError, match="tensions"):
        plant.reset((r, R), tensions=-np.ones(cdpr.n_cables))
    with pytest.raises(ValueError, match="timestep"):
        CdprPlantConfig(timestep=0.002)


def test_a_plant_timestep_below_the_documented_minimum_is_refused(tmp_path):
    """1e-9 s (a million plant steps a 1 ms cycle) was accepted from a plant file."""
    from msarm.errors import ConfigError
    from msarm.io.config import load_config
    from msarm.plant.cdpr_config import MAX_TIMESTEP, MIN_TIMESTEP

    assert (MIN_TIMESTEP, MAX_TIMESTEP) == (1e-5, 1e-3)
    path = tmp_path / "fine.yaml"
    path.write_text("timestep: 1.0e-9\n")
    with pytest.raises(ConfigError, match=r"timestep must be in \[1e-05, 0.001\] s .*got 1e-09"):
        load_config(path, CdprPlantConfig)
    assert CdprPlantConfig(timestep=MIN_TIMESTEP).timestep == 1e-5  # the bound itself is fine
    with pytest.raises(ValueError, match="timestep"):
        CdprPlantConfig(timestep=0.99 * MIN_TIMESTEP)


def test_a_nan_platform_speed_stops_the_run_though_mujoco_resets_its_state(cdpr):
    """MuJoCo resets a bad state silently (time included); the plant stops, naming it."""
    from msarm.plant.arm_plant import SimulationDivergedError

    r, R = off_home_pose(cdpr)
    plant = CdprPlant(cdpr, QUIET, seed=0)
    plant.reset((r, R))
    plant.step(5)
    end = plant.time + 5 * plant.mj_model.opt.timestep
    plant.mj_data.qvel[2] = np.nan
    before = plant.mj_data.qpos.tolist()
    with pytest.raises(SimulationDivergedError, match="velocity at DOF 2") as caught:
        plant.step(5)
    assert caught.value.time == pytest.approx(end)
    # the state named is the one the failed period started from, not MuJoCo's reset one
    assert "at the start of that period" in str(caught.value)
    np.testing.assert_array_equal(caught.value.state["qpos"], before)
    assert np.isnan(caught.value.state["qvel"][2])


def test_step_counts_must_be_whole_and_non_negative(cdpr):
    plant = CdprPlant(cdpr, QUIET)
    plant.reset(cdpr.home_pose)
    for bad in (-3, 2.7, True, "2"):
        with pytest.raises(InputError, match="n_steps must be an integer >= 0"):
            plant.step(bad)
    plant.step(np.int64(2))
    assert plant.time == pytest.approx(2 * QUIET.timestep)


@pytest.mark.parametrize(
    "block,key,value",
    [
        ("cable", "chain_length", ".inf"),
        ("cable", "axial_stiffness", ".inf"),
        ("cable", "damping_time", ".inf"),
        ("winch", "drum_radius", ".inf"),
        ("winch", "inertia", ".inf"),
        ("winch", "torque_limit", ".nan"),
        ("drive", "position_gain", ".inf"),
        ("drive", "integral_time", ".inf"),
        ("drive", "fe_compliance", "-.inf"),
        ("load_cell", "bias", ".nan"),
        ("load_cell", "bias", ".inf"),
        ("noise", "load_cell", ".inf"),
        ("noise", "encoder", "-1.0"),
    ],
)
def test_non_finite_plant_numbers_are_refused_naming_the_key(tmp_path, block, key, value):
    from msarm.errors import ConfigError
    from msarm.io.config import load_config

    path = tmp_path / "plant.yaml"
    path.write_text(f"{block}:\n  {key}: {value}\n")
    with pytest.raises(ConfigError, match=rf"key '{block}'.*{key} must be a finite value"):
        load_config(path, CdprPlantConfig)


def test_a_plant_file_that_is_not_yaml_gives_one_line(tmp_path):
    from msarm.errors import ConfigError
    from msarm.io.config import load_config

    path = tmp_path / "plant.yaml"
    path.write_text("cable:\n  chain_length: [1, 2\nwinch: {drum_radius: 0.02}\n")
    with pytest.raises(ConfigError) as caught:
        load_config(path, CdprPlantConfig)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: not valid YAML: line 3, column ")


@pytest.mark.parametrize("name", ["a/b", "../../x", "", ".hidden", "-x", "a b", "lab-delta=0.5"])
def test_plant_names_must_be_simple_identifiers(name):
    with pytest.raises(ValueError, match="name must be a simple identifier"):
        CdprPlantConfig(name=name)
    assert CdprPlantConfig(name="wire-x_2.b").name == "wire-x_2.b"


def test_the_cable_robot_plant_takes_the_arm_plant_s_seeds(cdpr):
    for bad in (None, 1.5, "a", True, -1):
        with pytest.raises(InputError, match="seed must be a non-negative integer"):
            CdprPlant(cdpr, DEFAULT_CDPR_PLANT, seed=bad)

    r, R = off_home_pose(cdpr)

    def noise(plant):
        plant.reset((r, R), tensions=np.full(cdpr.n_cables, 12.0))
        plant.step(3)
        return plant.sense().load_cell

    by_number = noise(CdprPlant(cdpr, DEFAULT_CDPR_PLANT, seed=7))
    generator = np.random.default_rng(7)
    plant = CdprPlant(cdpr, DEFAULT_CDPR_PLANT, seed=generator)
    generator.standard_normal(5)  # the caller's generator moving on changes nothing
    np.testing.assert_array_equal(noise(plant), by_number)
    np.testing.assert_array_equal(noise(plant), by_number)  # every reset starts again


def test_drives_too_weak_for_the_least_force_are_warned_about():
    """A torque limit below f_min r_D (5 N x 20 mm) was taken without a word; its runs ended
    hundreds of millimetres off."""
    import warnings

    from msarm.errors import MsarmWarning

    model = load_cable_robot()
    weak = replace(
        DEFAULT_CDPR_PLANT, name="weak", winch=replace(DEFAULT_CDPR_PLANT.winch, torque_limit=0.05)
    )
    with pytest.warns(MsarmWarning, match=r"plant 'weak': winch.torque_limit 0.05 N m is below"):
        CdprPlant(model, weak)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MsarmWarning)
        CdprPlant(model, DEFAULT_CDPR_PLANT)
