"""Slider matches to physical units, through the design object only."""

from __future__ import annotations

import pandas as pd

from studydesign import StudyDesign

__all__ = ["matches_to_physical", "read_matches_csv"]


def read_matches_csv(path) -> tuple[pd.DataFrame, list[str]]:
    """A CSV of matches (a session file or any tool's), its torn last row left out.

    The torn-tail rule of :mod:`labfiles`: a last line with the wrong number of fields or an
    open quote, or NUL bytes at the end (a crash or a full disk during a write), is not data;
    it is left out (the file is not changed) and a note says so. A whole last row without a
    line end (some tools write none) is read.

    Returns
    -------
    (DataFrame, notes)

    Raises
    ------
    labfiles.LabFileError, OSError, pandas.errors.ParserError
        As :func:`labfiles.read_csv_frame`.
    """
    import io

    from labfiles import csv_fields_check, find_torn_tail, read_csv_frame, read_text

    frame = read_csv_frame(path)
    text = read_text(path)
    data = text.encode("utf-8")
    check = csv_fields_check(len(frame.columns))
    found = find_torn_tail(data, check=check)
    if found is None:
        return frame, []
    offset, reason = found
    if reason == "no newline at its end" and check(data[offset:].rstrip(b"\r")):
        return frame, []
    line = data.count(b"\n", 0, offset) + 1
    whole = pd.read_csv(io.StringIO(data[:offset].decode("utf-8")))
    return whole, [(f"{path}: line {line} is torn ({reason}; a crash or a full disk during a "
                   f"write?): left out, {len(whole)} rows read (the file is not changed)")]


def matches_to_physical(frame: pd.DataFrame, design: StudyDesign) -> pd.DataFrame:
    """Add ``gloss_match_pct`` (%) and ``depth_match_cm`` (cm) from raw slider matches.

    Parameters
    ----------
    frame : DataFrame
        With columns ``gloss_match`` and ``depth_match``: raw slider values in
        ``[design.slider.min, design.slider.max]``.
    design : StudyDesign

    Returns
    -------
    DataFrame
        A copy of ``frame`` with the two new columns.

    Raises
    ------
    ValueError
        If a column is missing or a match lies outside the slider range.
    """
    missing = [c for c in ("gloss_match", "depth_match") if c not in frame.columns]
    if missing:
        raise ValueError(
            f"columns {missing} missing; session CSVs carry gloss_match and depth_match"
        )
    out = frame.copy()
    out["gloss_match_pct"] = design.slider.to_gloss_pct(frame["gloss_match"].to_numpy())
    out["depth_match_cm"] = design.slider.to_depth_cm(frame["depth_match"].to_numpy())
    return out
