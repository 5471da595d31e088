"""What the plots say: titles, axis labels, legends and drawn values read back from the figures
(never pixels): msarm.plots, the track plots' titles and msarm compare's error statistics."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.colors import to_rgba

import msarm.plots
from msarm.compensation.compare import (
    SHEATH_ONLY,
    TRUE_HATCH,
    WITH,
    WITHOUT,
    Comparison,
    plot_error_statistics,
)
from msarm.control import ArmControllerConfig
from msarm.plant import DEFAULT_PLANT
from msarm.tasks.evaluate import TrackingMetrics
from msarm.tasks.track import TrackSettings, run_title


@pytest.fixture
def figures(monkeypatch):
    """The figures the plots save, kept open to be read (and still written)."""
    kept = []

    def keep(fig, path):
        kept.append(fig)
        with msarm.plots.atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=40, format="png")
        return path

    monkeypatch.setattr(msarm.plots, "save_figure", keep)
    yield kept
    import matplotlib.pyplot as plt

    for fig in kept:
        plt.close(fig)


def _texts(legend) -> list[str]:
    return [text.get_text() for text in legend.get_texts()]


def test_moment_arms_colour_each_cable_alike_in_every_panel_and_say_what_is_held(
    arm, figures, tmp_path
):
    msarm.plots.plot_moment_arms(arm, tmp_path / "moment_arms.png", points=5)
    fig = figures[-1]
    assert len(fig.legends) == 1 and _texts(fig.legends[0]) == list(arm.cable_names)
    legend = fig.legends[0]
    legend_colors = {
        text.get_text(): to_rgba(handle.get_color())
        for text, handle in zip(legend.get_texts(), legend.legend_handles, strict=True)
    }
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == arm.n_joints
    drawn = set()
    for ax in panels:
        assert ax.get_legend() is None  # no legend over the curves
        for line in ax.get_lines():
            if line.get_label() in legend_colors:
                assert to_rgba(line.get_color()) == legend_colors[line.get_label()]
                drawn.add(line.get_label())
    assert drawn == set(arm.cable_names)
    # a cable keeps its colour by index, C0 for the first
    assert legend_colors[arm.cable_names[0]] == to_rgba("C0")
    assert "the other joints held at 0 deg" in fig._suptitle.get_text()
    home = np.array([0.1, 0.0, 0.0, -0.5])
    msarm.plots.plot_moment_arms(arm, tmp_path / "bent.png", home=home, points=3)
    assert "elbow -28.6 deg" in figures[-1]._suptitle.get_text()


def test_controllability_map_names_the_held_joints_and_the_margin_s_maximum(arm, figures, tmp_path):
    msarm.plots.plot_controllability(arm, tmp_path / "map.png", points=4)
    ax, colorbar = figures[-1].axes
    assert "shoulder_rotation, elbow held at 0 deg" in ax.get_title()
    assert colorbar.get_ylabel().startswith(f"positive-spanning margin [-] (max 1/{arm.n_cables}")
    # what the label claims: the margin is a share of the cable forces, at most 1/m
    margin = ax.collections[0].get_array()
    assert 0 < margin.max() <= 1 / arm.n_cables + 1e-12
    home = np.array([0.0, 0.0, 0.2, -1.0])
    msarm.plots.plot_controllability(arm, tmp_path / "bent.png", home=home, points=3)
    title = figures[-1].axes[0].get_title()
    assert "shoulder_rotation held at 11.5 deg, elbow held at -57.3 deg" in title


def _run_columns(joints, cables, rng, offset=0.0) -> dict[str, np.ndarray]:
    t = np.linspace(0.0, 1.0, 50)
    columns = {"t": t}
    for k, joint in enumerate(joints):
        columns[f"q_ref.{joint}"] = 0.1 * k * t
        columns[f"q.{joint}"] = columns[f"q_ref.{joint}"] + offset + 1e-3 * rng.standard_normal(50)
    for cable in cables:
        columns[f"tension_cmd.{cable}"] = 10.0 + t
        columns[f"tension_motor.{cable}"] = 10.0 + t + rng.standard_normal(50)
    return columns


def test_tension_plot_labels_time_tension_and_its_bounds(figures, tmp_path):
    cables = tuple(f"c{i}" for i in range(7))  # 3 rows, the last one with a single panel
    columns = _run_columns((), cables, np.random.default_rng(0))
    msarm.plots.plot_cable_tensions(
        columns, cables, tmp_path / "t.png", lower=5.0, upper=np.full(7, 100.0)
    )
    axes = [ax for ax in figures[-1].axes if ax.get_visible()]
    assert len(axes) == 7
    assert all(ax.get_ylabel() == "tension [N]" for ax in axes)
    # the lowest panel of each column says the time (here panels 4, 5 and 6)
    assert [ax.get_xlabel() for ax in axes] == [""] * 4 + ["time [s]"] * 3
    assert _texts(axes[0].get_legend()) == ["command", "load cell", "bounds"]
    msarm.plots.plot_cable_tensions(columns, cables, tmp_path / "none.png")
    assert "bounds" not in _texts(figures[-1].axes[0].get_legend())


def test_joint_tracking_labels_each_run_and_draws_its_tracking_error(figures, tmp_path):
    joints = ("a", "b")
    rng = np.random.default_rng(1)
    without, with_ff = _run_columns(joints, (), rng, 0.01), _run_columns(joints, (), rng)
    msarm.plots.plot_joint_tracking(
        without,
        joints,
        tmp_path / "q.png",
        title="task",
        others={WITH: with_ff},
        label=WITHOUT,
        error_panels=True,
    )
    axes = figures[-1].axes
    assert len(axes) == 4  # angle and error panel per joint
    assert _texts(axes[0].get_legend()) == ["reference", WITHOUT, WITH]
    assert [ax.get_ylabel() for ax in axes[1::2]] == ["q - q_ref\n[mrad]"] * 2
    for k, joint in enumerate(joints):
        lines = {line.get_label(): line for line in axes[2 * k + 1].get_lines()}
        for label, run in ((WITHOUT, without), (WITH, with_ff)):
            expected = 1000.0 * (run[f"q.{joint}"] - run[f"q_ref.{joint}"])
            np.testing.assert_allclose(lines[label].get_ydata(), expected)
    # without error panels: one panel a joint, the run labelled "measured" by default
    msarm.plots.plot_joint_tracking(without, joints, tmp_path / "plain.png")
    assert len(figures[-1].axes) == 2
    assert _texts(figures[-1].axes[0].get_legend()) == ["reference", "measured"]


def test_track_titles_name_the_feedforward_and_a_seed_other_than_0():
    settings = TrackSettings("table1-1", 0, DEFAULT_PLANT, ArmControllerConfig())
    assert run_title("table1-1", settings, False) == "table1-1 on the default plant"
    with_ff = TrackSettings("table1-1", 3, DEFAULT_PLANT, ArmControllerConfig(), "runs/c/ff.pt")
    assert run_title("table1-1", with_ff, True) == (
        "table1-1 on the default plant, with feedforward (ff.pt), seed 3"
    )


def test_a_run_with_feedforward_titles_its_plots_so(arm, figures, tmp_path):
    """``msarm track --ff``: joints.png and tensions.png say it (a zero feedforward here)."""
    from msarm.tasks.track import track
    from msarm.tasks.trajectories import hold_then_move

    class Zero:
        def reset(self) -> None:
            pass

        def __call__(self, readings, qdot_estimate, q_ref, qd_ref):
            return np.zeros(arm.n_joints)

    home = np.array([0.0, 0.0, 0.0, -0.2])
    task = hold_then_move("short", home, home + 0.05, wait=0.05, move_time=0.1, duration=0.2)
    settings = TrackSettings("short", 2, DEFAULT_PLANT, ArmControllerConfig(), "/x/ckpt.pt")
    track(arm, task, settings, tmp_path, feedforward=Zero())
    titles = [fig._suptitle.get_text() for fig in figures]
    expected = "short on the default plant, with feedforward (ckpt.pt), seed 2"
    assert titles == [expected, expected]


TASKS = ("table1-1", "table1-2", "random-7", "random-8")
HELD_OUT = ("random-7", "random-8")


def _metrics(final: float, outside: float, cable: tuple[float, ...]) -> TrackingMetrics:
    return TrackingMetrics(
        final_error_mm=final,
        final_error_percent=0.1,
        settle_error_mm=10 * final,
        joint_rmse=(1e-3, 1e-3),
        cable_length_error_percent=cable,
        cable_length_end_percent=tuple(v / 2 for v in cable),
        slack_events=(0, 0, 0),
        time_outside_bounds=(outside, 2 * outside, 0.0),
        completed=True,
    )


def _comparison(floor: dict[str, float]) -> Comparison:
    labels = (WITHOUT, WITH, SHEATH_ONLY)
    metrics = {
        task: {
            label: _metrics(
                1.0 / (1 + 10 * j) + 0.01 * k, 1.0 + 10 * j + k, (0.1 * (k + 1), 0.02, 1.5)
            )
            for j, label in enumerate(labels)
        }
        for k, task in enumerate(TASKS)
    }
    true = {
        task: {label: 0.5 * m.final_error_mm for label, m in runs.items()}
        for task, runs in metrics.items()
    }
    lowest = {task: dict.fromkeys(labels, 3.0) for task in TASKS}
    return Comparison(TASKS, HELD_OUT, metrics, true, {}, lowest, floor)


def test_error_statistics_show_true_errors_noise_floor_and_time_outside_the_bounds(
    figures, tmp_path
):
    floor = {task: 0.06 + 0.01 * k for k, task in enumerate(TASKS)}
    comparison = _comparison(floor)
    cables = ("c0", "c1", "c2")
    plot_error_statistics(comparison, cables, tmp_path / "e.png", "default")
    fig = figures[-1]
    ax_settle, ax_final, ax_bounds, ax_cable = fig.axes
    assert "on the default plant" in fig._suptitle.get_text()
    assert _texts(fig.legends[0]) == [WITHOUT, WITH, SHEATH_ONLY]
    # the end-effector errors span decades: log axes; the others linear
    assert ax_settle.get_yscale() == ax_final.get_yscale() == "log"
    assert ax_bounds.get_yscale() == "linear"
    # final error: the encoders' bars, the true angles' hatched ones and the noise floor
    hatched = [bar for bar in ax_final.patches if bar.get_hatch() == TRUE_HATCH]
    plain = [bar for bar in ax_final.patches if not bar.get_hatch()]
    for label, bars in zip(comparison.labels, np.split(np.array(plain), 3), strict=True):
        expected = [comparison.metrics[t][label].final_error_mm for t in TASKS]
        assert [bar.get_height() for bar in bars] == pytest.approx(expected)
    for label, bars in zip(comparison.labels, np.split(np.array(hatched), 3), strict=True):
        expected = [comparison.true_final_error_mm[t][label] for t in TASKS]
        assert [bar.get_height() for bar in bars] == pytest.approx(expected)
    segments = [c.get_segments()[0] for c in ax_final.collections]
    assert [s[0][1] for s in segments] == pytest.approx([floor[t] for t in TASKS])
    assert "encoder noise floor" in _texts(ax_final.get_legend())
    assert "true joint angles (simulation)" in _texts(ax_final.get_legend())
    # the cost of the feedforward: time outside the tension bounds, summed over the cables
    assert ax_bounds.get_ylabel() == "time outside tension bounds [s]"
    heights = [bar.get_height() for bar in ax_bounds.patches]
    expected = [
        sum(comparison.metrics[t][label].time_outside_bounds)
        for label in comparison.labels
        for t in TASKS
    ]
    assert heights == pytest.approx(expected)
    # Table I and held-out tasks told apart on every task axis
    for ax in (ax_settle, ax_final, ax_bounds):
        assert {"Table I", "held out"} <= {text.get_text() for text in ax.texts}
        italic = [t.get_text() for t in ax.get_xticklabels() if t.get_fontstyle() == "italic"]
        assert italic == list(HELD_OUT)
    # cable length errors: one point per task and variant, no error bar below zero
    assert not ax_cable.containers and ax_cable.get_ylim()[0] == 0
    points = [line for line in ax_cable.get_lines() if line.get_marker() in ("o", "^")]
    assert len(points) == len(TASKS) * 3
    assert sum(line.get_marker() == "^" for line in points) == len(HELD_OUT) * 3


def test_error_statistics_leave_the_noise_floor_out_when_unknown(figures, tmp_path):
    plot_error_statistics(_comparison({}), ("c0", "c1", "c2"), tmp_path / "e.png")
    ax_final = figures[-1].axes[1]
    assert not ax_final.collections
    assert "encoder noise floor" not in _texts(ax_final.get_legend())
    assert _comparison({}).as_dict()["encoder_noise_floor_mm"] == {}
