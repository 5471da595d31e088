"""msarm.io.logs: the Parquet log format, its checks, and the ground-truth sidecar."""

from __future__ import annotations

import builtins
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import msarm.io.logs as logs
from msarm.errors import InputError, LogError
from msarm.io.logs import (
    STANDARD_UNITS,
    LogMetadata,
    RunLog,
    nominal_step,
    read_log,
    read_log_with_missing_values,
    read_sidecar,
    sidecar_path,
    write_log,
    write_sidecar,
)

JOINTS = ("shoulder_abduction", "shoulder_flexion", "shoulder_rotation", "elbow")
CABLES = ("biceps", "triceps")
T = 50


def _metadata(**changes) -> LogMetadata:
    kwargs = dict(
        robot_model="msarm_arm",
        model_sha256="ab" * 32,
        sample_rate_hz=250,
        units={"q": "rad", "tension_motor": "N"},
        controller_config={"kp": (60.0, 1.0 / 3.0), "solver": "fast", "nested": {"a": None}},
        extra={"task": "table1-1", "seed": 7},
    )
    kwargs.update(changes)
    return LogMetadata(**kwargs)


def _log(seed: int = 0) -> RunLog:
    rng = np.random.default_rng(seed)
    t = np.arange(T) / 250.0
    q = rng.normal(size=(T, len(JOINTS)))
    q[0, 0] = -0.0  # the sign of zero survives
    q[1, 0] = 5e-324  # and subnormals
    tension = rng.uniform(0, 100, size=(T, len(CABLES)))
    return RunLog.from_quantities(
        t, {"q": (JOINTS, q), "tension_motor": (CABLES, tension)}, _metadata()
    )


def _write_raw(path: Path, columns: dict, kv: dict) -> Path:
    table = pa.table({k: pa.array(v) for k, v in columns.items()})
    pq.write_table(table.replace_schema_metadata(kv), path)
    return path


def _kv(**changes) -> dict[str, str]:
    kv = _metadata().to_kv()
    for key, value in changes.items():
        if value is None:
            kv.pop("msarm." + key)
        else:
            kv["msarm." + key] = value
    return kv


def test_round_trip_is_bit_identical_with_metadata(tmp_path):
    log = _log()
    path = write_log(tmp_path / "run.parquet", log)
    back = read_log(path)
    assert back == log
    assert list(back.columns) == list(log.columns)
    for name, col in log.columns.items():
        assert back.columns[name].dtype == np.float64
        assert back.columns[name].tobytes() == col.tobytes()
    assert back.metadata == log.metadata
    assert back.metadata.controller_config["kp"] == [60.0, 1.0 / 3.0]
    assert back.metadata.sample_rate_hz == 250.0
    assert [p.name for p in tmp_path.iterdir()] == ["run.parquet"]  # no temp file left
    kv = pq.read_schema(path).metadata
    assert json.loads(kv[b"msarm.schema_version"]) == 1
    assert json.loads(kv[b"msarm.robot_model"]) == "msarm_arm"
    assert json.loads(kv[b"msarm.units"]) == {"q": "rad", "tension_motor": "N"}
    assert pq.read_schema(path).names[0] == "t"


def test_helpers_names_matrix_quantities_duration_len():
    log = _log()
    assert log.quantities() == ["q", "tension_motor"]
    assert log.names("q") == list(JOINTS)
    assert log.names("tension_motor") == list(CABLES)
    assert log.matrix("q").shape == (T, 4)
    np.testing.assert_array_equal(
        log.matrix("q", ["elbow", "shoulder_abduction"]),
        np.column_stack([log.columns["q.elbow"], log.columns["q.shoulder_abduction"]]),
    )
    assert len(log) == T
    assert log.duration == pytest.approx((T - 1) / 250.0)
    with pytest.raises(InputError, match="quantities: q, tension_motor"):
        log.names("qd")
    with pytest.raises(InputError, match=r"no channel q.wrist"):
        log.matrix("q", ["wrist"])


def test_equality_is_bitwise():
    a, b = _log(), _log()
    assert a == b
    cols = dict(b.columns)
    cols["q.elbow"] = cols["q.elbow"].copy()
    cols["q.elbow"][3] = np.nextafter(cols["q.elbow"][3], np.inf)
    assert RunLog(cols, b.metadata) != a


