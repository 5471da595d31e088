"""Helpers shared by the CLI commands: resolving names given on the command line."""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from rich.console import Console

from msarm.errors import InputError
from msarm.io.config import folder_instead_of_file
from msarm.plant.config import DEFAULT_PLANT, PLANT_PRESETS, PlantConfig

if TYPE_CHECKING:
    from msarm.control import ArmControllerConfig
    from msarm.model import RobotModel

T = TypeVar("T")

#: Plants known by name; anything else is read as a YAML file.
PLANTS: dict[str, PlantConfig] = PLANT_PRESETS


def resolve_config(spec: str, presets: dict[str, T], cls: type[T], what: str) -> T:
    """A config from a preset name or, failing that, a YAML file of ``cls``.

    Args:
        spec: A name of ``presets`` or the path of a YAML file.
        presets: The presets by name.
        cls: The config's dataclass (how the YAML file is read).
        what: What the config is, for the error message (e.g. ``"plant"``).

    A run's ``config.yaml`` (a mapping whose ``plant`` key holds the plant, as ``msarm
    track`` and ``msarm cdpr run`` write it) gives its ``plant`` section, so a run's plant can
    be given back as it was recorded. A file without a ``name`` key is named after the file
    (its stem), so that its runs are not labelled, nor stored, as a preset's; a file whose
    ``name`` is a preset's is refused for the same reason, unless its config is that preset's
    exactly (then it is the preset), and so is a name that ends like a run folder's suffix
    (``-s<seed>``, ``-ff``: a plant ``default-s3`` would write into the default plant's
    seed-3 folder).

    Raises:
        InputError: ``spec`` is neither a preset nor an existing file (a folder is said to
            be one); the file's config is named like a preset but differs from it; or,
            without a ``name`` key, the file's stem is not a name the config takes (it names
            run folders).
    """
    if spec in presets:
        return presets[spec]
    path = Path(spec)
    folder = folder_instead_of_file(path, f"a {what} YAML file (or one of {', '.join(presets)})")
    if folder is not None:
        raise InputError(folder)
    if not path.is_file():
        looks_like_a_file = path.suffix in (".yaml", ".yml") or len(path.parts) > 1
        raise InputError(
            f"{what} file not found: {spec} (expected one of {', '.join(presets)} or a YAML file)"
            if looks_like_a_file
            else f"unknown {what} {spec!r}: expected one of {', '.join(presets)} or a YAML file"
        )
    import dataclasses

    config, raw = read_config_section(path, cls, what)
    names = {f.name for f in dataclasses.fields(config)} if dataclasses.is_dataclass(config) else ()
    if "name" in names:
        if not (isinstance(raw, dict) and "name" in raw):  # not the preset's name: the file's
            try:
                config = dataclasses.replace(config, name=path.stem)
            except ValueError as exc:  # the stem refused as a name
                raise InputError(
                    f"{spec}: {exc}; give the file a 'name' key or rename the file"
                ) from None
        if config.name in presets and config == presets[config.name]:
            return presets[config.name]  # the preset itself, written out (e.g. by a run)
        # a bare s<digits> too: the cable robot's default plant leaves its name out
        suffix = re.fullmatch(r"(?:.+-)?(s\d+)|.+(-ff)", config.name)
        if suffix:  # the run folder names' own suffixes: default-s3 is default's seed-3 folder
            ending = suffix.group(1) or suffix.group(2)
            raise InputError(
                f"{spec}: the file's {what} is named {config.name!r}, which ends like a run "
                f"folder's suffix ({ending}: -s<seed> for a seed, -ff with a "
                "compensator), so its runs could overwrite another plant's; expected another "
                "name (give the file a 'name' key or rename the file)"
            )
        if config.name in presets:
            raise InputError(
                f"{spec}: the file's {what} is named {config.name!r}, the name of a preset (its "
                f"runs would overwrite the preset's); expected another name (not "
                f"{', '.join(presets)})"
            )
    return config


