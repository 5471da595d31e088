"""Progress, caches, temporary files and default folders of the long ``msarm`` commands.

- progress goes to stderr (a bar on a terminal, a line a step elsewhere), ``--json`` too,
  and stdout carries only the result;
- ``msarm cdpr compare`` counts the steps it reports;
- an unreadable cached ``results.json`` of ``msarm bench diagnose`` is no cache (a warning);
- temporary files of a killed writer are removed, SIGTERM unwinds the command;
- the default run folders name a seed other than 0.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

from msarm.cli import app

REPO = Path(__file__).resolve().parents[1]


# --- progress on stderr, with --json too ---------------------------------------------------


def test_the_progress_bar_draws_on_stderr_and_only_on_a_terminal(monkeypatch):
    from msarm.cli.common import progress_bar

    bar = progress_bar()  # stderr captured by pytest: not a terminal, the lines show instead
    assert bar.console.stderr and bar.disable
    monkeypatch.setenv("TTY_COMPATIBLE", "1")  # as if stderr were a terminal
    bar = progress_bar()
    assert bar.console.stderr and not bar.disable


def test_bench_diagnose_json_keeps_its_progress_on_stderr(monkeypatch, tmp_path):
    import msarm.diagnose.bench as bench_module

    def fake(model, out, settings, progress=None, rescore=False):
        progress("[1/2] null-0: simulating (or reusing cached runs)")
        progress("[1/2] null-0: diagnosing")
        return {"scenarios": [], "summary": {}}

    monkeypatch.setattr(bench_module, "run_diagnosis_benchmark", fake)
    result = CliRunner().invoke(app, ["bench", "diagnose", "--out", str(tmp_path), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout) == {"scenarios": [], "summary": {}}
    assert result.stderr.splitlines() == [
        "bench diagnose [1]: [1/2] null-0: simulating (or reusing cached runs)",
        "bench diagnose [2]: [1/2] null-0: diagnosing",
    ]


def test_train_json_keeps_its_progress_on_stderr(monkeypatch):
    import msarm.compensation.pipeline as pipeline

    def fake(arm, recipe, plant, resume, on_run, on_epoch, on_round, on_sheath):
        on_run(1, 2, False)
        on_run(2, 2, True)
        on_epoch(1, 20, 0.75, 0.5)  # every epoch has its line (early stopping ends rounds
        on_epoch(2, 20, 0.5, 0.25)  # after a few: a line every tenth left them silent)
        return pipeline.TrainingReport(
            checkpoint=Path("runs/compensator/compensator.pt"),
            split={"train": [0], "validation": [1], "test": [2]},
            samples={"train": 1, "validation": 1, "test": 1},
            collect_time_s=1.0,
            train_time_s=2.0,
            epochs=(20, 10),
            test_rmse=(0.1,),
            test_baseline_rmse=(0.2,),
            test_r2=(0.5,),
        )

    monkeypatch.setattr(pipeline, "train_compensator", fake)
    recipe = REPO / "training" / "compensator.yaml"
    result = CliRunner().invoke(app, ["train", "--config", str(recipe), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["epochs_run"] == 20  # stdout: the JSON alone
    # (the note that numba compiles first comes only while its kernels are not cached)
    lines = [line for line in result.stderr.splitlines() if "numba compiles" not in line]
    assert lines == [
        "train [1]: run 1/2 collected",
        "train [2]: run 2/2 collected (reused)",
        "train [3]: epoch 1: train 0.7500, validation 0.5000",
        "train [4]: epoch 2: train 0.5000, validation 0.2500",
    ]


def test_train_outside_the_repository_says_it_runs_the_recipe_defaults(monkeypatch, tmp_path):
    import msarm.compensation.pipeline as pipeline
    from msarm.compensation.pipeline import CompensatorRecipe

    seen = []

    def fake(arm, recipe, plant, **callbacks):
        seen.append(recipe)
        raise SystemExit(0)  # the recipe is all this test looks at

    monkeypatch.setattr(pipeline, "train_compensator", fake)
    monkeypatch.chdir(tmp_path)  # no training/compensator.yaml here
    result = CliRunner().invoke(app, ["train"])
    assert seen == [CompensatorRecipe()], result.output
    assert "msarm train: no training/compensator.yaml here: the recipe's default values" in (
        result.stderr
    )
    result = CliRunner().invoke(app, ["train", "--config", "mine.yaml"])
    assert result.exit_code != 0 and "mine.yaml: recipe file not found" in str(result.exception)


def test_diagnose_prints_a_line_a_step_where_no_spinner_shows(monkeypatch, tmp_path):
    import msarm.cli.diagnose as command
    import msarm.diagnose.select as select

    answer = SimpleNamespace(as_dict=lambda: {"selected": []}, groups=("joint",))
    answer.with_where = lambda breakdowns, skipped: answer  # --json: with the where section

    def fake(model, train, held, progress=None, **options):
        progress(f"reading {len(train) + len(held)} log(s)")
        progress("step 1: screening 3 candidate(s)")
        return answer

    monkeypatch.setattr(select, "diagnose", fake)
    monkeypatch.setattr(command, "where_breakdowns", lambda *args, **kwargs: ({}, {}))
    logs = [tmp_path / f"run{k}.parquet" for k in range(2)]  # never read by the fake
    for log in logs:
        log.write_bytes(log.name.encode())
    for extra in ([], ["--json"]):
        result = CliRunner().invoke(app, ["diagnose", *map(str, logs), *extra])
        if extra:
            assert result.exit_code == 0, result.output
            assert json.loads(result.stdout) == {"selected": []}
        assert result.stderr.splitlines()[:2] == [
            "diagnose [1]: reading 2 log(s)",
            "diagnose [2]: step 1: screening 3 candidate(s)",
        ]


# --- cdpr compare: the steps counted are the steps reported -----------------------------


def test_cdpr_compare_counts_the_steps_it_reports():
    from msarm.tasks.cdpr_compare import REPEATABILITY_TESTS, _grid, progress_steps

    grid = len(_grid())
    assert progress_steps(0) == progress_steps(1) == grid
    assert progress_steps(2) == grid + len(REPEATABILITY_TESTS)
    assert progress_steps(15) == grid + 14 * len(REPEATABILITY_TESTS)  # 81 runs, as timed
    assert progress_steps(3, tests=["11", "12"]) == 2 + 2  # one repeated test


@pytest.mark.usefixtures("short_cdpr_trajectories")
def test_cdpr_compare_json_progress_ends_at_its_total(monkeypatch, tmp_path):
    import msarm.tasks.cdpr_compare as cdpr_compare

    monkeypatch.setattr(cdpr_compare, "_grid", lambda: [("11", "ikc", "triangle-12", {})])
    monkeypatch.setattr(cdpr_compare, "plot_sensitivity", lambda model, path: path)
    out = tmp_path / "grid"
    args = ["cdpr", "compare", "--repeats", "3", "--out", str(out), "--json"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["repeats"] == 3
    assert result.stderr.splitlines() == [
        "cdpr compare [1/3]: test 11: ikc, triangle-12",
        "cdpr compare [2/3]: repeatability 11: run 2/3",
        "cdpr compare [3/3]: repeatability 11: run 3/3",
    ]


# --- bench diagnose: an unreadable cache is no cache --------------------------------------


def _answer() -> dict:
    gap = {"joint": 1.0}
    return {
        "msarm": {
            "names": [],
            "confidence": [],
            "parameters": {},
            "gap_before": gap,
            "gap_after": gap,
            "seconds": 0.1,
            "selection_seconds": 0.1,
        },
        "sindy": {
            "names": [],
            "contributions": {},
            "gap_before": gap,
            "gap_after": gap,
            "seconds": 0.1,
        },
        "load_seconds": 0.0,
    }


@pytest.fixture
def fake_bench(monkeypatch):
    """The benchmark with two null scenarios, no simulation and a counted fake diagnosis."""
    import msarm.diagnose.bench as bench_module

    scenarios = [SimpleNamespace(name=f"null-{k}", effects=(), parameters={}) for k in range(2)]
    diagnosed: list[str] = []

    def diagnose(model, train, held, settings):
        diagnosed.append(train[0])
        return _answer()

    monkeypatch.setattr(bench_module, "_scenarios", lambda settings: scenarios)
    monkeypatch.setattr(bench_module, "scenario_tasks", lambda *args: ([], []))
    monkeypatch.setattr(
        bench_module,
        "generate_logs",
        lambda model, scenario, train, held, root: ([scenario.name], [scenario.name]),
    )
    monkeypatch.setattr(bench_module, "_diagnose_scenario", diagnose)
    monkeypatch.setattr(bench_module, "plot_benchmark", lambda report, path: path)
    return diagnosed


@pytest.mark.parametrize(
    "content, why",
    [
        (b'{"settings": {"seed": 0}, "scenarios": [{"scen', "not JSON"),
        (b"\xff\xfe\x00garbage", "not UTF-8"),
        (b"[1, 2]", "a JSON list, expected an object"),
        (b'{"scenarios": [{"scenario": "null-0"}]}', "lacks effects, msarm, sindy"),
    ],
)
def test_an_unreadable_cached_result_is_scored_again_with_a_warning(
    fake_bench, tmp_path, content, why
):
    from msarm.diagnose.bench import BenchCacheWarning, BenchSettings, run_diagnosis_benchmark

    model = SimpleNamespace(sha256="0" * 64)
    (tmp_path / "results.json").write_bytes(content)
    with pytest.warns(BenchCacheWarning, match=why) as caught:
        report = run_diagnosis_benchmark(model, tmp_path, BenchSettings())
    assert str(tmp_path / "results.json") in str(caught[0].message)
    assert fake_bench == ["null-0", "null-1"]  # both rescored (from their cached logs)
    saved = json.loads((tmp_path / "results.json").read_text())  # written anew
    assert saved["model_sha256"] == model.sha256
    assert [r["scenario"] for r in saved["scenarios"]] == ["null-0", "null-1"]
    assert report["summary"]["msarm"]["false_alarms"] == 0


def test_a_cached_result_is_reused_for_the_same_model_only(fake_bench, tmp_path, recwarn):
    from msarm.diagnose.bench import BenchSettings, run_diagnosis_benchmark

    model = SimpleNamespace(sha256="0" * 64)
    run_diagnosis_benchmark(model, tmp_path, BenchSettings())
    assert len(fake_bench) == 2
    run_diagnosis_benchmark(model, tmp_path, BenchSettings())
    assert len(fake_bench) == 2  # reused
    run_diagnosis_benchmark(SimpleNamespace(sha256="1" * 64), tmp_path, BenchSettings())
    assert len(fake_bench) == 4  # another model: scored again
    assert not [w for w in recwarn if "cached results" in str(w.message)]
    assert not [w for w in recwarn if "other settings" in str(w.message)]


def test_results_of_other_settings_are_replaced_with_a_warning(fake_bench, tmp_path):
    """A subset run (other effects, no pairs) replaced a full run's results.json silently."""
    from dataclasses import replace

    from msarm.diagnose.bench import BenchCacheWarning, BenchSettings, run_diagnosis_benchmark

    model = SimpleNamespace(sha256="0" * 64)
    run_diagnosis_benchmark(model, tmp_path, BenchSettings())
    other = replace(BenchSettings(), n_boot=3)
    with pytest.warns(
        BenchCacheWarning,
        match=r"results\.json: holds the results of other settings \(n_boot differs\); this "
        "run's results replace them",
    ):
        run_diagnosis_benchmark(model, tmp_path, other)
    assert len(fake_bench) == 4


