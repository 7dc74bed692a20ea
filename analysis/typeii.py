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

import json
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

from analysis.lmm import FIXED_TERMS

__all__ = ["WaldTest", "hypothesis_matrix", "type2_wald", "wald_chi2"]


@dataclass(frozen=True)
class WaldTest:
    """One term's Type II Wald test.

    Attributes
    ----------
    term : str
    chi2 : float
    df : int
    p : float
        Upper tail of the chi-square distribution with ``df`` degrees of freedom.
    """

    term: str
    chi2: float
    df: int
    p: float

    def to_json(self) -> str:
        return json.dumps(asdict(self))


def _factors(term: str) -> frozenset:
    return frozenset(term.split(":"))


def _conj_comp(X: np.ndarray, Z: np.ndarray, ip: np.ndarray) -> np.ndarray:
    """car's ``ConjComp``: the complement of span(X) in span(Z) conjugate under ``ip``."""
    M = Z.T @ ip @ X
    rank = np.linalg.matrix_rank(M)
    if rank == 0:
        return Z
    Q, _ = np.linalg.qr(M, mode="complete")
    return Z @ Q[:, rank:]


def hypothesis_matrix(term: str, vcov: np.ndarray, terms=FIXED_TERMS) -> np.ndarray:
    """car's Type II hypothesis matrix for ``term`` (rows: contrasts of the coefficients).

    Parameters
    ----------
    term : str
        A term of ``terms`` other than the intercept, e.g. ``"gloss"``.
    vcov : ndarray, shape (p, p)
        Fixed-effect covariance.
    terms : sequence of str
        Coefficient names; one coefficient per term, the first the intercept.

    Returns
    -------
    ndarray, shape (k, p)
    """
    if term not in terms[1:]:
        raise ValueError(f"unknown term {term!r}; the model's terms are {list(terms[1:])}")
    p = len(terms)
    eye = np.eye(p)
    own = [terms.index(term)]
    relatives = [i for i, t in enumerate(terms[1:], start=1)
                 if t != term and _factors(term) < _factors(t)]
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


def type2_wald(beta, vcov, terms=FIXED_TERMS) -> tuple[WaldTest, ...]:
    """Type II Wald chi-square test of every term but the intercept.

    Parameters
    ----------
    beta : array_like, shape (p,)
        Fixed effects, in the order of ``terms``.
    vcov : array_like, shape (p, p)
        Their covariance (lme4's ``vcov``).
    terms : sequence of str

    Returns
    -------
    tuple of WaldTest
        In the order of ``terms[1:]`` (car's row order).
    """
    beta = np.asarray(beta, float)
    vcov = np.asarray(vcov, float)
    out = []
    for term in terms[1:]:
        L = hypothesis_matrix(term, vcov, terms)
        chi2 = wald_chi2(L, beta, vcov)
        df = L.shape[0]
        out.append(WaldTest(term=term, chi2=chi2, df=df, p=float(stats.chi2.sf(chi2, df))))
    return tuple(out)
