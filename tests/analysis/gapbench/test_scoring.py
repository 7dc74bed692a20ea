"""The benchmarks' shared scores (analysis.gapbench.scoring)."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from analysis.gapbench.scoring import per_case, rate, score_line, seed_agreement, shrink_errors

RECORDS = [
    {"case": "a", "ok": True, "seed_verdicts": ["x", "x", "x"], "pred_shrink": 1.1,
     "true_shrink": 1.0},
    {"case": "a", "ok": False, "seed_verdicts": ["x", "y", "x"], "pred_shrink": 0.5,
     "true_shrink": 1.0},
    {"case": "b", "ok": True, "seed_verdicts": ["z", "z", "z"], "pred_shrink": 2.0,
     "true_shrink": 0.0},
]


def test_rate_selects_by_case_names_or_by_predicate_alike():
    assert rate(RECORDS, ("a",), lambda r: r["ok"]) == (0.5, 2)
    assert rate(RECORDS, lambda r: r["case"] == "a", lambda r: r["ok"]) == (0.5, 2)
    value, n = rate(RECORDS, ("c",), lambda r: r["ok"])
    assert n == 0 and math.isnan(value)


def test_seed_agreement_counts_each_seed_against_the_first():
    assert seed_agreement(RECORDS) == (1 + 2 / 3 + 1) / 3


def test_shrink_errors_only_of_right_cases_with_a_true_shrinkage():
    assert shrink_errors(RECORDS, ("a", "b"), lambda r: r["ok"]) == [abs(1.1 - 1.0)]


def test_per_case_and_score_line_say_what_was_measured():
    assert per_case(RECORDS, lambda r: r["ok"]) == {"a": [1, 2], "b": [1, 1]}
    assert score_line("x", "top-1", 0.9, 10, ">= 0.95", False) == \
        "x: top-1 0.900 (n=10; target >= 0.95) NOT met"
    assert score_line("x", "top-1", float("nan"), 0, ">= 0.95", False).endswith("n/a (no runs)")


def test_balanced_draw_gives_every_name_as_often_as_the_others_up_to_one():
    from analysis.gapbench.scoring import balanced_draw

    for n in (0, 3, 7, 11):
        counts = Counter(balanced_draw(np.random.default_rng(n), ("a", "b", "c", "d"), n))
        assert sum(counts.values()) == n
        assert not counts or max(counts.values()) - min(counts.values()) <= 1
        assert n < 4 or set(counts) == {"a", "b", "c", "d"}
