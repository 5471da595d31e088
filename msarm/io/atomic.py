"""Atomic writes: a file appears whole or not at all.

Every result msarm writes (logs, sidecars, configs, metrics, checkpoints, plots) goes through
:func:`atomic_path`: the writer fills a temporary file in the target's folder, which is then
flushed to disk and renamed onto the target (``os.replace``, atomic on one file system). An
interrupted run leaves the previous file, never a truncated one.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from msarm.errors import InputError

__all__ = ["atomic_path", "write_bytes_atomic", "write_json_atomic"]


def _umask() -> int:
    """The process's umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success move it onto ``path``.

    The folder is created if needed. If the body raises, the temporary file is removed and
    ``path`` is left as it was. The file gets the permissions of a plainly created one
    (``0o666`` less the umask), not the private ``0o600`` of a temporary file.

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
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
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
