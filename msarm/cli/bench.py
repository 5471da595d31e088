"""``msarm bench …``: speed measured as ratios against a reference run in the same process."""

from __future__ import annotations

import typer

bench_app = typer.Typer(
    help="Benchmarks: each times a fast path and its reference in the same run.",
    no_args_is_help=True,
)
