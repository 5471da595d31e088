"""YAML configs read into frozen dataclasses, and the resolved config written back.

A config class is a (frozen) dataclass whose field types are among:

- ``float`` (a YAML int is accepted and converted), ``int``, ``bool``, ``str``, ``pathlib.Path``;
- ``tuple[X, ...]`` and ``tuple[X, Y]`` of those (a YAML list), ``list[X]``;
- nested dataclasses (a YAML mapping), ``dict[str, X]`` (a mapping of any keys to ``X``);
- ``X | None`` / ``Optional[X]`` (YAML ``null``), ``Literal[...]``, and ``Any`` (kept as is).

Every key of the YAML mapping must name a field; a field without a default must be given. A
key a nested mapping omits takes the value of the block the enclosing class gives by default
(a recipe's ``controller`` defaults to tuned gains: ``controller: {kd: ...}`` keeps its
``kp`` and ``ki``), else the nested class's own default. Every
mistake raises :class:`msarm.errors.ConfigError` naming the source (file path, or
``<mapping>``), the dotted key path (``effects.sheath_friction.mu``) and what was expected:
the valid keys for an unknown one, the type for a mistyped one. A ``ValueError`` or
``TypeError`` raised by a dataclass's ``__post_init__`` is reported the same way, with the key
path of that dataclass.

YAML floats: PyYAML follows YAML 1.1, where ``1e-4`` (no dot) is a string. The loader used here
also reads such exponent notation as a float (YAML 1.2 behaviour), so ``mu: 8e-2`` works.

:func:`write_config` writes the resolved config (every field, defaults included) next to a
result; :func:`load_config` of that file gives back an equal object.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import re
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml

from msarm.errors import ConfigError, InputError
from msarm.io.atomic import write_bytes_atomic

__all__ = [
    "check_field_types",
    "check_numbers",
    "check_plant_name",
    "config_to_dict",
    "dump_config",
    "folder_instead_of_file",
    "MISSING",
    "join_differences",
    "load_config",
    "value_differences",
    "write_config",
    "yaml_problem",
]

T = TypeVar("T")

#: Label of a config given as a mapping rather than a file.
_MAPPING_SOURCE = "<mapping>"


@functools.cache
def _typed_fields(cls: type) -> tuple[tuple[str, type], ...]:
    """The fields of a config dataclass that are switches (bool) or blocks (dataclasses)."""
    hints = typing.get_type_hints(cls)
    return tuple(
        (f.name, hints[f.name])
        for f in dataclasses.fields(cls)
        if hints[f.name] is bool
        or (isinstance(hints[f.name], type) and dataclasses.is_dataclass(hints[f.name]))
    )


def check_field_types(config: object) -> None:
    """Refuse a switch that is not a bool, or a block that is not its dataclass.

    For a ``__post_init__``: a config built in Python is not checked by the YAML loader, and
    ``enabled="false"`` (a non-empty string, so true) would switch an effect on.

    Args:
        config: The config dataclass instance.

    Raises:
        InputError: The first offending field, named with what was expected (a config file's
            loader adds the file and the key).
    """
    for name, kind in _typed_fields(type(config)):
        value = getattr(config, name)
        if kind is bool:
            if not isinstance(value, bool | np.bool_):
                raise InputError(f"{name} must be true or false (a bool), got {value!r}")
        elif not isinstance(value, kind):
            raise InputError(
                f"{name} must be a {kind.__name__}, got {type(value).__name__} {value!r}"
            )


def check_numbers(
    config: object,
    positive: tuple[str, ...] = (),
    non_negative: tuple[str, ...] = (),
    finite: tuple[str, ...] = (),
) -> None:
    """Refuse a config field that would make a run silently wrong, for a ``__post_init__``.

    Args:
        config: The config dataclass instance.
        positive: Fields that must be finite and > 0.
        non_negative: Fields that must be finite and >= 0.
        finite: Fields that must be finite.

    Raises:
        InputError: The first offending field, named with what was expected (a config file's
            loader adds the file and the key).
    """
    for names, ok, expected in (
        (positive, lambda v: v > 0, "a finite value > 0"),
        (non_negative, lambda v: v >= 0, "a finite value >= 0"),
        (finite, lambda v: True, "a finite value"),
    ):
        for name in names:
            value = getattr(config, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise InputError(f"{name} must be a number, got {value!r}")
            if not (math.isfinite(value) and ok(value)):
                raise InputError(f"{name} must be {expected}, got {value}")


def folder_instead_of_file(path: str | Path, expected: str) -> str | None:
    """The message for a folder given where a file is expected, or None.

    A folder is not "not found": it is there, but is not what was asked for. Callers raise
    their own error class with the message (the file named, and what was expected).

    Args:
        path: The path given.
        expected: What was expected, e.g. ``"an MJCF .xml file"``.

    Returns:
        ``"<path> is a folder, expected <expected>"`` when ``path`` is a folder, else None.
    """
    if Path(path).is_dir():
        return f"{path} is a folder, expected {expected}"
    return None


_PLANT_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")


def check_plant_name(name: object) -> None:
    """Refuse a plant name that cannot be one part of an output folder's name.

    Args:
        name: The plant's name: letters, digits, ``_``, ``-``, ``+`` and ``.``, not starting
            with ``.`` or ``-`` (no ``/``, no ``..``, not empty). No ``=``: a cable-robot run
            folder names each controller option ``-KEY=VALUE`` after the plant, so a plant
            ``lab-delta=0.5`` would share its folder with plant ``lab`` and ``delta=0.5``.

    Raises:
        ValueError: Naming the name and what was expected.
    """
    if isinstance(name, str) and "=" in name:
        raise ValueError(
            f"name must be a simple identifier without '=', got {name!r}: run folders end in "
            "-KEY=VALUE for each controller option, so its runs could overwrite another "
            "plant's (a plant 'lab-delta=0.5' writes where plant 'lab' with --option "
            "delta=0.5 does); expected another name"
        )
    if not (isinstance(name, str) and _PLANT_NAME.fullmatch(name)):
        raise ValueError(
            "name must be a simple identifier (letters, digits, '_', '-', '+', '.', not "
            f"starting with '.' or '-'; it names the run folder), got {name!r}"
        )


def yaml_problem(exc: yaml.YAMLError) -> str:
    """One line for a PyYAML error: ``line L, column C: problem (context)``.

    PyYAML's own text spans several lines (the context, its mark, a snippet of the file with
    a caret); line and column here count from 1, as an editor does.

    Args:
        exc: The error PyYAML raised.

    Returns:
        The one-line description.
    """
    problem = getattr(exc, "problem", None)
    if not problem:
        return " ".join(str(exc).split())
    mark = getattr(exc, "problem_mark", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    context = getattr(exc, "context", None)
    text = where + " ".join(problem.split())
    return text + (f" ({' '.join(context.split())})" if context else "")


class _Loader(yaml.SafeLoader):
    """Safe YAML loader that also reads ``1e-4`` (exponent without a dot) as a float."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.VERBOSE,
    ),
    list("-+0123456789."),
)


