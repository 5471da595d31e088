"""Feedforward compensator of paper 003 (§2.2, eq. 9): an MLP from features to joint-torque errors.

Modules:
    network: :class:`NetworkConfig`, :class:`Normalizer`, :func:`build_mlp` and the
        reproducible, resumable :func:`train_network` (Adam, early stopping).
    checkpoint: the trained :class:`Compensator` (torch inference, safe save and load that
        refuses a file made for another robot model or feature spec: :class:`CheckpointError`).
    fast: :class:`FastCompensator`, the numpy single-sample path for the control loop.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# Imported on first use (PEP 562): the diagnosis uses msarm.compensation.target, and torch
# (1.5 s to import) is needed only by the network and the checkpoint.
_WHERE = {
    "CheckpointError": "checkpoint",
    "Compensator": "checkpoint",
    "FastCompensator": "fast",
    "EpochRecord": "network",
    "NetworkConfig": "network",
    "Normalizer": "network",
    "TrainingResult": "network",
    "build_mlp": "network",
    "check_finite": "network",
    "train_network": "network",
}

if TYPE_CHECKING:
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


def __getattr__(name: str) -> Any:
    """The public names, from their modules on first use."""
    if name in _WHERE:
        return getattr(importlib.import_module(f"msarm.compensation.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'msarm.compensation' has no attribute {name!r}")
