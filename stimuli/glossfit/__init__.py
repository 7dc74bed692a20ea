"""Gloss fitting: Ward parameters of the physical gloss spheres from HDR photos.

Pipeline: ``load_photo_set`` (envmap.exr, photos/gloss_XXX.exr, setup.toml; checked) ->
``register`` each photo to a reference render (the source study's affine Nelder-Mead) -> ``grid_fit``
(the source study's shrinking grid) or ``basis_fit`` (closed-form albedos from basis renders, 1-D alpha
search; same optimum, far fewer renders) -> residuals by region -> ``gloss_table_from_fits``
(common albedo, rho_s on a line in gloss with leave-one-out errors). ``fit_gloss`` runs it all
and writes the output folder; ``synth_photo_set`` renders test photo sets.

Photos of one sphere under directional lights (DiLiGenT's layout): ``load_light_set``,
``fit_lights`` (Ward through Mitsuba renders of each light), ``predict_lights`` (the fitted
material under lights the fit never saw; ``read_light_fit`` reads its fit.json),
``synth_light_set``. A panorama set photographed in several lightings: ``is_lighting_fit``,
``predict_lighting`` (the fitted levels rendered in a held-out lighting).

Command lines: ``python -m stimuli fit-gloss`` (``--lights`` for a directional-light set),
``python -m stimuli synth-photos`` and ``python -m stimuli synth-lights``.
"""

from stimuli.glossfit.fit import FitRun, fit_gloss, fit_level
from stimuli.glossfit.lightfit import fit_lights, predict_lights, read_light_fit
from stimuli.glossfit.lightings import is_lighting_fit, predict_lighting
from stimuli.glossfit.lightset import LightSet, load_light_set, parse_lights
from stimuli.glossfit.lightsynth import synth_light_set
from stimuli.glossfit.methods import BasisCache, FitSettings, LevelFit, basis_fit, grid_fit
from stimuli.glossfit.output import FITS_COLUMNS, write_residuals
from stimuli.glossfit.photoset import (
    GlossFitError,
    PhotoSet,
    PhotoSetup,
    load_photo_set,
    load_setup,
    photo_name,
)
from stimuli.glossfit.registration import Registration, register, warp_photo
from stimuli.glossfit.residuals import region_masks
from stimuli.glossfit.scene import Camera, SphereScene, fit_camera, photo_camera, sphere_distance_px
from stimuli.glossfit.synth import EFFECTS, MATERIALS, parse_effects, room_panorama, synth_photo_set
from stimuli.glossfit.table import gloss_table_from_fits, line_with_loo

__all__ = [
    "EFFECTS",
    "FITS_COLUMNS",
    "MATERIALS",
    "BasisCache",
    "Camera",
    "FitRun",
    "FitSettings",
    "GlossFitError",
    "LevelFit",
    "LightSet",
    "PhotoSet",
    "PhotoSetup",
    "Registration",
    "SphereScene",
    "basis_fit",
    "fit_camera",
    "fit_gloss",
    "fit_level",
    "fit_lights",
    "gloss_table_from_fits",
    "grid_fit",
    "is_lighting_fit",
    "line_with_loo",
    "load_light_set",
    "load_photo_set",
    "load_setup",
    "parse_effects",
    "parse_lights",
    "photo_camera",
    "photo_name",
    "predict_lighting",
    "predict_lights",
    "read_light_fit",
    "region_masks",
    "register",
    "room_panorama",
    "sphere_distance_px",
    "synth_light_set",
    "synth_photo_set",
    "warp_photo",
    "write_residuals",
]
