"""Winch models of paper 000: friction (eq. 4-7, Table 1), following error (eq. 8-9),
switching (eq. 10) and the force-distribution sensitivity index sigma_ij."""

import math

import numpy as np
import pytest

from msarm.cdpr import CableRobot
from msarm.cdpr.following_error import (
    C_F,
    C_V_MIN,
    K_P,
    PAPER_000_FOLLOWING_ERROR,
    FollowingErrorModel,
    c_v_to_si,
    following_error,
    torque_from_following_error,
)
from msarm.cdpr.sensitivity import (
    cable_sensitivities,
    pair_sensitivities,
    sensitivity_index,
    sensitivity_map,
    sensitivity_matrix,
)
from msarm.cdpr.switching import (
    HALF_PI,
    SwitchingFactor,
    scaling_factor,
    switching_cycles,
    switching_time,
)
from msarm.cdpr.winch_friction import (
    PAPER_000_WINCH_FRICTION,
    TABLE_1_FORCE_NEGATIVE,
    TABLE_1_FORCE_POSITIVE,
    TABLE_1_TORQUE_NEGATIVE,
    TABLE_1_TORQUE_POSITIVE,
    WinchFrictionModel,
    blend_coefficients,
    friction_force,
    friction_torque,
    m_per_min_to_m_per_s,
    m_per_s_to_m_per_min,
)
from msarm.errors import InputError

V_L = 0.25  # m/min
V_H = 6.0  # m/min
FORCES = [5.0, 12.5, 20.0, 27.5, 35.0]  # N
MODEL = PAPER_000_WINCH_FRICTION


def si(v_m_per_min):
    return np.asarray(v_m_per_min, dtype=float) / 60.0


def eq4_paper(c, f, v_m_per_min):
    """Eq. 4 written directly in the paper's units (f in N, v in m/min)."""
    return c[0] * v_m_per_min + c[1] * v_m_per_min**2 + c[2] * f + c[3]


def eq4_slope_paper(c, v_m_per_min):
    return c[0] + 2.0 * c[1] * v_m_per_min


def eq5_paper(neg, pos, f, v):
    """Eq. 5/7 in paper units with the eq. 6 polynomial solved from its five conditions."""
    rows = [
        [1.0, 0.0, 0.0, 0.0, 0.0],  # p(0) = 0 -> b_0 = 0
        [1.0, -V_L, V_L**2, -(V_L**3), V_L**4],  # p(-v_L)
        [1.0, V_L, V_L**2, V_L**3, V_L**4],  # p(v_L)
        [0.0, 1.0, -2 * V_L, 3 * V_L**2, -4 * V_L**3],  # p'(-v_L)
        [0.0, 1.0, 2 * V_L, 3 * V_L**2, 4 * V_L**3],  # p'(v_L)
    ]
    rhs = [
        0.0,
        eq4_paper(neg, f, -V_L),
        eq4_paper(pos, f, V_L),
        eq4_slope_paper(neg, -V_L),
        eq4_slope_paper(pos, V_L),
    ]
    b = np.linalg.solve(np.array(rows), np.array(rhs))
    if v <= -V_L:
        return eq4_paper(neg, f, v)
    if v >= V_L:
        return eq4_paper(pos, f, v)
    return float(np.polyval(b[::-1], v))


# --- units ---------------------------------------------------------------------------------


def test_velocity_conversion_round_trip():
    v = np.array([-6.0, -0.25, 0.0, 0.25, 1.0, 6.0])
    np.testing.assert_allclose(m_per_s_to_m_per_min(m_per_min_to_m_per_s(v)), v, rtol=1e-15)
    assert float(m_per_min_to_m_per_s(6.0)) == pytest.approx(0.1)
    assert float(m_per_s_to_m_per_min(1.0)) == 60.0
    assert MODEL.v_low == pytest.approx(0.25 / 60) and MODEL.v_high == pytest.approx(0.1)


