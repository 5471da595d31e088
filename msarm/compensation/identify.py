"""Identify the sheath stage's parameters from logs, with the diagnosis's candidate terms.

The sheath stage (:mod:`msarm.compensation.sheath`) needs the sheaths' friction coefficient
``mu`` and the cables' compliance. Both come from the training runs, fitted with the terms
that ``msarm diagnose`` uses, and are scored on the validation runs:

- ``mu``: the ``capstan`` term (:class:`~msarm.diagnose.effects.CableCapstanFriction`, one
  ``mu`` shared by the cables, its smoothing speed fitted too, by IPOPT) on the joint-torque
  residual. The smooth term follows the friction while the cables slide, which is where the
  capstan law holds with its full ``mu``;
- the compliance: the ``elasticity`` term (:class:`~msarm.diagnose.cable_effects.CableElasticity`,
  shared, least squares) on the cable length residual: motor encoder against path length.
  Without that residual (no motor encoders, or rigid cables) the compliance is 0; a negative
  fit (no stretch that grows with the tension) counts as 0 too, with a warning.

The logs are read as :class:`~msarm.diagnose.residuals.ResidualSpec` says: the cable length
residual turns motor angles into cable length with its ``drum_radius``, which must be the
plant's (:func:`msarm.compensation.pipeline.train_compensator` passes the plant's winch and
the recipe's target settings).

The score of each is its held-out explained share on the validation runs, the diagnosis's
score (:func:`msarm.diagnose.stack.group_scores`, ``1 - sum (r - pred)^2 / sum r^2``), so a
recipe can see how much of the residual each explains. Fitted alone, the ``capstan`` term
also takes part of the joints' Coulomb friction: on the default plant's runs ``mu`` comes out
about 0.01 high (0.1256 for 0.12; 0.1202 with the joint friction off), and on a plant without
sheath friction it still explains about half of the joint residual (``mu`` 0.0115, share
0.51), so its share does not tell whether a sheath is there (README, "The sheath stage").

:func:`reuse_or_identify_sheath` keeps the answer in a small JSON record next to the runs and
reuses it when the same logs (by their bytes' SHA-256), model and code (the ``"diagnosis"``
fingerprint, :func:`msarm.io.code_version.code_fingerprint`) ask again: the fit takes about
6 s, a third of a ``msarm train`` whose runs are all reused.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np

from msarm.compensation.sheath import SheathParameters
from msarm.compensation.target import TargetSpec
from msarm.diagnose.builder import channels_from_logs, check_log_file, check_same_rate
from msarm.diagnose.cable_effects import CableElasticity
from msarm.diagnose.effects import CableCapstanFriction
from msarm.diagnose.fitting import fit
from msarm.diagnose.residuals import ResidualSpec
from msarm.diagnose.stack import Layout, group_scores
from msarm.errors import InputError, MsarmWarning
from msarm.io.atomic import write_json_atomic
from msarm.io.code_version import code_fingerprint
from msarm.model import RobotModel
from msarm.plant.config import WinchConfig

__all__ = ["identify_sheath", "plant_reading", "reuse_or_identify_sheath"]


def plant_reading(winch: WinchConfig, target: TargetSpec) -> ResidualSpec:
    """How to read a simulated plant's logs: its winches' drum radius and drive gain.

    Args:
        winch: The plant's winch (``PlantConfig.winch``).
        target: The joint encoders' filter and the load cells' timing (a recipe's ``target``).

    Returns:
        The residual settings for :func:`identify_sheath`.
    """
    return ResidualSpec(target=target, drum_radius=winch.drum_radius, drive_gain=winch.drive_gain)


def identify_sheath(
    model: RobotModel,
    train_paths: Sequence[str | Path],
    validation_paths: Sequence[str | Path],
    spec: ResidualSpec | None = None,
) -> SheathParameters:
    """Fit ``mu`` and the cable compliance on ``train_paths``, score them on the others.

    Args:
        model: The nominal robot model the logs were recorded with.
        train_paths: Logs to fit on (runs without compensation), at least one.
        validation_paths: Logs to score on, at least one.
        spec: How the logs are read: the filter of the joint encoders and the load cells'
            timing (``target``) and the winch drums' radius [m] (``drum_radius``, the
            plant's); the defaults (msarm's arm: 3 mm) when None.

    Returns:
        The identified parameters with their held-out shares (a capstan fit that IPOPT did
        not bring to convergence is warned about, with its status).

    Raises:
        InputError: No logs on either side.
        LogError: A log the diagnosis cannot read (file and reason named).
    """
    return _identify(model, train_paths, validation_paths, spec)[0]


def _identify(
    model: RobotModel,
    train_paths: Sequence[str | Path],
    validation_paths: Sequence[str | Path],
    spec: ResidualSpec | None = None,
) -> tuple[SheathParameters, bool]:
    """:func:`identify_sheath`, and whether its capstan fit converged."""
    _require_logs(train_paths, validation_paths)
    train, residual, train_names = channels_from_logs(model, train_paths, spec)
    held, held_residual, held_names = channels_from_logs(model, validation_paths, spec)
    check_same_rate(train, train_names[0], held, held_names[0], ("training", "validation"))
    capstan = fit(
        CableCapstanFriction(n_cables=model.n_cables, n_joints=model.n_joints, fit_eps=True),
        train,
        residual["joint"],
    )
    if not capstan.success:
        warnings.warn(
            f"identify_sheath: the capstan fit did not converge (IPOPT: {capstan.message}); "
            f"mu = {capstan.parameters[0]:.4g} is where it stopped",
            MsarmWarning,
            stacklevel=3,
        )
    predictions = {"joint": capstan.predict(held)}
    compliance = 0.0
    if "length" in residual and "length" in held_residual:
        elastic = fit(CableElasticity(n_cables=model.n_cables), train, residual["length"])
        predictions["length"] = elastic.predict(held)
        compliance = float(elastic.parameters[0])
        if compliance < 0:
            warnings.warn(
                f"identify_sheath: the elasticity fit gives a negative compliance "
                f"({compliance:.3g} m/N); the sheath stage takes the cables as rigid (0)",
                MsarmWarning,
                stacklevel=2,
            )
            compliance = 0.0
    layout = Layout({g: held_residual[g] for g in predictions})
    scores = group_scores(
        layout,
        np.concatenate([held_residual[g] for g in layout.groups], axis=1),
        np.concatenate([predictions[g] for g in layout.groups], axis=1),
    )
    parameters = SheathParameters(
        mu=float(capstan.parameters[0]),
        compliance=compliance,
        mu_share=scores["joint"],
        compliance_share=scores.get("length", float("nan")),
    )
    return parameters, capstan.success


def _require_logs(
    train_paths: Sequence[str | Path], validation_paths: Sequence[str | Path]
) -> None:
    if not train_paths or not validation_paths:
        raise InputError("identify_sheath needs training and validation logs, at least one each")


def _identification_key(
    model: RobotModel,
    train_paths: Sequence[str | Path],
    validation_paths: Sequence[str | Path],
    spec: ResidualSpec,
) -> dict:
    """What an identification depends on: model, code, settings, each log's bytes, in order."""

    def digests(paths: Sequence[str | Path]) -> list[str]:
        for path in paths:  # a missing log or a run's folder: the log reader's message
            check_log_file(Path(path))
        return [hashlib.sha256(Path(path).read_bytes()).hexdigest() for path in paths]

    return {
        "model_sha256": model.sha256,
        "code": code_fingerprint("diagnosis"),
        "spec": asdict(spec),
        "train": digests(train_paths),
        "validation": digests(validation_paths),
    }


