"""Mixed models against lme4 1.1-31 + car 3.1-1 (R from Debian).

Reference files in tests/analysis/reference/ come from
``.venv/bin/python tests/analysis/reference/regenerate.py``, which simulates each data set of
``lmmdata.CASES`` with a fixed seed and runs ``analysis/r/lmm_formula_reference.R`` on it: lme4's
``devFunOnly`` deviance at given thetas, and ``lmer(REML = FALSE)`` with nloptwrap BOBYQA at
xtol_abs 1e-10 / ftol_abs 1e-12 from lme4's default start and from ``moment_start`` (the better
one kept, then polished by Newton steps on lme4's devfun), then ``car::Anova(type = 2)``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.formula import build_model
from analysis.lmm import LmmError, LmmFit, bc_power, fit, moment_start
from analysis.load import load_sessions
from analysis.models import ModelResult, fit_source_study_models
from analysis.pls import deviance, make_problem
from analysis.typeii import hypothesis_matrix, type2_wald

from .lmmdata import CASES, sample_thetas, simulate_case
from .lmmref import r_reference, read_reference
from .sessions import write_sessions

FORMULA = "y ~ gloss * depth + (1 + gloss + depth | participant)"
FIXED_TERMS = ("(Intercept)", "gloss", "depth", "gloss:depth")
RANDOM_TERMS = ("(Intercept)", "gloss", "depth")
REF = Path(__file__).parent / "reference"
ROOT = Path(__file__).resolve().parents[2]


def _data(case):
    return pd.read_csv(REF / f"{case}_data.csv", dtype={"participant": str})


def _by_coefficient(ref: dict) -> dict:
    """R's SDs and correlations keyed by coefficient alone (one grouping factor)."""
    for key in ("sd", "cor"):
        ref[key] = {name.split("|", 1)[1]: v for name, v in ref.get(key, {}).items()}
    return ref


def _ref(path: Path) -> dict:
    return _by_coefficient(read_reference(path))


def _problem(frame):
    return make_problem(build_model(FORMULA, frame), reml=False)


def _compare(fit: LmmFit, ref: dict, *, rel=1e-5, chi_rel=1e-4):
    for t in FIXED_TERMS:
        assert fit.fixef[t] == pytest.approx(ref["fixef"][t], rel=rel, abs=rel * 1e-3), t
        assert fit.se[t] == pytest.approx(ref["se"][t], rel=rel), t
    assert fit.loglik == pytest.approx(ref["loglik"][""], rel=rel)
    sd_max = max(ref["sd"].values())
    (participant,) = fit.random
    for t in RANDOM_TERMS:
        # A zero variance component (singular fit) is compared on the scale of the largest one.
        assert participant["sd"][t] == pytest.approx(ref["sd"][t], rel=rel, abs=rel * sd_max), t
    for pair, r in ref["cor"].items():
        a, b = pair.split(",")
        if min(ref["sd"][a], ref["sd"][b]) > 1e-2 * sd_max:
            assert participant["cor"][pair] == pytest.approx(r, abs=rel * 10), pair
    assert fit.sigma == pytest.approx(ref["sigma"][""], rel=rel)
    assert fit.singular == bool(ref["singular"][""])
    tests = type2_wald(fit)
    for w in tests:
        assert w.chi2 == pytest.approx(ref["chisq"][w.term], rel=chi_rel), w.term


def test_bc_power_matches_car():
    # car::bcPower(c(1, 2, 4), 0.83) in R 4.x, car 3.1-1.
    assert bc_power([1.0, 2.0, 4.0], 0.83) == pytest.approx([0.0, 0.9369703, 2.6026087], abs=1e-7)
    assert bc_power([np.e], 0.0) == pytest.approx([1.0])
    assert bc_power([np.e], 1e-7) == pytest.approx([1.0])


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan])
def test_bc_power_rejects_non_positive(bad):
    with pytest.raises(LmmError, match="strictly positive"):
        bc_power([1.0, bad], 0.83)


@pytest.mark.parametrize("case", list(CASES))
def test_deviance_at_fixed_theta_matches_lme4(case):
    pr = _problem(_data(case))
    thetas = np.loadtxt(REF / f"{case}_thetas.csv", delimiter=",")
    ref = _ref(REF / f"{case}_lme4.csv")["dev_at"]
    ours = [deviance(t, pr) for t in thetas]
    assert ours == pytest.approx([ref[str(k + 1)] for k in range(len(thetas))], rel=1e-10)


