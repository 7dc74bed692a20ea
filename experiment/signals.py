"""SIGTERM and SIGHUP end a session as Ctrl-C does.

A shutdown, a closed terminal or ``kill PID`` sends SIGTERM or SIGHUP, whose default action
ends Python at once: the shell prints a bare "Terminated", the run's end event and its log are
never written, and nobody is told what was kept. While a session runs, :func:`ending_signals`
turns the first of them into :class:`SessionSignal` (a ``KeyboardInterrupt``), so the run ends
through the same path as Ctrl-C: every answered trial is kept (each was appended and fsynced
when answered), the end event names the signal, the run log is written, and the command line
prints what was kept and how to continue. A second signal during that cleanup is ignored, so the
log is finished; ``kill -9`` cannot be caught (the answers are kept all the same).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["ENDING_SIGNALS", "SessionSignal", "ending_signals"]

#: Signals that end a session cleanly (SIGINT is Python's own KeyboardInterrupt).
ENDING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


class SessionSignal(KeyboardInterrupt):
    """The run was ended by a signal; ``name`` is e.g. ``"SIGTERM"``, ``signum`` its number."""

    def __init__(self, signum: int):
        self.signum = int(signum)
        self.name = signal.Signals(signum).name
        super().__init__(self.name)


@contextmanager
def ending_signals() -> Iterator[None]:
    """Raise :class:`SessionSignal` on the first SIGTERM or SIGHUP while the block runs.

    Only the main thread can set signal handlers; elsewhere the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    raised = []

    def handler(signum, _frame):
        if raised:  # the run is already ending: let its log be written
            return
        raised.append(signum)
        raise SessionSignal(signum)

    old = {sig: signal.signal(sig, handler) for sig in ENDING_SIGNALS}
    try:
        yield
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)
