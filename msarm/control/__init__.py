"""Controllers: they read sensor values only and output actuator commands."""

from msarm.control.arm_controller import ArmControllerConfig, ControlOutput, MuscleSpaceController

__all__ = ["ArmControllerConfig", "ControlOutput", "MuscleSpaceController"]
