"""A robot's own CSV recordings as msarm logs (``msarm.io.table_import``, ``msarm log import``)."""

from __future__ import annotations

import json
import math
import warnings
from decimal import Decimal

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pytest
from conftest import run_msarm

from msarm.errors import InputError, LogError
from msarm.io.logs import STANDARD_UNITS, LogMetadata, RunLog, read_log, write_log
from msarm.io.table_import import LogImportWarning, log_from_columns, read_csv_log

RATE = 250.0
T = 200


def _recording(arm, seed: int = 0) -> RunLog:
    """A log of the arm in msarm's units: q, tension_motor, tension_cmd, motor_angle."""
    rng = np.random.default_rng(seed)
    n, m = len(arm.joint_names), len(arm.cable_names)
    t = np.arange(T) / RATE
    channels = {
        "q": (arm.joint_names, rng.uniform(-1.0, 1.0, (T, n))),
        "tension_motor": (arm.cable_names, rng.uniform(5.0, 80.0, (T, m))),
        "tension_cmd": (arm.cable_names, rng.uniform(5.0, 80.0, (T, m))),
        "motor_angle": (arm.cable_names, rng.uniform(-20.0, 20.0, (T, m))),
    }
    return RunLog.from_quantities(t, channels, LogMetadata.for_model(arm, RATE))


def _write_csv(path, columns: dict) -> str:
    pacsv.write_csv(pa.table({k: pa.array(v, pa.float64()) for k, v in columns.items()}), path)
    return path


def _as_a_robot_writes_it(log: RunLog) -> dict:
    """The log's columns as another robot's software might write them: time in ms, angles
    in degrees, tensions in kN, the channels of each quantity in reverse order."""
    out = {"time_ms": 1e3 * log.t}
    for name in reversed(list(log.columns)):
        values = log.columns[name]
        if name.startswith(("q.", "motor_angle.")):
            out[name] = np.degrees(values)
        elif name.startswith("tension_"):
            out[name] = values / 1e3
        elif name != "t":
            out[name] = values
    return out


UNITS = {"q": "deg", "motor_angle": "deg", "tension_motor": "kN", "tension_cmd": "kN"}


def test_a_csv_in_other_units_and_order_becomes_the_log_it_records(arm, tmp_path):
    log = _recording(arm)
    path = _write_csv(tmp_path / "run.csv", _as_a_robot_writes_it(log))
    got = read_csv_log(path, arm, units=UNITS, time_column="time_ms", time_unit="ms")
    assert sorted(got.columns) == sorted(log.columns) and next(iter(got.columns)) == "t"
    for quantity in UNITS:  # each quantity's channels in the model's order
        assert [c for c in got.columns if c.startswith(quantity + ".")] == [
            c for c in log.columns if c.startswith(quantity + ".")
        ]
    for name, values in log.columns.items():
        np.testing.assert_allclose(got.columns[name], values, rtol=1e-13, atol=0, err_msg=name)
    assert got.metadata.sample_rate_hz == RATE  # from the mean step
    assert got.metadata.model_sha256 == arm.sha256 and got.metadata.robot_model == arm.name
    assert dict(got.metadata.units) == {q: STANDARD_UNITS[q] for q in UNITS}
    assert got.metadata.extra == {
        "imported_from": "run.csv",
        "time_origin": 0.0,
        "time_origin_unit": "ms",
        "time_origin_text": "0",
    }
    # written and read back, it is a log like any other
    assert read_log(write_log(tmp_path / "run.parquet", got)) == got


def test_units_are_converted_by_their_factor_or_refused_by_name(arm):
    t = np.arange(5) / RATE
    got = log_from_columns(
        {"t": t, "q.elbow": [0.0, 90.0, 180.0, -90.0, 1.0], "cable_length.biceps": [1.0] * 5},
        arm,
        units={"q": "deg", "cable_length": "mm"},
    )
    np.testing.assert_allclose(
        got.columns["q.elbow"], [0, math.pi / 2, math.pi, -math.pi / 2, math.pi / 180]
    )
    np.testing.assert_allclose(got.columns["cable_length.biceps"], 1e-3)
    same = log_from_columns({"t": t, "tau.elbow": np.ones(5)}, arm, units={"tau": "N·m"})
    np.testing.assert_array_equal(same.columns["tau.elbow"], 1.0)
    assert same.metadata.units["tau"] == "N m"
    with pytest.raises(
        InputError,
        match=r"table: quantity 'q' in 'grad' cannot be converted to 'rad' "
        r".*known for it: rad, deg, mrad",
    ):
        log_from_columns({"t": t, "q.elbow": np.ones(5)}, arm, units={"q": "grad"})
    with pytest.raises(
        InputError,
        match=r"no unit for quantity 'pressure' .* \(--unit pressure=UNIT\), or leave its "
        r"columns out \(--skip-column pressure\.<name>\)",
    ):
        log_from_columns({"t": t, "pressure.pump": np.ones(5)}, arm)
    own = log_from_columns({"t": t, "pressure.pump": np.ones(5)}, arm, units={"pressure": "Pa"})
    assert own.metadata.units == {"pressure": "Pa"}  # a quantity msarm does not know: as given
    with pytest.raises(InputError, match=r"a unit is given for 'tension_cmd', which no column has"):
        log_from_columns({"t": t, "q.elbow": np.ones(5)}, arm, units={"tension_cmd": "kN"})


