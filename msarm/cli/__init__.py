"""The ``msarm`` command: one Typer application with a sub-command per job.

Each sub-command lives in its own module of this package and registers itself on ``app``;
heavy imports happen inside the commands so that ``msarm --help`` stays fast.
"""

from __future__ import annotations

from typing import Any

import typer
from typer.core import TyperOption

from msarm.cli.arm import arm_command
from msarm.cli.bench import bench_app
from msarm.cli.cdpr import cdpr_app
from msarm.cli.common import RepeatedWarnings
from msarm.cli.compensator import compare_command, train_command
from msarm.cli.diagnose import diagnose_command
from msarm.cli.log import log_app
from msarm.cli.track import track_command
from msarm.errors import InputError


def _no_value_for_flags() -> None:
    """Show no value type beside a flag in ``--help`` (typer 0.29 showed ``--json <bool>``).

    A flag takes no value (``--json true`` is refused as an extra argument), so its help row
    should name none; options that take a value keep their ``<int>``, ``<path>`` ….
    """
    shown = TyperOption.display_type_rich

    def display_type_rich(self: TyperOption, ctx: Any) -> str | None:
        if self.is_flag and not self.count:
            return None
        return shown(self, ctx)

    TyperOption.display_type_rich = display_type_rich  # type: ignore[method-assign]


_no_value_for_flags()

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
app.add_typer(log_app, name="log")


#: Options of a sub-command that take several values after one flag (``--holdout A B C``),
#: as well as repeated (``--holdout A --holdout B``).
MULTI_VALUE_OPTIONS = {
    ("diagnose",): ("--holdout", "--candidates"),
    ("bench", "diagnose"): ("--effect",),
}
#: Of those, the options whose values are names (letters, digits, ``_``): a value that is not
#: one (a log path) ends the list, so that ``--candidates capstan LOG1 LOG2`` keeps its logs.
NAME_OPTIONS = ("--candidates", "--effect")
#: The exit code typer gives a command that a KeyboardInterrupt (Ctrl-C) ended (128 + SIGINT).
CTRL_C_EXIT = 130


def _greedy_option_hint(message: str, args: list[str]) -> str:
    """A hint when an argument is missing because a multi-value option took the values."""
    if not message.startswith("Missing argument"):
        return ""
    options = {name for names in MULTI_VALUE_OPTIONS.values() for name in names}
    options -= set(NAME_OPTIONS)  # those stop at the first value that is not a name
    greedy = ""
    for k, arg in enumerate(args):
        name, inline = arg.split("=", 1)[0], "=" in arg
        if name in options:
            taken = int(inline)  # --holdout=h1 h2: h1 is its first value
            for value in args[k + 1 :]:
                if value == "--" or value.startswith("-"):
                    break
                taken += 1
            if taken >= 2:  # it took values that were meant as the arguments
                greedy = name
    if not greedy:
        return ""
    return (
        f": {greedy} takes every value after it up to the next option, so give the "
        f"arguments before it (or end its values with --)"
    )


def spread_multi_value_options(args: list[str]) -> list[str]:
    """Rewrite ``--opt A B C`` as ``--opt A --opt B --opt C`` for :data:`MULTI_VALUE_OPTIONS`.

    Click gives a repeatable option one value per flag, so that ``msarm diagnose T1 T2
    --holdout H1 H2`` would hold out only ``H1`` and train on ``H2``: a silent mistake. Here
    every value after such an option up to the next option (a token starting with ``-``) or
    ``--`` belongs to it; for :data:`NAME_OPTIONS`, up to the first value that is not a name.

    Args:
        args: The command line without the program name.

    Returns:
        The rewritten command line.
    """
    options: tuple[str, ...] = ()
    for command, names in MULTI_VALUE_OPTIONS.items():
        if tuple(args[: len(command)]) == command:
            options = names
    out: list[str] = []
    current: str | None = None
    for k, arg in enumerate(args):
        if current is not None and out[-1] == current and (arg == "--" or arg.startswith("-")):
            # click would take the next option itself as the value (--candidates --boot 0)
            raise InputError(f"{current}: expected at least one value after it, got {arg}")
        if arg == "--":
            out.extend(args[k:])
            return out
        if arg.startswith("-"):
            name = arg.split("=", 1)[0]  # --holdout=A B: B belongs to it too
            current = name if name in options else None
            out.append(arg)
            continue
        if current in NAME_OPTIONS and out[-1] != current and not arg.isidentifier():
            current = None  # a path after the names: a positional argument
        if current is not None and out and out[-1] != current:
            out.append(current)
        out.append(arg)
    return out


