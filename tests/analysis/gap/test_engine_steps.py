"""The engine's named steps, one at a time, on losses with known gains: scoring, the greedy
combination and its backfitting, the gap's measures, the test of what remains with its
tolerance, the shares and verdict, the words, and the checks of the settings."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap.engine import (
    Candidate,
    Diagnosis,
    DiagnosisSettings,
    GapError,
    LayerFunctions,
    diagnose_losses,
    holm,
    summarise,
)
from analysis.gap.engine.heldout import CrossFit, cluster_codes, cross_fit
from analysis.gap.engine.stats import PairedTest, boot_idx
from analysis.gap.engine.steps import (
    Combination,
    apply_tolerance,
    combine_greedily,
    explained_shares,
    measure_gap,
    remaining_gap,
    score_candidates,
    verdict_of,
)

N = 400


def _setup(gains: dict, *, seed: int = 0, n_boot: int = 200):
    """A one-split cross-fit whose candidate ``name`` lowers every unit's loss by
    ``gains[name]`` (plus 0.01 nats of scatter); the bootstrap test drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    base = rng.normal(1.0, 0.1, N)
    drop = {n: g + rng.normal(0.0, 0.01, N) for n, g in gains.items()}

    def loss(_data, fitted):
        return base - sum((drop[n] for n, _ in fitted), np.zeros(N))
    cv = CrossFit([("train", "test", loss)], loss, None)
    return cv, base, PairedTest(boot_idx(rng, N, n_boot))


def _cands(*names, fit=None):
    return [Candidate(n, fit or (lambda _t, _c: {})) for n in names]


def test_scoring_ranks_candidates_by_held_out_gain_with_holm_adjusted_p():
    cv, base, test = _setup({"small": 0.05, "none": 0.0, "large": 0.2})
    ranking = score_candidates(_cands("small", "none", "large"), cv, base, test,
                               DiagnosisSettings(min_gain=0.1))
    assert [s.name for s in ranking] == ["large", "small", "none"]
    assert ranking[0].gain == pytest.approx(0.2, abs=0.005)
    assert ranking[0].ci_low < ranking[0].gain < ranking[0].ci_high
    by_name = {s.name: s for s in ranking}
    adjusted = holm(np.array([by_name[n].p_one_sided for n in ("small", "none", "large")]))
    assert [by_name[n].p_holm for n in ("small", "none", "large")] == list(adjusted)
    # 'small' is certain but below the minimum gain; 'none' is not significant.
    assert [s.significant for s in ranking] == [True, False, False]


def test_scoring_fits_each_candidate_alone_on_each_folds_training_data():
    seen = []
    cv, base, test = _setup({"a": 0.1})
    score_candidates(_cands("a", fit=lambda tr, ch: seen.append((tr, ch)) or {}), cv, base,
                     test, DiagnosisSettings())
    assert seen == [("train", [])]


def test_greedy_combination_adds_a_candidate_that_helps_only_beside_another():
    rng = np.random.default_rng(0)
    base = rng.normal(1.0, 0.1, N)

    def loss(_data, fitted):
        names = [n for n, _ in fitted]
        out = base - (0.2 if "a" in names else 0.0)
        return out - (0.1 if "a" in names else -0.05) if "b" in names else out
    cv = CrossFit([(None, None, loss)], loss, None)
    test = PairedTest(boot_idx(rng, N, 200))
    ranking = score_candidates(_cands("b", "a"), cv, base, test, DiagnosisSettings())
    assert not next(s for s in ranking if s.name == "b").significant
    comb = combine_greedily(_cands("b", "a"), cv, base, test, DiagnosisSettings())
    assert [s["added"] for s in comb.steps] == ["a", "b"]
    assert [n for n, _ in comb.chosen[0]] == ["a", "b"]
    assert comb.loss == pytest.approx(base - 0.3)


def test_greedy_combination_stops_at_max_steps_and_at_the_minimum_gain():
    cv, base, test = _setup({"a": 0.3, "b": 0.2, "c": 0.01})
    capped = combine_greedily(_cands("a", "b", "c"), cv, base, test,
                              DiagnosisSettings(max_steps=1))
    assert [s["added"] for s in capped.steps] == ["a"]
    floored = combine_greedily(_cands("a", "b", "c"), cv, base, test,
                               DiagnosisSettings(min_gain=0.05))
    assert [s["added"] for s in floored.steps] == ["a", "b"]