def progress_bar(*columns, transient: bool = True):
    """A rich progress bar drawn on stderr, and only when stderr is a terminal.

    Standard output is left to the command's result (the JSON of ``--json``, a table, or a
    file it is redirected to); where stderr is not a terminal (a log file, a CI job) the bar
    is off and :func:`progress_lines` prints the steps instead. Shown with ``--json`` too.

    Args:
        columns: The bar's columns (rich's default ones if none).
        transient: Remove the bar when done.

    Returns:
        A ``rich.progress.Progress`` (a context manager).
    """
    from rich.progress import Progress

    err = Console(stderr=True)
    return Progress(*columns, console=err, transient=transient, disable=not err.is_terminal)


def read_config_section(path: Path, cls: type[T], section: str) -> tuple[T, object]:
    """A config of ``cls`` from a YAML file of it, or from the ``section`` of a bigger file.

    A run's ``config.yaml`` (``msarm track``, ``msarm cdpr run``) holds the ``plant`` and the
    ``controller`` it ran with, and a training recipe its ``controller``: a mapping whose
    ``section`` key holds a mapping, beside keys ``cls`` does not have, is read as that
    section; any other file as a whole.

    Args:
        path: The YAML file.
        cls: The config's dataclass.
        section: The key of the section (e.g. ``"plant"``).

    Returns:
        The config, and the parsed mapping it was built from (the section, or the file).

    Raises:
        ConfigError: The file or its section is not a valid config (file, section and key
            named).
    """
    import dataclasses

    import yaml

    from msarm.errors import ConfigError
    from msarm.io.config import _load_yaml, load_config

    try:  # the loader of load_config: a key given twice is refused here too
        raw = _load_yaml(Path(path).read_text(encoding="utf-8"), str(path))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        raw = None  # load_config says what is wrong with the file
    fields = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    part = raw.get(section) if isinstance(raw, dict) and section not in fields else None
    if isinstance(part, str) and isinstance(raw, dict) and "trajectory" in raw:
        raise ConfigError(
            f"{path}: its '{section}' is the name {part!r}, not a section of "
            f"{cls.__name__}'s keys: this is a cable robot's run config (msarm cdpr run), "
            "not one of the arm's; expected a YAML file of the arm's controller gains, or one "
            f"with a '{section}:' section of them"
        )
    if isinstance(part, dict) and not set(raw) <= fields:
        try:
            return load_config(part, cls), part
        except ConfigError as exc:  # name the file and its section, not "<mapping>"
            raise ConfigError(
                str(exc).replace("<mapping>", f"{path} (its '{section}' section)", 1)
            ) from None
    return load_config(path, cls), raw


def check_controller_file(
    model: RobotModel, gains: ArmControllerConfig, source: str | Path
) -> None:
    """Check gains read from ``source`` against the arm, naming the file.

    The controller checks them too, but deep in a run and without the file. The control
    period against the plant's step is :func:`check_control_period`'s.

    Raises:
        InputError: Gains of the wrong count or a floor above a muscle's strength (``source``
            named).
    """
    from msarm.control import MuscleSpaceController

    try:
        MuscleSpaceController(model, gains)
    except InputError as exc:
        raise InputError(f"{source}: {exc}") from None


