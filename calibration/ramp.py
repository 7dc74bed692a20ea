"""A gamma ramp (hardware lookup table) that linearises the display, for other experiments.

The glossdepth stimuli are inverse-gamma corrected in their pixels and need no table; another
experiment that draws linear luminance values can load this table into the graphics card
instead, so that frame-buffer value ``i`` of ``N = 2^bits`` gives the luminance
``black + i / (N - 1) * (white - black)``:

* PsychoPy: ``win.gammaRamp = table.T`` (3 x N: PsychoPy's ``setGammaRamp`` reads the table's
  length before it transposes an N x 3 one);
* Psychtoolbox: ``Screen('LoadNormalizedGammaTable', win, table)`` (N x 3).

Entry ``i`` is the chosen model's inverse
(:meth:`~calibration.record.Calibration.drive_for_fraction`) at the fraction ``i / (N - 1)``:
any model the calibration can describe, the threshold of the extended power function included,
which PsychoPy's gamma equations cannot hold. The calibration measures grey (equal drives on
the three guns), so the three columns are the same curve.

``gamma_ramp.csv``: columns ``index``, ``r``, ``g``, ``b``; one row per entry, values in [0, 1]
with 7 decimals (1e-7 of the drive range, far below any DAC's step).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibration.errors import CalibrationError
from calibration.record import Calibration
from labfiles import atomic_write_text

__all__ = [
    "RAMP_BITS",
    "RAMP_FILE",
    "REPORT_FRACTIONS",
    "gamma_ramp",
    "linearity_error_pct",
    "ramp_error_pct",
    "read_gamma_ramp",
    "write_gamma_ramp",
]

#: Bits of the table written by ``calibration fit`` and ``run``: 256 entries, the size of the
#: hardware table on most systems (Psychtoolbox's LoadNormalizedGammaTable and the operating
#: systems' gamma ramps).
RAMP_BITS = 8
#: The file's name beside calibration.json.
RAMP_FILE = "gamma_ramp.csv"
#: Fractions of the luminance range the report lists.
REPORT_FRACTIONS = (0.05, 0.10, 0.25, 0.50, 0.75, 0.90, 0.95)
_HEADER = "index,r,g,b"


def _check_bits(bits) -> int:
    if not (isinstance(bits, (int, np.integer)) and 1 <= int(bits) <= 16):
        raise CalibrationError(f"ramp bits must be an int in 1..16, got {bits!r}")
    return int(bits)


def gamma_ramp(cal: Calibration, *, bits: int = RAMP_BITS) -> np.ndarray:
    """The drive of each table entry, the inverse of the chosen model.

    Parameters
    ----------
    cal : Calibration
    bits : int
        The table has ``2^bits`` entries.

    Returns
    -------
    ndarray, shape (2^bits,)
        Drive values in [0, 1]; entry ``i`` gives the fraction ``i / (2^bits - 1)`` of the
        luminance range (0 -> 0, last -> 1).
    """
    n = 2 ** _check_bits(bits)
    return np.asarray(cal.drive_for_fraction(np.arange(n) / (n - 1)), dtype=float)


def linearity_error_pct(cal: Calibration, fractions, drive) -> np.ndarray:
    """How far the luminance at ``drive`` is from the fraction of the range it was meant to give.

    Parameters
    ----------
    cal : Calibration
        Its model predicts the luminance at ``drive``.
    fractions : array_like
        Wanted fraction of the luminance range, (0, 1].
    drive : array_like
        The drive used for each, [0, 1].

    Returns
    -------
    ndarray
        ``100 (L(drive) - L_want) / (L_want - black)``: % of the luminance asked for above black
        (negative: too dark); at 5 % of the range, -44 means 2.8 % was shown.
    """
    f = np.asarray(fractions, dtype=float)
    span = cal.max_luminance_cd_m2 - cal.min_luminance_cd_m2
    got = cal.luminance_for_drive(np.clip(np.asarray(drive, dtype=float), 0.0, 1.0))
    return 100.0 * (got - cal.min_luminance_cd_m2 - f * span) / (f * span)


def ramp_error_pct(cal: Calibration, ramp, fractions=REPORT_FRACTIONS, *,
                   dac_bits: int | None = None) -> np.ndarray:
    """The table's error (:func:`linearity_error_pct`) at fractions of the range.

    Parameters
    ----------
    ramp : array_like, shape (N,) or (N, 3)
        Drive per entry (the first column of an N x 3 table).
    fractions : array_like
        Fractions of the range; each is shown by its nearest entry, whose own fraction
        ``i / (N - 1)`` is the one asked for.
    dac_bits : int or None
        Round the table's drives to this DAC's grid first (the quantisation a display with that
        DAC adds); None: as stored.
    """
    r = np.asarray(ramp, dtype=float)
    r = r[:, 0] if r.ndim == 2 else r
    n = r.size
    idx = np.clip(np.rint(np.asarray(fractions, dtype=float) * (n - 1)).astype(int), 1, n - 1)
    drive = r[idx]
    if dac_bits is not None:
        steps = 2 ** _check_bits(dac_bits) - 1
        drive = np.round(drive * steps) / steps
    return linearity_error_pct(cal, idx / (n - 1), drive)


def write_gamma_ramp(cal: Calibration, path, *, bits: int = RAMP_BITS) -> Path:
    """Write ``gamma_ramp.csv`` (atomically): ``index, r, g, b``, 2^bits rows, values 0-1.

    Returns the path written.
    """
    ramp = gamma_ramp(cal, bits=bits)
    rows = [f"{i},{v:.7f},{v:.7f},{v:.7f}" for i, v in enumerate(ramp)]
    return atomic_write_text(path, "\n".join([_HEADER, *rows]) + "\n")


def read_gamma_ramp(path) -> np.ndarray:
    """Read a ``gamma_ramp.csv``: the table, shape (N, 3), N a power of 2, values in [0, 1].

    Raises
    ------
    CalibrationError
        If the file is missing, has another header, a non-numeric value, a value outside
        [0, 1], indices out of order, or a length that is not a power of 2.
    """
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"gamma ramp {path} not found; `python -m calibration fit --out "
                               "DIR` writes DIR/gamma_ramp.csv")
    lines = path.read_text(encoding="utf-8").splitlines()
    if not lines or lines[0].strip() != _HEADER:
        raise CalibrationError(f"{path} does not start with the header {_HEADER!r}; it is not a "
                               "gamma ramp written by `python -m calibration`")
    try:
        table = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:] if ln.strip()])
    except ValueError as exc:
        raise CalibrationError(f"{path} holds a non-numeric value ({exc}); refit the folder to "
                               "write it again") from None
    n = len(table)
    if (table.ndim != 2 or table.shape[1] != 4 or n < 2 or n & (n - 1)
            or not np.array_equal(table[:, 0], np.arange(n))):
        raise CalibrationError(f"{path}: expected 2^bits rows of index,r,g,b with indices 0.."
                               f"N-1, got {n} rows; refit the folder to write it again")
    rgb = table[:, 1:]
    if rgb.min() < 0 or rgb.max() > 1:
        raise CalibrationError(f"{path} holds values outside [0, 1]; refit the folder")
    return rgb
