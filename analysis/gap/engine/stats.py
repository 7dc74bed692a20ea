"""The tests every step of a diagnosis shares: Holm's correction, the bootstrap draws over
held-out units, and the paired test of a per-unit loss difference (percentile bootstrap, or a
cluster-robust normal approximation)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PairedTest", "Resamples", "boot_idx", "boot_means", "holm", "mean_test"]

#: Resamples held as one index array up to this many indices (8 bytes each, 128 MiB); beyond,
#: :class:`Resamples` draws them again in blocks at each use. The render layer's units are
#: pixels: 24 held-out photos of a 158 px sphere are 380,000 units, whose 1,000 resamples
#: as one array took 3 GB, and as many again for each mean taken over them.
MAX_STORED_INDICES = 2**24


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


class Resamples:
    """Bootstrap resamples of ``n`` units, too many to hold at once: drawn in blocks of rows
    from their own generator, seeded once, so that every use sees the same resamples (the
    tests stay paired) while memory holds one block (:data:`MAX_STORED_INDICES`)."""

    def __init__(self, seed: int, n: int, n_boot: int):
        self.seed, self.n, self.n_boot = int(seed), int(n), int(n_boot)

    @property
    def shape(self) -> tuple[int, int]:
        return self.n_boot, self.n

    def means(self, x: np.ndarray) -> np.ndarray:
        """The mean of each row of ``x`` (shape (k, n)) in each resample, shape (k, n_boot):
        the indices drawn once per block for all rows."""
        gen = np.random.default_rng(self.seed)
        rows = max(1, MAX_STORED_INDICES // 8 // max(self.n, 1))
        out = np.empty((x.shape[0], self.n_boot))
        for start in range(0, self.n_boot, rows):
            k = min(rows, self.n_boot - start)
            idx = gen.integers(0, self.n, size=(k, self.n), dtype=np.int32)
            for row, values in zip(out, x):
                row[start:start + k] = values[idx].mean(axis=1)
        return out


def boot_idx(rng: np.random.Generator, n: int, n_boot: int) -> np.ndarray | Resamples:
    """Bootstrap resamples of ``n`` held-out units, drawn once per diagnosis so that every
    test of it is paired on the same resamples: indices, shape (n_boot, n), or, beyond
    :data:`MAX_STORED_INDICES`, :class:`Resamples` (one seed drawn from ``rng``) that draws
    them block by block at each use. Use them through :func:`boot_means`."""
    if n * n_boot > MAX_STORED_INDICES:
        return Resamples(rng.integers(2**63), n, n_boot)
    return rng.integers(0, n, size=(n_boot, n))


def boot_means(x: np.ndarray, idx: np.ndarray | Resamples) -> np.ndarray:
    """The mean of the per-unit ``x`` in each resample of ``idx`` (:func:`boot_idx`): ``x`` of
    shape (n,) gives shape (n_boot,); several per-unit vectors, shape (k, n), give (k,
    n_boot), each on the same resamples."""
    x = np.asarray(x, float)
    rows = x[None] if x.ndim == 1 else x
    if isinstance(idx, Resamples):
        out = idx.means(rows)
    else:
        out = np.stack([r[idx].mean(axis=1) for r in rows])
    return out[0] if x.ndim == 1 else out


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
        b = boot_means(diff, idx)
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
    idx       ndarray (n_boot, n) or  the bootstrap resamples of the held-out units
              Resamples               (:func:`boot_idx`)
    clusters  ndarray (n,) or None    a cluster code per unit (then the cluster-robust
                                      normal approximation; see :func:`mean_test`)
    ========= ======================= ====================================================
    """

    idx: np.ndarray
    clusters: np.ndarray | None = None

    def __call__(self, diff: np.ndarray) -> tuple[float, float, float, float]:
        """(mean, CI low, CI high, one-sided p for mean > 0) of ``diff``, shape (n,)."""
        return mean_test(diff, self.idx, self.clusters)
