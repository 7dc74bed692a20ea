"""Display layer, reading and checking the files: a check run's or calibration's readings (REAL)
and the calibration (SIM), kept out of sample.

The readings a calibration was fitted from cannot show its gap (the fit absorbed any offset or
gain change), so :func:`load_display` drops them, or stands in the calibration's held-out
validation readings, or refuses with the fix; it also gathers the readings the photometer's
noise is measured from. :func:`_seconds` gives each reading's time for the layer's time
models: from its ISO 8601 timestamps or, in a file without any (another lab's table), from the
measurement order (a ``measurement_order`` column, else the rows' order), which then names no
seconds. A lab's file keeps its extra columns (surround grey, size of a bright region...):
:func:`_conditions` reads them beside the readings.
"""

from __future__ import annotations

import csv
import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.gap.display.null.zeros import zeros_against_calibration
from analysis.gap.engine import GapError
from calibration import READINGS_COLUMNS, CalibrationError, load_calibration, load_readings
from calibration.readings import read_readings
from labfiles import LabFileError, read_csv_frame, read_text

_MIN_READINGS = 8
#: Validation readings (one per fraction, no repeats) needed to stand in for in-sample ones:
#: with the procedure's default 9, chance gains on 4 held-out readings were attributed (1 of
#: 20 effect-free calibrations); with 17, none of 20.
_MIN_VALIDATION = 16


def _find(path: Path, name: str) -> Path:
    if path.is_dir():
        hits = sorted(path.rglob(name))
        if not hits:
            raise GapError(f"no {name} under {path}; pass the file or the folder holding it")
        return hits[0]
    if not path.is_file():
        raise GapError(f"{path} not found; pass a {name} file or the folder holding it")
    return path


#: Columns of a readings file that are neither readings nor conditions.
_NOT_CONDITIONS = (*READINGS_COLUMNS, "target_fraction", "measurement_order", "level_0_1")
#: A condition column has at least 2 and at most this many distinct values.
_MAX_CONDITION_VALUES = 24


def _read_any(path: Path) -> pd.DataFrame:
    """Readings from ``readings.csv`` / ``warmup.csv`` (READINGS_COLUMNS exactly), from
    ``validation.csv`` (READINGS_COLUMNS plus target_fraction) or from another tool's file
    (level and luminance_cd_m2 at least: :func:`calibration.readings.read_readings`), with
    the file's condition columns and measurement order kept (:func:`_conditions`)."""
    try:
        frame = load_readings(path)
    except CalibrationError:
        frame = None
    if frame is not None:
        return _with_extras(frame, path)
    try:
        frame = read_csv_frame(path, dtype={"raw_reply": str, "calibration_id": str},
                               keep_default_na=False, on_bad_lines="skip")
    except (OSError, ValueError) as exc:
        raise GapError(f"{path} is not a readings CSV ({exc})") from exc
    missing = [c for c in READINGS_COLUMNS if c not in frame.columns]
    if missing:
        raise GapError(f"{path} lacks column(s) {missing}; pass readings.csv, warmup.csv or "
                       "validation.csv written by the calibration package")
    frame = frame[list(READINGS_COLUMNS)].copy()
    for c in ("x_norm", "y_norm", "level", "luminance_cd_m2", "repeat"):
        frame[c] = pd.to_numeric(frame[c], errors="coerce")
    frame = frame.dropna(subset=["x_norm", "y_norm", "level", "repeat", "luminance_cd_m2"])
    frame["repeat"] = frame["repeat"].astype(int)
    return frame.reset_index(drop=True)


def _with_extras(frame: pd.DataFrame, path: Path) -> pd.DataFrame:
    """``frame`` (the usable readings of ``path``) with the file's ``measurement_order`` and
    condition columns (:func:`_conditions`), where every row of the file was usable (so the
    rows align); ``frame.attrs["conditions"]`` names the condition columns."""
    header = _header(path)
    extra = [c for c in header if c not in READINGS_COLUMNS and c != "target_fraction"]
    if not extra:
        return frame
    table = read_readings(path)
    if table.n_dropped or table.n_duplicates or len(table.frame) != len(frame):
        warnings.warn(f"{path}: some rows were not usable, so its columns {extra} are not "
                      "used as conditions (fix the rows the calibration notes name)",
                      stacklevel=3)
        return frame
    with open(path, encoding="utf-8-sig", newline="") as fh:
        raw = pd.DataFrame(list(csv.DictReader(fh)))
    frame = frame.copy()
    if "measurement_order" in raw:
        frame["measurement_order"] = pd.to_numeric(raw["measurement_order"],
                                                   errors="coerce").to_numpy()
    conds = _conditions(raw)
    for c in conds:
        frame[c] = conds[c].to_numpy()
    frame.attrs["conditions"] = list(conds.columns)
    return frame