def test_channels_must_name_the_models_joints_and_cables(arm):
    t = np.arange(5) / RATE
    with pytest.raises(InputError, match=r"column 'q\.Elbow' names no joint of the model .*elbow"):
        log_from_columns({"t": t, "q.Elbow": np.ones(5)}, arm)
    with pytest.raises(InputError, match=r"column 'tension_motor\.bicep' names no cable"):
        log_from_columns({"t": t, "tension_motor.bicep": np.ones(5)}, arm)
    with pytest.raises(InputError, match=r"table: channel column 'elbow'.*--time-column"):
        log_from_columns({"t": t, "elbow": np.ones(5)}, arm)
    with pytest.raises(InputError, match=r"no time column 'time'; columns: t, q\.elbow"):
        log_from_columns({"t": t, "q.elbow": np.ones(5)}, arm, time_column="time")
    with pytest.raises(InputError, match=r"time unit 'min' is not known; expected one of s, ms"):
        log_from_columns({"t": t}, arm, time_unit="min")


def test_missing_values_are_refused_or_their_rows_left_out(arm, tmp_path):
    log = _recording(arm)
    columns = {name: values.copy() for name, values in log.columns.items()}
    columns["q.elbow"][[3, 4]] = np.nan
    columns["tension_cmd.biceps"][9] = np.inf
    with pytest.raises(
        InputError,
        match=r"table: 2 column\(s\) have missing values \(empty, NaN or infinite; 2 in "
        r"'q\.elbow' \(first at row 3\), 1 in 'tension_cmd\.biceps' \(first at row 9\); "
        r"rows count from 0, the header not counted\).*--drop-missing",
    ):
        log_from_columns(columns, arm)
    with pytest.warns(LogImportWarning, match=r"3 row\(s\) with a missing value left out"):
        got = log_from_columns(columns, arm, drop_missing=True)
    keep = np.ones(T, dtype=bool)
    keep[[3, 4, 9]] = False
    assert list(got.columns) == list(log.columns)
    for name, values in log.columns.items():
        np.testing.assert_array_equal(got.columns[name], values[keep], err_msg=name)
    # an empty CSV field is a missing value too; so is a column left empty
    csv = tmp_path / "gaps.csv"
    csv.write_text("t,q.elbow,q.shoulder_flexion\n0,1,\n0.004,,\n0.008,2,\n0.012,3,\n")
    with pytest.raises(InputError, match=r"gaps\.csv: 2 column\(s\) have missing values"):
        read_csv_log(csv, arm)
    rows = "".join(f"{0.004 * k:g},{'' if k == 3 else k}\n" for k in range(12))
    csv.write_text("t,q.elbow\n" + rows)
    with pytest.warns(LogImportWarning, match=r"gaps\.csv: 1 row\(s\)"):
        got = read_csv_log(csv, arm, drop_missing=True)
    np.testing.assert_array_equal(got.columns["q.elbow"], [k for k in range(12) if k != 3])
    assert got.metadata.sample_rate_hz == 250.0  # from the whole time column


def test_bad_files_and_times_are_named(arm, tmp_path):
    with pytest.raises(InputError, match=r"nope\.csv: no such CSV file"):
        read_csv_log(tmp_path / "nope.csv", arm)
    with pytest.raises(InputError, match=r"a folder, expected a CSV file"):
        read_csv_log(tmp_path, arm)
    words = tmp_path / "words.csv"
    words.write_text("t,q.elbow\n0,1\n1,up\n2,down\n")
    with pytest.raises(
        InputError,
        match=r"words\.csv: column 'q\.elbow' holds a value that is not a number: 'up' at "
        r"row 1 \(rows count from 0, the header not counted\)",
    ):
        read_csv_log(words, arm)
    twice = tmp_path / "twice.csv"
    twice.write_text("t,q.elbow,q.elbow\n0,1,2\n")
    with pytest.raises(InputError, match=r"column 'q\.elbow' appears more than once"):
        read_csv_log(twice, arm)
    back = tmp_path / "back.csv"
    back.write_text("t,q.elbow\n0,1\n0.004,2\n0.002,3\n")
    increasing = r"back\.csv: column 't' is not strictly increasing at row 2 .*rows count from 0"
    with pytest.raises(LogError, match=increasing):
        read_csv_log(back, arm)
    one = tmp_path / "one.csv"
    one.write_text("t,q.elbow\n0,1\n")
    with pytest.raises(InputError, match=r"sample rate cannot be taken .*\(--rate\)"):
        read_csv_log(one, arm)
    assert read_csv_log(one, arm, sample_rate_hz=100).metadata.sample_rate_hz == 100


@pytest.mark.parametrize("rows", ["", ",\n,\n"], ids=["header only", "empty rows only"])
def test_a_file_without_samples_is_refused(arm, tmp_path, rows):
    """Before, an IndexError (in _first_text) for both."""
    path = tmp_path / "h.csv"
    path.write_text(f"t,q.elbow\n{rows}")
    with pytest.raises(InputError, match=r"h\.csv: no samples \(a header and no data rows"):
        read_csv_log(path, arm)


