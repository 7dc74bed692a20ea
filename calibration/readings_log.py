"""The calibration procedure's own append-only records: ``readings.csv`` (one row per reading,
written the moment it exists), ``rejected.csv`` and ``validation.csv``; their columns, appending a
row, reading them back, and the times they record.

Any other tool's readings file is read by :func:`calibration.readings.read_readings`.
"""

from __future__ import annotations

import csv
import io
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from calibration.errors import CalibrationError
from labfiles import LabFileError, RecordFile, csv_fields_check, csv_record, read_records

__all__ = ["READINGS_COLUMNS", "REJECTED_COLUMNS", "append_row", "escape_reply",
           "newest_timestamp", "parse_csv_lines", "parse_utc", "read_record_csv"]

READINGS_COLUMNS = (
    "calibration_id",
    "timestamp_utc",
    "device",
    "x_norm",
    "y_norm",
    "level",
    "repeat",
    "luminance_cd_m2",
    "raw_reply",
)
REJECTED_COLUMNS = READINGS_COLUMNS + ("flag",)


def escape_reply(text) -> str:
    """An instrument's reply as one line: backslash, CR and LF written as ``\\\\``, ``\\r``,
    ``\\n`` (so a readings record never holds a line break)."""
    text = "" if text is None else str(text)
    return text.replace("\\", "\\\\").replace("\r", "\\r").replace("\n", "\\n")


def append_row(path, row: dict, columns=READINGS_COLUMNS) -> None:
    """Append one row to an append-only CSV (header first if the file is new), fsynced.

    A torn last row left by a crash is moved to a side file first (:class:`labfiles.RecordFile`
    warns with :class:`labfiles.TornTailWarning`, naming the file and the line).

    Raises
    ------
    CalibrationError
        If the file exists with a different header (it is never rewritten).
    """
    values = [escape_reply(row.get(c, "")) if c == "raw_reply" else row.get(c, "")
              for c in columns]
    try:
        with RecordFile(path, header=csv_record(columns),
                        check=csv_fields_check(len(columns))) as rec:
            rec.append(csv_record(values))
    except LabFileError as exc:
        raise CalibrationError(f"{exc} (expected the columns {list(columns)})") from exc


def parse_csv_lines(lines: list[str], path: Path) -> tuple[list[str], list[tuple[int, list]]]:
    """Header and (line number, fields) of each row; a row that does not parse keeps its text."""
    header = next(csv.reader([lines[0]]))
    rows = []
    for i, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        try:
            fields = next(csv.reader(io.StringIO(line), strict=True))
        except (csv.Error, StopIteration):
            fields = None
        rows.append((i, fields if fields is not None else line))
    return [h.strip() for h in header], rows


def read_record_csv(path, columns) -> pd.DataFrame:
    """Read one of the procedure's own append-only CSVs (``rejected.csv``, ``validation.csv``).

    The torn-tail rule is applied first. Returns all columns as text; an absent or empty file
    gives an empty frame with ``columns``.

    Raises
    ------
    CalibrationError
        If the header differs from ``columns``.
    """
    path = Path(path)
    try:
        lines = read_records(path, check=csv_fields_check(len(columns)))
    except LabFileError as exc:
        raise CalibrationError(str(exc)) from None
    if not lines:
        return pd.DataFrame({c: pd.Series(dtype=object) for c in columns})
    header, rows = parse_csv_lines(lines, path)
    if tuple(header) != tuple(columns):
        raise CalibrationError(f"{path} has columns {header}, expected {list(columns)}; "
                               "it was written by something else: move it aside")
    good = [r for _, r in rows if isinstance(r, list) and len(r) == len(columns)]
    return pd.DataFrame(good, columns=list(columns))


def parse_utc(text, name: str = "time") -> datetime:
    """An ISO 8601 time with a zone, as UTC: the one rule for every time the calibration
    records (reading times, ``created_utc``, ``measured_utc``, ``--measured-utc``).

    Raises
    ------
    CalibrationError
        If ``text`` is not an ISO 8601 time or has no zone (the message names ``name``).
    """
    try:
        t = datetime.fromisoformat(str(text).strip())
    except (TypeError, ValueError) as exc:
        raise CalibrationError(
            f"{name} {text!r} is not an ISO 8601 time; write e.g. 2026-11-22T13:00:00Z"
        ) from exc
    if t.tzinfo is None:
        raise CalibrationError(f"{name} {text!r} has no time zone; end it with 'Z' (UTC)")
    return t.astimezone(UTC)


def _parse_utc_or_none(text) -> datetime | None:
    try:
        return parse_utc(text)
    except CalibrationError:
        return None


def newest_timestamp(readings: pd.DataFrame) -> tuple[str | None, int]:
    """The newest ``timestamp_utc`` of the readings (ISO 8601, ``Z``) and how many rows had
    none that parses (a time without a zone is not used)."""
    times = [_parse_utc_or_none(t) for t in readings["timestamp_utc"]] if len(readings) else []
    ok = [t for t in times if t is not None]
    if not ok:
        return None, len(times)
    return max(ok).strftime("%Y-%m-%dT%H:%M:%S.%fZ"), len(times) - len(ok)
