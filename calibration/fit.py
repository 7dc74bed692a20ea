"""From readings to a :class:`~calibration.record.Calibration`: gamma, uniformity, validation.

Pure functions of data frames; nothing here touches a window or a port.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from calibration.errors import CalibrationError
from calibration.gamma import DAC_BITS, GammaFit, choose_gamma_model, fit_gamma_models
from calibration.noise import zero_bound
from calibration.readings import at_centre, newest_timestamp
from calibration.record import Calibration, utc_now_iso
from calibration.uniformity import fit_uniformity

__all__ = [
    "centre_readings",
    "fit_calibration",
    "monotonicity_warnings",
    "select_calibration",
    "select_position",
    "validation_deviation_pct",
]


def _positions_text(readings: pd.DataFrame) -> str:
    pos = readings[["x_norm", "y_norm"]].drop_duplicates().to_numpy(float)
    shown = ", ".join(f"{x:g},{y:g}" for x, y in pos[:12])
    return shown + (f" and {len(pos) - 12} more" if len(pos) > 12 else "")


def centre_readings(readings: pd.DataFrame) -> pd.DataFrame:
    """The readings at the screen centre (x_norm = y_norm = 0), the ones the gamma fit uses.

    Raises
    ------
    CalibrationError
        If there are none (the message lists the positions there are and the fix).
    """
    if readings.empty:
        raise CalibrationError("no readings to fit")
    c = readings[at_centre(readings)]
    if c.empty:
        raise CalibrationError(
            "no readings at the screen centre (x_norm = y_norm = 0); the readings are at "
            f"{_positions_text(readings)}: pass --position X,Y to fit one of those positions")
    return c


def select_calibration(readings: pd.DataFrame, calibration_id: str | None, *,
                       source="the readings") -> pd.DataFrame:
    """The rows of one calibration.

    Parameters
    ----------
    readings : DataFrame
        Column ``calibration_id``.
    calibration_id : str or None
        None: the file must hold a single calibration (or none named).
    source : str
        The file, for messages.

    Raises
    ------
    CalibrationError
        If no row has ``calibration_id`` (the message lists the ids found and how many rows
        each has), or None was given and several calibrations are present.
    """
    counts = readings["calibration_id"].astype(str).value_counts().sort_index()
    found = ", ".join(f"{k!r} ({v} rows)" for k, v in counts.items()) or "none"
    if calibration_id is None:
        if len(counts) > 1:
            raise CalibrationError(f"{source} holds several calibrations: {found}; pass "
                                   "--calibration-id with the one to fit")
        return readings
    picked = readings[readings["calibration_id"].astype(str) == str(calibration_id)]
    if picked.empty:
        raise CalibrationError(
            f"{source} has no reading of calibration {calibration_id!r}; its calibration ids "
            f"are {found}. Pass --calibration-id with one of them (a folder's id is in its "
            "run_meta.json)")
    return picked


def select_position(readings: pd.DataFrame, position) -> pd.DataFrame:
    """The readings at one screen position, moved to the centre (for a single-position fit).

    Parameters
    ----------
    position : (float, float)
        x_norm, y_norm; matched within 0.001.

    Raises
    ------
    CalibrationError
        If no reading lies there (the message lists the positions found).
    """
    x, y = (float(v) for v in position)
    at = readings[((readings["x_norm"] - x).abs() < 1e-3) & ((readings["y_norm"] - y).abs() < 1e-3)]
    if at.empty:
        raise CalibrationError(f"no readings at position {x:g},{y:g}; the readings are at "
                               f"{_positions_text(readings)}")
    return at.assign(x_norm=0.0, y_norm=0.0)


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


def _fit_centre(readings: pd.DataFrame, *, device: str, dac_bits: int | None,
                floor_cd_m2: float | None) -> tuple[np.ndarray, np.ndarray, tuple[GammaFit, ...]]:
    """Every gamma model fitted to the centre's readings (:func:`fit_calibration`'s
    ``dac_bits`` and ``floor_cd_m2``).

    Returns
    -------
    levels, luminance_cd_m2 : ndarray, shape (n,)
        The centre's drive levels in [0, 1] and readings (cd/m^2).
    fits : tuple of GammaFit
        One per model (:func:`calibration.gamma.fit_gamma_models`).
    """
    centre = centre_readings(readings)
    levels = centre["level"].to_numpy(float)
    lum = centre["luminance_cd_m2"].to_numpy(float)
    # A zero says the light was below the meter's own floor: the one given, else the
    # device's documented floor, else at most the lowest positive reading (zero_bound).
    positive = lum[lum > 0]
    zero = float(floor_cd_m2) if floor_cd_m2 is not None else zero_bound(
        device, float(positive.min()) if positive.size else None, 0.0)[0]
    fits = fit_gamma_models(levels, lum, dac_bits=dac_bits, floor_cd_m2=floor_cd_m2,
                            zero_floor_cd_m2=zero if zero > 0 else None)
    return levels, lum, fits


def fit_calibration(readings: pd.DataFrame, *, calibration_id: str, device: str,
                    monitor_name: str, resolution_px, width_cm: float, distance_cm: float,
                    refresh_hz: float, instrument: dict | None = None,
                    warnings=(), n_rejected: int = 0, validation: pd.DataFrame | None = None,
                    created_utc: str | None = None,
                    measured_utc: str | None = None,
                    dac_bits: int | None = DAC_BITS,
                    floor_cd_m2: float | None = None) -> Calibration:
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
    created_utc : str or None
        When the record is written (default: now).
    measured_utc : str or None
        When the newest reading was taken (the calibration's age counts from it); default the
        newest ``timestamp_utc`` of ``readings``. Without either, ``measured_utc`` is None and
        the age counts from ``created_utc`` (the command line refuses that: it asks for
        ``--measured-utc``).
    dac_bits : int or None
        Bits per gun of the display's output: levels are rounded to its grid before the fit
        (:func:`calibration.gamma.displayed_drive`; default 8, the frame buffer); None fits
        the levels as given (a display driven through a finer lookup table).
    floor_cd_m2 : float or None
        The photometer's floor, cd/m^2: readings at or below it are fitted as censored
        (default: 2 absolute noise SDs, :mod:`calibration.noise`).

    Returns
    -------
    Calibration
    """
    levels, lum, fits = _fit_centre(readings, device=device, dac_bits=dac_bits,
                                    floor_cd_m2=floor_cd_m2)
    best = choose_gamma_model(fits)
    warn = list(warnings) + monotonicity_warnings(levels, lum) + list(best.warnings)
    if measured_utc is None:
        measured_utc, _ = newest_timestamp(readings)
    if n_rejected:
        warn.append(f"{n_rejected} photometer repl{'y' if n_rejected == 1 else 'ies'} rejected "
                    "(garbled, out of range or saturated; see rejected.csv) and remeasured")
    positions = readings[["x_norm", "y_norm"]].drop_duplicates()
    uniformity = fit_uniformity(readings) if len(positions) > 1 else None
    cal = Calibration(
        calibration_id=calibration_id,
        created_utc=created_utc or utc_now_iso(),
        measured_utc=measured_utc,
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
