"""Candidate effects of the gap diagnosis: each recovers its own parameters from its own data."""

from __future__ import annotations

from dataclasses import replace

import casadi
import numpy as np
import pytest

from msarm.diagnose.cable_effects import CommandDelay
from msarm.diagnose.effects import (
    CANDIDATES,
    CableCapstanFriction,
    CableCapstanHysteresis,
    CandidateEffect,
    CasadiOps,
    CoulombFriction,
    DahlFriction,
    InertiaError,
    MotorCogging,
    SensorBiasScale,
    StribeckFriction,
    TensionDelay,
    ViscousFriction,
    create,
    register,
)
from msarm.diagnose.fitting import bootstrap, fit
from msarm.diagnose.signals import Signals, stick_slip_tension
from msarm.errors import InputError
from msarm.model import load_arm

N_RUNS = 8
PER_RUN = 150
DT = 0.01
DRUM = 0.012


@pytest.fixture(scope="module")
def arm():
    return load_arm()


def _smooth(rng, t, n, mean, amplitude):
    """Sum of 3 sinusoids per channel, with first and second derivatives."""
    x = np.tile(mean, (len(t), 1)).astype(float)
    xd = np.zeros_like(x)
    xdd = np.zeros_like(x)
    for _ in range(3):
        w = rng.uniform(0.5, 3.0, size=n)
        phase = rng.uniform(0, 2 * np.pi, size=n)
        a = amplitude / 3 * rng.uniform(0.5, 1.0, size=n)
        arg = np.outer(t, w) + phase
        x += a * np.sin(arg)
        xd += a * w * np.cos(arg)
        xdd -= a * w**2 * np.sin(arg)
    return x, xd, xdd


def _make_signals(arm, seed: int = 0) -> Signals:
    rng = np.random.default_rng(seed)
    n, m = arm.n_joints, arm.n_cables
    lo, hi = arm.joint_lower, arm.joint_upper
    parts = {k: [] for k in ("t", "q", "qd", "qdd", "F", "run")}
    for run in range(N_RUNS):
        t = run * 100.0 + np.arange(PER_RUN) * DT
        q, qd, qdd = _smooth(rng, t, n, 0.5 * (lo + hi), 0.3 * (hi - lo))
        F, _, _ = _smooth(rng, t, m, np.full(m, 32.5), np.full(m, 27.0))
        parts["t"].append(t)
        parts["q"].append(q)
        parts["qd"].append(qd)
        parts["qdd"].append(qdd)
        parts["F"].append(np.clip(F, 5.0, 60.0))
        parts["run"].append(np.full(PER_RUN, run))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    T = len(cat["t"])
    lengths, jac, wrap = np.empty((T, m)), np.empty((T, m, n)), np.empty((T, m))
    for k in range(T):
        g = arm.geometry(cat["q"][k])
        lengths[k], jac[k], wrap[k] = g.lengths, g.jacobian, g.wrap_angles
    motor_angle = (lengths[0] - lengths) / DRUM + rng.uniform(0, 2 * np.pi, size=m)
    return Signals(
        t=cat["t"],
        q=cat["q"],
        qd=cat["qd"],
        qdd=cat["qdd"],
        tension=cat["F"],
        lengths=lengths,
        cable_velocity=np.einsum("tmn,tn->tm", jac, cat["qd"]),
        jacobian=jac,
        wrap=wrap,
        motor_angle=motor_angle,
        dt=DT,
        run=cat["run"],
        tension_cmd=cat["F"],  # drives that render their commands exactly
        # the drums' speed, as the logs' motor angles give it (the cable speed over the radius)
        motor_speed=-np.einsum("tmn,tn->tm", jac, cat["qd"]) / DRUM,
    )


@pytest.fixture(scope="module")
def signals(arm):
    return _make_signals(arm)


