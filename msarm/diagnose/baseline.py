"""The PySINDy baseline of the withheld-effect benchmark: sparse regression over the same terms.

SINDy-style identification regresses the residual on a library of candidate terms and keeps
the terms whose coefficients survive sequential thresholding (PySINDy's ``STLSQ``). Here the
library is the diagnosis's own candidates, those that can be written linearly in their
parameters: every linear candidate as it is, the capstan term in its linearised form; the
Stribeck term (nonlinear in its Stribeck velocity) has no linear form and is left out. The
regression runs on the same normalised, stacked residual as :func:`msarm.diagnose.select.diagnose`
(each channel group divided by its spread), over the training runs only.

What it answers: the terms with a non-zero coefficient, ranked by their share of the fitted
model's energy on the training runs (a library regression has no held-out step; that is the
difference the benchmark measures). The held-out gap before and after uses the same groups and
RMSE as the diagnosis.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from msarm.diagnose.effects import CableCapstanFriction, CableCapstanHysteresis, CandidateEffect
from msarm.diagnose.fitting import one_blas_thread
from msarm.diagnose.stack import DiagnosisData, Embedded, pooled_rmse
from msarm.errors import InputError

__all__ = [
    "DEFAULT_SINDY_ALPHA",
    "DEFAULT_SINDY_THRESHOLD",
    "BaselineResult",
    "check_setting",
    "sindy_baseline",
]

FloatArray = NDArray[np.float64]

#: STLSQ threshold on the coefficients of unit-norm library columns for a unit-norm target.
DEFAULT_SINDY_THRESHOLD = 0.05
#: Ridge weight of STLSQ (on unit-norm columns): PySINDy's own default. Until 2026-11-29 it
#: was 1e-3, which let two nearly collinear mass-error columns (correlation 0.998) take large
#: opposite coefficients past the threshold: a mass error named on every null plant.
DEFAULT_SINDY_ALPHA = 0.05


@dataclass(frozen=True)
class BaselineResult:
    """What the sparse regression names, and the held-out gap with its model.

    Attributes:
        names: Terms with a non-zero coefficient, largest training contribution first.
        contributions: Each named term's share of the fitted model's training energy [-].
        library: The terms in the library, in column order.
        gap_before: Pooled held-out RMSE of each group, nominal model (group units).
        gap_after: The same after subtracting the sparse model's prediction.
        excluded: Candidates left out of the library (no linear form), with the reason.
        parameters: Each named term's coefficients in its parameters' units, by parameter
            name (a capstan term's ``mu`` is that of its linearised form).
    """

    names: tuple[str, ...]
    contributions: dict[str, float]
    library: tuple[str, ...]
    gap_before: dict[str, float]
    gap_after: dict[str, float]
    excluded: dict[str, str]
    parameters: dict[str, dict[str, float]] = field(default_factory=dict)

    def group_shrink(self, group: str) -> float:
        """``1 - RMSE_after / RMSE_before`` of a group, pooled over its channels [-]."""
        before, after = self.gap_before[group], self.gap_after[group]
        return 0.0 if before == 0.0 else 1.0 - after / before

    def as_dict(self) -> dict:
        """A JSON-ready dict."""
        return {
            "names": list(self.names),
            "contributions": dict(self.contributions),
            "library": list(self.library),
            "gap_before": dict(self.gap_before),
            "gap_after": dict(self.gap_after),
            "excluded": dict(self.excluded),
            "parameters": {k: dict(v) for k, v in self.parameters.items()},
        }


def check_setting(name: str, value: float) -> None:
    """Refuse a threshold or ridge weight that is not finite and >= 0 (InputError naming it)."""
    if not np.isfinite(value) or value < 0:
        raise InputError(f"{name}: expected a finite value >= 0, got {value}")


def _linear_form(term: CandidateEffect) -> CandidateEffect | None:
    if term.linear:
        return term
    if isinstance(term, CableCapstanFriction):
        return CableCapstanFriction(
            n_cables=term.n_cables,
            n_joints=term.n_joints,
            eps=term.eps,
            per_cable=term.per_cable,
            linearised=True,
        )
    if isinstance(term, CableCapstanHysteresis):
        return CableCapstanHysteresis(
            n_cables=term.n_cables,
            n_joints=term.n_joints,
            mus=term.mus,
            linearised=True,
        )
    return None


@one_blas_thread
def sindy_baseline(
    data: DiagnosisData,
    threshold: float = DEFAULT_SINDY_THRESHOLD,
    alpha: float = DEFAULT_SINDY_ALPHA,
) -> BaselineResult:
    """Sparse regression (PySINDy ``STLSQ``) of the residual on the candidates' library.

    Args:
        data: The diagnosis data (:func:`msarm.diagnose.select.load_data`): the same logs,
            groups and candidates as the diagnosis.
        threshold: STLSQ threshold on unit-norm-column coefficients for a unit-norm target.
        alpha: STLSQ ridge weight.

    Returns:
        The :class:`BaselineResult`.

    Raises:
        InputError: A threshold or alpha that is negative or not finite, or no library term.
    """
    import pysindy

    for name, value in (("threshold", threshold), ("alpha", alpha)):
        check_setting(name, value)
    library: list[Embedded] = []
    excluded: dict[str, str] = {}
    for candidate in data.candidates:
        linear = _linear_form(candidate.term)
        if linear is None:
            excluded[candidate.name] = "not linear in its parameters"
            continue
        library.append(Embedded(linear, data.layout))
    if not library:
        raise InputError("data: no candidate has a linear form for the library")
    train_design = [term.design(data.train) for term in library]
    sizes = [d.shape[2] for d in train_design]
    X = np.concatenate(train_design, axis=2).reshape(-1, sum(sizes))
    y = data.r_train.reshape(-1)
    column_norm = np.linalg.norm(X, axis=0)
    column_norm = np.where(column_norm > 0, column_norm, 1.0)
    target_norm = float(np.linalg.norm(y)) or 1.0
    optimizer = pysindy.STLSQ(threshold=float(threshold), alpha=float(alpha))
    with warnings.catch_warnings():
        # "eliminated all coefficients" is an answer here (nothing named), not a problem
        warnings.filterwarnings("ignore", message="Sparsity parameter is too big")
        optimizer.fit(X / column_norm, y / target_norm)
    coefficients = np.asarray(optimizer.coef_, dtype=float).reshape(-1)
    coefficients = coefficients / column_norm * target_norm
    parts = np.split(coefficients, np.cumsum(sizes)[:-1])

    energy: dict[str, float] = {}
    parameters: dict[str, dict[str, float]] = {}
    hold_prediction = np.zeros_like(data.r_hold)
    for term, design, theta in zip(library, train_design, parts, strict=True):
        if not np.any(theta != 0.0):
            continue
        energy[term.name] = float(np.sum(np.einsum("tnp,p->tn", design, theta) ** 2))
        parameters[term.name] = dict(zip(term.parameter_names, map(float, theta), strict=True))
        hold_prediction += np.einsum("tnp,p->tn", term.design(data.hold), theta)
    total = sum(energy.values()) or 1.0
    names = tuple(sorted(energy, key=lambda n: -energy[n]))
    before = data.layout.unstack(data.r_hold)
    after = data.layout.unstack(data.r_hold - hold_prediction)
    return BaselineResult(
        names=names,
        contributions={n: energy[n] / total for n in names},
        library=tuple(t.name for t in library),
        gap_before={g: pooled_rmse(v) for g, v in before.items()},
        gap_after={g: pooled_rmse(v) for g, v in after.items()},
        excluded=excluded,
        parameters={n: parameters[n] for n in names},
    )
