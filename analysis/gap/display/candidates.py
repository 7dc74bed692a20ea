"""Display layer, the catalogue: one registered Candidate per display effect.

Each candidate extends the plain simulation by one term of the extended mean; the table of
terms is the layer's overview (:mod:`analysis.gap.display`). Each carries its fit, its term
(``apply``), its benchmark injector and how its parameters read in reports.

They are registered with :func:`analysis.gap.engine.register` under ``"display"`` in this
order when the module is imported; :data:`DISPLAY_CANDIDATES` is the resulting catalogue.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.display.model import _mean
from analysis.gap.engine import Candidate, ParamDoc, catalogue, register

#: An attribution must remove >= 80 % of the held-out gap: the calibration was itself estimated
#: from noisy readings, so a small gap remains that no display effect explains.
DISPLAY_MIN_SHARE = 0.8
#: A candidate, a greedy step or a remaining gap counts only from 0.05 nats per reading: a
#: systematic misfit of about a third of the noise SD on every reading (a clean display
#: checked against a calibration left gaps of 0.02-0.04 nats per reading, "significant" with a
#: CI reaching 0, in 4 of 20 checks with a meter floor).
DISPLAY_MIN_GAIN = 0.05
_TAUS_S = np.geomspace(20.0, 5000.0, 40)
_BITS = (4, 5, 6, 7, 8, 9, 10)
#: A DAC step is visible when its non-smooth part adds up to this many squared noise SDs
#: over the readings (4 SDs in all).
_STEP_CHI2 = 16.0
#: Warm-up is not identifiable where the conditions explain this share of the readings' times.
_CONFOUNDED_R2 = 0.5
#: Longest warm-up time constant fitted, in records: a slower drift is a constant gain.
_TAU_RECORDS = 3.0


def _weights(train):
    """Weights 1 / sd^2 of the readings, 0 for a censored one (it says only "at most the
    floor"; its term in the likelihood is the censored one)."""
    w = 1 / train["sd"].to_numpy(float) ** 2
    return w * ~train["censored"].to_numpy(bool) if "censored" in train else w


def _wls(res, x, w):
    """Weighted least squares of residuals ``res`` on the columns of ``x``."""
    x = np.atleast_2d(np.asarray(x, float).T).T
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(x * sw[:, None], res * sw, rcond=None)
    return coef


def _above(train, chosen):
    """Above-black part of the model ``chosen`` (its offset removed), cd/m^2."""
    mu = _mean(train, chosen)
    off = sum(p["c"] for n, p in chosen if n == "black_offset")
    return mu, mu - train["lmin"].to_numpy(float) - off


# Each candidate: its fit, its term in the mean, its injector (a change of the simulated
# display's parameters, by name, so no simulator is imported here), its default strength and
# the parameters a right fit should recover at a strength.

def _apply_black(data, terms, p):
    return terms | {"offset": terms["offset"] + p["c"]}


def _fit_black(train, chosen):
    res = train["L"].to_numpy(float) - _mean(train, chosen)
    w = _weights(train)
    return {"c": float(_wls(res, np.ones(len(train)), w)[0])}


def _apply_nonuniformity(data, terms, p):
    x, y = data["x_norm"].to_numpy(float), data["y_norm"].to_numpy(float)
    return terms | {"gain": terms["gain"] * (1 + p["f"] * (x**2 + y**2) / 2 + p["g"] * x
                                             + p["h"] * y)}


def _fit_nonuniformity(train, chosen):
    mu, above = _above(train, chosen)
    x, y = train["x_norm"].to_numpy(float), train["y_norm"].to_numpy(float)
    if np.unique(np.c_[x, y], axis=0).shape[0] < 3:
        return {"f": 0.0, "g": 0.0, "h": 0.0}
    cols = np.c_[above * (x**2 + y**2) / 2, above * x, above * y]
    res = train["L"].to_numpy(float) - mu
    f, g, h = _wls(res, cols, _weights(train))
    return {"f": float(f), "g": float(g), "h": float(h)}


def _apply_warmup(data, terms, p):
    t = data["t_s"].to_numpy(float)
    return terms | {"gain": terms["gain"] * (1 + p.get("k", 0.0))
                    * (1 - p["w"] * np.exp(-t / p["tau_s"]))}


def _fit_warmup(train, chosen):
    """Deficit ``w`` and time constant ``tau_s`` of a warm-up; beside a chosen gain change also
    a re-fit of that gain ``k`` with them (a gain fitted alone has taken the warm-up's mean
    deficit, so the warm-up, fitted with that gain held, would show only a part of itself).
    Without a gain change ``k`` stays 0: the warm-up is never chosen for a constant gain."""
    res0 = train["L"].to_numpy(float) - _mean(train, chosen)
    base = [c for c in chosen if c[0] != "warmup_drift"]
    mu, above = _above(train, base)
    res = train["L"].to_numpy(float) - mu
    w = _weights(train)
    t = train["t_s"].to_numpy(float)
    joint = any(n == "gain_change" for n, _ in base)
    best = (np.sum(w * res0**2), {"w": 0.0, "tau_s": float(_TAUS_S[0]), "k": 0.0})
    # A drift must decay within the record: a longer time constant is a constant gain.
    for tau in _TAUS_S[_TAUS_S <= max(_TAU_RECORDS * t.max(), _TAUS_S[0])]:
        col = -above * np.exp(-t / tau)
        if joint:
            k, a = (float(v) for v in _wls(res, np.c_[above, col], w))
            if not 0.0 <= a <= 0.9:  # at a bound: the gain alone, given that deficit
                a = min(max(a, 0.0), 0.9)
                k = float(_wls(res - a * col, above, w)[0])
        else:
            k, a = 0.0, min(max(float(_wls(res, col, w)[0]), 0.0), 0.9)
        sse = float(np.sum(w * (res - k * above - a * col) ** 2))
        if sse < best[0]:
            best = (sse, {"w": a, "tau_s": float(tau), "k": k})
    return best[1]


def _apply_quantisation(data, terms, p):
    if not int(p["bits"]):  # no DAC grid the readings could show
        return terms
    steps = 2 ** int(p["bits"]) - 1
    return terms | {"drive": np.round(terms["drive"] * steps) / steps}


def _step_visible(data, bits: int) -> bool:
    """Whether a ``bits``-bit DAC's staircase shows in these readings: the luminance its
    rounding moves, less what a smooth change of the calibration explains of it (an offset and
    a gain that is a cubic in drive: a change of the transfer function's shape), adds up to at
    least :data:`_STEP_CHI2` (squared noise SDs) over the readings. With a handful of levels
    (5 or fewer) every rounding pattern is such a smooth change, and a coarser DAC cannot be
    told from one; with levels fine enough, the step's jump shows."""
    base = _mean(data, [])
    dev = _mean(data, [("quantisation", {"bits": bits})]) - base
    above = base - data["lmin"].to_numpy(float)
    level = data["level"].to_numpy(float)
    cols = np.c_[np.ones(len(data)), above[:, None] * level[:, None] ** np.arange(4)]
    w = _weights(data)
    resid = dev - cols @ _wls(dev, cols, w)
    return float(np.sum(w * resid**2)) >= _STEP_CHI2


def _fit_quantisation(train, chosen):
    base = [c for c in chosen if c[0] != "quantisation"]
    w = _weights(train)
    best = (float(np.sum(w * (train["L"].to_numpy(float) - _mean(train, base)) ** 2)), 0)
    for b in (b for b in _BITS if _step_visible(train, b)):
        mu = _mean(train, base + [("quantisation", {"bits": b})])
        sse = float(np.sum(w * (train["L"].to_numpy(float) - mu) ** 2))
        if sse < best[0] - 1e-9:
            best = (sse, b)
    return {"bits": int(best[1])}


def display_identifiability(data) -> dict:
    """``{effect: reason}`` for the catalogue effects these readings cannot identify:

    * quantisation, where no DAC of :data:`_BITS` bits would show a step (:func:`_step_visible`);
    * warm-up drift, where the readings have no timestamps (their order is no time course), or
      where the run's time course follows the file's condition columns (the conditions
      explain at least :data:`_CONFOUNDED_R2` of the variance of the readings' times: a
      change that follows the conditions cannot be told from one in time);
    * non-uniformity, with fewer than 3 screen positions.
    """
    out = {}
    if not any(_step_visible(data, b) for b in _BITS):
        out["quantisation"] = ("the drive levels are too coarse to show a DAC step: any coarser "
                               "DAC's rounding is as smooth as a small change of gamma; "
                               "measure adjacent levels (e.g. 8 consecutive DAC codes at "
                               "mid-grey) to test it")
    if not data.attrs.get("timed", True):
        out["warmup_drift"] = ("the readings have no timestamps, so their order is no time "
                               "course; measure with timestamps (python -m calibration check)")
    else:
        r2, cols = _time_explained_by_conditions(data)
        if r2 >= _CONFOUNDED_R2:
            out["warmup_drift"] = (f"the run's time course follows the conditions {cols} "
                                   f"({100 * r2:.0f} % of the variance of the readings' times): "
                                   "a change that follows them cannot be told from a warm-up; "
                                   "interleave the conditions in time")
    if np.unique(np.c_[data["x_norm"], data["y_norm"]], axis=0).shape[0] < 3:
        out["nonuniformity"] = "fewer than 3 screen positions were measured"
    return out


def quantisation_resolution(data) -> tuple[list[int], str]:
    """(the DAC resolutions of :data:`_BITS` whose step these readings would show
    (:func:`_step_visible`), a note in words where some but not all would): a DAC finer than
    the finest visible one rounds as smoothly as a small change of gamma at these levels, so a
    gap it leaves is unexplained, not quantisation."""
    bits = [b for b in _BITS if _step_visible(data, b)]
    if not bits or len(bits) == len(_BITS):
        return bits, ""
    return bits, (f"quantisation: at these drive levels only a DAC of {max(bits)} bits or "
                  f"fewer would show a step; a {max(bits) + 1}-{max(_BITS)}-bit DAC's rounding "
                  "is as smooth as a small change of gamma, so a gap it leaves reads as "
                  "unexplained (measure adjacent levels, e.g. 8 consecutive DAC codes at "
                  "mid-grey, to test a finer DAC)")


def _time_explained_by_conditions(data) -> tuple[float, list]:
    """(R^2 of the readings' times on their condition combinations, the condition columns)."""
    cols = list(data.attrs.get("conditions", []))
    if not cols:
        return 0.0, cols
    t = data["t_s"].to_numpy(float)
    combo = pd.Series(list(zip(*(data[c].astype(str) for c in cols))))
    fitted = pd.Series(t).groupby(combo.to_numpy()).transform("mean").to_numpy(float)
    var = float(np.var(t))
    return (float(1 - np.var(t - fitted) / var) if var > 0 else 0.0), cols


def _apply_gain(data, terms, p):
    return terms | {"gain": terms["gain"] * (1 + p["k"])}


def _fit_gain(train, chosen):
    base = [c for c in chosen if c[0] != "gain_change"]
    mu, above = _above(train, base)
    res = train["L"].to_numpy(float) - mu
    return {"k": float(_wls(res, above, _weights(train))[0])}


def _gain_words(p) -> str:
    k = float(p.get("k", 0.0))
    return (f"the display is {100 * abs(k):.0f} % {'brighter' if k >= 0 else 'dimmer'} than "
            "its calibration at every level")


def _change(**how):
    """An injector: ``inject(display, strength) -> display`` with the named parameters of a
    frozen-dataclass display changed by ``how[name](old value, strength)``."""
    from dataclasses import replace

    def inject(display, strength):
        return replace(display, **{k: f(getattr(display, k), float(strength))
                                   for k, f in how.items()})
    return inject


register("display", Candidate(
    "black_offset", _fit_black, "extra black level or reflected ambient light",
    apply=_apply_black, inject=_change(ambient_cd_m2=lambda v, s: v + s),
    default_strength=0.05, units="cd/m^2", truth=lambda s: {"c": float(s)},
    params={"c": ParamDoc("black offset", "cd/m²")}))
register("display", Candidate(
    "gain_change", _fit_gain,
    "the white level changed since the calibration (a brightness setting, ageing, another "
    "meter): the light above black scaled at every level",
    apply=_apply_gain, inject=_change(white_cd_m2=lambda v, s: v * (1 + s)),
    default_strength=0.04, units="fractional change of the white level",
    truth=lambda s: {"k": float(s)}, words=_gain_words,
    params={"k": ParamDoc("gain change of the light above black", "fraction")}))
register("display", Candidate(
    "nonuniformity", _fit_nonuniformity,
    "spatial non-uniformity beyond the calibration's map (falloff, gradients)",
    apply=_apply_nonuniformity,
    inject=_change(falloff=lambda v, s: v + s, tilt_x=lambda v, s: v + s / 2),
    default_strength=0.06, units="fractional loss at the corners",
    # To first order the extra falloff s and tilt s / 2 are f = -s, g = s / 2.
    truth=lambda s: {"f": -float(s), "g": float(s) / 2, "h": 0.0},
    params={"f": ParamDoc("radial falloff: gain change at the corners", "fraction"),
            "g": ParamDoc("horizontal gradient: gain change at the right edge", "fraction"),
            "h": ParamDoc("vertical gradient: gain change at the top edge", "fraction")}))
register("display", Candidate(
    "warmup_drift", _fit_warmup, "luminance rises while the display warms up",
    apply=_apply_warmup, inject=_change(warmup_drift=lambda v, s: s),
    default_strength=0.03, units="fractional deficit at switch-on",
    truth=lambda s: {"w": float(s), "tau_s": 600.0},
    params={"w": ParamDoc("luminance deficit at switch-on", "fraction"),
            "tau_s": ParamDoc("warm-up time constant", "s"),
            "k": ParamDoc("the chosen gain change re-fitted with the warm-up (0 without one)",
                          "fraction")}))
register("display", Candidate(
    "quantisation", _fit_quantisation, "coarser DAC than the calibration assumes",
    apply=_apply_quantisation, inject=_change(bits=lambda v, s: round(v - s)),
    default_strength=2.0, units="DAC bits lost", truth=lambda s: {"bits": 8 - round(s)},
    params={"bits": ParamDoc("DAC resolution", "bits")}))

DISPLAY_CANDIDATES = catalogue("display")