def test_files_that_are_not_csv_text_are_named(arm, tmp_path):
    """A log (Parquet), binary data, text not in UTF-8 and a header the csv module cannot
    parse: each an InputError saying what the file is (before, a Parquet log gave a
    csv.Error, a PNG a UnicodeDecodeError, a Latin-1 value "not a number: b'1' at row 0")."""
    import gzip

    log = write_log(tmp_path / "log.parquet", _recording(arm))
    with pytest.raises(InputError, match=r"log\.parquet: a Parquet file .*msarm log check reads"):
        read_csv_log(log, arm)
    png = tmp_path / "plot.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x02")
    with pytest.raises(InputError, match=r"plot\.png: not a readable CSV file: it holds binary"):
        read_csv_log(png, arm)
    fake = tmp_path / "fake.csv.gz"
    fake.write_bytes(b"t,q.elbow\n0,1\n")
    with pytest.raises(InputError, match=r"fake\.csv\.gz: not a readable CSV file: "):
        read_csv_log(fake, arm)
    zipped = tmp_path / "log.csv.gz"
    zipped.write_bytes(gzip.compress(log.read_bytes()))
    with pytest.raises(InputError, match=r"log\.csv\.gz: a Parquet file"):
        read_csv_log(zipped, arm)
    latin = tmp_path / "latin.csv"
    latin.write_bytes(b"t,q.elb\xb0\n0,1\n")
    with pytest.raises(InputError, match=r"its header is not UTF-8 text \(byte 0xb0 at position 7"):
        read_csv_log(latin, arm)
    latin.write_bytes(b"t,q.elbow\n0,1\n0.004,\xb0\n")
    with pytest.raises(
        InputError,
        match=r"column 'q\.elbow' holds a value that is not UTF-8 text: b'\\xb0' at row 1",
    ):
        read_csv_log(latin, arm)
    long = tmp_path / "long.csv"
    long.write_text("x" * 200_000 + "\n")
    with pytest.raises(InputError, match=r"long\.csv: not a readable CSV file: its header row "):
        read_csv_log(long, arm)
    # a line may end in \r alone, as the parser reads it (the header reader refused it)
    old_mac = tmp_path / "mac.csv"
    old_mac.write_bytes(b"t,q.elbow\r0,1\r0.004,2\r")
    np.testing.assert_array_equal(read_csv_log(old_mac, arm).columns["q.elbow"], [1.0, 2.0])


def test_msarm_log_import_says_what_is_not_a_csv_file_in_one_line(
    arm, tmp_path, monkeypatch, capsys
):
    """An empty file or a log given to import: exit 2, one line, no --out folder left (an
    IndexError or a csv.Error before, with an empty --out folder)."""
    empty = tmp_path / "h.csv"
    empty.write_text("t,q.elbow\n")
    log = write_log(tmp_path / "run" / "log.parquet", _recording(arm))
    out = tmp_path / "out"
    for path, message in [(empty, "no samples"), (log, "a Parquet file")]:
        code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(path), "--out", str(out))
        assert code == 2 and err.startswith(f"msarm: error: {path}: {message}")
        assert err.count("\n") == 1 and not out.exists()
    # without --out its log would replace it: said as a log given, not as a CSV file
    code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(log))
    assert code == 2 and err.startswith(f"msarm: error: {log}: a Parquet file")


def test_the_sample_rate_is_taken_from_jittered_times_to_six_digits(arm):
    rng = np.random.default_rng(3)
    t = np.arange(400) / 1000.0 + rng.uniform(-2e-6, 2e-6, 400)
    got = log_from_columns({"t": t, "q.elbow": np.zeros(400)}, arm)
    assert abs(got.metadata.sample_rate_hz - 1000.0) < 1.0
    assert got.metadata.sample_rate_hz == float(f"{got.metadata.sample_rate_hz:.6g}")