def check_control_period(
    gains: ArmControllerConfig,
    plant_config: PlantConfig,
    rate_source: str,
    plant_source: str | None = None,
) -> None:
    """Check that the control period is a whole number of plant steps, before a run.

    The runner refuses such a pair at the start of a run, but without the file that set
    either, and after the output folder is made. Here the message names the one that is odd:
    the plant's file when its step is not the default (1 ms) and the default step would fit
    the rate, else the rate.

    Args:
        gains: The controller's gains (``rate_hz``).
        plant_config: The plant (``timestep``).
        rate_source: Where the rate comes from, e.g. ``"recipe.yaml: controller.rate_hz"``.
        plant_source: The plant's file, or None for a preset.

    Raises:
        InputError: The plant's step does not divide the control period (the file and the
            key named, with the values that would fit).
    """
    from msarm.tasks.runner import plant_steps_per_tick

    period, step = 1.0 / gains.rate_hz, plant_config.timestep
    if plant_steps_per_tick(period, step) is not None:
        return
    default_step = DEFAULT_PLANT.timestep
    if (
        plant_source is not None
        and step != default_step
        and plant_steps_per_tick(period, default_step) is not None
    ):
        first = max(1, math.ceil(period / default_step - 1e-9))  # steps <= the default step
        fits = []
        for k in range(first, first + 100):
            text = f"{period / k:.3g}"
            if plant_steps_per_tick(period, float(text)) is not None:
                fits.append(text)
            if len(fits) == 4:
                break
        raise InputError(
            f"{plant_source}: the plant's timestep {step:g} s does not divide the control "
            f"period {period:.6g} s ({rate_source} {gains.rate_hz:g}); expected a step that "
            f"does, {period:.6g} s / k for a whole number k >= {first}, e.g. "
            f"{', '.join(fits)} s"
        )
    where = "" if plant_source is None else f" (the timestep of {plant_source})"
    rates = []  # rates that fit, as they would be written
    for k in range(1, 1000):
        text = f"{1 / (k * step):.6g}"
        if plant_steps_per_tick(1 / float(text), step) is not None:
            rates.append(float(text))
    near = sorted(sorted(rates, key=lambda r: abs(r - gains.rate_hz))[:2])
    example = f", e.g. {' or '.join(f'{r:g}' for r in near)} Hz" if near else ""
    raise InputError(
        f"{rate_source} {gains.rate_hz:g} gives a control period of {period:.6g} s, not a "
        f"whole number of the plant's steps of {step:g} s{where}; expected a rate that "
        f"divides {1 / step:g} Hz{example}"
    )


def progress_lines(what: str, total: int | None = None, enabled: bool = True):
    """A progress callback that prints one line a step to stderr when it is not a terminal.

    A live progress bar shows nothing in a log file or a CI job; there, each step is a line
    (``what [k/total]: label``) on stderr, which ``--json`` leaves alone (its JSON is on
    stdout). On a terminal (the bar of :func:`progress_bar` is shown) or when ``enabled`` is
    false the callback does nothing.

    Returns:
        A function of the step's label.
    """
    import sys

    from msarm.interrupts import raise_if_terminated

    if not enabled or Console(stderr=True).is_terminal:
        # no line to print; a SIGTERM a callback swallowed still takes effect at each step
        return lambda label: raise_if_terminated()
    done = [0]

    def line(label: str) -> None:
        raise_if_terminated()  # a SIGTERM a callback swallowed (garbage collection)
        done[0] += 1
        count = f"{done[0]}/{total}" if total else f"{done[0]}"
        print(f"{what} [{count}]: {label}", file=sys.stderr, flush=True)

    return line


def note_first_compile(command: str) -> bool:
    """Say on stderr that numba compiles the simulation loop first, when it will.

    Once after an install or an update of msarm, the first compiled run spends 10-20 s in
    numba's compiler before its progress moves
    (:func:`msarm.tasks.compiled_loop.compiled_loop_ready`).

    Args:
        command: The command's name, for the line (``track``, ``train``, ``compare``).

    Returns:
        Whether the line was printed.
    """
    from msarm.tasks.compiled_loop import compiled_loop_ready

    if compiled_loop_ready():
        return False
    print(
        f"msarm {command}: numba compiles the simulation loop before the first run "
        "(10-20 s, once after an install or an update of msarm)",
        file=sys.stderr,
    )
    return True


def seed_suffix(seed: int) -> str:
    """``-s<seed>`` for a seed other than 0, else ``""`` (default run folder names)."""
    return f"-s{seed}" if seed else ""


