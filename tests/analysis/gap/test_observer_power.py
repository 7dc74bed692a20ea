"""The observer layer's bound and power (issue 43): the misfit's upper 95 % bound from
resampled participants, and the PowerModel of an inconclusive verdict, checked by drawing
from it at the data sizes it suggests."""

from __future__ import annotations

import numpy as np

from analysis.gap.engine import OUTCOME_GAP, OUTCOME_NONE
from analysis.gap.engine.power import power_analysis
from analysis.gap.observer.power import misfit_power, misfit_upper

TOL = 0.25


def _terms(seed: int, misfit: float, n_units: int = 6, per_unit: int = 160, spread=0.5):
    """Per-trial squared distances whose units (participants) differ: unit j's mean squared
    distance is misfit^2 times a log-normal factor of SD ``spread``."""
    rng = np.random.default_rng(seed)
    scale = np.exp(spread * rng.standard_normal(n_units))
    scale /= scale.mean()
    terms = np.concatenate([misfit ** 2 * s * rng.exponential(1.0, per_unit) for s in scale])
    return terms, np.repeat([f"P{j}" for j in range(n_units)], per_unit)


def test_upper_bound_lies_above_the_misfit_and_widens_with_fewer_participants():
    t6, u6 = _terms(1, 0.2, n_units=6)
    t20, u20 = _terms(1, 0.2, n_units=20)
    for t, u in ((t6, u6), (t20, u20)):
        assert misfit_upper(t, u) > np.sqrt(t.mean())
    assert (misfit_upper(t6, u6) / np.sqrt(t6.mean())
            > misfit_upper(t20, u20) / np.sqrt(t20.mean()))


def test_power_model_decides_a_clear_gap_and_a_clear_none():
    t, u = _terms(2, 0.2)
    model = misfit_power(t, u, TOL)
    rng = np.random.default_rng(0)
    assert (model.draws(0.02, 1.0)(rng, 40) == OUTCOME_NONE).mean() >= 0.9
    assert (model.draws(4 * TOL, 1.0)(rng, 40) == OUTCOME_GAP).mean() >= 0.9


def test_to_decide_is_decided_in_about_80_percent_of_draws_at_the_size_it_names():
    """An inconclusive misfit (0.2 against 0.25, 6 participants): the factor to_decide names
    decides about 80 % (>= 70 %) of 400 fresh draws at that size (80 % targeted with 100 draws a
    point),
    and the next smaller factor tried decides fewer."""
    t, u = _terms(3, 0.2)
    model = misfit_power(t, u, TOL)
    out = power_analysis(model, seed=5)["to_decide"]
    assert out["factor"] is not None and "participants" in out["words"]
    rng = np.random.default_rng(11)
    decided = (model.draws(model.misfit_now, out["factor"])(rng, 400) != 2).mean()
    assert decided >= 0.7
    smaller = [f for f in model.factors if f < out["factor"]]
    if smaller:
        assert (model.draws(model.misfit_now, smaller[-1])(rng, 400) != 2).mean() < decided
