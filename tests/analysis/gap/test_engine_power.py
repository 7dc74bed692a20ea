"""The engine's detectable / to_decide (analysis.gap.engine.power) on a model whose answer is
known in closed form: a misfit read as the mean of n normal draws (SD 1), its bounds the mean
-/+ 1.645 SE. The simulation must land on the grid point the closed form predicts."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap.engine import (
    OUTCOME_GAP,
    OUTCOME_INCONCLUSIVE,
    OUTCOME_NONE,
    GapError,
    PowerModel,
    decide_size,
    power_analysis,
)

N, TOL = 4, 1.0  # SE of the mean at the data's size: 0.5


def _model(now=0.5):
    def draws(misfit, factor):
        se = 1 / np.sqrt(N * factor)

        def run(rng, k):
            mean = misfit + se * rng.standard_normal(k)
            return decide_size(np.maximum(mean, 0), mean - 1.645 * se, mean + 1.645 * se, TOL)
        return run
    return PowerModel(draws=draws, misfit_now=now, misfits=(1.0, 1.25, 1.5, 2.0, 3.0),
                      factors=(2, 4, 8, 16), unit="units",
                      more=lambda f: f"{f * N:g} draws", n_sim=100)


def test_decide_size_is_the_diagnosis_rule():
    out = decide_size([1.2, 0.3, 0.3, 1.2], [0.1, 0.0, 0.0, -0.1], [1.5, 0.9, 1.1, 1.6], 1.0)
    assert list(out) == [OUTCOME_GAP, OUTCOME_NONE, OUTCOME_INCONCLUSIVE,
                         OUTCOME_INCONCLUSIVE]


def test_detectable_and_to_decide_land_where_the_closed_form_says():
    # detectable: P(mean >= 1) >= 0.8 at mu = 1 + 0.84 * 0.5 = 1.42 -> grid point 1.5.
    # to_decide from a truth of 0.5: P(upper < 1) is 0.64 at f = 4, 0.88 at f = 8 -> 8.
    out = power_analysis(_model(), seed=3)
    assert out["detectable"]["value"] == 1.5
    assert out["to_decide"]["factor"] == 8
    assert out["to_decide"]["words"] == "32 draws"
    assert out["detectable"]["unit"] == "units" and out["detectable"]["power"] == 0.8
    # Reproducible from its seed.
    assert power_analysis(_model(), seed=3) == out


def test_a_truth_at_the_tolerance_is_never_decided_and_says_so():
    out = power_analysis(_model(now=1.0), seed=1)
    assert out["to_decide"]["factor"] is None
    assert out["to_decide"]["words"].startswith("more than 64 draws")


def test_a_power_model_without_draws_is_refused():
    with pytest.raises(GapError, match="draws and more"):
        PowerModel(draws=None, misfit_now=0.0, misfits=(1.0,), factors=(2,), unit="",
                   more=str)
