"""Reading the small TOML files the calibration takes (display and CRT descriptions)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import labfiles
from calibration.errors import CalibrationError

__all__ = ["read_toml"]


def read_toml(path, what: str, *, missing_fix: str = "") -> dict:
    """The parsed TOML file ``path``.

    Raises
    ------
    CalibrationError
        ``"<what> <path> not found[; missing_fix]"`` or ``"... is not valid TOML (...)"``.
    """
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{what} {path} not found" + (f"; {missing_fix}" if missing_fix
                                                             else ""))
    try:
        return labfiles.read_toml(path)
    except labfiles.LabFileError as exc:
        raise CalibrationError(f"{what} {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(f"{what} {path} is not valid TOML ({exc})") from exc
