"""Tracking tasks: reference trajectories, the named tasks, and the metrics of paper 003."""

from msarm.tasks import metrics
from msarm.tasks.registry import TABLE1_TARGETS, get_task, list_tasks
from msarm.tasks.trajectories import (
    HOME_POSTURE,
    Move,
    Task,
    minimum_jerk,
    random_reach_task,
)

__all__ = [
    "HOME_POSTURE",
    "TABLE1_TARGETS",
    "Move",
    "Task",
    "get_task",
    "list_tasks",
    "metrics",
    "minimum_jerk",
    "random_reach_task",
]