def _conditions(raw: pd.DataFrame) -> pd.DataFrame:
    """The condition columns of a file's rows ``raw``: columns other than the readings'
    (:data:`_NOT_CONDITIONS`) with 2 to :data:`_MAX_CONDITION_VALUES` distinct values, each
    kept once (a column that splits the rows as an earlier one does is dropped: a bias
    region's height beside its width); numbers as floats, else text."""
    out = {}
    seen = []
    for c in raw.columns:
        if c in _NOT_CONDITIONS or c is None:
            continue
        v = raw[c].astype(str).str.strip()
        num = pd.to_numeric(v, errors="coerce")
        col = num if not num.isna().any() else v
        codes = pd.factorize(col)[0]
        if not 2 <= codes.max() + 1 <= _MAX_CONDITION_VALUES:
            continue
        if any(np.array_equal(codes, s) for s in seen):
            continue
        seen.append(codes)
        out[c] = col
    return pd.DataFrame(out)

def load_display(real_path, sim_path):
    """Read the readings to diagnose (REAL) and the calibration (SIM), out of sample.

    Parameters
    ----------
    real_path : path
        A check run's folder (``check.json``, ``readings.csv``, optional ``warmup.csv``), a
        ``readings.csv`` or ``validation.csv``, or a folder holding one.
    sim_path : path
        ``calibration.json`` or the calibration's folder.

    Returns
    -------
    (readings, calibration)
        ``readings.attrs["display_source"]`` says what was diagnosed (``real``, ``kind``:
        check / readings / validation, ``in_sample_rows``, ``notes``) and
        ``readings.attrs["noise_frames"]`` holds the readings the noise floor comes from,
        ``display_source["zero_evidence"]`` the levels that read 0 where the calibration saw
        light (:func:`~analysis.gap.display.null.zeros.zeros_against_calibration`),
        ``readings.attrs["calibration_rows"]`` the calibration's own readings (or None).

    Raises
    ------
    GapError
        If a file is missing or malformed; if the readings are the calibration's own and no
        held-out readings exist (the message names the check run to measure); if fewer than 8
        readings are left.
    """
    real = Path(real_path)
    _refuse_swapped(real, Path(sim_path))
    cpath, cal = _load_calibration(Path(sim_path))
    notes: list[str] = []
    rpath, kind, check = _locate_readings(real, cal, notes)
    readings = _read_any(rpath)
    noise_frames = [readings]
    warm = rpath.parent / "warmup.csv"
    if check is not None and warm.is_file():
        noise_frames.append(_read_any(warm))
    own = cpath.parent / (cal.readings_file or "readings.csv")
    fitted_rows = _read_any(own) if own.is_file() else None
    notes += _dropped_rows(rpath)
    in_fit = _in_fit(readings, fitted_rows, cal, kind, own, notes)
    n_in = int(in_fit.sum())
    source = {"real": str(rpath), "calibration": str(cpath), "kind": kind,
              "in_sample_rows": n_in, "n_rows": len(readings)}
    if n_in:
        readings, noise_frames = _out_of_sample(readings, in_fit, fitted_rows, rpath, cpath,
                                                cal, source, notes)
    if len(readings) < _MIN_READINGS:
        raise GapError(f"{rpath}: {len(readings)} readings; the display diagnosis needs "
                       f">= {_MIN_READINGS}")
    _refuse_uninformative(readings, Path(source["real"]))
    # Said with the verdict (the layer's warnings), not only among the notes on the inputs.
    source["zero_evidence"] = zeros_against_calibration(readings, fitted_rows, cal,
                                                        Path(source["real"]))
    _add_noise_frames(readings, fitted_rows, noise_frames, notes)
    source["notes"] = notes
    for note in notes:
        warnings.warn(note, stacklevel=2)
    readings = readings.copy()
    readings.attrs["display_source"] = source
    readings.attrs["noise_frames"] = noise_frames
    readings.attrs["calibration_rows"] = fitted_rows
    return readings, cal


