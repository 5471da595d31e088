"""Atomic writes: a file appears whole or not at all.

Every result msarm writes (logs, sidecars, configs, metrics, checkpoints, plots) goes through
:func:`atomic_path`: the writer fills a temporary file in the target's folder, which is then
flushed to disk and renamed onto the target (``os.replace``, atomic on one file system). An
interrupted run leaves the previous file, never a truncated one.

The temporary file is removed when the writer raises (``KeyboardInterrupt``, and the
``SystemExit`` the ``msarm`` command turns SIGTERM into, included). A process killed outright
(SIGKILL, a power cut) cannot clean up: its ``.<name>.<random>.tmp`` is removed by the next
write of the same target once it is :data:`STALE_TEMP_AGE_S` old (never a temporary file of
another target, nor a fresh one that a live writer may still be filling).
"""

from __future__ import annotations

import json
import os
import re
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from msarm.errors import InputError
from msarm.interrupts import raise_if_terminated

__all__ = [
    "STALE_TEMP_AGE_S",
    "atomic_path",
    "remove_stale_temps",
    "write_bytes_atomic",
    "write_json_atomic",
]

#: Age [s] (since its last change) past which a temporary file of a target is taken as left
#: behind by a killed writer and removed by the next write of that target.
STALE_TEMP_AGE_S = 60.0


def _umask() -> int:
    """The process's umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _temp_prefix(path: Path) -> str:
    return f".{path.name}."


def remove_stale_temps(path: str | Path, age_s: float = STALE_TEMP_AGE_S) -> list[Path]:
    """Remove the temporary files of ``path`` that are older than ``age_s`` seconds.

    Only ``.<name>.<random>.tmp`` siblings of ``path`` itself match (``<random>`` without a
    dot, as :func:`atomic_path` names them), so another target's are never touched, such as
    ``.<name>.bak.<random>.tmp`` of ``<name>.bak``. Files that cannot be examined or removed
    are left (best effort).

    Returns:
        The files removed.
    """
    path = Path(path)
    own = re.compile(re.escape(_temp_prefix(path)) + r"[A-Za-z0-9_]+\.tmp")
    removed: list[Path] = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    now = time.time()
    for entry in entries:
        if not own.fullmatch(entry.name):
            continue
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
            if now - entry.stat(follow_symlinks=False).st_mtime <= age_s:
                continue  # perhaps a live writer's
            os.unlink(entry.path)
        except OSError:
            continue
        removed.append(Path(entry.path))
    return removed


#: A temporary file of :func:`atomic_path` of any target: ``.<target>.<random>.tmp``.
_ANY_TEMP = re.compile(r"\.(.+)\.[A-Za-z0-9_]+\.tmp")


def remove_stale_temps_in(folder: str | Path, age_s: float = STALE_TEMP_AGE_S) -> list[Path]:
    """Remove every temporary file of :func:`atomic_path` in ``folder`` older than ``age_s``.

    For a folder whose files are reused and never written again (a finished run reused by
    the next command): a killed writer's ``.<name>.<random>.tmp`` there would otherwise stay
    for good, as only the next write of ``<name>`` removes it.

    Returns:
        The files removed.
    """
    removed: list[Path] = []
    try:
        names = [entry.name for entry in os.scandir(folder)]
    except OSError:
        return removed
    targets = {m.group(1) for m in map(_ANY_TEMP.fullmatch, names) if m}
    for target in sorted(targets):  # each target's own temporary files, by its own rule
        removed += remove_stale_temps(Path(folder) / target, age_s)
    return removed


@contextmanager
def folder_for_writing(path: str | Path) -> Iterator[Path]:
    """Create the folder ``path`` (and its parents) for the block's files.

    If the block raises (a SIGTERM included) and this call created the folder, the folder
    is removed when it is still empty: an interrupted run leaves no empty folder of its own
    (a review found ``run-1001/`` left empty by a SIGTERM during ``msarm train``).

    Yields:
        The folder.
    """
    path = Path(path)
    made = not path.exists()
    path.mkdir(parents=True, exist_ok=True)
    try:
        yield path
    except BaseException:
        if made:
            try:
                path.rmdir()  # only if empty
            except OSError:
                pass
        raise


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success move it onto ``path``.

    The folder is created if needed. If the body raises, the temporary file is removed and
    ``path`` is left as it was. Temporary files of ``path`` left by a killed writer (older
    than :data:`STALE_TEMP_AGE_S`) are removed first (:func:`remove_stale_temps`). The file
    gets the permissions of a plainly created one (``0o666`` less the umask), not the
    private ``0o600`` of a temporary file.

    Args:
        path: The file to write.

    Yields:
        The temporary path to write to (its name does not end in the target's suffix).

    Raises:
        InputError: ``path`` is a folder, or a folder on its way is a file (both named).
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"cannot write {path}: it is a folder, expected a file path")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        blocker = next(
            (p for p in reversed(path.parents) if p.exists() and not p.is_dir()), path.parent
        )
        raise InputError(
            f"cannot write {path}: {blocker} is a file, not a folder (choose another path)"
        ) from None
    remove_stale_temps(path)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=_temp_prefix(path), suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        # a SIGTERM whose exception a callback swallowed (Python ignores exceptions raised in
        # garbage-collection and weakref callbacks): no new result after it
        raise_if_terminated()
        with open(tmp, "rb") as handle:
            os.fsync(handle.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; return the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_json_atomic(path: str | Path, payload: Any) -> Path:
    """Write ``payload`` as indented JSON (and a final newline) to ``path`` atomically."""
    return write_bytes_atomic(path, (json.dumps(payload, indent=2) + "\n").encode("utf-8"))
