"""Shared fixtures: the arm is loaded once per test session; property tests are seeded."""

from __future__ import annotations

import pytest
from hypothesis import settings

from msarm.model import load_arm

# Same seed, same result: hypothesis draws the same examples on every run, and keeps no
# example database in the checkout (a test's own @settings may still change other options).
settings.register_profile("msarm", derandomize=True, database=None)
settings.load_profile("msarm")


#: Test files that take minutes, in the order they are collected, before the others: ``make
#: test`` (``pytest -n 2 --dist loadfile --no-loadscope-reorder``) starts the first worker on
#: the first and the second on the second, while the other files fill in; left where they
#: fall, the slowest started halfway through and ran alone at the end. The second is the
#: cable robot's: the first compiles the arm's numba kernels (about 40 s on a 2-core
#: machine), and the second worker finds them in the cache once it comes to the arm, rather
#: than compiling them too at the same time (a clean clone has no cache).
SLOW_TEST_FILES = (
    "test_compensation_pipeline.py",
    "test_cdpr_runs.py",
    "test_compensation_small_recipe.py",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Move the tests of :data:`SLOW_TEST_FILES` to the front (the rest keep their order)."""

    def rank(item: pytest.Item) -> int:
        name = item.path.name
        return SLOW_TEST_FILES.index(name) if name in SLOW_TEST_FILES else len(SLOW_TEST_FILES)

    items.sort(key=rank)


@pytest.fixture(scope="session")
def arm():
    """The musculoskeletal arm of ``models/msarm_arm.xml``."""
    return load_arm()


def ideal_plant_with(name: str, *effects: str):
    """The ideal plant with the named effects switched on, at their default parameters."""
    from dataclasses import replace

    from msarm.plant import IDEAL_PLANT

    switched = {e: replace(getattr(IDEAL_PLANT.effects, e), enabled=True) for e in effects}
    return replace(IDEAL_PLANT, name=name, effects=replace(IDEAL_PLANT.effects, **switched))


def short_move_logs(arm, root, plant, n_runs: int, first_seed: int = 0) -> list:
    """Logs of ``n_runs`` short hold-then-move tasks (4 s, seeded) on ``plant``, in ``root``.

    Run ``k`` moves between two postures drawn with seed ``first_seed + k`` inside the middle
    half of every joint's range; its plant seed is the same number.
    """
    import numpy as np

    from msarm.control import ArmControllerConfig
    from msarm.tasks.track import TrackSettings, track
    from msarm.tasks.trajectories import hold_then_move

    lower, upper = np.asarray(arm.joint_lower), np.asarray(arm.joint_upper)
    width = upper - lower
    paths = []
    for seed in range(first_seed, first_seed + n_runs):
        rng = np.random.default_rng(seed)
        start, target = (rng.uniform(lower + 0.25 * width, upper - 0.25 * width) for _ in range(2))
        task = hold_then_move(f"move{seed}", start, target, wait=0.5, move_time=2.0, duration=4.0)
        settings = TrackSettings(f"move{seed}", seed, plant, ArmControllerConfig())
        paths.append(track(arm, task, settings, root / f"run{seed}", plots_too=False).files["log"])
    return paths


def trajectory_head(trajectory, n: int):
    """The first ``n`` samples of a cable-robot trajectory (a short run that starts as the
    full one)."""
    from dataclasses import replace

    return replace(
        trajectory,
        t=trajectory.t[:n],
        position=trajectory.position[:n],
        velocity=trajectory.velocity[:n],
        acceleration=trajectory.acceleration[:n],
    )


#: Samples a plumbing test keeps of a cable-robot trajectory: 3 s at 1 ms (the 0.5 s hold,
#: the 0.5 s ramp and 2 s at cruise speed).
SHORT_CDPR_SAMPLES = 3000


@pytest.fixture
def short_cdpr_trajectories(monkeypatch):
    """Every named cable-robot trajectory cut to its first :data:`SHORT_CDPR_SAMPLES`, where
    the commands and the comparison look them up, for tests of the commands' plumbing (folders,
    caches, progress, tables) rather than of the controllers' findings. Returns the short
    ``get_cdpr_trajectory``."""
    import msarm.tasks.cdpr_compare as cdpr_compare
    import msarm.tasks.cdpr_trajectories as cdpr_trajectories

    full = cdpr_trajectories.get_cdpr_trajectory

    def short(name: str, **options: float):
        return trajectory_head(full(name, **options), SHORT_CDPR_SAMPLES)

    monkeypatch.setattr(cdpr_trajectories, "get_cdpr_trajectory", short)
    monkeypatch.setattr(cdpr_compare, "get_cdpr_trajectory", short)
    return short


def assert_same_run_bits(python, compiled) -> None:
    """Two tracking runs (``run_tracking``'s) have the same columns and truth, bit for bit."""
    import numpy as np

    assert set(python.columns) == set(compiled.columns)
    assert set(python.truth) == set(compiled.truth)
    for name in python.columns:
        np.testing.assert_array_equal(
            python.columns[name].view(np.uint64), compiled.columns[name].view(np.uint64), name
        )
    for name in python.truth:
        np.testing.assert_array_equal(
            python.truth[name].view(np.uint64), compiled.truth[name].view(np.uint64), name
        )


def run_msarm(monkeypatch, capsys, *args: str) -> tuple[int, str, str]:
    """Run ``msarm ARGS...`` in this process: ``(exit code, stdout, stderr)``."""
    import sys

    from msarm.cli import main

    monkeypatch.setattr(sys, "argv", ["msarm", *args])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def hand_breakdown(rows, settings, samples: int = 1000):
    """A :class:`~msarm.diagnose.where.GapBreakdown` of the drive residual made of ``rows``
    by hand (total energy 100, RMS 1, a one-cell posture grid): for hot-spot rules."""
    import numpy as np

    from msarm.diagnose.where import GapBreakdown

    return GapBreakdown(
        kind="drive",
        unit="N",
        sources=("hand",),
        samples=samples,
        total_energy=100.0,
        rms=1.0,
        rows=rows,
        posture_joints=("a", "b"),
        posture_edges=(np.zeros(2), np.zeros(2)),
        posture_rms=np.zeros((1, 1)),
        posture_samples=np.ones((1, 1), dtype=np.int64),
        settings=settings,
    )
