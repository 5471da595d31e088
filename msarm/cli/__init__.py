"""The ``msarm`` command: one Typer application with a sub-command per job.

Each sub-command lives in its own module of this package and registers itself on ``app``;
heavy imports happen inside the commands so that ``msarm --help`` stays fast.
"""

from __future__ import annotations

import typer

from msarm.cli.arm import arm_command
from msarm.cli.bench import bench_app
from msarm.cli.cdpr import cdpr_app
from msarm.cli.compensator import compare_command, train_command
from msarm.cli.diagnose import diagnose_command
from msarm.cli.track import track_command

app = typer.Typer(
    name="msarm",
    help="Control, simulate and diagnose cable-driven robots with sheathed cables.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.command("arm")(arm_command)
app.command("track")(track_command)
app.command("train")(train_command)
app.command("compare")(compare_command)
app.command("diagnose")(diagnose_command)
app.add_typer(bench_app, name="bench")
app.add_typer(cdpr_app, name="cdpr")


def main() -> None:
    """Entry point of the ``msarm`` console script.

    msarm's own errors (bad input, a bad model or log file, ...) are printed as one line
    naming the problem, with exit code 2; anything else keeps its traceback (a bug).
    """
    from msarm.errors import MsarmError

    try:
        app()
    except MsarmError as exc:
        import sys

        print(f"msarm: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