def test_the_cli_says_which_cache_it_ignores_in_one_line(fake_bench, tmp_path, monkeypatch, capsys):
    from msarm.cli import main

    (tmp_path / "results.json").write_text("{truncated")
    monkeypatch.setattr(sys, "argv", ["msarm", "bench", "diagnose", "--out", str(tmp_path)])
    main()
    err = capsys.readouterr().err
    warning = [line for line in err.splitlines() if line.startswith("msarm: warning:")]
    assert len(warning) == 1
    assert f"{tmp_path / 'results.json'}: cached results unusable (not JSON" in warning[0]
    assert "Traceback" not in err


# --- temporary files -----------------------------------------------------------------------


def test_a_write_removes_stale_temp_files_of_its_own_target_only(tmp_path):
    from msarm.io.atomic import STALE_TEMP_AGE_S, write_json_atomic

    old = time.time() - STALE_TEMP_AGE_S - 5
    names = {
        ".a.json.k2x9_q0z.tmp": old,  # a's, left by a killed writer: removed
        ".a.json.fresh123.tmp": time.time(),  # a's, perhaps a live writer's: kept
        ".a.json.bak.k2x9_q0z.tmp": old,  # of a.json.bak: kept
        ".b.json.k2x9_q0z.tmp": old,  # of b.json: kept
        ".a.json.k2x9_q0z.tmp.keep": old,  # not a temporary file: kept
    }
    for name, mtime in names.items():
        (tmp_path / name).write_text("partial")
        os.utime(tmp_path / name, (mtime, mtime))
    write_json_atomic(tmp_path / "a.json", {"x": 1})
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted({*names} - {".a.json.k2x9_q0z.tmp"} | {"a.json"})