@pytest.mark.parametrize("case", list(CASES))
def test_fit_matches_lme4_and_car(case):
    _compare(fit(FORMULA, _data(case)), _ref(REF / f"{case}_lme4.csv"))


def test_singular_cases_are_singular_in_both():
    for case in ("singular_zero_slope", "singular_tiny", "singular_perfect_cor"):
        assert _ref(REF / f"{case}_lme4.csv")["singular"][""] == 1.0
        assert fit(FORMULA, _data(case)).singular


def test_better_of_two_starts_escapes_lme4s_local_optimum():
    # On this data set lme4's default start stops in a local optimum 1.6 deviance units above the
    # one the warm start finds (in R as in ours); a single cold start would report it.
    ref = _ref(REF / "singular_perfect_cor_lme4.csv")
    assert ref["dev_cold"][""] - ref["dev_warm"][""] > 1.0
    result = fit(FORMULA, _data("singular_perfect_cor"))
    assert result.deviance == pytest.approx(ref["dev_warm"][""], rel=1e-10)


@pytest.mark.r
def test_live_r_matches(tmp_path, design):
    """Runs R now, on a fresh data set; fails (does not skip) when R is missing."""
    rng = np.random.default_rng(99)
    frame = simulate_case("gloss", design, rng)
    thetas = sample_thetas(rng)
    ref = _by_coefficient(r_reference(tmp_path, frame, FORMULA, reml=False,
                                      factors=["participant"], thetas=thetas,
                                      start=moment_start(build_model(FORMULA, frame))))
    pr = _problem(frame)
    assert [deviance(t, pr) for t in thetas] == pytest.approx(
        [ref["dev_at"][str(k + 1)] for k in range(len(thetas))], rel=1e-10)
    _compare(fit(FORMULA, frame), ref)


def test_fit_recovers_known_fixed_effects(design, rng):
    frame = simulate_case("gloss", design, rng)
    result = fit(FORMULA, frame)
    truth = CASES["gloss"][1]
    for t, b in zip(FIXED_TERMS, truth):
        assert abs(result.fixef[t] - b) < 4 * result.se[t], t


def test_type2_chi2_does_not_depend_on_predictor_scale():
    frame = _data("gloss")
    base = type2_wald(fit(FORMULA, frame))
    scaled = frame.assign(gloss=frame["gloss"] * 10.0, depth=frame["depth"] * 0.4)
    other = type2_wald(fit(FORMULA, scaled))
    assert [w.chi2 for w in other] == pytest.approx([w.chi2 for w in base], rel=1e-5)


def test_hypothesis_of_highest_term_is_its_coefficient():
    spec = {"terms": ["gloss", "depth", "gloss:depth"], "assign": [-1, 0, 1, 2],
                "term_factors": [["gloss"], ["depth"], ["depth", "gloss"]]}
    L = hypothesis_matrix("gloss:depth", np.eye(4), **spec)
    assert L.tolist() == [[0.0, 0.0, 0.0, 1.0]]
    with pytest.raises(ValueError, match="unknown term"):
        hypothesis_matrix("illumination", np.eye(4), **spec)


def test_fit_round_trips_through_json():
    result = fit(FORMULA, _data("unbalanced_5"))
    assert LmmFit.from_json(result.to_json()) == result


@pytest.mark.parametrize(
    "change, formula, message",
    [
        (lambda f: f.drop(columns="depth"), FORMULA, "'depth', which is not a column"),
        (lambda f: f.assign(y="x"), FORMULA, "must be numeric"),
        (lambda f: f.assign(participant="P01"), FORMULA, "has one level"),
        (lambda f: f.assign(depth=0.5), FORMULA, "not estimable"),
        (lambda f: f, "y ~ gloss + (1 | observer)", "'observer' is not a column"),
        (lambda f: f, "y ~ gloss + illumination + (1 | participant)", "'illumination'"),
        (lambda f: f, "gloss ~ depth", "no random-effect term"),
        (lambda f: f, "y gloss + (1 | participant)", "exactly one '~'"),
        (lambda f: f, "y ~ gloss + (1 | participant", "unbalanced"),
        (lambda f: f, "y ~ gloss + (1 participant)", "one '|'"),
        (lambda f: f, "y ~ gloss + (1 | participant) + (1 | trial_id)", "'trial_id'"),
    ],
)
def test_bad_input_is_rejected_with_the_fix(change, formula, message):
    frame = _data("unbalanced_5")
    with pytest.raises(LmmError, match=message):
        fit(formula, change(frame))


