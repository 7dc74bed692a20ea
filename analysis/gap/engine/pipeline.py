"""The diagnosis as a pipeline of named steps (:mod:`analysis.gap.engine.steps`): score each
candidate -> combine greedily with re-tests -> measure the gap -> test what remains against
the ceiling -> shares, verdict and words."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict

import numpy as np

from analysis.gap.engine.errors import GapError
from analysis.gap.engine.heldout import cluster_codes, cross_fit
from analysis.gap.engine.registry import Candidate
from analysis.gap.engine.result import Diagnosis
from analysis.gap.engine.settings import DiagnosisSettings, LayerFunctions
from analysis.gap.engine.stats import PairedTest, boot_idx
from analysis.gap.engine.steps import (
    combine_greedily,
    explained_shares,
    measure_gap,
    remaining_gap,
    score_candidates,
    verdict_of,
)
from analysis.gap.engine.words import with_summary

__all__ = ["diagnose_losses"]

#: The settings of a diagnosis given none.
_DEFAULT_SETTINGS = DiagnosisSettings()


def diagnose_losses(
    layer: str,
    candidates: list[Candidate],
    functions: LayerFunctions,
    settings: DiagnosisSettings = _DEFAULT_SETTINGS,
    *,
    rng: np.random.Generator,
    seed: int,
    train=None,
    test=None,
    folds: Sequence | None = None,
    loss_info: dict | None = None,
    split: str = "",
    warnings: Sequence[str] = (),
    not_identifiable: dict | None = None,
) -> Diagnosis:
    """Rank candidates, combine greedily, measure the held-out gap before and after, and test
    what remains against a flexible ceiling.

    Parameters
    ----------
    layer : str
        The layer's name (recorded; in error messages).
    candidates : list of Candidate
        The catalogue, in registration order.
    functions : LayerFunctions
        The layer's loss, floor and (optional) ceiling, where, size, unit ids and clusters.
    settings : DiagnosisSettings
        alpha, resamples, greedy steps, minimum share and gain, backfitting, tolerance.
    rng : numpy.random.Generator
        Draws the bootstrap resamples, once, after the plain simulation's losses.
    seed : int
        The seed ``rng`` came from (recorded).
    train, test, folds
        One split (each a layer's data object), or ``folds`` ``[(train, test), ...]`` for
        cross-fitting: every unit held out once per repeat (needs ``functions.unit_ids``,
        which identify units across repeats; per-unit losses are averaged over repeats).
    loss_info, split, warnings
        Recorded as given: parameters of the loss itself (e.g. the noise model), how units
        were held out in words, warnings about the inputs (shown in the report).
    not_identifiable : dict or None
        ``{candidate name: reason}``: effects the layer found not identifiable from the data
        given (e.g. a DAC step with levels too coarse to show it); they are left out of the
        ranking and the combination, recorded and named in the words.

    Returns
    -------
    Diagnosis

    Raises
    ------
    GapError
        An empty catalogue, empty folds, several folds without ``unit_ids``, or
        ``cluster_of`` without ``unit_ids``.
    """
    if not candidates:
        raise GapError(f"layer {layer!r}: empty candidate catalogue; pass at least one candidate")
    skip = dict(not_identifiable or {})
    candidates = [c for c in candidates if c.name not in skip]
    cv = cross_fit(layer, functions.loss, functions.unit_ids, train, test, folds)
    base = cv.losses(cv.nothing_chosen())
    floor = cv.per_unit([functions.floor(te) for _, te, _ in cv.folds])
    paired = PairedTest(boot_idx(rng, base.size, settings.n_boot),
                        cluster_codes(cv, functions.cluster_of))
    ranking = score_candidates(candidates, cv, base, paired, settings)
    combination = combine_greedily(candidates, cv, base, paired, settings)
    gap = measure_gap(base, combination.loss, floor, paired.idx, settings.floor_sd)
    remaining, ceil = (remaining_gap(cv, combination, paired, functions, settings)
                       if functions.ceiling is not None else (None, None))
    share, ceiling_share = explained_shares(gap, base, combination.loss, ceil)
    return _record(layer, ranking, combination, gap, remaining, share, ceiling_share, settings,
                   seed=seed, heldout=tuple(str(u) for u in cv.units) if cv.units is not None
                   else (), loss_info=loss_info, split=split, warnings=tuple(warnings),
                   not_identifiable=skip)


def _record(layer, ranking, combination, gap, remaining, share, ceiling_share, settings,
            **recorded) -> Diagnosis:
    """The Diagnosis with its verdict (:func:`verdict_of`), the remaining misfit's upper 95 %
    bound in the layer's units (``misfit_upper``: the plain simulation's where chosen effects
    are held to the tolerance, else the chosen model's) and its words."""
    rem = remaining or {}
    upper = (rem.get("size_before_upper") if settings.tolerate_chosen and "size_before" in rem
             else rem.get("size_upper"))
    return with_summary(Diagnosis(
        layer=layer,
        ranking=tuple(asdict(s) for s in ranking),
        steps=tuple(combination.steps),
        verdict=verdict_of(combination.steps, share, settings.min_share,
                           floor_status=gap.floor_status, remaining=remaining,
                           gap_before_ci=gap.gap_before_ci, min_gain=settings.min_gain,
                           tolerate_chosen=settings.tolerate_chosen,
                           size_without_noise_model=settings.size_without_noise_model),
        explained_share=share,
        min_share=float(settings.min_share),
        min_gain=float(settings.min_gain),
        remaining=remaining,
        ceiling_share=ceiling_share,
        misfit_upper=float("nan") if upper is None else float(upper),
        tolerance=float(settings.min_size) if "tolerance" in rem else float("nan"),
        **recorded,
        **asdict(gap),
    ))
