"""Features of the feedforward compensator: the friction state of paper 003 eq. 8.

At each control tick, from what the robot's sensors give (joint encoders ``q``, the
controller's velocity estimate ``qdot``, motor encoders ``theta``, load cells ``F``) and the
nominal cable geometry ``l(q)``, ``J_c(q)``:

==========================  ===============================================  ==========
group (paper 003 eq. 8)     value                                            size
==========================  ===============================================  ==========
``q`` (U_A)                 joint angles [rad]                               n
``qdot`` (U_A)              joint velocities [rad/s]                         n
``cable_length_error``      ``l_hat - l`` [m]: the cable length the motor    m
(U_B)                       encoders say was reeled, ``l(q_0) - r (theta -
                            theta_0)``, minus the path length ``l(q)``
``sign_qdot`` (U_C)         ``s(qdot) = tanh(qdot / eps_q)``                 n
``exp_sign_qdot`` (U_D)     ``exp(-s(qdot)) s(qdot)``                        n
``exp_sign_ldot`` (U_E)     ``exp(-tanh(ldot / eps_l))``, ``ldot = J_c qdot``  m
``tension`` (U_F)           load-cell tensions ``F_sensor`` [N]              m
``joint_memory``            Dahl-type memory of each joint's last direction  n
``cable_memory``            Dahl-type memory of each cable's last direction  m
``sign_error``              ``tanh((q_r - q) / eps_e)``: the smoothed sign   n
                            of each joint's tracking error (measured ``q``)
``sheath_stiction``         ``J_c(q)^T (S_mu(F_cmd) - F_cmd)`` for each        n K
                            ``mu`` of ``stiction_mus``: the torque a sheath
                            with static friction ``mu`` would take from the
                            commanded tensions (see below)
==========================  ===============================================  ==========

The choice of inputs. All of paper 003's groups are available (43 inputs with 4 joints and
9 cables; the paper used 42), but two of them, ``tension`` and ``cable_length_error`` (the
cable's stretch, hence its tension), are outputs of the very loop the compensator closes:
its ``dtau`` raises the commanded tensions, which raise those inputs, which raise ``dtau``.
Trained on runs without feedforward, a network with those inputs predicts the torque error
well offline (R^2 about 0.95-0.98 on held-out runs) and drives the arm unstable in closed
loop (final errors of 170-500 mm where the plain controller has 1-6 mm, both with the
default gains; see the README). The default inputs (:data:`DEFAULT_GROUPS`, 25) are the
motion state of the task's reference: ``q`` (wrap angles, moment arms and gravity load:
posture-dependent capstan friction), ``qdot`` and its smoothed signs (the friction
direction) and the sign of each cable's velocity: a true feedforward, as in paper 003. What
a cable that sticks in its sheath does at rest (on either side of its friction band) no
function of the reference tells; the compensator's sheath stage
(:mod:`msarm.compensation.sheath`) deals with that in tension space, and the network learns
what it leaves. A network alone can be given ``sign_error``, the smoothed sign of each
joint's tracking error (measured): once the reference rests, the friction left to overcome
is in the direction the arm must still move. It was the default before the sheath stage
(final error on the validation tasks 0.55 -> 0.39 mm, against 0.56 mm without it); on top
of the stage it made the final error worse (0.12 -> 0.20 mm, README). It makes the
compensator a learned feedback on the error's sign, bounded by ``tanh``. Two
Dahl-type direction memories (``joint_memory``, ``cable_memory``; paper 001 eq. 14 uses the
same idea for friction at a direction change) remember which way each joint or cable last
moved; they were the default before ``sign_error`` and are still available. The sign
functions are smoothed (``tanh``) so that the network's input is continuous. ``theta_0``,
``q_0`` and the memories start at the first sample of a run: :meth:`reset` starts a new run.

``sheath_stiction`` carries the memory of a sheath that sticks. ``S_mu`` is a stick-slip
element (a play operator in log tension, as the diagnosis's ``capstan_hysteresis`` term,
:func:`msarm.diagnose.signals.stick_slip_tension`): it passes the commanded tension ``F`` on
while the two ends of the cable differ by less than the capstan factor ``exp(mu Theta(q))``
and keeps what the last slip left otherwise, so after a cable was pulled in it gives
``F exp(-mu Theta)``, after it was paid out ``F exp(mu Theta)``, and at rest whatever the last
motion left: which side of its friction band each cable rests on. It is built from the
controller's own previous command (the command of tick ``k - 1`` at tick ``k``; zero at the
first tick of a run, and the element starts balanced at the second) and the measured
posture's wrap angles ``Theta(q)`` and Jacobian, so it needs no sensor the robot lacks; in a
log it comes from the ``tension_cmd`` columns. It feeds back too (``dtau`` raises the
commands), but only through the friction band: its size is ``F (exp(mu Theta) - 1)``, not
``F``.

The same code computes the features online (one tick, :meth:`FeatureExtractor.__call__`) and
offline from a log (:meth:`FeatureExtractor.from_log`); a test keeps them equal.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from msarm.errors import InputError
from msarm.io.config import check_numbers
from msarm.io.logs import RunLog
from msarm.model import RobotModel
from msarm.muscle.batch_kinematics import current_wrap_angles
from msarm.muscle.geometry import cable_kinematics

__all__ = [
    "DEFAULT_GROUPS",
    "FEATURE_GROUPS",
    "REFERENCE_GROUPS",
    "STICTION_MUS",
    "FeatureExtractor",
    "FeatureSpec",
]

FloatArray = NDArray[np.float64]

#: Feature groups in their order, with whether each has one entry per joint or per cable.
FEATURE_GROUPS = {
    "q": "joint",
    "qdot": "joint",
    "cable_length_error": "cable",
    "sign_qdot": "joint",
    "exp_sign_qdot": "joint",
    "exp_sign_ldot": "cable",
    "tension": "cable",
    "joint_memory": "joint",
    "cable_memory": "cable",
    "sign_error": "joint",
    "sheath_stiction": "joint",
}
#: Friction coefficients of the ``sheath_stiction`` elements (the diagnosis's, from
#: :data:`msarm.diagnose.effects.CAPSTAN_STICTION_MUS`) [-].
STICTION_MUS = (0.03, 0.06, 0.12, 0.24)
#: Least tension taken for the logarithm of a stick-slip element [N].
_STICTION_FLOOR = 1e-3
#: Groups computed from the task's reference alone (with ``source="reference"``): a spec of
#: these only gives features that need no sensor (:meth:`FeatureExtractor.from_reference`).
REFERENCE_GROUPS = ("q", "qdot", "sign_qdot", "exp_sign_qdot", "exp_sign_ldot")
#: The default inputs: the motion state of paper 003 eq. 8 from the task's reference, without
#: the two groups that the compensator's own output feeds back into (``cable_length_error``
#: and ``tension``, see the module docstring): a true feedforward.
DEFAULT_GROUPS = (
    "q",
    "qdot",
    "sign_qdot",
    "exp_sign_qdot",
    "exp_sign_ldot",
)


@dataclass(frozen=True)
class FeatureSpec:
    """Which features, and how they are computed (stored with every checkpoint).

    Attributes:
        groups: Feature groups, in order (names of :data:`FEATURE_GROUPS`).
        sign_joint_speed: ``eps_q`` of ``tanh(qdot / eps_q)`` [rad/s].
        sign_cable_speed: ``eps_l`` of ``tanh(ldot / eps_l)`` [m/s].
        drum_radius: Winch drum radius ``r`` turning motor angles into cable length [m]: the
            plant's ``winch.drum_radius`` (``msarm train`` refuses a recipe where they differ).
        memory_angle: Joint travel over which the joint direction memory forgets [rad].
        memory_length: Cable travel over which the cable direction memory forgets [m].
        source: Where the motion groups (``q``, ``qdot``, the signs, the memories) come
            from: ``"reference"`` (the task's reference: a true feedforward, independent of
            the robot's response) or ``"measured"`` (encoders and the controller's velocity
            estimate: a learned feedback).
        sign_error_angle: ``eps_e`` of ``tanh((q_r - q) / eps_e)`` [rad] (``sign_error``).
        stiction_mus: Friction coefficients of the ``sheath_stiction`` elements [-], one
            group of ``n`` inputs each.

    The widths, the drum radius and the memory lengths must be finite and > 0.

    Raises:
        InputError: An unknown or repeated group, another source, a width, radius or
            memory length that is not a finite number > 0, or a friction coefficient that
            is not finite and > 0 (named, with the value given).
    """

    groups: tuple[str, ...] = DEFAULT_GROUPS
    sign_joint_speed: float = 0.05
    sign_cable_speed: float = 0.002
    drum_radius: float = 0.003
    memory_angle: float = 0.05
    memory_length: float = 0.001
    source: str = "reference"
    sign_error_angle: float = 0.005
    stiction_mus: tuple[float, ...] = STICTION_MUS

    def __post_init__(self) -> None:
        unknown = [g for g in self.groups if g not in FEATURE_GROUPS]
        if unknown or not self.groups:
            raise InputError(
                f"unknown feature groups {unknown}; expected some of {list(FEATURE_GROUPS)}"
            )
        if self.source not in ("reference", "measured"):
            raise InputError(f"source must be 'reference' or 'measured', got {self.source!r}")
        if len(set(self.groups)) != len(self.groups):
            raise InputError(f"feature groups repeat: {self.groups}")
        # widths and lengths: inf would make the sign features 0 and the memories still,
        # NaN every feature NaN
        check_numbers(
            self,
            positive=(
                "sign_joint_speed",
                "sign_cable_speed",
                "drum_radius",
                "memory_angle",
                "memory_length",
                "sign_error_angle",
            ),
        )
        mus = tuple(float(mu) for mu in self.stiction_mus)
        if not mus or not all(np.isfinite(mu) and mu > 0 for mu in mus):
            raise InputError(f"stiction_mus must be finite numbers > 0, got {self.stiction_mus}")
        object.__setattr__(self, "stiction_mus", mus)

    def as_dict(self) -> dict:
        """Plain-data form (lists, numbers) for checkpoints."""
        out = asdict(self)
        out["groups"] = list(self.groups)
        out["stiction_mus"] = list(self.stiction_mus)
        return out


class FeatureExtractor:
    """Computes the features of :class:`FeatureSpec` online and from logs.

    Args:
        model: The nominal robot model (cable geometry).
        spec: The features.
    """

    def __init__(self, model: RobotModel, spec: FeatureSpec | None = None) -> None:
        self.model = model
        self.spec = spec or FeatureSpec()
        self._data = model.create_data()
        self._jacobian = np.zeros((model.n_cables, model.n_joints))
        self._origin: tuple[FloatArray, FloatArray] | None = None
        self._memory: tuple[float, FloatArray, FloatArray] | None = None
        self._command: FloatArray | None = None
        self._stiction: FloatArray | None = None
        self._mus = np.asarray(self.spec.stiction_mus, dtype=float)[:, None]
        self.names: list[str] = []
        for group in self.spec.groups:
            names = model.joint_names if FEATURE_GROUPS[group] == "joint" else model.cable_names
            if group == "sheath_stiction":
                self.names += [
                    f"{group}[mu={mu:g}].{name}" for mu in self.spec.stiction_mus for name in names
                ]
            else:
                self.names += [f"{group}.{name}" for name in names]
        self.size = len(self.names)

    def reset(self) -> None:
        """Start a new run: the next sample fixes ``q_0`` and ``theta_0``, memories at 0."""
        self._origin = None
        self._memory = None
        self._command = None
        self._stiction = None

    def observe_command(self, tension_command: FloatArray) -> None:
        """Remember the tension command [N], ``(m,)``, sent this tick (``sheath_stiction``).

        The controller calls it after each tick (through
        :meth:`msarm.compensation.feedforward.LearnedFeedforward.observe_command`).
        """
        self._command = np.array(tension_command, dtype=float)

    def _sheath_stiction(self, command: FloatArray | None, jacobian: FloatArray) -> FloatArray:
        """``J_c^T (S_mu(F) - F)`` of each ``mu`` [N m], ``(K n,)``; advances the elements.

        ``jacobian`` and the wrap angles are those of the measured posture (``mj_tendon`` ran
        last on it).
        """
        if command is None:  # the first tick of a run: no command sent yet
            return np.zeros(self._mus.shape[0] * jacobian.shape[1])
        log_f = np.log(np.maximum(command, _STICTION_FLOOR))
        band = self._mus * current_wrap_angles(self.model.mj_model, self._data.mj)
        if self._stiction is None:
            self._stiction = np.repeat(log_f[None, :], self._mus.shape[0], axis=0)
        else:
            self._stiction = np.minimum(np.maximum(self._stiction, log_f - band), log_f + band)
        return ((np.exp(self._stiction) - command) @ jacobian).reshape(-1)

    def _geometry(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        lengths = cable_kinematics(self.model.mj_model, self._data.mj, q, self._jacobian)
        return lengths, self._jacobian

    def _memories(
        self, t: float, qdot: FloatArray, ldot: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Dahl-type direction memories: ``dm/dt = (tanh(v / eps) - m) |v| / travel``.

        ``m`` moves towards the sign of the velocity as the joint (cable) travels and keeps
        its value while it rests: it remembers the direction of the last motion, which sets
        the side of the friction hysteresis a resting cable sticks on.
        """
        spec = self.spec
        if self._memory is None:
            self._memory = (t, np.zeros_like(qdot), np.zeros_like(ldot))
        t_prev, joint, cable = self._memory
        dt = max(t - t_prev, 0.0)
        joint_rate = np.minimum(1.0, np.abs(qdot) * dt / spec.memory_angle)
        cable_rate = np.minimum(1.0, np.abs(ldot) * dt / spec.memory_length)
        joint = joint + (np.tanh(qdot / spec.sign_joint_speed) - joint) * joint_rate
        cable = cable + (np.tanh(ldot / spec.sign_cable_speed) - cable) * cable_rate
        self._memory = (t, joint, cable)
        return joint, cable

    def _features(
        self,
        t: float,
        measured: tuple[FloatArray, FloatArray],
        reference: tuple[FloatArray, FloatArray],
        motor_angle: FloatArray,
        tension: FloatArray,
        command: FloatArray | None = None,
    ) -> FloatArray:
        spec = self.spec
        q_meas = measured[0]
        q, qdot = reference if spec.source == "reference" else measured
        measured_lengths = None
        stiction = None
        if self._origin is None or "cable_length_error" in spec.groups:
            measured_lengths = self._geometry(q_meas)[0]  # before: the Jacobian buffer is shared
        if "sheath_stiction" in spec.groups:
            measured_lengths, measured_jacobian = self._geometry(q_meas)
            stiction = self._sheath_stiction(command, measured_jacobian)
        _, jacobian = self._geometry(q)
        if self._origin is None:
            self._origin = (measured_lengths.copy(), motor_angle.copy())
        length0, angle0 = self._origin
        groups = spec.groups
        sign_q = np.tanh(qdot / spec.sign_joint_speed)
        ldot = jacobian @ qdot
        joint_memory = cable_memory = None
        if "joint_memory" in groups or "cable_memory" in groups:  # state: only when used
            joint_memory, cable_memory = self._memories(t, qdot, ldot)
        values = {
            "q": q,
            "qdot": qdot,
            "cable_length_error": (
                (length0 - spec.drum_radius * (motor_angle - angle0)) - measured_lengths
                if measured_lengths is not None
                else None
            ),
            "sign_qdot": sign_q,
            "exp_sign_qdot": np.exp(-sign_q) * sign_q if "exp_sign_qdot" in groups else None,
            "exp_sign_ldot": (
                np.exp(-np.tanh(ldot / spec.sign_cable_speed))
                if "exp_sign_ldot" in groups
                else None
            ),
            "tension": tension,
            "joint_memory": joint_memory,
            "cable_memory": cable_memory,
            "sign_error": (
                np.tanh((reference[0] - q_meas) / spec.sign_error_angle)
                if "sign_error" in groups
                else None
            ),
            "sheath_stiction": stiction,
        }
        return np.concatenate([values[group] for group in spec.groups])  # type: ignore[misc]

    def __call__(
        self,
        readings,
        qdot_estimate: FloatArray,
        q_ref: FloatArray,
        qd_ref: FloatArray,
    ) -> FloatArray:
        """Features of one control tick, shape ``(d,)``.

        Args:
            readings: Sensor readings (``t``, ``q``, ``motor_angle``, ``tension_motor``).
            qdot_estimate: The controller's joint velocity estimate [rad/s], shape ``(n,)``.
            q_ref: Reference joint angles [rad], shape ``(n,)``.
            qd_ref: Reference joint velocities [rad/s], shape ``(n,)``.
        """
        return self._features(
            float(readings.t),
            (np.asarray(readings.q, dtype=float), np.asarray(qdot_estimate, dtype=float)),
            (np.asarray(q_ref, dtype=float), np.asarray(qd_ref, dtype=float)),
            np.asarray(readings.motor_angle, dtype=float),
            np.asarray(readings.tension_motor, dtype=float),
            self._command,
        )

    @property
    def reference_only(self) -> bool:
        """Whether the features are the task reference's alone, known before a run starts.

        That is: groups of :data:`REFERENCE_GROUPS` only, with ``source="reference"``.
        """
        return self.spec.source == "reference" and set(self.spec.groups) <= set(REFERENCE_GROUPS)

    def from_reference(self, q_ref: FloatArray, qd_ref: FloatArray) -> FloatArray:
        """Features of every tick of a run from its reference alone, shape ``(T, d)``.

        Row ``k`` is what :meth:`__call__` gives at tick ``k`` of a run from its start,
        whatever the sensors read (the same code, so the same bits): the compiled loop
        takes the network's inputs from here.

        Args:
            q_ref: Reference joint angles [rad], ``(T, n)``.
            qd_ref: Reference joint velocities [rad/s], ``(T, n)``.

        Raises:
            InputError: The spec has a group that needs the sensors (see
                :attr:`reference_only`); ``q_ref`` or ``qd_ref`` is not of shape ``(T, n)``,
                they differ in length, or they hold a NaN or inf (tick and joint named).
        """
        if not self.reference_only:
            raise InputError(
                f"features {list(self.spec.groups)} from the {self.spec.source}: expected "
                f"groups of {list(REFERENCE_GROUPS)} from the reference to compute them "
                "before the run"
            )
        q_ref, qd_ref = np.asarray(q_ref, dtype=float), np.asarray(qd_ref, dtype=float)
        n = self.model.n_joints
        for name, values in (("q_ref", q_ref), ("qd_ref", qd_ref)):
            if values.ndim != 2 or values.shape[1] != n:
                raise InputError(
                    f"{name}: expected shape (T, {n}) (one row of {n} joints per tick), "
                    f"got {values.shape}"
                )
        if len(q_ref) != len(qd_ref):
            raise InputError(
                f"q_ref has {len(q_ref)} ticks but qd_ref has {len(qd_ref)}; expected one row "
                "of each per tick"
            )
        for name, values in (("q_ref", q_ref), ("qd_ref", qd_ref)):
            bad = ~np.isfinite(values)
            if bad.any():
                tick, joint = (int(i) for i in np.argwhere(bad)[0])
                raise InputError(
                    f"{name} has {int(bad.sum())} non-finite value(s); first at tick {tick}, "
                    f"joint {self.model.joint_names[joint]!r}: {float(values[tick, joint])!r}; "
                    "expected finite values"
                )
        unread = np.zeros(self.model.n_cables)  # sensors the reference groups do not read
        self.reset()
        out = np.empty((len(q_ref), self.size))
        for k in range(len(q_ref)):
            motion = (q_ref[k], qd_ref[k])
            out[k] = self._features(0.0, motion, motion, unread, unread)
        self.reset()
        return out

    def from_log(self, log: RunLog, source: str = "log") -> FloatArray:
        """Features of every sample of a log, shape ``(T, d)`` (a run from its start).

        Args:
            log: A run's log with ``q``, ``qdot_est``, ``motor_angle`` and ``tension_motor``
                (and ``tension_cmd`` for ``sheath_stiction``).
            source: Name of the log (file) for error messages.

        Raises:
            InputError: A channel the features need is missing (file and column named).
        """
        joints, cables = list(self.model.joint_names), list(self.model.cable_names)
        needed = [("q", joints), ("qdot_est", joints), ("motor_angle", cables)]
        needed += [("tension_motor", cables), ("q_ref", joints), ("qd_ref", joints)]
        if "sheath_stiction" in self.spec.groups:
            needed.append(("tension_cmd", cables))
        for quantity, names in needed:
            for name in names:
                if f"{quantity}.{name}" not in log.columns:
                    raise InputError(
                        f"{source}: column {quantity}.{name} is missing; the compensator's "
                        f"features need {quantity} for every "
                        f"{'joint' if names is joints else 'cable'}"
                    )
        q = log.matrix("q", joints)
        qdot = log.matrix("qdot_est", joints)
        q_ref = log.matrix("q_ref", joints)
        qd_ref = log.matrix("qd_ref", joints)
        motor = log.matrix("motor_angle", cables)
        tension = log.matrix("tension_motor", cables)
        commands = (
            log.matrix("tension_cmd", cables) if "sheath_stiction" in self.spec.groups else None
        )
        t = log.t
        self.reset()
        out = np.empty((len(q), self.size))
        for k in range(len(q)):
            previous = None if commands is None or k == 0 else commands[k - 1]
            out[k] = self._features(
                float(t[k]), (q[k], qdot[k]), (q_ref[k], qd_ref[k]), motor[k], tension[k], previous
            )
        self.reset()
        return out
