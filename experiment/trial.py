"""One trial at the CRT: the stimulus and two sliders until a valid answer, as named phases.

:func:`run_trial` shows a trial (:func:`_show_trial`) until space with both sliders set; Esc
pauses (:func:`_pause`): Esc again quits, space shows the trial again from its start. The answer
is a frozen :class:`TrialResult`. Only the Slider's public API is used (``rating``,
``markerPos``, ``getHistory()``, and its ``mouse`` for the button state).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

__all__ = ["HINT_S", "TrialResult", "run_trial"]

#: How long the "set both sliders" hint stays up after an early space press (s).
HINT_S = 2.0


@dataclass(frozen=True)
class TrialResult:
    """One answered trial, as the window saw it.

    Attributes
    ----------
    gloss_match, depth_match : float
        Slider ratings, raw units in the design's [slider.min, slider.max].
    rt_s : float
        Stimulus onset to the space press (s).
    onset_s : float
        Stimulus onset on the session clock, at the flip (s).
    dropped_frames : int
        Frames dropped while the trial was on screen.
    gloss_history, depth_history : tuple of (float, float)
        PsychoPy's slider histories, (rating, time s).
    gloss_trace, depth_trace : tuple of (float, float)
        Marker positions at every frame they changed, (position, s since onset).
    early_space_s : tuple of float
        Space presses before both sliders were set (s since onset).
    pauses : tuple of (float, float)
        Pauses (Esc) as (start, end), s since onset of the trial's first showing.
    screenshot_taken : bool
        The screenshot was saved during this trial.
    """

    gloss_match: float
    depth_match: float
    rt_s: float
    onset_s: float
    dropped_frames: int
    gloss_history: tuple
    depth_history: tuple
    gloss_trace: tuple
    depth_trace: tuple
    early_space_s: tuple
    pauses: tuple
    screenshot_taken: bool = False

    def slider_record(self) -> dict:
        """The trial's line of the slider-histories file (without the row's identifiers)."""
        return {"onset_s": self.onset_s,
                "gloss_history": [list(h) for h in self.gloss_history],
                "depth_history": [list(h) for h in self.depth_history],
                "gloss_trace": [list(h) for h in self.gloss_trace],
                "depth_trace": [list(h) for h in self.depth_trace],
                "early_space_s": list(self.early_space_s),
                "pauses": [list(p) for p in self.pauses]}


def _sliders_settled(disp) -> bool:
    """Both sliders rated and the mouse button up (no marker being dragged)."""
    sliders = (disp.gloss_slider, disp.depth_slider)
    return (all(s.rating is not None for s in sliders)
            and not any(s.mouse.getPressed()[0] for s in sliders))


def _record_traces(disp, traces: dict, now_s: float) -> None:
    """Add each slider's marker position when it changed since the last frame."""
    for name, s in (("gloss", disp.gloss_slider), ("depth", disp.depth_slider)):
        pos = s.markerPos
        if pos is not None and (not traces[name] or traces[name][-1][0] != pos):
            traces[name].append((float(pos), now_s))


def run_trial(disp, row: dict, clock, hand, screenshot) -> TrialResult | None:
    """Show one trial until a valid response, or None when the operator confirms quitting.

    A pause (Esc, then space) shows the trial again from its start; space counts only once
    both sliders are set (an early press shows a hint for ``HINT_S`` and is recorded).
    """
    pauses: list = []
    early: list = []
    while True:  # a pause restarts the trial
        shown = _show_trial(disp, row, clock, hand, screenshot, early)
        if shown[0] == "answer":
            return replace(shown[1], pauses=tuple(pauses), early_space_s=tuple(early))
        t_pause, onset_s = shown[1], shown[2]
        if _pause(disp):
            return None
        pauses.append((t_pause - onset_s, clock.getTime() - onset_s))


def _show_trial(disp, row: dict, clock, hand, screenshot, early: list):
    """One showing of a trial: ``("answer", TrialResult)`` or ``("pause", t_s, onset_s)``."""
    win, kb = disp.win, disp.kb
    disp.reset_sliders()
    kb.clearEvents()
    onset: dict = {}

    def at_onset(onset=onset):
        onset["t"] = clock.getTime()
        kb.clock.reset()

    win.callOnFlip(at_onset)
    drop0 = win.nDroppedFrames
    hint_until = -1.0
    traces = {"gloss": [], "depth": []}
    first = True
    took_shot = False
    while True:
        disp.draw_trial(row["stimulus_id"], hint=clock.getTime() < hint_until)
        if screenshot and not took_shot and _sliders_settled(disp):
            win.getMovieFrame(buffer="back")
            win.saveMovieFrames(screenshot)
            took_shot = True
        disp.flip()
        if first:
            first = False
            if hand is not None:
                hand.trial(row, disp.slider_geometry())
        _record_traces(disp, traces, clock.getTime() - onset["t"])
        if hand is not None and hand.error is not None:
            raise RuntimeError(f"the simulated observer failed: {hand.error!r}")
        keys = kb.getKeys(["space", "escape"], waitRelease=False)
        if any(k.name == "escape" for k in keys):
            return ("pause", clock.getTime(), onset["t"])
        space = next((k for k in keys if k.name == "space"), None)
        if space is None:
            continue
        g, d = disp.gloss_slider.rating, disp.depth_slider.rating
        if g is None or d is None:
            early.append(float(space.rt))
            hint_until = clock.getTime() + HINT_S
            continue
        return ("answer", TrialResult(
            gloss_match=float(g), depth_match=float(d), rt_s=float(space.rt),
            onset_s=float(onset["t"]), dropped_frames=int(win.nDroppedFrames - drop0),
            gloss_history=tuple((float(r), float(t)) for r, t in disp.gloss_slider.getHistory()),
            depth_history=tuple((float(r), float(t)) for r, t in disp.depth_slider.getHistory()),
            gloss_trace=tuple(traces["gloss"]), depth_trace=tuple(traces["depth"]),
            early_space_s=(), pauses=(), screenshot_taken=took_shot))


def _pause(disp) -> bool:
    """The pause screen; True when the operator confirms quitting (Esc again)."""
    kb = disp.kb
    kb.clearEvents()
    while True:
        disp.draw_message("Paused. Your answers so far are saved.\n\nPress Esc again to quit "
                          "(run the same command later to continue where you stopped), "
                          "or space to go on.")
        disp.flip()
        keys = kb.getKeys(["space", "escape"], waitRelease=False)
        if any(k.name == "escape" for k in keys):
            return True
        if any(k.name == "space" for k in keys):
            return False
