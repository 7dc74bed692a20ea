"""Photometer readings on disk: the procedure's append-only ``readings.csv`` and any tool's file.

The procedure appends one CSV row per reading the moment it exists (:func:`append_row`, through
:class:`labfiles.RecordFile`: one line per record, fsynced; a torn last row from a crash is moved
to a side file ``readings.csv.torn-<UTC>`` on the next open and that patch is measured again).

:func:`read_readings` reads such a file, or a file written by any other tool, and says what it
did with every row it could not use.

Columns of a readings file
--------------------------
=================  ========  ==================================================================
column             needed    meaning
=================  ========  ==================================================================
level              yes       drive value; in [0, 1] (``level_scale`` converts 0-255, 0-1023..)
luminance_cd_m2    yes       the reading, cd/m^2 (a decimal point, not a comma)
x_norm, y_norm     no        patch centre in norm units ([-1, 1], y up); default 0, 0 (centre)
repeat             no        index of the repeat of one patch; default: order in the file
timestamp_utc      no        ISO 8601 time of the reading (sets the calibration's age)
calibration_id     no        which calibration the row belongs to (one file may hold several)
device             no        photometer
raw_reply          no        the instrument's reply, one line (CR/LF written as ``\\r``/``\\n``)
=================  ========  ==================================================================

Other columns are ignored (and named in the notes). The procedure's own files have exactly
:data:`READINGS_COLUMNS`.
"""

from __future__ import annotations

import csv
import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from calibration.errors import CalibrationError
from calibration.readings_log import (
    READINGS_COLUMNS,
    REJECTED_COLUMNS,
    append_row,
    escape_reply,
    newest_timestamp,
    parse_csv_lines,
    parse_utc,
    read_record_csv,
)
from labfiles import (
    LabFileError,
    TornTailWarning,
    csv_fields_check,
    read_records,
    read_text,
    text_encoding,
)

__all__ = [
    "READINGS_COLUMNS",
    "REJECTED_COLUMNS",
    "REQUIRED_COLUMNS",
    "ReadingsTable",
    "append_row",
    "at_centre",
    "escape_reply",
    "load_readings",
    "newest_timestamp",
    "parse_level_scale",
    "parse_utc",
    "read_readings",
    "read_record_csv",
]

#: The columns a readings file from another tool must have.
REQUIRED_COLUMNS = ("level", "luminance_cd_m2")

_DECIMAL_COMMA = re.compile(r"^\s*[-+]?\d*,\d+\s*$")


#: Positions are read rounded to this many decimals (norm units): a position written as 1e-12
#: or -0.0 is the same as 0 for the fit, the uniformity grid, the plots and the profile.
POSITION_DECIMALS = 6
#: A position within this of x_norm = y_norm = 0 (norm units) is the screen centre.
CENTRE_TOLERANCE_NORM = 1e-9


def at_centre(readings: pd.DataFrame) -> pd.Series:
    """Which rows are at the screen centre (x_norm = y_norm = 0, within
    :data:`CENTRE_TOLERANCE_NORM`): the rows the gamma fit, its plot and the monitor profile
    use, and the uniformity map's reference."""
    return ((readings["x_norm"].astype(float).abs() < CENTRE_TOLERANCE_NORM)
            & (readings["y_norm"].astype(float).abs() < CENTRE_TOLERANCE_NORM))


def parse_level_scale(text) -> float:
    """The drive value that means full white: ``"0-1"`` -> 1, ``"0-255"`` -> 255, ``"1023"``...

    Raises
    ------
    CalibrationError
        If ``text`` is not ``0-MAX`` or ``MAX`` with MAX > 0.
    """
    if isinstance(text, (int, float)):
        value = float(text)
    else:
        s = str(text).strip()
        s = s.removeprefix("0-")
        try:
            value = float(s)
        except ValueError:
            value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise CalibrationError(f"--level-scale {text!r}: write 0-1, 0-255, 0-1023 or the drive "
                               "value of full white (e.g. 4095)")
    return value


@dataclass(frozen=True)
class ReadingsTable:
    """A readings file as read: the usable rows and what happened to the others.

    Attributes
    ----------
    path : Path
    frame : DataFrame
        Columns :data:`READINGS_COLUMNS`, one row per usable reading (levels in [0, 1]).
    notes : tuple[str, ...]
        One line per dropped row (file and line, the value and the fix), per duplicated row,
        per ignored column, and for a torn tail.
    n_rows : int
        Data rows in the file.
    n_dropped, n_duplicates : int
        Rows not used because a value is unusable, and rows counted once as exact duplicates.
    columns : tuple[str, ...]
        The file's header.
    torn : tuple[str, ...]
        The torn-tail message, when the last row was torn and moved to a side file.
    """

    path: Path
    frame: pd.DataFrame
    notes: tuple = ()
    n_rows: int = 0
    n_dropped: int = 0
    n_duplicates: int = 0
    columns: tuple = ()
    torn: tuple = ()

    def calibration_ids(self) -> list[str]:
        return sorted(set(self.frame["calibration_id"].astype(str)))