def _refuse_swapped(real: Path, sim: Path) -> None:
    """A calibration passed as --real or readings passed as --sim: say so, with the order."""
    real_cal = real.is_file() and real.suffix.lower() == ".json"
    sim_readings = sim.is_file() and sim.suffix.lower() == ".csv"
    order = ("the display layer takes --real the readings (readings.csv, validation.csv or a "
             "check run's folder) and --sim the calibration (calibration.json or its folder)")
    if real_cal and sim_readings:
        raise GapError(f"--real {real} --sim {sim}: --real and --sim swapped? {order}")
    if sim_readings:
        raise GapError(f"--sim {sim} is a readings file, not a calibration: {order}")
    if real_cal:
        raise GapError(f"--real {real} is a calibration, not readings: {order}")


def _load_calibration(sim: Path):
    """``(path of calibration.json, Calibration)`` for the SIM path (the file or its folder);
    a malformed calibration raises GapError with the calibration package's message."""
    cpath = _find(sim, "calibration.json")
    try:
        cal = load_calibration(cpath)
    except CalibrationError as exc:
        raise GapError(str(exc)) from exc
    return cpath, cal


def _locate_readings(real: Path, cal, notes: list[str]):
    """``(readings path, kind, check record or None)`` for the REAL path: a check run's folder
    (kind "check"), else a readings file or the folder holding one (kind "validation" when it
    has a target_fraction column, else "readings"). Appends to ``notes`` when the check run
    checked another calibration than ``cal``."""
    check = None
    if real.is_dir() and (real / "check.json").is_file():
        check = _read_check(real / "check.json")
        rpath = real / "readings.csv"
        if not rpath.is_file():
            raise GapError(f"check run {real} has no readings.csv; rerun the check to resume")
        kind = "check"
        if check["checked_calibration_id"] != cal.calibration_id:
            notes.append(f"the check run {check['check_id']!r} checked calibration "
                         f"{check['checked_calibration_id']!r}, but --sim is calibration "
                         f"{cal.calibration_id!r}; its readings are compared with --sim")
    else:
        rpath = real if real.is_file() else _find(real, "readings.csv")
        kind = "validation" if "target_fraction" in _header(rpath) else "readings"
    return rpath, kind, check


def _in_fit(readings: pd.DataFrame, fitted_rows, cal, kind: str, own: Path,
            notes: list[str]) -> np.ndarray:
    """Boolean mask of the readings the calibration was fitted from (same calibration_id, same
    rows of its readings file ``fitted_rows``). Without that file none are known to be; a note
    is appended when readings carry the calibration's id all the same."""
    same_id = readings["calibration_id"].astype(str) == cal.calibration_id
    if fitted_rows is not None:
        keys = set(_row_keys_list(fitted_rows))
        in_fit = np.array([k in keys for k in _row_keys_list(readings)]) & same_id.to_numpy()
        by_content = _same_content(readings, fitted_rows)
        if (by_content & ~in_fit).any():
            notes.append(f"{int(by_content.sum())} of {len(readings)} readings are, position "
                         "by position and level by level, the very luminances calibration "
                         f"{cal.calibration_id!r} was fitted from ({own}), under another "
                         "file name or calibration_id: they are taken as its own readings")
            in_fit |= by_content
    else:
        in_fit = np.zeros(len(readings), bool)
        if kind == "readings" and same_id.any():
            notes.append(f"{int(same_id.sum())} readings carry the calibration's id "
                         f"{cal.calibration_id!r} but its readings file ({own}) is missing, so "
                         "whether they are the ones it was fitted from cannot be checked; if "
                         "they are, the diagnosis is in-sample and cannot show the gap")
    return in_fit


def _out_of_sample(readings: pd.DataFrame, in_fit: np.ndarray, fitted_rows, rpath: Path,
                   cpath: Path, cal, source: dict, notes: list[str]):
    """``(readings, noise_frames)`` without the in-sample readings ``in_fit``: the others when
    enough are left, else the calibration's held-out validation readings (``source`` then
    names them); a note says which. Raises GapError, naming the check run to measure, when
    neither is enough."""
    n_in = int(in_fit.sum())
    rest = readings[~in_fit].reset_index(drop=True)
    msg = (f"{n_in} of {len(readings)} readings in {rpath} are the ones calibration "
           f"{cal.calibration_id!r} was fitted from (the same readings): an "
           "in-sample fit absorbs an offset or a gain change, so they cannot show its gap")
    val = cpath.parent / "validation.csv"
    if len(rest) >= _MIN_READINGS:
        notes.append(msg + f"; diagnosing only the other {len(rest)} readings")
        readings = rest
    elif val.is_file() and len(_read_any(val)) >= _MIN_VALIDATION:
        readings = _read_any(val)
        source |= {"real": str(val), "kind": "validation"}
        notes.append(msg + f"; diagnosing the calibration's {len(readings)} held-out "
                     f"validation readings ({val}) instead. For a later state of the "
                     "display, measure a check run: python -m calibration check "
                     f"--calibration {cpath.parent} --out CHECK_DIR, then pass --real "
                     "CHECK_DIR")
    else:
        raise GapError(msg + ", and there are not enough held-out readings "
                       f"(validation.csv with >= {_MIN_VALIDATION} rows) beside {cpath}. "
                       "Measure a check run: "
                       f"python -m calibration check --calibration {cpath.parent} --out "
                       "CHECK_DIR, then pass --real CHECK_DIR")
    # The calibration's own readings still measure the photometer's noise: a pair of
    # repeats does not depend on the fit.
    noise_frames = [readings] + ([fitted_rows] if fitted_rows is not None else [])
    return readings, noise_frames


