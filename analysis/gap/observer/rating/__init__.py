"""Observer layer, one response on a rating scale: another lab's study (``study.toml``) against
the rating observer fitted to a pilot of it (``python -m experiment fit-observer DIR --study
DIR/study.toml``).

The same parts as the two-response layer, for one response: ``data.py`` (the study's files,
the simulation's file, the held-out scheme), ``model.py`` (the simulation's prediction and
ordered-probit likelihood on the scale's own steps, the noise floor), ``ceiling.py`` (the
flexible model), ``where.py`` (stimulus to stimulus, the split-half consistency; and how
far, in the rating scale's units, held to the design's tolerance as a share of the scale),
``candidates.py`` (the catalogue's effects that make sense for one response). :func:`plan`
is the layer's face to the engine; :func:`analysis.gap.observer.plan` hands over to it when a
study is given.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from analysis.gap.engine import DiagnosisSettings, GapError, LayerFunctions, LayerPlan, judged_plain
from analysis.gap.observer.power import misfit_power, misfit_upper
from analysis.gap.observer.rating.candidates import BY_NAME, rating_candidates
from analysis.gap.observer.rating.ceiling import (
    rating_ceiling_fit,
    rating_ceiling_floor,
    rating_ceiling_loss,
)
from analysis.gap.observer.rating.data import (
    check_rating_sim,
    load_rating_sim,
    rating_folds,
    rating_frame,
    rating_unit_ids,
    read_rating_study,
)
from analysis.gap.observer.rating.model import (
    RatingBase,
    adapt_rating_base,
    rating_loss,
)
from analysis.gap.observer.rating.where import (
    localise_rating,
    rating_misfit,
    rating_misfit_terms,
    rating_tolerance,
    rating_unit,
    rating_where,
)

__all__ = ["RatingBase", "plan"]

#: A candidate or a remaining gap must gain >= this many nats per held-out trial (as the
#: two-response layer's OBSERVER_MIN_GAIN).
RATING_MIN_GAIN = 0.02


def _labels_identifiable(study) -> tuple[bool, str]:
    """Whether rounding to labels beyond the scale's steps can be told from the steps."""
    if not study.labels:
        return False, ("rounding beyond the scale's steps is not tested: study.toml names no "
                       "labels coarser than its steps ([response] labels)")
    if study.step > 0 and len(study.labels) >= round((study.scale[1] - study.scale[0])
                                                      / study.step) + 1:
        return False, "rounding to labels is not tested: every step of the scale is labelled"
    return True, ""


def _spread_unknown(base: RatingBase) -> str:
    """Why individual differences cannot be told apart (a simulation fitted to fewer than
    2 participants: its between-observer SDs are no estimate), or ''."""
    n = len(base.participants)
    if not base.participants or n >= 2:
        return ""
    return (f"the rating observer was fitted to {n} participant ({', '.join(base.participants)})"
            ": its between-observer SDs (gain {:.3f}, offset {:.3f}) are no estimate of the "
            "population's, so individual differences cannot be told apart from the "
            "simulation's and are not tested; fit the observer to a pilot of several "
            "participants (fit-observer --study ... --participants 01 02 03 ...)"
            ).format(base.gain_sd, base.offset_sd)


def _size_functions(ceilings: dict, unit: str, tolerance: float):
    """``(size, size_upper, power, sizes)``: the misfit in the scale's units, its upper 95 %
    bound and the PowerModel, against the ceilings fitted per fold (``ceilings``, filled by
    the ceiling step), and the dict the misfits are kept in for the Diagnosis."""
    sizes, terms = {}, {}

    def size(fits):
        # The misfits against the ceilings just fitted on each fold's chosen model, kept for
        # the Diagnosis (sizes); the chosen model's is held to the tolerance.
        # The first call is remaining_gap's, with the chosen model; a later one (the plain
        # simulation's size) must not replace the record.
        measured = rating_misfit(fits, ceilings, BY_NAME, unit)
        if not sizes:
            sizes.update(measured)
        return measured.get("misfit_after", float("nan"))

    def size_upper(fits):
        # The chosen model's (the first call's, as size's) per-trial terms kept for power,
        # and the plain simulation's (a call with nothing chosen) for a verdict it decides.
        t, u = rating_misfit_terms(fits, ceilings, BY_NAME)
        terms.setdefault("after", (t, u))
        if not any(chosen for _tr, _te, chosen, _c in fits):
            terms["plain"] = (t, u)
        return misfit_upper(t, u)

    def power(diag):
        # Named effects held to the tolerance: the verdict judged the plain simulation.
        t, u = terms.get("plain" if judged_plain(diag) else "after", (np.zeros(0), np.zeros(0)))
        model = misfit_power(t, u, tolerance)
        return model if model is None else replace(model, unit=unit)
    return size, size_upper, power, sizes


