"""A simulated participant at the keyboard and mouse: real X11 input events through XTEST.

``--simulate OBSERVER`` starts a :class:`SimulatedHand` beside the session loop. For each trial
it asks the observer (``experiment.observers``) for its two answers and then moves the X
pointer, drags each slider's marker and presses space by XTEST requests to the X server (Xvfb in
tests and the demo). PsychoPy sees ordinary X events: the same pyglet mouse handling, the same
``Slider`` and the same psychtoolbox keyboard as with a person. The hand only *reads* the app's
frame counter, to give each event a couple of frames to be seen.
"""

from __future__ import annotations

import queue
import threading
import time
from typing import Self

import numpy as np

__all__ = ["SimulatedHand", "XTestInput", "start_hand"]

#: X11 keysyms of the keys the hand presses.
_KEYSYMS = {"space": 0x0020, "escape": 0xFF1B}


class XTestInput:
    """A connection to the X server that injects pointer and key events (a context manager)."""

    def __init__(self, display_name: str | None = None):
        from Xlib import display as xdisplay
        from Xlib.ext import xtest

        self._xtest = xtest
        self.d = xdisplay.Display(display_name)
        if not self.d.has_extension("XTEST"):
            self.d.close()
            raise RuntimeError("the X server has no XTEST extension; simulated input needs it "
                               "(Xvfb has it by default)")

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.d is not None:
            self.d.close()
            self.d = None

    def _send(self, kind, detail=0, **kw) -> None:
        self._xtest.fake_input(self.d, kind, detail, **kw)
        self.d.sync()

    def move(self, x: float, y: float) -> None:
        from Xlib import X

        self._send(X.MotionNotify, x=round(x), y=round(y))

    def button(self, press: bool) -> None:
        from Xlib import X

        self._send(X.ButtonPress if press else X.ButtonRelease, 1)

    def key(self, name: str, press: bool) -> None:
        from Xlib import X

        code = self.d.keysym_to_keycode(_KEYSYMS[name])
        self._send(X.KeyPress if press else X.KeyRelease, code)


class SimulatedHand(threading.Thread):
    """Answers trials with an observer by driving the mouse and keyboard (a daemon thread).

    Parameters
    ----------
    observer : experiment.Observer
    rng : numpy.random.Generator
        Trial noise, response times, drag paths.
    frames : callable
        Returns the app's flip count.
    fast : bool
        No waiting for the observer's response time; each event waits only for frames.
    early_space_probability : float
        Chance per trial of pressing space after the first slider only (exercises the hint).
    quit_at_trial : int or None
        On this trial, press Esc twice (pause, then confirm quitting) instead of answering.
    """

    def __init__(self, observer, rng: np.random.Generator, frames, *, fast: bool,
                 early_space_probability: float = 0.0, quit_at_trial: int | None = None):
        super().__init__(name="simulated-hand", daemon=True)
        self.observer, self.rng, self.frames, self.fast = observer, rng, frames, fast
        self.early = early_space_probability
        self.quit_at_trial = quit_at_trial
        self.jobs: queue.Queue = queue.Queue()
        self.intended: dict[int, tuple[float, float]] = {}
        self.error: BaseException | None = None
        self._stop = threading.Event()

    def trial(self, trial_row: dict, geometry: dict) -> None:
        """Called by the session at the trial's onset flip: answer this trial."""
        self.jobs.put((dict(trial_row), geometry))

    def stop(self) -> None:
        self._stop.set()
        self.jobs.put(None)

    def _wait_frames(self, n: int = 2) -> None:
        target = self.frames() + n
        t_end = time.monotonic() + 30.0
        while self.frames() < target:
            if self._stop.is_set():
                raise SystemExit
            if time.monotonic() > t_end:
                raise TimeoutError("the session window stopped flipping")
            time.sleep(0.001)

    def run(self) -> None:
        try:
            with XTestInput() as x:
                while not self._stop.is_set():
                    job = self.jobs.get()
                    if job is None:
                        break
                    self._answer(x, *job)
        except SystemExit:
            pass
        except Exception as exc:  # noqa: BLE001 -- reported by the session, which then stops
            self.error = exc

    def _press(self, x: XTestInput, key: str) -> None:
        x.key(key, True)
        self._wait_frames()
        x.key(key, False)

    def _drag(self, x: XTestInput, geometry: dict, name: str, value: float) -> None:
        """Press on the slider's line, drag the marker to ``value``, release.

        Each step waits two flips: an event sent just after one flip's event dispatch is only
        seen at the next, so two flips guarantee the app drew a frame with it. With ``fast``,
        the press and the drag to the target go in one step (the X server still gets press,
        motion with the button held, release; the app sees the drag in one frame).
        """
        x0, x1, y = geometry[name]
        lo, hi = geometry["min"], geometry["max"]
        target = x0 + (value - lo) / (hi - lo) * (x1 - x0)
        start = self.rng.uniform(x0, x1)
        x.move(start, y + self.rng.uniform(-2, 2))
        x.button(True)
        if not self.fast:
            self._wait_frames()
        x.move(target, y)
        self._wait_frames()
        x.button(False)
        self._wait_frames()

    def _answer(self, x: XTestInput, row: dict, geometry: dict) -> None:
        if self.quit_at_trial is not None and int(row["trial"]) == self.quit_at_trial:
            self._press(x, "escape")
            self._wait_frames()
            self._press(x, "escape")
            return
        gloss, depth = self.observer.respond(row, self.rng)
        self.intended[int(row["trial"])] = (gloss, depth)
        if not self.fast:
            time.sleep(float(self.observer.response_time_s(self.rng)) * 0.5)
        order = ["gloss", "depth"] if self.rng.random() < 0.5 else ["depth", "gloss"]
        values = {"gloss": gloss, "depth": depth}
        self._drag(x, geometry, order[0], values[order[0]])
        if self.rng.random() < self.early:
            self._press(x, "space")  # too early: the app must show its hint and wait
        if not self.fast:
            time.sleep(float(self.observer.response_time_s(self.rng)) * 0.5)
        self._drag(x, geometry, order[1], values[order[1]])
        self._press(x, "space")


def start_hand(req, prep, disp, log: dict) -> SimulatedHand:
    """Start the simulated observer's hand for a session's run (``req``: its request, ``prep``:
    what the pre-flight prepared, ``log``: the run's log, which records the observer and the
    seed ``[participant seed or --seed, session, run]``)."""
    from experiment.plan import participant_seed

    base = req.seed if req.seed is not None else participant_seed(req.participant)
    run = log["run"]
    hand = SimulatedHand(prep.observer, np.random.default_rng([base, prep.session, run]),
                         lambda: disp.frame_count, fast=req.fast,
                         early_space_probability=req.early_space_probability,
                         quit_at_trial=req.quit_at_trial)
    hand.start()
    log["simulated"] = {"observer": prep.observer.to_dict(), "seed": [base, prep.session, run],
                        "input": "XTEST events into the X display"}
    return hand