def test_a_reused_folder_loses_every_stale_temp_file(tmp_path):
    """A finished run reused by the next command is never written again, so a killed
    writer's temporary file in it stayed for good (a review: 800 kB after two reruns)."""
    from msarm.io.atomic import STALE_TEMP_AGE_S, remove_stale_temps_in

    old = time.time() - STALE_TEMP_AGE_S - 5
    names = {
        ".log.truth.parquet.b9ax66sk.tmp": old,  # removed
        ".metrics.json.k2x9_q0z.tmp": old,  # removed
        ".log.parquet.fresh123.tmp": time.time(),  # perhaps a live writer's: kept
        "log.parquet": old,  # the run itself: kept
        ".hidden.tmp.keep": old,  # not a temporary file: kept
    }
    for name, mtime in names.items():
        (tmp_path / name).write_text("x")
        os.utime(tmp_path / name, (mtime, mtime))
    removed = remove_stale_temps_in(tmp_path)
    assert sorted(p.name for p in removed) == [
        ".log.truth.parquet.b9ax66sk.tmp",
        ".metrics.json.k2x9_q0z.tmp",
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [".log.parquet.fresh123.tmp", "log.parquet", ".hidden.tmp.keep"]
    )


def test_sigterm_unwinds_the_command_and_removes_its_temp_file(monkeypatch, tmp_path, capsys):
    import warnings

    import mujoco

    import msarm.cli
    from msarm.io.atomic import atomic_path

    before = signal.getsignal(signal.SIGTERM)
    shown_before, mujoco_before = warnings.showwarning, mujoco.get_mju_user_warning()

    def killed(**kwargs):
        with atomic_path(tmp_path / "checkpoint.pt") as tmp:
            tmp.write_bytes(b"half a checkpoint")
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(10)  # interrupted by the handler
        raise AssertionError("not terminated")

    monkeypatch.setattr(msarm.cli, "app", killed)
    monkeypatch.setattr(sys, "argv", ["msarm", "train"])
    start = time.perf_counter()
    with pytest.raises(SystemExit) as exit_:
        msarm.cli.main()
    assert time.perf_counter() - start < 5
    assert exit_.value.code == 128 + signal.SIGTERM
    assert capsys.readouterr().err == "msarm: terminated\n"
    assert list(tmp_path.iterdir()) == []  # neither the target nor its temporary file
    assert signal.getsignal(signal.SIGTERM) == before  # the handler is given back
    # and so are the warnings' and MuJoCo's (msarm's stayed installed after main returned)
    assert warnings.showwarning is shown_before
    assert mujoco.get_mju_user_warning() is mujoco_before


