"""Slider matches to physical units, through the design object only."""

from __future__ import annotations

import pandas as pd

from studydesign import StudyDesign

__all__ = ["matches_to_physical"]


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