_MERGE_TAG = "tag:yaml.org,2002:merge"


def _load_yaml(text: str, label: str) -> Any:
    """Parse YAML text with :class:`_Loader`, refusing a key repeated in one mapping.

    PyYAML keeps the last of repeated keys without a word; here the composed node tree is
    checked first. Keys brought in by a merge key (``<<: *anchor``) may be overridden by the
    mapping's own keys (that is what merging is for), so only explicit keys are compared.

    Raises:
        yaml.YAMLError: Not valid YAML.
        ConfigError: A key appears twice in one mapping (file, line and dotted key path named).
    """
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_unique_keys(node, label, "", set())
        return loader.construct_document(node)
    finally:
        loader.dispose()


def _check_unique_keys(node: yaml.Node, label: str, key: str, visited: set[int]) -> None:
    if id(node) in visited:  # an alias of a node already checked (or a recursive one)
        return
    visited.add(id(node))
    if isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _check_unique_keys(item, label, f"{key}[{i}]", visited)
    elif isinstance(node, yaml.MappingNode):
        first: dict[str, int] = {}
        for key_node, value_node in node.value:
            if key_node.tag == _MERGE_TAG:
                _check_unique_keys(value_node, label, key, visited)
                continue
            if not isinstance(key_node, yaml.ScalarNode):
                continue
            name, line = key_node.value, key_node.start_mark.line + 1
            if name in first:
                raise ConfigError(
                    f"{label}: line {line}: key '{_join(key, name)}' appears twice in one "
                    f"mapping (first at line {first[name]}); expected each key once"
                )
            first[name] = line
            _check_unique_keys(value_node, label, _join(key, name), visited)


