"""Display layer, the calibration's own uncertainty: how far a calibration fitted from noisy
readings may be off (its gamma parameters, :func:`calibration_jacobian`; its uniformity map,
:func:`map_jacobian`) and how far its model form misses its own readings
(:func:`lack_of_fit_sd`). Neither is a change of the display: the null allows both."""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from calibration.noise import default_noise

__all__ = ["calibration_jacobian", "lack_of_fit_sd", "map_jacobian"]


def map_jacobian(data: pd.DataFrame, cal, rows, noise_rel: float, shot: float = 0.0):
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


def lack_of_fit_sd(cal, lum, noise_rel: float | None = None, rows=None) -> np.ndarray:
    """SD (cd/m^2) of the calibration model's own misfit at luminance ``lum``: where its
    gamma fit left more residual than its noise explains (reduced chi-square ``s`` above 1),
    its noise SD at ``lum`` times ``sqrt(s - 1)`` (the calibration's residuals: a model that
    misses its own readings by that much misses a repeat pass by as much, and that is no
    change of the display); ``s`` counts only beyond its 95th percentile under noise alone.
    Zero where the fit fits or was not recorded. The noise is the one the calibration was
    fitted under (its readings' weights: under another, a fit weighted otherwise misses them
    by more than that noise although its model fits).

    The misfit counted is the one the diagnosis meets: the model form's at the drive levels as
    the diagnosis predicts them. A calibration fitted with its levels rounded to a DAC grid
    (``dac_bits``) that the display did not round (levels between its codes) misses its
    readings only because of the rounding; the diagnosis predicts at the levels as given, where
    the model may fit. So where the calibration's own readings ``rows`` (its readings.csv) give
    the levels as measured, the model is refitted there without rounding
    (:func:`_unrounded_fit`), and the smaller of the two misfits counts (was: a clean check of
    such a display read 0.1-0.2 nats per reading below its floor, "mis-estimated")."""
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
    raw = _unrounded_fit(cal, fit, rows, noise)
    if raw is not None:
        chi2 = min(chi2, float(np.sum(((raw[1] - raw[2]) / sd(raw[1])) ** 2)))
    # Only the misfit the residuals show beyond what noise gives in 95 % of fits (the chi-square
    # above its 95th percentile): a reduced chi-square a little above 1 by chance (its SD is
    # sqrt(2 / dof), 0.2 with 50 readings) is noise, and counting it would loosen every
    # reading's SD (a clean check then reads below its floor); a model that misses its
    # readings by several noise SDs keeps nearly all of its misfit.
    excess = (chi2 - stats.chi2.ppf(0.95, dof)) / dof
    return sd(lum) * np.sqrt(max(excess, 0.0))



def _unrounded_fit(cal, fit, rows, noise):
    """``(levels, readings, fitted)`` of the calibration's model refitted at its readings'
    levels as measured (not rounded to its DAC grid), uncensored readings only; None where the
    fit did not round (``dac_bits`` None), ``rows`` are not given or do not match the fit's
    readings, or the refit fails."""
    from calibration import CalibrationError, fit_gamma

    if getattr(fit, "dac_bits", None) is None or rows is None or not len(rows):
        return None
    centre = rows[(rows["x_norm"].to_numpy(float) == 0) & (rows["y_norm"].to_numpy(float) == 0)]
    x = centre["level"].to_numpy(float)
    y = centre["luminance_cd_m2"].to_numpy(float)
    if x.size != len(fit.levels) or not np.allclose(y, np.asarray(fit.luminance_cd_m2, float)):
        return None
    keep = ~np.asarray(fit.censored, bool) if len(fit.censored) == x.size else y > 0
    try:
        refit = fit_gamma(x, y, model=cal.gamma_model, noise=noise, dac_bits=None,
                          floor_cd_m2=noise.floor_cd_m2)
    except (CalibrationError, ValueError, RuntimeError):
        return None
    from calibration import gamma_luminance

    mu = np.asarray(gamma_luminance(x[keep], model=cal.gamma_model, params=refit.params), float)
    return x[keep], y[keep], mu
