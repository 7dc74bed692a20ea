"""A PsychoPy Monitor profile from a calibration, written into a project folder.

PsychoPy keeps monitor profiles in ``psychopy.monitors.calibTools.monitorFolder`` (by default
``$HOME/.psychopy3/monitors``, fixed when PsychoPy is imported). We point that name at a scratch
folder while PsychoPy saves, and move the one file ``<monitor_name>.json`` into the
calibration's own ``monitors/`` folder, so nothing is written into the user's home and no other
profile is touched; a profile of the same name that holds another calibration (a lab's own
Monitor Center profile) is refused unless ``force`` (its calibrations are then kept beside
ours). The lab's other experiments use the profile by copying ``<name>.json`` into their monitor
folder (or by setting ``monitorFolder`` the same way).

What the profile holds (one calibration, named by the calibration id; the same curve for the
luminance row and the three guns, as the calibration measures grey):

* gamma grid (rows luminance, R, G, B; columns min, max, gamma, a, b, k) and linearise method 1:
  PsychoPy's eq. 1 ``min + (max - min) x^gamma``, whose inverse ``x = f^(1/gamma)`` is also what a
  PsychoPy ``Window`` applies through its hardware table. The gamma is the one that minimises
  PsychoPy's largest error on this display (:mod:`calibration.psychopy_gamma`); min and max are
  the first and last level means read (as PsychoPy's own GammaCalculator takes them).
* ``levelsPre`` (0-255) and ``lumsPre``: the centre's level means, scaled to 0 at the first level
  and 1 at the last, so that PsychoPy's linearise method 3 (linear interpolation), which
  normalises with ``lums - lums[0] / (lums[-1] - lums[0])`` (the division binds first), inverts
  the readings correctly. ``min + lumsPre * (max - min)`` gives the means in cd/m^2 back
  (:mod:`calibration.psychopy_import` reads them so).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd

from calibration.errors import CalibrationError
from calibration.psychopy_gamma import best_psychopy_gamma
from calibration.readings import at_centre
from calibration.record import Calibration
from labfiles import atomic_write_bytes

__all__ = ["check_profile_target", "gamma_grid", "level_means", "write_monitor_profile"]


def level_means(readings: pd.DataFrame | None) -> pd.Series:
    """Mean luminance (cd/m^2) of each level at the screen centre, sorted by level (0-1)."""
    if readings is None or not len(readings):
        return pd.Series(dtype=float)
    centre = readings[at_centre(readings)]
    return centre.groupby("level")["luminance_cd_m2"].mean().sort_index()


def gamma_grid(cal: Calibration, means: pd.Series | None = None) -> tuple[np.ndarray, int]:
    """PsychoPy gamma grid (4 x 6) and linearise method (1) for a calibration.

    Parameters
    ----------
    means : Series or None
        :func:`level_means`; its first and last values are the grid's min and max (default the
        model's black and white).
    """
    gamma = best_psychopy_gamma(cal).gamma
    if means is not None and len(means) >= 2 and means.iloc[-1] > means.iloc[0]:
        lo, hi = float(means.iloc[0]), float(means.iloc[-1])
    else:
        lo, hi = cal.min_luminance_cd_m2, cal.max_luminance_cd_m2
    row = [lo, hi, gamma, lo, (hi - lo) ** (1.0 / gamma), 1.0]
    return np.array([row] * 4, dtype=float), 1


def check_profile_target(folder, monitor_name: str, calibration_id: str, *,
                         force: bool = False) -> Path:
    """The profile's path, after checking that writing it loses nothing of anyone else's.

    Raises
    ------
    CalibrationError
        If ``folder/<monitor_name>.json`` exists and is not a PsychoPy profile, or holds a
        calibration other than ``calibration_id`` and ``force`` is False (the message names
        them and the two ways on).
    """
    target = Path(folder) / f"{monitor_name}.json"
    if not target.is_file():
        return target
    try:
        names = sorted(json.loads(target.read_text(encoding="utf-8")))
    except (ValueError, TypeError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{target} exists and is not a PsychoPy monitor profile ({exc}); "
                               "move it aside or pass --monitor-name with another name") from None
    others = [n for n in names if n != calibration_id]
    if others and not force:
        raise CalibrationError(
            f"{target} is another PsychoPy profile (calibrations {others}), not this "
            f"calibration's ({calibration_id!r}); it was left unchanged. Pass --monitor-name with "
            "a new name, or --force to add this calibration to it (its own are kept)")
    return target


def write_monitor_profile(cal: Calibration, folder, readings: pd.DataFrame | None = None, *,
                          force: bool = False) -> Path:
    """Save ``cal`` as PsychoPy Monitor ``cal.monitor_name`` in ``folder`` (one file, atomic).

    Parameters
    ----------
    readings : DataFrame or None
        The readings the calibration was fitted to (``levelsPre``/``lumsPre``).
    force : bool
        Add this calibration to a profile of the same name that holds others
        (:func:`check_profile_target`).

    Returns
    -------
    Path
        ``folder/<monitor_name>.json``.
    """
    from psychopy import logging, monitors
    from psychopy.monitors import calibTools

    folder = Path(folder)
    target = check_profile_target(folder, cal.monitor_name, cal.calibration_id, force=force)
    folder.mkdir(parents=True, exist_ok=True)
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
        means = level_means(readings)
        grid, method = gamma_grid(cal, means)
        mon.setGammaGrid(grid)
        mon.setLineariseMethod(method)
        if len(means) >= 2 and grid[0, 1] > grid[0, 0]:
            # An array: method 3 divides it by 255 (a list fails there).
            mon.setLevelsPre(np.round(means.index.to_numpy() * 255, 3))
            scaled = (means.to_numpy() - grid[0, 0]) / (grid[0, 1] - grid[0, 0])
            mon.setLumsPre(np.tile(scaled, (4, 1)))
        # The profile's date is that of the readings, as the calibration's age (a refit of old
        # readings is not a new calibration).
        date = datetime.fromisoformat(cal.age_from_utc).timestamp()
        mon.setCalibDate(date)
        mon.setNotes(
            f"glossdepth calibration {cal.calibration_id} ({cal.device}); chosen model "
            f"{cal.gamma_model} {cal.gamma_params}; gamma grid: eq. 1 with the gamma that "
            "minimises PsychoPy's error (see report.txt); lumsPre scaled 0-1 (min + lumsPre * "
            "(max - min) in cd/m^2); for a linear display load gamma_ramp.csv; refresh "
            f"{cal.refresh_hz:.1f} Hz; see calibration.json beside this folder"
        )
        mon.save()
        atomic_write_bytes(target, (scratch / target.name).read_bytes())
    finally:
        calibTools.monitorFolder = saved
        logging.console.setLevel(level)
        shutil.rmtree(scratch, ignore_errors=True)
    return target
