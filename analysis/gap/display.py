"""Display layer: photometer readings (``readings.csv``) vs the calibration model.

The plain simulation is what stimuli assume about the display: the calibration's gamma model
at the screen centre, its above-black part scaled by the calibration's uniformity map::

    mu0(d, x, y) = Lmin + (L_cal(d) - Lmin) * rel(x, y)

(``rel`` = 1 without a uniformity map). Each catalogue candidate extends it:

====================  ====================================================================
candidate             extension (parameters fitted on the training readings)
====================  ====================================================================
black_offset          mu += c (cd/m^2): extra black level or reflected ambient light
nonuniformity         above-black part * (1 + f (x^2 + y^2) / 2 + g x + h y)
warmup_drift          above-black part * (1 - w exp(-t / tau)), t = s since the first reading,
                      tau no longer than the record (a slower drift is a constant gain)
quantisation          drive rounded to a ``bits``-bit DAC grid before the gamma model
====================  ====================================================================

Loss per reading: Gaussian negative log-likelihood (nats) with the photometer's noise
``sd^2 = a^2 + (b L)^2``; ``a`` and ``b`` are fitted (maximum likelihood) to the spread of the
repeats of each patch, which no display model can explain, so the floor (the loss of a model
that is right up to noise) is ``0.5 log(2 pi sd^2) + 0.5`` per reading.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy import optimize

from analysis.gap.engine import Candidate, GapError, split_held_out
from calibration import CalibrationError, load_calibration, load_readings

__all__ = [
    "DISPLAY_CANDIDATES",
    "DISPLAY_MIN_SHARE",
    "display_floor",
    "display_frame",
    "display_loss",
    "display_nll",
    "display_unit_ids",
    "load_display",
    "localise_display",
    "split_display",
]

#: An attribution must remove >= 80 % of the held-out gap: the calibration was itself estimated
#: from noisy readings, so a small gap remains that no display effect explains.
DISPLAY_MIN_SHARE = 0.8
_TAUS_S = np.geomspace(20.0, 5000.0, 40)
_BITS = (4, 5, 6, 7, 8, 9, 10)


def _find(path: Path, name: str) -> Path:
    if path.is_dir():
        hits = sorted(path.rglob(name))
        if not hits:
            raise GapError(f"no {name} under {path}; pass the file or the folder holding it")
        return hits[0]
    if not path.is_file():
        raise GapError(f"{path} not found; pass a {name} file or the folder holding it")
    return path


def load_display(real_path, sim_path):
    """Read the photometer readings (REAL: ``readings.csv`` or a folder holding one) and the
    calibration (SIM: ``calibration.json`` or its folder). Returns ``(readings, calibration)``."""
    rpath = _find(Path(real_path), "readings.csv")
    cpath = _find(Path(sim_path), "calibration.json")
    try:
        readings = load_readings(rpath)
        cal = load_calibration(cpath)
    except CalibrationError as exc:
        raise GapError(str(exc)) from exc
    if len(readings) < 8:
        raise GapError(f"{rpath}: {len(readings)} readings; the display diagnosis needs >= 8")
    return readings, cal


def display_frame(readings: pd.DataFrame, cal) -> pd.DataFrame:
    """Readings with the plain simulation's prediction and the noise model's SD.

    Columns added: ``t_s`` (s since the first reading), ``L`` (cd/m^2), ``lmin``, ``rel``
    (calibration uniformity at the patch), ``mu0`` (plain prediction, cd/m^2), ``sd`` (noise SD,
    cd/m^2), ``cell`` (patch name ``x,y,level``).
    """
    out = readings.copy().reset_index(drop=True)
    t = pd.to_datetime(out["timestamp_utc"], utc=True, errors="coerce", format="ISO8601")
    if t.isna().any():
        raise GapError(f"{int(t.isna().sum())} readings have no ISO 8601 timestamp_utc; "
                       "the warm-up candidate needs them (fix or drop those rows)")
    out["t_s"] = (t - t.min()).dt.total_seconds().to_numpy(float)
    out["L"] = out["luminance_cd_m2"].to_numpy(float)
    out["lmin"] = float(cal.min_luminance_cd_m2)
    x, y = out["x_norm"].to_numpy(float), out["y_norm"].to_numpy(float)
    if cal.uniformity is not None:
        rel0 = float(np.min(np.asarray(cal.uniformity.relative, float)))
        out["rel"] = rel0 / cal.uniformity.gain_at(x, y)
    else:
        out["rel"] = 1.0
    out["cell"] = [f"{a:+.3f},{b:+.3f},{c:.4f}" for a, b, c in zip(x, y, out["level"])]
    out.attrs["cal"] = cal
    out["mu0"] = _mean(out, [])
    noise = _fit_noise(out)
    out.attrs["noise"] = noise
    out["sd"] = np.sqrt(noise["abs"] ** 2 + (noise["rel"] * out["L"]) ** 2)
    return out


def _fit_noise(data: pd.DataFrame) -> dict:
    """ML noise (absolute cd/m^2, relative) from the spread of repeats of each patch."""
    grp = data.groupby("cell")["L"]
    n = grp.transform("size").to_numpy(float)
    dev = (data["L"] - grp.transform("mean")).to_numpy(float)
    keep = n >= 2
    if keep.sum() < 4:
        raise GapError("the display diagnosis needs repeated readings of the same patch "
                       "(same x_norm, y_norm, level; >= 2 repeats) to measure the photometer's "
                       "noise; measure with --repeats 2 or more")
    dev, n, lum = dev[keep], n[keep], data["L"].to_numpy(float)[keep]

    def nll(p):
        var = (np.exp(2 * p[0]) + (np.exp(p[1]) * lum) ** 2) * (n - 1) / n
        return 0.5 * np.sum(np.log(var) + dev**2 / var)
    res = optimize.minimize(nll, x0=[np.log(0.01), np.log(0.005)], method="Nelder-Mead",
                            options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 2000})
    return {"abs": float(np.exp(res.x[0])), "rel": float(np.exp(res.x[1]))}


# --- the extended model -------------------------------------------------------------------

def _mean(data: pd.DataFrame, fitted: list) -> np.ndarray:
    cal = data.attrs["cal"]
    p = dict(fitted)
    d = data["level"].to_numpy(float)
    if "quantisation" in p:
        steps = 2 ** int(p["quantisation"]["bits"]) - 1
        d = np.round(d * steps) / steps
    lmin = data["lmin"].to_numpy(float)
    above = (cal.luminance_for_drive(d) - lmin) * data["rel"].to_numpy(float)
    x, y = data["x_norm"].to_numpy(float), data["y_norm"].to_numpy(float)
    if "nonuniformity" in p:
        q = p["nonuniformity"]
        above = above * (1 + q["f"] * (x**2 + y**2) / 2 + q["g"] * x + q["h"] * y)
    if "warmup_drift" in p:
        q = p["warmup_drift"]
        above = above * (1 - q["w"] * np.exp(-data["t_s"].to_numpy(float) / q["tau_s"]))
    mu = lmin + above
    if "black_offset" in p:
        mu = mu + p["black_offset"]["c"]
    return mu


def display_nll(data: pd.DataFrame, mean: np.ndarray) -> np.ndarray:
    """Per-reading Gaussian NLL (nats) of predictions ``mean`` (cd/m^2) under the noise model."""
    sd = data["sd"].to_numpy(float)
    return 0.5 * np.log(2 * np.pi * sd**2) + 0.5 * ((data["L"].to_numpy(float) - mean) / sd) ** 2


def display_loss(data: pd.DataFrame, fitted: list) -> np.ndarray:
    """Loss for the engine: NLL of the simulation extended by ``fitted``."""
    return display_nll(data, _mean(data, fitted))


def display_floor(data: pd.DataFrame) -> np.ndarray:
    """Expected NLL of a model right up to the photometer's noise."""
    return 0.5 * np.log(2 * np.pi * data["sd"].to_numpy(float) ** 2) + 0.5


