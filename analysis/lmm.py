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

The random-effects design is block diagonal by participant, so ``Lambda' Z' Z Lambda + I`` is
block diagonal with one q x q block per participant (q = 3): the sparse Cholesky factor of lme4
reduces to a batch of small dense ones. Only the cross-products ``Z'y``, ``X'y`` and ``y'y``
depend on the response, which the parametric bootstrap exploits (`with_response`).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field

import nlopt
import numpy as np
import pandas as pd

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
    out["gloss"] = (frame["true_gloss_pct"].to_numpy(float) - gloss_levels.mean()) / gloss_levels.std()
    out["depth"] = (frame["true_depth_cm"].to_numpy(float) - depth_levels.mean()) / depth_levels.std()
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
    return X, Z, y, groups, levels


@dataclass(frozen=True)
class CrossProducts:
    """Everything the profiled deviance needs: cross-products of X, Z and y by group.

    Attributes
    ----------
    ZtZ : ndarray, shape (J, q, q)
    ZtX : ndarray, shape (J, q, p)
    Zty : ndarray, shape (J, q)
    XtX : ndarray, shape (p, p)
    Xty : ndarray, shape (p,)
    yty : float
    n : int
        Number of observations.
    pattern_of : ndarray of int, shape (J,)
        Pattern of each group: groups with identical ``Z_j'Z_j`` and ``Z_j'X_j`` (the same
        stimuli) share one; a complete data set has one pattern.
    patterns : tuple
        Per pattern, as Python lists for the scalar deviance: ``(Z'Z, columns of [Z'X | mean
        Z'y], sum of Z'y y'Z, number of groups)``.
    """

    ZtZ: np.ndarray
    ZtX: np.ndarray
    Zty: np.ndarray
    XtX: np.ndarray
    Xty: np.ndarray
    yty: float
    n: int
    ZtXy: np.ndarray = field(repr=False)
    XtXy: np.ndarray = field(repr=False)
    tril: tuple = field(repr=False)
    diag_q: np.ndarray = field(repr=False)
    pattern_of: np.ndarray = field(repr=False)
    patterns: tuple = field(repr=False)
    py_XtXy: list = field(repr=False)


def crossproducts(X, Z, y, groups) -> CrossProducts:
    """Cross-products of a mixed model's matrices, per group for Z."""
    X = np.asarray(X, float)
    Z = np.asarray(Z, float)
    y = np.asarray(y, float)
    groups = np.asarray(groups)
    J = int(groups.max()) + 1
    q = Z.shape[1]
    ZtZ = np.zeros((J, q, q))
    ZtX = np.zeros((J, q, X.shape[1]))
    Zty = np.zeros((J, q))
    np.add.at(ZtZ, groups, Z[:, :, None] * Z[:, None, :])
    np.add.at(ZtX, groups, Z[:, :, None] * X[:, None, :])
    np.add.at(Zty, groups, Z * y[:, None])
    return _assemble(ZtZ, ZtX, Zty, X.T @ X, X.T @ y, float(y @ y), y.size)


def _assemble(ZtZ, ZtX, Zty, XtX, Xty, yty, n, pattern_of=None) -> CrossProducts:
    _, q, p = ZtX.shape
    XtXy = np.empty((p + 1, p + 1))
    XtXy[:p, :p] = XtX
    XtXy[:p, p] = XtXy[p, :p] = Xty
    XtXy[p, p] = yty
    # theta fills the lower triangle column by column (lme4's Lind); numpy's tril_indices runs
    # row by row, so take the transposed upper triangle's indices.
    upper = np.triu_indices(q)
    if pattern_of is None:
        pattern_of = _find_patterns(ZtZ, ZtX)
    patterns = []
    for k in range(int(pattern_of.max()) + 1):
        members = np.flatnonzero(pattern_of == k)
        zty = Zty[members]
        # Per pattern: Z'Z, the columns of [Z'X | mean of Z'y], sum of Z'y y'Z, group count.
        rhs = np.concatenate([ZtX[members[0]], zty.mean(axis=0)[:, None]], axis=1)
        patterns.append((ZtZ[members[0]].tolist(), [tuple(c) for c in rhs.T.tolist()],
                         (zty.T @ zty).tolist(), int(members.size)))
    return CrossProducts(
        ZtZ=ZtZ, ZtX=ZtX, Zty=Zty, XtX=XtX, Xty=Xty, yty=float(yty), n=int(n),
        ZtXy=np.concatenate([ZtX, Zty[:, :, None]], axis=2), XtXy=XtXy,
        tril=(upper[1], upper[0]), diag_q=np.arange(q), pattern_of=pattern_of,
        patterns=tuple(patterns), py_XtXy=XtXy.tolist(),
    )


