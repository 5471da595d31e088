"""The seed of a plant's random generator: one rule for every plant (same seed, same run)."""

from __future__ import annotations

import copy

import numpy as np

from msarm.errors import InputError

__all__ = ["seed_generator"]


def seed_generator(seed: object) -> np.random.Generator:
    """The generator a plant copies at every reset, from ``seed`` (checked).

    Args:
        seed: A non-negative integer, or a ``numpy.random.Generator`` (deep-copied: every
            reset starts again from the state it had here).

    Returns:
        A private generator; copy it at each reset rather than drawing from it.

    Raises:
        InputError: ``seed`` is neither a non-negative integer nor a generator (``None``,
            which would draw a fresh seed from the system, included).
    """
    if isinstance(seed, np.random.Generator):
        return copy.deepcopy(seed)
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
        if seed < 0:
            raise InputError(f"seed must be a non-negative integer, got {int(seed)}")
        return np.random.default_rng(int(seed))
    raise InputError(
        "seed must be a non-negative integer or a numpy.random.Generator (same seed, same run),"
        f" got {seed!r} of type {type(seed).__name__}"
    )
