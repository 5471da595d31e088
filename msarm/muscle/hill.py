"""Hill-type muscle-tendon units: forward (eq. 14) and inverse models of paper 003.

Paper 003, section 2.3, gives the normalised tendon force of a muscle-tendon unit (MTU) as

``F_T = (a f_l(l_M) f_v(v_M) + f_PE(l_M)) cos(alpha)``                       (eq. 14)

and, solved for the fibre velocity, the forward-dynamics form

``v_M = f_v^-1((F_T / cos(alpha) - f_PE(l_M)) / (a f_l(l_M)))``                 (eq. 15)

with the curves of :mod:`msarm.muscle.curves`. Here forces are in newtons (the normalised
force times the maximum isometric force ``F_max``).

Tendon and pennation: the tendon is rigid (its length is always the tendon slack length
``l_Ts``) and the muscle keeps a constant thickness, so with the MTU length ``l_MT``:

- ``l_M cos(alpha) = l_MT - l_Ts`` and ``l_M sin(alpha) = l_M0 sin(alpha_0)``, hence
  ``l_M = sqrt((l_MT - l_Ts)**2 + (l_M0 sin(alpha_0))**2)``;
- differentiating, the fibre velocity is ``v_M = v_MT cos(alpha)``.

An elastic tendon is not modelled yet. Normalisation: ``l_norm = l_M / l_M0`` and
``v_norm = v_M / (v_max l_M0)`` with ``v_max`` in optimal fibre lengths per second. Velocities
are negative when the fibre (or MTU) shortens.

All methods of :class:`HillMuscles` take and return arrays of shape ``(m,)``, one entry per
muscle in the order of the parameters given to the constructor.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError
from msarm.muscle.curves import (
    FORCE_VELOCITY_AT_MAX_INVERSE_LENGTHENING,
    FORCE_VELOCITY_AT_MAX_SHORTENING,
    MAX_INVERSE_LENGTHENING_VELOCITY,
    MAX_SHORTENING_VELOCITY,
    FloatArray,
    active_force_length,
    force_velocity,
    force_velocity_inverse,
    passive_force_length,
)

__all__ = ["MAX_FIBRE_LENGTH", "FiberState", "HillMuscles", "MuscleParameters"]

#: Longest normalised fibre length ``l_M / l_M0`` the model accepts: the passive force is
#: already about 400 ``F_max`` there (a torn fibre), and overflows to inf past about 100.
MAX_FIBRE_LENGTH = 2.5

#: Normalised fibre velocities this far below -1 are round-off and are taken as -1.
_VELOCITY_ROUNDOFF = 1e-12
#: Relative tolerance (of F_max) of the reachability test in :meth:`activation_for_force`.
_FORCE_ROUNDOFF = 1e-12


@dataclass(frozen=True)
class MuscleParameters:
    """Parameters of one muscle-tendon unit.

    Attributes:
        name: Muscle name, non-empty (used in error messages and as the array label).
        max_isometric_force: Maximum isometric force ``F_max`` [N], > 0.
        optimal_fiber_length: Optimal fibre length ``l_M0`` [m], > 0.
        tendon_slack_length: Tendon slack length ``l_Ts`` [m], > 0.
        max_contraction_velocity: Maximum contraction velocity ``v_max`` [optimal fibre
            lengths per second, l_M0/s], > 0; 10 is the usual value.
        pennation_at_optimal: Pennation angle ``alpha_0`` at the optimal fibre length [rad],
            in [0, pi/2).

    Raises:
        InputError: If a field has the wrong type or is outside its range.
    """

    name: str
    max_isometric_force: float
    optimal_fiber_length: float
    tendon_slack_length: float
    max_contraction_velocity: float = 10.0
    pennation_at_optimal: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"MuscleParameters.name must be a non-empty str; got {self.name!r}")
        for field, unit in (
            ("max_isometric_force", "N"),
            ("optimal_fiber_length", "m"),
            ("tendon_slack_length", "m"),
            ("max_contraction_velocity", "l_M0/s"),
        ):
            value = self._real(field)
            if not math.isfinite(value) or value <= 0.0:
                raise InputError(
                    f"muscle {self.name!r}: {field} must be a finite number > 0 [{unit}]; "
                    f"got {value!r}"
                )
            object.__setattr__(self, field, value)
        pennation = self._real("pennation_at_optimal")
        if not (0.0 <= pennation < math.pi / 2):
            raise InputError(
                f"muscle {self.name!r}: pennation_at_optimal must be in [0, pi/2) [rad]; "
                f"got {pennation!r}"
            )
        object.__setattr__(self, "pennation_at_optimal", pennation)

    def _real(self, field: str) -> float:
        """Return the field ``field`` as a float, rejecting non-numbers and booleans."""
        value = getattr(self, field)
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise InputError(f"muscle {self.name!r}: {field} must be a real number; got {value!r}")
        return float(value)


class FiberState(NamedTuple):
    """Fibre state of every muscle, each field of shape ``(m,)``.

    Attributes:
        length_norm: Normalised fibre length ``l_M / l_M0`` [-].
        velocity_norm: Normalised fibre velocity ``v_M / (v_max l_M0)`` [-], negative =
            shortening, >= -1.
        cos_pennation: Cosine of the pennation angle ``cos(alpha)`` [-], in (0, 1].
    """

    length_norm: FloatArray
    velocity_norm: FloatArray
    cos_pennation: FloatArray


def _read_only(values: Sequence[float]) -> FloatArray:
    """A read-only float64 array of ``values``."""
    array = np.array(values, dtype=np.float64)
    array.setflags(write=False)
    return array


class HillMuscles:
    """Forward and inverse Hill models of ``m`` muscle-tendon units, vectorised.

    Rigid tendon, constant-thickness pennation and the De Groote et al. (2016) curves; see
    the module docstring for the equations.

    Args:
        params: One :class:`MuscleParameters` per muscle (m >= 1, unique names); the order
            fixes the order of every array.

    Raises:
        InputError: If ``params`` is empty, holds something else than
            :class:`MuscleParameters`, or repeats a name.
    """

    def __init__(self, params: Sequence[MuscleParameters]) -> None:
        params = tuple(params)
        if not params:
            raise InputError("params must hold at least one MuscleParameters; got none")
        for index, item in enumerate(params):
            if not isinstance(item, MuscleParameters):
                raise InputError(
                    f"params[{index}] must be a MuscleParameters; got {type(item).__name__}"
                )
        names = tuple(p.name for p in params)
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise InputError(f"muscle names must be unique; repeated: {repeated}")
        self._params = params
        self._names = names
        self._f_max = _read_only([p.max_isometric_force for p in params])
        self._l_opt = _read_only([p.optimal_fiber_length for p in params])
        self._l_slack = _read_only([p.tendon_slack_length for p in params])
        self._v_max = _read_only([p.max_contraction_velocity for p in params])
        self._alpha_0 = _read_only([p.pennation_at_optimal for p in params])
        self._thickness = self._l_opt * np.sin(self._alpha_0)

    @classmethod
    def from_arrays(
        cls,
        names: Sequence[str],
        max_isometric_force: ArrayLike,
        optimal_fiber_length: ArrayLike,
        tendon_slack_length: ArrayLike,
        max_contraction_velocity: ArrayLike = 10.0,
        pennation_at_optimal: ArrayLike = 0.0,
    ) -> HillMuscles:
        """Build from per-muscle arrays (scalars are used for every muscle).

        Args:
            names: Muscle names, length ``m``.
            max_isometric_force: ``F_max`` [N], shape ``(m,)`` or scalar.
            optimal_fiber_length: ``l_M0`` [m], shape ``(m,)`` or scalar.
            tendon_slack_length: ``l_Ts`` [m], shape ``(m,)`` or scalar.
            max_contraction_velocity: ``v_max`` [l_M0/s], shape ``(m,)`` or scalar.
            pennation_at_optimal: ``alpha_0`` [rad], shape ``(m,)`` or scalar.

        Returns:
            The muscles.

        Raises:
            InputError: If an array has another shape or a value is invalid.
        """
        if isinstance(names, str):
            raise InputError(f"names must be a sequence of str, not one str; got {names!r}")
        names = list(names)
        columns = {
            "max_isometric_force": max_isometric_force,
            "optimal_fiber_length": optimal_fiber_length,
            "tendon_slack_length": tendon_slack_length,
            "max_contraction_velocity": max_contraction_velocity,
            "pennation_at_optimal": pennation_at_optimal,
        }
        arrays = {}
        for key, value in columns.items():
            try:
                array = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise InputError(f"{key} must be real numbers; got {value!r}") from exc
            if array.shape not in ((), (len(names),)):
                raise InputError(
                    f"{key} must be a scalar or have shape ({len(names)},) (one value per "
                    f"name); got shape {array.shape}"
                )
            arrays[key] = np.broadcast_to(array, (len(names),))
        return cls(
            [
                MuscleParameters(name, **{key: float(arrays[key][i]) for key in arrays})
                for i, name in enumerate(names)
            ]
        )

    def __len__(self) -> int:
        return len(self._params)

    def __repr__(self) -> str:
        return f"HillMuscles({list(self._names)!r})"

    @property
    def names(self) -> tuple[str, ...]:
        """Muscle names, in array order."""
        return self._names

    @property
    def params(self) -> tuple[MuscleParameters, ...]:
        """Per-muscle parameters, in array order."""
        return self._params

    @property
    def max_isometric_force(self) -> FloatArray:
        """``F_max`` [N], shape ``(m,)``, read-only."""
        return self._f_max

    @property
    def optimal_fiber_length(self) -> FloatArray:
        """``l_M0`` [m], shape ``(m,)``, read-only."""
        return self._l_opt

    @property
    def tendon_slack_length(self) -> FloatArray:
        """``l_Ts`` [m], shape ``(m,)``, read-only."""
        return self._l_slack

    @property
    def max_contraction_velocity(self) -> FloatArray:
        """``v_max`` [l_M0/s], shape ``(m,)``, read-only."""
        return self._v_max

    @property
    def pennation_at_optimal(self) -> FloatArray:
        """``alpha_0`` [rad], shape ``(m,)``, read-only."""
        return self._alpha_0

    # ------------------------------------------------------------------ validation

    def _fail(
        self, bad: NDArray[np.bool_], array: FloatArray, name: str, unit: str, expected: str
    ) -> None:
        """Raise an InputError naming the first muscle flagged by ``bad``."""
        if not np.any(bad):
            return
        i = int(np.flatnonzero(bad)[0])
        value = f"{float(array[i])} {unit}" if unit else f"{float(array[i])}"
        raise InputError(f"{name}[{i}] (muscle {self._names[i]!r}) = {value}; expected {expected}")

    def _per_muscle(self, value: ArrayLike, name: str, unit: str) -> FloatArray:
        """Validate a per-muscle input: shape ``(m,)`` and finite.

        Args:
            value: The input.
            name: Argument name used in error messages.
            unit: Unit used in error messages.

        Returns:
            A float64 array of shape ``(m,)``.

        Raises:
            InputError: On ``None``, a wrong shape, a non-numeric or complex value, a NaN or an
                infinity.
        """
        if value is None:
            raise InputError(
                f"{name} must be an array of shape ({len(self)},), one value per muscle "
                f"{list(self._names)}; got None"
            )
        if np.iscomplexobj(value):
            raise InputError(
                f"{name} must be real numbers; got complex values (dtype "
                f"{np.asarray(value).dtype}), whose imaginary part would be lost"
            )
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name} must be an array of real numbers; got {value!r}") from exc
        if array.shape != (len(self),):
            raise InputError(
                f"{name} must have shape ({len(self)},), one value per muscle "
                f"{list(self._names)}; got shape {array.shape}"
            )
        self._fail(~np.isfinite(array), array, name, unit, "a finite number")
        return array

    def _activation(self, value: ArrayLike) -> FloatArray:
        """Validate a per-muscle activation in [0, 1]."""
        array = self._per_muscle(value, "activation", "")
        self._fail((array < 0.0) | (array > 1.0), array, "activation", "", "a value in [0, 1]")
        return array

    def _mtu_length(self, value: ArrayLike) -> FloatArray:
        """Validate MTU lengths: positive and longer than the tendon slack length."""
        length = self._per_muscle(value, "mtu_length", "m")
        self._fail(length <= 0.0, length, "mtu_length", "m", "a length > 0 m")
        slack = self._l_slack
        too_short = length <= slack
        if np.any(too_short):
            i = int(np.flatnonzero(too_short)[0])
            raise InputError(
                f"mtu_length[{i}] (muscle {self._names[i]!r}) = {float(length[i])} m is not "
                f"longer than its tendon_slack_length {float(slack[i])} m; with a rigid "
                "tendon the fibre length would be <= 0"
            )
        return length

    # ------------------------------------------------------------------ kinematics

    def _geometry(self, mtu_length: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Normalised fibre length and cos(alpha) from validated MTU lengths.

        Raises:
            InputError: If a fibre would be longer than :data:`MAX_FIBRE_LENGTH` optimal
                lengths (the passive force is hundreds of ``F_max`` there and overflows soon
                after: a length in other units, say).
        """
        along = mtu_length - self._l_slack
        fiber_length = np.hypot(along, self._thickness)
        l_norm = fiber_length / self._l_opt
        too_long = l_norm > MAX_FIBRE_LENGTH
        if np.any(too_long):
            i = int(np.flatnonzero(too_long)[0])
            most = self._l_slack[i] + math.sqrt(
                max((MAX_FIBRE_LENGTH * self._l_opt[i]) ** 2 - self._thickness[i] ** 2, 0.0)
            )
            raise InputError(
                f"mtu_length[{i}] (muscle {self._names[i]!r}) = {float(mtu_length[i])!r} m "
                f"stretches its fibre to {float(l_norm[i]):.4g} optimal lengths; expected at "
                f"most {MAX_FIBRE_LENGTH:g} (an MTU length <= {most:.6g} m): are the lengths "
                "in metres?"
            )
        return l_norm, along / fiber_length

    def _velocity_norm(self, mtu_velocity: FloatArray, cos_alpha: FloatArray) -> FloatArray:
        """Normalised fibre velocity, rejecting shortening faster than v_max."""
        v_norm = mtu_velocity * cos_alpha / (self._v_max * self._l_opt)
        too_fast = v_norm < MAX_SHORTENING_VELOCITY - _VELOCITY_ROUNDOFF
        if np.any(too_fast):
            i = int(np.flatnonzero(too_fast)[0])
            v_max = float(self._v_max[i] * self._l_opt[i])
            raise InputError(
                f"mtu_velocity[{i}] (muscle {self._names[i]!r}) = {float(mtu_velocity[i])!r} "
                f"m/s makes the fibre shorten at {-float(v_norm[i]):.4g} x its maximum "
                f"contraction velocity ({v_max:.4g} m/s); expected a fibre velocity >= "
                f"-{v_max:.4g} m/s"
            )
        return np.maximum(v_norm, MAX_SHORTENING_VELOCITY)

    def fiber_state(self, mtu_length: ArrayLike, mtu_velocity: ArrayLike) -> FiberState:
        """Fibre length, velocity and pennation from the MTU length and velocity.

        Args:
            mtu_length: MTU lengths ``l_MT`` [m], shape ``(m,)``, each > ``l_Ts``.
            mtu_velocity: MTU velocities ``v_MT`` [m/s], shape ``(m,)``, negative =
                shortening; the fibre may not shorten faster than ``v_max``.

        Returns:
            :class:`FiberState` ``(length_norm, velocity_norm, cos_pennation)``, each of
            shape ``(m,)``.

        Raises:
            InputError: On a wrong shape, NaN, a length <= 0 or <= the tendon slack length,
                or a fibre shortening faster than ``v_max``.
        """
        length = self._mtu_length(mtu_length)
        velocity = self._per_muscle(mtu_velocity, "mtu_velocity", "m/s")
        l_norm, cos_alpha = self._geometry(length)
        return FiberState(l_norm, self._velocity_norm(velocity, cos_alpha), cos_alpha)

    # ------------------------------------------------------------------ forces

    def _force_parts(
        self, mtu_length: ArrayLike, mtu_velocity: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Tendon force at full activation minus passive, and passive tendon force [N]."""
        state = self.fiber_state(mtu_length, mtu_velocity)
        scale = self._f_max * state.cos_pennation
        active = (
            scale * active_force_length(state.length_norm) * force_velocity(state.velocity_norm)
        )
        passive = scale * passive_force_length(state.length_norm)
        return active, passive

    def force(
        self, activation: ArrayLike, mtu_length: ArrayLike, mtu_velocity: ArrayLike
    ) -> FloatArray:
        """Tendon force of every muscle (paper 003, eq. 14, times ``F_max``).

        ``F_T = F_max (a f_l(l_norm) f_v(v_norm) + f_PE(l_norm)) cos(alpha)``.

        Args:
            activation: Activations ``a`` [-], shape ``(m,)``, in [0, 1].
            mtu_length: MTU lengths ``l_MT`` [m], shape ``(m,)``, each > ``l_Ts``.
            mtu_velocity: MTU velocities ``v_MT`` [m/s], shape ``(m,)``, negative =
                shortening.

        Returns:
            Tendon forces [N], shape ``(m,)``, >= 0.

        Raises:
            InputError: On a wrong shape, NaN, an activation outside [0, 1], or an invalid
                length or velocity (see :meth:`fiber_state`).
        """
        a = self._activation(activation)
        active, passive = self._force_parts(mtu_length, mtu_velocity)
        return a * active + passive

    def force_capacity(
        self, mtu_length: ArrayLike, mtu_velocity: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Smallest and largest tendon force of every muscle in its current state.

        Args:
            mtu_length: MTU lengths ``l_MT`` [m], shape ``(m,)``, each > ``l_Ts``.
            mtu_velocity: MTU velocities ``v_MT`` [m/s], shape ``(m,)``.

        Returns:
            ``(f_min, f_max)`` [N], each of shape ``(m,)``: the force at activation 0 (the
            passive force) and at activation 1. Equal to ``force(0, ...)`` and
            ``force(1, ...)`` bit for bit.

        Raises:
            InputError: On an invalid length or velocity (see :meth:`fiber_state`).
        """
        active, passive = self._force_parts(mtu_length, mtu_velocity)
        return 0.0 * active + passive, 1.0 * active + passive

    def activation_for_force(
        self, force: ArrayLike, mtu_length: ArrayLike, mtu_velocity: ArrayLike
    ) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Inverse model: the activation that produces a wanted tendon force.

        ``a = (F / (F_max cos(alpha)) - f_PE) / (f_l f_v)``, clipped to [0, 1].

        Args:
            force: Wanted tendon forces [N], shape ``(m,)``, finite (any sign).
            mtu_length: MTU lengths ``l_MT`` [m], shape ``(m,)``, each > ``l_Ts``.
            mtu_velocity: MTU velocities ``v_MT`` [m/s], shape ``(m,)``.

        Returns:
            ``(activation, reachable)``, each of shape ``(m,)``: the activation [-] in
            [0, 1], and a bool array that is False where the wanted force is below the
            passive force (activation clipped to 0) or above the force at full activation
            (clipped to 1), beyond a round-off margin of ``1e-12 F_max``.

        Raises:
            InputError: On a wrong shape, NaN, or an invalid length or velocity.
        """
        wanted = self._per_muscle(force, "force", "N")
        active, passive = self._force_parts(mtu_length, mtu_velocity)
        margin = _FORCE_ROUNDOFF * self._f_max
        reachable = (wanted >= passive - margin) & (wanted <= passive + active + margin)
        with np.errstate(divide="ignore", invalid="ignore"):
            raw = (wanted - passive) / active
        raw = np.where(np.isnan(raw), 0.0, raw)
        return np.clip(raw, 0.0, 1.0), reachable

    def fiber_velocity_for_force(
        self, activation: ArrayLike, force: ArrayLike, mtu_length: ArrayLike
    ) -> FloatArray:
        """Forward dynamics: the fibre velocity at which the muscle gives ``force`` (eq. 15).

        ``v_norm = f_v^-1((F / (F_max cos(alpha)) - f_PE) / (a f_l))`` and
        ``v_M = v_norm v_max l_M0``. With the rigid tendon the MTU velocity is
        ``v_M / cos(alpha)`` (see :meth:`fiber_state` for ``cos(alpha)``).

        Args:
            activation: Activations ``a`` [-], shape ``(m,)``, in (0, 1] (eq. 15 divides by
                ``a``).
            force: Tendon forces [N], shape ``(m,)``.
            mtu_length: MTU lengths ``l_MT`` [m], shape ``(m,)``, each > ``l_Ts``.

        Returns:
            Fibre velocities ``v_M`` [m/s], shape ``(m,)``, negative = shortening, in
            ``[-v_max l_M0, 10 v_max l_M0]``.

        Raises:
            InputError: On a wrong shape, NaN, an activation outside (0, 1], an invalid
                length, a force below what the muscle gives at this activation while
                shortening at ``v_max`` (eq. 15 has no solution then), or a force above what
                it gives while lengthening at 10 ``v_max``
                (:data:`msarm.muscle.curves.MAX_INVERSE_LENGTHENING_VELOCITY`: the curve was
                fitted on [-1, 1] and its inverse grows exponentially beyond). Each names the
                muscle and the least or largest force reachable.
        """
        a = self._activation(activation)
        self._fail(a <= 0.0, a, "activation", "", "a value in (0, 1] (eq. 15 divides by a)")
        wanted = self._per_muscle(force, "force", "N")
        l_norm, cos_alpha = self._geometry(self._mtu_length(mtu_length))
        scale = self._f_max * cos_alpha
        f_l = active_force_length(l_norm)
        f_pe = passive_force_length(l_norm)
        f_v = (wanted / scale - f_pe) / (a * f_l)
        # Values below f_v(-1) by no more than the round-off of f_v are taken as f_v(-1).
        roundoff = _FORCE_ROUNDOFF * (1.0 + f_pe / (a * f_l))
        slowest = f_v < FORCE_VELOCITY_AT_MAX_SHORTENING - roundoff
        if np.any(slowest):
            i = int(np.flatnonzero(slowest)[0])
            least = scale[i] * (a[i] * f_l[i] * FORCE_VELOCITY_AT_MAX_SHORTENING + f_pe[i])
            raise InputError(
                f"force[{i}] (muscle {self._names[i]!r}) = {float(wanted[i])!r} N is below "
                f"{float(least):.6g} N, the force at activation {float(a[i]):.4g} while "
                "shortening at the maximum contraction velocity; eq. 15 has no solution"
            )
        # Values above f_v(10) by no more than the round-off are taken as f_v(10).
        fastest = f_v > FORCE_VELOCITY_AT_MAX_INVERSE_LENGTHENING + roundoff
        if np.any(fastest):
            i = int(np.flatnonzero(fastest)[0])
            most = scale[i] * (a[i] * f_l[i] * FORCE_VELOCITY_AT_MAX_INVERSE_LENGTHENING + f_pe[i])
            raise InputError(
                f"force[{i}] (muscle {self._names[i]!r}) = {float(wanted[i])!r} N is above "
                f"{float(most)!r} N, the force at activation {float(a[i]):.4g} while "
                f"lengthening at {MAX_INVERSE_LENGTHENING_VELOCITY:g} times the maximum "
                "contraction velocity; no plausible fibre velocity gives it (eq. 15)"
            )
        f_v = np.clip(
            f_v, FORCE_VELOCITY_AT_MAX_SHORTENING, FORCE_VELOCITY_AT_MAX_INVERSE_LENGTHENING
        )
        return force_velocity_inverse(f_v) * self._v_max * self._l_opt