class _Dumper(yaml.SafeDumper):
    """Safe YAML dumper: block-style mappings, flow-style (one line) lists of scalars."""


def _represent_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = all(not isinstance(v, list | dict) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def load_config(source: str | Path | Mapping[str, Any], cls: type[T]) -> T:
    """Build a config dataclass from a YAML file or an already parsed mapping.

    Args:
        source: Path of a YAML file (``str`` or ``Path``), or a mapping (as parsed from YAML).
            An empty file gives the defaults.
        cls: The dataclass to build (nested dataclasses are built from nested mappings).

    Returns:
        An instance of ``cls``; fields missing from ``source`` take their defaults.

    Raises:
        ConfigError: The file is missing, a folder or not valid YAML, or a key is unknown,
            missing or has a value of the wrong type (the file and the dotted key path are
            named).
        TypeError: ``cls`` is not a dataclass, or has a field type this loader does not
            support (a programming error, not a config error).
    """
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"load_config needs a dataclass type, got {cls!r}")
    if isinstance(source, Mapping):
        data: Any = source
        label = _MAPPING_SOURCE
    elif isinstance(source, str | Path):
        path = Path(source)
        label = str(path)
        folder = folder_instead_of_file(path, "a config file (YAML)")
        if folder is not None:
            raise ConfigError(folder)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise ConfigError(f"{label}: config file not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{label}: cannot read the config file: {exc}") from None
        try:
            data = _load_yaml(text, label)  # a SafeLoader subclass: safe
        except yaml.YAMLError as exc:
            raise ConfigError(f"{label}: not valid YAML: {yaml_problem(exc)}") from None
        if data is None:
            data = {}
    else:
        raise TypeError(f"config source must be a path or a mapping, got {type(source).__name__}")
    return _build_dataclass(data, cls, label, "")


def config_to_dict(obj: Any) -> dict[str, Any]:
    """The plain-data form of a config: what :func:`write_config` writes.

    Dataclasses become dicts (every ``init`` field, in declaration order), tuples and numpy
    arrays become lists, paths become strings, numpy scalars become Python numbers.

    Args:
        obj: A dataclass instance or a mapping.

    Returns:
        A dict of plain Python values (safe for YAML and JSON).

    Raises:
        TypeError: ``obj`` is neither a dataclass instance nor a mapping, or holds a value
            that has no plain-data form.
    """
    if not (dataclasses.is_dataclass(obj) and not isinstance(obj, type)) and not isinstance(
        obj, Mapping
    ):
        raise TypeError(f"config_to_dict needs a dataclass instance or a mapping, got {obj!r}")
    return _to_plain(obj, "")


def dump_config(obj: Any) -> str:
    """The YAML text of a config (see :func:`config_to_dict`), keys in declaration order.

    Args:
        obj: A config dataclass instance or a mapping.

    Returns:
        The YAML document (block style) that :func:`write_config` writes.

    Raises:
        TypeError: ``obj`` has no plain-data form (see :func:`config_to_dict`).
    """
    return yaml.dump(config_to_dict(obj), Dumper=_Dumper, sort_keys=False, default_flow_style=False)


