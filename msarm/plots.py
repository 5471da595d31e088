"""Plots of a robot model and its muscles, written as PNG files (headless, Agg backend)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D

from msarm.io.atomic import atomic_path
from msarm.model import RobotModel
from msarm.muscle import curves
from msarm.muscle.geometry import positive_spanning_margin

__all__ = [
    "cable_colors",
    "held_joints_text",
    "plot_cable_tensions",
    "plot_controllability",
    "plot_hill_curves",
    "plot_joint_tracking",
    "plot_moment_arms",
    "save_figure",
]


def save_figure(fig: plt.Figure, path: str | Path) -> Path:
    """Write ``fig`` as a PNG to ``path`` atomically, close it and return the path."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return Path(path)


def cable_colors(count: int) -> list:
    """One colour per cable index, the same in every panel and plot (``tab10`` up to 10)."""
    if count <= 10:
        return [f"C{i}" for i in range(count)]
    if count <= 20:
        return [plt.get_cmap("tab20")(i) for i in range(count)]
    return [plt.get_cmap("viridis")(i / (count - 1)) for i in range(count)]


def held_joints_text(model: RobotModel, held: Sequence[int], home: np.ndarray) -> str:
    """Which joints a plot holds and where, for its title.

    ``"shoulder_rotation, elbow held at 0 deg"`` when they share one value, else
    ``"shoulder_rotation held at 10 deg, elbow held at -20 deg"``.

    Args:
        model: The robot.
        held: Indices of the joints held (not swept by the plot).
        home: The posture they are held at [rad], shape ``(n,)``.
    """
    if not held:
        return "no joint held"
    degrees = [float(np.degrees(home[k])) for k in held]
    if all(abs(d - degrees[0]) < 1e-9 for d in degrees):
        return f"{', '.join(model.joint_names[k] for k in held)} held at {degrees[0]:.3g} deg"
    return ", ".join(
        f"{model.joint_names[k]} held at {d:.3g} deg" for k, d in zip(held, degrees, strict=True)
    )


