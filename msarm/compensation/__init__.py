"""Feedforward compensator of paper 003 (§2.2, eq. 9): an MLP from features to joint-torque errors.

Modules:
    network: :class:`NetworkConfig`, :class:`Normalizer`, :func:`build_mlp` and the
        reproducible, resumable :func:`train_network` (Adam, early stopping).
    checkpoint: the trained :class:`Compensator` (torch inference, safe save and load that
        refuses a file made for another robot model or feature spec: :class:`CheckpointError`).
    fast: :class:`FastCompensator`, the numpy single-sample path for the control loop.
"""

from msarm.compensation.checkpoint import CheckpointError, Compensator
from msarm.compensation.fast import FastCompensator
from msarm.compensation.network import (
    EpochRecord,
    NetworkConfig,
    Normalizer,
    TrainingResult,
    build_mlp,
    check_finite,
    train_network,
)

__all__ = [
    "CheckpointError",
    "Compensator",
    "EpochRecord",
    "FastCompensator",
    "NetworkConfig",
    "Normalizer",
    "TrainingResult",
    "build_mlp",
    "check_finite",
    "train_network",
]