def _add_noise_frames(readings: pd.DataFrame, fitted_rows, noise_frames: list,
                      notes: list[str]) -> None:
    """Append to ``noise_frames`` the calibration's own readings from the same photometer(s)
    when they are not there yet; note when the readings themselves have no repeats."""
    # The photometer's noise does not depend on the calibration's fit: the calibration's own
    # repeats, taken with the same instrument, measure it too (drift modelled per file).
    devices = set(readings["device"].astype(str))
    if fitted_rows is not None and not any(f is fitted_rows for f in noise_frames):
        same = fitted_rows[fitted_rows["device"].astype(str).isin(devices)]
        if len(same):
            noise_frames.append(same)
    if not _has_pairs(readings) and len(noise_frames) > 1:
        notes.append("the readings have no repeats: the photometer's noise is measured from "
                     "the repeated readings of the same photometer beside them")

#: Share of a file's readings that must equal the calibration's own (position, level and
#: luminance as written) for the file to be taken as those readings: a check run's reading
#: equals one of the calibration's by chance now and then (more often from a meter that
#: reports few digits, on a stable display), a copied or trimmed file in every row.
_SAME_CONTENT_SHARE = 0.9
#: Fewest distinct drive levels: an offset, a gain and a gamma change are told apart by how
#: the change grows with the drive, which needs three levels (calibration fit needs four).
_MIN_LEVELS = 3


def _content_keys(frame: pd.DataFrame) -> list:
    return [(round(float(x), 6), round(float(y), 6), round(float(lv), 6), float(f"{lum:.6g}"))
            for x, y, lv, lum in zip(frame["x_norm"], frame["y_norm"], frame["level"],
                                     frame["luminance_cd_m2"])]


def _same_content(readings: pd.DataFrame, fitted_rows: pd.DataFrame) -> np.ndarray:
    """Boolean mask of the readings whose position, level and luminance are one of the
    calibration's own readings, where most of them are (the same readings, whatever the
    file's name, calibration_id or timestamps); all False otherwise."""
    keys = set(_content_keys(fitted_rows))
    hit = np.array([k in keys for k in _content_keys(readings)], bool)
    if not len(hit) or hit.mean() < _SAME_CONTENT_SHARE:
        return np.zeros(len(readings), bool)
    return hit


def _dropped_rows(path: Path) -> list[str]:
    """A note naming the rows of a readings file that were dropped (a negative luminance, a
    value that is no number...): the calibration package's rule drops them, and without a
    word the diagnosis of what is left would not say what it left out."""
    try:
        table = read_readings(path)
    except CalibrationError:
        return []
    said = [n for n in table.notes if " dropped: " in n]
    if not said:
        return []
    neg = sum("is negative" in n for n in said)
    why = list(dict.fromkeys(n.split(" dropped: ", 1)[1] for n in said))[:3]
    lines = [n.split(" dropped: ", 1)[0].rsplit(" line ", 1)[-1] for n in said[:5]]
    return [f"{path}: {len(said)} of {table.n_rows} rows dropped (lines {', '.join(lines)}"
            f"{', ...' if len(said) > 5 else ''}: {'; '.join(why)})"
            + (f"; {neg} negative luminance(s): a photometer's noise around a dark patch can "
               "read below 0, and leaving them out raises the dark levels' mean; if the meter "
               "subtracts a dark reading, check its zero" if neg else "")]