def display_unit_ids(data: pd.DataFrame) -> list[str]:
    """Reading names ``cell|repeat|row``."""
    return [f"{c}|{r}|{i}" for c, r, i in zip(data["cell"], data["repeat"], data.index)]


def split_display(data: pd.DataFrame, rng: np.random.Generator):
    """Held-out split: odd repeats held out (even ones train) when patches are repeated, else
    half the readings at random."""
    reps = data["repeat"].to_numpy(int)
    return split_held_out(data, reps % 2 == 1 if np.unique(reps).size >= 2 else None, rng)


def _wls(res, x, w):
    """Weighted least squares of residuals ``res`` on the columns of ``x``."""
    x = np.atleast_2d(np.asarray(x, float).T).T
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(x * sw[:, None], res * sw, rcond=None)
    return coef


def _fit_black(train, chosen):
    res = train["L"].to_numpy(float) - _mean(train, chosen)
    w = 1 / train["sd"].to_numpy(float) ** 2
    return {"c": float(_wls(res, np.ones(len(train)), w)[0])}


def _fit_nonuniformity(train, chosen):
    mu = _mean(train, chosen)
    above = mu - train["lmin"].to_numpy(float) - dict(chosen).get("black_offset", {}).get("c", 0)
    x, y = train["x_norm"].to_numpy(float), train["y_norm"].to_numpy(float)
    if np.unique(np.c_[x, y], axis=0).shape[0] < 3:
        return {"f": 0.0, "g": 0.0, "h": 0.0}
    cols = np.c_[above * (x**2 + y**2) / 2, above * x, above * y]
    res = train["L"].to_numpy(float) - mu
    f, g, h = _wls(res, cols, 1 / train["sd"].to_numpy(float) ** 2)
    return {"f": float(f), "g": float(g), "h": float(h)}