def write_config(obj: Any, path: str | Path) -> Path:
    """Write a config as YAML, atomically (a temporary file in the same folder, then rename).

    Args:
        obj: A config dataclass instance (or a mapping).
        path: Destination file; its folder is created if missing.

    Returns:
        The path written.
    """
    path = Path(path)
    write_bytes_atomic(path, dump_config(obj).encode("utf-8"))
    return path


#: Stands, in :func:`value_differences`, for a key that one side's mapping lacks.
MISSING: Any = object()


def value_differences(before: Any, after: Any, key: str = "") -> list[tuple[str, Any, Any]]:
    """Where two plain values (:func:`config_to_dict`'s form) differ, by dotted key path.

    Mappings are compared key by key (keys only in ``before`` first, then ``after``'s keys in
    order), lists of the same length that hold mappings or lists item by item (``key[i]``);
    anything else is a leaf, which differs when its values differ or its types do (an int and
    a float of the same value are alike; a bool is not a number here).

    Args:
        before: One plain value (a dict, list, number, string, bool or None).
        after: The other.
        key: The path of both (the prefix of every path returned).

    Returns:
        ``(path, before_value, after_value)`` per differing leaf, :data:`MISSING` for a key
        that side lacks; empty when the two are alike.
    """
    if isinstance(before, Mapping) and isinstance(after, Mapping):
        out = [(_join(key, k), before[k], MISSING) for k in before if k not in after]
        for k in after:
            if k not in before:
                out.append((_join(key, k), MISSING, after[k]))
            else:
                out.extend(value_differences(before[k], after[k], _join(key, k)))
        return out
    if (
        isinstance(before, list)
        and isinstance(after, list)
        and len(before) == len(after)
        and any(isinstance(v, Mapping | list) for v in before)
    ):
        out = []
        for i, (a, b) in enumerate(zip(before, after, strict=True)):
            out.extend(value_differences(a, b, f"{key}[{i}]"))
        return out
    numbers = all(isinstance(v, int | float) and not isinstance(v, bool) for v in (before, after))
    if (type(before) is not type(after) and not numbers) or before != after:
        return [(key, before, after)]
    return []


def join_differences(lines: list[str], shown: int) -> str:
    """The first ``shown`` of ``lines`` joined by ``"; "``, then ``"; and N more"`` if cut."""
    more = f"; and {len(lines) - shown} more" if len(lines) > shown else ""
    return "; ".join(lines[:shown]) + more


# --- building -------------------------------------------------------------------------------


