"""Where the observer's remaining gap lies (observer layer).

:func:`observer_where` puts into words where the chosen model falls short of the ceiling (which
response, its mean or its spread, and which trend); :func:`localise_observer` is the table of
mean residuals from the simulation per gloss x depth x illumination cell with bootstrap CIs.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.observer.ceiling import (
    Ceiling,
    _ceiling_pred,
    _time_features,
    ceiling_prediction,
    fit_ceiling,
)
from analysis.gap.observer.model import RESP, _fit_sigma, _nll_parts, predict

__all__ = ["OBSERVER_SIZE_UNIT", "localise_observer", "observer_misfit", "observer_where",
           "slider_units_per_response"]


_TRENDS = ("gloss", "depth", "gloss x depth", "the previous response",
           "the time since the session's start", "the time since the last rest")


def observer_where(fits: list) -> str:
    """Words for where the chosen model falls short of the ceiling: which response, its mean or
    its spread, and the trend (rising or falling with gloss, depth, their product, the previous
    response, the time since the session's start or its last rest, or differing between
    illuminations) that best describes the shortfall.

    ``fits``: ``[(train, test, fitted, ceiling_loss), ...]`` per fold (see
    engine.diagnose_losses; the ceiling is refitted here for its predictions)."""
    rows = []
    for train, test, fitted, *_ in fits:
        model = fit_ceiling(train, by_participant=train.attrs.get("by_participant", bool(
            set(train["participant"]) & set(test["participant"]))), fitted=fitted)
        chosen = predict(test, fitted)
        sig = _fit_sigma(train, predict(train, fitted))
        c_pred, c_sd = _ceiling_pred(model, test)
        own = _nll_parts(test, chosen, sig)
        ceil = _nll_parts(test, c_pred, c_sd)
        for r in RESP:
            rows.append(pd.DataFrame({
                "response": r, "excess": own[r] - ceil[r],
                "d_mu": c_pred["mu"][r] - chosen["mu"][r],
                "d_time": (_time_features(test) @ model.time_coef[r]
                           if r in model.time_coef else np.zeros(len(test))),
                "log_sd": np.log(c_sd[r] / (sig[r] * chosen["sd"][r])),
                "sd": sig[r] * chosen["sd"][r],
                "gloss": test["gloss_u"].to_numpy(float),
                "depth": test["depth_u"].to_numpy(float),
                "prev": (test[f"{r}_prev"] - test[f"{r}_u"]).fillna(0.0).to_numpy(float),
                "t_session": _column(test, "t_session_min"),
                "t_rest": _column(test, "t_rest_min"),
                "illumination": test["illumination"].to_numpy(str),
                "participant": test["participant"].to_numpy(str)}))
    frame = pd.concat(rows, ignore_index=True)
    r = frame.groupby("response")["excess"].mean().idxmax()
    sub = frame[frame["response"] == r]
    mean_part = float(np.mean(sub["d_mu"] ** 2 / (2 * sub["sd"] ** 2)))
    ratio2 = np.exp(2 * sub["log_sd"])
    spread_part = float(np.mean(0.5 * (ratio2 - 1 - np.log(ratio2))))
    target, what = ((sub["d_mu"], f"in the {r} response") if mean_part >= spread_part
                    else (sub["log_sd"], f"in the spread of the {r} response"))
    t = target.to_numpy(float)
    timed = _time_words(sub, what) if mean_part >= spread_part else ""
    if timed:
        return timed
    g = sub["gloss"].to_numpy(float) - sub["gloss"].mean()
    d = sub["depth"].to_numpy(float) - sub["depth"].mean()
    feats = {"gloss": g, "depth": d, "gloss x depth": g * d,
             "the previous response": sub["prev"].to_numpy(float),
             "the time since the session's start": sub["t_session"].to_numpy(float),
             "the time since the last rest": sub["t_rest"].to_numpy(float)}
    corr = {n: _corr(t, v) for n, v in feats.items()}
    # A shortfall that lives in single stimuli, not in a smooth trend: the stimulus means of
    # the shortfall hold far more of its variance than the smooth features together.
    smooth = np.c_[np.ones(t.size), *feats.values(),
                   *[(sub["illumination"] == i).to_numpy(float) for i in _ill_levels(sub)]]
    r2_smooth = 1 - np.var(t - smooth @ np.linalg.lstsq(smooth, t, rcond=None)[0]) / max(
        np.var(t), 1e-12)
    stim_key = sub["gloss"].round(6).astype(str) + "|" + sub["depth"].round(6).astype(str)
    r2_stim = float(np.var(pd.Series(t).groupby(stim_key.to_numpy()).transform("mean"))
                    / max(np.var(t), 1e-12))
    # Shortfalls of single participants (their own intercepts and slopes), where the same
    # participants were trained on: a participant-specific linear fit explains far more.
    parts = sorted(sub["participant"].unique())
    if len(parts) > 1:
        who = sub["participant"].to_numpy(str)
        own = np.c_[*[(who == q) * v for q in parts for v in (np.ones(t.size), g, d)]]
        r2_own = 1 - np.var(t - own @ np.linalg.lstsq(own, t, rcond=None)[0]) / max(
            np.var(t), 1e-12)
        if r2_own > 0.3 and r2_own > 2 * r2_smooth:
            return (f"{what}, differing between participants (their own intercepts and "
                    "slopes; the simulation has no such individual differences)")
    ill_means = sub.assign(t=t).groupby("illumination")["t"].mean()
    ill_spread = float(ill_means.max() - ill_means.min()) if ill_means.size > 1 else 0.0
    name = max(corr, key=lambda n: abs(corr[n]))
    if ill_spread > 2 * np.std(t) * 0.5 and abs(corr[name]) < 0.5:
        hi_ill = ill_means.idxmax()
        return f"{what}, differing between illuminations (highest under {hi_ill})"
    if abs(corr[name]) < 0.3 or r2_smooth < 0.5 * r2_stim:
        return f"{what}, varying from stimulus to stimulus without a smooth trend"
    return f"{what}, {'rising' if corr[name] > 0 else 'falling'} with {name}"


def _time_words(sub: pd.DataFrame, what: str) -> str:
    """Words for a shortfall of the mean of which the ceiling's time-on-task part holds at
    least a quarter of the mean square, else ''. Where there is no drift that part is shrunk
    to next to nothing; a drift brings trends by stimulus along (both sliders creeping up by
    0.15 slider units a minute, 11 participants: the time part held 28 % of the depth
    response's shortfall, a trend with depth the rest), and the time is the news."""
    d_time = sub["d_time"].to_numpy(float)
    total = float(np.mean(sub["d_mu"].to_numpy(float) ** 2))
    if total <= 0 or float(np.mean(d_time ** 2)) < 0.25 * total:
        return ""
    corr = {"the time since the session's start": _corr(d_time, sub["t_session"].to_numpy(float)),
            "the time since the last rest": _corr(d_time, sub["t_rest"].to_numpy(float))}
    name = max(corr, key=lambda n: abs(corr[n]))
    return f"{what}, {'rising' if corr[name] > 0 else 'falling'} with {name}"


def _column(frame: pd.DataFrame, name: str) -> np.ndarray:
    """A numeric column of ``frame``, zeros where it is absent."""
    return frame[name].to_numpy(float) if name in frame else np.zeros(len(frame))


def _ill_levels(frame: pd.DataFrame) -> list:
    """Illumination names but the first (dummy coding)."""
    return sorted(frame["illumination"].unique())[1:]


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    if np.std(a) == 0 or np.std(b) == 0:
        return 0.0
    return float(np.corrcoef(a, b)[0, 1])


# --- localisation table -------------------------------------------------------------------

def localise_observer(data: pd.DataFrame, design, rng: np.random.Generator,
                      n_boot: int = 1000) -> pd.DataFrame:
    """Mean residual (response - the simulation's mean, slider units) per gloss x depth x
    illumination cell and response, with a 95 % bootstrap CI; cells use the design's analysis
    bins."""
    def bin_of(values, bins):
        out = np.full(len(values), "other", dtype=object)
        for name, members in bins.items():
            out[np.isin(np.round(values, 6), np.round(members, 6))] = name
        return out
    g = bin_of(data["true_gloss_pct"].to_numpy(float), design.analysis.gloss_bins_pct)
    d = bin_of(data["true_depth_cm"].to_numpy(float), design.analysis.depth_bins_cm)
    rows = []
    for r in RESP:
        res = data[f"{r}_match"].to_numpy(float) - data[f"{r}_base"].to_numpy(float)
        frame = pd.DataFrame({"gloss_bin": g, "depth_bin": d,
                              "illumination": data["illumination"].to_numpy(), "res": res})
        for key, grp in frame.groupby(["gloss_bin", "depth_bin", "illumination"]):
            v = grp["res"].to_numpy()
            b = v[rng.integers(0, v.size, (n_boot, v.size))].mean(axis=1)
            lo, hi = np.percentile(b, [2.5, 97.5])
            rows.append({"response": r, "gloss_bin": key[0], "depth_bin": key[1],
                         "illumination": key[2], "n": v.size, "mean_residual": v.mean(),
                         "ci_low": lo, "ci_high": hi})
    return pd.DataFrame(rows)


# How far: the misfit in the responses' own units (issue 38).
#
# How far the simulated observer is off, in the responses' own units (observer layer).
#
# Nats per trial are the statistics' currency, but a lab reads a misfit in its sliders' units:
# :func:`observer_misfit` measures, on the held-out trials, how far the predicted settings of
# the plain simulation and of the chosen model lie from those of the flexible model of the data
# (the ceiling built on the chosen model, :func:`analysis.gap.observer.ceiling.fit_ceiling`),
# in slider units and in the study's units (gloss in %, depth in cm, from the design's
# slider-to-unit mapping), and how far held-out settings scatter about the flexible model's
# prediction (their noise, which no model of the mean removes). The chosen model's misfit is
# the size the design's ``[gap] observer_tolerance_slider`` holds a remaining gap to.
#
# A model's misfit at one trial and response is the distance between its predicted settings
# and the flexible model's, the means' difference and the spreads' difference taken together as
# ``sqrt(dm^2 + ds^2)`` (the Wasserstein-2 distance between two normal distributions, in the
# settings' units; Dowson & Landau 1982): a misfit of the mean (a bias, a slope) and one of the
# noise's pattern (noise that grows with depth) both count, in one unit. The model's spread is
# first scaled to the flexible model's RMS spread over the held-out trials, as the noise SDs
# are fitted per model in the likelihood too: a uniformly noisier lab is no misfit. Means are
# clipped to the slider, where settings can be. Lapses and label rounding (the mixtures) are
# left out: the catalogue names them, and their share is no distance on the slider. The misfit
# is the RMS over held-out trials, per response, and for both together the RMS of the
# distance in the (gloss, depth) plane, ``sqrt(gloss^2 + depth^2)``, so that a misfit in one
# response alone is not halved by the other's fit.

#: The unit the observer layer's misfit and tolerance are in (the design's slider).
OBSERVER_SIZE_UNIT = "slider units"


def slider_units_per_response(slider) -> dict:
    """``{response: (unit words, study units per slider unit)}`` from the design's slider
    (linear maps: gloss % and depth cm per slider unit)."""
    lo = float(slider.min)
    return {"gloss": ("%", abs(float(slider.to_gloss_pct(lo + 1.0))
                                     - float(slider.to_gloss_pct(lo)))),
            "depth": ("cm", abs(float(slider.to_depth_cm(lo + 1.0))
                                      - float(slider.to_depth_cm(lo))))}


def _model_spread(train: pd.DataFrame, data: pd.DataFrame, fitted: list) -> tuple[dict, dict]:
    """The mean (slider units) and noise SD of the base extended by ``fitted`` on ``data``,
    the SDs fitted on ``train`` (as the likelihood fits them)."""
    pred = predict(data, list(fitted))
    sigma = _fit_sigma(train, predict(train, list(fitted)))
    return pred["mu"], {r: sigma[r] * np.broadcast_to(pred["sd"][r], pred["mu"][r].shape)
                        for r in RESP}


def _distance_sq(mu_m, sd_m, mu_c, sd_c, lo, hi) -> np.ndarray:
    """Per trial squared distance of a model's predicted settings from the ceiling's (see the
    module docstring): means clipped to the slider, the model's SD scaled to the ceiling's
    RMS SD."""
    k = np.sqrt(np.mean(sd_c ** 2) / max(float(np.mean(sd_m ** 2)), 1e-12))
    dm = np.clip(mu_m, lo, hi) - np.clip(mu_c, lo, hi)
    return dm ** 2 + (k * sd_m - sd_c) ** 2


def observer_misfit(fits: list, ceilings: dict, slider) -> dict:
    """The misfits of the plain simulation and the chosen model, and the scatter about the
    flexible model, on every fold's held-out trials.

    Parameters
    ----------
    fits : list of (train, test, chosen, ceiling loss)
        Per fold, as :func:`analysis.gap.engine.steps.remaining_gap` hands the layer's size
        (``chosen``: ``[(candidate, params), ...]``).
    ceilings : dict
        ``{id(test): Ceiling}``, the ceiling built on that fold's chosen model.
    slider : SliderSpec
        The design's slider (its units per slider unit).

    Returns
    -------
    dict
        ``misfit_before``, ``misfit_after``, ``misfit_ceiling`` (slider units; both responses
        together), ``misfit_unit`` and ``misfit_by_response`` (per response ``unit``,
        ``per_slider_unit`` and ``before``, ``after``, ``ceiling`` in that unit, with the same
        in slider units as ``before_slider`` etc.): the :class:`Diagnosis` fields.
    """
    sums = {r: np.zeros(3) for r in RESP}
    n = 0
    for train, test, chosen, _ in fits:
        model: Ceiling = ceilings[id(test)]
        lo, hi = test.attrs["range"]
        mu_c, sd_c = ceiling_prediction(model, test)
        plain = _model_spread(train, test, [])
        after = _model_spread(train, test, list(chosen))
        for r in RESP:
            x = test[f"{r}_match"].to_numpy(float)
            sums[r] += (float(_distance_sq(plain[0][r], plain[1][r], mu_c[r], sd_c[r], lo,
                                           hi).sum()),
                        float(_distance_sq(after[0][r], after[1][r], mu_c[r], sd_c[r], lo,
                                           hi).sum()),
                        float(np.sum((x - np.clip(mu_c[r], lo, hi)) ** 2)))
        n += len(test)
    if n == 0:
        return {}
    mean_sq = {r: sums[r] / n for r in RESP}
    both = np.sqrt(sum(mean_sq.values()))
    units = slider_units_per_response(slider)
    by_response = {}
    for r in RESP:
        rms = np.sqrt(mean_sq[r])
        unit, per = units[r]
        by_response[r] = {"unit": unit, "per_slider_unit": per,
                          **{k: float(v * per) for k, v in zip(_KEYS, rms)},
                          **{f"{k}_slider": float(v) for k, v in zip(_KEYS, rms)}}
    return {"misfit_before": float(both[0]), "misfit_after": float(both[1]),
            "misfit_ceiling": float(both[2]), "misfit_unit": OBSERVER_SIZE_UNIT,
            "misfit_by_response": by_response}


_KEYS = ("before", "after", "ceiling")