def _find_patterns(ZtZ, ZtX) -> np.ndarray:
    """Pattern index of each group: groups whose Z'Z and Z'X agree to 1e-12 share one.

    Participants who saw the same stimuli have the same blocks (a complete data set has one
    pattern, whatever the number of participants); their sums differ only by rounding, as the
    trials come in another order.
    """
    J = ZtZ.shape[0]
    keys = np.concatenate([ZtZ.reshape(J, -1), ZtX.reshape(J, -1)], axis=1)
    tol = 1e-12 * max(float(np.abs(keys).max()), 1.0)
    reps, out = [], np.empty(J, dtype=int)
    for j in range(J):
        for k, rep in enumerate(reps):
            if np.all(np.abs(keys[j] - rep) <= tol):
                out[j] = k
                break
        else:
            reps.append(keys[j])
            out[j] = len(reps) - 1
    return out


def with_response(cp: CrossProducts, Zty, Xty, yty) -> CrossProducts:
    """The same model with a new response: only the y cross-products change."""
    return _assemble(cp.ZtZ, cp.ZtX, Zty, cp.XtX, Xty, yty, cp.n, cp.pattern_of)


def _q(cp: CrossProducts) -> int:
    return cp.ZtZ.shape[1]


def theta_lower_bounds(q: int) -> np.ndarray:
    """lme4's bounds: 0 for the diagonal of the Cholesky block, -inf elsewhere.

    theta lists the lower triangle column by column (lme4's order).
    """
    return np.array([0.0 if i == j else -np.inf for j in range(q) for i in range(j, q)])


def _theta_to_T(theta, q: int) -> np.ndarray:
    T = np.zeros((q, q))
    # Column-major lower triangle, as lme4's Lind.
    T[np.triu_indices(q)[::-1]] = theta
    return T


def _solve_pls(theta, cp: CrossProducts):
    """Penalised least squares at theta: (log|L_theta|^2, R_X, c_beta, r^2).

    With ``A_j = T' Z_j'Z_j T + I = L_j L_j'`` per group and ``R_j = L_j^-1 T' Z_j'[X y]``, the
    Schur complement ``[X y]'[X y] - sum_j R_j' R_j`` has the Cholesky factor
    ``[[R_X', 0], [c_beta', r]]``: lme4's R_X, the fixed-effect right-hand side and the square
    root of the penalised residual sum of squares in one factorisation (Bates et al. 2015, eqs.
    16-18 and 30-34).
    """
    q = cp.ZtZ.shape[1]
    p = cp.XtX.shape[0]
    T = np.zeros((q, q))
    T[cp.tril] = theta
    A = T.T @ cp.ZtZ @ T
    A += np.eye(q)
    L = np.linalg.cholesky(A)
    R = np.linalg.solve(L, T.T @ cp.ZtXy)
    Rf = R.reshape(-1, p + 1)
    M = cp.XtXy - Rf.T @ Rf
    ldL2 = 2.0 * float(np.sum(np.log(L[:, cp.diag_q, cp.diag_q])))
    C = np.linalg.cholesky(M)
    return ldL2, C[:p, :p], C[p, :p], float(C[p, p]) ** 2


