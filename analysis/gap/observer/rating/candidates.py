"""The catalogue's effects that make sense for one response on a rating scale.

Central tendency, serial dependence, lapses, per-participant differences beyond the simulated
observer's spread, and rounding beyond the scale's own steps (to its labelled points, only
where the study names labels coarser than the steps: with every step labelled the scale's own
rounding is the simulation, and a coarser rounding is not identifiable). They are not
registered with the two-response catalogue (``analysis.gap.observer.candidates``): the rating
plan hands them to the engine itself (:func:`rating_candidates`). Each is fitted by maximum
likelihood on the training trials given the already chosen effects.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import optimize

from analysis.gap.engine import Candidate, ParamDoc
from analysis.gap.observer.rating.model import _fit_sigma, rating_nll_of, rating_predict

__all__ = ["BY_NAME", "rating_candidates"]


def _scalar_fit(name: str, key: str, bounds: tuple[float, float]):
    """A one-parameter ML fit (noise SD refitted at each value)."""
    def fit(train, chosen):
        cands = BY_NAME

        def f(v):
            fitted = list(chosen) + [(name, {key: float(v)})]
            pred = rating_predict(train, fitted, cands)
            return rating_nll_of(train, pred, _fit_sigma(train, pred)).sum()
        opt = optimize.minimize_scalar(f, bounds=bounds, method="bounded",
                                       options={"xatol": 2e-3})
        return {key: float(opt.x)}
    return fit


def _apply_central(data, pred, p):
    mid = data.attrs["mid"]
    return {**pred, "mu": pred["mu"] - p["share"] * (pred["mu"] - mid)}


def _apply_serial(data, pred, p):
    prev = data["prev"].to_numpy(float)
    pull = np.where(np.isnan(prev), 0.0, prev - pred["mu"])
    return {**pred, "mu": pred["mu"] + p["share"] * pull}


def _apply_lapses(data, pred, p):
    return {**pred, "lapse": 1 - (1 - pred["lapse"]) * (1 - p["rate"])}


def _apply_coarse(data, pred, p):
    return {**pred, "coarse": 1 - (1 - pred["coarse"]) * (1 - p["weight"])}


def _fit_own(train: pd.DataFrame, chosen):
    """Each participant's gain and offset change beyond the simulation's (ML, unshrunk)."""
    cands = BY_NAME
    pred = rating_predict(train, chosen, cands)
    sigma = _fit_sigma(train, pred)
    out = {}
    x_all = train["x"].to_numpy(float)
    who = train["participant"].to_numpy(str)
    for pid in np.unique(who):
        m = who == pid
        sub = train[m]
        sub_pred = {**pred, "mu": pred["mu"][m]}
        x = x_all[m]

        def f(t, sub=sub, sub_pred=sub_pred, x=x):
            moved = {**sub_pred, "mu": sub_pred["mu"] + t[1] + t[0] * x}
            return rating_nll_of(sub, moved, sigma).sum()
        t = optimize.minimize(f, np.zeros(2), method="Nelder-Mead",
                              options={"xatol": 1e-4, "fatol": 1e-6}).x
        out[str(pid)] = {"gain": float(t[0]), "offset": float(t[1])}
    return {"own": out}


def _apply_own(data, pred, p):
    who = data["participant"].astype(str)
    g = who.map({k: v["gain"] for k, v in p["own"].items()}).fillna(0.0).to_numpy(float)
    a = who.map({k: v["offset"] for k, v in p["own"].items()}).fillna(0.0).to_numpy(float)
    return {**pred, "mu": pred["mu"] + a + g * data["x"].to_numpy(float)}


_CENTRAL = Candidate(
    "central_tendency", _scalar_fit("central_tendency", "share", (-0.5, 0.9)),
    "responses compressed toward the scale's middle", apply=_apply_central,
    units="share of the distance to the middle",
    params={"share": ParamDoc("pull toward the scale's middle",
                              "share of the distance to the middle")})
_SERIAL = Candidate(
    "serial_dependence", _scalar_fit("serial_dependence", "share", (-0.5, 0.9)),
    "pull toward the previous trial's response", apply=_apply_serial,
    units="share of the distance to the previous response",
    params={"share": ParamDoc("pull toward the previous response", "share of the distance")})
_LAPSES = Candidate(
    "lapses", _scalar_fit("lapses", "rate", (0.0, 0.5)),
    "random responses anywhere on the scale (beyond the simulation's own lapse rate)",
    apply=_apply_lapses, units="lapse rate",
    params={"rate": ParamDoc("lapse rate", "fraction of responses")})
_OWN = Candidate(
    "individual_differences", _fit_own,
    "participants' own gain and offset beyond the simulated observers' spread",
    apply=_apply_own, units="scale units",
    params={"own": ParamDoc("gain and offset change", "scale units (per unit of the factor)",
                            where="participant {}")})
_COARSE = Candidate(
    "label_rounding", _scalar_fit("label_rounding", "weight", (0.0, 0.9)),
    "responses rounded to the scale's labels, beyond its own steps", apply=_apply_coarse,
    units="share of responses",
    params={"weight": ParamDoc("responses rounded to a label", "fraction of responses")})


def rating_candidates(labels_identifiable: bool) -> list[Candidate]:
    """The catalogue for one response, in order; label rounding only where the study names
    labels coarser than the scale's steps."""
    out = [_CENTRAL, _SERIAL, _LAPSES, _OWN]
    return out + [_COARSE] if labels_identifiable else out


#: Every rating candidate by name (what :func:`rating_predict` looks chosen effects up in).
BY_NAME = {c.name: c for c in (_CENTRAL, _SERIAL, _LAPSES, _OWN, _COARSE)}
