"""Parametric bootstrap of a fitted mixed model: 95 % CIs and p-values for the Type II tests.

Like lme4's ``bootMer(type = "parametric", use.u = FALSE)``: each run simulates a new response
from the fitted model (new random effects ``b ~ N(0, sigma^2 T_k T_k')`` per level of each
grouping factor and new residuals ``N(0, sigma^2)``), refits, and records the fixed effects, the
random-effect SDs and the Type II Wald statistics. Only the cross-products with y change between
runs (X, Z and the grouping are fixed), so a refit reuses every y-free product; each refit
starts at the original theta (initial step 0.1), as bootMer, and when that ends singular also
from lme4's start, keeping the better (`refit`).

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
from functools import partial

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from tqdm.auto import tqdm

from analysis.formula import build_model
from analysis.lmm import SINGULAR_TOL, LmmFit, fit_problem
from analysis.pls import make_problem, solve, term_factor, theta_lower, theta_start, with_y
from analysis.typeii import hypothesis_matrix, wald_chi2

__all__ = ["BootstrapResult", "parametric_bootstrap", "re_labels", "refit", "simulate_responses"]

BLOCK = 100
# lme4's default nloptwrap tolerances, the ones bootMer refits with.
BOOT_FTOL_ABS = 1e-8
BOOT_XTOL_ABS = 1e-8
# Diagonal of theta from which a singular gradient refit is restarted (`refit`).
NUDGE = 0.05


@dataclass(frozen=True)
class BootstrapResult:
    """Percentile CIs and bootstrap p-values of one model.

    Attributes
    ----------
    response, formula : str
    n_boot : int
        Runs requested.
    n_ok : int
        Runs whose refit succeeded (the others are left out and counted).
    seed : int
    fixef_ci : dict of str to [float, float]
        95 % percentile CI of each fixed effect.
    re_sd_ci : dict of str to [float, float]
        95 % percentile CI of each random-effect SD, keyed ``"group: coefficient"``.
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
    formula: str
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


def re_labels(fit: LmmFit) -> list[str]:
    """``"group: coefficient"`` of every random-effect SD, in lme4's order."""
    return [f"{r['group']}: {n}" for r in fit.random for n in r["names"]]


