"""The simulated observer of a one-response rating study (``study.toml``), and its fit to a pilot.

The observer judges one stimulus factor ``x`` (``[response] estimates``) on the study's scale::

    latent   = offset + gain (x - x_mid) + e,        e ~ N(0, noise^2)     (scale units)
    response = the scale's step nearest to latent, clipped to the scale's ends
               (with probability 1 - lapse_rate), else a step drawn uniformly

``x_mid`` is the middle of the stimuli's factor range, so ``offset`` is the response at a
middling stimulus and ``gain`` the response's change per unit of the factor. The scale's own
steps and ends are part of the model (an ordered-probit likelihood with equally spaced
thresholds half a step either side of each step: the probability of a step is the latent
density's mass over its interval, the end steps taking the tails), so integer ratings are no
gap. A continuous scale (``step = 0``) is censored at its ends instead.

:func:`fit_rating_observers` fits every participant of a pilot by maximum likelihood (gain,
offset, noise, lapse rate; standard errors from the observed information) and the population
by the method of moments (mean; between-observer SD = the estimates' variance less their mean
squared standard error, floored at 0); ``python -m experiment fit-observer DIR --study
DIR/study.toml --out observers.toml`` writes the result (:func:`write_rating_observers`).
"""

from __future__ import annotations

import tomllib
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import optimize
from scipy.special import expit, logit, ndtr

from experiment.observers import _refuse_non_finite
from labfiles import LabFileError, read_toml

__all__ = ["RATING_PARAMS", "fit_rating_observers", "load_rating_observers",
           "rating_levels", "rating_nll", "rating_probs", "simulate_ratings",
           "write_rating_observers"]

#: A participant's parameters, in the file's order.
RATING_PARAMS = ("gain", "offset", "noise", "lapse_rate")
_MAX_LAPSE = 0.5
_WINDOW = 0.025  # a continuous response this close to an end counts as at it (scale units)


def rating_levels(scale, step: float) -> np.ndarray:
    """The scale's steps (its ends included); empty for a continuous scale."""
    lo, hi = scale
    if step <= 0:
        return np.empty(0)
    return lo + step * np.arange(round((hi - lo) / step) + 1)


def rating_probs(mu, sigma, lapse, scale, step: float) -> np.ndarray:
    """Probability of each step (columns, :func:`rating_levels`) per trial (rows).

    ``mu`` (latent mean, scale units), ``sigma`` (noise SD) and ``lapse`` broadcast over trials.
    """
    levels = rating_levels(scale, step)
    mu = np.atleast_1d(np.asarray(mu, float))[:, None]
    sd = np.maximum(np.broadcast_to(np.asarray(sigma, float), mu.shape[:1])[:, None], 1e-6)
    edges = np.r_[-np.inf, levels[:-1] + step / 2, np.inf]
    cdf = ndtr((edges[None, :] - mu) / sd)
    p = np.diff(cdf, axis=1)
    lam = np.broadcast_to(np.asarray(lapse, float), mu.shape[:1])[:, None]
    return (1 - lam) * p + lam / levels.size


def rating_nll(y, mu, sigma, lapse, scale, step: float) -> np.ndarray:
    """Per-trial negative log-likelihood (nats) of responses ``y`` (scale units).

    Steps: the ordered-probit probability of the step given (:func:`rating_probs`); a
    continuous scale: the Gaussian density, censored at the ends (the tail's mass spread over
    a window of 0.025 units), mixed with a uniform density by ``lapse``.
    """
    y = np.asarray(y, float)
    lo, hi = scale
    if step > 0:
        k = np.clip(np.round((y - lo) / step).astype(int), 0, rating_levels(scale, step).size - 1)
        p = rating_probs(mu, sigma, lapse, scale, step)[np.arange(y.size), k]
        return -np.log(np.maximum(p, 1e-300))
    mu = np.broadcast_to(np.asarray(mu, float), y.shape)
    sd = np.maximum(np.broadcast_to(np.asarray(sigma, float), y.shape), 1e-6)
    z = (y - mu) / sd
    dens = np.exp(-0.5 * z * z) / (sd * np.sqrt(2 * np.pi))
    dens = np.where(y <= lo + 1e-9, ndtr((lo - mu) / sd) / _WINDOW, dens)
    dens = np.where(y >= hi - 1e-9, ndtr((mu - hi) / sd) / _WINDOW, dens)
    lam = np.asarray(lapse, float)
    return -np.log(np.maximum((1 - lam) * dens + lam / (hi - lo), 1e-300))


