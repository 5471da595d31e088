"""``msarm bench …``: speed measured as ratios against a reference run in the same process."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from msarm.diagnose.effect_classes import EFFECT_CLASSES

bench_app = typer.Typer(
    help="Benchmarks: each times a fast path and its reference in the same run.",
    no_args_is_help=True,
)


@bench_app.command("allocation")
def allocation(
    n_problems: int = typer.Option(1000, "--n-problems", min=1, help="Problems per robot."),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the problem generator."),
    json_output: bool = typer.Option(False, "--json", help="Print the report as JSON."),
) -> None:
    """Allocation solvers on the arm (M 4 x 9) and an 8-cable CDPR (M 6 x 8), against cvxpy."""
    import json

    from msarm.allocation.benchmark import run_benchmark

    report = run_benchmark(n_problems=n_problems, seed=seed)
    if json_output:
        typer.echo(json.dumps(report, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title=f"Allocation: median time per solve over {n_problems} problems (seed {seed})"
    )
    for name, justify in (
        ("robot", "left"),
        ("method", "left"),
        ("µs/solve", "right"),
        ("vs cvxpy", "right"),
        ("solves/s", "right"),
        ("feasible", "right"),
        ("fallback", "right"),
        ("obj. diff", "right"),
    ):
        table.add_column(name, justify=justify, no_wrap=True)
    table.caption = (
        "median wall time of one solve (validation included); batched: one call for all "
        "problems, per problem, the best of 5 calls (not a median); fallback: problems the "
        "method could not solve itself and handed to its fallback (timed with it); obj. "
        "diff: largest relative difference of the objective from cvxpy's (exact methods)"
    )
    for robot, entry in report["robots"].items():
        n, m = entry["shape"]  # M's shape: DOF x actuators
        label = f"{robot} (M {n}x{m})"
        for method, row in entry["methods"].items():
            diff = row.get("max_rel_objective_diff_vs_cvxpy")
            table.add_row(
                label,
                method,
                f"{row['median_us']:.1f}",
                f"{row['speedup_vs_cvxpy']:.1f}x",
                f"{row['solves_per_s']:,.0f}" if "solves_per_s" in row else "",
                f"{row['feasible']}/{entry['n_problems']}",
                f"{row.get('statuses', {}).get('fallback', 0)}",
                "" if diff is None or method == "cvxpy" else f"{diff:.1e}",  # not itself
            )
            label = ""
        table.add_section()
    console = Console()
    if not console.is_terminal:  # piped or captured: no terminal width to fit, use a wide one
        console = Console(width=120)
    console.print(table)
    targets = report["targets"]
    for robot, checks in report["targets_met"].items():
        marks = ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in checks.items())
        console.print(f"{robot}: {marks}")
    console.print(
        f"targets: fast >= {targets['fast_min_speedup']:.0f}x cvxpy and <= "
        f"{targets['fast_max_median_us']:.0f} µs; batched >= "
        f"{targets['batched_min_solves_per_s']:,.0f} solves/s"
    )
    for robot, entry in report["robots"].items():
        console.print(f"{robot}: problems from {entry['source']}, f_ref {entry['f_ref']}")


@bench_app.command("sim")
def sim(
    task: str = typer.Option("table1-1", "--task", help="Task to run (see msarm track --list)."),
    plant: str = typer.Option(
        "default",
        "--plant",
        help="default, ideal, a plant YAML file, or a run's config.yaml (its plant).",
    ),
    repeats: int = typer.Option(
        3, "--best-of", "--repeats", min=1, help="Runs of each; the fastest counts."
    ),
    ff: Annotated[
        Path | None,
        typer.Option(
            "--ff",
            help="Also time the closed loop with this compensator (msarm train's checkpoint), "
            "run with the gains it was trained with.",
        ),
    ] = None,
    json_output: bool = typer.Option(False, "--json", help="Print the report as JSON."),
) -> None:
    """Closed-loop real-time factor of a task and its ratio to bare MuJoCo stepping."""
    import json

    from rich.markup import escape
    from rich.table import Table

    from msarm.cli.common import PLANTS, check_control_period, console, resolve_plant
    from msarm.model import load_arm
    from msarm.tasks.bench import TARGET_REAL_TIME_FACTOR, run_sim_benchmark

    arm = load_arm()
    plant_config = resolve_plant(plant)
    plant_file = None if plant in PLANTS else plant
    from msarm.control import ArmControllerConfig

    # the plain loop runs the default gains: its control period against the plant's step
    rate_source = "ArmControllerConfig's default rate_hz"
    check_control_period(ArmControllerConfig(), plant_config, rate_source, plant_file)
    feedforward = None
    if ff is not None:
        from msarm.compensation.feedforward import load_feedforward, trained_controller

        compensation = load_feedforward(ff, arm)
        gains = trained_controller(compensation.compensator, str(ff))
        rate_source = f"the gains recorded in {ff}: rate_hz"
        check_control_period(gains, plant_config, rate_source, plant_file)
        feedforward = (compensation, gains)
    result = run_sim_benchmark(arm, plant_config, task, repeats, feedforward)
    if json_output:
        typer.echo(json.dumps(result.as_dict(), indent=2))
        return
    table = Table(
        title=f"Simulation speed: {result.task} ({result.simulated_s:.0f} s simulated)"
        f", plant {result.plant}, best of {repeats}"
    )
    for name in ("what", "wall [s]", "x real time", "x bare MuJoCo"):
        table.add_column(escape(name), justify="left" if name == "what" else "right")
    for what, wall, factor, ratio in result.rows():
        table.add_row(what, f"{wall:.3f}", f"{factor:.1f}", f"{ratio:.1f}")
    out = console()
    out.print(table)
    out.print(f"controller: {result.controller_tick_us:.1f} µs per tick")
    met = "met" if result.closed_loop_real_time_factor >= TARGET_REAL_TIME_FACTOR else "NOT met"
    out.print(f"target: closed loop >= {TARGET_REAL_TIME_FACTOR:.0f}x real time: {met}")


#: Effect classes of ``msarm bench diagnose --effect``.
BENCH_EFFECTS = EFFECT_CLASSES
_EFFECT_HELP = (
    f"Effect classes to cover, of {', '.join(BENCH_EFFECTS)}: every name after --effect up "
    "to the next option (or repeat the option); default all."
)
_BENCH_DIAGNOSE_HELP = (
    "Withheld-effect benchmark: name the effect each simulated plant was given (vs PySINDy)."
    "\n\n"
    "Each scenario is the arm plant with one effect (--draws seeded parameter draws per class, "
    "3 by default), "
    "two effects, or only sensor noise. Its logs (training and held-out tasks differ) go to "
    "the diagnosis and to a PySINDy sparse-regression baseline on the same data. Logs and "
    "results are cached under --out: a rerun resumes."
)


@bench_app.command("diagnose", help=_BENCH_DIAGNOSE_HELP)
def diagnose_bench(
    out: Path = typer.Option(  # noqa: B008
        Path("runs/bench-diagnose"), "--out", help="Folder of logs and results."
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of scenarios and tasks."),
    draws: int = typer.Option(3, "--draws", min=1, help="Parameter draws per effect class."),
    n_null: int = typer.Option(3, "--null", min=0, help="Null plants (sensor noise only)."),
    n_train: int = typer.Option(
        4, "--train-tasks", "--train", min=1, help="Training tasks per scenario."
    ),
    n_holdout: int = typer.Option(
        2,
        "--holdout-tasks",
        "--holdout",
        min=1,
        help="Held-out tasks per scenario (a number; msarm diagnose's --holdout takes logs).",
    ),
    duration: float = typer.Option(10.0, "--duration", min=2.0, help=r"Task length \[s]."),
    n_boot: int = typer.Option(10, "--boot", min=0, help="Bootstrap draws of the diagnosis."),
    effects: list[str] = typer.Option(  # noqa: B008
        [],
        "--effect",
        metavar="NAME",
        help=_EFFECT_HELP,
    ),
    pairs: bool = typer.Option(True, "--pairs/--no-pairs", help="Two-effect scenarios."),
    sindy_threshold: float = typer.Option(
        0.05,
        "--sindy-threshold",
        min=0.0,
        help="The PySINDy baseline's STLSQ threshold on unit-norm columns (a change re-scores "
        "the baseline and the diagnosis from the cached logs).",
    ),
    sindy_alpha: float = typer.Option(
        0.05,
        "--sindy-alpha",
        min=0.0,
        help="The PySINDy baseline's STLSQ ridge weight on unit-norm columns (PySINDy's "
        "default; a change re-scores as --sindy-threshold does).",
    ),
    rescore: bool = typer.Option(
        False, "--rescore", help="Diagnose again every scenario (cached logs are reused)."
    ),
    json_output: bool = typer.Option(False, "--json", help="Print the report as JSON."),
) -> None:
    """Withheld-effect benchmark (the help text is ``_BENCH_DIAGNOSE_HELP``)."""
    import json
    from pathlib import Path

    from rich.console import Console
    from rich.table import Table

    from msarm.cli.common import output_folder, progress_lines
    from msarm.diagnose.bench import BenchSettings, run_diagnosis_benchmark
    from msarm.model import load_arm

    settings = BenchSettings(
        seed=seed,
        draws=draws,
        n_null=n_null,
        n_train=n_train,
        n_holdout=n_holdout,
        duration=duration,
        n_boot=n_boot,
        effects=tuple(effects),
        pairs=pairs,
        sindy_threshold=sindy_threshold,
        sindy_alpha=sindy_alpha,
    )
    # progress on stderr with --json too: a spinner on a terminal, else a line a step
    err = Console(stderr=True)
    line = progress_lines("bench diagnose")
    with err.status("benchmark") as status:

        def step(text: str) -> None:
            status.update(text)
            line(text)

        report = run_diagnosis_benchmark(
            load_arm(),
            output_folder(Path(out)),
            settings,
            progress=step,
            rescore=rescore,
        )
    if json_output:
        typer.echo(json.dumps(report, indent=2))
        return
    console = Console()
    if not console.is_terminal:
        console = Console(width=140)
    rows = Table(title="Scenarios: what each method named (first = top-1)")
    for column in ("scenario", "msarm names", "confidence", "PySINDy names", "ms s", "sindy s"):
        rows.add_column(column)
    for row in report["scenarios"]:
        ours, theirs = row["msarm"], row["sindy"]
        rows.add_row(
            row["scenario"],
            ", ".join(ours["names"]) or "-",
            ", ".join("n/a" if c is None else f"{c:.2f}" for c in ours["confidence"]),
            ", ".join(theirs["names"][:4]) + (" …" if len(theirs["names"]) > 4 else "") or "-",
            f"{ours['seconds']:.1f}",
            f"{theirs['seconds']:.1f}",
        )
    console.print(rows)
    summary = report["summary"]
    from msarm.diagnose.bench_parameters import JOINT_SPEEDS

    def fmt(value, pattern="{:.0%}"):
        return "n/a" if value is None else pattern.format(value)

    shrink_format = "{:.1%}"  # the methods' shrinks differ by tenths of a point

    table = Table(title="Withheld-effect benchmark: msarm diagnosis vs PySINDy (same data)")
    for column in ("score", "target", "msarm", "PySINDy"):
        table.add_column(column)
    ours, theirs = summary["msarm"], summary["sindy"]
    table.add_row(
        f"top-1 accuracy ({ours['single_scenarios']} single-effect)",
        ">= 90 %",
        fmt(ours["top1_accuracy"]),
        fmt(theirs["top1_accuracy"]),
    )
    table.add_row(
        f"both found ({ours['pair_scenarios']} two-effect)",
        "",
        fmt(ours["both_found"]),
        fmt(theirs["both_found"]),
    )
    nulls = ours["null_scenarios"]
    table.add_row(
        f"false alarms ({nulls} null plants)",
        "0",
        str(ours["false_alarms"]) if nulls else "n/a",
        str(theirs["false_alarms"]) if nulls else "n/a",
    )
    table.add_row(
        "held-out gap shrink (single)",
        ">= 80 %",
        fmt(ours["mean_shrink"], shrink_format),
        fmt(theirs["mean_shrink"], shrink_format),
    )
    table.add_row(
        "  above the noise floor",
        "",
        fmt(ours["mean_excess_shrink"], shrink_format),
        fmt(theirs["mean_excess_shrink"], shrink_format),
    )
    ceiling = summary.get("shrink_ceiling")
    table.add_row(
        "  ceiling: a perfect diagnosis, only the noise left",
        "",
        fmt(ceiling, shrink_format),
        fmt(ceiling, shrink_format),
    )
    table.add_row(
        "extra terms named (per scenario with effects)",
        "",
        fmt(ours["mean_extra_terms"], "{:.2f}"),
        fmt(theirs["mean_extra_terms"], "{:.2f}"),
    )
    table.add_row(
        "time per scenario (diagnosis)",
        "",
        fmt(ours["seconds_per_scenario"], "{:.1f} s"),
        fmt(theirs["seconds_per_scenario"], "{:.1f} s"),
    )
    table.add_row(
        "  up to the end of the selection (no bootstrap, no replay)",
        "",
        fmt(ours.get("selection_seconds_per_scenario"), "{:.1f} s"),
        "",
    )
    console.print(table)
    by_effect = ", ".join(
        f"{e} {ours['top1_by_effect'][e]:.0%}/{theirs['top1_by_effect'].get(e, 0):.0%}"
        for e in ours["top1_by_effect"]
    )
    console.print(f"top-1 by effect (msarm/PySINDy): {by_effect}")
    ceilings = summary.get("shrink_ceiling_by_effect", {})
    shrink = ", ".join(
        f"{e} {ours['shrink_by_effect'][e]:.1%}/{theirs['shrink_by_effect'].get(e, 0):.1%}"
        f"/{fmt(ceilings.get(e), shrink_format)}"
        for e in ours["shrink_by_effect"]
    )
    console.print(f"held-out gap shrink by effect (msarm/PySINDy/ceiling): {shrink}")
    errors = ours.get("parameter_error_by_effect", {})
    if errors:
        other = theirs.get("parameter_error_by_effect", {})

        def median(e):
            value = None if e is None else e["median"]
            # two significant digits below 1 %: a bias recovered to 0.04 % read "0.0%"
            text = (
                f"{100 * value:.2g}%"
                if value is not None and value < 0.01
                else fmt(value, "{:.1%}")
            )
            if e is not None and e["compared"] < e["scenarios"]:
                text += f" ({e['compared']} of {e['scenarios']})"
            return text

        parts = [
            (effect if name == effect else f"{effect} {name}")
            + f" {median(e)}/{median(other.get(effect, {}).get(name))}"
            for effect, by_name in errors.items()
            for name, e in by_name.items()
        ]
        console.print(
            "parameters against the plant's, median relative error msarm/PySINDy "
            f"(joint friction: its steady curve at {', '.join(map(str, JOINT_SPEEDS))} rad/s; "
            "'n of m' where a method named the term on only n of the m scenarios): "
            + ", ".join(parts)
        )
    for failure in report["failed"]:
        console.print(
            f"not scored (simulation diverged): {failure['scenario']}: {failure['error']}"
        )
    console.print(f"results: {Path(out) / 'results.json'}, plot: {Path(out) / 'confusion.png'}")
