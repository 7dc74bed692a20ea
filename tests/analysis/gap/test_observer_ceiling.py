"""The observer layer's ceiling: a flexible extension of the chosen model that costs next to
nothing where that model is right, and the test of what remains on effects outside the
catalogue that an independently fitted ceiling missed."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap import diagnose
from analysis.gap.engine import candidate
from analysis.gap.observer import (
    base_from_params,
    ceiling_loss,
    fit_ceiling,
    observer_folds,
    observer_frame,
    observer_loss,
)
from analysis.gap.observer.ceiling import _ceiling_pred
from analysis.gap.observer.offsets import _cell_offsets
from analysis.gapbench.bench_observer import HarderCase, generate_sessions
from experiment import load_observer_params
from studydesign import load_design

DESIGN = load_design()


def _ideal():
    return base_from_params(load_observer_params()["ideal"], "ideal", DESIGN.slider)


def _diagnose_case(added: dict, seed: int, n_participants: int = 4):
    case = HarderCase("out", base=True, added=added)
    frame, _ = generate_sessions(DESIGN, case, n_participants, np.random.default_rng(seed))
    return diagnose("observer", frame, _ideal(), DESIGN, seed=seed, n_boot=500)[0]


def test_cell_offsets_are_shrunk_by_the_reliability_of_a_cell_mean():
    """81 cells with true offsets N(0, 0.5^2), 4 participants with 2 trials each per cell,
    trial noise SD 0.9: a cell mean over 8 trials has noise variance 0.81 / 8, so the
    empirical-Bayes factor is 0.25 / (0.25 + 0.81 / 8) = 0.71 (one-way random effects)."""
    rng = np.random.default_rng(4)
    cells = np.repeat(np.arange(81), 8)
    who = np.tile(np.repeat(np.arange(4), 2), 81).astype(str)
    truth = rng.normal(0.0, 0.5, 81)
    res = truth[cells] + rng.normal(0.0, 0.9, cells.size)
    off = _cell_offsets(res, cells.astype(str), who)
    means = np.array([res[cells == c].mean() for c in range(81)])
    factor = np.array([off[str(c)] for c in range(81)]) / means
    assert np.ptp(factor) < 1e-9  # one factor for cells of equal size
    assert factor[0] == pytest.approx(0.25 / (0.25 + 0.81 / 8), abs=0.08)


def test_lapses_in_the_same_cell_do_not_make_cells_differ():
    """One response per participant and cell (as in the harder benchmark's cells): where both
    participants lapsed in the same six cells (residual 4.5, chance of being no lapse 0.02),
    the lapse weights keep those products out of the between-cell variance. Weighting only
    within a participant's cell mean (one response: no weighting at all) gave those cells
    offsets of up to 2.9 slider units."""
    rng = np.random.default_rng(0)
    cells = np.tile(np.arange(162), 2)
    who = np.repeat(["A", "B"], 162)
    res = rng.normal(0.0, 0.9, cells.size)
    weights = np.ones(cells.size)
    lapsed = cells < 6
    res[lapsed], weights[lapsed] = 4.5, 0.02
    off = _cell_offsets(res, cells.astype(str), who, weights)
    assert max((abs(v) for v in off.values()), default=0.0) < 0.1


def test_ceiling_over_a_right_model_costs_next_to_nothing_on_held_out_observers():
    """Human-like observers with the catalogue's central tendency and crosstalk only: the
    ceiling built on those fitted effects loses less than 0.015 nats per held-out trial
    against them (an independently fitted flexible model lost 0.02 to 0.06 on such data; a
    remaining gap must be at least 0.02 to count)."""
    case = HarderCase("base", base=True)
    frame, _ = generate_sessions(DESIGN, case, 4, np.random.default_rng(6))
    data = observer_frame(frame, DESIGN, _ideal())
    folds, _ = observer_folds(data)
    excess = []
    for tr, te in folds:
        chosen = []
        for name in ("central_tendency", "crosstalk"):
            chosen.append((name, candidate("observer", name).fit(tr, chosen)))
        own = observer_loss(tr)(te, chosen)
        excess.append(ceiling_loss(fit_ceiling(tr, fitted=chosen), te).mean() - own.mean())
    assert np.mean(excess) < 0.015


def test_noise_growing_with_depth_is_a_remaining_gap_in_the_spread_of_depth():
    """Found by the ceiling (significant, in the depth response's spread); its size, about
    0.13 slider units (the noise SD from 0.6 to 1.4 times 0.7 slider units over the depths,
    the means right), is under the design's tolerance of 0.25 slider units: reported with
    its size and place, not counted (issue 38; before the tolerance it was counted)."""
    diag = _diagnose_case({"depth_noise": 0.6}, seed=1)
    assert {s["added"] for s in diag.steps} == {"central_tendency", "crosstalk"}
    rem = diag.remaining
    assert rem["p"] < 0.05 and rem["gap"] >= diag.min_gain
    assert rem["where"] == "in the spread of the depth response, rising with depth"
    assert rem["within_tolerance"] and rem["size"] == pytest.approx(0.13, abs=0.05)
    assert not diag.unexplained_remains
    assert diag.misfit_by_response["depth"]["after_slider"] > 3 * (
        diag.misfit_by_response["gloss"]["after_slider"])


def test_lapses_alone_leave_no_remaining_gap():
    """Lapses (mean at the slider's middle) must not pass for extra central tendency in the
    catalogue's fits, which the ceiling would then correct and flag."""
    case = HarderCase("catalogue", base=True, added={"lapses": 0.15})
    frame, _ = generate_sessions(DESIGN, case, 4, np.random.default_rng(16))
    diag = diagnose("observer", frame, _ideal(), DESIGN, seed=16, n_boot=500)[0]
    assert {s["added"] for s in diag.steps} == {"lapses", "central_tendency", "crosstalk"}
    central = next(s for s in diag.steps if s["added"] == "central_tendency")["params"]
    assert central["gloss"] == pytest.approx(0.10, abs=0.04)
    assert central["depth"] == pytest.approx(0.30, abs=0.04)
    assert not diag.unexplained_remains


def test_a_stimulus_bias_beside_lapses_is_a_remaining_gap():
    """Lapses chosen from the catalogue must not hide a per-stimulus gloss bias: the ceiling
    is built on the chosen lapse model (a ceiling fitted apart, its noise SD widened by the
    lapses, lay 0.18 nats per trial *below* the chosen model on such a case of the harder
    benchmark, seed 1). Missed before the cell offsets were kept on held-out error alone and
    the ceiling's noise fitted to what offsets fitted elsewhere leave: remaining gap 0.008
    nats per trial (p 0.19), then 0.030; 0.062 since lapse weights reach the
    cross-participant products and each level is kept on its own."""
    case = HarderCase("both", base=True, added={"lapses": 0.15, "stimulus_bias": 0.5})
    frame, _ = generate_sessions(DESIGN, case, 4, np.random.default_rng(3))
    diag = diagnose("observer", frame, _ideal(), DESIGN, seed=3, n_boot=500)[0]
    assert "lapses" in {s["added"] for s in diag.steps}
    assert diag.unexplained_remains
    assert "gloss response" in diag.remaining["where"]


def test_a_stimulus_bias_beside_lapses_is_flagged_where_cell_offsets_are_noise():
    """Stimulus offsets are kept on their own held-out error: decided together with the
    cell (x illumination) offsets, whose between-cell variance lapses in two participants'
    same cells made positive by chance, they were dropped in two of four folds although
    they lowered every inner fold's error (remaining gap 0.015 nats per trial, below the
    0.02 a remaining gap needs; now 0.039)."""
    case = HarderCase("both", base=True, added={"lapses": 0.15, "stimulus_bias": 0.5})
    frame, _ = generate_sessions(DESIGN, case, 4, np.random.default_rng(11))
    diag = diagnose("observer", frame, _ideal(), DESIGN, seed=11, n_boot=500)[0]
    assert "lapses" in {s["added"] for s in diag.steps}
    assert diag.unexplained_remains
    assert diag.remaining["gap"] > 0.03


def test_noise_growing_with_depth_beside_label_rounding_is_a_remaining_gap():
    """Label rounding leaves less of each response to tell the noise's spread by; with the
    ceiling's noise fitted to what offsets fitted to the same responses leave, a depth-
    dependent noise beside it came out at 0.015 nats per trial, below the 0.02 a remaining
    gap needs (harder benchmark draw, seed 200); fitted to what offsets fitted without each
    response leave, 0.026. Its size, about 0.12 slider units, is under the design's
    tolerance (0.25): found and placed, not counted (issue 38)."""
    diag = _diagnose_case({"label_rounding": 0.4, "depth_noise": 0.6}, seed=200)
    assert "label_rounding" in {s["added"] for s in diag.steps}
    rem = diag.remaining
    assert rem["p"] < 0.05 and rem["gap"] >= diag.min_gain
    assert rem["where"].startswith("in the spread of the depth response")
    assert rem["within_tolerance"] and rem["size"] < 0.25 and not diag.unexplained_remains


def test_ceiling_noise_is_that_of_responses_its_offsets_were_not_fitted_to():
    """With a per-stimulus bias the ceiling's offsets are fitted to the training responses;
    its noise SD, fitted to what those offsets leave of the same responses, came out narrower
    than on held-out participants (mean squared standardised held-out residual 1.15 on this
    case), which cost the ceiling on every held-out participant and hid the bias. Fitted to
    what the offsets of the inner folds a response was held out of leave, it is about 0.91
    (a little wide: those offsets come from one participant fewer)."""
    case = HarderCase("out", base=True, added={"stimulus_bias": 0.5})
    frame, _ = generate_sessions(DESIGN, case, 4, np.random.default_rng(301))
    data = observer_frame(frame, DESIGN, _ideal())
    z2 = []
    for tr, te in observer_folds(data)[0]:
        chosen = []
        for name in ("central_tendency", "crosstalk"):
            chosen.append((name, candidate("observer", name).fit(tr, chosen)))
        pred, sd = _ceiling_pred(fit_ceiling(tr, fitted=chosen), te)
        x = te["gloss_match"].to_numpy(float)
        inside = (x > 1.0) & (x < 11.0)
        z2.append(((x - pred["mu"]["gloss"]) / sd["gloss"])[inside] ** 2)
    assert 0.85 < np.mean(np.concatenate(z2)) < 1.07
