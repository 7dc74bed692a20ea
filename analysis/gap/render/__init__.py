"""Render layer: photos of the physical spheres vs their fitted Ward renders.

Input: the gloss fit's output folder (``OUT_DIR/residuals/*.npz``, one per gloss level, with
float32 ``photo``, ``render``, ``diffuse``, ``specular`` (h x w x 3, linear, photo units) and
boolean masks ``highlight``, ``body``, ``rim``, ``background``, ``sphere``, ``valid``), and, if
there, ``OUT_DIR/fit.json``, whose ``setup`` gives the camera's distance and the sphere's radius
(cm). Everything is compared in Rec. 709 luminance.

The plain simulation predicts the photo by the render ``R = B + D + S`` (background, the
panorama around the sphere, which reaches into the rim's edge pixels; diffuse; specular). Each
candidate is an image-space or component-space extension (approximations, documented):

=================  ===========================================================================
candidate          extension (c = fitted amplitude; geometry from the sphere mask, orthographic
                   unless noted)
=================  ===========================================================================
fresnel            S * (1 + c (1 - cos t)^5): Schlick's rise towards grazing view, with the
                   view angle t (cos t = sqrt(1 - r^2), r = distance from the sphere's centre in
                   radii) standing in for the half-vector angle
clearcoat          D * (1 + c (T(t) g - 1)), T = (1 - F(t)) / (1 - F(0)), F the exact
                   Fresnel reflectance of a coat of IOR 1.5: diffuse light leaves through the
                   coat at the view angle t, dimmed towards grazing, having entered it at the
                   light's angles: g = E_T / E, the irradiance weighted by T at entry over the
                   plain irradiance; g = 1 (entry "surround": a uniform surround, its entry
                   loss in rho_d), T(t) ("view": light along the view), ("lights") from the
                   diffuse shading fitted as a surround (spherical harmonics of bands 0-1) plus
                   a round key light (direction and half-angle searched from the highlight's
                   mirror direction), or ("mirror") from the room as the glossiest level's
                   specular render mirrors it (each pixel's light from its mirror direction);
                   T g normalised at the centre; the entry chosen by the fit. Normals and
                   view directions are a pinhole's when the folder's fit.json gives the
                   camera distance and sphere radius (the gloss fit's setup), else
                   orthographic
vignetting         R * (1 - c rho^2 - c2 rho^4), rho = distance from the image centre / half
                   diagonal (two terms of real lenses' calibration polynomial)
veiling_glare      R + c G_s * R: a blurred copy of the image spread by the lens (Gaussian, s
                   from a grid of large widths, or a power law (1 + (r / w)^2)^(-3/2) with a
                   narrow core w, from a grid)
misregistration    R shifted by (dx, dy) px per gloss level: the radiance by cubic splines, the
                   silhouette's pixel coverage recomputed at the shifted sphere
long_tail          S + c (W - S): highlight energy moved into wider wings W, either the lobe
                   blurred (Gaussian, 1-8 px, or a GTR1 haze's kernel 1 / (1 + (r / w)^2),
                   w 2-16 px), raised to a power k < 1 (a Ward lobe of alpha / sqrt(k)), or
                   a less glossy level's specular render (the same room through a wider
                   lobe: a haze reflects the room into the body, where the lobe itself shows
                   little of it), at the same energy; c and the form (from a grid) per
                   gloss level, as the tails' width follows the lobe's
=================  ===========================================================================

With every extension the Ward fit's diffuse and specular scales (its rho_d, rho_s) are fitted
again per level, as the gloss fit would have done had it known the effect.

Loss: Gaussian NLL per pixel on the sphere (highlight, body, rim; valid pixels) with a
Poisson-Gaussian noise model per level, ``sd^2 = a2 + b R`` (read noise and shot noise of the
camera; the render's Monte-Carlo noise grows with the signal too), measured from the second
differences of photo - render (:func:`noise_model`; a smooth misfit drops out), so the floor is
``0.5 log(2 pi sd^2) + 0.5`` per pixel. A constant SD would count a highlight's shot noise as a
gap. Held out: pixels in a checkerboard of 4 x 4 blocks (half train, half test) in every level.

Each candidate is one object registered with the engine (``register("render", ...)``): its fit,
its term (``apply``, in the registration order), its injector (the effect built into a Mitsuba
material or the camera, drawn with the benchmark's renderer), its default strength and the
parameters a right fit recovers. The ceiling (:func:`render_ceiling`) is the chosen model plus a
local smooth of what it leaves; a chosen model that stays significantly above it leaves a gap
outside the catalogue.

Files (each imports only those above it; the model is the bottom, as the reader measures each
photo's noise with its noise model):

=============  ===============================================================================
model.py       the photo's noise model, the effects' image-forming forms, the extended render
               and its likelihood (Gaussian NLL), pixel units and the held-out split, and the
               fit helpers the candidates share (the diffuse and specular scales' fit)
data.py        reading and checking the residual files and fit.json (:func:`load_render`,
               :class:`RenderData`) with the geometry and the coat's entry factors computed
               once per level
ceiling.py     the floor, the ceiling (:func:`render_ceiling`) and the remaining misfit's size
               (:func:`render_misfit_pct`), with the thresholds for what counts
where.py       where the misfit lies (:func:`render_where`, :func:`localise_render`,
               :func:`residual_maps`)
Under directional lights (a directional-light gloss fit, ``--lights``): the fit's lights
train, lights it never saw test (``data.load_lights``); one material, so one pair of scales
for all lights (``model._shared_scaled_fit``); the ceiling a cross-fitted smooth of each
held-out photo (``ceiling.light_ceiling``); the broad_lobe candidate (a second Ward lobe,
``model.ward_lobe``), registered as catalogue ``render_lights`` as its form needs each photo's
light; the clearcoat a whole coat there (``candidates._fit_coat_lights``: the diffuse light
through it, T(n.l) T(n.v) at full strength, and the coated surface's second lobe, the base's
beneath the coat's or the coat's above the base's, in broad_lobe's forms); the held-out misfit
in % (``ceiling.misfit_pct``) in diagnosis.json. A panorama set in
several lightings (``--lights NAME``, ``data.load_lighting``): the fit's lighting trains, the
held-out lighting's photos test, with the whole catalogue and the same ceiling and sizes.
candidates.py  one registered Candidate per effect (its term, fit and injector), in the order
               their terms apply
=============  ===============================================================================

``__init__.py`` (here)
    The layer's face to the engine, :func:`plan` (the same in every layer).

Importing the package registers the candidates (the engine's ``catalogue("render")`` imports
it).
"""

