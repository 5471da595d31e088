"""Following-error (FE) model of a CDPR winch drive: paper 000, eq. 8-9.

With a pure proportional drive controller of gain ``K_p`` the motor acts as a torsional
spring: a torque on its shaft shows up as a following error, the difference between the
actual and the commanded cable length. Statically (eq. 8) and in motion (eq. 9)::

    FE(tau, K_p) = c_f tau / K_p                    (8)
    FE(tau, v)   = c_f tau / K_p + c_v v            (9)

Published values (Sec. 2.3): ``c_f = -0.511``, ``c_v = 8.893e-5``, ``K_p = 200``, with FE in m,
the motor torque tau in N m (the paper prints "newtons per meter", a slip for newton metres:
tau is the motor torque of eq. 3) and v in m/min. ``K_p`` is the drive's gain in the drive's
own (undocumented) units; it is taken as a pure number, so ``c_f`` is in m/(N m) and
``c_f / K_p = -2.555e-3 m/(N m)`` (the paper rounds it to -2.55e-3). ``c_v`` is in m per m/min,
i.e. minutes; :func:`c_v_to_si` turns it into seconds (``c_v * 60 = 5.3358e-3 s``).

Sign convention: that of the paper's fit; a positive motor torque gives a negative FE.
Sec. 2.3 defines FE both as "set minus actual motor position" and as "actual minus commanded
cable length"; the published ``c_f`` is kept as is. ``v`` is the cable velocity as in
``msarm.cdpr.winch_friction`` (> 0: paid out).

Eq. 9 is affine in tau with a non-zero slope ``c_f / K_p``, so it inverts exactly:
``tau = K_p (FE - c_v v) / c_f`` (:meth:`FollowingErrorModel.torque`); HC-e uses the forward
direction to turn the wanted torque into the FE set-point.

All public functions take and return SI: tau [N m], v [m/s], FE [m]. The fit covered
``|v| <= 6 m/min`` (0.1 m/s), like the friction model, but eq. 9 is linear in ``v`` and is
evaluated at any finite velocity (only NaN and inf are refused).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = [
    "C_F",
    "C_V_MIN",
    "K_P",
    "PAPER_000_FOLLOWING_ERROR",
    "FollowingErrorModel",
    "c_v_to_si",
    "following_error",
    "torque_from_following_error",
]

SECONDS_PER_MINUTE = 60.0

C_F = -0.511
"""c_f of eq. 8-9 [m/(N m)], with K_p a pure number (paper 000, Sec. 2.3)."""
C_V_MIN = 8.893e-5
"""c_v of eq. 9 as published [m per (m/min)] = [min] (paper 000, Sec. 2.3)."""
K_P = 200.0
"""Proportional gain of the drive used throughout paper 000 [-]."""


def c_v_to_si(c_v_min: float) -> float:
    """Convert c_v from the paper's m per (m/min) to SI, m per (m/s) = s.

    ``c_v v_min = c_v (60 v_s) = (60 c_v) v_s``.

    Args:
        c_v_min: c_v [min].

    Returns:
        c_v [s].
    """
    return float(c_v_min) * SECONDS_PER_MINUTE


def _finite(value: ArrayLike, name: str, unit: str) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} [{unit}] must be finite (got NaN or inf)")
    return arr


@dataclass(frozen=True)
class FollowingErrorModel:
    """Eq. 9 of paper 000 in SI units.

    Attributes:
        c_f: Torque coefficient [m/(N m)] (K_p taken as a pure number); non-zero.
        c_v: Velocity coefficient [s].
        k_p: Proportional gain of the drive [-], > 0.
    """

    c_f: float = C_F
    c_v: float = c_v_to_si(C_V_MIN)
    k_p: float = K_P

    def __post_init__(self) -> None:
        for name in ("c_f", "c_v", "k_p"):
            if not np.isfinite(getattr(self, name)):
                raise InputError(f"{name} must be finite, got {getattr(self, name)}")
        if self.c_f == 0.0:
            raise InputError("c_f must be non-zero (eq. 9 would not depend on the torque)")
        if not self.k_p > 0.0:
            raise InputError(f"k_p must be > 0, got {self.k_p}")

    @property
    def compliance(self) -> float:
        """c_f / K_p [m/(N m)]: FE per unit motor torque (paper: -2.55e-3)."""
        return self.c_f / self.k_p

    def following_error(self, tau: ArrayLike, v: ArrayLike = 0.0) -> FloatArray:
        """FE(tau, v) = c_f tau / K_p + c_v v (eq. 9; eq. 8 when v = 0) [m].

        Args:
            tau: Motor torque [N m], any shape broadcastable with ``v``.
            v: Cable velocity [m/s].

        Returns:
            FE [m], broadcast shape (0-d for scalars).

        Raises:
            InputError: On NaN or inf.
        """
        tau_arr = _finite(tau, "motor torque tau", "N m")
        v_arr = _finite(v, "cable velocity v", "m/s")
        return self.compliance * tau_arr + self.c_v * v_arr

    def torque(self, fe: ArrayLike, v: ArrayLike = 0.0) -> FloatArray:
        """Inverse of eq. 9: tau = K_p (FE - c_v v) / c_f [N m].

        Args:
            fe: Following error [m], any shape broadcastable with ``v``.
            v: Cable velocity [m/s].

        Returns:
            Motor torque [N m], broadcast shape (0-d for scalars).

        Raises:
            InputError: On NaN or inf.
        """
        fe_arr = _finite(fe, "following error", "m")
        v_arr = _finite(v, "cable velocity v", "m/s")
        return (fe_arr - self.c_v * v_arr) / self.compliance


PAPER_000_FOLLOWING_ERROR = FollowingErrorModel()
"""The IPAnema 3 Mini drives of paper 000: c_f = -0.511, c_v = 8.893e-5 min, K_p = 200."""


def following_error(
    tau: ArrayLike, v: ArrayLike = 0.0, model: FollowingErrorModel = PAPER_000_FOLLOWING_ERROR
) -> FloatArray:
    """FE of paper 000, eq. 9 [m]; see :meth:`FollowingErrorModel.following_error`.

    Args:
        tau: Motor torque [N m].
        v: Cable velocity [m/s]; 0 gives the static eq. 8.
        model: The FE model; the paper's by default.

    Returns:
        FE [m], broadcast shape of tau and v.
    """
    return model.following_error(tau, v)


def torque_from_following_error(
    fe: ArrayLike, v: ArrayLike = 0.0, model: FollowingErrorModel = PAPER_000_FOLLOWING_ERROR
) -> FloatArray:
    """Motor torque from the FE, eq. 9 inverted [N m]; see :meth:`FollowingErrorModel.torque`.

    Args:
        fe: Following error [m].
        v: Cable velocity [m/s].
        model: The FE model; the paper's by default.

    Returns:
        Motor torque [N m], broadcast shape of fe and v.
    """
    return model.torque(fe, v)
