"""Held-out units: one random split (:func:`split_held_out`) or cross-fitting
(:class:`CrossFit`: every unit held out once per repeat, per-unit losses averaged over
repeats), so that a verdict does not hinge on one random split."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from analysis.gap.engine.errors import GapError

__all__ = ["CrossFit", "cluster_codes", "cross_fit", "split_held_out"]


def split_held_out(data, held_out, rng: np.random.Generator):
    """(train, test) rows of a data frame; ``held_out`` is a boolean mask, or None for a random
    half of the rows. Both parts keep ``data.attrs`` (the loaders' metadata)."""
    if held_out is None:
        held_out = np.zeros(len(data), bool)
        held_out[rng.permutation(len(data))[: len(data) // 2]] = True
    train, test = data[~held_out].copy(), data[held_out].copy()
    train.attrs, test.attrs = dict(data.attrs), dict(data.attrs)
    return train, test


class CrossFit:
    """Cross-fitting: per fold a (train, test, loss) triple; per-unit vectors are the held-out
    values of every fold, averaged over repeats by unit id.

    ``units`` are the held-out units' names in the order of the per-unit vectors (sorted
    with several folds; the test's order with one; None without ``unit_ids``)."""

    def __init__(self, folds, loss, unit_ids):
        self.folds = folds
        self.loss = loss
        ids = [np.asarray([str(u) for u in unit_ids(te)]) if unit_ids else None
               for _, te, _ in folds]
        self.ids = ids
        if len(folds) > 1:
            flat = np.concatenate(ids)
            self.codes, self.units = pd.factorize(pd.Series(flat), sort=True)
        else:
            self.codes, self.units = None, ids[0]

    def per_unit(self, parts: list[np.ndarray]) -> np.ndarray:
        """One value per held-out unit from one array per fold (averaged over repeats)."""
        v = np.concatenate([np.asarray(p, float) for p in parts])
        if self.codes is None:
            return v
        sums = np.bincount(self.codes, weights=v, minlength=len(self.units))
        return sums / np.bincount(self.codes, minlength=len(self.units))

    def losses(self, chosen: list[list]) -> np.ndarray:
        """Per-unit held-out loss with ``chosen[k]`` (``[(name, params), ...]``) in fold k."""
        return self.per_unit([lf(te, ch) for (_, te, lf), ch in zip(self.folds, chosen)])

    def nothing_chosen(self) -> list[list]:
        """An empty chosen list per fold (the plain simulation)."""
        return [[] for _ in range(len(self.folds))]

    def fit(self, cand, chosen: list[list]) -> list:
        """``cand``'s parameters fitted on each fold's training data given its ``chosen``."""
        return [cand.fit(tr, ch) for (tr, _, _), ch in zip(self.folds, chosen)]


def cross_fit(layer: str, loss: Callable, unit_ids: Callable | None, train, test,
              folds: Sequence | None) -> CrossFit:
    """The held-out units of one split (``train``, ``test``; ``loss(data, fitted)``) or of
    ``folds`` (``[(train, test), ...]``; ``loss(train)`` returns that fold's loss).

    Raises
    ------
    GapError
        If ``folds`` is empty, or has several folds without ``unit_ids``.
    """
    if folds is None:
        return CrossFit([(train, test, loss)], loss, unit_ids)
    if not folds:
        raise GapError(f"layer {layer!r}: no folds given")
    if len(folds) > 1 and unit_ids is None:
        raise GapError("cross-fitting needs unit_ids to average a unit over repeats")
    return CrossFit([(tr, te, loss(tr)) for tr, te in folds], loss, unit_ids)


def cluster_codes(cv: CrossFit, cluster_of: Callable[[str], str] | None) -> np.ndarray | None:
    """An integer code per held-out unit naming its cluster (``cluster_of(unit_id)``), or None
    without ``cluster_of``.

    Raises
    ------
    GapError
        If ``cluster_of`` is given but the units have no names (no ``unit_ids``).
    """
    if cluster_of is None:
        return None
    if cv.units is None:
        raise GapError("cluster_of needs unit_ids to name the units")
    return pd.factorize(pd.Series([cluster_of(str(u)) for u in cv.units]))[0]
