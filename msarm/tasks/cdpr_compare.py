"""The test grid of paper 000 section 4 on the simulated IPAnema 3 Mini (Tables 3-5).

Test ``ij`` runs controller ``i`` along trajectory ``j`` (Table 3; cables numbered from 1 in the
paper, from 0 in msarm):

====  ==========  ====  =====================================
``i``  controller  ``j``  trajectory (force-controlled cables)
====  ==========  ====  =====================================
1     IKC         1     triangle (1, 2) -- ``triangle-12``
2     HC-e        2     circle (1, 2) -- ``circle-12``
3     HC-f        3     triangle (3, 4) -- ``triangle-34``
4     NC          4     circle (3, 4) -- ``circle-34``
5     HC-e, all   5     rectangle, pair switched at y = 0
====  ==========  ====  =====================================

Test 51 is HC-e on all cables along the triangle. Two more runs compare HC-tau with and
without its friction model (paper 000 Fig. 10, last column). Repeatability (Table 5): tests
11, 21, 31 and 41 repeated with different sensor-noise seeds; ``rho(t)`` is the standard
deviation over the repetitions of the marker position error at each instant, reported as its
maximum and mean.

The first :data:`START_UP_TIME` (0.5 s, the trajectories' initial hold at rest) holds a start-up
transient: HC-e's position-controlled cables lose the following error the reset gave them
within about 30 ms (see the README). Table 4's largest error covers the whole run; the JSON
also gives each test's largest error after the start-up, and the switching comparison
(:func:`switching_statistics`, ``switching_delta.png``) reports its largest error and smallest
force after the start-up, where the switches of the force-controlled pair are.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import Normalize

from msarm import plots
from msarm.cdpr.robot_model import CableRobotModel
from msarm.io.atomic import write_json_atomic
from msarm.io.config import config_to_dict, write_config
from msarm.plant.cdpr_config import CdprPlantConfig
from msarm.tasks.cdpr_run_cache import CdprRunCache
from msarm.tasks.cdpr_runner import CdprMetrics, CdprRun, run_cdpr
from msarm.tasks.cdpr_trajectories import HOLD_TIME, get_cdpr_trajectory

__all__ = [
    "CONTROLLERS",
    "SIGMA_CLIP",
    "START_UP_TIME",
    "TRAJECTORIES",
    "CdprComparison",
    "compare_cdpr",
    "forces_title",
    "plot_forces",
    "progress_steps",
    "sigma_colour_scale",
    "switch_intervals",
    "switching_statistics",
]

#: Table 3: controller digit -> msarm controller name.
CONTROLLERS = {1: "ikc", 2: "hc-e", 3: "hc-f", 4: "nc"}
#: Table 3: trajectory digit -> msarm trajectory name.
TRAJECTORIES = {
    1: "triangle-12",
    2: "circle-12",
    3: "triangle-34",
    4: "circle-34",
    5: "rectangle-switch",
}
#: Switching steps of eq. 10 compared on the rectangle (paper 000 Fig. 13).
SWITCHING_DELTAS = (0.0005, 0.02, 0.5)
#: The controllers' default switching step.
DEFAULT_SWITCHING_DELTA = 0.02
#: Height of the trajectories and of the sensitivity map [m].
MAP_HEIGHT = 0.115
#: Start-up window [s] left out of the "after start-up" statistics: the trajectories' initial
#: hold at rest (0.5 s), whose first tens of ms hold HC-e's start-up transient.
START_UP_TIME = HOLD_TIME
#: Time after a switch's end still counted in its statistics [s] (its transient is over by then).
SWITCH_SETTLE_TIME = 0.1
#: The sensitivity map's colour scale ends here [N] (larger values are drawn in its top colour).
SIGMA_CLIP = 4.0
#: Tests repeated for Table 5.
REPEATABILITY_TESTS = ("11", "21", "31", "41")
#: Tests whose cable forces are plotted (with the switching runs of test 25).
PLOTTED_TESTS = ("11", "21", "31", "41", "51", "25", "hc-tau-no-friction/1")


@dataclass(frozen=True)
class CdprComparison:
    """Results of the grid.

    Attributes:
        tests: Test id -> (controller, trajectory, metrics) (Table 4 and the extra runs).
        repeatability: Test id -> (rho_max, rho_mean) [mm] (Table 5).
        repeats: Runs per repeatability test.
        files: Plots, JSON and config written.
        plant: The plant the grid ran on (None if not recorded).
        after_start_up: Test id -> largest position error [mm] after :data:`START_UP_TIME`
            (Table 4's ``max_position_error_mm`` is over the whole run).
        switching: Switching step delta -> :func:`switching_statistics` of its run on the
            rectangle (paper 000 Fig. 13).
    """

    tests: dict[str, tuple[str, str, CdprMetrics]]
    repeatability: dict[str, tuple[float, float]]
    repeats: int
    files: dict[str, Path]
    plant: CdprPlantConfig | None = None
    after_start_up: dict[str, float | None] = field(default_factory=dict)
    switching: dict[float, dict] = field(default_factory=dict)

    def as_dict(self) -> dict:
        """JSON-ready form (the plant as its resolved config)."""
        return {
            "plant": None if self.plant is None else config_to_dict(self.plant),
            "start_up_time_s": START_UP_TIME,
            "tests": {
                test: {
                    "controller": c,
                    "trajectory": t,
                    **m.as_dict(),
                    "max_position_error_after_start_up_mm": self.after_start_up.get(test),
                }
                for test, (c, t, m) in self.tests.items()
            },
            "switching": {f"{delta:g}": stats for delta, stats in self.switching.items()},
            "repeatability_mm": {
                test: {"rho_max": a, "rho_mean": b} for test, (a, b) in self.repeatability.items()
            },
            "repeats": self.repeats,
            "files": {kind: str(path) for kind, path in self.files.items()},
        }


def _grid() -> list[tuple[str, str, str, dict]]:
    runs = [
        (f"{i}{j}", controller, trajectory, {})
        for i, controller in CONTROLLERS.items()
        for j, trajectory in TRAJECTORIES.items()
    ]
    runs.append(("51", "hc-e-all", TRAJECTORIES[1], {}))
    runs.append(("hc-tau/1", "hc-tau", TRAJECTORIES[1], {}))
    runs.append(("hc-tau-no-friction/1", "hc-tau", TRAJECTORIES[1], {"friction_model": False}))
    for delta in SWITCHING_DELTAS:
        if delta != DEFAULT_SWITCHING_DELTA:
            runs.append((f"25/delta={delta:g}", "hc-e", TRAJECTORIES[5], {"delta": delta}))
    return runs


def progress_steps(repeats: int, tests: list[str] | None = None) -> int:
    """How many times :func:`compare_cdpr` calls its ``progress``: once per run it simulates.

    That is each test of the grid (or of ``tests``), then ``repeats - 1`` runs per
    repeatability test among them when ``repeats >= 2`` (the first of its repeats is its grid
    run, reused: no step).
    """
    ids = [g[0] for g in _grid() if tests is None or g[0] in tests]
    repeated = sum(test in ids for test in REPEATABILITY_TESTS)
    return len(ids) + (repeated * (repeats - 1) if repeats >= 2 else 0)


def compare_cdpr(
    model: CableRobotModel,
    plant_config: CdprPlantConfig,
    out_dir: Path,
    repeats: int = 15,
    tests: list[str] | None = None,
    progress: Callable[[str], None] | None = None,
    resume: bool = True,
) -> CdprComparison:
    """Run the grid (or the ``tests`` named) and the repeatability runs; write plots, JSON.

    Args:
        model: The cable robot.
        plant_config: The plant.
        out_dir: Folder for the plots, ``cdpr_comparison.json`` (results and plant),
            ``config.yaml`` (the resolved plant, repeats and tests) and ``runs/``, the
            finished runs (:class:`~msarm.tasks.cdpr_run_cache.CdprRunCache`).
        repeats: Runs per repeatability test (paper 000: 15); 0 skips Table 5.
        tests: Test ids to run (default: all of :func:`_grid`).
        progress: Called with a label before each run (:func:`progress_steps` times; not for
            the first repeat of a test, its grid run); the label ends in ``(cached)`` for a
            run taken from ``runs/``.
        resume: Take the runs already in ``out_dir/runs`` with the same key instead of
            simulating them again (an interrupted comparison goes on where it stopped).

    Returns:
        The comparison.
    """
    out_dir = Path(out_dir)
    grid = [g for g in _grid() if tests is None or g[0] in tests]
    results: dict[str, tuple[str, str, CdprMetrics]] = {}
    runs: dict[str, CdprRun] = {}
    cache = CdprRunCache(out_dir / "runs", model, plant_config)

    def run_or_reuse(
        name: str, controller: str, trajectory_name: str, seed: int, options: dict, label: str
    ) -> CdprRun:
        kept = cache.load(name, controller, trajectory_name, seed, options) if resume else None
        if progress is not None:
            progress(label + (" (cached)" if kept is not None else ""))
        if kept is not None:
            return kept
        trajectory = get_cdpr_trajectory(trajectory_name)
        run = run_cdpr(model, plant_config, controller, trajectory, seed, options)
        if seed == 0 and (name in PLOTTED_TESTS or name.startswith("25/")):
            cache.save(name, run, seed, options)  # what its plots read
        else:
            cache.save(name, run, seed, options, quantities=("marker",), truth=False)
        return run

    for test, controller, trajectory_name, options in grid:
        label = f"test {test}: {controller}, {trajectory_name}"
        run = run_or_reuse(test, controller, trajectory_name, 0, options, label)
        results[test] = (controller, trajectory_name, run.metrics)
        runs[test] = run
    repeatability: dict[str, tuple[float, float]] = {}
    for test in REPEATABILITY_TESTS:
        if repeats < 2 or test not in results:
            continue
        controller, trajectory_name, _ = results[test]
        trajectory = get_cdpr_trajectory(trajectory_name)
        errors = []
        for seed in range(repeats):
            if seed == 0:  # the grid run (seed 0), reused: not a step of its own
                run = runs[test]
            else:
                label = f"repeatability {test}: run {seed + 1}/{repeats}"
                run = run_or_reuse(test, controller, trajectory_name, seed, {}, label)
            marker = np.stack([run.columns[f"marker.{a}"] for a in "xyz"], axis=1)
            errors.append(np.linalg.norm(marker - trajectory.position[: len(marker)], axis=1))
        length = min(len(e) for e in errors)
        rho = np.std(np.stack([e[:length] for e in errors]), axis=0)
        repeatability[test] = (1000.0 * float(rho.max()), 1000.0 * float(rho.mean()))
    after_start_up = {
        test: _largest_error_mm(run, after=START_UP_TIME) for test, run in runs.items()
    }
    files: dict[str, Path] = {}
    options_of = {g[0]: g[3] for g in grid}
    # the results go last and the old ones first: a folder with cdpr_comparison.json holds
    # one whole comparison, not new plots beside an old run's results (a review's kill
    # during the plots left such a mix)
    (out_dir / "cdpr_comparison.json").unlink(missing_ok=True)
    for test in PLOTTED_TESTS:
        if test in runs:
            safe = test.replace("/", "_")
            files[f"forces_{safe}"] = plot_forces(
                runs[test],
                model,
                out_dir / f"forces_test_{safe}.png",
                f"test {test}",
                plant_config.name,
                0,
                options_of[test],
            )
    switching = {
        delta: runs[test]
        for delta, test in (
            (d, "25" if d == DEFAULT_SWITCHING_DELTA else f"25/delta={d:g}")
            for d in SWITCHING_DELTAS
        )
        if test in runs
    }
    switching_stats = {delta: switching_statistics(run) for delta, run in switching.items()}
    if len(switching) > 1:
        files["switching"] = plot_switching(switching, out_dir / "switching_delta.png")
    if tests is None:
        files["sensitivity"] = plot_sensitivity(model, out_dir / "sensitivity_map.png")
    files["config"] = write_config(
        {
            "repeats": repeats,
            "tests": [g[0] for g in grid],
            "plant": config_to_dict(plant_config),
        },
        out_dir / "config.yaml",
    )
    comparison = CdprComparison(
        results, repeatability, repeats, files, plant_config, after_start_up, switching_stats
    )
    files["json"] = write_json_atomic(out_dir / "cdpr_comparison.json", comparison.as_dict())
    return comparison


def forces_title(
    run: CdprRun,
    title: str = "",
    plant: str | None = None,
    seed: int | None = None,
    options: dict | None = None,
) -> str:
    """The title of :func:`plot_forces`.

    ``[<title>: ]<controller> on <trajectory>[, <plant> plant][, seed <seed>][, <options>]
    (...)``: the run's plant, noise seed and controller options (``KEY=VALUE``, as on the
    command line; ``no options`` when there are none) where given.
    """
    prefix = f"{title}: " if title else ""
    parts = [f"{run.controller} on {run.trajectory}"]
    if plant is not None:
        parts.append(f"{plant} plant")
    if seed is not None:
        parts.append(f"seed {seed}")
    if options is not None:
        parts.append(" ".join(f"{k}={_option_text(v)}" for k, v in options.items()) or "no options")
    return f"{prefix}{', '.join(parts)} (bounds dotted, force control shaded)"


def _option_text(value: object) -> str:
    """An option's value as written on the command line (YAML): ``true``, not ``True``."""
    if value is None:
        return "null"
    return str(value).lower() if isinstance(value, bool) else str(value)


