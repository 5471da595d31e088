"""Cable-driven parallel robots (CDPRs): geometry, kinematics and statics.

``CableRobot`` holds the frame and platform anchors of an m-cable, 6-DOF robot; its
``inverse_kinematics`` and ``structure_matrix`` follow paper 000, eq. 1-2. Cable tension
``f >= 0`` pulls the platform towards the frame anchor; the platform is in equilibrium when
``A^T f + w = 0`` for the external wrench ``w``. Force distribution (finding f) lives in
``msarm.allocation`` with ``M = A^T`` and ``b = -w``.

Cable force without a load cell (from the motor torque or current, or from the drive's
following error, with the winch friction model): :mod:`msarm.cdpr.force_estimation`.
"""

from msarm.cdpr.force_estimation import (
    WinchParameters,
    force_from_following_error,
    force_from_motor_current,
    force_from_motor_torque,
)
from msarm.cdpr.kinematics import CableKinematics, CableRobot

__all__ = [
    "CableKinematics",
    "CableRobot",
    "WinchParameters",
    "force_from_following_error",
    "force_from_motor_current",
    "force_from_motor_torque",
]
