"""Display layer, the photometer's noise: measured from pairs of repeats with the display's drift
between them modelled in time (:func:`fit_noise_drift`), else the calibration's noise or the
documented meter model (:func:`meter_noise`); and the meter's floor (:func:`meter_floor`; the zeros that say
the light fell below it since the calibration are :mod:`analysis.gap.display.null.zeros`).

Noise units: ``abs`` (cd/m^2), ``rel`` (fraction of the reading), ``shot`` (variance per
cd/m^2), so that a reading's variance is ``abs^2 + shot L + (rel L)^2``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import optimize
from scipy.interpolate import BSpline

from analysis.gap.display.data import _seconds
from analysis.gap.engine import GapError
from calibration.noise import FLOOR_SD_MULTIPLE, METER_FLOORS_CD_M2, default_noise, zero_bound

__all__ = ["METER_FLOORS_CD_M2", "fit_noise_drift", "meter_noise", "zero_floor"]

#: Interior knots of the time spline the noise fit may use for drift (None: no drift).
_DRIFT_KNOTS = (None, 0, 1, 2, 4, 8)


# --- the noise floor: pairs of repeats, drift modelled in time -----------------------------

def _pairs(frame: pd.DataFrame, floor: float = 0.0) -> tuple[np.ndarray, ...]:
    """Consecutive readings of each patch (x, y, level and the file's conditions), in time:
    (L1, L2, t1, t2) with t since the frame's first reading (:func:`_seconds`). Pairs with a
    reading at or below the meter's ``floor`` (cd/m^2; a zero at least) are left out: the
    meter's floor, not its noise, makes them agree."""
    f = frame.assign(_t=_seconds(frame)).sort_values("_t", kind="stable")
    out = [[], [], [], []]
    keys = ["x_norm", "y_norm", "level", *frame.attrs.get("conditions", [])]
    for _, grp in f.groupby(keys, sort=False):
        grp = grp[grp["luminance_cd_m2"].to_numpy(float) > max(floor, 0.0)]
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


def fit_noise_drift(frames, *, floor: float = 0.0) -> dict:
    """Photometer noise from pairs of consecutive repeats, with the display's drift in time.

    Each pair ``(L1 at t1, L2 at t2)`` of the same patch differs by noise and by whatever the
    display did between t1 and t2::

        L2 - L1 = Lbar (g(t2) - g(t1)) + (c(t2) - c(t1)) + e,
        var e = 2 a^2 + s (L1 + L2) + b^2 (L1^2 + L2^2)

    with ``g`` (relative, e.g. warm-up) and ``c`` (cd/m^2, e.g. room light) cubic splines in
    time. ``a``, ``b`` and the splines are fitted by maximum likelihood (splines by weighted
    least squares inside); the splines' knots (none, or 0-8 interior) are chosen by BIC, so a
    drift between repeats is modelled in time instead of being counted as noise; then the
    photometer's shot noise ``s`` (variance proportional to the light) is added where BIC
    prefers it.

    Parameters
    ----------
    frames : sequence of DataFrame
        Readings (READINGS_COLUMNS), e.g. a check's readings and its warm-up series; each
        file's time counts from its own first reading.
    floor : float
        The meter's floor, cd/m^2: pairs with a reading at or below it are left out.

    Returns
    -------
    dict
        ``abs`` (a, cd/m^2), ``rel`` (b, fraction), ``shot`` (s, cd/m^2: the variance's
        part ``s L``, 0 where BIC keeps it out), ``n_pairs``, ``drift_knots`` (None: no
        drift), ``drift_pct`` (range of the fitted relative drift g over the record, %),
        ``drift_abs_cd_m2`` (range of c).

    Raises
    ------
    GapError
        With fewer than 4 pairs of repeated readings.
    """
    frames = [f for f in frames if f is not None and len(f)]
    parts = [p for p in (_pairs(f, floor) for f in frames) if p[0].size]
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
            best = (bic, knots, fit, x)
    _, knots, fit, _x = best
    # Shot noise (variance proportional to the light) where it fits better by BIC: a meter
    # whose noise is neither constant nor proportional would else have an SD too large at
    # black and white to cover the mid-range (a floor too high there: no gap read as less).
    shot = _fit_pairs(d, s2, best[3], np.maximum(l1, 0.0) + np.maximum(l2, 0.0))
    if 2 * shot["nll"] + (best[3].shape[1] + 3) * np.log(d.size) < best[0]:
        fit = shot
    out = {"abs": fit["a"], "rel": fit["b"], "shot": fit["s"], "n_pairs": int(d.size),
           "drift_knots": knots, "drift_pct": 0.0, "drift_abs_cd_m2": 0.0}
    if knots is not None:
        out["drift_pct"], out["drift_abs_cd_m2"] = _drift_ranges(fit["beta"], spans, knots)
    return out


def _drift_ranges(beta, spans, knots: int) -> tuple[float, float]:
    """Largest range over the files' records of the fitted relative drift g (%) and of the
    absolute drift c (cd/m^2)."""
    k, at, pct, absolute = knots + 3, 0, 0.0, 0.0
    for lo, hi in spans:
        basis = _bspline(np.linspace(lo, hi, 200), lo, hi, knots)[:, 1:]
        g, c = basis @ beta[at:at + k], basis @ beta[at + k:at + 2 * k]
        pct, absolute = max(pct, float(100 * np.ptp(g))), max(absolute, float(np.ptp(c)))
        at += 2 * k
    return pct, absolute


def _fit_pairs(d, s2, x, shot_sum=None) -> dict:
    """ML fit of the pairs' noise (``a``, ``b``; with ``shot_sum`` = L1 + L2 also the shot
    noise ``s``, variance ``s L``) and drift coefficients ``beta`` on the columns ``x``."""
    def profile(p):
        var = 2 * np.exp(2 * p[0]) + np.exp(2 * p[1]) * s2
        if shot_sum is not None:
            var = var + np.exp(p[2]) * shot_sum
        if x.shape[1]:
            sw = 1 / np.sqrt(var)
            beta, *_ = np.linalg.lstsq(x * sw[:, None], d * sw, rcond=1e-10)
            r = d - x @ beta
        else:
            beta, r = np.zeros(0), d
        return 0.5 * np.sum(np.log(var) + r**2 / var), beta
    x0 = [np.log(0.01), np.log(0.003)] + ([np.log(1e-5)] if shot_sum is not None else [])
    res = optimize.minimize(lambda p: profile(p)[0], x0=x0, method="Nelder-Mead",
                            options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 2000})
    nll, beta = profile(res.x)
    return {"a": float(np.exp(res.x[0])), "b": float(np.exp(res.x[1])),
            "s": float(np.exp(res.x[2])) if shot_sum is not None else 0.0, "nll": float(nll),
            "beta": beta}