def rating_mean(mu, sigma, lapse, scale, step: float) -> np.ndarray:
    """Expected response (scale units) given the latent mean: the steps weighted by their
    probabilities (a continuous scale: the censored mean, lapses at the middle)."""
    if step > 0:
        return rating_probs(mu, sigma, lapse, scale, step) @ rating_levels(scale, step)
    lo, hi = scale
    mu = np.asarray(mu, float)
    sd = np.maximum(np.broadcast_to(np.asarray(sigma, float), mu.shape), 1e-6)
    a, b = (lo - mu) / sd, (hi - mu) / sd
    phi = lambda t: np.exp(-0.5 * t * t) / np.sqrt(2 * np.pi)
    inner = mu * (ndtr(b) - ndtr(a)) + sd * (phi(a) - phi(b))
    m = inner + lo * ndtr(a) + hi * (1 - ndtr(b))
    return (1 - lapse) * m + lapse * 0.5 * (lo + hi)


def simulate_ratings(params: dict, factor, x_mid: float, scale, step: float,
                     rng: np.random.Generator) -> np.ndarray:
    """Responses of one observer with ``params`` (:data:`RATING_PARAMS`) to stimuli of factor
    values ``factor``."""
    x = np.asarray(factor, float)
    latent = params["offset"] + params["gain"] * (x - x_mid) + params["noise"] * rng.standard_normal(x.size)
    lo, hi = scale
    levels = rating_levels(scale, step)
    if step > 0:
        resp = levels[np.clip(np.round((latent - lo) / step).astype(int), 0, levels.size - 1)]
        lapse = levels[rng.integers(0, levels.size, x.size)]
    else:
        resp, lapse = np.clip(latent, lo, hi), rng.uniform(lo, hi, x.size)
    return np.where(rng.random(x.size) < params["lapse_rate"], lapse, resp)


def _unpack(theta):
    return theta[0], theta[1], np.exp(theta[2]), _MAX_LAPSE * expit(theta[3])


def _fit_one(y, x, scale, step) -> tuple[dict, dict]:
    """ML fit of one participant: parameters and their standard errors."""
    def nll(theta):
        g, a, s, lam = _unpack(theta)
        return rating_nll(y, a + g * x, s, lam, scale, step).sum()
    g0, a0 = np.polyfit(x, y, 1) if np.ptp(x) > 0 else (0.0, float(np.mean(y)))
    s0 = max(float(np.std(y - a0 - g0 * x)), 0.1 * (scale[1] - scale[0]) / 6)
    start = np.array([g0, a0, np.log(s0), logit(0.02 / _MAX_LAPSE)])
    res = optimize.minimize(nll, start, method="Nelder-Mead",
                            options={"xatol": 1e-5, "fatol": 1e-7, "maxiter": 4000})
    theta = res.x
    g, a, s, lam = _unpack(theta)
    # Standard errors of gain and offset from the observed information (finite differences).
    h = np.array([1e-3 * max(1.0, abs(g)), 1e-3 * max(1.0, abs(a))])
    def shifted(i, di, j, dj):
        t = theta.copy()
        t[i] += di
        t[j] += dj
        return nll(t)
    hess = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            hess[i, j] = (shifted(i, h[i], j, h[j]) - shifted(i, h[i], j, -h[j])
                          - shifted(i, -h[i], j, h[j]) + shifted(i, -h[i], j, -h[j])
                          ) / (4 * h[i] * h[j])
    try:
        se = np.sqrt(np.clip(np.diag(np.linalg.inv(hess)), 0, None))
    except np.linalg.LinAlgError:
        se = np.array([np.nan, np.nan])
    return ({"gain": float(g), "offset": float(a), "noise": float(s), "lapse_rate": float(lam)},
            {"gain": float(se[0]), "offset": float(se[1])})


#: The fewest participants a rating population (its between-observer SDs) is fitted to.
MIN_POPULATION = 2


def _population(values: np.ndarray, se: np.ndarray) -> dict:
    """Mean and between-observer SD (method of moments: the estimates' variance less their
    mean squared SE, floored at 0)."""
    mean = float(np.mean(values))
    if values.size < 2:
        return {"mean": mean, "sd": 0.0}
    var = float(np.var(values, ddof=1) - np.nanmean(se ** 2))
    return {"mean": mean, "sd": float(np.sqrt(max(var, 0.0)))}


