"""The ceiling (the flexible model) for one response on a rating scale.

The chosen model's latent mean plus corrections fitted to the training trials by Newton's
method on the ordered-probit likelihood (each trial's working residual ``-g/h`` with weight
``h``, ``g`` and ``h`` the first and second derivatives of its NLL in the latent mean, as in
iteratively reweighted least squares): per-stimulus offsets shrunk across participants
(empirical Bayes, only the part that replicates *across* participants counts,
:func:`analysis.gap.observer.offsets._cell_offsets`), each participant's own gain and offset,
a cubic in the factor and the pull of the previous response (a light ridge penalty); then the
noise SD refitted. The remaining gap is tested against it (the engine's paired test).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.observer.offsets import _cell_offsets
from analysis.gap.observer.rating.model import (
    _fit_sigma,
    rating_floor,
    rating_nll_of,
    rating_predict,
)

__all__ = ["rating_ceiling_fit", "rating_ceiling_floor", "rating_ceiling_loss",
           "working_residuals"]

_RIDGE = 1e-2  # per unit weight, on columns scaled to unit mean square
_ROUNDS = 3   # backfitting rounds of the two corrections


def working_residuals(data: pd.DataFrame, pred: dict, sigma: float):
    """Per trial the Newton step in the latent mean (``-g/h``, scale units) and its weight
    ``h`` (floored, so a trial the likelihood hardly constrains gets little weight)."""
    eps = 1e-3
    f0 = rating_nll_of(data, pred, sigma)
    fp = rating_nll_of(data, {**pred, "mu": pred["mu"] + eps}, sigma)
    fm = rating_nll_of(data, {**pred, "mu": pred["mu"] - eps}, sigma)
    g = (fp - fm) / (2 * eps)
    h = np.maximum((fp - 2 * f0 + fm) / eps ** 2, 0.05 / sigma ** 2)
    return np.clip(-g / h, -3 * sigma, 3 * sigma), h


def _design(data: pd.DataFrame, parts: tuple, mu: np.ndarray) -> np.ndarray:
    x = data["x"].to_numpy(float)
    s = max(float(np.std(x)), 1e-9)
    u = x / s
    prev = data["prev"].to_numpy(float)
    pull = np.where(np.isnan(prev), 0.0, prev - mu)
    who = data["participant"].to_numpy(str)
    own = [(who == q).astype(float) for q in parts]
    return np.c_[np.ones(x.size), u, u ** 2, u ** 3, pull, *[o * v for o in own for v in (1, u)]]


def _ridge(x, y, w):
    ms = np.mean(x * x, axis=0)
    pen = np.diag(np.where(ms > 0, ms, 1.0)) * _RIDGE * w.sum()
    pen[0, 0] = 0.0
    a = x.T @ (w[:, None] * x) + pen + 1e-9 * np.eye(x.shape[1])
    return np.linalg.solve(a, x.T @ (w * y))


def _fit(train: pd.DataFrame, fitted: list, cands: dict):
    """The ceiling's corrections: (stimulus offsets, linear coefficients, participants)."""
    pred = rating_predict(train, fitted, cands)
    sigma = _fit_sigma(train, pred)
    parts = tuple(sorted(train["participant"].unique()))
    stim = train["stimulus"].to_numpy(str)
    who = train["participant"].to_numpy(str)
    x = _design(train, parts, pred["mu"])
    offsets, coef = {}, np.zeros(x.shape[1])
    lin, off = np.zeros(len(train)), np.zeros(len(train))
    for _ in range(_ROUNDS):
        z, h = working_residuals(train, {**pred, "mu": pred["mu"] + lin + off}, sigma)
        target = lin + off + z
        offsets = _cell_offsets(target - lin, stim, who, h)
        off = pd.Series(stim).map(offsets).fillna(0.0).to_numpy(float)
        coef = _ridge(x, target - off, h)
        lin = x @ coef
    return offsets, coef, parts


def _corrected(data, fitted, cands, offsets, coef, parts):
    pred = rating_predict(data, fitted, cands)
    x = _design(data, parts, pred["mu"])
    add = x @ coef + pd.Series(data["stimulus"].to_numpy(str)).map(offsets).fillna(
        0.0).to_numpy(float)
    return {**pred, "mu": pred["mu"] + add}


def rating_ceiling_fit(train: pd.DataFrame, fitted: list, cands: dict):
    """The ceiling built on the chosen model ``fitted``, fitted on ``train``:
    ``predict(data) -> (pred, sigma)``, its prediction on ``data`` (as
    :func:`rating_predict`'s, the latent mean corrected) and its noise SD (scale units)."""
    offsets, coef, parts = _fit(train, fitted, cands)
    sigma = _fit_sigma(train, _corrected(train, fitted, cands, offsets, coef, parts))

    def on(data):
        return _corrected(data, fitted, cands, offsets, coef, parts), sigma
    return on


def rating_ceiling_loss(train: pd.DataFrame, test: pd.DataFrame, fitted: list,
                        cands: dict, model=None) -> np.ndarray:
    """Per held-out trial NLL (nats) of the ceiling built on the chosen model ``fitted``
    (``model``: that ceiling, :func:`rating_ceiling_fit`, where already fitted)."""
    pred, sigma = (model or rating_ceiling_fit(train, fitted, cands))(test)
    return rating_nll_of(test, pred, sigma)


def rating_ceiling_floor(train: pd.DataFrame, test: pd.DataFrame, cands: dict) -> np.ndarray:
    """The noise floor per held-out trial: the predictive entropy (nats) of the ceiling built
    on the plain simulation, the expected loss of a model right up to its own noise."""
    from experiment import rating_probs

    offsets, coef, parts = _fit(train, [], cands)
    sigma = _fit_sigma(train, _corrected(train, [], cands, offsets, coef, parts))
    pred = _corrected(test, [], cands, offsets, coef, parts)
    scale, step = test.attrs["scale"], test.attrs["step"]
    if step <= 0:
        return rating_floor(train, test, cands)
    p = rating_probs(pred["mu"], sigma, pred["lapse"], scale, step)
    return -(p * np.log(np.maximum(p, 1e-300))).sum(axis=1)
