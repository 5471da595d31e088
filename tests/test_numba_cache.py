"""Cached numba kernels are compiled again when a module they import changes.

numba checks a cached kernel only against its own source file; ``msarm.numba_cache`` drops a
module's cached kernels when any msarm module it imports has changed.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import msarm
from msarm.numba_cache import msarm_imports

PACKAGE = Path(msarm.__file__).resolve().parent

CALLER = """
import numba
{drop}
from msarm._probe_callee import callee


@numba.njit(cache=True)
def caller():
    return callee()
"""
CALLEE = """
import numba


@numba.njit(cache=True)
def callee():
    return {value}
"""


def test_the_compiled_loop_depends_on_the_kernels_it_calls():
    files = {str(f.relative_to(PACKAGE)) for f in msarm_imports(PACKAGE / "tasks/compiled_loop.py")}
    assert {"plant/cable_kernel.py", "muscle/fast.py", "control/kernels.py"} <= files
    assert "small_linalg.py" in files  # through the newton allocation: at any depth
    assert "diagnose/select.py" not in files
    assert msarm_imports(PACKAGE / "small_linalg.py") == sorted(
        [PACKAGE / "__init__.py", PACKAGE / "numba_cache.py", PACKAGE / "small_linalg.py"]
    )


def _package_copy(root: Path, drop: bool) -> Path:
    package = root / "msarm"
    package.mkdir(parents=True)
    for name in ("__init__.py", "numba_cache.py"):
        shutil.copy(PACKAGE / name, package / name)
    line = (
        "from msarm.numba_cache import drop_stale_kernels\ndrop_stale_kernels(__file__)"
        if drop
        else ""
    )
    (package / "_probe_caller.py").write_text(CALLER.format(drop=line))
    (package / "_probe_callee.py").write_text(CALLEE.format(value=1))
    return package


def _call(root: Path) -> int:
    code = "from msarm._probe_caller import caller; print(caller())"
    result = subprocess.run(
        [sys.executable, "-c", code],
        cwd=root,
        env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        check=True,
    )
    return int(result.stdout.strip())


def test_a_changed_callee_is_compiled_again_into_its_caller(tmp_path):
    plain, checked = tmp_path / "plain", tmp_path / "checked"
    for root, drop in ((plain, False), (checked, True)):
        package = _package_copy(root, drop)
        assert _call(root) == 1  # compiled and cached
        (package / "_probe_callee.py").write_text(CALLEE.format(value=2))
    # numba alone keeps the caller's cached copy of the old callee ...
    assert _call(plain) == 1, "numba now checks imported kernels itself: msarm.numba_cache can go"
    # ... the check drops it and compiles the caller again
    assert _call(checked) == 2
    assert _call(checked) == 2  # and caches the new one
