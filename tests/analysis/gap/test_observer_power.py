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
    model = misfit_power(t, u, TOL, by_participant=True, n_sessions=2)
    rng = np.random.default_rng(0)
    assert (model.draws(0.02, 1.0)(rng, 40) == OUTCOME_NONE).mean() >= 0.9
    assert (model.draws(4 * TOL, 1.0)(rng, 40) == OUTCOME_GAP).mean() >= 0.9


def test_to_decide_is_decided_in_about_80_percent_of_draws_at_the_size_it_names():
    """An inconclusive misfit (0.2 against 0.25, 6 participants): the factor to_decide names
    decides about 80 % (>= 70 %) of 400 fresh draws at that size (80 % targeted with 100 draws a
    point),
    and the next smaller factor tried decides fewer."""
    t, u = _terms(3, 0.2)
    model = misfit_power(t, u, TOL, by_participant=True, n_sessions=2)
    out = power_analysis(model, seed=5)["to_decide"]
    assert out["factor"] is not None and "participants" in out["words"]
    rng = np.random.default_rng(11)
    decided = (model.draws(model.misfit_now, out["factor"])(rng, 400) != 2).mean()
    assert decided >= 0.7
    smaller = [f for f in model.factors if f < out["factor"]]
    if smaller:
        assert (model.draws(model.misfit_now, smaller[-1])(rng, 400) != 2).mean() < decided


def test_a_ceiling_whose_error_does_not_shrink_with_more_data_asks_for_more_data():
    """The flexible model's penalty falls with more data, so its error need not shrink as
    one over the data's size (nothing added at 6 participants: the SD of the squared misfit
    over its draws 0.008 slider units^2, at 12 participants 0.017-0.029): with the error the
    ceiling's draws at the larger data set's penalty give (``ceiling_at``), to_decide names
    more data than with today's error shrunk as one over the size."""
    t, u = _terms(3, 0.2)
    rng = np.random.default_rng(4)
    today = 0.008 * rng.standard_normal(200)

    def at_larger(factor):  # draws on today's data: var / factor is then today's var
        return np.sqrt(factor) * today

    shrunk = misfit_power(t, u, TOL, by_participant=True, n_sessions=2, ceiling=today)
    kept = misfit_power(t, u, TOL, by_participant=True, n_sessions=2, ceiling=today,
                        ceiling_at=at_larger)
    f_shrunk = power_analysis(shrunk, seed=5)["to_decide"]["factor"]
    f_kept = power_analysis(kept, seed=5)["to_decide"]["factor"]
    assert f_shrunk is not None
    assert f_kept is None or f_kept > f_shrunk, (f_shrunk, f_kept)


def test_coefficient_draws_for_a_larger_data_set_are_not_shrunk_by_todays_penalty():
    """Draws for a larger data set are refitted with no penalty to speak of (cross-validation
    chooses a smaller one as data grow): where today's choice was heavy, their spread on
    today's data is wider than today's draws'; a factor below 1 is refused."""
    import pytest

    from analysis.gap.observer.coefdraws import CoefficientDraws

    rng = np.random.default_rng(0)
    n = 600
    mx = np.c_[np.ones(n), rng.standard_normal((n, 3))]
    tx = rng.standard_normal((n, 2))
    y = mx @ np.array([0.0, 0.1, -0.05, 0.02]) + 0.5 * rng.standard_normal(n)
    who = np.repeat([f"P{j}" for j in range(6)], n // 6)
    draws = CoefficientDraws(mx, tx, y, np.ones(n), who, (1000.0, 1000.0))
    b1, _ = draws.at(1.0)
    b2, _ = draws.at(2.0)
    assert b2[:, 1:].std(axis=0).min() > 3 * b1[:, 1:].std(axis=0).max()
    with pytest.raises(ValueError, match="factor 0.5 < 1"):
        draws.at(0.5)