def test_a_sigterm_that_ipopt_swallows_still_ends_the_fit(monkeypatch):
    """IPOPT (through casadi) runs the SIGTERM handler itself while it iterates, catches its
    exception and returns early, as if it had failed to converge: the fit raises the
    termination again rather than go on with a half-finished answer (until 2026-11-29 a
    SIGTERM during `msarm train`'s sheath fit was ignored and a wrong mu cached)."""
    import numpy as np
    from conftest import load_arm
    from test_diagnose_effects import _make_signals

    from msarm import interrupts
    from msarm.diagnose import fitting
    from msarm.diagnose.effects import StribeckFriction

    arm = load_arm()
    signals = _make_signals(arm, seed=5)
    effect = StribeckFriction()
    residual = np.asarray(effect.torque(signals, effect.initial_guess(signals, None) + 0.1))
    built = fitting._NonlinearProblem.__init__

    def build(self, *args, **kwargs):
        built(self, *args, **kwargs)
        solver = self.solver

        class Swallowing:  # as casadi does: the handler runs inside, its exception is caught
            def __call__(self, **kwargs):
                try:
                    interrupts.on_sigterm(signal.SIGTERM, None)
                except interrupts.Terminated:
                    pass
                return solver(**kwargs)

            def stats(self):
                return solver.stats()

        self.solver = Swallowing()

    before = signal.getsignal(signal.SIGTERM)
    try:
        with monkeypatch.context() as patch:
            patch.setattr(fitting._NonlinearProblem, "__init__", build)
            with pytest.raises(interrupts.Terminated) as exit_:
                fitting.fit(effect, signals, residual)
        assert exit_.value.code == 128 + signal.SIGTERM
    finally:
        interrupts.clear()
        signal.signal(signal.SIGTERM, before)
    assert fitting.fit(effect, signals, residual).success  # cleared: fits again


