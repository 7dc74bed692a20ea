"""Linear mixed models by lme4's profiled deviance (maximum likelihood).

The model is the seed's ``y ~ gloss * depth + (1 + gloss + depth | participant)``: fixed effects
for the intercept, gloss, depth and their interaction; per participant a correlated random
intercept and random slopes for gloss and depth. It is fitted exactly as lme4 does (Bates,
Maechler, Bolker & Walker 2015, "Fitting linear mixed-effects models using lme4", J. Stat.
Softw. 67(1), section 3): the random effects are ``b = Lambda(theta) u`` with ``u ~ N(0, sigma^2
I)``; for a given relative covariance factor ``theta`` the fixed effects and ``sigma`` are profiled
out with a Cholesky factorisation, and the profiled ML deviance (their eq. 34) is minimised over
``theta`` alone by bound-constrained derivative-free optimisation (BOBYQA, as lme4's default
``nloptwrap``).

The deviance itself lives in `analysis.deviance`; this module holds the model frame, the
optimisation (two starts) and the fitted record.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import nlopt
import numpy as np
import pandas as pd

from analysis.deviance import (
    CrossProducts,
    _deviance_fast,
    _solve_pls,
    crossproducts,
    profiled_deviance,
    theta_lower_bounds,
    theta_to_T,
    with_response,
)
from studydesign import StudyDesign

__all__ = [
    "FIXED_TERMS",
    "RANDOM_TERMS",
    "CrossProducts",
    "LmmError",
    "LmmFit",
    "bc_power",
    "cold_start",
    "crossproducts",
    "fit_crossproducts",
    "fit_lmm",
    "model_matrices",
    "moment_start",
    "profiled_deviance",
    "standardise_predictors",
    "summarise_fit",
    "theta_lower_bounds",
    "with_response",
]

#: Fixed-effect coefficient names in lme4's order for ``gloss * depth``.
FIXED_TERMS = ("(Intercept)", "gloss", "depth", "gloss:depth")
#: Random-effect names per participant, in lme4's order for ``(1 + gloss + depth | participant)``.
RANDOM_TERMS = ("(Intercept)", "gloss", "depth")

# lme4's isSingular(): a diagonal element of a Cholesky block of theta below this is "singular".
SINGULAR_TOL = 1e-4


class LmmError(ValueError):
    """Bad input to a mixed model (missing columns, too few participants, non-finite values)."""


def bc_power(u, lam: float) -> np.ndarray:
    """Box-Cox power transform with the definition of R's ``car::bcPower``.

    ``(u**lam - 1) / lam``, or ``log(u)`` when ``|lam| <= 1e-6``; no geometric-mean scaling
    (``jacobian.adjusted = FALSE``, car's default).

    Parameters
    ----------
    u : array_like
        Strictly positive values (e.g. estimated depth in cm).
    lam : float
        Exponent (the design's ``analysis.depth_boxcox_lambda``).

    Returns
    -------
    ndarray
        Transformed values, same shape as ``u``.

    Raises
    ------
    LmmError
        If a value is not strictly positive and finite.
    """
    u = np.asarray(u, dtype=float)
    bad = ~np.isfinite(u) | (u <= 0)
    if bad.any():
        raise LmmError(
            f"Box-Cox needs strictly positive values; got {u[bad][:5].tolist()} "
            "(estimated depth must be > 0 cm; check the slider conversion)"
        )
    if abs(lam) <= 1e-6:
        return np.log(u)
    return (u**lam - 1.0) / lam


def standardise_predictors(frame: pd.DataFrame, design: StudyDesign) -> pd.DataFrame:
    """Add centred, scaled predictors ``gloss`` and ``depth`` from the true stimulus values.

    The seed codes its predictors centred. We also divide by the standard deviation: a Type II
    Wald chi-square does not depend on the predictors' scale (only on their centring, through the
    interaction), while lme4 fitted on raw % and cm units warned of non-convergence in most fits
    and its chi-square moved by up to 62 %. Centre and scale come from the design's rendered
    levels (the balanced stimulus set), not from the data, so that one coefficient means the same
    in every data set, incomplete ones included.

    Parameters
    ----------
    frame : DataFrame
        With ``true_gloss_pct`` (%) and ``true_depth_cm`` (cm).
    design : StudyDesign

    Returns
    -------
    DataFrame
        A copy with columns ``gloss`` and ``depth`` (dimensionless, mean 0 and SD 1 over the
        design's rendered levels).
    """
    missing = [c for c in ("true_gloss_pct", "true_depth_cm") if c not in frame.columns]
    if missing:
        raise LmmError(f"columns {missing} missing; load sessions with analysis.load_sessions")
    out = frame.copy()
    gloss_levels = np.asarray(design.gloss.rendered_pct, dtype=float)
    depth_levels = np.asarray(design.depth.rendered_cm, dtype=float)
    gloss_pct = frame["true_gloss_pct"].to_numpy(float)
    depth_cm = frame["true_depth_cm"].to_numpy(float)
    out["gloss"] = (gloss_pct - gloss_levels.mean()) / gloss_levels.std()
    out["depth"] = (depth_cm - depth_levels.mean()) / depth_levels.std()
    return out


def model_matrices(frame: pd.DataFrame, response: str, group: str = "participant"):
    """Fixed design X, random design Z, response y and group index for the seed's model.

    Parameters
    ----------
    frame : DataFrame
        With columns ``gloss``, ``depth`` (standardised), ``response`` and ``group``.
    response : str
        Column of the response.
    group : str
        Column of the grouping factor.

    Returns
    -------
    X : ndarray, shape (n, 4)
        Columns `FIXED_TERMS`.
    Z : ndarray, shape (n, 3)
        Columns `RANDOM_TERMS` (the per-observation rows of each participant's block).
    y : ndarray, shape (n,)
    groups : ndarray of int, shape (n,)
        Index of each row's group in ``levels``.
    levels : ndarray
        Group labels, sorted.
    """
    missing = [c for c in ("gloss", "depth", response, group) if c not in frame.columns]
    if missing:
        raise LmmError(f"columns {missing} missing from the model frame")
    g = frame["gloss"].to_numpy(float)
    d = frame["depth"].to_numpy(float)
    y = frame[response].to_numpy(float)
    if not (np.isfinite(g).all() and np.isfinite(d).all() and np.isfinite(y).all()):
        raise LmmError(f"non-finite gloss, depth or {response!r}; drop or fix those rows first")
    levels, groups = np.unique(frame[group].astype(str).to_numpy(), return_inverse=True)
    if levels.size < 2:
        raise LmmError(f"a mixed model needs >= 2 {group}s; got {levels.tolist()}")
    one = np.ones_like(g)
    X = np.column_stack([one, g, d, g * d])
    Z = np.column_stack([one, g, d])
    if np.linalg.matrix_rank(X) < X.shape[1]:
        raise LmmError(
            "the fixed effects cannot be estimated: the data need at least two gloss and two "
            f"depth levels (got gloss {np.unique(g).size}, depth {np.unique(d).size} distinct)"
        )
    return X, Z, y, groups, levels


@dataclass(frozen=True)
class LmmFit:
    """A fitted linear mixed model (ML), in lme4's terms.

    Attributes
    ----------
    response : str
    fixef : dict of str to float
        Fixed effects, keyed by `FIXED_TERMS` (per SD of the standardised predictors).
    se : dict of str to float
        Their standard errors (sqrt of the diagonal of ``vcov``).
    vcov : list of list of float
        Fixed-effect covariance, ``sigma^2 (R_X' R_X)^-1`` (lme4's ``vcov``).
    theta : list of float
        Relative covariance factor at the optimum (lme4's ``getME(fit, "theta")``).
    sigma : float
        Residual SD (ML: ``sqrt(r^2 / n)``).
    re_sd : dict of str to float
        Random-effect SDs per participant, keyed by `RANDOM_TERMS`.
    re_cor : dict of str to float
        Random-effect correlations, keyed ``"a,b"``.
    loglik, deviance : float
    n_obs, n_groups : int
    singular : bool
        A diagonal element of theta below 1e-4 (lme4's ``isSingular``).
    n_evals : int
        Deviance evaluations the optimiser used (both starts).
    start : str
        Which start gave the optimum: "warm" or "cold".
    """

    response: str
    fixef: dict
    se: dict
    vcov: list
    theta: list
    sigma: float
    re_sd: dict
    re_cor: dict
    loglik: float
    deviance: float
    n_obs: int
    n_groups: int
    singular: bool
    n_evals: int
    start: str

    def fixef_array(self) -> np.ndarray:
        return np.array([self.fixef[t] for t in FIXED_TERMS])

    def vcov_array(self) -> np.ndarray:
        return np.array(self.vcov)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1)

    @classmethod
    def from_json(cls, text: str) -> LmmFit:
        return cls(**json.loads(text))


def _optimise(cp: CrossProducts, start, step, ftol_abs, xtol_abs, maxeval):
    q = cp.ZtZ.shape[1]
    k = q * (q + 1) // 2
    opt = nlopt.opt(nlopt.LN_BOBYQA, k)
    opt.set_lower_bounds(theta_lower_bounds(q))
    n_evals = [0]

    fast = q == 3

    def objective(x, grad):
        n_evals[0] += 1
        if fast:
            return _deviance_fast(x.tolist(), cp)
        return profiled_deviance(x, cp)

    opt.set_min_objective(objective)
    opt.set_ftol_abs(ftol_abs)
    opt.set_xtol_abs(xtol_abs)
    opt.set_maxeval(maxeval)
    if step is not None:
        opt.set_initial_step(step)
    x0 = np.maximum(np.asarray(start, float), theta_lower_bounds(q))
    try:
        x = opt.optimize(x0)
        f = opt.last_optimum_value()
    except nlopt.RoundoffLimited:
        # BOBYQA stops on round-off when the deviance is flat to machine precision (an optimum
        # on the boundary); the best point seen so far is the answer.
        x = x0
        f = profiled_deviance(x0, cp)
    return np.asarray(x), float(f), n_evals[0]


def cold_start(q: int = 3) -> np.ndarray:
    """lme4's starting value: theta of the identity (1 on the diagonal, 0 elsewhere)."""
    return np.array([1.0 if i == j else 0.0 for j in range(q) for i in range(j, q)])


def moment_start(X, Z, y, groups) -> np.ndarray:
    """A warm start for theta from per-group least squares (method of moments).

    Each group's coefficients on ``X`` are fitted alone; the covariance of their ``Z`` part
    across groups, relative to the pooled residual variance, approximates ``T T'``. Its
    eigenvalues are clipped at 0 before the Cholesky factor is taken.
    """
    J = int(np.max(groups)) + 1
    q = Z.shape[1]
    coefs, rss, dof = [], 0.0, 0
    for j in range(J):
        rows = groups == j
        b, _, rank, _ = np.linalg.lstsq(X[rows], y[rows], rcond=None)
        coefs.append(b[:q])
        r = y[rows] - X[rows] @ b
        rss += float(r @ r)
        dof += int(rows.sum()) - rank
    sigma2 = rss / max(dof, 1)
    S = np.atleast_2d(np.cov(np.array(coefs).T)) / max(sigma2, 1e-300)
    w, V = np.linalg.eigh(S)
    S = (V * np.maximum(w, 0.0)) @ V.T + 1e-8 * np.eye(q)
    T = np.linalg.cholesky(S)
    return T[np.triu_indices(q)[::-1]]


def fit_crossproducts(
    cp: CrossProducts,
    *,
    warm_start=None,
    ftol_abs: float = 1e-12,
    xtol_abs: float = 1e-10,
    maxeval: int = 100_000,
):
    """Minimise the profiled deviance; the better of a warm and a cold start.

    Parameters
    ----------
    cp : CrossProducts
    warm_start : array_like or None
        A theta near the optimum (e.g. the original fit's, in a bootstrap); started with an
        initial step of 0.1. The cold start is lme4's (identity) with nlopt's default step. A
        single cold start missed the optimum in up to 7 % of bootstrap samples while planning.
    ftol_abs, xtol_abs : float
        nlopt's stopping tolerances on the deviance and on theta (lme4's defaults are 1e-8;
        tighter ones let two implementations agree to 1e-5 and better).
    maxeval : int

    Returns
    -------
    theta : ndarray
    deviance : float
    n_evals : int
    start : str
        "warm" or "cold".
    """
    q = cp.ZtZ.shape[1]
    best = None
    n_total = 0
    starts = [("cold", cold_start(q), None)]
    if warm_start is not None:
        starts.insert(0, ("warm", np.asarray(warm_start, float), 0.1))
    for name, start, step in starts:
        x, f, n = _optimise(cp, start, step, ftol_abs, xtol_abs, maxeval)
        n_total += n
        if best is None or f < best[1]:
            best = (x, f, name)
    return best[0], best[1], n_total, best[2]


def summarise_fit(theta, cp: CrossProducts, *, response: str, n_groups: int, n_evals=0,
                  start="cold") -> LmmFit:
    """Fixed effects, SEs, variance components and log-likelihood at theta."""
    theta = np.asarray(theta, float)
    q = cp.ZtZ.shape[1]
    ldL2, RX, cb, pwrss = _solve_pls(theta, cp)
    n = cp.n
    deviance = ldL2 + n * (1.0 + math.log(2.0 * math.pi * pwrss / n))
    beta = np.linalg.solve(RX.T, cb)
    sigma2 = pwrss / n
    RXinv = np.linalg.inv(RX)
    vcov = sigma2 * (RXinv.T @ RXinv)
    T = theta_to_T(theta, q)
    cov_b = sigma2 * (T @ T.T)
    sd = np.sqrt(np.diag(cov_b))
    cor = {}
    for i in range(q):
        for j in range(i + 1, q):
            denom = sd[i] * sd[j]
            cor[f"{RANDOM_TERMS[i]},{RANDOM_TERMS[j]}"] = (
                float(cov_b[i, j] / denom) if denom > 0 else float("nan")
            )
    diag = np.array([theta[k] for k, (i, j) in enumerate(
        (i, j) for j in range(q) for i in range(j, q)) if i == j])
    return LmmFit(
        response=response,
        fixef={t: float(b) for t, b in zip(FIXED_TERMS, beta)},
        se={t: float(s) for t, s in zip(FIXED_TERMS, np.sqrt(np.diag(vcov)))},
        vcov=vcov.tolist(),
        theta=theta.tolist(),
        sigma=float(math.sqrt(sigma2)),
        re_sd={t: float(s) for t, s in zip(RANDOM_TERMS, sd)},
        re_cor=cor,
        loglik=float(-deviance / 2.0),
        deviance=float(deviance),
        n_obs=int(n),
        n_groups=int(n_groups),
        singular=bool(np.min(diag) < SINGULAR_TOL),
        n_evals=int(n_evals),
        start=start,
    )


def fit_lmm(
    frame: pd.DataFrame,
    *,
    response: str,
    group: str = "participant",
    ftol_abs: float = 1e-12,
    xtol_abs: float = 1e-10,
) -> LmmFit:
    """Fit ``response ~ gloss * depth + (1 + gloss + depth | group)`` by ML, as lme4.

    Parameters
    ----------
    frame : DataFrame
        Standardised predictors ``gloss`` and ``depth`` (see `standardise_predictors`), the
        response column and the group column.
    response : str
        E.g. ``"gloss_match_pct"`` or ``"depth_match_bc"``.
    group : str
    ftol_abs, xtol_abs : float
        Optimiser tolerances (see `fit_crossproducts`).

    Returns
    -------
    LmmFit

    Raises
    ------
    LmmError
        Missing columns, non-finite values or fewer than two groups.
    """
    X, Z, y, groups, levels = model_matrices(frame, response, group)
    cp = crossproducts(X, Z, y, groups)
    theta, _, n_evals, start = fit_crossproducts(
        cp, warm_start=moment_start(X, Z, y, groups), ftol_abs=ftol_abs, xtol_abs=xtol_abs
    )
    return summarise_fit(theta, cp, response=response, n_groups=levels.size, n_evals=n_evals,
                         start=start)
