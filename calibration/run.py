"""One calibration run end to end: window + photometer -> readings -> fit -> validation -> files.

The edges (the PsychoPy window, the serial port) are opened here as context managers; the
logic between them lives in :mod:`calibration.procedure`, :mod:`calibration.fit` and
:mod:`calibration.report`.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict
from pathlib import Path

import pandas as pd

from calibration.errors import CalibrationError
from calibration.fit import fit_calibration
from calibration.photometers import open_photometer
from calibration.procedure import (
    PatchDisplay,
    ProcedureSettings,
    calibration_window,
    load_or_create_settings,
    measure_schedule,
    measure_validation,
)
from calibration.readings import load_readings
from calibration.record import DEFAULT_CRT
from calibration.report import report_text, write_outputs

__all__ = ["display_warnings", "refit", "run_calibration"]


def display_warnings(design, resolution_px, refresh_hz: float | None) -> tuple[list, float]:
    """Compare the window with the design; returns (warnings, refresh rate to record)."""
    warn = []
    want = tuple(design.display.resolution_px)
    if tuple(resolution_px) != want:
        warn.append(f"screen is {resolution_px[0]} x {resolution_px[1]} px but the design "
                    f"expects {want[0]} x {want[1]}: set the CRT's video mode before sessions")
    nominal = design.display.nominal_refresh_hz
    if refresh_hz is None:
        warn.append(f"refresh rate could not be measured; recorded the design's nominal "
                    f"{nominal:g} Hz")
        return warn, nominal
    if abs(refresh_hz - nominal) > 0.05 * nominal:
        warn.append(f"measured refresh rate {refresh_hz:.1f} Hz differs from the design's "
                    f"nominal {nominal:g} Hz (recorded as measured)")
    return warn, float(refresh_hz)


def _write_meta(out_dir: Path, meta: dict) -> None:
    path = out_dir / "run_meta.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(meta, indent=2) + "\n")
    os.replace(tmp, path)


def refit(out_dir, *, progress=print):
    """Fit again from ``out_dir``'s readings (no window, no photometer) and rewrite the outputs.

    Raises
    ------
    CalibrationError
        If ``run_meta.json`` or ``readings.csv`` is missing.
    """
    out_dir = Path(out_dir)
    meta_path = out_dir / "run_meta.json"
    if not meta_path.is_file():
        raise CalibrationError(f"{meta_path} not found; run `python -m calibration run` first")
    meta = json.loads(meta_path.read_text())
    readings = load_readings(out_dir / "readings.csv")
    if readings.empty:
        raise CalibrationError(f"{out_dir / 'readings.csv'} holds no readings")
    readings = readings[readings["calibration_id"] == meta["calibration_id"]]
    validation = None
    vpath = out_dir / "validation.csv"
    if vpath.is_file():
        validation = pd.read_csv(vpath, on_bad_lines="skip").dropna(subset=["luminance_cd_m2"])
    rejected = out_dir / "rejected.csv"
    n_rej = len(pd.read_csv(rejected, on_bad_lines="skip")) if rejected.is_file() else 0
    cal = fit_calibration(readings, n_rejected=n_rej, validation=validation, **meta["fit"])
    paths = write_outputs(cal, readings, out_dir, validation)
    progress(report_text(cal, readings))
    return cal, paths


def run_calibration(design, *, device: str, port: str, out_dir, settings: ProcedureSettings,
                    width_cm: float | None = None, monitor_name: str = "glossdepth-crt",
                    timeout_s: float = 30.0, retries: int = 2, fullscr: bool = True,
                    refresh_hz: float | None = None, sim_aim=None, progress=print):
    """Measure (resuming), fit, validate, and write the outputs into ``out_dir``.

    Parameters
    ----------
    design : studydesign.StudyDesign
        Resolution, viewing distance and nominal refresh rate.
    device, port
        Photometer and its serial port.
    out_dir : path
        Calibration folder; a rerun into the same folder resumes.
    settings : ProcedureSettings
        Used when ``out_dir`` holds no ``procedure.json`` yet; otherwise the stored ones are.
    width_cm : float or None
        Visible picture width measured with a ruler; None records the default (32 cm) with a
        warning.
    refresh_hz : float or None
        Refresh rate to record instead of measuring it (Hz), for a display that does not sync
        to the vertical blank (a virtual X display in tests and the demo measures hundreds of
        Hz). The record carries a warning that it was given, not measured.
    sim_aim : path or None
        Simulation only (see :mod:`calibration.fake_instrument`).

    Returns
    -------
    (Calibration, dict of paths)
    """
    if refresh_hz is not None and not refresh_hz > 0:
        raise CalibrationError(f"--refresh-hz {refresh_hz}: give the CRT's rate in Hz (> 0)")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    settings = load_or_create_settings(out_dir, settings)
    warn = []
    if width_cm is None:
        width_cm = DEFAULT_CRT["width_cm"]
        warn.append(f"screen width not given; recorded the default {width_cm:g} cm "
                    "(measure the visible picture and pass --width-cm)")
    with open_photometer(device, port, timeout_s=timeout_s, retries=retries) as phot, \
            calibration_window(fullscr=fullscr, size_px=design.display.resolution_px) as win:
        res = tuple(int(v) for v in win.size)
        if refresh_hz is None:
            measured_hz = win.getActualFrameRate(nIdentical=10, nMaxFrames=120,
                                                 nWarmUpFrames=10)
            dwarn, refresh_hz = display_warnings(design, res, measured_hz)
        else:
            dwarn, _ = display_warnings(design, res, float(refresh_hz))
            dwarn.append(f"refresh rate {refresh_hz:g} Hz was given (--refresh-hz), not measured")
            refresh_hz = float(refresh_hz)
        meta = {"calibration_id": settings.calibration_id, "fit": {
            "calibration_id": settings.calibration_id, "device": device,
            "monitor_name": monitor_name, "resolution_px": list(res), "width_cm": width_cm,
            "distance_cm": design.display.viewing_distance_cm, "refresh_hz": refresh_hz,
            "instrument": phot.info(), "warnings": warn + dwarn}, "settings": asdict(settings)}
        _write_meta(out_dir, meta)
        display = PatchDisplay(win, settings, sim_aim=sim_aim)
        measure_schedule(phot, display, settings, out_dir, progress=progress)
        if settings.n_validation:
            cal, _ = refit(out_dir, progress=lambda *_: None)
            measure_validation(phot, display, settings, cal, out_dir, progress=progress)
    return refit(out_dir, progress=progress)
