"""The high-level PID of paper 000, eq. 11, discretised for the 1 ms control cycle.

The high-level controller of the hybrid CDPR controllers (Fig. 8) turns an error ``e`` (a
force [N], a motor torque [N m] or a following error [m]) into a cable length correction
``Delta l`` [m] with the transfer function::

    G(s) = K_HL (1 + 1 / (T_i s) + T_v s / (1 + T_d s))                      (11)

Discretisation: backward Euler, ``s -> (1 - z^-1) / T`` with the cycle time ``T`` (1 ms),
applied to the integral and to the filtered derivative separately::

    P_k = K e_k
    I_k = I_{k-1} + (K T / T_i) e_k
    D_k = (T_d D_{k-1} + K T_v (e_k - e_{k-1})) / (T_d + T)
    u_k = P_k + I_k + D_k            (limited to [u_min, u_max] when limits are given)

so the integral of a unit step grows by ``K / T_i`` per second (``K T / T_i`` per cycle; the
backward rule counts the current sample, ``I_k = K (k + 1) T / T_i``), the derivative of a
unit step is the geometric sequence ``K T_v / (T_d + T) * rho^k`` with
``rho = T_d / (T_d + T) = 1 / (1 + T / T_d)`` (the backward-Euler image of the filter's pole
``exp(-T / T_d)``), whose area ``sum_k T D_k = K T_v`` equals the continuous one. With
``T_d = 0`` the derivative is the plain backward difference ``K T_v (e_k - e_{k-1}) / T``.
``T_v = 0`` switches the derivative off: the controller is a PI (paper 000 does this for
HC-tau and HC-e; Table 2 then also gives ``T_d = 0``). ``T_i = inf`` switches the integral off.

After :meth:`DiscretePID.reset` the state is zero and the previous error is taken as 0, so a
step in the error at the first cycle gives the response of eq. 11 to a step (a derivative
kick, as the continuous derivative's impulse).

Anti-windup (only with output limits): conditional integration. The integrator moves
towards a limit only until the output ``P + I + D`` reaches it (``I`` is clipped to
``[min(I_{k-1}, u_min - P - D), max(I_{k-1}, u_max - P - D)]``): it never winds up beyond
the limit, is never pushed back by it, and may always move away from it; the output is then
limited to ``[u_min, u_max]``. So the output leaves the limit as soon as the error changes
sign.

The controller is vectorised: one :class:`DiscretePID` holds ``n`` independent channels with
shared gains (one per cable), any channel can be reset alone.

Table 2 of paper 000 (the gains of the three high-level PIDs of Fig. 8) is kept as published,
with the times converted once from ms to s: :data:`HC_F_GAINS`, :data:`HC_TAU_GAINS`,
:data:`HC_E_GAINS`. Units of ``K_HL``: the output is ``Delta l`` in metres, the inputs are
newtons (HC-f), newton metres (HC-tau) and metres (HC-e), so ``K_HL`` is in m/N, m/(N m) and
m/m. The paper's figure does not show the sign of the summing junction; the caller
(``msarm.control.cdpr_controllers``) feeds an error whose sign makes the loop reel in cable
when the tension is too low, and the gains stay positive as published.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msarm.errors import InputError

FloatArray = NDArray[np.float64]

__all__ = [
    "CYCLE_TIME",
    "HC_E_GAINS",
    "HC_F_GAINS",
    "HC_TAU_GAINS",
    "TABLE_2",
    "DiscretePID",
    "PIDGains",
]

CYCLE_TIME = 1e-3
"""Cycle time of the high-level controller [s] (the IPAnema 3 Mini PLC, paper 000 Sec. 2.3)."""

MS = 1e-3
"""One millisecond [s] (Table 2 gives the times in ms)."""


@dataclass(frozen=True)
class PIDGains:
    """Parameters of eq. 11 of paper 000.

    Attributes:
        k: Proportional gain K_HL [output unit / input unit], finite (m/N, m/(N m) or m/m
            in paper 000).
        t_i: Integral action time T_i [s], > 0; ``math.inf`` switches the integral off.
        t_v: Derivative action time T_v [s], >= 0; 0 switches the derivative off (PI).
        t_d: Damping (derivative filter) time constant T_d [s], >= 0.
    """

    k: float
    t_i: float
    t_v: float = 0.0
    t_d: float = 0.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.k):
            raise InputError(f"PID gain k (K_HL) must be finite, got {self.k}")
        if not (self.t_i > 0.0):  # inf allowed, NaN refused
            raise InputError(f"PID t_i (T_i) must be > 0 s (inf: no integral), got {self.t_i}")
        for name in ("t_v", "t_d"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise InputError(f"PID {name} must be finite and >= 0 s, got {value}")

    @property
    def is_pi(self) -> bool:
        """True when the derivative part is off (T_v = 0)."""
        return self.t_v == 0.0

    @classmethod
    def from_ms(cls, k: float, t_i_ms: float, t_v_ms: float = 0.0, t_d_ms: float = 0.0) -> PIDGains:
        """Build from times in milliseconds, as Table 2 of paper 000 gives them.

        Args:
            k: K_HL [output unit / input unit].
            t_i_ms: T_i [ms].
            t_v_ms: T_v [ms].
            t_d_ms: T_d [ms].

        Returns:
            The gains with times in seconds.
        """
        return cls(float(k), float(t_i_ms) * MS, float(t_v_ms) * MS, float(t_d_ms) * MS)


# Table 2 of paper 000: K_HL, T_i [ms], T_v [ms], T_d [ms].
HC_F_GAINS = PIDGains.from_ms(3.0e-4, 70.0, 15.0, 5.0)
"""HC-f (load-cell force feedback): K_HL = 3.0e-4 m/N, T_i = 70 ms, T_v = 15 ms, T_d = 5 ms."""
HC_TAU_GAINS = PIDGains.from_ms(2.0e-2, 200.0, 0.0, 0.0)
"""HC-tau (motor torque feedback): K_HL = 2.0e-2 m/(N m), T_i = 200 ms, PI (T_v = T_d = 0)."""
HC_E_GAINS = PIDGains.from_ms(4.5e-1, 7.0, 0.0, 0.0)
"""HC-e (following-error feedback): K_HL = 0.45 m/m, T_i = 7 ms, PI (T_v = T_d = 0)."""
TABLE_2: dict[str, PIDGains] = {"hc-f": HC_F_GAINS, "hc-tau": HC_TAU_GAINS, "hc-e": HC_E_GAINS}
"""Table 2 of paper 000 by controller name."""


class DiscretePID:
    """Backward-Euler discretisation of eq. 11 with ``n`` channels and anti-windup.

    Args:
        gains: K_HL, T_i, T_v, T_d (shared by all channels).
        n: Number of channels (e.g. one per cable), >= 1.
        dt: Cycle time T [s], > 0 (1 ms in paper 000).
        output_min: Lower output limit [output unit], scalar or shape (n,); None: no limit.
        output_max: Upper output limit [output unit], scalar or shape (n,); None: no limit.

    Raises:
        InputError: On invalid sizes, cycle time or limits (``output_min >= output_max``).

    Example:
        >>> pid = DiscretePID(HC_F_GAINS, n=8)
        >>> f_set, f_measured = np.full(8, 20.0), np.full(8, 19.5)  # [N]
        >>> pid.step(f_measured - f_set).shape  # the cable length change delta_l [m]
        (8,)
    """

    def __init__(
        self,
        gains: PIDGains,
        n: int = 1,
        dt: float = CYCLE_TIME,
        *,
        output_min: ArrayLike | None = None,
        output_max: ArrayLike | None = None,
    ) -> None:
        if int(n) != n or n < 1:
            raise InputError(f"PID channel count n must be an integer >= 1, got {n}")
        if not (math.isfinite(dt) and dt > 0.0):
            raise InputError(f"PID cycle time dt must be finite and > 0 s, got {dt}")
        self.gains = gains
        self.n = int(n)
        self.dt = float(dt)
        lo = -np.inf if output_min is None else output_min
        hi = np.inf if output_max is None else output_max
        self._lo = np.broadcast_to(np.asarray(lo, dtype=np.float64), (self.n,)).copy()
        self._hi = np.broadcast_to(np.asarray(hi, dtype=np.float64), (self.n,)).copy()
        if np.isnan(self._lo).any() or np.isnan(self._hi).any() or np.any(self._lo >= self._hi):
            raise InputError(
                f"PID output limits must satisfy output_min < output_max, got {lo} and {hi}"
            )
        g = gains
        self._ki = 0.0 if math.isinf(g.t_i) else g.k * self.dt / g.t_i
        if g.is_pi:
            self._d_decay, self._d_gain = 0.0, 0.0
        else:
            self._d_decay = g.t_d / (g.t_d + self.dt)
            self._d_gain = g.k * g.t_v / (g.t_d + self.dt)
        self._integral = np.zeros(self.n)
        self._derivative = np.zeros(self.n)
        self._e_prev = np.zeros(self.n)
        self._output = np.zeros(self.n)

    @property
    def integral(self) -> FloatArray:
        """Integral state I_k [output unit], shape (n,) (a copy)."""
        return self._integral.copy()

    @property
    def derivative(self) -> FloatArray:
        """Filtered derivative state D_k [output unit], shape (n,) (a copy)."""
        return self._derivative.copy()

    @property
    def output(self) -> FloatArray:
        """Last output u_k [output unit], shape (n,) (a copy); zeros after a reset."""
        return self._output.copy()

    @property
    def integral_gain_per_cycle(self) -> float:
        """K T / T_i: integral increment per cycle for a unit error [output / input]."""
        return self._ki

    @property
    def derivative_decay(self) -> float:
        """Per-cycle decay rho = T_d / (T_d + T) of the filtered derivative [-] (0 for PI)."""
        return self._d_decay

    def reset(self, mask: ArrayLike | None = None) -> None:
        """Zero the state (integral, derivative, previous error, output) of some channels.

        Args:
            mask: Boolean mask of shape (n,) of the channels to reset; all if None.

        Raises:
            InputError: If the mask has the wrong shape.
        """
        if mask is None:
            sel: slice | NDArray[np.bool_] = slice(None)
        else:
            sel = np.asarray(mask, dtype=bool)
            if sel.shape != (self.n,):
                raise InputError(f"PID reset mask must have shape ({self.n},), got {sel.shape}")
        for state in (self._integral, self._derivative, self._e_prev, self._output):
            state[sel] = 0.0

    def step(self, error: ArrayLike) -> FloatArray:
        """Advance one cycle with the error e_k and return the output u_k.

        Args:
            error: e_k [input unit], scalar or shape (n,), finite.

        Returns:
            u_k [output unit], shape (n,) (a new array).

        Raises:
            InputError: On a wrong shape or a non-finite error.
        """
        e = np.asarray(error, dtype=np.float64)
        if e.shape not in ((), (self.n,)):
            raise InputError(f"PID error must be a scalar or shape ({self.n},), got {e.shape}")
        if not np.isfinite(e).all():
            raise InputError(f"PID error must be finite, got {e}")
        if e.shape != (self.n,):
            e = np.broadcast_to(e, (self.n,))
        p = self.gains.k * e
        self._derivative = self._d_decay * self._derivative + self._d_gain * (e - self._e_prev)
        candidate = self._integral + self._ki * e
        # Conditional integration: the integrator moves towards a limit only until the
        # output reaches it (it is never pushed back, and may always move away from it).
        upper = np.maximum(self._integral, self._hi - p - self._derivative)
        lower = np.minimum(self._integral, self._lo - p - self._derivative)
        self._integral = np.clip(candidate, lower, upper)
        u = np.clip(p + self._integral + self._derivative, self._lo, self._hi)
        self._e_prev = e.copy()
        self._output = u
        return u.copy()

    def __repr__(self) -> str:
        g = self.gains
        return (
            f"DiscretePID(k={g.k:g}, t_i={g.t_i:g} s, t_v={g.t_v:g} s, t_d={g.t_d:g} s, "
            f"n={self.n}, dt={self.dt:g} s)"
        )
