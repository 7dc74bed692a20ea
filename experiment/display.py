"""The session window: the CRT's PsychoPy window, the preloaded stimuli and the two sliders.

Everything PsychoPy-visual lives here, at the edge; ``experiment.session`` holds the trial logic.

Gamma: the stimuli PNGs are already inverse-gamma corrected for the calibration
(``stimuli`` tone mapping uses ``Calibration.drive_for_fraction``), so the window is opened with
gamma = 1 in the sense that it sets **no hardware gamma table**: the PsychoPy monitor is built
from the calibration's geometry only (no gamma grid), ``Window(gamma=None)`` then leaves the
operating system's ramp alone. (Under Xvfb, setting a gamma table raises ``OSError``; on the lab
machine the OS ramp must be the identity the CRT was calibrated with, see protocol.md.)
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Self

import pandas as pd

from calibration import Calibration
from studydesign import StudyDesign

__all__ = ["DisplayError", "Layout", "SessionDisplay", "find_font", "plan_layout"]

#: Fonts tried for the slider labels and texts, in order (must be installed; PsychoPy's default
#: "Helvetica Bold" is not on Linux and would fall back with a warning).
FONTS = ("DejaVu Sans", "Liberation Sans", "Noto Sans", "Arial")
_FONT_FILES = {"DejaVu Sans": "DejaVuSans.ttf", "Liberation Sans": "LiberationSans-Regular.ttf",
               "Noto Sans": "NotoSans-Regular.ttf", "Arial": "Arial.ttf"}


class DisplayError(RuntimeError):
    """The window cannot show the session as the design and calibration require."""


def find_font() -> str:
    """The first of :data:`FONTS` installed on this machine (fontconfig's folders)."""
    roots = [Path("/usr/share/fonts"), Path("/usr/local/share/fonts"),
             Path.home() / ".local/share/fonts"]
    for name in FONTS:
        for root in roots:
            if root.is_dir() and next(root.rglob(_FONT_FILES[name]), None) is not None:
                return name
    raise DisplayError(f"none of the fonts {FONTS} is installed; install fonts-dejavu-core")


@dataclass(frozen=True)
class Layout:
    """Where things go, in window pixels (origin at the centre, y up).

    Attributes
    ----------
    stim_centre_px : (float, float)
    stim_size_px : (float, float)
        The largest stimulus of the session at its physical size.
    slider_width_px, slider_height_px : float
    gloss_y_px, depth_y_px : float
        Slider centres; gloss above depth.
    label_height_px : float
        Height of the slider titles; tick labels are 0.8 of it.
    text_y_px : float
        Where the hint line goes (top of the screen).
    """

    stim_centre_px: tuple
    stim_size_px: tuple
    slider_width_px: float
    slider_height_px: float
    gloss_y_px: float
    depth_y_px: float
    label_height_px: float
    text_y_px: float


def plan_layout(design: StudyDesign, cal: Calibration, stimuli: pd.DataFrame) -> Layout:
    """Place the stimulus and the two sliders in the design's window.

    The stimulus is centred horizontally and as near the screen centre as the sliders below it
    allow; its size in pixels follows from its physical width (``image_width_cm``) and the
    calibration's visible screen width.

    Raises
    ------
    DisplayError
        The stimulus at its physical size does not fit above the sliders.
    """
    w_px, h_px = design.display.resolution_px
    px_per_cm = w_px / cal.width_cm
    widths = stimuli["image_width_cm"].to_numpy(float) * px_per_cm
    heights = widths * stimuli["height_px"].to_numpy(float) / stimuli["width_px"].to_numpy(float)
    stim_w, stim_h = float(widths.max()), float(heights.max())
    margin = 0.02 * h_px
    label = 0.025 * h_px
    slider_h = 0.02 * h_px
    # Two sliders, each with its name above and tick labels below, at the bottom of the screen.
    depth_y = -h_px / 2 + margin + 3.5 * label
    gloss_y = depth_y + 5 * label
    top_of_sliders = gloss_y + 2.2 * label
    text_y = h_px / 2 - margin - label
    centre_y = max(0.0, top_of_sliders + margin + stim_h / 2)
    if centre_y + stim_h / 2 > h_px / 2 or stim_w > w_px:
        raise DisplayError(
            f"the stimulus at its physical size ({stim_w / px_per_cm:.1f} cm = {stim_w:.0f} x "
            f"{stim_h:.0f} px on this {cal.width_cm:g} cm wide screen) does not fit above the "
            "sliders; render smaller stimuli (image_width_cm)"
        )
    return Layout(stim_centre_px=(0.0, centre_y), stim_size_px=(stim_w, stim_h),
                  slider_width_px=0.6 * w_px, slider_height_px=slider_h, gloss_y_px=gloss_y,
                  depth_y_px=depth_y, label_height_px=label, text_y_px=text_y)


class SessionDisplay:
    """The session's window and everything drawn in it (a context manager; closes the window).

    Parameters
    ----------
    design : StudyDesign
    cal : Calibration
        Geometry of the CRT (visible width, distance, resolution) for the PsychoPy monitor.
    stimuli : DataFrame
        ``SessionStimuli.frame``; all are preloaded as textures before the first trial.
    fullscr : bool
    fast : bool
        Do not wait for the vertical blank at flips (headless runs).
    monitor_profile : path-like, optional
        The calibration's saved PsychoPy profile (checked in pre-flight), recorded in the log.

    Attributes
    ----------
    win, gloss_slider, depth_slider, kb
    frame_count : int
        Flips so far (read by the simulated observer to pace its input).
    """

    def __init__(self, design: StudyDesign, cal: Calibration, stimuli: pd.DataFrame, *,
                 fullscr: bool = False, fast: bool = False, monitor_profile=None):
        self.design, self.cal, self.stimuli = design, cal, stimuli
        self.fullscr, self.fast = fullscr, fast
        self.monitor_profile = None if monitor_profile is None else str(monitor_profile)
        self.layout = plan_layout(design, cal, stimuli)
        self.win = None
        self.frame_count = 0
        self.textures = {}
        self.info = {}

    # --- the lifetime -----------------------------------------------------------------------
    def __enter__(self) -> Self:
        try:
            self._open()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.win is not None:
            win, self.win = self.win, None
            win.close()

    def _monitor(self):
        """A PsychoPy Monitor with the calibration's geometry and no gamma grid (see module)."""
        from psychopy import monitors

        mon = monitors.Monitor(f"{self.cal.monitor_name}-session", width=self.cal.width_cm,
                               distance=self.cal.distance_cm, verbose=False, autoLog=False)
        mon.setSizePix(list(self.cal.resolution_px))
        if not mon.gammaIsDefault():
            raise DisplayError("the session monitor carries a gamma grid; it must not (stimuli "
                               "are pre-corrected)")
        self.info["monitor"] = {"name": self.cal.monitor_name, "width_cm": self.cal.width_cm,
                                "distance_cm": self.cal.distance_cm,
                                "resolution_px": list(self.cal.resolution_px),
                                "calibration_id": self.cal.calibration_id,
                                "refresh_hz_calibrated": self.cal.refresh_hz}
        self.info["monitor"]["profile"] = self.monitor_profile
        return mon

    def _open(self) -> None:
        from psychopy import logging, visual
        from psychopy.hardware import keyboard

        font = find_font()
        mon = self._monitor()
        w, h = self.design.display.resolution_px
        self.win = visual.Window(
            size=(w, h), fullscr=self.fullscr, monitor=mon, units="pix", color=(-1, -1, -1),
            colorSpace="rgb", allowGUI=False, gamma=None, waitBlanking=not self.fast,
            checkTiming=False, winType="pyglet",
        )
        if tuple(int(v) for v in self.win.size) != (w, h):
            raise DisplayError(f"the window is {self.win.size[0]}x{self.win.size[1]} px, the "
                               f"design's CRT {w}x{h}; set the display mode to {w}x{h}")
        self.win.mouseVisible = True
        self.info["gamma"] = ("none: no hardware gamma table set (stimuli are pre-corrected; "
                              f"useNativeGamma={self.win.useNativeGamma})")
        # Keyboard: ptb (or iohub) only; the 'event' backend never matches keys in this PsychoPy.
        self.kb = keyboard.Keyboard(backend="ptb")
        backend = keyboard.KeyboardDevice.getBackend()
        if backend not in ("ptb", "iohub"):
            raise DisplayError(
                f"PsychoPy's keyboard backend is {backend!r}, not 'ptb' or 'iohub': psychtoolbox "
                "did not load (install libasound2 and libjack-jackd2-0, then `python -c 'import "
                "psychtoolbox'` must work); the 'event' backend drops key presses"
            )
        self.info["keyboard_backend"] = backend
        self.info["font"] = font
        lay = self.layout
        # Tick labels are TextStims, not the Slider's own labels: those are TextBox2 objects
        # whose draw() costs ~2.5 ms of Python each per frame (colour-palette copies; 22 labels
        # = two frames at 85 Hz). The TextStims, with the titles, are then drawn once into one
        # texture (_capture_static_layer). bench/experiment_frame_cost.py measures all three.
        slider_kw = {"ticks": list(self.design.slider.ticks), "labels": None,
                     "granularity": 0, "size": (lay.slider_width_px, lay.slider_height_px),
                     "units": "pix", "style": "rating", "markerColor": "Red",
                     "lineColor": "White", "labelColor": "White", "font": font,
                     "labelHeight": lay.label_height_px * 0.8, "autoLog": False}
        self.gloss_slider = visual.Slider(self.win, pos=(0, lay.gloss_y_px), name="gloss",
                                          **slider_kw)
        self.depth_slider = visual.Slider(self.win, pos=(0, lay.depth_y_px), name="depth",
                                          **slider_kw)
        self.tick_labels = [
            visual.TextStim(self.win, str(t), pos=(self._tick_x(t), y - 1.1 * lay.label_height_px),
                            height=0.8 * lay.label_height_px, font=font, units="pix",
                            color="White", autoLog=False)
            for y in (lay.gloss_y_px, lay.depth_y_px) for t in self.design.slider.ticks
        ]
        title = lay.label_height_px
        self.gloss_title = visual.TextStim(
            self.win, "gloss", pos=(0, lay.gloss_y_px + 1.3 * title), height=title, font=font,
            units="pix", color="White", autoLog=False)
        self.depth_title = visual.TextStim(
            self.win, "depth", pos=(0, lay.depth_y_px + 1.3 * title), height=title, font=font,
            units="pix", color="White", autoLog=False)
        self.hint = visual.TextStim(
            self.win, "Set both sliders (gloss and depth), then press space",
            pos=(0, lay.text_y_px), height=title, font=font, units="pix", color="Yellow",
            wrapWidth=0.9 * w, autoLog=False)
        self.message = visual.TextStim(self.win, "", pos=(0, 0), height=1.2 * title, font=font,
                                       units="pix", color="White", wrapWidth=0.8 * w,
                                       autoLog=False)
        self.static_layer = self._capture_static_layer()
        t0 = time.perf_counter()
        logging.console.setLevel(logging.ERROR)
        for row in self.stimuli.itertuples(index=False):
            h_cm = row.image_width_cm * row.height_px / row.width_px
            stim = visual.ImageStim(self.win, image=row.png, units="cm",
                                    size=(row.image_width_cm, h_cm), interpolate=True,
                                    autoLog=False)
            stim.pos = self._cm(lay.stim_centre_px)
            self.textures[row.stimulus_id] = stim
        self.info["preload_s"] = time.perf_counter() - t0
        self.info["n_textures"] = len(self.textures)
        self.win.recordFrameIntervals = False

    def _capture_static_layer(self):
        """Tick labels and slider titles, drawn once and kept as one texture.

        They never change during a session, and drawing 24 TextStims costs ~3.5 ms of Python per
        frame against ~0.2 ms for one texture (bench/experiment_frame_cost.py). The back buffer
        is captured (``getMovieFrame``) and the slider band at the bottom, which the stimulus
        never overlaps (``plan_layout``), becomes an ImageStim drawn pixel for pixel where it
        was taken. (``BufferImageStim`` would do the capture, but in this PsychoPy its draw
        ignores ``pos``.)
        """
        from psychopy import visual

        w, h = self.design.display.resolution_px
        lay = self.layout
        top_px = min(h / 2, lay.gloss_y_px + 2.2 * lay.label_height_px)
        self.win.clearBuffer()
        for stim in (*self.tick_labels, self.gloss_title, self.depth_title):
            stim.draw()
        frame = self.win.getMovieFrame(buffer="back")
        self.win.movieFrames.remove(frame)
        self.win.clearBuffer()
        rows = round(h / 2 - top_px)  # image rows above the band
        # Columns: the slider width and room for the end labels, symmetric about the centre.
        cols = max(0, int(w / 2 - lay.slider_width_px / 2 - 2 * lay.label_height_px))
        band = frame.convert("RGB").crop((cols, rows, w - cols, h))
        # Centred at (0, -rows / 2), its edges fall on pixel boundaries.
        return visual.ImageStim(self.win, image=band, units="pix", size=band.size,
                                pos=(0, -rows / 2), interpolate=False, autoLog=False)

    def _tick_x(self, value: float) -> float:
        """Window x (px) of a slider value (both sliders span the same x range)."""
        lo, hi = self.design.slider.ticks[0], self.design.slider.ticks[-1]
        return (value - lo) / (hi - lo) * self.layout.slider_width_px \
            - self.layout.slider_width_px / 2

    def _cm(self, xy_px):
        px_per_cm = self.design.display.resolution_px[0] / self.cal.width_cm
        return (xy_px[0] / px_per_cm, xy_px[1] / px_per_cm)

    # --- drawing ----------------------------------------------------------------------------
    def draw_trial(self, stimulus_id: str, *, hint: bool = False) -> None:
        """Draw one trial screen into the back buffer (no flip)."""
        self.static_layer.draw()
        self.textures[stimulus_id].draw()
        self.gloss_slider.draw()
        self.depth_slider.draw()
        if hint:
            self.hint.draw()

    def draw_message(self, text: str) -> None:
        self.message.text = text
        self.message.draw()

    def flip(self) -> float:
        """Flip and count the frame; returns the flip time (PsychoPy's clock, s)."""
        t = self.win.flip()
        self.frame_count += 1
        return t

    def reset_sliders(self) -> None:
        self.gloss_slider.reset()
        self.depth_slider.reset()

    def slider_geometry(self) -> dict:
        """Where the sliders are on the X screen: what a hand on the mouse needs to know.

        Returns
        -------
        dict
            ``{"gloss": (x0, x1, y), "depth": (x0, x1, y)}``: screen pixels of the slider's
            ``min`` and ``max`` ends and its line (X11 coordinates, y down), plus ``"min"``,
            ``"max"``.
        """
        loc = self.win.winHandle.get_location() if not self.fullscr else (0, 0)
        w, h = self.design.display.resolution_px
        lay = self.layout
        out = {"min": self.design.slider.ticks[0], "max": self.design.slider.ticks[-1]}
        for name, y in (("gloss", lay.gloss_y_px), ("depth", lay.depth_y_px)):
            out[name] = (loc[0] + w / 2 - lay.slider_width_px / 2,
                         loc[0] + w / 2 + lay.slider_width_px / 2, loc[1] + h / 2 - y)
        return out
