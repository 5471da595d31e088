"""Hill-type muscles: curves, activation dynamics, forward and inverse muscle models.

Units: SI inside the code (N, m, m/s, s, rad). The curves of :mod:`msarm.muscle.curves` work
in normalised units: fibre length over the optimal fibre length ``l_M0``, fibre velocity over
the maximum contraction velocity ``v_max l_M0`` (``v_max`` is given in optimal fibre lengths
per second, typically 10), force over the maximum isometric force ``F_max``.
:class:`HillMuscles` takes and returns SI quantities as arrays of shape ``(m,)``, one entry per
muscle, in the order of its parameters.

Sign of velocity: negative when the fibre or the muscle-tendon unit shortens (concentric
contraction), positive when it lengthens. Tendon forces are >= 0 and pull.

Modules:
    curves: De Groote et al. (2016) force-length, passive force-length and force-velocity
        curves and the force-velocity inverse.
    activation: first-order activation dynamics (De Groote et al. 2016, smooth form).
    hill: muscle-tendon units of paper 003, eq. 14 (force) and eq. 15 (fibre velocity from
        force), with a rigid tendon and constant-thickness pennation.
"""

from msarm.muscle.activation import (
    DEFAULT_ACTIVATION_SMOOTHING,
    DEFAULT_TAU_ACT,
    DEFAULT_TAU_DEACT,
    activation_derivative,
    activation_time_constant,
    step_activation,
)
from msarm.muscle.curves import (
    active_force_length,
    force_velocity,
    force_velocity_inverse,
    passive_force_length,
)
from msarm.muscle.hill import FiberState, HillMuscles, MuscleParameters

__all__ = [
    "DEFAULT_ACTIVATION_SMOOTHING",
    "DEFAULT_TAU_ACT",
    "DEFAULT_TAU_DEACT",
    "FiberState",
    "HillMuscles",
    "MuscleParameters",
    "activation_derivative",
    "activation_time_constant",
    "active_force_length",
    "force_velocity",
    "force_velocity_inverse",
    "passive_force_length",
    "step_activation",
]
