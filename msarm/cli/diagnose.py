"""``msarm diagnose``: which unmodelled effect explains the gap between logs and the model."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from msarm.cli.common import console
from msarm.errors import InputError


def split_runs(logs: list[Path], holdout: list[Path] | None) -> tuple[list[Path], list[Path]]:
    """Training and held-out logs: ``holdout`` as given, else the last quarter of ``logs``.

    Without ``holdout`` the logs are split by file, in the given order: the last
    ``max(1, len(logs) // 4)`` are held out, the rest trained on.

    Raises:
        InputError: Fewer than 2 logs without ``holdout``, no training log left, or a log
            both trained on and held out.
    """
    if holdout:
        held = {p.resolve() for p in holdout}
        train = [p for p in logs if p.resolve() not in held]
        if not train:
            raise InputError("logs: every log is also in --holdout; nothing is left to fit on")
        return train, list(holdout)
    if len(logs) < 2:
        raise InputError(
            f"logs: {len(logs)} log given: too few runs to hold any out (give at least 2 logs, "
            "or --holdout)"
        )
    k = max(1, len(logs) // 4)
    return list(logs[:-k]), list(logs[-k:])


def diagnose_command(
    logs: Annotated[list[Path], typer.Argument(help="Log files (Parquet) of the robot.")],
    holdout: Annotated[
        list[Path] | None,
        typer.Option(help="Held-out log (repeatable); default: the last quarter of LOGS."),
    ] = None,
    json_output: Annotated[
        bool, typer.Option("--json", help="Print the diagnosis as JSON.")
    ] = False,
    out: Annotated[
        Path | None,
        typer.Option(help="Folder to write diagnosis.md and diagnosis.json into."),
    ] = None,
) -> None:
    """Find which candidate effects explain the sim-to-real gap, scored on held-out runs."""
    from msarm.diagnose.select import diagnose
    from msarm.model import load_arm

    train, held = split_runs(list(logs), holdout)
    result = diagnose(load_arm(), train, held)
    payload = result.as_dict()
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "diagnosis.md").write_text(result.to_markdown())
        (out / "diagnosis.json").write_text(json.dumps(payload, indent=2) + "\n")
    if json_output:
        typer.echo(json.dumps(payload, indent=2))
        return
    screen = console()
    table = Table(title=f"diagnosis: {len(train)} training run(s), {len(held)} held-out run(s)")
    for column in ("step", "effect", "parameters", "held-out explained variance"):
        table.add_column(column)
    table.add_row("0", "nominal model", "", f"{result.explained_variance[0]:.3f}")
    for k, effect in enumerate(result.selected, start=1):
        params = ", ".join(
            f"{n}={v:.3g}" for n, v in zip(effect.parameter_names, effect.parameters, strict=True)
        )
        table.add_row(str(k), effect.name, escape(params), f"{effect.explained_variance:.3f}")
    screen.print(table)
    if not result.selected:
        screen.print(
            f"no candidate raises the held-out explained variance by more than "
            f"{result.threshold:g}: nothing selected"
        )
    gap = Table(title="held-out gap per joint (RMSE of the joint-torque residual)")
    for column in ("joint", "before [N m]", "after [N m]", "shrink"):
        gap.add_column(column, justify="right")
    for name, b, a, s in zip(
        result.joint_names, result.gap_before, result.gap_after, result.shrink, strict=True
    ):
        gap.add_row(name, f"{b:.4g}", f"{a:.4g}", f"{100 * s:.1f} %")
    gap.add_row("all", "", "", f"{100 * result.total_shrink:.1f} %")
    screen.print(gap)