def _cases(arm):
    """(effect, true parameters) of every implemented candidate and option."""
    rng = np.random.default_rng(1)
    inertia_mass = InertiaError(arm, subset="mass")
    inertia_all = InertiaError(arm, subset="all")
    return [
        (CoulombFriction(), np.array([0.3, 0.5, 0.2, 0.4])),
        (CoulombFriction(joints=[3], eps=0.05), np.array([0.7])),
        (ViscousFriction(), np.array([0.05, 0.1, 0.02, 0.08])),
        (DahlFriction(rate=30.0), np.array([0.3, 0.5, 0.2, 0.4])),
        (
            StribeckFriction(joints=[0, 3], viscous=True),
            np.array([0.3, 0.6, 0.15, 0.05, 0.2, 0.5, 0.25, 0.02]),
        ),
        (CableCapstanFriction(), np.array([0.12])),
        (CableCapstanFriction(per_cable=True), rng.uniform(0.05, 0.3, size=9)),
        (CableCapstanFriction(linearised=True), np.array([0.12])),
        (CableCapstanFriction(fit_eps=True), np.array([0.12, 0.003])),
        (
            CableCapstanFriction(per_cable=True, fit_eps=True),
            np.concatenate([rng.uniform(0.05, 0.3, size=9), [0.003]]),
        ),
        (CableCapstanHysteresis(), np.array([0.1, 0.3, 0.4, 0.2])),
        (CableCapstanHysteresis(linearised=True), np.array([0.1, 0.3, 0.4, 0.2])),
        (MotorCogging(n_periods=6, drum_radius=DRUM), rng.normal(0, 0.02, size=18)),
        (MotorCogging(n_periods=6, drum_radius=DRUM, shared=True), np.array([0.02, -0.01])),
        (SensorBiasScale(), np.concatenate([rng.normal(0, 1.0, 9), rng.normal(0, 0.05, 9)])),
        (SensorBiasScale(shared=True), np.array([0.8, 0.04])),
        (SensorBiasScale(shared=True, scale=False), np.array([-1.2])),
        (TensionDelay(), np.array([0.004])),
        (inertia_mass, rng.normal(0, 0.2, size=inertia_mass.n_parameters)),
        (inertia_all, rng.normal(0, 0.05, size=inertia_all.n_parameters)),
    ]


def _case_ids():
    return [
        "coulomb",
        "coulomb_elbow",
        "viscous",
        "dahl",
        "stribeck_viscous",
        "capstan",
        "capstan_per_cable",
        "capstan_linearised",
        "capstan_fitted_eps",
        "capstan_per_cable_fitted_eps",
        "capstan_hysteresis",
        "capstan_hysteresis_linearised",
        "cogging",
        "cogging_shared",
        "sensor",
        "sensor_shared",
        "sensor_bias_only",
        "delay",
        "inertia_mass",
        "inertia_all",
    ]


@pytest.mark.parametrize("case", range(len(_case_ids())), ids=_case_ids())
def test_noise_free_recovery(arm, signals, case):
    effect, truth = _cases(arm)[case]
    residual = effect.torque(signals, truth)
    assert np.std(residual) > 0
    result = fit(effect, signals, residual)
    assert result.success, result.message
    np.testing.assert_allclose(result.parameters, truth, rtol=1e-6, atol=1e-9 * np.abs(truth).max())
    assert result.reduction > 1 - 1e-9
    assert result.predict(signals).shape == residual.shape


@pytest.mark.parametrize(
    "effect, truth",
    [
        (CoulombFriction(), np.array([0.3, 0.5, 0.2, 0.4])),
        (CableCapstanFriction(), np.array([0.12])),
        (CableCapstanFriction(fit_eps=True), np.array([0.12, 0.003])),
        (CableCapstanHysteresis(), np.array([0.1, 0.3, 0.4, 0.2])),
        (StribeckFriction(joints=[1]), np.array([0.3, 0.6, 0.15])),
        (SensorBiasScale(shared=True), np.array([0.8, 0.04])),
    ],
    ids=["coulomb", "capstan", "capstan_fitted_eps", "capstan_hysteresis", "stribeck", "sensor"],
)
def test_noisy_recovery_within_bootstrap_std(signals, effect, truth):
    clean = effect.torque(signals, truth)
    rng = np.random.default_rng(7)
    residual = clean + rng.normal(0, 0.3 * np.std(clean), size=clean.shape)
    result = fit(effect, signals, residual)
    spread = bootstrap(effect, signals, residual, n_boot=30, seed=3)
    assert spread.samples.shape == (30, effect.n_parameters)
    assert np.all(spread.std > 0)
    assert np.all(np.abs(result.parameters - truth) < 3 * spread.std), (
        result.parameters,
        truth,
        spread.std,
    )
    # Same seed, same spread; different seed, different draws.
    again = bootstrap(effect, signals, residual, n_boot=30, seed=3)
    np.testing.assert_array_equal(again.samples, spread.samples)
    other = bootstrap(effect, signals, residual, n_boot=30, seed=4)
    assert not np.array_equal(other.samples, spread.samples)
    # the training error's reduction, 1 - (rms_after / rms_before)^2, by hand
    error = residual - result.predict(signals)
    assert result.reduction == pytest.approx(1.0 - np.sum(error**2) / np.sum(residual**2))
    assert 0.5 < result.reduction < 0.99  # noise of 0.3 std left: not all explained