def test_for_model_uses_name_hash_and_standard_units(arm):
    md = LogMetadata.for_model(arm, 250.0, controller_config={"kp": [1.0]})
    assert md.robot_model == arm.name and md.model_sha256 == arm.sha256
    assert md.units == dict(STANDARD_UNITS)


def test_standard_units_cover_what_msarm_logs(arm):
    """One source of units: the runner's log and truth quantities are in the defaults."""
    from msarm.control import MuscleSpaceController
    from msarm.io.logs import STANDARD_TRUTH_UNITS
    from msarm.plant import IDEAL_PLANT, ArmPlant
    from msarm.tasks.runner import LOG_UNITS, TRUTH_UNITS, run_tracking
    from msarm.tasks.trajectories import hold_then_move

    assert LOG_UNITS == {key: STANDARD_UNITS[key] for key in LOG_UNITS}
    assert TRUTH_UNITS == dict(STANDARD_TRUTH_UNITS)
    home = np.array([0.0, 0.0, 0.0, -0.2])
    task = hold_then_move("short", home, home + 0.05, wait=0.02, move_time=0.02, duration=0.05)
    run = run_tracking(ArmPlant(arm, IDEAL_PLANT), MuscleSpaceController(arm), task)
    log = RunLog(run.columns, LogMetadata.for_model(arm, 250.0))
    assert {"qdot_est", "tau_cmd"} <= set(log.quantities())


def test_sample_rate_accepts_numpy_numbers():
    assert _metadata(sample_rate_hz=np.int64(250)).sample_rate_hz == 250.0
    assert type(_metadata(sample_rate_hz=np.float32(250)).sample_rate_hz) is float
    for bad in (True, "250", None):
        with pytest.raises(InputError, match="sample_rate_hz must be a real number"):
            _metadata(sample_rate_hz=bad)


@pytest.mark.parametrize(
    ("field", "value", "key"),
    [
        ("extra", {"a": float("nan")}, r"extra\['a'\]"),
        ("extra", {"a": [1.0, np.inf]}, r"extra\['a'\]\[1\]"),
        ("controller_config", {"pid": {"ti": -np.inf}}, r"controller_config\['pid'\]\['ti'\]"),
    ],
)
def test_non_finite_metadata_is_refused_with_its_key(field, value, key):
    """Every metadata value is standard JSON: no NaN/Infinity tokens in the file."""
    with pytest.raises(InputError, match=key + " is not finite; metadata is standard JSON"):
        _metadata(**{field: value})


def test_write_under_a_file_names_the_path(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InputError, match=rf"cannot write .*run.parquet: {blocker} is a file"):
        write_log(blocker / "sub" / "run.parquet", _log(0))
    with pytest.raises(InputError, match="it is a folder, expected a file path"):
        write_log(tmp_path, _log(0))


def test_missing_file_and_not_parquet(tmp_path):
    with pytest.raises(LogError, match=r"nope\.parquet: file not found"):
        read_log(tmp_path / "nope.parquet")
    bad = tmp_path / "bad.parquet"
    bad.write_text("t,q.elbow\n0,1\n")
    with pytest.raises(LogError, match=r"bad\.parquet: not a readable Parquet file"):
        read_log(bad)


def test_wrong_schema_version(tmp_path):
    path = _write_raw(tmp_path / "v2.parquet", {"t": [0.0, 1.0]}, _kv(schema_version="2"))
    with pytest.raises(LogError, match=r"v2\.parquet: log schema version 2 is not supported"):
        read_log(path)
    path = _write_raw(tmp_path / "v0.parquet", {"t": [0.0, 1.0]}, _kv(schema_version=None))
    with pytest.raises(LogError, match=r"v0\.parquet: metadata key 'msarm.schema_version'"):
        read_log(path)


