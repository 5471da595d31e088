"""Named tracking tasks: the four Table I tasks of paper 003 and seeded random reaches.

Names:

- ``table1-1`` ... ``table1-4``: paper 003, Table I. Each lasts :data:`TABLE1_DURATION`
  (20 s): hold :data:`~msarm.tasks.trajectories.HOME_POSTURE` for :data:`TABLE1_WAIT`
  (0.5 s), a minimum-jerk move to the Table I target in :data:`TABLE1_MOVE_TIME` (2.0 s), then
  hold the target to the end.
- ``random-<seed>`` (``seed`` a non-negative integer): :func:`random_reach_task` inside the
  model's joint range (needs the model).
"""

from __future__ import annotations

import re
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from msarm.errors import InputError
from msarm.tasks.trajectories import HOME_POSTURE, Task, hold_then_move, random_reach_task

__all__ = [
    "TABLE1_DURATION",
    "TABLE1_MOVE_TIME",
    "TABLE1_TARGETS",
    "TABLE1_WAIT",
    "check_task_against",
    "get_task",
    "list_tasks",
    "table1_task",
]

#: Joint-angle targets of paper 003, Table I [rad], one row per task ``table1-k``, columns in
#: joint order (shoulder abduction, shoulder flexion, shoulder rotation, elbow). The paper
#: names its columns Joint1-3 (shoulder) and Joint4 (elbow) only: this order of the shoulder
#: joints is our reading (every target lies inside msarm's joint ranges).
TABLE1_TARGETS: NDArray[np.float64] = np.array(
    [
        [0.0, 0.4363, -0.5236, -1.2217],
        [0.0, 0.3491, -0.6109, -0.9599],
        [0.0, 0.5236, -0.4363, -0.8727],
        [-0.0873, 0.3491, -0.4363, -0.6109],
    ]
)
TABLE1_TARGETS.flags.writeable = False
#: Length of every Table I task [s] (paper 003: 20 s trials).
TABLE1_DURATION = 20.0
#: Hold at the home posture before the move [s].
TABLE1_WAIT = 0.5
#: Duration of the minimum-jerk move to the target [s].
TABLE1_MOVE_TIME = 2.0

_RANDOM_RE = re.compile(r"^random-([0-9]+)$")  # ASCII digits: int() reads others too
_TABLE1_RE = re.compile(r"^table1-([0-9]+)$")


class _HasJointLimits(Protocol):
    joint_names: tuple[str, ...]
    joint_lower: NDArray[np.float64]
    joint_upper: NDArray[np.float64]


def list_tasks() -> dict[str, str]:
    """Task names and patterns with a one-line description each (for the CLI).

    Returns:
        Name or pattern -> description, in a stable order.
    """
    out = {
        f"table1-{k + 1}": f"paper 003 Table I target {np.round(TABLE1_TARGETS[k], 4).tolist()} "
        f"rad, {TABLE1_DURATION:g} s"
        for k in range(len(TABLE1_TARGETS))
    }
    out["random-<seed>"] = (
        "seeded random reaches inside the joint range (seed: a non-negative integer)"
    )
    return out


def table1_task(k: int) -> Task:
    """Task ``table1-k`` of paper 003 (``k`` in 1..4).

    Args:
        k: Row of Table I, 1-based.

    Returns:
        The task.
    """
    if not 1 <= k <= len(TABLE1_TARGETS):
        raise InputError(f"Table I has tasks 1..{len(TABLE1_TARGETS)}, got {k}")
    return hold_then_move(
        name=f"table1-{k}",
        home=HOME_POSTURE,
        target=TABLE1_TARGETS[k - 1],
        wait=TABLE1_WAIT,
        move_time=TABLE1_MOVE_TIME,
        duration=TABLE1_DURATION,
    )


def get_task(name: str, model: _HasJointLimits | None = None) -> Task:
    """A task by name.

    Args:
        name: ``table1-1`` ... ``table1-4`` or ``random-<seed>``.
        model: The robot (a :class:`msarm.model.RobotModel`); needed for ``random-<seed>``
            (its joint limits). When given, the task's postures are checked against its joint
            count and limits.

    Returns:
        The task.

    Raises:
        InputError: Unknown name (the valid names and patterns are listed), no model for a
            random task, or a task posture outside the model's joint range.
    """
    table1 = _TABLE1_RE.match(name) if isinstance(name, str) else None
    random = _RANDOM_RE.match(name) if isinstance(name, str) else None
    if table1 and table1.group(1) != str(int(table1.group(1))):
        raise InputError(
            f"task {name!r}: write the number without leading zeros, table1-{int(table1.group(1))}"
            " (one task, one name: runs are stored by task name)"
        )
    if table1 and 1 <= int(table1.group(1)) <= len(TABLE1_TARGETS):
        task = table1_task(int(table1.group(1)))
    elif random and random.group(1) != str(int(random.group(1))):
        raise InputError(
            f"task {name!r}: write the seed without leading zeros, random-{int(random.group(1))}"
            " (one seed, one name: runs are stored by task name)"
        )
    elif random:
        if model is None:
            raise InputError(f"task {name!r} needs the robot model (its joint limits)")
        task = random_reach_task(
            int(random.group(1)), np.asarray(model.joint_lower), np.asarray(model.joint_upper)
        )
    else:
        raise InputError(f"unknown task {name!r}; valid tasks: {', '.join(list_tasks())}")
    if model is not None:
        check_task_against(task, model)
    return task


def check_task_against(task: Task, model: _HasJointLimits) -> None:
    """Refuse a task of another joint count or whose postures leave the model's joint range.

    Raises:
        InputError: The joint counts differ, or a posture (home, a move's target) puts a
            joint outside ``[joint_lower, joint_upper]`` (task, posture, joint and value named).
    """
    lower = np.asarray(model.joint_lower, dtype=float)
    upper = np.asarray(model.joint_upper, dtype=float)
    if task.n_joints != lower.shape[0]:
        raise InputError(
            f"task {task.name!r} has {task.n_joints} joints, the model has {lower.shape[0]}"
        )
    postures = task.postures()
    outside = (postures < lower) | (postures > upper)
    if outside.any():
        row, j = np.argwhere(outside)[0]
        raise InputError(
            f"task {task.name!r}: posture {row} puts joint {model.joint_names[j]!r} at "
            f"{postures[row, j]} rad, outside [{lower[j]}, {upper[j]}]"
        )