def _empty_frame() -> pd.DataFrame:
    return pd.DataFrame({c: pd.Series(dtype=float if c in ("x_norm", "y_norm", "level",
                                                            "luminance_cd_m2") else object)
                         for c in READINGS_COLUMNS})


def _number(text: str, name: str) -> tuple[float | None, str | None]:
    """(value, None) or (None, why the text is not a usable number)."""
    t = text.strip()
    if t == "":
        return None, f"{name} is empty"
    try:
        v = float(t)
    except ValueError:
        if _DECIMAL_COMMA.match(t):
            return None, (f"{name} {t!r} has a decimal comma; write {t.replace(',', '.')} "
                          "(export the file with a decimal point)")
        return None, f"{name} {t!r} is not a number"
    if not math.isfinite(v):
        return None, f"{name} {t!r} is not a finite number"
    return v, None


def _read_lines(path: Path, own_file: bool | None) -> tuple[str, list[str], tuple[str, ...]]:
    """The first line as written, the file's lines, and the torn-tail messages.

    ``own_file`` None is decided by the header (exactly :data:`READINGS_COLUMNS`). The
    procedure's own file is read with the torn-tail rule of :mod:`labfiles` (a torn last row is
    moved to a side file; its warning is returned, not shown); another tool's file as it is.

    Raises
    ------
    CalibrationError
        If the file is not UTF-8 or UTF-16 text, or ``own_file`` is True (the procedure appends
        to it) and it is UTF-16; the message names the fix.
    """
    # Line ends, a BOM and UTF-16 as labfiles.text reads them (Excel, MATLAB, Notepad).
    try:
        text = read_text(path)
    except LabFileError as exc:
        raise CalibrationError(str(exc)) from None
    first = text.split("\n", 1)[0]
    header = [h.strip() for h in next(csv.reader([first]), [])]
    with open(path, "rb") as fh:
        # A file re-saved in UTF-16 is a copy a tool wrote: read as such, unless the procedure
        # is to append to it (own_file=True), which the torn-tail rule refuses with the fix.
        resaved = text_encoding(fh.read(4)) in ("utf-16", "utf-32")
    if own_file is None:
        own_file = tuple(header) == READINGS_COLUMNS and not resaved
    if own_file:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TornTailWarning)
            try:
                lines = read_records(path, check=csv_fields_check(len(header)))
            except LabFileError as exc:
                raise CalibrationError(str(exc)) from None
        return first, lines, tuple(str(w.message) for w in caught)
    return first, text.splitlines(), ()


def _check_header(path: Path, header: list[str], first: str) -> list[str]:
    """The note on ignored columns, after checking the header's columns.

    Raises
    ------
    CalibrationError
        If a column of :data:`REQUIRED_COLUMNS` is missing (the message names a ';' or tab
        separator when the header is one such field), or a column appears twice.
    """
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        sep = next((name for ch, name in ((";", "';'"), ("\t", "tabs"))
                    if len(header) == 1 and ch in header[0]), None)
        hint = (f"; its columns are separated by {sep}: export it as CSV with commas (and a "
                "decimal point)" if sep else "")
        raise CalibrationError(
            f"{path} has no column {missing}; a readings file needs at least the columns "
            f"{list(REQUIRED_COLUMNS)} (optional: x_norm, y_norm, repeat, timestamp_utc, "
            "calibration_id, device, raw_reply); its header is " + repr(first.strip()[:200])
            + hint)
    dupes = [c for c in set(header) if header.count(c) > 1]
    if dupes:
        raise CalibrationError(f"{path}: column(s) {sorted(dupes)} appear twice in the header")
    ignored = [c for c in header if c not in READINGS_COLUMNS]
    return [f"{path}: column(s) {ignored} ignored"] if ignored else []


