"""The simulation's prediction and likelihood for one response on a rating scale (observer
layer, another lab's study).

The simulation is the rating observer fitted to a pilot (:mod:`experiment.rating_observer`):
a latent response ``offset + gain (x - x_mid)`` plus Gaussian noise, read out on the scale's
own steps (an ordered probit: integer ratings are part of the simulation, not a gap), with
lapses. :class:`RatingBase` holds its population values and between-observer SDs;
:func:`adapt_rating_base` gives each diagnosed participant their own gain and offset within
that spread (a MAP fit on their training trials with the population as the prior), so
individual differences the simulated observer allows are no gap. :func:`rating_predict`
extends the base by chosen candidates; :func:`rating_loss` is the engine's loss (per-trial NLL,
nats; the noise SD fitted on the training data for every model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import optimize

from experiment import rating_levels, rating_mean, rating_nll, rating_probs

__all__ = ["RatingBase", "adapt_rating_base", "rating_expected", "rating_floor",
           "rating_loss", "rating_nll_of", "rating_predict"]


@dataclass(frozen=True)
class RatingBase:
    """The simulated rating observer (population), scale units; ``gain`` per unit of the
    factor, ``x`` = factor - ``factor_mid``.

    Attributes
    ----------
    gain, offset : float
        Population means.
    gain_sd, offset_sd : float
        Between-observer SDs (how far one observer may depart).
    noise : float
        Latent noise SD.
    lapse_rate : float
    factor_mid : float
    participants : tuple of str
        The pilot's participants.
    source : str
    """

    gain: float
    offset: float
    gain_sd: float
    offset_sd: float
    noise: float
    lapse_rate: float
    factor_mid: float
    participants: tuple = ()
    source: str = ""


def _own_map(y, x, base: RatingBase, scale, step) -> tuple[float, float]:
    """A participant's MAP gain and offset (noise and lapses at the population's)."""
    prior_sd = np.maximum([base.gain_sd, base.offset_sd], 1e-6)
    prior_mean = np.array([base.gain, base.offset])

    def f(t):
        nll = rating_nll(y, t[1] + t[0] * x, base.noise, base.lapse_rate, scale, step).sum()
        return nll + 0.5 * np.sum(((t - prior_mean) / prior_sd) ** 2)
    return tuple(optimize.minimize(f, prior_mean, method="Nelder-Mead",
                                   options={"xatol": 1e-4, "fatol": 1e-6}).x)


def adapt_rating_base(train: pd.DataFrame, test: pd.DataFrame, base: RatingBase) -> None:
    """Set ``mu_base`` (the latent mean) in place: each participant's own gain and offset where
    they have training trials (:func:`_own_map`), else the population's."""
    scale, step = train.attrs["scale"], train.attrs["step"]
    for frame in (train, test):
        frame["mu_base"] = base.offset + base.gain * frame["x"].to_numpy(float)
    if base.gain_sd <= 0 and base.offset_sd <= 0:
        return
    for pid, rows in train.groupby("participant"):
        g, a = _own_map(rows["response"].to_numpy(float), rows["x"].to_numpy(float), base,
                        scale, step)
        for frame in (train, test):
            m = (frame["participant"] == pid).to_numpy()
            frame.loc[m, "mu_base"] = a + g * frame.loc[m, "x"].to_numpy(float)


def rating_predict(data: pd.DataFrame, fitted: list, cands: dict) -> dict:
    """The base extended by ``fitted`` (``[(name, params), ...]``, candidates ``cands`` by
    name): ``{"mu": latent mean, "lapse": rate, "coarse": weight}``."""
    pred = {"mu": data["mu_base"].to_numpy(float).copy(),
            "lapse": float(data.attrs["base_lapse"]), "coarse": 0.0}
    for name, p in fitted:
        pred = cands[name].apply(data, pred, p)
    return pred


