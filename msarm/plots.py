"""Plots of a robot model and its muscles, written as PNG files (headless, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from msarm.io.atomic import atomic_path
from msarm.model import RobotModel
from msarm.muscle import curves
from msarm.muscle.geometry import positive_spanning_margin

__all__ = ["save_figure", "plot_controllability", "plot_hill_curves", "plot_moment_arms"]


def save_figure(fig: plt.Figure, path: str | Path) -> Path:
    """Write ``fig`` as a PNG to ``path`` atomically, close it and return the path."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return Path(path)


def plot_moment_arms(
    model: RobotModel, path: str | Path, home: np.ndarray | None = None, points: int = 61
) -> Path:
    """Moment arms ``-J_c`` [cm] of every cable over each joint's range (others at ``home``).

    Args:
        model: The robot.
        path: PNG file to write.
        home: Posture at which the other joints are held [rad], shape ``(n,)``; zero if None.
        points: Samples over each joint's range.

    Returns:
        The path written.
    """
    home = np.zeros(model.n_joints) if home is None else np.asarray(home, dtype=float)
    columns = 2
    rows = int(np.ceil(model.n_joints / columns))
    fig, axes = plt.subplots(
        rows, columns, figsize=(11, 3.8 * rows), squeeze=False, layout="constrained"
    )
    for k, name in enumerate(model.joint_names):
        ax = axes.flat[k]
        angles = np.linspace(model.joint_lower[k], model.joint_upper[k], points)
        arms = []
        for angle in angles:
            q = home.copy()
            q[k] = angle
            arms.append(model.geometry(q, with_wrap_angles=False).moment_arms[:, k])
        arms = 100 * np.array(arms)
        for i, cable in enumerate(model.cable_names):
            if np.abs(arms[:, i]).max() > 1e-9:
                ax.plot(np.degrees(angles), arms[:, i], label=cable)
        ax.axhline(0, color="0.6", lw=0.8)
        ax.set_title(name)
        ax.set_xlabel("joint angle [deg]")
        ax.set_ylabel("moment arm -dl/dq [cm]")
        ax.legend(fontsize=7, ncol=2)
    for ax in axes.flat[model.n_joints :]:
        ax.set_visible(False)
    fig.suptitle(f"{model.name}: moment arms (positive: pulling turns the joint positively)")
    return save_figure(fig, path)


def plot_hill_curves(path: str | Path) -> Path:
    """The De Groote et al. (2016) curves: active and passive force-length, force-velocity."""
    fig, (ax_l, ax_v) = plt.subplots(1, 2, figsize=(11, 4), layout="constrained")
    length = np.linspace(0.4, 1.7, 300)
    ax_l.plot(length, curves.active_force_length(length), label="active f_l")
    ax_l.plot(length, curves.passive_force_length(length), label="passive f_PE")
    ax_l.plot(
        length,
        curves.active_force_length(length) + curves.passive_force_length(length),
        "--",
        label="total at a = 1",
    )
    ax_l.set_xlabel("normalised fibre length l_M / l_M0")
    ax_l.set_ylabel("normalised force")
    ax_l.set_ylim(0, 1.6)
    ax_l.legend()
    velocity = np.linspace(-1.0, 1.0, 300)
    ax_v.plot(velocity, curves.force_velocity(velocity))
    ax_v.axvline(0, color="0.6", lw=0.8)
    ax_v.set_xlabel("normalised fibre velocity v_M / v_max (negative: shortening)")
    ax_v.set_ylabel("f_v")
    fig.suptitle("Hill-type muscle curves (De Groote et al. 2016)")
    return save_figure(fig, path)