def _row_values(fields: list[str], col: dict[str, int]) -> tuple[dict, str | None]:
    """One row's numbers: ``(record, None)``, or ``(partial record, why the row is dropped)``.

    A position the file lacks is 0 (the centre); positions are rounded to
    :data:`POSITION_DECIMALS`; ``repeat`` must be a whole number >= 0 and the luminance >= 0.
    """
    rec = {}
    for name in ("level", "luminance_cd_m2", "x_norm", "y_norm"):
        if name not in col:
            rec[name] = 0.0
            continue
        rec[name], why = _number(fields[col[name]], name)
        if why:
            return rec, why
    # One position, one value: 1e-12 or -0.0 written by another tool is the centre.
    for name in ("x_norm", "y_norm"):
        rec[name] = round(rec[name], POSITION_DECIMALS) + 0.0
    if "repeat" in col:
        r, why = _number(fields[col["repeat"]], "repeat")
        if why is None and (r < 0 or r != int(r)):
            why = f"repeat {fields[col['repeat']]!r} is not a whole number >= 0"
        rec["repeat"] = None if why else int(r)
        if why is not None:
            return rec, why
    if rec["luminance_cd_m2"] < 0:
        return rec, f"luminance_cd_m2 {rec['luminance_cd_m2']:g} is negative"
    return rec, None


def _parse_rows(path: Path, header: list[str], rows: list) -> tuple[list[dict], list[str], int, int]:
    """The usable rows as records, with their line numbers and levels not yet scaled.

    Returns
    -------
    records : list of dict
        Values of :data:`READINGS_COLUMNS` (``repeat`` only when the file has it) and ``line``.
    notes : list of str
        One per dropped row (not a CSV row, a wrong number of fields, an unusable value) and per
        exact repeat of an earlier row.
    n_dropped, n_duplicates : int
        Rows dropped; rows counted once as exact duplicates (looked for only when the file has
        ``repeat`` or ``timestamp_utc``, which tell readings of one patch apart).
    """
    col = {c: header.index(c) for c in header}
    n = len(header)
    good, notes, seen, dropped, n_dup = [], [], {}, 0, 0
    check_dupes = "repeat" in col or "timestamp_utc" in col
    for line_no, fields in rows:
        where = f"{path} line {line_no}"
        if not isinstance(fields, list):
            notes.append(f"{where} dropped: not a CSV row ({fields[:80]!r})")
            dropped += 1
            continue
        if len(fields) != n:
            notes.append(f"{where} dropped: {len(fields)} fields, the header has {n}")
            dropped += 1
            continue
        if check_dupes:
            key = tuple(fields)
            if key in seen:
                notes.append(f"{where} repeats line {seen[key]} exactly; counted once")
                n_dup += 1
                continue
            seen[key] = line_no
        rec, why = _row_values(fields, col)
        if why is not None:
            notes.append(f"{where} dropped: {why}")
            dropped += 1
            continue
        rec["line"] = line_no
        for name in ("calibration_id", "timestamp_utc", "device", "raw_reply"):
            rec[name] = fields[col[name]].strip() if name in col else ""
        good.append(rec)
    return good, notes, dropped, n_dup


def _scale_levels(path: Path, records: list[dict], level_scale: float
                  ) -> tuple[list[dict], list[str]]:
    """The records whose level, divided by ``level_scale``, lies in [0, 1] (changed in place to
    the scaled level), and one note per record dropped for its level.

    Raises
    ------
    CalibrationError
        If most levels exceed 1 while read as 0-1 (the message names the ``--level-scale``).
    """
    raw = np.asarray([rec["level"] for rec in records], float)
    if raw.size and level_scale == 1.0 and np.mean(raw > 1) > 0.5:
        guess = "0-255" if raw.max() <= 255 else ("0-1023" if raw.max() <= 1023 else
                                                  f"0-{raw.max():g}")
        raise CalibrationError(
            f"{path}: levels run up to {raw.max():g}, but levels are read as 0-1; pass "
            f"--level-scale {guess} (the drive value of full white)")
    _refuse_scale_too_large(path, raw, level_scale)
    kept, notes = [], []
    for rec in records:
        level = rec["level"] / level_scale
        if not 0 <= level <= 1:
            notes.append(f"{path} line {rec['line']} dropped: level {rec['level']:g} lies "
                         f"outside [0, {level_scale:g}]")
            continue
        rec["level"] = level
        kept.append(rec)
    return kept, notes


