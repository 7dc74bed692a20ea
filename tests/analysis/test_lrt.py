"""Parametric bootstrap likelihood-ratio tests against pbkrtest::PBmodcomp, run live in R.

References: R 4.x with lme4 1.1-31 and pbkrtest 0.5.2 (Debian), ``PBmodcomp(large, small,
nsim = 200)`` and ``anova(small, large)`` on lme4's sleepstudy with an added pure-noise
predictor (numpy seed 1), run in the test.
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from analysis.lmm import fit
from analysis.lrt import bootstrap_lrt

from .lmmref import export_dataset, rscript

FORMULA = "Reaction ~ Days + noise + (Days | Subject)"
R_SCRIPT = """
suppressPackageStartupMessages({library(lme4); library(pbkrtest)})
d <- read.csv("%s", colClasses = c(Subject = "character"))
lg <- lmer(Reaction ~ Days + noise + (Days | Subject), d, REML = FALSE)
sm <- lmer(Reaction ~ Days + (Days | Subject), d, REML = FALSE)
set.seed(1)
pb <- suppressWarnings(PBmodcomp(lg, sm, nsim = 200))
cat(sprintf("%%.17g", pb$test["LRT", "stat"]), pb$test["PBtest", "p.value"],
    anova(sm, lg)$Chisq[2], "\\n")
"""


@pytest.fixture(scope="module")
def sleep(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lrt")
    data = export_dataset("sleepstudy", folder)
    data["Subject"] = data["Subject"].astype(str)
    data["noise"] = np.random.default_rng(1).normal(size=len(data))
    data.to_csv(folder / "data.csv", index=False, float_format="%.17g")
    return folder, data


@pytest.mark.r
@pytest.mark.slow
def test_lrt_and_bootstrap_p_agree_with_pbmodcomp(sleep):
    folder, data = sleep
    (folder / "pb.R").write_text(R_SCRIPT % (folder / "data.csv"))
    out = subprocess.run([rscript(), str(folder / "pb.R")], capture_output=True, text=True,
                         timeout=600, check=True)
    r_lrt, r_p, r_anova = map(float, out.stdout.split())
    result = bootstrap_lrt(data, fit(FORMULA, data), "noise", n_boot=200, seed=1, n_jobs=1,
                           progress=False)
    assert result.lrt == pytest.approx(r_lrt, rel=1e-6)
    assert result.lrt == pytest.approx(r_anova, rel=1e-6)
    # Two independent 200-run bootstraps: the p-values differ by Monte-Carlo error only
    # (s.e. of the difference ~ sqrt(2 p (1 - p) / 200) ~ 0.035 at p ~ 0.85).
    assert result.p_boot == pytest.approx(r_p, abs=0.15)
    assert result.n_ok == 200


def test_strong_effect_gets_the_smallest_p_and_reruns_are_identical(sleep):
    _, data = sleep
    large = fit(FORMULA, data)
    one = bootstrap_lrt(data, large, "Days", n_boot=50, seed=3, n_jobs=1, progress=False)
    assert one.p_boot == pytest.approx(1 / 51)
    assert one.p_chi2 < 1e-5 and one.df == 1
    two = bootstrap_lrt(data, large, "Days", n_boot=50, seed=3, n_jobs=2, progress=False)
    assert (one.lrt, one.p_boot) == (two.lrt, two.p_boot)


def test_unknown_term_is_rejected(sleep):
    _, data = sleep
    with pytest.raises(ValueError, match="unknown term 'shape'"):
        bootstrap_lrt(data, fit(FORMULA, data), "shape", n_boot=10)
