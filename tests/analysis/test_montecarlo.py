"""analysis.montecarlo: rates counted from simulated decisions, exact intervals, reproducible
seeds, and the smallest size that reaches a target rate."""

import numpy as np
import pytest

from analysis.montecarlo import (
    Rate,
    decision_rate,
    decision_rates,
    one_at_a_time,
    rate_curve,
    rates_curve,
    size_search,
    smallest_size,
)


def coin(p):
    return lambda rng, k: rng.random(k) < p


def test_a_known_rate_lies_inside_its_interval():
    r = decision_rate(coin(0.3), 2000, seed=1)
    lo, hi = r.ci
    assert lo < 0.3 < hi
    assert r.rate == pytest.approx(0.3, abs=4 * r.mc_se)


def test_the_same_seed_gives_the_same_count_and_another_seed_another():
    a = decision_rate(coin(0.5), 500, seed=7)
    b = decision_rate(coin(0.5), 500, seed=7)
    c = decision_rate(coin(0.5), 500, seed=8)
    assert a == b
    assert a != c


def test_a_one_draw_function_counts_like_a_batch():
    r = decision_rate(one_at_a_time(lambda rng: rng.random() < 0.9), 300, seed=2)
    assert r.n == 300 and 0.8 < r.rate < 0.97


def test_the_smallest_size_is_where_the_rate_first_reaches_the_target():
    # power rises with n as 1 - exp(-n / 5): 0.8 is first reached at n = 9 (0.835; n = 8: 0.798)
    found = smallest_size(lambda n: coin(1 - np.exp(-n / 5)), [2, 4, 6, 9, 12, 20, 40], 4000,
                          seed=3, target=0.8)
    assert found.size == 9
    lo, hi = found.size_range
    assert lo <= 9 <= (hi if hi is not None else 40)
    # the walk stopped once a size was decided beyond doubt
    assert found.curve[-1][0] < 40


def test_a_target_no_size_reaches_is_none():
    found = smallest_size(lambda n: coin(0.1), [1, 2, 3], 200, seed=0)
    assert found.size is None and found.size_range[1] is None


@pytest.mark.parametrize("kwargs, match", [
    ({"n_sim": 0}, "at least 1"),
    ({"sizes": [3, 2]}, "not increasing"),
    ({"sizes": []}, "no sizes"),
    ({"target": 1.5}, "between 0 and 1"),
])
def test_bad_searches_are_refused_naming_the_fix(kwargs, match):
    args = {"n_sim": 10, "sizes": [1, 2], "target": 0.8} | kwargs
    with pytest.raises(ValueError, match=match):
        smallest_size(lambda n: coin(0.5), args["sizes"], args["n_sim"], seed=0,
                      target=args["target"])


def test_a_draw_function_returning_the_wrong_count_is_refused():
    with pytest.raises(ValueError, match="must return 5"):
        decision_rate(lambda rng, k: np.ones(k + 1, bool), 5, seed=0, chunk=5)


def test_a_curve_keeps_its_points_apart():
    curve = rate_curve(lambda s: coin(s), [0.2, 0.8], 400, seed=4)
    assert [s for s, _ in curve] == [0.2, 0.8]
    assert curve[0][1].rate < curve[1][1].rate
    assert isinstance(curve[0][1], Rate)


def test_several_decisions_per_draw_are_counted_per_column_from_the_same_draws():
    def two(rng, k):
        u = rng.random(k)
        return np.column_stack([u < 0.2, u < 0.6])

    rates = decision_rates(two, 1000, columns=2, seed=5)
    assert rates[0].hits <= rates[1].hits  # same draws: u < 0.2 implies u < 0.6
    assert rates[0].rate == pytest.approx(0.2, abs=4 * rates[0].mc_se)
    assert rates[1].rate == pytest.approx(0.6, abs=4 * rates[1].mc_se)
    curve = rates_curve(lambda s: two, ["a", "b"], 50, columns=2, seed=5)
    assert [s for s, _ in curve] == ["a", "b"] and len(curve[0][1]) == 2


def test_a_curve_already_simulated_gives_the_same_search_as_walking_it():
    sizes = [2, 4, 6, 9, 12]
    walked = smallest_size(lambda n: coin(1 - np.exp(-n / 5)), sizes, 500, seed=3,
                           stop_early=False)
    assert size_search(walked.curve, 0.8) == walked
