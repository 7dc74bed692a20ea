"""The named steps of a diagnosis, in the order :func:`analysis.gap.engine.diagnose_losses`
runs them:

1. :func:`score_candidates`: each candidate alone, fitted on the training folds, scored by the
   held-out loss it removes (bootstrap CI, one-sided p, Holm across candidates);
2. :func:`combine_greedily`: candidates added one at a time, every remaining one re-fitted and
   re-tested at each step, the chosen ones backfitted (:func:`backfit`);
3. :func:`measure_gap`: the held-out gap above the floor before and after, and its shrinkage;
4. :func:`remaining_gap`: the chosen model against the flexible ceiling, with the practical
   tolerance on the misfit's size (:func:`apply_tolerance`);
5. :func:`explained_shares` and :func:`verdict_of`: how much of the gap the chosen candidates
   explain, and the verdict.

Loss units throughout: nats per held-out unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.gap.engine.heldout import CrossFit
from analysis.gap.engine.registry import Candidate
from analysis.gap.engine.result import CandidateScore, jsonable
from analysis.gap.engine.settings import DiagnosisSettings, LayerFunctions
from analysis.gap.engine.stats import PairedTest, boot_means, holm

__all__ = [
    "INCONCLUSIVE",
    "NOT_A_GAP",
    "NO_GAP_THAT_MATTERS",
    "Combination",
    "GapMeasures",
    "apply_tolerance",
    "backfit",
    "combine_greedily",
    "explained_shares",
    "judged_plain",
    "mean_params",
    "measure_gap",
    "remaining_gap",
    "score_candidates",
    "verdict_of",
]

#: The verdict of a diagnosis whose data exclude a gap that matters: nothing significant remains
#: beyond the catalogue (or what remains is smaller than the tolerance) and the upper 95 %
#: bound of the remaining misfit, in the layer's units, lies below the layer's tolerance (an
#: equivalence test). With chosen effects (``tolerate_chosen``) the plain simulation's own
#: misfit is held to it: a change smaller than what matters.
NO_GAP_THAT_MATTERS = "no_gap_that_matters"

#: The verdict of a diagnosis that neither finds a gap nor excludes one of the tolerance: the
#: words and the JSON then say the smallest misfit these data detect (``detectable``) and how
#: much more data would decide (``to_decide``), found by simulation (:mod:`.power`).
INCONCLUSIVE = "inconclusive"

#: The verdicts that are not a gap (every other verdict names effects or is "unexplained").
NOT_A_GAP = (NO_GAP_THAT_MATTERS, INCONCLUSIVE)


def judged_plain(diag) -> bool:
    """Whether a finished Diagnosis's verdict was decided by the plain simulation's own misfit:
    effects were chosen, held to the tolerance (``tolerate_chosen``), and the verdict is not a
    gap (:func:`verdict_of`). Its misfit is then ``remaining['size_before']`` and its bound
    ``misfit_upper``; the power of such a verdict is the plain simulation's (every layer's
    ``power`` hook and the words ask this)."""
    return (bool(diag.steps) and diag.verdict in NOT_A_GAP
            and "size_before" in (diag.remaining or {}))


def with_added(chosen: list[list], name: str, params: list) -> list[list]:
    """Each fold's chosen list with ``(name, params[k])`` appended (new lists)."""
    return [ch + [(name, p)] for ch, p in zip(chosen, params)]