def fit_rating_observers(frame: pd.DataFrame, study) -> dict:
    """Fit the rating observer to a pilot's trials (:func:`experiment.study.read_study_trials`).

    Returns
    -------
    dict
        ``{"study": {...}, "rating": {gain, offset: {mean, sd}, noise, lapse_rate},
        "participants": {id: {gain, offset, noise, lapse_rate, n_trials}}, "fit": {...}}``
        (gain in scale units per unit of the factor; offset, noise in scale units).

    Raises
    ------
    ValueError
        Fewer than 10 trials for a participant (the fit has four parameters), or fewer than
        :data:`MIN_POPULATION` participants (no between-observer spread to estimate).
    """
    ids = sorted(frame["participant"].astype(str).unique())
    if len(ids) < MIN_POPULATION:
        raise ValueError(f"only {len(ids)} participant ({', '.join(ids)}): a population's "
                         f"between-observer SDs need at least {MIN_POPULATION} participants "
                         "(with one they read 0, and a diagnosis would then call every "
                         "participant's own gain and offset a gap); fit a pilot of several "
                         "participants (--participants 01 02 03 ...)")
    x_mid = 0.5 * (float(frame["factor"].min()) + float(frame["factor"].max()))
    per, ses = {}, {}
    for pid, rows in frame.groupby("participant", sort=True):
        if len(rows) < 10:
            raise ValueError(f"participant {pid} has {len(rows)} trials; the rating observer "
                             "needs at least 10: drop them with --participants")
        p, se = _fit_one(rows["response"].to_numpy(float),
                         rows["factor"].to_numpy(float) - x_mid, study.scale, study.step)
        per[str(pid)] = {**p, "n_trials": len(rows)}
        ses[str(pid)] = se
    ids = sorted(per)
    pop = {k: _population(np.array([per[i][k] for i in ids]),
                          np.array([ses[i][k] for i in ids])) for k in ("gain", "offset")}
    pop["noise"] = float(np.mean([per[i]["noise"] for i in ids]))
    pop["lapse_rate"] = float(np.mean([per[i]["lapse_rate"] for i in ids]))
    return {
        "study": {"name": study.name, "estimates": study.estimates,
                  "scale": list(study.scale), "step": study.step,
                  "factor_mid": x_mid},
        "rating": pop,
        "participants": per,
        "fit": {"method": "maximum likelihood per participant (ordered probit on the scale's "
                          "steps, lapses); population by the method of moments",
                "participants": ids, "n_trials": len(frame),
                "files": sorted(set(frame["file"])) if "file" in frame else [],
                "created_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")},
    }


def write_rating_observers(path, params: dict) -> Path:
    """Write ``params`` (:func:`fit_rating_observers`) as TOML, never replacing a file."""
    from experiment.observers import _toml_table
    from labfiles import write_new_file

    lines = [("# A rating study's simulated observers, fitted by python -m experiment "
              "fit-observer --study (experiment.rating_observer)."),
             ("# gain: scale units per unit of the estimated factor; offset: the response at "
              "the factor's middle (factor_mid); noise: SD of the latent response.")]
    for name in ("study", "rating", "participants", "fit"):
        lines += ["", *_toml_table(name, params[name])]
    text = "\n".join(lines) + "\n"
    tomllib.loads(text)
    return write_new_file(Path(path), text)


def load_rating_observers(path) -> dict:
    """Read a file of :func:`write_rating_observers`.

    Raises
    ------
    ValueError
        Not such a file (the message says how to write one).
    """
    path = Path(path)
    try:
        raw = read_toml(path)
    except (OSError, LabFileError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"cannot read {path} ({exc}); write it with python -m experiment "
                         "fit-observer PILOT_DIR --study PILOT_DIR/study.toml --out "
                         "observers.toml") from exc
    missing = [k for k in ("study", "rating") if k not in raw]
    lacking = [k for k in RATING_PARAMS if k not in raw.get("rating", {})]
    if missing or lacking:
        raise ValueError(f"{path} is not a rating study's observers file (it lacks "
                         f"{missing or ['rating.' + k for k in lacking]}); write one with "
                         "python -m experiment fit-observer PILOT_DIR --study "
                         "PILOT_DIR/study.toml --out observers.toml")
    # nan/inf pass every check written as x < 0 and make every simulated rating nan: refused
    # here, as the study's own observers file is (experiment.observers), [fit] left alone.
    _refuse_non_finite(raw["rating"], path, "rating")
    return raw
