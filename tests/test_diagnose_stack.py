"""The selection's joint fit (msarm.diagnose.stack.fit_together): projection and blocks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_diagnose_effects import _make_signals

import msarm.diagnose.stack as stack
from msarm.diagnose.effects import (
    CableCapstanFriction,
    CandidateEffect,
    CoulombFriction,
    DahlFriction,
    InertiaError,
    SensorBiasScale,
    StribeckFriction,
    ViscousFriction,
)
from msarm.diagnose.stack import (
    DiagnosisData,
    Embedded,
    Layout,
    Sampled,
    fit_together,
    group_scores,
)
from msarm.errors import InputError


def diagnosis_data(arm, signals, torque, pool, n_train: int = 2):
    """Diagnosis data of a joint residual ``torque`` (runs below ``n_train`` trained on, the
    rest held out)."""
    layout = Layout({"joint": torque})
    stacked = layout.stack({"joint": torque})
    train, hold = signals.run < n_train, signals.run >= n_train
    return DiagnosisData(
        model=arm,
        train=signals.take(train),
        hold=signals.take(hold),
        layout=layout,
        r_train=stacked[train],
        r_hold=stacked[hold],
        candidates=tuple(Embedded(t, layout) for t in pool),
        skipped={},
        train_runs=tuple(f"run{k}" for k in range(n_train)),
        holdout_runs=tuple(f"run{k}" for k in np.unique(signals.run[hold])),
        channel_names={"joint": tuple(arm.joint_names)},
    )


def _data(arm, truth_terms, thetas):
    """Diagnosis data whose joint residual is exactly the given terms' sum (half held out)."""
    signals = _make_signals(arm, seed=4)
    torque = sum(np.asarray(t.torque(signals, p)) for t, p in zip(truth_terms, thetas, strict=True))
    data = diagnosis_data(arm, signals, torque, truth_terms)
    return data, data.candidates


def _viscous_and_stribeck(arm):
    """Data of an exact viscous + Stribeck residual: ``(data, terms, true parameters)``."""
    v_true = np.array([0.05, 0.08, 0.04, 0.06])
    s_true = np.tile([0.2, 0.35, 0.3], 4)  # coulomb, static, Stribeck velocity per joint
    data, terms = _data(arm, [ViscousFriction(), StribeckFriction()], [v_true, s_true])
    return data, terms, (v_true, s_true)


def _train_error(sampled, model):
    return float(np.sum((sampled.residual["train"] - model.predict(sampled, "train")) ** 2))


def test_blocks_refitted_in_turn_beat_one_pass(arm):
    data, (v_term, s_term), (v_true, s_true) = _viscous_and_stribeck(arm)
    sampled = Sampled(data, 20_000)
    one_pass = fit_together([v_term, s_term], sampled, rounds=1, method="blocks")
    joint = fit_together([v_term, s_term], sampled, method="blocks")
    # one pass: the viscous block, fitted first, takes up part of the Coulomb friction
    assert np.all(one_pass.parameters[0] > 4 * v_true)
    # refitting the blocks in turn lowers the error and moves every estimate towards the truth
    assert _train_error(sampled, joint) < 0.5 * _train_error(sampled, one_pass)
    assert np.all(np.abs(joint.parameters[0] - v_true) < np.abs(one_pass.parameters[0] - v_true))
    hold = {
        name: group_scores(data.layout, sampled.residual["hold"], m.predict(sampled, "hold"))
        for name, m in (("one pass", one_pass), ("joint", joint))
    }
    assert hold["joint"]["joint"] > hold["one pass"]["joint"]
    # but the blocks stop short of the optimum (the truth: the residual is exactly the terms)
    assert not np.allclose(joint.parameters[1], s_true, rtol=1e-2)
    # warm-started from the truth, the fit stays there (the truth is its fixed point)
    exact = fit_together([v_term, s_term], sampled, initial=[v_true, s_true], method="blocks")
    np.testing.assert_allclose(exact.parameters[0], v_true, rtol=1e-6)
    np.testing.assert_allclose(exact.parameters[1], s_true, rtol=1e-6)


