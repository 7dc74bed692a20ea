"""Parametric bootstrap: reproducible, parallel-invariant, covering, and fast enough to matter."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.bootstrap import BootstrapResult, parametric_bootstrap
from analysis.lmm import fit
from analysis.typeii import type2_wald

from .lmmdata import CASES, simulate_case

FORMULA = "y ~ gloss * depth + (1 + gloss + depth | participant)"


@pytest.fixture(scope="module")
def fitted(design):
    frame = simulate_case("gloss", design, np.random.default_rng(5))
    result = fit(FORMULA, frame)
    chi2 = {w.term: w.chi2 for w in type2_wald(result)}
    return frame, result, chi2


def test_same_seed_same_result_whatever_the_workers(fitted):
    frame, result, chi2 = fitted
    one = parametric_bootstrap(frame, result, observed_chi2=chi2, n_boot=120, seed=3, n_jobs=1,
                               progress=False)
    two = parametric_bootstrap(frame, result, observed_chi2=chi2, n_boot=120, seed=3, n_jobs=2,
                               progress=False)
    assert one.fixef_ci == two.fixef_ci
    assert one.chi2_p == two.chi2_p
    other = parametric_bootstrap(frame, result, observed_chi2=chi2, n_boot=120, seed=4, n_jobs=1,
                                 progress=False)
    assert other.fixef_ci != one.fixef_ci


def test_cis_match_wald_intervals_and_p_values_see_effects(fitted):
    frame, result, chi2 = fitted
    res, samples = parametric_bootstrap(frame, result, observed_chi2=chi2, n_boot=400, seed=1,
                                        n_jobs=2, progress=False, return_samples=True)
    assert res.n_ok == 400
    for i, t in enumerate(result.fixef):
        lo, hi = res.fixef_ci[t]
        # Percentile CIs of a linear model's fixed effects are close to beta +- 1.96 SE.
        assert lo < result.fixef[t] < hi
        assert (hi - lo) / (2 * 1.96 * result.se[t]) == pytest.approx(1.0, abs=0.2), t
        assert np.std(samples[:, i]) == pytest.approx(result.se[t], rel=0.2)
    # Every effect of the "gloss" case is far from zero: the smallest possible p-value.
    assert all(p == pytest.approx(1 / 401) for p in res.chi2_p.values())
    assert BootstrapResult.from_json(res.to_json()) == res


def test_null_effect_gets_a_large_p_value(design):
    # depth_bc has no gloss:depth interaction.
    frame = simulate_case("depth_bc", design, np.random.default_rng(2))
    null_fit = fit(FORMULA, frame)
    chi2 = {w.term: w.chi2 for w in type2_wald(null_fit)}
    assert CASES["depth_bc"][1][3] == 0.0
    res = parametric_bootstrap(frame, null_fit, observed_chi2=chi2, n_boot=200, seed=2, n_jobs=1,
                               progress=False)
    assert res.chi2_p["gloss:depth"] > 0.05
    assert res.chi2_p["depth"] < 0.01


def test_bad_arguments(fitted):
    frame, result, chi2 = fitted
    with pytest.raises(ValueError, match="n_boot"):
        parametric_bootstrap(frame, result, observed_chi2=chi2, n_boot=0)
    with pytest.raises(ValueError, match="unknown terms"):
        parametric_bootstrap(frame, result, observed_chi2={"shape": 1.0}, n_boot=10)


@pytest.mark.r
@pytest.mark.slow
def test_bench_against_bootmer_runs(repo_root):
    """The bench script end to end on a few runs (the claim itself is measured by `make bench`)."""
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, str(repo_root / "bench/analysis_bootstrap_vs_bootmer.py"), "--n", "40",
         "--n-r", "6"], capture_output=True, text=True, timeout=300, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "ratio (bootMer / ours, per refit):" in out.stdout
    assert out.stdout.count("ratio (bootMer / ours") == 2
    assert out.stdout.count("[") >= 16
