"""The observer layer's catalogue: one registered :class:`Candidate` per effect.

Effects, in registration order: crosstalk, central tendency, illumination gain, label
rounding, lapses, serial dependence (:data:`OBSERVER_CANDIDATES`). Importing this module
registers them with :func:`analysis.gap.engine.register` under the layer ``"observer"``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.engine import Candidate, ParamDoc, register
from analysis.gap.observer.model import (
    _AIM_SHARES,
    _LABEL_PULLS,
    _PULL_WEIGHTS,
    RESP,
    _fit_sigma,
    _gauss_share,
    _nll,
    predict,
)

__all__ = ["OBSERVER_CANDIDATES"]


# Each effect: fit (least squares on the current residual, or a grid for the mixtures), apply
# (its term in the prediction), inject (the blind benchmark's generator of the effect on top of
# the base observer's mean and noise; never called by the diagnosis), truth (the parameters
# an injected strength should give back).

def _resid(train: pd.DataFrame, chosen: list) -> tuple[dict, dict]:
    pred = predict(train, chosen)
    return pred, {r: train[f"{r}_match"].to_numpy(float) - pred["mu"][r] for r in RESP}


def _ls(y, x, w=None) -> float:
    """Weighted least-squares slope through the origin."""
    w = np.ones(len(y)) if w is None else w
    return float(np.dot(w * x, y) / max(np.dot(w * x, x), 1e-12))


def _inside(train: pd.DataFrame, r: str) -> np.ndarray:
    lo, hi = train.attrs["range"]
    x = train[f"{r}_match"].to_numpy(float)
    return (x > lo + 1e-9) & (x < hi - 1e-9)


def _weights(train: pd.DataFrame, pred: dict, res: dict, r: str) -> np.ndarray:
    """Weights of the responses in a least-squares fit of response ``r``: responses inside the
    slider, each weighted by its chance of being no lapse under ``pred`` (the E-step of the
    lapse mixture, noise SD from the residuals' median absolute deviation), so that lapses,
    whose mean is the slider's middle, do not pass for central tendency."""
    keep = _inside(train, r)
    w = keep.astype(float)
    if pred["lapse"] <= 0 or not keep.any():
        return w
    lo, hi = train.attrs["range"]
    x = res[r][keep]
    sd = max(1.4826 * float(np.median(np.abs(x - np.median(x)))), 1e-3)
    return w * _gauss_share(res[r], np.full(len(w), sd), float(pred["lapse"]), hi - lo)


def _with_mu(pred: dict, mu: dict) -> dict:
    return {**pred, "mu": {**pred["mu"], **mu}}


def _respond(ctx: dict, mu: dict, rng: np.random.Generator | None = None) -> dict:
    """Responses of the injected observer: mean + noise, clipped to the slider."""
    return {r: np.clip(mu[r] + ctx["noise"][r], ctx["lo"], ctx["hi"]) for r in RESP}


# crosstalk: deeper arrays look glossier (gloss slider units per depth slider unit).
def _fit_crosstalk(train, chosen):
    pred, res = _resid(train, chosen)
    w = _weights(train, pred, res, "gloss")
    x = train["depth_u"].to_numpy(float) - train.attrs["mid"]
    return {"c": _ls(res["gloss"], x, w)}


def _apply_crosstalk(data, pred, p):
    x = data["depth_u"].to_numpy(float) - data.attrs["mid"]
    return _with_mu(pred, {"gloss": pred["mu"]["gloss"] + p["c"] * x})


def _inject_crosstalk(ctx, s, rng):
    mu = dict(ctx["mu"])
    mu["gloss"] = mu["gloss"] + s * (ctx["truth"]["depth"] - ctx["mid"])
    return _respond(ctx, mu)


# central tendency: responses compressed toward the slider middle (share per response).
def _fit_central(train, chosen):
    pred, res = _resid(train, chosen)
    out = {}
    for r in RESP:
        out[r] = _ls(res[r], -(pred["mu"][r] - train.attrs["mid"]), _weights(train, pred, res, r))
    return out


def _apply_central(data, pred, p):
    mid = data.attrs["mid"]
    return _with_mu(pred, {r: pred["mu"][r] - p[r] * (pred["mu"][r] - mid) for r in RESP})


def _inject_central(ctx, s, rng):
    return _respond(ctx, {r: ctx["mu"][r] - s * (ctx["mu"][r] - ctx["mid"]) for r in RESP})


# illumination gain: the gloss gain differs by illumination (one gain per illumination name).
def _fit_illumination(train, chosen):
    pred, res = _resid(train, chosen)
    w = _weights(train, pred, res, "gloss")
    x = train["gloss_u"].to_numpy(float) - train.attrs["mid"]
    gain = {}
    for ill, idx in train.groupby("illumination").indices.items():
        idx = idx[w[idx] > 0]
        gain[str(ill)] = _ls(res["gloss"][idx], x[idx], w[idx]) if idx.size else 0.0
    return {"gain": gain}


def _apply_illumination(data, pred, p):
    g = data["illumination"].map(p["gain"]).fillna(0.0).to_numpy(float)
    x = data["gloss_u"].to_numpy(float) - data.attrs["mid"]
    return _with_mu(pred, {"gloss": pred["mu"]["gloss"] + g * x})


def _inject_illumination(ctx, s, rng):
    sign = np.where(ctx["illumination"] == ctx["illuminations"][0], 1.0, -1.0)
    mu = dict(ctx["mu"])
    mu["gloss"] = mu["gloss"] + sign * s * (ctx["truth"]["gloss"] - ctx["mid"])
    return _respond(ctx, mu)


def _truth_illumination(s, *, illuminations=(), **_):
    return [("illumination_gain",
             {"gain": {i: (s if k == 0 else -s) for k, i in enumerate(illuminations)}})]


# serial dependence: a pull toward the previous trial's response (share per response).
def _prev_x(data, pred, r):
    prev = data[f"{r}_prev"].to_numpy(float)
    return np.where(np.isnan(prev), 0.0, prev - pred["mu"][r])


def _fit_serial(train, chosen):
    pred, res = _resid(train, chosen)
    out = {}
    for r in RESP:
        out[r] = _ls(res[r], _prev_x(train, pred, r), _weights(train, pred, res, r))
    return out


def _apply_serial(data, pred, p):
    # The pull and the previous responses are kept: a label rounding of the aimed setting
    # (label_rounding's stage "aim") is undone through them (model._aim_frame).
    out = _with_mu(pred, {r: pred["mu"][r] + p[r] * _prev_x(data, pred, r) for r in RESP})
    out["serial"] = {r: (float(p[r]), data[f"{r}_prev"].to_numpy(float)) for r in RESP}
    return out


def _inject_serial(ctx, s, rng):
    n = len(ctx["noise"]["gloss"])
    out = {r: np.empty(n) for r in RESP}
    for k in range(n):
        for r in RESP:
            m = ctx["mu"][r][k]
            if not ctx["session_start"][k]:
                m = m + s * (out[r][k - 1] - m)
            out[r][k] = np.clip(m + ctx["noise"][r][k], ctx["lo"], ctx["hi"])
    return out


# label rounding and lapses: mixtures in the likelihood (weight, rate in [0, 1]).
def _fit_mixture(name: str, key: str, grid):
    def fit(train, chosen):
        best = None
        for v in grid:
            fitted = list(chosen) + [(name, {key: float(v)})]
            pred = predict(train, fitted)
            nll = _nll(train, pred, _fit_sigma(train, pred)).sum()
            if best is None or nll < best[0]:
                best = (nll, float(v))
        return {key: best[1]}
    return fit




def _fit_label(train, chosen):
    """Label rounding by maximum likelihood on a grid: snapped (weights 0-0.6, the noise SDs
    refitted at each, as before pulls were modelled; a snapped fit is returned as
    ``{"weight"}`` alone), or pulled (:data:`_LABEL_PULLS` x :data:`_PULL_WEIGHTS`, screened
    at the best snapped fit's noise SDs, the best of them refitted), the better kept."""
    def full(p):
        pred = predict(train, list(chosen) + [("label_rounding", p)])
        sigma = _fit_sigma(train, pred)
        return float(_nll(train, pred, sigma).sum()), sigma
    best = None
    for v in np.linspace(0.0, 0.6, 13):
        nll, sigma = full({"weight": float(v)})
        if best is None or nll < best[0]:
            best = (nll, {"weight": float(v)}, sigma)
    # Beside serial dependence, also the rounding of the aimed setting, before the pull
    # toward the previous response (stage "aim"; model._aim_frame), with its own share of
    # that pull (see _AIM_SHARES).
    stages = [{}]
    if any(n == "serial_dependence" for n, _ in chosen):
        stages += [{"stage": "aim", "share": a} for a in _AIM_SHARES]
    pulls = [{"weight": w, "pull": s, **st} for st in stages for s in _LABEL_PULLS
             for w in _PULL_WEIGHTS]
    screened = [_nll(train, predict(train, list(chosen) + [("label_rounding", p)]),
                     best[2]).sum() for p in pulls]
    pulled = pulls[int(np.argmin(screened))]
    return pulled if full(pulled)[0] < best[0] else best[1]


def _apply_label(data, pred, p):
    out = {**pred, "label": 1 - (1 - pred["label"]) * (1 - p["weight"])}
    if "pull" in p:
        out["label_pull"] = float(p["pull"])
    if p.get("stage") == "aim":
        out["label_stage"] = "aim"
        if "share" in p:
            out["label_share"] = float(p["share"])
    return out


def _inject_label(ctx, s, rng):
    out = {}
    for r in RESP:
        v = ctx["mu"][r] + ctx["noise"][r]
        v = np.where(rng.random(v.size) < s, np.round(v), v)
        out[r] = np.clip(v, ctx["lo"], ctx["hi"])
    return out


def _apply_lapses(data, pred, p):
    return {**pred, "lapse": 1 - (1 - pred["lapse"]) * (1 - p["rate"])}


def _inject_lapses(ctx, s, rng):
    out = {}
    for r in RESP:
        v = ctx["mu"][r] + ctx["noise"][r]
        v = np.where(rng.random(v.size) < s, rng.uniform(ctx["lo"], ctx["hi"], v.size), v)
        out[r] = np.clip(v, ctx["lo"], ctx["hi"])
    return out


def _per_response(name):
    return lambda s, **_: [(name, {r: float(s) for r in RESP})]


OBSERVER_CANDIDATES = [register("observer", c) for c in (
    Candidate("crosstalk", _fit_crosstalk, "deeper arrays look glossier",
              apply=_apply_crosstalk, inject=_inject_crosstalk, default_strength=0.3,
              units="gloss slider units per depth slider unit",
              truth=lambda s, **_: [("crosstalk", {"c": float(s)})],
              params={"c": ParamDoc("crosstalk slope",
                                    "gloss slider units per depth slider unit")}),
    Candidate("central_tendency", _fit_central, "responses compressed toward the slider middle",
              apply=_apply_central, inject=_inject_central, default_strength=0.3,
              units="share of the distance to the middle",
              truth=_per_response("central_tendency"),
              params={"*": ParamDoc("pull toward the slider's middle",
                                    "share of the distance to the middle", where="{} response")}),
    Candidate("illumination_gain", _fit_illumination, "gloss gain differs by illumination",
              apply=_apply_illumination, inject=_inject_illumination, default_strength=0.3,
              units="gloss gain change per illumination (+ first, - others)",
              truth=_truth_illumination,
              params={"gain": ParamDoc("gloss gain change",
                                       "gloss slider units per slider unit of true gloss")}),
    Candidate("label_rounding", _fit_label,
              "responses snap to tick labels, or are pulled toward them", apply=_apply_label,
              inject=_inject_label,
              default_strength=0.4, units="share of responses on a label",
              truth=lambda s, **_: [("label_rounding", {"weight": float(s)})],
              params={"weight": ParamDoc("responses snapped to (or pulled toward) a tick "
                                         "label", "fraction of responses"),
                      "pull": ParamDoc("pull toward the label", "share of the way to it"),
                      "stage": ParamDoc("rounded", "'aim': the setting aimed at, before the "
                                        "pull toward the previous response"),
                      "share": ParamDoc("pull toward the previous response after the "
                                        "rounding", "share of the way to it")}),
    Candidate("lapses", _fit_mixture("lapses", "rate", np.linspace(0.0, 0.3, 16)),
              "random responses anywhere on the slider", apply=_apply_lapses,
              inject=_inject_lapses, default_strength=0.15, units="lapse rate",
              truth=lambda s, **_: [("lapses", {"rate": float(s)})],
              params={"rate": ParamDoc("lapse rate", "fraction of responses")}),
    Candidate("serial_dependence", _fit_serial, "pull toward the previous trial's response",
              apply=_apply_serial, inject=_inject_serial, default_strength=0.3,
              units="share of the distance to the previous response",
              truth=_per_response("serial_dependence"),
              params={"*": ParamDoc("pull toward the previous response",
                                    "share of the distance to it", where="{} response")}),
)]
