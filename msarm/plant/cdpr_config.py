"""Parameters of the simulated IPAnema 3 Mini (:mod:`msarm.plant.cdpr_plant`).

Every block is a frozen dataclass that ``msarm.io.config.load_config(path, CdprPlantConfig)``
reads from YAML. Two presets: :data:`DEFAULT_CDPR_PLANT` ("the real robot": the winch friction
of paper 000, elastic cables, sensor noise) and :data:`IDEAL_CDPR_PLANT` (no friction, no
noise, stiff cables; the drives are the same).

Sources of the default values. Paper 000 gives the motors (Beckhoff AM3121-0201, nominal torque
0.69 N m, direct drive), the drive structure (P position loop in the PLC, PI or pure P velocity
loop in the drive, 1 ms cycle), the friction model (Table 1) and the following-error law
(eq. 8-9); everything else is a plausible value, marked *estimate*:

- drum radius r_D = 20 mm (*estimate*, from the paper's numbers): ``f_max r_D`` = 35 N x 20 mm
  = 0.70 N m, the motor's nominal torque (the usual sizing of a direct-drive winch), and the
  force slope of the friction torque in the hauling direction, ``c_3n / r_D`` = 3.10e-3 / 0.02
  = 0.155, is then just above that of the pulleys between load cell and platform alone
  (f_F's ``c_3n`` = 0.125), as it must be (tau_F covers drum and all five pulleys, f_F two);
  with r_D = 10 mm friction would eat 31 % of the cable force;
- winch inertia J_D = 3.0e-5 kg m^2 (*estimate*): rotor about 1.3e-5 kg m^2 (between the
  AM3021, 0.48 N m / 0.107 kg cm^2, and AM3022, 0.84 N m / 0.161 kg cm^2, of Beckhoff's AM3000
  manual, the same frame size as the 0.69 N m AM3121) plus an aluminium drum of 20 mm radius
  and about 30 mm length, 1.7e-5 kg m^2;
- torque limit 2.76 N m = 4 x 0.69 N m (Beckhoff AM3000/AM3100 manuals: the peak current is
  about 4 times the standstill current);
- drive gains from eq. 9 (paper 000, Sec. 2.3): with the PI drive and no velocity feedforward
  a P position loop lags a ramp by ``v / K_pos``, which is the measured ``c_v v`` of eq. 9, so
  ``K_pos = 1 / c_v = 1 / (8.893e-5 min x 60 s/min) = 187.4 1/s``. With the pure P drive the
  winch is a torsional spring, ``FE = -tau / (K_v K_pos)``, which is eq. 8 when
  ``K_v K_pos = -K_p / c_f = 391.4 N m/m``; so ``K_v = 2.088 N m s/m`` of cable speed (0.0418
  N m s/rad at the shaft: with J_D a velocity-loop bandwidth of 1390 rad/s, 220 Hz, typical of
  a small servo). The PI integral time T_n = 10 ms (*estimate*, a typical drive setting, well
  below the position loop's crossover);
- cable: 1 mm Dyneema (UHMWPE) braid (*estimate*), ``EA = 2.0e4 N`` (an effective modulus of
  about 25 GPa on its 0.79 mm^2 section), over the free length plus 0.5 m from drum to the
  frame's exit pulley (*estimate*); material damping as a time constant 2e-4 s (``c = k tau``;
  a loss factor of about 0.1 at the platform's 100 Hz modes, *estimate*);
- sensors (*estimates*): motor encoder noise 2.4e-5 rad (one count of an 18-bit single-turn
  encoder); motor torque (from the current) 0.01 N m, 1.5 % of the nominal torque (paper 000:
  the torque reading is noisy enough to need a filter); load cell (Futek LRM200, 25 lb = 111 N
  range) 0.05 N, 0.05 % of its range with a 24-bit bridge amplifier; drive velocity 1e-3 m/s.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from msarm.cdpr.following_error import C_F, C_V_MIN, K_P, c_v_to_si
from msarm.cdpr.winch_friction import (
    TABLE_1_FORCE_NEGATIVE,
    TABLE_1_FORCE_POSITIVE,
    TABLE_1_TORQUE_NEGATIVE,
    TABLE_1_TORQUE_POSITIVE,
    V_HIGH_M_PER_MIN,
    V_LOW_M_PER_MIN,
    WinchFrictionModel,
)
from msarm.io.config import check_field_types, check_numbers, check_plant_name

__all__ = [
    "DEFAULT_CDPR_PLANT",
    "DRIVE_MODES",
    "IDEAL_CDPR_PLANT",
    "MAX_TIMESTEP",
    "MIN_TIMESTEP",
    "CableConfig",
    "CdprFrictionConfig",
    "CdprNoiseConfig",
    "CdprPlantConfig",
    "CdprWinchConfig",
    "DriveConfig",
    "DriveMode",
    "LoadCellConfig",
    "check_plant_name",
    "ideal_cdpr_config",
]

DriveMode = Literal["pi", "p"]
#: Coarsest plant time step [s]: the PLC cycle of paper 000 (1 ms); the plant steps
#: ``1 ms / timestep`` times a control cycle, so a step must divide it (checked by the run).
MAX_TIMESTEP = 0.001
#: Finest plant time step [s]: 100 plant steps a 1 ms cycle. A finer one (e.g. 1e-9 s, a
#: million steps a cycle, 1e10 for a 10 s trajectory) would make a run practically endless.
MIN_TIMESTEP = 1.0e-5
#: The velocity-loop modes of a drive: PI (default) or pure P (HC-e, paper 000 Sec. 3).
DRIVE_MODES: tuple[str, ...] = ("pi", "p")


@dataclass(frozen=True)
class CdprWinchConfig:
    """A direct-drive winch: motor rotor and drum on one shaft.

    Attributes:
        drum_radius: Drum radius r_D [m].
        inertia: Rotor plus drum inertia J_D about the shaft [kg m^2].
        torque_limit: Largest motor torque the drive gives [N m].
        nominal_torque: Nominal motor torque [N m] (informative; paper 000: 0.69 N m).
    """

    drum_radius: float = 0.02
    inertia: float = 3.0e-5
    torque_limit: float = 2.76
    nominal_torque: float = 0.69

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, positive=("drum_radius", "inertia", "torque_limit", "nominal_torque"))


@dataclass(frozen=True)
class DriveConfig:
    """The PLC position loop and the drive's velocity loop of every winch (paper 000 Sec. 2.3).

    PLC, every cycle: ``v_cmd = v_ff + K_pos (l_set - l_motor)``. Drive (its loop is much faster
    than the PLC cycle and is simulated as continuous): motor torque, reel-in positive,
    ``tau = K_v (v - v_cmd) + K_v / T_n * int (v - v_cmd) dt`` (PI) or without the integral
    (pure P), with ``v`` the cable speed, paid out positive. The velocity gain is not set
    directly: it follows from eq. 8, ``K_v = -1 / (K_pos * fe_compliance)``.

    Attributes:
        position_gain: K_pos of the PLC's P position loop [1/s].
        fe_compliance: c_f / K_p of eq. 8 [m/(N m)], < 0: the following error per unit motor
            torque of the pure-P drive at rest.
        integral_time: T_n of the PI velocity loop [s].
        default_mode: Velocity-loop mode after a reset when none is given ("pi" or "p").
    """

    position_gain: float = 1.0 / c_v_to_si(C_V_MIN)
    fe_compliance: float = C_F / K_P
    integral_time: float = 0.01
    default_mode: DriveMode = "pi"

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, positive=("position_gain", "integral_time"), finite=("fe_compliance",))
        if not self.fe_compliance < 0.0:
            raise ValueError(
                f"fe_compliance (c_f / K_p) must be a finite value < 0 m/(N m), got "
                f"{self.fe_compliance}"
            )
        if self.default_mode not in DRIVE_MODES:
            raise ValueError(
                f"default_mode must be one of {DRIVE_MODES}, got {self.default_mode!r}"
            )

    @property
    def velocity_gain(self) -> float:
        """K_v [N m per m/s of cable speed]: ``-1 / (K_pos c_f / K_p)``."""
        return -1.0 / (self.position_gain * self.fe_compliance)


@dataclass(frozen=True)
class CableConfig:
    """Elastic cables that go slack (one-sided springs with material damping).

    Cable ``i`` of unstretched length ``L0_i`` (frame exit to platform) has the stiffness
    ``k_i = EA / (L0_i + chain_length)`` and pulls with ``f = max(0, k e + k tau_d de/dt)``
    while its stretch ``e = l(q) - L0`` is positive.

    Attributes:
        axial_stiffness: EA [N].
        chain_length: Cable length from the drum to the frame's exit pulley [m].
        damping_time: tau_d [s]: the damping coefficient is ``k tau_d``.
    """

    axial_stiffness: float = 2.0e4
    chain_length: float = 0.5
    damping_time: float = 2.0e-4

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(
            self, positive=("axial_stiffness",), non_negative=("chain_length", "damping_time")
        )


@dataclass(frozen=True)
class CdprFrictionConfig:
    """The winch friction of paper 000: tau_F of eq. 5 on the winch, f_F of eq. 7 on the load cell.

    Coefficients in the units of Table 1 (f in N, v in m/min), as published.

    Attributes:
        enabled: Switch (off: no friction torque and the load cell reads the platform force).
        torque_negative: (c1n, c2n, c3n, c4n) of tau_F [N m] (Table 1, row 2).
        torque_positive: (c1p, c2p, c3p, c4p) of tau_F [N m] (Table 1, row 1).
        force_negative: (c1n, c2n, c3n, c4n) of f_F [N] (Table 1, row 4).
        force_positive: (c1p, c2p, c3p, c4p) of f_F [N] (Table 1, row 3).
        v_low: v_L [m/min].
        v_high: v_H [m/min], the fastest velocity of the friction tests.
        beyond_v_high: What the plant does at cable speeds beyond ``v_H``, where the model was
            not fitted: "clamp" (default) evaluates it at ``+-v_H`` (friction saturates, a
            Coulomb-like plateau), "extrapolate" evaluates eq. 4 there (its quadratic terms
            turn the negative-direction torque back down from about -13 m/min).
    """

    enabled: bool = True
    torque_negative: tuple[float, float, float, float] = TABLE_1_TORQUE_NEGATIVE
    torque_positive: tuple[float, float, float, float] = TABLE_1_TORQUE_POSITIVE
    force_negative: tuple[float, float, float, float] = TABLE_1_FORCE_NEGATIVE
    force_positive: tuple[float, float, float, float] = TABLE_1_FORCE_POSITIVE
    v_low: float = V_LOW_M_PER_MIN
    v_high: float = V_HIGH_M_PER_MIN
    beyond_v_high: Literal["clamp", "extrapolate"] = "clamp"

    def __post_init__(self) -> None:
        check_field_types(self)
        if self.beyond_v_high not in ("clamp", "extrapolate"):
            raise ValueError(
                f"friction.beyond_v_high must be 'clamp' or 'extrapolate', got "
                f"{self.beyond_v_high!r}"
            )
        check_numbers(self, positive=("v_low", "v_high"))
        if not self.v_low < self.v_high:  # in the file's unit, before model() converts to m/s
            raise ValueError(
                f"need v_low < v_high [m/min], got v_low={self.v_low:g}, v_high={self.v_high:g}"
            )
        self.model()  # validates the coefficients

    def model(self) -> WinchFrictionModel:
        """The friction model in SI (``msarm.cdpr.winch_friction``)."""
        return WinchFrictionModel.from_paper_units(
            self.torque_negative,
            self.torque_positive,
            self.force_negative,
            self.force_positive,
            v_low_m_per_min=self.v_low,
            v_high_m_per_min=self.v_high,
            extrapolate=self.beyond_v_high == "extrapolate",
        )


@dataclass(frozen=True)
class LoadCellConfig:
    """The load cell on pulley 3 of every cable (Futek LRM200, paper 000 Fig. 3).

    It reads ``f + f_F(f, v)`` (eq. 7) while the cable is taut, 0 when it is slack, plus
    ``bias`` and noise.

    Attributes:
        bias: Constant offset of the reading [N].
    """

    bias: float = 0.0

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, finite=("bias",))


@dataclass(frozen=True)
class CdprNoiseConfig:
    """Gaussian sensor noise (standard deviations), drawn from the plant's seeded generator.

    Attributes:
        enabled: Switch.
        encoder: Motor encoder [rad] (enters the cable length as ``r_D`` times it, and the
            following error).
        velocity: Cable speed reported by the drive [m/s].
        torque: Motor torque from the current [N m].
        load_cell: Load cell [N].
    """

    enabled: bool = True
    encoder: float = 2.4e-5
    velocity: float = 1.0e-3
    torque: float = 0.01
    load_cell: float = 0.05

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, non_negative=("encoder", "velocity", "torque", "load_cell"))


@dataclass(frozen=True)
class CdprPlantConfig:
    """The simulated IPAnema 3 Mini.

    Attributes:
        name: Name of the plant (logged).
        timestep: Plant, PLC and MuJoCo time step [s] (paper 000: 1 ms), in
            [:data:`MIN_TIMESTEP`, :data:`MAX_TIMESTEP`] = [1e-5, 1e-3] s; a run also needs it
            to divide the controller's 1 ms cycle.
        winch: Winches.
        drive: PLC position loop and drive velocity loop.
        cable: Cable elasticity.
        friction: Winch friction (eq. 5) and load-cell friction (eq. 7).
        load_cell: The load cells.
        noise: Sensor noise.
    """

    name: str = "default"
    timestep: float = 0.001
    winch: CdprWinchConfig = field(default_factory=CdprWinchConfig)
    drive: DriveConfig = field(default_factory=DriveConfig)
    cable: CableConfig = field(default_factory=CableConfig)
    friction: CdprFrictionConfig = field(default_factory=CdprFrictionConfig)
    load_cell: LoadCellConfig = field(default_factory=LoadCellConfig)
    noise: CdprNoiseConfig = field(default_factory=CdprNoiseConfig)

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, positive=("timestep",))
        if not MIN_TIMESTEP <= self.timestep <= MAX_TIMESTEP:
            raise ValueError(
                f"timestep must be in [{MIN_TIMESTEP:g}, {MAX_TIMESTEP:g}] s (1 to "
                f"{round(MAX_TIMESTEP / MIN_TIMESTEP)} plant steps a 1 ms control cycle), got "
                f"{self.timestep:g}"
            )
        check_plant_name(self.name)


def ideal_cdpr_config(name: str = "ideal") -> CdprPlantConfig:
    """No friction, no noise, stiff cables (EA 100 times the default); the same drives."""
    return CdprPlantConfig(
        name=name,
        cable=CableConfig(axial_stiffness=2.0e6),
        friction=CdprFrictionConfig(enabled=False),
        noise=CdprNoiseConfig(enabled=False),
    )


DEFAULT_CDPR_PLANT = CdprPlantConfig()
IDEAL_CDPR_PLANT = ideal_cdpr_config()
