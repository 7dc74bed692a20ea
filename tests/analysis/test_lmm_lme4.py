"""`analysis.lmm.fit` against lme4, car and lmerTest run live in R, on lme4's own data and ours.

Every reference comes from ``analysis/r/lmm_formula_reference.R`` run now (marked ``r``; the
tests fail, never skip, without R): lme4 1.1-31 ``lmer`` with nloptwrap BOBYQA at xtol_abs 1e-10
/ ftol_abs 1e-12, ``devFunOnly`` deviances at given thetas, ``car::Anova(type = 2)`` and
lmerTest 3.1-3 (Debian's r-cran-lmertest). Data: lme4's sleepstudy, Penicillin (crossed), Pastes
(nested) and Dyestuff, exported by R in the test; the source study's models on simulated
sessions of 11 observers and of 2 (the demo's number); a crossed participant x stimulus model
with a two-level and a three-level factor, in treatment and sum contrasts.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from analysis.formula import build_model
from analysis.lmm import fit
from analysis.load import load_sessions
from analysis.models import model_frame
from analysis.pls import deviance, make_problem, theta_start
from analysis.satterthwaite import coefficient_tests, satterthwaite_terms
from analysis.typeii import hypothesis_matrices, type2_wald

from .lmmref import export_dataset, r_reference
from .sessions import write_sessions

# The R runs of every case (module fixture) take about two minutes.
pytestmark = [pytest.mark.r, pytest.mark.slow]

SOURCE = "gloss * depth + (1 + gloss + depth | participant)"
CROSSED = ("gloss_match_pct ~ gloss * depth + illumination + (1 + gloss + depth | participant)"
           " + (1 | stimulus_id)")
CROSSED_FACTOR = ("gloss_match_pct ~ gloss_bin * depth + C(illumination, contr.sum)"
                  " + (1 | participant) + (1 | stimulus_id)")
# The same with correlated participant slopes: singular on these data (the simulated observers
# differ in intercept only), so theta is not identified to 1e-6 along the boundary.
CROSSED_FACTOR_SINGULAR = ("gloss_match_pct ~ gloss_bin * depth + C(illumination, contr.sum)"
                           " + (1 + gloss + depth | participant) + (1 | stimulus_id)")
STUDY_FACTORS = ["participant", "stimulus_id", "illumination", "gloss_bin"]

# name: (data set, formula, REML, factor columns)
CASES = {
    "sleepstudy_ml": ("sleepstudy", "Reaction ~ Days + (Days | Subject)", False, ["Subject"]),
    "sleepstudy_reml": ("sleepstudy", "Reaction ~ Days + (Days | Subject)", True, ["Subject"]),
    "sleepstudy_uncorrelated": ("sleepstudy", "Reaction ~ Days + (Days || Subject)", False,
                                ["Subject"]),
    "penicillin_crossed_reml": ("Penicillin", "diameter ~ 1 + (1 | plate) + (1 | sample)", True,
                                ["plate", "sample"]),
    "penicillin_crossed_ml": ("Penicillin", "diameter ~ (1 | plate) + (1 | sample)", False,
                              ["plate", "sample"]),
    "pastes_nested": ("Pastes", "strength ~ 1 + (1 | batch/cask)", False, ["batch", "cask"]),
    "dyestuff_reml": ("Dyestuff", "Yield ~ 1 + (1 | Batch)", True, ["Batch"]),
    "source_gloss_11": ("study11", f"gloss_match_pct ~ {SOURCE}", False, STUDY_FACTORS),
    "source_depth_11": ("study11", f"depth_match_bc ~ {SOURCE}", False, STUDY_FACTORS),
    "source_gloss_demo_2": ("study2", f"gloss_match_pct ~ {SOURCE}", False, STUDY_FACTORS),
    "crossed_participant_stimulus": ("study11", CROSSED, False, STUDY_FACTORS),
    "crossed_three_level_factor": ("study11", CROSSED_FACTOR, False, STUDY_FACTORS),
    "crossed_reml": ("study11", CROSSED, True, STUDY_FACTORS),
    "crossed_singular": ("study11", CROSSED_FACTOR_SINGULAR, False, STUDY_FACTORS),
}
# Singular fits whose optimum lies on a flat boundary: compared by deviance and chi-square only.
FLAT = {"crossed_singular"}


@pytest.fixture(scope="module")
def datasets(tmp_path_factory, design):
    folder = tmp_path_factory.mktemp("lme4data")
    out = {name: export_dataset(name, folder)
           for name in ("sleepstudy", "Penicillin", "Pastes", "Dyestuff")}
    for key, n, seed in (("study11", 11, 31), ("study2", 2, 32)):
        write_sessions(folder / key, design, np.random.default_rng(seed), n_participants=n)
        out[key] = model_frame(load_sessions(folder / key, design).frame, design)
    return out


@pytest.fixture(scope="module")
def results(datasets, tmp_path_factory):
    """Per case: (our fit, lme4's output, thetas where both evaluated the deviance)."""
    folder = tmp_path_factory.mktemp("lme4out")
    out = {}
    for case, (data_name, formula, reml, factors) in CASES.items():
        data = datasets[data_name]
        ours = fit(formula, data, reml=reml)
        pr = make_problem(build_model(formula, data), reml=reml)
        rng = np.random.default_rng(len(out))
        thetas = np.vstack([theta_start(pr), 0.5 * np.asarray(ours.theta),
                            np.abs(rng.normal(0.5, 0.3, len(ours.theta)))])
        rows = [dict(zip(ours.fixef, row), term=term)
                for term, L in hypothesis_matrices(ours).items() for row in L]
        ref = r_reference(folder / case, data, formula, reml=reml,
                          factors=[f for f in factors if f in data.columns], thetas=thetas,
                          contrasts=pd.DataFrame(rows) if rows else None)
        out[case] = (ours, ref, [deviance(t, pr) for t in thetas])
    return out


def _scale(values) -> float:
    return max(abs(v) for v in values) if values else 1.0


@pytest.mark.parametrize("case", list(CASES))
def test_deviance_at_fixed_theta_equals_lme4s_devfun(results, case):
    _, ref, ours = results[case]
    assert ours == pytest.approx([ref["dev_at"][str(k + 1)] for k in range(len(ours))], rel=1e-10)


@pytest.mark.parametrize("case", [c for c in CASES if c not in FLAT])
def test_fit_equals_lme4_to_1e6(results, case):
    ours, ref, _ = results[case]
    assert list(ours.fixef) == list(ref["fixef"]), "coefficient names and order as R's"
    beta_scale = _scale(ref["fixef"].values())
    for name, value in ref["fixef"].items():
        assert ours.fixef[name] == pytest.approx(value, rel=1e-6, abs=1e-6 * beta_scale), name
    names = list(ours.fixef)
    V = ours.vcov_array()
    v_scale = _scale([ref["vcov"][f"{a}|{a}"] for a in names])
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            assert V[i, j] == pytest.approx(ref["vcov"][f"{a}|{b}"], rel=1e-6,
                                            abs=1e-6 * v_scale), (a, b)
    theta_ref = [ref["theta"][str(k + 1)] for k in range(len(ref["theta"]))]
    assert ours.theta == pytest.approx(theta_ref, rel=1e-6, abs=1e-6 * _scale(theta_ref))
    assert ours.sigma == pytest.approx(ref["sigma"][""], rel=1e-6)
    assert ours.loglik == pytest.approx(ref["loglik"][""], rel=1e-10)
    assert ours.deviance == pytest.approx(ref["deviance"][""], rel=1e-10)
    sds = [s for r in ours.random for s in r["sd"].values()]
    assert sds == pytest.approx(list(ref["sd"].values()), rel=1e-6, abs=1e-6 * _scale(sds))
    assert ours.singular == bool(ref["singular"][""])


@pytest.mark.parametrize("case", [c for c in CASES if c not in FLAT
                                  and "~ 1 +" not in CASES[c][1] and "~ (" not in CASES[c][1]])
def test_type2_chi2_equals_car_anova(results, case):
    ours, ref, _ = results[case]
    tests = type2_wald(ours)
    assert [t.term.replace(" ", "") for t in tests] == [
        k.replace(" ", "") for k in ref["chisq"]]
    for t, (name, chi2) in zip(tests, ref["chisq"].items()):
        assert t.chi2 == pytest.approx(chi2, rel=1e-5), name
        assert t.df == ref["chisq_df"][name], name


def test_flat_singular_fit_is_as_good_as_lme4s(results):
    """On a singular crossed fit theta drifts along the boundary (both implementations stop
    within 2e-6 of each other there); the criterion and the tests still agree."""
    ours, ref, _ = results["crossed_singular"]
    assert ours.singular and ref["singular"][""] == 1.0
    assert ours.deviance <= ref["deviance"][""] * (1 + 1e-12)
    for t in type2_wald(ours):
        assert t.chi2 == pytest.approx(ref["chisq"][t.term], rel=1e-4), t.term
        assert t.df == ref["chisq_df"][t.term]


def test_three_level_factor_has_two_df(results):
    tests = {t.term: t for t in type2_wald(results["crossed_three_level_factor"][0])}
    assert tests["gloss_bin"].df == 2
    assert tests["gloss_bin:depth"].df == 2


def test_singular_fits_are_flagged_as_lme4_does(results):
    # Penicillin and sleepstudy are not singular; the 2-observer source model is (a 3 x 3
    # covariance from two participants).
    assert not results["penicillin_crossed_reml"][0].singular
    assert not results["sleepstudy_ml"][0].singular
    assert results["source_gloss_demo_2"][0].singular
    assert results["source_gloss_demo_2"][1]["singular"][""] == 1.0


SATTERTHWAITE = [c for c in CASES if c not in FLAT and c != "source_gloss_demo_2"]


def _satterthwaite_rel(fit) -> float:
    """1e-6; 1e-5 for a singular fit, where the numerical derivatives straddle a theta of 0 that
    the two optimisers place 1e-8 apart."""
    return 1e-5 if fit.singular else 1e-6


@pytest.mark.parametrize("case", SATTERTHWAITE)
def test_satterthwaite_t_tests_equal_lmertest(results, datasets, case):
    """Per coefficient: df and t as ``summary(lmerTest::lmer(...))$coefficients``."""
    ours, ref, _ = results[case]
    tests = coefficient_tests(ours, datasets[CASES[case][0]])
    rel = _satterthwaite_rel(ours)
    for name, (df, t, _) in tests.items():
        assert df == pytest.approx(ref["satt_df"][name], rel=rel), name
        assert t == pytest.approx(ref["satt_t"][name], rel=1e-6), name


@pytest.mark.parametrize("case", SATTERTHWAITE)
def test_satterthwaite_f_tests_equal_lmertest_contest(results, datasets, case):
    """Per term: F, numerator and denominator df of car's Type II hypothesis, as
    ``lmerTest::contest(fit, L, ddf = "Satterthwaite", joint = TRUE)``."""
    ours, ref, _ = results[case]
    if not ours.terms:
        assert "contest_F" not in ref
        return
    rel = _satterthwaite_rel(ours)
    for term, (F, q, ddf, _) in satterthwaite_terms(ours, datasets[CASES[case][0]]).items():
        assert F == pytest.approx(ref["contest_F"][term], rel=1e-6), term
        assert q == ref["contest_numdf"][term], term
        assert ddf == pytest.approx(ref["contest_dendf"][term], rel=rel), term
