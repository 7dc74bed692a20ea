"""Observer layer: session-CSV responses vs a simulated observer (fitted or ideal).

Both responses are modelled in raw slider units (the design's slider spec maps physical units
to slider positions). The *base* model is the simulation: the observer a lab fitted to its own
pilot (``python -m experiment fit-observer``, the ``humanlike`` model's population means), an
observers TOML table, or the observer that generated simulated session CSVs (its mean response
fitted in the humanlike model's form). Each catalogue candidate (one :class:`Candidate` per
effect, registered here) extends the base; the per-trial loss is the negative log-likelihood
of both responses (nats), Gaussian noise censored at the slider ends. The noise SDs are fitted
on the training data for every model, so a uniformly noisier lab is no gap; noise that changes
with the stimulus is (the ceiling models it).

The *ceiling* (:func:`fit_ceiling`, ``ceiling.py``, whose docstring gives its terms) is a
flexible extension of a model fitted to the real data; the remaining gap is tested with the
ceiling built on the *chosen* model. The noise *floor* is the loss the ceiling over the plain
simulation has on data it generates itself, not an assumed noise of an ideal observer.

Fewer than 4 participants never exclude a gap (no ``'no_gap_that_matters'``): their trials are
held out within each person and the ceiling is fitted from these few people, so the misfit's
bound holds for them, not for the population (:func:`_few_to_exclude`; ``to_decide`` counts
participants there too).

Where things are
----------------
``model.py``
    The simulation's prediction and likelihood: :func:`to_slider_units`, the base model
    (:class:`ObserverBase`, :func:`base_from_params`, :func:`adapt_base`; where participants
    are held out whole, :func:`adapt_own_offsets` and :func:`adapt_population`: the null is the
    fitted population, and the tests count participants as the independent units),
    :func:`predict`,
    :func:`observer_nll`, :func:`observer_loss` (noise SDs fitted per model),
    :data:`OBSERVER_MIN_GAIN`.
``data.py``
    Reading and checking the files: :func:`read_session_csvs`, :func:`load_sim`
    (:func:`base_from_sessions`), :func:`check_sim`, :func:`observer_frame` (column checks,
    slider units, previous response, the base's mean); the held-out scheme
    (:func:`observer_folds`, :func:`observer_unit_ids`).
``ceiling.py``
    The flexible model and the noise floor: :func:`fit_ceiling`, :func:`ceiling_loss`,
    :func:`ceiling_floor`.
``where.py``
    Where the remaining gap lies: :func:`observer_where`, :func:`localise_observer`; and how
    far, in slider units and the study's units (gloss %, depth cm): the plain and the
    chosen model's predicted settings against the flexible model's, and the settings' scatter
    about the latter (:func:`observer_misfit`); the chosen model's is held to the design's
    ``[gap] observer_tolerance_slider``.
``candidates.py``
    The catalogue, one registered :class:`Candidate` per effect
    (:data:`OBSERVER_CANDIDATES`).
``participants/``
    Single participants who depart from the others where the misfit cannot see them
    (:func:`analysis.gap.observer.participants.participant_departures`; the engine weighs
    them into the verdict, :mod:`analysis.gap.engine.departures`).
``offsets/``
    The ceiling's per-stimulus and per-cell offsets, shrunk across participants.

``__init__.py`` (here)
    The layer's face to the engine, :func:`plan` (the same in every layer).

Imports run model <- data, model <- ceiling <- where, model <- candidates; importing this
package registers the candidates (:func:`analysis.gap.engine.catalogue` imports it for that).
"""

from pathlib import Path

import numpy as np

from analysis.gap.engine import (
    DiagnosisSettings,
    GapError,
    LayerFunctions,
    LayerPlan,
    judged_plain,
)
from analysis.gap.observer.candidates import OBSERVER_CANDIDATES
from analysis.gap.observer.ceiling import ceiling_floor, ceiling_loss, fit_ceiling
from analysis.gap.observer.data import (
    base_from_sessions,
    check_sim,
    load_sim,
    observer_folds,
    observer_frame,
    observer_unit_ids,
    read_session_csvs,
)
from analysis.gap.observer.model import (
    OBSERVER_MIN_GAIN,
    ObserverBase,
    adapt_base,
    adapt_own_offsets,
    adapt_population,
    base_from_params,
    observer_loss,
    observer_nll,
    predict,
    to_slider_units,
)
from analysis.gap.observer.participants import participant_departures
from analysis.gap.observer.power import (
    misfit_ceiling_draws,
    misfit_power,
    misfit_terms,
    misfit_upper,
)
from analysis.gap.observer.where import (
    OBSERVER_SIZE_UNIT,
    localise_observer,
    observer_misfit,
    observer_where,
)