def _fit_warmup(train, chosen):
    res0 = train["L"].to_numpy(float) - _mean(train, chosen)
    base = [c for c in chosen if c[0] != "warmup_drift"]
    mu = _mean(train, base)
    above = mu - train["lmin"].to_numpy(float) - dict(base).get("black_offset", {}).get("c", 0)
    res = train["L"].to_numpy(float) - mu
    w = 1 / train["sd"].to_numpy(float) ** 2
    t = train["t_s"].to_numpy(float)
    best = (np.sum(w * res0**2), {"w": 0.0, "tau_s": float(_TAUS_S[0])})
    # A drift must decay within the record: a longer time constant is a constant gain.
    for tau in _TAUS_S[_TAUS_S <= max(t.max(), _TAUS_S[0])]:
        col = -above * np.exp(-t / tau)
        a = float(_wls(res, col, w)[0])
        a = min(max(a, 0.0), 0.9)
        sse = float(np.sum(w * (res - a * col) ** 2))
        if sse < best[0]:
            best = (sse, {"w": a, "tau_s": float(tau)})
    return best[1]


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


DISPLAY_CANDIDATES = [
    Candidate("black_offset", _fit_black, "extra black level or reflected ambient light"),
    Candidate("nonuniformity", _fit_nonuniformity,
              "spatial non-uniformity beyond the calibration's map (falloff, gradients)"),
    Candidate("warmup_drift", _fit_warmup, "luminance rises while the display warms up"),
    Candidate("quantisation", _fit_quantisation, "coarser DAC than the calibration assumes"),
]


def localise_display(data: pd.DataFrame, rng: np.random.Generator,
                     n_boot: int = 1000) -> pd.DataFrame:
    """Mean relative residual (100 (L - mu0) / mu0, %) over the luminance range (the
    calibration's luminance fraction in 5 bins) and per screen position, with 95 % bootstrap
    CIs over readings. Generic localisation columns: axis, cell, n, mean_residual, ci_low,
    ci_high."""
    res = 100 * (data["L"] - data["mu0"]).to_numpy(float) / np.maximum(
        data["mu0"].to_numpy(float), 1e-6)
    cal = data.attrs["cal"]
    frac = (data["mu0"].to_numpy(float) - cal.min_luminance_cd_m2) / (
        cal.max_luminance_cd_m2 - cal.min_luminance_cd_m2)
    edges = np.linspace(0, 1, 6)
    lum_bin = np.clip(np.digitize(frac, edges[1:-1]), 0, 4)
    pos = [f"({a:+.2f}, {b:+.2f})" for a, b in zip(data["x_norm"], data["y_norm"])]
    rows = []
    for axis, labels in (("luminance fraction", [f"{edges[k]:.1f}-{edges[k + 1]:.1f}"
                                                 for k in lum_bin]),
                         ("screen position (x, y norm)", pos)):
        frame = pd.DataFrame({"cell": labels, "res": res})
        for cell, grp in frame.groupby("cell"):
            v = grp["res"].to_numpy()
            b = v[rng.integers(0, v.size, (n_boot, v.size))].mean(axis=1)
            lo, hi = np.percentile(b, [2.5, 97.5])
            rows.append({"axis": axis, "cell": cell, "n": v.size, "mean_residual": v.mean(),
                         "ci_low": lo, "ci_high": hi, "unit": "% of predicted luminance"})
    return pd.DataFrame(rows)