def plot_controllability(
    model: RobotModel,
    path: str | Path,
    joints: tuple[int, int] = (0, 1),
    home: np.ndarray | None = None,
    points: int = 25,
) -> Path:
    """Map of the positive-spanning margin over two joints (others held at ``home``).

    Positive everywhere means non-negative cable forces can produce any joint torque there.
    """
    home = np.zeros(model.n_joints) if home is None else np.asarray(home, dtype=float)
    a, b = joints
    xs = np.linspace(model.joint_lower[a], model.joint_upper[a], points)
    ys = np.linspace(model.joint_lower[b], model.joint_upper[b], points)
    margin = np.empty((points, points))
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            q = home.copy()
            q[a], q[b] = x, y
            margin[i, j] = positive_spanning_margin(
                model.geometry(q, with_wrap_angles=False).jacobian
            )
    fig, ax = plt.subplots(figsize=(6, 5), layout="constrained")
    mesh = ax.pcolormesh(np.degrees(xs), np.degrees(ys), margin, shading="auto", cmap="viridis")
    fig.colorbar(mesh, ax=ax, label="positive-spanning margin (> 0: controllable)")
    ax.set_xlabel(f"{model.joint_names[a]} [deg]")
    ax.set_ylabel(f"{model.joint_names[b]} [deg]")
    ax.set_title(f"min {margin.min():.3f}")
    return save_figure(fig, path)


def plot_joint_tracking(
    columns: dict[str, np.ndarray],
    joint_names: tuple[str, ...],
    path: str | Path,
    title: str = "",
    others: dict[str, dict[str, np.ndarray]] | None = None,
) -> Path:
    """Joint angles against their reference over time (as paper 003 Fig. 4 and 7).

    Args:
        columns: Log columns (``t``, ``q.<joint>``, ``q_ref.<joint>``).
        joint_names: Joints to draw, one panel each.
        path: PNG file to write.
        title: Figure title.
        others: More runs to overlay, by label (e.g. ``{"with feedforward": columns}``).
    """
    n = len(joint_names)
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.2 * n), sharex=True, layout="constrained")
    axes = np.atleast_1d(axes)
    t = columns["t"]
    for ax, name in zip(axes, joint_names, strict=True):
        ax.plot(t, np.degrees(columns[f"q_ref.{name}"]), "k--", lw=1.2, label="reference")
        ax.plot(t, np.degrees(columns[f"q.{name}"]), lw=1.2, label="measured")
        for label, other in (others or {}).items():
            ax.plot(other["t"], np.degrees(other[f"q.{name}"]), lw=1.2, label=label)
        ax.set_ylabel(f"{name}\n[deg]")
    axes[0].legend(fontsize=8, ncol=3)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title or "joint angles")
    return save_figure(fig, path)


def plot_cable_tensions(
    columns: dict[str, np.ndarray],
    cable_names: tuple[str, ...],
    path: str | Path,
    lower: float | None = None,
    upper: np.ndarray | None = None,
    title: str = "",
) -> Path:
    """Motor-side cable tensions (load cells) and their commands over time, bounds drawn.

    Args:
        columns: Log columns (``t``, ``tension_motor.<cable>``, ``tension_cmd.<cable>``).
        cable_names: Cables to draw, one panel each.
        path: PNG file to write.
        lower: Lower tension bound [N] drawn as a line, or None.
        upper: Upper bound per cable [N], shape ``(m,)``, or None (drawn where in view; the
            axis is scaled to the data).
        title: Figure title.
    """
    m = len(cable_names)
    columns_per_row = 3
    rows = int(np.ceil(m / columns_per_row))
    fig, axes = plt.subplots(
        rows, columns_per_row, figsize=(12, 2.4 * rows), sharex=True, layout="constrained"
    )
    t = columns["t"]
    for i, (ax, name) in enumerate(zip(axes.flat, cable_names, strict=False)):
        ax.plot(t, columns[f"tension_cmd.{name}"], "k--", lw=1.0, label="command")
        ax.plot(t, columns[f"tension_motor.{name}"], lw=1.0, label="load cell")
        top = 1.25 * max(
            float(np.max(columns[f"tension_motor.{name}"])),
            float(np.max(columns[f"tension_cmd.{name}"])),
            2.0 * (lower or 1.0),
        )
        if lower is not None:
            ax.axhline(lower, color="tab:red", lw=0.8, ls=":")
        if upper is not None and upper[i] < top:
            ax.axhline(upper[i], color="tab:red", lw=0.8, ls=":")
        ax.set_ylim(0.0, top)
        ax.set_title(name, fontsize=9)
        ax.set_ylabel("N")
    for ax in axes.flat[m:]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(title or "cable tensions (motor side)")
    return save_figure(fig, path)
