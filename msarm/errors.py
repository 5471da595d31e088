"""Exceptions raised by msarm: each names what is wrong and what was expected."""


class MsarmError(Exception):
    """Base class of every error msarm raises on purpose."""


class ModelError(MsarmError):
    """A robot model file is missing, malformed, or its two engines disagree."""


class InputError(MsarmError, ValueError):
    """An argument has the wrong shape, a NaN, or a value outside its valid range."""
