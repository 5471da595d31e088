"""``msarm diagnose``: which unmodelled effect explains the gap between logs and the model.

The command fits the candidate effects (:func:`msarm.diagnose.select.diagnose`) on the
training logs, scores them on the held-out ones and prints the named effects (parameters with
their bootstrap std, gain when selected, confidence), the held-out gap of each channel group
before and after them, and the candidates that could not be tried. With ``--out`` or
``--json`` it also breaks the gap of the training logs down by channel, phase and posture
(:mod:`msarm.diagnose.where`; the joint-torque residual, and the drive and cable-length
residuals when the logs have them), into the JSON's ``where`` section; with ``--out`` it
writes the report (:func:`msarm.diagnose.report.write_report`: ``report.md``,
``report.html``, ``diagnosis.json``, plots) plus ``diagnosis.md`` (the diagnosis' tables
alone).
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from collections.abc import Sequence
from contextlib import nullcontext
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from msarm.cli.common import (
    check_drum_radius,
    check_filter_window,
    console,
    output_folder,
    progress_lines,
)
from msarm.errors import InputError

if TYPE_CHECKING:
    from msarm.diagnose.residuals import ResidualSpec
    from msarm.diagnose.result import Diagnosis
    from msarm.diagnose.where import GapBreakdown
    from msarm.model import RobotModel

#: Residual kinds broken down by ``--out``, in report order (each only when the logs have it).
WHERE_KINDS = ("joint_torque", "drive", "cable_length")
#: The diagnosis' channel group of each residual kind of :data:`WHERE_KINDS`.
KIND_GROUPS = {"joint_torque": "joint", "drive": "drive", "cable_length": "length"}


def split_runs(logs: list[Path], holdout: list[Path] | None) -> tuple[list[Path], list[Path]]:
    """Training and held-out logs: ``holdout`` as given, else the last quarter of ``logs``.

    Without ``holdout`` the logs are split by file, in the given order: the last
    ``max(1, len(logs) // 4)`` are held out, the rest trained on.

    A log in both ``logs`` and ``holdout`` (a glob of every run, say) is held out only, with
    a :class:`~msarm.diagnose.residuals.DiagnosisWarning` that names it.

    Raises:
        InputError: A log given twice, fewer than 2 logs without ``holdout``, or no training
            log left.
    """
    resolved = [p.resolve() for p in logs]
    twice = sorted({str(p) for p in resolved if resolved.count(p) > 1})
    if twice:
        raise InputError(
            f"logs: {', '.join(twice)} given more than once; expected each run once (a "
            "repeated run would weigh twice in the fits, or be scored on itself)"
        )
    if holdout:
        held = {p.resolve() for p in holdout}
        train = [p for p in logs if p.resolve() not in held]
        if not train:
            raise InputError("logs: every log is also in --holdout; nothing is left to fit on")
        both = [str(p) for p in logs if p.resolve() in held]
        if both:  # e.g. a glob of every run with some of them held out
            from msarm.diagnose.residuals import DiagnosisWarning

            warnings.warn(
                f"{', '.join(both)}: given as a log and in --holdout: held out, not trained on "
                f"({len(train)} training log(s) left)",
                DiagnosisWarning,
                stacklevel=2,
            )
        return train, list(holdout)
    if len(logs) < 2:
        raise InputError(
            f"logs: {len(logs)} log given: too few runs to hold any out (give at least 2 logs, "
            "or --holdout)"
        )
    k = max(1, len(logs) // 4)
    return list(logs[:-k]), list(logs[-k:])


def where_breakdowns(
    model: RobotModel,
    logs: Sequence[Path],
    groups: Sequence[str] | None = None,
    spec: ResidualSpec | None = None,
) -> tuple[dict[str, GapBreakdown], dict[str, str]]:
    """The "where" breakdowns of ``logs`` for every residual kind they support.

    Each log's residuals are computed once (:func:`msarm.diagnose.residuals.residuals_from_log`)
    and broken down (:func:`msarm.diagnose.where.break_down`) for each of :data:`WHERE_KINDS`.
    A kind the logs lack (no ``tension_cmd.<cable>`` columns: no drive residual), whose
    residual is zero everywhere, or whose channel group is not in ``groups`` is skipped.

    Args:
        model: The nominal robot model.
        logs: Log files (their sidecars are never opened).
        groups: The channel groups to break down (:data:`KIND_GROUPS`), e.g. those the
            diagnosis kept (``Diagnosis.groups``: a cable-length error below the encoders'
            resolution is left out there); all when ``None``.
        spec: Residual settings (those of the diagnosis); the defaults when ``None``.

    Returns:
        ``(breakdowns, skipped)``: the breakdowns by kind, and the reason of each kind skipped.
    """
    from msarm.diagnose.residuals import DiagnosisWarning, ResidualSpec, residuals_from_log
    from msarm.diagnose.where import break_down

    # no replay: none of WHERE_KINDS is the replay (it took 0.8 s of 1 s on four 20 s logs)
    spec = dataclasses.replace(spec or ResidualSpec(), replay=False)
    with warnings.catch_warnings():
        # diagnose() has already warned about missing columns of these logs
        warnings.simplefilter("ignore", DiagnosisWarning)
        runs = [residuals_from_log(model, path, spec=spec) for path in logs]
    breakdowns: dict[str, GapBreakdown] = {}
    skipped: dict[str, str] = {}
    for kind in WHERE_KINDS:
        if groups is not None and KIND_GROUPS[kind] not in groups:
            skipped[kind] = (
                f"the diagnosis left the {KIND_GROUPS[kind]} residual out: missing, zero or "
                "below its resolution"
            )
            continue
        try:
            breakdowns[kind] = break_down(runs, kind, model=model)
        except ValueError as exc:
            skipped[kind] = str(exc)
    return breakdowns, skipped


#: Parameters of an effect shown in the console's table (the report lists every one).
SHOWN_PARAMETERS = 8


def _print_diagnosis(
    screen: Console, result: Diagnosis, n_train: int, n_held: int, where_skipped: dict[str, str]
) -> None:
    """The rich tables of a diagnosis: named effects, gap per group, candidates not tried."""
    import numpy as np

    from msarm.diagnose.builder import GROUP_UNITS

    table = Table(
        title=f"diagnosis: {n_train} training run(s), {n_held} held-out run(s)",
        caption="held-out score: explained share of the residual energy, mean over the groups; "
        "gain when selected: its rise on the effect's groups, from the fit at that step (the "
        "gap table's shrink is in RMSE, of the final model)",
    )
    for column in ("step", "effect", "acts on", "parameters ± bootstrap std"):
        table.add_column(column)
    for column in ("held-out score", "gain when selected", "confidence"):
        table.add_column(column, justify="right")
    table.add_row("0", "nominal model", "", "", f"{result.explained_variance[0]:.3f}", "", "")
    for k, effect in enumerate(result.selected, start=1):
        confidence = f"{effect.confidence:.2f}" if np.isfinite(effect.confidence) else "n/a"
        table.add_row(
            str(k),
            escape(effect.name),
            ", ".join(effect.groups),
            escape("\n".join(effect.parameter_texts(limit=SHOWN_PARAMETERS))),
            f"{effect.explained_variance:.3f}",
            f"{effect.gain:+.3f}",
            confidence,
        )
    screen.print(table)
    if any(len(effect.parameter_names) > SHOWN_PARAMETERS for effect in result.selected):
        screen.print(
            "every parameter of each effect: in the report and diagnosis.json (--out DIR writes "
            "them) or with --json",
            highlight=False,
        )
    if any(not np.isfinite(effect.confidence) for effect in result.selected):
        screen.print(
            "confidence n/a and no parameter spread: no bootstrap ran (it redraws the "
            f"training runs, so it needs at least 2 of them, here {n_train}, and --boot >= 2)",
            highlight=False,
        )
    for effect in result.selected:
        for note in effect.notes:
            screen.print(f"note on {escape(effect.name)}: {escape(note)}", highlight=False)
    if not result.selected:
        screen.print(
            f"no candidate raises the held-out explained variance by more than "
            f"{result.threshold:g}: nothing selected"
        )
    gap = Table(title="held-out gap per channel group (pooled RMSE of the residual, final model)")
    for column in ("group", "unit", "nominal model", "after the effects", "shrink"):
        gap.add_column(column, justify="left" if column in ("group", "unit") else "right")
    for g in result.groups:
        before = float(np.sqrt(np.mean(np.asarray(result.gap_before[g]) ** 2)))
        after = float(np.sqrt(np.mean(np.asarray(result.gap_after[g]) ** 2)))
        gap.add_row(
            g,
            escape(GROUP_UNITS[g]),
            f"{before:.4g}",
            f"{after:.4g}",
            f"{100 * result.group_shrink(g):.1f} %",
        )
    screen.print(gap)
    if result.skipped:
        skipped = Table(title="candidates not tried")
        skipped.add_column("candidate")
        skipped.add_column("why")
        for name, why in result.skipped.items():
            skipped.add_row(escape(name), escape(why))
        screen.print(skipped)
    for kind, why in where_skipped.items():
        screen.print(f"where: no {escape(kind)} breakdown ({escape(why)})")


def diagnose_command(
    logs: Annotated[
        list[Path],
        typer.Argument(
            metavar="LOG",
            help="Log files (Parquet) of the robot (msarm log import makes them from CSV files; "
            "msarm log check says what the diagnosis can make of them).",
        ),
    ],
    holdout: Annotated[
        list[Path] | None,
        typer.Option(
            metavar="LOG",
            help="Held-out logs: every path after --holdout up to the next option (or repeat "
            "the option); default: the last quarter of LOGS.",
        ),
    ] = None,
    json_output: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print the diagnosis as JSON (diagnosis.json's content, with the where "
            "breakdown; keys in the README).",
        ),
    ] = False,
    out: Annotated[
        Path | None,
        typer.Option(
            help="Folder for the report: report.md, report.html (self-contained), "
            "diagnosis.json, diagnosis.md, waterfall.png, gap.png and a where-<residual>.png "
            "heat map per residual (joint_torque, drive, cable_length); if omitted, the answer "
            "is only printed."
        ),
    ] = None,
    candidates: Annotated[
        list[str] | None,
        typer.Option(
            "--candidates",
            metavar="NAME",
            help="Candidate effects to try, by name: every name after --candidates up to "
            "the next option (or repeat the option); default: the default set "
            "(DEFAULT_CANDIDATES of msarm.diagnose.select). An unknown name lists the known "
            "ones.",
        ),
    ] = None,
    threshold: Annotated[
        float,
        typer.Option(
            help="Least rise of the held-out explained share (on the groups it acts on) for an "
            "effect to be named [-]; a quarter of it is enough for one that explains at least "
            "half of what its groups leave unexplained."
        ),
    ] = 0.02,
    boot: Annotated[
        int,
        typer.Option(
            "--boot",
            metavar="N",
            min=0,
            help="Bootstrap refits over training runs for the std and confidence (0 or 1: none).",
        ),
    ] = 20,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the bootstrap draws.")] = 0,
    shortlist: Annotated[
        int,
        typer.Option(
            metavar="N",
            help="Candidates of each step, best by their screening fit, fitted jointly with "
            "the effects already named; 0: every candidate (slower).",
        ),
    ] = 3,
    tension_timing: Annotated[
        str,
        typer.Option(
            metavar="period|instant",
            help="What a load-cell sample is: the tension held over the sample period that "
            "ends at its time stamp (period: drives that hold each command, as msarm's), or "
            "the tension at its time stamp (instant).",
        ),
    ] = "period",
    drum_radius: Annotated[
        float,
        typer.Option(
            metavar="METRES",
            help=r"Radius of the winch drums \[m]: a motor angle theta (drum angle, reel-in "
            "positive) moves the cable by -r theta. Used for the cable-length residual, and with "
            "--drive-gain it sets the drive terms' parameters in N m (winch friction, motor "
            "cogging scale with r).",
        ),
    ] = 0.003,
    drive_gain: Annotated[
        float,
        typer.Option(
            metavar="K",
            help="Gain of the drives' own tension loop [-]: the motor torque is r (T_cmd + K "
            "(T_cmd - T_load_cell)), so a winch friction torque tau shows as a tension error "
            "tau / (r (1 + K)). Sets the units of the drive terms' parameters (winch friction, "
            "motor cogging) in N m; 4 is msarm's drives.",
        ),
    ] = 4.0,
    filter_window: Annotated[
        int,
        typer.Option(
            metavar="SAMPLES",
            help=r"Savitzky-Golay window of the joint-angle derivatives \[samples], odd, >= 5 "
            "(25 = 0.1 s at 250 Hz; scale it with the sample rate; spans above 0.15 s bias "
            "the residual and are warned about).",
        ),
    ] = 25,
    model_path: Annotated[
        Path | None,
        typer.Option(
            "--model",
            help="The nominal model (MJCF) the logs were recorded with; default msarm's "
            "arm (models/msarm_arm.xml in the repository). Logs of another model are refused "
            "(hashes named). It needs no muscle (Hill) parameters: the diagnosis uses the "
            "cables' geometry; one joint will do, and without a 'hand_center' site the replay "
            "reports the joint error alone.",
        ),
    ] = None,
) -> None:
    """Find which candidate effects explain the sim-to-real gap, scored on held-out runs."""
    from msarm.compensation.target import TENSION_TIMINGS, TargetSpec
    from msarm.diagnose.builder import check_log_file
    from msarm.diagnose.residuals import DiagnosisWarning, ResidualSpec
    from msarm.diagnose.select import check_threshold, diagnose
    from msarm.model import ARM_MODEL_PATH, load_robot

    for path in [*logs, *(holdout or [])]:
        check_log_file(path)
    with warnings.catch_warnings(record=True) as split_caught:
        warnings.simplefilter("always")
        train, held = split_runs(list(logs), holdout)
    for w in split_caught:  # shown now, and kept with the answer below
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if boot < 0:
        raise InputError(f"--boot: expected a number of draws >= 0, got {boot}")
    check_threshold(threshold, "--threshold")  # before the logs are read
    if shortlist < 0:
        raise InputError(f"--shortlist: expected a number of candidates >= 0, got {shortlist}")
    if tension_timing not in TENSION_TIMINGS:
        raise InputError(
            f"--tension-timing: expected one of {', '.join(TENSION_TIMINGS)}, "
            f"got {tension_timing!r}"
        )
    check_drum_radius(drum_radius)
    if not (0 <= drive_gain < float("inf")):
        raise InputError(f"--drive-gain: expected a gain >= 0, got {drive_gain}")
    check_filter_window(filter_window)
    if out is not None:
        output_folder(out)  # before the diagnosis, not after it
    spec = ResidualSpec(
        target=TargetSpec(window=filter_window, tension_timing=tension_timing),
        drum_radius=drum_radius,
        drive_gain=drive_gain,
    )
    options: dict = {
        "n_boot": int(boot),
        "seed": int(seed),
        "shortlist": shortlist or None,
        "spec": spec,
    }
    if candidates:
        options["candidates"] = list(candidates)
    options["threshold"] = threshold
    # progress on stderr, with --json too: a spinner on a terminal, else a line a step
    err = Console(stderr=True)
    status = err.status("reading the logs", spinner="dots") if err.is_terminal else nullcontext()
    line = progress_lines("diagnose")
    where_skipped: dict[str, str] = {}
    written: dict[str, Path] = {}
    with status as spinner:

        def say(text: str) -> None:
            if spinner is not None:
                spinner.update(text)
            line(text)

        # the diagnosis needs no muscle model: any cable-driven arm msarm loads
        model = load_robot(ARM_MODEL_PATH if model_path is None else model_path)
        options["progress"] = say
        with warnings.catch_warnings():
            # the candidates skipped are listed in a table below
            warnings.filterwarnings(
                "ignore", message="candidates not tried", category=DiagnosisWarning
            )
            result = diagnose(model, train, held, **options)
        split_said = [str(w.message) for w in split_caught if w.category is DiagnosisWarning]
        if split_said:  # in diagnosis.json and the report, as the logs' own warnings are
            said = dict.fromkeys([*split_said, *result.log_warnings])
            result = dataclasses.replace(result, log_warnings=tuple(said))
        if out is not None or json_output:  # the "where" section of the JSON and report
            say("breaking the gap of the training logs down")
            breakdowns, where_skipped = where_breakdowns(model, train, result.groups, spec)
            result = result.with_where(breakdowns, where_skipped)
        if out is not None:
            from msarm.diagnose.report import write_report

            say(f"writing the report into {out}")
            tables = {"diagnosis.md": result.to_markdown().encode()}
            written = write_report(result, out, breakdowns, extra_files=tables)
            written["diagnosis_md"] = written.pop("diagnosis.md")
    if json_output:
        typer.echo(json.dumps(result.as_dict(), indent=2))
        for path in written.values():
            err.print(f"wrote {escape(str(path))}", highlight=False)
        return
    screen = console()
    _print_diagnosis(screen, result, len(train), len(held), where_skipped)
    if written:
        screen.print(f"report: {escape(str(written['markdown']))}", highlight=False)
        screen.print(f"        {escape(str(written['html']))} (self-contained)", highlight=False)
        others = [p.name for k, p in written.items() if k not in ("markdown", "html")]
        screen.print(f"also in {escape(str(out))}: {escape(', '.join(others))}", highlight=False)