def test_explained_variance_held_out(arm, signals):
    truth_effect, truth = CableCapstanFriction(), np.array([0.15])
    clean = truth_effect.torque(signals, truth)
    rng = np.random.default_rng(2)
    residual = clean + rng.normal(0, 0.05 * np.std(clean), size=clean.shape)
    train = signals.run < 6
    test = ~train
    right = fit(truth_effect, signals, residual, train)
    assert right.explained_variance(signals, residual, test) > 0.99
    per_joint = right.explained_variance(signals, residual, test, per_joint=True)
    assert per_joint.shape == (arm.n_joints,)
    # by hand: 1 - var(r - pred) / var(r) per joint, variances about each joint's mean
    r = residual[test]
    e = r - right.predict(signals)[test]
    var_r, var_e = np.var(r, axis=0), np.var(e, axis=0)
    moving = var_r > 0
    np.testing.assert_allclose(per_joint[moving], 1.0 - var_e[moving] / var_r[moving], rtol=1e-12)
    assert np.all(per_joint[moving] > 0.95)
    assert right.explained_variance(signals, residual, test) == pytest.approx(
        1.0 - var_e.sum() / var_r.sum(), rel=1e-12
    )
    wrong = fit(MotorCogging(n_periods=6, drum_radius=DRUM, shared=True), signals, residual, train)
    assert wrong.explained_variance(signals, residual, test) < 0.1
    unrelated = fit(InertiaError(arm), signals, residual, train)
    assert unrelated.explained_variance(signals, residual, test) < 0.1


def test_casadi_and_numpy_agree(arm, signals):
    small = signals.take(np.arange(40))
    for effect, truth in _cases(arm):
        theta = casadi.SX.sym("theta", effect.n_parameters)
        expression = effect.torque(small, theta, CasadiOps())
        function = casadi.Function("f", [theta], [expression])
        np.testing.assert_allclose(
            np.asarray(function(truth)), effect.torque(small, truth), rtol=1e-12, atol=1e-12
        )


def test_capstan_sign_pulled_in_cable_delivers_less(signals):
    effect = CableCapstanFriction()
    r = effect.torque(signals, np.array([0.2]))
    # Delivered torque -J^T F_insertion, with F_insertion < F on cables pulled in.
    s = np.tanh(-signals.cable_velocity / effect.eps)
    inserted = signals.tension * np.exp(-0.2 * signals.wrap * s)
    delivered = -np.einsum("tmn,tm->tn", signals.jacobian, inserted)
    tau_ms = -np.einsum("tmn,tm->tn", signals.jacobian, signals.tension)
    np.testing.assert_allclose(r, tau_ms - delivered, atol=1e-12)
    assert np.all(
        inserted[signals.cable_velocity < -0.01] < signals.tension[signals.cable_velocity < -0.01]
    )


def test_coulomb_opposes_motion(signals):
    r = CoulombFriction().torque(signals, np.full(4, 0.5))
    moving = np.abs(signals.qd) > 0.1
    assert np.all(np.sign(r[moving]) == np.sign(signals.qd[moving]))


def test_inertia_matches_rnea_of_perturbed_model(arm, signals):
    import pinocchio

    effect = InertiaError(arm, subset="all")
    model = arm.pin_model.copy()
    body = model.nbodies - 1
    model.inertias[body].mass = model.inertias[body].mass + 0.3
    small = signals.take(np.arange(20))
    data, data0 = model.createData(), arm.pin_model.createData()
    full = np.zeros(10 * (model.njoints - 1))
    dpi = (
        model.inertias[body].toDynamicParameters()
        - arm.pin_model.inertias[body].toDynamicParameters()
    )
    full[10 * (body - 1) : 10 * body] = dpi
    for k in range(small.n_samples):
        q, v, a = small.q[k], small.qd[k], small.qdd[k]
        expected = pinocchio.rnea(model, data, q, v, a) - pinocchio.rnea(
            arm.pin_model, data0, q, v, a
        )
        np.testing.assert_allclose(effect._regressor(q, v, a) @ full, expected, atol=1e-10)
    assert effect.parameter_names[0].endswith(".mcx") or ".m" in effect.parameter_names[0]
    # named after the body each joint moves: the upper arm (the shoulder's composite joint)
    # and the forearm (the elbow, the hand fixed to it), not the joints
    assert {name.split(".")[0] for name in effect.parameter_names} == {"upper_arm", "forearm"}


