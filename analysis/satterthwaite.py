"""t and F tests of fixed effects with Satterthwaite's degrees of freedom, as lmerTest.

Kuznetsova, Brockhoff & Christensen (2017), "lmerTest package: tests in linear mixed effects
models", J. Stat. Softw. 82(13), section 3 and appendix; the same computation as lmerTest 3.1:

- the variance parameters are ``varpar = (theta, sigma)``; their covariance is twice the
  (Moore-Penrose) inverse of the Hessian of the deviance in ``varpar`` (lmerTest's
  ``devfun_vp``: ``log|L|^2 + r^2 / sigma^2 + n log(2 pi sigma^2)``, for REML plus
  ``log|R_X|^2 - p log(2 pi sigma^2)``);
- ``J_k = d vcov(beta) / d varpar_k``, with ``vcov(beta) = sigma^2 (R_X' R_X)^-1``;
- a contrast ``l``: ``df = 2 (l' V l)^2 / (g' A g)`` with ``g_k = l' J_k l`` (their eq. 5);
- a hypothesis matrix ``L`` of q rows: ``F = sum_m t_m^2 / q`` over the eigen-directions of
  ``L V L'``, each with its own ``nu_m``; the denominator df is ``2 E / (E - q)``,
  ``E = sum nu_m / (nu_m - 2)`` (Fai & Cornelius 1996).

The derivatives are numDeriv's Richardson extrapolations with numDeriv's default steps (what
lmerTest calls), so the degrees of freedom agree with lmerTest's to the digits both report.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import stats

from analysis.formula import build_model
from analysis.lmm import LmmFit
from analysis.pls import Problem, _factorise, make_problem
from analysis.typeii import hypothesis_matrices

__all__ = ["coefficient_tests", "contrast_test", "richardson_hessian", "richardson_jacobian",
           "satterthwaite_terms", "varpar_derivatives"]

_ZERO_TOL = math.sqrt(np.finfo(float).eps / 7e-7)


def richardson_jacobian(f, x, *, d=1e-4, eps=1e-4, r=4, v=2) -> np.ndarray:
    """numDeriv's ``jacobian(method = "Richardson")``: shape (len(f(x)), len(x))."""
    x = np.asarray(x, float)
    h = np.abs(d * x) + eps * (np.abs(x) < _ZERO_TOL)
    a = []
    for _ in range(r):
        cols = []
        for i in range(x.size):
            e = np.zeros(x.size)
            e[i] = h[i]
            cols.append((np.ravel(f(x + e)) - np.ravel(f(x - e))) / (2 * h[i]))
        a.append(np.stack(cols, axis=1))
        h = h / v
    for m in range(1, r):
        a = [(a[k + 1] * 4**m - a[k]) / (4**m - 1) for k in range(r - m)]
    return a[0]


def richardson_hessian(f, x, *, d=0.1, eps=1e-4, r=4, v=2) -> np.ndarray:
    """numDeriv's ``hessian(method = "Richardson")`` (its ``genD``) of a scalar function."""
    x = np.asarray(x, float)
    n = x.size
    f0 = f(x)
    h0 = np.abs(d * x) + eps * (np.abs(x) < _ZERO_TOL)
    H = np.zeros((n, n))

    def extrapolate(a):
        for m in range(1, r):
            a = [(a[k + 1] * 4**m - a[k]) / (4**m - 1) for k in range(r - m)]
        return a[0]

    for i in range(n):
        h, approx = h0.copy(), []
        for _ in range(r):
            e = np.zeros(n)
            e[i] = h[i]
            approx.append((f(x + e) - 2 * f0 + f(x - e)) / h[i] ** 2)
            h = h / v
        H[i, i] = extrapolate(approx)
    for i in range(n):
        for j in range(i):
            h, approx = h0.copy(), []
            for _ in range(r):
                e = np.zeros(n)
                e[i], e[j] = h[i], h[j]
                approx.append((f(x + e) - 2 * f0 + f(x - e) - H[i, i] * h[i] ** 2
                               - H[j, j] * h[j] ** 2) / (2 * h[i] * h[j]))
                h = h / v
            H[i, j] = H[j, i] = extrapolate(approx)
    return H


def _parts(theta, pr: Problem):
    ld, C = _factorise(theta, pr)
    qr, p = pr.q_rest, pr.p
    RXt = np.tril(C[qr:qr + p, qr:qr + p])
    return ld, float(C[-1, -1]) ** 2, RXt


