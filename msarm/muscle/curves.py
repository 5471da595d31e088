"""Normalised Hill-muscle curves of De Groote et al. (2016).

Source: F. De Groote, A. L. Kinney, A. V. Rao, B. J. Fregly, "Evaluation of direct
collocation optimal control problem formulations for solving the muscle redundancy problem",
Annals of Biomedical Engineering 44(10):2922-2936, 2016 (supplementary material, "muscle
model"). The constants below are the published ones, unchanged; this module does not rescale
them, so the curves hit their defining points only to the accuracy of those constants:

==========================  ======================  =========================================
quantity                    value                   note
==========================  ======================  =========================================
``active_force_length(1)``  0.99933...              peak 1.00047 at ``l_norm`` ≈ 1.0136
``force_velocity(0)``       1.00232...              isometric
``force_velocity(-1)``      0.01208...              shortening at the maximum velocity
``force_velocity(1)``       1.78891...              lengthening at the maximum velocity
==========================  ======================  =========================================

Units: every input and output is normalised. Lengths are fibre lengths divided by the optimal
fibre length ``l_M0`` (dimensionless, > 0); velocities are fibre velocities divided by the
maximum contraction velocity ``v_max`` (dimensionless, negative = shortening, positive =
lengthening); forces are divided by the maximum isometric force ``F_max``.

Every function accepts a scalar or a numpy array of any shape and works element-wise; a scalar
(or 0-d array) gives a numpy float, an array gives an array of the same shape. NaN, infinity or
a value outside the documented domain raises :class:`msarm.errors.InputError` naming the
argument, the offending entry and what was expected; nothing is clipped silently.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

__all__ = [
    "ACTIVE_FORCE_LENGTH_COEFFICIENTS",
    "FORCE_VELOCITY_D1",
    "FORCE_VELOCITY_D2",
    "FORCE_VELOCITY_D3",
    "FORCE_VELOCITY_D4",
    "FORCE_VELOCITY_AT_MAX_INVERSE_LENGTHENING",
    "FORCE_VELOCITY_AT_MAX_SHORTENING",
    "MAX_INVERSE_LENGTHENING_VELOCITY",
    "MAX_SHORTENING_VELOCITY",
    "PASSIVE_E0",
    "PASSIVE_KPE",
    "active_force_length",
    "force_velocity",
    "force_velocity_inverse",
    "passive_force_length",
]

FloatArray = NDArray[np.float64]

#: Active force-length constants, one row ``(b1i, b2i, b3i, b4i)`` per Gaussian term
#: ``i = 1, 2, 3`` (De Groote et al. 2016): b11 = 0.815, b21 = 1.055, b31 = 0.162,
#: b41 = 0.063; b12 = 0.433, b22 = 0.717, b32 = -0.030, b42 = 0.200; b13 = 0.100,
#: b23 = 1.000, b33 = 0.354, b43 = 0.000. Shape (3, 4), read-only.
ACTIVE_FORCE_LENGTH_COEFFICIENTS: Final[FloatArray] = np.array(
    [
        [0.815, 1.055, 0.162, 0.063],
        [0.433, 0.717, -0.030, 0.200],
        [0.100, 1.000, 0.354, 0.000],
    ]
)
ACTIVE_FORCE_LENGTH_COEFFICIENTS.setflags(write=False)

#: Passive force-length shape factor kPE (De Groote et al. 2016).
PASSIVE_KPE: Final[float] = 4.0
#: Passive force-length strain e0 at which the passive force equals F_max.
PASSIVE_E0: Final[float] = 0.6

#: Force-velocity constant d1 (De Groote et al. 2016).
FORCE_VELOCITY_D1: Final[float] = -0.318
#: Force-velocity constant d2.
FORCE_VELOCITY_D2: Final[float] = -8.149
#: Force-velocity constant d3.
FORCE_VELOCITY_D3: Final[float] = -0.374
#: Force-velocity constant d4.
FORCE_VELOCITY_D4: Final[float] = 0.886

#: Fastest normalised shortening velocity the curves accept (fibre velocity = -v_max).
MAX_SHORTENING_VELOCITY: Final[float] = -1.0

#: Fastest normalised lengthening velocity :func:`force_velocity_inverse` returns (10 v_max,
#: ten times the end of the fitted range [-1, 1]). The curve rises only logarithmically past
#: +1, so a larger multiplier is no muscle's force at any plausible speed, and the analytic
#: inverse grows exponentially (``f_v = 4`` gives about 1e3 v_max, ``f_v = 40`` overflows).
MAX_INVERSE_LENGTHENING_VELOCITY: Final[float] = 10.0


def _checked_array(value: ArrayLike, name: str) -> FloatArray:
    """Convert ``value`` to a float array and reject NaN and infinities.

    Args:
        value: Scalar or array-like.
        name: Argument name used in error messages.

    Returns:
        A float64 array with the shape of ``value`` (0-d for a scalar).

    Raises:
        InputError: If ``value`` is not numeric or holds a NaN or an infinity.
    """
    if value is None or np.iscomplexobj(value):  # None would read as NaN, complex lose a part
        raise InputError(f"{name} must be a real number or array of them; got {value!r}")
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a real number or array of them; got {value!r}") from exc
    bad = ~np.isfinite(array)
    if np.any(bad):
        index = _first_index(bad)
        where = f" at index {index}" if array.ndim else ""
        raise InputError(f"{name} must be finite; got {float(array[index])!r}{where}")
    return array


def _first_index(mask: NDArray[np.bool_]) -> tuple[int, ...]:
    """Index of the first True entry of a non-empty boolean array.

    Args:
        mask: Boolean array with at least one True entry.

    Returns:
        The multi-index (a tuple, empty for a 0-d array).
    """
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _raise_where(bad: NDArray[np.bool_], array: FloatArray, name: str, expected: str) -> None:
    """Raise an InputError naming the first entry of ``array`` flagged by ``bad``.

    Args:
        bad: Boolean mask, same shape as ``array``.
        array: The checked values.
        name: Argument name used in the message.
        expected: What a valid entry looks like, e.g. ``"> 0"``.

    Raises:
        InputError: If any entry of ``bad`` is True.
    """
    if not np.any(bad):
        return
    index = _first_index(bad)
    where = f" at index {index}" if array.ndim else ""
    raise InputError(f"{name} must be {expected}; got {float(array[index])!r}{where}")


def _scalar_or_array(array: FloatArray) -> FloatArray:
    """Return a numpy float for a 0-d array and the array itself otherwise."""
    return array[()]


def _checked_length(l_norm: ArrayLike, name: str) -> FloatArray:
    """Validate a normalised fibre length: finite and strictly positive."""
    array = _checked_array(l_norm, name)
    _raise_where(array <= 0.0, array, name, "> 0 (a normalised fibre length)")
    return array


def active_force_length(l_norm: ArrayLike) -> FloatArray:
    """Active force-length curve ``f_l`` of De Groote et al. (2016).

    ``f_l(l) = sum_{i=1..3} b1i * exp(-0.5 * (l - b2i)**2 / (b3i + b4i * l)**2)``

    with the constants of :data:`ACTIVE_FORCE_LENGTH_COEFFICIENTS` (b11 = 0.815, b21 = 1.055,
    b31 = 0.162, b41 = 0.063, b12 = 0.433, b22 = 0.717, b32 = -0.030, b42 = 0.200,
    b13 = 0.100, b23 = 1.000, b33 = 0.354, b43 = 0). With these published constants
    ``f_l(1) = 0.99933`` and the peak is 1.00047 at ``l`` ≈ 1.0136 (not exactly 1 at 1). The
    second term's width ``b32 + b42 * l`` vanishes at ``l = 0.15``; the term is taken as its
    limit, 0, there.

    Args:
        l_norm: Normalised fibre length ``l_M / l_M0`` [-], scalar or array of any shape,
            finite and > 0.

    Returns:
        ``f_l`` [-], same shape as ``l_norm`` (a numpy float for a scalar), in (0, 1.0005].

    Raises:
        InputError: If ``l_norm`` holds a NaN, an infinity or a value <= 0.
    """
    length = _checked_length(l_norm, "l_norm")
    total = np.zeros_like(length)
    with np.errstate(divide="ignore"):
        for b1, b2, b3, b4 in ACTIVE_FORCE_LENGTH_COEFFICIENTS:
            total += b1 * np.exp(-0.5 * (length - b2) ** 2 / (b3 + b4 * length) ** 2)
    return _scalar_or_array(total)


def passive_force_length(l_norm: ArrayLike) -> FloatArray:
    """Passive (parallel elastic) force-length curve ``f_PE`` of De Groote et al. (2016).

    ``f_PE(l) = (exp(kPE * (l - 1) / e0) - 1) / (exp(kPE) - 1)`` for ``l > 1`` and
    ``f_PE(l) = 0`` for ``l <= 1``, with kPE = 4 and e0 = 0.6, so ``f_PE(1 + e0) = 1``.

    Region below 1: the published formula is negative for ``l < 1`` (it tends to ``(exp(-kPE / e0) -
    1) / (exp(kPE) - 1)`` ≈ -0.01863 as ``l`` -> 0), i.e. a slack fibre would push. A muscle cannot
    push, so this function returns exactly 0 at and below ``l = 1`` (the passive element's slack
    length). The curve is continuous at 1; its slope jumps there from 0 to ``kPE / (e0 * (exp(kPE) -
    1))`` ≈ 0.1244.

    Args:
        l_norm: Normalised fibre length ``l_M / l_M0`` [-], scalar or array of any shape,
            finite and > 0.

    Returns:
        ``f_PE`` [-], same shape as ``l_norm`` (a numpy float for a scalar), >= 0.

    Raises:
        InputError: If ``l_norm`` holds a NaN, an infinity or a value <= 0.
    """
    length = _checked_length(l_norm, "l_norm")
    stretch = np.maximum(length - 1.0, 0.0)
    raw = np.expm1(PASSIVE_KPE * stretch / PASSIVE_E0) / np.expm1(PASSIVE_KPE)
    return _scalar_or_array(raw)


def _force_velocity_unchecked(v_norm: FloatArray) -> FloatArray:
    """Evaluate the force-velocity formula without validating ``v_norm``."""
    x = FORCE_VELOCITY_D2 * v_norm + FORCE_VELOCITY_D3
    return FORCE_VELOCITY_D1 * np.arcsinh(x) + FORCE_VELOCITY_D4


#: ``force_velocity(-1)`` ≈ 0.01208: the smallest value :func:`force_velocity_inverse` accepts.
FORCE_VELOCITY_AT_MAX_SHORTENING: Final[float] = float(
    _force_velocity_unchecked(np.float64(MAX_SHORTENING_VELOCITY))
)

#: ``force_velocity(10)`` ≈ 2.507: the largest value :func:`force_velocity_inverse` accepts
#: (lengthening at :data:`MAX_INVERSE_LENGTHENING_VELOCITY`).
FORCE_VELOCITY_AT_MAX_INVERSE_LENGTHENING: Final[float] = float(
    _force_velocity_unchecked(np.float64(MAX_INVERSE_LENGTHENING_VELOCITY))
)


def force_velocity(v_norm: ArrayLike) -> FloatArray:
    """Force-velocity curve ``f_v`` of De Groote et al. (2016).

    ``f_v(v) = d1 * log((d2 * v + d3) + sqrt((d2 * v + d3)**2 + 1)) + d4``
    ``= d1 * asinh(d2 * v + d3) + d4``

    with d1 = -0.318, d2 = -8.149, d3 = -0.374, d4 = 0.886. With these published constants
    ``f_v(0) = 1.00232`` (not exactly 1), ``f_v(-1) = 0.01208`` and ``f_v(1) = 1.78891``.
    The curve is strictly increasing.

    Domain: ``v_norm >= -1``. Shortening faster than the maximum contraction velocity is
    rejected, because the formula turns negative (a pushing muscle) just below -1 (at
    ``v_norm`` ≈ -1.0372). Lengthening faster than ``v_max`` is accepted; the curve was fitted
    on [-1, 1] and beyond +1 it keeps rising slowly (``f_v(2)`` ≈ 2.00).

    Args:
        v_norm: Normalised fibre velocity ``v_M / v_max`` [-], negative = shortening, scalar
            or array of any shape, finite and >= -1.

    Returns:
        ``f_v`` [-], same shape as ``v_norm`` (a numpy float for a scalar), >= 0.01208.

    Raises:
        InputError: If ``v_norm`` holds a NaN, an infinity or a value < -1.
    """
    velocity = _checked_array(v_norm, "v_norm")
    _raise_where(
        velocity < MAX_SHORTENING_VELOCITY,
        velocity,
        "v_norm",
        ">= -1 (no shortening faster than the maximum contraction velocity)",
    )
    return _scalar_or_array(_force_velocity_unchecked(velocity))


def force_velocity_inverse(f_v: ArrayLike) -> FloatArray:
    """Analytic inverse of :func:`force_velocity`.

    ``v(f) = (sinh((f - d4) / d1) - d3) / d2`` with the constants of :func:`force_velocity`.

    Args:
        f_v: Force-velocity multiplier [-], scalar or array of any shape, finite, in
            ``[force_velocity(-1), force_velocity(10)]`` ≈ [0.01208, 2.507]
            (:data:`FORCE_VELOCITY_AT_MAX_SHORTENING`,
            :data:`FORCE_VELOCITY_AT_MAX_INVERSE_LENGTHENING`): the range of
            :func:`force_velocity` from shortening at ``v_max`` to lengthening at
            :data:`MAX_INVERSE_LENGTHENING_VELOCITY` ``v_max``.

    Returns:
        Normalised fibre velocity ``v_M / v_max`` [-], negative = shortening, in [-1, 10] up to
        round-off; same shape as ``f_v`` (a numpy float for a scalar).

    Raises:
        InputError: If ``f_v`` holds a NaN, an infinity, a value below ``force_velocity(-1)``
            or above ``force_velocity(10)`` (no plausible lengthening speed gives it; the
            formula would return up to 1e138 or overflow to inf).
    """
    multiplier = _checked_array(f_v, "f_v")
    _raise_where(
        multiplier < FORCE_VELOCITY_AT_MAX_SHORTENING,
        multiplier,
        "f_v",
        f">= force_velocity(-1) = {FORCE_VELOCITY_AT_MAX_SHORTENING:.6g} (the range of the "
        "force-velocity curve)",
    )
    _raise_where(
        multiplier > FORCE_VELOCITY_AT_MAX_INVERSE_LENGTHENING,
        multiplier,
        "f_v",
        f"<= force_velocity({MAX_INVERSE_LENGTHENING_VELOCITY:g}) = "
        f"{FORCE_VELOCITY_AT_MAX_INVERSE_LENGTHENING:.6g} (lengthening at most "
        f"{MAX_INVERSE_LENGTHENING_VELOCITY:g} v_max)",
    )
    velocity = (
        np.sinh((multiplier - FORCE_VELOCITY_D4) / FORCE_VELOCITY_D1) - FORCE_VELOCITY_D3
    ) / FORCE_VELOCITY_D2
    return _scalar_or_array(velocity)