def _refuse_scale_too_large(path: Path, raw: np.ndarray, level_scale: float) -> None:
    """A ``--level-scale`` whose full white lies above every level in the file: the file's
    white would read as a grey (and a fit would then ask for more levels, or brighter ones,
    when the scale is the cause). A calibration measures full white, so the file's highest
    level is its white; below 90 % of the scale it is refused."""
    if not raw.size or level_scale <= 1.0 or raw.max() >= 0.9 * level_scale:
        return
    top = raw.max()
    guess = ("drop --level-scale (0-1 is the default)" if top <= 1 else
             f"pass --level-scale {'0-255' if top <= 255 else f'0-{top:g}'} if that is full "
             "white, or measure full white")
    raise CalibrationError(
        f"{path}: levels run up to {top:g}, but --level-scale 0-{level_scale:g} says full white "
        f"is {level_scale:g}: the file's white would read as level {top / level_scale:.3g}; "
        f"{guess}")


def _readings_frame(path: Path, records: list[dict], *, has_repeat: bool
                    ) -> tuple[pd.DataFrame, list[str]]:
    """The records as a frame of :data:`READINGS_COLUMNS`, and one note per patch and repeat
    read more than once (every such reading is kept).

    Without a ``repeat`` column a reading's repeat is its order among the readings of its
    patch (calibration, position, level) in the file.
    """
    frame = (pd.DataFrame(records, columns=[*READINGS_COLUMNS, "line"]) if records
             else _empty_frame())
    if records and not has_repeat:
        frame["repeat"] = frame.groupby(["calibration_id", "x_norm", "y_norm", "level"]
                                        ).cumcount()
    notes = []
    if len(frame):
        frame["repeat"] = frame["repeat"].astype(int)
        key = ["calibration_id", "x_norm", "y_norm", "level", "repeat"]
        twice = frame[frame.duplicated(key, keep=False)]
        for _, grp in twice.groupby(key, sort=False):
            lines = ", ".join(str(v) for v in grp["line"])
            notes.append(f"{path} lines {lines}: the same patch and repeat (level "
                         f"{grp['level'].iloc[0]:.4f} at ({grp['x_norm'].iloc[0]:g}, "
                         f"{grp['y_norm'].iloc[0]:g}), repeat {grp['repeat'].iloc[0]}) was "
                         "measured more than once; every reading is used")
        frame = frame.drop(columns="line")
    return frame.reset_index(drop=True), notes


def read_readings(path, *, level_scale: float = 1.0, own_file: bool | None = None
                  ) -> ReadingsTable:
    """Read a readings file (the procedure's or any tool's) and account for every row.

    Parameters
    ----------
    path : str or Path
        CSV with at least the columns :data:`REQUIRED_COLUMNS` (see the module docstring).
    level_scale : float
        Drive value of full white in the file (1 for levels in [0, 1], 255 for 8-bit values);
        levels are divided by it.
    own_file : bool or None
        True for the procedure's append-only file: the torn-tail rule of :mod:`labfiles` is
        applied (a torn last row is moved to a side file, with a warning; a file re-saved as
        UTF-16 is refused with the fix). None: decided by the header (exactly
        :data:`READINGS_COLUMNS`, in UTF-8). Another tool's file is never changed; a last row
        without a line end is read as it is.

    Returns
    -------
    ReadingsTable
        An absent or empty (0 bytes) file gives an empty table.

    Raises
    ------
    CalibrationError
        If a required column is missing, or most levels exceed the scale (the message names
        the ``--level-scale`` to use).
    """
    path = Path(path)
    if not path.is_file() or path.stat().st_size == 0:
        return ReadingsTable(path=path, frame=_empty_frame())
    first, lines, torn = _read_lines(path, own_file)
    if not lines:  # a torn header line was moved aside: nothing was recorded
        return ReadingsTable(path=path, frame=_empty_frame(), notes=torn, torn=torn)
    header, rows = parse_csv_lines(lines, path)
    header_notes = _check_header(path, header, first)
    records, row_notes, n_bad, n_dup = _parse_rows(path, header, rows)
    records, level_notes = _scale_levels(path, records, level_scale)
    frame, twice_notes = _readings_frame(path, records, has_repeat="repeat" in header)
    notes = (*torn, *header_notes, *row_notes, *level_notes, *twice_notes)
    return ReadingsTable(path=path, frame=frame, notes=notes, n_rows=len(rows),
                         n_dropped=n_bad + len(level_notes), n_duplicates=n_dup,
                         columns=tuple(header), torn=torn)


def load_readings(path) -> pd.DataFrame:
    """The usable readings of a ``readings.csv`` (see :func:`read_readings`).

    Returns
    -------
    DataFrame
        Columns :data:`READINGS_COLUMNS`; an empty frame if the file does not exist.

    Raises
    ------
    CalibrationError
        If a required column is missing.
    """
    table = read_readings(path)
    for message in table.torn:
        warnings.warn(message, TornTailWarning, stacklevel=2)
    return table.frame
