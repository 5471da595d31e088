"""Keep numba's on-disk caches of msarm's kernels true to the code they call.

numba (``@njit(cache=True)``) checks a cached kernel only against the source file that defines
it. A kernel that calls another module's kernel, or reads another module's constant (numba
freezes globals at compile time), keeps running the old code after that other module
changes: the compiled arm loop of :mod:`msarm.tasks.compiled_loop` went on stepping an old
cable kernel after :mod:`msarm.plant.cable_kernel` was edited, and tests passed on the old
physics. :func:`drop_stale_kernels` closes the gap: called at the top of a module with cached
kernels, it hashes the sources of every msarm module that module imports, directly or through
others, and deletes the module's cached kernels when that hash differs from the one stored
beside them at their last check.

It looks after the caches numba writes beside the sources (``__pycache__``, the case for a
source checkout and an ordinary install). Where that folder cannot be written numba keeps its
cache elsewhere (``NUMBA_CACHE_DIR``) and this check does nothing: delete that folder after
changing msarm's source.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import json
import os
from pathlib import Path

__all__ = ["compiled_or_cached", "drop_stale_kernels", "msarm_imports"]

_PACKAGE_ROOT = Path(__file__).resolve().parent
_PACKAGE = _PACKAGE_ROOT.name


def _module_file(name: str) -> Path | None:
    """Source file of the msarm module ``name`` (dotted), or None if it is not one."""
    parts = name.split(".")
    if parts[0] != _PACKAGE:
        return None
    base = _PACKAGE_ROOT.joinpath(*parts[1:])
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _module_name(path: Path) -> str:
    relative = path.relative_to(_PACKAGE_ROOT).with_suffix("")
    parts = [_PACKAGE, *relative.parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@functools.cache
def _direct_imports(path: Path) -> frozenset[Path]:
    """Files of the msarm modules that ``path`` imports anywhere in its body."""
    tree = ast.parse(path.read_bytes(), filename=str(path))
    package = _module_name(path)
    if path.name != "__init__.py":
        package = package.rpartition(".")[0]
    found: set[Path] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, node.module] if node.module else anchor)
            else:
                base = node.module or ""
            # ``from msarm.tasks import metrics`` imports a module, ``from x import f`` a name
            names = [base, *(f"{base}.{alias.name}" for alias in node.names)]
        else:
            continue
        for name in names:
            # ``import msarm.a.b`` runs msarm/__init__, msarm/a/__init__ and msarm/a/b
            parts = name.split(".")
            for k in range(1, len(parts) + 1):
                file = _module_file(".".join(parts[:k]))
                if file is not None:
                    found.add(file)
    found.discard(path)
    return frozenset(found)


def msarm_imports(path: str | Path) -> list[Path]:
    """The msarm source files a module depends on, itself included, sorted.

    Args:
        path: Source file of an msarm module.

    Returns:
        Every msarm module file reachable through its imports (at any depth), and ``path``.
    """
    start = Path(path).resolve()
    seen = {start}
    todo = [start]
    while todo:
        for file in _direct_imports(todo.pop()):
            if file not in seen:
                seen.add(file)
                todo.append(file)
    return sorted(seen)


def _sources_digest(files: list[Path]) -> str:
    digest = hashlib.sha256()
    for file in files:
        digest.update(str(file.relative_to(_PACKAGE_ROOT)).encode())
        digest.update(b"\0")
        digest.update(file.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()


def _file_stamps(files: list[Path]) -> dict[str, list[int]]:
    """``{path: [mtime_ns, size]}`` of each file."""
    stamps = {}
    for file in files:
        status = file.stat()
        stamps[str(file.relative_to(_PACKAGE_ROOT))] = [status.st_mtime_ns, status.st_size]
    return stamps


def _read_stamp(stamp: Path) -> dict | None:
    try:
        recorded = json.loads(stamp.read_text())
    except (OSError, ValueError):
        return None  # no stamp yet (a fresh checkout, kernels never compiled here) or torn
    return recorded if isinstance(recorded, dict) else None


def _unchanged(recorded: dict) -> bool:
    """Whether every file the stamp lists still has its recorded time and size."""
    files = recorded.get("files")
    if not isinstance(files, dict) or not files:
        return False
    try:
        now = _file_stamps([_PACKAGE_ROOT / name for name in files])
    except OSError:
        return False  # a file went away
    return now == files


def drop_stale_kernels(module_file: str | Path) -> bool:
    """Delete a module's cached numba kernels if a module it imports changed since.

    Call it at the top of the module, before any of its kernels runs:
    ``drop_stale_kernels(__file__)``. When no file it depends on has a new time or size
    since the last check this costs a few ``stat`` calls; otherwise it reads them all and
    compares their contents' hash.

    Args:
        module_file: The module's source file (its ``__file__``).

    Returns:
        Whether cached kernels were deleted (False also where ``__pycache__`` cannot be
        written: then numba caches elsewhere, see the module doc).
    """
    path = Path(module_file).resolve()
    cache_dir = path.parent / "__pycache__"
    stamp = cache_dir / f"{path.stem}.numba-sources"
    recorded = _read_stamp(stamp)
    if recorded is not None and _unchanged(recorded):
        return False
    files = msarm_imports(path)
    digest = _sources_digest(files)
    dropped = False
    try:
        cache_dir.mkdir(exist_ok=True)
        if recorded is None or recorded.get("digest") != digest:
            for kernel in cache_dir.glob(f"{path.stem}.*.nb[ic]"):
                kernel.unlink(missing_ok=True)
                dropped = True
        temporary = stamp.with_name(f"{stamp.name}.{os.getpid()}.tmp")
        temporary.write_text(json.dumps({"digest": digest, "files": _file_stamps(files)}))
        os.replace(temporary, stamp)
    except OSError:
        return False
    return dropped


def compiled_or_cached(kernel: object) -> bool | None:
    """Whether calling ``kernel`` will skip numba's compiler: compiled here, or on disk.

    Args:
        kernel: An ``@numba.njit(cache=True)`` dispatcher.

    Returns:
        True when the process has compiled it already or numba's cache holds its index file
        (where numba keeps it: beside the source, or under ``NUMBA_CACHE_DIR``); False when
        neither, so its next call compiles it (10-20 s for the arm's loop); None when the
        dispatcher does not show its cache as numba 0.68 does (another numba version).
    """
    if getattr(kernel, "signatures", None):
        return True
    try:
        index = Path(kernel._cache._cache_file._index_path)  # type: ignore[attr-defined]
    except (AttributeError, TypeError):
        return None
    return index.is_file()
