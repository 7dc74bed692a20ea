"""A refit that differs from a folder's calibration: a new calibration beside the old one.

A calibration is never replaced (a session records its file's SHA-256 and resumes only with
the same bytes). When the readings of a calibration folder, or the fitting code, change, the
refit is written as a new calibration, ``<id>-refit-<UTC time>``, in a folder of its own beside
the old one; :func:`calibration.run.refit` decides when (:func:`same_fit`).
"""

from __future__ import annotations

import json
import shutil
from datetime import UTC, datetime
from pathlib import Path

from calibration.errors import CalibrationError
from calibration.runmeta import read_meta, write_meta

__all__ = ["refit_beside", "same_fit"]


def same_fit(a, b) -> bool:
    """Two calibrations equal but for the time of the fit (``created_utc``)."""
    da, db = json.loads(a.to_json()), json.loads(b.to_json())
    da.pop("created_utc"), db.pop("created_utc")
    return da == db


def refit_beside(out_dir: Path, cal, progress, *, refit):
    """A refit that differs from ``out_dir``'s calibration: a new calibration folder beside it.

    ``<folder>-refit-<UTC time>`` gets copies of the readings, validation, rejected readings and
    settings, a ``run_meta.json`` whose fit writes the new id ``<id>-refit-<UTC time>`` (the
    readings keep theirs), and the outputs of ``refit`` (:func:`calibration.run.refit`, passed
    in by it: the folder's own rules). The old folder is not touched.
    """
    base = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    for stamp in [base, *(f"{base}-{n}" for n in range(2, 100))]:  # refits within a second
        new_dir = out_dir.parent / f"{out_dir.name}-refit-{stamp}"
        try:
            new_dir.mkdir()
            break
        except FileExistsError:
            continue
    else:
        raise CalibrationError(f"too many refits of {out_dir} in one second; run it again")
    for name in ("readings.csv", "validation.csv", "rejected.csv", "procedure.json"):
        if (out_dir / name).is_file():
            shutil.copy2(out_dir / name, new_dir / name)
    meta = read_meta(out_dir)
    new_id = f"{cal.calibration_id}-refit-{stamp}"
    meta["fit"] = dict(meta["fit"], calibration_id=new_id)
    meta["refit_of"] = str((out_dir / "calibration.json").resolve())
    write_meta(new_dir, meta)
    new_cal, paths = refit(new_dir, progress=progress, lock=False)
    progress(f"{out_dir / 'calibration.json'} is kept as it was (a session that recorded it "
             f"stays resumable); the refit differs from it, so it is a new calibration {new_id} "
             f"in {new_dir}: give --calibration {paths['calibration']} to new sessions and "
             "renders")
    return new_cal, paths