def _pattern_terms(theta, G, cols, S):
    """One pattern's share of the profiled deviance, in scalar arithmetic (q = 3).

    With ``A = T' G T + I = L L'`` and ``Q = L^-1 T'``: the rows of ``R = Q [Z'X | mean Z'y]``,
    ``trace(Q S Q')`` (= sum over the pattern's groups of ``|c_u,j|^2``) and ``log det L``.
    Written out so that one deviance costs a few microseconds of Python instead of a dozen
    numpy calls on 3 x 3 arrays (the optimiser calls it ~250 times per bootstrap refit).
    """
    t0, t1, t2, t3, t4, t5 = theta
    (g00, g01, g02), (_, g11, g12), (_, _, g22) = G
    # GT = G T (T lower triangular, columns (t0, t1, t2), (0, t3, t4), (0, 0, t5)).
    gt00 = g00 * t0 + g01 * t1 + g02 * t2
    gt10 = g01 * t0 + g11 * t1 + g12 * t2
    gt20 = g02 * t0 + g12 * t1 + g22 * t2
    gt11 = g11 * t3 + g12 * t4
    gt21 = g12 * t3 + g22 * t4
    gt22 = g22 * t5
    # A = T' G T + I, lower triangle, and its Cholesky factor L; M = L^-1.
    l00 = math.sqrt(t0 * gt00 + t1 * gt10 + t2 * gt20 + 1.0)
    l10 = (t3 * gt10 + t4 * gt20) / l00
    l20 = t5 * gt20 / l00
    l11 = math.sqrt(t3 * gt11 + t4 * gt21 + 1.0 - l10 * l10)
    l21 = (t5 * gt21 - l20 * l10) / l11
    l22 = math.sqrt(t5 * gt22 + 1.0 - l20 * l20 - l21 * l21)
    m00, m11, m22 = 1.0 / l00, 1.0 / l11, 1.0 / l22
    m10 = -l10 * m00 * m11
    m21 = -l21 * m11 * m22
    m20 = -(l20 * m00 + l21 * m10) * m22
    # Q = L^-1 T'.
    q00, q01, q02 = m00 * t0, m00 * t1, m00 * t2
    q10, q11, q12 = m10 * t0, m10 * t1 + m11 * t3, m10 * t2 + m11 * t4
    q20, q21, q22 = m20 * t0, m20 * t1 + m21 * t3, m20 * t2 + m21 * t4 + m22 * t5
    R0 = [q00 * a + q01 * b + q02 * c for a, b, c in cols]
    R1 = [q10 * a + q11 * b + q12 * c for a, b, c in cols]
    R2 = [q20 * a + q21 * b + q22 * c for a, b, c in cols]
    (s00, s01, s02), (_, s11, s12), (_, _, s22) = S
    # trace(Q S Q') = sum over rows q of q S q'.
    quad = (
        (q00 * q00 + q10 * q10 + q20 * q20) * s00
        + (q01 * q01 + q11 * q11 + q21 * q21) * s11
        + (q02 * q02 + q12 * q12 + q22 * q22) * s22
        + 2.0 * ((q00 * q01 + q10 * q11 + q20 * q21) * s01
                 + (q00 * q02 + q10 * q12 + q20 * q22) * s02
                 + (q01 * q02 + q11 * q12 + q21 * q22) * s12)
    )
    return R0, R1, R2, quad, math.log(l00 * l11 * l22)


def _deviance_fast(theta, cp: CrossProducts) -> float:
    """`profiled_deviance` for q = 3 by patterns of identical participant blocks.

    Per pattern k (``n_k`` participants with the same ``Z_j'Z_j`` and ``Z_j'X_j``), the
    Schur complement loses ``n_k R_k' R_k`` (its y column through the pattern's mean ``Z'y``)
    and its y-y element ``trace(Q_k S_k Q_k')``; ``log|L|^2`` gains ``2 n_k log det L_k``.
    """
    x = cp.py_XtXy
    m_yy = cp.yty
    if len(cp.patterns) == 1:
        G, cols, S, J = cp.patterns[0]
        R0, R1, R2, quad, ld = _pattern_terms(theta, G, cols, S)
        if len(R0) == 5:
            pwrss = _schur5(x, R0, R1, R2, J, m_yy - quad)
        else:
            pwrss = _schur_loop(x, [(R0, R1, R2, J)], m_yy - quad)
        ldL2 = 2.0 * J * ld
    else:
        parts, ldL2 = [], 0.0
        for G, cols, S, nk in cp.patterns:
            R0, R1, R2, quad, ld = _pattern_terms(theta, G, cols, S)
            parts.append((R0, R1, R2, nk))
            m_yy -= quad
            ldL2 += 2.0 * nk * ld
        pwrss = _schur_loop(x, parts, m_yy)
    n = cp.n
    return ldL2 + n * (1.0 + math.log(2.0 * math.pi * pwrss / n))


