"""Sheath friction compensation in tension space: the inverse of a sheath that sticks.

A cable pulled through a sheath (a Bowden tube) with friction coefficient ``mu`` over a wrap
angle ``Theta`` delivers at its insertion between ``exp(-mu Theta)`` and ``exp(mu Theta)``
times the tension at the motor: the first while it slides towards the motor (pulled in), the
second while it slides out (paid out), anything in between while it sticks. This is the
capstan law with static friction of the plant (:mod:`msarm.plant.cable_kernel`) and of the
diagnosis's ``capstan_hysteresis`` term. To the joint controller the band is a dead zone. At
a hold, the wanted tension has to change by up to ``F (exp(2 mu Theta) - 1)`` before the
insertion feels it. So the joints stop short of their targets until the integral action has
crossed the band, and then they jump: the stick-slip that sets the default plant's final
error.

:class:`SheathInverse` asks the drive for the tension that makes the insertion receive what
the controller wants, ``F`` (the allocated muscle force of that tick)::

    T_cmd = F exp(g mu Theta(q_r) s)

``s`` in [-1, 1] is where the sheath's friction stands in its band: +1 once the cable has
been sliding towards the motor, -1 once it has been sliding out. It is a stop operator
(elastic-perfectly-plastic: it follows its input with unit slope between its bounds) of the
cable length the motor has to pull through the sheath, ``u = c_s F_bar - l(q_r)`` [m]:

- ``-l(q_r)``: the reference path's shortening;
- ``c_s F_bar``: the extra stretch of the cable beyond the sheath, ``c_s`` its compliance
  [m/N] and ``F_bar`` the wanted tension through a first-order low-pass of time constant
  ``filter_time``. The low-pass keeps the encoder noise that the joint PID passes on to
  ``F`` from turning the memory over.

It is updated as::

    s <- clip(s + (u - u_prev) / w, -1, 1)

``w`` [m] is the travel over which the friction turns over. A smaller ``w`` shrinks the dead
zone that is left, ``2 w / c_s`` in tension, and makes the stage quicker to turn, so less
stable.

The stage uses only the controller's wanted tension and the task's reference: it is a
feedforward in tension space and reads no sensor. Its inputs are those of the tick, so the
PID's feedback reaches it through ``F``.

The gain ``g <= 1`` compensates a share of the identified friction. The part left over
damps, where over-compensation (a negative friction) would drive the cables into oscillation.
``mu`` and the cable compliance are identified from logs by :mod:`msarm.compensation.identify`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.compensation.sheath_kernel import sheath_tick
from msarm.errors import InputError
from msarm.io.config import check_field_types
from msarm.model import RobotModel
from msarm.muscle.batch_kinematics import cable_kinematics_batch, current_wrap_angles
from msarm.muscle.geometry import cable_kinematics

__all__ = ["SheathInverse", "SheathParameters", "SheathSpec"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SheathSpec:
    """Settings of the sheath stage (the ``sheath:`` block of a compensator recipe).

    The defaults were chosen on the validation tasks ``random-3000`` ... ``random-3011`` with
    the recipe's gains (README): narrower memories or less filtering turn the stage over on
    the sensor noise (``w`` = 0.02 mm with 0.01 s diverged on one task), wider ones leave
    more of the dead zone, and ``g = 1`` did worse than 0.9 with the identified ``mu``.

    Attributes:
        enabled: Identify the sheath's friction and compensate it.
        width: Cable travel ``w`` over which the friction turns over [m] (> 0).
        gain: Share ``g`` of the identified friction that is compensated [-], in (0, 1].
        filter_time: Time constant of the low-pass on the wanted tension [s] (>= 0; 0: none).
        compliance_share: Share of the cable's identified compliance that lies beyond the
            sheath, ``c_s = compliance_share * c`` [-], in [0, 1]: the sheath's friction
            sits between the motor and the insertion, and only the stretch beyond it moves
            the cable through the sheath.
        floor: Lowest tension command the stage sends [N] (>= 0; 0: no bound). While a cable
            pays out, the stage asks its motor for ``F exp(-g mu Theta)``, less than the
            allocation's floor, because the sheath then delivers more at the insertion. A
            robot whose drives must stay above a tension at the motor sets it here (README:
            measured, it gives back a little of the final error).
    """

    enabled: bool = True
    width: float = 4e-5
    gain: float = 0.9
    filter_time: float = 0.02
    compliance_share: float = 0.5
    floor: float = 0.0

    def __post_init__(self) -> None:
        check_field_types(self)
        if not (np.isfinite(self.width) and self.width > 0):
            raise ValueError(f"sheath width must be > 0 [m], got {self.width}")
        if not (0 < self.gain <= 1):
            raise ValueError(f"sheath gain must be in (0, 1], got {self.gain}")
        if not (np.isfinite(self.filter_time) and self.filter_time >= 0):
            raise ValueError(f"sheath filter_time must be >= 0 [s], got {self.filter_time}")
        if not (0 <= self.compliance_share <= 1):
            raise ValueError(
                f"sheath compliance_share must be in [0, 1], got {self.compliance_share}"
            )
        if not (np.isfinite(self.floor) and self.floor >= 0):
            raise ValueError(f"sheath floor must be a finite tension >= 0 [N], got {self.floor}")


@dataclass(frozen=True)
class SheathParameters:
    """What the logs say about the sheaths and the cables (see ``identify``).

    Attributes:
        mu: Capstan friction coefficient of the sheaths [-] (one, shared by the cables).
        compliance: Compliance of a whole cable [m/N] (0 for rigid cables).
        mu_share: Held-out share of the joint-torque residual the capstan term explains.
        compliance_share: Held-out share of the cable length residual the elasticity term
            explains (NaN when the logs have no length residual).
    """

    mu: float
    compliance: float
    mu_share: float = float("nan")
    compliance_share: float = float("nan")

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mu) and self.mu >= 0):
            raise ValueError(f"sheath mu must be a finite value >= 0, got {self.mu}")
        if not (np.isfinite(self.compliance) and self.compliance >= 0):
            raise ValueError(
                f"cable compliance must be a finite value >= 0 [m/N], got {self.compliance}"
            )

    def as_dict(self) -> dict[str, float]:
        """Plain-data form for checkpoints (NaN as None)."""
        return {k: (None if np.isnan(v) else float(v)) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, raw: dict) -> SheathParameters:
        """Inverse of :meth:`as_dict`."""
        return cls(**{k: float("nan") if v is None else float(v) for k, v in raw.items()})


class SheathInverse:
    """The sheath stage for one run at a time (see the module docstring).

    Args:
        model: The nominal robot model (reference path lengths and wrap angles).
        spec: The stage's settings.
        parameters: The identified friction and compliance.
        period: Control period [s] (the low-pass's step).
    """

    def __init__(
        self,
        model: RobotModel,
        spec: SheathSpec,
        parameters: SheathParameters,
        period: float,
    ) -> None:
        self.model, self.spec, self.parameters = model, spec, parameters
        self.run_at(period)
        self._data = model.create_data()
        self._jacobian = np.zeros((model.n_cables, model.n_joints))
        self._stretch = spec.compliance_share * parameters.compliance
        self._friction = spec.gain * parameters.mu
        # F_bar, u of the last tick, s, and "started" (row 3, column 0): sheath_tick's state
        self._state = np.zeros((4, model.n_cables))

    def run_at(self, period: float) -> None:
        """Tick at ``period`` [s], the running controller's (the low-pass's step follows it).

        Raises:
            InputError: ``period`` not a finite time > 0.
        """
        if not (np.isfinite(period) and period > 0):
            raise InputError(f"period must be > 0 [s], got {period}")
        self.period = float(period)
        self._alpha = self.period / (self.spec.filter_time + self.period)

    @property
    def side(self) -> FloatArray:
        """``s`` of every cable [-], ``(m,)``: where each sheath's friction stands (0 at rest)."""
        if self._state[3, 0] == 0.0:
            return np.zeros(self.model.n_cables)
        return self._state[2].copy()

    def reset(self) -> None:
        """Start a new run: the next call starts the filter and ``s = 0`` (mid-band)."""
        self._state[:] = 0.0

    def check_inputs(self, tension: ArrayLike, q_ref: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``tension`` and ``q_ref`` as float arrays, checked as :meth:`__call__` checks them.

        Raises:
            InputError: A shape that is not ``(m,)`` / ``(n,)``, a non-finite value or a
                negative tension.
        """
        m, n = self.model.n_cables, self.model.n_joints
        force = np.asarray(tension, dtype=float)
        posture = np.asarray(q_ref, dtype=float)
        if force.shape != (m,) or posture.shape != (n,):
            raise InputError(
                f"sheath stage: tension must have shape ({m},) and q_ref ({n},), "
                f"got {force.shape} and {posture.shape}"
            )
        if not (np.all(np.isfinite(force)) and np.all(np.isfinite(posture))):
            raise InputError(f"sheath stage: non-finite tension {force} or q_ref {posture}")
        if np.any(force < 0):
            raise InputError(f"sheath stage: tensions must be >= 0 [N], got {force}")
        return force, posture

    def reference_geometry(self, q_ref: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Cable lengths [m] and wrap angles [rad] of every reference posture, each ``(T, m)``.

        Row ``k`` is what :meth:`__call__` computes at ``q_ref[k]`` (MuJoCo's same functions,
        so the same bits): the compiled loop takes them from here.

        Args:
            q_ref: Reference joint angles [rad], ``(T, n)``.
        """
        kinematics = cable_kinematics_batch(self.model, q_ref)
        return kinematics.lengths, kinematics.wrap_angles

    @property
    def constants(self) -> tuple[float, float, float, float, float]:
        """``(alpha, c_s, w, g mu, floor)``: :func:`sheath_tick`'s constants for this stage."""
        spec = self.spec
        return self._alpha, self._stretch, float(spec.width), self._friction, float(spec.floor)

    @property
    def state(self) -> FloatArray:
        """The stage's state ``(4, m)`` (see :func:`sheath_tick`), the array itself.

        The compiled loop runs the stage on it, so a run leaves the stage as the Python loop
        would.
        """
        return self._state

    def __call__(self, tension: ArrayLike, q_ref: ArrayLike) -> FloatArray:
        """The drive's tension command of this tick [N], ``(m,)``.

        Args:
            tension: The tension the controller wants at the insertions [N], ``(m,)``, >= 0.
            q_ref: The reference posture of this tick [rad], ``(n,)``.

        Raises:
            InputError: A shape that is not ``(m,)`` / ``(n,)``, a non-finite value or a
                negative tension.
        """
        force, posture = self.check_inputs(tension, q_ref)
        lengths = cable_kinematics(self.model.mj_model, self._data.mj, posture, self._jacobian)
        wrap = current_wrap_angles(self.model.mj_model, self._data.mj)
        alpha, stretch, width, friction, floor = self.constants
        command = np.empty_like(force)
        sheath_tick(
            force, lengths, wrap, alpha, stretch, width, friction, floor, self._state, command
        )
        return command