def test_the_projection_reaches_the_joint_optimum_from_a_cold_start(arm):
    # the default: IPOPT on the Stribeck parameters with the viscous ones eliminated finds the
    # truth (the least squares optimum of a noise-free residual) where backfitting stops
    data, (v_term, s_term), (v_true, s_true) = _viscous_and_stribeck(arm)
    sampled = Sampled(data, 20_000)
    blocks = fit_together([v_term, s_term], sampled, method="blocks")
    joint = fit_together([v_term, s_term], sampled)
    np.testing.assert_allclose(joint.parameters[0], v_true, rtol=1e-6)
    np.testing.assert_allclose(joint.parameters[1], s_true, rtol=1e-6)
    assert _train_error(sampled, joint) < 1e-6 * _train_error(sampled, blocks)
    assert joint.messages == ("least squares (joint)", "Solve_Succeeded (joint)")
    # with weights (a bootstrap draw: run 0 twice, run 1 left out) the same optimum
    weights = np.where(sampled.signals["train"].run == 0, 2.0, 0.0)
    drawn = fit_together([v_term, s_term], sampled, weights)
    np.testing.assert_allclose(drawn.parameters[0], v_true, rtol=1e-5)
    np.testing.assert_allclose(drawn.parameters[1], s_true, rtol=1e-5)
    with pytest.raises(InputError, match="method: expected 'projection' or 'blocks'"):
        fit_together([v_term, s_term], sampled, method="newton")


