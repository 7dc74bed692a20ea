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

__all__ = ["CrossProducts", "crossproducts", "deviance_gradient", "with_response"]


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
    return R0, R1, R2, quad, math.log(l00 * l11 * l22), (m00, m10, m11, m20, m21, m22), \
        (q00, q01, q02, q10, q11, q12, q20, q21, q22)


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
        R0, R1, R2, quad, ld, _, _ = _pattern_terms(theta, G, cols, S)
        if len(R0) == 5:
            pwrss = _schur5(x, R0, R1, R2, J, m_yy - quad)[0]
        else:
            pwrss = _schur_loop(x, [(R0, R1, R2, J)], m_yy - quad)[0]
        ldL2 = 2.0 * J * ld
    else:
        parts, ldL2 = [], 0.0
        for G, cols, S, nk in cp.patterns:
            R0, R1, R2, quad, ld, _, _ = _pattern_terms(theta, G, cols, S)
            parts.append((R0, R1, R2, nk))
            m_yy -= quad
            ldL2 += 2.0 * nk * ld
        pwrss = _schur_loop(x, parts, m_yy)[0]
    n = cp.n
    return ldL2 + n * (1.0 + math.log(2.0 * math.pi * pwrss / n))


def _schur_loop(XtXy, parts, m_yy):
    """r^2 and beta from chol(M), M = XtXy - sum n R'R with M[-1,-1] = m_yy.

    ``parts`` holds ``(R0, R1, R2, n)`` per pattern. Returns ``(r^2, beta)``: the last
    diagonal element of the lower Cholesky factor ``C`` squared, and the fixed effects
    ``C_X^-T c_beta`` (``C_X`` the leading p x p block, ``c_beta`` the last row's first p).
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
    p = k - 1
    beta = [0.0] * p
    for i in range(p - 1, -1, -1):
        v = C[p][i]
        for j in range(i + 1, p):
            v -= C[j][i] * beta[j]
        beta[i] = v / C[i][i]
    return C[p][p] ** 2, beta


def _schur5(XtXy, R0, R1, R2, J, m_yy):
    """`_schur_loop` unrolled for four fixed effects (the source study's model), about 3x faster.

    Returns ``(r^2, beta)`` as `_schur_loop`."""
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
    b3 = c43 / c33
    b2 = (c42 - c32 * b3) / c22
    b1 = (c41 - c21 * b2 - c31 * b3) / c11
    b0 = (c40 - c10 * b1 - c20 * b2 - c30 * b3) / c00
    return m_yy - c40 * c40 - c41 * c41 - c42 * c42 - c43 * c43, (b0, b1, b2, b3)


def _pattern_gradient(theta, G, cols, S, nk, M, Q, beta):
    """One pattern's two parts of :func:`deviance_gradient`, lower triangles in theta's order:
    ``P = G T A^-1`` (the log-determinant's, times ``2 n_k``) and ``H = (I - G K) C T A^-1``
    (the residual's, times ``-2 n / r^2``). ``M = L^-1`` and ``Q`` come from
    `_pattern_terms`."""
    t0, t1, t2, t3, t4, t5 = theta
    (g00, g01, g02), (_, g11, g12), (_, _, g22) = G
    m00, m10, m11, m20, m21, m22 = M
    q00, q01, q02, q10, q11, q12, q20, q21, q22 = Q
    # A^-1 = M'M (M = L^-1, lower triangular), symmetric.
    a00 = m00 * m00 + m10 * m10 + m20 * m20
    a01 = m10 * m11 + m20 * m21
    a02 = m20 * m22
    a11 = m11 * m11 + m21 * m21
    a12 = m21 * m22
    a22 = m22 * m22
    # F = T A^-1 (T lower triangular).
    f00, f01, f02 = t0 * a00, t0 * a01, t0 * a02
    f10, f11, f12 = t1 * a00 + t3 * a01, t1 * a01 + t3 * a11, t1 * a02 + t3 * a12
    f20 = t2 * a00 + t4 * a01 + t5 * a02
    f21 = t2 * a01 + t4 * a11 + t5 * a12
    f22 = t2 * a02 + t4 * a12 + t5 * a22
    # P = G T A^-1 = G F, lower triangle.
    p00 = g00 * f00 + g01 * f10 + g02 * f20
    p10 = g01 * f00 + g11 * f10 + g12 * f20
    p11 = g01 * f01 + g11 * f11 + g12 * f21
    p20 = g02 * f00 + g12 * f10 + g22 * f20
    p21 = g02 * f01 + g12 * f11 + g22 * f21
    p22 = g02 * f02 + g12 * f12 + g22 * f22
    # K = T A^-1 T' = Q'Q (symmetric).
    k00 = q00 * q00 + q10 * q10 + q20 * q20
    k01 = q00 * q01 + q10 * q11 + q20 * q21
    k02 = q00 * q02 + q10 * q12 + q20 * q22
    k11 = q01 * q01 + q11 * q11 + q21 * q21
    k12 = q01 * q02 + q11 * q12 + q21 * q22
    k22 = q02 * q02 + q12 * q12 + q22 * q22
    # E = I - G K.
    e00 = 1.0 - (g00 * k00 + g01 * k01 + g02 * k02)
    e01 = -(g00 * k01 + g01 * k11 + g02 * k12)
    e02 = -(g00 * k02 + g01 * k12 + g02 * k22)
    e10 = -(g01 * k00 + g11 * k01 + g12 * k02)
    e11 = 1.0 - (g01 * k01 + g11 * k11 + g12 * k12)
    e12 = -(g01 * k02 + g11 * k12 + g12 * k22)
    e20 = -(g02 * k00 + g12 * k01 + g22 * k02)
    e21 = -(g02 * k01 + g12 * k11 + g22 * k12)
    e22 = 1.0 - (g02 * k02 + g12 * k12 + g22 * k22)
    # C = S - n_k (m w' + w m') + n_k w w', w = W beta, m the mean Z'y.
    w0 = w1 = w2 = 0.0
    for (a, b, c), bk in zip(cols, beta):
        w0 += a * bk
        w1 += b * bk
        w2 += c * bk
    mu0, mu1, mu2 = cols[-1]
    (s00, s01, s02), (_, s11, s12), (_, _, s22) = S
    c00 = s00 + nk * (w0 * w0 - 2.0 * mu0 * w0)
    c11 = s11 + nk * (w1 * w1 - 2.0 * mu1 * w1)
    c22 = s22 + nk * (w2 * w2 - 2.0 * mu2 * w2)
    c01 = s01 + nk * (w0 * w1 - mu0 * w1 - w0 * mu1)
    c02 = s02 + nk * (w0 * w2 - mu0 * w2 - w0 * mu2)
    c12 = s12 + nk * (w1 * w2 - mu1 * w2 - w1 * mu2)
    # D = E C; H = D F (lower triangle only).
    d00 = e00 * c00 + e01 * c01 + e02 * c02
    d01 = e00 * c01 + e01 * c11 + e02 * c12
    d02 = e00 * c02 + e01 * c12 + e02 * c22
    d10 = e10 * c00 + e11 * c01 + e12 * c02
    d11 = e10 * c01 + e11 * c11 + e12 * c12
    d12 = e10 * c02 + e11 * c12 + e12 * c22
    d20 = e20 * c00 + e21 * c01 + e22 * c02
    d21 = e20 * c01 + e21 * c11 + e22 * c12
    d22 = e20 * c02 + e21 * c12 + e22 * c22
    h00 = d00 * f00 + d01 * f10 + d02 * f20
    h10 = d10 * f00 + d11 * f10 + d12 * f20
    h20 = d20 * f00 + d21 * f10 + d22 * f20
    h11 = d10 * f01 + d11 * f11 + d12 * f21
    h21 = d20 * f01 + d21 * f11 + d22 * f21
    h22 = d20 * f02 + d21 * f12 + d22 * f22
    return (p00, p10, p20, p11, p21, p22), (h00, h10, h20, h11, h21, h22)


def deviance_gradient(theta, cp: CrossProducts):
    """The profiled ML deviance of `_deviance_fast` and its gradient in theta (q = 3).

    With ``A = T' G T + I`` per pattern (``n_k`` groups with the same ``G = Z_j'Z_j`` and
    ``W = Z_j'X_j``), the deviance is ``sum_k n_k log|A_k| + n log(r^2) + const``. Its
    derivative in the factor ``T`` (Bates et al. 2015 do not give it; it follows from two
    standard results):

    - ``d log|A| / dT = 2 G T A^-1`` (Jacobi's formula, ``A`` symmetric);
    - ``d r^2 / dT = -2 sum_j (c_j - G T u_j) u_j'`` by the envelope theorem: ``r^2`` is the
      minimum over ``u`` and ``beta`` of ``sum_j |y_j - X_j beta - Z_j T u_j|^2 + |u_j|^2``,
      so only its explicit dependence on ``T`` counts, at the optimum ``beta`` and
      ``u_j = A^-1 T' c_j`` with ``c_j = Z_j'y - W beta``. Summed over a pattern's groups this
      is ``-2 (I - G K) C T A^-1`` with ``K = T A^-1 T'`` and ``C = sum_j c_j c_j'``
      ``= S - n_k (m w' + w m') + n_k w w'`` (``S = sum_j Z_j'y y'Z_j``, ``m`` the pattern's mean
      ``Z_j'y``, ``w = W beta``).

    The gradient is the lower triangle of ``d/dT`` in theta's order (column by column). It is
    tested against central differences of `_deviance_fast`. Written in scalars like
    `_pattern_terms`: a deviance with its gradient costs about twice a deviance, and lets the
    bootstrap's refits use a gradient method (`analysis.bootstrap.refit`).

    Parameters
    ----------
    theta : sequence of 6 float
    cp : CrossProducts

    Returns
    -------
    deviance : float
    gradient : list of 6 float
    """
    x = cp.py_XtXy
    m_yy = cp.yty
    parts, kept, ldL2 = [], [], 0.0
    for G, cols, S, nk in cp.patterns:
        R0, R1, R2, quad, ld, M, Q = _pattern_terms(theta, G, cols, S)
        parts.append((R0, R1, R2, nk))
        kept.append((M, Q))
        m_yy -= quad
        ldL2 += 2.0 * nk * ld
    if len(parts) == 1 and len(parts[0][0]) == 5:
        pwrss, beta = _schur5(x, *parts[0][:3], parts[0][3], m_yy)
    else:
        pwrss, beta = _schur_loop(x, parts, m_yy)
    n = cp.n
    dev = ldL2 + n * (1.0 + math.log(2.0 * math.pi * pwrss / n))
    scale = 2.0 * n / pwrss
    g = [0.0] * 6
    for (G, cols, S, nk), (M, Q) in zip(cp.patterns, kept):
        p, h = _pattern_gradient(theta, G, cols, S, nk, M, Q, beta)
        for i in range(6):
            g[i] += 2.0 * nk * p[i] - scale * h[i]
    return dev, g