def test_grouping_factor_with_a_level_per_observation_is_rejected():
    frame = _data("unbalanced_5").assign(row=lambda f: np.arange(len(f)).astype(str))
    with pytest.raises(LmmError, match="fewer levels than observations"):
        fit("y ~ gloss + (1 | row)", frame)


def test_missing_values_are_left_out_and_counted():
    frame = _data("unbalanced_5")
    holes = frame.assign(y=np.where(frame.index % 50 == 3, np.nan, frame["y"]))
    result = fit(FORMULA, holes)
    assert result.n_dropped == int((frame.index % 50 == 3).sum()) > 0
    assert result.n_obs == len(frame) - result.n_dropped
    complete = fit(FORMULA, holes.dropna().reset_index(drop=True))
    assert complete.n_dropped == 0
    assert result.fixef == pytest.approx(complete.fixef, rel=1e-12)
    assert result.loglik == pytest.approx(complete.loglik, rel=1e-12)


@pytest.mark.parametrize("case", ["gloss", "unbalanced_5"])
def test_scalar_kernel_equals_the_general_block_elimination(case):
    """The source-study kernel (patterns of identical blocks) against the general one."""
    pr = _problem(_data(case))
    assert pr.cp is not None
    general = dataclasses.replace(pr, cp=None)
    # Complete data: one pattern; 20 % of trials dropped at random: one per participant.
    assert len(pr.cp.patterns) == (1 if case == "gloss" else 5)
    for theta in sample_thetas(np.random.default_rng(3)):
        assert deviance(theta, pr) == pytest.approx(deviance(theta, general), rel=1e-12)


def test_patterns_group_identical_participants(design):
    frame = _data("gloss")
    # Drop the same trial for two participants and another for a third: 3 patterns.
    trial = frame.index % design.n_stimuli
    drop = frame.index[(frame["participant"].isin(["P01", "P02"]) & (trial == 5))
                       | ((frame["participant"] == "P03") & (trial == 9))]
    pr = _problem(frame.drop(index=drop).reset_index(drop=True))
    assert sorted(p[3] for p in pr.cp.patterns) == [1, 2, 8]
    general = dataclasses.replace(pr, cp=None)
    theta = sample_thetas(np.random.default_rng(1))[4]
    assert deviance(theta, pr) == pytest.approx(deviance(theta, general), rel=1e-12)


def test_unrolled_schur_complement_equals_the_loop():
    from analysis.deviance import _schur5, _schur_loop

    rng = np.random.default_rng(0)
    A = rng.random((30, 5))
    XtXy = (A.T @ A).tolist()
    R = (0.1 * rng.random((3, 5))).tolist()
    m_yy = XtXy[4][4] - 0.01
    r2, beta = _schur5(XtXy, *R, 2, m_yy)
    r2_loop, beta_loop = _schur_loop(XtXy, [(*R, 2)], m_yy)
    assert r2 == pytest.approx(r2_loop, rel=1e-12)
    assert beta == pytest.approx(beta_loop, rel=1e-12)


@pytest.mark.parametrize("case", ["gloss", "unbalanced_5"])
def test_deviance_gradient_equals_central_differences(case):
    """The analytic gradient (one pattern; five, where beta moves with theta) against central
    differences of the general deviance, at the start, boundary and random thetas."""
    from analysis.deviance import deviance_gradient

    pr = _problem(_data(case))
    general = dataclasses.replace(pr, cp=None)
    for theta in sample_thetas(np.random.default_rng(5))[[0, 1, 3, 4, 5]]:
        dev, grad = deviance_gradient(theta.tolist(), pr.cp)
        assert dev == pytest.approx(deviance(theta, general), rel=1e-12)
        h = 1e-5
        fd = [(deviance(theta + h * e, general) - deviance(theta - h * e, general)) / (2 * h)
              for e in np.eye(6)]
        assert grad == pytest.approx(fd, rel=1e-5, abs=1e-3)


