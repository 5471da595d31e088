"""MuJoCo's instability warnings: which a plant watches, and what to say when one fired.

When MuJoCo meets a NaN, infinite or huge joint position, velocity or acceleration it counts a
warning (``mjWARN_BADQPOS``, ``mjWARN_BADQVEL``, ``mjWARN_BADQACC``) and resets its own state,
time included, so the simulation would go on from the reference posture as if nothing had
happened. A plant that watches these counters stops the run instead.
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import NDArray

__all__ = ["UNSTABLE_INDEX", "UNSTABLE_WARNINGS", "instability_found"]

#: Index of each instability warning in ``MjData.warning`` -> the joint quantity that went bad.
UNSTABLE_WARNINGS: dict[int, str] = {
    int(mujoco.mjtWarning.mjWARN_BADQPOS): "position",
    int(mujoco.mjtWarning.mjWARN_BADQVEL): "velocity",
    int(mujoco.mjtWarning.mjWARN_BADQACC): "acceleration",
}
#: The same indices as an int64 array (for compiled checks).
UNSTABLE_INDEX: NDArray[np.int64] = np.array(sorted(UNSTABLE_WARNINGS), dtype=np.int64)


def instability_found(data: mujoco.MjData) -> list[str]:
    """What MuJoCo found, one sentence per instability warning that fired (empty if none)."""
    return [
        f"MuJoCo found a NaN, infinite or huge joint {kind} at DOF "
        f"{int(data.warning.lastinfo[index])} and reset its state"
        for index, kind in UNSTABLE_WARNINGS.items()
        if data.warning.number[index] > 0
    ]
