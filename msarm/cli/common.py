"""Helpers shared by the CLI commands: resolving names given on the command line."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from msarm.errors import InputError
from msarm.plant.config import DEFAULT_PLANT, IDEAL_PLANT, PlantConfig

#: Plants known by name; anything else is read as a YAML file.
PLANTS: dict[str, PlantConfig] = {"default": DEFAULT_PLANT, "ideal": IDEAL_PLANT}


def resolve_plant(spec: str) -> PlantConfig:
    """A plant config from a preset name (``default``, ``ideal``) or a YAML file.

    Raises:
        InputError: ``spec`` is neither a preset nor an existing file.
    """
    if spec in PLANTS:
        return PLANTS[spec]
    path = Path(spec)
    if not path.is_file():
        raise InputError(
            f"unknown plant {spec!r}: expected one of {', '.join(PLANTS)} or a YAML file"
        )
    from msarm.io.config import load_config

    return load_config(path, PlantConfig)


def console() -> Console:
    """A rich console; a wide one when output is not a terminal (tables stay readable)."""
    out = Console()
    return out if out.is_terminal else Console(width=120)
