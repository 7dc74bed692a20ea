"""The profiled deviance of one grouping factor with three random coefficients, in scalars.

The source study's ``(1 + gloss + depth | participant)`` models are refitted thousands of times
in a bootstrap; `analysis.pls` evaluates their deviance with this kernel (tested equal to its
general block elimination).

Bates, Maechler, Bolker & Walker (2015), "Fitting linear mixed-effects models using lme4", J. Stat.
Softw. 67(1), section 3. The random effects are ``b = Lambda(theta) u``, ``u ~ N(0, sigma^2 I)``;
for a given ``theta`` the penalised least-squares problem is solved by a Cholesky factorisation,
the fixed effects and ``sigma`` are profiled out, and what remains is the profiled ML deviance
``log|L_theta|^2 + n (1 + log(2 pi r^2 / n))`` (their eq. 34), a function of ``theta`` alone.

The random-effects design is block diagonal by participant, so ``Lambda' Z' Z Lambda + I`` is
block diagonal with one q x q block per participant: lme4's sparse Cholesky factor reduces to
small dense ones, and to a single one for all participants who saw the same stimuli (a
"pattern"). Only ``Z'y``, ``X'y`` and ``y'y`` depend on the response, which the parametric
bootstrap exploits (`with_response`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["CrossProducts", "crossproducts", "with_response"]


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
    """The profiled ML deviance for q = 3 by patterns of identical participant blocks.

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
    """`_schur_loop` unrolled for four fixed effects (the source study's model), about 3x faster."""
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