def plan(real, sim, design, rng: np.random.Generator, *, n_boot: int, study,
         participants=None, k_folds: int = 5) -> LayerPlan:
    """The study's trials at ``real`` (described by ``study``, a study.toml) against the rating
    observer of ``sim``, cross-fitted over folds of each participant's trials (by repeat).

    The study describes itself; ``design`` gives only the tolerance (its ``[gap]
    observer_tolerance_slider`` as a share of the scale, :func:`rating_tolerance`; the
    shipped design's where None). ``participants`` keeps only those.

    Raises
    ------
    GapError
        Unreadable files, a simulation of another scale or factor.
    """
    st, trials, notes = read_rating_study(real, study, participants)
    base, sim_study = load_rating_sim(sim)
    notes = list(notes) + check_rating_sim(trials, base, sim_study, st)
    labels_ok, why = _labels_identifiable(st)
    if why:
        notes.append(why)
    data = rating_frame(trials, base, st, labels_ok)
    if data["participant"].nunique() < 2:
        raise GapError("the diagnosis needs at least 2 participants (the split-half "
                       "consistency of a stimulus's deviation); pass more with --participants")
    unknown = _spread_unknown(base)
    if unknown:
        notes.append(unknown)
    folds, text = rating_folds(data, k_folds)
    floor = {}
    for tr, te in folds:
        adapt_rating_base(tr, te, base)
        floor[id(te)] = rating_ceiling_floor(tr, te, BY_NAME)
    adapt_rating_base(data, data.iloc[:0].copy(), base)

    ceilings = {}
    unit = rating_unit(st)
    if design is None:
        from studydesign import load_design

        design = load_design()
    tolerance, source = rating_tolerance(design, st)

    def ceiling(tr, te, fitted):
        ceilings[id(te)] = rating_ceiling_fit(tr, fitted, BY_NAME)
        return rating_ceiling_loss(tr, te, fitted, BY_NAME, ceilings[id(te)])

    size, size_upper, power, sizes = _size_functions(ceilings, unit, tolerance)

    def localise(diag, rng):
        chosen = ([(s["added"], s["params"]) for s in diag.steps]
                  if diag.verdict != "unexplained" else [])
        return localise_rating(data, chosen, BY_NAME, rng, n_boot=min(n_boot, 500))
    functions = LayerFunctions(
        loss=rating_loss(BY_NAME), floor=lambda te: floor[id(te)], ceiling=ceiling,
        ceiling_given_chosen=True, unit_ids=rating_unit_ids, size=size, size_upper=size_upper,
        where=lambda fits: rating_where(fits, BY_NAME, st.estimates))
    settings = DiagnosisSettings(n_boot=n_boot, min_gain=RATING_MIN_GAIN, min_size=tolerance,
                                 size_unit=unit, size_source=source, tolerate_chosen=True)
    return LayerPlan(
        functions, settings, sizes=lambda _diag: dict(sizes), power=power,
        localise=localise, folds=folds, split=text, warnings=tuple(notes),
        candidates=tuple(rating_candidates(labels_ok)),
        not_identifiable={"individual_differences": unknown} if unknown else {},
        loss_info={"base": {"kind": "rating", "source": base.source,
                            "gain": base.gain, "gain_sd": base.gain_sd,
                            "offset": base.offset, "offset_sd": base.offset_sd,
                            "noise": base.noise, "lapse_rate": base.lapse_rate,
                            "factor_mid": base.factor_mid, "study": str(st.source),
                            "estimates": st.estimates, "scale": list(st.scale),
                            "step": st.step},
                   "floor": "the predictive entropy of the ceiling over the plain simulation "
                            "(the expected loss of a model right up to its noise)"})
