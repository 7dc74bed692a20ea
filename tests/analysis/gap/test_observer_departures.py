"""Issue 43's two harmful misses of the observer layer, on the unseen blind seeds: a bias that
grows with the time on task, and one participant who now and then swaps the two sliders, each
read "no gap that matters" at twice the tolerance, because the misfit compared settings by
stimulus only (the drift is noise to it) and, with participants held out whole, one person's
swaps barely move a flexible model of the population. Now the flexible model knows the time on
task (minutes since the session's start and since its last rest) and each participant is
weighed against the others' scatter and the correlation of their two errors
(:mod:`analysis.gap.observer.participants`)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from analysis.gap import diagnose
from analysis.gap.engine import Diagnosis, summarise
from analysis.gap.engine.departures import with_departures
from analysis.gap.observer import observer_frame
from analysis.gap.observer.data import time_on_task
from analysis.gap.observer.participants import MIN_PARTICIPANTS, participant_departures
from tests.analysis.gap.observer_population_gen import DESIGN, fitted_simulation, population

TOL = DESIGN.gap.observer_tolerance_slider


def test_time_on_task_restarts_after_a_rest_and_goes_on_over_a_resumed_clock():
    """Minutes since the session's start and since the last rest: a pause of 30 s or more
    between a response and the next onset is a rest; a session clock that starts again (a
    resumed run) is one too, and the session's own time goes on from its last trial."""
    frame = pd.DataFrame({
        "participant": ["A"] * 6 + ["B"] * 2, "session": [1] * 6 + [1] * 2,
        "onset_s": [0.0, 60.0, 120.0, 215.0, 5.0, 65.0, 30.0, 90.0],
        "rt_s": [4.0, 4.0, 4.0, 4.0, 4.0, 4.0, 4.0, 4.0]})
    # A: gaps of 56 s (a rest? 60 - 4 = 56 >= 30: yes), 56, 91; then the clock restarts.
    t_sess, t_rest = time_on_task(frame)
    np.testing.assert_allclose(t_sess[:4], [0.0, 1.0, 2.0, 215 / 60])
    np.testing.assert_allclose(t_rest[:4], 0.0)
    assert t_sess[4] == pytest.approx(215 / 60) and t_rest[4] == 0.0
    assert t_sess[5] == pytest.approx(215 / 60 + 1.0)
    # B starts its own session at its first onset.
    np.testing.assert_allclose(t_sess[6:], [0.0, 1.0])
    short = frame.assign(onset_s=[0.0, 6.0, 12.0, 18.0, 24.0, 30.0, 0.0, 6.0])
    t_sess, t_rest = time_on_task(short)
    np.testing.assert_allclose(t_rest[:6], t_sess[:6])  # no pause: no rest
    assert t_sess[5] == pytest.approx(0.5)


def test_time_on_task_without_onsets_is_zero_and_claims_nothing():
    frame = pd.DataFrame({"participant": ["A", "A"], "session": [1, 1],
                          "onset_s": [np.nan, np.nan], "rt_s": [1.0, 1.0]})
    t_sess, t_rest = time_on_task(frame)
    assert not t_sess.any() and not t_rest.any()


def _fits(real: pd.DataFrame, pilot: pd.DataFrame):
    data = observer_frame(real, DESIGN, fitted_simulation(pilot))
    data.attrs = dict(data.attrs)
    return [(data, data, [], None)]


def test_a_participant_who_swaps_the_sliders_departs_from_the_others():
    """One participant of 20 sets gloss on the depth slider and back on 35 % of their trials:
    named first, their scatter well above the others' (seeds 1-8: 2.2-2.6x, Holm p 1e-7 to
    1e-28). Measured over seeds 1-10 at 3, 4, 6, 11 and 20 participants: the swapper named in
    50/50 (35 % swapped) and 48/50 (15 %), no one else named in any."""
    pilot, real = population(3, 20, "swap", 0.35)
    dep = participant_departures(_fits(real, pilot), TOL)
    assert dep["tested"] and dep["significant"], dep
    assert dep["departing"][0]["participant"] == "R00"
    assert dep["departing"][0]["scatter_ratio"] > 2.0 and dep["departing"][0]["p_holm"] < 1e-6
    assert dep["size"] >= TOL and "R00" in dep["where"]


def test_one_swap_in_ten_trials_is_named_by_the_correlation_of_the_two_errors():
    """One participant of 20 swaps the sliders on 9 % of their trials (issue 43's slider swap
    at 1x tolerance on the unseen blind seeds, read "no gap that matters" there): their
    scatter is about as ordinary as the noisiest others', but their gloss and depth errors
    move against each other. Named (measured on seeds 1-10 at 3-20 participants: named in
    49/50), and the verdict cannot then be "no gap that matters" (here the size read for the
    departure, 0.24 slider units at most, is below the tolerance: part of a swap passes for
    the participant's own slopes)."""
    pilot, real = population(2, 20, "swap", 0.09)
    dep = participant_departures(_fits(real, pilot), TOL)
    assert [d["participant"] for d in dep["departing"]] == ["R00"], dep["departing"]
    first = dep["departing"][0]
    assert first["error_correlation"] < first["others_error_correlation"] - 0.2
    d = with_departures(_diag("no_gap_that_matters"), dep)
    assert d.verdict == "inconclusive" and "R00" in summarise(d)