def plot_moment_arms(
    model: RobotModel, path: str | Path, home: np.ndarray | None = None, points: int = 61
) -> Path:
    """Moment arms ``-J_c`` [cm] of every cable over each joint's range (others at ``home``).

    A cable has the same colour in every panel (by its index; one legend for the figure, to
    the right of the panels); a cable without a moment arm about a joint is not drawn there.

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
        rows, columns, figsize=(12.5, 3.8 * rows), squeeze=False, layout="constrained"
    )
    colors = cable_colors(model.n_cables)
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
                ax.plot(np.degrees(angles), arms[:, i], color=colors[i], label=cable)
        ax.axhline(0, color="0.6", lw=0.8)
        ax.set_title(name)
        ax.set_xlabel("joint angle [deg]")
        ax.set_ylabel("moment arm -dl/dq [cm]")
    for ax in axes.flat[model.n_joints :]:
        ax.set_visible(False)
    handles = [
        Line2D([], [], color=colors[i], label=cable) for i, cable in enumerate(model.cable_names)
    ]
    fig.legend(handles=handles, loc="outside right upper", title="cable", fontsize=8)
    degrees = np.degrees(home)
    if np.all(np.abs(degrees - degrees[0]) < 1e-9):
        where = f"the other joints held at {degrees[0]:.3g} deg"
    else:
        where = "the other joints held at " + ", ".join(
            f"{name} {d:.3g} deg" for name, d in zip(model.joint_names, degrees, strict=True)
        )
    fig.suptitle(
        f"{model.name}: moment arms (positive: pulling turns the joint positively)\n"
        f"each panel sweeps one joint over its range, {where}"
    )
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
    The margin is the smallest share of the cable forces in the most even balancing force
    set (:func:`~msarm.muscle.geometry.positive_spanning_margin`), at most ``1/m`` for ``m``
    cables (all equal); the title names the joints held and where.

    Args:
        model: The robot.
        path: PNG file to write.
        joints: The two joints swept (x, y), indices.
        home: Posture at which the other joints are held [rad], shape ``(n,)``; zero if None.
        points: Samples over each joint's range.

    Returns:
        The path written.
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
    fig.colorbar(
        mesh,
        ax=ax,
        label=f"positive-spanning margin [-] (max 1/{model.n_cables}; > 0: controllable)",
    )
    ax.set_xlabel(f"{model.joint_names[a]} [deg]")
    ax.set_ylabel(f"{model.joint_names[b]} [deg]")
    held = [k for k in range(model.n_joints) if k not in joints]
    ax.set_title(
        f"{model.name}: positive-spanning margin\n{held_joints_text(model, held, home)}; "
        f"min {margin.min():.3f}",
        fontsize=10,
    )
    return save_figure(fig, path)


def plot_joint_tracking(
    columns: dict[str, np.ndarray],
    joint_names: tuple[str, ...],
    path: str | Path,
    title: str = "",
    others: dict[str, dict[str, np.ndarray]] | None = None,
    label: str = "measured",
    error_panels: bool = False,
) -> Path:
    """Joint angles against their reference over time (as paper 003 Fig. 4 and 7).

    Args:
        columns: Log columns (``t``, ``q.<joint>``, ``q_ref.<joint>``).
        joint_names: Joints to draw, one panel each.
        path: PNG file to write.
        title: Figure title.
        others: More runs to overlay, by label (e.g. ``{"with feedforward": columns}``), each
            against its own ``q_ref`` in the error panels.
        label: Legend label of the run in ``columns``.
        error_panels: Under each joint's panel, one of the tracking error ``q - q_ref``
            [mrad] of every run (differences too small to see at the scale of the angles).

    Returns:
        The path written.
    """
    n = len(joint_names)
    runs = {label: columns, **(others or {})}
    rows = 2 * n if error_panels else n
    heights = [2.0, 1.3] * n if error_panels else [1.0] * n
    fig, axes = plt.subplots(
        rows,
        1,
        figsize=(10, (3.3 if error_panels else 2.2) * n),
        sharex=True,
        layout="constrained",
        gridspec_kw={"height_ratios": heights},
    )
    axes = np.atleast_1d(axes)
    for k, name in enumerate(joint_names):
        ax = axes[2 * k] if error_panels else axes[k]
        t = columns["t"]
        ax.plot(t, np.degrees(columns[f"q_ref.{name}"]), "k--", lw=1.2, label="reference")
        for j, (run_label, run) in enumerate(runs.items()):
            ax.plot(run["t"], np.degrees(run[f"q.{name}"]), color=f"C{j}", lw=1.2, label=run_label)
        ax.set_ylabel(f"{name}\n[deg]")
        if error_panels:
            ax_error = axes[2 * k + 1]
            ax_error.axhline(0.0, color="k", ls="--", lw=0.8)
            for j, (run_label, run) in enumerate(runs.items()):
                error = 1000.0 * (run[f"q.{name}"] - run[f"q_ref.{name}"])
                ax_error.plot(run["t"], error, color=f"C{j}", lw=1.0, label=run_label)
            ax_error.set_ylabel("q - q_ref\n[mrad]")
    axes[0].legend(fontsize=8, ncol=len(runs) + 1)
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

    Returns:
        The path written.
    """
    m = len(cable_names)
    columns_per_row = 3
    rows = int(np.ceil(m / columns_per_row))
    fig, axes = plt.subplots(
        rows,
        columns_per_row,
        figsize=(12, 2.4 * rows),
        sharex=True,
        squeeze=False,
        layout="constrained",
    )
    t = columns["t"]
    bound_style = {"color": "tab:red", "lw": 0.8, "ls": ":"}
    bounds_drawn = False
    for i, (ax, name) in enumerate(zip(axes.flat, cable_names, strict=False)):
        ax.plot(t, columns[f"tension_cmd.{name}"], "k--", lw=1.0, label="command")
        ax.plot(t, columns[f"tension_motor.{name}"], lw=1.0, label="load cell")
        top = 1.25 * max(
            float(np.max(columns[f"tension_motor.{name}"])),
            float(np.max(columns[f"tension_cmd.{name}"])),
            2.0 * (lower or 1.0),
        )
        if lower is not None:
            ax.axhline(lower, **bound_style)
            bounds_drawn = True
        if upper is not None and upper[i] < top:
            ax.axhline(upper[i], **bound_style)
            bounds_drawn = True
        ax.set_ylim(0.0, top)
        ax.set_title(name, fontsize=9)
        ax.set_ylabel("tension [N]")
        if i + columns_per_row >= m:  # the lowest panel of its column
            ax.set_xlabel("time [s]")
            ax.tick_params(labelbottom=True)
    for ax in axes.flat[m:]:
        ax.set_visible(False)
    handles, _ = axes.flat[0].get_legend_handles_labels()
    if bounds_drawn:
        handles.append(Line2D([], [], label="bounds", **bound_style))
    axes.flat[0].legend(handles=handles, fontsize=7)
    fig.suptitle(title or "cable tensions (motor side)")
    return save_figure(fig, path)
