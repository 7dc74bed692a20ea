"""Offline stimulus rendering: ellipsoid arrays, Ward BSDF, Mitsuba, tone mapping, gloss fitting.

Public API
----------
The names below are what code outside the package uses: the experiment's preflight checks and the
image statistics read the render manifest; the benchmarks in ``bench/`` build scenes and render
sets. Everything else is imported from its module, which is named for what it holds:
``stimuli.ward`` (the BSDF and its closed form, ``ward_brdf``), ``stimuli.glosstable``
(``load_gloss_table``, ``write_gloss_table``, ``GLOSS_TABLE_COLUMNS``), ``stimuli.illumination``
(``read_exr``, ``write_exr``, ``SHIPPED_PROBES``), ``stimuli.sets`` (``parse_filters``,
``SET_NAMES``), ``stimuli.render`` (``CameraGeometry``), ``stimuli.tonemap`` (``gamma_encode``),
``stimuli.geometry`` (``write_mesh``), ``stimuli.contactsheet``, ``stimuli.noise``,
``stimuli.glossfit``, ``stimuli.dask_cluster`` (``open_client``, ``finished``,
``add_cluster_arguments``, ``JobSpec``, ``ClusterError``: Dask workers as labs start them, also
for ``analysis imagestats``), and ``stimuli.errors`` (``StimuliError`` and its subclasses, all
``ValueError``).

setup_mitsuba
    Select the Mitsuba variant (mono for achromatic sets), register ``ward``, smoke-test.
load_light_probe
    An HDR light probe (lat-long OpenEXR) for a Mitsuba ``envmap`` emitter.
default_gloss_table, ward_params_for_gloss
    The gloss table: gloss % -> Ward parameters (rho_d, rho_s, alpha).
draw_array, stimulus_seed
    The ellipsoid array, from the design and a seed.
camera_geometry, StimulusRenderer
    Camera at the viewing distance showing the array at its physical size; the reusable scene.
tone_curve
    The source study's tone map (linear + asymptotic logistic).
render_set, RenderJob
    Render a set into a folder (Dask, resumable).
stimulus_set, apply_filters
    Named stimulus sets, and a subset of one.
MANIFEST_COLUMNS, load_manifest, verify_manifest, append_manifest_row, sha256_file, ManifestError
    The render manifest (what the experiment shows and checks).
"""

from stimuli.geometry import draw_array, stimulus_seed
from stimuli.glosstable import default_gloss_table, ward_params_for_gloss
from stimuli.illumination import load_light_probe
from stimuli.manifest import (
    MANIFEST_COLUMNS,
    ManifestError,
    append_manifest_row,
    load_manifest,
    sha256_file,
    verify_manifest,
)
from stimuli.mitsuba_env import setup_mitsuba
from stimuli.pipeline import RenderJob, render_set
from stimuli.render import StimulusRenderer, camera_geometry
from stimuli.sets import apply_filters, stimulus_set
from stimuli.tonemap import tone_curve

__all__ = [
    "MANIFEST_COLUMNS",
    "ManifestError",
    "RenderJob",
    "StimulusRenderer",
    "append_manifest_row",
    "apply_filters",
    "camera_geometry",
    "default_gloss_table",
    "draw_array",
    "load_light_probe",
    "load_manifest",
    "render_set",
    "setup_mitsuba",
    "sha256_file",
    "stimulus_seed",
    "stimulus_set",
    "tone_curve",
    "verify_manifest",
    "ward_params_for_gloss",
]
