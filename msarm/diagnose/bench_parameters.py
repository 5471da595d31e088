"""How close the diagnosis's parameters come to the simulated plant's (withheld-effect benchmark).

The benchmark scores names and the held-out gap; a term can be named, and shrink the gap, with
parameters that say something false about the robot. This module compares, on each
single-effect scenario, the parameters of the term msarm named for the plant's effect with the
parameters the plant was built with:

- ``sheath_friction``: the capstan term's ``mu`` against the sheath's friction coefficient;
- ``winch_friction``: the drive term's Coulomb [N m] and viscous [N m s/rad] levels against the
  winch's;
- ``elasticity``: the compliance [m/N] against ``1 / stiffness`` of the cable;
- ``cogging``: the amplitude ``sqrt(a^2 + b^2)`` [N m] of the cogging term against the plant's;
- ``sensor_bias``: the load cells' bias [N] against the plant's;
- ``delay``: the delay kernel's ``sum_j j w_j`` [samples] against the plant's sensing plus
  actuation delay [control periods = log samples];
- ``joint_friction``: model-free, the steady friction the named joint terms (Coulomb, viscous,
  Stribeck, Dahl) give at 0.05, 0.2 and 0.5 rad/s on every joint up to the highest one a named
  term acts on (all of them, with the library's terms), against the plant's
  ``coulomb + viscous * speed``: the RMS of the difference over the RMS of the plant's. The
  smoothed signs are taken as reached (``tanh(0.05 / 0.01) = 1`` to 1e-4, with the library's
  ``eps`` of 0.01 rad/s), and a Dahl term at its steady level.

Each is a relative error ``|fitted - true| / |true|``; None where the method did not name a
term that carries the parameter (the benchmark's names score that case). The same comparison
runs on the PySINDy baseline's coefficients (its capstan term is linearised, so its ``mu`` is
that of the first-order law). The joint friction's is a curve over the speeds
the tasks reach, not its terms' parameters: the plant has no Stribeck effect, and how the
named Stribeck and Dahl terms split the friction between them is not the plant's to say
(before 2026-11-29 a Stribeck term fitted that curve with a Coulomb level of 6.19 N m, within
9 % of the plant's curve).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from msarm.diagnose.effects import parameter_index, parameter_kind

__all__ = ["JOINT_SPEEDS", "parameter_errors", "summarise_parameter_errors"]

#: Joint speeds [rad/s] at which the joint friction's steady curve is compared.
JOINT_SPEEDS = (0.05, 0.2, 0.5)


def _relative(fitted: float, true: float) -> float | None:
    """``|fitted - true| / |true|``; None for a true value of 0 (no relative error)."""
    if float(true) == 0.0:
        return None
    return abs(float(fitted) - float(true)) / abs(float(true))


def _indexed(parameters: Mapping[str, float], kind: str) -> dict[int, float]:
    """``{j: value}`` of the parameters named ``kind[j]``."""
    out = {}
    for name, value in parameters.items():
        index = parameter_index(name)
        if index is not None and parameter_kind(name) == kind:
            out[index] = float(value)
    return out


def _joint_friction_curve(named: Mapping[str, Mapping[str, float]], speeds: np.ndarray) -> Any:
    """Steady friction ``(n_joints, n_speeds)`` [N m] of the named joint terms, or None."""
    curve: dict[int, np.ndarray] = {}

    def add(joint: int, values: np.ndarray) -> None:
        curve[joint] = curve.get(joint, np.zeros_like(speeds)) + values

    for term in ("coulomb", "dahl"):  # a level at speed (tanh(v / eps) = 1 to 1e-4 here)
        for j, level in _indexed(named.get(term, {}), "coulomb").items():
            add(j, np.full_like(speeds, level))
    for j, b in _indexed(named.get("viscous", {}), "viscous").items():
        add(j, b * speeds)
    if "stribeck" in named:
        p = named["stribeck"]
        levels, static = _indexed(p, "coulomb"), _indexed(p, "static")
        velocity, viscous = _indexed(p, "stribeck_velocity"), _indexed(p, "viscous")
        for j, c in levels.items():
            bump = (static[j] - c) * np.exp(-((speeds / velocity[j]) ** 2))
            add(j, c + bump + viscous.get(j, 0.0) * speeds)
    return curve or None


def parameter_errors(row: Mapping[str, Any], method: str = "msarm") -> dict[str, float | None]:
    """Relative errors of a method's parameters on one single-effect scenario (see the module).

    Args:
        row: A scenario's entry of the benchmark's results (``effects``, ``parameters``: the
            plant's draw, ``<method>.parameters``: the named terms' fitted parameters by name).
        method: ``"msarm"`` or ``"sindy"``.

    Returns:
        ``{parameter: relative error or None}`` for the scenario's effect; empty for a null
        plant, a scenario of two effects, one without the plant's parameters or an effect this
        module has no comparison for.
    """
    effects = list(row.get("effects", []))
    if len(effects) != 1:
        return {}
    effect = effects[0]
    true = row.get("parameters", {}).get(effect)
    if not true:  # results without the plant's draw (hand-made ones)
        return {}
    named: Mapping[str, Mapping[str, float]] = row.get(method, {}).get("parameters", {})
    if effect == "sheath_friction":
        mu = named.get("capstan", {}).get("mu")
        return {"mu": None if mu is None else _relative(mu, true["mu"])}
    if effect == "winch_friction":
        fitted = named.get("winch_friction", {})
        return {
            k: None if f"{k}[all]" not in fitted else _relative(fitted[f"{k}[all]"], true[k])
            for k in ("coulomb", "viscous")
        }
    if effect == "elasticity":
        c = named.get("elasticity", {}).get("compliance[all]")
        return {"compliance": None if c is None else _relative(c, 1.0 / true["stiffness"])}
    if effect == "cogging":
        fitted = named.get("motor_cogging", {})
        if "cogging_a[all]" not in fitted:
            return {"amplitude": None}
        amplitude = float(np.hypot(fitted["cogging_a[all]"], fitted["cogging_b[all]"]))
        return {"amplitude": _relative(amplitude, true["amplitude"])}
    if effect == "sensor_bias":
        bias = named.get("sensor", {}).get("bias[all]")
        return {"bias": None if bias is None else _relative(bias, true["tension_bias"])}
    if effect == "delay":
        weights = named.get("command_delay")
        periods = float(true["sensing_periods"]) + float(true["actuation_periods"])
        if weights is None or periods == 0:
            return {"delay": None}
        taps = _indexed(weights, "w")
        return {"delay": _relative(sum(k * w for k, w in taps.items()), periods)}
    if effect == "joint_friction":
        speeds = np.asarray(JOINT_SPEEDS, dtype=float)
        curve = _joint_friction_curve(named, speeds)
        if curve is None:
            return {"friction_curve": None}
        truth = true["coulomb"] + true["viscous"] * speeds
        n_joints = max(curve) + 1
        fitted = np.array([curve.get(j, np.zeros_like(speeds)) for j in range(n_joints)])
        error = np.sqrt(np.mean((fitted - truth) ** 2)) / np.sqrt(np.mean(truth**2))
        return {"friction_curve": float(error)}
    return {}


def summarise_parameter_errors(
    rows: list[Mapping[str, Any]], method: str = "msarm"
) -> dict[str, dict[str, dict[str, float | int | None]]]:
    """Median and largest relative error of each effect's parameters over its scenarios.

    Args:
        rows: The benchmark's scenario entries (single-effect ones are used).
        method: ``"msarm"`` or ``"sindy"``.

    Returns:
        ``{effect: {parameter: {"median", "max", "compared", "scenarios"}}}``: over the
        scenarios where the parameter could be compared (``compared`` of ``scenarios``);
        ``median`` and ``max`` None when none could.
    """
    collected: dict[str, dict[str, list[float | None]]] = {}
    for row in rows:
        for name, error in parameter_errors(row, method).items():
            effect = row["effects"][0]
            collected.setdefault(effect, {}).setdefault(name, []).append(error)
    out: dict[str, dict[str, dict[str, float | int | None]]] = {}
    for effect, by_name in collected.items():
        out[effect] = {}
        for name, errors in by_name.items():
            known = [e for e in errors if e is not None]
            out[effect][name] = {
                "median": float(np.median(known)) if known else None,
                "max": float(np.max(known)) if known else None,
                "compared": len(known),
                "scenarios": len(errors),
            }
    return out