__all__ = [
    "OBSERVER_CANDIDATES",
    "OBSERVER_MIN_GAIN",
    "OBSERVER_SIZE_UNIT",
    "ObserverBase",
    "adapt_base",
    "adapt_own_offsets",
    "adapt_population",
    "base_from_params",
    "base_from_sessions",
    "ceiling_floor",
    "ceiling_loss",
    "check_sim",
    "fit_ceiling",
    "load_sim",
    "localise_observer",
    "observer_folds",
    "observer_frame",
    "observer_loss",
    "observer_misfit",
    "observer_nll",
    "observer_unit_ids",
    "observer_where",
    "plan",
    "predict",
    "read_session_csvs",
    "to_slider_units",
]


def _same_path(real, sim) -> None:
    if (isinstance(real, (str, Path)) and isinstance(sim, (str, Path))
            and Path(real).resolve() == Path(sim).resolve()):
        raise GapError(f"--real and --sim are the same path ({real}); pass the simulation")


def _has_spread(base: ObserverBase) -> bool:
    """Whether the simulation says how far its observers differ from each other."""
    return bool(base.sd) and any(any(v > 0 for v in sd) for sd in base.sd.values())


def _few_participants(data, base: ObserverBase) -> list[str]:
    """A warning where fewer than 4 participants are held out by trial and the simulation
    has no between-observer spread: individual differences are then not tested."""
    n = data["participant"].nunique()
    if n >= 4 or _has_spread(base):
        return []
    return [(f"only {n} participant(s) and a simulation without a between-observer spread: a "
            "participant's own offset and slopes cannot be told from a gap and are not tested; "
            "diagnose 4 or more participants, or simulate with an observers TOML or simulated "
            "sessions of several observers")]


def _few_to_exclude(data) -> tuple[str, ...]:
    """Why fewer than 4 participants cannot exclude a gap of the tolerance, whatever the
    misfit's bound says (:attr:`analysis.gap.engine.LayerPlan.cannot_exclude`); empty with 4
    or more.

    Their trials are held out within each person, and the flexible model the misfit is
    measured against is fitted from these few people, each with their own offset and slopes:
    its population part is shrunk toward the simulation, and one person's departure is judged
    against two others. Effects at the tolerance read "no gap that matters" there (blind dev
    seeds 0-3 at 3 participants, 2026-11-28: 3 of 48 effects at 1-2x the tolerance, a
    participant who now and then swaps the sliders and depth inflated under one illumination,
    bounds 0.22-0.25 slider units; the population generator's depth rising with gloss at 1.2x
    the tolerance, bound 0.21)."""
    n = data["participant"].nunique()
    if n >= 4:
        return ()
    why = (f"with {n} participant(s) the flexible model of the population is fitted from "
           "these few people, each with their own offset and slopes, and one person's "
           "departure is judged against the other one or two, so the misfit's bound holds "
           "for these people, not for the population (effects at the tolerance read no gap "
           "there); diagnose 4 or more participants, held out whole.")
    return (why,)


def _size_functions(design, ceilings: dict):
    """``(size, size_upper, power, sizes, departures)``: the layer's misfit, its upper 95 %
    bound and its PowerModel, measured against the ceilings fitted per fold (``ceilings``,
    filled by the ceiling step), the dict the misfits are kept in for the Diagnosis, and the
    check of single participants who depart from the others
    (:func:`analysis.gap.observer.participants.participant_departures`, on the chosen model's
    fits)."""
    sizes, terms = {}, {}

    def size(fits):
        # The ceilings just fitted on each fold's chosen model (remaining_gap's): the misfits
        # of the plain and the chosen model against them, kept for the Diagnosis (sizes).
        # The first call is remaining_gap's, with the chosen model; a later one (the plain
        # simulation's size) must not replace the record.
        measured = observer_misfit(fits, ceilings, design.slider)
        if not sizes:
            sizes.update(measured)
        return measured.get("misfit_after", float("nan"))

    def size_upper(fits):
        # The chosen model's (the first call's, as size's) per-trial terms kept for power,
        # and the plain simulation's (a call with nothing chosen) for a verdict it decides.
        t, u = misfit_terms(fits, ceilings)
        c = misfit_ceiling_draws(fits, ceilings)
        terms.setdefault("after", (t, u, c))
        terms.setdefault("fits", fits)
        if not any(chosen for _tr, _te, chosen, _c in fits):
            terms["plain"] = (t, u, c)
        return misfit_upper(t, u, c)

    def power(diag):
        # Named effects held to the tolerance: the verdict judged the plain simulation.
        t, u, c = terms.get("plain" if judged_plain(diag) else "after",
                            (np.zeros(0), np.zeros(0), np.zeros(0)))
        return misfit_power(t, u, design.gap.observer_tolerance_slider, ceiling=c)

    def departures(_diag):
        # On the chosen model's fits (size_upper's first call, as its terms).
        if "fits" not in terms:
            return {}
        return participant_departures(terms["fits"], design.gap.observer_tolerance_slider)
    return size, size_upper, power, sizes, departures


