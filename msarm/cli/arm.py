"""``msarm arm``: print the arm's joints and muscles and write its plots."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from msarm.model import RobotModel


def joints_table(model: RobotModel) -> Table:
    """A table of the joints: name, axis, range."""
    table = Table(title=f"{model.name}: joints (order of every joint-space array)")
    for column in ("#", "joint", "type", "axis (parent frame)", "range [deg]"):
        table.add_column(escape(column))
    for k, name in enumerate(model.joint_names):
        joint = model.mj_model.joint(name)
        table.add_row(
            str(k),
            name,
            "hinge" if int(joint.type[0]) == 3 else "slide",
            " ".join(f"{v:+.0f}" for v in model.mj_model.jnt_axis[k]),
            f"{np.degrees(model.joint_lower[k]):.0f} .. {np.degrees(model.joint_upper[k]):.0f}",
        )
    return table


def hill_table(model: RobotModel) -> Table:
    """A table of the cable muscles' Hill parameters."""
    table = Table(title="cable muscles: Hill parameters")
    for column in ("cable", "F_max [N]", "l_M0 [cm]", "l_Ts [cm]", "v_max [l_M0/s]", "pennation"):
        table.add_column(escape(column), justify="left" if column == "cable" else "right")
    muscles = model.muscles
    for i, name in enumerate(model.cable_names):
        if muscles is None:
            table.add_row(name, *["-"] * 5)
            continue
        table.add_row(
            name,
            f"{muscles.max_isometric_force[i]:.0f}",
            f"{100 * muscles.optimal_fiber_length[i]:.1f}",
            f"{100 * muscles.tendon_slack_length[i]:.1f}",
            f"{muscles.max_contraction_velocity[i]:.0f}",
            f"{np.degrees(muscles.pennation_at_optimal[i]):.0f} deg",
        )
    return table


def geometry_table(model: RobotModel, q: np.ndarray) -> Table:
    """A table of the cables at posture ``q``: length, wrap angle, moment arms."""
    geometry = model.geometry(q)
    table = Table(title=escape(f"cables at q = {np.round(q, 3).tolist()} rad; moment arms r [cm]"))
    for column in ("cable", "length [cm]", "wrap [deg]"):
        table.add_column(escape(column), justify="left" if column == "cable" else "right")
    for k in range(model.n_joints):
        table.add_column(f"r{k}", justify="right")
    for i, name in enumerate(model.cable_names):
        arms = [f"{100 * r:+.2f}" if abs(r) > 1e-9 else "0" for r in geometry.moment_arms[i]]
        table.add_row(
            name,
            f"{100 * geometry.lengths[i]:.1f}",
            f"{np.degrees(geometry.wrap_angles[i]):.0f}",
            *arms,
        )
    return table


def show_arm(model: RobotModel, out: Path | None, console: Console | None = None) -> list[Path]:
    """Print the arm's tables and, if ``out`` is given, write its plots there.

    Returns:
        The paths of the plots written.
    """
    from msarm import plots

    if console is None:
        from msarm.cli.common import console as wide_when_piped

        console = wide_when_piped()  # 80 columns cut the cable names when piped
    console.print(joints_table(model))
    console.print(hill_table(model))
    console.print(geometry_table(model, np.zeros(model.n_joints)))
    console.print(
        "r<k> = -dl/dq_k: torque on joint k per newton of cable tension (tau = -J_c^T f)."
    )
    if out is None:
        return []
    paths = [
        plots.plot_moment_arms(model, out / "moment_arms.png"),
        plots.plot_hill_curves(out / "hill_curves.png"),
        plots.plot_controllability(model, out / "controllability_shoulder.png"),
    ]
    for path in paths:
        console.print(f"wrote {path}")
    return paths


def arm_command(
    model: Annotated[
        Path | None,
        typer.Option(
            help="MJCF file of the arm (default: msarm's arm, models/msarm_arm.xml in the "
            "repository)."
        ),
    ] = None,
    out: Annotated[
        Path | None, typer.Option(help="Folder for the PNG plots; no plots if omitted.")
    ] = None,
) -> None:
    """Print the arm's joints and cable muscles (moment arms, Hill parameters); --out: plots."""
    from msarm.cli.common import output_folder
    from msarm.model import load_arm

    show_arm(load_arm(model), None if out is None else output_folder(out))