def test_msarm_log_import_writes_logs_the_diagnosis_reads(arm, tmp_path, monkeypatch, capsys):
    log = _recording(arm)
    robot = tmp_path / "robot"
    robot.mkdir()
    csv = _write_csv(robot / "run1.csv", _as_a_robot_writes_it(log))
    columns = {k: v for k, v in log.columns.items() if not k.startswith("tension_cmd.")}
    other = _write_csv(robot / "run2.csv", columns)
    options = ["--unit", "q=deg", "--unit", "motor_angle=deg", "--unit", "tension_motor=kN"]
    options += ["--unit", "tension_cmd=kN", "--time-column", "time_ms", "--time-unit", "ms"]
    code, out, err = run_msarm(monkeypatch, capsys, "log", "import", str(csv), *options, "--json")
    assert code == 0, err
    report = json.loads(out)
    written = report["logs"][0]
    assert written["path"] == str(robot / "run1.parquet")  # next to the CSV by default
    assert written["csv"] == str(csv) and written["error"] is None
    assert written["samples"] == T and written["sample_rate_hz"] == RATE
    everything = {"joint_torque", "drive", "cable_length"}  # no q_ref in these files
    assert written["residuals"] == {k: k in everything for k in written["residuals"]}
    assert sorted(read_log(robot / "run1.parquet").columns) == sorted(log.columns)
    # a run without tension commands: the drive residual is said to be unavailable
    code, out, err = run_msarm(
        monkeypatch, capsys, "log", "import", str(other), "--out", str(tmp_path / "logs")
    )
    assert code == 0, err
    assert "no drive residual" in out and "warning:" in out
    code, out, err = run_msarm(
        monkeypatch, capsys, "log", "import", str(other), "--out", str(tmp_path / "logs"), "--json"
    )
    support = json.loads(out)["logs"][0]["residuals"]
    assert support == {k: k in everything - {"drive"} for k in support}
    assert (tmp_path / "logs" / "run2.parquet").is_file()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--unit", "q"], "--unit: expected QUANTITY=UNIT (e.g. q=deg), got 'q'"),
        (
            ["--unit", "q=deg", "--unit", "q=rad"],
            "--unit: quantity 'q' given twice ('deg' and 'rad')",
        ),
        (["--time-unit", "h"], "--time-unit: expected one of s, ms, us, ns, got 'h'"),
        (["--rate", "0"], "--rate: expected a sample rate > 0 in Hz, got 0.0"),
    ],
)
def test_msarm_log_import_checks_its_options(tmp_path, monkeypatch, capsys, args, message):
    csv = tmp_path / "run.csv"
    csv.write_text("t,q.elbow\n0,1\n0.004,2\n")
    code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(csv), *args)
    assert code == 2 and err.strip() == f"msarm: error: {message}"


def test_msarm_log_import_writes_nothing_when_one_file_is_bad(arm, tmp_path, monkeypatch, capsys):
    good, bad = tmp_path / "good.csv", tmp_path / "bad.csv"
    names = [f"q.{j}" for j in arm.joint_names] + [f"tension_motor.{c}" for c in arm.cable_names]
    rows = [",".join(["t", *names])] + [f"{t},{','.join(['1'] * len(names))}" for t in (0, 0.004)]
    good.write_text("\n".join(rows) + "\n")
    bad.write_text("t,q.knee\n0,1\n0.004,2\n")
    code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(good), str(bad))
    assert code == 2 and "bad.csv: column 'q.knee' names no joint" in err
    worse = tmp_path / "worse.csv"
    worse.write_text("t;q.elbow\n0;1\n")
    code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(bad), str(good), str(worse))
    assert code == 2 and err.count("\n") == 1  # one line, naming every file refused
    assert "2 of 3 CSV files cannot be imported (nothing written): " in err
    assert "bad.csv: column 'q.knee'" in err and "worse.csv: the header is one column" in err
    assert not (tmp_path / "good.parquet").exists()
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    for folder in "ab":
        (tmp_path / folder / "run.csv").write_text("t,q.elbow\n0,1\n0.004,2\n")
    code, _, err = run_msarm(
        monkeypatch,
        capsys,
        "log",
        "import",
        str(tmp_path / "a" / "run.csv"),
        str(tmp_path / "b" / "run.csv"),
        "--out",
        str(tmp_path / "out"),
    )
    assert code == 2 and "run.csv would all write the log" in err
    assert not (tmp_path / "out" / "run.parquet").exists()
    # a CSV without every q.<joint> and tension_motor.<cable> column is refused before any
    # log is written (before, its log was written and then refused by the check)
    partial = tmp_path / "partial.csv"
    partial.write_text("t,q.elbow\n0,1\n0.004,2\n")
    code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(partial), str(good))
    assert code == 2 and err.count("\n") == 1
    assert "partial.csv: columns 'q.shoulder_abduction', 'q.shoulder_flexion'," in err
    assert "the diagnosis needs q.<joint> for every joint and tension_motor.<cable>" in err
    assert "(nothing written)" in err
    assert not (tmp_path / "partial.parquet").exists() and not (tmp_path / "good.parquet").exists()
    # a log never replaces a file given, nor is written when another's path is a folder
    own = tmp_path / "own.parquet"
    own.write_text("t,q.elbow\n0,1\n0.004,2\n")
    code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(own))
    assert code == 2 and "would replace a CSV file given" in err
    assert own.read_text().startswith("t,q.elbow")
    (tmp_path / "b" / "run.parquet").mkdir()
    code, _, err = run_msarm(
        monkeypatch, capsys, "log", "import", str(good), str(tmp_path / "b" / "run.csv")
    )
    assert code == 2 and "run.parquet is a folder" in err
    assert not (tmp_path / "good.parquet").exists()