def _where(label: str, key: str) -> str:
    return f"{label}: key '{key}'" if key else f"{label}: top level"


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def _type_name(tp: Any) -> str:
    if tp is type(None):
        return "null"
    if isinstance(tp, type) and not typing.get_args(tp):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _field_default(f: dataclasses.Field) -> Any:
    """A dataclass field's default value (``None`` when it has none)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def _build_dataclass(
    data: Any, cls: type[T], label: str, key: str, base: object | None = None
) -> T:
    """``cls`` from a mapping; a key it omits takes ``base``'s value, else the field default.

    ``base`` is the value the enclosing config gives the block when the file omits it (a
    recipe's ``controller: TUNED_CONTROLLER``), so that a block given in part keeps the rest
    of that value, not the block class's own defaults (a recipe that set one gain ran the
    other gains at ``ArmControllerConfig``'s untuned defaults until 2026-11-29).
    """
    if not isinstance(data, Mapping):
        raise ConfigError(
            f"{_where(label, key)}: expected a mapping for {cls.__name__}, "
            f"got {type(data).__name__} {data!r}"
        )
    try:
        hints = typing.get_type_hints(cls)
    except NameError as exc:  # pragma: no cover - a broken config class
        raise TypeError(f"cannot resolve the field types of {cls.__name__}: {exc}") from exc
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    valid = ", ".join(fields) or "(none)"
    for name in data:
        if not isinstance(name, str) or name not in fields:
            hint = ""
            if isinstance(name, str):
                close = difflib.get_close_matches(name, fields, n=1)
                if close:
                    hint = f" (did you mean '{close[0]}'?)"
            raise ConfigError(
                f"{label}: unknown key '{_join(key, str(name))}'{hint}; "
                f"valid keys{' of ' + key if key else ''}: {valid}"
            )
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        sub = _join(key, name)
        if name in data:
            inner = getattr(base, name) if base is not None else _field_default(f)
            kwargs[name] = _convert(data[name], hints[name], label, sub, inner)
        elif base is not None:
            kwargs[name] = getattr(base, name)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(
                f"{label}: missing key '{sub}' ({_type_name(hints[name])}, no default)"
            )
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{_where(label, key)}: invalid {cls.__name__}: {exc}") from exc


def _convert(value: Any, tp: Any, label: str, key: str, base: Any = None) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)

    def wrong(expected: str) -> ConfigError:
        return ConfigError(
            f"{label}: key '{key}' expects {expected}, got {type(value).__name__} {value!r}"
        )

    if tp is Any:
        return value
    if origin is typing.Union or origin is types.UnionType:
        if value is None:
            if type(None) in args:
                return None
            raise wrong(_type_name(tp))
        members = [a for a in args if a is not type(None)]
        errors = []
        for member in members:
            try:
                return _convert(value, member, label, key, base)
            except ConfigError as exc:
                errors.append(exc)
        if len(errors) == 1:
            raise errors[0]
        raise wrong(_type_name(tp))
    if origin is typing.Literal:
        if any(type(value) is type(a) and value == a for a in args):
            return value
        raise wrong("one of " + ", ".join(repr(a) for a in args))
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return _build_dataclass(value, tp, label, key, base if isinstance(base, tp) else None)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise wrong("a number (float)")
        try:
            return float(value)
        except OverflowError:  # an integer of 400 digits
            raise wrong("a finite number (float)") from None
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise wrong("an integer")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise wrong("a boolean (true or false)")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise wrong("a string")
        return value
    if tp is Path:
        if not isinstance(value, str | Path):
            raise wrong("a path (string)")
        return Path(value)
    if origin is tuple or origin is list:
        if not isinstance(value, list | tuple):
            raise wrong(f"a list ({_type_name(tp)})")
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis) and args:
            if len(value) != len(args):
                raise wrong(f"a list of {len(args)} items ({_type_name(tp)})")
            items = [
                _convert(v, a, label, f"{key}[{i}]")
                for i, (v, a) in enumerate(zip(value, args, strict=True))
            ]
        else:
            item_tp = args[0] if args else Any
            items = [_convert(v, item_tp, label, f"{key}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict or origin is Mapping or tp is dict:
        if not isinstance(value, Mapping):
            raise wrong(f"a mapping ({_type_name(tp)})")
        key_tp, value_tp = args if args else (Any, Any)
        out = {}
        for k, v in value.items():
            if key_tp is str and not isinstance(k, str):
                raise ConfigError(
                    f"{label}: key '{key}' expects string keys, got {type(k).__name__} {k!r}"
                )
            out[k] = _convert(v, value_tp, label, _join(key, str(k)))
        return out
    raise TypeError(f"{label}: key '{key}': unsupported config field type {tp!r}")


# --- plain data -----------------------------------------------------------------------------


def _to_plain(obj: Any, key: str) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {
            f.name: _to_plain(getattr(obj, f.name), _join(key, f.name))
            for f in dataclasses.fields(obj)
            if f.init
        }
    if isinstance(obj, Mapping):
        return {k: _to_plain(v, _join(key, str(k))) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_to_plain(v, f"{key}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, np.ndarray):
        return _to_plain(obj.tolist(), key)
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if obj is None or isinstance(obj, bool | int | float | str):
        return obj
    raise TypeError(f"config value '{key}' of type {type(obj).__name__} has no plain-data form")
