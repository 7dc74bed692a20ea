"""A lab's PsychoPy Monitor Center profile as a calibration of this project.

``python -m calibration import-psychopy NAME|FILE --out DIR``. The profile is read by PsychoPy
itself (``psychopy.monitors.Monitor``, its folder pointed at the file's for the reading), one
calibration of it (the current one, the last by name as PsychoPy takes it, unless named):

* **with readings** (``levelsPre``, ``lumsPre``: Monitor Center's gamma measurement): the
  luminance row ``lumsPre[0]`` at ``levelsPre / 255`` becomes ``DIR/readings.csv``, fitted as any
  readings (every model, the same choice), so ``calibration fit --out DIR`` refits it. A profile
  this project wrote stores ``lumsPre`` scaled 0-1 (first level 0, last 1); it is recognised by
  exactly those two values with a gamma grid whose white exceeds 1 and its black, and scaled back
  to cd/m^2 with the grid's min and max.
* **without readings** (a grid typed in, or PsychoPy's newer ``calibrateGamma``): the gamma grid's
  luminance row is kept as the fitted curve (eq. 1 ``power``, eq. 2 ``inner_power`` or eq. 4
  ``offset_power``, by the profile's linearise method), not refitted, and the record and report
  say so.

Either way the calibration is dated by the profile's ``calibDate`` (every reading's
``timestamp_utc``; the calibration's age counts from it, as for any readings), its geometry is
the profile's (width, distance, pixels; the design's where the profile has none, with a
warning), and the outputs are those of ``calibration fit``.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from calibration.errors import CalibrationError
from calibration.gamma import DAC_BITS, gamma_luminance
from calibration.readings import READINGS_COLUMNS, parse_utc
from calibration.record import DEFAULT_CRT, Calibration, load_calibration, utc_now_iso
from calibration.report import report_text, write_outputs
from calibration.run import _lock, _write_imported_readings, refit
from calibration.runmeta import write_meta
from labfiles.clock import future_problem

__all__ = ["PsychopyProfile", "import_psychopy_profile", "read_psychopy_profile"]


@dataclass(frozen=True)
class PsychopyProfile:
    """One calibration of a PsychoPy monitor profile, as PsychoPy reads it.

    Attributes
    ----------
    path : Path
        The profile's file.
    name : str
        The monitor's name (the file's stem).
    calib_name : str
        The calibration's name within the profile.
    calib : dict
        Its fields (``gammaGrid``, ``linearizeMethod``, ``levelsPre``, ``lumsPre``,
        ``calibDate``, ``width``, ``distance``, ``sizePix``, ...), arrays as numpy arrays.
    """

    path: Path
    name: str
    calib_name: str
    calib: dict


def _profile_path(source) -> Path:
    from psychopy.monitors import calibTools

    path = Path(source)
    if path.suffix == ".json" or path.is_file():
        if not path.is_file():
            raise CalibrationError(f"PsychoPy profile {path} not found; give the file's path or "
                                   "a monitor name from Monitor Center")
        return path
    folder = Path(calibTools.monitorFolder)
    path = folder / f"{source}.json"
    if not path.is_file():
        names = sorted(p.stem for p in folder.glob("*.json")) if folder.is_dir() else []
        raise CalibrationError(
            f"no PsychoPy monitor {source!r} in {folder} (monitors there: "
            f"{', '.join(names) or 'none'}); give one of those names or the profile's file "
            "path (NAME.json)")
    return path


def read_psychopy_profile(source, *, calib_name: str | None = None) -> PsychopyProfile:
    """Read one calibration of a PsychoPy monitor profile with ``psychopy.monitors.Monitor``.

    Parameters
    ----------
    source : str or path
        A monitor name in PsychoPy's monitor folder, or a profile file (``NAME.json``).
    calib_name : str or None
        The calibration to read; default the one PsychoPy makes current (the last by name).

    Raises
    ------
    CalibrationError
        If the profile is missing or unreadable, or has no calibration ``calib_name`` (the
        message lists those it has).
    """
    from psychopy import logging, monitors
    from psychopy.monitors import calibTools

    path = _profile_path(source)
    saved, level = calibTools.monitorFolder, logging.console.level
    calibTools.monitorFolder = str(path.parent)
    logging.console.setLevel(logging.ERROR)
    try:
        mon = monitors.Monitor(path.stem, verbose=False, autoLog=False)
    except (ValueError, TypeError, KeyError, OSError) as exc:
        raise CalibrationError(f"PsychoPy cannot read the monitor profile {path} ({exc}); "
                               "open it in Monitor Center and save it again") from None
    finally:
        calibTools.monitorFolder = saved
        logging.console.setLevel(level)
    if not mon.calibNames:
        raise CalibrationError(f"PsychoPy monitor profile {path} holds no calibration")
    if calib_name is not None:
        if calib_name not in mon.calibNames:
            raise CalibrationError(f"{path} has no calibration {calib_name!r}; its calibrations "
                                   f"are {mon.calibNames}: pass --psychopy-calibration with one")
        mon.setCurrent(calib_name)
    return PsychopyProfile(path=path, name=mon.name, calib_name=mon.currentCalibName,
                           calib=dict(mon.currentCalib))


def _calib_date_utc(profile: PsychopyProfile) -> str | None:
    """The profile's calibDate (seconds since the epoch; a struct_time in old files) as UTC."""
    d = profile.calib.get("calibDate")
    if isinstance(d, time.struct_time):
        d = time.mktime(d)
    if isinstance(d, (int, float)) and math.isfinite(d) and d > 0:
        return datetime.fromtimestamp(float(d), UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    return None


def profile_readings(profile: PsychopyProfile) -> tuple[np.ndarray, np.ndarray, list[str]] | None:
    """The luminance readings a profile holds: (levels 0-1, cd/m^2, notes), or None.

    ``levelsPre / 255`` (as PsychoPy's linearise method 3 reads them) and the luminance row of
    ``lumsPre`` (all guns together); non-finite pairs are left out with a note.
    """
    levels, lums = profile.calib.get("levelsPre"), profile.calib.get("lumsPre")
    if levels is None or lums is None:
        return None
    x = np.asarray(levels, dtype=float).ravel() / 255.0
    y = np.asarray(lums, dtype=float)
    y = y[0] if y.ndim == 2 else y.ravel()
    if x.size != y.size:
        raise CalibrationError(f"{profile.path}: levelsPre has {x.size} values but lumsPre "
                               f"{y.size}; re-measure in Monitor Center")
    notes = []
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.all():
        notes.append(f"{profile.path}: {int((~ok).sum())} level(s) without a finite reading "
                     "left out")
    x, y = x[ok], y[ok]
    grid = _grid_row(profile)
    if (y.size >= 2 and y[0] == 0.0 and y[-1] == 1.0 and grid is not None
            and grid[1] > max(grid[0], 1.0)):
        y = grid[0] + y * (grid[1] - grid[0])
        notes.append(f"{profile.path}: lumsPre scaled 0-1 (as glossdepth writes them); "
                     f"scaled back with the gamma grid's min {grid[0]:.4g} and max "
                     f"{grid[1]:.4g} cd/m^2")
    return x, y, notes


def _grid_row(profile: PsychopyProfile) -> np.ndarray | None:
    grid = profile.calib.get("gammaGrid")
    if grid is None:
        return None
    g = np.asarray(grid, dtype=float)
    return g.reshape(-1, g.shape[-1])[0] if g.ndim == 2 else None


#: Per-gun gammas further apart than this (relative) are said: one curve serves all guns.
_GUN_GAMMA_SPREAD = 0.05


def _gun_warnings(profile: PsychopyProfile) -> list[str]:
    """A warning where the gamma grid's gun rows (R, G, B: rows 1-3) hold gammas that differ:
    the calibration keeps one curve, the luminance row's (or the readings' lumsPre[0]), for
    all three guns, which is right for grey (R = G = B) but corrects no gun on its own."""
    grid = profile.calib.get("gammaGrid")
    if grid is None:
        return []
    g = np.asarray(grid, dtype=float)
    if g.ndim != 2 or g.shape[0] < 4 or g.shape[1] < 3:
        return []
    guns = g[1:4, 2]
    if not np.all(np.isfinite(guns) & (guns > 0)):
        return []
    if guns.max() / guns.min() - 1 <= _GUN_GAMMA_SPREAD:
        return []
    lum = g[0, 2]
    return [(f"{profile.path}: the profile's guns have gammas R {guns[0]:.3g}, G {guns[1]:.3g}, "
            f"B {guns[2]:.3g} (luminance {lum:.3g}); this calibration keeps one curve, the "
            "luminance's, for all three guns: grey (R = G = B, as glossdepth's stimuli) is "
            "linearised, a colour is not per gun. For coloured stimuli, load the profile in "
            "PsychoPy itself (its gammaGrid per gun)")]


def _curve_from_grid(profile: PsychopyProfile) -> tuple[str, dict, int]:
    """(model, params, PsychoPy equation) of the grid's luminance row."""
    row = _grid_row(profile)
    method = profile.calib.get("linearizeMethod", profile.calib.get("lineariseMethod", 1))
    if row is None or row.size < 3 or not np.all(np.isfinite(row[:3])):
        raise CalibrationError(f"{profile.path}: calibration {profile.calib_name!r} has neither "
                               "readings (lumsPre) nor a gamma grid; calibrate it in Monitor "
                               "Center or measure with `python -m calibration run`")
    lo, hi, g = (float(v) for v in row[:3])
    if not (hi > lo and g > 0) or (lo == 0.0 and hi == 1.0 and g == 1.0):
        raise CalibrationError(
            f"{profile.path}: calibration {profile.calib_name!r} holds PsychoPy's default grid "
            f"(min {lo:g}, max {hi:g}, gamma {g:g}), not a measurement; calibrate the monitor "
            "(`python -m calibration run`)")
    if method == 4 and row.size >= 6 and np.all(np.isfinite(row[3:6])):
        return "offset_power", {"a": float(row[3]), "b": float(row[4]), "k": float(row[5]),
                                "gamma": g}, 4
    if method == 2 and lo >= 0:
        b = lo ** (1 / g)
        return "inner_power", {"b": b, "k": hi ** (1 / g) - b, "gamma": g}, 2
    return "power", {"a": lo, "b": (hi - lo) ** (1 / g), "gamma": g}, 1


def _geometry(profile: PsychopyProfile, design) -> tuple[dict, list[str]]:
    c, dd, warn = profile.calib, design.display, []
    values = {"width_cm": c.get("width"), "distance_cm": c.get("distance"),
              "resolution_px": c.get("sizePix")}
    fallback = {"width_cm": DEFAULT_CRT["width_cm"], "distance_cm": dd.viewing_distance_cm,
                "resolution_px": list(dd.resolution_px)}
    for key, value in values.items():
        try:
            bad = (len(value) != 2 or min(int(v) for v in value) <= 0
                   if key == "resolution_px" else not float(value) > 0)
        except (TypeError, ValueError):
            bad = True
        if bad:
            values[key] = fallback[key]
            warn.append(f"the PsychoPy profile has no usable {key} ({value!r}); recorded "
                        f"{fallback[key]} (edit it in Monitor Center and import again)")
    values["resolution_px"] = [int(v) for v in values["resolution_px"]]
    values["refresh_hz"] = dd.nominal_refresh_hz
    warn.append(f"a PsychoPy profile records no refresh rate; recorded the design's nominal "
                f"{dd.nominal_refresh_hz:g} Hz")
    return {k: (float(v) if k != "resolution_px" else v) for k, v in values.items()}, warn


def _default_id(profile: PsychopyProfile) -> str:
    text = f"psychopy-{profile.name}-{profile.calib_name}"
    return re.sub(r"[^A-Za-z0-9_-]+", "-", text).strip("-")


def import_psychopy_profile(source, out_dir, design, *, calib_name: str | None = None,
                            calibration_id: str | None = None, measured_utc: str | None = None,
                            force_profile: bool = False, progress=print):
    """Import a PsychoPy monitor profile's calibration into ``out_dir`` (see the module).

    Parameters
    ----------
    source : str or path
        Monitor name (in PsychoPy's monitor folder) or profile file.
    out_dir : path
        The calibration folder written (locked while writing).
    design : studydesign.StudyDesign
        Refresh rate (a profile has none) and geometry the profile lacks.
    calib_name : str or None
        The profile's calibration (default: the current one).
    calibration_id : str or None
        The new calibration's id (default ``psychopy-<monitor>-<calibration name>``).
    measured_utc : str or None
        When it was measured, for a profile without ``calibDate`` (ISO 8601 UTC).
    force_profile : bool
        See :func:`calibration.run.refit`.

    Returns
    -------
    (Calibration, dict of paths)

    Raises
    ------
    CalibrationError
        A missing or unreadable profile, no date, neither readings nor a measured grid, or an
        ``out_dir`` that holds another calibration.
    """
    profile = read_psychopy_profile(source, calib_name=calib_name)
    out_dir = Path(out_dir)
    cal_id = calibration_id or _default_id(profile)
    if not cal_id.replace("-", "").replace("_", "").isalnum():
        raise CalibrationError(f"calibration id {cal_id!r} may hold letters, digits, '-' and "
                               "'_' only; pass --calibration-id")
    date = _calib_date_utc(profile)
    if date is not None and measured_utc is not None:
        raise CalibrationError(f"{profile.path} is dated {date} (its calibDate); --measured-utc "
                               "is for a profile without a date: leave it out")
    measured = date or measured_utc
    if measured is None:
        raise CalibrationError(f"{profile.path} has no calibDate, so the calibration's age is "
                               "unknown; pass --measured-utc with the time it was measured")
    problem = future_problem(parse_utc(measured, "--measured-utc"),
                             f"{profile.path}: calibDate" if date else "--measured-utc")
    if problem:
        raise CalibrationError(problem)
    geometry, warn = _geometry(profile, design)
    warn = warn + _gun_warnings(profile)
    source_note = (f"imported from the PsychoPy profile {profile.path.resolve()}, calibration "
                   f"{profile.calib_name!r} (`calibration import-psychopy`)")
    meta = {"calibration_id": cal_id, "device": "unknown", "monitor_name": profile.name,
            **geometry, "instrument": {"device": "unknown",
                                       "source": str(profile.path.resolve())}}
    readings = profile_readings(profile)
    # Checked before the folder is made: a profile without readings must hold a measured grid.
    curve = _curve_from_grid(profile) if readings is None else None
    with _lock(out_dir):
        if curve is not None:
            return _import_curve(curve, out_dir, meta, measured, warn + [source_note],
                                 force_profile, progress)
        x, y, notes = readings
        frame = pd.DataFrame({
            "calibration_id": cal_id, "timestamp_utc": measured, "device": "unknown",
            "x_norm": 0.0, "y_norm": 0.0, "level": x, "repeat": 0, "luminance_cd_m2": y,
            "raw_reply": [f"PsychoPy lumsPre[0][{i}]" for i in range(x.size)]})
        out_dir.mkdir(parents=True, exist_ok=True)
        _write_imported_readings(out_dir / "readings.csv", frame[list(READINGS_COLUMNS)],
                                 profile.path)
        write_meta(out_dir, {"calibration_id": cal_id, "source": str(profile.path.resolve()),
                              "measured_utc": measured, "source_notes": notes,
                              "fit": {**meta, "dac_bits": DAC_BITS,
                                      "warnings": warn + [source_note]}})
        return refit(out_dir, progress=progress, lock=False, force_profile=force_profile)


def _import_curve(curve: tuple, out_dir: Path, meta: dict, measured: str, warn: list,
                  force_profile: bool, progress):
    """A profile without readings: its grid's curve (:func:`_curve_from_grid`) as the
    calibration, not refitted."""
    model, params, eq = curve
    existing = out_dir / "calibration.json"
    if (out_dir / "readings.csv").exists() or (
            existing.is_file() and load_calibration(existing).calibration_id
            != meta["calibration_id"]):
        raise CalibrationError(f"{out_dir} holds another calibration; import into a new --out "
                               "(what a folder has recorded is never replaced)")
    warn = [*warn, (f"no readings in the PsychoPy profile: its fitted curve (PsychoPy eq. {eq}, "
                   f"model {model}) is kept as it is, not refitted, and cannot be checked "
                   "against readings; measure the display with `python -m calibration run`")]
    cal = Calibration(
        created_utc=utc_now_iso(), measured_utc=measured, gamma_model=model,
        gamma_params=params,
        min_luminance_cd_m2=float(gamma_luminance(0.0, model=model, params=params)),
        max_luminance_cd_m2=float(gamma_luminance(1.0, model=model, params=params)),
        warnings=tuple(warn), readings_file="",
        **(meta | {"resolution_px": tuple(meta["resolution_px"])}))
    readings = pd.DataFrame({c: pd.Series(dtype=float if c in ("x_norm", "y_norm", "level",
                                                                 "luminance_cd_m2") else object)
                             for c in READINGS_COLUMNS})
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = write_outputs(cal, readings, out_dir, force_profile=force_profile)
    progress(report_text(cal, readings))
    return cal, paths
