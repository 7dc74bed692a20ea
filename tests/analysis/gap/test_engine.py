"""The layer-independent engine on losses with known gains: greedy steps and the minimum gain."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap.engine import Candidate, DiagnosisSettings, LayerFunctions, diagnose_losses

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
    return diagnose_losses("test", cands, LayerFunctions(loss, lambda _d: np.zeros(N_UNITS)),
                           DiagnosisSettings(n_boot=400, **kw), rng=np.random.default_rng(1),
                           seed=1)


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


def test_greedy_re_tests_candidates_that_were_not_significant_at_first():
    """'b' helps only once 'a' is in the model (it was never retried before)."""
    rng = np.random.default_rng(0)
    base = rng.normal(1.0, 0.1, N_UNITS)

    def loss(_data, fitted):
        names = [n for n, _ in fitted]
        out = base - (0.2 if "a" in names else 0.0) + rng.normal(0, 1e-6, N_UNITS) * 0
        if "b" in names:
            out = out - (0.1 if "a" in names else -0.05)
        return out
    cands = [Candidate(n, lambda _train, _chosen: {}) for n in ("a", "b")]
    diag = diagnose_losses("test", cands, LayerFunctions(loss, lambda _d: np.zeros(N_UNITS)),
                           DiagnosisSettings(n_boot=400), rng=np.random.default_rng(1), seed=1)
    assert not next(s for s in diag.ranking if s["name"] == "b")["significant"]
    assert [s["added"] for s in diag.steps] == ["a", "b"]


def _with_ceiling(ceiling_drop: float, floor_shift: float = 0.0, **kw):
    cands, loss = _problem({"a": 0.3})
    functions = LayerFunctions(loss, lambda _d: np.full(N_UNITS, floor_shift),
                               ceiling=lambda _tr, _te: loss(None, []) - ceiling_drop,
                               where=lambda fits: "in the depth response, rising with gloss")
    return diagnose_losses("test", cands, functions,
                           DiagnosisSettings(n_boot=400, min_gain=0.02, **kw),
                           rng=np.random.default_rng(1), seed=1)


def test_a_gap_beyond_the_catalogue_is_reported_with_where_it_lies():
    diag = _with_ceiling(0.5)  # a flexible model removes 0.5 nats, the catalogue 0.3
    assert diag.verdict == "a" and diag.unexplained_remains
    assert diag.remaining["gap"] == pytest.approx(0.2, abs=0.01)
    assert diag.explained_share == pytest.approx(0.6, abs=0.02)
    assert ("a explains 60 % of the gap a flexible model of the data removes; a further gap "
            "remains, unexplained by the catalogue, in the depth response, rising with gloss"
            in diag.summary)


def test_a_catalogue_that_beats_the_ceiling_explains_at_most_everything():
    diag = _with_ceiling(0.2)
    assert not diag.unexplained_remains
    assert diag.explained_share == 1.0 and diag.shrink_pct <= 100.0
    assert "nothing significant remains" in diag.summary


@pytest.mark.parametrize("ceiling_drop", [0.0, -0.1])
def test_a_catalogue_where_the_ceiling_removes_nothing_explains_everything(ceiling_drop):
    """The ceiling removes nothing (or loses): the catalogue reaches all it allows. The share
    once fell back to the floor's (0.3 of a gap of 1), and min_share refused the attribution."""
    diag = _with_ceiling(ceiling_drop, min_share=0.8)
    assert diag.explained_share == 1.0
    assert diag.verdict == "a" and not diag.unexplained_remains


