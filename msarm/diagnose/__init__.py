"""The sim-to-real gap diagnosis: where the gap lies, which effect causes it, how far it shrinks.

Modules:

- ``residuals``: per-sample residuals of a log against the nominal model (the joint-torque
  residual ``tau_MS - ID``, the drive residual ``F - F_cmd``, the cable length error, a
  short-window replay of the nominal dynamics driven by the logged tensions); never opens the
  ground-truth sidecar; ``missing_values`` reads a log whose samples have gaps (NaN, nulls)
  and leaves them out as a dropout, with a warning; ``log_check`` says what the diagnosis
  can make of a log before it runs (``msarm log check``).
- ``where``: the residual energy broken down by channel, phase of motion, load and region of
  posture, as a ranked table and a heat map; ``noise_floor`` estimates the sensors' white
  noise from a log and the joint-torque residual it alone makes, which the breakdown takes
  off before it names hot spots.
- ``signals``, ``effects``, ``cable_effects``, ``fitting``: the library of candidate effects
  (joint friction: Coulomb, viscous, Stribeck, Dahl; capstan sheath friction; mass error
  through Pinocchio's regressor; load-cell bias and scale; winch friction, motor cogging and
  command delay on the drive; cable elasticity, sheath stretch, backlash, slack and encoder
  skew on the cable lengths), each a parametric term
  fitted by least squares or IPOPT (casadi), with bootstrap over runs.
- ``builder``: the signals and the residuals of several logs, by channel group, with run
  labels.
- ``select``: forward selection of candidate effects by the share of the held-out residual
  they explain, with a confounding guard and a confidence per effect, and the gap before and
  after (``msarm diagnose``); ``stack`` holds its internals (the normalised stack of channel
  groups, the cached fits), ``result`` its answer (``Diagnosis``).
- ``report``: the Markdown and HTML report with the waterfall, gap and heat-map plots.
- ``scenarios``, ``bench``, ``baseline``: the withheld-effect benchmark against a PySINDy
  baseline (``msarm bench diagnose``).

The entry points are importable from the package itself (``from msarm.diagnose import
diagnose, CandidateEffect, register``; see ``__all__``).
"""

from importlib import import_module
from typing import Any

#: The public API by name, and the module each comes from (imported when first asked for, so
#: that importing one submodule does not load them all).
_EXPORTS = {
    "diagnose": "select",
    "load_data": "select",
    "select_effects": "select",
    "available_candidates": "select",
    "default_candidates": "select",
    "Diagnosis": "result",
    "SelectedEffect": "result",
    "CandidateEffect": "effects",
    "register": "effects",
    "Signals": "signals",
    "ResidualSpec": "residuals",
    "DiagnosisWarning": "residuals",
    "diagnose_where": "where",
    "write_report": "report",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    """``msarm.diagnose.<name>`` for the names of :data:`__all__` (imported on first use)."""
    if name in _EXPORTS:
        value = getattr(import_module(f"{__name__}.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