def test_msarm_log_import_replaces_only_a_log_it_imported(arm, tmp_path, monkeypatch, capsys):
    """A log imported before is written again; a file of another kind at a log's path (a
    simulated run's ``log.parquet``, another tool's Parquet file) is refused, nothing written
    (before, it was replaced without a word, and a run folder then held two runs' files)."""
    import pyarrow.parquet as pq

    log = _recording(arm)
    csv = _write_csv(tmp_path / "log.csv", {k: v for k, v in log.columns.items()})
    code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(csv))
    assert code == 0, err
    code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(csv))  # again
    assert code == 0, err
    run = tmp_path / "run"
    run.mkdir()
    write_log(run / "log.parquet", log)  # as msarm track writes it: no imported_from
    kept = (run / "log.parquet").read_bytes()
    code, _, err = run_msarm(monkeypatch, capsys, "log", "import", str(csv), "--out", str(run))
    assert code == 2 and err.count("\n") == 1
    assert f"{run / 'log.parquet'}: already there and not a log that msarm log import" in err
    assert (run / "log.parquet").read_bytes() == kept
    other = tmp_path / "other"
    other.mkdir()
    pq.write_table(pa.table({"raw": [1.0, 2.0]}), other / "log.parquet")
    (other / "good.parquet").write_bytes(b"not parquet")
    good = _write_csv(tmp_path / "good.csv", {k: v for k, v in log.columns.items()})
    code, _, err = run_msarm(
        monkeypatch, capsys, "log", "import", str(good), str(csv), "--out", str(other)
    )
    assert code == 2 and "good.parquet, " in err and "log.parquet: already there" in err
    assert (other / "good.parquet").read_bytes() == b"not parquet"


def test_msarm_log_check_prints_each_warning_on_one_line(arm, tmp_path, monkeypatch, capsys):
    """Piped (a log file, CI), a warning longer than the table's width stays one line."""
    log = _recording(arm)
    columns = {k: v for k, v in log.columns.items() if not k.startswith("tension_cmd.")}
    csv = _write_csv(tmp_path / "run.csv", columns)
    code, out, err = run_msarm(monkeypatch, capsys, "log", "import", str(csv))
    assert code == 0, err
    line = next(x for x in out.splitlines() if "no drive residual" in x)
    assert len(line) > 120 and line.startswith("warning: ")
    assert line.endswith("residuals are still computed")


def test_the_time_unit_and_rate_are_checked_against_the_time_column(arm):
    """A time in ms read as seconds (0.25 Hz) or seconds read as us is refused, pointing at
    the time unit; a rate given that the time contradicts is refused too."""
    t = np.arange(50) * 4.0  # 250 Hz in milliseconds
    columns = {"time_ms": t, "q.elbow": np.zeros(50)}
    with pytest.raises(
        InputError,
        match=r"a sample rate of 0\.25 Hz \(from the mean step of 4 s\) is outside "
        r"1-100000 Hz: is the time column 'time_ms' in 's'\? \(--time-unit",
    ):
        log_from_columns(columns, arm, time_column="time_ms")
    got = log_from_columns(columns, arm, time_column="time_ms", time_unit="ms")
    assert got.metadata.sample_rate_hz == 250.0
    with pytest.raises(InputError, match=r"2\.5e\+08 Hz .* in 'us'"):
        log_from_columns({"t": t / 1e3, "q.elbow": np.zeros(50)}, arm, time_unit="us")
    with pytest.raises(
        InputError,
        match=r"the sample rate given, 1000 Hz, disagrees with the time column's mean step "
        r"of 0\.004 s \(250 Hz; gaps left out\)",
    ):
        log_from_columns(columns, arm, 1000.0, time_column="time_ms", time_unit="ms")
    assert log_from_columns(columns, arm, 251.0, time_column="time_ms", time_unit="ms")
    with pytest.raises(InputError, match=r"unit is given for the time column 't'.*--time-unit"):
        log_from_columns({"t": t, "q.elbow": np.zeros(50)}, arm, units={"t": "ms"})
    backwards = {"t": t[::-1] / 1e3, "q.elbow": np.zeros(50)}
    with pytest.raises(LogError, match=r"table: column 't' is not strictly increasing at row 1"):
        log_from_columns(backwards, arm)
    # named as the file has it: its own time column, in its own unit (was 't' in seconds)
    in_ms = {"time_ms": t[::-1], "q.elbow": np.zeros(50)}
    with pytest.raises(
        LogError,
        match=r"table: column 'time_ms' is not strictly increasing at row 1 \(time_ms\[0\] = "
        r"196.0 ms, time_ms\[1\] = 192.0 ms: a step of -4 ms",
    ):
        log_from_columns(in_ms, arm, time_column="time_ms", time_unit="ms")
    # an epoch time's step is in its last digits: each time is given whole
    epoch = 1.7e9 + 0.004 * np.arange(50)
    epoch[[10, 11]] = epoch[[11, 10]]
    with pytest.raises(LogError, match=r"t\[10\] = 1700000000\.044 s, t\[11\] = 1700000000\.04 s"):
        log_from_columns({"t": epoch, "q.elbow": np.zeros(50)}, arm)


