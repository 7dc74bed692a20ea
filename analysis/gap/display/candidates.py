"""Display layer, the catalogue: one registered Candidate per display effect.

Each candidate extends the plain simulation by one term of the extended mean; the table of
terms is the layer's overview (:mod:`analysis.gap.display`). Each carries its fit, its term
(``apply``), its benchmark injector and how its parameters read in reports.

They are registered with :func:`analysis.gap.engine.register` under ``"display"`` in this
order when the module is imported; :data:`DISPLAY_CANDIDATES` is the resulting catalogue.
"""

from __future__ import annotations

import numpy as np

from analysis.gap.display.model import _mean
from analysis.gap.engine import Candidate, ParamDoc, catalogue, register

#: An attribution must remove >= 80 % of the held-out gap: the calibration was itself estimated
#: from noisy readings, so a small gap remains that no display effect explains.
DISPLAY_MIN_SHARE = 0.8
_TAUS_S = np.geomspace(20.0, 5000.0, 40)
_BITS = (4, 5, 6, 7, 8, 9, 10)
#: Longest warm-up time constant fitted, in records: a slower drift is a constant gain.
_TAU_RECORDS = 3.0


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
    w = 1 / train["sd"].to_numpy(float) ** 2
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
    f, g, h = _wls(res, cols, 1 / train["sd"].to_numpy(float) ** 2)
    return {"f": float(f), "g": float(g), "h": float(h)}


def _apply_warmup(data, terms, p):
    t = data["t_s"].to_numpy(float)
    return terms | {"gain": terms["gain"] * (1 - p["w"] * np.exp(-t / p["tau_s"]))}


def _fit_warmup(train, chosen):
    res0 = train["L"].to_numpy(float) - _mean(train, chosen)
    base = [c for c in chosen if c[0] != "warmup_drift"]
    mu, above = _above(train, base)
    res = train["L"].to_numpy(float) - mu
    w = 1 / train["sd"].to_numpy(float) ** 2
    t = train["t_s"].to_numpy(float)
    best = (np.sum(w * res0**2), {"w": 0.0, "tau_s": float(_TAUS_S[0])})
    # A drift must decay within the record: a longer time constant is a constant gain.
    for tau in _TAUS_S[_TAUS_S <= max(_TAU_RECORDS * t.max(), _TAUS_S[0])]:
        col = -above * np.exp(-t / tau)
        a = float(_wls(res, col, w)[0])
        a = min(max(a, 0.0), 0.9)
        sse = float(np.sum(w * (res - a * col) ** 2))
        if sse < best[0]:
            best = (sse, {"w": a, "tau_s": float(tau)})
    return best[1]


def _apply_quantisation(data, terms, p):
    steps = 2 ** int(p["bits"]) - 1
    return terms | {"drive": np.round(terms["drive"] * steps) / steps}


def _fit_quantisation(train, chosen):
    base = [c for c in chosen if c[0] != "quantisation"]
    w = 1 / train["sd"].to_numpy(float) ** 2
    best = None
    for b in _BITS:
        mu = _mean(train, base + [("quantisation", {"bits": b})])
        sse = float(np.sum(w * (train["L"].to_numpy(float) - mu) ** 2))
        if best is None or sse < best[0] - 1e-9:
            best = (sse, b)
    return {"bits": int(best[1])}


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
            "tau_s": ParamDoc("warm-up time constant", "s")}))
register("display", Candidate(
    "quantisation", _fit_quantisation, "coarser DAC than the calibration assumes",
    apply=_apply_quantisation, inject=_change(bits=lambda v, s: round(v - s)),
    default_strength=2.0, units="DAC bits lost", truth=lambda s: {"bits": 8 - round(s)},
    params={"bits": ParamDoc("DAC resolution", "bits")}))

DISPLAY_CANDIDATES = catalogue("display")