def _refuse_uninformative(readings: pd.DataFrame, path: Path) -> None:
    """Refuse readings that cannot show a display's gap: fewer than :data:`_MIN_LEVELS`
    drive levels (an offset cannot be told from a gain change), or readings that do not rise
    with the drive (the photometer not aimed, the display off: ``calibration fit`` refuses
    the same file)."""
    levels = np.unique(readings["level"].to_numpy(float))
    if levels.size < _MIN_LEVELS:
        raise GapError(
            f"{path}: {len(readings)} readings at {levels.size} drive level(s) "
            f"({', '.join(f'{v:g}' for v in levels)}); the display diagnosis needs >= "
            f"{_MIN_LEVELS} distinct levels to tell an offset from a gain or gamma change: "
            "measure a check run (python -m calibration check --calibration CAL_DIR --out "
            "CHECK_DIR) or pass readings across the drive range")
    lum = readings["luminance_cd_m2"].to_numpy(float)
    by = readings.groupby("level")["luminance_cd_m2"]
    means = by.mean()
    sd = float(np.sqrt(np.nanmean(by.var(ddof=1).to_numpy(float)))) if by.size().max() > 1 \
        else 0.0
    rise = float(means.iloc[-1] - means.iloc[0])
    if not np.isfinite(sd):
        sd = 0.0
    if np.ptp(lum) == 0 or rise <= 5 * sd:
        raise GapError(
            f"{path}: the readings do not rise with the drive (level means "
            f"{means.min():.4g} to {means.max():.4g} cd/m^2, lowest level {means.iloc[0]:.4g}, "
            f"highest {means.iloc[-1]:.4g}): check that the photometer was aimed at the patch "
            "and the display was on, then remeasure (python -m calibration fit refuses the "
            "same file)")


def _header(path: Path) -> list[str]:
    try:
        first = read_text(path).split("\n", 1)[0]
    except LabFileError as exc:
        raise GapError(str(exc)) from None
    return next(csv.reader([first]), [])


def _row_keys_list(frame: pd.DataFrame) -> list:
    return [(str(t), round(float(x), 6), round(float(y), 6), round(float(lv), 6), int(r))
            for t, x, y, lv, r in zip(frame["timestamp_utc"], frame["x_norm"], frame["y_norm"],
                                      frame["level"], frame["repeat"])]


def _read_check(path: Path) -> dict:
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise GapError(f"{path} is not valid JSON ({exc}); rerun the check") from exc
    need = ("kind", "check_id", "checked_calibration_id")
    if not isinstance(rec, dict) or rec.get("kind") != "check" or any(k not in rec
                                                                        for k in need):
        raise GapError(f"{path} is not a check record (needs kind 'check', check_id, "
                       "checked_calibration_id); pass a folder written by python -m "
                       "calibration check")
    return rec


def _has_pairs(frame: pd.DataFrame) -> bool:
    return bool(frame.groupby(["x_norm", "y_norm", "level"]).size().max() >= 2)


def _timed(frame: pd.DataFrame) -> bool:
    """Whether any reading carries a timestamp (a file without any is measured in order)."""
    return bool(frame["timestamp_utc"].astype(str).str.strip().ne("").any())


def _seconds(frame: pd.DataFrame) -> np.ndarray:
    """Each reading's time since the frame's first, s: from ``timestamp_utc``; in a file
    without any timestamp, the measurement order (``measurement_order``, else the rows'
    order) counted from 0, one unit per reading (no seconds: :func:`_timed` is False).

    Raises
    ------
    GapError
        If some readings have a timestamp and others none or a malformed one.
    """
    if not _timed(frame):
        order = (frame["measurement_order"].to_numpy(float) if "measurement_order" in frame
                 else np.arange(len(frame), dtype=float))
        order = np.where(np.isfinite(order), order, np.arange(len(frame), dtype=float))
        return pd.Series(order).rank(method="first").to_numpy(float) - 1.0
    t = _times(frame)
    return (t - t.min()).dt.total_seconds().to_numpy(float)


def _times(frame: pd.DataFrame) -> pd.Series:
    t = pd.to_datetime(frame["timestamp_utc"], utc=True, errors="coerce", format="ISO8601")
    if t.isna().any():
        raise GapError(f"{int(t.isna().sum())} readings have no ISO 8601 timestamp_utc; "
                       "the drift model needs them (fix or drop those rows)")
    from labfiles.clock import future_problem

    problem = future_problem(t.max().to_pydatetime(), "newest reading's timestamp_utc")
    if problem:  # the drift model would extrapolate to a time that has not come
        raise GapError(problem)
    return t
