"""Size the virtual muscles of a cable robot from its cable travel.

A cable muscle's Hill model needs an optimal fibre length ``l_M0`` and a tendon slack length
``l_Ts`` (see :mod:`msarm.muscle.hill`). For a robot these are design choices: msarm sizes
them so that, over the robot's joint range, every fibre works between two normalised lengths
(by default 0.8 and 1.2 optimal lengths, where the active force-length curve stays above
about 0.79 of its peak). With a rigid tendon and constant-thickness pennation

``l_M(l) = sqrt((l - l_Ts)^2 + (l_M0 sin a0)^2)``,

and asking ``l_M(l_min) = s_lo l_M0`` and ``l_M(l_max) = s_hi l_M0`` gives

``l_M0 = (l_max - l_min) / (sqrt(s_hi^2 - sin^2 a0) - sqrt(s_lo^2 - sin^2 a0))`` and
``l_Ts = l_max - l_M0 sqrt(s_hi^2 - sin^2 a0)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError
from msarm.muscle.hill import MAX_FIBRE_LENGTH

__all__ = ["size_fibres"]


def size_fibres(
    cable_lengths: ArrayLike,
    pennation_at_optimal: ArrayLike,
    span: tuple[float, float] = (0.8, 1.2),
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Optimal fibre and tendon slack lengths that map the cable travel onto ``span``.

    Args:
        cable_lengths: Cable lengths [m] over a set of postures covering the joint range,
            shape ``(k, m)`` (k postures, m cables).
        pennation_at_optimal: Pennation angle at optimal fibre length [rad], shape ``(m,)``.
        span: Normalised fibre lengths ``(s_lo, s_hi)`` at the shortest and longest cable.

    Returns:
        ``(optimal_fiber_length, tendon_slack_length)`` [m], each of shape ``(m,)``.

    Raises:
        InputError: ``cable_lengths`` is not a finite ``(k, m)`` array with ``k >= 2``;
            ``pennation_at_optimal`` is not of shape ``(m,)`` or not in ``[0, pi/2)``;
            ``span`` is not two numbers with ``sin(a0) < s_lo < s_hi <= MAX_FIBRE_LENGTH``
            for every cable; or a cable does not change length over the postures.
    """
    lengths = np.asarray(cable_lengths, dtype=float)
    alpha = np.asarray(pennation_at_optimal, dtype=float)
    if lengths.ndim != 2 or lengths.shape[0] < 2 or not np.all(np.isfinite(lengths)):
        raise InputError(f"cable_lengths must be a finite (k >= 2, m) array, got {lengths.shape}")
    if alpha.shape != lengths.shape[1:]:
        raise InputError(
            f"pennation_at_optimal must have shape {lengths.shape[1:]}, got {alpha.shape}"
        )
    outside = ~((alpha >= 0.0) & (alpha < 0.5 * np.pi))  # NaN included
    if np.any(outside):
        i = int(np.flatnonzero(outside)[0])
        raise InputError(
            f"pennation_at_optimal[{i}] = {float(alpha[i])!r} rad; expected a value in "
            "[0, pi/2), as MuscleParameters takes"
        )
    try:
        s_lo, s_hi = (float(value) for value in span)
    except (TypeError, ValueError) as exc:
        raise InputError(
            f"span must be two numbers (s_lo, s_hi), normalised fibre lengths; got {span!r}"
        ) from exc
    sin2 = np.sin(alpha) ** 2
    if not 0 < s_lo < s_hi <= MAX_FIBRE_LENGTH or np.any(s_lo**2 <= sin2):
        raise InputError(
            f"span must satisfy sin(pennation) < s_lo < s_hi <= {MAX_FIBRE_LENGTH:g} (the "
            "longest fibre the Hill model takes) for every cable (largest sin(pennation) "
            f"{float(np.sqrt(sin2.max(initial=0.0))):.4g}); got {span!r}"
        )
    l_min, l_max = lengths.min(axis=0), lengths.max(axis=0)
    if np.any(l_max - l_min <= 0):
        raise InputError("every cable must change length over the postures given")
    root_hi, root_lo = np.sqrt(s_hi**2 - sin2), np.sqrt(s_lo**2 - sin2)
    optimal = (l_max - l_min) / (root_hi - root_lo)
    return optimal, l_max - optimal * root_hi
