"""The layer-independent engine on losses with known gains: greedy steps and the minimum gain."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap.benchmark import draw_schedule
from analysis.gap.engine import Candidate, diagnose_losses

N_UNITS = 2000


def _problem(gains: dict, seed: int = 0):
    """Candidates whose extension lowers every held-out unit's loss by ``gains[name]`` (plus
    unit-level scatter of 0.01 nats), independently of each other."""
    rng = np.random.default_rng(seed)
    base = rng.normal(1.0, 0.1, N_UNITS)
    drop = {n: g + rng.normal(0.0, 0.01, N_UNITS) for n, g in gains.items()}

    def loss(_data, fitted):
        return base - sum((drop[n] for n, _ in fitted), np.zeros(N_UNITS))
    cands = [Candidate(n, lambda _train, _chosen: {}) for n in gains]
    return cands, loss


def _diagnose(gains, **kw):
    cands, loss = _problem(gains)
    return diagnose_losses("test", cands, None, None, loss, lambda _d: np.zeros(N_UNITS),
                           rng=np.random.default_rng(1), seed=1, n_boot=400, **kw)


def test_greedy_combination_adds_every_effect_that_helps():
    """Five co-occurring effects are all reported (the combination was once capped at 3)."""
    gains = {f"e{k}": 0.1 * (k + 1) for k in range(5)}
    diag = _diagnose(gains)
    assert [s["added"] for s in diag.steps] == ["e4", "e3", "e2", "e1", "e0"]
    assert diag.shrink_abs == pytest.approx(sum(gains.values()), rel=0.01)


def test_a_significant_but_negligible_gain_is_not_attributed_under_a_minimum_gain():
    gains = {"tiny": 0.005, "none": 0.0}
    assert _diagnose(gains).verdict == "tiny"  # significant with 2000 units
    diag = _diagnose(gains, min_gain=0.02)
    assert diag.verdict == "unexplained" and not diag.steps
    assert not any(s["significant"] for s in diag.ranking)


def test_benchmark_schedule_scores_every_effect_equally_often():
    effects, out = ("a", "b", "c", "d", "e", "f"), ("x", "y")
    runs = draw_schedule(np.random.default_rng(3), 40, effects, out)
    kinds = [k for _, k in runs]
    assert (kinds.count("none"), kinds.count("out"), kinds.count("in")) == (10, 10, 20)
    counts = {e: sum(r == (e, "in") for r in runs) for e in effects}
    assert set(counts.values()) <= {3, 4} and sum(counts.values()) == 20
    assert all(sum(r == (e, "out") for r in runs) == 5 for e in out)
