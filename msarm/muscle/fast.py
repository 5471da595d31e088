"""A compiled fast path of :class:`msarm.muscle.hill.HillMuscles` for control loops.

:class:`FastHill` computes, in one compiled call per tick, each muscle's tendon force at full
activation minus its passive force (``active``) and its passive force (``passive``), from
which capacity, inverse and forward model are one line of arithmetic each:

- ``force_capacity = (passive, passive + active)``;
- ``force(a) = a * active + passive``;
- ``activation_for_force(F) = clip((F - passive) / active, 0, 1)``.

It skips the per-call validation of :class:`HillMuscles` (its inputs come from the
controller's own geometry) except what would make the numbers meaningless: a non-finite MTU
length or speed, or an MTU length at or below the tendon slack length, raises
:class:`msarm.errors.InputError`. The fibre velocity
is limited below at the maximum shortening velocity (callers limit the MTU velocity first;
see ``max_shortening_speed``). A test keeps it equal to :class:`HillMuscles` to round-off.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from msarm.errors import InputError
from msarm.muscle.curves import (
    ACTIVE_FORCE_LENGTH_COEFFICIENTS,
    FORCE_VELOCITY_D1,
    FORCE_VELOCITY_D2,
    FORCE_VELOCITY_D3,
    FORCE_VELOCITY_D4,
    PASSIVE_E0,
    PASSIVE_KPE,
)
from msarm.muscle.hill import MAX_FIBRE_LENGTH, HillMuscles
from msarm.numba_cache import drop_stale_kernels

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = ["FastHill", "hill_parts"]

FloatArray = NDArray[np.float64]


@numba.njit(cache=True)
def hill_parts(
    lengths,
    velocities,
    f_max,
    l_opt,
    l_slack,
    thickness,
    v_max,
    coefficients,
    curve,
    active,
    passive,
):
    """Write active and passive tendon-force parts [N]; return the first bad index or -1.

    A muscle is bad when its MTU length or speed is not finite, its length is not longer
    than its tendon slack length, or its fibre would be longer than
    :data:`~msarm.muscle.hill.MAX_FIBRE_LENGTH` optimal lengths (as :class:`HillMuscles`
    refuses). The compiled kernel of :meth:`FastHill.parts`, also for
    compiled callers: the muscle arrays between ``velocities`` and ``active`` are
    :attr:`FastHill.parameters`.
    """
    d1, d2, d3, d4, kpe, e0 = curve[0], curve[1], curve[2], curve[3], curve[4], curve[5]
    for i in range(lengths.shape[0]):
        along = lengths[i] - l_slack[i]
        if not (along > 0.0 and math.isfinite(along) and math.isfinite(velocities[i])):
            return i
        fiber = math.hypot(along, thickness[i])
        l_norm = fiber / l_opt[i]
        if l_norm > MAX_FIBRE_LENGTH:
            return i
        cos_alpha = along / fiber
        v_norm = velocities[i] * cos_alpha / (v_max[i] * l_opt[i])
        if v_norm < -1.0:
            v_norm = -1.0
        f_l = 0.0
        for k in range(coefficients.shape[0]):
            width = coefficients[k, 2] + coefficients[k, 3] * l_norm
            if width != 0.0:
                f_l += coefficients[k, 0] * math.exp(
                    -0.5 * (l_norm - coefficients[k, 1]) ** 2 / width**2
                )
        stretch = l_norm - 1.0
        f_pe = math.expm1(kpe * stretch / e0) / math.expm1(kpe) if stretch > 0.0 else 0.0
        f_v = d1 * math.asinh(d2 * v_norm + d3) + d4
        scale = f_max[i] * cos_alpha
        active[i] = scale * f_l * f_v
        passive[i] = scale * f_pe
    return -1


class FastHill:
    """Compiled active/passive force parts of a set of Hill muscles (see module docstring).

    Args:
        muscles: The muscles whose parameters to use.
    """

    def __init__(self, muscles: HillMuscles) -> None:
        self.muscles = muscles
        self._f_max = np.array(muscles.max_isometric_force, dtype=float)
        self._l_opt = np.array(muscles.optimal_fiber_length, dtype=float)
        self._l_slack = np.array(muscles.tendon_slack_length, dtype=float)
        self._v_max = np.array(muscles.max_contraction_velocity, dtype=float)
        self._thickness = self._l_opt * np.sin(np.array(muscles.pennation_at_optimal, dtype=float))
        self._coefficients = np.array(ACTIVE_FORCE_LENGTH_COEFFICIENTS, dtype=float)
        self._curve = np.array(
            [
                FORCE_VELOCITY_D1,
                FORCE_VELOCITY_D2,
                FORCE_VELOCITY_D3,
                FORCE_VELOCITY_D4,
                PASSIVE_KPE,
                PASSIVE_E0,
            ],
            dtype=float,
        )
        self.active = np.zeros(len(muscles))
        self.passive = np.zeros(len(muscles))

    @property
    def parameters(self) -> tuple[FloatArray, ...]:
        """The muscle arrays of the compiled kernel, in its order (for compiled callers).

        ``(f_max, l_opt, l_slack, thickness, v_max, coefficients, curve)``: what
        :meth:`parts` passes to the kernel between the MTU speeds and the outputs.
        """
        return (
            self._f_max,
            self._l_opt,
            self._l_slack,
            self._thickness,
            self._v_max,
            self._coefficients,
            self._curve,
        )

    @property
    def max_shortening_speed(self) -> FloatArray:
        """MTU shortening speed at which the fibre reaches ``v_max`` at optimal length [m/s]."""
        return self._v_max * self._l_opt / np.cos(self.muscles.pennation_at_optimal)

    def parts(
        self, mtu_length: FloatArray, mtu_velocity: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Compute ``(active, passive)`` [N], each ``(m,)`` (arrays reused between calls).

        Args:
            mtu_length: MTU lengths [m], shape ``(m,)``.
            mtu_velocity: MTU speeds [m/s], shape ``(m,)`` (lengthening positive).

        Raises:
            InputError: An argument is not of shape ``(m,)``, an MTU length or speed is not
                finite, or a length is not longer than its tendon slack length or stretches
                the fibre past ``MAX_FIBRE_LENGTH`` (argument, muscle and value named).
        """
        m = self.active.shape[0]
        mtu_length = np.asarray(mtu_length, dtype=np.float64)  # a list: not numba's TypingError
        mtu_velocity = np.asarray(mtu_velocity, dtype=np.float64)
        for name, value in (("mtu_length", mtu_length), ("mtu_velocity", mtu_velocity)):
            if np.shape(value) != (m,):
                raise InputError(
                    f"{name} has shape {np.shape(value)}; expected ({m},), one value per muscle"
                )
        bad = hill_parts(mtu_length, mtu_velocity, *self.parameters, self.active, self.passive)
        if bad >= 0:
            raise InputError(self._bad_message(bad, mtu_length, mtu_velocity))
        return self.active, self.passive

    def _bad_message(self, i: int, mtu_length: FloatArray, mtu_velocity: FloatArray) -> str:
        """What is wrong with muscle ``i`` (the kernel's bad index): NaN first, then length."""
        muscle = f"(muscle {self.muscles.names[i]!r})"
        length, speed = float(mtu_length[i]), float(mtu_velocity[i])
        if not math.isfinite(length):
            return f"mtu_length[{i}] {muscle} must be finite, got {length} m"
        if not math.isfinite(speed):
            return f"mtu_velocity[{i}] {muscle} must be finite, got {speed} m/s"
        if length > float(self._l_slack[i]):
            return (
                f"mtu_length[{i}] {muscle} = {length} m stretches its fibre past "
                f"{MAX_FIBRE_LENGTH:g} optimal lengths (the longest the Hill model takes): are "
                "the lengths in metres?"
            )
        return (
            f"mtu_length[{i}] {muscle} = {length} m is not longer than its tendon slack length "
            f"{float(self._l_slack[i])} m (the fibre length would be <= 0)"
        )