def test_a_schema_version_that_only_looks_like_1_is_named_as_what_it_is(tmp_path):
    for name, stored, got in (
        ("string", '"1"', "the string '1'"),
        ("float", "1.0", "the number 1.0"),
        ("bool", "true", "the boolean true"),
    ):
        path = _write_raw(
            tmp_path / f"{name}.parquet", {"t": [0.0, 1.0]}, _kv(schema_version=stored)
        )
        with pytest.raises(
            LogError,
            match=rf"{name}\.parquet: log schema version: expected the JSON integer 1, got {got}$",
        ):
            read_log(path)
    path = _write_raw(tmp_path / "v3.parquet", {"t": [0.0, 1.0]}, _kv(schema_version='"3"'))
    with pytest.raises(LogError, match=r"log schema version '3' is not supported \(expected 1\)"):
        read_log(path)


def test_missing_t_column(tmp_path):
    path = _write_raw(tmp_path / "no_t.parquet", {"q.elbow": [0.0, 1.0]}, _kv())
    with pytest.raises(LogError, match=r"no_t\.parquet: no time column 't'; columns: q.elbow"):
        read_log(path)


def test_non_increasing_t_names_row(tmp_path):
    path = _write_raw(
        tmp_path / "dt.parquet", {"t": [0.0, 0.1, 0.2, 0.2], "q.elbow": [0.0] * 4}, _kv()
    )
    with pytest.raises(LogError, match=r"dt\.parquet: column 't' is not strictly .* row 3"):
        read_log(path)


def test_nan_names_column_and_first_row(tmp_path):
    q = [0.0, 1.0, np.nan, np.nan]
    path = _write_raw(tmp_path / "nan.parquet", {"t": [0.0, 1.0, 2.0, 3.0], "q.elbow": q}, _kv())
    with pytest.raises(LogError, match=r"nan\.parquet: column 'q.elbow' has nan .* row 2"):
        read_log(path)


def test_missing_values_are_read_for_a_reader_that_works_around_them(tmp_path):
    """``read_log_with_missing_values`` keeps NaN and infinities and reads a null as NaN; the
    rest of the schema is checked as by ``read_log``, and ``t`` may hold no missing value."""
    columns = {"t": [0.0, 1.0, 2.0, 3.0], "q.elbow": [0.0, None, np.nan, -np.inf]}
    path = _write_raw(tmp_path / "holes.parquet", columns, _kv())
    got, metadata = read_log_with_missing_values(path)
    assert list(got) == ["t", "q.elbow"] and metadata == _metadata()
    np.testing.assert_array_equal(got["q.elbow"], [0.0, np.nan, np.nan, -np.inf])
    assert got["q.elbow"].dtype == np.float64
    with pytest.raises(LogError, match=r"holes\.parquet: column 'q.elbow' has a null at row 1"):
        read_log(path)
    clean = write_log(tmp_path / "clean.parquet", _log())
    got, metadata = read_log_with_missing_values(clean)
    assert RunLog(got, metadata) == read_log(clean)
    for value, message in ((None, "a null at row 2"), (np.nan, r"nan \(not finite\) at row 2")):
        times = _write_raw(
            tmp_path / "t.parquet", {"t": [0.0, 1.0, value], "q.elbow": [0.0] * 3}, _kv()
        )
        with pytest.raises(LogError, match=rf"t\.parquet: column 't' has {message}"):
            read_log_with_missing_values(times)
    unit = _write_raw(
        tmp_path / "unit.parquet", {"t": [0.0, 1.0], "qd.elbow": [1.0, np.nan]}, _kv()
    )
    with pytest.raises(LogError, match=r"unit\.parquet: no unit for quantity 'qd'"):
        read_log_with_missing_values(unit)


def test_wrong_dtype_null_and_unit_errors_name_the_column(tmp_path):
    path = _write_raw(tmp_path / "f32.parquet", {"t": [0.0, 1.0]}, _kv())
    table = pq.read_table(path)
    table = table.append_column("q.elbow", pa.array([1.0, 2.0], type=pa.float32()))
    pq.write_table(table, path)
    with pytest.raises(LogError, match=r"f32\.parquet: column 'q.elbow' has type float"):
        read_log(path)
    path = _write_raw(tmp_path / "null.parquet", {"t": [0.0, 1.0], "q.elbow": [1.0, None]}, _kv())
    with pytest.raises(LogError, match=r"null\.parquet: column 'q.elbow' has a null at row 1"):
        read_log(path)
    path = _write_raw(tmp_path / "unit.parquet", {"t": [0.0, 1.0], "qd.elbow": [1.0, 2.0]}, _kv())
    with pytest.raises(LogError, match=r"unit\.parquet: no unit for quantity 'qd'"):
        read_log(path)
    path = _write_raw(tmp_path / "name.parquet", {"t": [0.0, 1.0], "elbow": [1.0, 2.0]}, _kv())
    with pytest.raises(LogError, match=r"name\.parquet: channel column 'elbow'"):
        read_log(path)


