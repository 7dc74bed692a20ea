"""Image statistics of the render set, on Dask, and their relation to perceived gloss.

Public API
----------
compute_stats, StatsRun, StatsConfig, dask_client, problems_path
    Per-image statistics of a render folder into a resumable Parquet table
    (``python -m analysis imagestats``).
load_stats, ImageStatsError
    Read a table; the error every bad input raises.
measure_image, pixel_statistics, ps_statistics, ps_names, stimulus_region, read_luminance,
PIXEL_STATS
    The statistics of one image.
"""

from analysis.imagestats.config import StatsConfig
from analysis.imagestats.images import ImageStatsError, read_luminance
from analysis.imagestats.measure import measure_image
from analysis.imagestats.pixelstats import PIXEL_STATS, pixel_statistics
from analysis.imagestats.portilla import ps_names, ps_statistics
from analysis.imagestats.region import stimulus_region
from analysis.imagestats.run import StatsRun, compute_stats, dask_client, problems_path
from analysis.imagestats.store import load_stats

__all__ = [
    "PIXEL_STATS",
    "ImageStatsError",
    "StatsConfig",
    "StatsRun",
    "compute_stats",
    "dask_client",
    "load_stats",
    "measure_image",
    "pixel_statistics",
    "problems_path",
    "ps_names",
    "ps_statistics",
    "read_luminance",
    "stimulus_region",
]