def meter_noise(frames, cal, lum: np.ndarray) -> dict:
    """The photometer's noise (:func:`fit_noise_drift` fields plus ``source``, in words, and
    ``floor_cd_m2``, the meter's floor): from pairs of repeats where there are any, else the
    noise the calibration measured from its own repeats, else the documented meter model
    (:func:`calibration.noise.default_noise`: 0.1 % of the brightest reading plus 0.5 %)."""
    fit = cal.chosen_fit
    recorded = dict(fit.noise) if fit is not None and fit.noise else {}
    cal_floor = float(recorded.get("floor_cd_m2", 0.0))
    try:
        n = fit_noise_drift(frames, floor=cal_floor)
        n["source"] = f"{n['n_pairs']} pairs of repeated readings"
    except GapError:
        if recorded.get("source") == "repeats":
            a, b = float(recorded["abs_cd_m2"]), float(recorded["rel"])
            src = ("the calibration's repeated readings (no repeats here: the noise the "
                   "calibration measured with its photometer)")
        else:
            d = default_noise(lum)
            a, b = d.abs_cd_m2, d.rel
            src = ("the documented meter model (no repeats here or in the calibration: "
                   "calibration.noise.default_noise, 0.1 % of the brightest reading + 0.5 %)")
        n = {"abs": a, "rel": b, "shot": 0.0, "n_pairs": 0, "drift_knots": None, "drift_pct": 0.0,
             "drift_abs_cd_m2": 0.0, "source": src}
    n["floor_cd_m2"] = max(cal_floor, FLOOR_SD_MULTIPLE * n["abs"])
    return n


def zero_floor(device, noise: dict, lowest_positive: float | None = None) -> tuple[float, str]:
    """The upper bound, cd/m^2, a reading of 0 (or less) stands for, and where it comes from in
    words: :func:`calibration.noise.zero_bound` (the meter's documented floor, else the lowest
    positive reading of the file, else the noise model's floor, ``noise["floor_cd_m2"]``),
    the same rule the calibration's fit censors its zeros by. A zero then costs no model that
    keeps the light below that bound anything. Only the zeros are censored at it: a positive
    reading is never censored because a zero sits below it (was: the 12.5 cd/m^2 reading of an
    8-level LCD whose black read 0 was censored too)."""
    return zero_bound(device, lowest_positive, float(noise["floor_cd_m2"]))


def _foot(data: pd.DataFrame) -> float:
    """The meter's floor as the positive readings show it, cd/m^2: a constant foot, the lowest
    reading where the two lowest drive levels or more read exactly it (a meter at its floor
    reports the same value whatever lies below); else 0. Zeros are :func:`zero_floor`'s."""
    lum, level = data["L"].to_numpy(float), data["level"].to_numpy(float)
    pos = lum > 0
    if not pos.any():
        return 0.0
    low = lum[pos].min()
    at = np.unique(level[lum == low])
    below = np.unique(level[pos & (level <= at.max())]) if at.size else at
    return float(low) if at.size >= 2 and at.size == below.size else 0.0
