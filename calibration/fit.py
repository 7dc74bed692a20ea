"""From readings to a :class:`~calibration.record.Calibration`: gamma, uniformity, validation.

Pure functions of data frames; nothing here touches a window or a port.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from calibration.errors import CalibrationError
from calibration.gamma import choose_gamma_model, fit_gamma_models
from calibration.record import Calibration, utc_now_iso
from calibration.uniformity import fit_uniformity

__all__ = ["fit_calibration", "monotonicity_warnings", "validation_deviation_pct"]


def _centre(readings: pd.DataFrame) -> pd.DataFrame:
    c = readings[(readings["x_norm"].abs() < 1e-9) & (readings["y_norm"].abs() < 1e-9)]
    if c.empty:
        raise CalibrationError("no readings at the screen centre (x_norm = y_norm = 0)")
    return c


def monotonicity_warnings(levels, luminance_cd_m2, *, tolerance: float = 0.005) -> list[str]:
    """Warnings where mean luminance falls as the level rises.

    Parameters
    ----------
    levels, luminance_cd_m2 : array_like
        Readings (repeats allowed).
    tolerance : float
        A fall smaller than this fraction of the luminance range is taken as noise.
    """
    means = pd.Series(np.asarray(luminance_cd_m2, float)).groupby(
        np.asarray(levels, float)).mean().sort_index()
    span = means.max() - means.min()
    out = []
    for (l0, y0), (l1, y1) in zip(means.items(), list(means.items())[1:]):
        if y1 < y0 - tolerance * span:
            out.append(
                f"non-monotonic curve: luminance falls from {y0:.3f} cd/m^2 at level {l0:.3f} to "
                f"{y1:.3f} cd/m^2 at level {l1:.3f}; check the photometer's aim and the "
                "display's warm-up, then remeasure"
            )
    return out


def validation_deviation_pct(validation: pd.DataFrame, cal: Calibration) -> tuple[float, np.ndarray]:
    """Deviation of gamma-corrected readings from linear luminance.

    Parameters
    ----------
    validation : DataFrame
        Columns target_fraction, luminance_cd_m2.
    cal : Calibration
        The fit the correction came from.

    Returns
    -------
    max_abs_pct : float
        Largest |measured - target| in % of the luminance range (max - min).
    deviation_pct : ndarray
        Per row.
    """
    span = cal.max_luminance_cd_m2 - cal.min_luminance_cd_m2
    target = cal.min_luminance_cd_m2 + validation["target_fraction"].to_numpy(float) * span
    dev = 100 * (validation["luminance_cd_m2"].to_numpy(float) - target) / span
    return float(np.max(np.abs(dev))), dev


def fit_calibration(readings: pd.DataFrame, *, calibration_id: str, device: str,
                    monitor_name: str, resolution_px, width_cm: float, distance_cm: float,
                    refresh_hz: float, instrument: dict | None = None,
                    warnings=(), n_rejected: int = 0, validation: pd.DataFrame | None = None,
                    created_utc: str | None = None) -> Calibration:
    """Fit every gamma model to the centre's readings, choose one, add uniformity and validation.

    Parameters
    ----------
    readings : DataFrame
        ``readings.csv`` rows (:data:`calibration.readings.READINGS_COLUMNS`).
    calibration_id, device, monitor_name, resolution_px, width_cm, distance_cm, refresh_hz
        Recorded as given (see :class:`Calibration`).
    instrument : dict
        Port and identity of the photometer.
    warnings : sequence of str
        Warnings from the procedure (resolution, refresh rate), kept in the record.
    n_rejected : int
        Rejected replies during the run (reported as a warning when > 0).
    validation : DataFrame or None
        ``validation.csv`` rows; sets ``validation_max_deviation_pct``.

    Returns
    -------
    Calibration
    """
    centre = _centre(readings)
    levels = centre["level"].to_numpy(float)
    lum = centre["luminance_cd_m2"].to_numpy(float)
    fits = fit_gamma_models(levels, lum)
    best = choose_gamma_model(fits)
    warn = list(warnings) + monotonicity_warnings(levels, lum) + list(best.warnings)
    if n_rejected:
        warn.append(f"{n_rejected} photometer repl{'y' if n_rejected == 1 else 'ies'} rejected "
                    "(garbled, out of range or saturated; see rejected.csv) and remeasured")
    positions = readings[["x_norm", "y_norm"]].drop_duplicates()
    uniformity = fit_uniformity(readings) if len(positions) > 1 else None
    cal = Calibration(
        calibration_id=calibration_id,
        created_utc=created_utc or utc_now_iso(),
        device=device,
        monitor_name=monitor_name,
        resolution_px=tuple(int(v) for v in resolution_px),
        width_cm=float(width_cm),
        distance_cm=float(distance_cm),
        refresh_hz=float(refresh_hz),
        gamma_model=best.model,
        gamma_params=dict(best.params),
        min_luminance_cd_m2=float(best.luminance(0.0)),
        max_luminance_cd_m2=float(best.luminance(1.0)),
        fits=fits,
        uniformity=uniformity,
        warnings=tuple(warn),
        instrument=dict(instrument or {}),
        readings_file="readings.csv",
    )
    if validation is not None and len(validation):
        max_dev, _ = validation_deviation_pct(validation, cal)
        cal = Calibration.from_dict(cal.to_dict() | {"validation_max_deviation_pct": max_dev})
    return cal
