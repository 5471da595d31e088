"""Shared fixtures: the arm is loaded once per test session."""

from __future__ import annotations

import pytest

from msarm.model import load_arm


@pytest.fixture(scope="session")
def arm():
    """The musculoskeletal arm of ``models/msarm_arm.xml``."""
    return load_arm()