def score_candidates(candidates: list[Candidate], cv: CrossFit, base: np.ndarray,
                     test: PairedTest, settings: DiagnosisSettings) -> list[CandidateScore]:
    """Step 1: each candidate alone against the plain simulation, best first.

    Each is fitted on every fold's training data and scored by the per-unit held-out loss it
    removes from ``base`` (shape (n_units,)); its p-value is adjusted for the number of
    candidates by Holm (1979). It counts when ``p_holm < alpha`` and ``gain >= min_gain``.
    """
    empty = cv.nothing_chosen()
    scores = []
    for cand in candidates:
        params = cv.fit(cand, empty)
        diff = base - cv.losses(with_added(empty, cand.name, params))
        scores.append((cand.name, *test(diff)))
    p_adj = holm(np.array([s[4] for s in scores]))
    return sorted(
        (CandidateScore(n, g, lo, hi, p, float(pa),
                        bool(pa < settings.alpha and g >= settings.min_gain))
         for (n, g, lo, hi, p), pa in zip(scores, p_adj)),
        key=lambda s: -s.gain,
    )


@dataclass(frozen=True, eq=False)
class Combination:
    """The greedy combination's outcome.

    ======= ============================ ===================================================
    field   type                         meaning
    ======= ============================ ===================================================
    steps   list of dict                 per step ``added``, ``gain`` (nats per unit), ``p``,
                                         ``params`` (mean over folds, after backfitting) and
                                         ``params_per_fold``
    chosen  list of list                 per fold the chosen ``[(name, params), ...]``
    loss    ndarray (n_units,)           the chosen model's per-unit held-out loss
    ======= ============================ ===================================================
    """

    steps: list
    chosen: list
    loss: np.ndarray


def combine_greedily(candidates: list[Candidate], cv: CrossFit, base: np.ndarray,
                     test: PairedTest, settings: DiagnosisSettings) -> Combination:
    """Step 2: add candidates one at a time while one reduces the held-out loss.

    At each step every candidate not yet chosen is re-fitted given the chosen ones and
    re-tested (:func:`best_addition`), so a candidate that helps only beside another is found;
    after a step that leaves two or more chosen, each is re-fitted given the others
    (``refit_rounds`` rounds of :func:`backfit`). At most ``max_steps`` steps.
    """
    max_steps = len(candidates) if settings.max_steps is None else settings.max_steps
    chosen = cv.nothing_chosen()
    steps = []
    current = base
    remaining = [c.name for c in candidates]
    by_name = {c.name: c for c in candidates}
    while remaining and len(steps) < max_steps:
        best = best_addition(by_name, remaining, cv, chosen, current, test, settings)
        if best is None:
            break
        name, gain, params, trial, p, chosen = best
        if settings.refit_rounds and len(chosen[0]) > 1:
            chosen, trial, params = _backfit_folds(by_name, cv, chosen, name, steps,
                                                   settings.refit_rounds)
        current = trial
        remaining.remove(name)
        steps.append({"added": name, "gain": gain, "p": p,
                      "params": jsonable(mean_params(params)),
                      "params_per_fold": [jsonable(x) for x in params]})
    return Combination(steps, chosen, current)


def best_addition(by_name: dict, remaining: list[str], cv: CrossFit, chosen: list[list],
                  current: np.ndarray, test: PairedTest, settings: DiagnosisSettings):
    """One greedy step: the candidate of ``remaining`` whose addition to ``chosen`` lowers the
    held-out loss ``current`` most, among those that lower it significantly (one-sided p
    times the number of candidates left < alpha, Holm-like) by at least ``min_gain``.

    Returns
    -------
    tuple or None
        ``(name, gain, params per fold, per-unit loss, p, chosen per fold)``, or None.
    """
    best = None
    for name in remaining:
        params = cv.fit(by_name[name], chosen)
        trial_chosen = with_added(chosen, name, params)
        trial = cv.losses(trial_chosen)
        gain, _, _, p = test(current - trial)
        # Each step is tested against the number of candidates left (Holm-like).
        if (p * len(remaining) < settings.alpha and gain >= settings.min_gain
                and (best is None or gain > best[1])):
            best = (name, gain, params, trial, p, trial_chosen)
    return best


