"""Write a calibration's outputs: JSON, gamma ramp, PsychoPy monitor profile, figures, a report."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from calibration.gamma import GAMMA_MODELS
from calibration.plots import plot_gamma, plot_uniformity
from calibration.profile import check_profile_target, write_monitor_profile
from calibration.psychopy_gamma import best_psychopy_gamma
from calibration.ramp import (
    RAMP_BITS,
    RAMP_FILE,
    REPORT_FRACTIONS,
    gamma_ramp,
    ramp_error_pct,
    write_gamma_ramp,
)
from calibration.record import Calibration, save_calibration
from labfiles import atomic_write_text

__all__ = ["report_text", "write_outputs"]


def report_text(cal: Calibration, readings: pd.DataFrame, notes=()) -> str:
    """A plain-text summary: the models, the choice, uniformity, validation, warnings.

    ``notes`` (what reading the file did with rows it could not use) are listed at the end.
    """
    measured = cal.measured_utc or "unknown (the age counts from the fit)"
    lines = [
        f"Calibration {cal.calibration_id}  (readings up to {measured}; fitted {cal.created_utc})",
        (f"instrument: {cal.device} (readings from {cal.instrument['source']})"
         if "source" in cal.instrument else
         f"instrument: {cal.device} {cal.instrument.get('identity', '')} on "
         f"{cal.instrument.get('port', '?')}"),
        (f"display: {cal.monitor_name}, {cal.resolution_px[0]} x {cal.resolution_px[1]} px, "
        f"{cal.width_cm:g} cm wide, viewed at {cal.distance_cm:g} cm, {cal.refresh_hz:.1f} Hz"),
        (f"readings: {len(readings)} accepted "
        f"({readings[['x_norm', 'y_norm']].drop_duplicates().shape[0]} positions)"),
        "",
        "gamma models (screen centre): RMSE and leave-one-level-out (held-out) errors",
        (f"   {'model':<19} {'RMSE':>8}  {'held-out RMSE':>13}  {'held-out RMS':>12}  "
         f"{'held-out RMS':>12}  {'misfit':<7} parameters"),
        (f"   {'':<19} {'cd/m^2':>8}  {'cd/m^2':>13}  {'% of reading':>12}  "
         f"{'noise SDs':>12}"),
    ]
    for f in cal.fits:
        mark = "*" if f.model == cal.gamma_model else " "
        params = ", ".join(f"{k}={f.params[k]:.4g}" for k in GAMMA_MODELS[f.model])
        if not params:
            params = f"{f.n_params or len(f.params) // 2} knots"
        lines.append(f" {mark} {f.model:<19} {f.rmse_cd_m2:8.4f}  {f.heldout_rmse_cd_m2:13.4f}"
                     f"  {f.heldout_rms_pct:10.3f} %  {f.heldout_rms_z:12.2f}  "
                     f"{_misfit_flag(f):<7} {params}")
    lines += [
        (f"chosen: {cal.gamma_model} (the simplest model whose held-out error in noise SDs is "
         "within one standard error of the best)") if cal.fits else
        (f"curve: {cal.gamma_model} {cal.gamma_params} (given, not fitted: no readings; see the "
         "warnings)"),
        f"luminance range: {cal.min_luminance_cd_m2:.3f} - {cal.max_luminance_cd_m2:.3f} cd/m^2",
    ]
    lines += _fit_summary(cal)
    lines += ["", *other_experiments_lines(cal)]
    if cal.uniformity is not None:
        u = cal.uniformity
        lines += ["", (f"uniformity: non-uniformity {u.nonuniformity_pct:.2f} % "
                      "(relative luminance, rows top to bottom):")]
        for y, row in zip(reversed(u.y_norm), reversed(u.relative)):
            lines.append(f"  y={y:+.2f}: " + "  ".join(f"{v:.3f}" for v in row))
    if cal.validation_max_deviation_pct is not None:
        lines += ["", (f"validation after correction: max deviation from linear luminance "
                      f"{cal.validation_max_deviation_pct:.2f} % of the range")]
    lines += ["", "warnings:" if cal.warnings else "warnings: none"]
    lines += [f"  - {w}" for w in cal.warnings]
    if notes:
        lines += ["", "rows of the readings file not used as they are:"]
        lines += [f"  - {n}" for n in notes]
    return "\n".join(lines) + "\n"


def _pcts(values) -> str:
    return " / ".join(f"{round(float(v), 1) + 0.0:+.1f}" for v in values)


def other_experiments_lines(cal: Calibration) -> list[str]:
    """The report's lines on the gamma ramp and the PsychoPy profile: the error each leaves at
    :data:`calibration.ramp.REPORT_FRACTIONS` of the luminance range (% of the luminance asked
    for above black)."""
    ramp = gamma_ramp(cal, bits=RAMP_BITS)
    fractions = REPORT_FRACTIONS
    at = " / ".join(f"{100 * f:g}" for f in fractions)
    exact = ramp_error_pct(cal, ramp, fractions)
    dac8 = ramp_error_pct(cal, ramp, fractions, dac_bits=8)
    dac10 = ramp_error_pct(cal, ramp, fractions, dac_bits=10)
    pp = best_psychopy_gamma(cal)
    return [
        ("for the lab's other experiments (glossdepth's stimuli are corrected in their pixels: "
        "load neither for them); error in % of the luminance asked for above black at "
        f"{at} % of the range:"),
        (f"  {RAMP_FILE} ({ramp.size} entries per gun, the chosen model's inverse): "
        f"{_pcts(exact)} %"),
        f"    after an 8-bit DAC's rounding: {_pcts(dac8)} %; 10-bit: {_pcts(dac10)} %",
        f"  {pp.statement()}",
        f"    PsychoPy's gamma {pp.gamma:.3f}: {_pcts(pp.error_pct)} %",
    ]


def _misfit_flag(fit) -> str:
    """FLAGGED (residuals not noise-like), no, or n/a (too few readings per parameter to
    test: an interpolating model, or a record written before the test)."""
    if fit.warnings:
        return "FLAGGED"
    tested = any(fit.misfit.get(k) is not None for k in ("chi2_p", "runs_p"))
    return "no" if tested else "n/a"


def _fit_summary(cal: Calibration) -> list[str]:
    """Lines on the chosen fit: fitted against measured white and black, the noise model and
    the censored readings (none for a record without the fits)."""
    fit = cal.chosen_fit
    if fit is None or not fit.levels:
        return []
    x = np.asarray(fit.levels, float)
    y = np.asarray(fit.luminance_cd_m2, float)
    out = []
    if x.max() >= 1.0 - 1e-9:
        white = float(y[x == x.max()].mean())
        fitted = cal.max_luminance_cd_m2
        out.append(f"white (drive 1): fitted {fitted:.3f} cd/m^2, measured {white:.3f} cd/m^2 "
                   f"({100 * (fitted - white) / white:+.2f} %); held-out RMSE "
                   f"{fit.heldout_rmse_cd_m2:.4f} cd/m^2 = "
                   f"{100 * fit.heldout_rmse_cd_m2 / white:.3f} % of white")
    if x.min() <= 1e-9:
        out.append(f"black (drive 0): fitted {cal.min_luminance_cd_m2:.3f} cd/m^2, measured "
                   f"{float(y[x == x.min()].mean()):.3f} cd/m^2")
    n = fit.noise
    if n:
        where = ("fitted to repeated readings" if n.get("source") == "repeats" else
                 "the default: no repeated readings" if n.get("source") == "default" else
                 str(n.get("source")))
        n_cens = int(sum(fit.censored))
        zero = n.get("zero_floor_cd_m2")
        zeros = ("" if zero is None or not (y <= 0).any() else
                 f"; a reading of 0 taken as at most {float(zero):.3g} cd/m^2 (the meter's own "
                 "floor: documented, given, or at most the lowest positive reading)")
        out.append(f"noise: SD = sqrt({n['abs_cd_m2']:.3g}^2 + ({n['rel']:.3g} L)^2) cd/m^2 "
                   f"({where}); meter floor {n['floor_cd_m2']:.3g} cd/m^2: {n_cens} of "
                   f"{len(y)} readings at or below it, fitted as censored{zeros}")
    return out


def write_outputs(cal: Calibration, readings: pd.DataFrame, out_dir,
                  validation: pd.DataFrame | None = None, notes=(), *,
                  force_profile: bool = False, keep_calibration: bool = False) -> dict:
    """Write calibration.json, gamma_ramp.csv, monitors/<name>.json, gamma.png, uniformity.png,
    report.txt.

    Parameters
    ----------
    force_profile : bool
        Add the calibration to a profile ``monitors/<name>.json`` that holds other calibrations
        (:func:`calibration.profile.check_profile_target`); without it such a profile stops the
        writing before any file is written.
    keep_calibration : bool
        calibration.json holds ``cal`` already and is not written again (its bytes, and so the
        SHA-256 a session recorded, stay as they are).

    Returns
    -------
    dict
        Name -> path of each file written.
    """
    out_dir = Path(out_dir)
    check_profile_target(out_dir / "monitors", cal.monitor_name, cal.calibration_id,
                         force=force_profile)
    paths = {"calibration": out_dir / "calibration.json" if keep_calibration else
             save_calibration(cal, out_dir / "calibration.json")}
    paths["gamma_ramp"] = write_gamma_ramp(cal, out_dir / RAMP_FILE)
    paths["monitor"] = write_monitor_profile(cal, out_dir / "monitors", readings,
                                             force=force_profile)
    paths["gamma_plot"] = plot_gamma(cal, readings, out_dir / "gamma.png", validation)
    uni = plot_uniformity(cal, out_dir / "uniformity.png")
    if uni is not None:
        paths["uniformity_plot"] = uni
    text = report_text(cal, readings, notes)
    atomic_write_text(out_dir / "report.txt", text)
    paths["report"] = out_dir / "report.txt"
    return paths