def plot_forces(
    run: CdprRun,
    model: CableRobotModel,
    path: Path,
    title: str = "",
    plant: str | None = None,
    seed: int | None = None,
    options: dict | None = None,
) -> Path:
    """Cable forces over time (as paper 000 Fig. 10, 11 and 13), bounds drawn.

    One plot per cable, four to a row; the shared force axis runs from 0 N (or the lowest
    force) to above the largest force and bound, so no peak is cut off.

    Solid: the platform-side forces the simulation computes (its ground truth, not a sensor
    reading); dashed: the force distribution's desired forces; shaded: while the cable is
    force controlled.

    Args:
        run: The run.
        model: The cable robot (names and force bounds).
        path: The PNG file to write.
        title: What the figure is (e.g. ``"test 21"``), put before the controller and the
            trajectory, which the title always names.
        plant: The plant's name (in the title when given: :func:`forces_title`).
        seed: The sensor-noise seed (in the title when given).
        options: The controller's keyword options (in the title when given).

    Returns:
        The path written.
    """
    t = run.columns["t"]
    m = model.n_cables
    cols = min(4, m)
    rows = -(-m // cols)
    fig, grid = plt.subplots(
        rows,
        cols,
        figsize=(15, 3 * rows),
        sharex=True,
        sharey=True,
        squeeze=False,
        layout="constrained",
    )
    axes = grid.flat[:m]
    for ax in grid.flat[m:]:  # the last row's empty places
        ax.remove()
    for i, (ax, name) in enumerate(zip(axes, model.cable_names, strict=True)):
        ax.plot(t, run.truth[f"tension.{name}"], lw=1.0, label="true force (simulation)")
        ax.plot(t, run.columns[f"f_desired.{name}"], "k--", lw=0.8, label="desired")
        ax.axhline(float(model.f_min[i]), color="tab:red", ls=":", lw=0.8)
        ax.axhline(float(model.f_max[i]), color="tab:red", ls=":", lw=0.8)
        controlled = run.columns[f"h.{name}"] > 0.5
        if controlled.any():
            ax.fill_between(
                t,
                0,
                1,
                where=controlled,
                color="tab:green",
                alpha=0.1,
                transform=ax.get_xaxis_transform(),
            )
        ax.set_title(f"{name} (paper: cable {i + 1})", fontsize=9)
        if i + cols >= m:  # no plot below it: its time axis is the column's
            ax.xaxis.set_tick_params(labelbottom=True)
            ax.set_xlabel("time [s]")
    # From 0 N (or the lowest force) to above the largest force and bound: no peak is cut.
    drawn = [run.truth[f"tension.{n}"] for n in model.cable_names]
    drawn += [run.columns[f"f_desired.{n}"] for n in model.cable_names]
    values = np.concatenate([np.ravel(v) for v in drawn] + [model.f_min, model.f_max])
    values = values[np.isfinite(values)]
    low, high = min(0.0, float(values.min())), float(values.max())
    axes[0].set_ylim(low, high + 0.1 * (high - low))
    axes[0].legend(fontsize=7)
    for ax in grid[:, 0]:
        ax.set_ylabel("N")
    fig.suptitle(forces_title(run, title, plant, seed, options))
    return plots.save_figure(fig, path)


def _path_error_mm(run: CdprRun) -> np.ndarray:
    """The marker's distance to the trajectory at each sample [mm] (Table 4's error)."""
    marker = np.stack([run.columns[f"marker.{a}"] for a in "xyz"], axis=1)
    reference = get_cdpr_trajectory(run.trajectory).position[: len(marker)]
    return 1000.0 * np.linalg.norm(marker - reference, axis=1)


def _largest_error_mm(run: CdprRun, after: float = 0.0) -> float | None:
    """The largest path error [mm] from ``after`` [s] on (None: no sample that late)."""
    error = _path_error_mm(run)[run.columns["t"] >= after]
    return float(error.max()) if error.size else None


def switch_intervals(run: CdprRun) -> list[tuple[float, float]]:
    """The times [s] some cable's force-control share ``h`` (eq. 10) changes, as intervals.

    Each interval runs from the last sample before a stretch of samples with some ``h``
    strictly in (0, 1) to the first sample after it, where ``h`` is at its end value (the
    run's first or last sample where the stretch starts or ends the run): so an eq. 10 switch
    of ``N`` cycles is ``N`` control periods long (before 2026-11-29 the stretch's own first
    and last samples were given, two periods short, and half of a 4-cycle switch). The
    intervals are the controller's activation (the one from ``t = 0``, ``h`` rising from 0
    on the first pair) and each switch of the force-controlled pair.
    """
    t = run.columns["t"]
    shares = [v for k, v in run.columns.items() if k.startswith("h.")]
    if not shares:
        return []
    h = np.stack(shares, axis=1)
    moving = np.any((h > 0.0) & (h < 1.0), axis=1).astype(np.int8)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], moving, [0]])))
    last = len(t) - 1
    return [
        (round(float(t[max(a - 1, 0)]), 6), round(float(t[min(b, last)]), 6))
        for a, b in zip(edges[::2], edges[1::2], strict=True)
    ]


