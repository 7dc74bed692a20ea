"""How far the simulated observer is off, in the responses' own units (observer layer).

Nats per trial are the statistics' currency, but a lab reads a misfit in its sliders' units:
:func:`observer_misfit` measures, on the held-out trials, how far the predicted settings of
the plain simulation and of the chosen model lie from those of the flexible model of the data
(the ceiling built on the chosen model, :func:`analysis.gap.observer.ceiling.fit_ceiling`),
in slider units and in the study's units (gloss in %, depth in cm, from the design's
slider-to-unit mapping), and how far held-out settings scatter about the flexible model's
prediction (their noise, which no model of the mean removes). The chosen model's misfit is
the size the design's ``[gap] observer_tolerance_slider`` holds a remaining gap to.

A model's misfit at one trial and response is the distance between its predicted settings
and the flexible model's, the means' difference and the spreads' difference taken together as
``sqrt(dm^2 + ds^2)`` (the Wasserstein-2 distance between two normal distributions, in the
settings' units; Dowson & Landau 1982): a misfit of the mean (a bias, a slope) and one of the
noise's pattern (noise that grows with depth) both count, in one unit. The model's spread is
first scaled to the flexible model's RMS spread over the held-out trials, as the noise SDs
are fitted per model in the likelihood too: a uniformly noisier lab is no misfit. Means are
clipped to the slider, where settings can be. Lapses and label rounding (the mixtures) are
left out: the catalogue names them, and their share is no distance on the slider. The misfit
is the RMS over held-out trials, per response, and for both together the RMS of the
distance in the (gloss, depth) plane, ``sqrt(gloss^2 + depth^2)``, so that a misfit in one
response alone is not halved by the other's fit.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.observer.ceiling import Ceiling, ceiling_prediction
from analysis.gap.observer.model import RESP, _fit_sigma, predict

__all__ = ["OBSERVER_SIZE_UNIT", "observer_misfit", "slider_units_per_response"]

#: The unit the observer layer's misfit and tolerance are in (the design's slider).
OBSERVER_SIZE_UNIT = "slider units"


def slider_units_per_response(slider) -> dict:
    """``{response: (unit words, study units per slider unit)}`` from the design's slider
    (linear maps: gloss % and depth cm per slider unit)."""
    lo = float(slider.min)
    return {"gloss": ("%", abs(float(slider.to_gloss_pct(lo + 1.0))
                                     - float(slider.to_gloss_pct(lo)))),
            "depth": ("cm", abs(float(slider.to_depth_cm(lo + 1.0))
                                      - float(slider.to_depth_cm(lo))))}


def _model_spread(train: pd.DataFrame, data: pd.DataFrame, fitted: list) -> tuple[dict, dict]:
    """The mean (slider units) and noise SD of the base extended by ``fitted`` on ``data``,
    the SDs fitted on ``train`` (as the likelihood fits them)."""
    pred = predict(data, list(fitted))
    sigma = _fit_sigma(train, predict(train, list(fitted)))
    return pred["mu"], {r: sigma[r] * np.broadcast_to(pred["sd"][r], pred["mu"][r].shape)
                        for r in RESP}


def _distance_sq(mu_m, sd_m, mu_c, sd_c, lo, hi) -> np.ndarray:
    """Per trial squared distance of a model's predicted settings from the ceiling's (see the
    module docstring): means clipped to the slider, the model's SD scaled to the ceiling's
    RMS SD."""
    k = np.sqrt(np.mean(sd_c ** 2) / max(float(np.mean(sd_m ** 2)), 1e-12))
    dm = np.clip(mu_m, lo, hi) - np.clip(mu_c, lo, hi)
    return dm ** 2 + (k * sd_m - sd_c) ** 2


def observer_misfit(fits: list, ceilings: dict, slider) -> dict:
    """The misfits of the plain simulation and the chosen model, and the scatter about the
    flexible model, on every fold's held-out trials.

    Parameters
    ----------
    fits : list of (train, test, chosen, ceiling loss)
        Per fold, as :func:`analysis.gap.engine.steps.remaining_gap` hands the layer's size
        (``chosen``: ``[(candidate, params), ...]``).
    ceilings : dict
        ``{id(test): Ceiling}``, the ceiling built on that fold's chosen model.
    slider : SliderSpec
        The design's slider (its units per slider unit).

    Returns
    -------
    dict
        ``misfit_before``, ``misfit_after``, ``misfit_ceiling`` (slider units; both responses
        together), ``misfit_unit`` and ``misfit_by_response`` (per response ``unit``,
        ``per_slider_unit`` and ``before``, ``after``, ``ceiling`` in that unit, with the same
        in slider units as ``before_slider`` etc.): the :class:`Diagnosis` fields.
    """
    sums = {r: np.zeros(3) for r in RESP}
    n = 0
    for train, test, chosen, _ in fits:
        model: Ceiling = ceilings[id(test)]
        lo, hi = test.attrs["range"]
        mu_c, sd_c = ceiling_prediction(model, test)
        plain = _model_spread(train, test, [])
        after = _model_spread(train, test, list(chosen))
        for r in RESP:
            x = test[f"{r}_match"].to_numpy(float)
            sums[r] += (float(_distance_sq(plain[0][r], plain[1][r], mu_c[r], sd_c[r], lo,
                                           hi).sum()),
                        float(_distance_sq(after[0][r], after[1][r], mu_c[r], sd_c[r], lo,
                                           hi).sum()),
                        float(np.sum((x - np.clip(mu_c[r], lo, hi)) ** 2)))
        n += len(test)
    if n == 0:
        return {}
    mean_sq = {r: sums[r] / n for r in RESP}
    both = np.sqrt(sum(mean_sq.values()))
    units = slider_units_per_response(slider)
    by_response = {}
    for r in RESP:
        rms = np.sqrt(mean_sq[r])
        unit, per = units[r]
        by_response[r] = {"unit": unit, "per_slider_unit": per,
                          **{k: float(v * per) for k, v in zip(_KEYS, rms)},
                          **{f"{k}_slider": float(v) for k, v in zip(_KEYS, rms)}}
    return {"misfit_before": float(both[0]), "misfit_after": float(both[1]),
            "misfit_ceiling": float(both[2]), "misfit_unit": OBSERVER_SIZE_UNIT,
            "misfit_by_response": by_response}


_KEYS = ("before", "after", "ceiling")
