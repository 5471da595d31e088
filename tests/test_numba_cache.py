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
    # No bytecode: Python checks a .pyc against its source's mtime in whole seconds and its
    # size, so a callee rewritten (same size) within the second of its first write, when the
    # first call is fast, was imported from the stale .pyc (the test failed now and then).
    result = subprocess.run(
        [sys.executable, "-c", code],
        cwd=root,
        env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin", "PYTHONDONTWRITEBYTECODE": "1"},
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


KERNEL = """
import numba


@numba.njit(cache=True)
def twice(x):
    return 2.0 * x
"""


def test_a_kernel_is_ready_once_compiled_here_or_cached_on_disk(tmp_path, monkeypatch):
    import importlib

    from msarm.numba_cache import compiled_or_cached

    (tmp_path / "probe_ready_kernel.py").write_text(KERNEL)
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("probe_ready_kernel")
    try:
        assert compiled_or_cached(module.twice) is False  # never compiled: its call compiles
        assert module.twice(2.0) == 4.0
        assert compiled_or_cached(module.twice) is True  # compiled in this process
        module = importlib.reload(module)  # a new dispatcher, as in a new process
        assert not module.twice.signatures
        assert compiled_or_cached(module.twice) is True  # numba's cache on disk
        for index in (tmp_path / "__pycache__").glob("probe_ready_kernel.twice-*.nbi"):
            index.unlink()
        module = importlib.reload(module)
        assert compiled_or_cached(module.twice) is False
        assert compiled_or_cached(len) is None  # not a numba dispatcher: no answer
    finally:
        sys.modules.pop("probe_ready_kernel", None)


def test_the_commands_say_when_numba_compiles_the_loop_first(monkeypatch, capsys):
    import msarm.tasks.compiled_loop as compiled_loop
    from msarm.cli.common import note_first_compile

    monkeypatch.setattr(compiled_loop, "compiled_loop_ready", lambda: False)
    assert note_first_compile("track") is True
    assert "msarm track: numba compiles the simulation loop" in capsys.readouterr().err
    monkeypatch.setattr(compiled_loop, "compiled_loop_ready", lambda: True)
    assert note_first_compile("track") is False
    assert capsys.readouterr().err == ""
