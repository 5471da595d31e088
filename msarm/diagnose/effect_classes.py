"""The plant effect classes the withheld-effect benchmark covers.

A light module: the CLI's ``--help`` lists them without importing the simulation.
"""

from __future__ import annotations

__all__ = ["EFFECT_CLASSES"]

#: The plant effect classes the benchmark covers, in a fixed order (part of the seeding).
EFFECT_CLASSES: tuple[str, ...] = (
    "sheath_friction",
    "winch_friction",
    "elasticity",
    "joint_friction",
    "cogging",
    "sensor_bias",
    "delay",
)