def test_bad_metadata_is_named(tmp_path):
    path = _write_raw(tmp_path / "m.parquet", {"t": [0.0, 1.0]}, _kv(sample_rate_hz="-3"))
    with pytest.raises(LogError, match=r"m\.parquet: metadata: sample_rate_hz"):
        read_log(path)
    path = _write_raw(tmp_path / "j.parquet", {"t": [0.0, 1.0]}, _kv(units="{q: rad}"))
    with pytest.raises(LogError, match=r"j\.parquet: metadata key 'msarm.units' is not valid"):
        read_log(path)
    path = _write_raw(tmp_path / "u.parquet", {"t": [0.0, 1.0]}, _kv(secret="1"))
    with pytest.raises(LogError, match=r"u\.parquet: unknown metadata key 'msarm.secret'"):
        read_log(path)


def test_foreign_log_with_t_not_first_and_no_optional_keys(tmp_path):
    kv = _kv(controller_config=None, extra=None)
    kv["pandas"] = "{}"  # other tools' metadata is ignored
    path = _write_raw(tmp_path / "own.parquet", {"q.elbow": [3.0, 4.0], "t": [0.0, 1.0]}, kv)
    log = read_log(path)
    assert list(log.columns) == ["t", "q.elbow"]
    assert log.metadata.controller_config == {} and log.metadata.extra == {}


def test_mismatched_lengths_and_other_in_memory_errors():
    md = _metadata()
    with pytest.raises(LogError, match=r"column 'q.elbow' has 2 rows, column 't' has 3"):
        RunLog({"t": np.arange(3.0), "q.elbow": np.zeros(2)}, md)
    with pytest.raises(LogError, match="no time column"):
        RunLog({"q.elbow": np.zeros(2)}, md)
    with pytest.raises(LogError, match=r"column 'q.elbow' has inf .* row 1"):
        RunLog({"t": np.arange(2.0), "q.elbow": np.array([0.0, np.inf])}, md)
    with pytest.raises(LogError, match="no unit for quantity 'tau'"):
        RunLog({"t": np.arange(2.0), "tau.elbow": np.zeros(2)}, md)
    with pytest.raises(LogError, match="no samples"):
        RunLog({"t": np.zeros(0)}, md)
    with pytest.raises(InputError, match="JSON"):
        _metadata(extra={"x": object()})


def test_write_is_atomic(tmp_path, monkeypatch):
    path = write_log(tmp_path / "run.parquet", _log(0))

    def fail(*args):
        raise OSError("disk full")

    monkeypatch.setattr("msarm.io.atomic.os.replace", fail)
    with pytest.raises(OSError, match="disk full"):
        write_log(path, _log(1))
    monkeypatch.undo()
    assert read_log(path) == _log(0)
    assert [p.name for p in tmp_path.iterdir()] == ["run.parquet"]


def test_sidecar_round_trip_and_location(tmp_path):
    log_path = write_log(tmp_path / "run.parquet", _log())
    assert sidecar_path(log_path) == tmp_path / "run.truth.parquet"
    t = _log().t
    columns = {"t": t, "tension_insertion.biceps": np.sin(t), "tension_insertion.triceps": t}
    truth = {"effects": {"sheath_friction": {"enabled": True, "mu": 0.08}}, "seed": 3}
    path = write_sidecar(log_path, columns, truth, units={"tension_insertion": "N"})
    assert path == sidecar_path(log_path)
    side = read_sidecar(log_path)
    assert side.ground_truth == truth and side.units == {"tension_insertion": "N"}
    assert side.names("tension_insertion") == list(CABLES)
    for name, col in columns.items():
        assert side.columns[name].tobytes() == col.tobytes()
    # The log knows nothing of it.
    kv = pq.read_schema(log_path).metadata
    assert not any(b"truth" in k or b"effects" in v for k, v in kv.items())
    with pytest.raises(LogError, match="ground-truth sidecar, not a log"):
        read_log(path)
    with pytest.raises(LogError, match="must not be named"):
        write_log(path, _log())