@pytest.mark.parametrize("rounds,first", [(0, 0.0), (1, 1.0)])
def test_backfitting_refits_an_earlier_choice_given_the_later_ones(rounds, first):
    """Each fit returns how many candidates were chosen before it: after 'b' joins, a
    backfitted 'a' was fitted given one other, and its step reports the re-fitted value."""
    cv, base, test = _setup({"a": 0.3, "b": 0.2})
    comb = combine_greedily(_cands("a", "b", fit=lambda _t, ch: {"k": len(ch)}), cv, base,
                            test, DiagnosisSettings(refit_rounds=rounds))
    assert [s["added"] for s in comb.steps] == ["a", "b"]
    assert comb.steps[0]["params"] == {"k": first}
    assert comb.steps[1]["params"] == {"k": 1.0} and comb.steps[1]["params_per_fold"] == [
        {"k": 1}]


def test_gap_measures_before_and_after_and_the_shrinkage_from_known_losses():
    rng = np.random.default_rng(2)
    base = rng.normal(1.0, 0.05, N)
    idx = boot_idx(rng, N, 200)
    gap = measure_gap(base, base - 0.4, np.full(N, base.mean() - 0.5), idx)
    assert gap.gap_before == pytest.approx(0.5) and gap.gap_after == pytest.approx(0.1)
    assert gap.shrink_abs == pytest.approx(0.4) and gap.shrink_pct == pytest.approx(80.0)
    assert gap.gap_before_ci[0] < 0.5 < gap.gap_before_ci[1]
    assert gap.shrink_pct_ci == pytest.approx((80.0, 80.0), abs=1.0)
    assert gap.floor_status == "ok" and gap.loss_after == pytest.approx(base.mean() - 0.4)
    # A floor above the loss after the chosen candidates is a wrong floor.
    assert measure_gap(base, base - 0.6, np.full(N, base.mean() - 0.5),
                       idx).floor_status == "misestimated"


def _remaining(ceiling_drop, **settings):
    cv, _, test = _setup({"a": 0.3})
    comb = Combination([{"added": "a"}], [[("a", {})]], cv.losses([[("a", {})]]))
    calls = []

    def where(fits):
        calls.append(fits)
        return "in the highlights"
    functions = LayerFunctions(cv.loss, lambda _d: np.zeros(N),
                               ceiling=lambda _tr, _te, ch: cv.loss(None, ch) - ceiling_drop,
                               ceiling_given_chosen=True, where=where,
                               size=lambda fits: 0.5)
    rem, ceil = remaining_gap(cv, comb, test, functions, DiagnosisSettings(**settings))
    return rem, ceil, calls


def test_remaining_gap_beyond_the_ceiling_is_significant_and_says_where_it_lies():
    rem, ceil, calls = _remaining(0.05, min_size=0.1)
    assert rem["significant"] and rem["gap"] == pytest.approx(0.05)
    assert rem["where"] == "in the highlights"
    assert len(calls) == 1 and [n for n, _ in calls[0][0][2]] == ["a"]
    assert ceil.shape == (N,) and rem["loss_ceiling"] == pytest.approx(ceil.mean())
    rem, _, calls = _remaining(0.0)
    assert not rem["significant"] and rem["where"] == "" and not calls


def test_a_significant_remainder_below_the_size_tolerance_is_within_it_not_significant():
    rem, _, _ = _remaining(0.05, min_size=1.0, size_unit="% of the RMS", size_source="here")
    assert not rem["significant"] and rem["within_tolerance"]
    assert (rem["size"], rem["tolerance"], rem["size_unit"], rem["size_source"]) == (
        0.5, 1.0, "% of the RMS", "here")
    assert rem["where"] == "in the highlights"  # still said where it lies
    # A size that cannot be measured never excuses a gap.
    assert apply_tolerance(True, float("nan"), DiagnosisSettings(min_size=1.0))["significant"]
    assert not apply_tolerance(False, 5.0, DiagnosisSettings(min_size=1.0))["significant"]


def test_explained_share_is_bounded_by_what_the_ceiling_removes():
    base = np.full(10, 1.0)
    gap = measure_gap(base, base - 0.3, np.zeros(10), boot_idx(np.random.default_rng(0), 10,
                                                                   20))
    assert explained_shares(gap, base, base - 0.3, None) == (pytest.approx(0.3),
                                                             pytest.approx(float("nan"),
                                                                           nan_ok=True))
    share, ceiling_share = explained_shares(gap, base, base - 0.3, base - 0.5)
    assert share == pytest.approx(0.6) and ceiling_share == pytest.approx(0.5)
    assert explained_shares(gap, base, base - 0.3, base - 0.2)[0] == 1.0  # beats the ceiling
    assert explained_shares(gap, base, base - 0.3, base + 0.1)[0] == 1.0  # ceiling removes none


