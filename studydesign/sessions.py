"""What the observer meets: ``[sessions]`` (how the trials are split), ``[display]`` (the CRT)
and ``[slider]`` (the answer scale and its physical units)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from studydesign.errors import DesignError, require
from studydesign.objects import FIRST_GLOSS_LABEL
from studydesign.tables import build, section

__all__ = ["DisplaySpec", "SessionSpec", "SliderSpec", "read_display", "read_sessions",
           "read_slider"]


@dataclass(frozen=True)
class SessionSpec:
    n_sessions: int
    trials_per_session: int


@dataclass(frozen=True)
class DisplaySpec:
    """The CRT as the design expects it."""

    resolution_px: tuple[int, int]
    viewing_distance_cm: float
    nominal_refresh_hz: float

    def __post_init__(self) -> None:
        require(
            len(self.resolution_px) == 2 and all(v > 0 for v in self.resolution_px),
            f"display.resolution_px must be [width, height] in pixels, got {self.resolution_px}",
        )
        require(self.viewing_distance_cm > 0, "display.viewing_distance_cm must be > 0")
        require(self.nominal_refresh_hz > 0, "display.nominal_refresh_hz must be > 0")

    @property
    def frame_s(self) -> float:
        """Nominal frame duration in s."""
        return 1.0 / self.nominal_refresh_hz


@dataclass(frozen=True)
class SliderSpec:
    """Continuous slider scale and its mapping to physical units."""

    min: float
    max: float
    depth_cm_per_unit: float
    gloss_pct_per_unit: float

    def __post_init__(self) -> None:
        require(self.max > self.min, "slider.max must exceed slider.min")

    @property
    def ticks(self) -> tuple[int, ...]:
        return tuple(range(int(np.ceil(self.min)), int(np.floor(self.max)) + 1))

    def _check(self, value) -> np.ndarray:
        v = np.asarray(value, dtype=float)
        bad = ~np.isfinite(v) | (v < self.min) | (v > self.max)
        if np.any(bad):
            raise DesignError(
                f"slider value(s) {np.atleast_1d(v)[np.atleast_1d(bad)][:5].tolist()} lie outside "
                f"[{self.min:g}, {self.max:g}]; slider matches are raw slider positions"
            )
        return v

    def to_depth_cm(self, value):
        """Slider position(s) in [min, max] -> matched depth in cm (``depth_cm_per_unit * v``,
        0.4 v in the shipped design: position v matches the depth reference labelled v)."""
        return self.depth_cm_per_unit * self._check(value)

    def to_gloss_pct(self, value):
        """Slider position(s) in [min, max] -> matched gloss in %
        (``gloss_pct_per_unit * (v - FIRST_GLOSS_LABEL)``, 10 (v - 1) in the shipped design:
        position v matches the gloss reference labelled v whatever ``min`` is; ``min`` and
        ``max`` bound the positions accepted)."""
        return self.gloss_pct_per_unit * (self._check(value) - FIRST_GLOSS_LABEL)

    def from_depth_cm(self, depth_cm, *, clip: bool):
        """Depth in cm -> slider position(s), the inverse of :meth:`to_depth_cm`.

        ``clip=True`` clips to [min, max], where a slider's marker can be (a simulated
        observer's answer); ``clip=False`` returns positions the slider may not reach.
        """
        v = np.asarray(depth_cm, dtype=float) / self.depth_cm_per_unit
        return np.clip(v, self.min, self.max) if clip else v

    def from_gloss_pct(self, gloss_pct, *, clip: bool):
        """Gloss in % -> slider position(s), the inverse of :meth:`to_gloss_pct` (whatever
        ``min`` is, ``to_gloss_pct(from_gloss_pct(g)) == g``); ``clip`` as
        :meth:`from_depth_cm`."""
        v = FIRST_GLOSS_LABEL + np.asarray(gloss_pct, dtype=float) / self.gloss_pct_per_unit
        return np.clip(v, self.min, self.max) if clip else v


def read_sessions(raw: dict, path: Path) -> SessionSpec:
    """The ``[sessions]`` table of a design file's ``raw`` tables."""
    return build(SessionSpec, section(raw, "sessions", path), "sessions", path)


def read_display(raw: dict, path: Path) -> DisplaySpec:
    """The ``[display]`` table of a design file's ``raw`` tables."""
    disp = section(raw, "display", path, DisplaySpec)
    return build(DisplaySpec, disp, "display", path,
                 resolution_px=tuple(int(v) for v in disp.get("resolution_px", ())))


def read_slider(raw: dict, path: Path) -> SliderSpec:
    """The ``[slider]`` table of a design file's ``raw`` tables."""
    return build(SliderSpec, section(raw, "slider", path), "slider", path)
