"""``msarm bench …``: speed measured as ratios against a reference run in the same process."""

from __future__ import annotations

import typer

bench_app = typer.Typer(
    help="Benchmarks: each times a fast path and its reference in the same run.",
    no_args_is_help=True,
)


@bench_app.command("allocation")
def allocation(
    n_problems: int = typer.Option(1000, "--n-problems", min=1, help="Problems per robot."),
    seed: int = typer.Option(0, "--seed", help="Seed of the problem generator."),
    json_output: bool = typer.Option(False, "--json", help="Print the report as JSON."),
) -> None:
    """Allocation solvers on the arm (9 x 4) and an 8-cable CDPR (8 x 6), against cvxpy."""
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
        ("obj. diff", "right"),
    ):
        table.add_column(name, justify=justify, no_wrap=True)
    table.caption = (
        "median wall time of one solve (validation included); batched: one call for all "
        "problems, per problem; obj. diff: largest relative difference of the objective "
        "from cvxpy's (exact methods)"
    )
    for robot, entry in report["robots"].items():
        n, m = entry["shape"]
        label = f"{robot} {m}x{n}"
        for method, row in entry["methods"].items():
            diff = row.get("max_rel_objective_diff_vs_cvxpy")
            table.add_row(
                label,
                method,
                f"{row['median_us']:.1f}",
                f"{row['speedup_vs_cvxpy']:.1f}x",
                f"{row['solves_per_s']:,.0f}" if "solves_per_s" in row else "",
                f"{row['feasible']}/{entry['n_problems']}",
                "" if diff is None else f"{diff:.1e}",
            )
            label = ""
        table.add_section()
    console = Console()
    if not console.is_terminal:  # piped or captured: no terminal width to fit, use a wide one
        console = Console(width=110)
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
    plant: str = typer.Option("default", "--plant", help="default, ideal or a plant YAML file."),
    repeats: int = typer.Option(3, "--repeats", min=1, help="Runs of each; the best counts."),
    json_output: bool = typer.Option(False, "--json", help="Print the report as JSON."),
) -> None:
    """Closed-loop real-time factor of a task and its ratio to bare MuJoCo stepping."""
    import json

    from rich.markup import escape
    from rich.table import Table

    from msarm.cli.common import console, resolve_plant
    from msarm.model import load_arm
    from msarm.tasks.bench import TARGET_REAL_TIME_FACTOR, run_sim_benchmark

    result = run_sim_benchmark(load_arm(), resolve_plant(plant), task, repeats)
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