def rating_nll_of(data: pd.DataFrame, pred: dict, sigma: float) -> np.ndarray:
    """Per-trial NLL (nats) of the responses under ``pred`` at noise SD ``sigma``; with a
    coarse-rounding weight, a share of the latent responses is read out at the nearest
    labelled point instead of the nearest step."""
    scale, step = data.attrs["scale"], data.attrs["step"]
    y = data["response"].to_numpy(float)
    nll = rating_nll(y, pred["mu"], sigma, pred["lapse"], scale, step)
    w = pred["coarse"]
    if w <= 0:
        return nll
    labels = np.asarray(data.attrs["labels"], float)
    edges = np.r_[-np.inf, 0.5 * (labels[1:] + labels[:-1]), np.inf]
    from scipy.special import ndtr

    mu = pred["mu"][:, None]
    p_lab = np.diff(ndtr((edges[None, :] - mu) / sigma), axis=1)
    on = np.isclose(y[:, None], labels[None, :])
    p_coarse = (1 - pred["lapse"]) * (p_lab * on).sum(axis=1)
    p = (1 - w) * np.exp(-nll) + w * p_coarse
    return -np.log(np.maximum(p, 1e-300))


def _fit_sigma(train: pd.DataFrame, pred: dict) -> float:
    """ML noise SD given the prediction (bounded search)."""
    span = float(np.subtract(*train.attrs["scale"][::-1]))
    opt = optimize.minimize_scalar(lambda ls: rating_nll_of(train, pred, np.exp(ls)).sum(),
                                   bounds=(np.log(span / 200), np.log(span)), method="bounded",
                                   options={"xatol": 1e-3})
    return float(np.exp(opt.x))


def rating_loss(cands: dict):
    """The engine's loss: ``loss(train)`` returns ``loss(data, fitted)``, per-trial NLL (nats)
    with the noise SD fitted on ``train`` for each model."""
    def per_fold(train: pd.DataFrame):
        cache = {}

        def loss(data: pd.DataFrame, fitted: list) -> np.ndarray:
            key = repr(fitted)
            if key not in cache:
                cache[key] = _fit_sigma(train, rating_predict(train, fitted, cands))
            return rating_nll_of(data, rating_predict(data, fitted, cands), cache[key])
        return loss
    return per_fold


def rating_expected(data: pd.DataFrame, pred: dict, sigma: float) -> np.ndarray:
    """Expected response (scale units) under ``pred`` (coarse rounding ignored)."""
    return rating_mean(pred["mu"], sigma, pred["lapse"], data.attrs["scale"],
                       data.attrs["step"])


def rating_floor(train: pd.DataFrame, test: pd.DataFrame, cands: dict) -> np.ndarray:
    """The noise floor per held-out trial: the plain simulation's expected NLL of a response
    drawn from itself (its predictive entropy, nats), the noise SD fitted on ``train``."""
    pred = rating_predict(test, [], cands)
    sigma = _fit_sigma(train, rating_predict(train, [], cands))
    scale, step = test.attrs["scale"], test.attrs["step"]
    if step > 0:
        p = rating_probs(pred["mu"], sigma, pred["lapse"], scale, step)
        return -(p * np.log(np.maximum(p, 1e-300))).sum(axis=1)
    # Continuous: Monte-Carlo over 20 draws per trial from a fixed generator.
    rng = np.random.default_rng(0)
    mu = np.repeat(pred["mu"], 20)
    lo, hi = scale
    y = np.clip(mu + sigma * rng.standard_normal(mu.size), lo, hi)
    lapse = rng.random(mu.size) < pred["lapse"]
    y = np.where(lapse, rng.uniform(lo, hi, mu.size), y)
    nll = rating_nll(y, mu, sigma, pred["lapse"], scale, step)
    return nll.reshape(-1, 20).mean(axis=1)


def levels_of(data: pd.DataFrame) -> np.ndarray:
    """The scale's steps of ``data`` (empty: continuous)."""
    return rating_levels(data.attrs["scale"], data.attrs["step"])