@pytest.mark.parametrize("case", ["depth_bc", "singular_tiny", "unbalanced_5"])
def test_bootstrap_refits_reach_bootmers_optimum_or_a_better_one(case):
    """The bootstrap's gradient refits against bootMer's procedure (BOBYQA from the original
    theta, lme4's tolerances), on simulated responses of a fitted model; and SLSQP needs fewer
    deviance evaluations than BOBYQA from the same start."""
    from analysis.bootstrap import BOOT_FTOL_ABS, BOOT_XTOL_ABS, refit, simulate_responses
    from analysis.lmm import fit_problem
    from analysis.pls import with_y

    frame = _data(case)
    result = fit(FORMULA, frame)
    pr = _problem(frame)
    theta0 = np.asarray(result.theta)
    ys = simulate_responses(pr, result.fixef_array(), theta0, result.sigma,
                            np.random.default_rng(1), 20)
    kw = {"starts": [(theta0, 0.1)], "ftol_abs": BOOT_FTOL_ABS, "xtol_abs": BOOT_XTOL_ABS}
    evals_b = evals_g = 0
    for y in ys:
        prb = with_y(pr, y)
        _, dev_bootmer, n_b = fit_problem(prb, **kw)
        _, dev_refit = refit(prb, theta0)
        assert dev_refit <= dev_bootmer + 1e-6
        evals_b += n_b
        evals_g += fit_problem(prb, gradient=True, **kw)[2]
    assert evals_g < 0.7 * evals_b


@pytest.mark.parametrize("case, index", [("singular_tiny", 43), ("singular_perfect_cor", 70)])
def test_singular_refit_restarts_from_the_nudged_theta(case, index, monkeypatch):
    """A response where SLSQP stops on the boundary above bootMer's optimum from both starts
    (found among 150 simulated responses of the data set; seed 1): the restart from the
    optimum with its zero diagonal raised to `NUDGE` reaches bootMer's optimum. Without the
    restart (``NUDGE = 0`` restarts from the same point) the refit stays above it."""
    import analysis.bootstrap as boot
    from analysis.lmm import fit_problem
    from analysis.pls import with_y

    frame = _data(case)
    result = fit(FORMULA, frame)
    pr = _problem(frame)
    theta0 = np.asarray(result.theta)
    y = boot.simulate_responses(pr, result.fixef_array(), theta0, result.sigma,
                                np.random.default_rng(1), index + 1)[index]
    prb = with_y(pr, y)
    _, dev_bootmer, _ = fit_problem(prb, starts=[(theta0, 0.1)], ftol_abs=boot.BOOT_FTOL_ABS,
                                    xtol_abs=boot.BOOT_XTOL_ABS)
    assert boot.refit(prb, theta0)[1] <= dev_bootmer + 1e-6
    monkeypatch.setattr(boot, "NUDGE", 0.0)
    assert boot.refit(prb, theta0)[1] > dev_bootmer + 1e-3


def test_bootstrap_refit_of_the_source_model_uses_the_gradient(monkeypatch):
    """The source model's refits minimise with the analytic gradient (what makes them fast:
    bench/analysis_bootstrap_vs_bootmer.py); the crossed model's, which has no scalar kernel,
    do not."""
    import analysis.bootstrap as boot
    from analysis import lmm
    from analysis.deviance import deviance_gradient
    from analysis.pls import with_y

    calls = []

    def counted(x, cp):
        calls.append(1)
        return deviance_gradient(x, cp)

    monkeypatch.setattr(lmm, "deviance_gradient", counted)
    frame = _data("depth_bc")
    for formula, used in [(FORMULA, True), (FORMULA + " + (1 | stimulus)", False)]:
        framed = frame.assign(stimulus=(frame.index % 162).astype(str))
        result = fit(formula, framed)
        pr = make_problem(build_model(formula, framed), reml=False)
        y = boot.simulate_responses(pr, result.fixef_array(), np.asarray(result.theta),
                                    result.sigma, np.random.default_rng(1), 1)[0]
        calls.clear()
        boot.refit(with_y(pr, y), np.asarray(result.theta))
        assert bool(calls) is used, formula