def varpar_derivatives(fit: LmmFit, pr: Problem):
    """lmerTest's ``vcov_varpar`` and ``Jac_list`` at the fit's ``(theta, sigma)``.

    Returns
    -------
    A : ndarray, shape (k, k)
        Asymptotic covariance of ``varpar`` (2 x the pseudo-inverse of the Hessian, eigenvalues
        <= 1e-8 left out as lmerTest does).
    J : ndarray, shape (k, p, p)
        Derivative of ``vcov(beta)`` with respect to each element of ``varpar``.
    """
    pr = dataclasses.replace(pr, cp=None)
    n, p = pr.n, pr.p

    def dev_vp(vp):
        theta, sigma2 = vp[:-1], vp[-1] ** 2
        ld, r2, RXt = _parts(theta, pr)
        dev = ld + r2 / sigma2 + n * math.log(2 * math.pi * sigma2)
        if pr.reml:
            dev += 2 * float(np.sum(np.log(np.abs(np.diag(RXt))))) - p * math.log(
                2 * math.pi * sigma2)
        return dev

    def covbeta(vp):
        _, _, RXt = _parts(vp[:-1], pr)
        inv = np.linalg.inv(RXt)
        return vp[-1] ** 2 * (inv.T @ inv)

    varpar = np.concatenate([fit.theta, [fit.sigma]])
    H = richardson_hessian(dev_vp, varpar)
    w, V = np.linalg.eigh(H)
    pos = w > 1e-8
    A = 2 * (V[:, pos] / w[pos]) @ V[:, pos].T
    Jac = richardson_jacobian(covbeta, varpar)
    J = np.stack([Jac[:, k].reshape(p, p).T for k in range(varpar.size)])
    return A, J


def contrast_test(L, beta, V, A, J) -> tuple[float, float, float]:
    """lmerTest's ``contestMD`` (or ``contest1D`` for one row): (F, numerator df, denominator df).

    For one row F is the square of the t statistic.
    """
    L = np.atleast_2d(np.asarray(L, float))
    VL = L @ V @ L.T
    if L.shape[0] == 1:
        var = float(VL[0, 0])
        g = np.array([float(L[0] @ Jk @ L[0]) for Jk in J])
        df = 2 * var**2 / float(g @ A @ g)
        return float((L[0] @ beta) ** 2 / var), 1.0, df
    d, P = np.linalg.eigh(VL)
    order = np.argsort(d)[::-1]
    d, P = d[order], P[:, order]
    tol = max(math.sqrt(np.finfo(float).eps) * d[0], 0.0)
    q = int(np.sum(d > tol))
    PtL = (P.T @ L)[:q]
    F = float(np.sum((PtL @ beta) ** 2 / d[:q]) / q)
    nu = []
    for m in range(q):
        g = np.array([float(PtL[m] @ Jk @ PtL[m]) for Jk in J])
        nu.append(2 * d[m] ** 2 / float(g @ A @ g))
    nu = np.array(nu)
    if q == 1 or np.all(np.abs(np.diff(nu)) < 1e-8):
        ddf = float(np.mean(nu))
    elif np.any(nu <= 2):
        ddf = 2.0
    else:
        E = float(np.sum(nu / (nu - 2)))
        ddf = 2 * E / (E - q)
    return F, float(q), ddf


def _problem(fit: LmmFit, data) -> Problem:
    return make_problem(build_model(fit.formula, data), reml=fit.reml)


def coefficient_tests(fit: LmmFit, data) -> dict:
    """Each coefficient's t test with Satterthwaite df, as ``summary(lmerTest::lmer(...))``.

    Parameters
    ----------
    fit : LmmFit
    data : DataFrame
        The data the fit came from.

    Returns
    -------
    dict of str to (df, t, p)
    """
    A, J = varpar_derivatives(fit, _problem(fit, data))
    beta, V = fit.fixef_array(), fit.vcov_array()
    out = {}
    for i, name in enumerate(fit.fixef):
        L = np.zeros(beta.size)
        L[i] = 1.0
        _, _, df = contrast_test(L, beta, V, A, J)
        t = beta[i] / math.sqrt(V[i, i])
        out[name] = (df, float(t), float(2 * stats.t.sf(abs(t), df)))
    return out


def satterthwaite_terms(fit: LmmFit, data) -> dict:
    """F test of each term's Type II hypothesis (car's, `analysis.typeii`) with Satterthwaite df.

    What ``lmerTest::contest(fit, L, ddf = "Satterthwaite")`` gives for the same ``L``.

    Returns
    -------
    dict of str to (F, numerator df, denominator df, p)
    """
    A, J = varpar_derivatives(fit, _problem(fit, data))
    beta, V = fit.fixef_array(), fit.vcov_array()
    out = {}
    for term, L in hypothesis_matrices(fit).items():
        F, q, ddf = contrast_test(L, beta, V, A, J)
        out[term] = (F, q, ddf, float(stats.f.sf(F, q, ddf)))
    return out