def test_a_sparse_column_is_skipped_or_left_out_when_empty(arm):
    """A sensor logged every tenth row is named in the refusal and can be skipped; with
    --drop-missing a column with no value at all is left out, not every row."""
    t = np.arange(100) / RATE
    pump = np.full(100, np.nan)
    pump[::10] = 1.0
    columns = {"t": t, "q.elbow": np.zeros(100), "pressure.pump": pump, "q_ref.elbow": np.nan * t}
    units = {"pressure": "bar"}
    with pytest.raises(InputError, match=r"'pressure\.pump': a sensor logged at a lower rate"):
        log_from_columns(columns, arm, units=units)
    got = log_from_columns(columns, arm, units={}, skip_columns=["pressure.pump", "q_ref.elbow"])
    assert list(got.columns) == ["t", "q.elbow"] and len(got) == 100
    with pytest.warns(LogImportWarning, match=r"'q_ref\.elbow' have no value in any row"):
        got = log_from_columns(columns, arm, drop_missing=True, skip_columns=["pressure.pump"])
    assert list(got.columns) == ["t", "q.elbow"] and len(got) == 100
    with pytest.raises(InputError, match=r"column 'pressure\.pumps' to skip is not in the file"):
        log_from_columns(columns, arm, skip_columns=["pressure.pumps"])


def test_a_header_that_starts_with_a_comment_mark_is_still_a_header(arm, tmp_path):
    """``rostopic echo -p`` writes ``%time,...``: a header that names the time column."""
    names = [f"q.{j}" for j in arm.joint_names] + [f"tension_motor.{c}" for c in arm.cable_names]
    rows = [",".join([f"{0.004 * k:.3f}"] + ["0.1"] * len(names)) for k in range(5)]
    path = tmp_path / "ros.csv"
    path.write_text("\n".join([",".join(["%time", *names]), *rows]) + "\n")
    log = read_csv_log(path, arm, sample_rate_hz=250, time_column="%time")
    assert len(log) == 5


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("t;q.elbow\n0;1\n", "separated by something else than commas"),
        # a European spreadsheet's export: the parser's own error named no separator
        (
            "t;q.elbow\n0,0;1,5\n0,004;2,5\n",
            r"separated by something else than commas \(semicolons, as a spreadsheet set to "
            r"decimal commas writes: export it with commas between the fields and decimal "
            r"points in the numbers\)",
        ),
        ("t\tq.elbow\n0.0\t1.5\n0.004\t2.5\n", r"separated by something else than commas;"),
        ("0,1\n0.004,2\n", r"the first row \(0, 1, \.\.\.\) holds numbers; expected a header"),
        ("t,q.elbow,\n0,1,\n", r"column 3 of the header has no name \(a trailing comma\?\)"),
        # a logger's comment lines before the header (the mis-tool data's "%..." lines): the
        # parser said "Expected 1 columns, got 2"
        (
            "%Used left spindle, tool 4\nt,q.elbow\n0,1\n",
            r"first line starts with '%' and names no time column 't', a comment",
        ),
        (
            "# written by rig 2\nt,q.elbow\n0,1\n",
            r"starts with '#' and names .* a comment .*grep -v '\^#'",
        ),
    ],
)
def test_a_header_that_is_not_one_is_named(arm, tmp_path, text, message):
    path = tmp_path / "odd.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=rf"odd\.csv: .*{message}"):
        read_csv_log(path, arm, sample_rate_hz=250)


def test_spaces_around_header_names_and_compressed_files_are_read(arm, tmp_path):
    import gzip

    from msarm.cli.log import log_paths

    path = tmp_path / "run.csv.gz"
    path.write_bytes(gzip.compress(b"t, q.elbow\n0, 1\n0.004, 2\n0.008, 3\n"))
    got = read_csv_log(path, arm)
    np.testing.assert_array_equal(got.columns["q.elbow"], [1.0, 2.0, 3.0])
    assert log_paths([path], None) == [tmp_path / "run.parquet"]


def test_epoch_times_keep_their_steps_and_a_missing_time_is_refused(arm):
    """An epoch time (1.7e9 s, or integer ms) is counted from its first sample, so that its
    rate comes out exact; a missing time is refused even with drop_missing."""
    start = 1.7e9
    t = start + np.arange(1000) / RATE
    got = log_from_columns({"t": t * 1e6, "q.elbow": np.zeros(1000)}, arm, time_unit="us")
    assert got.metadata.sample_rate_hz == RATE
    assert got.t[0] == 0.0 and got.metadata.extra["time_origin"] == t[0] * 1e6
    millis = np.round(t * 1e3)  # integer epoch milliseconds, 4 ms apart
    got = log_from_columns({"t": millis, "q.elbow": np.zeros(1000)}, arm, time_unit="ms")
    assert got.metadata.sample_rate_hz == RATE
    np.testing.assert_allclose(np.diff(got.t), 0.004, rtol=1e-12)
    t = np.arange(20) / RATE
    t[4] = np.nan
    with pytest.raises(InputError, match=r"the time column 't' has 1 missing value\(s\), the "):
        log_from_columns({"t": t, "q.elbow": np.zeros(20)}, arm, drop_missing=True)
    with pytest.raises(InputError, match=r"table: no samples"):
        log_from_columns({"t": np.array([]), "q.elbow": np.array([])}, arm)


