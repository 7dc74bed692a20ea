"""Offline stimulus rendering: ellipsoid arrays, Ward BSDF, Mitsuba, tone mapping, gloss fitting.

Public API (what the other packages and the lab's scripts use; everything else is imported from
its module, e.g. ``stimuli.ward.ward_brdf``)
----------
setup_mitsuba
    Select the Mitsuba variant (mono for achromatic sets), register ``ward``, smoke-test.
read_exr, write_exr, load_light_probe, SHIPPED_PROBES
    HDR light probes (lat-long OpenEXR) -> Mitsuba ``envmap`` emitters.
GLOSS_TABLE_COLUMNS, load_gloss_table, write_gloss_table, default_gloss_table,
ward_params_for_gloss
    The gloss table: gloss % -> Ward parameters (rho_d, rho_s, alpha).
draw_array, stimulus_seed, write_mesh
    The ellipsoid array (from the design and a seed) and its watertight print mesh.
camera_geometry, CameraGeometry, StimulusRenderer
    Camera at the viewing distance showing the array at its physical size; the reusable scene.
tone_curve, gamma_encode
    The source study's tone map (linear + asymptotic logistic) and the calibration's inverse gamma.
render_set, RenderJob, contact_sheet
    Render a set into a folder (Dask, resumable); tile its PNGs.
stimulus_set, SET_NAMES, parse_filters, apply_filters
    Named stimulus sets.
MANIFEST_COLUMNS, load_manifest, verify_manifest, append_manifest_row, sha256_file
    The render manifest (what the experiment shows and checks).
StimuliError, MitsubaSetupError, IlluminationError, GlossTableError, ManifestError
    Errors (all ``ValueError`` subclasses).
"""

from stimuli.contactsheet import contact_sheet
from stimuli.errors import GlossTableError, IlluminationError, MitsubaSetupError, StimuliError
from stimuli.geometry import draw_array, stimulus_seed, write_mesh
from stimuli.glosstable import (
    GLOSS_TABLE_COLUMNS,
    default_gloss_table,
    load_gloss_table,
    ward_params_for_gloss,
    write_gloss_table,
)
from stimuli.illumination import SHIPPED_PROBES, load_light_probe, read_exr, write_exr
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
from stimuli.render import CameraGeometry, StimulusRenderer, camera_geometry
from stimuli.sets import SET_NAMES, apply_filters, parse_filters, stimulus_set
from stimuli.tonemap import gamma_encode, tone_curve

__all__ = [
    "GLOSS_TABLE_COLUMNS",
    "MANIFEST_COLUMNS",
    "SET_NAMES",
    "SHIPPED_PROBES",
    "CameraGeometry",
    "GlossTableError",
    "IlluminationError",
    "ManifestError",
    "MitsubaSetupError",
    "RenderJob",
    "StimuliError",
    "StimulusRenderer",
    "append_manifest_row",
    "apply_filters",
    "camera_geometry",
    "contact_sheet",
    "default_gloss_table",
    "draw_array",
    "gamma_encode",
    "load_gloss_table",
    "load_light_probe",
    "load_manifest",
    "parse_filters",
    "read_exr",
    "render_set",
    "setup_mitsuba",
    "sha256_file",
    "stimulus_seed",
    "stimulus_set",
    "tone_curve",
    "verify_manifest",
    "ward_params_for_gloss",
    "write_exr",
    "write_gloss_table",
    "write_mesh",
]
