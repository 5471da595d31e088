"""The sheath stage's tick compiled (numba): one kernel for the Python loop and the compiled one.

:class:`msarm.compensation.sheath.SheathInverse` calls :func:`sheath_tick` every control
tick, and so does the compiled closed loop of :mod:`msarm.tasks.compiled_loop`: both give the
same bits. The kernel evaluates the stage's formulas (module docstring of
:mod:`msarm.compensation.sheath`) element by element, in the order of the NumPy expressions
they stand for, with no fused multiply-add (``fastmath`` is off). ``exp`` is the C library's
(NumPy's own vectorised ``exp`` may differ from it in the last bit).

This module imports numba and NumPy only: the compiled loop imports it without torch.
"""

from __future__ import annotations

import numba
import numpy as np

from msarm.control.kernels import _clip, _maximum
from msarm.numba_cache import drop_stale_kernels

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = ["sheath_tick"]


@numba.njit(cache=True, error_model="numpy")
def sheath_tick(
    force, lengths, wrap, alpha, stretch, width, friction, floor, state, command
):  # pragma: no cover - compiled
    """One tick of the sheath stage, in place.

    Args:
        force: The tension the controller wants at the insertions [N], ``(m,)``.
        lengths: Nominal cable lengths at the reference posture [m], ``(m,)``.
        wrap: Wrap angles at the reference posture [rad], ``(m,)``.
        alpha: The low-pass's weight of the new value, ``period / (filter_time + period)``.
        stretch: Compliance of the cable beyond the sheath, ``c_s`` [m/N].
        width: Cable travel ``w`` over which the friction turns over [m].
        friction: ``g mu`` [-].
        floor: Lowest command [N] (0: none).
        state: ``(4, m)``, updated: the filtered tension ``F_bar`` [N], the cable pulled
            through the sheath at the last tick ``u`` [m], the side ``s`` [-], and in row 3
            (column 0) 1.0 once the stage has run a tick since its reset (0.0 before).
        command: The drives' command [N], ``(m,)``, written.
    """
    filtered, previous, side = state[0], state[1], state[2]
    first = state[3, 0] == 0.0
    for i in range(force.shape[0]):
        if first:
            filtered[i] = force[i]
            side[i] = 0.0
        else:
            filtered[i] = filtered[i] + alpha * (force[i] - filtered[i])
        pulled = stretch * filtered[i] - lengths[i]
        if not first:
            side[i] = _clip(side[i] + (pulled - previous[i]) / width, -1.0, 1.0)
        previous[i] = pulled
        value = force[i] * np.exp(friction * wrap[i] * side[i])
        command[i] = _maximum(value, floor) if floor > 0 else value
    state[3, 0] = 1.0
