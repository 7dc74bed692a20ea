"""Real files for the session app's tests: a small stimulus manifest of real PNGs and a fresh
calibration, made through the stimuli and calibration public APIs (no renderer needed)."""

from __future__ import annotations

import dataclasses
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from PIL import Image

from calibration import default_calibration, save_calibration
from stimuli import MANIFEST_COLUMNS, append_manifest_row, sha256_file

#: Stimulus PNGs are this many pixels square, shown this wide (cm) on the CRT.
SIZE_PX = 64
WIDTH_CM = 8.0
#: The stimulus colour in tests: a saturated green no slider element uses.
GREEN = (40, 200, 60)


def make_calibration(folder: Path, design, *, calibration_id="test", age_days=1.0,
                     white_cd_m2: float | None = None, gamma: float | None = None) -> Path:
    """A calibration (the default CRT curve, or one of another white and gamma: a display that
    drifted) dated ``age_days`` ago, saved as JSON."""
    created = (datetime.now(UTC) - timedelta(days=age_days)).strftime("%Y-%m-%dT%H:%M:%SZ")
    cal = dataclasses.replace(default_calibration(design), calibration_id=calibration_id,
                              created_utc=created, monitor_name="glossdepth-test")
    if white_cd_m2 is not None or gamma is not None:
        white = white_cd_m2 if white_cd_m2 is not None else cal.max_luminance_cd_m2
        g = gamma if gamma is not None else cal.gamma_params["gamma"]
        black = cal.gamma_params["a"]
        cal = dataclasses.replace(cal, max_luminance_cd_m2=white, gamma_params={
            "a": black, "b": 0.0, "k": (white - black) ** (1 / g), "gamma": g})
    return save_calibration(cal, Path(folder) / "calibration.json")


def make_manifest(folder: Path, design, *, calibration_id="test", stimulus_ids=None,
                  size_px: int = SIZE_PX, width_cm: float = WIDTH_CM,
                  calibration_sha256: str = "") -> Path:
    """Write one real PNG per stimulus and a manifest listing them; returns the manifest path.

    Each PNG is a green square with a darker border and a stripe pattern unique to its stimulus.
    """
    folder = Path(folder)
    (folder / "png").mkdir(parents=True, exist_ok=True)
    manifest = folder / "manifest.csv"
    stim = design.stimuli()
    if stimulus_ids is not None:
        stim = stim[stim["stimulus_id"].isin(stimulus_ids)]
    for k, row in enumerate(stim.itertuples(index=False)):
        img = np.zeros((size_px, size_px, 3), np.uint8)
        img[:] = GREEN
        img[:, :: 2 + k % 7] = (20, 120, 40)
        img[:4], img[-4:], img[:, :4], img[:, -4:] = 10, 10, 10, 10
        png = folder / "png" / f"{row.stimulus_id}.png"
        Image.fromarray(img).save(png)
        values = {c: "" for c in MANIFEST_COLUMNS}
        values.update(
            stimulus_id=row.stimulus_id, illumination=row.illumination,
            gloss_level=row.gloss_level, depth_level=row.depth_level,
            true_gloss_pct=row.true_gloss_pct, true_depth_cm=row.true_depth_cm,
            light_field=row.illumination, array_index=0, seed=k, rho_d=0.1, rho_s=0.05,
            alpha=0.1, spp=1, width_px=size_px, height_px=size_px, image_width_cm=width_cm,
            variant="test", envmap="none", calibration_id=calibration_id,
            exr_path="", exr_sha256="", png_path=f"png/{row.stimulus_id}.png",
            png_sha256=sha256_file(png), calibration_sha256=calibration_sha256,
        )
        append_manifest_row(manifest, values)
    return manifest
