"""Per-sample signals a candidate effect may use to explain a joint-torque residual.

A :class:`Signals` holds, for ``T`` samples of ``n`` joints and ``m`` cables, the measured
motion, the motor-side cable tensions and the cable geometry at the measured posture. Sign
conventions (as everywhere in msarm): ``J_c = dl/dq`` (``m x n``), the joint torque the cable
tensions ``f`` deliver is ``tau = -J_c^T f``, the cable velocity is ``ldot = J_c qd`` (negative
while the motor pulls the cable in).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from msarm.errors import InputError
from msarm.numba_cache import drop_stale_kernels

drop_stale_kernels(__file__)  # cached kernels of old imported code: compile again

__all__ = ["Signals", "direction_memory", "stick_slip_tension"]

FloatArray = NDArray[np.float64]

# field name -> shape pattern; "T", "n", "m" are the sizes every field must agree on.
_SHAPES: dict[str, tuple[str, ...]] = {
    "t": ("T",),
    "q": ("T", "n"),
    "qd": ("T", "n"),
    "qdd": ("T", "n"),
    "tension": ("T", "m"),
    "lengths": ("T", "m"),
    "cable_velocity": ("T", "m"),
    "jacobian": ("T", "m", "n"),
    "wrap": ("T", "m"),
    "motor_angle": ("T", "m"),
}
# Optional fields (None when a log lacks the channels): what the drive-side terms need.
_OPTIONAL_SHAPES: dict[str, tuple[str, ...]] = {
    "tension_cmd": ("T", "m"),
    "motor_speed": ("T", "m"),
    "qdd_ref": ("T", "n"),
}


@dataclass(frozen=True)
class Signals:
    """Per-sample signals of one or several runs (immutable; arrays are copied read-only).

    Attributes:
        t: Sample times [s], shape ``(T,)``.
        q: Joint positions [rad], shape ``(T, n)``.
        qd: Joint velocities [rad/s], shape ``(T, n)``.
        qdd: Joint accelerations [rad/s^2], shape ``(T, n)``.
        tension: Motor-side cable tensions (load cells) [N], shape ``(T, m)``.
        lengths: Cable path lengths ``l(q)`` [m], shape ``(T, m)``.
        cable_velocity: ``ldot = J_c(q) qd`` [m/s], shape ``(T, m)``.
        jacobian: Cable Jacobians ``J_c(q) = dl/dq`` [m/rad], shape ``(T, m, n)``.
        wrap: Wrap angles ``Theta(q)`` of the cables' sheaths [rad], shape ``(T, m)``.
        motor_angle: Motor (drum) angles [rad], shape ``(T, m)``.
        dt: Sample period [s], > 0.
        run: Integer label of the run each sample comes from, shape ``(T,)``; all zero when
            omitted. Samples of one run are contiguous in the arrays.
        tension_cmd: Tension commands sent to the drives, aligned with the tension they
            produce (the command of the previous sample) [N], shape ``(T, m)``; optional.
        motor_speed: Motor (drum) speeds, filtered derivative of ``motor_angle`` [rad/s],
            shape ``(T, m)``; optional.
        qdd_ref: Accelerations of the logged reference, filtered as ``qdd`` [rad/s^2], shape
            ``(T, n)``; optional. ``qdd`` carries the encoders' noise, which is in the
            joint-torque residual too (through the inverse dynamics), so a term whose
            regressor holds ``qdd`` can "predict" that noise on held-out runs; the
            reference's accelerations carry none.
        segment: Integer label of the stretch of a run without a time gap that each sample
            belongs to, shape ``(T,)``; ``run`` when omitted (no gaps). Segments refine runs:
            stored relabelled 0, 1, ... with a new segment wherever the run or the given label
            changes. A log with gaps in time (dropped samples) is one run of several segments:
            its per-run quantities (the cable lengths' offset, the bootstrap's unit, the
            direction and stick-slip states, which carry across a gap as their own equations
            say) stay per run, while what needs the samples just before (delay taps, tension
            rates) and the replay restart at each segment, as the residuals do.

    Raises:
        InputError: A field has the wrong shape or type, a non-finite value, or ``dt <= 0``;
            the message names the field and the expected shape.
    """

    t: FloatArray
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    tension: FloatArray
    lengths: FloatArray
    cable_velocity: FloatArray
    jacobian: FloatArray
    wrap: FloatArray
    motor_angle: FloatArray
    dt: float
    run: NDArray[np.int64] | None = None
    tension_cmd: FloatArray | None = None
    motor_speed: FloatArray | None = None
    qdd_ref: FloatArray | None = None
    segment: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        sizes: dict[str, int] = {}
        source: dict[str, str] = {}
        shapes = {
            **_SHAPES,
            **{k: v for k, v in _OPTIONAL_SHAPES.items() if getattr(self, k) is not None},
        }
        for name, pattern in shapes.items():
            try:
                value = np.array(getattr(self, name), dtype=float)
            except (TypeError, ValueError) as exc:
                raise InputError(f"Signals.{name}: not a numeric array ({exc})") from exc
            if value.ndim != len(pattern):
                raise InputError(
                    f"Signals.{name}: expected shape ({', '.join(pattern)}), "
                    f"got {value.shape} ({value.ndim} dimensions)"
                )
            for axis, symbol in enumerate(pattern):
                size = value.shape[axis]
                if symbol not in sizes:
                    sizes[symbol], source[symbol] = size, name
                elif sizes[symbol] != size:
                    raise InputError(
                        f"Signals.{name}: expected shape ({', '.join(pattern)}) with "
                        f"{symbol}={sizes[symbol]} (as in Signals.{source[symbol]}), "
                        f"got {value.shape}"
                    )
            if not np.all(np.isfinite(value)):
                bad = np.argwhere(~np.isfinite(value))[0]
                raise InputError(
                    f"Signals.{name}: non-finite value (NaN or inf) at index {tuple(bad)}"
                )
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if sizes["T"] == 0:
            raise InputError("Signals.t: no samples")
        dt = float(self.dt)
        if not np.isfinite(dt) or dt <= 0.0:
            raise InputError(f"Signals.dt: expected a finite sample period > 0 s, got {self.dt}")
        object.__setattr__(self, "dt", dt)
        T = sizes["T"]
        run = _labels("run", np.zeros(T, dtype=np.int64) if self.run is None else self.run, T)
        object.__setattr__(self, "run", run)
        given = run if self.segment is None else _labels("segment", self.segment, T)
        # segments refine runs: a new one wherever the run or the given label changes (so a
        # replace(run=...) or labels restarting in each run cannot join two runs)
        changes = np.ones(T, dtype=np.int64)
        changes[1:] = (run[1:] != run[:-1]) | (given[1:] != given[:-1])
        segment = np.cumsum(changes) - 1
        segment.setflags(write=False)
        object.__setattr__(self, "segment", segment)

    @property
    def n_samples(self) -> int:
        """Number of samples ``T``."""
        return int(self.t.shape[0])

    @property
    def n_joints(self) -> int:
        """Number of joints ``n``."""
        return int(self.q.shape[1])

    @property
    def n_cables(self) -> int:
        """Number of cables ``m``."""
        return int(self.tension.shape[1])

    def take(self, index: NDArray[np.bool_] | NDArray[np.intp]) -> Signals:
        """The signals of some samples (a boolean mask of shape ``(T,)`` or an index array).

        The result remembers where its samples come from (:attr:`origin`), so that a term
        with memory can compute its state on the whole runs and then take these samples.

        Raises:
            InputError: A mask of the wrong length.
        """
        index = np.asarray(index)
        if index.dtype == bool and index.shape != (self.n_samples,):
            raise InputError(f"mask: expected shape ({self.n_samples},), got {index.shape}")
        rows = np.arange(self.n_samples)[index]
        changes = {
            f.name: getattr(self, f.name)[index]
            for f in fields(self)
            if f.name != "dt" and getattr(self, f.name) is not None
        }
        taken = replace(self, **changes)
        root, within = self.origin if self.origin is not None else (self, None)
        rows = rows if within is None else within[rows]
        rows.setflags(write=False)
        object.__setattr__(taken, "_origin", (root, rows))
        return taken

    @property
    def origin(self) -> tuple[Signals, NDArray[np.intp]] | None:
        """Where the samples come from: ``(whole, rows)``, or ``None``.

        For signals made by :meth:`take` (through any number of takes), ``self`` holds the
        samples ``rows`` of ``whole``; ``None`` for signals built directly.
        """
        return getattr(self, "_origin", None)

    def require(self, name: str, who: str) -> FloatArray:
        """An optional field that a term needs.

        Args:
            name: The field (``"tension_cmd"`` or ``"motor_speed"``).
            who: The term that needs it (for the message).

        Raises:
            InputError: The field is absent (the logs lack the channels it comes from).
        """
        value = getattr(self, name)
        if value is None:
            source = {"tension_cmd": "tension_cmd.<cable>", "motor_speed": "motor_angle.<cable>"}
            raise InputError(
                f"{who}: needs Signals.{name}, which is absent (not every log has the "
                f"{source.get(name, name)} columns)"
            )
        return value

    def run_mean(self, values: FloatArray) -> FloatArray:
        """Each run's mean of ``values`` ``(T, k)``, repeated over that run's samples."""
        out = np.empty_like(values)
        for label in np.unique(self.run):
            index = self.run == label
            out[index] = values[index].mean(axis=0)
        return out

    def tension_rate(self) -> FloatArray:
        """Time derivative of the tensions [N/s], shape ``(T, m)``.

        Central differences within each segment (one-sided at a segment's ends; zero for a
        segment of one sample).
        """
        out = np.zeros_like(self.tension)
        for label in np.unique(self.segment):
            index = np.flatnonzero(self.segment == label)
            if index.size >= 2:
                out[index] = np.gradient(self.tension[index], self.t[index], axis=0)
        return out


def _labels(name: str, value: Any, T: int) -> NDArray[np.int64]:
    """Checked integer labels ``(T,)`` of a :class:`Signals` field (read-only copy).

    Raises:
        InputError: Wrong shape, or values that are not whole numbers (the field named).
    """
    array = np.asarray(value)
    if array.shape != (T,):
        raise InputError(f"Signals.{name}: expected shape (T,) with T={T}, got {array.shape}")
    if array.dtype.kind not in "iu":
        if array.dtype.kind == "f" and np.all(np.isfinite(array)):
            if not np.all(array == np.round(array)) or np.any(np.abs(array) > 2.0**53):
                raise InputError(
                    f"Signals.{name}: expected integer {name} labels (whole numbers within "
                    "+-2**53 as floats)"
                )
        else:
            raise InputError(f"Signals.{name}: expected integer {name} labels, got {array.dtype}")
    labels = array.astype(np.int64)
    labels.setflags(write=False)
    return labels


def direction_memory(
    speed: FloatArray, t: FloatArray, run: NDArray[np.int64], rate: float
) -> FloatArray:
    """A Dahl-type memory of the direction of motion, per channel, in ``[-1, 1]``.

    ``dz/dt = rate (v - |v| z)``: ``z`` tends to ``sgn(v)`` over a travel of about
    ``1 / rate`` and holds its value while ``v = 0``. Integrated by implicit Euler (stable for
    any step) within each run, from ``z = 0`` at the run's first sample; across a time gap
    inside a run (:attr:`Signals.segment`) one step spans the gap's elapsed time, so a state
    that the motion during the gap would have turned ends near the new direction.

    Args:
        speed: Velocities ``v``, shape ``(T, k)`` [unit/s].
        t: Sample times [s], shape ``(T,)``.
        run: Run labels, shape ``(T,)``; each run contiguous.
        rate: ``1 /`` the travel over which the memory reverses [1/unit].

    Returns:
        ``z`` [-], shape ``(T, k)``.
    """
    speed = np.ascontiguousarray(speed, dtype=float)
    z = np.zeros_like(speed)
    for label in np.unique(run):
        index = np.flatnonzero(run == label)
        _direction_memory_run(speed, np.asarray(t, dtype=float), index, float(rate), z)
    return z


@numba.njit(cache=True)
def _direction_memory_run(speed, t, index, rate, z):  # pragma: no cover - compiled
    """:func:`direction_memory` of one run (rows ``index``), into ``z``; numpy's arithmetic."""
    current = np.zeros(speed.shape[1])
    for k in range(index.shape[0]):
        i = index[k]
        if k:
            h = rate * (t[i] - t[index[k - 1]])
            for c in range(speed.shape[1]):
                current[c] = (current[c] + h * speed[i, c]) / (1.0 + h * abs(speed[i, c]))
        for c in range(speed.shape[1]):
            z[i, c] = current[c]