def _backfit_folds(by_name: dict, cv: CrossFit, chosen: list[list], name: str, steps: list,
                   rounds: int):
    """Backfit every fold's chosen list; returns (chosen, per-unit loss, ``name``'s params per
    fold) and rewrites the earlier ``steps``' mean ``params`` to the re-fitted ones."""
    # Backfitting: each chosen candidate re-fitted given all the others, so that an early
    # candidate does not keep a share of an effect a later one explains.
    chosen = [backfit(by_name, tr, ch, rounds) for (tr, _, _), ch in zip(cv.folds, chosen)]
    trial = cv.losses(chosen)
    params = [dict(ch)[name] for ch in chosen]
    for st in steps:
        st["params"] = jsonable(mean_params([dict(ch)[st["added"]] for ch in chosen]))
    return chosen, trial, params


def backfit(by_name: dict, train, chosen: list, rounds: int) -> list:
    """Re-fit each of ``chosen`` given all the others, ``rounds`` times; returns the list in
    the original order of names."""
    order = [n for n, _ in chosen]
    current = list(chosen)
    for _ in range(rounds):
        for name in order:
            others = [(n, q) for n, q in current if n != name]
            current = others + [(name, by_name[name].fit(train, others))]
    params = dict(current)
    return [(n, params[n]) for n in order]


def mean_params(params: list):
    """The mean of a candidate's parameters over folds (numbers averaged, dicts recursively)."""
    first = params[0]
    if isinstance(first, dict):
        keys = [k for k in first if all(isinstance(p, dict) and k in p for p in params)]
        return {k: mean_params([p[k] for p in params]) for k in keys}
    try:
        return float(np.mean([float(p) for p in params]))
    except (TypeError, ValueError):
        return first


@dataclass(frozen=True)
class GapMeasures:
    """The held-out gap above the floor before and after the chosen candidates (nats per
    unit, 95 % percentile-bootstrap CIs) and its shrinkage (absolute; % of the gap before,
    in [0, 100]); ``floor_status`` is ``'misestimated'`` when a gap's CI lies wholly below
    zero, else ``'ok'``. The field names are :class:`Diagnosis`'s."""

    gap_before: float
    gap_after: float
    gap_before_ci: tuple
    gap_after_ci: tuple
    shrink_abs: float
    shrink_abs_ci: tuple
    shrink_pct: float
    shrink_pct_ci: tuple
    loss_before: float
    loss_after: float
    floor_status: str


def measure_gap(base: np.ndarray, current: np.ndarray, floor: np.ndarray,
                idx: np.ndarray, floor_sd: float = 0.0) -> GapMeasures:
    """Step 3: the gap before (``base - floor``) and after (``current - floor``), per-unit
    arrays of shape (n_units,), with CIs from the bootstrap resamples ``idx``. The floor is
    called mis-estimated where a gap's CI, widened by the floor's own uncertainty ``floor_sd``
    (independent of the units' sampling, added in quadrature), lies wholly below zero."""
    gap_b, gap_a = base - floor, current - floor
    gb, ga = float(gap_b.mean()), float(gap_a.mean())
    d = base - current
    gap_b_boot, gap_a_boot, shrink_b = boot_means(np.stack([gap_b, gap_a, d]), idx)
    gb_ci = tuple(float(x) for x in np.percentile(gap_b_boot, [2.5, 97.5]))
    ga_ci = tuple(float(x) for x in np.percentile(gap_a_boot, [2.5, 97.5]))
    pct_b = 100 * np.clip(shrink_b / np.maximum(gap_b_boot, 1e-12), 0.0, 1.0)
    def below(g, ci):
        return bool(ci) and g + np.hypot(ci[1] - g, 1.96 * floor_sd) < 0
    floor_bad = below(gb, gb_ci) or below(ga, ga_ci)
    return GapMeasures(
        gap_before=gb,
        gap_after=ga,
        gap_before_ci=gb_ci,
        gap_after_ci=ga_ci,
        shrink_abs=gb - ga,
        shrink_abs_ci=tuple(float(x) for x in np.percentile(shrink_b, [2.5, 97.5])),
        shrink_pct=float(100 * np.clip((gb - ga) / gb, 0.0, 1.0)) if gb > 0 else float("nan"),
        shrink_pct_ci=tuple(float(x) for x in np.percentile(pct_b, [2.5, 97.5])),
        loss_before=float(base.mean()),
        loss_after=float(current.mean()),
        floor_status="misestimated" if floor_bad else "ok",
    )