def test_ordinary_differences_in_noise_between_participants_are_no_departure():
    """Noise SDs of 0.6-1.0 (gloss) and 0.5-0.8 (depth) slider units between people: no one
    flagged, and the bound excludes a departure of the tolerance (seeds 1-3, 4 and 20
    participants; measured over seeds 1-10 at 3-20 participants: no one a gap in 50/50, a
    participant named without a gap in 2/50, the bound below the tolerance in 48/50)."""
    for seed, n in ((1, 20), (2, 20), (3, 4)):
        pilot, real = population(seed, n)
        dep = participant_departures(_fits(real, pilot), TOL)
        assert dep["tested"] and not dep["departing"] and not dep["significant"], (seed, dep)
        assert dep["size_upper"] < TOL, (seed, dep)


def test_too_few_participants_to_judge_one_against_the_others_is_said_not_tested():
    pilot, real = population(1, MIN_PARTICIPANTS - 1)  # 2: which of them departs?
    dep = participant_departures(_fits(real, pilot), TOL)
    assert not dep["tested"] and "not tested" in dep["reason"]


def _diag(verdict: str) -> Diagnosis:
    rem = {"gap": 0.0, "ci": (-0.01, 0.01), "p": 0.5, "significant": False, "where": "",
           "size": 0.05, "size_upper": 0.08, "tolerance": TOL, "size_unit": "slider units",
           "size_source": "the design's [gap] observer_tolerance_slider",
           "within_tolerance": False, "loss_ceiling": 1.0}
    return Diagnosis(layer="observer", ranking=(), steps=(), verdict=verdict, gap_before=0.0,
                     gap_after=0.0, shrink_abs=0.0, shrink_abs_ci=(0, 0), shrink_pct=0.0,
                     shrink_pct_ci=(0, 0), seed=0, remaining=rem, misfit_upper=0.08,
                     tolerance=TOL, misfit_unit="slider units", gap_before_ci=(-0.01, 0.01))


def test_a_departing_participant_turns_no_gap_into_a_gap_and_untested_ones_into_inconclusive():
    flagged = {"tested": True, "significant": True, "size": 0.5, "size_upper": 0.6,
               "tolerance": TOL, "where": "in single participants: R00 (2.6x) scatter ..."}
    d = with_departures(_diag("no_gap_that_matters"), flagged)
    assert d.verdict == "unexplained" and d.unexplained_remains
    words = summarise(d)
    assert words.startswith("A gap, unexplained by the catalogue, in single participants: R00")
    assert "is excluded" in words  # what the population's settings do exclude is still said
    untested = {"tested": False, "significant": False, "size": float("nan"),
                "size_upper": float("nan"), "tolerance": TOL,
                "reason": "with 3 participant(s) ... it is not tested"}
    d = with_departures(_diag("no_gap_that_matters"), untested)
    assert d.verdict == "inconclusive"
    assert "is excluded for the population" in summarise(d) and "not tested" in summarise(d)
    wide = dict(untested, tested=True, size=0.1, size_upper=0.3, reason=None)
    assert with_departures(_diag("no_gap_that_matters"), wide).verdict == "inconclusive"
    narrow = dict(wide, size_upper=0.2)
    d = with_departures(_diag("no_gap_that_matters"), narrow)
    assert d.verdict == "no_gap_that_matters" and summarise(d).startswith("No gap that matters")
    named = dict(narrow, departing=[{"participant": "R00"}], where="in single participants: R00")
    d = with_departures(_diag("no_gap_that_matters"), named)
    assert d.verdict == "inconclusive" and "own slopes" in summarise(d)
    assert with_departures(_diag("lapses"), flagged).verdict == "lapses"  # a gap stays one


@pytest.mark.slow
def test_a_bias_growing_with_time_on_task_is_a_gap_named_by_the_time():
    """Both sliders creep up by 0.15 slider units a minute since the session's start (11
    participants): before, "no gap that matters" (the misfit by stimulus saw noise); now a gap,
    rising with the time on task."""
    pilot, real = population(1, 11, "drift", 0.15)
    d = diagnose("observer", real, pilot, DESIGN, seed=1, n_boot=200)[0]
    assert d.verdict == "unexplained", d.summary
    assert "rising with the time since the session's start" in d.remaining["where"]
    assert d.misfit_after > TOL


@pytest.mark.slow
def test_a_participant_who_swaps_the_sliders_is_a_gap_that_names_them():
    pilot, real = population(3, 20, "swap", 0.35)
    d = diagnose("observer", real, pilot, DESIGN, seed=3, n_boot=200)[0]
    assert d.verdict not in ("no_gap_that_matters", "inconclusive"), d.summary
    assert d.departures["significant"] and "R00" in d.summary


@pytest.mark.slow
def test_a_drift_just_above_the_tolerance_within_a_person_is_not_excluded():
    """Both sliders creep up by 0.095 slider units a minute since the session's start (each
    participant a share U(0.5, 1.5)), 20 participants: 0.27 slider units RMS within a person,
    1.06x the tolerance. The flexible model's time term is shrunk and estimated, so the
    misfit reads 0.24; the bound resampled only held-out participants (0.245: "no gap that
    matters", seeds 1-3 alike). With the ceiling's own estimation error (its corrections
    refitted on resampled training participants) the bound reaches above the tolerance."""
    pilot, real = population(2, 20, "drift", 0.095)
    d = diagnose("observer", real, pilot, DESIGN, seed=2, n_boot=200)[0]
    assert d.verdict != "no_gap_that_matters", d.summary
    assert d.remaining["size_upper"] > TOL > d.remaining["size"]
