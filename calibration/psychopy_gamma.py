"""The error PsychoPy makes with a monitor profile's gamma, and the gamma that makes it smallest.

A PsychoPy ``Window`` linearises a monitor through the hardware table
``v -> v^(1 / gamma)`` with the profile's gamma (``psychopy.visual.backends.gamma.setGamma``),
and ``Monitor.lineariseLums`` with linearise method 1 inverts the same pure power
(``calibTools.gammaInvFun``, eq. 1: the black and white of the gamma grid play no part). No
gamma value reproduces a display whose gun starts at a threshold (the extended power function
of Brainard, Pelli & Robson 2002) or with an offset: PsychoPy's equations 1, 2 and 4 have no
threshold. This module measures that error on the calibration's model and chooses the gamma that
minimises its largest value over :data:`ERROR_RANGE` of the luminance range (each fraction's
error rises monotonically with gamma, so the largest is quasi-convex in gamma and a bounded
scalar search finds its minimum).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from calibration.ramp import REPORT_FRACTIONS, linearity_error_pct
from calibration.record import Calibration

__all__ = ["ERROR_RANGE", "PsychopyGamma", "best_psychopy_gamma", "psychopy_gamma_error_pct"]

#: Fractions of the luminance range over which the error is minimised and stated.
ERROR_RANGE = (0.05, 0.95)
_GRID = np.linspace(*ERROR_RANGE, 901)
_GAMMA_BOUNDS = (0.3, 10.0)


def psychopy_gamma_error_pct(cal: Calibration, gamma: float, fractions) -> np.ndarray:
    """Error of PsychoPy's pure power (drive = fraction^(1/gamma)) on the calibration's display.

    Returns
    -------
    ndarray
        % of the luminance asked for above black
        (:func:`calibration.ramp.linearity_error_pct`).
    """
    f = np.asarray(fractions, dtype=float)
    return linearity_error_pct(cal, f, f ** (1.0 / float(gamma)))


@dataclass(frozen=True)
class PsychopyGamma:
    """The gamma written into the PsychoPy profile and the error PsychoPy makes with it.

    Attributes
    ----------
    gamma : float
        Minimises the largest |error| over :data:`ERROR_RANGE`.
    max_error_pct : float
        That largest |error|, % of the luminance asked for above black.
    worst_fraction : float
        Where it occurs (fraction of the luminance range).
    fractions : tuple[float, ...]
        :data:`calibration.ramp.REPORT_FRACTIONS`.
    error_pct : tuple[float, ...]
        The signed error at each (negative: too dark).
    """

    gamma: float
    max_error_pct: float
    worst_fraction: float
    fractions: tuple
    error_pct: tuple

    def statement(self) -> str:
        """The report's sentence on the profile, e.g. '... within 44 % at 5 % of the range:
        load gamma_ramp.csv instead'."""
        # Rounded up, so that "within" is a bound.
        step = 1.0 if self.max_error_pct >= 10 else 0.1
        bound = math.ceil(self.max_error_pct / step - 1e-9) * step
        head = (f"PsychoPy's monitor gamma ({self.gamma:.3f}, the pure power a Window applies) "
                f"reproduces this display within {bound:.{0 if step == 1 else 1}f} % at "
                f"{100 * self.worst_fraction:.0f} % of the range")
        if self.max_error_pct > 1.0:
            return head + ": load gamma_ramp.csv instead"
        return head + " (gamma_ramp.csv does as well)"


def best_psychopy_gamma(cal: Calibration) -> PsychopyGamma:
    """The gamma with the smallest largest error over :data:`ERROR_RANGE`, and its errors."""

    def worst(g: float) -> float:
        return float(np.max(np.abs(psychopy_gamma_error_pct(cal, g, _GRID))))

    coarse = np.geomspace(*_GAMMA_BOUNDS, 60)
    i = int(np.argmin([worst(g) for g in coarse]))
    lo, hi = coarse[max(i - 1, 0)], coarse[min(i + 1, coarse.size - 1)]
    gamma = float(minimize_scalar(worst, bounds=(lo, hi), method="bounded",
                                  options={"xatol": 1e-5}).x)
    err = psychopy_gamma_error_pct(cal, gamma, _GRID)
    k = int(np.argmax(np.abs(err)))
    return PsychopyGamma(
        gamma=gamma, max_error_pct=float(abs(err[k])), worst_fraction=float(_GRID[k]),
        fractions=tuple(REPORT_FRACTIONS),
        error_pct=tuple(float(v) for v in psychopy_gamma_error_pct(cal, gamma,
                                                                   REPORT_FRACTIONS)))