def _schur_loop(XtXy, parts, m_yy) -> float:
    """r^2: the last diagonal element of chol(M) squared, M = XtXy - sum n R'R, M[-1,-1] = m_yy.

    ``parts`` holds ``(R0, R1, R2, n)`` per pattern.
    """
    k = len(XtXy)
    M = [list(row[: c + 1]) for c, row in enumerate(XtXy)]
    for R0, R1, R2, nk in parts:
        for c in range(k):
            a, b, e = R0[c], R1[c], R2[c]
            Mc = M[c]
            for d in range(c + 1):
                Mc[d] -= nk * (a * R0[d] + b * R1[d] + e * R2[d])
    M[k - 1][k - 1] = m_yy
    C = []
    for c in range(k):
        Cc = []
        for d in range(c + 1):
            Cd = C[d] if d < c else Cc
            v = M[c][d]
            for e in range(d):
                v -= Cc[e] * Cd[e]
            Cc.append(v / Cd[d] if d < c else math.sqrt(v))
        C.append(Cc)
    return C[k - 1][k - 1] ** 2


def _schur5(XtXy, R0, R1, R2, J, m_yy) -> float:
    """`_schur_loop` unrolled for four fixed effects (the seed's model), about 3x faster."""
    a0, a1, a2, a3, a4 = R0
    b0, b1, b2, b3, b4 = R1
    e0, e1, e2, e3, e4 = R2
    x = XtXy
    c00 = math.sqrt(x[0][0] - J * (a0 * a0 + b0 * b0 + e0 * e0))
    c10 = (x[1][0] - J * (a1 * a0 + b1 * b0 + e1 * e0)) / c00
    c11 = math.sqrt(x[1][1] - J * (a1 * a1 + b1 * b1 + e1 * e1) - c10 * c10)
    c20 = (x[2][0] - J * (a2 * a0 + b2 * b0 + e2 * e0)) / c00
    c21 = (x[2][1] - J * (a2 * a1 + b2 * b1 + e2 * e1) - c20 * c10) / c11
    c22 = math.sqrt(x[2][2] - J * (a2 * a2 + b2 * b2 + e2 * e2) - c20 * c20 - c21 * c21)
    c30 = (x[3][0] - J * (a3 * a0 + b3 * b0 + e3 * e0)) / c00
    c31 = (x[3][1] - J * (a3 * a1 + b3 * b1 + e3 * e1) - c30 * c10) / c11
    c32 = (x[3][2] - J * (a3 * a2 + b3 * b2 + e3 * e2) - c30 * c20 - c31 * c21) / c22
    c33 = math.sqrt(x[3][3] - J * (a3 * a3 + b3 * b3 + e3 * e3)
                    - c30 * c30 - c31 * c31 - c32 * c32)
    c40 = (x[4][0] - J * (a4 * a0 + b4 * b0 + e4 * e0)) / c00
    c41 = (x[4][1] - J * (a4 * a1 + b4 * b1 + e4 * e1) - c40 * c10) / c11
    c42 = (x[4][2] - J * (a4 * a2 + b4 * b2 + e4 * e2) - c40 * c20 - c41 * c21) / c22
    c43 = (x[4][3] - J * (a4 * a3 + b4 * b3 + e4 * e3) - c40 * c30 - c41 * c31
           - c42 * c32) / c33
    return m_yy - c40 * c40 - c41 * c41 - c42 * c42 - c43 * c43


def profiled_deviance(theta, cp: CrossProducts) -> float:
    """lme4's profiled ML deviance at theta (Bates et al. 2015, eq. 34).

    ``-2 log L = log|L_theta|^2 + n (1 + log(2 pi r^2(theta) / n))``, with ``r^2`` the penalised
    residual sum of squares at the conditional estimates of beta and u.

    Parameters
    ----------
    theta : array_like, shape (q (q + 1) / 2,)
        Lower triangle of the relative covariance factor, column by column (lme4's order).
    cp : CrossProducts

    Returns
    -------
    float
        The deviance (what ``lmer(..., REML = FALSE, devFunOnly = TRUE)(theta)`` returns).
    """
    if cp.ZtZ.shape[1] == 3:
        return _deviance_fast(np.asarray(theta, float).tolist(), cp)
    ldL2, _, _, pwrss = _solve_pls(np.asarray(theta, float), cp)
    n = cp.n
    return ldL2 + n * (1.0 + math.log(2.0 * math.pi * pwrss / n))


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
    q = _q(cp)
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
    q = _q(cp)
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
    q = _q(cp)
    ldL2, RX, cb, pwrss = _solve_pls(theta, cp)
    n = cp.n
    deviance = ldL2 + n * (1.0 + math.log(2.0 * math.pi * pwrss / n))
    beta = np.linalg.solve(RX.T, cb)
    sigma2 = pwrss / n
    RXinv = np.linalg.inv(RX)
    vcov = sigma2 * (RXinv.T @ RXinv)
    T = _theta_to_T(theta, q)
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
