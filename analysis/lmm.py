"""Linear mixed models by formula, fitted exactly as lme4 does (ML or REML).

``fit("y ~ gloss * depth + (1 + gloss + depth | participant) + (1 | stimulus_id)", data)``
takes lme4's formula syntax (`analysis.formula`) and minimises lme4's profiled deviance or REML
criterion (Bates, Maechler, Bolker & Walker 2015, "Fitting linear mixed-effects models using
lme4", J. Stat. Softw. 67(1), section 3; the deviance is in `analysis.pls`) over the relative
covariance factor theta alone, by bound-constrained derivative-free optimisation (BOBYQA, lme4's
default ``nloptwrap``), from lme4's start (every factor the identity) and, for one grouping
factor whose random coefficients are also fixed ones, from a method-of-moments start; the better
optimum is kept. The record, `LmmFit`, holds what ``summary(lmer(...))`` prints and round-trips
through JSON.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import nlopt
import numpy as np
import pandas as pd

from analysis.deviance import deviance_gradient
from analysis.formula import LmmError, ModelSpec, build_model
from analysis.pls import (
    Problem,
    deviance,
    make_problem,
    solve,
    term_factor,
    theta_lower,
    theta_start,
)
from studydesign import StudyDesign

__all__ = [
    "LmmError",
    "LmmFit",
    "bc_power",
    "fit",
    "fit_problem",
    "moment_start",
    "polish",
    "standardise_predictors",
    "summarise",
]

# lme4's isSingular(): a diagonal element of a term's factor below this is "singular".
SINGULAR_TOL = 1e-4


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

    The source study codes its predictors centred. We also divide by the standard deviation: a
    Type II Wald chi-square does not depend on the predictors' scale (only on their centring,
    through the interaction), while lme4 fitted on raw % and cm units warned of non-convergence in most fits
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


@dataclass(frozen=True)
class LmmFit:
    """A fitted linear mixed model, in lme4's terms.

    Attributes
    ----------
    formula, response : str
    reml : bool
    fixef : dict of str to float
        Fixed effects, R's coefficient names, in the design's order.
    se : dict of str to float
        Their standard errors.
    vcov : list of list of float
        ``sigma^2 (R_X' R_X)^-1`` (lme4's ``vcov``).
    terms : list of str
        Fixed-effect terms without the intercept (``"gloss"``, ``"gloss:depth"``).
    assign : list of int
        Per coefficient, its index into ``terms`` (-1: intercept), as R's ``assign``.
    term_factors : list of list of str
        Per term, the variables it is made of.
    theta : list of float
        lme4's ``getME(fit, "theta")``.
    sigma : float
        Residual SD.
    random : list of dict
        Per random term (lme4's order): ``group``, ``names`` (its coefficients), ``n_levels``,
        ``sd`` (name -> SD) and ``cor`` ("a,b" -> correlation), as ``VarCorr``.
    loglik : float
        ``logLik`` (for REML fits the REML log-likelihood, as lme4).
    deviance : float
        ``-2 loglik``: the ML deviance, or the REML criterion (lme4's ``REMLcrit``).
    n_obs, n_dropped : int
        Observations used, and rows left out for missing values.
    singular : bool
        lme4's ``isSingular``: a diagonal element of theta below 1e-4.
    n_evals : int
        Deviance evaluations the optimiser used.
    """

    formula: str
    response: str
    reml: bool
    fixef: dict
    se: dict
    vcov: list
    terms: list
    assign: list
    term_factors: list
    theta: list
    sigma: float
    random: list
    loglik: float
    deviance: float
    n_obs: int
    n_dropped: int
    singular: bool
    n_evals: int

    def fixef_array(self) -> np.ndarray:
        return np.array(list(self.fixef.values()))

    def vcov_array(self) -> np.ndarray:
        return np.array(self.vcov)

    def n_groups(self) -> dict:
        """Levels of each grouping factor (lme4's ``ngrps``)."""
        return {r["group"]: r["n_levels"] for r in self.random}

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1)

    @classmethod
    def from_json(cls, text: str) -> LmmFit:
        return cls(**json.loads(text))


def _optimise(pr: Problem, start, step, ftol_abs, xtol_abs, maxeval):
    lower = theta_lower(pr)
    opt = nlopt.opt(nlopt.LN_BOBYQA, lower.size)
    opt.set_lower_bounds(lower)
    n_evals = [0]

    def objective(x, grad):
        n_evals[0] += 1
        return deviance(x, pr)

    opt.set_min_objective(objective)
    opt.set_ftol_abs(ftol_abs)
    opt.set_xtol_abs(xtol_abs)
    opt.set_maxeval(maxeval)
    if step is not None:
        opt.set_initial_step(step)
    x0 = np.maximum(np.asarray(start, float), lower)
    try:
        x = opt.optimize(x0)
        f = opt.last_optimum_value()
    except nlopt.RoundoffLimited:
        # BOBYQA stops on round-off when the deviance is flat to machine precision (an optimum
        # on the boundary); the start is then as good as any point it saw.
        x, f = x0, deviance(x0, pr)
    return np.asarray(x), float(f), n_evals[0]


# SLSQP's first step is the negative gradient (its Hessian estimate starts as the identity). The
# deviance's gradient in theta is of order 10-1000, so that step would leave the region of
# plausible thetas (and reach ones where the Schur complement is singular to rounding);
# minimising deviance / 100 makes it of order 0.1-10. Chosen on 150 simulated refits of each of
# six data sets (tests/analysis/lmmdata.CASES) with `analysis.bootstrap.refit`: with 1 a first
# step reached a singular Schur complement; with 1000 the refit ended worse than bootMer's
# procedure (BOBYQA from the original theta) in one refit of each of two data sets, with 100 in
# none.
GRADIENT_SCALE = 100.0


def _optimise_gradient(pr: Problem, start, ftol_abs, xtol_abs, maxeval):
    """SLSQP (nlopt's LD_SLSQP) on the deviance with its analytic gradient (ML, q = 3).

    Keeps the best point it evaluated, which is what it returns if nlopt stops on round-off.
    """
    lower = theta_lower(pr)
    opt = nlopt.opt(nlopt.LD_SLSQP, lower.size)
    opt.set_lower_bounds(lower)
    cp = pr.cp
    best = [math.inf, None]
    n_evals = [0]

    scale = 1.0 / GRADIENT_SCALE

    def objective(x, grad):
        n_evals[0] += 1
        f, g = deviance_gradient(x.tolist(), cp)
        if grad.size:
            grad[:] = g
            grad *= scale
        if f < best[0]:
            best[0], best[1] = f, x.copy()
        return f * scale

    opt.set_min_objective(objective)
    opt.set_ftol_abs(ftol_abs * scale)
    opt.set_xtol_abs(xtol_abs)
    opt.set_maxeval(maxeval)
    x0 = np.maximum(np.asarray(start, float), lower)
    try:
        opt.optimize(x0)
    except nlopt.RoundoffLimited:
        pass
    if best[1] is None:
        return x0, deviance(x0, pr), n_evals[0]
    return best[1], float(best[0]), n_evals[0]


def fit_problem(pr: Problem, *, starts, ftol_abs: float = 1e-12, xtol_abs: float = 1e-10,
                maxeval: int = 100_000, gradient: bool = False):
    """Minimise the deviance from each start; the best optimum.

    Parameters
    ----------
    pr : Problem
    starts : sequence of (array_like, float or None)
        Start thetas with an initial step (None: nlopt's default, what lme4 uses).
    ftol_abs, xtol_abs : float
        nlopt's stopping tolerances on the deviance and on theta (lme4's defaults are 1e-8;
        tighter ones let two implementations agree to 1e-6 and better).
    maxeval : int
    gradient : bool
        Minimise with SLSQP and the analytic gradient (`analysis.deviance.deviance_gradient`)
        instead of BOBYQA; only for ML fits of one grouping factor with three random
        coefficients (``pr.cp`` set). The steps are then ignored, but for a fall-back to
        BOBYQA if a probe of SLSQP's fails.

    Returns
    -------
    theta : ndarray
    deviance : float
    n_evals : int
    """
    if gradient and pr.cp is None:
        raise ValueError("gradient=True needs an ML model of one grouping factor with three "
                         "random coefficients (pr.cp); use the default BOBYQA")
    best, n_total = None, 0
    for start, step in starts:
        if gradient:
            try:
                x, f, n = _optimise_gradient(pr, start, ftol_abs, xtol_abs, maxeval)
            except (ValueError, ZeroDivisionError):
                # A probe where the fixed effects' Schur complement is singular to rounding:
                # BOBYQA's smaller steps from the same start.
                x, f, n = _optimise(pr, start, step if step is not None else 0.1, ftol_abs,
                                    xtol_abs, maxeval)
        else:
            x, f, n = _optimise(pr, start, step, ftol_abs, xtol_abs, maxeval)
        n_total += n
        if best is None or f < best[1]:
            best = (x, f)
    return best[0], best[1], n_total


def _derivatives(f, x, free, h):
    """Central-difference gradient and Hessian of ``f`` at ``x`` in the coordinates ``free``."""
    k = len(free)
    f0 = f(x)
    g, H = np.zeros(k), np.zeros((k, k))
    step = [h * max(abs(x[i]), 0.1) for i in free]

    def at(moves):
        y = x.copy()
        for i, d in moves:
            y[free[i]] += d
        return f(y)

    for i in range(k):
        fp, fm = at([(i, step[i])]), at([(i, -step[i])])
        g[i] = (fp - fm) / (2 * step[i])
        H[i, i] = (fp - 2 * f0 + fm) / step[i] ** 2
        for j in range(i):
            H[i, j] = H[j, i] = (at([(i, step[i]), (j, step[j])]) - at([(i, step[i]), (j, -step[j])])
                                 - at([(i, -step[i]), (j, step[j])])
                                 + at([(i, -step[i]), (j, -step[j])])) / (4 * step[i] * step[j])
    return f0, g, H


def polish(pr: Problem, theta, *, steps: int = 4) -> np.ndarray:
    """Newton steps on the deviance from a BOBYQA optimum, off the bounds only.

    BOBYQA stops where the deviance changes by less than its tolerance, which on a flat
    likelihood (crossed designs, REML) leaves theta uncertain in the 6th digit, and with it the
    fixed-effect covariance. A few Newton steps with central-difference derivatives (relative
    step 1e-4) bring theta to where the gradient vanishes, to about 1e-8. The deviance is then
    flat to its rounding error (~1e-13 relative), so a step is kept if the Hessian is positive
    definite and the deviance does not rise by more than 1e-10 relative; elements on their bound
    (a zero variance) stay there.
    """
    x = np.asarray(theta, float).copy()
    lower = theta_lower(pr)
    free = [i for i in range(x.size) if not (lower[i] == 0.0 and x[i] < 1e-6)]
    if not free:
        return x

    def f(y):
        return deviance(y, pr)

    for _ in range(steps):
        f0, g, H = _derivatives(f, x, free, 1e-4)
        try:
            delta = np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(delta)) or np.any(np.linalg.eigvalsh(H) <= 0):
            break
        y = x.copy()
        y[free] -= delta
        y = np.maximum(y, lower)
        if f(y) > f0 + 1e-10 * abs(f0):
            break
        x = y
        if np.max(np.abs(delta)) < 1e-10 * max(1.0, float(np.max(np.abs(x)))):
            break
    return x


def moment_start(spec: ModelSpec) -> np.ndarray | None:
    """A warm start for theta from per-group least squares (method of moments).

    Only for one grouping factor whose random coefficients are all fixed coefficients too (as
    ``y ~ gloss * depth + (1 + gloss + depth | participant)``); else None. Each group's
    coefficients on X are fitted alone; the covariance of the random ones across groups,
    relative to the pooled residual variance, approximates ``T T'``; its eigenvalues are clipped
    at 0 before the Cholesky factor is taken.
    """
    if len(spec.re_groups) != 1:
        return None
    names = list(spec.fixed.names)
    if any(n not in names for n in spec.re_names[0]):
        return None
    cols = [names.index(n) for n in spec.re_names[0]]
    X, y, groups = spec.fixed.X, spec.y, spec.re_index[0]
    coefs, rss, dof = [], 0.0, 0
    for j in range(int(groups.max()) + 1):
        rows = groups == j
        b, _, rank, _ = np.linalg.lstsq(X[rows], y[rows], rcond=None)
        coefs.append(b[cols])
        r = y[rows] - X[rows] @ b
        rss += float(r @ r)
        dof += int(rows.sum()) - rank
    q = len(cols)
    sigma2 = rss / max(dof, 1)
    S = np.atleast_2d(np.cov(np.array(coefs).T)) / max(sigma2, 1e-300)
    w, V = np.linalg.eigh(S)
    S = (V * np.maximum(w, 0.0)) @ V.T + 1e-8 * np.eye(q)
    T = np.linalg.cholesky(S)
    return T[np.triu_indices(q)[::-1]]


def summarise(theta, pr: Problem, spec: ModelSpec, *, n_evals: int = 0) -> LmmFit:
    """The fitted record at ``theta``: fixed effects, VarCorr, log-likelihood."""
    theta = np.asarray(theta, float)
    sol = solve(theta, pr)
    names = spec.fixed.names
    se = np.sqrt(np.diag(sol.vcov))
    random, diag = [], []
    for k, (group, rnames) in enumerate(zip(spec.re_groups, spec.re_names)):
        T = term_factor(theta, pr.q_sizes, k)
        diag.extend(np.diag(T).tolist())
        cov = sol.sigma**2 * (T @ T.T)
        sd = np.sqrt(np.diag(cov))
        cor = {}
        for i in range(len(rnames)):
            for j in range(i + 1, len(rnames)):
                den = sd[i] * sd[j]
                cor[f"{rnames[i]},{rnames[j]}"] = float(cov[i, j] / den) if den > 0 else math.nan
        random.append({"group": group, "names": list(rnames), "n_levels": int(pr.n_levels[k]),
                       "sd": {n: float(v) for n, v in zip(rnames, sd)}, "cor": cor})
    return LmmFit(
        formula=spec.formula, response=spec.response, reml=pr.reml,
        fixef={n: float(b) for n, b in zip(names, sol.beta)},
        se={n: float(s) for n, s in zip(names, se)},
        vcov=sol.vcov.tolist(), terms=list(spec.fixed.terms), assign=list(spec.fixed.assign),
        term_factors=[sorted(f) for f in spec.fixed.term_factors], theta=theta.tolist(),
        sigma=float(sol.sigma), random=random, loglik=float(-sol.deviance / 2.0),
        deviance=float(sol.deviance), n_obs=pr.n, n_dropped=spec.n_dropped,
        singular=bool(min(diag) < SINGULAR_TOL), n_evals=int(n_evals),
    )


def fit(formula: str, data: pd.DataFrame, *, reml: bool = False, ftol_abs: float = 1e-12,
        xtol_abs: float = 1e-10) -> LmmFit:
    """Fit a linear mixed model given by an lme4 formula, as ``lmer(formula, data, REML = reml)``.

    Parameters
    ----------
    formula : str
        lme4 syntax, e.g. ``"gloss_match_pct ~ gloss * depth + illumination +
        (1 + gloss + depth | participant) + (1 | stimulus_id)"``; see `analysis.formula`.
    data : DataFrame
        Long format, one row per observation. Rows with missing values in the formula's
        variables are left out (and counted in ``n_dropped``).
    reml : bool
        Restricted maximum likelihood (lme4's default is True; the source study used ML, which
        likelihood-ratio tests of fixed effects need, so ours is False).
    ftol_abs, xtol_abs : float
        Optimiser tolerances (see `fit_problem`).

    Returns
    -------
    LmmFit

    Raises
    ------
    LmmError
        A formula that does not parse or names a column not in the data, a grouping factor
        with one level, non-finite responses, or fixed effects the data cannot estimate.
    """
    spec = build_model(formula, data)
    pr = make_problem(spec, reml=reml)
    starts = [(theta_start(pr), None)]
    warm = moment_start(spec)
    if warm is not None:
        starts.insert(0, (warm, 0.1))
    theta, _, n_evals = fit_problem(pr, starts=starts, ftol_abs=ftol_abs, xtol_abs=xtol_abs)
    return summarise(polish(pr, theta), pr, spec, n_evals=n_evals)