def test_gradient_fit_falls_back_to_bobyqa_when_a_probe_fails(monkeypatch):
    """A probe whose deviance cannot be computed (the fixed effects' Schur complement singular
    to rounding raises ZeroDivisionError or ValueError in the scalar kernel) sends the fit from
    that start to BOBYQA, which reaches the same optimum as a BOBYQA fit."""
    from analysis import lmm
    from analysis.deviance import deviance_gradient
    from analysis.lmm import fit_problem

    frame = _data("depth_bc")
    pr = _problem(frame)
    start = [(np.asarray(fit(FORMULA, frame).theta) * 1.5, 0.1)]
    calls = []

    def failing_probe(x, cp):
        calls.append(1)
        if len(calls) == 3:
            raise ZeroDivisionError("float division by zero")
        return deviance_gradient(x, cp)

    monkeypatch.setattr(lmm, "deviance_gradient", failing_probe)
    _, dev, _ = fit_problem(pr, starts=start, gradient=True)
    _, dev_bobyqa, _ = fit_problem(pr, starts=start)
    assert len(calls) == 3
    assert dev == pytest.approx(dev_bobyqa, abs=1e-6)


def test_gradient_fit_needs_the_scalar_kernel(design):
    from analysis.lmm import fit_problem

    pr = make_problem(build_model(FORMULA, _data("gloss")), reml=True)
    assert pr.cp is None
    with pytest.raises(ValueError, match="BOBYQA"):
        fit_problem(pr, starts=[(np.ones(6), None)], gradient=True)


@pytest.mark.parametrize("formula", [FORMULA, FORMULA + " + (1 | stimulus)"])
def test_new_response_needs_only_its_cross_products(formula):
    from analysis.pls import theta_lower, with_y

    frame = _data("gloss").assign(stimulus=lambda f: (f.index % 162).astype(str))
    pr = make_problem(build_model(formula, frame), reml=False)
    y2 = frame["y"].to_numpy()[::-1].copy()
    fresh = make_problem(build_model(formula, frame.assign(y=y2)), reml=False)
    swapped = with_y(pr, y2)
    rng = np.random.default_rng(8)
    for _ in range(5):
        theta = np.abs(rng.normal(0.5, 0.3, theta_lower(pr).size))
        assert deviance(theta, swapped) == pytest.approx(deviance(theta, fresh), rel=1e-12)


def test_model_results_round_trip_through_json(design, tmp_path):
    write_sessions(tmp_path, design, np.random.default_rng(3), n_participants=3)
    models = fit_source_study_models(load_sessions(tmp_path, design).frame, design)
    for res in models.values():
        assert ModelResult.from_json(res.to_json()) == res
    assert models["depth"].boxcox_lambda == design.analysis.depth_boxcox_lambda


def test_trial_order_does_not_split_patterns():
    # Participants see the stimuli in different orders: their sums differ by rounding only.
    frame = _data("gloss").sample(frac=1.0, random_state=2).reset_index(drop=True)
    assert len(_problem(frame).cp.patterns) == 1


@pytest.mark.parametrize("formula", [
    FORMULA + " + (1 | stimulus)",
    "y ~ gloss * depth + (1 | stimulus) + (1 + gloss | participant)",
    "y ~ gloss + (1 + gloss | participant)",
    "y ~ gloss * depth + (1 | participant) + (1 | stimulus)",
])
@pytest.mark.parametrize("reml", [False, True])
def test_patterns_of_levels_equal_level_by_level_elimination(formula, reml):
    """Levels of the first term with equal Z'Z blocks taken together (what makes the crossed
    model fast) against eliminating them one by one, complete and incomplete data."""
    frame = _data("unbalanced_5").assign(stimulus=lambda f: (f.index % 40).astype(str))
    for data in (frame, frame.iloc[::2].reset_index(drop=True)):
        pr = make_problem(build_model(formula, data), reml=reml)
        general = dataclasses.replace(pr, cp=None)
        one_by_one = dataclasses.replace(pr, cp=None, patterns=())
        from analysis.pls import theta_lower

        for theta in np.abs(np.random.default_rng(5).normal(0.6, 0.4, (4, theta_lower(pr).size))):
            assert deviance(theta, general) == pytest.approx(deviance(theta, one_by_one),
                                                             rel=1e-12)