def _extremes(t: np.ndarray, error: np.ndarray, forces: np.ndarray, names, keep) -> dict:
    """Largest error and smallest force over the samples ``keep``, with time and cable."""
    if not keep.any():
        return {}
    index = np.flatnonzero(keep)
    worst = index[int(np.argmax(error[keep]))]
    sample, cable = np.unravel_index(int(np.argmin(forces[keep])), forces[keep].shape)
    return {
        "max_position_error_mm": float(error[worst]),
        "max_position_error_time_s": round(float(t[worst]), 6),
        "min_force_N": float(forces[index[sample], cable]),
        "min_force_time_s": round(float(t[index[sample]]), 6),
        "min_force_cable": names[cable],
    }


def switching_statistics(
    run: CdprRun, start_up: float = START_UP_TIME, settle: float = SWITCH_SETTLE_TIME
) -> dict:
    """Largest position error and smallest cable force of a switching run (Fig. 13).

    Args:
        run: A run with the true cable forces (``run.truth``) and the shares ``h.*``.
        start_up: The start-up window left out of ``after_start_up`` [s].
        settle: Time after a switch's end still counted in that switch's statistics [s].

    Returns:
        ``start_up_time_s``; ``whole_run`` and ``after_start_up`` (from ``start_up`` on): each
        ``max_position_error_mm`` and ``min_force_N`` (over all cables) with the time of each
        and the cable; ``activation_s``, the controller's activation from ``t = 0``
        (``[first, last]``, or None); ``switches``: each later interval of
        :func:`switch_intervals` (``start_s``, ``end_s``) with the same extremes from its
        start to ``settle`` after its end.
    """
    t = run.columns["t"]
    error = _path_error_mm(run)
    names = _cable_names(run)
    forces = np.stack([run.truth[f"tension.{n}"] for n in names], axis=1)[: len(t)]
    intervals = switch_intervals(run)
    activation = intervals[0] if intervals and intervals[0][0] <= t[0] else None
    switches = [
        {
            "start_s": a,
            "end_s": b,
            **_extremes(t, error, forces, names, (t >= a) & (t <= b + settle)),
        }
        for a, b in intervals
        if (a, b) != activation
    ]
    return {
        "start_up_time_s": start_up,
        "whole_run": _extremes(t, error, forces, names, np.ones(len(t), dtype=bool)),
        "after_start_up": _extremes(t, error, forces, names, t >= start_up),
        "activation_s": None if activation is None else list(activation),
        "switches": switches,
    }


