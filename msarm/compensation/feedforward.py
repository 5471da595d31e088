"""The learned feedforward in the control loop: features online, fast network, ``dtau``.

``dtau = T_f_hat(features)`` is added to the controller's wanted joint torque, so it goes
through the same allocation and inverse muscle model (paper 003 section 3.1).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from msarm.compensation.checkpoint import Compensator
from msarm.compensation.fast import FastCompensator
from msarm.compensation.features import FeatureExtractor, FeatureSpec
from msarm.control import ArmControllerConfig
from msarm.io.config import load_config
from msarm.model import RobotModel

__all__ = ["LearnedFeedforward", "feature_spec_of", "load_feedforward", "trained_controller"]

FloatArray = NDArray[np.float64]


def feature_spec_of(compensator: Compensator) -> FeatureSpec:
    """The feature spec stored in a compensator's metadata."""
    raw = dict(compensator.metadata["feature_spec"])
    raw["groups"] = tuple(raw["groups"])
    if "stiction_mus" in raw:
        raw["stiction_mus"] = tuple(raw["stiction_mus"])
    return FeatureSpec(**raw)


def trained_controller(compensator: Compensator) -> ArmControllerConfig:
    """The controller gains a compensator was trained with (its recipe's), else the defaults.

    The feedforward learned the torque error that this controller leaves, so it is run, and
    compared, with the same gains.
    """
    recipe = compensator.metadata.get("recipe", {})
    if "controller" not in recipe:
        return ArmControllerConfig()
    return load_config(recipe["controller"], ArmControllerConfig)


class LearnedFeedforward:
    """A trained compensator as the controller's feedforward (see ``msarm.tasks.runner``).

    Args:
        model: The nominal arm model.
        compensator: The trained compensator.
    """

    def __init__(self, model: RobotModel, compensator: Compensator) -> None:
        self.compensator = compensator
        self.extractor = FeatureExtractor(model, feature_spec_of(compensator))
        self.fast = FastCompensator(compensator)

    def reset(self) -> None:
        """Start a new run."""
        self.extractor.reset()

    def __call__(
        self, readings, qdot_estimate: FloatArray, q_ref: FloatArray, qd_ref: FloatArray
    ) -> FloatArray:
        """``dtau`` [N m], shape ``(n,)``, for this tick."""
        return self.fast(self.extractor(readings, qdot_estimate, q_ref, qd_ref))

    def observe_command(self, tension_command: FloatArray) -> None:
        """The tension command [N], ``(m,)``, the controller sent this tick (features)."""
        self.extractor.observe_command(tension_command)


def load_feedforward(path: str | Path, model: RobotModel) -> LearnedFeedforward:
    """Load a checkpoint for ``model``; refuses one made for another model (reason given)."""
    compensator = Compensator.load(path, expected_model_sha256=model.sha256)
    return LearnedFeedforward(model, compensator)