# --- default folders name the seed -----------------------------------------------------------


def test_track_s_default_folder_names_a_seed_other_than_0(monkeypatch, tmp_path):
    import msarm.tasks.track as track_module
    from msarm.cli.track import default_folder

    assert default_folder("table1-1", "ideal", 0, False) == Path("runs/track-table1-1-ideal")
    assert default_folder("table1-1", "ideal", 2, True) == Path("runs/track-table1-1-ideal-s2-ff")

    def fake(arm, task, settings, out_dir, feedforward=None, progress=None):
        progress(1.0)
        return SimpleNamespace(
            metrics=SimpleNamespace(as_dict=lambda: {"seed": settings.seed}),
            files={"log": out_dir / "log.parquet"},
            run=SimpleNamespace(error=None),
        )

    monkeypatch.setattr(track_module, "track", fake)
    monkeypatch.chdir(tmp_path)
    for seed, folder in ((0, "track-table1-1-ideal"), (1, "track-table1-1-ideal-s1")):
        args = ["track", "--task", "table1-1", "--plant", "ideal", "--seed", str(seed), "--json"]
        # seed 1 as on a terminal: the bar is drawn, on stderr, the JSON alone on stdout
        result = CliRunner().invoke(app, args, env={"TTY_COMPATIBLE": "1" if seed else "0"})
        assert result.exit_code == 0, result.output
        payload = json.loads(result.stdout)
        assert payload["seed"] == seed
        assert payload["files"]["log"] == str(Path("runs") / folder / "log.parquet")
        assert (tmp_path / "runs" / folder).is_dir()