def _cable_names(run: CdprRun) -> list[str]:
    """The cables of the run's true forces, in order (``cable_10`` after ``cable_9``)."""

    def order(name: str) -> tuple[int, str]:
        head, _, number = name.rpartition("_")
        return (int(number), head) if number.isdigit() else (-1, name)

    return sorted(
        (k.removeprefix("tension.") for k in run.truth if k.startswith("tension.")), key=order
    )


def plot_switching(runs: dict[float, CdprRun], path: Path) -> Path:
    """Forces and the position error on the rectangle for each delta (Fig. 13).

    Per delta: all cables' true forces (the switchable cables 1-4, paper numbering, in colour,
    5-8 in grey), the 5 N bound and the position error; shaded as in the paper while pair
    (1, 2) (blue) or (3, 4) (yellow) is force controlled, hatched grey the start-up
    (:data:`START_UP_TIME`), dashed lines where each switch starts and ends. The largest
    error and the smallest force after the start-up are circled and written, with the whole
    run's; the error axes share one scale, set by the parts after the start-up (a start-up
    peak above it is named, off scale).
    """
    fig, axes = plt.subplots(
        2,
        len(runs),
        figsize=(5.5 * len(runs), 7),
        sharex=True,
        sharey="row",
        squeeze=False,
        layout="constrained",
    )
    statistics = {delta: switching_statistics(run) for delta, run in runs.items()}
    # one error scale, set by the part after the start-up (not by a start-up peak)
    top = 1.3 * max(
        (
            s["after_start_up"]["max_position_error_mm"]
            for s in statistics.values()
            if s["after_start_up"]
        ),
        default=1.0,
    )
    for column, (delta, run) in enumerate(sorted(runs.items())):
        t = run.columns["t"]
        stats = statistics[delta]
        after, whole = stats["after_start_up"], stats["whole_run"]
        force_ax, error_ax = axes[0, column], axes[1, column]
        names = _cable_names(run)
        for i, name in enumerate(names):
            switchable = i < 4
            force_ax.plot(
                t,
                run.truth[f"tension.{name}"][: len(t)],
                lw=0.9 if switchable else 0.6,
                color=f"C{i}" if switchable else "0.6",
                label=f"{name} (paper {i + 1})" if switchable else None,
                zorder=3 if switchable else 2,
            )
        force_ax.plot([], [], lw=0.6, color="0.6", label="cables 5-8 (paper), never switched")
        force_ax.axhline(5.0, color="tab:red", ls=":", lw=0.8, label="5 N bound")
        error = _path_error_mm(run)
        error_ax.plot(t, error, lw=0.9, color="C0", zorder=3)
        for ax in (force_ax, error_ax):
            for name, colour, label in (
                ("cable_0", "tab:blue", "pair 1,2 force controlled"),
                ("cable_2", "gold", "pair 3,4 force controlled"),
            ):
                share = run.columns.get(f"h.{name}")
                if share is not None:
                    ax.fill_between(
                        t,
                        0,
                        1,
                        where=share > 0.5,
                        color=colour,
                        alpha=0.12,
                        lw=0,
                        transform=ax.get_xaxis_transform(),
                        label=label,
                    )
            ax.axvspan(
                t[0],
                START_UP_TIME,
                facecolor="0.85",
                edgecolor="0.5",
                hatch="//",
                lw=0,
                zorder=1,
                label=f"start-up (first {START_UP_TIME:g} s), left out",
            )
            for k, switch in enumerate(stats["switches"]):
                ends = {switch["start_s"], switch["end_s"]}
                for moment in sorted(ends):
                    ax.axvline(
                        moment,
                        color="k",
                        ls="--",
                        lw=0.7,
                        label="switch starts / ends" if k == 0 and moment == min(ends) else None,
                    )
        if after:
            for ax, at, value, label in (
                (force_ax, "min_force_time_s", "min_force_N", "extreme after start-up"),
                (error_ax, "max_position_error_time_s", "max_position_error_mm", None),
            ):
                ax.plot(after[at], after[value], "ko", ms=8, mfc="none", zorder=4, label=label)
            error_ax.set_ylim(0.0, top)
            if whole["max_position_error_mm"] > top:
                error_ax.annotate(
                    f"start-up peak {whole['max_position_error_mm']:.2f} mm at "
                    f"{whole['max_position_error_time_s']:.3f} s (off scale)",
                    (START_UP_TIME, 1.0),
                    xycoords=("data", "axes fraction"),
                    xytext=(3, -3),
                    textcoords="offset points",
                    ha="left",
                    va="top",
                    fontsize=7,
                )
            error_ax.set_title(_switching_summary(stats), fontsize=7)
        force_ax.set_ylim(bottom=0.0)
        force_ax.set_title(
            f"delta = {delta:g}\na switch (and the activation at t = 0) takes "
            f"{int(np.ceil(np.pi / 2 / delta))} ms",
            fontsize=10,
        )
        error_ax.set_xlabel("time [s]")
    axes[0, 0].set_ylabel("true cable force [N]")
    axes[1, 0].set_ylabel("position error [mm]")
    axes[0, 0].legend(fontsize=6, loc="lower right", ncols=2)
    fig.suptitle(
        "switching the force-controlled pair on the rectangle (HC-e, paper 000 Fig. 13); "
        f"largest error and smallest force (all 8 cables) after the {START_UP_TIME:g} s "
        "start-up circled"
    )
    return plots.save_figure(fig, path)