def remaining_gap(cv: CrossFit, combination: Combination, test: PairedTest,
                  functions: LayerFunctions, settings: DiagnosisSettings):
    """Step 4: the chosen model's held-out loss against the layer's ceiling, paired,
    one-sided; a significant excess of at least ``min_gain`` is a gap the catalogue does not
    explain (unless within the tolerance on its size: :func:`apply_tolerance`).

    Returns
    -------
    (dict, ndarray)
        ``Diagnosis.remaining`` (``gap``, ``ci``, ``p``, ``significant``, ``loss_ceiling``,
        ``where``; with ``size`` also the tolerance's fields) and the ceiling's per-unit
        held-out loss, shape (n_units,).
    """
    ceiling = functions.ceiling
    ceil_folds = [ceiling(tr, te, ch) if functions.ceiling_given_chosen else ceiling(tr, te)
                  for (tr, te, _), ch in zip(cv.folds, combination.chosen)]
    ceil = cv.per_unit(ceil_folds)
    r_gap, r_lo, r_hi, r_p = test(combination.loss - ceil)
    detected = bool(r_p < settings.alpha and r_gap >= settings.min_gain)
    fits = [(tr, te, ch, cf)
            for (tr, te, _), ch, cf in zip(cv.folds, combination.chosen, ceil_folds)]
    rem = {"gap": r_gap, "ci": (r_lo, r_hi), "p": r_p, "significant": detected,
           "loss_ceiling": float(ceil.mean()), "where": ""}
    if functions.size is not None:
        rem.update(apply_tolerance(detected, float(functions.size(fits)), settings))
        if functions.size_upper is not None:
            rem["size_upper"] = float(functions.size_upper(fits))
        if settings.tolerate_chosen and any(combination.chosen):
            # The plain simulation's own misfit, for a verdict on chosen effects that are
            # smaller than the tolerance.
            plain = [(tr, te, [], cf) for tr, te, _, cf in fits]
            rem["size_before"] = float(functions.size(plain))
            if functions.size_upper is not None:
                rem["size_before_upper"] = float(functions.size_upper(plain))
            if functions.absorbed is not None:
                rem["absorbed"] = float(functions.absorbed(fits))
    if detected and functions.where is not None:
        rem["where"] = functions.where(fits)
    return rem, ceil


def apply_tolerance(detected: bool, size: float, settings: DiagnosisSettings) -> dict:
    """The practical tolerance on the remaining misfit's ``size`` (in the data's units): a
    ``detected`` gap smaller than ``min_size`` is within the tolerance and not significant.

    Returns
    -------
    dict
        ``size``, ``tolerance``, ``size_unit``, ``size_source``, ``within_tolerance`` and
        ``significant`` (the fields it adds to ``Diagnosis.remaining``).
    """
    within = bool(detected and np.isfinite(size) and size < settings.min_size)
    return {"size": size, "tolerance": float(settings.min_size),
            "size_unit": settings.size_unit, "size_source": settings.size_source,
            "within_tolerance": within, "significant": detected and not within}


