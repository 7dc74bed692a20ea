"""An image-statistics observer: perceived gloss predicted from image statistics alone.

A candidate explanation of human gloss matches (for the sim-to-real diagnosis): if people judged
gloss from these statistics, their matches would be ``predict(stats)``. The model is a ridge
regression of the mean perceived gloss of each stimulus cell on the standardised statistics,
with the ridge penalty chosen by leave-one-out cross-validation (closed form, Hastie et al. 2009
eq. 7.52 via the hat matrix).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

from analysis.imagestats.images import ImageStatsError
from analysis.imagestats.relate import (
    CELL,
    SCALAR_STATS,
    join_perception,
    project_ps,
    ps_components,
)

__all__ = ["ImageStatsObserver"]

_PENALTIES = tuple(10.0 ** np.arange(-3, 4.01, 0.5))


def _features(stats: pd.DataFrame, features: tuple, ps_basis: dict | None) -> pd.DataFrame:
    missing = [c for c in features if not c.startswith("ps_pc") and c not in stats.columns]
    if missing:
        raise ImageStatsError(f"the statistics table lacks {missing}, which the observer uses")
    frame = stats[[c for c in features if not c.startswith("ps_pc")]].astype(float)
    if ps_basis is not None:
        frame = pd.concat([frame, project_ps(stats, ps_basis)], axis=1)
    return frame[list(features)]


@dataclass(frozen=True)
class ImageStatsObserver:
    """Perceived gloss (%) as a ridge regression on image statistics.

    Build it with `ImageStatsObserver.fit`; it round-trips through JSON (`to_json`,
    `from_json`).

    Attributes
    ----------
    features : tuple of str
        Statistics used (`SCALAR_STATS` and, optionally, ``ps_pc1..``).
    mean, sd : tuple of float
        Standardisation of each feature (over the fitting images).
    coef : tuple of float
        Ridge coefficients on the standardised features, % per SD.
    intercept : float
        %.
    penalty : float
        Ridge penalty chosen by leave-one-out CV.
    loo_r2 : float
        Leave-one-out R^2 of the cell means at that penalty (out-of-sample fit).
    r2 : float
        In-sample R^2.
    n_cells : int
        Stimulus cells fitted.
    ps_basis : dict or None
        PS principal axes (see `ps_components`) when ``ps_pc*`` features are used.
    """

    features: tuple
    mean: tuple
    sd: tuple
    coef: tuple
    intercept: float
    penalty: float
    loo_r2: float
    r2: float
    n_cells: int
    ps_basis: dict | None = field(default=None, repr=False)

    @classmethod
    def fit(cls, stats: pd.DataFrame, trials: pd.DataFrame, *,
            features: tuple = SCALAR_STATS, n_ps_components: int = 0) -> ImageStatsObserver:
        """Fit to the mean perceived gloss of each stimulus cell.

        Parameters
        ----------
        stats : DataFrame
            An image-statistics table (`load_stats`).
        trials : DataFrame
            Session trials with ``gloss_match_pct`` (``load_sessions(...).frame``).
        features : tuple of str
            Scalar statistics to use.
        n_ps_components : int
            Also use this many principal components of the PS statistics.

        Only cells with images in ``stats`` are fitted (see `join_perception`).

        Raises
        ------
        ImageStatsError
            If the table lacks a feature, or has images of fewer cells than features + 2.
        """
        features = tuple(features)
        basis = None
        stats = stats.reset_index(drop=True)
        if n_ps_components > 0:
            _, basis = ps_components(stats, n_components=n_ps_components)
            features += tuple(f"ps_pc{i + 1}" for i in range(len(basis["axes"])))
        x_all = _features(stats, features, basis)
        frame = pd.concat([stats[["stimulus_id", *CELL, "true_gloss_pct", "true_depth_cm"]],
                           x_all], axis=1)
        joined, _, _ = join_perception(frame, list(features), trials)
        cells = joined.groupby(list(CELL), as_index=False)[
            ["gloss_match_pct", *features]].mean()
        if len(cells) < len(features) + 2:
            raise ImageStatsError(
                f"{len(cells)} stimulus cells are too few to fit {len(features)} features"
            )
        x = cells[list(features)].to_numpy(np.float64)
        y = cells["gloss_match_pct"].to_numpy(np.float64)
        mean, sd = x.mean(axis=0), x.std(axis=0)
        sd[sd == 0] = 1.0
        z = (x - mean) / sd
        best = None
        for penalty in _PENALTIES:
            coef, icpt, loo = _ridge_loo(z, y, penalty)
            if best is None or loo < best[3]:
                best = (penalty, coef, icpt, loo)
        penalty, coef, icpt, loo = best
        ss = np.sum((y - y.mean()) ** 2)
        r2 = 1 - np.sum((y - icpt - z @ coef) ** 2) / ss
        return cls(features=features, mean=tuple(mean.tolist()), sd=tuple(sd.tolist()),
                   coef=tuple(coef.tolist()), intercept=float(icpt), penalty=float(penalty),
                   loo_r2=float(1 - loo * len(y) / ss), r2=float(r2), n_cells=len(cells),
                   ps_basis=basis)

    def predict(self, stats: pd.DataFrame) -> pd.Series:
        """Predicted perceived gloss (%) of every image of a statistics table.

        Returns
        -------
        Series
            Indexed by ``stimulus_id``, named ``gloss_pct_predicted``.
        """
        x = _features(stats.reset_index(drop=True), self.features, self.ps_basis)
        z = (x.to_numpy(np.float64) - np.asarray(self.mean)) / np.asarray(self.sd)
        pred = self.intercept + z @ np.asarray(self.coef)
        return pd.Series(pred, index=stats["stimulus_id"].to_numpy(), name="gloss_pct_predicted")

    def predict_trials(self, trials: pd.DataFrame, stats: pd.DataFrame) -> np.ndarray:
        """Predicted perceived gloss (%) of each trial (row) of a session frame.

        Trials are matched by ``stimulus_id`` when the table holds them all, else by design cell
        (mean prediction over the cell's images).

        Raises
        ------
        ImageStatsError
            If a trial's stimulus (or cell) has no image in ``stats``.
        """
        pred = self.predict(stats)
        if set(trials["stimulus_id"]) <= set(pred.index):
            return pred.loc[trials["stimulus_id"]].to_numpy()
        per_cell = stats[list(CELL)].assign(pred=pred.to_numpy()).groupby(list(CELL))[
            "pred"].mean()
        keys = pd.MultiIndex.from_frame(trials[list(CELL)])
        missing = ~keys.isin(per_cell.index)
        if missing.any():
            raise ImageStatsError(
                f"{int(missing.sum())} trials show cells without images in the statistics table "
                f"(e.g. {keys[missing][0]})"
            )
        return per_cell.loc[keys].to_numpy()

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ImageStatsObserver:
        raw = json.loads(text)
        for key in ("features", "mean", "sd", "coef"):
            raw[key] = tuple(raw[key])
        return cls(**raw)


def _ridge_loo(z: np.ndarray, y: np.ndarray, penalty: float) -> tuple[np.ndarray, float, float]:
    """Ridge fit (unpenalised intercept) and its leave-one-out mean squared error."""
    n, k = z.shape
    design = np.column_stack([np.ones(n), z])
    reg = penalty * np.eye(k + 1)
    reg[0, 0] = 0.0
    inv = np.linalg.inv(design.T @ design + reg)
    beta = inv @ design.T @ y
    hat = np.einsum("ij,jk,ik->i", design, inv, design)
    resid = (y - design @ beta) / (1 - hat)
    return beta[1:], float(beta[0]), float(np.mean(resid**2))