def _switching_summary(stats: dict) -> str:
    """The text box of a :func:`plot_switching` column."""
    after, whole = stats["after_start_up"], stats["whole_run"]

    def line(label: str, s: dict) -> str:
        return (
            f"{label}: max error {s['max_position_error_mm']:.2f} mm "
            f"({s['max_position_error_time_s']:.3f} s), min force {s['min_force_N']:.2f} N "
            f"({s['min_force_cable']}, {s['min_force_time_s']:.3f} s)"
        )

    return "\n".join(
        (line(f"after {stats['start_up_time_s']:g} s", after), line("whole run", whole))
    )


def sigma_colour_scale(maps: list[np.ndarray]) -> tuple[Normalize, str, str]:
    """The one colour scale of the sensitivity maps: norm, colour bar ``extend`` and label.

    From 0 to :data:`SIGMA_CLIP` [N]; when a map goes above it (drawn in the top colour) the
    colour bar is extended (``"max"``) and its label says it is clipped.
    """
    largest = max((float(np.nanmax(m)) for m in maps if np.isfinite(m).any()), default=0.0)
    if largest > SIGMA_CLIP:
        return (
            Normalize(0.0, SIGMA_CLIP),
            "max",
            f"sigma [N], clipped at {SIGMA_CLIP:g} N (white: 1.5 N)",
        )
    return Normalize(0.0, SIGMA_CLIP), "neither", "sigma [N] (white: 1.5 N)"