def explained_shares(gap: GapMeasures, base: np.ndarray, current: np.ndarray,
                     ceil: np.ndarray | None) -> tuple[float, float]:
    """Step 5: (explained share, ceiling share), each in [0, 1] or NaN.

    The explained share is the share of the held-out gap above the floor that the chosen
    candidates remove or, with a ceiling (``ceil``: its per-unit loss) that removes any, the
    share of what the ceiling removes, capped at 1 (a catalogue may beat the ceiling); where
    the ceiling removes nothing and the candidates remove something, 1. The ceiling share is
    the share of the gap above the floor that the ceiling removes (NaN without one).
    """
    gb, ga = gap.gap_before, gap.gap_after
    share = float(np.clip((gb - ga) / gb, 0.0, 1.0)) if gb > 0 else float("nan")
    ceiling_share = float("nan")
    if ceil is None:
        return share, ceiling_share
    d = base - current
    reach = float((base - ceil).mean())
    if gb > 0:
        ceiling_share = float(np.clip(reach / gb, 0.0, 1.0))
    if reach > 0:
        share = float(np.clip(float(d.mean()) / reach, 0.0, 1.0))
    elif float(d.mean()) > 0:
        share = 1.0
    return share, ceiling_share


def verdict_of(steps: list, share: float, min_share: float, *, floor_status: str = "ok",
               remaining: dict | None = None, gap_before_ci=(), min_gain: float = 0.0,
               tolerate_chosen: bool = False, size_without_noise_model: bool = False) -> str:
    """The verdict: a gap (the chosen candidates' names ``a + b``, or ``'unexplained'``),
    :data:`NO_GAP_THAT_MATTERS` or :data:`INCONCLUSIVE`.

    - Chosen effects: their names, or ``'unexplained'`` where they explain less than
      ``min_share`` of the gap (a NaN share does not refuse them). With ``tolerate_chosen``,
      the floor sound (or the size not using the noise model) and nothing significant beyond
      them, the plain simulation's own misfit decides first: its upper 95 % bound
      (``remaining['size_before_upper']``) below the tolerance is no gap that matters; its
      point (``size_before``) below but not its bound, inconclusive -- unless the simulation's
      own fit absorbed the chosen effects by at least the tolerance (``remaining['absorbed']``,
      ``LayerFunctions.absorbed``): then they are a gap.
    - Nothing chosen: inconclusive where the floor is mis-estimated (the held-out loss below
      it: neither a gap nor excluded), unless the size does not use the noise model
      (``size_without_noise_model``) and its bound excludes a gap; ``'unexplained'`` where what remains beyond the ceiling
      is significant (and, with a size, at least the tolerance); no gap that
      matters where the remaining misfit's upper 95 % bound (``remaining['size_upper']``)
      lies below the tolerance; else inconclusive. Without a ceiling: ``'unexplained'``
      where the held-out gap's 95 % CI lies above ``min_gain``, else inconclusive.
    """
    rem = remaining or {}
    sound = floor_status == "ok"
    if steps:
        held = sound or size_without_noise_model
        absorbed = rem.get("absorbed", 0.0) >= rem.get("tolerance", np.inf)
        if (tolerate_chosen and held and not rem.get("significant") and "size_before" in rem
                and not absorbed):
            tol = rem["tolerance"]
            if rem.get("size_before_upper", np.inf) < tol:
                return NO_GAP_THAT_MATTERS
            if rem["size_before"] < tol:
                return INCONCLUSIVE
        explained = share >= min_share if np.isfinite(share) else True
        return " + ".join(s["added"] for s in steps) if explained else "unexplained"
    if not sound:
        # The held-out loss below the noise floor: the floor is wrong, which is neither a gap
        # nor its exclusion -- unless the misfit's bound does not rest on the noise model.
        excluded = rem.get("size_upper", np.inf) < rem.get("tolerance", -np.inf)
        return NO_GAP_THAT_MATTERS if size_without_noise_model and excluded else INCONCLUSIVE
    if remaining is None:
        above = bool(gap_before_ci) and gap_before_ci[0] > max(min_gain, 0.0)
        return "unexplained" if above else INCONCLUSIVE
    if rem.get("significant"):
        return "unexplained"
    if rem.get("size_upper", np.inf) < rem.get("tolerance", -np.inf):
        return NO_GAP_THAT_MATTERS
    return INCONCLUSIVE