def reuse_or_identify_sheath(
    model: RobotModel,
    train_paths: Sequence[str | Path],
    validation_paths: Sequence[str | Path],
    record: str | Path,
    spec: ResidualSpec | None = None,
) -> tuple[SheathParameters, bool]:
    """:func:`identify_sheath`, reusing the answer ``record`` holds for the same input.

    The record (JSON) holds the parameters and what they were identified from: the model's
    SHA-256, the ``"diagnosis"`` code fingerprint, the settings the logs are read with
    (``spec``) and the SHA-256 of each log file, training and validation in order. The
    parameters are reused only when all of these are the same, so the answer is the one
    :func:`identify_sheath` would give (the fit is deterministic), to the bit. Otherwise (no
    record, another input, a record that cannot be read) the parameters are identified and
    the record written anew, atomically (not when the capstan fit did not converge: that
    answer is warned about and used, not kept).

    Args:
        model: The nominal robot model the logs were recorded with.
        train_paths: Logs to fit on (runs without compensation), at least one.
        validation_paths: Logs to score on, at least one.
        record: The JSON file to reuse and write.
        spec: How the logs are read (see :func:`identify_sheath`); the defaults when None.

    Returns:
        ``(parameters, reused)``: the identified parameters and whether the record gave them.

    Raises:
        InputError: No logs on either side, or a log that cannot be read.
        LogError: A log the diagnosis cannot read (file and reason named).
    """
    _require_logs(train_paths, validation_paths)
    record = Path(record)
    spec = spec or ResidualSpec()
    try:
        key = _identification_key(model, train_paths, validation_paths, spec)
    except OSError as exc:
        raise InputError(f"cannot read a log to identify the sheath stage: {exc}") from None
    try:
        kept = json.loads(record.read_text(encoding="utf-8"))
        if kept.get("key") == key:
            return SheathParameters.from_dict(kept["parameters"]), True
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        pass  # no record, or one that cannot be used: identify again
    parameters, converged = _identify(model, train_paths, validation_paths, spec)
    if converged:  # a fit stopped short is not kept: the next run fits again
        write_json_atomic(record, {"key": key, "parameters": parameters.as_dict()})
    return parameters, False
