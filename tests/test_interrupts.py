"""nca_qd.interrupts: an interruption waits until the work in hand is recorded (a screened batch
is minutes of one JAX call that cannot be resumed half-way), then acts as it would have."""

from __future__ import annotations

import os
import signal

import pytest

from nca_qd.interrupts import deferred_interrupts


@pytest.fixture(autouse=True)
def _ctrl_c(ctrl_c_raises):
    """Every test here: Ctrl-C raises KeyboardInterrupt (conftest.py)."""


def test_ctrl_c_and_sigterm_act_after_the_block_not_inside_it():
    done = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        old = signal.getsignal(signal.SIGTERM)

        def raise_interrupt(signum, frame):
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, raise_interrupt)  # as main_guard installs it
        try:
            with pytest.raises(KeyboardInterrupt):
                with deferred_interrupts():
                    os.kill(os.getpid(), sig)
                    done.append(sig)  # reached: the signal waits for the block's end
        finally:
            signal.signal(signal.SIGTERM, old)
    assert done == [signal.SIGINT, signal.SIGTERM]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers restored


def test_a_campaigns_deadline_is_its_own_handlers_exception_after_the_block():
    class LegEnded(KeyboardInterrupt):
        pass

    def ring(signum, frame):
        raise LegEnded

    old = signal.signal(signal.SIGALRM, ring)
    done = []
    try:
        with pytest.raises(LegEnded):
            with deferred_interrupts():
                signal.raise_signal(signal.SIGALRM)
                done.append("recorded")
        assert signal.getsignal(signal.SIGALRM) is ring
    finally:
        signal.signal(signal.SIGALRM, old)
    assert done == ["recorded"]


def test_a_second_signal_acts_at_once_and_none_acts_without_one():
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with deferred_interrupts():
            os.kill(os.getpid(), signal.SIGINT)
            reached.append(1)
            os.kill(os.getpid(), signal.SIGINT)
            reached.append(2)  # not reached: the second Ctrl-C does not wait
    assert reached == [1]
    with deferred_interrupts():
        reached.append(3)
    assert reached == [1, 3]
