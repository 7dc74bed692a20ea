"""A layer's one face to the engine: what each layer folder hands :func:`diagnose_losses`.

Every layer package ``analysis.gap.<layer>`` defines ``plan(real, sim, design, rng, *,
n_boot, **options) -> LayerPlan``: it reads and checks the files (its ``data.py``), builds the
held-out units, the floor and the ceiling (``model.py``, ``ceiling.py``) and says how to
localise (``where.py``). :func:`analysis.gap.diagnose.diagnose` is written once over these
plans, so a fourth layer is a fourth folder of the same shape plus its name in
:data:`analysis.gap.engine.registry.LAYER_NAMES`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from analysis.gap.engine.result import Diagnosis
from analysis.gap.engine.settings import DiagnosisSettings, LayerFunctions

__all__ = ["LayerPlan"]


@dataclass(frozen=True)
class LayerPlan:
    """What a layer prepares for one diagnosis.

    ================ =========================================================================
    field            meaning
    ================ =========================================================================
    functions        the layer's loss, floor, ceiling, where and size (:class:`LayerFunctions`)
    settings         the statistical choices (:class:`DiagnosisSettings`)
    localise         ``localise(diag, rng) -> table``: where real and simulated data part, with
                     the diagnosis's chosen effects (drawn from the same Generator, after it)
    folds            cross-fitting folds ``[(train, test), ...]``, or None with ``train`` and
                     ``test`` (one split)
    split            how the held-out units were made, in words
    loss_info        what the loss assumes (noise model, base model), recorded in the result
    warnings         notes on the input, shown with the verdict
    candidates       the candidates that apply to this data (Candidate objects, in the order
                     their terms apply); empty: the layer's whole catalogue
    sizes            ``sizes(diag) -> dict``: :class:`Diagnosis` fields measured once the chosen
                     effects are known (the render layer's ``misfit_pct_before`` / ``_after``, the
                     observer layer's ``misfit_*``), or None; the words are written again after
    not_identifiable ``{effect: reason}``: catalogue effects the data cannot identify (left
                     out of the ranking, named in the words)
    power            ``power(diag) -> PowerModel`` or None: how to simulate this layer's data
                     from the diagnosis's fitted models (:class:`~analysis.gap.engine.power.
                     PowerModel`), called only for an ``'inconclusive'`` verdict, after
                     ``sizes``; the engine then finds ``detectable`` and ``to_decide``
                     (:func:`~analysis.gap.engine.power.power_analysis`) and writes the words
                     again. None: an inconclusive verdict says neither
    cannot_exclude   reasons, in words, that the data cannot exclude a gap whatever the misfit's
                     bound says (the display layer's blacks that read 0 where the calibration
                     saw light; the observer layer's fewer than 4 participants): a
                     ``'no_gap_that_matters'`` verdict becomes ``'inconclusive'`` with the
                     reasons in its words (and ``power``'s, where the plan has one)
    excluded_where   words that say what the misfit's bound covers where ``cannot_exclude``
                     keeps it from excluding a gap ("where the meter measured")
    departures       ``departures(diag) -> dict`` or None: single units (the observer layer's
                     participants) that depart from the others where the misfit cannot see
                     them, weighed into the verdict by
                     :func:`~analysis.gap.engine.departures.with_departures`
    ================ =========================================================================

    A layer with three verdicts gives, besides the loss, floor and ceiling:
    ``functions.size`` (the remaining misfit in the lab's units), ``functions.size_upper``
    (its upper 95 % bound: below ``settings.min_size``, the layer's [gap] tolerance, the
    verdict is no gap that matters) and ``power``.
    """

    functions: LayerFunctions
    settings: DiagnosisSettings
    localise: Callable[[Diagnosis, np.random.Generator], object]
    folds: Sequence | None = None
    train: object = None
    test: object = None
    split: str = ""
    loss_info: dict | None = None
    warnings: tuple = field(default_factory=tuple)
    candidates: tuple = ()
    sizes: Callable[[Diagnosis], dict] | None = None
    not_identifiable: dict = field(default_factory=dict)
    power: Callable[[Diagnosis], object] | None = None
    cannot_exclude: tuple = ()
    excluded_where: str = "where the meter measured"
    departures: Callable[[Diagnosis], dict] | None = None
