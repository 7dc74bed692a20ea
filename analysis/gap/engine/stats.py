"""The tests every step of a diagnosis shares: Holm's correction, the bootstrap draws over
held-out units, and the paired test of a per-unit loss difference (percentile bootstrap, or a
cluster-robust normal approximation)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PairedTest", "boot_idx", "holm", "mean_test"]


def holm(p: np.ndarray) -> np.ndarray:
    """Holm step-down adjusted p-values (Holm 1979), monotone and capped at 1."""
    p = np.asarray(p, float)
    order = np.argsort(p)
    m = p.size
    adj = np.empty(m)
    running = 0.0
    for rank, idx in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[idx]))
        adj[idx] = running
    return adj


def boot_idx(rng: np.random.Generator, n: int, n_boot: int) -> np.ndarray:
    """Bootstrap resamples of ``n`` held-out units: indices, shape (n_boot, n), drawn once per
    diagnosis so that every test of it is paired on the same resamples."""
    return rng.integers(0, n, size=(n_boot, n))


def mean_test(diff: np.ndarray, idx: np.ndarray,
              clusters: np.ndarray | None = None) -> tuple[float, float, float, float]:
    """(mean, CI low, CI high, one-sided p for mean > 0) of a per-unit difference.

    Without ``clusters``: percentile bootstrap over units (``idx``). With ``clusters`` (a code
    per unit; units sharing one are dependent): the normal approximation with a cluster-robust
    standard error (Liang & Zeger 1986), SE^2 = sum_g (sum_{i in g} (d_i - mean))^2 / n^2 --
    the limit of a bootstrap over clusters as its resamples grow, without its Monte-Carlo
    error (a p-value near alpha / k counted from a few hundred resamples rests on a handful of
    them, and flips with the seed)."""
    if clusters is None:
        b = diff[idx].mean(axis=1)
        lo, hi = np.percentile(b, [2.5, 97.5])
        p = (np.sum(b <= 0) + 1) / (b.size + 1)
        return float(diff.mean()), float(lo), float(hi), float(p)
    from scipy.stats import norm

    mean = float(diff.mean())
    se = float(np.sqrt(np.sum(np.bincount(clusters, weights=diff - mean) ** 2)) / diff.size)
    if se <= 0:
        return mean, mean, mean, 0.0 if mean > 0 else 1.0
    return mean, mean - 1.96 * se, mean + 1.96 * se, float(norm.sf(mean / se))


@dataclass(frozen=True, eq=False)
class PairedTest:
    """The test of a per-unit loss difference that every step of one diagnosis uses.

    ========= ======================= ====================================================
    field     type                    meaning
    ========= ======================= ====================================================
    idx       ndarray (n_boot, n)     the bootstrap resamples of the held-out units
    clusters  ndarray (n,) or None    a cluster code per unit (then the cluster-robust
                                      normal approximation; see :func:`mean_test`)
    ========= ======================= ====================================================
    """

    idx: np.ndarray
    clusters: np.ndarray | None = None

    def __call__(self, diff: np.ndarray) -> tuple[float, float, float, float]:
        """(mean, CI low, CI high, one-sided p for mean > 0) of ``diff``, shape (n,)."""
        return mean_test(diff, self.idx, self.clusters)
