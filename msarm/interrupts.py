"""SIGTERM as an exception that unwinds a command, also out of a solver that swallows it.

The command line (:func:`msarm.cli.main`) installs :func:`on_sigterm` as the SIGTERM handler:
it raises :class:`Terminated` where Python code runs. A solver in compiled code that checks
for signals while it works (IPOPT through casadi does) runs the handler itself, catches the
exception and returns early with a failure status: the command would then go on with a
half-finished fit. So the handler also records the request, and code after such a solver
calls :func:`raise_if_terminated`, which raises it again.

A script of its own (the examples) wraps its work in :func:`sigterm_raises`: SIGTERM then
unwinds it the same way (its temporary folders and files are removed) instead of ending the
process where it stands.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

__all__ = [
    "Terminated",
    "clear",
    "on_sigterm",
    "raise_if_terminated",
    "sigterm_raises",
    "signals_held",
]

#: The exit code of a SIGTERM received and not yet acted on (None: none received).
_pending: int | None = None


class Terminated(SystemExit):
    """SIGTERM received: unwinds the command (its ``finally`` and ``except`` blocks run)."""


def on_sigterm(signum: int, frame: object) -> None:
    """SIGTERM handler: record the request and raise :class:`Terminated` (exit 128 + signum)."""
    import signal

    global _pending
    _pending = 128 + signum
    # a second SIGTERM while unwinding ends the process the usual way
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    raise Terminated(_pending)


def raise_if_terminated() -> None:
    """Raise :class:`Terminated` again if a SIGTERM came.

    Call it after a solver that may have caught the handler's exception.

    Raises:
        Terminated: A SIGTERM was received since the last :func:`clear`.
    """
    if _pending is not None:
        raise Terminated(_pending)


def clear() -> None:
    """Forget a received SIGTERM (the command line does at the start and end of a command)."""
    global _pending
    _pending = None


@contextmanager
def sigterm_raises() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` (exit code 143).

    The block's ``with`` and ``finally`` clauses then run (a ``TemporaryDirectory`` is
    removed, an atomic write's temporary file too); catch :class:`Terminated` outside the
    block to print a line and return its ``code``. On the way out the previous handler is
    restored and a received SIGTERM forgotten. Outside the main thread, where no handler can
    be set, the block runs with the handler as it is. Not to be nested: an inner block
    forgets a SIGTERM the outer one has received and not yet acted on.

    Yields:
        Nothing; the block runs with the handler installed.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    clear()
    previous = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)
        clear()


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back within the block; they act when it ends.

    For a few quick steps that must happen all or none, such as moving a report's files into
    place: a Ctrl-C or SIGTERM between two of them would leave a mix of two reports. Within
    the block the two signals are only recorded; when it ends (also when it raises) the
    previous handlers are put back and each recorded signal is raised again, so that its
    handler acts then (a ``KeyboardInterrupt``, :class:`Terminated`, or the process ends).
    Outside the main thread, where no handler can be set, the block runs as it is.

    Yields:
        Nothing; the block runs with the two signals recorded, not acted on.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def record(signum: int, frame: object) -> None:
        received.append(signum)

    held = (signal.SIGINT, signal.SIGTERM)
    previous = {number: signal.signal(number, record) for number in held}
    try:
        yield
    finally:
        for number, handler in previous.items():
            # None: a handler set from C, which Python cannot put back; the default then
            signal.signal(number, signal.SIG_DFL if handler is None else handler)
        # SIGTERM first: its handler raises, and a SIGINT raised after it would never act
        for number in sorted(set(received), key=lambda n: n != signal.SIGTERM):
            signal.raise_signal(number)
