"""Display layer, the simulation: the calibration's prediction, the noise model, the likelihood
and the held-out folds.

The plain simulation (what stimuli assume about the display) is the calibration's gamma model
at the screen centre, its above-black part scaled by the calibration's uniformity map; each
fitted candidate (:mod:`analysis.gap.display.candidates`) changes its drive, gain or offset
(:func:`_mean`). The loss per reading is the Gaussian NLL under the photometer's noise
``sd^2 = a^2 + (b L)^2``, measured from pairs of consecutive repeats with the display's drift
between them modelled in time (:func:`fit_noise_drift`). :func:`display_frame` builds the
frame the engine works on; :func:`display_folds` cross-fits its two halves.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import optimize
from scipy.interpolate import BSpline

from analysis.gap.display.data import _has_pairs, _times
from analysis.gap.engine import GapError, candidate, split_held_out

#: Interior knots of the time spline the noise fit may use for drift (None: no drift).
_DRIFT_KNOTS = (None, 0, 1, 2, 4, 8)


# --- the noise floor: pairs of repeats, drift modelled in time -----------------------------

def _pairs(frame: pd.DataFrame, t0) -> tuple[np.ndarray, ...]:
    """Consecutive readings of each patch (x, y, level), in time: (L1, L2, t1, t2) with t in
    s since ``t0``."""
    f = frame.assign(_t=(_times(frame) - t0).dt.total_seconds().to_numpy(float))
    f = f.sort_values("_t", kind="stable")
    out = [[], [], [], []]
    for _, grp in f.groupby(["x_norm", "y_norm", "level"], sort=False):
        if len(grp) < 2:
            continue
        lum, t = grp["luminance_cd_m2"].to_numpy(float), grp["_t"].to_numpy(float)
        for k, v in enumerate((lum[:-1], lum[1:], t[:-1], t[1:])):
            out[k].append(v)
    return tuple(np.concatenate(v) if v else np.zeros(0) for v in out)


def _bspline(x, lo: float, hi: float, n_interior: int, degree: int = 3) -> np.ndarray:
    """Cubic B-spline basis on [lo, hi] (x clipped to it), ``n_interior`` equal interior
    knots; shape (n, n_interior + degree + 1)."""
    hi = max(hi, lo + 1e-9)
    inner = np.linspace(lo, hi, n_interior + 2)[1:-1]
    knots = np.r_[[lo] * (degree + 1), inner, [hi] * (degree + 1)]
    return BSpline.design_matrix(np.clip(np.asarray(x, float), lo, hi), knots,
                                 degree).toarray()


def fit_noise_drift(frames, *, t0=None) -> dict:
    """Photometer noise from pairs of consecutive repeats, with the display's drift in time.

    Each pair ``(L1 at t1, L2 at t2)`` of the same patch differs by noise and by whatever the
    display did between t1 and t2::

        L2 - L1 = Lbar (g(t2) - g(t1)) + (c(t2) - c(t1)) + e,  var e = 2 a^2 + b^2 (L1^2 + L2^2)

    with ``g`` (relative, e.g. warm-up) and ``c`` (cd/m^2, e.g. room light) cubic splines in
    time. ``a``, ``b`` and the splines are fitted by maximum likelihood (splines by weighted
    least squares inside); the splines' knots (none, or 0-8 interior) are chosen by BIC, so a
    drift between repeats is modelled in time instead of being counted as noise.

    Parameters
    ----------
    frames : sequence of DataFrame
        Readings (READINGS_COLUMNS), e.g. a check's readings and its warm-up series.
    t0 : pandas.Timestamp, optional
        Time origin (default: the earliest reading).

    Returns
    -------
    dict
        ``abs`` (a, cd/m^2), ``rel`` (b, fraction), ``n_pairs``, ``drift_knots`` (None: no
        drift), ``drift_pct`` (range of the fitted relative drift g over the record, %),
        ``drift_abs_cd_m2`` (range of c).

    Raises
    ------
    GapError
        With fewer than 4 pairs of repeated readings.
    """
    frames = [f for f in frames if f is not None and len(f)]
    if t0 is None:
        t0 = min(_times(f).min() for f in frames)
    parts = [p for p in (_pairs(f, t0) for f in frames) if p[0].size]
    if sum(p[0].size for p in parts) < 4:
        raise GapError("the display diagnosis needs repeated readings of the same patch "
                       "(same x_norm, y_norm, level; >= 2 repeats) to measure the photometer's "
                       "noise; measure with --repeats 2 or more")
    l1, l2 = (np.concatenate([p[k] for p in parts]) for k in range(2))
    d, lbar, s2 = l2 - l1, 0.5 * (l1 + l2), l1**2 + l2**2
    # Each file (a session) drifts on its own: one spline per file over its own record.
    spans = [(float(min(p[2].min(), p[3].min())), float(max(p[2].max(), p[3].max())))
             for p in parts]
    best = None
    for knots in _DRIFT_KNOTS:
        cols = []
        if knots is not None:
            row = 0
            for p, (lo, hi) in zip(parts, spans):
                db = _bspline(p[3], lo, hi, knots) - _bspline(p[2], lo, hi, knots)
                db = db[:, 1:]  # the splines sum to 1: a constant drops out of a difference
                block = np.zeros((d.size, 2 * db.shape[1]))
                sl = slice(row, row + db.shape[0])
                block[sl] = np.c_[lbar[sl, None] * db, db]
                cols.append(block)
                row += db.shape[0]
        x = np.concatenate(cols, axis=1) if cols else np.zeros((d.size, 0))
        if x.shape[1] > d.size / 3:
            continue
        fit = _fit_pairs(d, s2, x)
        bic = 2 * fit["nll"] + (x.shape[1] + 2) * np.log(d.size)
        if best is None or bic < best[0]:
            best = (bic, knots, fit)
    _, knots, fit = best
    out = {"abs": fit["a"], "rel": fit["b"], "n_pairs": int(d.size), "drift_knots": knots,
           "drift_pct": 0.0, "drift_abs_cd_m2": 0.0}
    if knots is not None:
        k, at = knots + 3, 0
        for lo, hi in spans:
            basis = _bspline(np.linspace(lo, hi, 200), lo, hi, knots)[:, 1:]
            g, c = basis @ fit["beta"][at:at + k], basis @ fit["beta"][at + k:at + 2 * k]
            out["drift_pct"] = max(out["drift_pct"], float(100 * np.ptp(g)))
            out["drift_abs_cd_m2"] = max(out["drift_abs_cd_m2"], float(np.ptp(c)))
            at += 2 * k
    return out


def _fit_pairs(d, s2, x) -> dict:
    def profile(p):
        var = 2 * np.exp(2 * p[0]) + np.exp(2 * p[1]) * s2
        if x.shape[1]:
            sw = 1 / np.sqrt(var)
            beta, *_ = np.linalg.lstsq(x * sw[:, None], d * sw, rcond=1e-10)
            r = d - x @ beta
        else:
            beta, r = np.zeros(0), d
        return 0.5 * np.sum(np.log(var) + r**2 / var), beta
    res = optimize.minimize(lambda p: profile(p)[0], x0=[np.log(0.01), np.log(0.003)],
                            method="Nelder-Mead",
                            options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 2000})
    nll, beta = profile(res.x)
    return {"a": float(np.exp(res.x[0])), "b": float(np.exp(res.x[1])), "nll": float(nll),
            "beta": beta}


# --- the data frame the engine works on -------------------------------------------------------

def display_frame(readings: pd.DataFrame, cal) -> pd.DataFrame:
    """Readings with the plain simulation's prediction and the noise model's SD.

    Columns added: ``t_s`` (s since the first reading), ``L`` (cd/m^2), ``lmin``, ``rel``
    (calibration uniformity at the patch), ``mu0`` (plain prediction, cd/m^2), ``sd`` (noise SD,
    cd/m^2), ``cell`` (patch name ``x,y,level``). ``attrs["noise"]``: :func:`fit_noise_drift`
    on ``readings.attrs["noise_frames"]`` (default: the readings themselves).
    """
    noise_frames = readings.attrs.get("noise_frames") or [readings]
    source = readings.attrs.get("display_source", {})
    out = readings.copy().reset_index(drop=True)
    out.attrs = {}
    t = _times(out)
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
    out.attrs["display_source"] = source
    out["mu0"] = _mean(out, [])
    noise = fit_noise_drift(noise_frames)
    out.attrs["noise"] = noise
    out["sd"] = np.sqrt(noise["abs"] ** 2 + (noise["rel"] * out["L"]) ** 2)
    return out


def display_loss_info(data: pd.DataFrame) -> dict:
    """The noise model, the drift between repeats and what was diagnosed (for the report)."""
    n = data.attrs["noise"]
    return {"noise_abs_cd_m2": n["abs"], "noise_rel": n["rel"], "noise_pairs": n["n_pairs"],
            "drift_between_repeats_pct": n["drift_pct"],
            "drift_between_repeats_cd_m2": n["drift_abs_cd_m2"],
            "source": data.attrs.get("display_source", {})}


# --- the extended model -------------------------------------------------------------------

def _mean(data: pd.DataFrame, fitted: list) -> np.ndarray:
    """mu = Lmin + (L_cal(drive) - Lmin) rel gain + offset, each fitted candidate's ``apply``
    changing drive, gain or offset."""
    cal = data.attrs["cal"]
    terms = {"drive": data["level"].to_numpy(float), "gain": np.ones(len(data)),
             "offset": np.zeros(len(data))}
    for name, params in fitted:
        terms = candidate("display", name).apply(data, terms, params)
    lmin = data["lmin"].to_numpy(float)
    above = (cal.luminance_for_drive(terms["drive"]) - lmin) * data["rel"].to_numpy(float)
    return lmin + above * terms["gain"] + terms["offset"]


def display_nll(data: pd.DataFrame, mean: np.ndarray) -> np.ndarray:
    """Per-reading Gaussian NLL (nats) of predictions ``mean`` (cd/m^2) under the noise model."""
    sd = data["sd"].to_numpy(float)
    return 0.5 * np.log(2 * np.pi * sd**2) + 0.5 * ((data["L"].to_numpy(float) - mean) / sd) ** 2


def display_loss(data: pd.DataFrame, fitted: list) -> np.ndarray:
    """Loss for the engine: NLL of the simulation extended by ``fitted``."""
    return display_nll(data, _mean(data, fitted))


def display_unit_ids(data: pd.DataFrame) -> list[str]:
    """Reading names ``cell|repeat|row``."""
    return [f"{c}|{r}|{i}" for c, r, i in zip(data["cell"], data["repeat"], data.index)]


def split_display(data: pd.DataFrame, rng: np.random.Generator):
    """Held-out split, the same for any seed when patches are repeated: each patch's readings
    in time order alternate between train and held out, starting with train for every other
    patch (patches in order of their first reading). So both halves hold every patch and span
    the whole record, also when the repeats were measured in passes (a drift in time is then
    interpolated, not extrapolated). Without repeats, half the readings at random."""
    if not _has_pairs(data):
        return split_held_out(data, None, rng)
    order = data.sort_values("t_s", kind="stable")
    first = order.groupby("cell", sort=False).ngroup()
    rank = order.groupby("cell", sort=False).cumcount()
    held = pd.Series(((first + rank) % 2 == 1).to_numpy(), index=order.index)
    return split_held_out(data, held.reindex(data.index).to_numpy(bool), rng)


def display_folds(data: pd.DataFrame, rng: np.random.Generator):
    """Cross-fitting folds: the :func:`split_display` halves, each held out once.

    Every reading is then held out (fitted on the other half), so a test rests on all the
    readings, not half of them: an effect seen only in a few readings (a black offset shows in
    the darkest patches alone) is tested on twice as many of them as with one split.

    Returns
    -------
    (folds, text)
        ``folds``: ``[(train, test), (test, train)]``; ``text``: how readings were held out,
        in words.
    """
    train, test = split_display(data, rng)
    how = ("each patch's repeats alternating between two halves" if _has_pairs(data)
           else "two random halves")
    return [(train, test), (test, train)], (f"cross-fitted: {how}, each half fitted on the "
                                            "other and held out once")