@pytest.mark.usefixtures("short_cdpr_trajectories")
def test_cdpr_run_s_default_folder_names_a_seed_other_than_0(monkeypatch, tmp_path):
    from msarm.cli.cdpr import default_run_folder
    from msarm.plant.cdpr_config import DEFAULT_CDPR_PLANT, IDEAL_CDPR_PLANT

    assert default_run_folder("hc-e", "triangle-12", DEFAULT_CDPR_PLANT, 0, {}) == Path(
        "runs/cdpr-hc-e-triangle-12"
    )
    assert default_run_folder(
        "hc-e", "triangle-12", IDEAL_CDPR_PLANT, 2, {"fe_feedforward": True}
    ) == Path("runs/cdpr-hc-e-triangle-12-ideal-s2-fe_feedforward=true")
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["cdpr", "run", "--controller", "ikc", "--seed", "1"])
    assert result.exit_code == 0, result.output
    folder = tmp_path / "runs" / "cdpr-ikc-triangle-12-s1"
    assert (folder / "log.parquet").is_file()
    assert not (tmp_path / "runs" / "cdpr-ikc-triangle-12").exists()


def test_a_sigterm_a_callback_swallowed_still_ends_the_command(monkeypatch, capsys, tmp_path):
    """Python ignores an exception raised in a garbage-collection or weakref callback: a
    SIGTERM that arrived there (matplotlib's plots, 3 of 27 tries in a review) let the
    command run on and exit 0. The command's next atomic write, its next progress step and
    main() after the command now raise it again: 143, 'msarm: terminated'."""
    import signal
    import sys

    import msarm.cli as cli
    from msarm import interrupts
    from msarm.cli import common, main
    from msarm.io.atomic import write_json_atomic

    def swallowed():
        try:
            interrupts.on_sigterm(signal.SIGTERM, None)
        except interrupts.Terminated:
            pass  # as "Exception ignored in <function WeakSet._remove ...>"

    before = signal.getsignal(signal.SIGTERM)
    try:
        swallowed()
        with pytest.raises(interrupts.Terminated):  # no result committed after it
            write_json_atomic(tmp_path / "result.json", {})
        assert not list(tmp_path.iterdir())  # nor its temporary file left
        with pytest.raises(interrupts.Terminated):
            common.progress_lines("test")("a step")
    finally:
        interrupts.clear()
        signal.signal(signal.SIGTERM, before)

    def command(*args, **kwargs):  # a command whose SIGTERM was swallowed, then returns
        swallowed()

    monkeypatch.setattr(sys, "argv", ["msarm", "arm"])
    monkeypatch.setattr(cli, "app", command)
    with pytest.raises(SystemExit) as exit_:
        main()
    assert exit_.value.code == 128 + signal.SIGTERM
    assert "msarm: terminated" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGTERM) == before  # main() gave the handler back


def test_an_interrupted_write_leaves_no_empty_folder_of_its_own(tmp_path):
    """A SIGTERM between a run folder's creation and its first file left it empty (a
    review: `run-1001/` after `msarm train`); a folder that was there stays."""
    from msarm import interrupts
    from msarm.io.atomic import folder_for_writing

    with pytest.raises(interrupts.Terminated):
        with folder_for_writing(tmp_path / "runs" / "run-1001"):
            raise interrupts.Terminated(143)
    assert not (tmp_path / "runs" / "run-1001").exists()
    (tmp_path / "kept").mkdir()
    with pytest.raises(interrupts.Terminated):
        with folder_for_writing(tmp_path / "kept"):
            raise interrupts.Terminated(143)
    assert (tmp_path / "kept").is_dir()  # not this call's: left as it was
    with folder_for_writing(tmp_path / "done") as folder:
        (folder / "log.parquet").write_text("x")
    assert (tmp_path / "done" / "log.parquet").is_file()
