"""Exceptions raised by msarm: each names what is wrong and what was expected."""


class MsarmError(Exception):
    """Base class of every error msarm raises on purpose."""


class ModelError(MsarmError):
    """A robot model file is missing, malformed, or its two engines disagree."""


class InputError(MsarmError, ValueError):
    """An argument has the wrong shape, a NaN, or a value outside its valid range."""


class ConfigError(MsarmError, ValueError):
    """A config file or mapping has an unknown, missing or mistyped key (named, with its file)."""


class LogError(MsarmError, ValueError):
    """A run log or its sidecar is missing or breaks the log schema (file and column named)."""


class MsarmWarning(UserWarning):
    """Base class of every warning msarm gives on purpose (the CLI prints it as one line).

    The message says what limits a result and what is still done.
    """


class ModelWarning(MsarmWarning):
    """A robot model loads, but a value in it looks like a unit slip (named, with its file)."""
