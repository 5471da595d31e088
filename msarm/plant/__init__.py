"""MuJoCo plants with winches and cables, and the effects that make them differ from the model."""

from msarm.plant.arm_plant import ArmPlant, SimulationDivergedError
from msarm.plant.config import DEFAULT_PLANT, IDEAL_PLANT, EffectsConfig, PlantConfig, ideal_config
from msarm.plant.effects import CableState, Effect, SensorReadings, build_effects

__all__ = [
    "DEFAULT_PLANT",
    "IDEAL_PLANT",
    "ArmPlant",
    "CableState",
    "Effect",
    "EffectsConfig",
    "PlantConfig",
    "SensorReadings",
    "SimulationDivergedError",
    "build_effects",
    "ideal_config",
]