def _mujoco_warning(message: str) -> None:
    """MuJoCo's warnings under the command line: one ``msarm: warning:`` line each.

    An instability warning ("... The simulation is unstable") is left out: the plant stops
    the run itself with an error naming the time, the state and what MuJoCo found (MuJoCo's
    own line gave another time, and its default handler wrote ``MUJOCO_LOG.TXT`` into the
    working folder).
    """
    import sys

    if "simulation is unstable" not in message:
        print(f"msarm: warning: MuJoCo: {message}", file=sys.stderr)


def main() -> None:
    """Entry point of the ``msarm`` console script.

    msarm's own errors (bad input, a bad model or log file, ...) and the command line's
    (an unknown option, a value out of an option's range, ...) are printed as one line
    naming the problem, with exit code 2; anything else keeps its traceback (a bug). SIGTERM
    ends the command as an exception would (temporary files removed, see
    :mod:`msarm.io.atomic`, and the output folders it created and left empty), with
    ``msarm: terminated`` and exit code 143; Ctrl-C likewise, with ``msarm: interrupted``
    and exit code 130.
    """
    import sys
    import warnings

    import mujoco
    from typer import Abort

    # typer's own copy of click's errors (typer exports only BadParameter of these)
    from typer._click.exceptions import ClickException, NoArgsIsHelpError, UsageError

    from msarm import interrupts
    from msarm.cli.common import remove_empty_created_folders
    from msarm.errors import MsarmError, MsarmWarning

    default_show = warnings.showwarning
    repeats = RepeatedWarnings()

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        # msarm's own warnings name their file and column: one line, no source location; the
        # same warning about further logs is counted and summarised at the end
        if issubclass(category, MsarmWarning):
            if repeats.first(str(message)):
                print(f"msarm: warning: {message}", file=sys.stderr if file is None else file)
        else:
            default_show(message, category, filename, lineno, file, line)

    warnings.showwarning = show
    previous_mujoco_warning = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(_mujoco_warning)
    try:
        # SIGTERM raises in the command (the handler set, in the main thread only, and given
        # back after it)
        with interrupts.sigterm_raises():
            code = app(
                args=spread_multi_value_options(sys.argv[1:]),
                prog_name="msarm",
                standalone_mode=False,
            )
            # a SIGTERM whose exception a garbage-collection or weakref callback swallowed
            # (Python prints "Exception ignored in" and goes on): the command still ends 143
            interrupts.raise_if_terminated()
    except MsarmError as exc:
        remove_empty_created_folders()  # an --out made for a command refused: not left behind
        print(f"msarm: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    except NoArgsIsHelpError as exc:  # a command group without its command: its help
        print(exc.format_message(), file=sys.stderr)
        raise SystemExit(exc.exit_code) from None
    except UsageError as exc:
        command = exc.ctx.command_path if exc.ctx is not None else "msarm"
        text = exc.format_message()
        hint = _greedy_option_hint(text, sys.argv[1:])
        text = f"{text.rstrip('.')}{hint}" if hint else text
        print(f"msarm: error: {text} (see '{command} --help')", file=sys.stderr)
        raise SystemExit(exc.exit_code) from None
    except ClickException as exc:
        print(f"msarm: error: {exc.format_message()}", file=sys.stderr)
        raise SystemExit(exc.exit_code) from None
    except Abort:
        remove_empty_created_folders()  # an --out made for a run cut off: not left behind
        print("msarm: aborted", file=sys.stderr)
        raise SystemExit(1) from None
    except interrupts.Terminated as exc:
        remove_empty_created_folders()  # an --out made for a run cut off: not left behind
        print("msarm: terminated", file=sys.stderr)
        raise SystemExit(exc.code) from None
    else:
        if isinstance(code, int) and code != 0:  # typer.Exit(code) of a command
            remove_empty_created_folders()  # an --out made for a run cut off: not left behind
            if code == CTRL_C_EXIT:  # typer's answer to a KeyboardInterrupt: no line of its own
                print("msarm: interrupted", file=sys.stderr)
            raise SystemExit(code)
    finally:
        mujoco.set_mju_user_warning(previous_mujoco_warning)
        for text in repeats.summary():
            print(f"msarm: warning: {text}", file=sys.stderr)
        warnings.showwarning = default_show  # as it was, for code that runs after the command