def test_registry_and_custom_effect(signals):
    assert {
        "coulomb",
        "viscous",
        "stribeck",
        "capstan",
        "cogging",
        "sensor",
        "delay",
        "inertia",
    } <= set(CANDIDATES)
    assert isinstance(create("viscous"), ViscousFriction)
    with pytest.raises(InputError, match="unknown candidate"):
        create("nope")

    @register
    class ConstantOffset(CandidateEffect):
        name = "test_constant_offset"
        description = "r_j = c_j"
        linear = True

        def __init__(self, n_joints: int = 4) -> None:
            self.channels = tuple(range(n_joints))
            self.parameter_names = tuple(f"c[{j}]" for j in self.channels)

        def design(self, signals):
            T, n = signals.n_samples, signals.n_joints
            return np.broadcast_to(np.eye(n)[None], (T, n, n)).copy()

    try:
        truth = np.array([1.0, -2.0, 0.5, 3.0])
        effect = create("test_constant_offset")
        result = fit(effect, signals, effect.torque(signals, truth))
        np.testing.assert_allclose(result.parameters, truth, rtol=1e-10)
        with pytest.raises(InputError, match="already registered"):

            @register
            class Clash(ConstantOffset):
                name = "test_constant_offset"

    finally:
        CANDIDATES.pop("test_constant_offset", None)


def _fields(signals):
    return {
        "t": signals.t,
        "q": signals.q,
        "qd": signals.qd,
        "qdd": signals.qdd,
        "tension": signals.tension,
        "lengths": signals.lengths,
        "cable_velocity": signals.cable_velocity,
        "jacobian": signals.jacobian,
        "wrap": signals.wrap,
        "motor_angle": signals.motor_angle,
        "dt": signals.dt,
        "run": signals.run,
    }


@pytest.mark.parametrize("field", ["q", "qd", "tension", "jacobian", "wrap", "motor_angle", "t"])
def test_signals_shape_mismatch_names_field(signals, field):
    kwargs = _fields(signals)
    kwargs[field] = kwargs[field][:-1]
    with pytest.raises(InputError, match=rf"Signals\.{field}\b"):
        Signals(**kwargs)


@pytest.mark.parametrize("field", ["qdd", "tension", "cable_velocity", "lengths", "jacobian"])
def test_signals_nan_names_field(signals, field):
    kwargs = _fields(signals)
    bad = np.array(kwargs[field])
    bad.flat[5] = np.nan
    kwargs[field] = bad
    with pytest.raises(InputError, match=rf"Signals\.{field}: non-finite"):
        Signals(**kwargs)


def test_signals_other_bad_input(signals):
    kwargs = _fields(signals)
    with pytest.raises(InputError, match=r"Signals\.dt"):
        Signals(**{**kwargs, "dt": 0.0})
    with pytest.raises(InputError, match=r"Signals\.run"):
        Signals(**{**kwargs, "run": kwargs["run"][:-1]})
    # whole floats past 2**53 would all cast to one int64: refused, not merged
    with pytest.raises(InputError, match=r"Signals\.run: expected integer run labels"):
        Signals(**{**kwargs, "run": np.where(kwargs["run"] < 3, 1e19, 2e19)})
    with pytest.raises(InputError, match=r"Signals\.q"):
        Signals(**{**kwargs, "q": kwargs["q"][:, :3]})
    assert not signals.q.flags.writeable


def test_segments_refine_runs_whatever_labels_are_given():
    """Segments (stretches without a time gap) never join two runs: labels restarting in each
    run, or a replace(run=...) that keeps the old segments, give the delay taps a run start."""
    from dataclasses import replace

    from msarm.diagnose.cable_effects import CommandDelay

    T = 8
    base = dict(
        t=np.arange(T) * 0.004,
        q=np.zeros((T, 1)),
        qd=np.zeros((T, 1)),
        qdd=np.zeros((T, 1)),
        tension=np.ones((T, 1)),
        lengths=np.ones((T, 1)),
        cable_velocity=np.zeros((T, 1)),
        jacobian=np.zeros((T, 1, 1)),
        wrap=np.ones((T, 1)),
        motor_angle=np.zeros((T, 1)),
        dt=0.004,
        tension_cmd=10.0 * np.arange(T, dtype=float)[:, None],
    )
    run = np.repeat([0, 1], 4)
    delay = CommandDelay(n_cables=1, taps=1)
    per_run = Signals(**base, run=run, segment=np.tile([0, 0, 1, 1], 2))
    assert per_run.segment.tolist() == [0, 0, 1, 1, 2, 2, 3, 3]
    assert delay.design(per_run)[[0, 2, 4, 6], 0, 0].tolist() == [0.0] * 4  # each a start
    later = replace(Signals(**base), run=run)  # segments of the one-run signals kept
    assert later.segment.tolist() == [0] * 4 + [1] * 4
    assert delay.design(later)[4, 0, 0] == 0.0
    assert Signals(**base, run=run).segment.tolist() == [0] * 4 + [1] * 4


