"""The readings file: one row per accepted photometer reading, appended and fsynced at once.

``readings.csv`` columns (exactly, in this order):

===============  ====================================================================
column           meaning
===============  ====================================================================
calibration_id   the calibration the reading belongs to
timestamp_utc    when the reading was returned, ISO 8601 UTC
device           photometer: pr655, pr650 or ls100
x_norm, y_norm   patch centre in PsychoPy norm units ([-1, 1], centre 0, y up)
level            drive value in [0, 1] (PsychoPy rgb = 2 level - 1 on every gun)
repeat           repeat index, 0-based
luminance_cd_m2  the luminance read, cd/m^2
raw_reply        the instrument's reply, as received (for audit)
===============  ====================================================================

Rejected replies (garbled, out of range, saturated) never enter ``readings.csv``; they go to
``rejected.csv`` with the same columns plus ``flag`` and an empty luminance, so they are kept for
audit and the procedure measures that patch again.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import pandas as pd

from calibration.errors import CalibrationError

__all__ = ["READINGS_COLUMNS", "REJECTED_COLUMNS", "append_row", "load_readings"]

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


def append_row(path, row: dict, columns=READINGS_COLUMNS) -> None:
    """Append one row to a CSV, writing the header first if the file is new; flush and fsync.

    Raises
    ------
    CalibrationError
        If the file exists with a different header (it is never rewritten).
    """
    path = Path(path)
    new = not path.exists() or path.stat().st_size == 0
    if not new:
        with open(path, newline="", encoding="utf-8") as fh:
            header = next(csv.reader(fh), [])
        if tuple(header) != tuple(columns):
            raise CalibrationError(
                f"{path} has columns {header}, expected {list(columns)}; "
                "write to a new --out folder"
            )
    with open(path, "a", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        if new:
            w.writerow(columns)
        w.writerow([row.get(c, "") for c in columns])
        fh.flush()
        os.fsync(fh.fileno())


def load_readings(path) -> pd.DataFrame:
    """Read ``readings.csv`` and check its columns and values.

    Returns
    -------
    DataFrame
        Columns :data:`READINGS_COLUMNS`; an empty frame if the file does not exist.

    Raises
    ------
    CalibrationError
        If the columns differ, or a level lies outside [0, 1], or a luminance is not a number.
    """
    path = Path(path)
    if not path.exists():
        return pd.DataFrame({c: pd.Series(dtype=object) for c in READINGS_COLUMNS})
    # A row cut short by a crash mid-write has fewer fields; it is dropped (never rewritten).
    df = pd.read_csv(path, dtype={"raw_reply": str, "calibration_id": str}, keep_default_na=False,
                     on_bad_lines="skip")
    if tuple(df.columns) != READINGS_COLUMNS:
        raise CalibrationError(
            f"{path} has columns {list(df.columns)}, expected {list(READINGS_COLUMNS)}"
        )
    for c in ("x_norm", "y_norm", "level", "luminance_cd_m2"):
        df[c] = pd.to_numeric(df[c], errors="coerce")
    df["repeat"] = pd.to_numeric(df["repeat"], errors="coerce")
    df = df.dropna(subset=["x_norm", "y_norm", "level", "repeat", "luminance_cd_m2"])
    df["repeat"] = df["repeat"].astype(int)
    bad = df[(df["level"] < 0) | (df["level"] > 1)]
    if not bad.empty:
        raise CalibrationError(
            f"{path}: level outside [0, 1] in row(s) {list(bad.index[:5] + 2)}"
        )
    return df.reset_index(drop=True)
