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
ImageStatsObserver
    Perceived gloss predicted from image statistics (a candidate observer for the sim-to-real
    diagnosis): ``ImageStatsObserver.fit(stats, trials)``, ``.predict(stats)``,
    ``.predict_trials(trials, stats)``, JSON round trip.
stat_table, depth_effects, DepthEffect, gloss_regression, join_perception, cell_means,
ps_components, SCALAR_STATS
    Relating the statistics to depth and perceived gloss.
light_field_effects, light_field_spread, light_field_means
    How each statistic follows gloss and depth within and across light fields (indoor vs
    outdoor), and the statistics per light field.
build_relate_report
    The HTML report (``python -m analysis imagestats relate``).
"""

from analysis.imagestats.config import StatsConfig
from analysis.imagestats.images import ImageStatsError, read_luminance
from analysis.imagestats.lightfields import (
    light_field_effects,
    light_field_means,
    light_field_spread,
)
from analysis.imagestats.measure import measure_image
from analysis.imagestats.observer import ImageStatsObserver
from analysis.imagestats.pixelstats import PIXEL_STATS, pixel_statistics
from analysis.imagestats.portilla import ps_names, ps_statistics
from analysis.imagestats.region import stimulus_region
from analysis.imagestats.relate import (
    SCALAR_STATS,
    DepthEffect,
    cell_means,
    depth_effects,
    gloss_regression,
    join_perception,
    ps_components,
    stat_table,
)
from analysis.imagestats.report import build_relate_report
from analysis.imagestats.run import StatsRun, compute_stats, dask_client, problems_path
from analysis.imagestats.store import load_stats

__all__ = [
    "PIXEL_STATS",
    "SCALAR_STATS",
    "DepthEffect",
    "ImageStatsError",
    "ImageStatsObserver",
    "StatsConfig",
    "StatsRun",
    "build_relate_report",
    "cell_means",
    "compute_stats",
    "dask_client",
    "depth_effects",
    "gloss_regression",
    "join_perception",
    "light_field_effects",
    "light_field_means",
    "light_field_spread",
    "load_stats",
    "measure_image",
    "pixel_statistics",
    "problems_path",
    "ps_components",
    "ps_names",
    "ps_statistics",
    "read_luminance",
    "stat_table",
    "stimulus_region",
]
