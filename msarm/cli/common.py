"""Helpers shared by the CLI commands: resolving names given on the command line."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

from rich.console import Console

from msarm.errors import InputError
from msarm.plant.config import DEFAULT_PLANT, IDEAL_PLANT, PlantConfig

T = TypeVar("T")

#: Plants known by name; anything else is read as a YAML file.
PLANTS: dict[str, PlantConfig] = {"default": DEFAULT_PLANT, "ideal": IDEAL_PLANT}


def resolve_config(spec: str, presets: dict[str, T], cls: type[T], what: str) -> T:
    """A config from a preset name or, failing that, a YAML file of ``cls``.

    Args:
        spec: A name of ``presets`` or the path of a YAML file.
        presets: The presets by name.
        cls: The config's dataclass (how the YAML file is read).
        what: What the config is, for the error message (e.g. ``"plant"``).

    Raises:
        InputError: ``spec`` is neither a preset nor an existing file.
    """
    if spec in presets:
        return presets[spec]
    path = Path(spec)
    if not path.is_file():
        raise InputError(
            f"unknown {what} {spec!r}: expected one of {', '.join(presets)} or a YAML file"
        )
    from msarm.io.config import load_config

    return load_config(path, cls)


def resolve_plant(spec: str) -> PlantConfig:
    """The arm plant from a preset name (``default``, ``ideal``) or a YAML file."""
    return resolve_config(spec, PLANTS, PlantConfig, "plant")


def console() -> Console:
    """A rich console; a wide one when output is not a terminal (tables stay readable)."""
    out = Console()
    return out if out.is_terminal else Console(width=120)
