"""The gloss table: physical gloss (%) -> Ward parameters, the contract between gloss fitting and rendering.

Format: a CSV with one row per gloss level and at least the columns of :data:`GLOSS_TABLE_COLUMNS`

============  ==========================================================================
gloss_pct     gloss of the physical reference sample, % (0-100), strictly increasing
rho_d         Ward diffuse reflectance, [0, 1]
rho_s         Ward specular reflectance, [0, 1]; rho_d + rho_s <= 1
alpha         Ward lobe width (RMS slope), > 0
fit_error     error of the fit to that sample's measurements (empty = not fitted)
loo_error     leave-one-out (held-out) error of the fit (empty = not fitted)
============  ==========================================================================

Extra columns (e.g. the fit's units or photo ids) are allowed and kept; lines starting with ``#``
are comments. ``python -m stimuli fit-gloss`` (stimuli.glossfit) writes it with
:func:`write_gloss_table`. Until the lab has fitted its samples, :func:`default_gloss_table` is used:
``gloss_table_default.csv``, a documented placeholder (rho_d 0.30; rho_s 0.10 * gloss/100; alpha
log-linear from 0.30 at 0 % to 0.02 at 100 %), which spans matte to sharply glossy but is *not*
fitted to any sample. Renders record the table's rho_d, rho_s, alpha per stimulus.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from labfiles import LabFileError, atomic_open, read_csv_frame
from stimuli.errors import GlossTableError
from stimuli.ward import check_ward_params

__all__ = [
    "GLOSS_TABLE_COLUMNS",
    "default_gloss_table",
    "default_gloss_table_path",
    "load_gloss_table",
    "validate_gloss_table",
    "ward_params_for_gloss",
    "write_gloss_table",
]

GLOSS_TABLE_COLUMNS = ["gloss_pct", "rho_d", "rho_s", "alpha", "fit_error", "loo_error"]
_REQUIRED_FINITE = ["gloss_pct", "rho_d", "rho_s", "alpha"]


def default_gloss_table_path() -> Path:
    """Path of the shipped default table ``stimuli/gloss_table_default.csv``."""
    return Path(__file__).resolve().parent / "gloss_table_default.csv"


def validate_gloss_table(frame: pd.DataFrame, source: str = "gloss table") -> pd.DataFrame:
    """Check a gloss table and return a clean copy (sorted columns first, float dtypes).

    Raises
    ------
    GlossTableError
        Missing columns, non-numeric or non-finite parameters, gloss_pct not strictly increasing
        or outside [0, 100], fewer than 2 rows, or Ward parameters out of range; the message names
        the source, the row and the fix.
    """
    fix = "fix the file or re-run `python -m stimuli fit-gloss`"
    missing = [c for c in GLOSS_TABLE_COLUMNS if c not in frame.columns]
    if missing:
        raise GlossTableError(f"{source} lacks columns {missing} (needs {GLOSS_TABLE_COLUMNS}); {fix}")
    out = frame.copy()
    for c in GLOSS_TABLE_COLUMNS:
        try:
            out[c] = pd.to_numeric(out[c], errors="raise").astype(float)
        except (ValueError, TypeError) as exc:
            raise GlossTableError(f"{source}: column {c} is not numeric ({exc}); {fix}") from exc
    if len(out) < 2:
        raise GlossTableError(f"{source} has {len(out)} rows; needs >= 2 gloss levels; {fix}")
    for c in _REQUIRED_FINITE:
        bad = out.index[~np.isfinite(out[c])].tolist()
        if bad:
            raise GlossTableError(f"{source}: column {c} is empty or not finite in rows {bad}; {fix}")
    g = out["gloss_pct"].to_numpy()
    if np.any(np.diff(g) <= 0):
        raise GlossTableError(f"{source}: gloss_pct must be strictly increasing, got {g.tolist()}; {fix}")
    if g.min() < 0 or g.max() > 100:
        raise GlossTableError(f"{source}: gloss_pct must lie in [0, 100], got {g.tolist()}; {fix}")
    for i, r in out.iterrows():
        try:
            check_ward_params(r["rho_d"], r["rho_s"], r["alpha"])
        except ValueError as exc:
            raise GlossTableError(f"{source}, row {i} (gloss {r['gloss_pct']:g} %): {exc}; {fix}") from exc
    cols = GLOSS_TABLE_COLUMNS + [c for c in out.columns if c not in GLOSS_TABLE_COLUMNS]
    return out[cols].reset_index(drop=True)


def load_gloss_table(path: str | os.PathLike) -> pd.DataFrame:
    """Read and validate a gloss table CSV (``#`` lines are comments).

    Raises
    ------
    GlossTableError
        If the file is missing, unreadable, or fails :func:`validate_gloss_table`.
    """
    path = Path(path)
    if not path.is_file():
        raise GlossTableError(
            f"gloss table {path} not found; fit one with `python -m stimuli fit-gloss` or leave "
            f"--gloss-table out to use the documented default {default_gloss_table_path()}")
    try:
        frame = read_csv_frame(path, comment="#", skipinitialspace=True)
    except LabFileError as exc:
        raise GlossTableError(f"gloss table {exc}") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise GlossTableError(f"gloss table {path} is not a readable CSV ({exc})") from exc
    table = validate_gloss_table(frame, source=f"gloss table {path}")
    table.attrs["path"] = str(path)
    return table


def write_gloss_table(frame: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Validate and write a gloss table atomically (temporary file, fsync, ``os.replace``)."""
    path = Path(path)
    table = validate_gloss_table(frame, source="gloss table to write")
    with atomic_open(path, "w", newline="", encoding="utf-8") as fh:
        table.to_csv(fh, index=False, float_format="%.10g")
    return path


def default_gloss_table() -> pd.DataFrame:
    """The shipped placeholder table (module docstring), used until the lab fits one."""
    return load_gloss_table(default_gloss_table_path())


def ward_params_for_gloss(table: pd.DataFrame, gloss_pct) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ward (rho_d, rho_s, alpha) for gloss values, interpolated in the table.

    rho_d and rho_s interpolate linearly in gloss %, alpha log-linearly (the lobe width spans
    more than a decade). Values at the table's rows are returned exactly.

    Parameters
    ----------
    table : DataFrame
        A validated gloss table.
    gloss_pct : float or array_like
        Gloss, %, within the table's range.

    Raises
    ------
    GlossTableError
        If a gloss value lies outside the table's range.
    """
    g = np.atleast_1d(np.asarray(gloss_pct, dtype=float))
    lo, hi = table["gloss_pct"].iloc[0], table["gloss_pct"].iloc[-1]
    if np.any(g < lo - 1e-9) or np.any(g > hi + 1e-9):
        raise GlossTableError(
            f"gloss {g[(g < lo) | (g > hi)].tolist()} % outside the gloss table's range "
            f"[{lo:g}, {hi:g}] %{' (' + table.attrs['path'] + ')' if 'path' in table.attrs else ''}; "
            "use a table that covers the rendered gloss levels")
    x = table["gloss_pct"].to_numpy()
    rho_d = np.interp(g, x, table["rho_d"].to_numpy())
    rho_s = np.interp(g, x, table["rho_s"].to_numpy())
    alpha = np.exp(np.interp(g, x, np.log(table["alpha"].to_numpy())))
    return rho_d, rho_s, alpha
