"""One calibration run end to end: window + photometer -> readings -> fit -> validation -> files.

The edges (the PsychoPy window, the serial port) are opened here as context managers; the
logic between them lives in :mod:`calibration.procedure`, :mod:`calibration.fit` and
:mod:`calibration.report`.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict
from pathlib import Path

import pandas as pd

from calibration.beside import refit_beside, same_fit
from calibration.errors import CalibrationError
from calibration.fit import (
    centre_readings,
    fit_calibration,
    select_calibration,
    select_position,
)
from calibration.gamma import DAC_BITS
from calibration.photometers import open_photometer
from calibration.procedure import (
    PatchDisplay,
    ProcedureSettings,
    calibration_window,
    load_or_create_settings,
    measure_schedule,
    measure_validation,
    read_validation,
    reserved_id_problem,
)
from calibration.profile import check_profile_target
from calibration.readings import (
    READINGS_COLUMNS,
    REJECTED_COLUMNS,
    REQUIRED_COLUMNS,
    newest_timestamp,
    parse_utc,
    read_readings,
    read_record_csv,
)
from calibration.record import DEFAULT_CRT, load_calibration
from calibration.report import report_text, write_outputs
from calibration.runmeta import read_meta as _read_meta
from calibration.runmeta import write_meta as _write_meta
from labfiles import FolderLock, csv_record, write_new_file
from labfiles.clock import future_problem

__all__ = [
    "DISPLAY_KEYS",
    "display_warnings",
    "fit_readings_file",
    "load_display_file",
    "refit",
    "run_calibration",
]


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


def _usable_rows(table, path: Path, progress, why_empty: str):
    """``table`` (a :func:`read_readings` result) when it has usable rows; its notes are
    passed to ``progress`` as warnings. ``why_empty`` ends the error for a file with none
    (what it holds, then the fix)."""
    if table.n_rows == 0:
        raise CalibrationError(f"{path} holds no readings {why_empty}")
    for note in table.notes:
        progress(f"warning: {note}")
    if table.frame.empty:
        raise CalibrationError(f"{path}: none of its {table.n_rows} rows is usable (see the "
                               "warnings above)")
    return table


def refit(out_dir, *, progress=print, lock: bool = True, force_profile: bool = False):
    """Fit again from ``out_dir``'s readings (no window, no photometer) and write the outputs.

    A calibration is never replaced: where ``out_dir/calibration.json`` exists and the refit
    gives the same calibration, the file is kept byte for byte (a session that recorded its
    SHA-256 stays resumable); where the refit differs (readings edited, other fit code), it is a
    new calibration, written with a folder of its own beside the old one
    (:func:`calibration.beside.refit_beside`). The calibration's age stays that of its newest
    reading (``measured_utc``): a refit never makes an old calibration look new. Each row of
    ``readings.csv`` that cannot be used is reported (``progress`` and ``report.txt``).

    Parameters
    ----------
    lock : bool
        Hold the folder's lock while fitting (False when the caller holds it).
    force_profile : bool
        Add the calibration to a PsychoPy profile ``monitors/<name>.json`` that holds others
        (:func:`calibration.profile.check_profile_target`).

    Returns
    -------
    (Calibration, dict of paths)
        ``paths["calibration"]`` is the calibration written (or kept).

    Raises
    ------
    CalibrationError
        If ``run_meta.json`` or the readings are missing or unusable, or no reading belongs to
        the folder's calibration (the message lists the ids found).
    """
    out_dir = Path(out_dir)
    if lock:
        with _lock(out_dir):
            return refit(out_dir, progress=progress, lock=False, force_profile=force_profile)
    cal, readings, validation, notes = _fit_folder(out_dir, progress)
    old = out_dir / "calibration.json"
    keep = old.exists()
    if keep:
        try:
            kept = load_calibration(old)
        except CalibrationError as exc:  # damaged: kept for whoever looks, the refit beside
            progress(f"warning: {exc}")
            return refit_beside(out_dir, cal, progress, refit=refit)
        if not same_fit(kept, cal):
            return refit_beside(out_dir, cal, progress, refit=refit)
        cal = kept  # not written again: the same bytes, the same SHA-256
    paths = write_outputs(cal, readings, out_dir, validation, notes=notes,
                          force_profile=force_profile, keep_calibration=keep)
    progress(report_text(cal, readings, notes))
    return cal, paths


def _fit_folder(out_dir: Path, progress):
    """The calibration fitted from a calibration folder's readings (nothing written).

    Returns
    -------
    (Calibration, readings DataFrame, validation DataFrame, notes tuple)
    """
    meta = _read_meta(out_dir)
    cal_id = meta["calibration_id"]
    path = out_dir / "readings.csv"
    table = _usable_rows(read_readings(path, own_file=True), path, progress,
                         f"({'empty' if path.is_file() else 'missing'}); run `python -m "
                         "calibration run` with the same --out to measure them")
    notes = tuple(meta.get("source_notes", ())) + table.notes
    readings = select_calibration(table.frame, cal_id, source=path)
    others = table.frame[table.frame["calibration_id"] != cal_id]
    if len(others):
        ids = sorted(set(others["calibration_id"].astype(str)))
        note = (f"{path}: {len(others)} row(s) of other calibration(s) {ids} not used (this "
                f"folder's calibration is {cal_id!r})")
        progress(f"warning: {note}")
        notes += (note,)
    measured, _ = newest_timestamp(readings)
    measured = measured or meta.get("measured_utc")
    if measured is None:
        raise CalibrationError(
            f"{path}: no reading has a timestamp_utc, so the calibration's age is unknown; fit "
            "the file with `python -m calibration fit READINGS.csv --measured-utc TIME`")
    validation = read_validation(out_dir / "validation.csv")
    validation = validation[validation["calibration_id"] == cal_id]
    rejected = read_record_csv(out_dir / "rejected.csv", REJECTED_COLUMNS)
    n_rej = int((rejected["calibration_id"] == cal_id).sum())
    cal = fit_calibration(readings, n_rejected=n_rej, validation=validation,
                          measured_utc=measured, **meta["fit"])
    return cal, readings, validation, notes


def _lock(out_dir: Path) -> FolderLock:
    return FolderLock(out_dir, what="calibration folder")


#: Keys of the ``[display]`` table of a ``--display`` file for ``calibration fit READINGS.csv``.
DISPLAY_KEYS = ("monitor_name", "resolution_px", "width_cm", "distance_cm", "refresh_hz",
                "device")


def load_display_file(path) -> dict:
    """The ``[display]`` table of a TOML file (other tables, e.g. ``[crt]``, are ignored).

    Keys (all optional): monitor_name, resolution_px ([w, h]), width_cm (visible picture),
    distance_cm (viewing), refresh_hz, device (photometer).

    Raises
    ------
    CalibrationError
        If the file is missing or not TOML, has no ``[display]`` table, or an unknown key.
    """
    from calibration.tomlfile import read_toml

    path = Path(path)
    table = read_toml(path, "display file").get("display")
    if not isinstance(table, dict):
        raise CalibrationError(
            f"display file {path} has no [display] table; write e.g. [display] width_cm = 32.4, "
            "resolution_px = [1024, 768], distance_cm = 55, refresh_hz = 85")
    unknown = sorted(set(table) - set(DISPLAY_KEYS))
    if unknown:
        raise CalibrationError(f"display file {path}: unknown key(s) {unknown} in [display]; "
                               f"known: {list(DISPLAY_KEYS)}")
    return dict(table)


def _imported_id(frame, calibration_id: str | None, readings_path: Path) -> str:
    """The id of a calibration fitted from a file: ``calibration_id``, else the file's single
    id, else ``import-<file stem>``; refused if it holds other characters or is reserved."""
    file_ids = sorted(set(frame["calibration_id"]) - {""})
    cal_id = calibration_id or (file_ids[0] if file_ids else
                                "import-" + re.sub(r"[^A-Za-z0-9_-]+", "-",
                                                   readings_path.stem).strip("-"))
    if not cal_id.replace("-", "").replace("_", "").isalnum():
        raise CalibrationError(f"calibration id {cal_id!r} may hold letters, digits, '-' "
                               "and '_' only; pass --calibration-id")
    if reserved_id_problem(cal_id):
        raise CalibrationError(reserved_id_problem(cal_id))
    return cal_id


def _measured_time(frame, measured_utc: str | None, readings_path: Path) -> str:
    """When the readings were taken (ISO 8601 UTC): the newest ``timestamp_utc`` of the file,
    else ``--measured-utc``; refused when both or neither are given, or in the future."""
    newest, _ = newest_timestamp(frame)
    if newest is not None and measured_utc is not None:
        raise CalibrationError(
            f"{readings_path} has timestamp_utc values (newest {newest}); --measured-utc is "
            "for files without them: leave it out")
    measured = newest or measured_utc
    if measured is None:
        raise CalibrationError(
            f"{readings_path} has no timestamp_utc column (or none with a zone), so the "
            "calibration's age is unknown; pass --measured-utc with the time the readings "
            "were taken (ISO 8601 UTC, e.g. 2026-08-01T10:00:00Z)")
    problem = future_problem(parse_utc(measured, "--measured-utc"),
                             "--measured-utc" if newest is None
                             else f"{readings_path}: newest timestamp_utc")
    if problem:
        raise CalibrationError(problem + (" with --measured-utc" if newest is None else
                                          " in the file's timestamp_utc column"))
    return measured


def _imported_fit_meta(frame, display: dict, design, cal_id: str, *, dac_bits,
                       floor_cd_m2: float | None, readings_path: Path) -> dict:
    """``run_meta.json``'s ``fit`` of a calibration fitted from a file: the display, the
    instrument (the file's single device, else ``unknown``), the DAC bits, the floor
    (refused unless finite and >= 0, cd/m^2) and the warnings."""
    devices = sorted(set(frame["device"]) - {""})
    device = str(display.get("device") or (devices[0] if len(devices) == 1 else "unknown"))
    warn, fit_meta = _display_meta(display, design, cal_id, device)
    fit_meta["dac_bits"] = dac_bits
    if floor_cd_m2 is not None:
        if not (math.isfinite(floor_cd_m2) and floor_cd_m2 >= 0):
            raise CalibrationError(f"--floor-cd-m2 {floor_cd_m2!r}: give the photometer's "
                                   "lowest reading in cd/m^2 (>= 0), e.g. 0.01")
        fit_meta["floor_cd_m2"] = float(floor_cd_m2)
    fit_meta["instrument"] = {"device": device, "source": str(readings_path.resolve())}
    fit_meta["warnings"] = [*warn, (f"fitted from {readings_path.name} (`calibration fit "
                                    "READINGS.csv`), not measured by the procedure")]
    return fit_meta


def fit_readings_file(readings_path, out_dir, design, *, level_scale: float = 1.0,
                      position=None, calibration_id: str | None = None,
                      display: dict | None = None, measured_utc: str | None = None,
                      dac_bits: int | None = DAC_BITS, floor_cd_m2: float | None = None,
                      progress=print, force_profile: bool = False):
    """Fit a calibration from a readings file alone (any tool's; no window, no photometer).

    The usable readings are copied into ``out_dir/readings.csv`` (the procedure's columns, the
    source untouched), with ``run_meta.json``, so ``python -m calibration fit --out DIR`` refits
    the folder later. Then the outputs of :func:`refit` are written.

    Parameters
    ----------
    readings_path : path
        CSV with at least ``level`` and ``luminance_cd_m2`` (:mod:`calibration.readings`).
    out_dir : path
        The calibration folder written (locked while writing).
    design : studydesign.StudyDesign
        Resolution, viewing distance and nominal refresh rate where ``display`` gives none.
    level_scale : float
        Drive value of full white in the file (255 for 8-bit values).
    position : (float, float) or None
        Fit the readings at this position (norm units) only, as if at the centre.
    calibration_id : str or None
        Which calibration of the file to fit (needed when it holds several); also the new
        folder's id. Default: the file's single id, else ``import-<file stem>``.
    display : dict or None
        :data:`DISPLAY_KEYS` (from :func:`load_display_file`).
    measured_utc : str or None
        When the readings were taken, for a file without ``timestamp_utc`` (ISO 8601, UTC).
    dac_bits : int or None
        Bits per gun of the display's output: the levels are rounded to its grid before the
        fit (default 8); None fits them as given (a display behind a finer lookup table).
        Kept in ``run_meta.json``, so a refit uses it too.
    floor_cd_m2 : float or None
        The photometer's floor, cd/m^2 (readings at or below it are censored); default 2
        absolute noise SDs. Kept in ``run_meta.json``.
    force_profile : bool
        See :func:`refit`.

    Raises
    ------
    CalibrationError
        Empty file, missing columns, a wrong level scale, an unknown calibration id or
        position, no time for the readings, or an ``out_dir`` that holds other readings.
    """
    readings_path, out_dir = Path(readings_path), Path(out_dir)
    display = dict(display or {})
    unknown = sorted(set(display) - set(DISPLAY_KEYS))
    if unknown:
        raise CalibrationError(f"unknown display key(s) {unknown}; known: {list(DISPLAY_KEYS)}")
    if not readings_path.is_file():
        raise CalibrationError(f"readings file {readings_path} not found")
    with _lock(out_dir):
        table = read_readings(readings_path, level_scale=level_scale)
        table = _usable_rows(table, readings_path, progress,
                             f"({'a header only' if table.columns else 'it is empty'}); a "
                             f"readings file needs the columns {list(REQUIRED_COLUMNS)} and "
                             "one row per reading")
        frame = select_calibration(table.frame, calibration_id, source=readings_path)
        if position is not None:
            frame = select_position(frame, position)
        centre_readings(frame)  # before anything is written
        cal_id = _imported_id(frame, calibration_id, readings_path)
        frame = frame.assign(calibration_id=cal_id)
        measured = _measured_time(frame, measured_utc, readings_path)
        fit_meta = _imported_fit_meta(frame, display, design, cal_id, dac_bits=dac_bits,
                                      floor_cd_m2=floor_cd_m2, readings_path=readings_path)
        meta = {"calibration_id": cal_id, "source": str(readings_path.resolve()),
                "level_scale": level_scale,
                "position": None if position is None else list(position),
                "measured_utc": measured, "source_notes": list(table.notes), "fit": fit_meta}
        _refuse_other_fit(out_dir, meta)
        out_dir.mkdir(parents=True, exist_ok=True)
        _write_imported_readings(out_dir / "readings.csv", frame, readings_path)
        _write_meta(out_dir, meta)
        return refit(out_dir, progress=progress, lock=False, force_profile=force_profile)


def _refuse_other_fit(out_dir: Path, meta: dict) -> None:
    """A folder holding a calibration takes only the same fit again (a rerun of the command):
    other readings or options would replace the calibration a session may have recorded."""
    if not (out_dir / "calibration.json").exists():
        return
    try:
        same = _read_meta(out_dir) == json.loads(json.dumps(meta))
    except CalibrationError:
        same = False
    if not same:
        raise CalibrationError(
            f"{out_dir} holds a calibration (calibration.json) fitted from other readings or "
            "options, and a calibration is never replaced: fit into a new --out, or refit that "
            f"folder with `python -m calibration fit --out {out_dir}` (a refit that differs is "
            "written beside it)")


def _display_meta(display: dict, design, cal_id: str, device: str) -> tuple[list, dict]:
    warn = []
    dd = design.display
    values = {"resolution_px": list(dd.resolution_px), "distance_cm": dd.viewing_distance_cm,
              "refresh_hz": dd.nominal_refresh_hz, "width_cm": DEFAULT_CRT["width_cm"]}
    for name, value in values.items():
        if name not in display:
            what = "the default" if name == "width_cm" else "the design's"
            warn.append(f"{name} not given; recorded {what} {value} (pass --display FILE with "
                        f"{name} in its [display] table)")
    values |= {k: v for k, v in display.items() if k in values}
    return warn, {"calibration_id": cal_id, "device": device,
                  "monitor_name": str(display.get("monitor_name", "glossdepth-crt")),
                  **values}


def _write_imported_readings(path: Path, frame: pd.DataFrame, source: Path) -> None:
    """The imported readings as the procedure's ``readings.csv``; never replaces other data."""
    text = "\n".join([csv_record(READINGS_COLUMNS)] + [
        csv_record([row[c] for c in READINGS_COLUMNS])
        for row in frame[list(READINGS_COLUMNS)].to_dict("records")]) + "\n"
    if path.exists():
        if path.read_text(encoding="utf-8") == text:
            return
        raise CalibrationError(
            f"{path} exists and holds other readings than {source}; fit into a new --out (what "
            "a folder has recorded is never replaced)")
    write_new_file(path, text)


def run_calibration(design, *, device: str, port: str, out_dir, settings: ProcedureSettings,
                    width_cm: float | None = None, monitor_name: str = "glossdepth-crt",
                    timeout_s: float = 30.0, retries: int = 2, fullscr: bool = True,
                    refresh_hz: float | None = None, sim_aim=None, progress=print,
                    given=None, force_profile: bool = False):
    """Measure (resuming), fit, validate, and write the outputs into ``out_dir``.

    The folder is locked for the run (a second run into it stops with a message naming this
    one).

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
    given : iterable of str or None
        Settings given explicitly; on a resume they must equal the stored ones
        (:func:`calibration.procedure.load_or_create_settings`). None: all of them.
    force_profile : bool
        See :func:`refit`; checked before anything is measured.

    Returns
    -------
    (Calibration, dict of paths)
    """
    if refresh_hz is not None and not refresh_hz > 0:
        raise CalibrationError(f"--refresh-hz {refresh_hz}: give the CRT's rate in Hz (> 0)")
    out_dir = Path(out_dir)
    with _lock(out_dir):
        return _run_locked(design, device=device, port=port, out_dir=out_dir,
                           settings=settings, width_cm=width_cm, monitor_name=monitor_name,
                           timeout_s=timeout_s, retries=retries, fullscr=fullscr,
                           refresh_hz=refresh_hz, sim_aim=sim_aim, progress=progress,
                           given=given, force_profile=force_profile)


def _run_locked(design, *, device, port, out_dir: Path, settings, width_cm, monitor_name,
                timeout_s, retries, fullscr, refresh_hz, sim_aim, progress, given,
                force_profile):
    settings = load_or_create_settings(out_dir, settings, given=given)
    # A profile that would be refused is refused before anything is measured.
    check_profile_target(out_dir / "monitors", monitor_name, settings.calibration_id,
                         force=force_profile)
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
            cal = _fit_folder(out_dir, lambda *_: None)[0]  # written once, after validation
            measure_validation(phot, display, settings, cal, out_dir, progress=progress)
    return refit(out_dir, progress=progress, lock=False, force_profile=force_profile)