def test_cluster_robust_tests_do_not_depend_on_the_seed_and_count_clusters():
    """With ``cluster_of`` the p-values are deterministic; units that move together (20 per
    cluster, one shared gain each) count as one: a gain that 2000 independent units would
    make certain is uncertain from 100 clusters."""
    rng = np.random.default_rng(0)
    shared = np.repeat(rng.normal(0.01, 0.1, 100), 20)  # per-cluster gain, mean ~0.01
    base = np.full(N_UNITS, 1.0)

    def loss(_data, fitted):
        return base - (shared if fitted else 0.0)
    units = [f"u{k:04d}" for k in range(N_UNITS)]

    def run(seed, **kw):
        functions = LayerFunctions(loss, lambda _d: np.zeros(N_UNITS),
                                   unit_ids=lambda _d: units, **kw)
        return diagnose_losses("test", [Candidate("a", lambda _t, _c: {})], functions,
                               DiagnosisSettings(n_boot=300), rng=np.random.default_rng(seed),
                               seed=seed)
    clustered = [run(s, cluster_of=lambda u: str(int(u[1:]) // 20)) for s in (0, 1, 2)]
    p = {d.ranking[0]["p_one_sided"] for d in clustered}
    assert len(p) == 1  # the same p under every seed
    se = np.std(shared[::20]) / np.sqrt(100)
    assert p.pop() == pytest.approx(__import__("scipy").stats.norm.sf(shared.mean() / se),
                                    rel=0.05)
    # Per unit, the bootstrap sees 2000 independent gains: a far smaller p.
    assert run(0).ranking[0]["p_one_sided"] < clustered[0].ranking[0]["p_one_sided"] / 3


def test_a_floor_above_the_loss_is_reported_as_misestimated_never_as_no_gap():
    diag = _with_ceiling(0.3, floor_shift=5.0)  # every loss far below the floor
    assert diag.floor_status == "misestimated"
    assert "mis-estimated" in diag.summary and "No gap" not in diag.summary
    assert diag.verdict != "no_gap_that_matters"


def test_cross_fitting_averages_each_unit_over_repeats():
    """Two repeats of a 2-fold split: every unit's loss is the mean of its two held-out
    values, in sorted unit order."""
    import pandas as pd

    units = pd.DataFrame({"u": [f"u{k:02d}" for k in range(8)], "x": np.arange(8.0)})
    folds = []
    for rep in range(2):
        m = (np.arange(8) + rep) % 2 == 0
        folds.append((units[~m], units[m]))

    def loss_for(_train):
        return lambda data, fitted: data["x"].to_numpy() + (0 if not fitted else -1.0)
    functions = LayerFunctions(loss_for, lambda d: np.zeros(len(d)),
                               unit_ids=lambda d: list(d["u"]))
    diag = diagnose_losses("test", [Candidate("c", lambda _t, _c: {})], functions,
                           DiagnosisSettings(n_boot=200), rng=np.random.default_rng(0), seed=0,
                           folds=folds)
    assert diag.heldout == tuple(units["u"])
    assert diag.loss_before == pytest.approx(3.5)
    assert diag.loss_after == pytest.approx(2.5)


def test_registry_knows_every_observer_candidate_and_refuses_unknown_names():
    from analysis.gap.engine import GapError, candidate, catalogue, register

    names = [c.name for c in catalogue("observer")]
    assert names == ["crosstalk", "central_tendency", "illumination_gain", "label_rounding",
                     "lapses", "serial_dependence"]
    for c in catalogue("observer"):
        assert callable(c.apply) and callable(c.inject) and callable(c.truth)
        assert c.default_strength > 0 and c.units
    with pytest.raises(GapError, match="unknown candidate 'glare'.*known: crosstalk"):
        candidate("observer", "glare")
    with pytest.raises(GapError, match="already has a candidate"):
        register("observer", Candidate("crosstalk", lambda _t, _c: {}))
    with pytest.raises(GapError, match="no candidates registered"):
        catalogue("no-such-layer")


def test_a_new_candidate_is_one_object():
    """Registering one object adds an effect to the observer model's prediction."""
    from analysis.gap.engine import register
    from analysis.gap.observer import observer_frame, predict
    from studydesign import load_design

    def apply(data, pred, p):
        return {**pred, "mu": {**pred["mu"], "depth": pred["mu"]["depth"] + p["shift"]}}
    register("observer", Candidate("depth_shift_for_test", lambda _t, _c: {"shift": 0.5},
                                   apply=apply))
    try:
        import pandas as pd

        design = load_design()
        frame = pd.DataFrame({"participant": ["A"], "session": [1], "order": [1],
                              "illumination": ["x"], "gloss_level": [1], "depth_level": [1],
                              "true_gloss_pct": [50.0], "true_depth_cm": [2.4],
                              "gloss_match": [6.0], "depth_match": [6.0]})
        data = observer_frame(frame, design)
        mu = predict(data, [("depth_shift_for_test", {"shift": 0.5})])["mu"]
        assert mu["depth"][0] == pytest.approx(6.5)
    finally:
        from analysis.gap.engine import registry

        registry._REGISTRY["observer"].pop("depth_shift_for_test")


def test_ceiling_given_chosen_sees_each_folds_chosen_candidates():
    """A ceiling that models what the chosen model leaves is called with the chosen list; it
    then stays at or below the chosen model's loss, so a gap beside the catalogue shows."""
    cands, loss = _problem({"a": 0.3})
    seen = []

    def ceiling(_train, _test, fitted):
        seen.append([n for n, _ in fitted])
        return loss(None, fitted) - 0.05  # 0.05 nats per unit the catalogue leaves

    functions = LayerFunctions(loss, lambda _d: np.zeros(N_UNITS), ceiling=ceiling,
                               ceiling_given_chosen=True)
    diag = diagnose_losses("test", cands, functions, DiagnosisSettings(n_boot=400),
                           rng=np.random.default_rng(1), seed=1)
    assert seen == [["a"]]
    assert diag.verdict == "a" and diag.remaining["significant"]
    assert diag.remaining["gap"] == pytest.approx(0.05, abs=1e-9)