# The private names are re-exported for the tests that reach them (as before the split).
import json
from pathlib import Path

import numpy as np

from analysis.gap.engine import DiagnosisSettings, LayerFunctions, LayerPlan, catalogue
from analysis.gap.render.candidates import LIGHT_CANDIDATES, RENDER_CANDIDATES
from analysis.gap.render.ceiling import (
    RENDER_MIN_GAIN,
    RENDER_MIN_SHARE,
    RENDER_SIZE_UNIT,
    light_ceiling,
    material_shift,
    misfit_pct,
    render_ceiling,
    render_floor,
    render_misfit_pct,
    render_misfit_upper,
)
from analysis.gap.render.data import (
    NPZ_ARRAYS,
    NPZ_MASKS,
    RenderData,
    load_lighting,
    load_lights,
    load_render,
)
from analysis.gap.render.model import (
    render_loss,
    render_unit_ids,
    split_render,
)
from analysis.gap.render.optics.sphere import noise_model, noise_sd
from analysis.gap.render.power import render_power
from analysis.gap.render.where import localise_render, render_where, residual_maps

__all__ = [
    "NPZ_ARRAYS",
    "NPZ_MASKS",
    "RENDER_CANDIDATES",
    "RENDER_MIN_GAIN",
    "RENDER_MIN_SHARE",
    "RENDER_SIZE_UNIT",
    "RenderData",
    "load_render",
    "localise_render",
    "noise_model",
    "noise_sd",
    "plan",
    "render_ceiling",
    "render_floor",
    "render_loss",
    "render_misfit_pct",
    "render_misfit_upper",
    "render_power",
    "render_unit_ids",
    "render_where",
    "residual_maps",
    "split_render",
]


