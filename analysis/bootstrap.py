"""Parametric bootstrap of a fitted mixed model: 95 % CIs and p-values for the Type II tests.

Like lme4's ``bootMer(type = "parametric", use.u = FALSE)``: each run simulates a new response
from the fitted model (new random effects ``b ~ N(0, sigma^2 T T')`` per participant and new
residuals ``N(0, sigma^2)``), refits, and records the fixed effects, the random-effect SDs and
the Type II Wald statistics. Only the cross-products with y change between runs (X, Z and the
grouping are fixed), so a refit reuses every y-free product; each refit takes the better of a
warm start at the original theta (initial step 0.1) and lme4's cold start.

CIs are percentile intervals. The p-value of a term's Type II test is the bootstrap Wald test:
``chi2*`` of the refit's estimate *centred at the original estimate* (the Wald pivot
``(L (b* - b))' (L V* L')^-1 (L (b* - b))``, Hall & Wilson 1991, "Two guidelines for bootstrap
hypothesis testing", Biometrics 47) approximates the statistic's null distribution;
``p = (1 + #{chi2* >= chi2}) / (N + 1)``.

Runs are split into blocks of fixed size, each with its own child of one ``SeedSequence``, and
the blocks run in parallel (joblib); the result depends on the seed only, not on the number of
workers.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from tqdm.auto import tqdm

from analysis.deviance import crossproducts, with_response
from analysis.lmm import (
    FIXED_TERMS,
    RANDOM_TERMS,
    LmmFit,
    fit_crossproducts,
    model_matrices,
    summarise_fit,
)
from analysis.typeii import hypothesis_matrix, wald_chi2

__all__ = ["BootstrapResult", "parametric_bootstrap"]

BLOCK = 100
# lme4's default nloptwrap tolerances, the ones bootMer refits with.
BOOT_FTOL_ABS = 1e-8
BOOT_XTOL_ABS = 1e-8


@dataclass(frozen=True)
class BootstrapResult:
    """Percentile CIs and bootstrap p-values of one model.

    Attributes
    ----------
    response : str
    n_boot : int
        Runs requested.
    n_ok : int
        Runs whose refit succeeded (the others are left out and counted).
    seed : int
    fixef_ci : dict of str to [float, float]
        95 % percentile CI of each fixed effect.
    re_sd_ci : dict of str to [float, float]
        95 % percentile CI of each random-effect SD.
    sigma_ci : [float, float]
    chi2_p : dict of str to float
        Bootstrap p-value of each term's Type II Wald test.
    singular_fraction : float
        Share of refits that were singular.
    seconds : float
        Wall-clock time of the bootstrap.
    n_jobs : int
    """

    response: str
    n_boot: int
    n_ok: int
    seed: int
    fixef_ci: dict
    re_sd_ci: dict
    sigma_ci: list
    chi2_p: dict
    singular_fraction: float
    seconds: float
    n_jobs: int

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1)

    @classmethod
    def from_json(cls, text: str) -> BootstrapResult:
        return cls(**json.loads(text))


def _sorted_problem(frame: pd.DataFrame, response: str, group: str):
    X, Z, y, groups, levels = model_matrices(frame, response, group)
    order = np.argsort(groups, kind="stable")
    X, Z, y, groups = X[order], Z[order], y[order], groups[order]
    starts = np.flatnonzero(np.r_[True, groups[1:] != groups[:-1]])
    return X, Z, y, groups, starts, levels


def _block(X, Z, groups, starts, fit: LmmFit, seed_seq, n_runs: int, terms):
    """Refit ``n_runs`` simulated responses; rows of fixef, SDs, sigma, chi2, pivot, singular."""
    rng = np.random.default_rng(seed_seq)
    beta = fit.fixef_array()
    theta = np.asarray(fit.theta)
    q = Z.shape[1]
    T = np.zeros((q, q))
    T[np.triu_indices(q)[::-1]] = theta
    sigma = fit.sigma
    J = starts.size
    mean = X @ beta
    base = crossproducts(X, Z, mean, groups)
    out = np.full((n_runs, len(beta) + q + 1 + (len(terms) - 1) + 1), np.nan)
    for r in range(n_runs):
        b = sigma * (rng.standard_normal((J, q)) @ T.T)
        y = mean + np.einsum("nk,nk->n", Z, b[groups]) + sigma * rng.standard_normal(mean.size)
        Zty = np.add.reduceat(Z * y[:, None], starts, axis=0)
        cp = with_response(base, Zty, X.T @ y, y @ y)
        try:
            th, _, _, _ = fit_crossproducts(
                cp, warm_start=theta, ftol_abs=BOOT_FTOL_ABS, xtol_abs=BOOT_XTOL_ABS
            )
            refit = summarise_fit(th, cp, response=fit.response, n_groups=J)
        except (np.linalg.LinAlgError, ValueError):
            continue
        b_star = refit.fixef_array()
        V = refit.vcov_array()
        chi2 = []
        for term in terms[1:]:
            L = hypothesis_matrix(term, V, terms)
            chi2.append(wald_chi2(L, b_star, V, beta0=beta))
        out[r] = np.concatenate([
            b_star, [refit.re_sd[t] for t in RANDOM_TERMS], [refit.sigma], chi2,
            [float(refit.singular)],
        ])
    return out


def parametric_bootstrap(
    frame: pd.DataFrame,
    fit: LmmFit,
    *,
    observed_chi2: dict,
    n_boot: int = 10_000,
    seed: int = 0,
    n_jobs: int = 2,
    group: str = "participant",
    progress: bool = True,
    return_samples: bool = False,
):
    """Parametric bootstrap of ``fit`` on ``frame``: percentile CIs and Wald p-values.

    Parameters
    ----------
    frame : DataFrame
        The model frame the fit came from (standardised ``gloss``, ``depth``, the response).
    fit : LmmFit
    observed_chi2 : dict of str to float
        The observed Type II chi-square of each term (`analysis.typeii.type2_wald`).
    n_boot : int
        Number of runs (default 10,000).
    seed : int
        Seed of the ``SeedSequence`` the runs' generators are spawned from (record it).
    n_jobs : int
        Parallel workers (joblib processes).
    progress : bool
        Show a tqdm progress bar (on stderr).
    return_samples : bool
        Also return the per-run array (columns: fixef, SDs, sigma, centred chi2, singular).

    Returns
    -------
    BootstrapResult, or (BootstrapResult, ndarray) with ``return_samples``.

    Raises
    ------
    ValueError
        If ``n_boot`` < 1 or a term of ``observed_chi2`` is unknown.
    """
    if n_boot < 1:
        raise ValueError(f"n_boot must be >= 1; got {n_boot}")
    terms = FIXED_TERMS
    unknown = set(observed_chi2) - set(terms[1:])
    if unknown:
        raise ValueError(f"unknown terms {sorted(unknown)} in observed_chi2; use {terms[1:]}")
    X, Z, _, groups, starts, _ = _sorted_problem(frame, fit.response, group)
    sizes = [BLOCK] * (n_boot // BLOCK) + ([n_boot % BLOCK] if n_boot % BLOCK else [])
    seeds = np.random.SeedSequence(seed).spawn(len(sizes))
    t0 = time.perf_counter()
    jobs = (delayed(_block)(X, Z, groups, starts, fit, s, n, terms) for s, n in zip(seeds, sizes))
    parts = []
    with tqdm(total=n_boot, desc=f"bootstrap {fit.response}", unit="refit",
              disable=not progress) as bar:
        runner = Parallel(n_jobs=n_jobs, return_as="generator")
        for part in runner(jobs):
            parts.append(part)
            bar.update(part.shape[0])
    seconds = time.perf_counter() - t0
    samples = np.vstack(parts)
    ok = np.all(np.isfinite(samples[:, : len(terms)]), axis=1)
    s = samples[ok]
    p = len(terms)
    q = len(RANDOM_TERMS)
    k = len(terms) - 1

    def ci(col):
        return [float(v) for v in np.percentile(s[:, col], [2.5, 97.5])]

    chi2 = s[:, p + q + 1: p + q + 1 + k]
    pvals = {}
    for i, term in enumerate(terms[1:]):
        if term in observed_chi2:
            exceed = int(np.sum(chi2[:, i] >= observed_chi2[term]))
            pvals[term] = (1 + exceed) / (s.shape[0] + 1)
    result = BootstrapResult(
        response=fit.response,
        n_boot=int(n_boot),
        n_ok=int(s.shape[0]),
        seed=int(seed),
        fixef_ci={t: ci(i) for i, t in enumerate(terms)},
        re_sd_ci={t: ci(p + i) for i, t in enumerate(RANDOM_TERMS)},
        sigma_ci=ci(p + q),
        chi2_p=pvals,
        singular_fraction=float(np.mean(s[:, p + q + 1 + k])),
        seconds=float(seconds),
        n_jobs=int(n_jobs),
    )
    return (result, s) if return_samples else result
