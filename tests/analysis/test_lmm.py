"""Mixed models against lme4 1.1-31 + car 3.1-1 (R from Debian).

Reference files in tests/analysis/reference/ come from
``.venv/bin/python tests/analysis/reference/regenerate.py``, which simulates each data set of
``lmmdata.CASES`` with a fixed seed and runs ``analysis/r/lmm_reference.R`` on it: lme4's
``devFunOnly`` deviance at given thetas, and ``lmer(REML = FALSE)`` with nloptwrap BOBYQA at
xtol_abs 1e-10 / ftol_abs 1e-12 from lme4's default start and from ``moment_start`` (the better
one kept), then ``car::Anova(type = 2)``.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.lmm import (
    FIXED_TERMS,
    RANDOM_TERMS,
    LmmError,
    LmmFit,
    bc_power,
    crossproducts,
    fit_lmm,
    model_matrices,
    moment_start,
    profiled_deviance,
)
from analysis.load import load_sessions
from analysis.models import ModelResult, fit_seed_models
from analysis.typeii import hypothesis_matrix, type2_wald

from .lmmdata import CASES, sample_thetas, simulate_case
from .sessions import write_sessions

REF = Path(__file__).parent / "reference"
ROOT = Path(__file__).resolve().parents[2]


def _data(case):
    return pd.read_csv(REF / f"{case}_data.csv", dtype={"participant": str})


def _ref(path: Path) -> dict:
    t = pd.read_csv(path, dtype={"name": str}, keep_default_na=False)
    out = {}
    for key, grp in t.groupby("key", sort=False):
        out[key] = dict(zip(grp["name"], grp["value"].astype(float)))
    return out


def _compare(fit: LmmFit, ref: dict, *, rel=1e-5, chi_rel=1e-4):
    for t in FIXED_TERMS:
        assert fit.fixef[t] == pytest.approx(ref["fixef"][t], rel=rel, abs=rel * 1e-3), t
        assert fit.se[t] == pytest.approx(ref["se"][t], rel=rel), t
    assert fit.loglik == pytest.approx(ref["loglik"][""], rel=rel)
    sd_max = max(ref["sd"].values())
    for t in RANDOM_TERMS:
        # A zero variance component (singular fit) is compared on the scale of the largest one.
        assert fit.re_sd[t] == pytest.approx(ref["sd"][t], rel=rel, abs=rel * sd_max), t
    for pair, r in ref["cor"].items():
        a, b = pair.split(",")
        if min(ref["sd"][a], ref["sd"][b]) > 1e-2 * sd_max:
            assert fit.re_cor[pair] == pytest.approx(r, abs=rel * 10), pair
    assert fit.sigma == pytest.approx(ref["sigma"][""], rel=rel)
    assert fit.singular == bool(ref["singular"][""])
    tests = type2_wald(fit.fixef_array(), fit.vcov_array())
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
    X, Z, y, groups, _ = model_matrices(_data(case), "y")
    cp = crossproducts(X, Z, y, groups)
    thetas = np.loadtxt(REF / f"{case}_thetas.csv", delimiter=",")
    ref = _ref(REF / f"{case}_lme4.csv")["dev_at"]
    ours = [profiled_deviance(t, cp) for t in thetas]
    assert ours == pytest.approx([ref[str(k + 1)] for k in range(len(thetas))], rel=1e-10)


@pytest.mark.parametrize("case", list(CASES))
def test_fit_matches_lme4_and_car(case):
    fit = fit_lmm(_data(case), response="y")
    _compare(fit, _ref(REF / f"{case}_lme4.csv"))


def test_singular_cases_are_singular_in_both():
    for case in ("singular_zero_slope", "singular_tiny", "singular_perfect_cor"):
        assert _ref(REF / f"{case}_lme4.csv")["singular"][""] == 1.0
        assert fit_lmm(_data(case), response="y").singular


def test_better_of_two_starts_escapes_lme4s_local_optimum():
    # On this data set lme4's default start stops in a local optimum 1.6 deviance units above the
    # one the warm start finds (in R as in ours); a single cold start would report it.
    ref = _ref(REF / "singular_perfect_cor_lme4.csv")
    assert ref["dev_cold"][""] - ref["dev_warm"][""] > 1.0
    fit = fit_lmm(_data("singular_perfect_cor"), response="y")
    assert fit.deviance == pytest.approx(ref["dev_warm"][""], rel=1e-10)


@pytest.mark.r
def test_live_r_matches(tmp_path, design):
    """Runs R now, on a fresh data set; fails (does not skip) when R is missing."""
    rscript = shutil.which("Rscript")
    assert rscript, "Rscript not found: install r-base-core r-cran-lme4 r-cran-car (make test does)"
    rng = np.random.default_rng(99)
    frame = simulate_case("gloss", design, rng)
    frame.to_csv(tmp_path / "data.csv", index=False, float_format="%.17g")
    thetas = sample_thetas(rng)
    np.savetxt(tmp_path / "thetas.csv", thetas, delimiter=",", fmt="%.17g")
    X, Z, y, groups, _ = model_matrices(frame, "y")
    np.savetxt(tmp_path / "start.csv", moment_start(X, Z, y, groups)[None, :], delimiter=",",
               fmt="%.17g")
    subprocess.run([rscript, str(ROOT / "analysis/r/lmm_reference.R"), str(tmp_path / "data.csv"),
                    str(tmp_path / "thetas.csv"), str(tmp_path / "start.csv"),
                    str(tmp_path / "out.csv")], check=True, capture_output=True, timeout=120)
    ref = _ref(tmp_path / "out.csv")
    cp = crossproducts(X, Z, y, groups)
    assert [profiled_deviance(t, cp) for t in thetas] == pytest.approx(
        [ref["dev_at"][str(k + 1)] for k in range(len(thetas))], rel=1e-10)
    _compare(fit_lmm(frame, response="y"), ref)


def test_fit_recovers_known_fixed_effects(design, rng):
    frame = simulate_case("gloss", design, rng)
    fit = fit_lmm(frame, response="y")
    truth = CASES["gloss"][1]
    for t, b in zip(FIXED_TERMS, truth):
        assert abs(fit.fixef[t] - b) < 4 * fit.se[t], t


def test_type2_chi2_does_not_depend_on_predictor_scale():
    frame = _data("gloss")
    base = type2_wald(*_fe_vcov(fit_lmm(frame, response="y")))
    scaled = frame.assign(gloss=frame["gloss"] * 10.0, depth=frame["depth"] * 0.4)
    other = type2_wald(*_fe_vcov(fit_lmm(scaled, response="y")))
    assert [w.chi2 for w in other] == pytest.approx([w.chi2 for w in base], rel=1e-5)


def _fe_vcov(fit):
    return fit.fixef_array(), fit.vcov_array()


def test_hypothesis_of_highest_term_is_its_coefficient():
    L = hypothesis_matrix("gloss:depth", np.eye(4))
    assert L.tolist() == [[0.0, 0.0, 0.0, 1.0]]
    with pytest.raises(ValueError, match="unknown term"):
        hypothesis_matrix("illumination", np.eye(4))


def test_fit_round_trips_through_json():
    fit = fit_lmm(_data("unbalanced_5"), response="y")
    assert LmmFit.from_json(fit.to_json()) == fit


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda f: f.drop(columns="depth"), "missing"),
        (lambda f: f.assign(y=np.where(f.index == 3, np.nan, f["y"])), "non-finite"),
        (lambda f: f.assign(participant="P01"), ">= 2"),
        (lambda f: f.assign(depth=0.5), "at least two gloss and two depth levels"),
    ],
)
def test_bad_model_frames_are_rejected(change, message):
    with pytest.raises(LmmError, match=message):
        fit_lmm(change(_data("unbalanced_5")), response="y")


@pytest.mark.parametrize("case", ["gloss", "unbalanced_5"])
def test_scalar_deviance_equals_the_numpy_blocks(case):
    """The fast scalar path (patterns of identical blocks) against per-participant numpy blocks."""
    from analysis.deviance import _solve_pls

    X, Z, y, groups, _ = model_matrices(_data(case), "y")
    cp = crossproducts(X, Z, y, groups)
    # Complete data: one pattern; 20 % of trials dropped at random: one per participant.
    assert len(cp.patterns) == (1 if case == "gloss" else 5)
    for theta in sample_thetas(np.random.default_rng(3)):
        ldL2, _, _, pwrss = _solve_pls(theta, cp)
        slow = ldL2 + cp.n * (1 + np.log(2 * np.pi * pwrss / cp.n))
        assert profiled_deviance(theta, cp) == pytest.approx(slow, rel=1e-12)


def test_patterns_group_identical_participants(design):
    frame = _data("gloss")
    # Drop the same trial for two participants and another for a third: 3 patterns.
    trial = frame.index % design.n_stimuli
    drop = frame.index[(frame["participant"].isin(["P01", "P02"]) & (trial == 5))
                       | ((frame["participant"] == "P03") & (trial == 9))]
    X, Z, y, groups, _ = model_matrices(frame.drop(index=drop), "y")
    cp = crossproducts(X, Z, y, groups)
    assert sorted(p[3] for p in cp.patterns) == [1, 2, 8]
    from analysis.deviance import _solve_pls

    theta = sample_thetas(np.random.default_rng(1))[4]
    ldL2, _, _, pwrss = _solve_pls(theta, cp)
    assert profiled_deviance(theta, cp) == pytest.approx(
        ldL2 + cp.n * (1 + np.log(2 * np.pi * pwrss / cp.n)), rel=1e-12)


def test_unrolled_schur_complement_equals_the_loop():
    from analysis.deviance import _schur5, _schur_loop

    rng = np.random.default_rng(0)
    A = rng.random((30, 5))
    XtXy = (A.T @ A).tolist()
    R = (0.1 * rng.random((3, 5))).tolist()
    m_yy = XtXy[4][4] - 0.01
    assert _schur5(XtXy, *R, 2, m_yy) == pytest.approx(
        _schur_loop(XtXy, [(*R, 2)], m_yy), rel=1e-12)


def test_new_response_needs_only_its_cross_products():
    from analysis.deviance import with_response

    X, Z, y, groups, _ = model_matrices(_data("gloss"), "y")
    base = crossproducts(X, Z, y, groups)
    y2 = y[::-1].copy()
    fresh = crossproducts(X, Z, y2, groups)
    Zty = np.zeros_like(base.Zty)
    np.add.at(Zty, groups, Z * y2[:, None])
    swapped = with_response(base, Zty, X.T @ y2, y2 @ y2)
    for theta in sample_thetas(np.random.default_rng(8)):
        assert profiled_deviance(theta, swapped) == pytest.approx(
            profiled_deviance(theta, fresh), rel=1e-12)


def test_model_results_round_trip_through_json(design, tmp_path):
    write_sessions(tmp_path, design, np.random.default_rng(3), n_participants=3)
    models = fit_seed_models(load_sessions(tmp_path, design).frame, design)
    for res in models.values():
        assert ModelResult.from_json(res.to_json()) == res
    assert models["depth"].boxcox_lambda == design.analysis.depth_boxcox_lambda


def test_trial_order_does_not_split_patterns():
    # Participants see the stimuli in different orders: their sums differ by rounding only.
    frame = _data("gloss").sample(frac=1.0, random_state=2)
    X, Z, y, groups, _ = model_matrices(frame, "y")
    assert len(crossproducts(X, Z, y, groups).patterns) == 1