def test_the_projection_equals_the_blocks_run_to_convergence(arm, monkeypatch):
    # noisy: the optimum is not the truth; backfitting with no tolerance creeps to the
    # optimum that the projection solves for at once (here in about 2000 rounds: after 10,
    # the default cap, a viscous coefficient was 0.0376 where the optimum has -0.0015)
    data, (v_term, s_term), (v_true, s_true) = _viscous_and_stribeck(arm)
    noise = np.random.default_rng(3).normal(0.0, 0.02, size=data.r_train.shape)
    noisy = replace(data, r_train=data.r_train + noise)
    v_term, s_term = noisy.candidates
    sampled = Sampled(noisy, 20_000)
    joint = fit_together([v_term, s_term], sampled)
    monkeypatch.setattr(stack, "BACKFIT_TOLERANCE", 0.0)  # every round, up to the cap
    start = [v_true, s_true]
    crept = fit_together([v_term, s_term], sampled, initial=start, rounds=3000, method="blocks")
    for a, b in zip(joint.parameters, crept.parameters, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
    assert _train_error(sampled, joint) <= _train_error(sampled, crept) * (1 + 1e-9)


def test_weights_and_a_single_block(arm):
    viscous = ViscousFriction()
    v_true = np.array([0.05, 0.08, 0.04, 0.06])
    data, (v_term,) = _data(arm, [viscous], [v_true])
    sampled = Sampled(data, 20_000)
    weights = np.where(sampled.signals["train"].run == 0, 2.0, 0.0)  # one run counted twice
    for model in (fit_together([v_term], sampled), fit_together([v_term], sampled, weights)):
        np.testing.assert_allclose(model.parameters[0], v_true, rtol=1e-9)


def test_a_none_start_leaves_that_term_to_its_own_guess(arm):
    """The selection's warm start: fitted terms start where they ended, a new one from None."""
    data, (v_term, s_term), (v_true, s_true) = _viscous_and_stribeck(arm)
    sampled = Sampled(data, 20_000)
    for method in ("blocks", "projection"):
        cold = fit_together([v_term, s_term], sampled, method=method)
        # None everywhere, or a start for the linear term only (not a prediction): cold
        for start in ([None, None], [v_true, None]):
            same = fit_together([v_term, s_term], sampled, initial=start, method=method)
            for a, b in zip(same.parameters, cold.parameters, strict=True):
                np.testing.assert_array_equal(a, b)
        # the nonlinear term started at the truth with the linear one left to its guess: the
        # linear part is fitted to what the truth leaves, and both stay at the truth
        warm = fit_together([v_term, s_term], sampled, initial=[None, s_true], method=method)
        np.testing.assert_allclose(warm.parameters[0], v_true, rtol=1e-6)
        np.testing.assert_allclose(warm.parameters[1], s_true, rtol=1e-6)


def test_a_fit_asked_again_is_not_solved_again(arm, monkeypatch):
    import msarm.diagnose.fitting as fitting

    stribeck = StribeckFriction()
    s_true = np.tile([0.2, 0.35, 0.3], 4)
    data, (s_term,) = _data(arm, [stribeck], [s_true])
    sampled = Sampled(data, 20_000)
    calls = []
    solve = fitting._NonlinearProblem.solve

    def counted(self, *args, **kwargs):
        calls.append(1)
        return solve(self, *args, **kwargs)

    monkeypatch.setattr(fitting._NonlinearProblem, "solve", counted)
    r = sampled.residual["train"]
    first = sampled.fit_nonlinear(s_term, r)
    again = sampled.fit_nonlinear(s_term, r.copy())
    assert len(calls) == 1
    np.testing.assert_array_equal(first[0], again[0])
    again[0][0] = -1.0  # the answer handed out is a copy
    np.testing.assert_array_equal(sampled.fit_nonlinear(s_term, r)[0], first[0])
    # another residual, another start or other weights: solved
    sampled.fit_nonlinear(s_term, 0.5 * r)
    sampled.fit_nonlinear(s_term, r, initial=s_true)
    sampled.fit_nonlinear(s_term, r, weights=np.full(r.shape[0], 2.0))
    assert len(calls) == 4


def test_the_factored_solver_is_least_squares():
    """LinearSolver: numpy's lstsq to round-off, min-norm on a rank-deficient design."""
    import pytest

    from msarm.diagnose.fitting import LinearSolver, _solve_linear
    from msarm.errors import InputError

    rng = np.random.default_rng(3)
    design = rng.normal(size=(400, 3, 5)) * np.array([1e-3, 1.0, 50.0, 2.0, 0.1])
    solver = LinearSolver(design)
    for _ in range(3):  # one factoring, many residuals
        r = rng.normal(size=(400, 3))
        np.testing.assert_allclose(solver.solve(r), _solve_linear(design, r), rtol=1e-10)
    # a repeated column and a zero column: lstsq's minimum-norm answer
    deficient = np.concatenate([design, design[:, :, :1], np.zeros((400, 3, 1))], axis=2)
    r = rng.normal(size=(400, 3))
    theta = LinearSolver(deficient).solve(r)
    np.testing.assert_allclose(theta, _solve_linear(deficient, r), rtol=1e-8, atol=1e-12)
    assert theta[-1] == 0.0 and np.isclose(theta[0], theta[5])
    # rows zero in every column (channels the terms do not touch, runs a bootstrap left out)
    # are left out of the factorisation: the same answer, whatever the residual there
    sparse = design.copy()
    sparse[:, 1:, :] = 0.0
    sparse[100:250] = 0.0
    r = rng.normal(size=(400, 3))
    solver = LinearSolver(sparse)
    assert solver.rows is not None and solver.rows.size == 250
    np.testing.assert_allclose(solver.solve(r), _solve_linear(sparse, r), rtol=1e-10)
    moved = r.copy()
    moved[:, 1:] += 7.0
    np.testing.assert_array_equal(solver.solve(moved), solver.solve(r))
    with pytest.raises(InputError, match=r"residual: expected shape \(400, 3\)"):
        solver.solve(r[:10])


def test_the_solvers_are_kept_for_single_terms_and_the_last_set(arm):
    viscous, stribeck = ViscousFriction(), StribeckFriction()
    data, (v_term, s_term) = _data(
        arm, [viscous, stribeck], [np.full(4, 0.05), np.tile([0.2, 0.35, 0.3], 4)]
    )
    sampled = Sampled(data, 20_000)
    single = sampled.solver([v_term])
    assert sampled.solver([v_term]) is single
    pair = sampled.solver([v_term, v_term])
    assert sampled.solver([v_term, v_term]) is pair
    r = sampled.residual["train"]
    np.testing.assert_allclose(pair.solve(r)[:4] + pair.solve(r)[4:], single.solve(r), rtol=1e-9)


def test_a_thinned_child_takes_its_parents_samples_and_designs(arm):
    viscous = ViscousFriction()
    data, (v_term,) = _data(arm, [viscous], [np.full(4, 0.05)])
    parent = Sampled(data, 500)
    child = Sampled(data, 120, parent=parent)
    for split in ("train", "hold"):
        assert set(child.rows[split]) <= set(parent.rows[split])
        assert len(child.rows[split]) <= 120
        np.testing.assert_array_equal(
            child.design(v_term, split),
            v_term.design(data.train if split == "train" else data.hold)[child.rows[split]],
        )
    np.testing.assert_array_equal(child.residual["train"], data.r_train[child.rows["train"]])


def test_a_memoryless_design_is_computed_on_the_samples_used_only(arm, monkeypatch):
    # the mass-error regressor at a sample needs that sample alone: computed on the thinned
    # rows, it is the whole runs' design at those rows, bit for bit, at a fraction of the cost
    inertia, dahl = InertiaError(arm), DahlFriction()
    assert inertia.memoryless and not dahl.memoryless  # Dahl's state runs over the runs
    zeros = [np.zeros(t.n_parameters) for t in (inertia, dahl)]
    data, (i_term, d_term) = _data(arm, [inertia, dahl], zeros)
    assert i_term.memoryless and not d_term.memoryless
    sampled = Sampled(data, 120, max_hold=100)
    seen = []
    for term in (inertia, dahl):
        design = term.design

        def spy(signals, design=design):
            seen.append((signals.n_samples, signals.origin is not None))
            return design(signals)

        monkeypatch.setattr(term, "design", spy)
    for split, whole in (("train", data.train), ("hold", data.hold)):
        rows = sampled.rows[split]
        assert len(rows) < whole.n_samples
        seen.clear()
        got = sampled.design(i_term, split)
        assert seen == [(len(rows), True)]
        np.testing.assert_array_equal(got, i_term.design(whole)[rows])
        seen.clear()
        sampled.design(d_term, split)
        assert seen == [(whole.n_samples, whole.origin is not None)]  # the whole runs


def test_two_nonlinear_terms_and_a_linear_one_on_shared_columns(arm):
    # a capstan friction (all joints), a Stribeck friction on two joints and a viscous
    # friction: one coupled set with two nonlinear terms, fitted in one projected problem
    from msarm.diagnose.projection import ProjectedProblem

    capstan, stribeck, viscous = (
        CableCapstanFriction(),
        StribeckFriction(joints=[0, 1]),
        ViscousFriction(),
    )
    truth = [np.array([0.12]), np.tile([0.2, 0.35, 0.3], 2), np.array([0.05, 0.08, 0.04, 0.06])]
    data, terms = _data(arm, [capstan, stribeck, viscous], truth)
    sampled = Sampled(data, 20_000)
    start = [np.array([0.05]), np.tile([0.1, 0.2, 0.5], 2), None]
    joint = fit_together(list(terms), sampled, initial=start)
    for got, want in zip(joint.parameters, truth, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-4)
    problem = sampled.projection([terms[2]], [terms[0], terms[1]])
    assert problem.p == 4 and list(problem.columns) == [0, 1, 2, 3]
    with pytest.raises(InputError, match="residual: expected shape"):
        problem.solve(np.zeros((3, 4)), [], [])
    r = sampled.residual["train"]
    with pytest.raises(InputError, match="weights: expected"):
        problem.solve(r, [], [], weights=-np.ones(r.shape[0]))
    with pytest.raises(InputError, match="no nonlinear term"):
        ProjectedProblem([], [], np.arange(4), None, sampled.signals["train"])


@pytest.mark.parametrize(
    "make",
    [
        lambda arm: [CableCapstanFriction(fit_eps=True), CoulombFriction()],
        lambda arm: [StribeckFriction(), SensorBiasScale(n_cables=9, n_joints=4)],
        lambda arm: [StribeckFriction(joints=[1, 2]), CableCapstanFriction(), InertiaError(arm)],
    ],
    ids=["capstan+coulomb", "stribeck+sensor", "stribeck+capstan+inertia"],
)
def test_the_projection_is_the_optimum_the_blocks_cannot_improve(arm, make):
    # noisy residuals of mixed sets: the projection's fit is no worse than the blocks', and
    # blocks started there stay there (a fixed point of refitting each block to the rest)
    rng = np.random.default_rng(1)
    terms = make(arm)
    truth = []
    for term in terms:
        if term.linear:
            truth.append(rng.normal(0.0, 0.05, term.n_parameters))
        else:
            low, high = term.bounds()
            guess = term.initial_guess(None) if not isinstance(term, StribeckFriction) else None
            guess = np.tile([0.2, 0.35, 0.3], len(term.channels)) if guess is None else guess
            truth.append(np.clip(guess * rng.uniform(0.8, 1.6, guess.shape), low, high))
    data, _ = _data(arm, terms, truth)
    noise = rng.normal(0.0, 0.1 * np.std(data.r_train), data.r_train.shape)
    data = replace(data, r_train=data.r_train + noise)
    sampled = Sampled(data, 20_000)
    joint = fit_together(list(data.candidates), sampled)
    blocks = fit_together(list(data.candidates), sampled, method="blocks")
    again = fit_together(
        list(data.candidates), sampled, initial=list(joint.parameters), method="blocks"
    )
    assert _train_error(sampled, joint) <= _train_error(sampled, blocks) * (1 + 1e-9)
    assert _train_error(sampled, again) == pytest.approx(_train_error(sampled, joint), rel=1e-7)


def test_the_joint_optimum_keeps_a_terms_constraints(arm):
    """Variable projection passes the Stribeck term's ``s >= c`` to IPOPT with the Dahl term's
    linear part eliminated: on Coulomb + viscous friction beside a Dahl friction the joint fit
    keeps the order and finds the laws that made the residual."""
    coulomb, viscous = np.array([0.2, 0.3, 0.25, 0.15]), np.array([0.08, 0.05, 0.1, 0.06])
    dahl_true = np.array([0.05, 0.1, 0.08, 0.04])
    truth = [CoulombFriction(), ViscousFriction(), DahlFriction()]
    signals = _make_signals(arm, seed=4)
    torque = sum(
        np.asarray(t.torque(signals, p))
        for t, p in zip(truth, [coulomb, viscous, dahl_true], strict=True)
    )
    data = diagnosis_data(arm, signals, torque, [StribeckFriction(viscous=True), DahlFriction()])
    stribeck, dahl = data.candidates
    sampled = Sampled(data, 20_000)
    joint = fit_together([stribeck, dahl], sampled)
    theta = joint.parameters[0]
    assert np.all(stribeck.constraints() @ theta >= -1e-7)
    np.testing.assert_allclose(theta.reshape(4, 4)[:, 3], viscous, rtol=1e-3)
    np.testing.assert_allclose(joint.parameters[1], dahl_true, rtol=1e-2)
    assert _train_error(sampled, joint) < 1e-8 * float(np.sum(sampled.residual["train"] ** 2))


class _Fixed(CandidateEffect):
    """A linear term with a given design (its groups' columns), to test the solvers."""

    description = "a given design"

    def __init__(self, name: str, groups: tuple[str, ...], design: np.ndarray) -> None:
        self.name = name  # type: ignore[misc]
        self.groups = groups
        self.values = design
        self.parameter_names = tuple(f"a{k}" for k in range(design.shape[2]))
        self.channels = tuple(range(design.shape[1]))

    def design(self, signals):
        return self.values


def test_terms_on_different_groups_are_factored_by_blocks(arm):
    """The joint least squares of terms on disjoint rows, a block at a time: the same answer
    as the whole design's (numpy's lstsq, to round-off), with the whole design's cut."""
    from msarm.diagnose.fitting import BlockSolver, LinearSolver, _solve_linear

    rng = np.random.default_rng(5)
    signals = _make_signals(arm, seed=4)
    T, n, m = signals.n_samples, signals.n_joints, signals.n_cables
    groups = {"joint": rng.normal(size=(T, n)), "drive": rng.normal(size=(T, m))}
    layout = Layout(groups)
    stacked = layout.stack(groups)
    data = DiagnosisData(
        model=arm,
        train=signals,
        hold=signals,
        layout=layout,
        r_train=stacked,
        r_hold=stacked,
        candidates=(),
        skipped={},
        train_runs=("run0",),
        holdout_runs=("run0",),
        channel_names={"joint": tuple(arm.joint_names), "drive": tuple(arm.cable_names)},
    )
    sampled = Sampled(data, T)
    a = Embedded(_Fixed("a", ("joint",), rng.normal(size=(T, n, 3))), layout)
    b = Embedded(_Fixed("b", ("drive",), rng.normal(size=(T, m, 4))), layout)
    c = Embedded(_Fixed("c", ("joint",), rng.normal(size=(T, n, 2))), layout)
    terms = [a, b, c]
    solver = sampled.solver(terms)
    assert isinstance(solver, BlockSolver) and len(solver.parts) == 2
    assert sampled.solver(terms) is solver  # the last set is kept
    whole = sampled.joint_design(terms)
    r = stacked + rng.normal(size=stacked.shape)
    np.testing.assert_allclose(solver.solve(r), _solve_linear(whole, r), rtol=1e-9)
    weights = rng.integers(0, 3, size=T).astype(float)
    root = np.sqrt(weights)[:, None]
    np.testing.assert_allclose(
        sampled.weighted_solver(terms, weights)(r),
        _solve_linear(whole * root[:, :, None], r * root),
        rtol=1e-9,
    )
    # the blocks are kept: a set that shares the joint block factors only the new one
    d = Embedded(_Fixed("d", ("drive",), rng.normal(size=(T, m, 2))), layout)
    again = sampled.solver([a, c, d])
    assert isinstance(again, BlockSolver) and again.parts[0][1] is solver.parts[0][1]
    # a singular value above its block's own cut but not above the whole design's (set by
    # the other block's largest, 30 equal columns): dropped, as the whole design drops it
    base = rng.normal(size=(T, n, 1))
    other = rng.normal(size=(T, n, 1))
    own = LinearSolver(np.concatenate([base, base], axis=2))
    largest = float(own.singular.max())
    size = T * layout.width
    for nudge in np.geomspace(1e-14, 1e-9, 60):
        pair = np.concatenate([base, base + nudge * other], axis=2)
        singular = np.linalg.svd(
            (pair / np.linalg.norm(pair.reshape(-1, 2), axis=0)).reshape(-1, 2), compute_uv=False
        )
        if singular[-1] > 3.0 * np.finfo(float).eps * size * largest:
            break
    equal = Embedded(_Fixed("e", ("drive",), np.repeat(rng.normal(size=(T, m, 1)), 30, 2)), layout)
    near = Embedded(_Fixed("f", ("joint",), pair), layout)
    solver = sampled.solver([near, equal])
    cut = np.finfo(float).eps * size * float(np.sqrt(30.0))
    assert LinearSolver(sampled.design(near, "train")).singular.size == 2  # its own cut keeps it
    assert singular[-1] <= cut  # the whole design's drops it
    theta = solver.solve(r)
    np.testing.assert_allclose(theta[:2], theta[0], rtol=1e-9)  # as for two equal columns
    np.testing.assert_allclose(theta[2:], theta[2], rtol=1e-9)  # the min-norm share


def test_the_buffered_solver_gives_casadis_answer_bit_for_bit():
    import casadi

    from msarm.diagnose.fitting import IPOPT_OPTIONS, BufferedNlpsol

    x, p = casadi.MX.sym("x", 2), casadi.MX.sym("p", 3)
    problem = {"x": x, "p": p, "f": casadi.sumsqr(casadi.exp(x * p[:2]) - p[2]), "g": x[0] - x[1]}
    solver = casadi.nlpsol("s", "ipopt", problem, IPOPT_OPTIONS)
    buffered = BufferedNlpsol(solver)
    for values in ([0.3, 1.2, 2.0], [1.0, 0.5, 3.0]):
        arguments = {"x0": [0.1, 0.2], "p": values, "lbx": [-1.0, -1.0], "ubx": 5.0, "lbg": 0.0}
        expected = np.asarray(solver(**arguments)["x"], dtype=float).reshape(-1)
        np.testing.assert_array_equal(buffered(**arguments)["x"], expected)
        assert buffered.stats()["return_status"] == solver.stats()["return_status"]
    with pytest.raises(InputError, match="input p has 2 values, expected 3"):
        buffered(x0=[0.1, 0.2], p=[1.0, 2.0])
    with pytest.raises(InputError, match="unknown input"):
        buffered(x1=[0.1, 0.2])


def test_problems_of_one_structure_share_a_solver_with_the_same_answers(arm):
    """A term on as many samples of other data: one built solver, each problem's own answer."""
    import casadi

    import msarm.diagnose.nlp as nlp
    from msarm.diagnose.effects import CasadiOps
    from msarm.diagnose.fitting import _NonlinearProblem

    s_true = np.tile([0.2, 0.35, 0.3], 4)
    stribeck = StribeckFriction()
    problems = []
    for seed in (4, 6):
        signals = _make_signals(arm, seed=seed)
        residual = np.asarray(stribeck.torque(signals, s_true))
        wobble = 0.01 * np.sin(np.arange(residual.size)).reshape(residual.shape)
        problems.append((signals, residual + wobble))
    nlp._SOLVERS.clear()
    first = _NonlinearProblem(stribeck, *problems[0])
    second = _NonlinearProblem(stribeck, *problems[1])
    assert second.solver is first.solver
    shared = second.solve(None)[0]
    nlp._SOLVERS.clear()
    alone = _NonlinearProblem(stribeck, *problems[1])
    assert alone.solver is not first.solver
    np.testing.assert_array_equal(shared, alone.solve(None)[0])
    np.testing.assert_array_equal(
        first.solve(None)[0], _NonlinearProblem(stribeck, *problems[0]).solve(None)[0]
    )
    # another constant of the equation (the smoothing speed) is another structure
    other = _NonlinearProblem(StribeckFriction(eps=0.02), *problems[0])
    assert other.solver is not alone.solver
    # the answer of the problem with its data as constants (as casadi built it before)
    signals, residual = problems[0]
    theta = casadi.MX.sym("theta", stribeck.n_parameters)
    error = residual - stribeck.torque(signals, theta, CasadiOps())
    problem = {"x": theta, "f": casadi.sumsqr(error) / np.sum(residual**2)}
    G = stribeck.constraints()
    problem["g"] = casadi.mtimes(casadi.DM(G), theta)
    constants = casadi.nlpsol("constants", "ipopt", problem, nlp.IPOPT_OPTIONS)
    lower, upper = stribeck.bounds()
    start = np.clip(stribeck.initial_guess(signals, residual), lower, upper)
    bounds = {"lbx": lower, "ubx": upper, "lbg": 0.0, "ubg": np.inf}
    expected = np.clip(np.asarray(constants(x0=start, **bounds)["x"]).ravel(), lower, upper)
    np.testing.assert_allclose(first.solve(None)[0], expected, rtol=1e-9, atol=1e-12)


def test_sparse_parameters_of_other_patterns_get_their_own_solver():
    """Given symbols of one shape and count of nonzeros but other patterns: two solvers."""
    import casadi

    import msarm.diagnose.nlp as nlp

    x = casadi.MX.sym("x", 2)
    answers = []
    for rows, columns in (([0, 1], [0, 0]), ([0, 1], [0, 1])):  # first column, diagonal
        A = casadi.MX.sym("A", casadi.Sparsity.triplet(2, 2, rows, columns))
        data = nlp.DataOps()
        objective = casadi.bilin(A, x, x) + casadi.sumsqr(x - data.const(np.array([1.0, 2.0])))
        solver, values, _ = nlp.shared_solver("sparse", x, [A], objective, data, np.zeros((0, 2)))
        answers.append(solver(x0=[0.0, 0.0], p=np.concatenate([[1.0, 1.0], values]))["x"])
    # min x0^2 + x1 x0 + |x - (1, 2)|^2 is at (0, 2); min x0^2 + x1^2 + |x - (1, 2)|^2 at (0.5, 1)
    np.testing.assert_allclose(answers[0], [0.0, 2.0], atol=1e-8)
    np.testing.assert_allclose(answers[1], [0.5, 1.0], atol=1e-8)