def plot_sensitivity(model: CableRobotModel, path: Path, points: int = 41) -> Path:
    """The sensitivity index over the workspace for pairs (1, 2) and (3, 4) (paper 000 Fig. 7).

    Horizontal slice at the trajectories' height, R = I, the platform's weight; blank where
    the statics are infeasible; the 1.5 N contour drawn and the Fig. 9 paths overlaid. Both
    panels share one colour scale and colour bar (:func:`sigma_colour_scale`).
    """
    from msarm.cdpr.sensitivity import sensitivity_map

    lower, upper = np.asarray(model.workspace_lower), np.asarray(model.workspace_upper)
    x = np.linspace(lower[0], upper[0], points)
    y = np.linspace(lower[1], upper[1], points)
    weight = np.concatenate([model.mass * np.asarray(model.gravity, dtype=float), np.zeros(3)])
    pairs = ((0, 1), (2, 3))
    maps = []
    for pair in pairs:
        result = sensitivity_map(
            model.robot,
            pair,
            x,
            y,
            [MAP_HEIGHT],
            wrench=weight,
            f_min=model.f_min,
            f_max=model.f_max,
        )
        maps.append(np.where(result.feasible, result.sigma, np.nan)[:, :, 0].T)
    norm, extend, label = sigma_colour_scale(maps)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), layout="constrained")
    for ax, pair, sigma in zip(axes, pairs, maps, strict=True):
        mesh = ax.pcolormesh(x, y, sigma, shading="auto", cmap="viridis", norm=norm)
        ax.contour(x, y, sigma, levels=[1.5], colors="w", linewidths=1.2)
        for name in TRAJECTORIES.values():
            path_xy = get_cdpr_trajectory(name).position
            ax.plot(path_xy[:, 0], path_xy[:, 1], lw=0.8, color="tab:red")
        ax.set_title(f"force-controlled cables {pair[0] + 1},{pair[1] + 1} (msarm {pair})")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal")
    fig.colorbar(mesh, ax=axes, label=label, extend=extend, shrink=0.85)
    fig.suptitle(f"sensitivity index at z = {MAP_HEIGHT} m, R = I (paper 000 Fig. 7)")
    return plots.save_figure(fig, path)