def test_fit_bad_input(signals):
    effect = CoulombFriction()
    good = effect.torque(signals, np.ones(4))
    with pytest.raises(InputError, match="residual"):
        fit(effect, signals, good[:, :3])
    bad = good.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="residual"):
        fit(effect, signals, bad)
    with pytest.raises(InputError, match="train_mask"):
        fit(effect, signals, good, np.ones(5, dtype=bool))
    with pytest.raises(InputError, match="theta"):
        effect.torque(signals, np.ones(3))
    with pytest.raises(InputError, match="runs"):
        bootstrap(effect, signals, good, runs=np.zeros(signals.n_samples, dtype=int))
    with pytest.raises(InputError, match="cables"):
        fit(CableCapstanFriction(n_cables=8), signals, good)


def test_dahl_state_lags_behind_a_reversal():
    """After a reversal z goes from +1 to -1 over an angle of a few 1/a, not at once."""
    t = np.arange(0, 2.0, 0.001)
    qd = np.where(t < 1.0, 0.5, -0.5)[:, None]  # rad/s, reverses at t = 1 s
    base = dict(
        t=t,
        q=np.cumsum(qd, axis=0) * 0.001,
        qd=qd,
        qdd=np.zeros_like(qd),
        tension=np.ones((len(t), 1)),
        lengths=np.ones((len(t), 1)),
        cable_velocity=np.zeros((len(t), 1)),
        jacobian=np.zeros((len(t), 1, 1)),
        wrap=np.ones((len(t), 1)),
        motor_angle=np.zeros((len(t), 1)),
        dt=0.001,
    )
    signals = Signals(**base)
    z = DahlFriction(n_joints=1, rate=50.0).state(signals)[:, 0]
    assert z[999] == pytest.approx(1.0, abs=1e-6)  # saturated before the reversal
    # implicit Euler of dz/dx = -a (1 + z) after the reversal: z = -1 + 2 exp(-a |dx|)
    k = 1000 + 40  # 20 mrad later
    assert z[k] == pytest.approx(-1 + 2 * np.exp(-50 * 0.02), abs=0.02)
    assert z[-1] == pytest.approx(-1.0, abs=1e-6)
    steep = DahlFriction(n_joints=1, rate=1e5).state(signals)[:, 0]
    np.testing.assert_allclose(steep[5:995], 1.0, atol=1e-6)  # a large a: Coulomb


def test_stick_slip_tension_by_hand():
    """log T = clip(log T_prev, log F - mu Theta, log F + mu Theta); balanced at a run's start."""
    band = np.log(1.1)  # mu Theta: the ends may differ by 10 %
    F = np.array([10.0, 12.0, 11.0, 8.0, 8.0, 20.0, 21.0])[:, None]
    run = np.array([0, 0, 0, 0, 0, 1, 1])
    out = stick_slip_tension(F, np.full(F.shape, 2.0), run, band / 2.0)[:, 0]
    # pulled up: follows 12 / 1.1; sticks at 11; pulled down: follows 8 * 1.1; a new run
    # starts balanced at 20 and sticks at 21 (21 / 1.1 < 20)
    want = [10.0, 12.0 / 1.1, 12.0 / 1.1, 8.0 * 1.1, 8.0 * 1.1, 20.0, 20.0]
    np.testing.assert_allclose(out, want, rtol=1e-12)
    np.testing.assert_allclose(stick_slip_tension(F, np.ones(F.shape), run, 0.0), F, rtol=1e-14)
    with pytest.raises(InputError, match="mu"):
        stick_slip_tension(F, np.ones(F.shape), run, -0.1)


