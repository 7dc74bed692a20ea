"""lme4's profiled deviance for any random-effect structure, by block elimination.

Bates, Maechler, Bolker & Walker (2015), "Fitting linear mixed-effects models using lme4", J.
Stat. Softw. 67(1), section 3. With ``b = Lambda(theta) u`` and ``u ~ N(0, sigma^2 I)`` the
penalised least-squares system for ``[u, beta, 1]`` has the matrix

``[[Lambda' Z'Z Lambda + I, Lambda' Z'X, Lambda' Z'y], [., X'X, X'y], [., ., y'y]]``

whose Cholesky factor holds ``L_theta``, lme4's ``R_X``, ``c_beta`` and ``r`` (the square root of
the penalised residual sum of squares). The deviance is (their eqs. 34 and 41)

- ML:   ``log|L|^2 + n (1 + log(2 pi r^2 / n))``
- REML: ``log|L|^2 + log|R_X|^2 + (n - p) (1 + log(2 pi r^2 / (n - p)))``.

The first random term (the one with most levels, in lme4's order) makes ``Z_1'Z_1`` block
diagonal: every observation belongs to one level. Its ``q_1 x q_1`` blocks are factored all at
once, and only the rest (the other terms' effects, X and y; 33 + 8 columns for a participant x
stimulus model, 5 for one grouping factor) is factored densely. Z itself is sparse. A model with
one grouping factor and three random coefficients (the source study's) uses the scalar kernel of
`analysis.deviance`, which is tested equal to this one.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.linalg.lapack import dpotrf

from analysis.deviance import CrossProducts, _deviance_fast, crossproducts, with_response
from analysis.formula import ModelSpec

__all__ = ["Problem", "Solution", "deviance", "make_problem", "solve", "term_factor",
           "theta_lower", "theta_start", "with_y"]


@functools.cache
def _tril(q: int):
    """Row and column of each theta element of a q x q factor (column-major lower triangle).

    Cached (the bootstrap asks for them in every refit), so read-only."""
    upper = np.triu_indices(q)
    rows, cols = upper[1], upper[0]
    rows.flags.writeable = False
    cols.flags.writeable = False
    return rows, cols


@dataclass(frozen=True)
class Problem:
    """The cross-products a deviance evaluation needs; only those with y change with y.

    Attributes
    ----------
    q_sizes : tuple of int
        Random coefficients per level, per term (lme4's order).
    n_levels : tuple of int
    n, p : int
        Observations and fixed effects.
    reml : bool
    G1 : ndarray, shape (J1, q1, q1)
        Blocks of ``Z_1'Z_1``.
    Z1W : ndarray, shape (J1, q1, m)
        ``Z_1' [Z_rest | X | y]`` by level of the first term.
    WW : ndarray, shape (m, m)
        ``[Z_rest | X | y]' [Z_rest | X | y]``.
    patterns : tuple of (ndarray of int, ndarray)
        Levels of the first term with the same ``Z_1'Z_1`` block (e.g. every stimulus seen by
        all participants) and, per pattern, ``P[a, b] = sum_j Z1W_j[a]' Z1W_j[b]``, shape
        (q1, q1, m, m); empty when patterns would not save work (then the levels are factored
        one by one).
    """

    q_sizes: tuple
    n_levels: tuple
    n: int
    p: int
    reml: bool
    G1: np.ndarray
    Z1W: np.ndarray
    WW: np.ndarray
    q_rest: int
    theta_sizes: tuple = field(repr=False)
    lam_rows: np.ndarray = field(repr=False)
    lam_cols: np.ndarray = field(repr=False)
    lam_theta: np.ndarray = field(repr=False)
    Z: sp.csc_matrix = field(repr=False)
    X: np.ndarray = field(repr=False)
    cp: CrossProducts | None = field(repr=False, default=None)
    patterns: tuple = field(repr=False, default=())


def make_problem(spec: ModelSpec, *, reml: bool, y=None, columns=None) -> Problem:
    """Cross-products of ``spec``'s model.

    Parameters
    ----------
    spec : ModelSpec
    reml : bool
    y : array_like, optional
        Another response (default the spec's).
    columns : sequence of int, optional
        Keep only these columns of X (a reduced model, e.g. without one term).
    """
    y = spec.y if y is None else np.asarray(y, float)
    X = spec.fixed.X if columns is None else spec.fixed.X[:, list(columns)]
    Z = spec.Z()
    q_sizes = spec.q_sizes
    n_levels = tuple(int(lv.size) for lv in spec.re_levels)
    k1 = q_sizes[0] * n_levels[0]
    q1 = q_sizes[0]
    # Lambda of the other terms: block diagonal, Kronecker of I_J with each term's T.
    rows, cols, which = [], [], []
    offset_col, offset_theta = 0, q1 * (q1 + 1) // 2
    theta_sizes = [offset_theta]
    for q, J in zip(q_sizes[1:], n_levels[1:]):
        r, c = _tril(q)
        t = np.arange(r.size) + offset_theta
        base = offset_col + q * np.arange(J)
        rows.append((base[:, None] + r[None, :]).ravel())
        cols.append((base[:, None] + c[None, :]).ravel())
        which.append(np.tile(t, J))
        offset_col += q * J
        offset_theta += r.size
        theta_sizes.append(r.size)
    cat = (lambda parts: np.concatenate(parts) if parts else np.zeros(0, int))
    cp = None
    if len(q_sizes) == 1 and q1 == 3 and not reml:
        cp = crossproducts(X, spec.re_values[0], y, spec.re_index[0])
    pr = Problem(
        q_sizes=q_sizes, n_levels=n_levels, n=int(y.size), p=X.shape[1], reml=bool(reml),
        G1=np.zeros(0), Z1W=np.zeros(0), WW=np.zeros(0), q_rest=int(Z.shape[1] - k1),
        theta_sizes=tuple(theta_sizes), lam_rows=cat(rows), lam_cols=cat(cols),
        lam_theta=cat(which), Z=Z, X=X, cp=cp,
    )
    return _with_products(pr, y, first=True)


def _with_products(pr: Problem, y, *, first: bool = False) -> Problem:
    Z, X = pr.Z, pr.X
    q1, J1 = pr.q_sizes[0], pr.n_levels[0]
    k1 = q1 * J1
    Z1 = Z[:, :k1]
    if first:
        Zr = Z[:, k1:]
        W = sp.hstack([Zr, sp.csc_matrix(X), sp.csc_matrix(y[:, None])], format="csc")
        WW = (W.T @ W).toarray()
        Z1W = (Z1.T @ W).toarray().reshape(J1, q1, -1)
        G1d = (Z1.T @ Z1).toarray()
        G1 = np.stack([G1d[j * q1:(j + 1) * q1, j * q1:(j + 1) * q1] for j in range(J1)])
        object.__setattr__(pr, "G1", G1)
        groups = _block_patterns(G1)
        if len(groups) * q1 <= J1 // 2:
            object.__setattr__(pr, "patterns", tuple(
                (members, np.einsum("jam,jbn->abmn", Z1W[members], Z1W[members]))
                for members in groups))
    else:
        WW = pr.WW.copy()
        Z1W = pr.Z1W.copy()
        Zr = Z[:, k1:]
        wy = np.concatenate([Zr.T @ y, X.T @ y, [y @ y]])
        WW[:, -1] = wy
        WW[-1, :] = wy
        Z1W[:, :, -1] = (Z1.T @ y).reshape(J1, q1)
        if pr.patterns:
            new = []
            for members, P in pr.patterns:
                P = P.copy()
                cross = np.einsum("jam,jb->abm", Z1W[members], Z1W[members, :, -1])
                P[:, :, :, -1] = cross
                P[:, :, -1, :] = cross.transpose(1, 0, 2)
                new.append((members, P))
            object.__setattr__(pr, "patterns", tuple(new))
    object.__setattr__(pr, "WW", WW)
    object.__setattr__(pr, "Z1W", Z1W)
    return pr


def _block_patterns(G1) -> list:
    """Levels whose ``Z_1'Z_1`` blocks agree to 1e-12 (relative), as index arrays."""
    J = G1.shape[0]
    keys = G1.reshape(J, -1)
    tol = 1e-12 * max(float(np.abs(keys).max()), 1.0)
    reps, members = [], []
    for j in range(J):
        for k, rep in enumerate(reps):
            if np.all(np.abs(keys[j] - rep) <= tol):
                members[k].append(j)
                break
        else:
            reps.append(keys[j])
            members.append([j])
    return [np.array(m) for m in members]


def with_y(pr: Problem, y) -> Problem:
    """The same model with a new response: only the y cross-products are recomputed."""
    y = np.asarray(y, float)
    new = Problem(**{f: getattr(pr, f) for f in pr.__dataclass_fields__})
    new = _with_products(new, y)
    if pr.cp is not None:
        q1, J1 = pr.q_sizes[0], pr.n_levels[0]
        Zty = new.Z1W[:, :, -1].reshape(J1, q1)
        object.__setattr__(new, "cp", with_response(pr.cp, Zty, pr.X.T @ y, float(y @ y)))
    return new


def theta_lower(pr: Problem) -> np.ndarray:
    """lme4's bounds: 0 on the diagonal of each term's factor, -inf elsewhere."""
    out = []
    for q in pr.q_sizes:
        r, c = _tril(q)
        out.append(np.where(r == c, 0.0, -np.inf))
    return np.concatenate(out)


def theta_start(pr: Problem) -> np.ndarray:
    """lme4's default start: every term's factor the identity."""
    out = []
    for q in pr.q_sizes:
        r, c = _tril(q)
        out.append((r == c).astype(float))
    return np.concatenate(out)


def term_factor(theta, q_sizes, k: int) -> np.ndarray:
    """The lower-triangular relative covariance factor ``T_k`` of term ``k``."""
    start = sum(q * (q + 1) // 2 for q in q_sizes[:k])
    q = q_sizes[k]
    T = np.zeros((q, q))
    T[_tril(q)] = np.asarray(theta, float)[start:start + q * (q + 1) // 2]
    return T


def _factorise(theta, pr: Problem):
    """Cholesky factor of the reduced system: ``(log|L|^2, C)``; C holds R_X', c_beta, r."""
    theta = np.asarray(theta, float)
    q1 = pr.q_sizes[0]
    qr = pr.q_rest
    if pr.patterns:
        return _factorise_patterns(theta, pr)
    M = pr.WW.copy()
    Z1W = pr.Z1W
    if qr:
        lam = np.zeros((qr, qr))
        lam[pr.lam_rows, pr.lam_cols] = theta[pr.lam_theta]
        M[:qr, :] = lam.T @ M[:qr, :]
        M[:, :qr] = M[:, :qr] @ lam
        M[np.arange(qr), np.arange(qr)] += 1.0
        Z1W = Z1W.copy()
        Z1W[:, :, :qr] = Z1W[:, :, :qr] @ lam
    if q1 == 1:
        t = theta[0]
        d = np.sqrt(t * t * pr.G1[:, 0, 0] + 1.0)
        B = (t / d)[:, None] * Z1W[:, 0, :]
        ld1 = 2.0 * float(np.sum(np.log(d)))
    else:
        T = term_factor(theta, pr.q_sizes, 0)
        A = T.T @ pr.G1 @ T
        A += np.eye(q1)
        L = np.linalg.cholesky(A)
        B = np.linalg.solve(L, T.T @ Z1W).reshape(-1, M.shape[0])
        diag = L[:, np.arange(q1), np.arange(q1)]
        ld1 = 2.0 * float(np.sum(np.log(diag)))
    M -= B.T @ B
    C = np.linalg.cholesky(M)
    ld = ld1 + 2.0 * float(np.sum(np.log(np.diag(C)[:qr])))
    return ld, C


def _factorise_patterns(theta, pr: Problem):
    """`_factorise` with the first term's levels taken a pattern at a time.

    Within a pattern every level has the same ``A = T' G T + I``, so the levels' share of the
    Schur complement, ``sum_j (Z1W_j S)' T A^-1 T' (Z1W_j S)``, is ``S' (sum_ab K_ab P_ab) S``
    with ``K = T A^-1 T'``: the cost no longer grows with the number of levels (162 stimuli are
    one pattern when every participant saw every stimulus).
    """
    q1, qr = pr.q_sizes[0], pr.q_rest
    M = pr.WW.copy()
    ld1 = 0.0
    if q1 == 1:
        t2 = theta[0] * theta[0]
        for members, P in pr.patterns:
            g = pr.G1[members[0], 0, 0]
            M -= (t2 / (t2 * g + 1.0)) * P[0, 0]
            ld1 += members.size * math.log(t2 * g + 1.0)
    else:
        T = term_factor(theta, pr.q_sizes, 0)
        for members, P in pr.patterns:
            A = T.T @ pr.G1[members[0]] @ T + np.eye(q1)
            L = np.linalg.cholesky(A)
            Q = np.linalg.solve(L, T.T)
            M -= np.tensordot(Q.T @ Q, P, axes=([0, 1], [0, 1]))
            ld1 += 2.0 * members.size * float(np.log(np.diag(L)).sum())
    if qr:
        lam = np.zeros((qr, qr))
        lam[pr.lam_rows, pr.lam_cols] = theta[pr.lam_theta]
        M[:qr, :] = lam.T @ M[:qr, :]
        M[:, :qr] = M[:, :qr] @ lam
        M.flat[: qr * (M.shape[0] + 1): M.shape[0] + 1] += 1.0
    C = _cholesky(M)
    return ld1 + 2.0 * float(np.log(C.diagonal()[:qr]).sum()), C


def _cholesky(M: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor by LAPACK's dpotrf (numpy's wrapper costs more than a 40 x 40
    factorisation); the upper triangle is left as garbage, so read only the lower one."""
    C, info = dpotrf(M, lower=1, clean=0, overwrite_a=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"not positive definite (dpotrf info {info})")
    return C


def deviance(theta, pr: Problem) -> float:
    """lme4's profiled deviance (ML) or REML criterion at ``theta``.

    Equals ``lmer(..., devFunOnly = TRUE)(theta)``.

    Parameters
    ----------
    theta : array_like
        Each term's factor, lower triangle column by column, terms in lme4's order.
    pr : Problem

    Returns
    -------
    float
        ``inf`` where the system is not positive definite (a theta the optimiser may probe).
    """
    if pr.cp is not None:
        return _deviance_fast(np.asarray(theta, float).tolist(), pr.cp)
    try:
        ld, C = _factorise(theta, pr)
    except np.linalg.LinAlgError:
        return math.inf
    r2 = float(C[-1, -1]) ** 2
    n, p = pr.n, pr.p
    if not pr.reml:
        return ld + n * (1.0 + math.log(2.0 * math.pi * r2 / n))
    qr = pr.q_rest
    ldRX = 2.0 * float(np.sum(np.log(np.diag(C)[qr:qr + p])))
    return ld + ldRX + (n - p) * (1.0 + math.log(2.0 * math.pi * r2 / (n - p)))


@dataclass(frozen=True)
class Solution:
    """Fixed effects and their covariance at theta.

    Attributes
    ----------
    beta : ndarray, shape (p,)
    vcov : ndarray, shape (p, p)
        ``sigma^2 (R_X' R_X)^-1``.
    sigma : float
        ML: ``r / sqrt(n)``; REML: ``r / sqrt(n - p)``.
    deviance : float
        The criterion (ML deviance or REML criterion).
    """

    beta: np.ndarray
    vcov: np.ndarray
    sigma: float
    deviance: float


def solve(theta, pr: Problem) -> Solution:
    """Profile beta and sigma out at ``theta`` (Bates et al. 2015, eqs. 30-33)."""
    ld, C = _factorise(theta, pr)
    qr, p, n = pr.q_rest, pr.p, pr.n
    RXt = np.tril(C[qr:qr + p, qr:qr + p])
    cb = C[-1, qr:qr + p]
    r2 = float(C[-1, -1]) ** 2
    beta = np.linalg.solve(RXt.T, cb)
    dof = n - p if pr.reml else n
    sigma2 = r2 / dof
    inv = np.linalg.inv(RXt)
    vcov = sigma2 * (inv.T @ inv)
    if pr.reml:
        dev = ld + 2.0 * float(np.sum(np.log(np.diag(RXt)))) + dof * (
            1.0 + math.log(2.0 * math.pi * sigma2))
    else:
        dev = ld + n * (1.0 + math.log(2.0 * math.pi * sigma2))
    return Solution(beta=beta, vcov=vcov, sigma=math.sqrt(sigma2), deviance=float(dev))