def test_dropping_rows_may_not_change_the_time_step(arm):
    """A column logged every other row: its rows left out would make a log at half the rate,
    so that is refused (with the hint to skip the column), and the hint comes without it."""
    t = np.arange(100) / RATE
    half = np.zeros(100)
    half[1::2] = np.nan
    columns = {"t": t, "q.elbow": np.zeros(100), "q_ref.elbow": half}
    with pytest.raises(InputError, match=r"'q_ref\.elbow': a sensor logged at a lower rate"):
        log_from_columns(columns, arm)
    with pytest.raises(
        InputError,
        match=r"changes the time step from 0\.004 s to 0\.008 s \(the mean step between gaps\): "
        r"a column logged "
        r"at a lower rate\? Leave it out \(--skip-column\)",
    ):
        log_from_columns(columns, arm, drop_missing=True)


def test_the_other_conversions(arm):
    t = np.arange(3) / RATE
    got = log_from_columns(
        {
            "t": t,
            "q.elbow": [0.0, 500.0, -1000.0],
            "qd.elbow": [60.0, 0.0, -30.0],
            "activation.biceps": [0.0, 50.0, 100.0],
            "motor_torque.biceps": [1.0, 2.0, 3.0],
        },
        arm,
        units={"q": "mrad", "qd": "rpm", "activation": "%", "motor_torque": "N mm"},
    )
    np.testing.assert_allclose(got.columns["q.elbow"], [0.0, 0.5, -1.0])
    np.testing.assert_allclose(got.columns["qd.elbow"], [2 * np.pi, 0.0, -np.pi])
    np.testing.assert_allclose(got.columns["activation.biceps"], [0.0, 0.5, 1.0])
    np.testing.assert_allclose(got.columns["motor_torque.biceps"], [1e-3, 2e-3, 3e-3])


def test_time_stamps_rounded_to_whole_milliseconds_give_the_mean_step(arm):
    """300 Hz stamped floor(t * 1000) ms steps 3, 3, 4 ms: the rate is their mean (the median
    made 333.333 Hz, without a word, and refused --rate 300), and the uneven steps are said."""
    n = 3000
    columns = {"time_ms": np.floor(np.arange(n) * 1000 / 300), "q.elbow": np.zeros(n)}
    options = {"time_column": "time_ms", "time_unit": "ms"}
    with pytest.warns(
        LogImportWarning,
        match=r"table: the time column 'time_ms' steps unevenly: from 3 to 4 ms \(standard "
        r"deviation 14 % of the mean step, 3\.33\d* ms; gaps left out\).* evenly spaced at "
        r"300 Hz \(their mean; give the rate the robot was logged at with --rate\)",
    ):
        got = log_from_columns(columns, arm, **options)
    # 1 / 3.33311 ms is 300.02 Hz, which whole-ms stamps cannot tell from 300 Hz
    assert got.metadata.sample_rate_hz == 300.0
    with pytest.warns(LogImportWarning, match=r"evenly spaced at 300 Hz \(given\)"):
        given = log_from_columns(columns, arm, 300.0, **options)
    assert given.metadata.sample_rate_hz == 300.0
    with pytest.raises(
        InputError,
        match=r"the sample rate given, 333\.333 Hz, disagrees with the time column's mean step "
        r"of 0\.00333\d* s \(300 Hz; gaps left out\)",
    ):
        log_from_columns(columns, arm, 333.333, **options)
    # rounded to whole ms at 700 and 450 Hz the steps are 1, 2 and 2, 3 ms, the median the
    # shorter one (whose 1.5 times left the longer rounding out: 1000 and 485 Hz); logs of
    # one robot but of other lengths get one rate (300.03 Hz beside 300 Hz before)
    for rate, n in ((700.0, 7000), (450.0, 4500), (300.0, 1000), (300.0, 998)):
        stamps = {"time_ms": np.round(np.arange(n) * 1000 / rate), "q.elbow": np.zeros(n)}
        with pytest.warns(LogImportWarning, match="steps unevenly"):
            got = log_from_columns(stamps, arm, **options)
        assert got.metadata.sample_rate_hz == rate, (rate, n)
        with pytest.warns(LogImportWarning, match="steps unevenly"):
            log_from_columns(stamps, arm, rate, **options)  # the right rate is taken
    # a gap is left out of the mean; even steps are not warned about
    t = np.delete(np.arange(1000) / RATE, np.s_[500:520])
    with warnings.catch_warnings():
        warnings.simplefilter("error", LogImportWarning)
        got = log_from_columns({"t": t, "q.elbow": np.zeros(len(t))}, arm)
    assert got.metadata.sample_rate_hz == RATE


