"""Hold an interruption until a piece of work that cannot be resumed half-way is recorded.

Why: a screened batch at 101x102 is one vmapped JAX call of minutes. Ctrl-C, SIGTERM or a
campaign's leg deadline (SIGALRM) cannot stop it half-way anyway (Python runs a signal handler
only when the call returns), but the handler then raised before the batch's runs reached the
record file, so the minutes were lost. Inside :func:`deferred_interrupts` the first such signal
is noted and acted on (its own handler called: KeyboardInterrupt, the campaign's LegEnded) as
the block ends, after the work is recorded; a second one acts at once, for a user who will not
wait.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

# The signals that stop a run: Ctrl-C, a scheduler's or a session's end, a campaign's deadline.
SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGALRM)


def _act(signum: int, handler: Any, frame: Any) -> None:
    """Do what ``handler`` would have done with ``signum``."""
    if callable(handler):
        handler(signum, frame)
    elif handler == signal.SIG_DFL and signum == signal.SIGINT:
        raise KeyboardInterrupt
    elif handler == signal.SIG_DFL:  # the default would have ended the process
        signal.signal(signum, signal.SIG_DFL)
        signal.raise_signal(signum)


@contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Run the block with SIGINT, SIGTERM and SIGALRM held (module docstring). Outside the main
    thread (where Python delivers no signals) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in SIGNALS}
    pending: list[tuple[int, Any]] = []

    def note(signum: int, frame: Any) -> None:
        if pending:  # the second one: act now
            _restore()
            _act(signum, old[signum], frame)
            return
        pending.append((signum, frame))

    def _restore() -> None:
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)

    for s, h in old.items():
        if h != signal.SIG_IGN:
            signal.signal(s, note)
    try:
        yield
    finally:
        _restore()
    if pending:
        signum, frame = pending[0]
        _act(signum, old[signum], frame)
