"""SIGINT and SIGTERM held back over steps that must happen all or none (signals_held)."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from msarm import interrupts


@pytest.fixture
def sigterm_raises():
    with interrupts.sigterm_raises():
        yield


def test_a_signal_in_the_block_acts_when_it_ends(sigterm_raises):
    done = []
    with pytest.raises(interrupts.Terminated) as caught:
        with interrupts.signals_held():
            os.kill(os.getpid(), signal.SIGTERM)
            done.append("after the signal")  # the block is not cut
    assert done == ["after the signal"]
    assert caught.value.code == 143
    assert signal.getsignal(signal.SIGTERM) is not None  # a handler is back in place


def test_both_signals_give_sigterm_not_only_the_ctrl_c(sigterm_raises):
    """SIGINT raised first made a KeyboardInterrupt and the SIGTERM was lost (exit 130)."""
    with pytest.raises(interrupts.Terminated):
        with interrupts.signals_held():
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGTERM)


def test_nested_blocks_and_a_quiet_block_change_nothing(sigterm_raises):
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with interrupts.signals_held(), interrupts.signals_held():
        pass
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    with pytest.raises(KeyboardInterrupt):
        with interrupts.signals_held():
            with interrupts.signals_held():
                os.kill(os.getpid(), signal.SIGINT)
            # the inner block ends: its own handler, the outer's recorder, takes the signal


def test_outside_the_main_thread_the_block_runs_as_it_is():
    seen = []

    def work() -> None:
        with interrupts.signals_held():
            seen.append(signal.getsignal(signal.SIGINT))

    thread = threading.Thread(target=work)
    thread.start()
    thread.join()
    assert seen == [signal.getsignal(signal.SIGINT)]