def test_epoch_seconds_as_text_keep_the_digits_of_their_steps(arm, tmp_path):
    """t = 1700000123.456 + k / 250 s as written: the first time is subtracted in decimals,
    then the rest made floats (parsed as floats first, the steps kept 2e-7 s of their 4 ms:
    250.003 Hz, and a diagnosis with another 250 Hz log refused the two periods)."""
    n = 5000
    stamps = [str(1700000123456 + 4 * k) for k in range(n)]  # ms, written as s
    text = [f"{stamp[:-3]}.{stamp[-3:]}" for stamp in stamps]
    path = tmp_path / "epoch.csv"
    path.write_text("t,q.elbow\n" + "".join(f"{t},{k % 7}\n" for k, t in enumerate(text)))
    got = read_csv_log(path, arm)
    assert got.metadata.sample_rate_hz == RATE
    np.testing.assert_allclose(np.diff(got.t), 1 / RATE, rtol=1e-11)
    # blank lines before the header (pyarrow skips them): the time is still read as text
    blank = tmp_path / "blank_first.csv"
    blank.write_text("\n\r\n" + path.read_text())
    np.testing.assert_array_equal(read_csv_log(blank, arm).t, got.t)
    assert got.t[0] == 0.0 and got.metadata.extra["time_origin"] == 1700000123.456
    assert got.metadata.extra["time_origin_text"] == text[0]  # every digit (ns epochs: 19)
    # text or decimals given to log_from_columns are counted exactly too
    for times in (np.array(text), [Decimal(t) for t in text]):
        same = log_from_columns({"t": times, "q.elbow": np.arange(n) % 7}, arm)
        np.testing.assert_array_equal(same.t, got.t)
    words = tmp_path / "words.csv"
    words.write_text("t,q.elbow\n0,1\n0.004,2\nlate,3\n")
    with pytest.raises(
        InputError, match=r"column 't' holds a value that is not a number: 'late' at row 2"
    ):
        read_csv_log(words, arm)


def test_degrees_given_for_some_angle_quantities_only_are_warned(arm):
    """--unit q=deg without --unit q_ref=deg read the reference in degrees as radians."""
    t = np.arange(5) / RATE
    ones = np.ones(5)
    columns = {"t": t, "q.elbow": ones, "q_ref.elbow": ones, "motor_angle.biceps": ones}
    with pytest.warns(
        LogImportWarning,
        match=r"table: q in degrees \(--unit q=deg\), but no unit is given for q_ref, "
        r"motor_angle, which are taken to be in rad: are they in degrees too \(--unit "
        r"q_ref=deg --unit motor_angle=deg\)\? Say so if they are in rad \(--unit q_ref=rad "
        r"--unit motor_angle=rad\)",
    ):
        log_from_columns(columns, arm, units={"q": "deg"})
    with warnings.catch_warnings():
        warnings.simplefilter("error", LogImportWarning)
        log_from_columns(columns, arm, units={"q": "deg", "q_ref": "deg", "motor_angle": "rad"})
        log_from_columns(columns, arm)  # all in SI


def test_a_unit_in_a_header_name_is_hinted_and_empty_rows_are_skipped(arm, tmp_path):
    """A header "q_ref.elbow [rad]" gets a hint; rows of empty fields only (",," as a
    spreadsheet leaves) are skipped, a row with data but no time still refused."""
    hint = r"a unit in the header\? Name the columns <quantity>\.<name> alone .*--unit"
    path = tmp_path / "units.csv"
    path.write_text("t,q_ref.shoulder_abduction [rad]\n0,1\n0.004,2\n")
    with pytest.raises(
        InputError, match=rf"column 'q_ref\.shoulder_abduction \[rad\]' names no joint .*{hint}"
    ):
        read_csv_log(path, arm)
    path.write_text("t,pressure (bar).pump\n0,1\n0.004,2\n")
    with pytest.raises(InputError, match=rf"'pressure \(bar\)\.pump' is not named .*{hint}"):
        read_csv_log(path, arm)
    with pytest.raises(InputError, match=r"names no joint") as refused:
        log_from_columns({"t": np.arange(2) / RATE, "q.Elbow": np.ones(2)}, arm)
    assert "a unit in the header" not in str(refused.value)
    path = tmp_path / "trailing.csv"
    path.write_text("t,q.elbow,tension_motor.biceps\n0,1,2\n,,\n0.004,2,3\n0.008,3,4\n,,\n,,\n")
    got = read_csv_log(path, arm)
    np.testing.assert_array_equal(got.t, [0.0, 0.004, 0.008])
    np.testing.assert_array_equal(got.columns["q.elbow"], [1.0, 2.0, 3.0])
    path.write_text("t,q.elbow\n0,1\n0.004,2\n,3\n,\n")
    with pytest.raises(
        InputError, match=r"the time column 't' has 1 missing value\(s\), the first"
    ):
        read_csv_log(path, arm)


def test_tensions_in_kn_imported_as_n_are_warned_with_the_unit_to_give(
    arm, tmp_path, monkeypatch, capsys
):
    """Load cells and commands both in kN, imported without --unit: before, no warning."""
    log = _recording(arm)
    columns = {k: (v / 1e3 if k.startswith("tension_") else v) for k, v in log.columns.items()}
    csv = _write_csv(tmp_path / "kn.csv", columns)
    code, out, err = run_msarm(monkeypatch, capsys, "log", "import", str(csv), "--json")
    assert code == 0, err
    (said,) = [w for w in json.loads(out)["logs"][0]["warnings"] if "below 1 N" in w]
    assert f"{tmp_path / 'kn.parquet'}: the tensions tension_motor.* (median " in said
    assert "import it again with --unit tension_motor=kN --unit tension_cmd=kN" in said
    units = ["--unit", "tension_motor=kN", "--unit", "tension_cmd=kN"]
    code, out, err = run_msarm(monkeypatch, capsys, "log", "import", str(csv), *units, "--json")
    assert code == 0, err
    assert not [w for w in json.loads(out)["logs"][0]["warnings"] if "below 1 N" in w]