def test_verdict_is_unexplained_without_steps_or_below_the_minimum_share():
    steps = [{"added": "a"}, {"added": "b"}]
    assert verdict_of(steps, 0.6, 0.5) == "a + b"
    assert verdict_of(steps, 0.4, 0.5) == "unexplained"
    assert verdict_of(steps, float("nan"), 0.5) == "a + b"
    # Without a ceiling: a held-out gap whose CI lies above min_gain is unexplained; one that
    # does not is not excluded (no misfit bound): inconclusive, never "no gap".
    assert verdict_of([], 1.0, 0.0, gap_before_ci=(0.1, 0.3)) == "unexplained"
    assert verdict_of([], 1.0, 0.0, gap_before_ci=(-0.1, 0.3)) == "inconclusive"
    # A mis-estimated floor is neither a gap nor its exclusion.
    assert verdict_of([], 1.0, 0.0, floor_status="misestimated") == "inconclusive"
    # ... unless the misfit's bound rests on no noise model and excludes a gap.
    bounded = {"significant": False, "size": 0.1, "size_upper": 0.4, "tolerance": 1.0}
    assert verdict_of([], 1.0, 0.0, floor_status="misestimated", remaining=bounded) \
        == "inconclusive"
    assert verdict_of([], 1.0, 0.0, floor_status="misestimated", remaining=bounded,
                      size_without_noise_model=True) == "no_gap_that_matters"


def _rem(significant, size, upper, tol=1.0, **more):
    return {"significant": significant, "size": size, "size_upper": upper, "tolerance": tol,
            **more}


def test_no_gap_that_matters_only_when_the_misfits_upper_bound_lies_below_the_tolerance():
    # Nothing significant and the bound below the tolerance: the data exclude a gap.
    assert verdict_of([], 0.0, 0.0, remaining=_rem(False, 0.2, 0.8)) == "no_gap_that_matters"
    # Nothing significant but the bound above: neither found nor excluded.
    assert verdict_of([], 0.0, 0.0, remaining=_rem(False, 0.2, 1.4)) == "inconclusive"
    # Significant in nats but small and well bounded: excluded all the same.
    assert verdict_of([], 0.0, 0.0, remaining=_rem(False, 0.2, 0.5, within_tolerance=True)
                      ) == "no_gap_that_matters"
    assert verdict_of([], 0.0, 0.0, remaining=_rem(True, 1.5, 2.0)) == "unexplained"
    # A layer without a bound can never exclude a gap.
    assert verdict_of([], 0.0, 0.0, remaining={"significant": False}) == "inconclusive"
    # Chosen effects held to the tolerance by the plain simulation's own misfit.
    steps = [{"added": "a"}]
    small = _rem(False, 0.1, 0.2, size_before=0.4, size_before_upper=0.7)
    unsure = _rem(False, 0.1, 0.2, size_before=0.4, size_before_upper=1.3)
    large = _rem(False, 0.1, 0.2, size_before=1.4, size_before_upper=1.9)
    kw = {"tolerate_chosen": True}
    assert verdict_of(steps, 1.0, 0.5, remaining=small, **kw) == "no_gap_that_matters"
    assert verdict_of(steps, 1.0, 0.5, remaining=unsure, **kw) == "inconclusive"
    assert verdict_of(steps, 1.0, 0.5, remaining=large, **kw) == "a"
    assert verdict_of(steps, 1.0, 0.5, remaining=small) == "a"  # not held to it
    # A mis-estimated floor: the nats prove nothing, so the size decides only where it does
    # not use the noise model (the render layer's; blind render seed 1004's plain Ward sphere
    # read "broad_lobe", its misfit 0.04 % of the photos' RMS, bound 0.10 %).
    assert verdict_of(steps, 1.0, 0.5, remaining=small, floor_status="misestimated", **kw) == "a"
    assert verdict_of(steps, 1.0, 0.5, remaining=small, floor_status="misestimated",
                      size_without_noise_model=True, **kw) == "no_gap_that_matters"
    assert verdict_of(steps, 1.0, 0.5, remaining=large, floor_status="misestimated",
                      size_without_noise_model=True, **kw) == "a"


def test_summary_says_what_is_explained_and_what_remains_within_the_tolerance():
    d = Diagnosis(layer="render", ranking=(), steps=({"added": "long_tail"},),
                  verdict="long_tail", gap_before=0.3, gap_after=0.1, shrink_abs=0.2,
                  shrink_abs_ci=(0.1, 0.3), shrink_pct=66.0, shrink_pct_ci=(50.0, 80.0), seed=1,
                  explained_share=0.8, gap_before_ci=(0.2, 0.4), gap_after_ci=(0.05, 0.15),
                  remaining={"gap": 0.02, "ci": (0.01, 0.03), "p": 0.001, "significant": False,
                             "within_tolerance": True, "where": "in the rim", "size": 0.24,
                             "tolerance": 1.0, "size_unit": "% of the RMS",
                             "size_source": "the design"})
    assert summarise(d) == (
        "long tail explains 80 % of the gap a flexible model of the data removes; what "
        "remains is statistically significant (0.020 nats per unit above a flexible model of "
        "the data, 95 % CI 0.010 to 0.030) but within the tolerance: a misfit of about 0.24 % "
        "of the RMS, below the tolerance of 1 % (the design), in the rim; not counted as a gap "
        "beyond the catalogue.")