def test_read_log_never_opens_the_sidecar(tmp_path, monkeypatch):
    log_path = write_log(tmp_path / "run.parquet", _log())
    write_sidecar(log_path, {"t": _log().t}, {"effects": {}})
    side = sidecar_path(log_path)
    opened: list[str] = []
    real_open = builtins.open

    def guarded_open(file, *args, **kwargs):
        opened.append(str(file))
        if Path(str(file)).resolve() == side.resolve():
            raise AssertionError("read_log opened the sidecar")
        return real_open(file, *args, **kwargs)

    def no_sidecar(*args, **kwargs):
        raise AssertionError("read_log called read_sidecar")

    real_parquet_file = pq.ParquetFile

    def guarded_parquet_file(source, *args, **kwargs):
        name = getattr(source, "name", source)
        if Path(str(name)).resolve() == side.resolve():
            raise AssertionError("read_log opened the sidecar with pyarrow")
        return real_parquet_file(source, *args, **kwargs)

    real_os_file = logs.pa.OSFile

    def guarded_os_file(file, *args, **kwargs):
        opened.append(str(file))
        if Path(str(file)).resolve() == side.resolve():
            raise AssertionError("read_log opened the sidecar with pyarrow's OSFile")
        return real_os_file(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded_open)
    monkeypatch.setattr(logs, "read_sidecar", no_sidecar)
    monkeypatch.setattr(logs.pq, "ParquetFile", guarded_parquet_file)
    monkeypatch.setattr(logs.pa, "OSFile", guarded_os_file)
    assert read_log(log_path) == _log()
    assert str(log_path) in opened
    monkeypatch.undo()
    # A corrupt sidecar and a deleted one change nothing either.
    side.write_bytes(b"garbage")
    assert read_log(log_path) == _log()
    side.unlink()
    assert read_log(log_path) == _log()
    with pytest.raises(LogError, match=r"run\.truth\.parquet: file not found"):
        read_sidecar(log_path)


def test_a_channel_name_given_twice_is_refused_not_overwritten():
    """The second column replaced the first without a word (one channel lost)."""
    t = np.arange(5) / 100.0
    values = np.column_stack([np.ones(5), 2.0 * np.ones(5)])
    with pytest.raises(InputError, match=r"channels\['q'\]: channel names must be unique; 'a'"):
        logs.columns_from_quantities(t, {"q": (("a", "a"), values)})
    metadata = LogMetadata(robot_model="arm", model_sha256="0" * 64, sample_rate_hz=100.0)
    with pytest.raises(InputError, match="'a' given more than once"):
        RunLog.from_quantities(t, {"q": (("a", "a"), values)}, metadata)


def test_the_nominal_step_is_the_mean_step_between_gaps():
    """300 Hz stamped in whole ms steps 3, 3, 4 ms: the median is 3 ms, the mean the period;
    a gap (longer than 1.5 median steps) is left out."""
    t = np.floor(np.arange(301) * 1000 / 300) / 1000
    assert np.median(np.diff(t)) == pytest.approx(0.003)
    assert nominal_step(t) == pytest.approx(1 / 300, rel=1e-12)
    gapped = np.concatenate([t, t[-1] + 0.5 + t])
    assert nominal_step(gapped) == pytest.approx(1 / 300, rel=1e-12)


def test_a_model_checksum_that_is_not_one_is_refused():
    with pytest.raises(InputError, match=r"model_sha256 must be the SHA-256 .* 64 hex digits"):
        LogMetadata(robot_model="arm", model_sha256="xyz", sample_rate_hz=250.0)
    LogMetadata(robot_model="arm", model_sha256="AB" * 32, sample_rate_hz=250.0)  # any case
