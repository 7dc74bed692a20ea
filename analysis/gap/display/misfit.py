"""Display layer, how far in the lab's units: the held-out misfit of the readings in % of
luminance (and in cd/m^2 near black, where a percentage of almost no light means nothing),
before (the plain calibration), after the chosen effects, and the flexible model's (the
ceiling), and the size a practical tolerance is held to.

A reading's misfit is ``L - prediction`` (cd/m^2), the prediction held out as the diagnosis
scores it (each reading predicted by the fold that did not see it, the calibration moved
within its own uncertainty: :func:`analysis.gap.display.model.display_mean_given`). Readings
at or below the meter's floor (censored) carry no number and are left out.

``% of luminance``
    ``100 (L - prediction) / prediction``, over the readings above :data:`NEAR_BLACK_FRACTION`
    of the calibration's white. A lab reads it as the Weber fraction: 1 % is about the smallest
    step of luminance an observer sees at photopic levels.
``cd/m^2 near black``
    ``L - prediction`` over the readings below that light: the eye's threshold there is no
    longer a constant fraction, and the meter's absolute noise dominates.

The RMS figures include the meter's noise (what a direct comparison of two passes shows); the
``size`` held to the tolerance (:func:`display_misfit_size`) is the systematic part alone: the
mean square of the relative misfit less the mean square the meter's noise gives (with the
calibration's own misfit; not the change between passes, which is the display's and is what a
lab wants the size of), so a check no further off than a repeat reads about 0 whatever its
meter's noise.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.display.ceiling import ceiling_prediction
from analysis.gap.display.model import display_mean_given

__all__ = ["DISPLAY_SIZE_UNIT", "NEAR_BLACK_FRACTION", "display_misfit",
           "display_misfit_size"]

#: Readings predicted below this fraction of the calibration's white count as near black:
#: their misfit is given in cd/m^2, not in % (5 % of a 100 cd/m^2 white is 5 cd/m^2, where
#: photopic contrast thresholds begin to rise above the Weber fraction).
NEAR_BLACK_FRACTION = 0.05

#: The unit of the display layer's misfit and tolerance, in words (the summary's).
DISPLAY_SIZE_UNIT = "% of luminance (systematic RMS over the readings above near black)"


def _near_black(data: pd.DataFrame) -> float:
    """The light (cd/m^2) below which a reading counts as near black."""
    return NEAR_BLACK_FRACTION * float(data.attrs["cal"].max_luminance_cd_m2)


def _parts(data: pd.DataFrame, pred: np.ndarray):
    """(relative misfit, relative noise SD, cell names) above near black and (misfit in
    cd/m^2) near black, uncensored readings only."""
    lum, pred = data["L"].to_numpy(float), np.asarray(pred, float)
    use = ~data["censored"].to_numpy(bool) & np.isfinite(pred)
    bright = use & (pred >= _near_black(data)) & (pred > 0)
    dark = use & ~bright
    rel = (lum[bright] - pred[bright]) / pred[bright]
    var = data["var_expected"] if "var_expected" in data else data["sd"] ** 2
    sd = np.sqrt(var.to_numpy(float)[bright]) / pred[bright]
    return rel, sd, data["cell"].to_numpy()[bright], lum[dark] - pred[dark]


def _summary(parts: list) -> dict:
    """RMS %, systematic %, worst patch % and near-black RMS cd/m^2 of folds' ``_parts``."""
    rel = np.concatenate([p[0] for p in parts])
    sd = np.concatenate([p[1] for p in parts])
    cells = np.concatenate([p[2] for p in parts])
    dark = np.concatenate([p[3] for p in parts])
    if rel.size:
        by_cell = pd.Series(rel).groupby(cells).mean()
        worst = float(100 * by_cell.abs().max())
        rms = float(100 * np.sqrt(np.mean(rel**2)))
        systematic = float(100 * np.sqrt(max(np.mean(rel**2 - sd**2), 0.0)))
    else:
        worst = rms = systematic = float("nan")
    black = float(np.sqrt(np.mean(dark**2))) if dark.size else float("nan")
    return {"rms_pct": rms, "systematic_pct": systematic, "worst_pct": worst,
            "black_cd_m2": black}


def display_misfit_size(fits: list) -> float:
    """The engine's ``size``: the systematic RMS misfit (% of luminance, noise removed) of the
    chosen model on the held-out readings above near black. ``fits``: per fold
    ``(train, test, fitted, ceiling_loss)``."""
    return _summary([_parts(te, display_mean_given(tr, te, list(ch)))
                     for tr, te, ch, _ in fits])["systematic_pct"]


def display_misfit(folds: list, chosen: list) -> dict:
    """The held-out misfit in the lab's units before, after the chosen effects and of the
    ceiling (:func:`~analysis.gap.display.ceiling.ceiling_prediction`), pooled over the
    cross-fitting ``folds`` ``[(train, test), ...]`` (each reading held out once).

    Parameters
    ----------
    folds : list of (DataFrame, DataFrame)
    chosen : list of (name, params)
        The chosen effects with their (fold-mean) parameters.

    Returns
    -------
    dict
        ``misfit_pct_before``, ``misfit_pct_after`` (RMS % of luminance, noise included: the
        :class:`~analysis.gap.engine.Diagnosis` fields) and ``misfit``: ``unit``,
        ``ceiling_pct``, ``systematic_pct_before`` / ``_after`` (noise removed),
        ``worst_pct_before`` / ``_after`` (the patch whose mean misfit is largest),
        ``black_cd_m2_before`` / ``_after`` / ``ceiling_black_cd_m2`` (RMS near black) and
        ``black_below_cd_m2`` (where near black ends). NaN where no reading qualifies.
    """
    before = _summary([_parts(te, display_mean_given(tr, te, [])) for tr, te in folds])
    after = _summary([_parts(te, display_mean_given(tr, te, chosen)) for tr, te in folds])
    ceil = _summary([_parts(te, ceiling_prediction(tr, te)) for tr, te in folds])
    misfit = {"unit": "of luminance", "ceiling_pct": ceil["rms_pct"],
              "black_below_cd_m2": _near_black(folds[0][1]),
              "ceiling_black_cd_m2": ceil["black_cd_m2"]}
    for key in ("systematic_pct", "worst_pct", "black_cd_m2"):
        misfit[f"{key}_before"], misfit[f"{key}_after"] = before[key], after[key]
    return {"misfit_pct_before": before["rms_pct"], "misfit_pct_after": after["rms_pct"],
            "misfit": misfit}
