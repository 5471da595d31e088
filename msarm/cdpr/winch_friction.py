"""Dynamic friction of a CDPR winch: paper 000, eq. 4-7 and Table 1.

The motor of cable ``i`` must give (eq. 3) ``tau_i = f_i r_D + tau_F(f_i, v_i) + tau_In(a_i)``;
``tau_F`` [N m] is the friction torque of motor, drum and pulleys, and ``f_F`` [N] the friction
force between the load cell's pulley and the platform (the load cell reads ``f + f_F``). Both
models share one shape (eq. 5 and 7)::

    y(f, v) = c1n v + c2n v^2 + c3n f + c4n        v in [-v_H, -v_L]   (eq. 4, negative)
    y(f, v) = sum_{j=1..4} b_j(f) v^j              v in [-v_L,  v_L]   (eq. 6 polynomial)
    y(f, v) = c1p v + c2p v^2 + c3p f + c4p        v in [ v_L,  v_H]   (eq. 4, positive)

with ``v_L = 0.25 m/min`` and ``v_H = 6 m/min`` the slowest and fastest velocities of the
friction tests. ``v`` is the cable velocity: ``v > 0`` pays the cable out (the cable gets
longer). The paper does not state the sign; it follows from Table 1 and eq. 3: for v > 0
tau_F < 0 (friction brakes the cable the load pulls out, so the motor needs less torque) and
for v < 0 tau_F > 0 (the motor hauls the cable in against friction). ``f >= 0`` is the
cable tension.

The degree-4 polynomial (eq. 6) has five coefficients and five conditions, so it is fully
determined (no extra condition is chosen here): ``p(f, 0) = 0`` (dynamic friction vanishes at
rest, ``b_0 = 0``), ``p(f, +-v_L) = y(f, +-v_L)`` of the outer branches, and
``dp/dv(f, +-v_L) = dy/dv(f, +-v_L)``. The closed form is :func:`blend_coefficients`; its
conditions do not depend on units, so it is applied to the SI coefficients directly.

Units: Table 1 gives the coefficients for ``f`` in N and ``v`` in m/min. They are kept here as
published (``TABLE_1_*``) and converted once to SI by :func:`coefficients_to_si` (only the
velocity terms change: ``c1 * 60``, ``c2 * 3600``). :class:`WinchFrictionModel` holds SI
coefficients, and every public function takes ``v`` in m/s and ``f`` in N.

Outside ``[-v_H, v_H]`` the model was never fitted: by default a velocity beyond ``v_H`` is
refused with an :class:`~msarm.errors.InputError` (the quadratic terms of eq. 4 are not safe
to extrapolate: the negative-direction torque starts to fall again at about -13 m/min). A
model built with ``extrapolate=True`` evaluates eq. 4 there instead. The force ``f`` is not
limited to the tested 2.7-31.3 N (the model is linear in ``f``), only to ``f >= 0``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = [
    "PAPER_000_WINCH_FRICTION",
    "TABLE_1_FORCE_NEGATIVE",
    "TABLE_1_FORCE_POSITIVE",
    "TABLE_1_TORQUE_NEGATIVE",
    "TABLE_1_TORQUE_POSITIVE",
    "V_HIGH_M_PER_MIN",
    "V_LOW_M_PER_MIN",
    "BranchCoefficients",
    "FrictionBranches",
    "WinchFrictionModel",
    "blend_coefficients",
    "coefficients_to_si",
    "friction_force",
    "friction_torque",
    "m_per_min_to_m_per_s",
    "m_per_s_to_m_per_min",
]

SECONDS_PER_MINUTE = 60.0

V_LOW_M_PER_MIN = 0.25
"""v_L, the slowest velocity of the friction tests [m/min] (paper 000, Sec. 2.2)."""
V_HIGH_M_PER_MIN = 6.0
"""v_H, the fastest velocity of the friction tests [m/min] (paper 000, Sec. 2.2)."""

# Table 1 of paper 000, as published: (c1, c2, c3, c4) for f in N and v in m/min.
TABLE_1_TORQUE_POSITIVE = (-3.64e-3, -5.85e-6, -4.66e-4, -2.45e-2)
"""c_ip of the friction torque tau_F [N m] (row 1): c1 [N m min/m], c2 [N m min^2/m^2],
c3 [N m/N], c4 [N m]."""
TABLE_1_TORQUE_NEGATIVE = (-5.97e-3, -2.31e-4, 3.10e-3, 2.52e-2)
"""c_in of the friction torque tau_F [N m] (row 2), units as ``TABLE_1_TORQUE_POSITIVE``."""
TABLE_1_FORCE_POSITIVE = (-1.73e-1, 1.62e-2, -2.51e-2, 2.93e-1)
"""c_ip of the friction force f_F [N] (row 3): c1 [N min/m], c2 [N min^2/m^2], c3 [-],
c4 [N]."""
TABLE_1_FORCE_NEGATIVE = (-1.60e-1, -1.40e-2, 1.25e-1, 1.81e-1)
"""c_in of the friction force f_F [N] (row 4), units as ``TABLE_1_FORCE_POSITIVE``."""


def m_per_min_to_m_per_s(v: ArrayLike) -> FloatArray:
    """Convert a velocity from m/min (the paper's unit) to m/s.

    Args:
        v: Velocity [m/min], any shape.

    Returns:
        Velocity [m/s], same shape.
    """
    return np.asarray(v, dtype=np.float64) / SECONDS_PER_MINUTE


def m_per_s_to_m_per_min(v: ArrayLike) -> FloatArray:
    """Convert a velocity from m/s to m/min (the paper's unit).

    Args:
        v: Velocity [m/s], any shape.

    Returns:
        Velocity [m/min], same shape.
    """
    return np.asarray(v, dtype=np.float64) * SECONDS_PER_MINUTE


@dataclass(frozen=True)
class BranchCoefficients:
    """Coefficients of eq. 4 for one motion direction, in SI units.

    ``y = c1 v + c2 v^2 + c3 f + c4`` with ``v`` [m/s] and ``f`` [N]; ``y`` is a torque
    [N m] or a force [N] (called "out" below).

    Attributes:
        c1: Linear velocity coefficient [out s/m].
        c2: Quadratic velocity coefficient [out s^2/m^2].
        c3: Force coefficient [out/N].
        c4: Constant [out].
    """

    c1: float
    c2: float
    c3: float
    c4: float

    def __post_init__(self) -> None:
        values = (self.c1, self.c2, self.c3, self.c4)
        if not all(np.isfinite(values)):
            raise InputError(f"friction coefficients must be finite, got {values}")

    def value(self, f: FloatArray, v: FloatArray) -> FloatArray:
        """Eq. 4 at (f [N], v [m/s]), broadcast; [out]."""
        return self.c1 * v + self.c2 * v * v + self.c3 * f + self.c4

    def slope(self, v: FloatArray) -> FloatArray:
        """d(eq. 4)/dv at v [m/s]; [out s/m] (independent of f)."""
        return self.c1 + 2.0 * self.c2 * v


def coefficients_to_si(paper_coefficients: tuple[float, float, float, float]) -> BranchCoefficients:
    """Convert eq. 4 coefficients from the paper's units (f in N, v in m/min) to SI.

    With ``v_min = 60 v_s``: ``c1 v_min = (60 c1) v_s`` and ``c2 v_min^2 = (3600 c2) v_s^2``;
    ``c3`` and ``c4`` do not involve the velocity and are unchanged.

    Args:
        paper_coefficients: ``(c1, c2, c3, c4)`` as in Table 1 of paper 000.

    Returns:
        The same branch with ``v`` in m/s.

    Raises:
        InputError: If there are not four finite coefficients.
    """
    if len(paper_coefficients) != 4:
        raise InputError(f"expected 4 coefficients (c1, c2, c3, c4), got {paper_coefficients}")
    c1, c2, c3, c4 = (float(c) for c in paper_coefficients)
    s = SECONDS_PER_MINUTE
    return BranchCoefficients(c1 * s, c2 * s * s, c3, c4)


def blend_coefficients(
    value_negative: ArrayLike,
    value_positive: ArrayLike,
    slope_negative: ArrayLike,
    slope_positive: ArrayLike,
    v_low: float,
) -> FloatArray:
    """Coefficients b_0..b_4 of the eq. 6 polynomial p(v) = sum_j b_j v^j.

    The unique quartic with ``p(0) = 0``, ``p(-v_L) = value_negative``,
    ``p(v_L) = value_positive``, ``p'(-v_L) = slope_negative``, ``p'(v_L) = slope_positive``
    (paper 000, eq. 6, with tau_vn, tau_vp, d tau_vn, d tau_vp). Any consistent units.

    Args:
        value_negative: y(f, -v_L), any shape (broadcast with the others).
        value_positive: y(f, v_L).
        slope_negative: dy/dv(f, -v_L).
        slope_positive: dy/dv(f, v_L).
        v_low: v_L > 0, same velocity unit as the slopes.

    Returns:
        Shape (5, ...): b_0 (zero), b_1, b_2, b_3, b_4 along the first axis.

    Raises:
        InputError: If ``v_low`` is not > 0.
    """
    yn, yp, dn, dp = np.broadcast_arrays(
        *(
            np.asarray(a, dtype=np.float64)
            for a in (value_negative, value_positive, slope_negative, slope_positive)
        )
    )
    L = float(v_low)
    if not L > 0.0:
        raise InputError(f"v_low must be > 0, got {v_low}")
    b0 = np.zeros_like(yn)
    b1 = -(3.0 * (yn - yp) + L * (dn + dp)) / (4.0 * L)
    b2 = (4.0 * (yn + yp) + L * (dn - dp)) / (4.0 * L**2)
    b3 = (yn - yp + L * (dn + dp)) / (4.0 * L**3)
    b4 = -(2.0 * (yn + yp) + L * (dn - dp)) / (4.0 * L**4)
    return np.stack([b0, b1, b2, b3, b4])


@dataclass(frozen=True)
class FrictionBranches:
    """The two outer branches of one friction model (eq. 5 or eq. 7), SI.

    Attributes:
        negative: Coefficients for ``v in [-v_H, -v_L]`` (c_in).
        positive: Coefficients for ``v in [v_L, v_H]`` (c_ip).
    """

    negative: BranchCoefficients
    positive: BranchCoefficients

    @classmethod
    def from_paper_units(
        cls,
        negative: tuple[float, float, float, float],
        positive: tuple[float, float, float, float],
    ) -> FrictionBranches:
        """Build from Table 1 style coefficients (f in N, v in m/min)."""
        return cls(coefficients_to_si(negative), coefficients_to_si(positive))

    def polynomial(self, f: FloatArray, v_low: float) -> FloatArray:
        """b_0..b_4 of eq. 6 at the forces f [N]: shape (5, *f.shape), v in m/s."""
        vl = np.float64(v_low)
        return blend_coefficients(
            self.negative.value(f, -vl),
            self.positive.value(f, vl),
            self.negative.slope(-vl),
            self.positive.slope(vl),
            v_low,
        )

    def evaluate(self, f: FloatArray, v: FloatArray, v_low: float) -> FloatArray:
        """Eq. 5/7 at broadcast-equal arrays f [N] and v [m/s] (no validation).

        The eq. 6 polynomial's b_1..b_4 as :meth:`polynomial` gives them, the same floating
        point operations, with its f-independent parts computed once per (branches, v_low).
        """
        c3n, c4n, c3p, c4p, sn, sp, k1, k2, d1, d2, d3, d4 = _blend_constants(self, v_low)
        yn = sn + c3n * f + c4n
        yp = sp + c3p * f + c4p
        b1 = -(3.0 * (yn - yp) + k1) / d1
        b2 = (4.0 * (yn + yp) + k2) / d2
        b3 = (yn - yp + k1) / d3
        b4 = -(2.0 * (yn + yp) + k2) / d4
        inner = v * (b1 + v * (b2 + v * (b3 + v * b4)))
        out = np.where(v < 0.0, self.negative.value(f, v), self.positive.value(f, v))
        return np.where(np.abs(v) < v_low, inner, out)


@functools.lru_cache(maxsize=64)
def _blend_constants(branches: FrictionBranches, v_low: float) -> tuple[Any, ...]:
    """The f-independent parts of :meth:`FrictionBranches.polynomial`, for ``evaluate``.

    Computed as :func:`blend_coefficients` computes them from the branch values (same
    operations, same types): ``(c3n, c4n, c3p, c4p, sn, sp, k1, k2, d1, d2, d3, d4)`` with
    ``y(f, -+v_L) = s + c3 f + c4``, ``k1 = L (dn + dp)``, ``k2 = L (dn - dp)`` and the
    denominators ``4 L``, ``4 L^2``, ``4 L^3``, ``4 L^4``.
    """
    neg, pos = branches.negative, branches.positive
    vl = np.float64(v_low)
    sn = neg.c1 * -vl + neg.c2 * -vl * -vl
    sp = pos.c1 * vl + pos.c2 * vl * vl
    dn = np.asarray(neg.slope(-vl), dtype=np.float64)
    dp = np.asarray(pos.slope(vl), dtype=np.float64)
    L = float(v_low)
    k1 = L * (dn + dp)
    k2 = L * (dn - dp)
    return (
        neg.c3,
        neg.c4,
        pos.c3,
        pos.c4,
        sn,
        sp,
        k1,
        k2,
        4.0 * L,
        4.0 * L**2,
        4.0 * L**3,
        4.0 * L**4,
    )


def _check_speed(v_low: float, v_high: float) -> None:
    if not (np.isfinite(v_low) and np.isfinite(v_high) and 0.0 < v_low < v_high):
        raise InputError(
            f"need 0 < v_low < v_high [m/s], finite; got v_low={v_low}, v_high={v_high}"
        )


@dataclass(frozen=True)
class WinchFrictionModel:
    """Friction torque (eq. 5) and friction force (eq. 7) of one winch, SI inside.

    The default instance :data:`PAPER_000_WINCH_FRICTION` holds Table 1; build another with
    :meth:`from_paper_units` (coefficients in the paper's units) or directly with SI
    :class:`FrictionBranches`, and give it to a plant or controller.

    Attributes:
        torque_branches: Outer branches of tau_F [N m] (Table 1 rows 1-2, SI).
        force_branches: Outer branches of f_F [N] (Table 1 rows 3-4, SI).
        v_low: v_L [m/s], the edge of the eq. 6 polynomial.
        v_high: v_H [m/s], the fastest velocity the model was fitted at.
        extrapolate: If True, eq. 4 is also used beyond ``+-v_high``; if False (default), a
            velocity beyond ``v_high`` raises ``InputError``.
    """

    torque_branches: FrictionBranches
    force_branches: FrictionBranches
    v_low: float = field(default_factory=lambda: float(m_per_min_to_m_per_s(V_LOW_M_PER_MIN)))
    v_high: float = field(default_factory=lambda: float(m_per_min_to_m_per_s(V_HIGH_M_PER_MIN)))
    extrapolate: bool = False

    def __post_init__(self) -> None:
        _check_speed(self.v_low, self.v_high)

    @classmethod
    def from_paper_units(
        cls,
        torque_negative: tuple[float, float, float, float] = TABLE_1_TORQUE_NEGATIVE,
        torque_positive: tuple[float, float, float, float] = TABLE_1_TORQUE_POSITIVE,
        force_negative: tuple[float, float, float, float] = TABLE_1_FORCE_NEGATIVE,
        force_positive: tuple[float, float, float, float] = TABLE_1_FORCE_POSITIVE,
        *,
        v_low_m_per_min: float = V_LOW_M_PER_MIN,
        v_high_m_per_min: float = V_HIGH_M_PER_MIN,
        extrapolate: bool = False,
    ) -> WinchFrictionModel:
        """Build a model from coefficients in the units of Table 1 (f in N, v in m/min).

        Args:
            torque_negative: (c1n, c2n, c3n, c4n) of tau_F [N m].
            torque_positive: (c1p, c2p, c3p, c4p) of tau_F [N m].
            force_negative: (c1n, c2n, c3n, c4n) of f_F [N].
            force_positive: (c1p, c2p, c3p, c4p) of f_F [N].
            v_low_m_per_min: v_L [m/min].
            v_high_m_per_min: v_H [m/min].
            extrapolate: See the class attribute.

        Returns:
            The model, with every coefficient and speed converted to SI.
        """
        return cls(
            FrictionBranches.from_paper_units(torque_negative, torque_positive),
            FrictionBranches.from_paper_units(force_negative, force_positive),
            v_low=float(m_per_min_to_m_per_s(v_low_m_per_min)),
            v_high=float(m_per_min_to_m_per_s(v_high_m_per_min)),
            extrapolate=extrapolate,
        )

    def _inputs(self, f: ArrayLike, v: ArrayLike) -> tuple[FloatArray, FloatArray]:
        try:
            f_arr = np.asarray(f, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"cable force f [N] must be numbers, got {f!r}") from None
        try:
            v_arr = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"cable velocity v [m/s] must be numbers, got {v!r}") from None
        if f_arr.shape == v_arr.shape and f_arr.ndim == 1 and self._fast_ok(f_arr, v_arr):
            return f_arr, v_arr  # what the checks below return for them
        try:
            f_arr, v_arr = np.broadcast_arrays(f_arr, v_arr)
        except ValueError as err:
            raise InputError(
                f"f {f_arr.shape} and v {v_arr.shape} must broadcast to one shape"
            ) from err
        if not np.all(np.isfinite(f_arr)):
            raise InputError("cable force f [N] must be finite (got NaN or inf)")
        if not np.all(np.isfinite(v_arr)):
            raise InputError("cable velocity v [m/s] must be finite (got NaN or inf)")
        if np.any(f_arr < 0.0):
            raise InputError(f"cable force f must be >= 0 N (a tension), min is {f_arr.min()}")
        if not self.extrapolate:
            # Relative slack for round-off of a velocity converted from 6 m/min.
            limit = self.v_high * (1.0 + 1e-12)
            v_abs = np.abs(v_arr)
            if np.any(v_abs > limit):
                raise InputError(
                    f"cable velocity |v| = {v_abs.max():.6g} m/s "
                    f"({float(m_per_s_to_m_per_min(v_abs.max())):.6g} m/min) is beyond "
                    f"v_H = {self.v_high:.6g} m/s, where the friction model was not fitted; "
                    "build the model with extrapolate=True to use eq. 4 there"
                )
        return f_arr, v_arr

    def _fast_ok(self, f: FloatArray, v: FloatArray) -> bool:
        """Whether 1-d f [N] and v [m/s] surely pass ``_inputs``'s checks (scalar loop).

        False sends them through the checks, which raise their errors or let them pass.
        """
        limit = math.inf if self.extrapolate else self.v_high * (1.0 + 1e-12)
        for fi, vi in zip(f.tolist(), v.tolist(), strict=True):
            if not (0.0 <= fi < math.inf and abs(vi) <= limit and math.isfinite(vi)):
                return False
        return True

    def torque(self, f: ArrayLike, v: ArrayLike) -> FloatArray:
        """Friction torque tau_F(f, v) of eq. 5 [N m].

        Args:
            f: Cable tension [N], >= 0, any shape broadcastable with ``v``.
            v: Cable velocity [m/s] (> 0: cable paid out), within ``+-v_high`` unless the
                model extrapolates.

        Returns:
            tau_F [N m], the broadcast shape (0-d for scalars). It enters eq. 3 as
            ``tau = f r_D + tau_F + tau_In``.

        Raises:
            InputError: On NaN/inf, a negative tension, shapes that do not broadcast, or
                ``|v| > v_high`` without ``extrapolate``.
        """
        f_arr, v_arr = self._inputs(f, v)
        return self.torque_branches.evaluate(f_arr, v_arr, self.v_low)

    def force(self, f: ArrayLike, v: ArrayLike) -> FloatArray:
        """Friction force f_F(f, v) of eq. 7 [N] (load cell pulley to platform).

        Args:
            f: Cable tension [N], >= 0, any shape broadcastable with ``v``.
            v: Cable velocity [m/s] (> 0: cable paid out), within ``+-v_high`` unless the
                model extrapolates.

        Returns:
            f_F [N], the broadcast shape (0-d for scalars).

        Raises:
            InputError: As :meth:`torque`.
        """
        f_arr, v_arr = self._inputs(f, v)
        return self.force_branches.evaluate(f_arr, v_arr, self.v_low)

    def torque_polynomial(self, f: ArrayLike) -> FloatArray:
        """b_0..b_4 of the eq. 6 polynomial of tau_F at the forces f [N].

        Args:
            f: Cable tension [N], any shape.

        Returns:
            Shape (5, *f.shape); b_j in [N m (s/m)^j] (v in m/s).
        """
        f_arr, _ = self._inputs(f, 0.0)
        return self.torque_branches.polynomial(f_arr, self.v_low)

    def force_polynomial(self, f: ArrayLike) -> FloatArray:
        """b_0..b_4 of the eq. 6 polynomial of f_F at the forces f [N].

        Args:
            f: Cable tension [N], any shape.

        Returns:
            Shape (5, *f.shape); b_j in [N (s/m)^j] (v in m/s).
        """
        f_arr, _ = self._inputs(f, 0.0)
        return self.force_branches.polynomial(f_arr, self.v_low)


PAPER_000_WINCH_FRICTION = WinchFrictionModel.from_paper_units()
"""The IPAnema 3 Mini winch of paper 000 (Table 1), v_L = 0.25 m/min, v_H = 6 m/min."""


def friction_torque(
    f: ArrayLike, v: ArrayLike, model: WinchFrictionModel = PAPER_000_WINCH_FRICTION
) -> FloatArray:
    """Friction torque tau_F(f, v) of paper 000, eq. 5 [N m]; see :meth:`WinchFrictionModel.torque`.

    Args:
        f: Cable tension [N], >= 0.
        v: Cable velocity [m/s] (> 0: cable paid out).
        model: The friction model; Table 1 by default.

    Returns:
        tau_F [N m], broadcast shape of f and v.
    """
    return model.torque(f, v)


def friction_force(
    f: ArrayLike, v: ArrayLike, model: WinchFrictionModel = PAPER_000_WINCH_FRICTION
) -> FloatArray:
    """Friction force f_F(f, v) of paper 000, eq. 7 [N]; see :meth:`WinchFrictionModel.force`.

    Args:
        f: Cable tension [N], >= 0.
        v: Cable velocity [m/s] (> 0: cable paid out).
        model: The friction model; Table 1 by default.

    Returns:
        f_F [N], broadcast shape of f and v.
    """
    return model.force(f, v)