def test_capstan_hysteresis_keeps_the_friction_of_a_cable_at_rest():
    """Pulled in, then held: the stiction term still delivers less; the smooth one does not."""
    T = 300
    rising = np.concatenate([np.linspace(20.0, 40.0, 100), np.full(T - 100, 40.0)])[:, None]
    length = np.concatenate([np.linspace(0.30, 0.29, 100), np.full(T - 100, 0.29)])[:, None]
    base = dict(
        t=np.arange(T) * 0.004,
        q=np.zeros((T, 1)),
        qd=np.zeros((T, 1)),
        qdd=np.zeros((T, 1)),
        tension=rising + np.random.default_rng(0).normal(0.0, 0.3, rising.shape),  # load cells
        tension_cmd=rising,
        lengths=length,
        cable_velocity=np.gradient(length, 0.004, axis=0),
        jacobian=np.full((T, 1, 1), -0.03),
        wrap=np.full((T, 1), 3.0),
        motor_angle=np.zeros((T, 1)),
        dt=0.004,
    )
    signals = Signals(**base)
    still = slice(150, None)
    held = CableCapstanHysteresis(n_cables=1, n_joints=1, mus=(0.1,))
    r = held.torque(signals, np.array([1.0]))  # r = J^T (T_insertion - F)
    delivered_less = 40.0 * (np.exp(-0.3) - 1.0) * -0.03
    np.testing.assert_allclose(r[still, 0], delivered_less, rtol=1e-12)
    smooth = CableCapstanFriction(n_cables=1, n_joints=1).torque(signals, np.array([0.1]))
    np.testing.assert_allclose(smooth[still, 0], 0.0, atol=1e-12)
    # the elements follow the commands, not the noisy load cells; logs without commands: refused
    without = Signals(**{**base, "tension_cmd": None})
    with pytest.raises(InputError, match="tension_cmd"):
        held.check(without)


def test_nonlinear_fit_reports_a_parameter_at_its_bound_on_the_bound(signals):
    """IPOPT relaxes bounds by ~1e-8; a friction coefficient that wants to be < 0 is 0."""
    effect = CableCapstanFriction()
    opposite = -effect.torque(signals, np.array([0.1]))  # friction that would need mu < 0
    result = fit(effect, signals, opposite)
    assert result.parameters[0] == 0.0


def test_capstan_smoothing_speed_is_fitted_within_its_bounds(signals):
    effect = CableCapstanFriction(fit_eps=True, eps=0.002, eps_bounds=(5e-4, 0.01))
    assert effect.parameter_names == ("mu", "eps")
    np.testing.assert_array_equal(effect.initial_guess(signals), [0.05, 0.002])
    lower, upper = effect.bounds()
    np.testing.assert_array_equal(lower, [0.0, 5e-4])
    np.testing.assert_array_equal(upper, [2.0, 0.01])
    # the smoothing speed changes the prediction where cables reverse: it is identifiable
    slow, fast = (effect.torque(signals, np.array([0.1, e])) for e in (6e-4, 0.008))
    assert np.abs(slow - fast).max() > 0.01 * np.abs(slow).max()
    # a sharper law than the bounds allow: the fit stops on the bound
    sharp = CableCapstanFriction(eps=1e-4).torque(signals, np.array([0.1]))
    assert fit(effect, signals, sharp).parameters[1] == 5e-4
    with pytest.raises(InputError, match="linearised"):
        CableCapstanFriction(fit_eps=True, linearised=True)
    with pytest.raises(InputError, match="eps_bounds"):
        CableCapstanFriction(fit_eps=True, eps=0.1, eps_bounds=(1e-4, 0.05))


def test_capstan_hysteresis_columns_are_kept_per_signals(signals):
    effect = CableCapstanHysteresis()
    theta = np.array([0.1, 0.3, 0.4, 0.2])
    first = effect.torque(signals, theta)
    columns = effect._columns(signals)
    assert effect._columns(signals) is columns  # not computed again
    with pytest.raises(ValueError):
        columns[0, 0, 0] = 1.0  # shared: read-only
    other = signals.take(np.arange(50))
    np.testing.assert_array_equal(effect.torque(other, theta), first[:50])
    fresh = CableCapstanHysteresis()._compute_columns(signals)
    np.testing.assert_array_equal(columns, fresh)
    for k in range(10):  # a bounded cache
        effect._columns(signals.take(np.arange(k + 1)))
    assert len(effect._columns_of) <= 8


def test_terms_with_memory_run_over_whole_runs_when_samples_are_thinned_or_masked(signals):
    """The selection thins runs and fit() takes a mask: a state must not skip the gaps."""
    every_other = np.arange(0, signals.n_samples, 2)
    thinned = signals.take(every_other)
    assert thinned.origin[0] is signals
    twice = thinned.take(np.arange(0, thinned.n_samples, 3))  # a take of a take
    assert twice.origin[0] is signals
    np.testing.assert_array_equal(twice.origin[1], every_other[::3])
    hysteresis = CableCapstanHysteresis()
    theta = np.array([0.1, 0.3, 0.4, 0.2])
    whole = hysteresis.torque(signals, theta)
    np.testing.assert_array_equal(hysteresis.torque(thinned, theta), whole[every_other])
    np.testing.assert_array_equal(hysteresis.torque(twice, theta), whole[every_other][::3])
    # computed on the thinned samples alone, the play operators see other tensions
    alone = CableCapstanHysteresis()._compute_columns(thinned)
    assert not np.allclose(alone, hysteresis._columns(thinned))
    # a linear term with memory (the delay taps) fitted on every other sample: exact
    delay = CommandDelay()
    truth = np.array([0.0, 1.0, 0.0, 0.0])
    rng = np.random.default_rng(4)
    commanded = replace(
        signals, tension_cmd=signals.tension + rng.normal(0, 2.0, signals.tension.shape)
    )
    residual = np.asarray(delay.torque(commanded, truth))
    mask = np.zeros(signals.n_samples, dtype=bool)
    mask[::2] = True
    result = fit(delay, commanded, residual, train_mask=mask)
    np.testing.assert_allclose(result.parameters, truth, atol=1e-9)
    assert result.explained_variance(commanded, residual, ~mask) == pytest.approx(1.0)


