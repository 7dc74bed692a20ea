"""Pass 2 of a render: each light field's EXRs tone-mapped with one curve into PNGs, manifest rows
and its line of ``tonemaps.csv`` (:mod:`stimuli.pipeline`'s module docstring has the folder
layout). :class:`TonemapWriter` runs it on a thread beside pass 1, a light field as soon as its
last EXR is logged, so that the next light field renders while the previous one is tone-mapped
and written (on a GPU the PNG pass took 36 % of the wall time of a run when it came after).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from labfiles import read_csv_records
from stimuli.errors import StimuliError
from stimuli.illumination import read_exr
from stimuli.manifest import (
    TONEMAP_COLUMNS,
    append_manifest_row,
    load_manifest,
    record_tone_curves,
    sha256_file,
)
from stimuli.renderjob import RenderJob
from stimuli.tonemap import (
    display_fraction,
    gamma_encode,
    luminance_range,
    tone_curve,
    tone_curve_record,
    write_png,
)

__all__ = ["LOG_TEXT", "TONEMAP_COLUMNS", "TonemapWriter", "progress_bar", "record_tone_curves",
           "tonemap_light_fields"]

#: Render-log columns read as text (a checksum of digits and one "e" would read as a number).
LOG_TEXT = {"stimulus_id": str, "exr_sha256": str, "envmap_sha256": str}


def progress_bar(total: int, desc: str, enabled: bool):
    """A tqdm progress bar on stderr (disabled when not ``enabled`` or nothing to do)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="img", disable=not enabled or total == 0,
                file=sys.stderr, dynamic_ncols=True, smoothing=0.1)


def tonemap_light_fields(out: Path, plan: pd.DataFrame, job: RenderJob, calibration,
                         tonemap_spec, progress: bool,
                         calibration_sha256: str) -> tuple[int, int, Path]:
    """Pass 2: tone map each light field's EXRs with one curve (its largest luminance), write
    the PNGs and append their manifest rows. Returns (PNGs written, skipped, manifest path).

    Raises
    ------
    StimuliError
        If the manifest already lists a stimulus rendered or tone-mapped differently, or a listed
        PNG is missing or changed (recorded data are never overwritten).
    """
    records = read_csv_records(out / "renders.csv", dtype=LOG_TEXT)
    records = records.drop_duplicates("stimulus_id", keep="last").set_index("stimulus_id")
    manifest_path = out / "manifest.csv"
    existing = load_manifest(manifest_path) if manifest_path.exists() else None
    have = {} if existing is None else existing.set_index("stimulus_id").to_dict("index")
    bar = progress_bar(len(plan), "tone map PNG", progress)
    n_png = n_png_skipped = 0
    curves = []
    try:
        for lf, group in plan.groupby("light_field", sort=False):
            # streamed (one image in memory at a time): a light field of the imagestats set
            # holds thousands of EXRs
            lmax = max(luminance_range([read_exr(out / p)]) for p in group["exr_path"])
            curve = tone_curve(tonemap_spec, lmax)
            first = group.iloc[0]
            curves.append({"light_field": lf, "illumination": first["illumination"],
                           "envmap": first["envmap"],
                           "envmap_sha256": records.loc[first["stimulus_id"], "envmap_sha256"],
                           "envmap_scale": first.get("envmap_scale", float("nan")),
                           "n_images": len(group), **tone_curve_record(curve)})
            for row in group.itertuples(index=False):
                rec = records.loc[row.stimulus_id]
                prior = have.get(row.stimulus_id)
                if prior is not None:
                    if (not np.isclose(prior["tonemap_lmax"], lmax, rtol=1e-6)
                            or prior["exr_sha256"] != rec["exr_sha256"]):
                        raise StimuliError(
                            f"{manifest_path} already lists {row.stimulus_id} rendered or "
                            f"tone-mapped differently (L_max {prior['tonemap_lmax']:.6g} vs "
                            f"{lmax:.6g}); recorded data are never overwritten: render into a new "
                            "--out folder")
                    png = out / row.png_path
                    if png.is_file() and sha256_file(png) == prior["png_sha256"]:
                        n_png_skipped += 1
                        bar.update(1)
                        continue
                    raise StimuliError(
                        f"{png} is missing or changed but {manifest_path} lists it; recorded data "
                        "are never overwritten: render into a new --out folder")
                lum = read_exr(out / row.exr_path)
                u8 = gamma_encode(display_fraction(lum, curve), calibration)
                png = out / row.png_path
                png.parent.mkdir(parents=True, exist_ok=True)
                write_png(png, u8)
                append_manifest_row(manifest_path, {
                    "stimulus_id": row.stimulus_id, "illumination": row.illumination,
                    "gloss_level": int(row.gloss_level), "depth_level": int(row.depth_level),
                    "true_gloss_pct": row.true_gloss_pct, "true_depth_cm": row.true_depth_cm,
                    "light_field": row.light_field, "array_index": int(row.array_index),
                    "seed": int(row.seed), "rho_d": row.rho_d, "rho_s": row.rho_s,
                    "alpha": row.alpha, "spp": int(rec["spp"]), "width_px": job.size_px,
                    "height_px": job.size_px, "image_width_cm": job.camera.image_width_cm,
                    "variant": rec["variant"], "envmap": row.envmap,
                    "calibration_id": calibration.calibration_id, "exr_path": row.exr_path,
                    "png_path": row.png_path, "exr_sha256": rec["exr_sha256"],
                    "png_sha256": sha256_file(png), "envmap_sha256": rec["envmap_sha256"],
                    "rotation_deg": row.rotation_deg, "tonemap_lmax": lmax,
                    "distance_cm": job.camera.distance_cm,
                    "calibration_sha256": calibration_sha256,
                })
                n_png += 1
                bar.update(1)
    finally:
        bar.close()
    record_tone_curves(out / "tonemaps.csv", curves)
    return n_png, n_png_skipped, manifest_path


class TonemapWriter:
    """Pass 2 beside pass 1: one thread tone-maps each light field (its PNGs, manifest rows and
    curve) as soon as its last EXR is logged, while the next light field renders; the queue
    holds light-field names only. ``started``: light field -> when its tone map began
    (``time.monotonic``)."""

    def __init__(self, out: Path, plan: pd.DataFrame, job: RenderJob, tonemap: dict):
        from concurrent.futures import ThreadPoolExecutor

        self.out, self.plan, self.job, self.tonemap = out, plan, job, tonemap
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tonemap")
        self.futures, self.started = [], {}

    def _run(self, lf: str) -> tuple[int, int, Path]:
        self.started[lf] = time.monotonic()
        t = self.tonemap
        return tonemap_light_fields(self.out, self.plan[self.plan["light_field"] == lf], self.job,
                             t["calibration"], t["tonemap_spec"], False,
                             t["calibration_sha256"])

    def submit(self, lf: str) -> None:
        self.futures.append(self.pool.submit(self._run, lf))

    def close(self) -> None:
        self.pool.shutdown(wait=True)

    def counts(self) -> tuple[int, int]:
        """(PNGs written, skipped) by the thread; raises what a tone map raised."""
        results = [f.result() for f in self.futures]
        return sum(r[0] for r in results), sum(r[1] for r in results)


