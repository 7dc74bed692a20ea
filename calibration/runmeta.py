"""A calibration folder's ``run_meta.json``: what the run was (its id, the device, the fit's
settings), read and written by the folder's every writer (a run, a refit, an import)."""

from __future__ import annotations

import json
from pathlib import Path

from calibration.errors import CalibrationError
from labfiles import atomic_write_text

__all__ = ["read_meta", "write_meta"]


def write_meta(out_dir: Path, meta: dict) -> None:
    """Write ``out_dir/run_meta.json`` atomically."""
    atomic_write_text(out_dir / "run_meta.json", json.dumps(meta, indent=2) + "\n")


def read_meta(out_dir: Path) -> dict:
    """``out_dir/run_meta.json``, checked.

    Raises
    ------
    CalibrationError
        The file is missing (not a calibration folder) or malformed, with the command that
        makes a good one.
    """
    path = out_dir / "run_meta.json"
    if not path.is_file():
        raise CalibrationError(
            f"{path} not found: {out_dir} is not a calibration folder. Measure with `python -m "
            "calibration run`, or fit a readings file with `python -m calibration fit "
            "READINGS.csv --out DIR`")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(meta.get("fit"), dict) or "calibration_id" not in meta:
            raise KeyError("calibration_id or fit")
    except (ValueError, KeyError, TypeError) as exc:
        raise CalibrationError(f"{path} is malformed ({exc}); rerun `python -m calibration "
                               "run` into a new --out") from exc
    return meta
