"""Parameters of the arm plant: winches, cables and the effects that make it a "real robot".

Every block is a frozen dataclass; ``msarm.io.config.load_config(path, PlantConfig)`` reads
one from YAML (unknown or missing keys are refused with the key named). Two presets:
:data:`DEFAULT_PLANT` ("the real robot": sheath friction, winch friction, elastic cables,
joint friction and sensor noise on) and :data:`IDEAL_PLANT` (no effect at all: the nominal
model with perfect tension sources).

Sources of the default values (plausible values for a robot of this size, not measurements):

- winch: drum radius 3 mm and peak torque F_max * r, as the model file's header sizes the
  motors; rotor inertia 3e-5 kg m^2 reflected at the drum (a 60 W flat brushless motor,
  ~1.2e-6 kg m^2, through a 5:1 gearbox);
- cable: 1 mm Dyneema (UHMWPE) rope, EA of about 1.5e4 N, over ~0.7 m: 2e4 N/m; internal
  damping 40 N s/m (a damping time c/k of 2 ms, a few percent of critical for the cable-arm
  modes);
- sheath friction: a Bowden sheath against a polymer cable, mu = 0.12 per radian of wrap.
  At q = 0 the arm's cables wrap 2.4-3.9 rad, which transmits exp(-mu Theta) = 62-75 % of
  the force when pulling, inside the 60-85 % reported for Bowden cables over about half a
  metre (Schiele et al., IEEE BioRob 2006; Jeong and Cho, IJPEM 2016). Over the whole joint
  range the wrap spans 1.8-5.9 rad (measured on a 9^4 grid of the range, edges included):
  49-81 % transmitted, the low end from the elbow cables (up to 4.7 and 5.9 rad) at the
  range's edges;
- winch friction: Coulomb 0.02 N m and viscous 2e-4 N m s/rad, about 1-2 % of the peak torque,
  a simplification of paper 000 eq. 4-5 (Coulomb + viscous, without its load and v^2 terms);
- joint friction: 0.15 N m Coulomb and 0.05 N m s/rad viscous at every joint (plain bearings);
- sensor noise: encoder 1e-4 rad (14-bit), load cell 0.3 N, motor torque (current) 0.005 N m.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field, replace

from msarm.errors import InputError
from msarm.io.config import check_field_types, check_numbers, check_plant_name

__all__ = [
    "DEFAULT_PLANT",
    "IDEAL_PLANT",
    "MAX_DELAY_PERIODS",
    "PLANT_PRESETS",
    "CoggingConfig",
    "DelayConfig",
    "EffectsConfig",
    "ElasticityConfig",
    "JointFrictionConfig",
    "PlantConfig",
    "SensorNoiseConfig",
    "SheathFrictionConfig",
    "WinchConfig",
    "WinchFrictionConfig",
    "ideal_config",
]


def _check_count(config: object, name: str, least: int) -> None:
    """Refuse a count that is not an integer >= ``least`` (``InputError``, named)."""
    value = getattr(config, name)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < least:
        raise InputError(f"{name} must be an integer >= {least}, got {value!r}")


@dataclass(frozen=True)
class WinchConfig:
    """The winch of every cable and its drive (the motor's own tension loop).

    Attributes:
        drum_radius: Winch drum radius r [m].
        rotor_inertia: Rotor and drum inertia about the drum axis [kg m^2].
        torque_limit_factor: Peak motor torque as a multiple of ``F_max * r`` [-].
        drive_gain: Proportional gain of the drive's tension loop on the load cell [-]: the
            motor torque is ``r (T_cmd + drive_gain (T_cmd - T_load_cell))``.
    """

    drum_radius: float = 0.003
    rotor_inertia: float = 3e-5
    torque_limit_factor: float = 1.0
    drive_gain: float = 4.0

    def __post_init__(self) -> None:
        check_numbers(self, positive=("drum_radius", "rotor_inertia", "torque_limit_factor"))
        check_numbers(self, non_negative=("drive_gain",))


@dataclass(frozen=True)
class ElasticityConfig:
    """Elastic cables that go slack (one-sided springs); off: rigid cables.

    Attributes:
        enabled: On: winch dynamics and elastic, slackening cables (and sheath friction with
            stiction). Off: the cable is rigid and the winch quasi-static, the tension is what
            the drive renders.
        stiffness: Cable stiffness k [N/m] (end to end).
        damping: The rope's internal damping c [N s/m], a dashpot in parallel with the whole
            cable acting on its stretch rate while it is taut.
    """

    enabled: bool = True
    stiffness: float = 2.0e4
    damping: float = 40.0

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, positive=("stiffness",), non_negative=("damping",))


@dataclass(frozen=True)
class SheathFrictionConfig:
    """Capstan friction of the cable in its sheath (:class:`msarm.plant.effects.SheathFriction`).

    Attributes:
        enabled: Switch.
        mu: Friction coefficient per radian of wrap [1/rad].
        smoothing_velocity: Cable speed over which sgn(v) is smoothed (tanh) [m/s].
    """

    enabled: bool = True
    mu: float = 0.12
    smoothing_velocity: float = 0.002

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, positive=("smoothing_velocity",), non_negative=("mu",))


@dataclass(frozen=True)
class WinchFrictionConfig:
    """Coulomb + viscous friction of winch and motor (paper 000 eq. 4-5 without load and v^2 terms).

    Attributes:
        enabled: Switch.
        coulomb: Coulomb friction torque [N m].
        viscous: Viscous coefficient [N m s/rad].
        smoothing_speed: Winch speed over which sgn is smoothed (tanh) [rad/s].
    """

    enabled: bool = True
    coulomb: float = 0.02
    viscous: float = 2e-4
    smoothing_speed: float = 0.5

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, positive=("smoothing_speed",), non_negative=("coulomb", "viscous"))


@dataclass(frozen=True)
class JointFrictionConfig:
    """Coulomb + viscous joint friction (MuJoCo's dry friction constraint and damping).

    Attributes:
        enabled: Switch.
        coulomb: Coulomb friction torque of every joint [N m].
        viscous: Viscous coefficient of every joint [N m s/rad].
    """

    enabled: bool = True
    coulomb: float = 0.15
    viscous: float = 0.05

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, non_negative=("coulomb", "viscous"))


@dataclass(frozen=True)
class CoggingConfig:
    """Motor cogging torque, periodic in the motor angle (paper 001 eq. 2-3).

    Attributes:
        enabled: Switch.
        amplitude: Cogging torque amplitude [N m].
        periods_per_revolution: Cogging periods per motor revolution (pole/slot pattern).
        phase: Phase [rad].
    """

    enabled: bool = False
    amplitude: float = 0.01
    periods_per_revolution: int = 24
    phase: float = 0.0

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(self, finite=("amplitude", "phase"))
        _check_count(self, "periods_per_revolution", 1)


@dataclass(frozen=True)
class SensorNoiseConfig:
    """Gaussian sensor noise and constant bias.

    Attributes:
        enabled: Switch.
        joint_noise: Joint encoder noise std [rad].
        motor_angle_noise: Motor encoder noise std [rad].
        tension_noise: Load cell noise std [N].
        tension_bias: Load cell bias [N].
        torque_noise: Motor torque (current) noise std [N m].
    """

    enabled: bool = True
    joint_noise: float = 1e-4
    motor_angle_noise: float = 1e-4
    tension_noise: float = 0.3
    tension_bias: float = 0.0
    torque_noise: float = 0.005

    def __post_init__(self) -> None:
        check_field_types(self)
        check_numbers(
            self,
            non_negative=("joint_noise", "motor_angle_noise", "tension_noise", "torque_noise"),
            finite=("tension_bias",),
        )


#: Longest delay a :class:`DelayConfig` takes, in control periods (40 s at 250 Hz, longer
#: than any task; a run refuses a delay as long as itself).
MAX_DELAY_PERIODS = 10_000


@dataclass(frozen=True)
class DelayConfig:
    """A delay on sensing and on actuation, in control periods.

    Attributes:
        enabled: Switch.
        sensing_periods: Readings reach the controller this many control periods late.
        actuation_periods: Commands reach the drives this many control periods late.
    """

    enabled: bool = False
    sensing_periods: int = 1
    actuation_periods: int = 0

    def __post_init__(self) -> None:
        check_field_types(self)
        for name in ("sensing_periods", "actuation_periods"):
            _check_count(self, name, 0)
            if getattr(self, name) > MAX_DELAY_PERIODS:  # its buffer would not fit in memory
                raise InputError(
                    f"{name} must be at most {MAX_DELAY_PERIODS} control periods, got "
                    f"{getattr(self, name)}"
                )


@dataclass(frozen=True)
class EffectsConfig:
    """Switches and parameters of the built-in effects.

    Attributes:
        sheath_friction: Capstan friction of each cable in its sheath.
        winch_friction: Coulomb + viscous friction of each winch.
        elasticity: Elastic, damped cables and winch dynamics (off: rigid cables).
        joint_friction: Coulomb + viscous friction at each joint.
        cogging: Motor cogging torque.
        sensor_noise: Gaussian noise and load-cell bias on the readings.
        delay: Sensing and actuation delay in control periods.
    """

    sheath_friction: SheathFrictionConfig = field(default_factory=SheathFrictionConfig)
    winch_friction: WinchFrictionConfig = field(default_factory=WinchFrictionConfig)
    elasticity: ElasticityConfig = field(default_factory=ElasticityConfig)
    joint_friction: JointFrictionConfig = field(default_factory=JointFrictionConfig)
    cogging: CoggingConfig = field(default_factory=CoggingConfig)
    sensor_noise: SensorNoiseConfig = field(default_factory=SensorNoiseConfig)
    delay: DelayConfig = field(default_factory=DelayConfig)

    def __post_init__(self) -> None:
        check_field_types(self)

    def enabled(self) -> list[str]:
        """Names of the effects switched on.

        Returns:
            The names (as in :data:`EFFECT_NAMES`, in that order) of the blocks whose
            ``enabled`` is true.
        """
        return [name for name in EFFECT_NAMES if getattr(self, name).enabled]


#: Names of the built-in effects, in the order the plant applies them.
EFFECT_NAMES = (
    "sheath_friction",
    "winch_friction",
    "elasticity",
    "joint_friction",
    "cogging",
    "sensor_noise",
    "delay",
)


@dataclass(frozen=True)
class PlantConfig:
    """The arm plant.

    Attributes:
        name: Name of the plant (logged).
        timestep: Plant (MuJoCo) time step [s]; 1 ms or finer.
        winch: Winches and drives.
        effects: The effects and their switches.
    """

    name: str = "default"
    timestep: float = 0.001
    winch: WinchConfig = field(default_factory=WinchConfig)
    effects: EffectsConfig = field(default_factory=EffectsConfig)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"name must be a non-empty string, got {self.name!r}")
        check_plant_name(self.name)
        check_field_types(self)
        check_numbers(self, positive=("timestep",))
        if not 0 < self.timestep <= 0.001:
            raise InputError(f"timestep must be in (0, 0.001] s, got {self.timestep}")


def ideal_config(name: str = "ideal") -> PlantConfig:
    """A plant with every effect off: rigid cables, perfect tension sources, no noise.

    Args:
        name: Name of the plant (logged; it names the run folder).

    Returns:
        The default plant's configuration with every effect's ``enabled`` false.

    Raises:
        InputError: ``name`` is not a valid plant name.
    """
    off = {name_: replace(getattr(EffectsConfig(), name_), enabled=False) for name_ in EFFECT_NAMES}
    return PlantConfig(name=name, effects=EffectsConfig(**off))


DEFAULT_PLANT = PlantConfig()
IDEAL_PLANT = ideal_config()
#: Plants known by name (``--plant default``, a recipe's ``data.plant: ideal``).
PLANT_PRESETS: dict[str, PlantConfig] = {"default": DEFAULT_PLANT, "ideal": IDEAL_PLANT}