@pytest.mark.parametrize("f", [5.0, 20.0, 35.0])
@pytest.mark.parametrize("v", [-6.0, -3.5, -1.0, -0.25, -0.1, 0.0, 0.07, 0.25, 2.0, 6.0])
def test_si_functions_equal_paper_unit_formulas(f, v):
    tau = friction_torque(f, si(v))
    force = friction_force(f, si(v))
    assert float(tau) == pytest.approx(
        eq5_paper(TABLE_1_TORQUE_NEGATIVE, TABLE_1_TORQUE_POSITIVE, f, v), rel=1e-12, abs=1e-15
    )
    assert float(force) == pytest.approx(
        eq5_paper(TABLE_1_FORCE_NEGATIVE, TABLE_1_FORCE_POSITIVE, f, v), rel=1e-12, abs=1e-14
    )


# --- eq. 6 ---------------------------------------------------------------------------------


def test_blend_coefficients_meet_the_five_conditions():
    rng = np.random.default_rng(0)
    yn, yp, dn, dp = rng.normal(size=(4, 7))
    L = 0.3
    b = blend_coefficients(yn, yp, dn, dp, L)
    assert b.shape == (5, 7)
    p = np.polynomial.Polynomial
    for k in range(7):
        poly = p(b[:, k])
        assert poly(0.0) == 0.0
        np.testing.assert_allclose([poly(-L), poly(L)], [yn[k], yp[k]], rtol=1e-12, atol=1e-13)
        d = poly.deriv()
        np.testing.assert_allclose([d(-L), d(L)], [dn[k], dp[k]], rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("which", ["torque", "force"])
@pytest.mark.parametrize("f", FORCES)
def test_friction_model_continuous_with_continuous_derivative(which, f):
    evaluate = MODEL.torque if which == "torque" else MODEL.force
    branches = MODEL.torque_branches if which == "torque" else MODEL.force_branches
    vl = MODEL.v_low
    # The polynomial meets both outer branch formulas at +-v_L, value and slope.
    b = (MODEL.torque_polynomial if which == "torque" else MODEL.force_polynomial)(f)
    poly = np.polynomial.Polynomial(b)
    scale = abs(branches.negative.value(f, -vl)) + abs(branches.positive.value(f, vl))
    assert poly(-vl) == pytest.approx(branches.negative.value(f, -vl), abs=1e-12 * scale)
    assert poly(vl) == pytest.approx(branches.positive.value(f, vl), abs=1e-12 * scale)
    assert poly.deriv()(-vl) == pytest.approx(branches.negative.slope(-vl), rel=1e-10)
    assert poly.deriv()(vl) == pytest.approx(branches.positive.slope(vl), rel=1e-10)
    # Zero at rest.
    assert float(evaluate(f, 0.0)) == 0.0
    # One-sided (second-order) finite differences of the public function agree on both
    # sides of +-v_L with each other and with the outer branch's slope.
    h = 1e-5 * vl
    for edge in (-vl, vl):
        y = [float(evaluate(f, edge + k * h)) for k in (-2, -1, 0, 1, 2)]
        assert y[1] == pytest.approx(y[2], abs=1e-4 * scale)
        assert y[3] == pytest.approx(y[2], abs=1e-4 * scale)
        slope_left = (3.0 * y[2] - 4.0 * y[1] + y[0]) / (2.0 * h)
        slope_right = (-3.0 * y[2] + 4.0 * y[3] - y[4]) / (2.0 * h)
        slope = branches.positive.slope(vl) if edge > 0 else branches.negative.slope(-vl)
        assert slope_left == pytest.approx(slope, rel=1e-6)
        assert slope_right == pytest.approx(slope, rel=1e-6)


def test_friction_model_breaks_without_the_polynomial():
    """Counter-check: the outer branches alone jump at v = 0 (what eq. 6 repairs)."""
    for f in FORCES:
        jump = eq4_paper(TABLE_1_TORQUE_NEGATIVE, f, 0.0) - eq4_paper(
            TABLE_1_TORQUE_POSITIVE, f, 0.0
        )
        assert jump > 0.05


# --- the paper's number: largest friction torque ----------------------------------------------


def test_largest_friction_torque_of_table_1():
    f = np.linspace(5.0, 35.0, 121)[:, None]
    v = si(np.linspace(-V_H, V_H, 9601))[None, :]
    tau = friction_torque(f, v)
    assert tau.shape == (121, 9601)
    k = np.unravel_index(np.abs(tau).argmax(), tau.shape)
    # At v = -6 m/min, f = 35 N: 0.0358 - 0.0083 + 0.1085 + 0.0252 = 0.161204 N m.
    assert np.abs(tau).max() == pytest.approx(0.161204, abs=1e-9)
    assert f[k[0], 0] == 35.0 and v[0, k[1]] == pytest.approx(-0.1)
    # With the heaviest test weight (3.19 kg, 31.3 N) it is the paper's 0.15 N m, 22 % of 0.69.
    heaviest = 3.19 * 9.80665
    tau_max = float(friction_torque(heaviest, si(-V_H)))
    assert tau_max == pytest.approx(0.1497, abs=1e-4)
    assert round(tau_max, 2) == 0.15 and round(100 * tau_max / 0.69) == 22


# --- bad input -------------------------------------------------------------------------------


def test_friction_rejects_bad_input():
    with pytest.raises(InputError, match="finite"):
        friction_torque(np.nan, 0.01)
    with pytest.raises(InputError, match="finite"):
        friction_force(10.0, [0.0, np.nan])
    with pytest.raises(InputError, match=">= 0"):
        friction_torque(-1.0, 0.01)
    with pytest.raises(InputError, match="v_H"):
        friction_torque(10.0, si(6.5))
    with pytest.raises(InputError, match="broadcast"):
        friction_torque(np.ones(3), np.zeros(4))
    # v_H itself (after a unit round trip) is inside; extrapolation is opt-in.
    friction_torque(10.0, m_per_min_to_m_per_s(-6.0))
    wide = WinchFrictionModel.from_paper_units(extrapolate=True)
    assert float(wide.torque(10.0, si(-8.0))) == pytest.approx(
        eq4_paper(TABLE_1_TORQUE_NEGATIVE, 10.0, -8.0), rel=1e-12
    )
    with pytest.raises(InputError):
        WinchFrictionModel.from_paper_units(v_low_m_per_min=7.0)


def test_friction_is_vectorised():
    f = np.array([[5.0], [20.0], [35.0]])
    v = si(np.array([-3.0, -0.1, 0.0, 0.2, 4.0]))
    tau = friction_torque(f, v)
    assert tau.shape == (3, 5)
    for i in range(3):
        for j in range(5):
            assert tau[i, j] == float(friction_torque(f[i, 0], v[j]))
    assert np.asarray(friction_torque(20.0, 0.01)).shape == ()


# --- following error ------------------------------------------------------------------------


def test_following_error_constants():
    assert PAPER_000_FOLLOWING_ERROR.compliance == pytest.approx(-2.55e-3, rel=3e-3)
    assert C_F / K_P == pytest.approx(-2.555e-3, rel=1e-12)
    assert c_v_to_si(C_V_MIN) == pytest.approx(5.3358e-3, rel=1e-12)


@pytest.mark.parametrize("tau", [-0.3, 0.0, 0.25, 0.69])
@pytest.mark.parametrize("v", [-6.0, -0.5, 0.0, 3.0, 6.0])
def test_following_error_si_equals_paper_units(tau, v):
    paper = C_F * tau / K_P + C_V_MIN * v  # FE [m], tau [N m], v [m/min]
    assert float(following_error(tau, si(v))) == pytest.approx(paper, rel=1e-12, abs=1e-18)
    # Eq. 8 is eq. 9 at rest; the inverse gives the torque back.
    assert float(following_error(tau)) == pytest.approx(C_F * tau / K_P, rel=1e-12)
    back = torque_from_following_error(following_error(tau, si(v)), si(v))
    assert float(back) == pytest.approx(tau, abs=1e-12)


def test_following_error_bad_input_and_model():
    with pytest.raises(InputError, match="finite"):
        following_error(np.nan)
    with pytest.raises(InputError, match="finite"):
        torque_from_following_error(1e-3, np.inf)
    with pytest.raises(InputError):
        FollowingErrorModel(c_f=0.0)
    with pytest.raises(InputError):
        FollowingErrorModel(k_p=-1.0)
    stiff = FollowingErrorModel(k_p=400.0)
    assert float(stiff.following_error(0.5)) == pytest.approx(0.5 * float(following_error(0.5)))


# --- switching (eq. 10) ---------------------------------------------------------------------


@pytest.mark.parametrize(("delta", "cycles"), [(0.0005, 3142), (0.02, 79), (0.5, 4)])
def test_switching_times_of_the_paper(delta, cycles):
    assert switching_cycles(delta) == cycles
    assert switching_time(delta) == pytest.approx(cycles * 1e-3)
    s = SwitchingFactor(delta)
    assert s.h == 0.0 and not s.switching
    s.activate()
    assert s.cycles_left == cycles
    hs = []
    while s.switching:
        hs.append(s.step())
    assert len(hs) == cycles and hs[-1] == 1.0
    assert hs[0] == pytest.approx(math.sin(delta) ** 2)
    assert np.all(np.diff(hs) > 0) and all(0.0 <= h <= 1.0 for h in hs)
    assert s.step() == 1.0 and s.alpha == HALF_PI  # held at pi/2
    s.deactivate()
    hs = []
    while s.switching:
        hs.append(s.step())
    assert len(hs) == cycles and hs[-1] == 0.0 and np.all(np.diff(hs) < 0)


def test_switching_reverses_from_where_it_is():
    s = SwitchingFactor(0.02)
    s.activate()
    for _ in range(10):
        s.step()
    assert s.alpha == pytest.approx(0.2)
    s.deactivate()
    assert s.cycles_left == 10
    for _ in range(10):
        s.step()
    assert s.alpha == 0.0 and s.h == 0.0
    assert SwitchingFactor(0.1, active=True).h == 1.0
    np.testing.assert_allclose(scaling_factor([0.0, HALF_PI / 2, HALF_PI]), [0.0, 0.5, 1.0])
    assert switching_cycles(3.0) == 1
    for bad in (0.0, -0.1, math.nan, math.inf):
        with pytest.raises(InputError, match="delta"):
            SwitchingFactor(bad)
        with pytest.raises(InputError, match="delta"):
            switching_cycles(bad)


# --- sensitivity index ----------------------------------------------------------------------


def symmetric_robot() -> CableRobot:
    """8 cables, frame 4 x 3 x 2 m, mirror-symmetric in x: cables 0<->1, 2<->3, 4<->5, 6<->7."""
    top = np.array([[-2.0, 1.5, 2.0], [2.0, 1.5, 2.0], [2.0, -1.5, 2.0], [-2.0, -1.5, 2.0]])
    bottom = top * [1.0, 1.0, 0.0]
    # Platform anchors at z = +-0.07 m: with +-0.05 m the platform's x-z rectangle would be
    # homothetic to the frame's (4 x 2 m) and every pose singular.
    plate = np.array([[-0.1, 0.1, 0.07], [0.1, 0.1, 0.07], [0.1, -0.1, 0.07], [-0.1, -0.1, 0.07]])
    plate_low = plate * [1.0, 1.0, -1.0]
    return CableRobot(np.vstack([top, bottom]), np.vstack([plate, plate_low]))


MIRROR = np.array([1, 0, 3, 2, 5, 4, 7, 6])
WEIGHT = np.array([0.0, 0.0, -2.0 * 9.81, 0.0, 0.0, 0.0])


def test_sensitivity_is_the_worst_corner_of_the_error_box():
    robot = symmetric_robot()
    At = robot.structure_matrix(np.array([0.4, -0.3, 0.9]), np.eye(3))
    pair = (2, 6)
    others = [k for k in range(8) if k not in pair]
    worst = 0.0
    for d in [(-1, -1), (-1, 1), (1, -1), (1, 1)]:
        delta_c = 0.7 * np.array(d, dtype=float)
        delta_p = np.linalg.solve(At[:, others], -At[:, list(pair)] @ delta_c)
        delta_f = np.zeros(8)
        delta_f[list(pair)], delta_f[others] = delta_c, delta_p
        np.testing.assert_allclose(At @ delta_f, 0.0, atol=1e-12)  # still in equilibrium
        worst = max(worst, np.abs(delta_p).max())
    assert float(sensitivity_index(At, pair, error=0.7)) == pytest.approx(worst, rel=1e-12)
    # Linear in the error bound, independent of the order of the pair.
    assert float(sensitivity_index(At, (6, 2), error=1.4)) == pytest.approx(2 * worst, rel=1e-12)
    s = cable_sensitivities(At, pair, error=0.7)
    assert s.shape == (8,) and s[2] == s[6] == 0.7 and s[others].max() == pytest.approx(worst)
    S = sensitivity_matrix(At, pair)
    assert S.shape == (6, 2)
    table = pair_sensitivities(At)
    assert len(table) == 28 and table[(2, 6)] == pytest.approx(worst / 0.7)


def test_sensitivity_rejects_bad_input():
    robot = symmetric_robot()
    At = robot.structure_matrix(np.array([0.0, 0.0, 1.0]), np.eye(3))
    with pytest.raises(InputError, match="m - 6 = 2"):
        sensitivity_index(At, (1,))
    with pytest.raises(InputError, match="distinct"):
        sensitivity_index(At, (1, 1))
    with pytest.raises(InputError, match="distinct"):
        sensitivity_index(At, (0, 8))
    with pytest.raises(InputError, match="error"):
        sensitivity_index(At, (0, 1), error=0.0)
    with pytest.raises(InputError, match="6 rows"):
        sensitivity_index(At[:, :6], (0, 1))


def test_sensitivity_map_is_mirror_symmetric():
    robot = symmetric_robot()
    x = np.array([-0.6, -0.2, 0.2, 0.6])
    y = np.array([-0.4, 0.0, 0.4])
    z = np.array([0.6, 1.0, 1.4])
    kwargs = {"wrench": WEIGHT, "f_min": 5.0, "f_max": 35.0}
    a = sensitivity_map(robot, (0, 3), x, y, z, **kwargs)
    b = sensitivity_map(robot, (1, 2), x, y, z, **kwargs)  # the mirror image of the pair (0, 3)
    assert a.sigma.shape == a.margin.shape == a.feasible.shape == (4, 3, 3)
    assert a.forces.shape == (4, 3, 3, 8)
    assert np.all(np.isfinite(a.sigma)) and np.all(a.sigma > 0)
    assert a.feasible.any()
    np.testing.assert_allclose(a.sigma, b.sigma[::-1], rtol=1e-10)
    np.testing.assert_array_equal(a.feasible, b.feasible[::-1])
    np.testing.assert_allclose(a.forces, b.forces[::-1][..., MIRROR], atol=1e-6)
    np.testing.assert_allclose(a.margin, b.margin[::-1], atol=1e-6)
    # A self-mirrored pair gives a map symmetric in x.
    c = sensitivity_map(robot, (0, 1), x, y, z, **kwargs)
    np.testing.assert_allclose(c.sigma, c.sigma[::-1], rtol=1e-10)
    # Consistent with the per-pose functions and with the margin's meaning.
    At = robot.structure_matrix(a.positions.reshape(-1, 3), np.eye(3))
    np.testing.assert_allclose(a.sigma.ravel(), sensitivity_index(At, (0, 3)), rtol=1e-12)
    f = a.forces.reshape(-1, 8)
    balance = (At @ f[..., None])[..., 0][a.feasible.ravel()]
    np.testing.assert_allclose(balance, np.broadcast_to(-WEIGHT, balance.shape), atol=1e-6)
    k = int(np.argmax(np.where(a.feasible.ravel(), a.margin.ravel(), -np.inf)))
    others = [i for i in range(8) if i not in (0, 3)]
    for d in [(-1, -1), (-1, 1), (1, -1), (1, 1)]:
        g = f[k].copy()
        g[[0, 3]] += d
        g[others] = np.linalg.solve(At[k][:, others], -WEIGHT - At[k][:, [0, 3]] @ g[[0, 3]])
        assert min(g.min() - 5.0, 35.0 - g.max()) >= a.margin.ravel()[k] - 1e-9
    assert 0.0 <= a.fraction_acceptable(1.5) <= 1.0


def test_words_for_numbers_are_named():
    """A string where a number goes gave a bare ValueError; now the argument is named."""
    with pytest.raises(InputError, match=r"delta \(the step of alpha per cycle\) must be finite"):
        switching_cycles("a")
    with pytest.raises(InputError, match=r"cable force f \[N\] must be numbers, got 'a'"):
        friction_torque("a", 0.01)
    with pytest.raises(InputError, match=r"cable velocity v \[m/s\] must be numbers"):
        friction_force(10.0, "fast")