def _participant(unit_id: str) -> str:
    """The participant of a held-out trial (``participant|session|order``)."""
    return unit_id.split("|", 1)[0]


def plan(real, sim, design, rng: np.random.Generator, *, n_boot: int,
         sim_kind: str | None = None, k_folds: int = 5, study=None,
         participants=None) -> LayerPlan:
    """Session CSVs (or a session frame) against the simulated observer (``sim``: an
    observers TOML, simulated session CSVs or a frame; see :func:`load_sim`), cross-fitted
    over ``k_folds`` folds of participants or trials.

    With ``study`` (another lab's study.toml: one response on a rating scale) the rating
    plan does it instead (:func:`analysis.gap.observer.rating.plan`; ``participants`` keeps
    only those).

    The floor of each fold is the noise of the ceiling over the plain simulation (data-driven,
    drawn from ``rng``); the ceiling of the chosen model is what a flexible extension of it
    still gains. What remains counts as a gap only where the chosen model's settings also lie
    at least the design's ``[gap] observer_tolerance_slider`` from the ceiling's
    (:func:`observer_misfit`, in slider units; the Diagnosis's ``misfit_*`` fields). Named
    effects are held to it too (``tolerate_chosen``, as in every layer): where nothing
    significant remains beyond them, the plain simulation's own misfit and its bound decide
    (a catalogue effect significant at 0.1-0.2 slider units, below the 0.25 tolerance, is no
    gap that matters where the bound excludes the tolerance, else inconclusive).
    """
    _same_path(real, sim)
    if study is not None:
        from analysis.gap.observer import rating

        return rating.plan(real, sim, design, rng, n_boot=n_boot, study=study,
                           participants=participants, k_folds=k_folds)
    if participants is not None:
        raise GapError("--participants is for --study (another lab's study); session CSVs "
                       "are diagnosed whole")
    frame = real if not isinstance(real, (str, Path)) else read_session_csvs(real)
    base = load_sim(sim, design, kind=sim_kind)
    notes = check_sim(frame, base)
    data = observer_frame(frame, design, base)
    folds, text = observer_folds(data, k_folds)
    notes = notes + _few_participants(data, base)
    floor, shared = {}, {}
    for tr, te in folds:
        # Participants' own intercepts and slopes in the ceiling only where the simulation
        # says how far observers differ (its between-observer SDs): without that spread a
        # person's own offset, held out by trial, is no more a gap than it is held out by
        # participant (issue 43).
        shared[id(te)] = (bool(set(tr["participant"]) & set(te["participant"]))
                          and _has_spread(base))
        tr.attrs["by_participant"] = shared[id(te)]
        if not shared[id(te)]:
            adapt_own_offsets(tr, base)
            adapt_own_offsets(te, base)
            adapt_population(tr, te, base)
        adapt_base(tr, te, base)
        model = fit_ceiling(tr, by_participant=shared[id(te)])
        floor[id(te)] = ceiling_floor(model, te, rng)

    ceilings = {}

    def ceiling(tr, te, fitted):
        ceilings[id(te)] = fit_ceiling(tr, by_participant=shared[id(te)], fitted=fitted)
        return ceiling_loss(ceilings[id(te)], te)

    size, size_upper, power, sizes, departures = _size_functions(design, ceilings)
    functions = LayerFunctions(loss=observer_loss, floor=lambda te: floor[id(te)],
                               ceiling=ceiling, ceiling_given_chosen=True, where=observer_where,
                               size=size, size_upper=size_upper, unit_ids=observer_unit_ids,
                               cluster_of=None if any(shared.values()) else _participant)
    settings = DiagnosisSettings(n_boot=n_boot, min_gain=OBSERVER_MIN_GAIN,
                                 min_size=design.gap.observer_tolerance_slider,
                                 size_unit=OBSERVER_SIZE_UNIT,
                                 size_source="the design's [gap] observer_tolerance_slider",
                                 tolerate_chosen=True)
    return LayerPlan(
        functions, settings,
        localise=lambda _diag, rng: localise_observer(data, design, rng, n_boot=min(n_boot, 500)),
        folds=folds, split=text, warnings=notes, sizes=lambda _diag: dict(sizes), power=power,
        departures=departures, cannot_exclude=_few_to_exclude(data),
        excluded_where="for these participants",
        loss_info={"base": {"kind": base.kind, "source": base.source,
                            "coef_slider_units": {r: list(v) for r, v in base.coef.items()}},
                   "floor": "the ceiling model's own loss on data it draws (data-driven)"})
