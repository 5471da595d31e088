"""Joint-space reference trajectories: minimum-jerk moves separated by holds.

A :class:`Task` starts at its ``home`` posture and is a sequence of :class:`Move` s; each move
goes from the previous target (or ``home``) to its own target along a minimum-jerk profile
(zero velocity and acceleration at both ends) and the reference then holds that target until
the next move starts. Times in seconds, angles in radians, arrays in the model's joint order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

__all__ = [
    "HOME_POSTURE",
    "MIN_FINAL_HOLD",
    "MIN_HOLD",
    "MOVE_TIME_RANGE",
    "Move",
    "Task",
    "hold_then_move",
    "minimum_jerk",
    "random_reach_task",
]

FloatArray = NDArray[np.float64]

#: Home posture of the arm [rad], joint order (abduction, flexion, rotation, elbow): the arm
#: hanging, elbow slightly flexed.
HOME_POSTURE: FloatArray = np.array([0.0, 0.0, 0.0, -0.2])
HOME_POSTURE.flags.writeable = False

#: Range of the durations of the moves of a random reach task [s].
MOVE_TIME_RANGE = (1.5, 3.0)
#: Shortest hold before each move of a random reach task [s].
MIN_HOLD = 0.5
#: Shortest final hold of a random reach task [s].
MIN_FINAL_HOLD = 5.0


def _numbers(value: ArrayLike, name: str) -> FloatArray:
    """``value`` as a float array; a value that is not numbers is refused by name."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numbers, got {value!r} ({exc})") from None


def _vector(value: ArrayLike, name: str, n: int | None = None) -> FloatArray:
    arr = _numbers(value, name)
    if arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim != 1 or (n is not None and arr.shape != (n,)):
        want = f"({n},)" if n is not None else "(n,)"
        raise InputError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} must be finite, got {arr}")
    return arr


def _times(t: ArrayLike) -> tuple[FloatArray, bool]:
    """``t`` as a 1-D float array, and whether it was a scalar."""
    arr = _numbers(t, "t")
    if arr.ndim > 1:
        raise InputError(f"t must be a scalar or of shape (T,), got {arr.shape}")
    if np.isnan(arr).any():
        raise InputError("t has NaN")
    return arr.reshape(-1), arr.ndim == 0


