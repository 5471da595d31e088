"""``msarm bench sim``: closed-loop speed against bare MuJoCo stepping, in one run.

Measures, on one core and in one process:

- bare MuJoCo: ``mj_step`` of the arm model for the task's duration at the plant's time step
  (the reference);
- the plant alone: the arm plant (winches, cables, effects) stepping with a constant command,
  the whole duration in one call;
- the controller alone: one control tick called from Python (µs);
- the closed loop: a whole task, plant and controller at their rates, logging included, as
  ``run_tracking`` runs it (the compiled loop of :mod:`msarm.tasks.compiled_loop` where the
  run qualifies);
- the closed loop with Python ticks: the same task through the Python loop (the path of runs
  with user effects or a feedforward that reads the sensors), for comparison;
- optionally, the closed loop with a learned feedforward (a trained compensator: network and
  sheath stage, with the gains it was trained with), compiled where the run qualifies and
  with Python ticks.

Each is the best of ``repeats`` runs. The real-time factor is simulated time over wall time;
the ratio says how many times slower than bare MuJoCo stepping each one is.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import mujoco
import numpy as np

from msarm.control import ArmControllerConfig, MuscleSpaceController
from msarm.errors import InputError
from msarm.model import RobotModel
from msarm.plant import ArmPlant, PlantConfig
from msarm.tasks.compiled_loop import compiled_loop_supported
from msarm.tasks.registry import get_task
from msarm.tasks.runner import Feedforward, run_tracking

__all__ = ["SimBenchmark", "run_sim_benchmark"]

#: Target of the closed loop (issue: a 20 s task in 0.2 s).
TARGET_REAL_TIME_FACTOR = 100.0


@dataclass(frozen=True)
class SimBenchmark:
    """Result of :func:`run_sim_benchmark` (times in seconds of wall time)."""

    task: str
    plant: str
    simulated_s: float
    bare_mujoco_s: float
    plant_only_s: float
    controller_tick_us: float
    closed_loop_s: float
    closed_loop_python_s: float
    closed_loop_path: str
    feedforward_s: float | None = None
    feedforward_python_s: float | None = None
    feedforward_path: str | None = None

    @property
    def closed_loop_real_time_factor(self) -> float:
        """Simulated time over the closed loop's wall time."""
        return self.simulated_s / self.closed_loop_s

    def rows(self) -> list[tuple[str, float, float, float]]:
        """(what, wall [s], real-time factor, ratio to bare MuJoCo) rows of the table."""
        return [
            (name, wall, self.simulated_s / wall, wall / self.bare_mujoco_s)
            for name, wall in [
                ("bare MuJoCo mj_step", self.bare_mujoco_s),
                ("plant alone (winches, cables, effects)", self.plant_only_s),
                (
                    f"closed loop (plant + controller + log), {self.closed_loop_path} ticks",
                    self.closed_loop_s,
                ),
                ("closed loop, Python ticks", self.closed_loop_python_s),
                (
                    f"closed loop with the feedforward, {self.feedforward_path} ticks",
                    self.feedforward_s,
                ),
                ("closed loop with the feedforward, Python ticks", self.feedforward_python_s),
            ]
            if wall is not None
        ]

    def as_dict(self) -> dict:
        """JSON-ready dict, derived numbers included."""
        out = asdict(self)
        out["closed_loop_real_time_factor"] = self.closed_loop_real_time_factor
        out["closed_loop_ratio_to_bare_mujoco"] = self.closed_loop_s / self.bare_mujoco_s
        out["target_real_time_factor"] = TARGET_REAL_TIME_FACTOR
        out["target_met"] = self.closed_loop_real_time_factor >= TARGET_REAL_TIME_FACTOR
        return out


def _best(repeats: int, run) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def run_sim_benchmark(
    model: RobotModel,
    plant_config: PlantConfig,
    task_name: str = "table1-1",
    repeats: int = 3,
    feedforward: tuple[Feedforward, ArmControllerConfig] | None = None,
) -> SimBenchmark:
    """Time bare MuJoCo, the plant, the controller and the closed loop on one task.

    Args:
        model: The arm.
        plant_config: The plant.
        task_name: The task (``msarm track --list``).
        repeats: Runs of each measurement; the fastest counts.
        feedforward: Also time the closed loop with this feedforward, run with these
            controller gains (a compensator's: ``load_feedforward`` and
            ``trained_controller``).

    Returns:
        The timings.

    Raises:
        InputError: The plant's closed loop diverges on the task (nothing to time).
    """
    task = get_task(task_name, model)
    steps = int(round(task.duration / plant_config.timestep))

    bare_model = mujoco.MjModel.from_xml_path(str(model.path))
    bare_model.opt.timestep = plant_config.timestep
    bare_data = mujoco.MjData(bare_model)

    def bare() -> None:
        mujoco.mj_resetData(bare_model, bare_data)
        bare_data.qpos[:] = task.home
        for _ in range(steps):
            mujoco.mj_step(bare_model, bare_data)

    plant = ArmPlant(model, plant_config, seed=0)
    controller = MuscleSpaceController(model)
    warm_up = run_tracking(plant, controller, task)  # compiles the kernels
    if warm_up.error is not None:  # timed calls would report it at their end, misleadingly
        raise InputError(
            f"plant {plant_config.name!r}: the closed loop diverges on {task.name} "
            f"({warm_up.error}); the benchmark times runs that finish (msarm track --task "
            f"{task.name} --plant ... shows the run up to there)"
        )

    pretension = np.minimum(np.full(model.n_cables, 20.0), plant.holding_tension)

    def plant_only() -> None:
        plant.reset(task.home, tensions=pretension)
        plant.step(steps)

    plant.reset(task.home, tensions=pretension)
    readings = plant.sense()
    zeros = np.zeros(model.n_joints)
    controller.reset(readings.q)  # at rest there: no velocity estimate left from the warm-up
    ticks = 2000

    def controller_only() -> None:  # holding the posture the sensors read
        for _ in range(ticks):
            controller.update(readings, readings.q, zeros, zeros)

    supported = compiled_loop_supported(plant, controller, None)
    with_feedforward: dict = {}
    if feedforward is not None:
        compensation, gains = feedforward
        tuned = MuscleSpaceController(model, gains)

        def closed_loop_with(compiled: bool | None):
            return lambda: run_tracking(plant, tuned, task, compensation, compiled=compiled)

        closed_loop_with(None)()  # warm-up
        compiled = compiled_loop_supported(plant, tuned, compensation) and (
            compensation.precompute(*task.reference(np.zeros(1))[:2]) is not None
        )
        with_feedforward = {
            "feedforward_s": _best(repeats, closed_loop_with(None)),
            "feedforward_python_s": _best(repeats, closed_loop_with(False)),
            "feedforward_path": "compiled" if compiled else "Python",
        }
    return SimBenchmark(
        task=task.name,
        plant=plant_config.name,
        simulated_s=task.duration,
        bare_mujoco_s=_best(repeats, bare),
        plant_only_s=_best(repeats, plant_only),
        controller_tick_us=_best(repeats, controller_only) / ticks * 1e6,
        closed_loop_s=_best(repeats, lambda: run_tracking(plant, controller, task)),
        closed_loop_python_s=_best(
            repeats, lambda: run_tracking(plant, controller, task, compiled=False)
        ),
        closed_loop_path="compiled" if supported else "Python",
        **with_feedforward,
    )
