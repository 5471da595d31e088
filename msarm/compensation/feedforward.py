"""The learned feedforward in the control loop: features online, fast network, ``dtau``.

``dtau = T_f_hat(features)`` is added to the controller's wanted joint torque, so it goes
through the same allocation and inverse muscle model (paper 003 section 3.1). A compensator
trained with the sheath stage (:mod:`msarm.compensation.sheath`, its identified parameters in
the checkpoint) also turns the wanted tensions into the drives' command.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from msarm.compensation.checkpoint import CheckpointError, Compensator
from msarm.compensation.fast import FastCompensator
from msarm.compensation.features import FeatureExtractor, FeatureSpec
from msarm.compensation.sheath import SheathInverse, SheathParameters, SheathSpec
from msarm.control import ArmControllerConfig
from msarm.errors import ConfigError, InputError, MsarmWarning
from msarm.io.config import config_to_dict, join_differences, load_config, value_differences
from msarm.model import RobotModel
from msarm.plant.config import PLANT_PRESETS, PlantConfig

__all__ = [
    "LearnedFeedforward",
    "feature_spec_of",
    "load_feedforward",
    "plant_differences",
    "sheath_stage_of",
    "trained_controller",
    "trained_plant",
    "warn_if_other_plant",
]

FloatArray = NDArray[np.float64]


def feature_spec_of(compensator: Compensator, source: str = "compensator") -> FeatureSpec:
    """The feature spec stored in a compensator's metadata.

    Args:
        compensator: A loaded compensator.
        source: What to call it in an error (its file).

    Returns:
        The spec its network's inputs were extracted with.

    Raises:
        CheckpointError: The metadata has no feature spec, or not a valid one (``source``
            named).
    """
    raw = compensator.metadata.get("feature_spec")
    if not isinstance(raw, Mapping):
        raise CheckpointError(f"{source}: records no feature spec (metadata has no 'feature_spec')")
    raw = dict(raw)
    try:
        raw["groups"] = tuple(raw["groups"])
        if "stiction_mus" in raw:
            raw["stiction_mus"] = tuple(raw["stiction_mus"])
        return FeatureSpec(**raw)
    except (InputError, KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{source}: invalid feature_spec: {exc}") from None


def trained_controller(
    compensator: Compensator, source: str = "compensator"
) -> ArmControllerConfig:
    """The controller gains a compensator was trained with (its recipe's ``controller``).

    The feedforward learned the torque error that this controller leaves, so it is run, and
    compared, with the same gains.

    Args:
        compensator: A loaded compensator.
        source: What to call it in an error (its file).

    Returns:
        The controller configuration of its training recipe.

    Raises:
        CheckpointError: The metadata records no gains, or invalid ones (``source`` named).
    """
    recipe = compensator.metadata.get("recipe")
    if not isinstance(recipe, Mapping) or "controller" not in recipe:
        raise CheckpointError(
            f"{source}: records no controller gains (metadata has no 'recipe.controller'); "
            "the feedforward must run with the gains it was trained with: retrain it with "
            "msarm train, or give msarm track --controller"
        )
    try:
        return load_config(recipe["controller"], ArmControllerConfig)
    except ConfigError as exc:
        raise CheckpointError(f"{source}: invalid recipe.controller: {exc}") from None


def sheath_stage_of(
    model: RobotModel, compensator: Compensator, source: str = "compensator"
) -> SheathInverse | None:
    """The sheath stage a compensator was trained with, or None (a network alone).

    Args:
        model: The arm the stage runs on.
        compensator: A loaded compensator.
        source: What to call it in an error (its file).

    Returns:
        The stage (its identified sheath parameters, run at the trained controller's
        period), or None when the compensator was trained without one.

    Raises:
        CheckpointError: The stage's settings or parameters are missing or invalid (``source``
            named).
    """
    saved = compensator.metadata.get("sheath")
    if not saved:
        return None
    try:
        spec = SheathSpec(**saved["spec"])
        parameters = SheathParameters.from_dict(saved["parameters"])
    except (InputError, KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{source}: invalid sheath stage: {exc}") from None
    period = 1.0 / trained_controller(compensator, source).rate_hz
    return SheathInverse(model, spec, parameters, period)


class LearnedFeedforward:
    """A trained compensator as the controller's feedforward (see ``msarm.tasks.runner``).

    Args:
        model: The nominal arm model.
        compensator: The trained network, or None (no ``dtau``: the sheath stage alone, as
            while the first network's data are collected).
        sheath: The sheath stage, or None (the compensator's own when ``compensator`` has
            one, see :func:`load_feedforward`).
    """

    def __init__(
        self,
        model: RobotModel,
        compensator: Compensator | None,
        sheath: SheathInverse | None = None,
    ) -> None:
        self.compensator = compensator
        self.sheath = sheath
        self._zeros = np.zeros(model.n_joints)
        self.extractor = None
        self.fast = None
        if compensator is not None:
            self.extractor = FeatureExtractor(model, feature_spec_of(compensator))
            self.fast = FastCompensator(compensator)

    def reset(self) -> None:
        """Start a new run."""
        if self.extractor is not None:
            self.extractor.reset()
        if self.sheath is not None:
            self.sheath.reset()

    def run_at(self, period: float) -> None:
        """Run at the controller's ``period`` [s]: the sheath stage's filter steps with it.

        The stage is built at the trained controller's period; ``msarm track --controller``
        may run another rate.
        """
        if self.sheath is not None:
            self.sheath.run_at(period)

    def __call__(
        self, readings, qdot_estimate: FloatArray, q_ref: FloatArray, qd_ref: FloatArray
    ) -> FloatArray:
        """``dtau`` [N m], shape ``(n,)``, for this tick."""
        if self.fast is None:
            return self._zeros.copy()
        return self.fast(self.extractor(readings, qdot_estimate, q_ref, qd_ref))

    def precompute(
        self, q_ref: FloatArray, qd_ref: FloatArray
    ) -> tuple[FloatArray, SheathInverse | None] | None:
        """What this feedforward gives a whole run, before it starts (the compiled loop).

        Args:
            q_ref: The run's reference joint angles [rad], ``(T, n)``.
            qd_ref: Its reference joint velocities [rad/s], ``(T, n)``.

        Returns:
            ``(dtau, stage)``: the ``dtau`` of every tick [N m], ``(T, n)``, the same bits as
            the calls of a run from its start (:meth:`__call__`), and the sheath stage (or
            None), which the loop runs tick by tick; or None when ``dtau`` needs the robot's
            sensors (features beyond :data:`~msarm.compensation.features.REFERENCE_GROUPS`)
            or is not finite (the Python loop then raises it at its tick).
        """
        if self.fast is None:
            dtau = np.zeros(np.shape(q_ref))
        elif not self.extractor.reference_only:
            return None
        else:
            features = self.extractor.from_reference(q_ref, qd_ref)
            dtau = np.empty(np.shape(q_ref))
            for k, row in enumerate(features):
                dtau[k] = self.fast(row)
            if not np.all(np.isfinite(dtau)):
                return None
        return dtau, self.sheath

    def tension_command(self, tension: FloatArray, q_ref: FloatArray) -> FloatArray:
        """The drives' command [N], ``(m,)``, for the wanted tensions ``(m,)`` [N]."""
        if self.sheath is None:
            return tension
        return self.sheath(tension, q_ref)

    def observe_command(self, tension_command: FloatArray) -> None:
        """The tension command [N], ``(m,)``, the controller sent this tick (features)."""
        if self.extractor is not None:
            self.extractor.observe_command(tension_command)


def trained_plant(compensator: Compensator) -> PlantConfig | None:
    """The plant a compensator's training runs were collected on, if the checkpoint says.

    ``msarm train`` records it (``metadata["training"]["plant"]``); a checkpoint from before
    that is known only by its recipe's ``data.plant``, which names a preset (``default``,
    ``ideal``) or a file that may have changed since: the preset is returned, a file gives
    ``None``, as does a record that is not a valid plant.

    Args:
        compensator: A loaded compensator.

    Returns:
        The plant configuration, or ``None`` when the checkpoint does not tell.
    """
    training = compensator.metadata.get("training")
    recorded = training.get("plant") if isinstance(training, Mapping) else None
    if isinstance(recorded, Mapping):
        try:
            return load_config(recorded, PlantConfig)
        except (ConfigError, InputError, TypeError, ValueError):
            return None
    recipe = compensator.metadata.get("recipe")
    data = recipe.get("data") if isinstance(recipe, Mapping) else None
    spec = data.get("plant") if isinstance(data, Mapping) else None
    return PLANT_PRESETS.get(spec) if isinstance(spec, str) else None


def plant_differences(trained: PlantConfig, plant: PlantConfig) -> list[str]:
    """The settings in which ``plant`` differs from ``trained``, names aside.

    Args:
        trained: The plant a compensator was trained on (:func:`trained_plant`).
        plant: The plant it is about to run on.

    Returns:
        One ``"path: trained value -> this value"`` line per differing setting (dotted
        paths, e.g. ``effects.sheath_friction.enabled: True -> False``), in the config's
        order; empty when the plants are the same.
    """
    return [
        f"{path}: {before!r} -> {after!r}"
        for path, before, after in value_differences(config_to_dict(trained), config_to_dict(plant))
        if path != "name"
    ]


def warn_if_other_plant(
    compensator: Compensator, plant: PlantConfig, source: str = "compensator", shown: int = 3
) -> list[str]:
    """Warn when ``plant`` is not the plant the compensator was trained on.

    The feedforward learned the effects of its training plant; on another it compensates
    effects that may not be there (the default plant's compensator on the ideal plant:
    ``random-7`` ends 0.35 mm from its target instead of 3e-6 mm without it). Running it
    there is allowed (to see how it carries over), with a :class:`~msarm.errors.MsarmWarning`
    that names the first ``shown`` differing settings. No warning when the checkpoint does
    not say which plant it was trained on (:func:`trained_plant`).

    Args:
        compensator: A loaded compensator.
        plant: The plant it is about to run on.
        source: What to call the compensator (its file).
        shown: How many differing settings the warning names.

    Returns:
        The differences (:func:`plant_differences`); empty for the same plant or an unknown
        one.
    """
    trained = trained_plant(compensator)
    if trained is None:
        return []
    differences = plant_differences(trained, plant)
    if differences:
        warnings.warn(
            f"{source} was trained on the plant {trained.name!r}; this plant "
            f"{plant.name!r} differs in {len(differences)} setting(s) "
            f"({join_differences(differences, shown)}): the feedforward compensates the "
            "effects of the plant it was trained on and can track worse on another "
            "(train one for this plant: data.plant in the recipe of msarm train)",
            MsarmWarning,
            stacklevel=2,
        )
    return differences


def load_feedforward(path: str | Path, model: RobotModel) -> LearnedFeedforward:
    """Load a checkpoint for ``model`` (with its sheath stage, if it was trained with one).

    Args:
        path: The checkpoint file (``msarm train`` writes ``runs/compensator/compensator.pt``).
        model: The arm it must have been trained for (its SHA-256 is checked).

    Returns:
        The feedforward, ready for the control loop: the network, its feature extractor and
        the sheath stage.

    Raises:
        CheckpointError: The file is not a compensator for ``model`` (another model, a
            corrupt file), or what it records does not fit together: no controller gains or
            not one per joint, a feature spec whose inputs are not the network's, an invalid
            sheath stage. The message names the file and the reason.
    """
    source = str(path)
    compensator = Compensator.load(path, expected_model_sha256=model.sha256)
    feature_spec_of(compensator, source)  # an invalid spec: refused with the file named
    if compensator.output_dim != model.n_joints:
        raise CheckpointError(
            f"{source}: its network gives {compensator.output_dim} torques, the arm has "
            f"{model.n_joints} joints"
        )
    gains = trained_controller(compensator, source)  # the gains it must run with: recorded
    for name in ("kp", "ki", "kd"):
        if len(getattr(gains, name)) != model.n_joints:
            raise CheckpointError(
                f"{source}: its recipe.controller {name} has {len(getattr(gains, name))} "
                f"gains, the arm has {model.n_joints} joints; the file was edited or made for "
                "another arm"
            )
    stage = sheath_stage_of(model, compensator, source)
    feedforward = LearnedFeedforward(model, compensator, stage)
    inputs = feedforward.extractor.size  # the extractor the loop will run
    if inputs != compensator.input_dim:
        raise CheckpointError(
            f"{source}: its feature spec gives {inputs} inputs, its network takes "
            f"{compensator.input_dim}; the file was edited or mixed from two trainings"
        )
    return feedforward
