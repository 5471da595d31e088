"""The compiled dual Newton allocation: DAQP's optimum, and no answer where it has none."""

from __future__ import annotations

import numpy as np

from msarm.allocation import make_allocator
from msarm.allocation.solvers import newton
from msarm.allocation.solvers.newton import INFEASIBLE_CODE, NOT_CONVERGED, dual_newton_tick


def _problems(seed: int, count: int, m: int = 9, n: int = 4):
    """Random arm-sized problems: feasible ones (b from a force within the bounds) and some
    scaled beyond what the bounds allow."""
    rng = np.random.default_rng(seed)
    for k in range(count):
        M = rng.normal(size=(n, m))
        f_min = rng.uniform(0.0, 20.0, m)
        f_max = f_min + rng.uniform(0.0, 300.0, m)
        b = M @ rng.uniform(f_min, f_max)
        yield M, b * (rng.uniform(1.0, 3.0) if k % 3 == 0 else 1.0), f_min, f_max


def test_kernel_finds_daqps_optimum_and_proves_the_rest_infeasible():
    weights = 1.0 / np.random.default_rng(0).uniform(100.0, 500.0, 9)
    daqp = make_allocator(9, 4, "fast", weights=weights)
    f, active = np.empty(9), np.empty(9, dtype=np.int8)
    solved = proven = 0
    for M, b, f_min, f_max in _problems(1, 1500):
        want = daqp.solve(M, b, f_min, f_max)
        code = dual_newton_tick(M, b, weights, np.zeros(9), f_min, f_max, f, active, 15)
        if want.status == "optimal":
            assert code >= 0
            np.testing.assert_allclose(f, want.f, rtol=1e-9, atol=1e-9 * np.abs(want.f).max())
            assert np.all(f >= f_min) and np.all(f <= f_max)
            np.testing.assert_array_equal(f[active < 0], f_min[active < 0])  # on the bound
            np.testing.assert_array_equal(f[active > 0], f_max[active > 0])
            solved += 1
        else:
            assert code == INFEASIBLE_CODE
            proven += 1
    assert solved > 800 and proven > 200


def test_kernel_gives_no_answer_rather_than_a_wrong_one_when_cut_short():
    weights = np.ones(9)
    f = np.full(9, -7.0)
    active = np.empty(9, dtype=np.int8)
    cut = 0
    for M, b, f_min, f_max in _problems(2, 200):
        code = dual_newton_tick(M, b, weights, np.zeros(9), f_min, f_max, f, active, 0)
        if code == NOT_CONVERGED:
            cut += 1
            assert np.all(f == -7.0)  # untouched
        else:  # settled by the first estimate: every bound inactive there
            assert code in (0, INFEASIBLE_CODE)
            f[:] = -7.0
    assert cut > 100


def test_allocator_hands_an_unsettled_tick_to_daqp(monkeypatch):
    weights = 1.0 / np.linspace(100.0, 500.0, 9)
    want_alloc = make_allocator(9, 4, "fast", weights=weights)
    alloc = make_allocator(9, 4, "newton", weights=weights)
    monkeypatch.setattr(newton, "MAX_ITER", 0)  # the kernel gives up at once
    for M, b, f_min, f_max in _problems(3, 50):
        got, want = alloc.solve(M, b, f_min, f_max), want_alloc.solve(M, b, f_min, f_max)
        assert got.status == want.status or (got.status, want.status) == ("fallback", "optimal")
        np.testing.assert_allclose(got.f, want.f, rtol=1e-9, atol=1e-7)
