"""How far the simulated rating observer is off, in the rating scale's own units (observer
layer, another lab's study; the two-response layer's :mod:`analysis.gap.observer.misfit`).

On the held-out trials: how far the expected rating of the plain simulation and of the
chosen model lies from that of the flexible model of the data (the ceiling built on the
chosen model, :func:`analysis.gap.observer.rating.ceiling.rating_ceiling_fit`), RMS over
trials, in scale units; and how far held-out ratings scatter about the flexible model's
expected rating (their noise, which no model of the mean removes). Each expected rating is
read out on the scale's own steps at the flexible model's noise SD and without lapses, so the
misfit is the latent means' (a uniformly noisier lab, or lapses the catalogue names, are no
distance on the scale). The chosen model's misfit is the size held to the tolerance: the
design's ``[gap] observer_tolerance_slider`` as the same share of the study's scale as of the
design's slider (:func:`rating_tolerance`).
"""

from __future__ import annotations

import numpy as np

from analysis.gap.observer.rating.model import rating_expected, rating_predict

__all__ = ["rating_misfit", "rating_tolerance", "rating_unit"]


def rating_unit(study) -> str:
    """The misfit's unit in words: 'rating units' (of the study's scale; ``study`` for a
    scale that names its own unit one day)."""
    return "rating units"


def rating_tolerance(design, study) -> tuple[float, str]:
    """``(tolerance in scale units, where it comes from)``: the design's
    ``observer_tolerance_slider`` as a share of its slider's span, times the study's span."""
    s = design.slider
    share = float(design.gap.observer_tolerance_slider) / (float(s.max) - float(s.min))
    lo, hi = study.scale
    words = (f"{100 * share:.3g} % of the scale {lo:g}-{hi:g}: the design's [gap] "
             "observer_tolerance_slider as a share of its slider's span")
    return share * (float(hi) - float(lo)), words


def rating_misfit(fits: list, ceilings: dict, cands: dict, unit: str) -> dict:
    """The misfits of the plain simulation and the chosen model against the ceiling, and the
    ratings' scatter about the ceiling, on every fold's held-out trials.

    Parameters
    ----------
    fits : list of (train, test, chosen, ceiling loss)
        Per fold, as :func:`analysis.gap.engine.steps.remaining_gap` hands the layer's size.
    ceilings : dict
        ``{id(test): ceiling}`` (:func:`rating_ceiling_fit` on that fold's chosen model).
    cands : dict
        The candidates by name.
    unit : str
        The scale's unit in words (:func:`rating_unit`).

    Returns
    -------
    dict
        The :class:`Diagnosis` fields ``misfit_before``, ``misfit_after``, ``misfit_ceiling``
        (scale units), ``misfit_unit`` and ``misfit_by_response`` (``{"rating": ...}``).
    """
    sums, n = np.zeros(3), 0
    for _train, test, chosen, _ in fits:
        pred_c, sigma = ceilings[id(test)](test)
        y = test["response"].to_numpy(float)

        e_c = _expected(test, pred_c, sigma)
        plain = _expected(test, rating_predict(test, [], cands), sigma)
        after = _expected(test, rating_predict(test, list(chosen), cands), sigma)
        sums += (float(np.sum((plain - e_c) ** 2)), float(np.sum((after - e_c) ** 2)),
                 float(np.sum((y - rating_expected(test, pred_c, sigma)) ** 2)))
        n += len(test)
    if n == 0:
        return {}
    before, after, scatter = (float(v) for v in np.sqrt(sums / n))
    return {"misfit_before": before, "misfit_after": after, "misfit_ceiling": scatter,
            "misfit_unit": unit,
            "misfit_by_response": {"rating": {
                "unit": unit, "before": before,
                "after": after, "ceiling": scatter}}}


def _expected(data, pred: dict, sigma: float) -> np.ndarray:
    """Expected rating without lapses at noise SD ``sigma`` (scale units)."""
    return rating_expected(data, {**pred, "lapse": 0.0}, sigma)
