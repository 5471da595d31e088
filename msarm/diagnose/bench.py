"""The withheld-effect benchmark: does the diagnosis name the effect the logs were made with?

For every scenario of :mod:`msarm.diagnose.scenarios` (a plant with one effect, two effects,
or only sensor noise), the logs of its training and held-out tasks are diagnosed twice from
the same data (:func:`msarm.diagnose.select.load_data`): by the forward selection of
:func:`msarm.diagnose.select.select_effects` and by the PySINDy baseline
(:func:`msarm.diagnose.baseline.sindy_baseline`). Neither sees the sidecar or the scenario.

Scores (each for both methods):

- **top-1 accuracy** on single-effect scenarios: the first named term is one of the
  candidates of the plant's effect (:data:`EFFECT_CANDIDATES`);
- **both found** on two-effect scenarios: each effect has one of its candidates among the
  named terms;
- **false alarms** on null plants: any term named;
- **held-out gap shrink** on single-effect scenarios: ``1 - RMSE_after / RMSE_before`` of the
  pooled held-out residual on the groups the effect shows in (:data:`EFFECT_GROUPS`, mean over
  them). Sensor noise bounds it below 1, so the *excess* shrink is also given: the same with
  the noise floor removed, ``1 - sqrt((after^2 - floor^2) / (before^2 - floor^2))``, the floor
  of each group being the mean held-out RMSE of the null scenarios (same tasks, same noise;
  a group without a floor counted noise-free, as in the ceiling: until 2026-11-29 such
  scenarios, the elasticity draws, were left out of the mean).
  The *ceiling* is the raw shrink of a perfect diagnosis, one that leaves only the noise:
  ``1 - floor / RMSE_before`` (a group without a floor, such as the cable lengths that rigid
  null plants lack, counted noise-free). It is an estimate (the floor is the null plants'
  mean), so a method can land a little above it;
- **extra terms**: terms named beyond the candidates of the scenario's effects, mean per
  scenario with effects (a precision score; some are real side effects of the plant, e.g. an
  elastic cable's winch dynamics show as a drive lag);
- **time per scenario**: reading the logs and diagnosing (log generation excluded); for the
  diagnosis also the part up to the end of the forward selection (reading the logs, the
  screening and joint fits), without the bootstrap and the replay that PySINDy does not do.

Results are written after each scenario (atomically) to ``results.json`` in the output
folder, with ``confusion.png`` (:func:`plot_benchmark`) at the end; a rerun with the same
settings, model (its SHA-256) and code (:func:`~msarm.io.code_version.code_fingerprint`,
scope ``"diagnosis"``: another msarm version or library version scores again) reuses the
scenarios already scored (``rescore`` diagnoses them again from their cached logs; an
unreadable ``results.json`` is no cache, with a :class:`BenchCacheWarning`).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msarm.diagnose.baseline import (
    DEFAULT_SINDY_ALPHA,
    DEFAULT_SINDY_THRESHOLD,
    check_setting,
    sindy_baseline,
)
from msarm.diagnose.bench_parameters import summarise_parameter_errors
from msarm.diagnose.residuals import DiagnosisWarning
from msarm.diagnose.scenarios import (
    Scenario,
    ScenarioRunError,
    build_scenarios,
    generate_logs,
    scenario_tasks,
)
from msarm.diagnose.select import DEFAULT_THRESHOLD, check_threshold, load_data, select_effects
from msarm.errors import InputError, MsarmWarning
from msarm.io.atomic import write_json_atomic
from msarm.io.code_version import code_fingerprint
from msarm.model import RobotModel

__all__ = [
    "EFFECT_CANDIDATES",
    "EFFECT_GROUPS",
    "BenchCacheWarning",
    "BenchSettings",
    "confusion_columns",
    "plot_benchmark",
    "run_diagnosis_benchmark",
    "summarise",
]

#: Plant effect -> the candidate names that count as naming it.
EFFECT_CANDIDATES: dict[str, tuple[str, ...]] = {
    # sheath_stretch: the sheath's friction seen in the lengths of elastic cables
    "sheath_friction": ("capstan", "capstan_hysteresis", "sheath_stretch"),
    "winch_friction": ("winch_friction",),
    "elasticity": ("elasticity",),
    "joint_friction": ("coulomb", "viscous", "stribeck", "dahl"),
    "cogging": ("motor_cogging",),
    "sensor_bias": ("sensor",),
    "delay": ("command_delay",),
}
#: Plant effect -> the residual groups it shows in (where its gap shrink is measured).
EFFECT_GROUPS: dict[str, tuple[str, ...]] = {
    "sheath_friction": ("joint",),
    "winch_friction": ("drive",),
    "elasticity": ("length",),
    "joint_friction": ("joint",),
    "cogging": ("drive",),
    "sensor_bias": ("joint", "drive"),
    "delay": ("drive",),
}


class BenchCacheWarning(MsarmWarning):
    """The cached ``results.json`` cannot be read: its scenarios are scored again.

    The message names the file and what is wrong with it; the scenarios' cached logs are
    still reused (only the diagnosis runs again), and the file is written anew.
    """


@dataclass(frozen=True)
class BenchSettings:
    """Settings of the benchmark (written with the results; a change re-scores).

    Attributes:
        seed: Seed of the scenarios and tasks.
        draws: Parameter draws per effect class.
        n_null: Null scenarios (sensor noise only).
        n_train: Training tasks per scenario.
        n_holdout: Held-out tasks per scenario.
        duration: Duration of each task [s].
        threshold: The diagnosis's selection threshold [-].
        n_boot: Bootstrap draws of the diagnosis (confidence and std).
        effects: Effect classes to cover (all of :data:`EFFECT_CANDIDATES` when empty).
        pairs: Include the two-effect scenarios.
        sindy_threshold: The PySINDy baseline's STLSQ threshold (on unit-norm columns).
        sindy_alpha: The PySINDy baseline's STLSQ ridge weight (PySINDy's default).
    """

    seed: int = 0
    draws: int = 3
    n_null: int = 3
    n_train: int = 4
    n_holdout: int = 2
    duration: float = 10.0
    threshold: float = DEFAULT_THRESHOLD
    n_boot: int = 10
    effects: tuple[str, ...] = ()
    pairs: bool = True
    sindy_threshold: float = DEFAULT_SINDY_THRESHOLD
    sindy_alpha: float = DEFAULT_SINDY_ALPHA


def _check(settings: BenchSettings) -> None:
    unknown = [e for e in settings.effects if e not in EFFECT_CANDIDATES]
    if unknown:
        raise InputError(
            f"effects: unknown effect class {unknown[0]!r}; known: {', '.join(EFFECT_CANDIDATES)}"
        )
    for name in ("draws", "n_train", "n_holdout"):
        if int(getattr(settings, name)) < 1:
            raise InputError(f"{name}: expected an integer >= 1, got {getattr(settings, name)}")
    if settings.n_null < 0:
        raise InputError(f"n_null: expected an integer >= 0, got {settings.n_null}")
    if not settings.duration > 0:
        raise InputError(f"duration: expected > 0 s, got {settings.duration}")
    check_threshold(settings.threshold)  # select_effects' own check, before any simulation
    check_setting("sindy_threshold", settings.sindy_threshold)  # before any simulation
    check_setting("sindy_alpha", settings.sindy_alpha)


def _scenarios(settings: BenchSettings) -> list[Scenario]:
    kwargs: dict[str, Any] = {
        "seed": settings.seed,
        "draws": settings.draws,
        "n_null": settings.n_null,
    }
    if not settings.pairs:
        kwargs["pairs"] = ()
    scenarios = build_scenarios(**kwargs)
    if settings.effects:
        wanted = set(settings.effects)
        scenarios = [s for s in scenarios if not s.effects or set(s.effects) <= wanted]
    # null plants first: their residuals give the noise floor of the excess shrink
    return sorted(scenarios, key=lambda s: len(s.effects) > 0)


def _named(names: tuple[str, ...], effect: str) -> bool:
    return any(n in EFFECT_CANDIDATES[effect] for n in names)


def _score_one(scenario: Scenario, names: tuple[str, ...]) -> dict[str, Any]:
    if not scenario.effects:
        return {"kind": "null", "false_alarm": bool(names)}
    if len(scenario.effects) == 1:
        effect = scenario.effects[0]
        return {"kind": "single", "top1": bool(names) and _named(names[:1], effect)}
    return {"kind": "pair", "both": all(_named(names, e) for e in scenario.effects)}


def _shrink(before: dict[str, float], after: dict[str, float], groups: tuple[str, ...]) -> float:
    values = [1.0 - after[g] / before[g] for g in groups if g in before and before[g] > 0]
    return float(np.mean(values)) if values else float("nan")


def _excess_shrink(
    before: dict[str, float],
    after: dict[str, float],
    groups: tuple[str, ...],
    floor: dict[str, float],
) -> float:
    values = []
    for g in groups:
        if g not in before:
            continue
        level = floor.get(g, 0.0)  # no floor: noise-free, as in the ceiling
        gap = before[g] ** 2 - level**2
        if gap <= 0:
            continue
        values.append(1.0 - np.sqrt(max(after[g] ** 2 - level**2, 0.0) / gap))
    return float(np.mean(values)) if values else float("nan")


def _diagnose_scenario(
    model: RobotModel, train: list[Path], held: list[Path], settings: BenchSettings
) -> dict[str, Any]:
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DiagnosisWarning)
        data = load_data(model, train, held)
    loaded = time.perf_counter()
    marks: list[tuple[float, str]] = []
    diagnosis = select_effects(
        data,
        settings.threshold,
        settings.n_boot,
        settings.seed,
        progress=lambda text: marks.append((time.perf_counter(), text)),
    )
    selected = time.perf_counter()
    # the forward selection ends where the bootstrap (or, without one, the replay) starts
    chosen_at = next(
        (t for t, text in marks if text.startswith(("bootstrap", "replaying"))), selected
    )
    baseline = sindy_baseline(data, threshold=settings.sindy_threshold, alpha=settings.sindy_alpha)
    done = time.perf_counter()
    return {
        "msarm": {
            "names": list(diagnosis.names),
            "confidence": [
                s.confidence if np.isfinite(s.confidence) else None for s in diagnosis.selected
            ],
            "parameters": {s.name: s.as_dict()["parameters"] for s in diagnosis.selected},
            "gap_before": {g: float(diagnosis.waterfall[0][g]) for g in diagnosis.groups},
            "gap_after": {g: float(diagnosis.waterfall[-1][g]) for g in diagnosis.groups},
            "seconds": selected - start,
            "selection_seconds": chosen_at - start,
        },
        "sindy": {
            "names": list(baseline.names),
            "contributions": baseline.contributions,
            "gap_before": baseline.gap_before,
            "gap_after": baseline.gap_after,
            "parameters": baseline.parameters,
            "seconds": (done - selected) + (loaded - start),
        },
        "load_seconds": loaded - start,
    }


def run_diagnosis_benchmark(
    model: RobotModel,
    out: Path,
    settings: BenchSettings | None = None,
    progress: Callable[[str], None] | None = None,
    rescore: bool = False,
) -> dict[str, Any]:
    """Generate (or reuse) the scenarios' logs, diagnose each with both methods, score.

    Args:
        model: The nominal arm model.
        out: Folder of the logs (``out/logs``) and of ``results.json``.
        settings: The benchmark settings.
        progress: Called with a line of text before each scenario.
        rescore: Diagnose every scenario again (its logs are still reused).

    Returns:
        The report: settings, one entry per scenario (effects, drawn parameters, both
        methods' answers, gaps and times, scores), the scenarios whose simulation diverged
        (``failed``, not scored), the model's SHA-256 (``model_sha256``) and the summary of
        :func:`summarise`. An unreadable ``results.json`` is no cache
        (:class:`BenchCacheWarning`).

    Raises:
        InputError: Bad settings.
    """
    settings = settings or BenchSettings()
    _check(settings)
    out = Path(out)
    _check_out(out)
    out.mkdir(parents=True, exist_ok=True)
    results_path = out / "results.json"
    # the set of effects, not their order or repeats, makes the scenarios
    settings_dict = {**asdict(settings), "effects": sorted(set(settings.effects))}
    done: dict[str, Any] = {}
    code = code_fingerprint("diagnosis")
    if results_path.is_file() and not rescore:
        done = _cached_rows(results_path, settings_dict, model.sha256, code)
    scenarios = _scenarios(settings)
    reused = sum(scenario.name in done for scenario in scenarios)
    if reused and progress is not None:
        progress(
            f"{reused} of {len(scenarios)} scenarios reused from {results_path} (their times "
            "are those of the run that scored them; --rescore scores them again)"
        )
    plot_path = out / "confusion.png"
    if reused < len(scenarios):  # the plot is of the results being replaced: not left beside
        plot_path.unlink(missing_ok=True)  # the new ones, should this run be interrupted
    train_tasks, held_tasks = scenario_tasks(
        model, settings.n_train, settings.n_holdout, settings.duration, settings.seed
    )
    rows: list[dict[str, Any]] = []
    failed: list[dict[str, str]] = []
    for k, scenario in enumerate(scenarios, start=1):
        if scenario.name in done:
            rows.append(done[scenario.name])
            continue
        if progress is not None:
            progress(f"[{k}/{len(scenarios)}] {scenario.name}: simulating (or reusing cached runs)")
        sim_start = time.perf_counter()
        try:
            train, held = generate_logs(model, scenario, train_tasks, held_tasks, out / "logs")
        except ScenarioRunError as exc:  # a diverged run: reported, not scored
            failed.append({"scenario": scenario.name, "error": str(exc)})
            if progress is not None:
                progress(f"[{k}/{len(scenarios)}] {scenario.name}: {exc}")
            continue
        sim_seconds = time.perf_counter() - sim_start
        if progress is not None:
            progress(f"[{k}/{len(scenarios)}] {scenario.name}: diagnosing")
        answer = _diagnose_scenario(model, list(train), list(held), settings)
        row = {
            "scenario": scenario.name,
            "effects": list(scenario.effects),
            "parameters": scenario.parameters,
            "simulation_seconds": sim_seconds,
            **answer,
        }
        for method in ("msarm", "sindy"):
            row[method]["score"] = _score_one(scenario, tuple(row[method]["names"]))
        rows.append(row)
        report = {
            "settings": settings_dict,
            "model_sha256": model.sha256,
            "code": code,
            "scenarios": rows,
            "failed": failed,
        }
        write_json_atomic(results_path, report)
    summary = summarise(rows)
    report = {
        "settings": settings_dict,
        "model_sha256": model.sha256,
        "code": code,
        "scenarios": rows,
        "failed": failed,
        "summary": summary,
    }
    write_json_atomic(results_path, report)
    plot_benchmark(report, plot_path)
    return report


def _check_out(out: Path) -> None:
    """Refuse, before any simulation, an ``out`` whose results, plot or logs cannot be written.

    Raises:
        InputError: ``out`` is a file, ``results.json`` or ``confusion.png`` in it a folder,
            or ``logs`` in it a file.
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: {out} is a file; expected a folder (created if missing)")
    for name in ("results.json", "confusion.png"):
        if (out / name).is_dir():
            raise InputError(f"cannot write {out / name}: it is a folder, expected a file path")
    logs = out / "logs"
    if logs.exists() and not logs.is_dir():
        raise InputError(f"{logs} is a file; expected the folder of the scenarios' logs")


#: Keys of a scored scenario's entry in ``results.json``, and of each method's answer in it.
_ROW_KEYS = ("scenario", "effects", "msarm", "sindy")
_ANSWER_KEYS = ("names", "gap_before", "gap_after", "seconds", "score")


def _row_problem(row: Any) -> str | None:
    """What makes a cached scenario entry unusable (None if nothing)."""
    if not isinstance(row, dict):
        return f"a scenario entry is a {type(row).__name__}, not an object"
    missing = [k for k in _ROW_KEYS if k not in row]
    if missing:
        return f"a scenario entry lacks {', '.join(missing)}"
    if not isinstance(row["scenario"], str) or not isinstance(row["effects"], list):
        return f"scenario entry {row['scenario']!r}: 'scenario' or 'effects' of the wrong type"
    for method in ("msarm", "sindy"):
        answer = row[method]
        if not isinstance(answer, dict) or any(k not in answer for k in _ANSWER_KEYS):
            return (
                f"scenario {row['scenario']!r}: its {method} answer lacks one of "
                f"{', '.join(_ANSWER_KEYS)}"
            )
        if not isinstance(answer["names"], list) or not isinstance(answer["score"], dict):
            return f"scenario {row['scenario']!r}: its {method} names or score of the wrong type"
    if not isinstance(row["msarm"].get("confidence", []), list):
        return f"scenario {row['scenario']!r}: its msarm confidence is not a list"
    return None


def _cached_rows(
    path: Path, settings: dict[str, Any], model_sha256: str, code: str
) -> dict[str, Any]:
    """The scored scenarios of a previous ``results.json`` that can be reused, by name.

    Empty when the file was written with other settings, for another model (a file
    without ``model_sha256``, from before it was recorded, is taken as the same model's) or
    by other code (its ``code`` is not ``code``, the fingerprint in use; a file without one
    is from before it was recorded, and is scored again). An
    unreadable or malformed file is no cache: :class:`BenchCacheWarning` names it, and every
    scenario is scored again (from its cached logs).
    """
    import json

    def unusable(why: str) -> dict[str, Any]:
        warnings.warn(
            f"{path}: cached results unusable ({why}); scoring every scenario again from its "
            "cached logs, and writing the file anew",
            BenchCacheWarning,
            stacklevel=3,
        )
        return {}

    try:
        previous = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        return unusable(f"cannot read it: {exc.strerror or exc}")
    except UnicodeDecodeError:
        return unusable("not UTF-8 text")
    except ValueError as exc:  # json.JSONDecodeError: truncated or not JSON
        return unusable(f"not JSON: {exc}")
    if not isinstance(previous, dict):
        return unusable(f"a JSON {type(previous).__name__}, expected an object")
    scenarios = previous.get("scenarios", [])
    if not isinstance(scenarios, list):
        return unusable("'scenarios' is not a list")
    for row in scenarios:
        problem = _row_problem(row)
        if problem is not None:
            return unusable(problem)
    if previous.get("settings") != settings:
        old = previous.get("settings")
        differ = (
            sorted(k for k in {*old, *settings} if old.get(k) != settings.get(k))
            if isinstance(old, dict)
            else ["all"]
        )
        warnings.warn(
            f"{path}: holds the results of other settings ({', '.join(differ)} "
            f"{'differs' if len(differ) == 1 and differ != ['all'] else 'differ'}); this run's "
            "results replace them (a scenario's cached logs are reused where its plant and "
            "tasks are unchanged, simulated again otherwise)",
            BenchCacheWarning,
            stacklevel=3,
        )
        return {}
    if previous.get("model_sha256", model_sha256) != model_sha256:
        return {}  # scored against another version of the model
    if previous.get("code") != code:
        return {}  # scored by another version of msarm or of its libraries
    return {row["scenario"]: row for row in scenarios}


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The scores of both methods over scored scenarios (see the module docstring).

    Args:
        rows: The per-scenario entries of :func:`run_diagnosis_benchmark`.

    Returns:
        ``{method: {top1_accuracy, both_found, false_alarms, null_scenarios, mean_shrink,
        mean_excess_shrink, seconds_per_scenario, ...}}`` plus the noise floor used and the
        shrink ceiling: the raw shrink of a perfect diagnosis, which leaves only the noise
        floor (``1 - floor / before`` on the effect's groups, a group without a floor counted
        as noise-free; None without null scenarios), overall and by effect.
    """
    null = [r for r in rows if not r["effects"]]
    floor: dict[str, float] = {}
    if null:
        groups = set.intersection(*(set(r["msarm"]["gap_before"]) for r in null))
        floor = {g: float(np.mean([r["msarm"]["gap_before"][g] for r in null])) for g in groups}
    single = [r for r in rows if len(r["effects"]) == 1]
    pairs = [r for r in rows if len(r["effects"]) == 2]
    # a perfect diagnosis leaves the noise: its shrink is the ceiling of any method's
    ceiling_by_effect: dict[str, list[float]] = {}
    for r in single:
        before = r["msarm"]["gap_before"]
        perfect = {g: min(floor.get(g, 0.0), gap) for g, gap in before.items()}
        effect = r["effects"][0]
        ceiling_by_effect.setdefault(effect, []).append(
            _shrink(before, perfect, EFFECT_GROUPS[effect])
        )
    ceilings = [c for values in ceiling_by_effect.values() for c in values]
    out: dict[str, Any] = {
        "noise_floor": floor,
        "shrink_ceiling": float(np.nanmean(ceilings)) if ceilings and null else None,
        "shrink_ceiling_by_effect": (
            {e: float(np.nanmean(v)) for e, v in ceiling_by_effect.items()} if null else {}
        ),
    }
    for method in ("msarm", "sindy"):
        shrinks, excess = [], []
        shrink_by_effect: dict[str, list[float]] = {}
        for r in single:
            groups = EFFECT_GROUPS[r["effects"][0]]
            answer = r[method]
            shrinks.append(_shrink(answer["gap_before"], answer["gap_after"], groups))
            if null:  # no null plants, no noise floor: no excess shrink
                excess.append(
                    _excess_shrink(answer["gap_before"], answer["gap_after"], groups, floor)
                )
            shrink_by_effect.setdefault(r["effects"][0], []).append(shrinks[-1])
        extra = []
        for r in [*single, *pairs]:
            allowed = {c for e in r["effects"] for c in EFFECT_CANDIDATES[e]}
            extra.append(sum(n not in allowed for n in r[method]["names"]))
        per_effect: dict[str, list[bool]] = {}
        for r in single:
            per_effect.setdefault(r["effects"][0], []).append(r[method]["score"]["top1"])
        out[method] = {
            "single_scenarios": len(single),
            "top1_accuracy": (
                float(np.mean([r[method]["score"]["top1"] for r in single])) if single else None
            ),
            "top1_by_effect": {e: float(np.mean(v)) for e, v in per_effect.items()},
            "shrink_by_effect": {e: float(np.nanmean(v)) for e, v in shrink_by_effect.items()},
            "pair_scenarios": len(pairs),
            "both_found": (
                float(np.mean([r[method]["score"]["both"] for r in pairs])) if pairs else None
            ),
            "null_scenarios": len(null),
            "false_alarms": int(sum(r[method]["score"]["false_alarm"] for r in null)),
            "mean_shrink": float(np.nanmean(shrinks)) if shrinks else None,
            "mean_excess_shrink": (
                float(np.nanmean(excess)) if excess and np.isfinite(excess).any() else None
            ),
            "mean_extra_terms": float(np.mean(extra)) if extra else None,
            "seconds_per_scenario": (
                float(np.mean([r[method]["seconds"] for r in rows])) if rows else None
            ),
            "selection_seconds_per_scenario": _mean_seconds(rows, method, "selection_seconds"),
            "parameter_error_by_effect": summarise_parameter_errors(single, method),
        }
    return out


def _mean_seconds(rows: list[dict[str, Any]], method: str, key: str) -> float | None:
    """Mean of a timing over the scenarios that have it (older results may lack it)."""
    values = [r[method][key] for r in rows if key in r[method]]
    return float(np.mean(values)) if values else None


def plot_benchmark(report: dict[str, Any], path: str | Path) -> Path:
    """Confusion of each method: the plant's effect (rows) against the first term named.

    Single-effect scenarios give one row per effect class, null plants the row ``null``
    (two-effect scenarios are left out); columns are the candidates named first (``none``
    when nothing was named), ordered by :func:`confusion_columns` so that the right answers
    (the effect's own candidates, outlined) run down the diagonal. Cell numbers count
    scenarios.

    Args:
        report: The report of :func:`run_diagnosis_benchmark`.
        path: PNG file to write (atomically).

    Returns:
        The path written.
    """
    from msarm.plots import plt, save_figure

    rows = [r for r in report["scenarios"] if len(r["effects"]) <= 1]
    truths = sorted({r["effects"][0] if r["effects"] else "null" for r in rows}, key=_row_order)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), layout="constrained")
    for ax, method, title in zip(
        axes, ("msarm", "sindy"), ("msarm diagnosis", "PySINDy"), strict=True
    ):
        named = [r[method]["names"][0] if r[method]["names"] else "none" for r in rows]
        columns = confusion_columns(truths, named)
        counts = np.zeros((len(truths), len(columns)), dtype=int)
        for r, first in zip(rows, named, strict=True):
            truth = r["effects"][0] if r["effects"] else "null"
            counts[truths.index(truth), columns.index(first)] += 1
        ax.imshow(counts, cmap="Blues", aspect="auto")
        for i, truth in enumerate(truths):
            for j, column in enumerate(columns):
                if column in _right_answers(truth):
                    ax.add_patch(
                        plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, lw=2, ec="tab:green")
                    )
                if counts[i, j]:
                    colour = "white" if counts[i, j] > counts.max() / 2 else "black"
                    ax.text(j, i, str(counts[i, j]), ha="center", va="center", color=colour)
        ax.set_xticks(range(len(columns)), columns, rotation=35, ha="right")
        ax.set_yticks(range(len(truths)), truths)
        ax.set_xlabel("first term named")
        ax.set_ylabel("effect of the plant")
        summary = report["summary"][method]
        accuracy = summary["top1_accuracy"]
        ax.set_title(
            f"{title}: top-1 {'n/a' if accuracy is None else f'{accuracy:.0%}'}, "
            f"false alarms {summary['false_alarms']}/{summary['null_scenarios']}"
        )
    left_out = len(report["scenarios"]) - len(rows)
    fig.suptitle(
        "Withheld-effect benchmark: which term each method names first, on the "
        f"{len(rows)} single-effect and null scenarios"
        + (f" (two-effect scenarios left out: {left_out})" if left_out else "")
    )
    return save_figure(fig, path)


def _right_answers(truth: str) -> tuple[str, ...]:
    """The first terms that count as right in a row: its effect's candidates (null: ``none``)."""
    return ("none",) if truth == "null" else EFFECT_CANDIDATES.get(truth, ())


def confusion_columns(truths: list[str], named: list[str]) -> list[str]:
    """The confusion matrix's columns, so that the right answers form its diagonal.

    For each row in turn, its right answers (:func:`_right_answers`) that some scenario
    named first, or its first right answer when none did (an empty column: the row's misses
    then lie off the diagonal); then the other names named, alphabetically, ``none`` last.

    Args:
        truths: The rows, in display order.
        named: The first term named in each scenario (``none`` when nothing was).

    Returns:
        The columns, each once.
    """
    seen = set(named)
    columns: list[str] = []
    for truth in truths:
        right = _right_answers(truth)
        chosen = [c for c in right if c in seen] or list(right[:1])
        columns += [c for c in chosen if c not in columns]
    columns += sorted((n for n in seen if n not in columns), key=lambda n: (n == "none", n))
    return columns


def _row_order(name: str) -> tuple[int, str]:
    order = list(EFFECT_CANDIDATES)
    return (order.index(name), name) if name in order else (len(order), name)
