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
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msarm import plots  # noqa: E402
from msarm.cdpr.robot_model import CableRobotModel  # noqa: E402
from msarm.plant.cdpr_config import CdprPlantConfig  # noqa: E402
from msarm.tasks.cdpr_runner import CdprMetrics, CdprRun, run_cdpr  # noqa: E402
from msarm.tasks.cdpr_trajectories import get_cdpr_trajectory  # noqa: E402
from msarm.tasks.track import write_json_atomic  # noqa: E402

__all__ = ["CONTROLLERS", "TRAJECTORIES", "CdprComparison", "compare_cdpr", "plot_forces"]

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
#: Tests repeated for Table 5.
REPEATABILITY_TESTS = ("11", "21", "31", "41")


@dataclass(frozen=True)
class CdprComparison:
    """Results of the grid.

    Attributes:
        tests: Test id -> (controller, trajectory, metrics) (Table 4 and the extra runs).
        repeatability: Test id -> (rho_max, rho_mean) [mm] (Table 5).
        repeats: Runs per repeatability test.
        files: Plots and JSON written.
    """

    tests: dict[str, tuple[str, str, CdprMetrics]]
    repeatability: dict[str, tuple[float, float]]
    repeats: int
    files: dict[str, Path]

    def as_dict(self) -> dict:
        """JSON-ready form."""
        return {
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
    return runs


def compare_cdpr(
    model: CableRobotModel,
    plant_config: CdprPlantConfig,
    out_dir: Path,
    repeats: int = 15,
    tests: list[str] | None = None,
    progress: Callable[[str], None] | None = None,
) -> CdprComparison:
    """Run the grid (or the ``tests`` named) and the repeatability runs; write plots, JSON.

    Args:
        model: The cable robot.
        plant_config: The plant.
        out_dir: Folder for the plots and ``cdpr_comparison.json``.
        repeats: Runs per repeatability test (paper 000: 15); 0 skips Table 5.
        tests: Test ids to run (default: all of :func:`_grid`).
        progress: Called with a label before each run.

    Returns:
        The comparison.
    """
    out_dir = Path(out_dir)
    grid = [g for g in _grid() if tests is None or g[0] in tests]
    results: dict[str, tuple[str, str, CdprMetrics]] = {}
    runs: dict[str, CdprRun] = {}
    for test, controller, trajectory_name, options in grid:
        if progress is not None:
            progress(f"test {test}: {controller}, {trajectory_name}")
        trajectory = get_cdpr_trajectory(trajectory_name)
        run = run_cdpr(model, plant_config, controller, trajectory, 0, options)
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
            if progress is not None:
                progress(f"repeatability {test}: run {seed + 1}/{repeats}")
            run = (
                runs[test]
                if seed == 0
                else run_cdpr(model, plant_config, controller, trajectory, seed)
            )
            marker = np.stack([run.columns[f"marker.{a}"] for a in "xyz"], axis=1)
            errors.append(np.linalg.norm(marker - trajectory.position[: len(marker)], axis=1))
        length = min(len(e) for e in errors)
        rho = np.std(np.stack([e[:length] for e in errors]), axis=0)
        repeatability[test] = (1000.0 * float(rho.max()), 1000.0 * float(rho.mean()))
    files: dict[str, Path] = {}
    for test in ("11", "21", "31", "41", "51", "25", "hc-tau-no-friction/1"):
        if test in runs:
            safe = test.replace("/", "_")
            files[f"forces_{safe}"] = plot_forces(
                runs[test], model, out_dir / f"forces_test_{safe}.png", title=f"test {test}"
            )
    comparison = CdprComparison(results, repeatability, repeats, files)
    files["json"] = write_json_atomic(out_dir / "cdpr_comparison.json", comparison.as_dict())
    return comparison


def plot_forces(run: CdprRun, model: CableRobotModel, path: Path, title: str = "") -> Path:
    """Cable forces over time (as paper 000 Fig. 10, 11 and 13), bounds drawn.

    Solid: platform-side forces; dashed: the force distribution's desired forces; shaded:
    while the cable is force controlled.
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
    fig.suptitle(
        f"{title}: {run.controller} on {run.trajectory} (bounds dotted, force control shaded)"
    )
    return plots._save(fig, path)
