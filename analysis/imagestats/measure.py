"""Statistics of one image and of a batch of manifest rows (the unit of work sent to Dask)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from analysis.imagestats.config import StatsConfig
from analysis.imagestats.images import ImageStatsError, read_luminance
from analysis.imagestats.pixelstats import pixel_statistics
from analysis.imagestats.portilla import ps_names, ps_statistics
from analysis.imagestats.region import ps_window, stimulus_region

__all__ = ["measure_batch", "measure_image"]


def measure_image(luminance: np.ndarray, *, image_width_cm: float, extent_cm: float,
                  config: StatsConfig) -> dict[str, float]:
    """All statistics of one luminance image, on its stimulus region.

    Parameters
    ----------
    luminance : ndarray, shape (height, width)
        The render's luminance (linear, the EXR's CIE Y).
    image_width_cm : float
        Width of the image on the array's plane, cm (manifest column).
    extent_cm : float
        Side of the array square, cm (``design.array.extent_cm``).
    config : StatsConfig
        Highlight threshold and Portilla-Simoncelli options.

    Returns
    -------
    dict
        ``region_px`` (side of the region), the pixel statistics (`PIXEL_STATS`), and with
        ``config.ps`` ``texture_window_px`` (side of the PS window) and one ``ps_*`` value per
        Portilla-Simoncelli statistic.

    Raises
    ------
    ValueError
        If the region does not fit, holds bad values, or is too small for the PS pyramid.
    """
    lum = np.asarray(luminance, dtype=np.float64)
    rows, cols = stimulus_region(lum.shape[1], lum.shape[0], image_width_cm=image_width_cm,
                                 extent_cm=extent_cm)
    region = lum[rows, cols]
    out: dict[str, float] = {"region_px": float(region.shape[0])}
    out.update(pixel_statistics(region, highlight_factor=config.highlight_factor))
    if config.ps:
        win = ps_window(region.shape[0], n_scales=config.ps_n_scales)
        kwargs = {"n_scales": config.ps_n_scales, "n_orientations": config.ps_n_orientations,
                  "spatial_corr_width": config.ps_spatial_corr_width}
        values = ps_statistics(region[win, win], **kwargs)
        out["texture_window_px"] = float(win.stop - win.start)
        out.update(zip(ps_names(win.stop - win.start, **kwargs), values.tolist()))
    return out


def measure_batch(rows: list[dict], root: str, extent_cm: float,
                  config_json: str) -> tuple[list[dict], list[tuple[str, str]]]:
    """Statistics of a batch of manifest rows; runs on a Dask worker.

    Every image either yields a record (its manifest row, its statistics and ``stats_s``, the
    seconds spent on it) or a problem ``(stimulus_id, message)``; one bad image never costs the
    rest of the batch.
    """
    config = StatsConfig.from_json(config_json)
    if config.ps:
        import torch

        torch.set_num_threads(1)  # one Dask worker = one core
    records, problems = [], []
    for row in rows:
        start = time.perf_counter()
        sid = str(row["stimulus_id"])
        path = Path(root) / str(row["exr_path"])
        try:
            lum = read_luminance(path, sha256=row["exr_sha256"])
            expected = (int(row["height_px"]), int(row["width_px"]))
            if lum.shape != expected:
                raise ImageStatsError(
                    f"{path} is {lum.shape[1]}x{lum.shape[0]} px but the manifest says "
                    f"{expected[1]}x{expected[0]}; re-render it or fix the manifest"
                )
            stats = measure_image(lum, image_width_cm=float(row["image_width_cm"]),
                                  extent_cm=extent_cm, config=config)
        except ImageStatsError as exc:
            problems.append((sid, str(exc)))
            continue
        except Exception as exc:  # noqa: BLE001 - listed per image, never lost (docstring)
            problems.append((sid, f"{path}: {type(exc).__name__}: {exc}"))
            continue
        stats["stats_s"] = time.perf_counter() - start
        records.append({**row, **stats})
    return records, problems
