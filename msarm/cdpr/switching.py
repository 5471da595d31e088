"""Smooth switching of a cable between position and force control: paper 000, eq. 10.

The correction ``Delta l`` of the high-level force controller enters a force-controlled cable's
length command scaled by ``h`` in [0, 1]::

    h = sin^2(alpha +- delta)                                              (10)

Every control cycle (1 ms on the IPAnema 3 Mini's PLC) ``alpha`` moves by ``delta`` towards
``pi/2`` while the force control is being switched on, and towards 0 while it is switched off;
it stops at (is clamped to) ``pi/2`` (``h = 1``) or 0 (``h = 0``). A switch from rest thus
takes ``ceil((pi/2) / delta)`` cycles: 3142 for ``delta = 0.0005``, 79 for 0.02, 4 for 0.5,
the paper's 3142 ms, 79 ms and 4 ms (Sec. 4). To change the force-controlled pair, switch the
new pair on and the old one off in the same cycle.

``alpha`` is kept as its value at the last change of direction plus ``k delta`` after ``k``
steps (not a running sum), so it does not drift and :func:`switching_cycles` counts exactly
the steps :class:`SwitchingFactor` takes.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = [
    "CYCLE_TIME",
    "HALF_PI",
    "SwitchingFactor",
    "scaling_factor",
    "switching_cycles",
    "switching_time",
]

CYCLE_TIME = 1e-3
"""Control cycle of the IPAnema 3 Mini PLC [s] (paper 000, Sec. 2.3)."""
HALF_PI = 0.5 * math.pi
"""alpha at which the force control is fully on (h = 1) [rad]."""


def _check_delta(delta: float) -> float:
    try:
        d = float(delta)
    except (TypeError, ValueError):
        d = math.nan
    if not (math.isfinite(d) and d > 0.0):
        raise InputError(
            f"delta (the step of alpha per cycle) must be finite and > 0 rad, got {delta}"
        )
    return d


def scaling_factor(alpha: ArrayLike) -> FloatArray:
    """The scaling factor h = sin^2(alpha) of eq. 10 [-].

    Args:
        alpha: Switching angle [rad], any shape.

    Returns:
        h in [0, 1], same shape.
    """
    return np.sin(np.asarray(alpha, dtype=np.float64)) ** 2


def _reached(start: float, steps: int, delta: float, up: bool) -> bool:
    """Has alpha, from ``start`` after ``steps`` steps of ``delta``, reached its end?"""
    if up:
        return start + steps * delta >= HALF_PI
    return start - steps * delta <= 0.0


def _steps_to_end(start: float, delta: float, up: bool) -> int:
    """Smallest k >= 0 with alpha at its end after k steps (the test ``SwitchingFactor`` uses)."""
    span = HALF_PI - start if up else start
    k = max(math.ceil(span / delta), 0)
    while k > 0 and _reached(start, k - 1, delta, up):
        k -= 1
    while not _reached(start, k, delta, up):
        k += 1
    return k


def switching_cycles(delta: float) -> int:
    """Cycles for alpha to go from 0 to pi/2 (or back) in steps of delta (eq. 10).

    Args:
        delta: Step of alpha per cycle [rad], > 0.

    Returns:
        The smallest n with ``n delta >= pi/2``: after n cycles h = 1 (or 0).

    Raises:
        InputError: If delta is not finite and > 0.
    """
    return _steps_to_end(0.0, _check_delta(delta), up=True)


def switching_time(delta: float, cycle_time: float = CYCLE_TIME) -> float:
    """Time a full switch takes, ``switching_cycles(delta) * cycle_time`` [s].

    Args:
        delta: Step of alpha per cycle [rad], > 0.
        cycle_time: Control cycle [s], > 0 (1 ms in paper 000).

    Returns:
        Switching time [s].

    Raises:
        InputError: If delta or cycle_time is not finite and > 0.
    """
    if not (math.isfinite(cycle_time) and cycle_time > 0.0):
        raise InputError(f"cycle_time must be finite and > 0 s, got {cycle_time}")
    return switching_cycles(delta) * float(cycle_time)


def _scaling(alpha: float) -> float:
    """The scaling factor h = sin^2(alpha) [-] of a switching angle alpha [rad]."""
    if alpha == HALF_PI:
        return 1.0
    return math.sin(alpha) ** 2


class SwitchingFactor:
    """The scaling factor h of one force-controllable cable, stepped once per control cycle.

    Args:
        delta: Step of alpha per cycle [rad], > 0 (paper 000 uses 0.0005 to 0.5).
        active: Start with the force control fully on (alpha = pi/2, h = 1) instead of off.

    Raises:
        InputError: If delta is not finite and > 0.

    Example:
        >>> s = SwitchingFactor(0.02)
        >>> s.activate()
        >>> hs = [s.step() for _ in range(79)]  # hs[-1] == 1.0
    """

    def __init__(self, delta: float, active: bool = False) -> None:
        self._delta = _check_delta(delta)
        self._active = bool(active)
        self._alpha0 = HALF_PI if active else 0.0
        self._steps = 0

    @property
    def delta(self) -> float:
        """Step of alpha per cycle [rad]."""
        return self._delta

    @property
    def active(self) -> bool:
        """True when alpha moves towards (or sits at) pi/2: force control on or switching on."""
        return self._active

    @property
    def alpha(self) -> float:
        """Current switching angle [rad], in [0, pi/2]."""
        if _reached(self._alpha0, self._steps, self._delta, self._active):
            return HALF_PI if self._active else 0.0
        if self._active:
            return self._alpha0 + self._steps * self._delta
        return self._alpha0 - self._steps * self._delta

    @property
    def h(self) -> float:
        """Current scaling factor h = sin^2(alpha) [-], in [0, 1]."""
        return _scaling(self.alpha)

    @property
    def switching(self) -> bool:
        """True while alpha has not reached its end (pi/2 when active, 0 when not)."""
        return self.alpha != self._end

    @property
    def cycles_left(self) -> int:
        """Steps until alpha reaches its end [cycles]."""
        return max(_steps_to_end(self._alpha0, self._delta, self._active) - self._steps, 0)

    def set_active(self, active: bool) -> None:
        """Switch the force control on (True) or off (False); alpha moves from where it is."""
        if bool(active) == self._active:
            return
        self._alpha0 = self.alpha
        self._steps = 0
        self._active = bool(active)

    def activate(self) -> None:
        """Start switching the force control on (alpha towards pi/2)."""
        self.set_active(True)

    def deactivate(self) -> None:
        """Start switching the force control off (alpha towards 0)."""
        self.set_active(False)

    def step(self) -> float:
        """Advance one control cycle: alpha +- delta, clamped; return the new h [-]."""
        alpha = self.alpha  # switching and h, with alpha computed once per state
        if alpha != self._end:
            self._steps += 1
            alpha = self.alpha
        return _scaling(alpha)

    @property
    def _end(self) -> float:
        """Where alpha is heading [rad]: pi/2 when active, 0 when not."""
        return HALF_PI if self._active else 0.0

    def __repr__(self) -> str:
        return (
            f"SwitchingFactor(delta={self._delta:g}, active={self._active}, alpha={self.alpha:.6g})"
        )
