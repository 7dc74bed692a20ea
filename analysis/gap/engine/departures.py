"""Single units that depart from the others, weighed into the verdict (issue 43).

A layer's misfit measures how far the chosen model lies from a flexible model of the data as a
whole; where units are held out whole (the observer layer's participants), one unit that does
something the others do not barely moves that model. A layer may check such departures itself
(:attr:`analysis.gap.engine.LayerPlan.departures`, e.g.
:func:`analysis.gap.observer.participants.participant_departures`) and hand the engine a dict:
``tested``, ``size`` and ``size_upper`` (in the misfit's units), ``tolerance``,
``significant``, ``where`` (words) and, untested, ``reason``. :func:`with_departures` weighs it:

- significant (and at least the tolerance): a gap. A verdict that was not one becomes
  ``'unexplained'``; a gap stays as it is and the words add the departing units;
- otherwise, where the verdict was no gap that matters but the departures were not tested,
  some unit departs (``departing``, however small its measured size: part of a departure passes
  for the unit's own slopes, so its size is a low estimate) or their bound reaches the
  tolerance: inconclusive (what the misfit excludes is said, and that single units are not
  excluded).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from analysis.gap.engine.result import Diagnosis
from analysis.gap.engine.steps import INCONCLUSIVE, NO_GAP_THAT_MATTERS, NOT_A_GAP

__all__ = ["with_departures"]


def with_departures(diag: Diagnosis, departures: dict) -> Diagnosis:
    """``diag`` with ``departures`` recorded (``verdict_without``: the verdict before) and the
    verdict they call for (module docstring); the words are written again by the caller."""
    dep = dict(departures, verdict_without=diag.verdict)
    verdict = diag.verdict
    if dep.get("significant"):
        if verdict in NOT_A_GAP:
            verdict = "unexplained"
    elif verdict == NO_GAP_THAT_MATTERS:
        upper = dep.get("size_upper", float("nan"))
        if (not dep.get("tested") or dep.get("departing")
                or not (np.isfinite(upper) and upper < dep["tolerance"])):
            verdict = INCONCLUSIVE
    return replace(diag, verdict=verdict, departures=dep)
