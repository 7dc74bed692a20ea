"""Other tools' gamma fits, scored on the same readings as ours (tests and the benchmark).

* PsychoPy's ``GammaCalculator`` (``psychopy.monitors.calibTools``), equations 1, 2 and 4, fitted
  the way PsychoPy's Monitor Center fits them: to the mean luminance of each level in level
  order (its black and white are the first and last means), then evaluated with PsychoPy's own
  ``gammaFun``. Scored by the same leave-one-level-out as :func:`calibration.gamma.fit_gamma`.
* A toolbox's own fitted table (drive, luminance), e.g. Psychtoolbox's ``gammaTable``: it was
  fitted to all the readings, so only its in-sample error exists (an advantage over a held-out
  error).
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["PSYCHOPY_EQUATIONS", "psychopy_heldout", "table_error"]

#: The equations PsychoPy's GammaCalculator fits.
PSYCHOPY_EQUATIONS = (1, 2, 4)


def _psychopy_fit_predict(x_in: np.ndarray, y_in: np.ndarray, x_out: np.ndarray,
                          eq: int) -> np.ndarray:
    from psychopy.monitors.calibTools import GammaCalculator, gammaFun

    uniq = np.unique(x_in)
    means = np.array([y_in[x_in == v].mean() for v in uniq])
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        calc = GammaCalculator(inputs=list(uniq), lums=list(means), eq=eq)
        if eq == 4:
            pred = gammaFun(x_out, calc.min, calc.max, calc.gamma, eq=4, a=calc.a, b=calc.b,
                            k=calc.k)
        else:
            pred = gammaFun(x_out, calc.min, calc.max, calc.gamma, eq=eq)
    return np.asarray(pred, dtype=float)


def psychopy_heldout(levels, luminance_cd_m2, *, eq: int) -> np.ndarray:
    """Leave-one-level-out predictions of PsychoPy's GammaCalculator, cd/m^2.

    Parameters
    ----------
    levels, luminance_cd_m2 : array_like, shape (n,)
        Drive values in [0, 1] and readings, cd/m^2.
    eq : {1, 2, 4}
        PsychoPy's equation.

    Returns
    -------
    ndarray, shape (n,)
        Each reading's prediction by a fit without its level (NaN where PsychoPy's equation is
        undefined, e.g. eq. 2 with a negative black).
    """
    x = np.asarray(levels, dtype=float)
    y = np.asarray(luminance_cd_m2, dtype=float)
    out = np.empty_like(y)
    for level in np.unique(x):
        held = x == level
        out[held] = _psychopy_fit_predict(x[~held], y[~held], x[held], eq)
    return out


def table_error(levels, luminance_cd_m2, table_levels, table_cd_m2) -> np.ndarray:
    """Reading minus a fitted table's luminance (linear interpolation in the table), cd/m^2."""
    pred = np.interp(np.asarray(levels, float), np.asarray(table_levels, float),
                     np.asarray(table_cd_m2, float))
    return np.asarray(luminance_cd_m2, float) - pred
