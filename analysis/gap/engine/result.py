"""What a diagnosis returns: one :class:`CandidateScore` per candidate and the
:class:`Diagnosis` record, which round-trips to JSON through :meth:`Diagnosis.to_dict`."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

import numpy as np

__all__ = ["CandidateScore", "Diagnosis", "jsonable"]


@dataclass(frozen=True)
class CandidateScore:
    """One candidate alone against the plain simulation (loss units: mean NLL per held-out
    unit): its mean held-out ``gain``, the 95 % CI ``ci_low``-``ci_high``, the one-sided
    p-value (H1: gain > 0), the Holm-adjusted one and whether it counts (``p_holm < alpha``
    and ``gain >= min_gain``)."""

    name: str
    gain: float
    ci_low: float
    ci_high: float
    p_one_sided: float
    p_holm: float
    significant: bool


@dataclass(frozen=True)
class Diagnosis:
    """Ranking, greedy steps, before/after gap and the remaining gap (loss units: mean NLL per
    held-out unit).

    ``verdict`` is one of three outcomes: a gap (the chosen candidates' names ``a + b``, or
    ``'unexplained'``); ``'no_gap_that_matters'`` (the data exclude a gap of the layer's
    tolerance: the upper 95 % bound of the remaining misfit, ``misfit_upper``, in the lab's
    units, lies below ``tolerance``); or ``'inconclusive'`` (neither: then ``detectable``
    and ``to_decide`` say the smallest misfit these data would detect with 80 % power and how
    much more data would decide, both found by simulation from the fitted models:
    :func:`analysis.gap.engine.power.power_analysis`). ``summary`` is the plain-language
    sentence. ``not_identifiable`` maps effects the data given cannot
    identify (left out of the ranking) to the reason, in words. ``remaining`` (with a ceiling) holds the chosen model's
    held-out loss above the ceiling's: ``gap``, ``ci``, ``p``, ``significant``, ``where``;
    in a layer with a practical tolerance also ``size`` (the misfit in the data's units),
    ``tolerance``, ``size_unit``, ``size_source`` and ``within_tolerance`` (significant in
    nats but smaller than the tolerance: then ``significant`` is False).
    ``floor_status`` is ``'ok'`` or ``'misestimated'`` (a gap, before or after, whose 95 % CI
    lies wholly below zero: the floor is wrong, not the simulation right).
    ``explained_share``, in [0, 1], is the share of the held-out loss above the floor that the
    chosen candidates remove or, with a ceiling that removes any, the share of what the ceiling
    removes (so a share never exceeds what a flexible model of the data allows; all of it
    where the ceiling removes nothing and the chosen candidates remove something);
    ``ceiling_share`` is the share of the gap above the floor that the ceiling removes.
    ``misfit_pct_before`` / ``misfit_pct_after`` (render layer; NaN elsewhere): the held-out
    RMS misfit of the plain simulation / with the chosen effects, in % of the held-out data's
    RMS (noise included).
    ``misfit_before`` / ``misfit_after`` / ``misfit_ceiling`` (observer layer; NaN elsewhere):
    how far the plain simulation's / the chosen model's predicted responses lie from a
    flexible model of the data's, and how far held-out responses scatter about the latter
    (their noise), RMS over held-out trials in ``misfit_unit`` (slider units; a rating
    study's scale units); ``misfit_by_response`` the same per response in the study's units
    (``unit``, ``before``, ``after``, ``ceiling``; ``*_slider`` in slider units).
    ``misfit_pct_before`` / ``misfit_pct_after`` (render and display layers; NaN elsewhere):
    the held-out RMS misfit of the plain simulation / with the chosen effects, in % of the
    held-out data's RMS (render) or of each reading's luminance (display), noise included.
    ``misfit`` (display layer; else empty): the same and more in the lab's units, keyed as the
    layer documents (e.g. ``worst_pct_after``, ``ceiling_pct``, ``black_cd_m2_before``).
    ``misfit_upper``: the one-sided upper 95 % bound of the remaining misfit in the units of
    ``remaining['size_unit']`` (the plain simulation's where the layer holds chosen effects
    to the tolerance), NaN where the layer gives none; ``tolerance`` the layer's (same
    units). ``remaining['absorbed']`` (render layer, where effects were chosen): how far the
    simulation's own fit moved to take them up, same units (at least the tolerance: a gap).
    ``detectable`` (inconclusive only; else empty): ``value`` (None: above ``tried_up_to``), ``unit``, ``power``, ``curve``; ``to_decide``: ``factor`` (times the
    data; None: beyond ``tried_up_to``), ``words`` (the larger data set in the lab's
    words), ``truth``, ``curve``. ``departures`` (observer layer; else empty): single units
    (participants) that depart from the others in a way the misfit by stimulus cannot see
    (:func:`analysis.gap.engine.departures.with_departures`): ``tested``, ``size``,
    ``size_upper``, ``significant``, ``where``, ``departing`` and ``verdict_without`` (the
    verdict before they were weighed).
    """

    layer: str
    ranking: tuple
    steps: tuple
    verdict: str
    gap_before: float
    gap_after: float
    shrink_abs: float
    shrink_abs_ci: tuple
    shrink_pct: float
    shrink_pct_ci: tuple
    seed: int
    loss_before: float = float("nan")
    loss_after: float = float("nan")
    heldout: tuple = ()
    explained_share: float = float("nan")
    min_share: float = 0.0
    min_gain: float = 0.0
    loss_info: dict | None = None
    gap_before_ci: tuple = ()
    gap_after_ci: tuple = ()
    remaining: dict | None = None
    ceiling_share: float = float("nan")
    floor_status: str = "ok"
    summary: str = ""
    split: str = ""
    warnings: tuple = ()
    misfit_pct_before: float = float("nan")
    misfit_pct_after: float = float("nan")
    not_identifiable: dict = field(default_factory=dict)
    misfit_before: float = float("nan")
    misfit_after: float = float("nan")
    misfit_ceiling: float = float("nan")
    misfit_unit: str = ""
    misfit_by_response: dict = field(default_factory=dict)
    misfit: dict = field(default_factory=dict)
    misfit_upper: float = float("nan")
    tolerance: float = float("nan")
    detectable: dict = field(default_factory=dict)
    to_decide: dict = field(default_factory=dict)
    departures: dict = field(default_factory=dict)

    @property
    def unexplained_remains(self) -> bool:
        """True when a gap is left that the catalogue does not explain: with a ceiling, the
        chosen model (or the plain simulation, if nothing is chosen) falls significantly short
        of it; without one, nothing (or too little) attributed of a gap above tolerance."""
        if (self.departures or {}).get("significant"):
            return True
        if self.remaining is not None:
            return bool(self.remaining.get("significant"))
        if self.verdict != "unexplained":
            return False
        return bool(self.steps) or bool(
            self.gap_before_ci and self.gap_before_ci[0] > max(self.min_gain, 0.0))

    def to_dict(self) -> dict:
        """The record as plain JSON types, with ``unexplained_remains``. The held-out units'
        names are copied as one list of strings: dataclasses.asdict deep-copied each one (the
        render layer's units are pixels: 380,000 names took 5 s)."""
        out = {f.name: None if f.name == "heldout" else getattr(self, f.name)
               for f in fields(self)}
        out["ranking"] = [asdict(s) if not isinstance(s, dict) else s for s in self.ranking]
        out["unexplained_remains"] = self.unexplained_remains
        out = jsonable(out)
        out["heldout"] = [str(u) for u in self.heldout]  # in its place among the fields
        return out


def jsonable(params):
    """``params`` with numpy scalars and arrays turned into Python numbers and lists, dict
    keys into strings (tuples become lists), ready for ``json.dump``."""
    if isinstance(params, dict):
        return {str(k): jsonable(v) for k, v in params.items()}
    if isinstance(params, (list, tuple)):
        return [jsonable(v) for v in params]
    if isinstance(params, (np.floating, np.integer, np.bool_)):
        return params.item()
    if isinstance(params, np.ndarray):
        return params.tolist()
    return params