def plan(real, sim, design, rng: np.random.Generator, *, n_boot: int, lights=None,
         **_) -> LayerPlan:
    """Photos from REAL's and renders from SIM's ``residuals/*.npz`` (the gloss fit's output
    folder, usually the same; SIM None: REAL's), or loaded residual files, split once into
    training and held-out blocks drawn from ``rng``. A directional-light fit
    (:mod:`analysis.gap.render.lights`): with ``lights`` (e.g. ``"25-48"``) REAL is the photo
    set and those lights, which the fit never saw, are held out. A panorama fit of one
    lighting of several (:mod:`stimuli.glossfit.lightings`): ``lights`` names the lighting
    held out. A remaining gap counts only
    from the design's ``[gap] render_tolerance_pct`` (the shipped design's when ``design`` is
    None); no gap that matters only where the misfit's upper 95 % bound
    (:func:`render_misfit_upper`) lies below it; else inconclusive, with the misfit these
    photos detect and how many more decide (:func:`render_power`). Named effects are held to
    the tolerance too (``tolerate_chosen``, as in the display layer): where nothing
    significant remains beyond them, the plain render's own misfit decides (its bound below
    the tolerance: no gap that matters, the effects named in the words; its point below:
    inconclusive). Photos of thousands of pixels make a lobe's slight misshape significant
    (blind seed 1002's plain Ward sphere: "broad_lobe" at 0.17 % of the photos' RMS)."""
    from stimuli.glossfit import is_lighting_fit

    paths = isinstance(real, (str, Path))
    fit_dir = sim if sim is not None else real
    light_mode = lights is not None or (paths and is_light_fit(fit_dir))
    candidates, split, ceiling = (), "", render_ceiling
    if lights is not None and paths and is_lighting_fit(fit_dir):
        # A panorama set photographed in several lightings: one held out (the whole catalogue).
        train, test, split = load_lighting(real, fit_dir, lights)
        ceiling, shown = light_ceiling, test
    elif light_mode:
        train, test, split = load_lights(real, sim, lights)
        candidates = (tuple(c for c in catalogue("render") if c.name in LIGHT_CANDIDATES)
                      + tuple(catalogue("render_lights")))
        if lights is not None:
            ceiling = light_ceiling
        shown = test
    else:
        data = load_render(real, sim if sim is not None else real) if paths else real
        train, test = split_render(data, rng)
        shown = data
    if design is None:
        from studydesign import load_design

        design = load_design()
    functions = LayerFunctions(
        loss=render_loss, floor=render_floor, ceiling=ceiling, ceiling_given_chosen=True,
        where=render_where, size=render_misfit_pct, size_upper=render_misfit_upper,
        absorbed=material_shift,
        unit_ids=render_unit_ids,
        # Each held-out pixel its own cluster: the tests' normal limit, with no Monte-Carlo
        # error (the split is fixed, so the verdict does not depend on the seed). Under the
        # null of nothing systematic left, the pixels' camera noise is independent.
        cluster_of=str)
    settings = DiagnosisSettings(n_boot=n_boot, min_share=RENDER_MIN_SHARE,
                                 min_gain=RENDER_MIN_GAIN,
                                 min_size=design.gap.render_tolerance_pct,
                                 size_unit=RENDER_SIZE_UNIT,
                                 size_source="the design's [gap] render_tolerance_pct",
                                 size_without_noise_model=True, tolerate_chosen=True)

    def chosen(diag):
        return [(s["added"], s["params"]) for s in diag.steps]

    def localise(diag, rng):
        local = localise_render(shown, rng, n_boot=min(n_boot, 500))
        local.attrs["maps"] = residual_maps(_some(shown, _MAX_MAPS), chosen(diag))
        return local

    def sizes(diag):
        return {"misfit_pct_before": misfit_pct(test, []),
                "misfit_pct_after": misfit_pct(test, chosen(diag))}
    noun = ("held-out lights' photos" if light_mode and lights is not None
            else "photos (levels or lights)")
    return LayerPlan(functions, settings, localise=localise, train=train, test=test,
                     split=split, candidates=candidates, sizes=sizes,
                     power=lambda diag: render_power(test, diag, noun=noun),
                     loss_info={"noise_a2_b": _noise_by_name(train, test)})


#: At most this many levels (held-out lights) drawn in the report's residual maps.
_MAX_MAPS = 8


def _noise_by_name(train: RenderData, test: RenderData) -> dict:
    """Each level's noise model (a2, b) by name; a held-out lighting's levels, named as the
    fit's, as ``NAME (held out)``."""
    out = {lv["name"]: lv["noise"] for lv in train.levels}
    for lv in test.levels:
        seen = lv["name"] in out and lv["noise"] is not out[lv["name"]]
        out[f"{lv['name']} (held out)" if seen else lv["name"]] = lv["noise"]
    return out


def is_light_fit(folder) -> bool:
    """True when ``folder`` holds a directional-light gloss fit (fit.json kind "lights")."""
    try:
        return json.loads((Path(folder) / "fit.json").read_text()).get("kind") == "lights"
    except (OSError, json.JSONDecodeError, AttributeError):
        return False


def _some(data: RenderData, n: int) -> RenderData:
    """``data`` with at most ``n`` of its levels, evenly spaced (the report's maps)."""
    if len(data.levels) <= n:
        return data
    idx = np.unique(np.linspace(0, len(data.levels) - 1, n).round().astype(int))
    return RenderData([data.levels[i] for i in idx])
