"""Candidate effects of the drives and cables: terms for the drive and cable-length residuals.

The joint-torque terms of :mod:`msarm.diagnose.effects` explain what is lost between the load
cells and the joints. What happens between the controller's tension command and the load cell
(winch friction, cogging, delay, a load-cell error) and between the motor encoder and the
cable's path (elastic stretch) shows in two other channel groups (see
:mod:`msarm.diagnose.builder`):

- ``"drive"`` [N], ``(T, m)``: ``e = F - F_cmd``, the load-cell tension minus the command it
  answers. The nominal drive renders each command exactly. A drive that closes its tension
  loop on the load cell with gain ``K`` (``tau_m = rho (F_cmd + K (F_cmd - F))``) and a winch
  torque ``tau_w`` (friction, cogging) settles at ``e = tau_w / (rho (1 + K))`` (drum radius
  ``rho``): a quasi-static winch; its inertia adds ``-J domega/dt / (rho (1 + K))``.
- ``"length"`` [m], ``(T, m)``: the cable length the motor encoder says minus the path length
  of the logged posture, minus its mean over each run (the encoder gives lengths up to an
  offset per run). Zero for rigid cables.

Terms here follow the same interface as the joint terms (``design`` of shape ``(T, W, p)``
with ``W`` the width of the term's groups), so the same fitting and selection apply. Motor
angle ``theta`` is positive when the winch reels cable in (as the plant and logs have it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.effects import CandidateEffect, register
from msarm.diagnose.signals import Signals, direction_memory
from msarm.errors import InputError

__all__ = [
    "CableBacklash",
    "CableElasticity",
    "CableSheathStretch",
    "CableSlack",
    "CommandDelay",
    "DriveCogging",
    "EncoderSkew",
    "WinchFriction",
]

FloatArray = NDArray[np.float64]


def _drive_factor(drum_radius: float, drive_gain: float) -> float:
    """``1 / (rho (1 + K))``: tension error [N] per winch torque [N m] of a settled drive."""
    if not drum_radius > 0:
        raise InputError(f"drum_radius: expected > 0 m, got {drum_radius}")
    if not drive_gain >= 0:
        raise InputError(f"drive_gain: expected >= 0, got {drive_gain}")
    return 1.0 / (drum_radius * (1.0 + drive_gain))


def _per_cable_or_shared(columns: list[FloatArray], shared: bool) -> FloatArray:
    """``(T, m)`` feature columns -> a ``(T, m, p)`` design, per cable or shared."""
    T, m = columns[0].shape
    if shared:
        return np.stack(columns, axis=2)
    out = np.zeros((T, m, m * len(columns)))
    for k, column in enumerate(columns):
        for c in range(m):
            out[:, c, c * len(columns) + k] = column[:, c]
    return out


def _names(kinds: Sequence[str], shared: bool, n_cables: int) -> tuple[str, ...]:
    cables = ("all",) if shared else tuple(str(c) for c in range(n_cables))
    return tuple(f"{k}[{c}]" for c in cables for k in kinds)


@register
class WinchFriction(CandidateEffect):
    """Coulomb + viscous friction of winch and motor, on the drive.

    Paper 000 eq. 4-5 without its load term and its ``v^2`` term.

    ``tau_f = -tau_c tanh(omega / omega_s) - b omega`` on each winch (motor speed ``omega``);
    through a settled drive ``e = tau_f / (rho (1 + K))``. Linear in ``tau_c`` [N m] and ``b``
    [N m s/rad], shared by all winches or per winch; ``omega_s`` [rad/s] is fixed.
    """

    indexed_by = "cable"
    name = "winch_friction"
    constant_symbols: ClassVar[Mapping[str, str]] = {
        "rho": "drum_radius",
        "K": "drive_gain",
        "omega_s": "smoothing_speed",
    }
    parameter_units: ClassVar[Mapping[str, str]] = {"coulomb": "N m", "viscous": "N m s/rad"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"coulomb", "viscous"})
    description = (
        "e = -(tau_c tanh(omega/omega_s) + b omega) / (rho (1 + K)): Coulomb + viscous friction "
        "of winch and motor, seen as a tension error of the drive"
    )
    linear = True
    groups = ("drive",)

    def __init__(
        self,
        drum_radius: float,
        drive_gain: float,
        n_cables: int = 9,
        smoothing_speed: float = 0.5,
        shared: bool = True,
    ) -> None:
        """Build the term.

        Args:
            drum_radius: Drum radius ``rho`` [m].
            drive_gain: Gain ``K`` of the drive's tension loop [-].
            n_cables: Number of cables ``m``.
            smoothing_speed: ``omega_s`` of the smoothed sign [rad/s].
            shared: One pair of coefficients for all winches.
        """
        self.factor = _drive_factor(drum_radius, drive_gain)
        self.drum_radius, self.drive_gain = float(drum_radius), float(drive_gain)
        if not smoothing_speed > 0:
            raise InputError(f"smoothing_speed: expected > 0 rad/s, got {smoothing_speed}")
        self.smoothing_speed = float(smoothing_speed)
        self.n_cables, self.shared = int(n_cables), bool(shared)
        self.channels = tuple(range(self.n_cables))
        self.parameter_names = _names(("coulomb", "viscous"), self.shared, self.n_cables)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_cables(signals, self.n_cables)
        omega = signals.require("motor_speed", self.name)
        columns = [
            -self.factor * np.tanh(omega / self.smoothing_speed),
            -self.factor * omega,
        ]
        return _per_cable_or_shared(columns, self.shared)


@register
class DriveCogging(CandidateEffect):
    """Motor cogging torque, periodic in the motor angle (paper 001 eq. 2-3), on the drive.

    ``tau_cog = A sin(N theta + phi) = a sin(N theta) + b cos(N theta)`` with ``a = A cos
    phi``, ``b = A sin phi`` [N m]; through a settled drive ``e = tau_cog / (rho (1 + K))``.
    Linear in ``(a, b)`` for a known number ``N`` of periods per revolution, shared by all
    motors (identical motors, one phase) or per motor.
    """

    indexed_by = "cable"
    name = "motor_cogging"
    constant_symbols: ClassVar[Mapping[str, str]] = {
        "N": "n_periods",
        "rho": "drum_radius",
        "K": "drive_gain",
    }
    parameter_units: ClassVar[Mapping[str, str]] = {"cogging_a": "N m", "cogging_b": "N m"}
    description = (
        "e = (a sin(N theta) + b cos(N theta)) / (rho (1 + K)) (amplitude hypot(a, b)): motor "
        "cogging torque periodic in the motor angle theta, seen as a tension error of the drive"
    )
    linear = True
    groups = ("drive",)

    def __init__(
        self,
        n_periods: int,
        drum_radius: float,
        drive_gain: float,
        n_cables: int = 9,
        shared: bool = True,
    ) -> None:
        """Build the term.

        Args:
            n_periods: Cogging periods per motor revolution ``N``.
            drum_radius: Drum radius ``rho`` [m].
            drive_gain: Gain ``K`` of the drive's tension loop [-].
            n_cables: Number of cables ``m``.
            shared: One amplitude-phase pair for all motors.
        """
        if int(n_periods) < 1:
            raise InputError(f"n_periods: expected an integer >= 1, got {n_periods}")
        self.n_periods = int(n_periods)
        self.factor = _drive_factor(drum_radius, drive_gain)
        self.drum_radius, self.drive_gain = float(drum_radius), float(drive_gain)
        self.n_cables, self.shared = int(n_cables), bool(shared)
        self.channels = tuple(range(self.n_cables))
        self.parameter_names = _names(("cogging_a", "cogging_b"), self.shared, self.n_cables)

    def parameter_groups(self) -> tuple[tuple[int, ...], ...]:
        """None: the sine and cosine parts make one amplitude and phase together."""
        return ()

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_cables(signals, self.n_cables)
        # the motor speed is there exactly when every log has its motor angles (else they
        # would be zeros standing in for the missing columns)
        signals.require("motor_speed", self.name)
        angle = self.n_periods * signals.motor_angle
        columns = [self.factor * np.sin(angle), self.factor * np.cos(angle)]
        return _per_cable_or_shared(columns, self.shared)

    @staticmethod
    def amplitude_phase(a: float, b: float) -> tuple[float, float]:
        """``(A [N m], phi [rad])`` of fitted ``(a, b)``."""
        return float(np.hypot(a, b)), float(np.arctan2(b, a))


@register
class CommandDelay(CandidateEffect):
    """A delay between the tension command and the measured tension, as a short FIR kernel.

    The load cell reads a weighted mix of past commands (a drive that acts late, a reading
    that arrives late, or a lag): ``F(t_k) = sum_j w_j F_cmd(t_{k-j}) + (1 - sum_j w_j)
    F_cmd(t_k)`` for ``j = 1..J`` samples (``F_cmd`` the aligned command), so

    ``e_k = sum_j w_j (F_cmd(t_{k-j}) - F_cmd(t_k))``.

    Linear in the weights ``w_j`` [-]; a pure delay of ``s`` samples is ``w_s = 1`` (exact, as
    commands change from sample to sample with the controller's noise, which a first-order
    ``-d dF/dt`` term would miss), a fractional one splits between two taps. The delay is
    ``d = dt sum_j j w_j`` [s] (:meth:`delay`). Samples before a segment's start (a run's, or
    the end of a time gap's) repeat its first.
    """

    name = "command_delay"
    parameter_units: ClassVar[Mapping[str, str]] = {"w": "-"}
    description = (
        "e = sum_j w_j (F_cmd(t - j dt) - F_cmd(t)): tensions follow their commands late "
        "(delay d = dt sum_j j w_j)"
    )
    linear = True
    groups = ("drive",)

    def __init__(self, n_cables: int = 9, taps: int = 4) -> None:
        """Build the term.

        Args:
            n_cables: Number of cables ``m``.
            taps: Number of past samples ``J`` (the longest delay it can express).
        """
        if int(taps) < 1:
            raise InputError(f"taps: expected an integer >= 1, got {taps}")
        self.n_cables, self.taps = int(n_cables), int(taps)
        self.channels = tuple(range(self.n_cables))
        self.parameter_names = tuple(f"w[{j}]" for j in range(1, self.taps + 1))

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_cables(signals, self.n_cables)
        command = signals.require("tension_cmd", self.name)
        out = np.zeros(command.shape + (self.taps,))
        for label in np.unique(signals.segment):
            index = np.flatnonzero(signals.segment == label)
            run = command[index]
            for j in range(1, self.taps + 1):
                past = np.concatenate([np.repeat(run[:1], min(j, len(run)), axis=0), run[:-j]])
                out[index, :, j - 1] = past[: len(run)] - run
        return out

    def parameter_groups(self) -> tuple[tuple[int, ...], ...]:
        """Each tap alone, the last first: a delay the logs do not need is left out tap by tap."""
        return tuple((j,) for j in reversed(range(self.taps)))

    def delay(self, theta: Sequence[float], dt: float) -> float:
        """The delay ``d = dt sum_j j w_j`` [s] of fitted weights (sample period ``dt`` [s])."""
        weights = np.asarray(theta, dtype=float)
        return float(dt * np.sum(np.arange(1, weights.size + 1) * weights))


@register
class CableElasticity(CandidateEffect):
    """Elastic cables: the encoder's length differs from the path by the cable's stretch.

    A taut cable of compliance ``c = 1/k`` [m/N] is stretched by ``c F``; the motor encoder,
    which measures the unstretched length paid out, then says ``l_hat = l(q) - c F + const``,
    so the run-demeaned length error is ``-c (F - mean_run(F))``. Linear in ``c``, shared by
    all cables or per cable. A slack cable (``F = 0``) has an unmeasured negative stretch the
    term cannot explain: slack shows as what is left.

    The regressor is the load cells' reading, noise and all, so the least squares is biased
    towards zero by about ``sigma^2 / var(F - mean_run F)`` (errors in variables), which a
    bootstrap over runs does not see: a review (2026-11-29, six seeded plants with 0.3 N of
    load-cell noise) measured errors of -0.09 to -0.19 % against a bootstrap std of
    0.03-0.06 %, and a predicted attenuation of -0.07 to -0.18 %.
    """

    indexed_by = "cable"
    name = "elasticity"
    parameter_units: ClassVar[Mapping[str, str]] = {"compliance": "m/N"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"compliance"})
    description = (
        "e_l = -c (F - mean_run F): cable stretch of compliance c = 1/k [m/N] between the "
        "encoder's length and the path length (slack is what is left)"
    )
    linear = True
    groups = ("length",)

    def __init__(self, n_cables: int = 9, shared: bool = True) -> None:
        """Build the term.

        Args:
            n_cables: Number of cables ``m``.
            shared: One compliance for all cables.
        """
        self.n_cables, self.shared = int(n_cables), bool(shared)
        self.channels = tuple(range(self.n_cables))
        self.parameter_names = _names(("compliance",), self.shared, self.n_cables)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_cables(signals, self.n_cables)
        tension = signals.tension
        return _per_cable_or_shared([-(tension - signals.run_mean(tension))], self.shared)


@register
class EncoderSkew(CandidateEffect):
    """The joint encoders and the motor encoders read at different instants.

    Joint encoders that read ``delta`` [s] after the motor encoders (before, for
    ``delta < 0``) see the posture the cables reach ``delta`` later, so the path length the
    residual takes from them is ``l(q(t + delta)) = l(q(t)) + delta ldot`` to first order,
    with the cable speed ``ldot = J_c(q) qd`` [m/s] of the logged motion: ``e_l = -delta
    (ldot - mean_run ldot)``, demeaned per run like the length residual. Linear in
    ``delta``, shared by all cables (the two sensor sets are read by one clock each).
    Sensors on different buses, or a simulation that reads its cables' state one step
    before its joints', show it; a cable length error in phase with the cables' speed, not
    with their tension, is its mark.
    """

    name = "encoder_skew"
    parameter_units: ClassVar[Mapping[str, str]] = {"skew": "s"}
    description = (
        "e_l = -delta (ldot - mean_run ldot): the joint encoders read delta [s] after the "
        "motor encoders, ldot = J_c(q) qd the cables' speed"
    )
    linear = True
    groups = ("length",)

    def __init__(self, n_cables: int = 9) -> None:
        """Build the term.

        Args:
            n_cables: Number of cables ``m``.
        """
        self.n_cables = int(n_cables)
        self.channels = tuple(range(self.n_cables))
        self.parameter_names = ("skew",)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_cables(signals, self.n_cables)
        speed = signals.cable_velocity
        return -(speed - signals.run_mean(speed))[:, :, None]


class _DrumDirectionTerm(CandidateEffect):
    """A cable-length term driven by the drums' direction state (backlash, sheath stretch).

    ``z`` in ``[-1, 1]`` is the direction the drum last moved in, smoothed over a travel ``w``
    [m]: a Dahl-type state ``dz/dt = (v - |v| z) / w`` on the drum's surface speed
    ``v = rho omega`` (positive reeling in), integrated per run from 0.
    """

    indexed_by = "cable"
    linear = True
    groups = ("length",)
    #: The kind of the term's parameter, in its parameter names.
    parameter_kind = ""
    constant_symbols: ClassVar[Mapping[str, str]] = {"rho": "drum_radius", "w": "travel"}

    def __init__(
        self, drum_radius: float, n_cables: int = 9, travel: float = 5e-4, shared: bool = True
    ) -> None:
        """Build the term.

        Args:
            drum_radius: Drum radius ``rho`` [m].
            n_cables: Number of cables ``m``.
            travel: Drum travel ``w`` over which the direction state reverses [m].
            shared: One parameter for all cables.
        """
        if not drum_radius > 0:
            raise InputError(f"drum_radius: expected > 0 m, got {drum_radius}")
        if not travel > 0:
            raise InputError(f"travel: expected > 0 m, got {travel}")
        self.drum_radius, self.travel = float(drum_radius), float(travel)
        self.n_cables, self.shared = int(n_cables), bool(shared)
        self.channels = tuple(range(self.n_cables))
        self.parameter_names = _names((self.parameter_kind,), self.shared, self.n_cables)

    def state(self, signals: Signals) -> FloatArray:
        """The direction state ``z`` [-] of every drum, shape ``(T, m)``."""
        speed = self.drum_radius * signals.require("motor_speed", self.name)
        return direction_memory(speed, signals.t, signals.run, 1.0 / self.travel)


@register
class CableBacklash(_DrumDirectionTerm):
    """Backlash between winch and cable: a play that the cable takes up at each reversal.

    With a play ``b`` [m] the cable end follows the drum only once the play is taken up: it
    lags the drum by ``b / 2`` about the middle of the play, so while the drum reels in
    (``z = +1``, :class:`_DrumDirectionTerm`) the encoder's length is shorter than the path
    length, and longer while it pays out: ``e_l = -(b / 2) z``. Demeaned per run like the
    length residual; linear in ``b`` for a fixed ``w``, shared by all cables or per cable.
    """

    name = "backlash"
    parameter_units: ClassVar[Mapping[str, str]] = {"play": "m"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"play"})
    description = (
        "e_l = -(b/2) (z - mean_run z), dz/dt = (v - |v| z)/w: play b [m] taken up at each "
        "reversal of the drum (travel w to reverse; the cable end lags the drum)"
    )
    parameter_kind = "play"

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_cables(signals, self.n_cables)
        z = self.state(signals)
        return _per_cable_or_shared([-0.5 * (z - signals.run_mean(z))], self.shared)


@register
class CableSheathStretch(_DrumDirectionTerm):
    """An elastic cable in a sheath with friction: it stretches less while pulled in.

    A cable of compliance ``c`` [m/N] that runs through a sheath is stretched on the motor's
    side of the sheath by the load cell's tension ``F`` and on the insertion's side by the
    tension the sheath lets through, ``F exp(-mu Theta z)``: ``z = +1`` while the drum reels
    in (the cable slides towards the motor and the sheath holds part of the tension back),
    ``-1`` while it pays out, in between while the cable sticks (the drum's direction state,
    see :class:`_DrumDirectionTerm`). With half the compliance on either side, the stretch is
    ``(c / 2) F (1 + exp(-mu Theta z))``, to first order in ``mu Theta``
    ``c F - (c mu / 2) Theta z F``. :class:`CableElasticity` explains ``c F``; this term the
    rest, in the length residual: ``e_l = b (Theta z F - mean_run)`` with ``b = c mu / 2``
    [m/N], linear, shared by all cables or per cable. With the elasticity term's ``c``, the
    sheath's friction coefficient is ``mu = 2 b / c``. It is the sheath friction's trace in
    the cable lengths; rigid cables, or cables without sheath friction, leave none.
    """

    name = "sheath_stretch"
    parameter_units: ClassVar[Mapping[str, str]] = {"c_mu_half": "m/N"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"c_mu_half"})
    description = (
        "e_l = b (Theta z F - mean_run), b = c mu / 2: an elastic cable stretches less while "
        "pulled in through a sheath with friction (z: the drum's direction, Theta: wrap angle)"
    )
    parameter_kind = "c_mu_half"

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_cables(signals, self.n_cables)
        held = signals.wrap * self.state(signals) * signals.tension
        return _per_cable_or_shared([held - signals.run_mean(held)], self.shared)


@register
class CableSlack(CandidateEffect):
    """Slack, a dead zone of the cable: length paid out that carries no tension until taken up.

    A cable with a slack ``s`` [m] in its dead zone is stretched only once the slack is taken
    up, so the motor encoder's length exceeds the path length by ``s`` while the cable is
    slack and by nothing once it is taut. The dead zone is smoothed over a tension scale
    ``F_0`` [N] (a toe region): ``e_l = s (g(F) - mean_run g(F))`` with
    ``g(F) = exp(-max(F, 0) / F_0)``, ``g = 1`` at zero tension and ``-> 0`` once ``F >> F_0``.
    Demeaned per run like the length residual. Linear in ``s`` for a fixed ``F_0``, shared by
    all cables or per cable. The term is seen only where tensions come near zero: on logs whose
    cables never drop below a few ``F_0`` it explains nothing and is not selected.
    """

    indexed_by = "cable"
    name = "slack"
    constant_symbols: ClassVar[Mapping[str, str]] = {"F_0": "tension_scale"}
    parameter_units: ClassVar[Mapping[str, str]] = {"slack": "m"}
    nonnegative: ClassVar[frozenset[str]] = frozenset({"slack"})
    description = (
        "e_l = s (g - mean_run g), g = exp(-max(F, 0)/F_0): slack s [m] paid out beyond the "
        "path while the cable is slack, taken up over a tension scale F_0 (a dead zone)"
    )
    linear = True
    groups = ("length",)

    def __init__(self, n_cables: int = 9, tension_scale: float = 1.0, shared: bool = True) -> None:
        """Build the term.

        Args:
            n_cables: Number of cables ``m``.
            tension_scale: ``F_0``, the tension over which the slack is taken up [N].
            shared: One slack for all cables.
        """
        if not tension_scale > 0:
            raise InputError(f"tension_scale: expected > 0 N, got {tension_scale}")
        self.tension_scale = float(tension_scale)
        self.n_cables, self.shared = int(n_cables), bool(shared)
        self.channels = tuple(range(self.n_cables))
        self.parameter_names = _names(("slack",), self.shared, self.n_cables)

    def dead_zone(self, signals: Signals) -> FloatArray:
        """``g(F)`` [-] of every cable, 1 when slack and 0 when taut, shape ``(T, m)``."""
        return np.exp(-np.maximum(signals.tension, 0.0) / self.tension_scale)

    def design(self, signals: Signals) -> FloatArray:  # noqa: D102
        self._check_cables(signals, self.n_cables)
        g = self.dead_zone(signals)
        return _per_cable_or_shared([g - signals.run_mean(g)], self.shared)