def stick_slip_tension(
    tension: FloatArray, wrap: FloatArray, run: NDArray[np.int64], mu: float, floor: float = 1e-3
) -> FloatArray:
    """The tension a capstan stick-slip element passes on: a play operator in log tension.

    A cable in a sheath with static friction ``mu`` over a wrap angle ``Theta`` slips once
    the tensions at its two ends differ by the capstan factor ``exp(mu Theta)`` and sticks
    in between: the far end keeps its tension while the near end's tension ``F`` stays within
    the band. Per cable, within each run (starting balanced, ``T_out = F``; across a time
    gap inside a run the band clamps the held level, exact for a tension that moved one way
    during the gap):

    ``log T_out,k = min(max(log T_out,k-1, log F_k - mu Theta_k), log F_k + mu Theta_k)``

    (``F`` below ``floor`` is taken as ``floor``). After the near end pulled the cable in,
    ``T_out = F exp(-mu Theta)``; after it paid out, ``F exp(mu Theta)``; at rest, whatever
    the last slip left.

    Args:
        tension: Near-end (motor-side) tensions ``F`` [N], shape ``(T, m)``.
        wrap: Wrap angles ``Theta`` [rad], shape ``(T, m)``.
        run: Run labels, shape ``(T,)``; each run contiguous.
        mu: Friction coefficient [1/rad], >= 0.
        floor: Least tension taken for the logarithm [N], > 0.

    Returns:
        ``T_out`` [N], shape ``(T, m)``.

    Raises:
        InputError: ``mu`` < 0 or ``floor`` <= 0, or either not finite.
    """
    if not (np.isfinite(mu) and mu >= 0.0):
        raise InputError(f"mu must be a finite number >= 0, got {mu}")
    if not (np.isfinite(floor) and floor > 0.0):
        raise InputError(f"floor must be a finite number > 0 N, got {floor}")
    return _stick_slip(
        np.ascontiguousarray(tension, dtype=np.float64),
        np.ascontiguousarray(wrap, dtype=np.float64),
        np.ascontiguousarray(run, dtype=np.int64),
        float(mu),
        float(floor),
    )


@numba.njit(cache=True)
def _stick_slip(tension, wrap, run, mu, floor):
    out = np.empty_like(tension)
    level = np.empty(tension.shape[1])
    for i in range(tension.shape[0]):
        start = i == 0 or run[i] != run[i - 1]
        for c in range(tension.shape[1]):
            near = math.log(max(tension[i, c], floor))
            if start:
                level[c] = near
            band = mu * wrap[i, c]
            level[c] = min(max(level[c], near - band), near + band)
            out[i, c] = math.exp(level[c])
    return out