def test_the_pipeline_draws_the_bootstrap_once_after_the_plain_losses():
    """The only draw from ``rng`` is the (n_boot, n_units) resample, so a seed gives the same
    resamples as before the engine was split into steps."""
    cv, _, _ = _setup({"a": 0.2})
    rng = np.random.default_rng(7)
    diag = diagnose_losses("test", _cands("a"), LayerFunctions(cv.loss, lambda _d: np.zeros(N)),
                           DiagnosisSettings(n_boot=50), rng=rng, seed=7)
    twin = np.random.default_rng(7)
    twin.integers(0, N, size=(50, N))
    assert rng.integers(0, 2**62) == twin.integers(0, 2**62)
    assert diag.verdict == "a" and diag.summary.startswith("a explains")


@pytest.mark.parametrize("field,value,match", [
    ("alpha", 0.0, "alpha must be in \\(0, 1\\); got 0.0"),
    ("alpha", 1.5, "alpha must be in"),
    ("n_boot", 0, "n_boot must be an integer >= 1; got 0"),
    ("n_boot", 100.0, "n_boot must be an integer"),
    ("max_steps", -1, "max_steps must be an integer >= 0"),
    ("min_share", 1.2, "min_share must be in \\[0, 1\\]"),
    ("min_gain", float("nan"), "min_gain must be a finite number"),
    ("refit_rounds", True, "refit_rounds must be an integer"),
    ("min_size", -0.5, "min_size must be >= 0 and finite"),
    ("size_unit", 3, "size_unit must be a string"),
])
def test_settings_refuse_a_value_out_of_range_and_name_it(field, value, match):
    with pytest.raises(GapError, match=match):
        DiagnosisSettings(**{field: value})


def test_layer_functions_refuse_what_the_engine_cannot_call():
    with pytest.raises(GapError, match="loss must be a function; got None"):
        LayerFunctions(None, lambda d: d)
    with pytest.raises(GapError, match="where must be a function or None; got 'x'"):
        LayerFunctions(len, len, where="x")
    with pytest.raises(GapError, match="ceiling_given_chosen=True needs a ceiling"):
        LayerFunctions(len, len, ceiling_given_chosen=True)


def test_held_out_units_refuse_empty_folds_unnamed_repeats_and_unnamed_clusters():
    with pytest.raises(GapError, match="layer 'x': no folds given"):
        cross_fit("x", len, None, None, None, [])
    with pytest.raises(GapError, match="cross-fitting needs unit_ids"):
        cross_fit("x", lambda tr: len, None, None, None, [(1, 2), (3, 4)])
    cv = cross_fit("x", len, None, None, None, None)
    with pytest.raises(GapError, match="cluster_of needs unit_ids"):
        cluster_codes(cv, str)
    named = CrossFit([(None, None, len)], len, lambda _te: ["p0", "p1", "q0"])
    assert list(cluster_codes(named, lambda u: u[0])) == [0, 0, 1]


def test_a_misestimated_floor_held_to_the_tolerance_says_the_plain_simulations_misfit():
    """Chosen effects under a mis-estimated floor, excluded by the plain simulation's own
    misfit (the render layer): the words give that misfit and its bound, not the chosen
    model's, which did not decide."""
    d = Diagnosis(layer="render", ranking=(), steps=({"added": "broad_lobe"},),
                  verdict="no_gap_that_matters", gap_before=0.02, gap_after=-0.05,
                  shrink_abs=0.07, shrink_abs_ci=(0.05, 0.09), shrink_pct=300.0,
                  shrink_pct_ci=(200.0, 400.0), seed=1, explained_share=1.0,
                  gap_before_ci=(0.01, 0.03), gap_after_ci=(-0.06, -0.04),
                  floor_status="misestimated", misfit_upper=0.10,
                  remaining={"gap": 0.0, "ci": (-0.01, 0.01), "p": 0.5, "significant": False,
                             "size": 0.16, "size_upper": 0.18, "size_before": 0.038,
                             "size_before_upper": 0.10, "tolerance": 1.0,
                             "size_unit": "% of the RMS", "size_source": "the design"})
    words = summarise(d)
    assert words.startswith("No gap that matters (the misfit's bound rests on no noise "
                            "model): The noise floor is mis-estimated"), words
    assert ("Attributed: broad lobe. Without it the plain simulation leaves a misfit of about "
            "0.038 % of the RMS (upper 95 % bound 0.1 %), so a misfit of the tolerance, 1 % "
            "(the design), is excluded.") in words, words