def test_the_compiled_direction_memory_is_the_implicit_euler_loop():
    """direction_memory (compiled) against the loop it replaces, bit for bit."""
    from msarm.diagnose.signals import direction_memory

    rng = np.random.default_rng(11)
    speed = rng.normal(0.0, 0.5, size=(700, 3))
    speed[100:140] = 0.0  # at rest the memory holds
    run = np.repeat([0, 1, 2], [300, 250, 150])
    t = np.concatenate([np.arange(300) * 0.004, 5 + np.arange(250) * 0.004, np.arange(150) * 0.01])
    expected = np.zeros_like(speed)
    for label in np.unique(run):
        index = np.flatnonzero(run == label)
        current = np.zeros(3)
        for k, i in enumerate(index):
            if k:
                h = 40.0 * (t[index[k]] - t[index[k - 1]])
                current = (current + h * speed[i]) / (1.0 + h * np.abs(speed[i]))
            expected[i] = current
    got = direction_memory(speed, t, run, 40.0)
    np.testing.assert_array_equal(got, expected)
    assert np.all(got[300] == 0.0) and np.all(np.abs(got) < 1.0)
    np.testing.assert_array_equal(got[101:140], np.repeat(got[100:101], 39, axis=0))


def test_stribeck_fit_keeps_the_breakaway_level_at_or_above_the_coulomb_level(signals):
    """Friction that rises with speed (Coulomb + viscous) is not a Stribeck effect.

    Unconstrained, the plain Stribeck term (no viscous part) fits this residual with a static
    level below its Coulomb level: its exponential branch then rises with speed, standing in for
    the viscous friction. With ``s >= c`` kept, the start and the fit stay on that order, and
    the term with its own viscous part recovers the viscous coefficient.
    """
    coulomb, viscous = np.array([0.2, 0.3, 0.25, 0.15]), np.array([0.08, 0.05, 0.1, 0.06])
    residual = CoulombFriction().torque(signals, coulomb) + ViscousFriction().torque(
        signals, viscous
    )
    plain = StribeckFriction()
    G = plain.constraints()
    assert G.shape == (4, 12)
    np.testing.assert_array_equal(G @ np.tile([0.2, 0.5, 0.1], 4), np.full(4, 0.3))  # s - c
    for effect in (plain, StribeckFriction(viscous=True)):
        start = effect.initial_guess(signals, residual)
        assert np.all(effect.constraints() @ start >= 0.0)
        theta = fit(effect, signals, residual).parameters
        assert np.all(effect.constraints() @ theta >= -1e-7)
    per = theta.reshape(4, 4)  # coulomb, static, Stribeck velocity, viscous per joint
    # at s = c the Stribeck velocity plays no part (a flat direction of the fit, which the
    # objective's tolerance leaves a few 1e-4 off): the fit is the Coulomb + viscous law
    fitted = StribeckFriction(viscous=True).torque(signals, theta)
    assert np.sqrt(np.mean((fitted - residual) ** 2)) < 1e-4 * np.sqrt(np.mean(residual**2))
    np.testing.assert_allclose(per[:, 0], coulomb, rtol=1e-2)
    np.testing.assert_allclose(per[:, 1], coulomb, rtol=1e-2)
    np.testing.assert_allclose(per[:, 3], viscous, rtol=1e-3)


def test_a_user_term_with_malformed_constraints_is_refused_by_name(signals):
    class Misshapen(StribeckFriction):
        name = "test_misshapen_constraints"

        def constraints(self):
            return np.ones(3)  # not (k, p)

    with pytest.raises(InputError, match=r"test_misshapen_constraints: constraints\(\) must be"):
        fit(Misshapen(), signals, StribeckFriction().torque(signals, np.tile([0.2, 0.4, 0.1], 4)))


