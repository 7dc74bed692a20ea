"""A PsychoPy Monitor profile from a calibration, written into a project folder.

PsychoPy keeps monitor profiles in ``psychopy.monitors.calibTools.monitorFolder`` (by default
``$HOME/.psychopy3/monitors``, fixed when PsychoPy is imported). We point that name at the
calibration's own ``monitors/`` folder while saving, so nothing is written into the user's
home; the lab's other experiments use the profile by copying ``<name>.json`` into their
monitor folder (or by setting ``monitorFolder`` the same way).

The gamma grid (rows luminance, R, G, B; columns min, max, gamma, a, b, k) holds PsychoPy's
eq. 4 parameters when the chosen model is ``offset_power``; otherwise the eq. 1 (``power``) fit,
which PsychoPy can invert (the extended power function's threshold has no PsychoPy equation).
The readings themselves are stored as ``levelsPre``/``lumsPre`` for PsychoPy's interpolation.
"""

from __future__ import annotations

import shutil
import tempfile
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd

from calibration.gamma import fit_gamma
from calibration.readings import at_centre
from calibration.record import Calibration
from labfiles import atomic_write_bytes

__all__ = ["gamma_grid", "write_monitor_profile"]


def gamma_grid(cal: Calibration) -> tuple[np.ndarray, int]:
    """PsychoPy gamma grid (4 x 6) and linearise method for a calibration."""
    fit = {f.model: f for f in cal.fits}
    if cal.gamma_model == "offset_power" or not fit:
        p = cal.gamma_params if cal.gamma_model == "offset_power" else None
    else:
        p = None
    if p is not None:
        row = [cal.min_luminance_cd_m2, cal.max_luminance_cd_m2, p["gamma"], p["a"], p["b"],
               p["k"]]
        method = 4
    else:
        power = fit.get("power")
        if power is None:
            # PsychoPy inverts eq. 1 and eq. 4 only: fit eq. 1 to the chosen curve itself.
            x = np.linspace(0, 1, 256)
            power = fit_gamma(x, cal.luminance_for_drive(x), model="power")
        q = power.params
        row = [q["a"], q["a"] + q["b"] ** q["gamma"], q["gamma"], q["a"], q["b"], 1.0]
        method = 1
    return np.array([row] * 4, dtype=float), method


def write_monitor_profile(cal: Calibration, folder, readings: pd.DataFrame | None = None) -> Path:
    """Save ``cal`` as PsychoPy Monitor ``cal.monitor_name`` in ``folder``.

    Returns
    -------
    Path
        ``folder/<monitor_name>.json``.
    """
    from psychopy import logging, monitors
    from psychopy.monitors import calibTools

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / f"{cal.monitor_name}.json"
    # PsychoPy writes the profile in place; it writes into a scratch folder here, and the file is
    # then moved onto the target atomically (with the umask's permissions).
    scratch = Path(tempfile.mkdtemp(dir=folder, prefix=".profile-"))
    saved, level = calibTools.monitorFolder, logging.console.level
    calibTools.monitorFolder = str(scratch)
    # A new profile makes Monitor() warn "specification not found"; that is expected here.
    logging.console.setLevel(logging.ERROR)
    try:
        existed = target.is_file()
        if existed:
            shutil.copyfile(target, scratch / target.name)
        mon = monitors.Monitor(cal.monitor_name, verbose=False, autoLog=False)
        # Monitor() makes a temporary calibration for a new profile; a refit replaces its own.
        stale = [n for n in mon.calibNames if not existed or n == cal.calibration_id]
        for name in stale:
            mon.calibNames.remove(name)
            mon.calibs.pop(name, None)
        mon.newCalib(calibName=cal.calibration_id, width=cal.width_cm, distance=cal.distance_cm)
        mon.setSizePix(list(cal.resolution_px))
        grid, method = gamma_grid(cal)
        mon.setGammaGrid(grid)
        mon.setLineariseMethod(method)
        if readings is not None and len(readings):
            centre = readings[at_centre(readings)]
            means = centre.groupby("level")["luminance_cd_m2"].mean()
            mon.setLevelsPre(list(np.round(means.index.to_numpy() * 255, 3)))
            mon.setLumsPre(np.tile(means.to_numpy(), (4, 1)))
        # The profile's date is that of the readings, as the calibration's age (a refit of old
        # readings is not a new calibration).
        date = datetime.fromisoformat(cal.age_from_utc).timestamp()
        mon.setCalibDate(date)
        mon.setNotes(
            f"glossdepth calibration {cal.calibration_id} ({cal.device}); chosen model "
            f"{cal.gamma_model} {cal.gamma_params}; refresh {cal.refresh_hz:.1f} Hz; see "
            "calibration.json beside this folder"
        )
        mon.save()
        atomic_write_bytes(target, (scratch / target.name).read_bytes())
    finally:
        calibTools.monitorFolder = saved
        logging.console.setLevel(level)
        shutil.rmtree(scratch, ignore_errors=True)
    return target
