"""The code fingerprint that keeps the caches from reusing another msarm version's results."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import msarm
from msarm.io.code_version import SCOPES, code_fingerprint, source_fingerprint


def _package(root: Path) -> Path:
    (root / "pkg" / "cli").mkdir(parents=True)
    (root / "pkg" / "sub").mkdir()
    (root / "pkg" / "__init__.py").write_text("A = 1\n")
    (root / "pkg" / "sub" / "physics.py").write_text("K = 2.0\n")
    (root / "pkg" / "cli" / "main.py").write_text("print('help')\n")
    (root / "pkg" / "notes.txt").write_text("not code\n")
    return root / "pkg"


def test_the_fingerprint_follows_the_counted_sources_only(tmp_path):
    package = _package(tmp_path)
    first = source_fingerprint(package, left_out=("cli",))
    assert len(first) == 64 and int(first, 16) >= 0
    assert source_fingerprint(package, left_out=("cli",)) == first  # deterministic
    # a left-out part, a file that is not Python, and compiled files do not count
    (package / "cli" / "main.py").write_text("print('other help')\n")
    (package / "notes.txt").write_text("other notes\n")
    (package / "sub" / "__pycache__").mkdir()
    (package / "sub" / "__pycache__" / "physics.py").write_text("stale\n")
    assert source_fingerprint(package, left_out=("cli",)) == first
    # a counted file's bytes, a new file, a renamed file: all change it
    (package / "sub" / "physics.py").write_text("K = 2.5\n")
    edited = source_fingerprint(package, left_out=("cli",))
    assert edited != first
    (package / "sub" / "physics.py").write_text("K = 2.0\n")
    assert source_fingerprint(package, left_out=("cli",)) == first
    (package / "sub" / "extra.py").write_text("")
    assert source_fingerprint(package, left_out=("cli",)) != first
    (package / "sub" / "extra.py").unlink()
    (package / "sub" / "physics.py").rename(package / "sub" / "kinetics.py")
    assert source_fingerprint(package, left_out=("cli",)) != first
    # the same bytes split differently between files differ too
    (package / "sub" / "kinetics.py").rename(package / "sub" / "physics.py")
    (package / "__init__.py").write_text("A = 1\nK = 2.0\n")
    (package / "sub" / "physics.py").write_text("")
    assert source_fingerprint(package, left_out=("cli",)) != first


def test_library_versions_count(tmp_path):
    package = _package(tmp_path)
    bare = source_fingerprint(package)
    with_numpy = source_fingerprint(package, libraries=("numpy",))
    assert with_numpy != bare
    # a library that is not installed counts as absent, which is a version of its own
    missing = source_fingerprint(package, libraries=("no-such-distribution-msarm",))
    assert missing not in (bare, with_numpy)
    assert source_fingerprint(package, libraries=("numpy", "numpy")) == with_numpy


def test_the_simulation_scope_ignores_the_diagnosis_the_diagnosis_scope_does_not(tmp_path):
    copy = tmp_path / "msarm"
    shutil.copytree(Path(msarm.__file__).parent, copy)
    left_out, libraries = SCOPES["simulation"]
    assert source_fingerprint(copy, left_out, libraries) == code_fingerprint("simulation")
    d_left_out, d_libraries = SCOPES["diagnosis"]
    assert source_fingerprint(copy, d_left_out, d_libraries) == code_fingerprint("diagnosis")
    assert code_fingerprint("simulation") != code_fingerprint("diagnosis")
    diagnosis_file = copy / "diagnose" / "select.py"
    diagnosis_file.write_text(diagnosis_file.read_text() + "\n# edited\n")
    assert source_fingerprint(copy, left_out, libraries) == code_fingerprint("simulation")
    assert source_fingerprint(copy, d_left_out, d_libraries) != code_fingerprint("diagnosis")
    # the plant decides both a run's numbers and the logs a diagnosis reads
    plant_file = copy / "plant" / "arm_plant.py"
    plant_file.write_text(plant_file.read_text() + "\n# edited\n")
    assert source_fingerprint(copy, left_out, libraries) != code_fingerprint("simulation")
    # the command line and the plots change no number
    cli_file = copy / "cli" / "__init__.py"
    other = tmp_path / "again"
    shutil.copytree(Path(msarm.__file__).parent, other)
    (other / "cli" / "__init__.py").write_text(cli_file.read_text() + "\n# edited\n")
    (other / "plots.py").write_text((other / "plots.py").read_text() + "\n# edited\n")
    assert source_fingerprint(other, left_out, libraries) == code_fingerprint("simulation")


def test_bad_scope_and_root_are_refused(tmp_path):
    with pytest.raises(ValueError, match="scope must be one of simulation, diagnosis"):
        code_fingerprint("training")
    with pytest.raises(ValueError, match="not a folder"):
        source_fingerprint(tmp_path / "missing")
