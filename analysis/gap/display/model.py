"""Display layer, the simulation: the calibration's prediction, the noise model, the likelihood
and the held-out folds.

The plain simulation (what stimuli assume about the display) is the calibration's gamma model
at the screen centre, its above-black part scaled by the calibration's uniformity map; each
fitted candidate (:mod:`analysis.gap.display.candidates`) changes its drive, gain or offset
(:func:`_mean`). The loss per reading is the Gaussian NLL under the photometer's noise
``sd^2 = a^2 + s L + (b L)^2``, measured from pairs of consecutive repeats with the display's
drift between them modelled in time (:func:`fit_noise_drift`). :func:`display_frame` builds the
frame the engine works on; :func:`display_folds` cross-fits its two halves.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import optimize, stats
from scipy.interpolate import BSpline
from scipy.special import log_ndtr

from analysis.gap.display.data import _has_pairs, _seconds, _timed
from analysis.gap.engine import GapError, candidate, split_held_out
from calibration.noise import FLOOR_SD_MULTIPLE, default_noise

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


# --- the data frame the engine works on -------------------------------------------------------

def display_frame(readings: pd.DataFrame, cal) -> pd.DataFrame:
    """Readings with the plain simulation's prediction and the noise model's SD.

    Columns added: ``t_s`` (time since the first reading: s, or the measurement order where
    the file has no timestamps, ``attrs["timed"]`` False), ``L`` (cd/m^2), ``lmin``, ``rel``
    (calibration uniformity at the patch), ``mu0`` (plain prediction, cd/m^2), ``sd`` (SD of a
    reading, cd/m^2: noise and the calibration model's misfit, :func:`_reading_sd`),
    ``censored``
    (at or below the meter's floor, ``attrs["floor"]``), ``cell`` (patch name ``x,y,level``).
    ``attrs["noise"]``: the photometer's noise (:func:`_noise`); ``attrs["conditions"]``: the
    file's condition columns (kept); ``attrs["cal_jac"]``, ``attrs["cal_prec"]``: the
    calibration's own uncertainty (:func:`calibration_jacobian`), rows in this frame's order.
    """
    noise_frames = readings.attrs.get("noise_frames") or [readings]
    source = readings.attrs.get("display_source", {})
    conditions = list(readings.attrs.get("conditions", []))
    cal_rows = readings.attrs.get("calibration_rows")
    out = readings.copy().reset_index(drop=True)
    out.attrs = {}
    out["t_s"] = _seconds(out)
    out["L"] = out["luminance_cd_m2"].to_numpy(float)
    out["lmin"] = float(cal.min_luminance_cd_m2)
    x, y = out["x_norm"].to_numpy(float), out["y_norm"].to_numpy(float)
    if cal.uniformity is not None:
        rel0 = float(np.min(np.asarray(cal.uniformity.relative, float)))
        out["rel"] = rel0 / cal.uniformity.gain_at(x, y)
    else:
        out["rel"] = 1.0
    out["cell"] = [f"{a:+.3f},{b:+.3f},{c:.4f}" for a, b, c in zip(x, y, out["level"])]
    out.attrs |= {"cal": cal, "display_source": source, "timed": _timed(out),
                  "conditions": conditions}
    out["mu0"] = _mean(out, [])
    noise = _noise(noise_frames, cal, out["L"].to_numpy(float))
    out.attrs["noise"] = noise
    out.attrs["floor"] = floor = max(noise["floor_cd_m2"], _foot(out), 0.0)
    out["censored"] = out["L"].to_numpy(float) <= floor
    lof = lack_of_fit_sd(cal, out["mu0"].to_numpy(float), noise["rel"])
    out["sd"], out["var_expected"] = _reading_sd(out, noise, lof)
    jac, prec = calibration_jacobian(cal, out["level"].to_numpy(float), noise["rel"],
                                     noise.get("shot", 0.0))
    if jac is not None:
        jac = jac * out["rel"].to_numpy(float)[:, None]
        pos_jac, pos_prec = _map_jacobian(out, cal, cal_rows, noise["rel"],
                                          noise.get("shot", 0.0))
        jac = np.c_[jac, pos_jac]
        prec = np.block([[prec, np.zeros((prec.shape[0], pos_prec.size))],
                         [np.zeros((pos_prec.size, prec.shape[0])), np.diag(pos_prec)]])
    out.attrs["cal_jac"], out.attrs["cal_prec"] = jac, prec
    return out


def _map_jacobian(data: pd.DataFrame, cal, rows, noise_rel: float, shot: float = 0.0):
    """The uniformity map's own uncertainty: per measured position off the centre, a column
    of the above-black light there (a relative gain of the map) and its precision, ``n`` bright
    readings pooled there and ``n0`` at the centre: ``1 / (b^2 (1 / n + 1 / n0))`` with ``b``
    the calibration's relative noise (where that was only the default, the photometer's:
    ``noise_rel`` and its shot noise ``shot`` at the bright readings' median light). No
    columns without a map or the calibration's readings."""
    fit = cal.chosen_fit
    none = np.zeros((len(data), 0)), np.zeros(0)
    if cal.uniformity is None or rows is None or not len(rows):
        return none
    bright = rows[rows["level"].to_numpy(float) >= cal.uniformity.min_level]
    lum = float(np.median(bright["luminance_cd_m2"])) if len(bright) else 0.0
    b = float(fit.noise["rel"]) if fit is not None and fit.noise.get("source") == "repeats" \
        else float(np.sqrt(noise_rel**2 + (shot / lum if lum > 0 else 0.0)))
    count = bright.groupby([bright["x_norm"].round(4), bright["y_norm"].round(4)]).size()
    n0 = float(count.get((0.0, 0.0), 0))
    pos = list(zip(data["x_norm"].round(4), data["y_norm"].round(4)))
    cells = sorted({p for p in pos if p != (0.0, 0.0) and p in count.index})
    if n0 <= 0 or not cells:
        return none
    above = np.maximum(data["mu0"].to_numpy(float) - data["lmin"].to_numpy(float), 0.0)
    cols = np.array([[float(p == c) for c in cells] for p in pos]) * above[:, None]
    prec = np.array([1 / (b**2 * (1 / float(count[c]) + 1 / n0)) for c in cells])
    return cols, prec


def _noise(frames, cal, lum: np.ndarray) -> dict:
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


def _foot(data: pd.DataFrame) -> float:
    """The meter's floor as the readings show it, cd/m^2: where some read 0 (or less), the
    lowest positive reading (a zero says only "below the floor", and no reading above the
    floor was reported as 0, so the floor is at most that); else a constant foot, the lowest
    reading where the two lowest drive levels or more read exactly it (a meter at its floor
    reports the same value whatever lies below); else 0."""
    lum, level = data["L"].to_numpy(float), data["level"].to_numpy(float)
    if (lum <= 0).any() and (lum > 0).any():
        return float(lum[lum > 0].min())
    low = lum.min(initial=0.0)
    at = np.unique(level[lum == low])
    below = np.unique(level[level <= at.max()]) if at.size else at
    return float(low) if at.size >= 2 and at.size == below.size else 0.0


def _reading_sd(data: pd.DataFrame, noise: dict, lof) -> tuple[np.ndarray, np.ndarray]:
    """SD of each reading about the calibration's prediction, cd/m^2: the photometer's noise
    ``a^2 + s L + (b L)^2`` (L at least the floor) and the calibration model's own misfit ``lof``
    (:func:`lack_of_fit_sd`); and its square (the floor's expected squared deviation)."""
    lum = np.maximum(data["L"].to_numpy(float), data.attrs.get("floor", 0.0))
    var = (noise["abs"] ** 2 + noise.get("shot", 0.0) * lum + (noise["rel"] * lum) ** 2
           + np.asarray(lof, float) ** 2)
    return np.sqrt(var), var


def calibration_jacobian(cal, drive, noise_rel: float | None = None, shot: float = 0.0):
    """The calibration's own uncertainty, for the null: ``(J, P)`` with ``J`` (n, p) the
    derivative of its predicted luminance at ``drive`` (cd/m^2 per unit of each gamma
    parameter) and ``P`` (p, p) the precision of its parameters, the Fisher information of the
    readings it was fitted from (uncensored, under its recorded noise, or a relative noise
    ``noise_rel`` and shot noise ``shot``, the photometer's, where that noise was only the
    documented default). ``(None, None)`` where the fit's readings were not recorded."""
    from calibration import gamma_luminance
    from calibration.noise import NoiseModel

    fit = cal.chosen_fit
    if fit is None or len(fit.levels) < 3:
        return None, None
    x, y = np.asarray(fit.levels, float), np.asarray(fit.luminance_cd_m2, float)
    keep = ~np.asarray(fit.censored, bool) if len(fit.censored) == x.size else y > 0
    noise = NoiseModel.from_dict(fit.noise) if fit.noise else default_noise(y)
    given = noise.source != "repeats" and noise_rel is not None
    if given:
        noise = NoiseModel(noise.abs_cd_m2, float(noise_rel), noise.floor_cd_m2, "given")
    sd = np.sqrt(noise.sd(y[keep]) ** 2 + (shot * np.maximum(y[keep], 0.0) if given else 0.0))
    params = {k: float(v) for k, v in cal.gamma_params.items()}

    def grad(at):
        cols = []
        for k, v in params.items():
            h = 1e-4 * max(abs(v), 1e-2)
            up = gamma_luminance(at, model=cal.gamma_model, params=params | {k: v + h})
            down = gamma_luminance(at, model=cal.gamma_model, params=params | {k: v - h})
            cols.append((np.asarray(up, float) - np.asarray(down, float)) / (2 * h))
        return np.stack(cols, axis=-1)
    jac_cal, jac = grad(x[keep]) / sd[:, None], grad(np.asarray(drive, float))
    if not (np.all(np.isfinite(jac_cal)) and np.all(np.isfinite(jac))):
        return None, None
    # A misfit of the model (more residual than noise) is not a parameter error: it is the
    # reading's lack_of_fit_sd, not a looser prior here.
    return jac, jac_cal.T @ jac_cal


def lack_of_fit_sd(cal, lum, noise_rel: float | None = None) -> np.ndarray:
    """SD (cd/m^2) of the calibration model's own misfit at luminance ``lum``: where its
    gamma fit left more residual than its noise explains (reduced chi-square ``s`` above 1),
    its noise SD at ``lum`` times ``sqrt(s - 1)`` (the calibration's residuals: a model that
    misses its own readings by that much misses a repeat pass by as much, and that is no
    change of the display); ``s`` counts only beyond its 95th percentile under noise alone.
    Zero where the fit fits or was not recorded. The noise is the one the calibration was
    fitted under (its readings' weights: under another, a fit weighted otherwise misses them
    by more than that noise although its model fits)."""
    from calibration import gamma_luminance
    from calibration.noise import NoiseModel

    lum = np.asarray(lum, float)
    fit = cal.chosen_fit
    if fit is None or len(fit.levels) < 3:
        return np.zeros(lum.shape)
    x, y = np.asarray(fit.levels, float), np.asarray(fit.luminance_cd_m2, float)
    keep = ~np.asarray(fit.censored, bool) if len(fit.censored) == x.size else y > 0
    noise = NoiseModel.from_dict(fit.noise) if fit.noise else default_noise(y)
    if noise.source != "repeats" and noise_rel is not None:
        noise = NoiseModel(noise.abs_cd_m2, float(noise_rel), noise.floor_cd_m2, "given")
    sd = noise.sd
    mu = np.asarray(gamma_luminance(x[keep], model=cal.gamma_model,
                                    params=cal.gamma_params), float)
    dof = max(int(keep.sum()) - len(cal.gamma_params), 1)
    chi2 = float(np.sum(((y[keep] - mu) / sd(y[keep])) ** 2))
    # Only the misfit the residuals show beyond what noise gives in 95 % of fits (the chi-square
    # above its 95th percentile): a reduced chi-square a little above 1 by chance (its SD is
    # sqrt(2 / dof), 0.2 with 50 readings) is noise, and counting it would loosen every
    # reading's SD (a clean check then reads below its floor); a model that misses its
    # readings by several noise SDs keeps nearly all of its misfit.
    excess = (chi2 - stats.chi2.ppf(0.95, dof)) / dof
    return sd(lum) * np.sqrt(max(excess, 0.0))


def _calibration_shift(train: pd.DataFrame, fitted: list) -> np.ndarray | None:
    """The calibration's gamma parameters and uniformity map moved within their uncertainty to
    fit ``train`` beside the ``fitted`` candidates (linearised, maximum a posteriori: a ridge
    with the calibration's precision as prior; :func:`calibration_jacobian`,
    :func:`_map_jacobian`): what a calibration fitted from noisy readings may be off by, which
    is no gap."""
    jac, prec = train.attrs.get("cal_jac"), train.attrs.get("cal_prec")
    if jac is None:
        return None
    j = jac[train.index.to_numpy()]
    r = train["L"].to_numpy(float) - _mean(train, fitted)
    w = 1 / train["sd"].to_numpy(float) ** 2 * ~train["censored"].to_numpy(bool)
    return np.linalg.lstsq((j.T * w) @ j + prec, (j.T * w) @ r, rcond=None)[0]


def display_loss_given(train: pd.DataFrame):
    """The engine's loss for a fold trained on ``train``: ``loss(data, fitted)``, the NLL of
    the simulation extended by ``fitted``, its calibration moved within its uncertainty to fit
    ``train`` (:func:`_calibration_shift`)."""
    def loss(data: pd.DataFrame, fitted: list) -> np.ndarray:
        mean = _mean(data, fitted)
        delta = _calibration_shift(train, fitted)
        if delta is not None:
            mean = mean + data.attrs["cal_jac"][data.index.to_numpy()] @ delta
        return display_nll(data, mean)
    return loss


def display_loss_info(data: pd.DataFrame) -> dict:
    """The noise model, the drift between repeats and what was diagnosed (for the report)."""
    n = data.attrs["noise"]
    return {"noise_abs_cd_m2": n["abs"], "noise_rel": n["rel"],
            "noise_shot_cd_m2": n.get("shot", 0.0), "noise_pairs": n["n_pairs"],
            "noise_source": n["source"], "floor_cd_m2": data.attrs["floor"],
            "censored_readings": int(data["censored"].sum()),
            "timed": bool(data.attrs["timed"]), "conditions": data.attrs["conditions"],
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
    """Per-reading NLL (nats) of predictions ``mean`` (cd/m^2): Gaussian under the reading's
    SD; a reading at or below the meter's floor is censored, ``-log P(L <= floor)`` (it says
    only "no more than the floor", as in the calibration's fit), so a zero is never exact."""
    sd = data["sd"].to_numpy(float)
    nll = 0.5 * np.log(2 * np.pi * sd**2) + 0.5 * ((data["L"].to_numpy(float) - mean) / sd) ** 2
    cens = data["censored"].to_numpy(bool) if "censored" in data else np.zeros(len(data), bool)
    if cens.any():
        z = (data.attrs["floor"] - np.asarray(mean, float)[cens]) / sd[cens]
        nll[cens] = -log_ndtr(z)
    return nll


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