def test_the_real_data_examples_sums_keep_their_terms_constraints():
    """examples/real_cable_transmission.py fits sums of terms: a Stribeck term in a sum keeps
    its ``s >= c`` (the sum's parameters: viscous b, then Stribeck c, s, v)."""
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / "real_cable_transmission.py"
    spec = importlib.util.spec_from_file_location("real_cable_transmission", path)
    module = sys.modules.get(spec.name)  # tests/test_real_cable_transmission.py loads it too
    if module is None:
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # dataclasses look their module up
        spec.loader.exec_module(module)
    total = module.SumOfTerms([ViscousFriction(n_joints=1), StribeckFriction(n_joints=1)])
    np.testing.assert_array_equal(total.constraints(), [[0.0, -1.0, 1.0, 0.0]])
    linear = module.SumOfTerms([ViscousFriction(n_joints=1), CoulombFriction(n_joints=1)])
    assert linear.constraints().shape == (0, 2)


def _stribeck_with(**methods):
    """A Stribeck term (two joints) whose methods are replaced, named for the test."""
    cls = type("Broken", (StribeckFriction,), {"name": "test_broken", **methods})
    return cls(joints=[0, 1])


@pytest.mark.parametrize(
    ("constraints", "message"),
    [
        (lambda self: [[1.0, 0.0], [1.0]], r"must be a matrix of numbers of shape \(k, 6\)"),
        (lambda self: "nonsense", r"must be a matrix of numbers"),
        (lambda self: np.ones((1, 5)), r"got shape \(1, 5\)"),
        (
            lambda self: np.array([[0.0, 1.0, np.nan, 0.0, 0.0, 0.0]]),
            r"non-finite value \(NaN or inf\) at row 0, column 2 \(stribeck_velocity\[0\]\)",
        ),
    ],
)
def test_malformed_constraints_are_refused_with_the_term_and_what_is_wrong(
    signals, constraints, message
):
    from msarm.diagnose.fitting import check_interface

    term = _stribeck_with(constraints=constraints)
    with pytest.raises(InputError, match=r"test_broken: constraints\(\)"):
        check_interface(term)
    with pytest.raises(InputError, match=message):
        fit(term, signals, term.torque(signals, np.tile([0.2, 0.4, 0.1], 2)))


def test_an_empty_constraint_list_is_no_constraint(signals):
    from msarm.diagnose.fitting import constraint_matrix

    term = _stribeck_with(constraints=lambda self: [])
    assert constraint_matrix(term).shape == (0, 6)
    truth = np.tile([0.2, 0.4, 0.1], 2)
    np.testing.assert_allclose(fit(term, signals, term.torque(signals, truth)).parameters, truth)


@pytest.mark.parametrize(
    ("bounds", "message"),
    [
        (lambda self: (np.zeros(3), np.ones(3)), r"got shapes \(3,\) and \(3,\)"),
        (lambda self: None, r"must return two arrays \(lower, upper\) of 6 numbers"),
        (
            lambda self: (np.full(6, np.nan), np.full(6, np.inf)),
            r"the lower bound of coulomb\[0\] is NaN",
        ),
        (
            lambda self: (np.ones(6), np.zeros(6)),
            r"the lower bound of coulomb\[0\] \(1\) is above its upper bound \(0\)",
        ),
        (
            lambda self: (np.full(6, np.inf), np.full(6, np.inf)),
            r"the lower bound of coulomb\[0\] is \+inf, which leaves the parameter no value",
        ),
    ],
)
def test_malformed_bounds_are_refused_with_the_term_and_the_parameter(signals, bounds, message):
    from msarm.diagnose.fitting import check_interface

    term = _stribeck_with(bounds=bounds)
    with pytest.raises(InputError, match=rf"test_broken: bounds\(\).*{message}"):
        check_interface(term)
    with pytest.raises(InputError, match=message):
        fit(term, signals, np.zeros((signals.n_samples, 4)))


def test_a_linear_term_may_state_no_constraint_and_indexed_by_is_checked():
    from msarm.diagnose.fitting import check_interface

    class Capped(CoulombFriction):
        name = "test_capped"

        def constraints(self):
            return -np.eye(self.n_parameters)

    with pytest.raises(InputError, match="test_capped: a linear term is fitted by least squares"):
        check_interface(Capped())

    class Misspelt(CoulombFriction):
        name = "test_misspelt"
        indexed_by = "joints"

    with pytest.raises(InputError, match=r"test_misspelt: indexed_by must be 'joint', 'cable'"):
        check_interface(Misspelt())
    held = CableCapstanFriction(
        fit_eps=True, eps=0.003, eps_bounds=(0.003, 0.003)
    )  # eps held fixed
    for fine in (CoulombFriction(), StribeckFriction(), CableCapstanFriction(), held):
        check_interface(fine)
