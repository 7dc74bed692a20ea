"""Parametric bootstrap likelihood-ratio test of each fixed-effect term (pbkrtest's PBmodcomp).

Halekoh & Hojsgaard (2014), "A Kenward-Roger approximation and parametric bootstrap methods for
tests in linear mixed models - the R package pbkrtest", J. Stat. Softw. 59(9), section 5. For a
term, the small model is the fitted one without the term's columns of X (as
``update(fit, . ~ . - term)`` for numeric predictors); both are fitted by ML, and
``LRT = deviance(small) - deviance(large)``. Responses are simulated from the *small* fitted model
(the null hypothesis), both models refitted to each, and the p-value is PBmodcomp's
``(1 + #{LRT* > LRT}) / (1 + N)``. Each simulated response is refitted with the y-free
cross-products reused (`analysis.pls.with_y`), in parallel blocks seeded from one
``SeedSequence``, as `analysis.bootstrap`.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from functools import partial

import numpy as np
import pandas as pd
from scipy import stats

from analysis.bootstrap import _run_blocks, refit, simulate_responses
from analysis.formula import build_model
from analysis.lmm import LmmFit, fit_problem, polish
from analysis.pls import make_problem, solve, theta_start, with_y

__all__ = ["LrtResult", "bootstrap_lrt"]


@dataclass(frozen=True)
class LrtResult:
    """One term's likelihood-ratio test, asymptotic and parametric bootstrap.

    Attributes
    ----------
    term : str
    lrt : float
        ``deviance(small) - deviance(large)`` (ML).
    df : int
        Columns of X the term has.
    p_chi2 : float
        Upper tail of chi-square(df) (the asymptotic test).
    p_boot : float
        ``(1 + #{LRT* > LRT}) / (1 + n_ok)`` (pbkrtest's PBtest).
    n_boot, n_ok, seed : int
    seconds : float
    """

    term: str
    lrt: float
    df: int
    p_chi2: float
    p_boot: float
    n_boot: int
    n_ok: int
    seed: int
    seconds: float

    def to_json(self) -> str:
        return json.dumps(asdict(self))


def _fit_ml(pr, starts):
    theta, _, _ = fit_problem(pr, starts=starts)
    theta = polish(pr, theta)
    return theta, solve(theta, pr)


def _block(large, small, null, seed_seq, n_runs: int):
    """LRT* of ``n_runs`` responses simulated from the small model's fit ``null``."""
    rng = np.random.default_rng(seed_seq)
    beta0, theta_small, sigma0, theta_large = null
    ys = simulate_responses(small, beta0, theta_small, sigma0, rng, n_runs)
    out = np.full(n_runs, np.nan)
    for r in range(n_runs):
        try:
            devs = []
            for pr, theta0 in ((large, theta_large), (small, theta_small)):
                devs.append(refit(with_y(pr, ys[r]), theta0)[1])
        except (np.linalg.LinAlgError, ValueError):
            continue
        out[r] = devs[1] - devs[0]
    return out[:, None]


def bootstrap_lrt(data: pd.DataFrame, fit: LmmFit, term: str, *, n_boot: int = 1000,
                  seed: int = 0, n_jobs: int = 2, progress: bool = True) -> LrtResult:
    """Parametric bootstrap likelihood-ratio test of one term, as ``pbkrtest::PBmodcomp``.

    Parameters
    ----------
    data : DataFrame
        The data the fit came from.
    fit : LmmFit
        The large model. A REML fit is compared by ML (a likelihood-ratio test of fixed
        effects needs ML), as PBmodcomp does.
    term : str
        One of ``fit.terms``.
    n_boot : int
        Simulated responses (PBmodcomp's ``nsim``).
    seed : int
        Seed of the ``SeedSequence`` (record it).
    n_jobs : int
    progress : bool

    Returns
    -------
    LrtResult

    Raises
    ------
    ValueError
        Unknown term or ``n_boot`` < 1.
    """
    if term not in fit.terms:
        raise ValueError(f"unknown term {term!r}; the model's terms are {fit.terms}")
    if n_boot < 1:
        raise ValueError(f"n_boot must be >= 1; got {n_boot}")
    spec = build_model(fit.formula, data)
    k = fit.terms.index(term)
    keep = [i for i, a in enumerate(fit.assign) if a != k]
    large = make_problem(spec, reml=False)
    small = make_problem(spec, reml=False, columns=keep)
    theta_large, sol_large = _fit_ml(large, [(theta_start(large), None),
                                            (np.asarray(fit.theta), 0.1)])
    theta_small, sol_small = _fit_ml(small, [(theta_start(small), None),
                                            (theta_large, 0.1)])
    lrt = sol_small.deviance - sol_large.deviance
    df = len(fit.assign) - len(keep)
    null = (sol_small.beta, theta_small, sol_small.sigma, theta_large)
    t0 = time.perf_counter()
    ref = _run_blocks(partial(_block, large, small, null), n_boot, seed, n_jobs,
                      f"LRT {term}", progress)[:, 0]
    seconds = time.perf_counter() - t0
    ref = ref[np.isfinite(ref)]
    return LrtResult(term=term, lrt=float(lrt), df=int(df),
                     p_chi2=float(stats.chi2.sf(max(lrt, 0.0), df)),
                     p_boot=float((1 + np.sum(ref > lrt)) / (1 + ref.size)),
                     n_boot=int(n_boot), n_ok=int(ref.size), seed=int(seed),
                     seconds=float(seconds))
