"""Render folders of known images for the image-statistics tests (real EXR/PNG files and a real
manifest written with ``stimuli.append_manifest_row``).

Each image's array square is a two-level image: a fraction ``p`` of its pixels at ``high``, the
rest at ``low``, in random places. Its statistics are known in closed form (the Bernoulli
distribution, scaled): with q = 1 - p, mean = low + p (high - low), RMS contrast =
(high - low) sqrt(pq) / mean, skewness = (q - p) / sqrt(pq), Pearson kurtosis = (1 - 3pq) / (pq),
and for p < 1/2 the median is ``low``, so the highlight coverage is p when high > factor * low.
Outside the square the image holds ``BORDER``, which would spoil every statistic if the stimulus
region were wrong.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image

from stimuli import MANIFEST_COLUMNS, append_manifest_row, sha256_file

BORDER = 50.0
EXTENT_CM = 5.0  # the shipped design's array.extent_cm (checked by the tests)


def expected_stats(p: float, low: float, high: float, factor: float = 2.0) -> dict:
    q = 1.0 - p
    mean = low + p * (high - low)
    return {
        "mean_luminance": mean,
        "rms_contrast": (high - low) * np.sqrt(p * q) / mean,
        "skewness": (q - p) / np.sqrt(p * q),
        "kurtosis": (1 - 3 * p * q) / (p * q),
        "highlight_coverage": p if high > factor * low else 0.0,
        "diffuse_luminance": low,
    }


def two_level_image(rng, *, side_px: int, width_px: int, height_px: int, p: float, low: float,
                    high: float) -> np.ndarray:
    """A width x height luminance image whose centred side x side square is two-level."""
    n = side_px * side_px
    square = np.full(n, low, dtype=np.float32)
    square[rng.permutation(n)[: round(p * n)]] = high
    img = np.full((height_px, width_px), BORDER, dtype=np.float32)
    top, left = (height_px - side_px) // 2, (width_px - side_px) // 2
    img[top:top + side_px, left:left + side_px] = square.reshape(side_px, side_px)
    return img


def write_exr(path: Path, luminance: np.ndarray, channel: str = "Y") -> None:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {channel: np.ascontiguousarray(luminance, dtype=np.float32)}).write(
        str(path))


def write_render_set(folder: Path, rng, *, n_images: int, side_px: int = 128,
                     width_px: int = 160, height_px: int = 144,
                     cells: list | None = None) -> dict:
    """Write ``n_images`` known images, their PNGs and ``folder/manifest.csv``.

    Returns
    -------
    dict
        stimulus_id -> (p, low, high) of each image.
    """
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "exr").mkdir(exist_ok=True)
    (folder / "png").mkdir(exist_ok=True)
    params = {}
    for k in range(n_images):
        illumination, gloss, depth = (cells[k] if cells else
                                      (("indoor", "outdoor")[k % 2], 2 + k % 9, 2 + (k // 9) % 9))
        # float32 values and a whole number of bright pixels, so the closed forms are exact
        p = round(float(rng.uniform(0.02, 0.3)) * side_px**2) / side_px**2
        low = float(np.float32(rng.uniform(0.5, 2.0)))
        high = float(np.float32(low * rng.uniform(2.5, 10.0)))
        sid = f"{illumination}_g{gloss:02d}_d{depth:02d}_lf00_a{k:02d}"
        img = two_level_image(rng, side_px=side_px, width_px=width_px, height_px=height_px,
                              p=p, low=low, high=high)
        exr = folder / "exr" / f"{sid}.exr"
        png = folder / "png" / f"{sid}.png"
        write_exr(exr, img)
        Image.fromarray(np.clip(img / img.max() * 255, 0, 255).astype(np.uint8)).save(png)
        # columns the renderer may add beyond these stay empty
        append_manifest_row(folder / "manifest.csv", dict.fromkeys(MANIFEST_COLUMNS, "") | {
            "stimulus_id": sid, "illumination": illumination, "gloss_level": gloss,
            "depth_level": depth, "true_gloss_pct": 10.0 * (gloss - 1),
            "true_depth_cm": 0.4 * depth, "light_field": 0, "array_index": k, "seed": 1000 + k,
            "rho_d": 0.3, "rho_s": 0.05, "alpha": 0.1, "spp": 16, "width_px": width_px,
            "height_px": height_px, "image_width_cm": EXTENT_CM * width_px / side_px,
            "variant": "test", "envmap": "none", "calibration_id": "default",
            "exr_path": f"exr/{sid}.exr", "png_path": f"png/{sid}.png",
            "exr_sha256": sha256_file(exr), "png_sha256": sha256_file(png),
        })
        params[sid] = (p, low, high)
    return params