#: Folders :func:`output_folder` created in this process, deepest first within each call.
CREATED_FOLDERS: list[Path] = []


def output_folder(path: Path, option: str = "--out") -> Path:
    """Create the output folder ``path`` up front, before any long run writes into it.

    The folders it creates are remembered (:data:`CREATED_FOLDERS`): a command that then
    fails on its input, or is interrupted (SIGTERM, Ctrl-C), leaves none of them behind empty
    (:func:`remove_empty_created_folders`).

    Raises:
        InputError: ``path`` is an existing file, or the folder cannot be created (the reason
            given).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option}: {path} is a file; expected a folder (created if missing)")
    missing = [part for part in (path, *path.parents) if not part.exists()]
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{option}: cannot create the folder {path}: {exc.strerror}") from None
    CREATED_FOLDERS.extend(missing)
    return path


def remove_empty_created_folders() -> None:
    """Remove the folders :func:`output_folder` created that are still empty (deepest first)."""
    while CREATED_FOLDERS:
        folder = CREATED_FOLDERS.pop(0)
        try:
            folder.rmdir()  # only if empty
        except OSError:
            pass


def run_script(prog: str, work: Callable[[], int | None]) -> int:
    """Run a script's ``work`` so that SIGTERM unwinds it; the exit status.

    For scripts of their own (the examples): SIGTERM raises inside ``work``
    (:func:`msarm.interrupts.sigterm_raises`), so its temporary folders and files are removed
    on the way out; ``prog: terminated`` is printed and 143 returned, as by ``msarm``. An
    ``--out`` folder :func:`output_folder` made and left empty is removed in any case.

    Args:
        prog: The script's name, for the message.
        work: The script's work; what it returns is the exit status (None: 0).

    Returns:
        The exit status: ``work``'s, or 143 after a SIGTERM.
    """
    from msarm import interrupts

    try:
        with interrupts.sigterm_raises():
            return int(work() or 0)
    except interrupts.Terminated as exc:
        print(f"{prog}: terminated", file=sys.stderr)
        return int(exc.code)
    finally:
        remove_empty_created_folders()  # --out, if this run made it and wrote nothing there


def check_drum_radius(drum_radius: float) -> None:
    """Refuse a ``--drum-radius`` that is not a finite radius > 0 [m] (InputError)."""
    if not (0 < drum_radius < float("inf")):
        raise InputError(f"--drum-radius: expected a radius > 0 in metres, got {drum_radius}")


def check_filter_window(filter_window: int) -> None:
    """Refuse a ``--filter-window`` that is not an odd number of samples >= 5 (InputError)."""
    if filter_window < 5 or filter_window % 2 == 0:
        raise InputError(
            f"--filter-window: expected an odd number of samples >= 5, got {filter_window}"
        )


def resolve_plant(spec: str) -> PlantConfig:
    """The arm plant from a preset name (``default``, ``ideal``) or a YAML file.

    Raises:
        InputError: As :func:`resolve_config`.
        ConfigError: The file is not a valid arm plant (with a hint when it looks like a cable
            robot's plant).
    """
    from msarm.plant.cdpr_config import CdprPlantConfig

    return resolve_plant_of(spec, PLANTS, PlantConfig, CdprPlantConfig)


#: What to call each robot's plant in a hint, and the command that takes it.
_PLANT_KINDS = {
    "PlantConfig": ("an arm plant", "msarm track --plant"),
    "CdprPlantConfig": ("a cable robot's plant", "msarm cdpr run --plant"),
}


def resolve_plant_of(spec: str, presets: dict[str, T], cls: type[T], other: type) -> T:
    """A plant of class ``cls`` as :func:`resolve_config` reads it, with a hint on a refusal.

    When the file is refused and has keys only ``other``'s plant has (an arm plant given to
    the cable robot, or the reverse), the error says so and names the command for it.

    Raises:
        InputError: As :func:`resolve_config`.
        ConfigError: The file is not a valid plant of ``cls``.
    """
    from msarm.errors import ConfigError

    try:
        return resolve_config(spec, presets, cls, "plant")
    except ConfigError as exc:
        keys = other_plant_keys(spec, cls, other)
        if not keys:
            raise
        (own, _), (theirs, command) = _PLANT_KINDS[cls.__name__], _PLANT_KINDS[other.__name__]
        raise ConfigError(
            f"{exc}; this looks like {theirs} ({keys}; for {command}), not {own}"
        ) from None


def other_plant_keys(spec: str, cls: type, other: type) -> str:
    """The keys of a plant file that only the other robot's plant has, as ``key 'a', 'b'``.

    Args:
        spec: The plant file (a run's ``config.yaml``: its ``plant`` section).
        cls: The plant config class expected.
        other: The other robot's plant config class.

    Returns:
        The keys that ``other`` has and ``cls`` has not, for a hint that the file is the other
        robot's plant; ``""`` when the file has none of them (or cannot be read).
    """
    import dataclasses

    import yaml

    from msarm.errors import ConfigError
    from msarm.io.config import _load_yaml

    try:
        raw = _load_yaml(Path(spec).read_text(encoding="utf-8"), spec)
    except (OSError, UnicodeDecodeError, yaml.YAMLError, ConfigError):
        return ""
    if isinstance(raw, dict) and isinstance(raw.get("plant"), dict):
        raw = raw["plant"]  # a run's config.yaml
    if not isinstance(raw, dict):
        return ""
    own = {f.name for f in dataclasses.fields(cls)}
    theirs = {f.name for f in dataclasses.fields(other)} - own
    keys = [repr(k) for k in raw if k in theirs]
    if not keys:
        return ""
    return ("key " if len(keys) == 1 else "keys ") + ", ".join(keys)


def console(width: int = 120) -> Console:
    """A rich console; a wide one when output is not a terminal (tables stay readable).

    Args:
        width: Columns when output is not a terminal (piped, logged): as wide as the widest
            table the command prints, so that none is cut.
    """
    out = Console()
    return out if out.is_terminal else Console(width=width)


class RepeatedWarnings:
    """Tells the first of a warning about several log files from its repeats.

    A warning ``"<file>: <what>"`` about a log (``.parquet``) or a table being imported
    (``.csv``, ``.tsv``, ``.txt``, compressed or not; any case) is shown for its first file;
    the same ``<what>`` for further files is only counted, and :meth:`summary` names those
    files once. Any other warning is shown once: the same words again (a check made before a
    run and again by the run) add nothing.
    """

    _ABOUT_A_FILE = re.compile(
        r"^(?P<source>\S+\.(?:parquet|(?:csv|tsv|txt)(?:\.(?:gz|bz2|xz|zst))?)): (?P<what>.*)$",
        re.DOTALL | re.IGNORECASE,
    )

    def __init__(self) -> None:
        self.sources: dict[str, list[str]] = {}
        self.shown: set[str] = set()

    def first(self, text: str) -> bool:
        """Whether ``text`` is to be shown (not the repeat of a warning about another file)."""
        match = self._ABOUT_A_FILE.match(text)
        if match is None:
            new = text not in self.shown
            self.shown.add(text)
            return new
        sources = self.sources.setdefault(match["what"], [])
        sources.append(match["source"])
        return len(sources) == 1

    def summary(self) -> list[str]:
        """One line per repeated warning: how many more files, and which."""
        lines = []
        for what, sources in self.sources.items():
            if len(sources) > 1:
                head = what if len(what) <= 60 else what[:57] + "..."
                lines.append(
                    f"the same ({head}) for {len(sources) - 1} more log(s): "
                    + ", ".join(sources[1:])
                )
        return lines
