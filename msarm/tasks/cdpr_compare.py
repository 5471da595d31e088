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
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from msarm import plots
from msarm.cdpr.robot_model import CableRobotModel
from msarm.io.atomic import write_json_atomic
from msarm.io.config import config_to_dict, write_config
from msarm.plant.cdpr_config import CdprPlantConfig
from msarm.tasks.cdpr_run_cache import CdprRunCache
from msarm.tasks.cdpr_runner import CdprMetrics, CdprRun, run_cdpr
from msarm.tasks.cdpr_trajectories import get_cdpr_trajectory

__all__ = [
    "CONTROLLERS",
    "TRAJECTORIES",
    "CdprComparison",
    "compare_cdpr",
    "plot_forces",
    "progress_steps",
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
    """

    tests: dict[str, tuple[str, str, CdprMetrics]]
    repeatability: dict[str, tuple[float, float]]
    repeats: int
    files: dict[str, Path]
    plant: CdprPlantConfig | None = None

    def as_dict(self) -> dict:
        """JSON-ready form (the plant as its resolved config)."""
        return {
            "plant": None if self.plant is None else config_to_dict(self.plant),
            "tests": {
                test: {"controller": c, "trajectory": t, **m.as_dict()}
                for test, (c, t, m) in self.tests.items()
            },
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
    files: dict[str, Path] = {}
    for test in PLOTTED_TESTS:
        if test in runs:
            safe = test.replace("/", "_")
            files[f"forces_{safe}"] = plot_forces(
                runs[test], model, out_dir / f"forces_test_{safe}.png", title=f"test {test}"
            )
    switching = {
        delta: runs[test]
        for delta, test in (
            (d, "25" if d == DEFAULT_SWITCHING_DELTA else f"25/delta={d:g}")
            for d in SWITCHING_DELTAS
        )
        if test in runs
    }
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
    comparison = CdprComparison(results, repeatability, repeats, files, plant_config)
    files["json"] = write_json_atomic(out_dir / "cdpr_comparison.json", comparison.as_dict())
    return comparison


def forces_title(run: CdprRun, title: str = "") -> str:
    """The title of :func:`plot_forces`: ``[<title>: ]<controller> on <trajectory> (...)``."""
    prefix = f"{title}: " if title else ""
    return f"{prefix}{run.controller} on {run.trajectory} (bounds dotted, force control shaded)"


def plot_forces(run: CdprRun, model: CableRobotModel, path: Path, title: str = "") -> Path:
    """Cable forces over time (as paper 000 Fig. 10, 11 and 13), bounds drawn.

    Solid: platform-side forces; dashed: the force distribution's desired forces; shaded:
    while the cable is force controlled.

    Args:
        run: The run.
        model: The cable robot (names and force bounds).
        path: The PNG file to write.
        title: What the figure is (e.g. ``"test 21"``), put before the controller and the
            trajectory, which the title always names.

    Returns:
        The path written.
    """
    t = run.columns["t"]
    fig, axes = plt.subplots(2, 4, figsize=(15, 6), sharex=True, sharey=True, layout="constrained")
    for i, (ax, name) in enumerate(zip(axes.flat, model.cable_names, strict=True)):
        ax.plot(t, run.truth[f"tension.{name}"], lw=1.0, label="force")
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
        ax.set_ylim(0, 40)
    axes[0, 0].legend(fontsize=7)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("N")
    fig.suptitle(forces_title(run, title))
    return plots.save_figure(fig, path)


def plot_switching(runs: dict[float, CdprRun], path: Path) -> Path:
    """Forces of cables 1-4 and the position error on the rectangle for each delta (Fig. 13)."""
    fig, axes = plt.subplots(
        2, len(runs), figsize=(5 * len(runs), 6), sharex=True, squeeze=False, layout="constrained"
    )
    for column, (delta, run) in enumerate(sorted(runs.items())):
        t = run.columns["t"]
        for i in range(4):
            name = f"cable_{i}"
            axes[0, column].plot(
                t, run.truth[f"tension.{name}"], lw=0.9, label=f"{name} (paper {i + 1})"
            )
        axes[0, column].axhline(5.0, color="tab:red", ls=":", lw=0.8)
        axes[0, column].set_title(f"delta = {delta:g} ({int(np.ceil(np.pi / 2 / delta))} ms)")
        marker = np.stack([run.columns[f"marker.{a}"] for a in "xyz"], axis=1)
        reference = np.stack([run.columns[f"r_ref.{a}"] for a in "xyz"], axis=1)
        axes[1, column].plot(t, 1000 * np.linalg.norm(marker - reference, axis=1), lw=0.9)
        axes[1, column].set_xlabel("time [s]")
    axes[0, 0].set_ylabel("cable force [N]")
    axes[1, 0].set_ylabel("position error [mm]")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("switching the force-controlled pair on the rectangle (HC-e, paper 000 Fig. 13)")
    return plots.save_figure(fig, path)


def plot_sensitivity(model: CableRobotModel, path: Path, points: int = 41) -> Path:
    """The sensitivity index over the workspace for pairs (1, 2) and (3, 4) (paper 000 Fig. 7).

    Horizontal slice at the trajectories' height, R = I, the platform's weight; hatched where
    the statics are infeasible; the 1.5 N contour drawn and the Fig. 9 paths overlaid.
    """
    from msarm.cdpr.sensitivity import sensitivity_map

    lower, upper = np.asarray(model.workspace_lower), np.asarray(model.workspace_upper)
    x = np.linspace(lower[0], upper[0], points)
    y = np.linspace(lower[1], upper[1], points)
    weight = np.concatenate([model.mass * np.asarray(model.gravity, dtype=float), np.zeros(3)])
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), layout="constrained")
    for ax, pair in zip(axes, ((0, 1), (2, 3)), strict=True):
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
        sigma = np.where(result.feasible, result.sigma, np.nan)[:, :, 0].T
        mesh = ax.pcolormesh(x, y, np.clip(sigma, 0, 4), shading="auto", cmap="viridis")
        ax.contour(x, y, sigma, levels=[1.5], colors="w", linewidths=1.2)
        for name in TRAJECTORIES.values():
            path_xy = get_cdpr_trajectory(name).position
            ax.plot(path_xy[:, 0], path_xy[:, 1], lw=0.8, color="tab:red")
        ax.set_title(f"force-controlled cables {pair[0] + 1},{pair[1] + 1} (msarm {pair})")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal")
        fig.colorbar(mesh, ax=ax, label="sigma [N] (white: 1.5 N)")
    fig.suptitle(f"sensitivity index at z = {MAP_HEIGHT} m, R = I (paper 000 Fig. 7)")
    return plots.save_figure(fig, path)
