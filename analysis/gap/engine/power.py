"""What an inconclusive diagnosis needs besides its verdict: the smallest misfit these data
would detect (``detectable``) and how much more data would decide (``to_decide``), both found
by simulating the layer's data from its fitted models (:mod:`analysis.montecarlo`), not by a
formula that assumes normality.

A layer says how to simulate with a :class:`PowerModel` (its ``LayerPlan.power`` hook builds
one from the finished :class:`~analysis.gap.engine.result.Diagnosis`); :func:`power_analysis`
walks two grids with :func:`analysis.montecarlo.smallest_size`:

- ``detectable``: misfits of increasing size added to the fitted model at the data's own size
  (``factor`` 1); the smallest whose simulated data give the verdict "gap" in 80 % of draws;
- ``to_decide``: the data's size times increasing factors, the truth being the fitted model
  with the misfit as measured (``misfit_now``); the smallest factor whose simulated data are
  decided (a gap, or no gap that matters) in 80 % of draws.

Outcomes of one simulated data set are coded :data:`OUTCOME_NONE` (no gap that matters: the
upper 95 % bound of the misfit below the tolerance), :data:`OUTCOME_GAP` and
:data:`OUTCOME_INCONCLUSIVE`, decided by the layer's own rule on the simulated data (the same
functions that size the real data's misfit and its bound).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from analysis.gap.engine.errors import GapError
from analysis.montecarlo import smallest_size

__all__ = ["OUTCOME_GAP", "OUTCOME_INCONCLUSIVE", "OUTCOME_NONE", "PowerModel",
           "decide_size", "power_analysis"]

OUTCOME_NONE = 0
OUTCOME_GAP = 1
OUTCOME_INCONCLUSIVE = 2

#: The power the ``detectable`` misfit and the ``to_decide`` factor are found for.
TARGET_POWER = 0.8


def decide_size(size, lower, upper, tolerance: float) -> np.ndarray:
    """The verdict on simulated misfits, the rule the diagnosis applies to the real data's:
    a gap where the misfit is significant (``lower``, its lower 95 % bound, above 0) and at
    least the tolerance; no gap that matters where its ``upper`` 95 % bound lies below the
    tolerance; else inconclusive. Arrays of one shape (lab units); returns int8 outcomes."""
    size, lower, upper = (np.asarray(v, float) for v in (size, lower, upper))
    out = np.full(size.shape, OUTCOME_INCONCLUSIVE, np.int8)
    out[upper < tolerance] = OUTCOME_NONE
    out[(lower > 0) & (size >= tolerance)] = OUTCOME_GAP
    return out


@dataclass(frozen=True)
class PowerModel:
    """What a layer provides to find ``detectable`` and ``to_decide``.

    ============ ======================== =====================================================
    field        type                     meaning
    ============ ======================== =====================================================
    draws        callable                 ``draws(misfit, factor)`` returns ``f(rng, k) -> int
                                          array (k,)``: the outcomes (``OUTCOME_*``) of ``k``
                                          data sets simulated from the fitted model with a
                                          remaining misfit of
                                          ``misfit`` (lab units, the size the diagnosis
                                          measures) at ``factor`` times the data's size,
                                          each decided as the diagnosis decides (e.g. with
                                          :func:`decide_size`). Uses only ``rng``
    misfit_now   float                    the remaining misfit as measured (lab units): the
                                          truth ``to_decide`` simulates
    misfits      tuple of float           increasing misfits to try for ``detectable``
    factors      tuple of float           increasing data-size factors to try (> 1)
    unit         str                      the misfit's unit, in words
    more         ``more(factor) -> str``  the larger data set in the lab's words (e.g. "4
                                          repeats of each patch instead of 2")
    n_sim        int                      simulated data sets per grid point (>= 10)
    ============ ======================== =====================================================
    """

    draws: Callable
    misfit_now: float
    misfits: tuple
    factors: tuple
    unit: str
    more: Callable[[float], str]
    n_sim: int = 40

    def __post_init__(self):
        if not callable(self.draws) or not callable(self.more):
            raise GapError("PowerModel: draws and more must be functions")
        if self.n_sim < 10:
            raise GapError(f"PowerModel: n_sim is {self.n_sim}; use at least 10 draws")
        if not self.misfits or not self.factors:
            raise GapError("PowerModel: give at least one misfit and one factor to try")


def power_analysis(model: PowerModel, *, seed: int) -> dict:
    """``detectable`` and ``to_decide`` by simulation (see the module's docstring).

    Returns
    -------
    dict
        ``detectable``: ``value`` (lab units; None when no misfit tried reaches 80 %),
        ``unit``, ``power`` (0.8), ``tried_up_to``, ``curve`` ((misfit, rate) pairs);
        ``to_decide``: ``factor`` (None when no factor tried decides 80 % of draws),
        ``words`` (the larger data set, from ``model.more``), ``truth`` (``misfit_now``),
        ``tried_up_to``, ``curve``. Each curve entry has the rate's exact 95 % interval.
    """
    def detect_at(misfit):
        inner = model.draws(float(misfit), 1.0)
        return lambda rng, k: np.asarray(inner(rng, k)) == OUTCOME_GAP

    def decide_at(factor):
        inner = model.draws(float(model.misfit_now), float(factor))
        return lambda rng, k: np.asarray(inner(rng, k)) != OUTCOME_INCONCLUSIVE

    det = smallest_size(detect_at, list(model.misfits), model.n_sim, seed=seed,
                        target=TARGET_POWER, chunk=model.n_sim)
    dec = smallest_size(decide_at, list(model.factors), model.n_sim, seed=seed + 1,
                        target=TARGET_POWER, chunk=model.n_sim)
    return {
        "detectable": {"value": det.size, "unit": model.unit, "power": TARGET_POWER,
                       "tried_up_to": float(model.misfits[-1]),
                       "curve": _curve(det.curve), "n_sim": model.n_sim},
        "to_decide": {"factor": dec.size,
                      "words": model.more(dec.size) if dec.size is not None else
                      f"more than {model.more(model.factors[-1])}",
                      "truth": float(model.misfit_now), "unit": model.unit,
                      "power": TARGET_POWER, "tried_up_to": float(model.factors[-1]),
                      "curve": _curve(dec.curve), "n_sim": model.n_sim},
    }


def _curve(curve) -> list:
    return [{"size": float(s), **r.to_dict()} for s, r in curve]
