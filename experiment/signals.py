"""SIGTERM and SIGHUP end a session as Ctrl-C does.

A shutdown, a closed terminal or ``kill PID`` sends SIGTERM or SIGHUP, whose default action
ends Python at once: the shell prints a bare "Terminated", the run's end event and its log are
never written, and nobody is told what was kept. While a session runs, :func:`ending_signals`
turns the first of them into :class:`SessionSignal` (a ``KeyboardInterrupt``), so the run ends
through the same path as Ctrl-C: every answered trial is kept (each was appended and fsynced
when answered), the end event names the signal, the run log is written, and the command line
prints what was kept and how to continue. A second signal during that cleanup is ignored, so the
log is finished; ``kill -9`` cannot be caught (the answers are kept all the same).

A trial is committed in several writes (its CSV row, the run's own count, its frame intervals).
:func:`held_signals` holds a signal (and Ctrl-C) that arrives between them until the commit is
whole, so the line printed at the end ("N of M trials are saved"), the run history and the run
log all count the same trials as the session file (a SIGTERM landing just after a row's write
once printed "0 of 6 saved" beside a file holding 1).

Once the run's end has begun (:func:`run_ending`: its last answer is in, or it was quit or
interrupted), a signal is recorded and no longer raised, so the run's log, its end event and the
window's closing are finished: an operator closing the window with Ctrl-C right after the last
answer once left a complete session with no log and a run history that never ended.
"""

from __future__ import annotations

import ctypes
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["ENDING_SIGNALS", "SessionSignal", "ending_signals", "held_signals", "run_ending",
           "unwrapped_signals"]

#: Signals that end a session cleanly (SIGINT is Python's own KeyboardInterrupt).
ENDING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)

#: Signals held by the innermost :func:`held_signals` block (a stack: one list per block).
_HELD: list[list[int]] = []
#: One record per :func:`ending_signals` block: the signals that arrived after
#: :func:`run_ending` (``None`` before it was called).
_BLOCKS: list[dict] = []


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
    block = {"late": None, "raised": raised}

    def handler(signum, _frame):
        if block["late"] is not None:  # the run's end has begun: recorded, not raised
            block["late"].append(signum)
            return
        if raised:  # the run is already ending: let its log be written
            return
        if _HELD:  # a trial is being committed: raised when its last write is done
            _HELD[-1].append(signum)
            return
        raised.append(signum)
        raise SessionSignal(signum)

    old = {sig: signal.signal(sig, handler) for sig in ENDING_SIGNALS}
    old[signal.SIGINT] = signal.getsignal(signal.SIGINT)
    _BLOCKS.append(block)
    try:
        yield
    finally:
        _BLOCKS.pop()
        for sig, previous in old.items():
            signal.signal(sig, previous)


def run_ending() -> list[int]:
    """From now until the innermost :func:`ending_signals` block exits, SIGTERM, SIGHUP and
    Ctrl-C are recorded in the list returned, not raised: the run is ending, and its log, its
    end event and the window's closing are finished first.

    Outside such a block (or the main thread) nothing changes and the list stays empty.
    """
    if threading.current_thread() is not threading.main_thread() or not _BLOCKS:
        return []
    block = _BLOCKS[-1]
    if block["late"] is None:
        late: list[int] = []
        block["late"] = late
        signal.signal(signal.SIGINT, lambda signum, _frame: late.append(signum))
    return block["late"]


@contextmanager
def held_signals() -> Iterator[None]:
    """Hold SIGTERM, SIGHUP and Ctrl-C that arrive while the block runs; raise the first of
    them (as :class:`SessionSignal` or ``KeyboardInterrupt``) once the block has finished.

    Wrap the writes that together commit one trial. A block that raises keeps its own error
    (the held signal is dropped: the run is ending anyway). Outside the main thread, or
    outside :func:`ending_signals`, SIGTERM and SIGHUP are not held (their default ends the
    process at once); Ctrl-C is held all the same.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []

    def hold(signum, _frame):
        held.append(signum)

    old_int = signal.signal(signal.SIGINT, hold)
    _HELD.append(held)
    try:
        yield
    finally:
        _HELD.pop()
        signal.signal(signal.SIGINT, old_int)
    if held:
        signum = held[0]
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        handler = signal.getsignal(signum)
        if callable(handler):
            handler(signum, None)


@contextmanager
def unwrapped_signals() -> Iterator[None]:
    """Raise a signal that a C library's ctypes call wrapped as what it is.

    A Python signal handler runs between bytecodes, also inside the Python code that converts a
    ctypes call's arguments (pyglet's, under PsychoPy's window); ctypes then reports the
    handler's exception as ``ctypes.ArgumentError("argument 1: <class
    '...SessionSignal'>: SIGTERM")``, and the run ended with exit 1 and no word on what was
    kept. Inside this block such an error is raised again as the :class:`SessionSignal` (or
    ``KeyboardInterrupt``) it stands for; any other ``ArgumentError`` is left as it is.
    """
    try:
        yield
    except ctypes.ArgumentError as exc:
        text = str(exc)
        if "SessionSignal" in text:
            raise SessionSignal(_wrapped_signal(text)) from exc
        if "KeyboardInterrupt" in text:
            raise KeyboardInterrupt from exc
        raise


def _wrapped_signal(text: str) -> int:
    """The signal a wrapped :class:`SessionSignal`'s text names (its last word, e.g. SIGTERM),
    else the one the innermost :func:`ending_signals` block raised, else SIGTERM."""
    name = text.rsplit(":", 1)[-1].strip()
    if name in signal.Signals.__members__:
        return int(signal.Signals[name])
    raised = _BLOCKS[-1]["raised"] if _BLOCKS else []
    return int(raised[0]) if raised else int(signal.SIGTERM)
