"""Which code made a cached result: a fingerprint of msarm's source and the libraries' versions.

msarm reuses finished work instead of doing it again: ``msarm train`` and ``msarm compare``
reuse tracking runs, ``msarm cdpr compare`` its runs, ``msarm bench diagnose`` its scenarios'
logs and scores. A result is only the same result if the same code made it: after an upgrade
of msarm, an edit of its plant or controller, or a new MuJoCo, the old run would be reused
under the new name and the numbers printed would be the old code's. So every cache records
the fingerprint of the code it was made with and reuses a result only when the fingerprint
is the one in use.

A fingerprint is the SHA-256 of

- every ``.py`` file of the msarm packages that decide the result (their paths relative to
  the msarm package and their bytes, in sorted order), and
- the installed versions of the libraries that compute it (``name==version``, or
  ``name==absent``).

Two scopes (:data:`SCOPES`):

- ``"simulation"``: a simulated run (plant, controller, allocation, muscles, tasks, the
  compensator in the loop, the log writer): every msarm module but the command line, the
  plots and the diagnosis;
- ``"diagnosis"``: a diagnosis of logs: the simulation scope plus ``msarm.diagnose`` and the
  fitting libraries (casadi, PySINDy, scikit-learn).

It is conservative: a change of a comment in a counted module changes the fingerprint too, and
the work is done again. A fingerprint is computed once per process (the files are read once,
about 1 MB).
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Iterable
from importlib import metadata
from pathlib import Path

__all__ = ["LIBRARIES", "SCOPES", "code_fingerprint", "source_fingerprint"]

#: msarm's package folder (the sources that are fingerprinted).
_PACKAGE = Path(__file__).resolve().parent.parent

#: Parts of msarm that never change a number: the command line, the plots, and the models
#: folder an installed wheel carries inside the package (its ``size_muscles.py`` is a
#: re-sizing script; the model files themselves are checked by their SHA-256), so that a
#: checkout and a wheel of the same sources have the same fingerprint.
_NEVER_COUNTED = ("cli", "plots.py", "models")

#: Libraries that compute a simulated run (distribution names, as pip knows them).
_SIMULATION_LIBRARIES = (
    "mujoco",
    "pin",
    "numpy",
    "scipy",
    "numba",
    "cvxpy",
    "torch",
    "pyarrow",
    # the allocation's QP solvers: DAQP (the cable robot's default "fast" solver, the arm's
    # fallback) and Clarabel (under cvxpy)
    "daqp",
    "clarabel",
)

#: Scope -> (msarm parts left out, libraries whose versions count).
SCOPES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "simulation": ((*_NEVER_COUNTED, "diagnose"), _SIMULATION_LIBRARIES),
    "diagnosis": (_NEVER_COUNTED, (*_SIMULATION_LIBRARIES, "casadi", "pysindy", "scikit-learn")),
}

#: Every library some scope counts.
LIBRARIES: tuple[str, ...] = tuple(sorted({lib for _, libs in SCOPES.values() for lib in libs}))


def source_fingerprint(
    root: str | Path, left_out: Iterable[str] = (), libraries: Iterable[str] = ()
) -> str:
    """SHA-256 (hex) of the ``.py`` files under ``root`` and the libraries' versions.

    Args:
        root: The package folder.
        left_out: Parts of it not counted: a top-level file or folder name (``"cli"``,
            ``"plots.py"``).
        libraries: Distribution names (as pip knows them) whose installed version counts.

    Returns:
        The fingerprint, 64 hex digits.

    Raises:
        ValueError: ``root`` is not a folder.
    """
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"root must be a package folder, got {root} (not a folder)")
    skip = set(left_out)
    digest = hashlib.sha256()
    files = sorted(
        path
        for path in root.rglob("*.py")
        if path.relative_to(root).parts[0] not in skip and "__pycache__" not in path.parts
    )
    for path in files:
        name = path.relative_to(root).as_posix().encode()
        content = path.read_bytes()
        # lengths first, so that no two different sets of files give the same byte stream
        digest.update(b"%d:%s%d:" % (len(name), name, len(content)))
        digest.update(content)
    for library in sorted(set(libraries)):
        digest.update(f"{library}=={_version(library)}\n".encode())
    return digest.hexdigest()


@functools.cache
def code_fingerprint(scope: str = "simulation") -> str:
    """The fingerprint of the msarm in use, for one scope (see the module docstring).

    Args:
        scope: ``"simulation"`` or ``"diagnosis"``.

    Returns:
        64 hex digits, the same for the same sources and library versions.

    Raises:
        ValueError: Unknown scope.
    """
    if scope not in SCOPES:
        raise ValueError(f"scope must be one of {', '.join(SCOPES)}, got {scope!r}")
    left_out, libraries = SCOPES[scope]
    return source_fingerprint(_PACKAGE, left_out, libraries)


def _version(library: str) -> str:
    try:
        return metadata.version(library)
    except metadata.PackageNotFoundError:
        return "absent"