def minimum_jerk(
    q0: ArrayLike, q1: ArrayLike, duration: float, t: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Minimum-jerk move from ``q0`` to ``q1`` (Flash and Hogan's quintic).

    With ``s = t / duration`` clipped to [0, 1] and ``d = q1 - q0``:
    ``q = q0 + d (10 s^3 - 15 s^4 + 6 s^5)``, ``qd = d (30 s^2 - 60 s^3 + 30 s^4) / duration``,
    ``qdd = d (60 s - 180 s^2 + 120 s^3) / duration^2``: velocity and acceleration are zero at
    both ends; before ``t = 0`` the position is ``q0``, from ``duration`` on it is ``q1``
    exactly.

    Args:
        q0: Start posture, shape ``(n,)`` (a scalar counts as ``n = 1``).
        q1: End posture, shape ``(n,)``.
        duration: Duration of the move [s], > 0.
        t: Time(s) since the start of the move [s], scalar or shape ``(T,)``.

    Returns:
        ``(q, qd, qdd)`` [rad, rad/s, rad/s^2], each of shape ``(T, n)``, or ``(n,)`` for a
        scalar ``t``.

    Raises:
        InputError: Shapes differ, a value is not finite, or ``duration <= 0``.
    """
    q0 = _vector(q0, "q0")
    q1 = _vector(q1, "q1", q0.shape[0])
    duration = float(duration)
    if not (np.isfinite(duration) and duration > 0):
        raise InputError(f"duration must be finite and > 0 [s], got {duration}")
    times, scalar = _times(t)
    s = np.clip(times / duration, 0.0, 1.0)[:, None]
    d = (q1 - q0)[None, :]
    s2 = s * s
    s3 = s2 * s
    # After the move the position is q1 exactly (q0 + d may differ from q1 by rounding).
    q = np.where(s >= 1.0, q1, q0 + d * (s3 * (10.0 - 15.0 * s + 6.0 * s2)))
    qd = d * (s2 * (30.0 - 60.0 * s + 30.0 * s2)) / duration
    qdd = d * (s * (60.0 - 180.0 * s + 120.0 * s2)) / duration**2
    if scalar:
        return q[0], qd[0], qdd[0]
    return q, qd, qdd


@dataclass(frozen=True, eq=False)
class Move:
    """One minimum-jerk move of a task (then a hold at its target until the next move).

    Attributes:
        start: Start time of the move [s].
        duration: Duration of the move [s], > 0.
        target: Posture at the end of the move [rad], shape ``(n,)`` (read-only).
    """

    start: float
    duration: float
    target: FloatArray

    def __post_init__(self) -> None:
        if not (np.isfinite(self.start) and self.start >= 0):
            raise InputError(f"move start must be finite and >= 0 [s], got {self.start}")
        if not (np.isfinite(self.duration) and self.duration > 0):
            raise InputError(f"move duration must be finite and > 0 [s], got {self.duration}")
        target = _vector(self.target, "move target").copy()
        target.flags.writeable = False
        object.__setattr__(self, "start", float(self.start))
        object.__setattr__(self, "duration", float(self.duration))
        object.__setattr__(self, "target", target)

    @property
    def end(self) -> float:
        """End time of the move [s]."""
        return self.start + self.duration

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Move):
            return NotImplemented
        return (
            self.start == other.start
            and self.duration == other.duration
            and np.array_equal(self.target, other.target)
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class Task:
    """A tracking task: a joint-space reference made of minimum-jerk moves and holds.

    Attributes:
        name: Task name (e.g. ``"table1-1"``, ``"random-7"``).
        duration: Length of the task [s].
        home: Start posture [rad], shape ``(n,)`` (read-only).
        moves: The moves, in time order, not overlapping, all ending by ``duration``.
    """

    name: str
    duration: float
    home: FloatArray
    moves: tuple[Move, ...]

    def __post_init__(self) -> None:
        if not (np.isfinite(self.duration) and self.duration > 0):
            raise InputError(f"task duration must be finite and > 0 [s], got {self.duration}")
        home = _vector(self.home, "home").copy()
        home.flags.writeable = False
        object.__setattr__(self, "home", home)
        object.__setattr__(self, "duration", float(self.duration))
        moves = tuple(self.moves)
        object.__setattr__(self, "moves", moves)
        previous_end = 0.0
        for k, move in enumerate(moves):
            if not isinstance(move, Move):
                raise InputError(f"moves[{k}] must be a Move, got {type(move).__name__}")
            if move.target.shape != home.shape:
                raise InputError(
                    f"moves[{k}].target has shape {move.target.shape}, home has {home.shape}"
                )
            if move.start < previous_end:
                raise InputError(
                    f"moves[{k}] starts at {move.start} s, before the previous move ends "
                    f"({previous_end} s)"
                )
            previous_end = move.end
        if previous_end > self.duration:
            raise InputError(
                f"the last move ends at {previous_end} s, after the task's {self.duration} s"
            )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Task):
            return NotImplemented
        return (
            self.name == other.name
            and self.duration == other.duration
            and np.array_equal(self.home, other.home)
            and self.moves == other.moves
        )

    __hash__ = None  # type: ignore[assignment]

    @property
    def n_joints(self) -> int:
        """Number of joints ``n``."""
        return self.home.shape[0]

    @property
    def target(self) -> FloatArray:
        """Final posture [rad], shape ``(n,)``: the last move's target (``home`` if none)."""
        return self.moves[-1].target if self.moves else self.home

    def postures(self) -> FloatArray:
        """Home and every move's target [rad], shape ``(1 + len(moves), n)``.

        Returns:
            ``home`` then the moves' targets in time order [rad], shape
            ``(1 + len(moves), n)``, a new array.
        """
        return np.vstack([self.home, *(m.target for m in self.moves)])

    def reference(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The reference at time(s) ``t``.

        Before the first move the reference is ``home``; after the last one (also beyond
        ``duration``) it holds :attr:`target`.

        Args:
            t: Time(s) since the start of the task [s], scalar or shape ``(T,)``.

        Returns:
            ``(q, qd, qdd)`` [rad, rad/s, rad/s^2], each ``(T, n)``, or ``(n,)`` for scalar t.
        """
        times, scalar = _times(t)
        n = self.n_joints
        q = np.broadcast_to(self.home, (times.shape[0], n)).copy()
        qd = np.zeros_like(q)
        qdd = np.zeros_like(q)
        if self.moves:
            starts = np.array([m.start for m in self.moves])
            # Index of the last move started at each time (-1: none yet).
            k_of_t = np.searchsorted(starts, times, side="right") - 1
            postures = self.postures()
            for k in np.unique(k_of_t[k_of_t >= 0]):
                move = self.moves[k]
                rows = k_of_t == k
                q[rows], qd[rows], qdd[rows] = minimum_jerk(
                    postures[k], move.target, move.duration, times[rows] - move.start
                )
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd


#: Length of a ``random-<seed>`` task [s] (paper 003's runs: 20 s).
RANDOM_TASK_DURATION = 20.0


def random_reach_task(
    seed: int,
    lower: ArrayLike,
    upper: ArrayLike,
    duration: float = RANDOM_TASK_DURATION,
    n_moves: int = 3,
    margin: float = 0.15,
    home: ArrayLike = HOME_POSTURE,
) -> Task:
    """A seeded random reaching task inside the joint range.

    Draws, from ``np.random.default_rng(seed)``: ``n_moves`` targets uniform in the joint
    range shrunk by ``margin`` of its width at each end; the move durations uniform in
    :data:`MOVE_TIME_RANGE`; the holds: each move is preceded by a hold of at least
    :data:`MIN_HOLD` and the task ends with a hold of at least :data:`MIN_FINAL_HOLD`, the
    spare time split among them by a flat Dirichlet draw.

    Args:
        seed: Non-negative integer seed; the same seed gives the same task, bit for bit.
        lower: Lower joint limits [rad], shape ``(n,)``.
        upper: Upper joint limits [rad], shape ``(n,)``.
        duration: Task length [s].
        n_moves: Number of moves, >= 1.
        margin: Fraction of each joint's range kept free at each end, in [0, 0.5).
        home: Start posture [rad], shape ``(n,)``; default :data:`HOME_POSTURE`.

    Returns:
        The task, named ``random-<seed>``.

    Raises:
        InputError: Bad limits, margin, count or seed, or a duration too short for the moves
            and holds.
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    lower = _vector(lower, "lower")
    upper = _vector(upper, "upper", lower.shape[0])
    home = _vector(home, "home", lower.shape[0])
    if not (upper > lower).all():
        raise InputError(f"upper must exceed lower at every joint: lower={lower}, upper={upper}")
    if not ((home >= lower) & (home <= upper)).all():
        j = int(np.argmax((home < lower) | (home > upper)))
        raise InputError(
            f"home must lie in the joint range: joint {j} is {home[j]:g} rad, outside "
            f"[{lower[j]:g}, {upper[j]:g}]"
        )
    if not math.isfinite(duration):
        raise InputError(f"duration must be a finite time [s], got {duration}")
    if not 0.0 <= margin < 0.5:
        raise InputError(f"margin must be in [0, 0.5), got {margin}")
    if isinstance(n_moves, bool) or not isinstance(n_moves, int) or n_moves < 1:
        raise InputError(f"n_moves must be an integer >= 1, got {n_moves!r}")
    width = upper - lower
    lo = lower + margin * width
    hi = upper - margin * width
    rng = np.random.default_rng(int(seed))
    targets = rng.uniform(lo, hi, size=(n_moves, lower.shape[0]))
    move_times = rng.uniform(*MOVE_TIME_RANGE, size=n_moves)
    spare = duration - move_times.sum() - n_moves * MIN_HOLD - MIN_FINAL_HOLD
    if spare < 0:
        raise InputError(
            f"duration {duration} s is too short for {n_moves} moves of "
            f"{move_times.sum():.2f} s, holds of {MIN_HOLD} s and a final hold of "
            f"{MIN_FINAL_HOLD} s"
        )
    shares = spare * rng.dirichlet(np.ones(n_moves + 1))
    moves = []
    clock = 0.0
    for k in range(n_moves):
        clock += MIN_HOLD + shares[k]
        moves.append(Move(start=clock, duration=float(move_times[k]), target=targets[k]))
        clock += move_times[k]
    return Task(name=f"random-{int(seed)}", duration=duration, home=home, moves=tuple(moves))


def hold_then_move(
    name: str, home: ArrayLike, target: ArrayLike, wait: float, move_time: float, duration: float
) -> Task:
    """A task of one move: hold ``home`` for ``wait``, move in ``move_time``, hold to the end.

    Args:
        name: Task name.
        home: Start posture [rad], shape ``(n,)``.
        target: End posture [rad], shape ``(n,)``.
        wait: Hold before the move [s].
        move_time: Duration of the minimum-jerk move [s].
        duration: Task length [s].

    Returns:
        The task.
    """
    return Task(name=name, duration=duration, home=home, moves=(Move(wait, move_time, target),))
