"""Type II Wald chi-square tests per term, with the semantics of R's ``car::Anova(type = 2)``.

For a term, its *relatives* are the higher-order terms that contain it (gloss:depth contains gloss
and depth). car's ``Anova.II.mer`` tests the term after its marginal terms and before its
relatives: with ``H1`` the identity rows of the relatives' coefficients and ``H2`` those rows
plus the term's own, the hypothesis matrix is the part of ``H2``'s row space conjugate to
``H1``'s under the inner product of the fixed-effect covariance (car's ``ConjComp``):

``ConjComp(X, Z, V)``: ``Z Q[:, r:]`` where ``Q`` is the complete Q of the QR decomposition of
``Z' V X`` and ``r`` its rank. The Wald statistic ``(L b)' (L V L')^-1 (L b)`` on ``df = rows(L)``
does not depend on which basis of that space ``L`` holds, so numpy's QR signs do not matter.
"""

from __future__ import annotations

import functools
import json
import operator
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

__all__ = ["WaldTest", "hypothesis_matrices", "hypothesis_matrix", "type2_wald", "wald_chi2"]


@dataclass(frozen=True)
class WaldTest:
    """One term's Type II Wald test.

    Attributes
    ----------
    term : str
    chi2 : float
    df : int
        Rows of the hypothesis (coefficients of the term; 2 for a three-level factor).
    p : float
        Upper tail of the chi-square distribution with ``df`` degrees of freedom.
    """

    term: str
    chi2: float
    df: int
    p: float

    def to_json(self) -> str:
        return json.dumps(asdict(self))


def _conj_comp(X: np.ndarray, Z: np.ndarray, ip: np.ndarray) -> np.ndarray:
    """car's ``ConjComp``: the complement of span(X) in span(Z) conjugate under ``ip``."""
    M = Z.T @ ip @ X
    Q, R = np.linalg.qr(M, mode="complete")
    # R's qr() rank: diagonal elements of R above 1e-7 of the largest column norm.
    diag = np.abs(np.diag(R))
    rank = int(np.sum(diag > 1e-7 * max(float(np.max(np.linalg.norm(M, axis=0))), 1e-300)))
    if rank == 0:
        return Z
    return Z @ Q[:, rank:]


def hypothesis_matrix(term: str, vcov, *, terms, assign, term_factors) -> np.ndarray:
    """car's Type II hypothesis matrix for ``term`` (rows: contrasts of the coefficients).

    Parameters
    ----------
    term : str
        A fixed-effect term, e.g. ``"gloss"`` or ``"illumination"``.
    vcov : ndarray, shape (p, p)
        Fixed-effect covariance.
    terms : sequence of str
        The model's terms without the intercept (`analysis.lmm.LmmFit.terms`).
    assign : sequence of int
        Per coefficient, its term's index (-1: intercept).
    term_factors : sequence of collection of str
        Per term, its variables; a term's relatives are the other terms containing all of them.

    Returns
    -------
    ndarray, shape (k, p)

    Raises
    ------
    ValueError
        If ``term`` is not one of ``terms``.
    """
    terms = list(terms)
    if term not in terms:
        raise ValueError(f"unknown term {term!r}; the model's terms are {terms}")
    vcov = np.asarray(vcov, float)
    assign = np.asarray(assign)
    k = terms.index(term)
    mine = set(term_factors[k])
    eye = np.eye(assign.size)
    own = np.flatnonzero(assign == k).tolist()
    relatives = [np.flatnonzero(assign == j).tolist() for j in range(len(terms))
                 if j != k and mine <= set(term_factors[j])]
    relatives = functools.reduce(operator.iadd, relatives, [])
    H2 = eye[relatives + own]
    if not relatives:
        return H2
    H1 = eye[relatives]
    L = _conj_comp(H1.T, H2.T, vcov).T
    return L[~np.all(L == 0, axis=1)]


def wald_chi2(L: np.ndarray, beta: np.ndarray, vcov: np.ndarray, beta0=None) -> float:
    """``(L (b - b0))' (L V L')^-1 (L (b - b0))`` (car's ``linearHypothesis``, test "Chisq")."""
    diff = beta if beta0 is None else beta - beta0
    Lb = L @ diff
    return float(Lb @ np.linalg.solve(L @ vcov @ L.T, Lb))


def hypothesis_matrices(fit) -> dict:
    """car's Type II hypothesis matrix of every term of a fitted model, in ``fit.terms`` order."""
    V = fit.vcov_array()
    return {t: hypothesis_matrix(t, V, terms=fit.terms, assign=fit.assign,
                                 term_factors=fit.term_factors) for t in fit.terms}


def type2_wald(fit) -> tuple[WaldTest, ...]:
    """Type II Wald chi-square test of every fixed-effect term, as ``car::Anova(fit, type = 2)``.

    Parameters
    ----------
    fit : analysis.lmm.LmmFit

    Returns
    -------
    tuple of WaldTest
        In the order of ``fit.terms`` (car's row order).
    """
    beta = fit.fixef_array()
    V = fit.vcov_array()
    out = []
    for term, L in hypothesis_matrices(fit).items():
        chi2 = wald_chi2(L, beta, V)
        df = L.shape[0]
        out.append(WaldTest(term=term, chi2=chi2, df=df, p=float(stats.chi2.sf(chi2, df))))
    return tuple(out)