def simulate_responses(pr, beta, theta, sigma, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` responses from the fitted model, as lme4's ``simulate(use.u = FALSE)``.

    ``y = X beta + Z Lambda(theta) u + e`` with ``u ~ N(0, sigma^2 I)`` and ``e ~ N(0,
    sigma^2 I)``; returns shape (n, n_obs).
    """
    theta = np.asarray(theta, float)
    mean = pr.X @ np.asarray(beta, float)
    out = np.empty((n, mean.size))
    for r in range(n):
        b = []
        for k, (q, J) in enumerate(zip(pr.q_sizes, pr.n_levels)):
            T = term_factor(theta, pr.q_sizes, k)
            b.append((sigma * rng.standard_normal((J, q)) @ T.T).ravel())
        out[r] = mean + pr.Z @ np.concatenate(b) + sigma * rng.standard_normal(mean.size)
    return out


def refit(prb, theta0):
    """Refit a simulated response: from the original theta, and from lme4's start if singular.

    ``bootMer`` refits from the original theta only. On the source study's model and the
    crossed one (800 simulated responses, ``bench/analysis_bootstrap_vs_bootmer.py``'s data)
    that start missed the optimum by more than 0.01 deviance units 4 times (by up to 1.9), each
    time at a singular point; lme4's start (identity) found the better optimum. It is tried only
    there (about a third of refits).

    For an ML model of one grouping factor with three random coefficients (the source study's)
    the deviance's analytic gradient (`analysis.deviance.deviance_gradient`) is minimised by
    SLSQP instead of BOBYQA, with lme4's tolerances, and a refit still singular after both
    starts is tried once more from its optimum with the zero diagonal elements of theta raised
    to `NUDGE` (SLSQP can stop at a stationary point on the boundary that BOBYQA's
    derivative-free steps pass by). Measured on 150 simulated responses of each of the six data
    sets of tests/analysis/lmmdata.CASES (fitted by the source model): never worse than
    bootMer's procedure (BOBYQA from the original theta) by more than 1e-6 deviance units;
    against the previous BOBYQA from both starts, lower by more than 1e-6 in 47 of 900 refits
    (where BOBYQA stopped on its tolerance) and higher in 2 (by 0.09 and 0.19, both on the
    perfectly correlated singular data set); 2.4-3.7x faster per refit.

    Returns
    -------
    theta : ndarray
    deviance : float
    """
    gradient = prb.cp is not None
    th, dev, _ = fit_problem(prb, starts=[(theta0, 0.1)], ftol_abs=BOOT_FTOL_ABS,
                             xtol_abs=BOOT_XTOL_ABS, gradient=gradient)
    lower = theta_lower(prb)
    if np.any(th[lower == 0] < SINGULAR_TOL):
        th2, dev2, _ = fit_problem(prb, starts=[(theta_start(prb), None)],
                                   ftol_abs=BOOT_FTOL_ABS, xtol_abs=BOOT_XTOL_ABS,
                                   gradient=gradient)
        if dev2 < dev:
            th, dev = th2, dev2
        if gradient and np.any(th[lower == 0] < SINGULAR_TOL):
            nudged = th.copy()
            nudged[lower == 0] = np.maximum(nudged[lower == 0], NUDGE)
            th3, dev3, _ = fit_problem(prb, starts=[(nudged, None)], ftol_abs=BOOT_FTOL_ABS,
                                       xtol_abs=BOOT_XTOL_ABS, gradient=True)
            if dev3 < dev:
                th, dev = th3, dev3
    return th, dev


def _refit(pr, y, theta0):
    prb = with_y(pr, y)
    th, _ = refit(prb, theta0)
    return th, solve(th, prb)


def _block(pr, fit: LmmFit, seed_seq, n_runs: int):
    """Refit ``n_runs`` simulated responses; rows of fixef, SDs, sigma, chi2, singular."""
    rng = np.random.default_rng(seed_seq)
    beta = fit.fixef_array()
    theta0 = np.asarray(fit.theta)
    n_sd = sum(pr.q_sizes)
    out = np.full((n_runs, beta.size + n_sd + 1 + len(fit.terms) + 1), np.nan)
    ys = simulate_responses(pr, beta, theta0, fit.sigma, rng, n_runs)
    for r in range(n_runs):
        try:
            th, sol = _refit(pr, ys[r], theta0)
        except (np.linalg.LinAlgError, ValueError):
            continue
        sds, diag = [], []
        for k in range(len(pr.q_sizes)):
            T = term_factor(th, pr.q_sizes, k)
            sds.extend(sol.sigma * np.sqrt(np.sum(T * T, axis=1)))
            diag.extend(np.diag(T))
        chi2 = [wald_chi2(hypothesis_matrix(t, sol.vcov, terms=fit.terms, assign=fit.assign,
                                            term_factors=fit.term_factors),
                          sol.beta, sol.vcov, beta0=beta) for t in fit.terms]
        out[r] = np.concatenate([sol.beta, sds, [sol.sigma], chi2,
                                 [float(min(diag) < SINGULAR_TOL)]])
    return out


def _run_blocks(worker, n_boot: int, seed: int, n_jobs: int, desc: str, progress: bool):
    sizes = [BLOCK] * (n_boot // BLOCK) + ([n_boot % BLOCK] if n_boot % BLOCK else [])
    seeds = np.random.SeedSequence(seed).spawn(len(sizes))
    parts = []
    with tqdm(total=n_boot, desc=desc, unit="refit", disable=not progress) as bar:
        runner = Parallel(n_jobs=n_jobs, return_as="generator")
        for part in runner(delayed(worker)(s, n) for s, n in zip(seeds, sizes)):
            parts.append(part)
            bar.update(part.shape[0])
    return np.vstack(parts)


def parametric_bootstrap(
    data: pd.DataFrame,
    fit: LmmFit,
    *,
    observed_chi2: dict,
    n_boot: int = 10_000,
    seed: int = 0,
    n_jobs: int = 2,
    progress: bool = True,
    return_samples: bool = False,
):
    """Parametric bootstrap of ``fit`` on ``data``: percentile CIs and Wald p-values.

    Parameters
    ----------
    data : DataFrame
        The data the fit came from (its formula is rebuilt on them).
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
    unknown = set(observed_chi2) - set(fit.terms)
    if unknown:
        raise ValueError(f"unknown terms {sorted(unknown)} in observed_chi2; use {fit.terms}")
    pr = make_problem(build_model(fit.formula, data), reml=fit.reml)
    t0 = time.perf_counter()
    samples = _run_blocks(partial(_block, pr, fit), n_boot, seed, n_jobs,
                          f"bootstrap {fit.response}", progress)
    seconds = time.perf_counter() - t0
    names = list(fit.fixef)
    labels = re_labels(fit)
    p, q, k = len(names), len(labels), len(fit.terms)
    ok = np.all(np.isfinite(samples[:, :p]), axis=1)
    s = samples[ok]

    def ci(col):
        return [float(v) for v in np.percentile(s[:, col], [2.5, 97.5])]

    chi2 = s[:, p + q + 1: p + q + 1 + k]
    pvals = {}
    for i, term in enumerate(fit.terms):
        if term in observed_chi2:
            exceed = int(np.sum(chi2[:, i] >= observed_chi2[term]))
            pvals[term] = (1 + exceed) / (s.shape[0] + 1)
    result = BootstrapResult(
        response=fit.response,
        formula=fit.formula,
        n_boot=int(n_boot),
        n_ok=int(s.shape[0]),
        seed=int(seed),
        fixef_ci={t: ci(i) for i, t in enumerate(names)},
        re_sd_ci={t: ci(p + i) for i, t in enumerate(labels)},
        sigma_ci=ci(p + q),
        chi2_p=pvals,
        singular_fraction=float(np.mean(s[:, p + q + 1 + k])),
        seconds=float(seconds),
        n_jobs=int(n_jobs),
    )
    return (result, s) if return_samples else result
